//! The stress-free reference of a membrane's shear elasticity as [`super::skalak`] keeps it
//! inside a [`super::membrane::Membrane`]: its metric on the upsampled grid and the scratch of
//! the tension tensor.

/// The reference metric on the order-`q` grid and the scratch for the tension tensor.
pub(super) struct Reference {
    /// Its order-`p` coefficients.
    pub(super) coefs: Vec<f64>,
    /// `[E, F, G]` of the reference surface.
    pub(super) metric: Vec<[f64; 3]>,
    /// `W_ref / W` is needed for the energy; `W_ref` here.
    pub(super) w: Vec<f64>,
    /// Six tension components (xx, xy, xz, yy, yz, zz), each `nq` values.
    pub(super) tau: Vec<f64>,
    pub(super) ctau: Vec<f64>,
    pub(super) dt: Vec<f64>,
    pub(super) dp: Vec<f64>,
}

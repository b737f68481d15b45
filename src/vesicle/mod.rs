//! Cells as spherical-harmonic surfaces: shapes, surface geometry and membrane mechanics.
//!
//! A cell membrane is a closed surface `X(θ, φ) = Σ_{n≤p} x̂_nm Y_n^m(θ, φ)` (one expansion per
//! Cartesian component, see [`Surface`]) sampled on the Gauss–Legendre × uniform grid of order `p`
//! ([`crate::sph_harmonics::Grid`]). Following MOBO (Veerapaneni, Rahimian, Biros & Zorin,
//! *A fast algorithm for simulating vesicle flows in three dimensions*, J. Comput. Phys. 230,
//! 2011) and Zhao, Isfahani, Olson & Freund (*A spectral boundary integral method for flowing
//! blood cells*, J. Comput. Phys. 229, 2010), every derivative is spectral: the grid values of
//! `X_θ, X_φ, X_θθ, X_θφ, X_φφ` come from the inverse transform with derivative matrices.
//!
//! ## Geometry ([`geometry`])
//!
//! * metric `E = X_θ·X_θ`, `F = X_θ·X_φ`, `G = X_φ·X_φ`; area element `W = |X_θ × X_φ| = √(EG − F²)`;
//! * outward normal `n = X_θ × X_φ / W` (for the standard parametrisation, `θ` from the north pole,
//!   this is outward; an inward-oriented surface is reported as an error);
//! * second fundamental form `L = X_θθ·n`, `M = X_θφ·n`, `N = X_φφ·n`;
//! * **sign convention**: mean curvature `H = (EN − 2FM + GL) / (2W²)` (the *average* of the
//!   principal curvatures) and Gaussian curvature `K = (LN − M²)/W²`, so that a sphere of radius
//!   `R` has `H = −1/R`, `K = 1/R²`, and `Δ_s X = 2H n`;
//! * with `g^{θθ} = G/W²`, `g^{θφ} = −F/W²`, `g^{φφ} = E/W²`: surface gradient
//!   `∇_s f = g^{ij} f_i X_j`, surface divergence `∇_s·v = g^{ij} X_i·v_j`, Laplace–Beltrami
//!   `Δ_s f = g^{ij} f_ij − (g^{ij} X_ij)·∇_s f` (the Christoffel terms are the tangential part
//!   of `X_ij`);
//! * integrals: `∫ f dA = Σ_{i,k} w_i (π/p) f W / sin θ_i` (Gauss–Legendre weights `w_i` in
//!   `cos θ`; `W / sin θ` is the area per unit solid angle). Volume `V = ⅓∫ X·n dA`, centroid
//!   `c = (1/4V) ∫ X (X·n) dA`, inertia of the enclosed solid (unit density) from
//!   `∫_V r_i r_j dV = ⅕ ∫ r_i r_j (r·n) dA`, `r = X − c`;
//! * reduced volume `v = 6√π V / A^{3/2}` (1 for a sphere) and *equivalent radius*
//!   `R_eq = (3V/4π)^{1/3}`, the radius of the sphere of equal **volume**.
//!
//! ## Membrane forces ([`Membrane`])
//!
//! Forces are densities per unit current area, computed on the upsampled grid of order `q`
//! (default `2p`; the surface is band-limited at `p`, so its geometry on the fine grid is exact)
//! and filtered back to order `p` (forward transform at `q`, truncation to degree `p`, inverse at
//! `p`) against aliasing. Each is the negative variational derivative of its energy:
//! `∫ f·δX dA = −δE` for every smooth `δX` (checked by finite differences in the tests).
//!
//! * Helfrich bending, `E_b = (κ_b/2) ∫ (2H)² dA`, force
//!   `f_b = −2κ_b (Δ_s H + 2H(H² − K)) n` (this is the design's `−κ_b(Δ_s H + 2H(H² − K)) n` with
//!   its energy `κ_b ∫ H² dA`; the factor 2 comes from using the average, not the sum, of the
//!   principal curvatures); also as the operator linearised at frozen geometry,
//!   `Y ↦ −2κ_b (Δ_s H_Y + 2H_Y(H² − K)) n` with `H_Y = ½ n·Δ_s Y` (exact at `Y = X`), as used by
//!   the semi-implicit step of Veerapaneni et al. (2011).
//! * Tension (Lagrange multiplier of local inextensibility), `E_σ = ∫ σ dA` with `σ` attached to
//!   material points: `f_σ = ∇_s σ + 2σH n`; the constraint is `∇_s·u = 0`.
//! * Skalak shear elasticity (Skalak, Tozeren, Zarda & Chien, Biophys. J. 13, 1973) relative to a
//!   stress-free reference surface with the same parametrisation: with `A` the reference metric
//!   and `a` the current one, `I₁ = tr(A⁻¹a) − 2`, `J² = det a / det A`, `I₂ = J² − 1`,
//!   `W_s = (G_s/4)(I₁² + 2I₁ − 2I₂ + C I₂²)`, `E_s = ∫ W_s dA_ref`. The Cauchy tension is
//!   `τ = T^{ij} X_i ⊗ X_j`, `T^{ij} = (G_s/J)[(I₁+1)A^{ij} + J²(C I₂ − 1) a^{ij}]`, and the force is
//!   its surface divergence `f_k = ∇_s·(τ e_k)`.
//!
//! Singular integrals (the cell's own Stokes layer potentials) use the rotations of
//! [`crate::sph_harmonics::rotation`] and the Graham–Sloan rule (Graham & Sloan, *Fully discrete
//! spectral boundary integral methods for Helmholtz problems on smooth closed surfaces in ℝ³*,
//! Numer. Math. 92, 2002).
//!
//! ## Layout
//!
//! Vector fields on the grid (positions, forces, velocities) are stored component-major:
//! the `np` values of `x`, then of `y`, then of `z` (`np = 2p(p+1)`), like a batch of three
//! functions for [`crate::sph_harmonics::ShTransform`]; coefficients likewise.
//!
//! ```
//! use mobo::vesicle::{shapes, SurfaceCalculus};
//! // The biconcave red blood cell (Evans–Fung profile, unit equivalent radius).
//! let rbc = shapes::rbc(16).unwrap();
//! let mut calc = SurfaceCalculus::new(16).unwrap();
//! let g = calc.geometry(rbc.coefs()).unwrap();
//! assert!((g.equivalent_radius() - 1.0).abs() < 3e-5);
//! assert!((g.reduced_volume() - 0.644).abs() < 2e-3);
//! ```

pub mod bending;
pub mod coefficient_operator;
pub mod far_side;
pub mod geometry;
pub mod layer;
pub mod layer_kernel;
pub mod material_labels;
pub mod membrane;
pub mod mesh;
pub mod near;
mod point;
pub mod reparam;
pub mod shapes;
pub mod skalak;
mod skalak_reference;
pub mod smooth_layer;
pub mod smooth_sources;
pub mod surface_distance;
pub mod tank_treading;
pub mod tension;
pub mod vector_field;

pub use coefficient_operator::CoefficientOperator;
pub use geometry::{Geometry, SurfaceCalculus};
pub use layer::{LayerKernel, RotationAlgorithm, SelfInteraction};
pub use membrane::Membrane;
pub use mesh::CellMesh;
pub use near::{NearParams, OffSurface, TargetInfo};
pub use reparam::{reparametrize, ReparamParams, ReparamReport, Reparametrizer};
pub use shapes::{Spheroid, Surface};
pub use skalak::SkalakParams;

use crate::sph_harmonics::SphError;

/// Errors of the cell-surface routines.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum VesicleError {
    /// An error of the underlying spherical-harmonic routines.
    #[error(transparent)]
    Sph(#[from] SphError),
    /// A buffer of the wrong length.
    #[error("{what} has {len} values, expected {expected}")]
    Length {
        /// The buffer.
        what: &'static str,
        /// Its length.
        len: usize,
        /// The length needed.
        expected: usize,
    },
    /// A parameter outside its domain.
    #[error("invalid {name} = {value}: {reason}")]
    Parameter {
        /// The parameter.
        name: &'static str,
        /// Its value.
        value: f64,
        /// The domain it is outside of.
        reason: &'static str,
    },
    /// The operator rows over coefficients need a quadrature order above the surface order.
    #[error(
        "the operator rows over coefficients need an upsampled order q > p (here q = p = {p})"
    )]
    NotUpsampled {
        /// Surface order (= quadrature order).
        p: usize,
    },
    /// The quadrature (upsampled) order is below the surface order.
    #[error("upsampled order q = {q} is below the surface order p = {p}")]
    Order {
        /// Surface order.
        p: usize,
        /// Quadrature order.
        q: usize,
    },
    /// A surface whose parametrisation degenerates or is inward-oriented.
    #[error("degenerate surface: {0}")]
    Degenerate(String),
    /// A matrix that is not a proper rotation.
    #[error("not a rotation matrix (|RᵀR − I| = {0:.2e} or det ≠ 1)")]
    NotRotation(f64),
    /// An operation that needs state set first (e.g. a geometry or a reference surface).
    #[error("{0} must be set first")]
    Missing(&'static str),
}

/// Check the length of a buffer.
pub(crate) fn check_len(
    what: &'static str,
    len: usize,
    expected: usize,
) -> Result<(), VesicleError> {
    if len == expected {
        Ok(())
    } else {
        Err(VesicleError::Length {
            what,
            len,
            expected,
        })
    }
}

/// `a · b`.
#[inline]
pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a × b`.
#[inline]
pub(crate) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Point `j` of a component-major vector field with `np` points per component.
#[inline]
pub(crate) fn get3(v: &[f64], np: usize, j: usize) -> [f64; 3] {
    [v[j], v[np + j], v[2 * np + j]]
}

/// Store point `j` of a component-major vector field.
#[inline]
pub(crate) fn set3(v: &mut [f64], np: usize, j: usize, x: [f64; 3]) {
    v[j] = x[0];
    v[np + j] = x[1];
    v[2 * np + j] = x[2];
}

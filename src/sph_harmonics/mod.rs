//! Spherical harmonics on the Gauss–Legendre × uniform grid.
//!
//! Every cell surface in `mobo` is a vector function on the unit sphere expanded in real
//! spherical harmonics of degree `≤ p`. This module provides:
//!
//! * [`Grid`]: `p+1` Gauss–Legendre latitudes × `2p` uniform longitudes (`2p(p+1)` points);
//! * [`ShTransform`]: batched forward/inverse transforms and grid derivatives (`∂θ, ∂φ, ∂θθ, ∂θφ,
//!   ∂φφ`): a real FFT along latitudes and one Legendre GEMM per order `m` over many functions;
//! * [`resample`]: resampling between orders and spectral filters;
//! * [`rotation`]: rotations that carry a grid point to the north pole, direct and via
//!   spherical harmonics;
//! * [`GrahamSloan`]: weights for on-surface `1/r`-singular integrals;
//! * [`mod@reference`]: naive implementations used as test oracles.
//!
//! ```
//! use mobo::sph_harmonics::ShTransform;
//! let sht = ShTransform::new(8).unwrap();
//! let mut ws = sht.workspace();
//! // f = z = cos θ on the grid
//! let grid = sht.grid();
//! let f: Vec<f64> = (0..grid.n_points()).map(|j| grid.angles(j).0.cos()).collect();
//! let mut a = vec![0.0; sht.n_coefs()];
//! sht.forward(&f, &mut a, &mut ws).unwrap();
//! // cos θ = √(4π/3) Y_1^0
//! let i = sht.layout().index(1, 0).unwrap();
//! assert!((a[i] - (4.0 * std::f64::consts::PI / 3.0).sqrt()).abs() < 1e-14);
//! let mut back = vec![0.0; f.len()];
//! sht.inverse(&a, &mut back, &mut ws).unwrap();
//! assert!(back.iter().zip(&f).all(|(x, y)| (x - y).abs() < 1e-14));
//! ```

pub mod basis;
pub mod grid;
pub mod layout;
pub mod legendre;
pub mod reference;
pub mod resample;
pub mod rotation;
pub mod singular;
pub mod transform;

pub use grid::Grid;
pub use layout::CoefLayout;
pub use resample::{resample_coefs, Filter, Resampler};
pub use rotation::{DirectRotation, ShRotation};
pub use singular::GrahamSloan;
pub use transform::{Deriv, PhaseTimings, ShTransform, ShWorkspace};

/// Errors of the spherical-harmonic routines.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum SphError {
    /// The order must be at least 1.
    #[error("spherical-harmonic order must be at least 1, got {0}")]
    InvalidOrder(usize),
    /// Grid data is not a whole number of functions.
    #[error("grid data has {len} values, not a multiple of {per_function} per function")]
    GridLength {
        /// Values given.
        len: usize,
        /// Grid points per function.
        per_function: usize,
    },
    /// Coefficient data does not match the batch.
    #[error("coefficient data has {len} values, expected {expected}")]
    CoefLength {
        /// Values given.
        len: usize,
        /// Values expected.
        expected: usize,
    },
    /// Different numbers of requested derivatives and output buffers.
    #[error("{derivs} derivatives requested but {outputs} output buffers given")]
    OutputCount {
        /// Derivatives requested.
        derivs: usize,
        /// Output buffers given.
        outputs: usize,
    },
    /// A workspace made for another plan or block size.
    #[error("workspace was made for a different transform plan")]
    Workspace,
    /// Coefficients of a higher order than the transform's grid resolves.
    #[error(
        "coefficients of order {order} do not fit the grid of a transform of order {transform}"
    )]
    LayoutOrder {
        /// The coefficients' order.
        order: usize,
        /// The transform's order.
        transform: usize,
    },
    /// The output order of a rotation must not be below the input order.
    #[error("rotation output order q = {q} is below the input order p = {p}")]
    UpsampleOrder {
        /// Input order.
        p: usize,
        /// Output order.
        q: usize,
    },
    /// A latitude outside the grid or whose rotation was not built.
    #[error("latitude {lat} is outside the grid of order {p} or was not built")]
    Latitude {
        /// The latitude index asked for.
        lat: usize,
        /// The grid's order.
        p: usize,
    },
}

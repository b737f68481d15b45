//! Brownian dynamics with hydrodynamic interactions.
//!
//! Beads of radius `a` in a solvent of viscosity `η` at temperature `k_BT` move by the
//! Ermak–McCammon scheme with the Rotne–Prager–Yamakawa diffusion tensor ([`rpy`]). The
//! correlated noise comes from the Geyer–Winter TEA-HI approximation in one fused `O(N²)` pass
//! ([`tea_hi`]), or, as references, from an exact Cholesky factor or a Lanczos square root
//! ([`noise`]); free draining (no HI) is there for comparison. Forces: harmonic bonds, overlap
//! repulsion, the sub-cellular-element potential and external forces ([`forces`]).
//!
//! ```
//! use mobo::brownian::{BrownianParams, BrownianSimulation, ForceField, NoiseModel};
//! let params = BrownianParams {
//!     radius: 1.0, kt: 1.0, viscosity: 1.0 / (6.0 * std::f64::consts::PI), dt: 1e-3,
//!     noise: NoiseModel::TeaHi, seed: 7,
//! };
//! assert!((params.d0() - 1.0).abs() < 1e-15);
//! let ff = ForceField { bonds: vec![(0, 1)], bond_stiffness: 50.0, bond_length: 4.0,
//!                       repulsion: 50.0, radius: 1.0, ..Default::default() };
//! let mut sim = BrownianSimulation::new(params, vec![[0.0; 3], [4.0, 0.0, 0.0]], ff).unwrap();
//! for _ in 0..100 { sim.step().unwrap(); }
//! assert_eq!(sim.steps, 100);
//! ```
//!
//! The seam for a GPU version is [`tea_hi::row_sums`]: one target's four partial sums over all
//! sources from structure-of-arrays inputs, nothing stored between pairs.

pub mod forces;
pub mod gpu_pass;
pub mod integrator;
pub mod noise;
pub mod observables;
pub mod rpy;
pub mod tea_hi;

pub use forces::{ForceField, SubcellularElement};
pub use integrator::{BrownianParams, BrownianSimulation, NoiseModel};
pub use tea_hi::TeaHiCoefficients;

/// Errors of the Brownian dynamics module.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum BrownianError {
    /// A parameter is out of range.
    #[error("invalid parameter: {0}")]
    Parameter(String),
    /// The mobility matrix is not positive definite (should not happen for RPY).
    #[error("mobility matrix is not positive definite")]
    NotPositiveDefinite,
    /// TEA-HI's expansion does not exist for this coupling strength.
    #[error("TEA-HI breaks down at step {step}: mean coupling ε = {epsilon:.4} is too strong (A > 1); use exact or Lanczos noise")]
    TeaHiBreakdown {
        /// Step number at which it happened.
        step: u64,
        /// Mean off-diagonal coupling `ε` of the diffusion tensor.
        epsilon: f64,
    },
    /// A position became NaN or infinite.
    #[error("particle {particle} left the finite numbers at step {step} (time step too large?)")]
    NonFinite {
        /// Step number at which it happened.
        step: u64,
        /// Index of the first non-finite bead.
        particle: usize,
    },
    /// Exchanging rows between MPI ranks failed.
    #[error("{0}")]
    Comm(#[from] crate::comm::CommError),
    /// The GPU pass failed or was asked for where there is none.
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
}

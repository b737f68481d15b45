//! Dissipative particle dynamics (DPD) with explicit solvent, and visco-elastic membranes on
//! triangle meshes: the model of Mirheo (Alexeev et al. 2020) on the same cells as the
//! boundary-integral solver.
//!
//! # The fluid ([`pair_force`], [`system`])
//! Particles `i, j` closer than `r_c` interact by the pair force (Groot & Warren 1997; Español
//! & Warren 1995)
//!
//! ```text
//! F_ij = a w(r) e − γ w(r)^{2k} (v_ij·e) e + σ w(r)^k ξ_ij / √dt e,
//! w = 1 − r/r_c,  σ² = 2γ k_BT,  e = r_ij / r,  v_ij = v_i − v_j,
//! ```
//!
//! with `k` the kernel exponent (`k = 1`: Groot–Warren; `k = 1/4`: Fedosov's softer kernel),
//! `ξ_ij = ξ_ji` a random number of zero mean and unit variance drawn from a counter-based
//! generator keyed on `(seed, step, min(id), max(id))` ([`rng`]), so the trajectory does not
//! depend on thread count, rank count or particle order. Cell lists are rebuilt every step
//! (particles sorted by cell, structure of arrays, [`cell_list`]), time steps are
//! velocity-Verlet in a periodic box, with body forces (the periodic "reverse" Poiseuille force
//! of Backer et al. 2005 measures the viscosity, [`poiseuille`]).
//!
//! # Membranes ([`membrane`])
//! A cell is the triangulated surface of its spherical-harmonic shape (the icosphere mapped onto
//! it); its vertices are particles with spring (WLC + POW), bending (Kantor–Nelson or Jülicher),
//! area and volume forces, and membrane viscosity (Fedosov, Caswell & Karniadakis 2010), the
//! parameters mapped from the physical moduli.
//!
//! # Example
//!
//! ```
//! use mobo::dpd::pair_force::PairParams;
//! use mobo::dpd::system::{BodyForce, DpdParams, DpdSystem};
//!
//! let pair = PairParams { a: 25.0, gamma: 4.5, kbt: 1.0, rc: 1.0, power: 1.0 };
//! let params = DpdParams { box_len: [5.0; 3], pair, dt: 0.01, mass: 1.0, seed: 1 };
//! let mut fluid = DpdSystem::random_fluid(params, 3.0, BodyForce::None)?;
//! for _ in 0..20 {
//!     fluid.step()?;
//! }
//! assert_eq!(fluid.len(), 375);
//! println!("k_BT = {:.3}, p = {:.2}", fluid.kinetic_temperature(), fluid.pressure());
//! # Ok::<(), mobo::dpd::DpdError>(())
//! ```

mod bounce;
pub mod cell_list;
pub mod contact;
pub mod crossing;
pub mod fluid_cell;
#[cfg(feature = "gpu")]
pub mod gpu_fluid;
#[cfg(feature = "gpu")]
pub mod gpu_pairs;
pub mod membrane;
pub mod pair_force;
pub mod poiseuille;
pub mod rng;
pub mod suspension;
pub mod system;
pub mod walls;

/// Errors of the DPD module.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DpdError {
    /// A parameter outside its domain.
    #[error("invalid {name} = {value}: {reason}")]
    Parameter {
        /// The parameter's name.
        name: &'static str,
        /// The value given.
        value: f64,
        /// The condition it breaks.
        reason: &'static str,
    },
    /// Buffers that disagree in length.
    #[error("{what} has {len} values, expected {expected}")]
    Length {
        /// The buffer, in words.
        what: &'static str,
        /// Its length.
        len: usize,
        /// The length expected.
        expected: usize,
    },
    /// A mesh that is not a closed, consistently oriented triangulation.
    #[error("bad membrane mesh: {0}")]
    Mesh(String),
    /// A particle left the box by more than one box length in a step, or became non-finite:
    /// the time step is too large for the forces.
    #[error("unstable at step {step}: particle {particle} at {position:?} (time step too large?)")]
    Unstable {
        /// Step number at which it happened.
        step: u64,
        /// Index of the particle.
        particle: usize,
        /// Its position.
        position: [f64; 3],
    },
    /// The GPU path failed (no adapter, a size it cannot take, a failed submission).
    #[error("DPD on the GPU: {0}")]
    Gpu(#[from] crate::gpu::GpuError),
}

/// Check a parameter: `Ok` when `ok`, else a [`DpdError::Parameter`].
pub(crate) fn require(
    ok: bool,
    name: &'static str,
    value: f64,
    reason: &'static str,
) -> Result<(), DpdError> {
    if ok {
        Ok(())
    } else {
        Err(DpdError::Parameter {
            name,
            value,
            reason,
        })
    }
}

//! Rigid boundaries as boundary integrals: containers and rigid bodies with a prescribed
//! surface velocity, by the completed double layer.
//!
//! ## The representation
//!
//! The fluid (viscosity `μ`) fills the region inside at most one closed **container** surface
//! `S_0` and outside any number of closed **bodies** `S_k` (rigid particles, obstacles). On
//! every surface the velocity `U` is prescribed. The velocity in the fluid is written as
//!
//! ```text
//! u(x) = Σ_k D_k[ψ_k](x) + Σ_bodies (1/8π) [ G(x − c_k) a_k + (b_k × r) / r³ ],   r = x − c_k,
//! D[ψ](x) = (3/4π) ∫ (r·n)(r⊗r)/r⁵ ψ dA,   G(r) = I/r + r⊗r/r³,
//! a_k = ∫_{S_k} ψ_k dA,   b_k = ∫_{S_k} (y − c_k) × ψ_k dA,
//! ```
//!
//! with `n` the outward normal of each surface (the convention of [`crate::vesicle::layer`]),
//! `c_k` a body's centroid, and the double-layer densities `ψ_k` (velocities) the unknowns.
//! The double layer alone is second kind but incomplete: on a body, `½ψ + K ψ` annihilates the
//! six rigid motions, and inside a container `−½ψ + K ψ` misses the normal direction. Power &
//! Miranda (*Second kind integral equation formulation of Stokes' flows past a particle of
//! arbitrary shape*, SIAM J. Appl. Math. 47, 1987) complete it with the Stokeslet and rotlet
//! above for each body; a container gets the rank-one term `n(x) (1/A_0) ∫ n·ψ dA` on its own
//! equation (Pozrikidis, *Boundary Integral and Singularity Methods for Linearized Viscous
//! Flow*, 1992, §6.4). With the jumps `D_in = D_PV − ψ/2`, `D_out = D_PV + ψ/2` the equations are
//!
//! ```text
//! container:  −½ψ_0 + K_00 ψ_0 + n (1/A_0) ∫ n·ψ_0 dA + Σ_{k≠0} D_k[ψ_k] + completions = U_0,
//! body k:     +½ψ_k + K_kk ψ_k + Σ_{j≠k} D_j[ψ_j] + completions = U_k.
//! ```
//!
//! A container's data must carry no net flux (`∫ U·n dA = 0`: the fluid is incompressible and
//! the rigid bodies' own motions carry none); then `∫ n·ψ_0 dA = 0` and the rank-one term
//! vanishes. The completions have a meaning: a body exerts the force `F_k = μ a_k` and the
//! torque `T_k = μ b_k` on the fluid (the double layer carries neither), so the drag on a body
//! comes with the solve.
//!
//! ## Discretisation
//!
//! Every surface is a spherical-harmonic surface of order `p`, like a cell
//! ([`crate::vesicle`]). Its own block `K_kk` is the singular (rotated Graham–Sloan) quadrature
//! of [`crate::vesicle::layer::SelfInteraction`]. The blocks between surfaces are the smooth
//! quadrature on the source surface upsampled to an order `q` chosen per pair from the
//! distance (the error falls like `exp(−c d/h)` in the distance over the spacing `h` of the
//! upsampled grid; a pair too close for the largest order is refused, not silently
//! inaccurate). The whole system is dense, assembled once and factored once
//! ([`WallSystem`]); every new boundary velocity is then one solve. Over MPI ranks it can
//! instead be split by bands of the walls' latitudes, each rank assembling and holding its rows
//! and the factors of their diagonal block, and solved by GMRES over the ranks ([`WallRows`]). The velocity at points in
//! the fluid uses the near-singular evaluation of [`crate::vesicle::near`] for each surface.
//!
//! ## Checked against
//!
//! `tests/walls.rs`: the interior field of a Stokeslet outside a spherical and an ellipsoidal
//! container (exact), a translating and rotating sphere in free space (Stokes' drag and torque,
//! and the field), and a sphere at the centre of a spherical container against the exact drag
//! of Williams (1915) / Haberman & Sayre (1958), `K = (1 − λ⁵)/(1 − 9λ/4 + 5λ³/2 − 9λ⁵/4 + λ⁶)`;
//! Poiseuille's flow through a [`tube_surface`] (exact), and a sphere on the axis of the tube
//! against the drag of Haberman & Sayre (1958) and Bohlin (1960); plane Poiseuille flow between
//! the plates of a [`channel_surface`] (exact), and a sphere midway between them against
//! Faxén's drag (Happel & Brenner 1965, eq. 7-4.39).
//!
//! ```
//! use mobo::vesicle::shapes;
//! use mobo::wall::{Wall, WallKind, WallParams, WallSystem};
//! // A unit sphere translating along x in free space: the drag is Stokes', 6πμaU.
//! let sphere = Wall::new(WallKind::Body, shapes::sphere(8, 1.0).unwrap()).unwrap();
//! let system = WallSystem::new(vec![sphere], WallParams::default()).unwrap();
//! let u: Vec<f64> = (0..3)
//!     .flat_map(|a| vec![if a == 0 { 1.0 } else { 0.0 }; system.wall(0).n_points()])
//!     .collect();
//! let solution = system.solve(&u).unwrap();
//! let f = solution.force(0, 1.0); // the fluid's force on the sphere: −6πμaU
//! assert!((f[0] + 6.0 * std::f64::consts::PI).abs() < 1e-8);
//! ```

mod channel;
mod field;
mod plane;
mod quadrature;
mod rows;
mod surface;
mod system;
mod tube;

pub use channel::{channel_surface, flat_area, flat_fraction, CHANNEL_EXPONENT};
pub use field::{scatter_add, WallField, NEAR_ZONE};
pub use plane::PlaneWall;
pub use rows::{RowShare, WallBand, WallRows};
pub use surface::{Wall, WallKind};
pub use system::{WallParams, WallSolution, WallSystem, MAX_NET_FLUX};
pub use tube::{straight_length, tube_surface, TUBE_END_EXPONENT};

use crate::vesicle::VesicleError;

/// Errors of the wall solver.
#[derive(Debug, thiserror::Error)]
pub enum WallError {
    /// An error of the surface routines.
    #[error(transparent)]
    Vesicle(#[from] VesicleError),
    /// An error of the spherical-harmonic routines.
    #[error(transparent)]
    Sph(#[from] crate::sph_harmonics::SphError),
    /// No surfaces were given.
    #[error("a wall system needs at least one surface")]
    Empty,
    /// More than one container.
    #[error("walls {first} and {second} are both containers; the fluid has at most one")]
    TwoContainers {
        /// The first container's index.
        first: usize,
        /// The second one's.
        second: usize,
    },
    /// Two surfaces closer than the largest quadrature order resolves, or crossing.
    #[error(
        "walls {target} and {from} are {distance:.3e} apart, closer than the order-{order} \
         quadrature resolves ({needed:.3e} needed)"
    )]
    TooClose {
        /// The target wall.
        target: usize,
        /// The source wall.
        from: usize,
        /// Their distance (grid points of `target` to the upsampled points of `source`).
        distance: f64,
        /// The largest order tried.
        order: usize,
        /// The distance that order resolves.
        needed: f64,
    },
    /// A body outside the container, or two bodies inside one another.
    #[error("wall {index} is not in the fluid: {reason}")]
    Placement {
        /// The wall.
        index: usize,
        /// Why.
        reason: &'static str,
    },
    /// A container's boundary velocity has a net flux.
    #[error(
        "the container's boundary velocity has a net flux ∫U·n dA = {flux:.3e} (relative \
         {relative:.1e}); an incompressible fluid inside a closed wall needs none"
    )]
    NetFlux {
        /// `∫ U·n dA`.
        flux: f64,
        /// Over `∫ |U| dA`.
        relative: f64,
    },
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
    /// A non-finite value in the data or the operator.
    #[error("non-finite value in {what}")]
    NonFinite {
        /// Where.
        what: &'static str,
    },
    /// The assembled operator is numerically singular.
    #[error("the wall operator is singular (smallest/largest pivot {pivot_ratio:.1e})")]
    Singular {
        /// Smallest over largest pivot of the LU factorisation.
        pivot_ratio: f64,
    },
    /// A parameter out of its domain.
    #[error("invalid wall parameter {name} = {value}: {reason}")]
    Parameter {
        /// The parameter.
        name: &'static str,
        /// Its value.
        value: f64,
        /// Why.
        reason: &'static str,
    },
    /// A solve of a system split over ranks asked of one rank alone.
    #[error("the wall system is split over ranks: it is solved over all of them, not by one rank")]
    Split,
    /// A target point outside the fluid.
    #[error("target {index} at {point:?} is not in the fluid ({reason})")]
    NotInFluid {
        /// The target's index.
        index: usize,
        /// The target.
        point: [f64; 3],
        /// Which wall it is on the wrong side of.
        reason: String,
    },
}

fn check_len(what: &'static str, len: usize, expected: usize) -> Result<(), WallError> {
    if len != expected {
        return Err(WallError::Length {
            what,
            len,
            expected,
        });
    }
    Ok(())
}

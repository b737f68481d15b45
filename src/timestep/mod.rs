//! Time stepping: the Krylov layer (linear operators, preconditioners, restarted GMRES), the
//! semi-implicit step of one cell ([`semi_implicit`]: the scheme, Euler or BDF2, any viscosity
//! ratio; [`cell_state`]: what a cell carries from step to step; [`cell_stepper`]: what steps
//! it, in the phases of [`step_phases`]) with its preconditioners (the sphere's,
//! [`sphere_preconditioner`], and the cell's own, [`cell_preconditioner`]); many cells coupled
//! through the FMM ([`suspension`], [`coupling`]) and adaptive `dt` ([`adaptive`]).
//!
//! The semi-implicit step of Veerapaneni, Rahimian, Biros & Zorin (*A fast algorithm for
//! simulating vesicle flows in three dimensions*, J. Comput. Phys. 230, 2011) freezes the
//! bending, tension and self-interaction operators at the current geometry and leaves one
//! nonsymmetric linear system per step, `A x = b`, whose unknowns are the new positions and
//! tensions of all cells. `A` is only available as a product (local operators per cell plus the
//! FMM for the coupling), so it is solved matrix-free by GMRES. Today each cell's system is
//! solved on its own, the other cells' velocity taken explicitly ([`suspension`]).
//!
//! ## Linear operators ([`LinearOperator`])
//!
//! Anything that computes `y = A x` for `x, y ∈ ℝⁿ`: a dense [`faer::Mat`] (or [`faer::MatRef`]),
//! or a closure wrapped in [`FnOperator`]. The trait is `Sync` so that operators can be shared by
//! the worker threads of a parallel product.
//!
//! ## Preconditioners ([`Preconditioner`])
//!
//! A preconditioner applies `z = M⁻¹ v` for an approximation `M ≈ A`. [`Identity`] is `M = I`;
//! [`FnPreconditioner`] wraps a closure (matrix-free `M⁻¹`);
//! [`BlockDiagonal`] is `M = diag(B₁, …, B_K)` with dense square blocks of possibly different sizes,
//! each factored once as `P_k B_k = L_k U_k` (partial pivoting, [`faer::Mat::partial_piv_lu`]) and
//! applied per block as `z_k = U_k⁻¹ L_k⁻¹ P_k v_k`, in parallel over blocks (rayon). This is the
//! structure of the *spectral block-diagonal preconditioner* of Veerapaneni et al. (2011): each
//! block is one cell's self-interaction operator (in MOBO, built on the sphere, where it is
//! diagonal in spherical harmonics); the inter-cell coupling, which is weak and smooth for cells
//! not in contact, is left to the Krylov iteration.
//!
//! ## GMRES ([`gmres`])
//!
//! Restarted GMRES(m) of Saad & Schultz (*GMRES: a generalized minimal residual algorithm for
//! solving nonsymmetric linear systems*, SIAM J. Sci. Stat. Comput. 7, 1986), **right**
//! preconditioned: it solves `A M⁻¹ u = b` and returns `x = x₀ + M⁻¹ u`. With `r₀ = b − A x₀`,
//! `β = ‖r₀‖₂`, `v₁ = r₀/β`, the Arnoldi process on `A M⁻¹` builds an orthonormal basis
//! `V_{j+1} = [v₁ … v_{j+1}]` and the upper Hessenberg `H̄_j ∈ ℝ^{(j+1)×j}` with
//! `A M⁻¹ V_j = V_{j+1} H̄_j`. The iterate is `x_j = x₀ + M⁻¹ V_j y_j` with
//!
//! ```text
//!     y_j = argmin_y ‖β e₁ − H̄_j y‖₂ ,      ‖b − A x_j‖₂ = ‖β e₁ − H̄_j y_j‖₂ ,
//! ```
//!
//! and the least-squares problem is kept triangular by Givens rotations
//! `G_i = [[c_i, s_i], [−s_i, c_i]]` applied to each new column of `H̄` and to `g = β e₁`; after
//! `j` steps `|g_{j+1}|` is the residual norm of `x_j`. Because the preconditioner is applied on the
//! right, this is the residual of the **unpreconditioned** system, so the stopping test
//! `‖b − A x‖₂ ≤ tol ‖b‖₂` means the same with and without a preconditioner.
//!
//! * Orthogonalisation: modified Gram–Schmidt, with a second pass when the norm of `w = A M⁻¹ v_j`
//!   drops below `‖w‖/√2` during the first (the criterion of Daniel, Gragg, Kaufman & Stewart,
//!   Math. Comp. 30, 1976: "twice is enough").
//! * Restart: after `m` steps (or when the residual estimate meets the tolerance) the iterate is
//!   formed, the **true** residual `r = b − A x` is computed (one extra product per cycle, which is
//!   also the start vector of the next cycle), and the solve stops only when the true relative
//!   residual meets the tolerance. The true residual norm is non-increasing across cycles (each
//!   cycle minimises it over a space containing its start).
//! * Memory: a [`GmresWorkspace`] of `(m + 1)` vectors of length `n` plus `O(m²)` scalars is
//!   allocated once and reused; nothing is allocated inside the iteration (the returned
//!   [`GmresReport`] allocates once per solve). Inner products are sequential, so results are
//!   bit-for-bit reproducible for a given operator, preconditioner and input.
//!
//! faer 0.24 has matrix-free conjugate gradients, BiCGSTAB and LSMR (`faer::matrix_free`) but no
//! GMRES, hence this implementation.
//!
//! ## Example
//!
//! ```
//! use faer::Mat;
//! use mobo::timestep::{gmres, GmresParams, GmresWorkspace, Identity};
//!
//! // A small nonsymmetric system A x = b with solution x = (1, 2, 3).
//! let a = Mat::from_fn(3, 3, |i, j| if i == j { 4.0 } else { (i + 2 * j) as f64 * 0.1 });
//! let x_true = [1.0, 2.0, 3.0];
//! let b: Vec<f64> = (0..3).map(|i| (0..3).map(|j| a[(i, j)] * x_true[j]).sum()).collect();
//!
//! let params = GmresParams { tol: 1e-12, restart: 10, max_iters: 100, ..Default::default() };
//! let mut ws = GmresWorkspace::new(3, params.restart);
//! let mut x = vec![0.0; 3];
//! let report = gmres(&a, &Identity::new(3), &b, None, &mut x, &params, &mut ws).unwrap();
//! assert!(report.converged && report.iterations <= 3);
//! assert!(report.relative_residual <= 1e-12);
//! for (xi, ti) in x.iter().zip(x_true) {
//!     assert!((xi - ti).abs() < 1e-10);
//! }
//! ```

pub mod adaptive;
pub mod anderson;
pub mod bead_pair;
pub mod cell_force;
pub mod cell_preconditioner;
pub mod cell_state;
pub mod cell_stepper;
pub mod contact;
pub mod coupling;
pub mod fixed_surface;
mod gmres;
pub mod grid_frame;
pub mod image_quadrature;
pub mod near_images;
pub mod near_implicit;
pub mod near_pairs;
mod operator;
pub mod operator_storage;
mod own_preconditioner;
pub mod plane_coupling;
mod rank_sums;
pub mod semi_implicit;
pub mod sphere_preconditioner;
mod step_engine;
mod step_operator;
pub mod step_phases;
mod step_plan;
pub mod step_solve;
pub mod suspension;
pub mod vesicle_stepper;
pub mod wall_coupling;
pub mod wall_rows_solve;

pub use gmres::{gmres, GmresParams, GmresReport, GmresWorkspace};
pub use operator::{
    BlockDiagonal, FnOperator, FnPreconditioner, Identity, LinearOperator, Preconditioner,
};

/// Errors of the time-stepping layer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TimestepError {
    /// An error of the cell geometry, forces or layer potentials (its message).
    #[error("{0}")]
    Vesicle(String),
    /// A vector or operator whose size does not match the system.
    #[error("size mismatch: {what} has size {got}, expected {expected}")]
    DimensionMismatch {
        /// Which argument.
        what: &'static str,
        /// Size required by the system.
        expected: usize,
        /// Size given.
        got: usize,
    },
    /// An operator or block that is not square.
    #[error("{what} is not square: {nrows}×{ncols}")]
    NotSquare {
        /// Which operator or block.
        what: String,
        /// Rows.
        nrows: usize,
        /// Columns.
        ncols: usize,
    },
    /// A solver parameter outside its valid range.
    #[error("invalid parameter {name} = {value}: {reason}")]
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
        /// Its value, as text.
        value: String,
        /// What is required.
        reason: &'static str,
    },
    /// NaN or infinity in an input, or produced by the operator or preconditioner.
    #[error("non-finite value in {what}")]
    NonFinite {
        /// Where it was found.
        what: &'static str,
    },
    /// A preconditioner block that is singular to working precision.
    #[error(
        "preconditioner block {index} ({size}×{size}) is singular to working precision \
         (min |U_ii| / max |U_ii| = {pivot_ratio:.3e})"
    )]
    SingularBlock {
        /// Index of the block.
        index: usize,
        /// Its size.
        size: usize,
        /// Ratio of smallest to largest pivot magnitude of its LU factor.
        pivot_ratio: f64,
    },
    /// GMRES reached its iteration limit without meeting the tolerance; `x` holds the last iterate.
    #[error(
        "GMRES did not converge: relative residual {:.3e} > tol {:.3e} after {} iterations \
         ({} restarts)",
        .0.relative_residual, .0.tol, .0.iterations, .0.restarts
    )]
    NotConverged(GmresReport),
    /// The Krylov space stopped growing (`h_{j+1,j} = 0`) without meeting the tolerance: the
    /// preconditioned operator is singular on it; `x` holds the last iterate.
    #[error(
        "GMRES breakdown: Krylov space invariant at relative residual {:.3e} > tol {:.3e} after \
         {} iterations (singular operator?)",
        .0.relative_residual, .0.tol, .0.iterations
    )]
    Breakdown(GmresReport),
    /// A full restart cycle lowered the true residual by less than
    /// [`GmresParams::min_cycle_reduction`]: GMRES stopped making progress; `x` holds the last
    /// iterate. The message gives the residual after every cycle.
    #[error(
        "GMRES stagnated: relative residual {:.3e} > tol {:.3e} after {} iterations ({} \
         restarts): the last full restart cycle gained less than the required fraction \
         (residual after each cycle: {})",
        .0.relative_residual, .0.tol, .0.iterations, .0.restarts,
        residual_history(&.0.cycle_residuals)
    )]
    Stagnated(GmresReport),
    /// Communication between ranks failed, or another rank failed (its message).
    #[error("{0}")]
    Comm(#[from] crate::comm::CommError),
    /// The contact projection could not keep the cells `d_min` apart.
    #[error("{0}")]
    Contact(#[from] contact::ContactError),
    /// The walls' solve or evaluation failed (its message; [`crate::wall::WallError`]).
    #[error("walls: {0}")]
    Wall(String),
    /// A cell sent to this rank could not be taken in (its state does not decode, or it is
    /// not one of the run's cells).
    #[error("a cell moving to rank {rank}: {source}")]
    Moved {
        /// The rank taking the cell in.
        rank: usize,
        /// Why its state was refused.
        source: cell_state::CellStateError,
    },
    /// A force of the caller ([`cell_force::CellForce`]) panicked while it added its traction
    /// (the panic is caught: the step fails with this error instead of killing a worker).
    #[error("user force \"{force}\" panicked: {message}")]
    UserForcePanicked {
        /// The force's name.
        force: String,
        /// The panic's message.
        message: String,
    },
    /// A cell's step failed on another rank (its message, agreed by every rank);
    /// `solver_failure` says whether it was a failed linear solve ([`TimestepError::report`]
    /// there), which an adaptive step may retry smaller.
    #[error("(on rank {rank}) {message}")]
    Remote {
        /// The rank whose cell failed.
        rank: usize,
        /// Its error message.
        message: String,
        /// Whether it was a failed linear solve.
        solver_failure: bool,
    },
}

/// The residual history of a solve, shortened to its first three and last five cycles.
fn residual_history(r: &[f64]) -> String {
    let fmt = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:.2e}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    if r.len() <= 8 {
        fmt(r)
    } else {
        format!("{}, … {}", fmt(&r[..3]), fmt(&r[r.len() - 5..]))
    }
}

impl TimestepError {
    /// The solver report carried by [`TimestepError::NotConverged`],
    /// [`TimestepError::Breakdown`] and [`TimestepError::Stagnated`].
    pub fn report(&self) -> Option<&GmresReport> {
        match self {
            TimestepError::NotConverged(r)
            | TimestepError::Breakdown(r)
            | TimestepError::Stagnated(r) => Some(r),
            _ => None,
        }
    }

    /// Whether a linear solve failed (here or, [`TimestepError::Remote`], on another rank):
    /// what an adaptive step retries with a smaller `dt`.
    pub fn is_solver_failure(&self) -> bool {
        match self {
            TimestepError::Remote { solver_failure, .. } => *solver_failure,
            e => e.report().is_some(),
        }
    }
}

impl From<crate::vesicle::VesicleError> for TimestepError {
    fn from(e: crate::vesicle::VesicleError) -> Self {
        TimestepError::Vesicle(e.to_string())
    }
}

impl From<crate::wall::WallError> for TimestepError {
    fn from(e: crate::wall::WallError) -> Self {
        TimestepError::Wall(e.to_string())
    }
}

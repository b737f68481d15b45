//! The semi-implicit step of one vesicle (Veerapaneni, Rahimian, Biros & Zorin, *A fast
//! algorithm for simulating vesicle flows in three dimensions*, J. Comput. Phys. 230 (2011)
//! 5610), first order (Euler) or second order (BDF2 with extrapolated operators), any viscosity
//! ratio `λ = μ_in/μ_out`, in a background flow with a body force.
//!
//! ## The boundary integral equation
//!
//! On the membrane the velocity `u = dX/dt` satisfies (design 3.3; Pozrikidis 1992)
//!
//! ```text
//!     ((1+λ)/2) u − (1−λ) D[u] = u_∞ + S[f],      f = f_b(X) + f_σ(σ) + f_ext,
//!     ∇ₛ·u = 0                                    (local inextensibility),
//! ```
//!
//! with `S` the single layer of the outer viscosity `μ`, `D` the double layer (principal value,
//! `D[c] = −c/2` for a constant `c`, see [`crate::vesicle::layer`]), `f_b` the bending and
//! `f_σ = ∇ₛσ + 2σH n` the tension force. A rigid translation `u = U` gives `D[U] = −U/2` and
//! `U = u_∞ + S[f]` whatever `λ`. `D` is assembled only when `λ ≠ 1`.
//!
//! ## Euler (first order)
//!
//! With every operator frozen at `Xⁿ` (`S`, `D`, the linearised bending `B`, tension `T`,
//! surface divergence `Div`) and `u = (X − Xⁿ)/Δt`:
//!
//! ```text
//!     a (X − Xⁿ) − (1−λ) D (X − Xⁿ) − Δt S (B X + T σ) = Δt (u_∞(Xⁿ) + S f_ext)
//!     Div X = Div Xⁿ                                           (∇ₛⁿ·(X − Xⁿ) = 0)
//! ```
//!
//! (`a = (1+λ)/2`), a nonsymmetric system in `4n` unknowns (`n = 2p(p+1)` grid points) solved
//! by GMRES. `S` (and `D`) are assembled once per step as dense self-interaction operators and
//! applied as GEMVs in every iteration; `B X` and `T σ` are applied matrix-free on the upsampled
//! grid. Bending is implicit, so `Δt` is not bound by the explicit stiffness limit
//! `Δt ~ μ h³/κ`.
//!
//! ## BDF2 (second order)
//!
//! Veerapaneni et al. (2011; the 2D scheme of Veerapaneni, Gueyffier, Zorin & Biros,
//! J. Comput. Phys. 228 (2009) 2334): `u ≈ (3Xⁿ⁺¹ − 4Xⁿ + Xⁿ⁻¹)/(2Δt)`, every operator and
//! explicit term frozen at the extrapolated geometry `X* = 2Xⁿ − Xⁿ⁻¹`, and the constraint
//! `∇ₛ*·(3Xⁿ⁺¹ − 4Xⁿ + Xⁿ⁻¹) = 0`. With `X̂ = (4Xⁿ − Xⁿ⁻¹)/3` and `τ = 2Δt/3` this is the
//! Euler system with `Xⁿ → X̂`, `Δt → τ` and the operators of `X*`:
//!
//! ```text
//!     a (X − X̂) − (1−λ) D* (X − X̂) − τ S* (B* X + T* σ) = τ (u_∞(X*) + S* f_ext(X*))
//!     Div* X = Div* X̂
//! ```
//!
//! The first step (no `Xⁿ⁻¹`) is Euler. The stepper keeps `Xⁿ⁻¹`
//! ([`CellState::previous_coefs`], carried by checkpoints for restarts).
//! Explicit velocities passed by the caller ([`ExplicitTerms`]) are taken as they are (the
//! caller extrapolates them for second order). The area/volume drift correction keeps the
//! order (tests/timestep_order.rs: 1.98, 2.00, 2.01). Reparametrisation moves the grid of `Xⁿ⁺¹`
//! tangentially; the history `Xⁿ` is relabelled by the same parameter map, so that
//! `Xⁿ⁺¹ − Xⁿ` stays the flow's (without this, BDF2 falls to order ≈ 0.9). The
//! reparametrisation itself changes the shape slightly per call, independently of `Δt`, which
//! caps the accuracy at small `Δt` (measured orders 1.94, 1.75, 1.40 over Δt = 0.05 … 0.00625).
//!
//! The membrane velocity of the solve, `u = (Xⁿ⁺¹ − X̂)/τ` on the grid (before the
//! reparametrisation and the drift correction), is kept ([`CellState::membrane_velocity`]): a
//! suspension passes `(1 − λ) u` to the other cells as the density of this cell's double layer
//! (explicitly, in the next step).
//!
//! ## Capsules
//!
//! Without the inextensibility constraint ([`VesicleParams::inextensible`] `= false`) the
//! membrane resists through its hyperelastic law `f_e(X)` ([`crate::vesicle::skalak`]) and the
//! tension disappears. The elastic force is linearised about the operators' geometry,
//! `f_e(X) ≈ f_e(X*) + J (X − X*)` (linearly implicit, "implicit where it pays": the explicit
//! limit `Δt ~ μ a / (G_s p)` falls with the order), and with `δ = X − X*` the step is
//!
//! ```text
//!     a δ − (1−λ) D δ − τ S (B + J) δ = a (X̂ − X*) − (1−λ) D (X̂ − X*)
//!                                        + τ (u_∞(X*) + S (f_e(X*) + B X* + f_ext))
//! ```
//!
//! in `3n` unknowns. `J δ` is the directional derivative of the elastic force, taken by a
//! central difference `(f_e(X* + εδ) − f_e(X* − εδ))/2ε` with `ε|δ|` a `10⁻⁵` fraction of the
//! cell's size (relative error `~10⁻¹⁰`, which multiplies the small `δ = O(Δt)`, not the
//! surface; a one-sided difference left GMRES at a `10⁻⁹` floor at small `Ca`).
//! [`VesicleParams::elastic_stepping`] `= Some(Explicit)` drops `J` (forward Euler in the
//! elasticity; the reference whose stability limit this removes). The area is not a constraint:
//! the step's error estimate is the change of volume alone, and the drift correction (if asked)
//! restores the volume only, by a uniform normal displacement.
//!
//! An inextensible cell with shear elasticity (an RBC) may take the same linearisation
//! (`elastic_stepping = Some(LinearlyImplicit)`; its default is explicit, the tension carrying
//! most of the in-plane load): its `4n` system is then solved for `[δ; σ]`, the right-hand side
//! shifted by the operator (without `J`) applied to `[X*; 0]`, and `−τ S J δ` added to every
//! product. The sphere preconditioner does not see `J`, so the iterations grow with `G_s Δt`.
//!
//! ## Preconditioner
//!
//! With [`VesicleParams::preconditioner`] GMRES is right-preconditioned by the inverse step
//! operator of the sphere of the cell's area-equivalent radius `R = √(A/4π)`
//! ([`super::sphere_preconditioner`]), built once and rebuilt only when `R` drifts by more than
//! 1% or `τ`, `κ`, `μ`, `λ` change (the two `τ` of a BDF2 run are both kept). The sphere's
//! grid point `ξ` has the normal `ξ`; a cell's grid, carried by tank-treading or tumbling, turns
//! away from that, so at every step the preconditioner is turned by the rotation that best maps
//! the grid directions onto the cell's normals ([`super::grid_frame`]). Without this the
//! iterations per step grow with the angle the grid has turned, until a step fails (one
//! vesicle of reduced volume 0.85 in shear at p = 12: 19 → 326 iterations per step from t = 0.4
//! to t = 6, then no convergence; turned: 16–19 for t ≤ 40).
//!
//! The sphere's error grows with the cell's distance from the sphere (p = 12: 9 iterations per
//! step for a sphere, 18 for a prolate of reduced volume 0.85, 22 for an RBC, and more with
//! `p`). [`Preconditioning::Cell`] ([`CellStepper::set_preconditioning`], scene
//! `[numerics] preconditioner = "cell"`) uses the exact inverse of the cell's own step
//! operator instead ([`super::cell_preconditioner`]): built at a step from that step's operator
//! (GMRES then takes at most two iterations), turned with the grid at later steps like the
//! sphere's (by the rotation from the grid's frame at the build to the current one), and rebuilt
//! when a step takes more than `rebuild_after` iterations or `τ` changes by more than 10 %
//! (an adaptive `Δt`, BDF2 after its first step). It is rebuilt bit for
//! bit from its [`PreconditionerRecord`] (the surface, `τ` and Skalak reference it was built
//! from), which travels with the cell's state, so runs with it resume and migrate exactly.
//! Not with matrix-free operators (the build would apply them `4n_c` times): those keep the
//! sphere's.
//!
//! ## Local area
//!
//! The linearised constraint `Div (X − X̂) = 0` keeps each material point's area element `W`
//! only to first order, and over many steps `W` drifts from its start. A vesicle does not
//! notice, but with shear elasticity and a large area-dilation ratio `C` the drift is an area
//! strain `J = W/W_ref ≠ 1` whose Skalak stress `~ G_s C (J² − 1)` the tension must balance.
//! (An RBC with Skalak, `G_s = 0.2`, `C = 10`, in shear at p = 12: the largest `|J − 1|` grew
//! 0.07 → 0.5 → 2.0 over t = 2, 56, 74, with the reference itself drifting, until GMRES
//! stagnated at t = 76; docs/long_runs_cause.md.) For an inextensible cell with a Skalak
//! reference the constraint therefore carries the source
//!
//! ```text
//!     Div (X − X̂) = (τ/Δt) (W_ref (A/A_ref) / Wⁿ − 1)
//! ```
//!
//! (filtered as `Div` is, so that it lies in its range), which brings `W` back to the
//! reference's area element at the same material point (the reference moves with the grid, so
//! that `W_ref` is at the same point), scaled to the area `A` the drift correction restores, in
//! one step for Euler (`Wⁿ⁺¹ ≈ Wⁿ (1 + Div (X − Xⁿ))`). For BDF2 the constraint is linearised
//! about `X̂`, `Wⁿ⁺¹ ≈ Ŵ (1 + Div (X − X̂))`, and this source closes the share `τ/Δt` (2/3 at a
//! constant step) of the gap per step; the error of the gap then obeys a two-step recursion
//! that is stable for step ratios `ω ≲ 2.4`, above the adaptive controller's bound `√2`. (The
//! one-step form `W_ref/Ŵ − 1` was tried: it broke the second order of BDF2 measured by
//! tests/capsule.rs, the difference of the explicit and the implicit elasticity rising from
//! 7.8e-6 at Δt = 0.001 to 1.5e-5 at 0.0005.) A correction toward the constraint's manifold,
//! zero when `W = W_ref` and of the size of the linearisation's error (`O(Δt²)` per step)
//! otherwise, so the step keeps its order.
//! [`CellStepper::set_local_area_relaxation`] switches it off.
//!
//! ## After the step
//!
//! Optionally the grid is reparametrised (tank-treading carries grid points along the membrane
//! and degrades the parametrisation; without it long runs at large `Δt` degenerate). The grid
//! points then move along the surface, and everything the cell keeps per membrane point moves
//! with them (relabelled by the same parameter map): the Skalak reference (otherwise the move
//! reads as a strain), the tension, the membrane velocity and the BDF2 history `Xⁿ⁻¹`. The
//! reference moves through its material labels and is composed afresh from its first surface
//! ([`crate::vesicle::material_labels`]): relabelled itself, its re-fits at every move added up
//! to a change of its shape. The
//! linearised constraint keeps the area only approximately; with `correct_drift` each step ends
//! with a normal displacement `(α + β H) n` whose `α, β` restore the area and volume of the first
//! step (Newton on `δV = ∫ φ dA`, `δA = −2 ∫ H φ dA` for `φ = α + β H`).

pub use super::operator_storage::OperatorStorage;
use std::sync::{Arc, Mutex};

use super::cell_preconditioner::{CellPreconditioner, CellPreconditionerOp};
use super::cell_state::{CellState, PreconditionerRecord};
use super::grid_frame::{
    grid_rotation, relative_rotation, RotatedPreconditioner, Rotation, IDENTITY,
};
use super::sphere_preconditioner::{self, SpherePreconditioner, StepCoefficients};
use super::step_engine::{ElasticWork, EngineLease, EnginePool, OperatorWork, StepEngine};
use super::step_operator::{
    add_elastic_jacobian, apply_operators, InextensibleOperator, StepOperator,
};
use super::TimestepError;
use super::{gmres, FnOperator, GmresParams, GmresReport, GmresWorkspace, Identity};
use crate::sph_harmonics::{ShTransform, ShWorkspace};
use crate::vesicle::far_side::FarSideParams;
use crate::vesicle::layer::{LayerKernel, RotationAlgorithm, SelfInteraction};
use crate::vesicle::material_labels::MaterialLabels;
use crate::vesicle::membrane::Membrane;
use crate::vesicle::reparam::{ReparamParams, Reparametrizer};
use crate::vesicle::shapes::Surface;
use crate::vesicle::skalak::SkalakParams;

/// Time discretisation of the step (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TimeScheme {
    /// First-order semi-implicit Euler, operators at `Xⁿ`.
    #[default]
    Euler,
    /// Second-order BDF2, operators at `X* = 2Xⁿ − Xⁿ⁻¹`; the first step is Euler.
    Bdf2,
}

/// How the membrane's elastic force (Skalak or neo-Hookean) enters the step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ElasticStepping {
    /// Evaluated at the operators' geometry `X*` (`Xⁿ` for Euler, the extrapolation for BDF2;
    /// stable only below `Δt ~ μa/(G_s p)`).
    Explicit,
    /// Linearised about `X*`: `f_e(X) ≈ f_e(X*) + J (X − X*)`, the Jacobian applied in every
    /// GMRES iteration by a central difference ("Capsules" in the module docs).
    LinearlyImplicit,
}

/// Relative drift of the area-equivalent radius that triggers a rebuild of the preconditioner.
const PRECONDITIONER_RADIUS_RTOL: f64 = 1e-2;

/// Which preconditioner GMRES uses for an inextensible cell (with
/// [`VesicleParams::preconditioner`] on; see "Preconditioner" in the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Preconditioning {
    /// The inverse step operator of the sphere of the cell's area, turned with the grid
    /// ([`super::sphere_preconditioner`]): built once, cheap to keep, its error grows with the
    /// cell's distance from the sphere.
    #[default]
    Sphere,
    /// The inverse of the cell's own step operator ([`super::cell_preconditioner`]), built at a
    /// step, turned with the grid at later steps, and rebuilt by the step after one of more
    /// than `rebuild_after` GMRES iterations (or by a step whose `τ` differs by more than 10 %,
    /// or whose other coefficients differ). A cell too close to a sphere to invert its own
    /// operator uses the sphere's.
    Cell {
        /// Iterations of a step above which the next step rebuilds the preconditioner.
        rebuild_after: usize,
    },
}

impl Preconditioning {
    /// The default of [`Preconditioning::Cell`]'s `rebuild_after`.
    pub const DEFAULT_REBUILD_AFTER: usize = 8;
    /// The cell's own operator, rebuilt after a step of more than 8 iterations.
    pub const CELL: Preconditioning = Preconditioning::Cell {
        rebuild_after: Self::DEFAULT_REBUILD_AFTER,
    };
}

/// A cell's own preconditioner: what it was built from, and the inverse.
struct OwnPreconditioner {
    record: PreconditionerRecord,
    /// The operator's coefficients (`τ` is the record's; the rest are the stepper's at the
    /// build, compared so that a changed parameter rebuilds it).
    coefs: StepCoefficients,
    inverse: OwnInverse,
    /// The grid's frame at the build ([`super::grid_frame`]): later steps turn the
    /// preconditioner by how far the grid has turned since.
    frame: Rotation,
}

enum OwnInverse {
    Built(CellPreconditioner),
    /// The cell was too close to a sphere to invert its own operator: the sphere's
    /// preconditioner serves until this goes stale.
    Singular,
    /// To be rebuilt from the record before its next use (a restored state).
    Pending,
}

/// The inverse of `op` (the step's operator, identity coefficient `a_id`), or `Singular`
/// when the cell is too close to a sphere; a failure of the membrane operators is reported
/// as such.
fn own_inverse(
    op: &InextensibleOperator<'_>,
    sht: &ShTransform,
    a_id: f64,
) -> Result<OwnInverse, TimestepError> {
    match CellPreconditioner::build(op, sht, a_id) {
        Ok(pc) => Ok(OwnInverse::Built(pc)),
        Err(TimestepError::SingularBlock { .. }) => Ok(OwnInverse::Singular),
        Err(e) => Err(op.take_failure().map_or(e, TimestepError::from)),
    }
}

/// Relative change of `τ` (an adaptive or BDF2 step) beyond which the cell's own
/// preconditioner is rebuilt; within it the iterations decide.
const OWN_TAU_RTOL: f64 = 0.1;

/// A singular own operator is tried again only after a step of more than this many times
/// `rebuild_after` iterations with the sphere's preconditioner (a cell near a sphere, which
/// the sphere's serves well, would otherwise try at every step).
const SINGULAR_RETRY_FACTOR: usize = 3;

/// Physical and numerical parameters of a vesicle step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VesicleParams {
    /// Bending modulus `κ_b`.
    pub bending_modulus: f64,
    /// Viscosity `μ` of the outer fluid (`μ_out`; the inner one is `λ μ`).
    pub viscosity: f64,
    /// Body force on the cell (spread as a uniform traction `F / A`).
    pub force: [f64; 3],
    /// Time step.
    pub dt: f64,
    /// Quadrature order of the forces and the singular integrals (`q ≥ p`, usually `2p`).
    pub upsampled_order: usize,
    /// Linear solver settings.
    pub gmres: GmresParams,
    /// Restore the initial area and volume after every step.
    pub correct_drift: bool,
    /// Reparametrise the grid after every step (remove tangential drift; Veerapaneni et al.
    /// 2011 §3.4), before the drift correction.
    pub reparametrize: Option<ReparamParams>,
    /// Right-precondition GMRES by the inverse step operator of the area-equivalent sphere
    /// ([`super::sphere_preconditioner`]). Inextensible cells only: a capsule's system has no
    /// tension block, and it is solved unpreconditioned whatever this says.
    pub preconditioner: bool,
    /// Euler or BDF2.
    pub scheme: TimeScheme,
    /// Viscosity ratio `λ = μ_in / μ_out` (positive; 1: no double layer).
    pub viscosity_ratio: f64,
    /// `true`: a vesicle or RBC, locally inextensible (`∇ₛ·u = 0`, with the tension as
    /// unknown). `false`: a capsule, whose membrane stretches and resists through its elastic law
    /// alone ([`CellStepper::set_skalak`], required); see "Capsules" in the module docs.
    pub inextensible: bool,
    /// How the elastic force enters the step (`None`: linearly implicit for a capsule,
    /// explicit for an inextensible cell, whose tension carries most of the in-plane load).
    pub elastic_stepping: Option<ElasticStepping>,
}

/// Explicit terms of one step (other cells, elastic forces computed at `Xⁿ`).
#[derive(Clone, Copy, Debug, Default)]
pub struct ExplicitTerms<'a> {
    /// A velocity on the order-`p` grid (`3n`, component-major) added to `u_∞(Xⁿ)`: the
    /// velocity induced by the other cells.
    pub velocity: Option<&'a [f64]>,
    /// A traction on the order-`p` grid (`3n`) added to the body-force traction and applied
    /// through the cell's own single layer (e.g. a contact repulsion).
    pub traction: Option<&'a [f64]>,
}

/// What one step did.
#[derive(Clone, Debug)]
pub struct StepReport {
    /// The GMRES solve.
    pub gmres: GmresReport,
    /// The scheme of this step (the first step of a BDF2 run is Euler).
    pub scheme: TimeScheme,
    /// Whether a preconditioner (the sphere's or the cell's own) was (re)built in this step.
    pub preconditioner_built: bool,
    /// The step's area/volume error, `max(|Aⁿ⁺¹ − Aⁿ|/Aⁿ, |Vⁿ⁺¹ − Vⁿ|/Vⁿ)` measured before the
    /// drift correction: the exact flow keeps both, so this is an error estimate of the step
    /// (what [`super::adaptive`] controls).
    pub area_volume_error: f64,
}

/// Steps one cell of SH order `p`: the algorithm, its operators, preconditioners and the
/// engines it leases, apart from the cell's state.
///
/// A [`CellState`] holds what the cell is and what its next step needs (coefficients, tension,
/// the BDF2 history, the membrane velocity, the Skalak reference and its material labels, the
/// drift targets, the record of its own preconditioner); [`CellStepper::step_with`] advances
/// a state by one step. The stepper keeps only what can be rebuilt from the state and its
/// parameters: the dense operators of the last step, the sphere preconditioners, the cell's
/// own preconditioner (rebuilt from the state's record when it is not the one held).
/// Transforms, the membrane-force engine, the layer potentials and scratch are lent per call by
/// a pool shared by every stepper of the same `(p, q, restart)` in the process (the crate's
/// private `step_engine`), so that a suspension holds one such engine per thread, not per
/// cell. [`super::vesicle_stepper::VesicleStepper`] is one cell with its state, for studies of
/// a single cell.
pub struct CellStepper {
    p: usize,
    /// Grid points and coefficients per component.
    n: usize,
    nc: usize,
    params: VesicleParams,
    pool: Arc<EnginePool>,
    far_side: FarSideParams,
    storage: OperatorStorage,
    /// Dense single layer: `3n_c × 3n_c` in coefficient space (column-major), or on the grid
    /// its rows over coefficients, `3n × 3n_c` row-major (`3n × 3n` column-major without
    /// upsampling) (empty before the first step).
    s_op: Vec<f64>,
    /// Dense double layer, the same (empty when `λ = 1`).
    d_op: Vec<f64>,
    /// Shear elasticity (explicit or linearly implicit); its reference surface is the state's.
    skalak: Option<SkalakParams>,
    /// Double-layer operators assembled by the steps so far (0 for `λ = 1`: only what is called
    /// for; a preconditioner rebuilt from its record assembles again, not counted here).
    pub double_layer_assemblies: usize,
    /// Sphere preconditioners in use (at most two: the Euler and the BDF2 `τ`), shared with
    /// the other cells of the same sphere ([`sphere_preconditioner::shared`]).
    preconditioners: Vec<Arc<SpherePreconditioner>>,
    /// Which preconditioner the steps use.
    preconditioning: Preconditioning,
    /// The cell's own preconditioner ([`Preconditioning::Cell`]), once built (its record is
    /// also the state's).
    own: Option<OwnPreconditioner>,
    /// Own preconditioners built so far.
    pub own_preconditioner_builds: usize,
    /// Whether an inextensible cell with a Skalak reference relaxes its local area element to
    /// the reference's in the constraint (see "Local area" in the module docs).
    local_area_relaxation: bool,
}

fn check(name: &'static str, v: f64) -> Result<(), TimestepError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(TimestepError::InvalidParameter {
            name,
            value: format!("{v}"),
            reason: "must be positive and finite",
        })
    }
}

impl CellStepper {
    /// Plans for order `p`.
    pub fn new(p: usize, params: VesicleParams) -> Result<Self, TimestepError> {
        if params.inextensible || params.bending_modulus != 0.0 {
            // A capsule may have no bending stiffness at all.
            check("bending_modulus", params.bending_modulus)?;
        }
        check("viscosity", params.viscosity)?;
        check("dt", params.dt)?;
        check("viscosity_ratio", params.viscosity_ratio)?;
        if !params.force.iter().all(|f| f.is_finite()) {
            return Err(TimestepError::NonFinite { what: "force" });
        }
        params.gmres.validate()?;
        let q = params.upsampled_order.max(p);
        let pool = EnginePool::shared(p, q, params.gmres.restart);
        // Plans the engine (or takes an idle one), which also checks `p` and `q`.
        let (n, nc) = {
            let e = pool.lease()?;
            (e.sht.n_points(), e.sht.n_coefs())
        };
        Ok(CellStepper {
            p,
            n,
            nc,
            params,
            pool,
            far_side: FarSideParams::default(),
            storage: OperatorStorage::default(),
            s_op: Vec::new(),
            d_op: Vec::new(),
            skalak: None,
            double_layer_assemblies: 0,
            preconditioners: Vec::new(),
            preconditioning: Preconditioning::default(),
            own: None,
            own_preconditioner_builds: 0,
            local_area_relaxation: true,
        })
    }

    /// A cell's state at its first step: the surface `coefs` (order-`p` coefficients), zero
    /// tension, no history; with shear elasticity, the stress-free `skalak_reference`
    /// (coefficients, the same parametrisation) and material labels starting as the identity.
    ///
    /// # Errors
    /// [`TimestepError::DimensionMismatch`] for a surface or reference of the wrong length,
    /// [`TimestepError::InvalidParameter`] for a reference without shear elasticity or shear
    /// elasticity without a reference, and the checks of the reference as a surface.
    pub fn initial_state(
        &self,
        coefs: &[f64],
        skalak_reference: Option<&[f64]>,
    ) -> Result<CellState, TimestepError> {
        if coefs.len() != 3 * self.nc {
            return Err(TimestepError::DimensionMismatch {
                what: "surface coefficients",
                expected: 3 * self.nc,
                got: coefs.len(),
            });
        }
        let material_labels = match (skalak_reference, self.skalak.is_some()) {
            (Some(r), true) => Some(self.identity_labels(r)?),
            (None, false) => None,
            (r, _) => {
                return Err(TimestepError::InvalidParameter {
                    name: "skalak reference",
                    value: if r.is_some() { "given" } else { "none" }.into(),
                    reason: "a cell has a Skalak reference exactly when it has shear elasticity \
                             (CellStepper::set_skalak)",
                })
            }
        };
        Ok(CellState {
            coefs: coefs.to_vec(),
            sigma: vec![0.0; self.n],
            drift_targets: None,
            previous_coefs: None,
            previous_dt: None,
            membrane_velocity: None,
            skalak_reference: skalak_reference.map(|r| r.to_vec()),
            material_labels,
            velocity: None,
            previous_velocity: None,
            iterations: 0,
            preconditioner: None,
        })
    }

    /// The material labels of a fresh Skalak reference `reference` (the identity map; the
    /// reference is checked as a surface).
    pub fn identity_labels(&self, reference: &[f64]) -> Result<MaterialLabels, TimestepError> {
        let mut engine = self.pool.lease()?;
        let StepEngine { sht, ws, work, .. } = &mut *engine;
        work.get_mut()
            .expect("operator lock")
            .membrane
            .set_reference(reference)?;
        Ok(MaterialLabels::identity(sht, ws, reference)?)
    }

    /// Check that `state` is one of this stepper's cells: the lengths of its vectors, finite
    /// history, a Skalak reference (with labels of its size) exactly when the stepper has
    /// shear elasticity.
    pub fn check_state(&self, state: &CellState) -> Result<(), TimestepError> {
        let (n, nc) = (self.n, self.nc);
        let len = |what: &'static str, got: usize, expected: usize| {
            if got == expected {
                Ok(())
            } else {
                Err(TimestepError::DimensionMismatch {
                    what,
                    expected,
                    got,
                })
            }
        };
        len("surface coefficients", state.coefs.len(), 3 * nc)?;
        len("tension", state.sigma.len(), n)?;
        if let Some(c) = &state.previous_coefs {
            len("previous coefficients", c.len(), 3 * nc)?;
            if !c.iter().all(|v| v.is_finite()) {
                return Err(TimestepError::NonFinite {
                    what: "previous coefficients",
                });
            }
        }
        if let Some(dt) = state.previous_dt {
            check("previous dt", dt)?;
        }
        if let Some(v) = &state.membrane_velocity {
            len("membrane velocity", v.len(), 3 * n)?;
            if !v.iter().all(|x| x.is_finite()) {
                return Err(TimestepError::NonFinite {
                    what: "membrane velocity",
                });
            }
        }
        if state.material_labels.is_some() && state.skalak_reference.is_none() {
            return Err(TimestepError::InvalidParameter {
                name: "material labels",
                value: "present".into(),
                reason: "a cell state with material labels needs its Skalak reference",
            });
        }
        if let Some(r) = &state.skalak_reference {
            if self.skalak.is_none() {
                return Err(TimestepError::InvalidParameter {
                    name: "skalak reference",
                    value: format!("{} coefficients", r.len()),
                    reason: "the cell has no shear elasticity",
                });
            }
            len("skalak reference", r.len(), 3 * nc)?;
        }
        if let Some(l) = &state.material_labels {
            if l.original.len() != 3 * nc || l.map.len() != 3 * nc {
                return Err(TimestepError::InvalidParameter {
                    name: "material labels",
                    value: format!("{} + {} coefficients", l.original.len(), l.map.len()),
                    reason: "need a cell with shear elasticity and 3 n_c coefficients each",
                });
            }
        }
        Ok(())
    }

    /// An engine for one call, set up for this cell (far-side settings, the Skalak reference
    /// `reference` of its state).
    fn lease(&self, reference: Option<&[f64]>) -> Result<EngineLease, TimestepError> {
        let mut e = self.pool.lease()?;
        e.work
            .get_mut()
            .expect("operator lock")
            .products
            .layer
            .set_far_side_params(self.far_side)?;
        if let (Some(_), Some(reference)) = (&self.skalak, reference) {
            e.work
                .get_mut()
                .expect("operator lock")
                .membrane
                .set_reference(reference)?;
        }
        Ok(e)
    }

    /// Add Skalak shear elasticity (explicit in time, or linearly implicit as
    /// [`VesicleParams::elastic_stepping`] says) relative to the stress-free surface of each
    /// state ([`CellState::skalak_reference`], from [`Self::initial_state`]).
    pub fn set_skalak(&mut self, params: SkalakParams) {
        // Other elastic parameters change the Jacobian in the cell's own preconditioner (a
        // relabelled reference does not: the record keeps the one it was built with).
        if self.skalak.is_none_or(|p| p != params) {
            self.own = None;
        }
        self.skalak = Some(params);
    }

    /// The shear elasticity (`None`: none).
    pub fn skalak(&self) -> Option<SkalakParams> {
        self.skalak
    }

    /// Which preconditioner the steps use.
    pub fn preconditioning(&self) -> Preconditioning {
        self.preconditioning
    }

    /// Use `preconditioning` from the next step on (a change drops the cell's own
    /// preconditioner, if any).
    pub fn set_preconditioning(&mut self, preconditioning: Preconditioning) {
        if preconditioning != self.preconditioning {
            self.own = None;
        }
        self.preconditioning = preconditioning;
    }

    /// Switch the local area relaxation of an inextensible cell with shear elasticity (on by
    /// default; module docs, "Local area"). Off, the constraint is `∇ₛ·u = 0` alone and the
    /// local area element drifts from the reference's by the linearisation's error, which the
    /// tension then has to balance against the elastic area-dilation stress. On, the
    /// membrane's local area follows the reference's: a reference whose area elements differ
    /// from the initial surface's (scenes always start on their reference) is reached within
    /// the first step.
    pub fn set_local_area_relaxation(&mut self, on: bool) {
        self.local_area_relaxation = on;
    }

    /// Hold the own preconditioner of `record` (`None`: none): unless it is the one held, it is
    /// rebuilt from the record before the next step that uses it, bit for bit the one the
    /// record came from (a resumed run, a cell moved here, a repeated step). Every step first
    /// adopts its state's record this way.
    fn adopt_own_record(&mut self, record: Option<&PreconditionerRecord>) {
        let bits = |a: &[f64], b: &[f64]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
        };
        let same = |a: &PreconditionerRecord, b: &PreconditionerRecord| {
            bits(&a.surface, &b.surface)
                && a.tau.to_bits() == b.tau.to_bits()
                && match (&a.jacobian_reference, &b.jacobian_reference) {
                    (Some(x), Some(y)) => bits(x, y),
                    (None, None) => true,
                    _ => false,
                }
        };
        match (record, &mut self.own) {
            (None, _) => self.own = None,
            (Some(r), Some(o)) if same(r, &o.record) => {
                o.record.last_iterations = r.last_iterations;
            }
            (Some(r), _) => {
                self.own = Some(OwnPreconditioner {
                    record: r.clone(),
                    coefs: self.step_coefficients(r.tau),
                    inverse: OwnInverse::Pending,
                    frame: IDENTITY,
                })
            }
        }
    }

    /// How the dense self-interaction operators are kept between assembly and application.
    pub fn operator_storage(&self) -> OperatorStorage {
        self.storage
    }

    /// Keep the dense self-interaction operators in coefficient space (the default) or on the
    /// grid, from the next step on.
    pub fn set_operator_storage(&mut self, storage: OperatorStorage) {
        if storage != self.storage {
            self.s_op = Vec::new();
            self.d_op = Vec::new();
            self.own = None;
        }
        self.storage = storage;
    }

    /// Bytes the stepper keeps for its cell (its dense operators and preconditioners; the
    /// engines lent by the pool are shared and not counted, the state is
    /// [`CellState::memory_bytes`]).
    pub fn memory_bytes(&self) -> usize {
        8 * (self.s_op.capacity() + self.d_op.capacity())
            + self
                .preconditioners
                .iter()
                // A shared preconditioner counts in equal shares to the cells holding it.
                .map(|m| m.memory_bytes() / Arc::strong_count(m))
                .sum::<usize>()
            + match self.own.as_ref().map(|o| &o.inverse) {
                Some(OwnInverse::Built(pc)) => pc.memory_bytes(),
                _ => 0,
            }
            + std::mem::size_of::<Self>()
    }

    /// Change the time step (adaptive `dt`). A BDF2 run then takes the variable-step formula
    /// with the ratio `ω = Δtⁿ/Δtⁿ⁻¹`.
    pub fn set_dt(&mut self, dt: f64) -> Result<(), TimestepError> {
        check("dt", dt)?;
        self.params.dt = dt;
        Ok(())
    }

    /// `ω = Δtⁿ/Δtⁿ⁻¹` when the next step of `state` is a BDF2 step (`None`: an Euler step):
    /// explicit terms are extrapolated to the operators' geometry `X* = (1 + ω)Xⁿ − ωXⁿ⁻¹`.
    pub fn extrapolation_ratio(&self, state: &CellState) -> Option<f64> {
        (self.params.scheme == TimeScheme::Bdf2 && state.previous_coefs.is_some())
            .then(|| self.params.dt / state.previous_dt.unwrap_or(self.params.dt))
    }

    /// Parameters.
    pub fn params(&self) -> &VesicleParams {
        &self.params
    }

    /// Settings of the far-side split in the cell's own layer potentials.
    pub fn far_side_params(&self) -> FarSideParams {
        self.far_side
    }

    /// Change the settings of the far-side split in the cell's own layer potentials
    /// ([`crate::vesicle::far_side`]); they apply from the next step's assembly on.
    pub fn set_far_side_params(&mut self, params: FarSideParams) -> Result<(), TimestepError> {
        // Checked on an engine now, set on each engine lent to this cell.
        self.pool
            .lease()?
            .work
            .get_mut()
            .expect("operator lock")
            .products
            .layer
            .set_far_side_params(params)?;
        if params != self.far_side {
            self.own = None;
        }
        self.far_side = params;
        Ok(())
    }

    /// The traction the membrane exerts on the fluid at the surface of `state`, with its
    /// tension: `f_b(X) + f_σ(σ) + f_Skalak(X) + F/A` on the order-`p` grid (`3n`). This is
    /// the density whose single layer the other cells feel (explicit coupling).
    pub fn traction(&self, state: &CellState, out: &mut [f64]) -> Result<(), TimestepError> {
        let n = self.n;
        if out.len() != 3 * n {
            return Err(TimestepError::DimensionMismatch {
                what: "traction",
                expected: 3 * n,
                got: out.len(),
            });
        }
        let mut engine = self.lease(state.skalak_reference.as_deref())?;
        let OperatorWork {
            membrane, fb, ft, ..
        } = engine.work.get_mut().expect("operator lock");
        membrane.set_geometry(&state.coefs)?;
        let area = membrane.geometry()?.area();
        membrane.bending_force(self.params.bending_modulus, out)?;
        membrane.tension_force(&state.sigma, ft)?;
        for (o, t) in out.iter_mut().zip(ft.iter()) {
            *o += t;
        }
        if let Some(sk) = &self.skalak {
            membrane.skalak_force(sk, fb)?;
            for (o, t) in out.iter_mut().zip(fb.iter()) {
                *o += t;
            }
        }
        for c in 0..3 {
            for o in &mut out[c * n..(c + 1) * n] {
                *o += self.params.force[c] / area;
            }
        }
        Ok(())
    }

    /// `f` applied to the geometry of the surface `coefs` on the order-`p` grid (with the
    /// transforms of the stepper's engine).
    pub fn with_geometry<R>(
        &self,
        coefs: &[f64],
        f: impl FnOnce(&crate::vesicle::geometry::Geometry) -> R,
    ) -> Result<R, TimestepError> {
        let mut engine = self.lease(None)?;
        let g = engine.calc.geometry(coefs)?;
        Ok(f(&g))
    }

    /// SH order.
    pub fn order(&self) -> usize {
        self.p
    }

    /// Grid points per cell, `n = 2p(p+1)`.
    pub fn n_points(&self) -> usize {
        self.n
    }

    /// Coefficients per component, `n_c = (p+1)² − 1`.
    pub fn n_coefs(&self) -> usize {
        self.nc
    }

    fn preconditioner_for(
        &mut self,
        engine: &mut StepEngine,
        radius: f64,
        c: StepCoefficients,
    ) -> Result<(usize, bool), TimestepError> {
        let q = engine.sht.order().max(self.params.upsampled_order);
        if let Some(i) = self
            .preconditioners
            .iter()
            .position(|m| m.matches(self.p, q, radius, &c, PRECONDITIONER_RADIUS_RTOL))
        {
            return Ok((i, false));
        }
        let (kept, built) = {
            let work = engine.work.get_mut().expect("operator lock");
            sphere_preconditioner::shared(&mut work.membrane, &mut work.products.layer, radius, c)?
        };
        // Keep at most two (Euler's and BDF2's τ); a stale radius or τ is replaced.
        if self.preconditioners.len() >= 2 {
            self.preconditioners.remove(0);
        }
        self.preconditioners.push(kept);
        Ok((self.preconditioners.len() - 1, built))
    }

    /// The step operator's coefficients for time factor `tau` with this cell's parameters.
    fn step_coefficients(&self, tau: f64) -> StepCoefficients {
        let p = &self.params;
        StepCoefficients::new(p.viscosity_ratio, tau, p.bending_modulus, p.viscosity)
    }

    /// Get the cell's own preconditioner ready for a step with coefficients `coef` (and the
    /// elastic Jacobian if `with_jacobian`): dropped when stale, rebuilt from its record when
    /// pending. Returns whether the step must build a new one (from its own operator) and
    /// whether one was rebuilt from a record.
    fn prepare_own(
        &mut self,
        engine: &mut StepEngine,
        coef: &StepCoefficients,
        with_jacobian: bool,
        precondition: bool,
    ) -> Result<(bool, bool), TimestepError> {
        let Preconditioning::Cell { rebuild_after } = self.preconditioning else {
            self.own = None;
            return Ok((false, false));
        };
        // Matrix-free storage would apply a matrix-free product per column of the build.
        if !precondition || self.storage == OperatorStorage::MatrixFree {
            self.own = None;
            return Ok((false, false));
        }
        let retry = SINGULAR_RETRY_FACTOR.saturating_mul(rebuild_after);
        // Stale whatever its inverse: built for another operator, or iterations beyond even a
        // singular one's limit.
        let stale = self.own.as_ref().is_none_or(|o| {
            !o.coefs.same_operator(coef)
                || (o.record.tau - coef.tau).abs() > OWN_TAU_RTOL * o.record.tau
                || o.record.jacobian_reference.is_some() != with_jacobian
                || o.record.last_iterations > retry
        });
        if stale {
            self.own = None;
            return Ok((true, false));
        }
        // A pending inverse is rebuilt first: whether it is singular decides its limit, as in
        // the run the record came from.
        let mut rebuilt = false;
        if let Some(mut o) = self.own.take() {
            if matches!(o.inverse, OwnInverse::Pending) {
                o.inverse = self.rebuild_from_record(engine, &o.record)?;
                let g = engine.calc.geometry(&o.record.surface)?;
                o.frame = grid_rotation(&g, &engine.sht.grid().unit_points());
                self.own_preconditioner_builds += 1;
                rebuilt = true;
            }
            let limit = match o.inverse {
                OwnInverse::Singular => retry,
                _ => rebuild_after,
            };
            if o.record.last_iterations > limit {
                return Ok((true, rebuilt));
            }
            self.own = Some(o);
        }
        Ok((false, rebuilt))
    }

    /// The own preconditioner of `record`, built as the step that made the record built it:
    /// the operators assembled at its surface, with its `τ` and Jacobian.
    fn rebuild_from_record(
        &mut self,
        engine: &mut StepEngine,
        record: &PreconditionerRecord,
    ) -> Result<OwnInverse, TimestepError> {
        let coef = self.step_coefficients(record.tau);
        let (a_id, c_d) = (coef.identity, coef.double_layer);
        let size = {
            let w = engine.work.get_mut().expect("operator lock");
            w.membrane.set_geometry(&record.surface)?;
            (w.membrane.geometry()?.area() / (4.0 * std::f64::consts::PI)).sqrt()
        };
        let viscosity = self.params.viscosity;
        // The cell's operator buffers (with grid storage, the engine's, lent for this step):
        // the step reassembles them after this rebuild.
        let (mut s_op, mut d_op) = (
            std::mem::take(&mut self.s_op),
            std::mem::take(&mut self.d_op),
        );
        let single = LayerKernel::SingleLayer { viscosity };
        assemble_operator(engine, self.storage, single, &record.surface, &mut s_op)?;
        if c_d != 0.0 {
            let double = LayerKernel::DoubleLayer;
            // Not counted in `double_layer_assemblies` (the steps' own): this one belongs to the
            // rebuild, counted in `own_preconditioner_builds`.
            assemble_operator(engine, self.storage, double, &record.surface, &mut d_op)?;
        }
        let jacobian = match (&record.jacobian_reference, &self.skalak) {
            (Some(reference), Some(sk)) => {
                let OperatorWork {
                    membrane, elastic, ..
                } = engine.work.get_mut().expect("operator lock");
                elastic_work(elastic, membrane, self.nc, reference)?;
                Some(*sk)
            }
            _ => None,
        };
        let op = InextensibleOperator::new(
            self.n,
            &engine.work,
            &engine.sht,
            self.storage,
            &record.surface,
            (
                StepOperator::Dense(&s_op),
                (c_d != 0.0).then_some(StepOperator::Dense(&d_op)),
            ),
            [a_id, c_d, record.tau, self.params.bending_modulus],
            jacobian,
            size,
        );
        if jacobian.is_some() {
            op.enable_jacobian();
        }
        let inverse = own_inverse(&op, &engine.sht, a_id);
        drop(op);
        (self.s_op, self.d_op) = (s_op, d_op);
        inverse
    }

    /// Advance `state` by one step in the background flow `u_inf`.
    pub fn step(
        &mut self,
        state: &mut CellState,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
    ) -> Result<StepReport, TimestepError> {
        self.step_with(state, u_inf, ExplicitTerms::default())
    }

    /// Advance `state` by one step with explicit terms (the velocity induced by other cells,
    /// extra tractions). The state's own-preconditioner record is the one the step uses
    /// (rebuilt from it when it is not the one held) and the one it leaves.
    pub fn step_with(
        &mut self,
        state: &mut CellState,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        extra: ExplicitTerms<'_>,
    ) -> Result<StepReport, TimestepError> {
        let (n, nc) = (self.n, self.nc);
        if state.coefs.len() != 3 * nc || state.sigma.len() != n {
            return Err(TimestepError::DimensionMismatch {
                what: "cell state (coefficients and tension)",
                expected: 3 * nc + n,
                got: state.coefs.len() + state.sigma.len(),
            });
        }
        for (what, v) in [("velocity", extra.velocity), ("traction", extra.traction)] {
            if let Some(v) = v {
                if v.len() != 3 * n {
                    return Err(TimestepError::DimensionMismatch {
                        what,
                        expected: 3 * n,
                        got: v.len(),
                    });
                }
            }
        }
        self.adopt_own_record(state.preconditioner.as_ref());
        let mut lease = self.lease(state.skalak_reference.as_deref())?;
        let engine: &mut StepEngine = &mut lease;
        // Grid storage: the operators live in the engine (one pair per thread), lent to this
        // cell for its step and handed back whatever the step's outcome.
        let lent = !storage_keeps_per_cell(self.storage);
        if lent {
            std::mem::swap(&mut self.s_op, &mut engine.grid_single);
            std::mem::swap(&mut self.d_op, &mut engine.grid_double);
        }
        let report = self.step_on(engine, state, u_inf, extra);
        if lent {
            std::mem::swap(&mut self.s_op, &mut engine.grid_single);
            std::mem::swap(&mut self.d_op, &mut engine.grid_double);
        }
        state.preconditioner = self.own.as_ref().map(|o| o.record.clone());
        report
    }

    /// [`Self::step_with`] on a leased engine, the sizes checked: the step's phases in order.
    fn step_on(
        &mut self,
        engine: &mut StepEngine,
        state: &mut CellState,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        extra: ExplicitTerms<'_>,
    ) -> Result<StepReport, TimestepError> {
        let plan = self.plan(engine, state)?;
        let pcs = self.prepare_preconditioners(engine, &plan, state)?;
        let terms = self.explicit_grid_terms(engine, &plan, u_inf, extra)?;
        self.assemble(engine, &plan)?;
        let (report, x_new, own_built) = self.solve(engine, &plan, &pcs, &terms, state)?;
        let area_volume_error = self.advance(engine, state, &plan, &x_new, &terms.xh_grid)?;
        self.regrid_and_correct(engine, state, &plan)?;
        Ok(StepReport {
            gmres: report,
            scheme: plan.scheme,
            preconditioner_built: pcs.sphere_built || own_built,
            area_volume_error,
        })
    }

    /// Phase 1, the plan of the step from the history: the scheme (BDF2 once `Xⁿ⁻¹` is
    /// known), `τ`, the operator's coefficients, `X*` and `X̂`, the drift targets (set at the
    /// first step) and the local area source.
    fn plan(
        &self,
        engine: &mut StepEngine,
        state: &mut CellState,
    ) -> Result<StepPlan, TimestepError> {
        let omega = self.extrapolation_ratio(state);
        let bdf2 = omega.is_some();
        let scheme = if bdf2 {
            TimeScheme::Bdf2
        } else {
            TimeScheme::Euler
        };
        // Variable-step BDF2 with ω = Δtⁿ/Δtⁿ⁻¹:
        //   ((1+2ω)/(1+ω)) Xⁿ⁺¹ − (1+ω) Xⁿ + (ω²/(1+ω)) Xⁿ⁻¹ = Δtⁿ F(X*),
        // i.e. Xⁿ⁺¹ − X̂ = τ F(X*) with τ = Δtⁿ (1+ω)/(1+2ω), X̂ = ((1+ω)² Xⁿ − ω² Xⁿ⁻¹)/(1+2ω),
        // X* = (1+ω) Xⁿ − ω Xⁿ⁻¹ (ω = 1: τ = 2Δt/3, X̂ = (4Xⁿ − Xⁿ⁻¹)/3, X* = 2Xⁿ − Xⁿ⁻¹).
        let w = omega.unwrap_or(1.0);
        let tau = if bdf2 {
            (1.0 + w) * self.params.dt / (1.0 + 2.0 * w)
        } else {
            self.params.dt
        };
        let coef = self.step_coefficients(tau);
        // The geometry of Xⁿ: its area and volume, and its area element for the local area
        // source.
        let g_now = engine.calc.geometry(&state.coefs)?;
        let (area0, volume0) = (g_now.area(), g_now.volume());
        if state.drift_targets.is_none() {
            state.drift_targets = Some((area0, volume0));
        }
        let coefs = &state.coefs;
        // X* (geometry of the operators) and X̂ (the history term), as coefficients.
        let (xstar, xhat): (Vec<f64>, Vec<f64>) = match (&state.previous_coefs, bdf2) {
            (Some(prev), true) => (
                coefs
                    .iter()
                    .zip(prev)
                    .map(|(c, o)| (1.0 + w) * c - w * o)
                    .collect(),
                coefs
                    .iter()
                    .zip(prev)
                    .map(|(c, o)| ((1.0 + w) * (1.0 + w) * c - w * w * o) / (1.0 + 2.0 * w))
                    .collect(),
            ),
            _ => (coefs.to_vec(), coefs.to_vec()),
        };
        let area_source = self.local_area_source(engine, state, &g_now.w, tau)?;
        drop(g_now);
        let inextensible = self.params.inextensible;
        if !inextensible && self.skalak.is_none() {
            return Err(TimestepError::InvalidParameter {
                name: "elasticity",
                value: "none".into(),
                reason: "a capsule (inextensible = false) needs a membrane elasticity \
                         (VesicleStepper::set_skalak)",
            });
        }
        let implicit_elastic = self.skalak.is_some()
            && self
                .params
                .elastic_stepping
                .map_or(!inextensible, |e| e == ElasticStepping::LinearlyImplicit);
        Ok(StepPlan {
            scheme,
            tau,
            coef,
            area0,
            volume0,
            xstar,
            xhat,
            area_source,
            inextensible,
            implicit_elastic,
            // The sphere preconditioner is that of the inextensible system.
            precondition: self.params.preconditioner && inextensible,
        })
    }

    /// Phase 2, the preconditioners of the step: the sphere's (built or reused) and the cell's
    /// own (to be built in the solve when stale), and how far the grid has turned with the
    /// cell.
    fn prepare_preconditioners(
        &mut self,
        engine: &mut StepEngine,
        plan: &StepPlan,
        state: &CellState,
    ) -> Result<StepPreconditioners, TimestepError> {
        let (sphere, sphere_built) = if plan.precondition {
            // With the drift correction the area is the target area at every step: the sphere
            // is built from it (not from the current area, which differs in the last bits), so
            // that a restarted run rebuilds the very same preconditioner (bit-identical restart).
            let area = match (self.params.correct_drift, state.drift_targets) {
                (true, Some((a, _))) => a,
                _ => engine.calc.geometry(&plan.xstar)?.area(),
            };
            let radius = (area / (4.0 * std::f64::consts::PI)).sqrt();
            let (i, b) = self.preconditioner_for(engine, radius, plan.coef)?;
            (Some(i), b)
        } else {
            (None, false)
        };
        let (build_own, own_rebuilt) = self.prepare_own(
            engine,
            &plan.coef,
            plan.precondition && plan.implicit_elastic,
            plan.precondition,
        )?;
        // How far the grid has turned with the cell: the sphere preconditioner is turned with
        // it (see super::grid_frame).
        let rotation = if plan.precondition {
            let g = engine.calc.geometry(&plan.xstar)?;
            grid_rotation(&g, &engine.sht.grid().unit_points())
        } else {
            IDENTITY
        };
        Ok(StepPreconditioners {
            sphere,
            sphere_built,
            build_own,
            own_rebuilt,
            rotation,
        })
    }

    /// Phase 3, the explicit terms on the grid: `X*` and `X̂`, the explicit traction
    /// `f_e(X*) + f_extra + F/A` and the velocity `u_∞(X*) + u_other`.
    fn explicit_grid_terms(
        &mut self,
        engine: &mut StepEngine,
        plan: &StepPlan,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        extra: ExplicitTerms<'_>,
    ) -> Result<GridTerms, TimestepError> {
        let n = self.n;
        let mut xs_grid = vec![0.0; 3 * n];
        let mut xh_grid = vec![0.0; 3 * n];
        engine
            .sht
            .inverse(&plan.xstar, &mut xs_grid, &mut engine.ws)
            .map_err(crate::vesicle::VesicleError::from)?;
        engine
            .sht
            .inverse(&plan.xhat, &mut xh_grid, &mut engine.ws)
            .map_err(crate::vesicle::VesicleError::from)?;
        let mut traction = vec![0.0; 3 * n];
        let area = {
            let OperatorWork { membrane, fb, .. } = engine.work.get_mut().expect("operator lock");
            membrane.set_geometry(&plan.xstar)?;
            if let Some(sk) = &self.skalak {
                membrane.skalak_force(sk, fb)?;
                traction.copy_from_slice(fb);
            }
            membrane.geometry()?.area()
        };
        if let Some(t) = extra.traction {
            for (a, b) in traction.iter_mut().zip(t) {
                *a += b;
            }
        }
        for c in 0..3 {
            for f in &mut traction[c * n..(c + 1) * n] {
                *f += self.params.force[c] / area;
            }
        }
        // u_∞(X*) + the other cells' velocity on the grid.
        let mut velocity = vec![0.0; 3 * n];
        for j in 0..n {
            let ui = u_inf([xs_grid[j], xs_grid[n + j], xs_grid[2 * n + j]]);
            for c in 0..3 {
                velocity[c * n + j] = ui[c] + extra.velocity.map_or(0.0, |v| v[c * n + j]);
            }
        }
        Ok(GridTerms {
            xs_grid,
            xh_grid,
            traction,
            velocity,
            // The cell's size (area-equivalent radius), the scale of the Jacobian's
            // difference step.
            size: (area / (4.0 * std::f64::consts::PI)).sqrt(),
        })
    }

    /// Phase 4, the operators at `X*`: the single layer, and the double layer for `λ ≠ 1`
    /// (kept per cell or lent by the engine, as [`Self::operator_storage`] says).
    fn assemble(&mut self, engine: &mut StepEngine, plan: &StepPlan) -> Result<(), TimestepError> {
        assemble_operator(
            engine,
            self.storage,
            LayerKernel::SingleLayer {
                viscosity: self.params.viscosity,
            },
            &plan.xstar,
            &mut self.s_op,
        )?;
        if plan.coef.double_layer != 0.0 {
            assemble_operator(
                engine,
                self.storage,
                LayerKernel::DoubleLayer,
                &plan.xstar,
                &mut self.d_op,
            )?;
            self.double_layer_assemblies += 1;
        } else if storage_keeps_per_cell(self.storage) {
            // No double layer: a kept one is freed (a lent one goes back to the engine).
            self.d_op = Vec::new();
        }
        Ok(())
    }

    /// Phase 5, the linear system of the step, solved by GMRES: a capsule's for `X − X*`, an
    /// inextensible cell's for `[X; σ]`. Returns the solve's report, `Xⁿ⁺¹` on the grid, and
    /// whether the cell's own preconditioner was built (or rebuilt from its record).
    fn solve(
        &mut self,
        engine: &mut StepEngine,
        plan: &StepPlan,
        pcs: &StepPreconditioners,
        terms: &GridTerms,
        state: &mut CellState,
    ) -> Result<(GmresReport, Vec<f64>, bool), TimestepError> {
        match (&self.skalak, plan.inextensible) {
            (Some(sk), false) => {
                let reference =
                    state
                        .skalak_reference
                        .as_deref()
                        .ok_or(TimestepError::InvalidParameter {
                            name: "skalak reference",
                            value: "none".into(),
                            reason: "a cell with shear elasticity needs its reference in its state",
                        })?;
                let (s_op, d_op) = step_operators(
                    self.storage,
                    self.params.viscosity,
                    &self.s_op,
                    &self.d_op,
                    plan.coef.double_layer,
                );
                let (report, x) = solve_capsule(
                    engine,
                    &CapsuleSystem {
                        storage: self.storage,
                        s_op,
                        d_op,
                        xstar: &plan.xstar,
                        xs_grid: &terms.xs_grid,
                        xh_grid: &terms.xh_grid,
                        traction: &terms.traction,
                        velocity: &terms.velocity,
                        a_id: plan.coef.identity,
                        c_d: plan.coef.double_layer,
                        tau: plan.tau,
                        kappa: self.params.bending_modulus,
                        jacobian: plan.implicit_elastic.then_some((sk, reference)),
                        size: terms.size,
                    },
                    &self.params.gmres,
                )?;
                Ok((report, x, pcs.own_rebuilt))
            }
            _ => self.solve_inextensible(engine, plan, pcs, terms, state),
        }
    }

    /// An inextensible cell's system for `[X; σ]` (the elastic Jacobian in the operator when
    /// linearly implicit), the cell's own preconditioner built first when phase 2 found it
    /// stale.
    fn solve_inextensible(
        &mut self,
        engine: &mut StepEngine,
        plan: &StepPlan,
        pcs: &StepPreconditioners,
        terms: &GridTerms,
        state: &mut CellState,
    ) -> Result<(GmresReport, Vec<f64>, bool), TimestepError> {
        let (n, nc) = (self.n, self.nc);
        let (a_id, c_d, tau) = (plan.coef.identity, plan.coef.double_layer, plan.tau);
        let kappa = self.params.bending_modulus;
        let storage = self.storage;
        let (s_op, d_op) =
            step_operators(storage, self.params.viscosity, &self.s_op, &self.d_op, c_d);
        let (xs_grid, size) = (&terms.xs_grid, terms.size);
        let xstar = &plan.xstar;
        let mut own_built = pcs.own_rebuilt;
        let mut b = self.inextensible_rhs(engine, plan, terms, s_op, d_op)?;
        // With the elasticity linearly implicit, the Jacobian's engine (see below).
        let jacobian = match (&self.skalak, &state.skalak_reference, plan.implicit_elastic) {
            (Some(sk), Some(reference), true) => {
                let OperatorWork {
                    membrane, elastic, ..
                } = engine.work.get_mut().expect("operator lock");
                elastic_work(elastic, membrane, nc, reference)?;
                Some(*sk)
            }
            _ => None,
        };
        // The operator [X; σ] ↦ [a X − c_D D X − τ S (B X + T σ); Div X] (plus −τ S J X
        // once the Jacobian is enabled).
        let op = InextensibleOperator::new(
            n,
            &engine.work,
            &engine.sht,
            storage,
            xstar,
            (s_op, d_op),
            [a_id, c_d, tau, kappa],
            jacobian,
            size,
        );
        // Initial guess: X* (the extrapolation for BDF2, Xⁿ for Euler) and the last tension.
        let mut z0 = vec![0.0; 4 * n];
        z0[..3 * n].copy_from_slice(xs_grid);
        z0[3 * n..].copy_from_slice(&state.sigma);
        if jacobian.is_some() {
            // Solve for δ = X − X* (so that the Jacobian's relative error multiplies the
            // small δ, as for capsules): b ← b − A [X*; 0] with A without J, then J on.
            let mut xs0 = vec![0.0; 4 * n];
            xs0[..3 * n].copy_from_slice(xs_grid);
            let mut shift = vec![0.0; 4 * n];
            super::LinearOperator::apply(&op, &xs0, &mut shift);
            for (bi, si) in b.iter_mut().zip(&shift) {
                *bi -= si;
            }
            z0[..3 * n].fill(0.0);
            op.enable_jacobian();
        }
        // The cell's own preconditioner, (re)built now if `prepare_own` found it stale.
        if pcs.build_own {
            let jacobian_reference = jacobian.and(state.skalak_reference.clone());
            self.own =
                Some(self.own_preconditioner(&op, &engine.sht, plan, pcs, jacobian_reference)?);
            self.own_preconditioner_builds += 1;
            own_built = true;
        }
        let (report, mut z) = self.run_gmres(&op, &engine.sht, &mut engine.gmres_ws, pcs, &b, &z0);
        if let Some(e) = op.take_failure() {
            return Err(e.into());
        }
        // A (nearly) spherical cell makes the system singular: a constant tension gives the
        // traction 2σHn with H constant, whose single layer vanishes on a closed surface. A
        // right-hand side with a component outside the range (a sphere in a straining flow,
        // to discretisation accuracy) then ends in `Breakdown`, which is reported as an error:
        // the least-squares answer carries an arbitrary, possibly huge mean tension, and the
        // explicit coupling would spread it to the other cells.
        let report = report?;
        if let Some(o) = &mut self.own {
            o.record.last_iterations = report.iterations;
        }
        state.sigma.copy_from_slice(&z[3 * n..]);
        z.truncate(3 * n);
        if jacobian.is_some() {
            for (zi, s) in z.iter_mut().zip(xs_grid) {
                *zi += s;
            }
        }
        Ok((report, z, own_built))
    }

    /// The right-hand side of an inextensible cell's system,
    /// `[a X̂ − c_D D X̂ + τ (u_∞(X*) + u_other + S f_ext); Div X̂ + r]` (`r` the local area
    /// source).
    fn inextensible_rhs(
        &self,
        engine: &mut StepEngine,
        plan: &StepPlan,
        terms: &GridTerms,
        s_op: StepOperator<'_>,
        d_op: Option<StepOperator<'_>>,
    ) -> Result<Vec<f64>, TimestepError> {
        let n = self.n;
        let (a_id, c_d, tau) = (plan.coef.identity, plan.coef.double_layer, plan.tau);
        let GridTerms {
            xh_grid,
            traction: fext,
            velocity: u,
            ..
        } = terms;
        let xstar = &plan.xstar;
        let storage = self.storage;
        let mut b = vec![0.0; 4 * n];
        for ((bi, h), ui) in b.iter_mut().zip(xh_grid).zip(u) {
            *bi = a_id * h + tau * ui;
        }
        {
            let OperatorWork {
                membrane, products, ..
            } = engine.work.get_mut().expect("operator lock");
            apply_operators(
                storage,
                &engine.sht,
                products,
                xstar,
                (s_op, fext, tau),
                d_op.map(|d| (d, &xh_grid[..], -c_d)),
                &mut b[..3 * n],
            )?;
            membrane.surface_divergence(xh_grid, &mut b[3 * n..])?;
            if let Some(r) = &plan.area_source {
                // Filtered as the divergence is, so that the source lies in the range of
                // `Div` (unfiltered, GMRES stagnates at the part outside it).
                let mut rq = vec![0.0; membrane.n_points_upsampled()];
                membrane.upsample(r, &mut rq)?;
                let mut rp = vec![0.0; n];
                membrane.filter_density(&mut rq, &mut rp)?;
                for (bi, ri) in b[3 * n..].iter_mut().zip(&rp) {
                    *bi += ri;
                }
            }
        }
        Ok(b)
    }

    /// The cell's own preconditioner: the inverse of the step's operator `op` at `X*` (with
    /// the elastic Jacobian of `jacobian_reference`, if any), recorded with what it was built
    /// from.
    fn own_preconditioner(
        &self,
        op: &InextensibleOperator<'_>,
        sht: &ShTransform,
        plan: &StepPlan,
        pcs: &StepPreconditioners,
        jacobian_reference: Option<Vec<f64>>,
    ) -> Result<OwnPreconditioner, TimestepError> {
        let inverse = own_inverse(op, sht, plan.coef.identity)?;
        Ok(OwnPreconditioner {
            record: PreconditionerRecord {
                surface: plan.xstar.clone(),
                tau: plan.tau,
                jacobian_reference,
                last_iterations: 0,
            },
            coefs: plan.coef,
            inverse,
            frame: pcs.rotation,
        })
    }

    /// GMRES on the step's system `op z = b` from `z0` (returns its report and `z`),
    /// preconditioned by the cell's own
    /// preconditioner (where built), else the sphere's, both turned with the grid, else none.
    fn run_gmres(
        &self,
        op: &InextensibleOperator<'_>,
        sht: &ShTransform,
        ws: &mut GmresWorkspace,
        pcs: &StepPreconditioners,
        b: &[f64],
        z0: &[f64],
    ) -> (Result<GmresReport, TimestepError>, Vec<f64>) {
        let n = self.n;
        let mut z = vec![0.0; 4 * n];
        let own_pc = match self.own.as_ref() {
            Some(OwnPreconditioner {
                inverse: OwnInverse::Built(pc),
                frame,
                ..
            }) => Some((pc, relative_rotation(&pcs.rotation, frame))),
            _ => None,
        };
        let report = match (pcs.sphere, own_pc) {
            (Some(_), Some((pc, turn))) => gmres(
                op,
                &RotatedPreconditioner::new(&CellPreconditionerOp::new(pc, sht), turn, n),
                b,
                Some(z0),
                &mut z,
                &self.params.gmres,
                ws,
            ),
            (Some(i), None) => gmres(
                op,
                &RotatedPreconditioner::new(&*self.preconditioners[i], pcs.rotation, n),
                b,
                Some(z0),
                &mut z,
                &self.params.gmres,
                ws,
            ),
            (None, _) => gmres(
                op,
                &Identity::new(4 * n),
                b,
                Some(z0),
                &mut z,
                &self.params.gmres,
                ws,
            ),
        };
        (report, z)
    }

    /// Phase 6, the new surface: the membrane velocity `(Xⁿ⁺¹ − X̂)/τ`, the history moved on
    /// (BDF2), `Xⁿ⁺¹` into `coefs`. Returns the relative area and volume change of the flow
    /// step (a capsule: the volume's alone), the adaptive step's error estimate.
    fn advance(
        &self,
        engine: &mut StepEngine,
        state: &mut CellState,
        plan: &StepPlan,
        x_new: &[f64],
        xh_grid: &[f64],
    ) -> Result<f64, TimestepError> {
        // The membrane velocity of this step, u = (Xⁿ⁺¹ − X̂)/τ on the grid.
        let tau = plan.tau;
        let velocity = state.membrane_velocity.get_or_insert_with(Vec::new);
        velocity.clear();
        velocity.extend(x_new.iter().zip(xh_grid).map(|(x, h)| (x - h) / tau));
        if self.params.scheme == TimeScheme::Bdf2 {
            match &mut state.previous_coefs {
                Some(prev) => prev.copy_from_slice(&state.coefs),
                None => state.previous_coefs = Some(state.coefs.clone()),
            }
            state.previous_dt = Some(self.params.dt);
        }
        engine
            .sht
            .forward(x_new, &mut state.coefs, &mut engine.ws)
            .map_err(crate::vesicle::VesicleError::from)?;
        // The error estimate of the flow step itself (before the reparametrisation, which
        // changes area and volume by the discretisation error, whatever the step).
        let g = engine.calc.geometry(&state.coefs)?;
        let dv = ((g.volume() - plan.volume0) / plan.volume0).abs();
        // A capsule's area changes with the flow: only the volume is an invariant.
        Ok(if plan.inextensible {
            ((g.area() - plan.area0) / plan.area0).abs().max(dv)
        } else {
            dv
        })
    }

    /// Phase 7, the surface's grid and drift: the reparametrisation (when asked for) and the
    /// correction of area and volume to the targets (a capsule: the volume's alone).
    fn regrid_and_correct(
        &self,
        engine: &mut StepEngine,
        state: &mut CellState,
        plan: &StepPlan,
    ) -> Result<(), TimestepError> {
        if let Some(rp) = self.params.reparametrize {
            self.regrid(engine, state, &rp)?;
        }
        if self.params.correct_drift {
            let (area, volume) = state.drift_targets.expect("set by the plan");
            // A capsule's area is free: the volume alone.
            correct_shape(
                engine,
                &mut state.coefs,
                plan.inextensible.then_some(area),
                volume,
            )?;
        }
        Ok(())
    }

    /// The source `r = (τ/Δt)(W_ref (A/A_ref) / Wⁿ − 1)` of the constraint `Div (X − X̂) = r`
    /// that brings the area element `W` of every material point back toward the reference's
    /// (module docs, "Local area"), `w_now` the area element `Wⁿ` on the grid; `None` without
    /// a Skalak reference, for a capsule, or when switched off. Needs the drift targets set.
    fn local_area_source(
        &self,
        engine: &mut StepEngine,
        state: &CellState,
        w_now: &[f64],
        tau: f64,
    ) -> Result<Option<Vec<f64>>, TimestepError> {
        let reference = match (&self.skalak, &state.skalak_reference) {
            (Some(_), Some(r)) if self.params.inextensible && self.local_area_relaxation => r,
            _ => return Ok(None),
        };
        let g_ref = engine.calc.geometry(reference)?;
        // The reference's area element scaled to the area the drift correction restores (the
        // reference composed from its labels differs from its first area by one re-fit): both
        // corrections then ask for the same total area instead of undoing each other.
        let (target, _) = state
            .drift_targets
            .expect("set by the step before this call");
        let ratio = target / g_ref.area();
        let scale = tau / self.params.dt;
        Ok(Some(
            w_now
                .iter()
                .zip(&g_ref.w)
                .map(|(w, r)| scale * (ratio * r / w - 1.0))
                .collect(),
        ))
    }

    /// Relax the parametrisation after a step ([`Reparametrizer::run_with`]), relabelling every
    /// material quantity of the cell with the grid: the Skalak reference (otherwise the shear
    /// elasticity would see the tangential move as a strain), the tension, the membrane
    /// velocity and the BDF2 history, so that each stays attached to the same membrane point.
    fn regrid(
        &self,
        engine: &mut StepEngine,
        state: &mut CellState,
        rp: &ReparamParams,
    ) -> Result<(), TimestepError> {
        use crate::vesicle::VesicleError;
        let nc = self.nc;
        if engine.reparametrizer.is_none() {
            engine.reparametrizer = Some(Reparametrizer::new(self.p)?);
        }
        // The tension (a scalar, padded to three functions) and the velocity as coefficients.
        let mut sigma_c = vec![0.0; 3 * nc];
        engine
            .sht
            .forward(&state.sigma, &mut sigma_c[..nc], &mut engine.ws)
            .map_err(VesicleError::from)?;
        let mut velocity_c = match &state.membrane_velocity {
            Some(v) => {
                let mut c = vec![0.0; 3 * nc];
                engine
                    .sht
                    .forward(v, &mut c, &mut engine.ws)
                    .map_err(VesicleError::from)?;
                Some(c)
            }
            None => None,
        };
        let mut surf = Surface::from_coefs(self.p, state.coefs.clone())?;
        {
            let mut passengers: Vec<&mut [f64]> = vec![&mut sigma_c[..]];
            if let Some(v) = velocity_c.as_mut() {
                passengers.push(&mut v[..]);
            }
            // The Skalak reference moves with the grid through its labels (composed below;
            // `set_skalak` gives every Skalak cell labels): relabelled itself, its re-fits
            // would change its shape.
            if let Some(l) = state.material_labels.as_mut() {
                passengers.push(&mut l.map[..]);
            }
            if let Some(prev) = state.previous_coefs.as_mut() {
                passengers.push(&mut prev[..]);
            }
            engine
                .reparametrizer
                .as_mut()
                .expect("planned above")
                .run_with(&mut surf, rp, &mut passengers)?;
        }
        state.coefs.copy_from_slice(surf.coefs());
        if let (Some(l), Some(reference)) =
            (&state.material_labels, state.skalak_reference.as_mut())
        {
            l.compose(&engine.sht, &mut engine.ws, reference)?;
        }
        engine
            .sht
            .inverse(&sigma_c[..nc], &mut state.sigma, &mut engine.ws)
            .map_err(VesicleError::from)?;
        if let (Some(c), Some(v)) = (velocity_c, state.membrane_velocity.as_mut()) {
            engine
                .sht
                .inverse(&c, v, &mut engine.ws)
                .map_err(VesicleError::from)?;
        }
        Ok(())
    }

    /// Move the surface along its normal by `(α + β H) n` so that its area and volume become
    /// `area` and `volume` (three Newton steps; quadratic convergence from a small drift). For
    /// both, whatever the cell: the step's own correction of a capsule restores the volume
    /// alone.
    pub fn correct_area_volume(
        &self,
        coefs: &mut [f64],
        area: f64,
        volume: f64,
    ) -> Result<(), TimestepError> {
        let mut engine = self.lease(None)?;
        correct_shape(&mut engine, coefs, Some(area), volume)
    }
}

/// [`VesicleStepper::correct_area_volume`] with a lent engine; with `area = None` (a capsule,
/// whose area is free) the volume alone, by a uniform normal displacement `α n`.
fn correct_shape(
    engine: &mut StepEngine,
    coefs: &mut [f64],
    area: Option<f64>,
    volume: f64,
) -> Result<(), TimestepError> {
    let n = engine.sht.n_points();
    let mut xg = vec![0.0; 3 * n];
    for _ in 0..3 {
        let g = engine.calc.geometry(coefs)?;
        let da = area.map_or(0.0, |a| a - g.area());
        let dv = volume - g.volume();
        if da.abs() <= 1e-14 * area.unwrap_or(0.0) && dv.abs() <= 1e-14 * volume {
            break;
        }
        let hh: Vec<f64> = g.h.iter().map(|h| h * h).collect();
        let (i0, i1, i2) = (g.area(), g.integrate(&g.h), g.integrate(&hh));
        // [i0 i1; −2 i1 −2 i2] [α; β] = [δV; δA]
        let det = -2.0 * i0 * i2 + 2.0 * i1 * i1;
        // On a sphere H is constant and the system is singular (Cauchy–Schwarz): a sphere
        // of the target volume is the only freedom left, so restore the volume alone.
        let (alpha, beta) = if area.is_none() || det.abs() <= 1e-8 * 2.0 * i0 * i2 {
            (dv / i0, 0.0)
        } else {
            (
                (-2.0 * i2 * dv - i1 * da) / det,
                (i0 * da + 2.0 * i1 * dv) / det,
            )
        };
        engine
            .sht
            .inverse(coefs, &mut xg, &mut engine.ws)
            .map_err(crate::vesicle::VesicleError::from)?;
        for j in 0..n {
            let phi = alpha + beta * g.h[j];
            for c in 0..3 {
                xg[c * n + j] += phi * g.normal[j][c];
            }
        }
        engine
            .sht
            .forward(&xg, coefs, &mut engine.ws)
            .map_err(crate::vesicle::VesicleError::from)?;
    }
    Ok(())
}

/// The engine of the elastic Jacobian in `work` (made at its first use), with `reference` set.
fn elastic_work<'a>(
    elastic: &'a mut Option<ElasticWork>,
    membrane: &Membrane,
    nc: usize,
    reference: &[f64],
) -> Result<&'a mut ElasticWork, TimestepError> {
    let el = match elastic {
        Some(el) => el,
        None => elastic.insert(ElasticWork::new(
            membrane.order(),
            membrane.upsampled_order(),
            nc,
        )?),
    };
    el.membrane.set_reference(reference)?;
    Ok(el)
}

/// What a step takes from the history (phase 1 of [`VesicleStepper::step_with`]).
struct StepPlan {
    scheme: TimeScheme,
    tau: f64,
    coef: StepCoefficients,
    /// Area and volume of `Xⁿ`.
    area0: f64,
    volume0: f64,
    /// `X*` (the operators' geometry) and `X̂` (the history term), as coefficients.
    xstar: Vec<f64>,
    xhat: Vec<f64>,
    /// The local area source of the constraint (`None`: none).
    area_source: Option<Vec<f64>>,
    inextensible: bool,
    /// Whether the elastic force is linearised in the operator.
    implicit_elastic: bool,
    /// Whether GMRES is preconditioned (an inextensible cell with the preconditioner on).
    precondition: bool,
}

/// The preconditioners of a step (phase 2).
struct StepPreconditioners {
    /// The sphere preconditioner in use (`None`: unpreconditioned), and whether it was built
    /// for this step.
    sphere: Option<usize>,
    sphere_built: bool,
    /// Whether the cell's own preconditioner is to be built in the solve, and whether it was
    /// rebuilt from its record.
    build_own: bool,
    own_rebuilt: bool,
    /// How far the grid has turned with the cell.
    rotation: Rotation,
}

/// The explicit terms of a step on the order-`p` grid (phase 3).
struct GridTerms {
    /// `X*` and `X̂`.
    xs_grid: Vec<f64>,
    xh_grid: Vec<f64>,
    /// `f_e(X*) + f_extra + F/A`.
    traction: Vec<f64>,
    /// `u_∞(X*) + u_other`.
    velocity: Vec<f64>,
    /// The area-equivalent radius at `X*`.
    size: f64,
}

/// The linear system of a capsule's step (see "Capsules" in the module docs): operators at
/// `X*`, grid vectors `3n`.
struct CapsuleSystem<'a> {
    storage: OperatorStorage,
    s_op: StepOperator<'a>,
    d_op: Option<StepOperator<'a>>,
    /// `X*` as coefficients and on the grid, `X̂` on the grid.
    xstar: &'a [f64],
    xs_grid: &'a [f64],
    xh_grid: &'a [f64],
    /// `f_e(X*) + f_ext` (body force and extra tractions).
    traction: &'a [f64],
    /// `u_∞(X*)` plus the other cells' velocity.
    velocity: &'a [f64],
    a_id: f64,
    c_d: f64,
    tau: f64,
    kappa: f64,
    /// The elasticity whose Jacobian enters the operator (`None`: explicit elasticity) and its
    /// reference surface.
    jacobian: Option<(&'a SkalakParams, &'a [f64])>,
    /// The cell's size (area-equivalent radius), the scale of the difference step.
    size: f64,
}

/// The single and double layer of a step as its operators apply them: the cell's dense
/// matrices (`s_op`, `d_op`), or their kernels for matrix-free storage; no double layer when
/// `c_d = 0` (`λ = 1`).
fn step_operators<'a>(
    storage: OperatorStorage,
    viscosity: f64,
    s_op: &'a [f64],
    d_op: &'a [f64],
    c_d: f64,
) -> (StepOperator<'a>, Option<StepOperator<'a>>) {
    match storage {
        OperatorStorage::MatrixFree => (
            StepOperator::Kernel(LayerKernel::SingleLayer { viscosity }),
            (c_d != 0.0).then_some(StepOperator::Kernel(LayerKernel::DoubleLayer)),
        ),
        _ => (
            StepOperator::Dense(s_op),
            (c_d != 0.0).then_some(StepOperator::Dense(d_op)),
        ),
    }
}

/// Solve a capsule's step for `δ = X − X*`; returns the solve's report and `X = X* + δ` on the
/// grid.
fn solve_capsule(
    engine: &mut StepEngine,
    sys: &CapsuleSystem<'_>,
    gmres_params: &GmresParams,
) -> Result<(GmresReport, Vec<f64>), TimestepError> {
    use crate::vesicle::VesicleError;
    let n = engine.sht.n_points();
    let nc = engine.sht.n_coefs();
    let (a_id, c_d, tau, kappa) = (sys.a_id, sys.c_d, sys.tau, sys.kappa);
    // Right-hand side a (X̂ − X*) − c_D D (X̂ − X*) + τ (u + S (f_e(X*) + f_ext + B X*)).
    let dh: Vec<f64> = sys
        .xh_grid
        .iter()
        .zip(sys.xs_grid)
        .map(|(h, s)| h - s)
        .collect();
    let mut b: Vec<f64> = dh
        .iter()
        .zip(sys.velocity)
        .map(|(d, u)| a_id * d + tau * u)
        .collect();
    {
        let OperatorWork {
            membrane,
            fb,
            products,
            elastic,
            ..
        } = engine.work.get_mut().expect("operator lock");
        membrane.bending_linear(kappa, sys.xs_grid, fb)?;
        for (f, t) in fb.iter_mut().zip(sys.traction) {
            *f += t;
        }
        apply_operators(
            sys.storage,
            &engine.sht,
            products,
            sys.xstar,
            (sys.s_op, fb, tau),
            sys.d_op.map(|d| (d, &dh[..], -c_d)),
            &mut b,
        )?;
        if let Some((_, reference)) = sys.jacobian {
            elastic_work(elastic, membrane, nc, reference)?;
        }
    }
    let (work, sht) = (&engine.work, &engine.sht);
    let failure: Mutex<Option<VesicleError>> = Mutex::new(None);
    let op = FnOperator::new(3 * n, |x: &[f64], y: &mut [f64]| {
        let mut guard = work.lock().expect("operator lock");
        let OperatorWork {
            membrane,
            fb,
            products,
            elastic,
            ..
        } = &mut *guard;
        let r = (|| {
            membrane.bending_linear(kappa, x, fb)?;
            if let (Some((par, _)), Some(el)) = (sys.jacobian, elastic.as_mut()) {
                add_elastic_jacobian(el, sht, &mut products.ws, par, sys.xstar, sys.size, x, fb)?;
            }
            for (yi, xi) in y.iter_mut().zip(x) {
                *yi = a_id * xi;
            }
            apply_operators(
                sys.storage,
                sht,
                products,
                sys.xstar,
                (sys.s_op, fb, -tau),
                sys.d_op.map(|d| (d, x, -c_d)),
                y,
            )
        })();
        if let Err(e) = r {
            *failure.lock().expect("failure lock") = Some(e);
            y.fill(f64::NAN);
        }
    });
    let mut z = vec![0.0; 3 * n];
    let report = gmres(
        &op,
        &Identity::new(3 * n),
        &b,
        None,
        &mut z,
        gmres_params,
        &mut engine.gmres_ws,
    );
    if let Some(e) = failure.into_inner().expect("failure lock") {
        return Err(e.into());
    }
    let report = report?;
    for (zi, s) in z.iter_mut().zip(sys.xs_grid) {
        *zi += s;
    }
    Ok((report, z))
}

/// Whether `storage` keeps a cell's operators in the cell (not lent by the step engine).
fn storage_keeps_per_cell(storage: OperatorStorage) -> bool {
    storage != OperatorStorage::Grid
}

/// Assemble the dense operator of `kernel` at the surface `coefs` into `out`, kept as `storage`
/// says (coefficient space: assembled on the grid in the engine's scratch, then compressed).
fn assemble_operator(
    engine: &mut StepEngine,
    storage: OperatorStorage,
    kernel: LayerKernel,
    coefs: &[f64],
    out: &mut Vec<f64>,
) -> Result<(), TimestepError> {
    let (n, nc) = (engine.sht.n_points(), engine.sht.n_coefs());
    let layer = &mut engine.work.get_mut().expect("operator lock").products.layer;
    match storage {
        OperatorStorage::Grid if layer.quadrature_order() > layer.order() => {
            // The rows over the density's coefficients: A = P F (half of A's entries at p = 12).
            out.resize(9 * n * nc, 0.0);
            layer.assemble_rows(kernel, coefs, out)?;
        }
        OperatorStorage::Grid => {
            out.resize(9 * n * n, 0.0);
            layer.assemble(kernel, coefs, out)?;
        }
        OperatorStorage::Coefficients if layer.quadrature_order() > layer.order() => {
            // A_c = F P from the rows over coefficients.
            engine.grid_op.resize(9 * n * nc, 0.0);
            layer.assemble_rows(kernel, coefs, &mut engine.grid_op)?;
            out.resize(9 * nc * nc, 0.0);
            engine.compressor.compress_rows(&engine.grid_op, out)?;
        }
        OperatorStorage::Coefficients => {
            engine.grid_op.resize(9 * n * n, 0.0);
            layer.assemble(kernel, coefs, &mut engine.grid_op)?;
            out.resize(9 * nc * nc, 0.0);
            engine.compressor.compress(&engine.grid_op, out)?;
        }
        OperatorStorage::MatrixFree => *out = Vec::new(),
    }
    Ok(())
}

/// Forward Euler of bending-driven flow, `X ← X + Δt (u_∞(X) + S[f_b(X)])`, without the
/// inextensibility constraint: the explicit reference whose stiffness limit `Δt ~ μh³/κ` the
/// semi-implicit step removes (used to measure that limit).
pub struct ExplicitStepper {
    kappa: f64,
    viscosity: f64,
    dt: f64,
    membrane: Membrane,
    layer: SelfInteraction,
    sht: ShTransform,
    ws: ShWorkspace,
    x: Vec<f64>,
    fb: Vec<f64>,
    u: Vec<f64>,
}

impl ExplicitStepper {
    /// Plan for order `p`, forces and quadrature at order `q`.
    pub fn new(
        p: usize,
        q: usize,
        kappa: f64,
        viscosity: f64,
        dt: f64,
    ) -> Result<Self, TimestepError> {
        check("bending_modulus", kappa)?;
        check("viscosity", viscosity)?;
        check("dt", dt)?;
        let sht = ShTransform::new(p).map_err(crate::vesicle::VesicleError::from)?;
        let n = sht.n_points();
        Ok(ExplicitStepper {
            kappa,
            viscosity,
            dt,
            membrane: Membrane::new(p, q)?,
            layer: SelfInteraction::new(p, q, RotationAlgorithm::Direct)?,
            ws: sht.workspace(),
            sht,
            x: vec![0.0; 3 * n],
            fb: vec![0.0; 3 * n],
            u: vec![0.0; 3 * n],
        })
    }

    /// The bending energy `(κ/2)∫(2H)² dA` of a surface.
    pub fn bending_energy(&mut self, coefs: &[f64]) -> Result<f64, TimestepError> {
        self.membrane.set_geometry(coefs)?;
        Ok(self.membrane.bending_energy(self.kappa)?)
    }

    /// One explicit step.
    pub fn step(
        &mut self,
        coefs: &mut [f64],
        u_inf: &dyn Fn([f64; 3]) -> [f64; 3],
    ) -> Result<(), TimestepError> {
        let n = self.sht.n_points();
        self.membrane.set_geometry(coefs)?;
        self.membrane.bending_force(self.kappa, &mut self.fb)?;
        self.layer.evaluate(
            LayerKernel::SingleLayer {
                viscosity: self.viscosity,
            },
            coefs,
            &self.fb,
            &mut self.u,
        )?;
        self.sht
            .inverse(coefs, &mut self.x, &mut self.ws)
            .map_err(crate::vesicle::VesicleError::from)?;
        for j in 0..n {
            let b = u_inf([self.x[j], self.x[n + j], self.x[2 * n + j]]);
            for (c, bc) in b.iter().enumerate() {
                self.x[c * n + j] += self.dt * (self.u[c * n + j] + bc);
            }
        }
        self.sht
            .forward(&self.x, coefs, &mut self.ws)
            .map_err(crate::vesicle::VesicleError::from)?;
        Ok(())
    }
}

/// Whether forward Euler at step `dt` keeps the bending energy below `growth` times its start
/// for `steps` steps (an error or a non-finite energy counts as divergence).
pub fn explicit_is_stable(
    stepper: &mut ExplicitStepper,
    coefs: &[f64],
    steps: usize,
    growth: f64,
    u_inf: &dyn Fn([f64; 3]) -> [f64; 3],
) -> bool {
    let mut c = coefs.to_vec();
    let Ok(e0) = stepper.bending_energy(&c) else {
        return false;
    };
    for _ in 0..steps {
        if stepper.step(&mut c, u_inf).is_err() {
            return false;
        }
        match stepper.bending_energy(&c) {
            Ok(e) if e.is_finite() && e < growth * e0 => {}
            _ => return false,
        }
    }
    true
}

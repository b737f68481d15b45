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
//! ([`VesicleStepper::previous_coefs`], [`VesicleStepper::set_previous_coefs`] for restarts).
//! Explicit velocities passed by the caller ([`ExplicitTerms`]) are taken as they are (the
//! caller extrapolates them for second order). The area/volume drift correction keeps the
//! order (tests/timestep_order.rs: 1.98, 2.00, 2.01). Reparametrisation moves the grid of `Xⁿ⁺¹`
//! tangentially; the history `Xⁿ` is relabelled by the same parameter map, so that
//! `Xⁿ⁺¹ − Xⁿ` stays the flow's (without this, BDF2 falls to order ≈ 0.9). The
//! reparametrisation itself changes the shape slightly per call, independently of `Δt`, which
//! caps the accuracy at small `Δt` (measured orders 1.94, 1.75, 1.40 over Δt = 0.05 … 0.00625).
//!
//! The membrane velocity of the solve, `u = (Xⁿ⁺¹ − X̂)/τ` on the grid (before the
//! reparametrisation and the drift correction), is kept ([`VesicleStepper::velocity`]): a
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
//! `p`). [`Preconditioning::Cell`] ([`VesicleStepper::set_preconditioning`], scene
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
//! [`VesicleStepper::set_local_area_relaxation`] switches it off.
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
use super::cell_state::PreconditionerRecord;
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
    /// alone ([`VesicleStepper::set_skalak`], required); see "Capsules" in the module docs.
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

/// Steps one vesicle of SH order `p`.
///
/// The stepper holds the cell's own state; transforms, the membrane-force engine, the layer
/// potentials and scratch are lent per call by a pool shared by every stepper of the same
/// `(p, q, restart)` in the process (the crate's private `step_engine`), so that a suspension holds one
/// such engine per thread, not per cell.
pub struct VesicleStepper {
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
    /// Tension of the last step (initial guess of the next).
    pub sigma: Vec<f64>,
    /// Area and volume to restore (those of the first step's surface).
    targets: Option<(f64, f64)>,
    /// Shear elasticity (explicit) and its stress-free reference surface (coefficients).
    skalak: Option<(SkalakParams, Vec<f64>)>,
    /// The Skalak reference as its first surface and the grid's material labels (the reference
    /// above is composed from them after every reparametrisation).
    labels: Option<MaterialLabels>,
    /// Double-layer operators assembled by the steps so far (0 for `λ = 1`: only what is called
    /// for; a preconditioner rebuilt from its record assembles again, not counted here).
    pub double_layer_assemblies: usize,
    /// `Xⁿ⁻¹` (coefficients) for BDF2.
    previous: Option<Vec<f64>>,
    /// The step `Δtⁿ⁻¹` that led from `Xⁿ⁻¹` to `Xⁿ` (variable-step BDF2).
    previous_dt: Option<f64>,
    /// Sphere preconditioners in use (at most two: the Euler and the BDF2 `τ`), shared with
    /// the other cells of the same sphere ([`sphere_preconditioner::shared`]).
    preconditioners: Vec<Arc<SpherePreconditioner>>,
    /// Which preconditioner the steps use.
    preconditioning: Preconditioning,
    /// The cell's own preconditioner ([`Preconditioning::Cell`]), once built.
    own: Option<OwnPreconditioner>,
    /// Own preconditioners built so far.
    pub own_preconditioner_builds: usize,
    /// Membrane velocity of the last solve on the order-`p` grid (see
    /// [`VesicleStepper::velocity`]).
    velocity: Option<Vec<f64>>,
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

impl VesicleStepper {
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
        Ok(VesicleStepper {
            p,
            n,
            nc,
            params,
            pool,
            far_side: FarSideParams::default(),
            storage: OperatorStorage::default(),
            s_op: Vec::new(),
            d_op: Vec::new(),
            sigma: vec![0.0; n],
            targets: None,
            skalak: None,
            labels: None,
            double_layer_assemblies: 0,
            previous: None,
            previous_dt: None,
            preconditioners: Vec::new(),
            preconditioning: Preconditioning::default(),
            own: None,
            own_preconditioner_builds: 0,
            velocity: None,
            local_area_relaxation: true,
        })
    }

    /// An engine for one call, set up for this cell (far-side settings, Skalak reference).
    fn lease(&self) -> Result<EngineLease, TimestepError> {
        let mut e = self.pool.lease()?;
        e.work
            .get_mut()
            .expect("operator lock")
            .products
            .layer
            .set_far_side_params(self.far_side)?;
        if let Some((_, reference)) = &self.skalak {
            e.work
                .get_mut()
                .expect("operator lock")
                .membrane
                .set_reference(reference)?;
        }
        Ok(e)
    }

    /// Add Skalak shear elasticity (explicit in time) relative to the stress-free surface
    /// `reference` (order-`p` coefficients, same parametrisation as the stepped surface).
    pub fn set_skalak(
        &mut self,
        params: SkalakParams,
        reference: &[f64],
    ) -> Result<(), TimestepError> {
        // Checked here (length, a proper surface), set on each engine lent to this cell; the
        // labels start as the identity.
        let labels = {
            let mut engine = self.pool.lease()?;
            let StepEngine { sht, ws, work, .. } = &mut *engine;
            work.get_mut()
                .expect("operator lock")
                .membrane
                .set_reference(reference)?;
            MaterialLabels::identity(sht, ws, reference)?
        };
        // Other elastic parameters change the Jacobian in the cell's own preconditioner (a
        // relabelled reference does not: the record keeps the one it was built with).
        if self.skalak.as_ref().is_none_or(|(p, _)| *p != params) {
            self.own = None;
        }
        self.skalak = Some((params, reference.to_vec()));
        self.labels = Some(labels);
        Ok(())
    }

    /// The Skalak reference's first surface and the grid's material labels
    /// ([`crate::vesicle::material_labels`]); `None` without shear elasticity.
    pub fn material_labels(&self) -> Option<&MaterialLabels> {
        self.labels.as_ref()
    }

    /// Restore the material labels (a restarted run or a repeated step), after
    /// [`VesicleStepper::set_skalak_reference`] (which starts the labels afresh from the
    /// reference it is given).
    ///
    /// # Errors
    /// [`TimestepError::InvalidParameter`] for a cell without shear elasticity or labels of
    /// the wrong size.
    pub fn set_material_labels(&mut self, labels: MaterialLabels) -> Result<(), TimestepError> {
        let expected = 3 * self.nc;
        if self.skalak.is_none()
            || labels.original.len() != expected
            || labels.map.len() != expected
        {
            return Err(TimestepError::InvalidParameter {
                name: "material labels",
                value: format!(
                    "{} + {} coefficients",
                    labels.original.len(),
                    labels.map.len()
                ),
                reason: "need a cell with shear elasticity and 3 n_c coefficients each",
            });
        }
        self.labels = Some(labels);
        Ok(())
    }

    /// The stress-free reference of the Skalak elasticity (coefficients) in the current
    /// parametrisation, composed from the material labels after every reparametrisation
    /// ([`VesicleStepper::material_labels`]); `None` without shear elasticity.
    pub fn skalak_reference(&self) -> Option<&[f64]> {
        self.skalak.as_ref().map(|(_, r)| &r[..])
    }

    /// Replace the (relabelled) Skalak reference (a restarted run or a repeated step restores
    /// it). The material labels start afresh from it (the identity map): a caller that kept
    /// them restores them next with [`VesicleStepper::set_material_labels`].
    ///
    /// # Errors
    /// [`TimestepError::InvalidParameter`] for a cell without shear elasticity; the checks of
    /// [`VesicleStepper::set_skalak`] for the surface.
    pub fn set_skalak_reference(&mut self, reference: &[f64]) -> Result<(), TimestepError> {
        let Some((params, _)) = self.skalak else {
            return Err(TimestepError::InvalidParameter {
                name: "skalak reference",
                value: format!("{} coefficients", reference.len()),
                reason: "the cell has no shear elasticity",
            });
        };
        self.set_skalak(params, reference)
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

    /// What the cell's own preconditioner was built from (`None`: it has none), for a
    /// checkpoint or a cell moving to another rank.
    pub fn own_preconditioner_record(&self) -> Option<&PreconditionerRecord> {
        self.own.as_ref().map(|o| &o.record)
    }

    /// Give the cell the own preconditioner built from `record` (`None`: none): unless it is
    /// the one it holds, it is rebuilt from the record before the next step that uses it, bit
    /// for bit the one the record came from (a resumed run, a cell moved here, a repeated
    /// step).
    pub fn set_own_preconditioner_record(&mut self, record: Option<&PreconditionerRecord>) {
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

    /// Bytes of this cell's own state (its dense operators, preconditioners and vectors;
    /// the engines lent by the pool are shared and not counted).
    pub fn memory_bytes(&self) -> usize {
        let vecs = self.s_op.capacity()
            + self.d_op.capacity()
            + self.sigma.capacity()
            + self.previous.as_ref().map_or(0, |v| v.capacity())
            + self.velocity.as_ref().map_or(0, |v| v.capacity())
            + self.skalak.as_ref().map_or(0, |(_, r)| r.capacity())
            + self
                .labels
                .as_ref()
                .map_or(0, |l| l.original.capacity() + l.map.capacity());
        8 * vecs
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

    /// The area and volume the drift correction restores (set at the first step).
    pub fn drift_targets(&self) -> Option<(f64, f64)> {
        self.targets
    }

    /// Set the area and volume the drift correction restores (a restarted run keeps those of
    /// its first step).
    pub fn set_drift_targets(&mut self, targets: Option<(f64, f64)>) {
        self.targets = targets;
    }

    /// The coefficients `Xⁿ⁻¹` of the surface before the last step (kept by BDF2 runs; `None`
    /// before the first step or for Euler).
    pub fn previous_coefs(&self) -> Option<&[f64]> {
        self.previous.as_deref()
    }

    /// Set (or clear) `Xⁿ⁻¹` (a restarted BDF2 run restores it; `None` makes the next step
    /// Euler).
    ///
    /// # Errors
    /// [`TimestepError::DimensionMismatch`] for a wrong length, [`TimestepError::NonFinite`]
    /// for NaN or infinite coefficients.
    pub fn set_previous_coefs(&mut self, coefs: Option<&[f64]>) -> Result<(), TimestepError> {
        match coefs {
            None => self.previous = None,
            Some(c) => {
                let expected = 3 * self.nc;
                if c.len() != expected {
                    return Err(TimestepError::DimensionMismatch {
                        what: "previous coefficients",
                        expected,
                        got: c.len(),
                    });
                }
                if !c.iter().all(|v| v.is_finite()) {
                    return Err(TimestepError::NonFinite {
                        what: "previous coefficients",
                    });
                }
                self.previous = Some(c.to_vec());
            }
        }
        Ok(())
    }

    /// The step `Δtⁿ⁻¹` from `Xⁿ⁻¹` to `Xⁿ` (`None`: the step size of the run so far, `dt`).
    pub fn previous_dt(&self) -> Option<f64> {
        self.previous_dt
    }

    /// Set `Δtⁿ⁻¹` (restart of an adaptive BDF2 run).
    pub fn set_previous_dt(&mut self, dt: Option<f64>) -> Result<(), TimestepError> {
        if let Some(v) = dt {
            check("previous dt", v)?;
        }
        self.previous_dt = dt;
        Ok(())
    }

    /// Change the time step (adaptive `dt`). A BDF2 run then takes the variable-step formula
    /// with the ratio `ω = Δtⁿ/Δtⁿ⁻¹`.
    pub fn set_dt(&mut self, dt: f64) -> Result<(), TimestepError> {
        check("dt", dt)?;
        self.params.dt = dt;
        Ok(())
    }

    /// `ω = Δtⁿ/Δtⁿ⁻¹` when the next step is a BDF2 step (`None`: an Euler step): explicit
    /// terms are extrapolated to the operators' geometry `X* = (1 + ω)Xⁿ − ωXⁿ⁻¹`.
    pub fn extrapolation_ratio(&self) -> Option<f64> {
        (self.params.scheme == TimeScheme::Bdf2 && self.previous.is_some())
            .then(|| self.params.dt / self.previous_dt.unwrap_or(self.params.dt))
    }

    /// The membrane velocity of the last step on the order-`p` grid (`3n`, component-major):
    /// `u = (Xⁿ⁺¹ − X̂)/τ` from the solution of the linear system, before the
    /// reparametrisation and the drift correction (`(Xⁿ⁺¹ − Xⁿ)/Δt` for Euler, the BDF2
    /// derivative `(3Xⁿ⁺¹ − 4Xⁿ + Xⁿ⁻¹)/(2Δt)` for BDF2). Value `k` is the velocity of grid
    /// point `k`, relabelled with the grid by the reparametrisation. `None` before the first
    /// step. A suspension with a viscosity
    /// contrast takes it as the density of the cell's double layer seen by the other cells
    /// (explicitly, in the next step).
    pub fn velocity(&self) -> Option<&[f64]> {
        self.velocity.as_deref()
    }

    /// Set (or clear) the recorded membrane velocity (a restarted run restores it).
    ///
    /// # Errors
    /// [`TimestepError::DimensionMismatch`] for a wrong length, [`TimestepError::NonFinite`]
    /// for NaN or infinite values.
    pub fn set_velocity(&mut self, velocity: Option<&[f64]>) -> Result<(), TimestepError> {
        match velocity {
            None => self.velocity = None,
            Some(v) => {
                let expected = 3 * self.n;
                if v.len() != expected {
                    return Err(TimestepError::DimensionMismatch {
                        what: "membrane velocity",
                        expected,
                        got: v.len(),
                    });
                }
                if !v.iter().all(|x| x.is_finite()) {
                    return Err(TimestepError::NonFinite {
                        what: "membrane velocity",
                    });
                }
                self.velocity = Some(v.to_vec());
            }
        }
        Ok(())
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

    /// The traction the membrane exerts on the fluid at the surface `coefs`, with the tension
    /// of the last step: `f_b(X) + f_σ(σ) + f_Skalak(X) + F/A` on the order-`p` grid (`3n`).
    /// This is the density whose single layer the other cells feel (explicit coupling).
    pub fn traction(&mut self, coefs: &[f64], out: &mut [f64]) -> Result<(), TimestepError> {
        let n = self.n;
        if out.len() != 3 * n {
            return Err(TimestepError::DimensionMismatch {
                what: "traction",
                expected: 3 * n,
                got: out.len(),
            });
        }
        let mut engine = self.lease()?;
        let OperatorWork {
            membrane, fb, ft, ..
        } = engine.work.get_mut().expect("operator lock");
        membrane.set_geometry(coefs)?;
        let area = membrane.geometry()?.area();
        membrane.bending_force(self.params.bending_modulus, out)?;
        membrane.tension_force(&self.sigma, ft)?;
        for (o, t) in out.iter_mut().zip(ft.iter()) {
            *o += t;
        }
        if let Some((sk, _)) = &self.skalak {
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
        &mut self,
        coefs: &[f64],
        f: impl FnOnce(&crate::vesicle::geometry::Geometry) -> R,
    ) -> Result<R, TimestepError> {
        let mut engine = self.lease()?;
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

    /// Advance the surface with coefficients `coefs` (x, y, z at order `p`) by one step in the
    /// background flow `u_inf`.
    pub fn step(
        &mut self,
        coefs: &mut [f64],
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
    ) -> Result<StepReport, TimestepError> {
        self.step_with(coefs, u_inf, ExplicitTerms::default())
    }

    /// The sphere preconditioner for radius `radius` and coefficients `c`, built if none of the
    /// kept ones matches; returns its index and whether it was built.
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
            (Some(reference), Some((sk, _))) => {
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

    /// One step with explicit terms (the velocity induced by other cells, extra tractions).
    pub fn step_with(
        &mut self,
        coefs: &mut [f64],
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        extra: ExplicitTerms<'_>,
    ) -> Result<StepReport, TimestepError> {
        let (n, nc) = (self.n, self.nc);
        if coefs.len() != 3 * nc {
            return Err(TimestepError::DimensionMismatch {
                what: "surface coefficients",
                expected: 3 * nc,
                got: coefs.len(),
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
        let mut lease = self.lease()?;
        let engine: &mut StepEngine = &mut lease;
        // Grid storage: the operators live in the engine (one pair per thread), lent to this
        // cell for its step and handed back whatever the step's outcome.
        let lent = !storage_keeps_per_cell(self.storage);
        if lent {
            std::mem::swap(&mut self.s_op, &mut engine.grid_single);
            std::mem::swap(&mut self.d_op, &mut engine.grid_double);
        }
        let report = self.step_on(engine, coefs, u_inf, extra);
        if lent {
            std::mem::swap(&mut self.s_op, &mut engine.grid_single);
            std::mem::swap(&mut self.d_op, &mut engine.grid_double);
        }
        report
    }

    /// [`Self::step_with`] on a leased engine, the sizes checked: the step's phases in order.
    fn step_on(
        &mut self,
        engine: &mut StepEngine,
        coefs: &mut [f64],
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        extra: ExplicitTerms<'_>,
    ) -> Result<StepReport, TimestepError> {
        let plan = self.plan(engine, coefs)?;
        let pcs = self.prepare_preconditioners(engine, &plan)?;
        let terms = self.explicit_grid_terms(engine, &plan, u_inf, extra)?;
        self.assemble(engine, &plan)?;
        let (report, x_new, own_built) = self.solve(engine, &plan, &pcs, &terms)?;
        let area_volume_error = self.advance(engine, coefs, &plan, &x_new, &terms.xh_grid)?;
        self.regrid_and_correct(engine, coefs, &plan)?;
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
    fn plan(&mut self, engine: &mut StepEngine, coefs: &[f64]) -> Result<StepPlan, TimestepError> {
        let omega = self.extrapolation_ratio();
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
        let g_now = engine.calc.geometry(coefs)?;
        let (area0, volume0) = (g_now.area(), g_now.volume());
        if self.targets.is_none() {
            self.targets = Some((area0, volume0));
        }
        // X* (geometry of the operators) and X̂ (the history term), as coefficients.
        let (xstar, xhat): (Vec<f64>, Vec<f64>) = match (&self.previous, bdf2) {
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
        let area_source = self.local_area_source(engine, &g_now.w, tau)?;
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
    ) -> Result<StepPreconditioners, TimestepError> {
        let (sphere, sphere_built) = if plan.precondition {
            // With the drift correction the area is the target area at every step: the sphere
            // is built from it (not from the current area, which differs in the last bits), so
            // that a restarted run rebuilds the very same preconditioner (bit-identical restart).
            let area = match (self.params.correct_drift, self.targets) {
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
            if let Some((sk, _)) = &self.skalak {
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
    ) -> Result<(GmresReport, Vec<f64>, bool), TimestepError> {
        match (&self.skalak, plan.inextensible) {
            (Some((sk, reference)), false) => {
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
                        jacobian: plan.implicit_elastic.then_some((sk, &reference[..])),
                        size: terms.size,
                    },
                    &self.params.gmres,
                )?;
                Ok((report, x, pcs.own_rebuilt))
            }
            _ => self.solve_inextensible(engine, plan, pcs, terms),
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
        let jacobian = match (&self.skalak, plan.implicit_elastic) {
            (Some((sk, reference)), true) => {
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
        z0[3 * n..].copy_from_slice(&self.sigma);
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
            self.own =
                Some(self.own_preconditioner(&op, &engine.sht, plan, pcs, jacobian.is_some())?);
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
        self.sigma.copy_from_slice(&z[3 * n..]);
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
    /// the elastic Jacobian when `with_jacobian`), recorded with what it was built from.
    fn own_preconditioner(
        &self,
        op: &InextensibleOperator<'_>,
        sht: &ShTransform,
        plan: &StepPlan,
        pcs: &StepPreconditioners,
        with_jacobian: bool,
    ) -> Result<OwnPreconditioner, TimestepError> {
        let inverse = own_inverse(op, sht, plan.coef.identity)?;
        Ok(OwnPreconditioner {
            record: PreconditionerRecord {
                surface: plan.xstar.clone(),
                tau: plan.tau,
                jacobian_reference: if with_jacobian {
                    self.skalak.as_ref().map(|(_, r)| r.clone())
                } else {
                    None
                },
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
        &mut self,
        engine: &mut StepEngine,
        coefs: &mut [f64],
        plan: &StepPlan,
        x_new: &[f64],
        xh_grid: &[f64],
    ) -> Result<f64, TimestepError> {
        // The membrane velocity of this step, u = (Xⁿ⁺¹ − X̂)/τ on the grid.
        let tau = plan.tau;
        let velocity = self.velocity.get_or_insert_with(Vec::new);
        velocity.clear();
        velocity.extend(x_new.iter().zip(xh_grid).map(|(x, h)| (x - h) / tau));
        if self.params.scheme == TimeScheme::Bdf2 {
            match &mut self.previous {
                Some(prev) => prev.copy_from_slice(coefs),
                None => self.previous = Some(coefs.to_vec()),
            }
            self.previous_dt = Some(self.params.dt);
        }
        engine
            .sht
            .forward(x_new, coefs, &mut engine.ws)
            .map_err(crate::vesicle::VesicleError::from)?;
        // The error estimate of the flow step itself (before the reparametrisation, which
        // changes area and volume by the discretisation error, whatever the step).
        let g = engine.calc.geometry(coefs)?;
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
        &mut self,
        engine: &mut StepEngine,
        coefs: &mut [f64],
        plan: &StepPlan,
    ) -> Result<(), TimestepError> {
        if let Some(rp) = self.params.reparametrize {
            self.regrid(engine, coefs, &rp)?;
        }
        if self.params.correct_drift {
            let (area, volume) = self.targets.expect("set by the plan");
            // A capsule's area is free: the volume alone.
            correct_shape(engine, coefs, plan.inextensible.then_some(area), volume)?;
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
        w_now: &[f64],
        tau: f64,
    ) -> Result<Option<Vec<f64>>, TimestepError> {
        let reference = match &self.skalak {
            Some((_, r)) if self.params.inextensible && self.local_area_relaxation => r,
            _ => return Ok(None),
        };
        let g_ref = engine.calc.geometry(reference)?;
        // The reference's area element scaled to the area the drift correction restores (the
        // reference composed from its labels differs from its first area by one re-fit): both
        // corrections then ask for the same total area instead of undoing each other.
        let (target, _) = self.targets.expect("set by the step before this call");
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
        &mut self,
        engine: &mut StepEngine,
        coefs: &mut [f64],
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
            .forward(&self.sigma, &mut sigma_c[..nc], &mut engine.ws)
            .map_err(VesicleError::from)?;
        let mut velocity_c = match &self.velocity {
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
        let mut surf = Surface::from_coefs(self.p, coefs.to_vec())?;
        {
            let mut passengers: Vec<&mut [f64]> = vec![&mut sigma_c[..]];
            if let Some(v) = velocity_c.as_mut() {
                passengers.push(&mut v[..]);
            }
            // The Skalak reference moves with the grid through its labels (composed below;
            // `set_skalak` gives every Skalak cell labels): relabelled itself, its re-fits
            // would change its shape.
            if let Some(l) = self.labels.as_mut() {
                passengers.push(&mut l.map[..]);
            }
            if let Some(prev) = self.previous.as_mut() {
                passengers.push(&mut prev[..]);
            }
            engine
                .reparametrizer
                .as_mut()
                .expect("planned above")
                .run_with(&mut surf, rp, &mut passengers)?;
        }
        coefs.copy_from_slice(surf.coefs());
        if let (Some(l), Some((_, reference))) = (&self.labels, self.skalak.as_mut()) {
            l.compose(&engine.sht, &mut engine.ws, reference)?;
        }
        engine
            .sht
            .inverse(&sigma_c[..nc], &mut self.sigma, &mut engine.ws)
            .map_err(VesicleError::from)?;
        if let (Some(c), Some(v)) = (velocity_c, self.velocity.as_mut()) {
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
        &mut self,
        coefs: &mut [f64],
        area: f64,
        volume: f64,
    ) -> Result<(), TimestepError> {
        let mut engine = self.lease()?;
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

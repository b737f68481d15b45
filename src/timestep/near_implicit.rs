//! Near cells coupled inside the solve: one linear system for the cells of a near cluster.
//!
//! With the explicit coupling ([`super::coupling`], [`super::suspension`]) every cell feels
//! the others through the velocity of the last step's densities, extrapolated for BDF2:
//! `v* = (1+ω) K ρⁿ − ω K ρⁿ⁻¹` (`ρ = (f, g)`: the traction and the double-layer density
//! `g = (1 − λ) u`). On a density that alternates from step to step the extrapolation has the
//! gain `1 + 2ω = 3`; two close cells with a viscosity contrast couple through the near part
//! of `K` with a gain near `|1 − λ|/(1 + λ)` (the double layer's jump), and a dense
//! suspension at `λ = 5` blows up whatever `Δt` (docs/hard_cases.md).
//!
//! The near-implicit coupling (Quaife & Biros, J. Comput. Phys. 274 (2014); Lu, Rahimian &
//! Zorin, J. Comput. Phys. 347 (2017)) takes the near part of `K` at the new time. For the
//! cells `i` of a cluster ([`super::near_pairs::NearZones::clusters`]) the step solves one
//! system in all their unknowns `zᵢ = [Xᵢ; σᵢ]`:
//!
//! ```text
//!     Aᵢ zᵢ − τᵢ Σ_j K*ᵢⱼ ρⱼ(zⱼ) = bᵢ + τᵢ Σ_j K*ᵢⱼ (cⱼ − ρⱼ*)
//!     ρⱼ(zⱼ) = (B* Xⱼ + T* σⱼ,  (1 − λⱼ) Xⱼ / τⱼ)       (linear in zⱼ)
//!     cⱼ     = (f_e(X*ⱼ) + F/A + f_user,  −(1 − λⱼ) X̂ⱼ / τⱼ)
//!     ρⱼ*    = (1+ω) ρⱼⁿ − ω ρⱼⁿ⁻¹                      (the densities v* was built from)
//! ```
//!
//! (`Aᵢ zᵢ = bᵢ` the cell's own step of [`super::semi_implicit`], whose right-hand side holds
//! `τᵢ v*ᵢ`; `K*ᵢⱼ` the near-zone operator of [`super::near_pairs`] at the operators'
//! geometry `X*`). The velocity cell `i` feels is then `v*ᵢ + Σ_j K*ᵢⱼ (ρⱼⁿ⁺¹ − ρⱼ*)`: the
//! explicit field with its near part replaced, to `O(Δt²)`, by the implicit one. A density
//! mode that alternates between steps cancels between `v*` and `K* ρ*`, so the near coupling
//! no longer has the extrapolation's gain (the correction vanishes as `ρⁿ⁺¹ − ρ* = O(Δt²)`).
//! The far field stays explicit through the FMM. Measured orders (tests/hard_cases.rs, two
//! RBCs with `λ = 5` sliding past each other in shear, p = 6, docs/hard_cases.md): with the
//! grid left where the flow takes it, 2.04, 2.08, 2.32 with the surfaces 0.8 apart and 1.98,
//! 1.99, 2.22 with them 0.1 apart, where the explicit coupling gives 1.04, 1.19, 1.57 at 0.8
//! without the start-up (the first step's `σ⁰ = 0` coupled explicitly; 1.89, 2.04 with it,
//! [`super::suspension`]) and fails at 0.1. With the grid relaxed
//! (`[numerics] grid = "relaxed"`; an RBC's grid follows its material points by default), the
//! reparametrisation of every step re-fits the moved grid at order `p`, which changes the shape
//! a little at every call:
//! at p = 6 that error, summed over `T/Δt` calls, is first order (1.22, 1.08, 1.13 at 0.1
//! apart); at p = 12 it caps the order only at the smallest steps, as for one cell (1.95,
//! 1.78, 1.39).
//!
//! The zone where the coupling is implicit ([`IMPLICIT_ZONE`]) is wider than the coupling's
//! near-singular zone: the double layer of a neighbour a little beyond it still couples
//! strongly enough for BDF2's extrapolation to blow up.
//!
//! GMRES solves the joint system, right-preconditioned block by block with each cell's own
//! preconditioner (the cell's exact inverse, or its rotated sphere): the iterations are those
//! of a single cell plus the coupling's. Each product applies every cell's own operator and
//! the near-zone operator once. The near-zone operator's on-surface values (its near-singular
//! evaluation extrapolates from them) are each source cell's `S f` and `D g` from the dense
//! operators its own step already holds, a matrix–vector product instead of a singular
//! quadrature at every grid point (27 RBCs at `λ = 5`: 1.65× at `p = 8`, 1.42× at `p = 12`;
//! [`super::near_pairs::OnSurface`]). Over ranks they travel with the densities. Cells whose
//! step is not the inextensible `[X; σ]` system (a capsule, a linearly implicit elasticity)
//! step alone with the explicit coupling.

use std::sync::Mutex;

mod over_ranks;

pub(super) use over_ranks::{step_all_on, RanksStep};

use rayon::prelude::*;

use super::cell_preconditioner::CellPreconditionerOp;
use super::cell_state::CellState;
use super::cell_stepper::CellStepper;
use super::grid_frame::{relative_rotation, RotatedPreconditioner, Rotation};
use super::near_pairs::{NearPairs, NearZones, OnSurface, ZoneCell};
use super::own_preconditioner::{OwnInverse, OwnPreconditioner};
use super::semi_implicit::{extrapolate, ElasticStepping, ExplicitTerms, StepReport};
use super::sphere_preconditioner::SpherePreconditioner;
use super::step_engine::{EngineLease, StepEngine};
use super::step_operator::{InextensibleOperator, LayerValues};
use super::step_plan::{GridTerms, StepPlan, StepPreconditioners};
use super::step_solve::{step_operators, storage_keeps_per_cell};
use super::{gmres, GmresReport, GmresWorkspace, LinearOperator, Preconditioner, TimestepError};

/// The implicit zone: the targets of cell `i` within `δ = IMPLICIT_ZONE · R_j / √p` of cell `j`
/// take `j`'s densities implicitly (the coupling's near-singular zone is `2 R/√p`). Measured
/// on 27 RBCs at 17 %, `λ = 5`, `p = 8`, BDF2, `Δt = 0.01` (`mobo run`): the explicit coupling
/// fails at step 35, an implicit zone of `2 R/√p` at step 44; zones of `4 R/√p` and `8 R/√p`
/// ran the 60 steps tried (2.3 and 5.6 s a step against the explicit 1.08; benches/RESULTS.md).
/// The wider is the default until longer runs show that the narrower holds. The far field
/// beyond it stays explicit. A scene sets it with `[numerics] implicit_zone`. Since the
/// near-zone operator takes each cell's on-surface values from its own step's operators, the
/// width costs less: at `p = 12` (27 RBCs, 2 steps on one thread) zone 4 took 28.2 s and zone 8
/// 31.2 s, with the same GMRES iterations. Above `p = 8` the default is wider in these units
/// ([`default_implicit_zone`]): the zone's width is physical, not a quadrature's.
pub const IMPLICIT_ZONE: f64 = 8.0;

/// The implicit zone's default for cells of order `p`, in units of `R/√p`: [`IMPLICIT_ZONE`] up
/// to `p = 8`, and `IMPLICIT_ZONE · √(p/8)` above it, so that the width never falls below its
/// `p = 8` value `2√2 R`. How strongly a neighbour's double layer couples, and so whether BDF2's
/// extrapolation of the part beyond the zone grows, depends on the distance and on `λ`, not on
/// the resolution. Measured (27 RBCs at 17 %, `λ = 10`, p = 12, `Δt = 0.01`, docs/hard_cases.md):
/// with `8 R/√p` (2.31 R) the area/volume error before correction grew from 7e-6 at step 2 to
/// 2.7e-4 at step 15 and 5.7e-3 at step 96, with the dissipation alternating between steps and
/// the gaps closing from 0.13 to 0.04; at `Δt = 0.005` it grew alike (1.6e-4 at step 20); with
/// `9.8 R/√p` (2.83 R, this default) it fell to 7e-8 by step 50. The same lattice at `p = 8`
/// (zone 2.83 R) ran 2000 steps.
pub fn default_implicit_zone(p: usize) -> f64 {
    IMPLICIT_ZONE * (p as f64 / 8.0).sqrt().max(1.0)
}

/// How the cells' hydrodynamic coupling enters a step (scene `[numerics] coupling`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CouplingMode {
    /// Every other cell through last step's densities (extrapolated for BDF2).
    #[default]
    Explicit,
    /// Cells in each other's near zone in one linear system (this module).
    NearImplicit,
}

impl CouplingMode {
    /// The name a scene gives it (`[numerics] coupling`), as the summary and reports print it.
    pub fn name(self) -> &'static str {
        match self {
            CouplingMode::Explicit => "explicit",
            CouplingMode::NearImplicit => "near_implicit",
        }
    }
}

/// A cell's step between its phases 1–4 (plan, preconditioners, explicit terms, operators)
/// and its phases 6–7 (advance, regrid), while the joint system is solved.
pub(super) struct JointStep {
    lease: EngineLease,
    lent: bool,
    plan: StepPlan,
    pcs: StepPreconditioners,
    terms: GridTerms,
    b: Vec<f64>,
    own_built: bool,
}

impl CellStepper {
    /// Whether the cell's step is the inextensible `[X; σ]` system that a near cluster solves
    /// jointly (not a capsule, no linearly implicit elasticity).
    pub fn joins_near_solve(&self) -> bool {
        let implicit_elastic = self.skalak.is_some()
            && self.params.elastic_stepping == Some(ElasticStepping::LinearlyImplicit);
        self.params.inextensible && !implicit_elastic
    }

    /// Phases 1–4 of a joint step and the cell's right-hand side (its own preconditioner
    /// built if stale); the engine stays leased until [`Self::end_joint`] or
    /// [`Self::abort_joint`].
    pub(super) fn begin_joint(
        &mut self,
        state: &mut CellState,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        extra: ExplicitTerms<'_>,
    ) -> Result<JointStep, TimestepError> {
        self.check_step_inputs(state, &extra)?;
        self.adopt_own_record(state.preconditioner.as_ref());
        let mut lease = self.lease(state.skalak_reference.as_deref())?;
        let lent = !storage_keeps_per_cell(self.storage);
        if lent {
            std::mem::swap(&mut self.s_op, &mut lease.grid_single);
            std::mem::swap(&mut self.d_op, &mut lease.grid_double);
        }
        match self.joint_phases(&mut lease, state, u_inf, extra) {
            Ok((plan, pcs, terms, b, own_built)) => Ok(JointStep {
                lease,
                lent,
                plan,
                pcs,
                terms,
                b,
                own_built,
            }),
            Err(e) => {
                self.release(lease, lent, state);
                Err(e)
            }
        }
    }

    #[allow(clippy::type_complexity)] // the phases' products, handed on together
    fn joint_phases(
        &mut self,
        engine: &mut StepEngine,
        state: &mut CellState,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        extra: ExplicitTerms<'_>,
    ) -> Result<(StepPlan, StepPreconditioners, GridTerms, Vec<f64>, bool), TimestepError> {
        let plan = self.plan(engine, state)?;
        let pcs = self.prepare_preconditioners(engine, &plan, state)?;
        let terms = self.explicit_grid_terms(engine, &plan, u_inf, extra)?;
        self.assemble(engine, &plan)?;
        let (s_op, d_op) = step_operators(
            self.storage,
            self.params.viscosity,
            &self.s_op,
            &self.d_op,
            plan.coef.double_layer,
        );
        let b = self.inextensible_rhs(engine, &plan, &terms, s_op, d_op)?;
        let mut own_built = pcs.own_rebuilt;
        if pcs.build_own {
            let op = self.joint_operator(engine, &plan, terms.size);
            let own = self.own_preconditioner(&op, &engine.sht, &plan, &pcs, None)?;
            drop(op);
            self.own = Some(own);
            self.own_preconditioner_builds += 1;
            own_built = true;
        }
        Ok((plan, pcs, terms, b, own_built))
    }

    /// The step operator of a joint step (no elastic Jacobian: such cells step alone) on
    /// `engine` with the plan `plan`; `size` the cell's area-equivalent radius.
    fn joint_operator<'a>(
        &'a self,
        engine: &'a StepEngine,
        plan: &'a StepPlan,
        size: f64,
    ) -> InextensibleOperator<'a> {
        let c_d = plan.coef.double_layer;
        let (s_op, d_op) = step_operators(
            self.storage,
            self.params.viscosity,
            &self.s_op,
            &self.d_op,
            c_d,
        );
        InextensibleOperator::new(
            self.n,
            &engine.work,
            &engine.sht,
            self.storage,
            &plan.xstar,
            (s_op, d_op),
            [
                plan.coef.identity,
                c_d,
                plan.tau,
                self.params.bending_modulus,
            ],
            None,
            size,
        )
    }

    /// The block of a joint step's preconditioner: the one [`Self::run_gmres`] would use.
    fn joint_block<'a>(&'a self, step: &'a JointStep) -> Block<'a> {
        let own = match self.own.as_ref() {
            Some(OwnPreconditioner {
                inverse: OwnInverse::Built(pc),
                frame,
                ..
            }) => Some((pc, relative_rotation(&step.pcs.rotation, frame))),
            _ => None,
        };
        match (step.pcs.sphere, own) {
            (Some(_), Some((pc, turn))) => Block::Own(
                Box::new(CellPreconditionerOp::new(pc, &step.lease.sht)),
                turn,
            ),
            (Some(i), None) => Block::Sphere(&self.preconditioners[i], step.pcs.rotation),
            (None, _) => Block::Identity,
        }
    }

    /// Phases 6–7 of a joint step from its solution `z = [Xⁿ⁺¹; σⁿ⁺¹]`; the engine goes back.
    pub(super) fn end_joint(
        &mut self,
        mut step: JointStep,
        state: &mut CellState,
        z: &[f64],
        report: &GmresReport,
    ) -> Result<StepReport, TimestepError> {
        let n = self.n;
        if let Some(o) = &mut self.own {
            o.record.last_iterations = report.iterations;
        }
        state.sigma.copy_from_slice(&z[3 * n..]);
        let outcome = self
            .advance(
                &mut step.lease,
                state,
                &step.plan,
                &z[..3 * n],
                &step.terms.xh_grid,
            )
            .and_then(|area_volume_error| {
                self.regrid_and_correct(&mut step.lease, state, &step.plan)?;
                Ok(StepReport {
                    gmres: report.clone(),
                    scheme: step.plan.scheme,
                    preconditioner_built: step.pcs.sphere_built || step.own_built,
                    area_volume_error,
                })
            });
        self.release(step.lease, step.lent, state);
        outcome
    }

    /// A joint step given up: the engine goes back, the state keeps its own-preconditioner
    /// record.
    pub(super) fn abort_joint(&mut self, step: JointStep, state: &mut CellState) {
        self.release(step.lease, step.lent, state);
    }

    fn release(&mut self, mut lease: EngineLease, lent: bool, state: &mut CellState) {
        if lent {
            std::mem::swap(&mut self.s_op, &mut lease.grid_single);
            std::mem::swap(&mut self.d_op, &mut lease.grid_double);
        }
        state.preconditioner = self.own.as_ref().map(|o| o.record.clone());
    }
}

/// One cell's block of the joint preconditioner.
enum Block<'a> {
    Own(Box<CellPreconditionerOp<'a>>, Rotation),
    Sphere(&'a SpherePreconditioner, Rotation),
    Identity,
}

impl Block<'_> {
    fn apply(&self, n: usize, v: &[f64], z: &mut [f64]) {
        match self {
            Block::Own(pc, turn) => RotatedPreconditioner::new(&**pc, *turn, n).apply(v, z),
            Block::Sphere(pc, rotation) => {
                RotatedPreconditioner::new(*pc, *rotation, n).apply(v, z)
            }
            Block::Identity => z.copy_from_slice(v),
        }
    }
}

/// The block-diagonal preconditioner of a cluster.
struct ClusterPreconditioner<'a> {
    n: usize,
    blocks: Vec<Block<'a>>,
}

impl<'a> ClusterPreconditioner<'a> {
    /// The blocks of the cells' joint steps ([`CellStepper::joint_block`]).
    fn of(cells: &'a [&mut JointCell<'_>], steps: &'a [JointStep], n: usize) -> Self {
        ClusterPreconditioner {
            n,
            blocks: cells
                .iter()
                .zip(steps)
                .map(|(c, s)| c.stepper.joint_block(s))
                .collect(),
        }
    }
}

impl Preconditioner for ClusterPreconditioner<'_> {
    fn nrows(&self) -> usize {
        4 * self.n * self.blocks.len()
    }

    fn apply(&self, v: &[f64], z: &mut [f64]) {
        let n4 = 4 * self.n;
        self.blocks
            .par_iter()
            .zip(v.par_chunks(n4))
            .zip(z.par_chunks_mut(n4))
            .for_each(|((b, vk), zk)| b.apply(self.n, vk, zk));
    }
}

/// The joint operator of a cluster (module docs): each cell's own operator, minus `τᵢ` times
/// the near-zone velocities of the other cells' densities.
struct ClusterOperator<'a> {
    n: usize,
    ops: Vec<InextensibleOperator<'a>>,
    near: &'a NearPairs,
    zones: &'a NearZones,
    surfaces: Vec<&'a [f64]>,
    tau: Vec<f64>,
    /// `(1 − λⱼ)/τⱼ` where the cell's double layer is coupled.
    dl: Vec<Option<f64>>,
    failure: Mutex<Option<TimestepError>>,
}

impl LinearOperator for ClusterOperator<'_> {
    fn nrows(&self) -> usize {
        4 * self.n * self.ops.len()
    }

    fn apply(&self, x: &[f64], y: &mut [f64]) {
        let (n3, n4) = (3 * self.n, 4 * self.n);
        let (f, g) = own_products(&self.ops, &self.dl, self.n, x, y);
        let m = self.ops.len();
        let mut w = vec![vec![0.0; n3]; m];
        if let Err(e) = near_field(
            &self.ops,
            self.near,
            self.zones,
            &self.surfaces,
            &f,
            &g,
            &mut w,
        ) {
            let mut slot = self.failure.lock().unwrap_or_else(|e| e.into_inner());
            slot.get_or_insert(e);
            y.fill(f64::NAN);
            return;
        }
        for (k, wk) in w.iter().enumerate() {
            for (yi, wi) in y[k * n4..k * n4 + n3].iter_mut().zip(wk) {
                *yi -= self.tau[k] * wi;
            }
        }
    }
}

/// `out_i += Σ_j K_ij (f_j, g_j)` ([`NearPairs::apply`]) with each source cell's layers on its
/// own surface from its step's dense operators `ops[j]` where it holds them ([`OnSurface`]).
fn near_field(
    ops: &[InextensibleOperator<'_>],
    near: &NearPairs,
    zones: &NearZones,
    surfaces: &[&[f64]],
    f: &[Vec<f64>],
    g: &[Option<Vec<f64>>],
    out: &mut [Vec<f64>],
) -> Result<(), TimestepError> {
    let values = layer_values(ops, &zones.is_source(ops.len()), f, g)?;
    let on: Vec<Option<OnSurface<'_>>> = values.iter().map(on_surface).collect();
    let fref: Vec<&[f64]> = f.iter().map(|v| v.as_slice()).collect();
    let gref: Vec<Option<&[f64]>> = g.iter().map(|v| v.as_deref()).collect();
    near.apply(zones, surfaces, &fref, &gref, &on, out)
}

/// [`InextensibleOperator::layer_values`] of the cells `k` with `source[k]` (the others
/// `None`), in parallel.
fn layer_values(
    ops: &[InextensibleOperator<'_>],
    source: &[bool],
    f: &[Vec<f64>],
    g: &[Option<Vec<f64>>],
) -> Result<Vec<LayerValues>, TimestepError> {
    ops.par_iter()
        .enumerate()
        .map(|(k, op)| {
            if source[k] {
                Ok(op.layer_values(&f[k], g[k].as_deref())?)
            } else {
                Ok(None)
            }
        })
        .collect()
}

/// The borrowed [`OnSurface`] of a cell's [`LayerValues`].
fn on_surface(v: &LayerValues) -> Option<OnSurface<'_>> {
    v.as_ref().map(|(single, double)| OnSurface {
        single,
        double: double.as_deref(),
    })
}

/// `y = A x` block by block (each cell's own step operator) and the densities of the iterate
/// `ρ(z) = (B X + T σ, (1 − λ) X / τ)` that the near-zone operator takes (`dl[k]`: the factor
/// `(1 − λ)/τ` where the cell's double layer is coupled).
fn own_products(
    ops: &[InextensibleOperator<'_>],
    dl: &[Option<f64>],
    n: usize,
    x: &[f64],
    y: &mut [f64],
) -> (Vec<Vec<f64>>, Vec<Option<Vec<f64>>>) {
    let (n3, n4) = (3 * n, 4 * n);
    let mut f = vec![vec![0.0; n3]; ops.len()];
    ops.par_iter()
        .zip(x.par_chunks(n4))
        .zip(y.par_chunks_mut(n4))
        .zip(f.par_iter_mut())
        .for_each(|(((op, xk), yk), fk)| op.apply_with_traction(xk, yk, fk));
    let g = (0..ops.len())
        .map(|k| dl[k].map(|c| x[k * n4..k * n4 + n3].iter().map(|v| c * v).collect()))
        .collect();
    (f, g)
}

/// One cell of a cluster's step.
pub(super) struct JointCell<'a> {
    pub stepper: &'a mut CellStepper,
    pub state: &'a mut CellState,
    /// The explicit terms of its own step (`v*`, the explicit tractions).
    pub extra: ExplicitTerms<'a>,
    /// The part of `extra.traction` that is the contact repulsion (not a coupling density).
    pub repulsion: Option<&'a [f64]>,
    /// `ρⁿ`: the traction and double-layer density the coupling was given this step.
    pub traction_now: &'a [f64],
    /// (`None`: no double layer.)
    pub dl_now: Option<&'a [f64]>,
    /// `ρⁿ⁻¹` (`6n`: traction, double-layer density), on the grid of `Xⁿ` (relabelled by the
    /// last step's reparametrisation); `None` before the second step.
    pub previous: Option<&'a [f64]>,
}

/// One step of the cells of a cluster (`zones` renumbered to them) as one linear system
/// (module docs); `with_dl`: the double layers of cells with `λ ≠ 1` are coupled. An error
/// names the cell (its index in `cells`) when it is one cell's.
pub(super) fn step_cluster(
    cells: &mut [&mut JointCell<'_>],
    near: &NearPairs,
    zones: &NearZones,
    u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
    with_dl: bool,
) -> Result<Vec<StepReport>, (Option<usize>, TimestepError)> {
    let omegas: Vec<Option<f64>> = cells
        .iter()
        .map(|c| c.stepper.extrapolation_ratio(c.state))
        .collect();
    let (steps, failed) = begin_all(cells, u_inf);
    if let Some(e) = failed {
        abort_all(cells, steps);
        return Err(e);
    }
    let steps: Vec<JointStep> = steps.into_iter().flatten().collect();
    let solved = solve_joint(cells, &steps, &omegas, near, zones, with_dl);
    let (z, report) = match solved {
        Ok(r) => r,
        Err(e) => {
            abort_all(cells, steps.into_iter().map(Some).collect());
            return Err((None, e));
        }
    };
    end_all(cells, steps, &z, &report)
}

/// Phases 1–4 of every cell's joint step ([`CellStepper::begin_joint`]), and the first
/// failure (its index in `cells`).
#[allow(clippy::type_complexity)] // the steps begun and the first failure, handed on together
fn begin_all(
    cells: &mut [&mut JointCell<'_>],
    u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
) -> (
    Vec<Option<JointStep>>,
    Option<(Option<usize>, TimestepError)>,
) {
    let begun: Vec<Result<JointStep, TimestepError>> = cells
        .par_iter_mut()
        .map(|c| c.stepper.begin_joint(c.state, u_inf, c.extra))
        .collect();
    let mut steps = Vec::with_capacity(cells.len());
    let mut first_error = None;
    for (k, r) in begun.into_iter().enumerate() {
        match r {
            Ok(s) => steps.push(Some(s)),
            Err(e) => {
                steps.push(None);
                first_error.get_or_insert((Some(k), e));
            }
        }
    }
    (steps, first_error)
}

/// The joint steps begun given up (their engines go back).
fn abort_all(cells: &mut [&mut JointCell<'_>], steps: Vec<Option<JointStep>>) {
    for (c, s) in cells.iter_mut().zip(steps) {
        if let Some(s) = s {
            c.stepper.abort_joint(s, c.state);
        }
    }
}

/// Phases 6–7 of every cell's joint step from the joint solution `z` (`4n` per cell); a
/// failure names the cell (its index in `cells`).
fn end_all(
    cells: &mut [&mut JointCell<'_>],
    steps: Vec<JointStep>,
    z: &[f64],
    report: &GmresReport,
) -> Result<Vec<StepReport>, (Option<usize>, TimestepError)> {
    let n4 = z.len() / cells.len().max(1);
    let ended: Vec<Result<StepReport, TimestepError>> = cells
        .par_iter_mut()
        .zip(steps.into_par_iter())
        .zip(z.par_chunks(n4.max(1)))
        .map(|((c, s), zk)| c.stepper.end_joint(s, c.state, zk, report))
        .collect();
    ended
        .into_iter()
        .enumerate()
        .map(|(k, r)| r.map_err(|e| (Some(k), e)))
        .collect()
}

/// The joint system's right-hand side, operator and preconditioner, solved by GMRES.
fn solve_joint(
    cells: &[&mut JointCell<'_>],
    steps: &[JointStep],
    omegas: &[Option<f64>],
    near: &NearPairs,
    zones: &NearZones,
    with_dl: bool,
) -> Result<(Vec<f64>, GmresReport), TimestepError> {
    let m = cells.len();
    let n = cells[0].stepper.n_points();
    let (n3, n4) = (3 * n, 4 * n);
    let (tau, dl) = joint_factors(steps, with_dl);
    let surfaces: Vec<&[f64]> = steps.iter().map(|s| s.plan.xstar.as_slice()).collect();
    let (fc, gc) = constant_densities(cells, steps, omegas, &dl, n3);
    let ops = joint_operators(cells, steps);
    let mut w = vec![vec![0.0; n3]; m];
    near_field(&ops, near, zones, &surfaces, &fc, &gc, &mut w)?;
    let (b, z0) = rhs_and_guess(cells, steps, &tau, |k| &w[k]);
    let op = ClusterOperator {
        n,
        ops,
        near,
        zones,
        surfaces,
        tau,
        dl,
        failure: Mutex::new(None),
    };
    let pc = ClusterPreconditioner::of(cells, steps, n);
    let params = cells[0].stepper.params().gmres;
    let mut ws = GmresWorkspace::new(n4 * m, params.restart);
    let mut z = vec![0.0; n4 * m];
    let report = gmres(&op, &pc, &b, Some(&z0), &mut z, &params, &mut ws);
    operator_failure(op.failure, &op.ops)?;
    Ok((z, report?))
}

/// Every cell's own step operator of a joint step (no elastic Jacobian).
fn joint_operators<'a>(
    cells: &'a [&mut JointCell<'_>],
    steps: &'a [JointStep],
) -> Vec<InextensibleOperator<'a>> {
    cells
        .iter()
        .zip(steps)
        .map(|(c, s)| c.stepper.joint_operator(&s.lease, &s.plan, s.terms.size))
        .collect()
}

/// The failure the joint operator (`failure`) or one of the cells' operators recorded during
/// a solve.
fn operator_failure(
    failure: Mutex<Option<TimestepError>>,
    ops: &[InextensibleOperator<'_>],
) -> Result<(), TimestepError> {
    if let Some(e) = failure.into_inner().unwrap_or_else(|e| e.into_inner()) {
        return Err(e);
    }
    for o in ops {
        if let Some(e) = o.take_failure() {
            return Err(e.into());
        }
    }
    Ok(())
}

/// The cells `k` with `alone(k)` stepped alone, with the explicit coupling (in parallel), their
/// reports into `reports[k]`; the first failure names its cell.
fn step_alone(
    cells: &mut [JointCell<'_>],
    alone: impl Fn(usize) -> bool + Sync,
    u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
    reports: &mut [Option<StepReport>],
) -> Result<(), (Option<usize>, TimestepError)> {
    type Alone = Result<(usize, StepReport), (Option<usize>, TimestepError)>;
    let stepped: Vec<Alone> = cells
        .par_iter_mut()
        .enumerate()
        .filter(|(k, _)| alone(*k))
        .map(|(k, c)| {
            c.stepper
                .step_with(c.state, u_inf, c.extra)
                .map(|r| (k, r))
                .map_err(|e| (Some(k), e))
        })
        .collect();
    for r in stepped {
        let (k, report) = r?;
        reports[k] = Some(report);
    }
    Ok(())
}

/// `τⱼ` and the double-layer factors `(1 − λⱼ)/τⱼ` (where coupled) of a joint step's cells.
fn joint_factors(steps: &[JointStep], with_dl: bool) -> (Vec<f64>, Vec<Option<f64>>) {
    let tau = steps.iter().map(|s| s.plan.tau).collect();
    let dl = steps
        .iter()
        .map(|s| {
            let c_d = s.plan.coef.double_layer;
            (with_dl && c_d != 0.0).then_some(c_d / s.plan.tau)
        })
        .collect();
    (tau, dl)
}

/// The constant densities `cⱼ − ρⱼ*` of the cells of a joint step (module docs): traction and,
/// where the double layer is coupled, double-layer density, `3n` each.
fn constant_densities(
    cells: &[&mut JointCell<'_>],
    steps: &[JointStep],
    omegas: &[Option<f64>],
    dl: &[Option<f64>],
    n3: usize,
) -> (Vec<Vec<f64>>, Vec<Option<Vec<f64>>>) {
    let m = cells.len();
    let mut fc = Vec::with_capacity(m);
    let mut gc = Vec::with_capacity(m);
    for k in 0..m {
        let c = &cells[k];
        let prev = c.previous;
        let f_star = extrapolate(c.traction_now, prev.map(|p| &p[..n3]), omegas[k]);
        let mut f = steps[k].terms.traction.clone();
        if let Some(r) = c.repulsion {
            for (a, b) in f.iter_mut().zip(r) {
                *a -= b;
            }
        }
        for (a, b) in f.iter_mut().zip(&f_star) {
            *a -= b;
        }
        fc.push(f);
        gc.push(dl[k].map(|factor| {
            let zero = vec![0.0; n3];
            let g_now = c.dl_now.unwrap_or(&zero);
            let g_star = extrapolate(g_now, prev.map(|p| &p[n3..]), omegas[k]);
            steps[k]
                .terms
                .xh_grid
                .iter()
                .zip(&g_star)
                .map(|(h, gs)| -factor * h - gs)
                .collect::<Vec<f64>>()
        }));
    }
    (fc, gc)
}

/// The joint system's right-hand side (each cell's own plus `τ` times the near field `w(k)`
/// of the constant densities) and initial guess (`X*` on the grid and the last tension `σⁿ`).
fn rhs_and_guess<'w>(
    cells: &[&mut JointCell<'_>],
    steps: &[JointStep],
    tau: &[f64],
    w: impl Fn(usize) -> &'w [f64],
) -> (Vec<f64>, Vec<f64>) {
    let m = cells.len();
    let n4 = steps.first().map_or(0, |s| s.b.len());
    let n3 = 3 * n4 / 4;
    let mut b = vec![0.0; n4 * m];
    let mut z0 = vec![0.0; n4 * m];
    for k in 0..m {
        let bk = &mut b[k * n4..(k + 1) * n4];
        bk.copy_from_slice(&steps[k].b);
        for (bi, wi) in bk[..n3].iter_mut().zip(w(k)) {
            *bi += tau[k] * wi;
        }
        z0[k * n4..k * n4 + n3].copy_from_slice(&steps[k].terms.xs_grid);
        z0[k * n4 + n3..(k + 1) * n4].copy_from_slice(&cells[k].state.sigma);
    }
    (b, z0)
}

/// What the near-implicit coupling did in a step.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct JointStats {
    /// Clusters solved jointly.
    pub clusters: usize,
    /// Cells in them.
    pub cells: usize,
    /// Cells of the largest.
    pub largest: usize,
    /// GMRES iterations of the joint solves (summed over the clusters).
    pub iterations: usize,
}

impl JointStats {
    /// One more cluster of `cells` cells, solved in `iterations` GMRES iterations.
    pub fn add_cluster(&mut self, cells: usize, iterations: usize) {
        self.merge(&JointStats {
            clusters: 1,
            cells,
            largest: cells,
            iterations,
        });
    }

    /// `other`'s clusters added to these.
    pub fn merge(&mut self, other: &JointStats) {
        self.clusters += other.clusters;
        self.cells += other.cells;
        self.largest = self.largest.max(other.largest);
        self.iterations += other.iterations;
    }
}

/// One step of all `cells` with the near-implicit coupling: the near zones found at the
/// operators' geometry `X*`, each cluster's cells stepped as one system
/// ([`step_cluster`]), every other cell alone with its explicit terms. An error names the
/// cell (its index in `cells`) when it is one cell's.
pub(super) fn step_all(
    cells: &mut [JointCell<'_>],
    near: &NearPairs,
    u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
    with_dl: bool,
) -> Result<(Vec<StepReport>, JointStats), (Option<usize>, TimestepError)> {
    let placed: Result<Vec<Placed>, (Option<usize>, TimestepError)> = cells
        .par_iter()
        .enumerate()
        .map(|(k, c)| place(c).map_err(|e| (Some(k), e)))
        .collect();
    let placed = placed?;
    let zone_cells: Vec<ZoneCell<'_>> = placed
        .iter()
        .zip(cells.iter())
        .map(|(p, c)| ZoneCell {
            surface: &p.surface,
            points: &p.points,
            centroid: p.centroid,
            radius: p.radius,
            joins: c.stepper.joins_near_solve(),
        })
        .collect();
    let zones = near.zones(&zone_cells).map_err(|e| (None, e))?;
    drop(zone_cells);
    let clusters = zones.clusters(cells.len());
    let mut cluster_of = vec![None; cells.len()];
    for (ci, cl) in clusters.iter().enumerate() {
        for &k in cl {
            cluster_of[k] = Some(ci);
        }
    }
    let mut reports: Vec<Option<StepReport>> = vec![None; cells.len()];
    step_alone(cells, |k| cluster_of[k].is_none(), u_inf, &mut reports)?;
    let mut stats = JointStats::default();
    for cl in &clusters {
        let held = HeldCluster {
            members: cl,
            zones: &zones.restricted(cl),
        };
        held.step(cells, near, u_inf, with_dl, &mut stats, &mut reports)?;
    }
    Ok((reports.into_iter().flatten().collect(), stats))
}

/// A cell at the operators' geometry `X*`, as the near zones take it.
pub(super) struct Placed {
    /// `X*` (order-`p` coefficients).
    pub surface: Vec<f64>,
    /// Its grid points.
    pub points: Vec<[f64; 3]>,
    pub centroid: [f64; 3],
    /// The largest distance of a grid point from the centroid.
    pub radius: f64,
}

/// `c` at its operators' geometry (on every rank the same numbers: the zones over ranks
/// must be one rank's).
pub(super) fn place(c: &JointCell<'_>) -> Result<Placed, TimestepError> {
    let surface = c.stepper.operator_surface(c.state);
    let (points, centroid) = c
        .stepper
        .with_geometry(&surface, |g| (g.x.clone(), g.centroid()))?;
    let radius = points
        .iter()
        .map(|x| {
            ((x[0] - centroid[0]).powi(2)
                + (x[1] - centroid[1]).powi(2)
                + (x[2] - centroid[2]).powi(2))
            .sqrt()
        })
        .fold(0.0, f64::max);
    Ok(Placed {
        surface,
        points,
        centroid,
        radius,
    })
}

/// A cluster whose cells are all held here: `members` their indices among the cells given
/// (ascending), `zones` the near zones restricted (renumbered) to them.
pub(super) struct HeldCluster<'a> {
    pub members: &'a [usize],
    pub zones: &'a NearZones,
}

impl HeldCluster<'_> {
    /// [`step_cluster`] of the members; their reports into `reports`, the cluster into `stats`.
    /// A failure names the member's index among `cells`.
    pub(super) fn step(
        &self,
        cells: &mut [JointCell<'_>],
        near: &NearPairs,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        with_dl: bool,
        stats: &mut JointStats,
        reports: &mut [Option<StepReport>],
    ) -> Result<(), (Option<usize>, TimestepError)> {
        let mut members: Vec<&mut JointCell<'_>> = cells
            .iter_mut()
            .enumerate()
            .filter(|(k, _)| self.members.binary_search(k).is_ok())
            .map(|(_, c)| c)
            .collect();
        let done = step_cluster(&mut members, near, self.zones, u_inf, with_dl)
            .map_err(|(k, e)| (k.map(|k| self.members[k]), e))?;
        stats.add_cluster(
            self.members.len(),
            done.first().map_or(0, |r| r.gmres.iterations),
        );
        for (&k, r) in self.members.iter().zip(done) {
            reports[k] = Some(r);
        }
        Ok(())
    }
}

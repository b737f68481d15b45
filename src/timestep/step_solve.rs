//! The linear solve of a cell's step ([`super::step_phases`] phase 5) and its preconditioners:
//! the capsule's system for `X − X*`, the inextensible cell's for `[X; σ]`, the sphere's and the
//! cell's own preconditioner, and the dense operators they apply.

use super::operator_storage::OperatorStorage;
use std::sync::Mutex;

use super::cell_preconditioner::CellPreconditionerOp;
use super::cell_state::{CellState, PreconditionerRecord};
use super::grid_frame::{grid_rotation, relative_rotation, RotatedPreconditioner};
use super::sphere_preconditioner::{self, StepCoefficients};
use super::step_engine::{ElasticWork, OperatorWork, StepEngine};
use super::step_operator::{
    add_elastic_jacobian, apply_operators, InextensibleOperator, StepOperator,
};
use super::TimestepError;
use super::{gmres, FnOperator, GmresParams, GmresReport, GmresWorkspace, Identity};
use crate::sph_harmonics::ShTransform;
use crate::vesicle::layer::LayerKernel;
use crate::vesicle::membrane::Membrane;
use crate::vesicle::skalak::SkalakParams;

use super::cell_stepper::CellStepper;
use super::own_preconditioner::{own_inverse, OwnInverse, OwnPreconditioner};
use super::semi_implicit::Preconditioning;
use super::step_plan::{GridTerms, StepPlan, StepPreconditioners};

/// Relative drift of the area-equivalent radius that triggers a rebuild of the preconditioner.
pub(super) const PRECONDITIONER_RADIUS_RTOL: f64 = 1e-2;

/// Relative change of `τ` (an adaptive or BDF2 step) beyond which the cell's own
/// preconditioner is rebuilt; within it the iterations decide.
pub(super) const OWN_TAU_RTOL: f64 = 0.1;

/// A singular own operator is tried again only after a step of more than this many times
/// `rebuild_after` iterations with the sphere's preconditioner (a cell near a sphere, which
/// the sphere's serves well, would otherwise try at every step).
pub(super) const SINGULAR_RETRY_FACTOR: usize = 3;

/// The linear system of a capsule's step (see "Capsules" in the module docs): operators at
/// `X*`, grid vectors `3n`.
pub(super) struct CapsuleSystem<'a> {
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
pub(super) fn step_operators<'a>(
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
pub(super) fn solve_capsule(
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

/// The engine of the elastic Jacobian in `work` (made at its first use), with `reference` set.
pub(super) fn elastic_work<'a>(
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

/// Whether `storage` keeps a cell's operators in the cell (not lent by the step engine).
pub(super) fn storage_keeps_per_cell(storage: OperatorStorage) -> bool {
    storage != OperatorStorage::Grid
}

/// Assemble the dense operator of `kernel` at the surface `coefs` into `out`, kept as `storage`
/// says (coefficient space: assembled on the grid in the engine's scratch, then compressed).
pub(super) fn assemble_operator(
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

impl CellStepper {
    pub(super) fn preconditioner_for(
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

    /// Get the cell's own preconditioner ready for a step with coefficients `coef` (and the
    /// elastic Jacobian if `with_jacobian`): dropped when stale, rebuilt from its record when
    /// pending. Returns whether the step must build a new one (from its own operator) and
    /// whether one was rebuilt from a record.
    pub(super) fn prepare_own(
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
    pub(super) fn rebuild_from_record(
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

    /// Phase 5, the linear system of the step, solved by GMRES: a capsule's for `X − X*`, an
    /// inextensible cell's for `[X; σ]`. Returns the solve's report, `Xⁿ⁺¹` on the grid, and
    /// whether the cell's own preconditioner was built (or rebuilt from its record).
    pub(super) fn solve(
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
    pub(super) fn solve_inextensible(
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
    pub(super) fn inextensible_rhs(
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
    pub(super) fn own_preconditioner(
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
    pub(super) fn run_gmres(
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
}

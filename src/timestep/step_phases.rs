//! One step of a cell ([`CellStepper::step_with`]) in named phases: the plan from the history,
//! the preconditioners, the explicit terms, the operators, the solve ([`super::step_solve`]),
//! the new surface, the regrid and the correction of area and volume (the scheme:
//! [`super::semi_implicit`]).

use super::cell_state::CellState;
use super::grid_frame::{grid_rotation, IDENTITY};
use super::step_engine::{OperatorWork, StepEngine};
use super::TimestepError;
use crate::vesicle::layer::LayerKernel;
use crate::vesicle::reparam::{ReparamParams, Reparametrizer};
use crate::vesicle::shapes::Surface;

use super::cell_stepper::CellStepper;
use super::semi_implicit::{extrapolate, ElasticStepping, ExplicitTerms, StepReport, TimeScheme};
use super::step_plan::{GridTerms, StepPlan, StepPreconditioners};
use super::step_solve::{assemble_operator, storage_keeps_per_cell};

/// [`VesicleStepper::correct_area_volume`] with a lent engine; with `area = None` (a capsule,
/// whose area is free) the volume alone, by a uniform normal displacement `α n`.
pub(super) fn correct_shape(
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

impl CellStepper {
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
        self.check_step_inputs(state, &extra)?;
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

    /// The sizes of a step's state and explicit terms.
    pub(super) fn check_step_inputs(
        &self,
        state: &CellState,
        extra: &ExplicitTerms<'_>,
    ) -> Result<(), TimestepError> {
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
        Ok(())
    }

    /// The operators' geometry `X*` of the next step of `state` (coefficients):
    /// `(1 + ω) Xⁿ − ω Xⁿ⁻¹` for BDF2 (`ω = Δtⁿ/Δtⁿ⁻¹`), `Xⁿ` for Euler and a first step.
    pub fn operator_surface(&self, state: &CellState) -> Vec<f64> {
        extrapolate(
            &state.coefs,
            state.previous_coefs.as_deref(),
            self.extrapolation_ratio(state),
        )
    }

    /// [`Self::step_with`] on a leased engine, the sizes checked: the step's phases in order.
    pub(super) fn step_on(
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
    pub(super) fn plan(
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
        // X* (geometry of the operators) and X̂ (the history term), as coefficients.
        let xstar = self.operator_surface(state);
        let xhat: Vec<f64> = match (&state.previous_coefs, bdf2) {
            (Some(prev), true) => state
                .coefs
                .iter()
                .zip(prev)
                .map(|(c, o)| ((1.0 + w) * (1.0 + w) * c - w * w * o) / (1.0 + 2.0 * w))
                .collect(),
            _ => state.coefs.clone(),
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
    pub(super) fn prepare_preconditioners(
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
    pub(super) fn explicit_grid_terms(
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
    pub(super) fn assemble(
        &mut self,
        engine: &mut StepEngine,
        plan: &StepPlan,
    ) -> Result<(), TimestepError> {
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

    /// Phase 6, the new surface: the membrane velocity `(Xⁿ⁺¹ − X̂)/τ`, the history moved on
    /// (BDF2), `Xⁿ⁺¹` into `coefs`. Returns the relative area and volume change of the flow
    /// step (a capsule: the volume's alone), the adaptive step's error estimate.
    pub(super) fn advance(
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
    pub(super) fn regrid_and_correct(
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

    /// The source `r = min(k Δt, 1)(τ/Δt)(W_ref (A/A_ref) / Wⁿ − 1)` of the constraint `Div (X − X̂) = r`
    /// that brings the area element `W` of every material point back toward the reference's
    /// (module docs, "Local area"), `w_now` the area element `Wⁿ` on the grid; `None` without
    /// a Skalak reference, for a capsule, or when switched off. Needs the drift targets set.
    pub(super) fn local_area_source(
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
        // The share `min(k Δt, 1)` of the gap closed in this step.
        let scale = (self.local_area_rate * self.params.dt).min(1.0) * tau / self.params.dt;
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
    /// velocity, the coupling's velocity, the near-implicit densities and the BDF2 history, so
    /// that each stays attached to the same membrane point.
    pub(super) fn regrid(
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
        let mut velocity_c = vector_coefs(engine, state.membrane_velocity.as_deref(), nc)?;
        // The coupling's velocity of this step, `vⁿ`: the next step extrapolates
        // `(1 + ω) vⁿ⁺¹ − ω vⁿ` point by point, so `vⁿ` must sit on the grid `vⁿ⁺¹` is computed
        // on. Left on the old grid, the two differ by the reparametrisation's move (`O(Δt)`)
        // times the velocity's gradient along the surface (docs/hard_cases.md: small beside the
        // re-fit's own error in the cases measured).
        let mut coupling_c = vector_coefs(engine, state.velocity.as_deref(), nc)?;
        // The near-implicit coupling's densities of this step (traction, double-layer density),
        // extrapolated at the next step on the grid they will then sit on.
        let mut density_c = match &state.previous_density {
            Some(d) => {
                let mut c = vec![0.0; 6 * nc];
                for (block, cb) in d.chunks_exact(d.len() / 2).zip(c.chunks_exact_mut(3 * nc)) {
                    engine
                        .sht
                        .forward(block, cb, &mut engine.ws)
                        .map_err(VesicleError::from)?;
                }
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
            if let Some(v) = coupling_c.as_mut() {
                passengers.push(&mut v[..]);
            }
            if let Some(d) = density_c.as_mut() {
                let (f, g) = d.split_at_mut(3 * nc);
                passengers.push(f);
                passengers.push(g);
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
        for (c, v) in [
            (velocity_c, state.membrane_velocity.as_mut()),
            (coupling_c, state.velocity.as_mut()),
        ] {
            if let (Some(c), Some(v)) = (c, v) {
                engine
                    .sht
                    .inverse(&c, v, &mut engine.ws)
                    .map_err(VesicleError::from)?;
            }
        }
        if let (Some(c), Some(d)) = (density_c, state.previous_density.as_mut()) {
            let half = d.len() / 2;
            for (cb, block) in c.chunks_exact(3 * nc).zip(d.chunks_exact_mut(half)) {
                engine
                    .sht
                    .inverse(cb, block, &mut engine.ws)
                    .map_err(VesicleError::from)?;
            }
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

/// The coefficients of a vector field on the grid (`3n` values; `None` stays `None`).
fn vector_coefs(
    engine: &mut StepEngine,
    v: Option<&[f64]>,
    nc: usize,
) -> Result<Option<Vec<f64>>, TimestepError> {
    let Some(v) = v else { return Ok(None) };
    let mut c = vec![0.0; 3 * nc];
    engine
        .sht
        .forward(v, &mut c, &mut engine.ws)
        .map_err(crate::vesicle::VesicleError::from)?;
    Ok(Some(c))
}

//! The stepper of one cell ([`CellStepper`]): its parameters, operators and preconditioners,
//! apart from the cell's state ([`super::cell_state::CellState`]), and what a program sets and
//! reads on it. The step itself is in [`super::step_phases`], its linear solve in
//! [`super::step_solve`]; the scheme is described in [`super::semi_implicit`].

use super::operator_storage::OperatorStorage;
use std::sync::Arc;

use super::cell_state::{CellState, PreconditionerRecord};
use super::grid_frame::IDENTITY;
use super::sphere_preconditioner::{SpherePreconditioner, StepCoefficients};
use super::step_engine::{EngineLease, EnginePool, OperatorWork, StepEngine};
use super::TimestepError;
use crate::vesicle::far_side::FarSideParams;
use crate::vesicle::material_labels::MaterialLabels;
use crate::vesicle::skalak::SkalakParams;

use super::own_preconditioner::{OwnInverse, OwnPreconditioner};
use super::semi_implicit::{check, Preconditioning, TimeScheme, VesicleParams};

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
    pub(super) p: usize,
    /// Grid points and coefficients per component.
    pub(super) n: usize,
    pub(super) nc: usize,
    pub(super) params: VesicleParams,
    pub(super) pool: Arc<EnginePool>,
    pub(super) far_side: FarSideParams,
    pub(super) storage: OperatorStorage,
    /// Dense single layer: `3n_c × 3n_c` in coefficient space (column-major), or on the grid
    /// its rows over coefficients, `3n × 3n_c` row-major (`3n × 3n` column-major without
    /// upsampling) (empty before the first step).
    pub(super) s_op: Vec<f64>,
    /// Dense double layer, the same (empty when `λ = 1`).
    pub(super) d_op: Vec<f64>,
    /// Shear elasticity (explicit or linearly implicit); its reference surface is the state's.
    pub(super) skalak: Option<SkalakParams>,
    /// Double-layer operators assembled by the steps so far (0 for `λ = 1`: only what is called
    /// for; a preconditioner rebuilt from its record assembles again, not counted here).
    pub double_layer_assemblies: usize,
    /// Sphere preconditioners in use (at most two: the Euler and the BDF2 `τ`), shared with
    /// the other cells of the same sphere ([`sphere_preconditioner::shared`]).
    pub(super) preconditioners: Vec<Arc<SpherePreconditioner>>,
    /// Which preconditioner the steps use.
    pub(super) preconditioning: Preconditioning,
    /// The cell's own preconditioner ([`Preconditioning::Cell`]), once built (its record is
    /// also the state's).
    pub(super) own: Option<OwnPreconditioner>,
    /// Own preconditioners built so far.
    pub own_preconditioner_builds: usize,
    /// Whether an inextensible cell with a Skalak reference relaxes its local area element to
    /// the reference's in the constraint (see "Local area" in the module docs).
    pub(super) local_area_relaxation: bool,
    /// The rate (per unit time) at which that relaxation closes the gap between the area
    /// element and the reference's ([`CellStepper::set_local_area_rate`]).
    pub(super) local_area_rate: f64,
}

/// The default rate (per unit time) of the local area relaxation
/// ([`CellStepper::set_local_area_rate`]): the share `min(k Δt, 1)` of the gap is closed per
/// step. Ten per unit of the cell's fastest time scale; `mobo run` scales it by that scale
/// (`run::assembly`).
pub const LOCAL_AREA_RATE: f64 = 10.0;

/// A local area rate must be positive ([`CellStepper::set_local_area_rate`]).
pub(super) fn check_local_area_rate(rate: f64) -> Result<(), TimestepError> {
    if rate > 0.0 {
        Ok(())
    } else {
        Err(TimestepError::InvalidParameter {
            name: "local_area_rate",
            value: format!("{rate}"),
            reason: "must be positive (infinity: the whole gap every step)",
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
            local_area_rate: LOCAL_AREA_RATE,
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
            previous_density: None,
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
    pub(super) fn lease(&self, reference: Option<&[f64]>) -> Result<EngineLease, TimestepError> {
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

    /// The rate `k` (per unit time, positive; default [`LOCAL_AREA_RATE`]) at which the local
    /// area relaxation closes the gap: the share `min(k Δt, 1)` of it per step, so
    /// `f64::INFINITY` closes the whole gap every step. A finite rate keeps BDF2's order: the
    /// relaxation and the drift correction pull toward targets that differ by the
    /// discretisation's error, and closing the whole gap every step moves the surface by an
    /// amount that does not shrink with `Δt` (module docs, "Local area").
    ///
    /// # Errors
    /// [`TimestepError::InvalidParameter`] unless `rate > 0` (NaN included).
    pub fn set_local_area_rate(&mut self, rate: f64) -> Result<(), TimestepError> {
        check_local_area_rate(rate)?;
        self.local_area_rate = rate;
        Ok(())
    }

    /// The rate set by [`Self::set_local_area_rate`].
    pub fn local_area_rate(&self) -> f64 {
        self.local_area_rate
    }

    /// Hold the own preconditioner of `record` (`None`: none): unless it is the one held, it is
    /// rebuilt from the record before the next step that uses it, bit for bit the one the
    /// record came from (a resumed run, a cell moved here, a repeated step). Every step first
    /// adopts its state's record this way.
    pub(super) fn adopt_own_record(&mut self, record: Option<&PreconditionerRecord>) {
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

    /// The step operator's coefficients for time factor `tau` with this cell's parameters.
    pub(super) fn step_coefficients(&self, tau: f64) -> StepCoefficients {
        let p = &self.params;
        StepCoefficients::new(p.viscosity_ratio, tau, p.bending_modulus, p.viscosity)
    }
}

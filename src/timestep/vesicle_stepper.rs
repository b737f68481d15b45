//! One cell with its state, for studies of a single cell: a [`CellStepper`] (the algorithm,
//! its operators and preconditioners) and the [`CellState`] it advances, behind the calls a
//! single-cell study makes (a surface given at every step, the tension and history read and
//! set by name).
//!
//! A suspension keeps the two apart ([`super::suspension::SuspensionCell`]): its checkpoints
//! and the moves of cells between ranks carry the state alone. Here the surface is the
//! caller's: [`VesicleStepper::step`] takes it in, steps the state, and writes it back, so that
//! a study may change it between steps.
//!
//! ```
//! use mobo::timestep::semi_implicit::{TimeScheme, VesicleParams};
//! use mobo::timestep::vesicle_stepper::VesicleStepper;
//! use mobo::timestep::GmresParams;
//! use mobo::vesicle::shapes;
//!
//! let p = 6;
//! let mut coefs = shapes::ellipsoid(p, [1.0, 0.8, 0.6]).unwrap().coefs().to_vec();
//! let params = VesicleParams {
//!     bending_modulus: 1.0,
//!     viscosity: 1.0,
//!     force: [0.0; 3],
//!     dt: 0.01,
//!     upsampled_order: 2 * p,
//!     gmres: GmresParams::default(),
//!     correct_drift: true,
//!     reparametrize: None,
//!     preconditioner: true,
//!     scheme: TimeScheme::Euler,
//!     viscosity_ratio: 1.0,
//!     inextensible: true,
//!     elastic_stepping: None,
//! };
//! let mut st = VesicleStepper::new(p, params).unwrap();
//! let report = st.step(&mut coefs, &|_| [0.0; 3]).unwrap();
//! assert!(report.gmres.converged);
//! // The tension of the step and the membrane velocity are the state's.
//! assert_eq!(st.state().sigma.len(), st.n_points());
//! assert!(st.velocity().is_some());
//! ```

use super::cell_state::{CellState, PreconditionerRecord};
use super::cell_stepper::CellStepper;
use super::semi_implicit::{
    ExplicitTerms, OperatorStorage, Preconditioning, StepReport, VesicleParams,
};
use super::TimestepError;
use crate::vesicle::far_side::FarSideParams;
use crate::vesicle::material_labels::MaterialLabels;
use crate::vesicle::skalak::SkalakParams;

/// One cell: its stepper and its state.
pub struct VesicleStepper {
    stepper: CellStepper,
    state: CellState,
}

impl VesicleStepper {
    /// Plans for order `p`; the state is that of a first step (no history, zero tension).
    pub fn new(p: usize, params: VesicleParams) -> Result<Self, TimestepError> {
        let stepper = CellStepper::new(p, params)?;
        // The surface is the caller's, taken in at every step.
        let state = stepper.initial_state(&vec![0.0; 3 * stepper.n_coefs()], None)?;
        Ok(VesicleStepper { stepper, state })
    }

    /// The stepper (operators, preconditioners, parameters).
    pub fn stepper(&self) -> &CellStepper {
        &self.stepper
    }

    /// The cell's state (its surface is the one of the last step).
    pub fn state(&self) -> &CellState {
        &self.state
    }

    /// The cell's state, mutable (checked at the next step).
    pub fn state_mut(&mut self) -> &mut CellState {
        &mut self.state
    }

    /// Add Skalak shear elasticity (explicit in time) relative to the stress-free surface
    /// `reference` (order-`p` coefficients, same parametrisation as the stepped surface); the
    /// material labels start as the identity.
    pub fn set_skalak(
        &mut self,
        params: SkalakParams,
        reference: &[f64],
    ) -> Result<(), TimestepError> {
        // Checks the reference as a surface (its length included).
        let labels = self.stepper.identity_labels(reference)?;
        // Other elastic parameters change the Jacobian in the cell's own preconditioner.
        if self.stepper.skalak() != Some(params) {
            self.state.preconditioner = None;
        }
        self.stepper.set_skalak(params);
        self.state.skalak_reference = Some(reference.to_vec());
        self.state.material_labels = Some(labels);
        Ok(())
    }

    /// The Skalak reference's first surface and the grid's material labels
    /// ([`crate::vesicle::material_labels`]); `None` without shear elasticity.
    pub fn material_labels(&self) -> Option<&MaterialLabels> {
        self.state.material_labels.as_ref()
    }

    /// Restore the material labels (a restarted run or a repeated step), after
    /// [`VesicleStepper::set_skalak_reference`] (which starts the labels afresh from the
    /// reference it is given).
    ///
    /// # Errors
    /// [`TimestepError::InvalidParameter`] for a cell without shear elasticity or labels of
    /// the wrong size.
    pub fn set_material_labels(&mut self, labels: MaterialLabels) -> Result<(), TimestepError> {
        let expected = 3 * self.stepper.n_coefs();
        if self.stepper.skalak().is_none()
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
        self.state.material_labels = Some(labels);
        Ok(())
    }

    /// The stress-free reference of the Skalak elasticity (coefficients) in the current
    /// parametrisation, composed from the material labels after every reparametrisation;
    /// `None` without shear elasticity.
    pub fn skalak_reference(&self) -> Option<&[f64]> {
        self.state.skalak_reference.as_deref()
    }

    /// Replace the (relabelled) Skalak reference (a restarted run or a repeated step restores
    /// it). The material labels start afresh from it (the identity map): a caller that kept
    /// them restores them next with [`VesicleStepper::set_material_labels`].
    ///
    /// # Errors
    /// [`TimestepError::InvalidParameter`] for a cell without shear elasticity; the checks of
    /// [`VesicleStepper::set_skalak`] for the surface.
    pub fn set_skalak_reference(&mut self, reference: &[f64]) -> Result<(), TimestepError> {
        let Some(params) = self.stepper.skalak() else {
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
        self.stepper.preconditioning()
    }

    /// Use `preconditioning` from the next step on (a change drops the cell's own
    /// preconditioner, if any).
    pub fn set_preconditioning(&mut self, preconditioning: Preconditioning) {
        if preconditioning != self.stepper.preconditioning() {
            self.state.preconditioner = None;
        }
        self.stepper.set_preconditioning(preconditioning);
    }

    /// Switch the local area relaxation of an inextensible cell with shear elasticity
    /// ([`CellStepper::set_local_area_relaxation`]).
    pub fn set_local_area_relaxation(&mut self, on: bool) {
        self.stepper.set_local_area_relaxation(on);
    }

    /// The local area relaxation's rate ([`CellStepper::set_local_area_rate`]).
    ///
    /// # Errors
    /// [`TimestepError::InvalidParameter`] unless `rate > 0`.
    pub fn set_local_area_rate(&mut self, rate: f64) -> Result<(), TimestepError> {
        self.stepper.set_local_area_rate(rate)
    }

    /// What the cell's own preconditioner was built from (`None`: it has none).
    pub fn own_preconditioner_record(&self) -> Option<&PreconditionerRecord> {
        self.state.preconditioner.as_ref()
    }

    /// Give the cell the own preconditioner built from `record` (`None`: none): unless it is
    /// the one it holds, it is rebuilt from the record before the next step that uses it, bit
    /// for bit the one the record came from.
    pub fn set_own_preconditioner_record(&mut self, record: Option<&PreconditionerRecord>) {
        self.state.preconditioner = record.cloned();
    }

    /// How the dense self-interaction operators are kept between assembly and application.
    pub fn operator_storage(&self) -> OperatorStorage {
        self.stepper.operator_storage()
    }

    /// Keep the dense self-interaction operators in coefficient space (the default) or on the
    /// grid, from the next step on.
    pub fn set_operator_storage(&mut self, storage: OperatorStorage) {
        if storage != self.stepper.operator_storage() {
            self.state.preconditioner = None;
        }
        self.stepper.set_operator_storage(storage);
    }

    /// Bytes of this cell (its dense operators, preconditioners and state; the engines lent
    /// by the pool are shared and not counted).
    pub fn memory_bytes(&self) -> usize {
        self.stepper.memory_bytes() + self.state.memory_bytes()
    }

    /// Double-layer operators assembled by the steps so far.
    pub fn double_layer_assemblies(&self) -> usize {
        self.stepper.double_layer_assemblies
    }

    /// Own preconditioners built so far.
    pub fn own_preconditioner_builds(&self) -> usize {
        self.stepper.own_preconditioner_builds
    }

    /// The area and volume the drift correction restores (set at the first step).
    pub fn drift_targets(&self) -> Option<(f64, f64)> {
        self.state.drift_targets
    }

    /// Set the area and volume the drift correction restores (a restarted run keeps those of
    /// its first step).
    pub fn set_drift_targets(&mut self, targets: Option<(f64, f64)>) {
        self.state.drift_targets = targets;
    }

    /// The coefficients `Xⁿ⁻¹` of the surface before the last step (kept by BDF2 runs; `None`
    /// before the first step or for Euler).
    pub fn previous_coefs(&self) -> Option<&[f64]> {
        self.state.previous_coefs.as_deref()
    }

    /// Set (or clear) `Xⁿ⁻¹` (a restarted BDF2 run restores it; `None` makes the next step
    /// Euler).
    ///
    /// # Errors
    /// [`TimestepError::DimensionMismatch`] for a wrong length, [`TimestepError::NonFinite`]
    /// for NaN or infinite coefficients.
    pub fn set_previous_coefs(&mut self, coefs: Option<&[f64]>) -> Result<(), TimestepError> {
        self.set_checked(|s| s.previous_coefs = coefs.map(|c| c.to_vec()))
    }

    /// The step `Δtⁿ⁻¹` from `Xⁿ⁻¹` to `Xⁿ` (`None`: the step size of the run so far, `dt`).
    pub fn previous_dt(&self) -> Option<f64> {
        self.state.previous_dt
    }

    /// Set `Δtⁿ⁻¹` (restart of an adaptive BDF2 run).
    pub fn set_previous_dt(&mut self, dt: Option<f64>) -> Result<(), TimestepError> {
        self.set_checked(|s| s.previous_dt = dt)
    }

    /// Change the time step (adaptive `dt`).
    pub fn set_dt(&mut self, dt: f64) -> Result<(), TimestepError> {
        self.stepper.set_dt(dt)
    }

    /// `ω = Δtⁿ/Δtⁿ⁻¹` when the next step is a BDF2 step (`None`: an Euler step).
    pub fn extrapolation_ratio(&self) -> Option<f64> {
        self.stepper.extrapolation_ratio(&self.state)
    }

    /// The membrane velocity of the last step on the order-`p` grid (`3n`, component-major)
    /// (see [`CellState::membrane_velocity`]); `None` before the first step.
    pub fn velocity(&self) -> Option<&[f64]> {
        self.state.membrane_velocity.as_deref()
    }

    /// Set (or clear) the recorded membrane velocity (a restarted run restores it).
    ///
    /// # Errors
    /// [`TimestepError::DimensionMismatch`] for a wrong length, [`TimestepError::NonFinite`]
    /// for NaN or infinite values.
    pub fn set_velocity(&mut self, velocity: Option<&[f64]>) -> Result<(), TimestepError> {
        self.set_checked(|s| s.membrane_velocity = velocity.map(|v| v.to_vec()))
    }

    /// Parameters.
    pub fn params(&self) -> &VesicleParams {
        self.stepper.params()
    }

    /// Settings of the far-side split in the cell's own layer potentials.
    pub fn far_side_params(&self) -> FarSideParams {
        self.stepper.far_side_params()
    }

    /// Change the settings of the far-side split ([`CellStepper::set_far_side_params`]).
    pub fn set_far_side_params(&mut self, params: FarSideParams) -> Result<(), TimestepError> {
        if params != self.stepper.far_side_params() {
            self.state.preconditioner = None;
        }
        self.stepper.set_far_side_params(params)
    }

    /// The traction the membrane exerts on the fluid at the surface `coefs`, with the tension
    /// of the last step ([`CellStepper::traction`]).
    pub fn traction(&mut self, coefs: &[f64], out: &mut [f64]) -> Result<(), TimestepError> {
        self.take_surface(coefs)?;
        self.stepper.traction(&self.state, out)
    }

    /// `f` applied to the geometry of the surface `coefs` on the order-`p` grid.
    pub fn with_geometry<R>(
        &mut self,
        coefs: &[f64],
        f: impl FnOnce(&crate::vesicle::geometry::Geometry) -> R,
    ) -> Result<R, TimestepError> {
        self.stepper.with_geometry(coefs, f)
    }

    /// SH order.
    pub fn order(&self) -> usize {
        self.stepper.order()
    }

    /// Grid points per cell, `n = 2p(p+1)`.
    pub fn n_points(&self) -> usize {
        self.stepper.n_points()
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

    /// One step with explicit terms (the velocity induced by other cells, extra tractions):
    /// `coefs` is taken in as the state's surface, stepped, and written back.
    pub fn step_with(
        &mut self,
        coefs: &mut [f64],
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        extra: ExplicitTerms<'_>,
    ) -> Result<StepReport, TimestepError> {
        self.take_surface(coefs)?;
        let report = self.stepper.step_with(&mut self.state, u_inf, extra);
        coefs.copy_from_slice(&self.state.coefs);
        report
    }

    /// Move the surface along its normal so that its area and volume become `area` and
    /// `volume` ([`CellStepper::correct_area_volume`]).
    pub fn correct_area_volume(
        &mut self,
        coefs: &mut [f64],
        area: f64,
        volume: f64,
    ) -> Result<(), TimestepError> {
        self.stepper.correct_area_volume(coefs, area, volume)
    }

    /// Change the state by `set`, kept only if the result passes
    /// [`CellStepper::check_state`].
    fn set_checked(&mut self, set: impl FnOnce(&mut CellState)) -> Result<(), TimestepError> {
        let mut state = self.state.clone();
        set(&mut state);
        self.stepper.check_state(&state)?;
        self.state = state;
        Ok(())
    }

    /// The caller's surface as the state's.
    fn take_surface(&mut self, coefs: &[f64]) -> Result<(), TimestepError> {
        if coefs.len() != self.state.coefs.len() {
            return Err(TimestepError::DimensionMismatch {
                what: "surface coefficients",
                expected: self.state.coefs.len(),
                got: coefs.len(),
            });
        }
        self.state.coefs.copy_from_slice(coefs);
        Ok(())
    }
}

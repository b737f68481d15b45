//! Many cells in one flow: each cell advanced by its own semi-implicit step
//! ([`CellStepper`]: bending, tension and self-interaction implicit), the cells coupled
//! explicitly through the velocity their membrane tractions at `Xⁿ` induce on each other
//! ([`Coupling`]: FMM, minus each cell's own smooth quadrature, plus near-singular corrections).
//!
//! This is the splitting of Veerapaneni et al. (J. Comput. Phys. 230, 2011, §3.3) and of MOBO
//! (Rahimian et al., SC'10): per step one FMM evaluation for the inter-cell velocities, then
//! independent per-cell solves (in parallel over cells; each cell's dense operators are applied
//! serially). A scene of one cell builds no [`Coupling`] and no FMM. With BDF2 the explicit
//! inter-cell velocity is extrapolated to `X* = 2Xⁿ − Xⁿ⁻¹` as `2vⁿ − vⁿ⁻¹`; the contact
//! repulsion stays first order (a penalty acting only near contact).
//!
//! **Viscosity contrast between cells.** A cell with `λ ≠ 1` is felt by the others through its
//! single layer and its double layer `(1 − λ) D[u]` ([`Coupling::velocities_with`]). Its own
//! double layer is implicit in its step; the one the others feel takes the membrane velocity
//! `u` of the cell's previous solve ([`CellState::membrane_velocity`]: `(Xⁿ − Xⁿ⁻¹)/Δt` for Euler,
//! a first-order lag, consistent with the explicit coupling; the BDF2 derivative
//! `(3Xⁿ − 4Xⁿ⁻¹ + Xⁿ⁻²)/(2Δt)` for BDF2, which then extrapolates the whole inter-cell velocity
//! as above). A scene gives no tension and no velocity at `t = 0`: the start-up
//! ([`Suspension::set_start_up_passes`], on by default) solves the first step and throws it
//! away, keeping its tension and membrane velocity as `σ⁰` and `u⁰`, so that the first step
//! couples the tension's traction and the double layer too, off by `O(Δt)` only (without it,
//! `σ⁰ = 0`, the double layer enters from the second step on, and every explicit part of the
//! coupling is first order in `Δt`). A restart restores the velocities
//! (the state's membrane velocity). Only what is called for: with every `λ = 1` (or one cell)
//! no double-layer density is passed and no stresslet FMM is built.
//!
//! **Over MPI ranks** ([`Suspension::new_part`], [`Suspension::step_on`]): each rank holds some
//! of the cells, whole (one [`SuspensionCell`] each: stepper, coefficients, history), named by their global indices
//! ([`Suspension::ids`], kept ascending); the coupling is collective
//! ([`Coupling::velocities_on`]: one distributed FMM, ghost copies of nearby cells), every
//! per-cell solve stays on its rank. A failure of one cell's step ends the step on every rank
//! with the failure of the lowest failing cell (its message on the others). Cells move between
//! ranks as their [`CellState`] ([`Suspension::take_cell`], [`Suspension::insert_cell`]): a
//! step's result does not depend on where a cell is stepped.

use rayon::prelude::*;

mod contacts;
mod dissipation;
mod field;
mod gather;
mod recycle;
mod rigid_move;
mod start_up;
mod stepping;
mod walls;

pub use recycle::{RecycleStats, Recycling};
pub use start_up::{StartUpReport, START_UP_ANDERSON_DEPTH, START_UP_PASSES, START_UP_TOLERANCE};

use super::cell_force::{CellForce, CellView, VectorField};
use super::cell_state::CellState;
use super::cell_stepper::CellStepper;
use super::contact::{ContactSolver, ContactStats};
use super::coupling::{Coupling, CouplingParams, CouplingStats};
use super::near_implicit::{
    default_implicit_zone, step_all_on, CouplingMode, JointCell, JointStats, RanksStep,
};
use super::near_pairs::NearPairs;
use super::semi_implicit::{
    extrapolate, ExplicitTerms, OperatorStorage, Preconditioning, StepReport, VesicleParams,
};
use super::TimestepError;
use crate::comm::{text_words, words_text, Communicator, SerialComm};
use crate::vesicle::far_side::FarSideParams;
use crate::vesicle::skalak::SkalakParams;

/// One cell of a suspension: its initial surface and parameters.
#[derive(Clone, Debug)]
pub struct CellSetup {
    /// Order-`p` SH coefficients (x, y, z).
    pub coefs: Vec<f64>,
    /// Step parameters of this cell (moduli, force, `dt`, …; `dt` must agree between cells).
    pub params: VesicleParams,
    /// Shear elasticity and the stress-free reference surface (coefficients).
    pub skalak: Option<(SkalakParams, Vec<f64>)>,
}

/// A failure of one cell's step.
#[derive(Debug, thiserror::Error)]
#[error("{}: {source}", match .cell { Some(c) => format!("cell {c}"), None => "inter-cell coupling".to_string() })]
pub struct CellStepError {
    /// Global index of the cell (`None`: the coupling).
    pub cell: Option<usize>,
    /// What went wrong.
    pub source: TimestepError,
}

/// A failure of the ranks' communication is the coupling's (no cell named).
impl From<crate::comm::CommError> for CellStepError {
    fn from(e: crate::comm::CommError) -> Self {
        CellStepError {
            cell: None,
            source: TimestepError::Comm(e),
        }
    }
}

/// What one step of the suspension did.
#[derive(Clone, Debug)]
pub struct SuspensionReport {
    /// Per cell of this rank (in the order of [`Suspension::ids`]): the GMRES solve.
    pub cells: Vec<StepReport>,
}

impl SuspensionReport {
    /// The largest area/volume error of a cell (of this rank) in this step (the adaptive-`dt`
    /// estimate) and the cell (this rank's index) that committed it.
    pub fn area_volume_error(&self) -> (f64, usize) {
        self.cells
            .iter()
            .enumerate()
            .fold((0.0, 0), |(e, c), (i, r)| {
                // NaN wins: a failed estimate must not pass as small.
                if r.area_volume_error > e || r.area_volume_error.is_nan() && !e.is_nan() {
                    (r.area_volume_error, i)
                } else {
                    (e, c)
                }
            })
    }
}

/// Everything a step changes, kept to repeat a rejected step (adaptive `dt`): each cell's
/// [`CellState`].
#[derive(Clone, Debug)]
pub struct SuspensionState {
    cells: Vec<CellState>,
}

/// One cell held by a [`Suspension`]: its global index, its stepper (operators,
/// preconditioners) and its state (surface, tension, history, inter-cell velocities, GMRES
/// iterations: what a checkpoint saves and a move to another rank carries).
pub struct SuspensionCell {
    /// Global index of the cell (its place in the scene, over all ranks).
    pub id: usize,
    /// The cell's semi-implicit stepper.
    pub stepper: CellStepper,
    /// The cell's state.
    pub state: CellState,
}

/// Cells of order `p`, stepped together (all of them, or one rank's share).
pub struct Suspension {
    /// The cells held here, by ascending global index.
    cells: Vec<SuspensionCell>,
    /// Cells over all ranks.
    n_global: usize,
    coupling: Option<Coupling>,
    /// Whether the cells with `λ ≠ 1` pass their double layer to the others (on by default;
    /// switched off only to measure what it does).
    inter_cell_double_layer: bool,
    /// Whether some cell (on any rank) has `λ ≠ 1`.
    contrast: bool,
    /// Operator storage and far-side settings of every cell, also of cells inserted later
    /// (`None`: the stepper's default).
    storage: Option<OperatorStorage>,
    far_side: Option<FarSideParams>,
    /// The local area relaxation's rate of every cell ([`Suspension::set_local_area_rate`]).
    local_area_rate: Option<f64>,
    /// Preconditioner of every cell, also of cells inserted later (`None`: the stepper's
    /// default).
    preconditioning: Option<Preconditioning>,
    /// Seconds in this rank's per-cell work (tractions and solves), without waiting for other
    /// ranks (cumulative).
    solve_s: f64,
    /// How the coupling enters a step, and the near-zone operator of the near-implicit one.
    coupling_mode: CouplingMode,
    near_pairs: NearPairs,
    /// What the near-implicit coupling did (cumulative).
    joint: JointStats,
    /// The contact projection after every step (`None`: off) and what it did.
    contacts: Option<ContactSolver>,
    contact_stats: ContactStats,
    /// Rigid walls around or among the cells (`None`: free space).
    walls: Option<super::wall_coupling::WallCoupling>,
    /// A plane wall beside the cells (`None`: none).
    plane: Option<super::plane_coupling::PlaneCoupling>,
    /// The velocity each cell felt from the others (and the walls) at the start of the last
    /// step, on the grid that step began on (`None`: not recorded; [`Suspension::record_coupling`]).
    coupling_record: Option<Vec<Vec<f64>>>,
    /// The evaluators of [`Suspension::velocity_at`], kept between calls.
    field: Option<field::FieldEvaluators>,
    /// The most start-up passes before the first step, and what they did
    /// ([`Suspension::set_start_up_passes`]).
    start_up_passes: usize,
    /// The depth of Anderson's mixing of the start-up passes (0: plain passes).
    start_up_depth: usize,
    start_up: Option<StartUpReport>,
    /// Cells recycled through a tube's window (`None`: off) and what that did.
    recycling: Option<Recycling>,
    recycle_stats: RecycleStats,
}

impl Suspension {
    /// Set up the cells (all of order `p`). With two or more cells the coupling is built with
    /// `coupling` (its far-field quadrature at each cell's upsampled order); with one cell
    /// nothing is coupled and no FMM is ever built.
    pub fn new(
        p: usize,
        cells: Vec<CellSetup>,
        coupling: CouplingParams,
    ) -> Result<Self, CellStepError> {
        let n = cells.len();
        let q = cells.first().map_or(p, |c| c.params.upsampled_order.max(p));
        let contrast = cells.iter().any(|c| c.params.viscosity_ratio != 1.0);
        Self::new_part(
            p,
            q,
            cells.into_iter().enumerate().collect(),
            n,
            contrast,
            coupling,
        )
    }

    /// One rank's share of a suspension of `n_global` cells: `cells` are `(global index,
    /// setup)`; `q` the upsampled order of every cell, `contrast` whether any cell of any rank
    /// has `λ ≠ 1`. The coupling is built when `n_global > 1` (also on a rank that holds no
    /// cell: it takes part in every collective step).
    pub fn new_part(
        p: usize,
        q: usize,
        cells: Vec<(usize, CellSetup)>,
        n_global: usize,
        contrast: bool,
        coupling: CouplingParams,
    ) -> Result<Self, CellStepError> {
        let mut s = Suspension {
            cells: Vec::new(),
            n_global,
            coupling: None,
            inter_cell_double_layer: true,
            coupling_record: None,
            contrast,
            storage: None,
            far_side: None,
            local_area_rate: None,
            preconditioning: None,
            solve_s: 0.0,
            coupling_mode: CouplingMode::Explicit,
            near_pairs: NearPairs::new(p, coupling.viscosity, default_implicit_zone(p)),
            joint: JointStats::default(),
            contacts: None,
            contact_stats: ContactStats::default(),
            walls: None,
            plane: None,
            field: None,
            start_up_passes: START_UP_PASSES,
            start_up_depth: START_UP_ANDERSON_DEPTH,
            start_up: None,
            recycling: None,
            recycle_stats: RecycleStats::default(),
        };
        let dt0 = cells.first().map(|c| c.1.params.dt);
        for (id, c) in cells {
            if Some(c.params.dt) != dt0 {
                return Err(CellStepError {
                    cell: Some(id),
                    source: TimestepError::InvalidParameter {
                        name: "dt",
                        value: format!("{}", c.params.dt),
                        reason: "all cells of a suspension share one time step",
                    },
                });
            }
            s.insert_cell(p, id, &c, None)?;
        }
        if n_global > 1 {
            s.coupling = Some(
                Coupling::new(p, q, coupling)
                    .map_err(|source| CellStepError { cell: None, source })?,
            );
        }
        Ok(s)
    }

    /// Add the cell `id` built from `setup`, in the state `state` (`None`: its initial state),
    /// at its place in the ascending order of ids (a cell moving to this rank).
    pub fn insert_cell(
        &mut self,
        p: usize,
        id: usize,
        setup: &CellSetup,
        state: Option<&CellState>,
    ) -> Result<(), CellStepError> {
        let err = |source| CellStepError {
            cell: Some(id),
            source,
        };
        let mut st = CellStepper::new(p, setup.params).map_err(err)?;
        if let Some((sk, _)) = &setup.skalak {
            st.set_skalak(*sk);
        }
        if let Some(storage) = self.storage {
            st.set_operator_storage(storage);
        }
        if let Some(pc) = self.preconditioning {
            st.set_preconditioning(pc);
        }
        if let Some(far_side) = self.far_side {
            st.set_far_side_params(far_side).map_err(err)?;
        }
        if let Some(rate) = self.local_area_rate {
            st.set_local_area_rate(rate).map_err(err)?;
        }
        let at = self.cells.partition_point(|c| c.id < id);
        if self.cells.get(at).map(|c| c.id) == Some(id) {
            return Err(err(TimestepError::InvalidParameter {
                name: "cell",
                value: format!("{id}"),
                reason: "is already held here",
            }));
        }
        let initial = st
            .initial_state(&setup.coefs, setup.skalak.as_ref().map(|(_, r)| &r[..]))
            .map_err(err)?;
        self.cells.insert(
            at,
            SuspensionCell {
                id,
                stepper: st,
                state: initial,
            },
        );
        if let Some(state) = state {
            self.set_cell_state(at, state)?;
        }
        Ok(())
    }

    /// Remove this rank's cell `i` (a cell moving away): its global index and state.
    pub fn take_cell(&mut self, i: usize) -> (usize, CellState) {
        let state = self.cell_state(i);
        (self.cells.remove(i).id, state)
    }

    /// The state of this rank's cell `i`.
    pub fn cell_state(&self, i: usize) -> CellState {
        self.cells[i].state.clone()
    }

    /// Put this rank's cell `i` into `state` (a restart, a cell that moved here, a rejected
    /// step), checked against its stepper ([`CellStepper::check_state`]). A Skalak reference
    /// without material labels (a checkpoint written before them) starts its labels afresh; a
    /// cell without shear elasticity ignores a reference; a Skalak cell given none keeps its
    /// own.
    pub fn set_cell_state(&mut self, i: usize, state: &CellState) -> Result<(), CellStepError> {
        let cell = &mut self.cells[i];
        let err = |source| CellStepError {
            cell: Some(cell.id),
            source,
        };
        if state.material_labels.is_some() && state.skalak_reference.is_none() {
            return Err(err(TimestepError::InvalidParameter {
                name: "material labels",
                value: "present".into(),
                reason: "a cell state with material labels needs its Skalak reference",
            }));
        }
        let mut new = state.clone();
        match (cell.stepper.skalak(), &new.skalak_reference) {
            (None, _) => {
                new.skalak_reference = None;
                new.material_labels = None;
            }
            (Some(_), None) => {
                new.skalak_reference = cell.state.skalak_reference.clone();
                new.material_labels = cell.state.material_labels.clone();
            }
            (Some(_), Some(r)) if new.material_labels.is_none() => {
                new.material_labels = Some(cell.stepper.identity_labels(r).map_err(err)?);
            }
            _ => {}
        }
        cell.stepper.check_state(&new).map_err(err)?;
        cell.state = new;
        Ok(())
    }

    /// Store the operators of every cell (also of cells inserted later) as `storage`.
    pub fn set_operator_storage(&mut self, storage: OperatorStorage) {
        self.storage = Some(storage);
        for c in &mut self.cells {
            // A change drops the cell's own preconditioner (the stepper's and its record).
            if c.stepper.operator_storage() != storage {
                c.state.preconditioner = None;
            }
            c.stepper.set_operator_storage(storage);
        }
    }

    /// The preconditioner of every cell (also of cells inserted later).
    pub fn set_preconditioning(&mut self, preconditioning: Preconditioning) {
        self.preconditioning = Some(preconditioning);
        for c in &mut self.cells {
            if c.stepper.preconditioning() != preconditioning {
                c.state.preconditioner = None;
            }
            c.stepper.set_preconditioning(preconditioning);
        }
    }

    /// The storage set by [`Self::set_operator_storage`] (`None`: each stepper's default).
    pub fn operator_storage(&self) -> Option<OperatorStorage> {
        self.storage
    }

    /// The preconditioner set by [`Self::set_preconditioning`] (`None`: each stepper's default).
    pub fn preconditioning(&self) -> Option<Preconditioning> {
        self.preconditioning
    }

    /// Own preconditioners built by this rank's cells so far (see
    /// [`super::semi_implicit::Preconditioning::Cell`]).
    pub fn own_preconditioner_builds(&self) -> usize {
        self.cells
            .iter()
            .map(|c| c.stepper.own_preconditioner_builds)
            .sum()
    }

    /// The local area relaxation's rate of every cell, also of cells inserted later
    /// ([`CellStepper::set_local_area_rate`]).
    ///
    /// # Errors
    /// A rate that is not positive (no cell named).
    pub fn set_local_area_rate(&mut self, rate: f64) -> Result<(), CellStepError> {
        super::cell_stepper::check_local_area_rate(rate)
            .map_err(|source| CellStepError { cell: None, source })?;
        for c in &mut self.cells {
            c.stepper
                .set_local_area_rate(rate)
                .map_err(|source| CellStepError {
                    cell: Some(c.id),
                    source,
                })?;
        }
        self.local_area_rate = Some(rate);
        Ok(())
    }

    /// Far-side settings of every cell (also of cells inserted later).
    pub fn set_far_side_params(&mut self, params: FarSideParams) -> Result<(), CellStepError> {
        self.far_side = Some(params);
        for c in &mut self.cells {
            if c.stepper.far_side_params() != params {
                c.state.preconditioner = None;
            }
            c.stepper
                .set_far_side_params(params)
                .map_err(|source| CellStepError {
                    cell: Some(c.id),
                    source,
                })?;
        }
        Ok(())
    }

    /// The cells held here, by ascending global index.
    pub fn cells(&self) -> &[SuspensionCell] {
        &self.cells
    }

    /// The cells held here, mutable (a restart, a study that sets a cell's surface).
    pub fn cells_mut(&mut self) -> &mut [SuspensionCell] {
        &mut self.cells
    }

    /// Global indices of the cells held here, ascending.
    pub fn ids(&self) -> Vec<usize> {
        self.cells.iter().map(|c| c.id).collect()
    }

    /// Cells over all ranks.
    pub fn n_global(&self) -> usize {
        self.n_global
    }

    /// Number of cells held here.
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    /// Whether no cell is held here.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// Each cell's SH coefficients (a view of [`Self::cells`]).
    pub fn coefs(&self) -> Vec<&[f64]> {
        self.cells
            .iter()
            .map(|c| c.state.coefs.as_slice())
            .collect()
    }

    /// Each cell's SH coefficients, mutable (a restart; a view of [`Self::cells_mut`]).
    pub fn coefs_mut(&mut self) -> Vec<&mut Vec<f64>> {
        self.cells.iter_mut().map(|c| &mut c.state.coefs).collect()
    }

    /// The per-cell steppers (tension, drift targets; a view of [`Self::cells`]).
    pub fn steppers(&self) -> Vec<&CellStepper> {
        self.cells.iter().map(|c| &c.stepper).collect()
    }

    /// Mutable per-cell steppers (a restart; a view of [`Self::cells_mut`]).
    pub fn steppers_mut(&mut self) -> Vec<&mut CellStepper> {
        self.cells.iter_mut().map(|c| &mut c.stepper).collect()
    }

    /// Seconds this rank spent in its cells' own work (tractions, solves), not counting the
    /// coupling nor waiting for other ranks (cumulative).
    pub fn solve_seconds(&self) -> f64 {
        self.solve_s
    }

    /// GMRES iterations of each cell's last solve (0 before the first).
    pub fn iterations(&self) -> Vec<usize> {
        self.cells.iter().map(|c| c.state.iterations).collect()
    }

    /// Counters of the coupling (`None` for one cell: nothing coupled, no FMM).
    pub fn coupling_stats(&self) -> Option<CouplingStats> {
        self.coupling.as_ref().map(|c| c.stats)
    }

    /// Where the last FMM's near field ran and why (`None` before any FMM).
    pub fn near_field_decision(&self) -> Option<crate::fmm::gpu_near::NearDecision> {
        self.coupling.as_ref().and_then(|c| c.near_field.clone())
    }

    /// The velocity the other cells induced on each cell in the last step (an empty vector
    /// for a cell before its first coupled step).
    pub fn inter_cell_velocities(&self) -> Vec<&[f64]> {
        self.cells
            .iter()
            .map(|c| c.state.velocity.as_deref().unwrap_or_default())
            .collect()
    }

    /// The inter-cell velocities at `Xⁿ⁻¹` kept for the BDF2 extrapolation (empty vectors
    /// for one cell or the Euler scheme before the first step).
    pub fn previous_inter_cell_velocities(&self) -> Vec<&[f64]> {
        self.cells
            .iter()
            .map(|c| c.state.previous_velocity.as_deref().unwrap_or_default())
            .collect()
    }

    /// The time step (shared by all cells).
    pub fn dt(&self) -> f64 {
        self.cells.first().map_or(0.0, |c| c.stepper.params().dt)
    }

    /// Change the time step of every cell (adaptive `dt`).
    pub fn set_dt(&mut self, dt: f64) -> Result<(), CellStepError> {
        for c in &mut self.cells {
            c.stepper.set_dt(dt).map_err(|source| CellStepError {
                cell: Some(c.id),
                source,
            })?;
        }
        Ok(())
    }

    /// A copy of everything [`Suspension::step`] changes (each cell's [`CellState`]);
    /// [`Suspension::restore`] goes back to it.
    pub fn snapshot(&self) -> SuspensionState {
        SuspensionState {
            cells: (0..self.len()).map(|i| self.cell_state(i)).collect(),
        }
    }

    /// Go back to a [`Suspension::snapshot`] (a rejected step). The sphere preconditioners are
    /// not part of the state (they depend only on the drift targets and `dt`); a cell's own
    /// preconditioner is, as the record it is rebuilt from (kept when it is the one held).
    pub fn restore(&mut self, state: &SuspensionState) -> Result<(), CellStepError> {
        for (i, c) in state.cells.iter().enumerate() {
            self.set_cell_state(i, c)?;
        }
        Ok(())
    }

    /// Whether some cell has a viscosity contrast and there are other cells to feel its double
    /// layer (the inter-cell double layer is then built from the second step on).
    pub fn has_inter_cell_double_layer(&self) -> bool {
        self.inter_cell_double_layer && self.coupling.is_some() && self.contrast
    }

    /// Switch the inter-cell double layer off (or on again): the cells then feel only each
    /// other's single layers, as if every `λ` were 1 outside their own step. For studies and
    /// tests of what the double layer does; a physical run keeps it on.
    pub fn set_inter_cell_double_layer(&mut self, on: bool) {
        self.inter_cell_double_layer = on;
    }

    /// How the coupling enters a step ([`CouplingMode::Explicit`] unless set).
    pub fn coupling_mode(&self) -> CouplingMode {
        self.coupling_mode
    }

    /// Set how the coupling enters a step: [`CouplingMode::NearImplicit`] solves the cells in
    /// each other's near zones as one system ([`super::near_implicit`]; one rank only).
    pub fn set_coupling_mode(&mut self, mode: CouplingMode) {
        self.coupling_mode = mode;
    }

    /// The near-implicit coupling's zone, `zone · R/√p` around each cell (default
    /// [`default_implicit_zone`]); a plane wall's images set before are kept.
    pub fn set_implicit_zone(&mut self, zone: f64) {
        self.near_pairs.set_zone(zone);
    }

    /// Record, at every step, the velocity each cell feels from the other cells and the walls,
    /// as computed at the start of the step on the grid the step began on
    /// ([`Suspension::recorded_coupling`]; off by default: it copies `3n` values per cell a
    /// step). The cell's own copy, [`CellState::velocity`], is relabelled by the step's
    /// reparametrisation for the next step's extrapolation, so it sits on a grid that depends on
    /// the step taken.
    pub fn record_coupling(&mut self, on: bool) {
        self.coupling_record = on.then(Vec::new);
    }

    /// The velocities recorded at the start of the last step (per cell of this rank, in the
    /// order of [`Suspension::ids`]); `None` when not recording, or before the first step (or
    /// with a single cell and no walls: nothing couples).
    pub fn recorded_coupling(&self) -> Option<&[Vec<f64>]> {
        self.coupling_record.as_deref().filter(|r| !r.is_empty())
    }

    /// What the near-implicit coupling did so far: clusters solved jointly, their cells, the
    /// largest, and their GMRES iterations (cumulative; zero with the explicit coupling).
    pub fn joint_stats(&self) -> JointStats {
        self.joint
    }

    /// Advance every cell by one step in the background flow `u_inf`.
    pub fn step(
        &mut self,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
    ) -> Result<SuspensionReport, CellStepError> {
        self.step_on(&SerialComm, u_inf)
    }

    /// [`Suspension::step`] over the ranks of `comm` (collective: every rank steps its own
    /// cells, the coupling spans all). A failure on any rank is returned on every rank.
    pub fn step_on(
        &mut self,
        comm: &dyn Communicator,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
    ) -> Result<SuspensionReport, CellStepError> {
        self.step_with_forces(comm, u_inf, 0.0, &[])
    }
}

/// `local` where every rank succeeded; otherwise, on every rank, the failure of the lowest
/// failing cell: the original error on its rank, [`TimestepError::Remote`] with its message on
/// the others (so that all ranks stop at the same step with the same cell named).
pub(crate) fn agree_cells<T>(
    comm: &dyn Communicator,
    local: Result<T, CellStepError>,
) -> Result<T, CellStepError> {
    if comm.size() == 1 {
        return local;
    }
    let key = |e: &CellStepError| e.cell.map_or(0, |c| c as u64 + 1);
    let mine: Vec<u64> = match &local {
        Ok(_) => Vec::new(),
        Err(e) => [key(e), u64::from(e.source.is_solver_failure())]
            .into_iter()
            .chain(text_words(&e.source.to_string()))
            .collect(),
    };
    let all = comm.all_gather_u64(&mine)?;
    let Some((rank, first)) = all
        .iter()
        .enumerate()
        .filter(|(_, b)| b.len() >= 2)
        .min_by_key(|(_, b)| b[0])
    else {
        return local;
    };
    match local {
        Err(e) if rank == comm.rank() => Err(e),
        _ => Err(CellStepError {
            cell: first[0].checked_sub(1).map(|c| c as usize),
            source: TimestepError::Remote {
                rank,
                message: words_text(&first[2..]),
                solver_failure: first[1] != 0,
            },
        }),
    }
}

//! Running a cell scene (`mobo run`): the semi-implicit steps, saved frames and a summary.
//!
//! Writes into the output directory, each file atomically (written, then renamed):
//! * `frames/frame_NNNNN_coefs.npy` (`3 × n_coefs`: x, y, z SH coefficients),
//!   `frames/frame_NNNNN_positions.npy` (`3 × n_points` grid positions),
//!   `frames/frame_NNNNN_tension.npy` (`n_points`), `frames/times.npy` (time of every frame);
//! * `summary.json`: effects built and why, settings, steps, timings, GMRES iterations, area
//!   and volume drift, centroid and its velocity, inclination angle, final time.
//!
//! Any number of cells (coupled through the FMM when there are two or more), shear elasticity
//! (Skalak, explicit, stress-free at the initial shape), the first-order and the BDF2 scheme,
//! a viscosity contrast (with several cells, the double layer of each cell with `λ ≠ 1` is
//! felt by the others through a second, stresslet FMM, with its membrane velocity from the
//! previous step; see [`crate::timestep::coupling`]), a fixed or an adaptive `dt`
//! ([`crate::timestep::adaptive`]: steps whose area/volume error is too large are repeated
//! smaller). Scenes that ask for what is not built are refused with a message
//! that says what is missing.
//!
//! **Over MPI ranks** ([`run_on`]): every rank reads the scene and builds every cell's setup,
//! holds a share of the cells ([`super::cells_partition`]) and steps them
//! ([`Suspension::step_on`]); rank 0 gathers the coefficients and tensions for each frame and
//! every cell's state for each checkpoint and writes the same files as one rank (the memory
//! at rank 0 is that of every cell's state during a checkpoint, `docs/scaling.md`). A
//! checkpoint records the split: resumed on as many ranks it continues bit for bit; on another
//! number it is split afresh and continues to round-off. A failure on any rank (a cell's step,
//! an output file) is returned on every rank; a stop request on any rank stops all after the
//! step, with a checkpoint.

use crate::fmm::gpu_near::NearDecision;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

use super::cells::{CellScene, Effect, Flow, Scheme};
use super::cells_checkpoint::{self, Progress, Split};
use super::cells_partition::{self, Reason};
use super::cells_step::{accepted_step, adaptive_control, flow_origin, step_error};
use crate::comm::{spread, CommError, Communicator, SerialComm};
use crate::io::frames::{CellFrame, FrameFormats, FrameWriter};
use crate::io::{write_atomic, IoError};
use crate::sph_harmonics::{ShTransform, ShWorkspace};
use crate::timestep::cell_preconditioner;
use crate::timestep::cell_state::{CellState, CellStateError};
use crate::timestep::coupling::CouplingParams;
use crate::timestep::semi_implicit::{OperatorStorage, Preconditioning, TimeScheme, VesicleParams};
use crate::timestep::suspension::{agree_cells, CellSetup, CellStepError, Suspension};
use crate::timestep::{GmresParams, TimestepError};
use crate::vesicle::far_side::FarSideParams;
use crate::vesicle::geometry::{Geometry, SurfaceCalculus};
use crate::vesicle::reparam::ReparamParams;
use crate::vesicle::skalak::SkalakParams;
use crate::vesicle::VesicleError;

/// Errors of a cell run.
#[derive(Debug, thiserror::Error)]
pub enum CellRunError {
    /// The step failed (solver, geometry), with the step number and the cell (1-based).
    #[error("step {step} (t = {time}){}: {source}", .cell.map(|c| format!(", cell {c}")).unwrap_or_default())]
    Step {
        /// The step that failed (numbered from 1; 0: building the cells).
        step: usize,
        /// The time the step was to reach.
        time: f64,
        /// The cell that failed, numbered from 1 in scene order (`None`: not one cell's).
        cell: Option<usize>,
        /// What failed.
        source: Box<TimestepError>,
    },
    /// Building a cell failed.
    #[error("{0}")]
    Cell(#[from] VesicleError),
    /// Output could not be written.
    #[error("{0}")]
    Io(#[from] IoError),
    /// A checkpoint does not fit the scene.
    #[error("cannot resume: {0}")]
    Resume(String),
    /// Communication between ranks failed, or another rank failed (its message).
    #[error("{0}")]
    Comm(CommError),
    /// A cell index beyond the scene's cells.
    #[error("no cell {index}: the scene has {cells} cells (indices from 0)")]
    NoSuchCell {
        /// The index asked for.
        index: usize,
        /// Cells in the scene.
        cells: usize,
    },
    /// A cell state gathered from the ranks does not decode.
    #[error("{0}")]
    State(#[from] CellStateError),
}

/// Per-cell observables at the end of the run (`summary.json`'s `per_cell`, in scene order).
#[derive(Clone, Debug, Serialize)]
pub struct CellSummary {
    /// Relative change of the area since the start of the run, `(A − A₀)/A₀` (signed). An
    /// error for an inextensible cell; for a capsule its strain (the area changes physically).
    pub area_drift: f64,
    /// Relative change of the enclosed volume since the start, `(V − V₀)/V₀` (signed).
    pub volume_drift: f64,
    /// Centroid at the end.
    pub centroid: [f64; 3],
    /// Centroid velocity over the last step: its displacement divided by the last `dt` (NaN,
    /// `null` in JSON, when this invocation stopped before the end of the run).
    pub centroid_velocity: [f64; 3],
    /// Inclination in degrees: the angle from the x axis of the cell's long axis (the axis of
    /// its smallest moment of inertia) in the x–y plane, `atan(a_y / a_x)`, in `[−90, 90]`
    /// (in shear, the angle to the flow direction in the shear plane).
    pub inclination_deg: f64,
    /// Taylor deformation `D = (L − B)/(L + B)` of the equivalent ellipsoid in the `x`–`y`
    /// plane ([`crate::vesicle::Geometry::taylor_deformation`] about `z`).
    pub taylor_deformation: f64,
    /// Tank-treading rate: the membrane's mean phase rate about the `z` axis through its
    /// centre in the last step ([`crate::vesicle::Geometry::tank_treading_rate`]), clockwise
    /// seen from `+z` (the sense of the shear `u = (γ̇y, 0, 0)`). For a cell tank-treading
    /// steadily, `2π` over the period of its material points; a rigid sphere in that shear
    /// turns at `γ̇/2`. NaN (`null`) before the first step.
    pub tank_treading_rate: f64,
}

/// What `summary.json` holds. The top-level drifts are the largest over the cells; centroid,
/// velocity and inclination are those of the mean over the cells (of cell 0 for one cell);
/// `per_cell` has every cell's.
#[derive(Clone, Debug, Serialize)]
pub struct CellRunSummary {
    /// Number of cells.
    pub cells: usize,
    /// Spherical-harmonic order `p`.
    pub order: usize,
    /// Quadrature order `q = upsample · p`.
    pub upsampled_order: usize,
    /// The (first) time step.
    pub dt: f64,
    /// Steps taken (accepted steps, all invocations of a resumed run).
    pub steps: usize,
    /// Time reached.
    pub final_time: f64,
    /// Whether the run reached `t_end` (false: stopped early with a checkpoint).
    pub completed: bool,
    /// The adaptive time step's record (`null`: fixed `dt`).
    pub adaptive: Option<AdaptiveSummary>,
    /// The sum over the steps of the area/volume error estimate (the error the steps
    /// committed before the drift correction restored area and volume).
    pub area_volume_error_sum: f64,
    /// Time-integration scheme: `"euler"` or `"bdf2"`.
    pub scheme: &'static str,
    /// GMRES relative residual tolerance.
    pub gmres_tol: f64,
    /// Digits asked of the FMM (`null` for one cell: no FMM).
    pub fmm_digits: Option<u32>,
    /// Where the FMM's near field ran (on rank 0) and why (`null`: no FMM was built).
    pub near_field: Option<NearDecision>,
    /// What the scene builds and why ([`super::cells::effects`], plus `adaptive_dt`).
    pub effects: Vec<Effect>,
    /// Wall seconds of the time loop (setup excluded; all invocations of a resumed run).
    pub wall_s: f64,
    /// Seconds in the steps (solves, coupling, rejected tries; all invocations).
    pub step_s: f64,
    /// Seconds of the coupling on rank 0 in this invocation (quadrature setup, FMM, self
    /// subtraction, ghost exchange, near corrections; part of `step_s`).
    pub coupling_s: f64,
    /// Seconds writing frames and checkpoints, gathers included (all invocations).
    pub output_s: f64,
    /// Threads in all: rayon threads per rank times ranks.
    pub threads: usize,
    /// Throughput: `steps · cells / (step_s · threads)`.
    pub cell_steps_per_core_second: f64,
    /// GMRES iterations per cell and accepted step, averaged over the run.
    pub gmres_iterations_mean: f64,
    /// The most GMRES iterations of one cell's solve in an accepted step.
    pub gmres_iterations_max: usize,
    /// Counters of what was built (checked by the tests: a one-cell scene builds no FMM).
    pub counters: Counters,
    /// The area drift of the cell whose drift is largest in magnitude (signed; see
    /// [`CellSummary::area_drift`]).
    pub area_drift: f64,
    /// The volume drift of the cell whose drift is largest in magnitude (signed).
    pub volume_drift: f64,
    /// Mean of the cells' centroids.
    pub centroid: [f64; 3],
    /// Mean of the cells' centroid velocities.
    pub centroid_velocity: [f64; 3],
    /// Mean of the cells' inclinations, in degrees.
    pub inclination_deg: f64,
    /// Smallest distance between a grid point of one cell and another cell's surface seen in
    /// the run (`null`: no point ever came within a near zone).
    pub min_gap: Option<f64>,
    /// Every cell's observables, in scene order.
    pub per_cell: Vec<CellSummary>,
    /// Frames written, the initial one included.
    pub frames: usize,
    /// How the work was split between MPI ranks (one rank: all of it on rank 0).
    pub split: SplitSummary,
}

/// What the adaptive time step did.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct AdaptiveSummary {
    /// Relative area/volume error allowed over the run.
    pub tolerance: f64,
    /// Smallest step allowed.
    pub dt_min: f64,
    /// Largest step allowed.
    pub dt_max: f64,
    /// Steps rejected (their area/volume error too large, or their solve failed) and repeated
    /// with a smaller `dt`.
    pub rejected_steps: usize,
    /// Steps accepted at `dt_min` although their error exceeded what they may commit.
    pub steps_above_tolerance: usize,
    /// Smallest step taken.
    pub dt_smallest: f64,
    /// Largest step taken.
    pub dt_largest: f64,
    /// Last step taken.
    pub dt_last: f64,
}

/// What the run built and how often (this invocation of a resumed run; `summary.json`'s
/// `counters`).
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Counters {
    /// FMM trees built for the single layer between cells (one per coupling evaluation; 0
    /// for one cell).
    pub fmm_builds: usize,
    /// Point–cell pairs pushed apart by the contact repulsion.
    pub repulsion_points: usize,
    /// Double-layer operators assembled (cells with a viscosity contrast, once per step; in this
    /// invocation).
    pub double_layer_assemblies: usize,
    /// Grid points that received a near-singular correction, summed over the ranks and the
    /// coupling evaluations.
    pub near_points: usize,
    /// Ordered cell pairs (target, source) with near points, summed over the coupling
    /// evaluations.
    pub near_pairs: usize,
    /// Stresslet FMMs built for the inter-cell double layer (several cells, some `λ ≠ 1`: one
    /// per step from the second on; 0 otherwise).
    pub double_layer_fmm_builds: usize,
    /// Cells' own preconditioners built (`[numerics] preconditioner = "cell"`; in this
    /// invocation, those rebuilt from a checkpoint's records included).
    pub preconditioner_builds: usize,
}

/// One cell's observables from its coefficients.
fn observe(
    calc: &mut SurfaceCalculus,
    coefs: &[f64],
) -> Result<([f64; 3], f64, f64, f64), CellRunError> {
    Ok(observe_geometry(&calc.geometry(coefs)?))
}

/// One cell's observables from its geometry: centroid, area, volume, inclination (degrees).
fn observe_geometry(g: &Geometry) -> ([f64; 3], f64, f64, f64) {
    let (_, axes) = g.principal_axes();
    (
        g.centroid(),
        g.area(),
        g.volume(),
        (axes[0][1] / axes[0][0]).atan().to_degrees(),
    )
}

/// How a run is started and when it stops early.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// No progress bar.
    pub quiet: bool,
    /// Continue from `out/checkpoint.bin` (written by an earlier run of the same scene).
    pub resume: bool,
    /// Stop after this many steps of this invocation (with a checkpoint), e.g. to fit a job's
    /// wall-time limit; the run is then continued with `resume`.
    pub max_steps: Option<usize>,
    /// Set (e.g. by a Ctrl-C handler) to stop cleanly after the current step, with a
    /// checkpoint.
    pub stop: Option<Arc<AtomicBool>>,
}

/// The checkpoint file in the output directory.
pub const CHECKPOINT: &str = "checkpoint.bin";
/// The copy of the scene in the output directory (what `--resume` runs).
pub const SCENE_COPY: &str = "scene.toml";

/// The setup of every cell of `scene`, in scene order (the settings `mobo run` uses: drift
/// correction and reparametrisation every step, GMRES restart 200).
pub fn setups(scene: &CellScene) -> Result<Vec<CellSetup>, CellRunError> {
    let p = scene.numerics.order;
    let q = scene.numerics.upsample * p;
    let mut setups = Vec::with_capacity(scene.cells.len());
    for cell in &scene.cells {
        let coefs = cell.surface(p)?.coefs().to_vec();
        let params = VesicleParams {
            bending_modulus: cell.bending_modulus,
            viscosity: scene.viscosity,
            force: cell.force,
            dt: scene.numerics.dt,
            upsampled_order: q,
            gmres: GmresParams {
                tol: scene.numerics.gmres_tol,
                restart: 200,
                max_iters: 5000,
                ..Default::default()
            },
            correct_drift: true,
            // A capsule's elasticity is measured from material points: its grid follows them.
            reparametrize: cell.inextensible.then(|| ReparamParams {
                max_iterations: 10,
                ..Default::default()
            }),
            preconditioner: true,
            scheme: match scene.numerics.scheme {
                Scheme::Euler => TimeScheme::Euler,
                Scheme::Bdf2 => TimeScheme::Bdf2,
            },
            viscosity_ratio: cell.viscosity_ratio,
            inextensible: cell.inextensible,
            elastic_stepping: scene.numerics.elasticity,
        };
        let skalak = (cell.shear_modulus > 0.0).then(|| {
            (
                SkalakParams {
                    shear_modulus: cell.shear_modulus,
                    dilation_ratio: cell.skalak_c,
                    law: cell.elastic_law,
                },
                coefs.clone(),
            )
        });
        setups.push(CellSetup {
            coefs,
            params,
            skalak,
        });
    }
    Ok(setups)
}

/// The coupling settings of `scene` (the contact repulsion's strength, when the scene leaves
/// it out, from the cells' bending, the flow and the forces).
fn coupling_params(scene: &CellScene) -> CouplingParams {
    let rate = match scene.flow {
        Flow::None => 0.0,
        Flow::Shear { rate } | Flow::Extensional { rate, .. } => rate.abs(),
        Flow::Poiseuille { speed, radius } => (speed / radius).abs(),
    };
    let auto_strength = scene
        .cells
        .iter()
        .map(|c| {
            let r = c.radius;
            let f = c.force.iter().map(|v| v * v).sum::<f64>().sqrt();
            (c.bending_modulus / r.powi(3))
                .max(scene.viscosity * rate)
                .max(f / (4.0 * std::f64::consts::PI * r * r))
        })
        .fold(0.0, f64::max)
        * 10.0;
    CouplingParams {
        viscosity: scene.viscosity,
        fmm_digits: scene.numerics.fmm_digits,
        repulsion_range: scene.numerics.repulsion_range,
        repulsion_strength: scene.numerics.repulsion_strength.unwrap_or(auto_strength),
        gpu: scene.numerics.gpu,
        ..Default::default()
    }
}

/// The cells of `scene` as a [`Suspension`] ready to step (the settings `mobo run` uses:
/// drift correction and reparametrisation every step, GMRES restart 200). Library users and
/// studies (`mobo report`) step it themselves.
pub fn build(scene: &CellScene) -> Result<Suspension, CellRunError> {
    let setups = setups(scene)?;
    let all = (0..setups.len()).collect::<Vec<_>>();
    build_part(scene, &setups, &all)
}

/// One rank's share of the cells of `scene`: the cells `ids` (global indices) of `setups`
/// (every cell's, from [`setups`]).
pub fn build_part(
    scene: &CellScene,
    setups: &[CellSetup],
    ids: &[usize],
) -> Result<Suspension, CellRunError> {
    let p = scene.numerics.order;
    let q = scene.numerics.upsample * p;
    let contrast = scene.cells.iter().any(|c| c.viscosity_ratio != 1.0);
    let cells = ids.iter().map(|&i| (i, setups[i].clone())).collect();
    let mut susp = Suspension::new_part(
        p,
        q.max(p),
        cells,
        setups.len(),
        contrast,
        coupling_params(scene),
    )
    .map_err(|e| step_error(0, 0.0, e))?;
    // Chosen for all cells alike (the memory of the whole scene), so that the split between
    // ranks does not change how a cell is stepped.
    let (storage, preconditioning) = memory_plan(scene, setups.len(), contrast);
    susp.set_operator_storage(storage);
    susp.set_preconditioning(preconditioning);
    if !scene.numerics.far_side_split {
        let off = FarSideParams {
            enabled: false,
            ..FarSideParams::default()
        };
        susp.set_far_side_params(off)
            .map_err(|e| step_error(0, 0.0, e))?;
    }
    Ok(susp)
}

/// The scene's effects, and the cells' own preconditioners where [`memory_plan`] left them
/// out.
fn run_effects(scene: &CellScene, susp: &Suspension) -> Vec<Effect> {
    let mut effects = scene.effects.clone();
    if let (Preconditioning::Cell { .. }, Some(Preconditioning::Sphere)) =
        (scene.numerics.preconditioning, susp.preconditioning())
    {
        let (cells, p) = (scene.cells.len(), scene.numerics.order);
        let bytes = cells as f64 * cell_preconditioner::bytes_per_cell(p) as f64;
        let reason = if susp.operator_storage() == Some(OperatorStorage::MatrixFree) {
            "matrix-free operators keep the sphere's preconditioner".to_string()
        } else {
            format!(
                "the own preconditioners of {cells} cells at p = {p} need {:.1} GB, more than \
                 60 % of the available memory allows beside the operators: every cell takes \
                 the sphere's",
                bytes / 1e9
            )
        };
        effects.push(Effect {
            name: "cell_preconditioner",
            enabled: false,
            reason,
        });
    }
    effects
}

/// Where the cells' operators and preconditioners are kept, within 60 % of the available
/// memory (8 GiB where it is unknown): the scene's choices, except where they do not fit.
/// The cells' own preconditioners ((4 n_c)² doubles each, 3.6 MB at `p = 12`) are kept per
/// cell; where those of all cells do not fit, or leave room only for matrix-free operators
/// (which do without them), every cell takes the sphere's (shared by the cells of one size;
/// the summary says so). Then the fastest operator storage that fits what is left
/// ([`OperatorStorage::for_budget`]: the grid wherever the threads can hold its operators).
fn memory_plan(
    scene: &CellScene,
    cells: usize,
    contrast: bool,
) -> (OperatorStorage, Preconditioning) {
    let p = scene.numerics.order;
    let budget = available_memory().map_or(8 << 30, |m| m / 10 * 6);
    let threads = rayon::current_num_threads();
    let auto =
        |budget| OperatorStorage::for_budget(cells, threads, p, 1 + usize::from(contrast), budget);
    let own = cells as u64 * cell_preconditioner::bytes_per_cell(p) as u64;
    if let Preconditioning::Cell { .. } = scene.numerics.preconditioning {
        // The own preconditioners first; matrix-free operators would drop them anyway.
        if own <= budget {
            let storage = scene
                .numerics
                .operator_storage
                .unwrap_or_else(|| auto(budget - own));
            if storage != OperatorStorage::MatrixFree {
                return (storage, scene.numerics.preconditioning);
            }
        }
    }
    let storage = scene
        .numerics
        .operator_storage
        .unwrap_or_else(|| auto(budget));
    (storage, Preconditioning::Sphere)
}

/// [`crate::comm::agreed`] with communication failures as [`CellRunError::Comm`].
fn agreed<T>(comm: &dyn Communicator, local: Result<T, CellRunError>) -> Result<T, CellRunError> {
    crate::comm::agreed(comm, local, CellRunError::Comm)
}

/// Every cell's `width` values from `local` (`(global index, values)`), in global order, at
/// rank 0 (`None` on the others).
fn gather_rows(
    comm: &dyn Communicator,
    local: Vec<(usize, Vec<f64>)>,
    n_global: usize,
    width: usize,
) -> Result<Option<Vec<Vec<f64>>>, CellRunError> {
    let mut buf = Vec::with_capacity(local.len() * (width + 1));
    for (id, v) in local {
        buf.push(id as f64);
        buf.extend_from_slice(&v);
    }
    let all = comm.gather_f64(&buf, 0).map_err(CellRunError::Comm)?;
    if comm.rank() != 0 {
        return Ok(None);
    }
    let mut rows = vec![Vec::new(); n_global];
    for rec in all.iter().flat_map(|b| b.chunks_exact(width + 1)) {
        rows[rec[0] as usize] = rec[1..].to_vec();
    }
    Ok(Some(rows))
}

/// Every cell's state at rank 0, global order (`None` on the others).
fn gather_states(
    comm: &dyn Communicator,
    susp: &Suspension,
    ncoef: usize,
    n: usize,
) -> Result<Option<Vec<CellState>>, CellRunError> {
    let width = CellState::encoded_len(ncoef, n);
    let local = (0..susp.len())
        .map(|i| {
            let mut v = Vec::with_capacity(width);
            susp.cell_state(i).encode(&mut v);
            (susp.ids()[i], v)
        })
        .collect();
    let Some(rows) = gather_rows(comm, local, susp.n_global(), width)? else {
        return Ok(None);
    };
    rows.iter()
        .map(|r| CellState::decode(r, ncoef, n).map_err(CellRunError::from))
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}

/// Write frame `frames.times().len()` at `time` from every cell's coefficients and tension
/// (global order).
fn write_frame(
    frames: &mut FrameWriter,
    cells: &[(Vec<f64>, Vec<f64>)],
    sht: &ShTransform,
    ws: &mut ShWorkspace,
    time: f64,
) -> Result<(), CellRunError> {
    let n = sht.n_points();
    let mut x = vec![0.0; 3 * n * cells.len()];
    for (i, (c, _)) in cells.iter().enumerate() {
        sht.inverse(c, &mut x[3 * n * i..3 * n * (i + 1)], ws)
            .map_err(VesicleError::from)?;
    }
    let frame: Vec<CellFrame<'_>> = cells
        .iter()
        .enumerate()
        .map(|(i, (c, sigma))| CellFrame {
            order: sht.order(),
            coefs: c,
            positions: &x[3 * n * i..3 * n * (i + 1)],
            tension: sigma,
        })
        .collect();
    let index = frames.times().len();
    frames.write_frame(index, time, &frame)?;
    Ok(())
}

/// Gather the coefficients and tensions and write a frame at rank 0 (collective; an output
/// failure is returned on every rank).
fn gathered_frame(
    comm: &dyn Communicator,
    susp: &Suspension,
    frames: Option<&mut FrameWriter>,
    sht: &ShTransform,
    ws: &mut ShWorkspace,
    time: f64,
) -> Result<(), CellRunError> {
    let (ncoef, n) = (sht.n_coefs() * 3, sht.n_points());
    let local = susp
        .ids()
        .iter()
        .zip(susp.coefs())
        .zip(susp.steppers())
        .map(|((&id, c), st)| (id, c.iter().chain(&st.sigma).copied().collect()))
        .collect();
    let rows = gather_rows(comm, local, susp.n_global(), ncoef + n)?;
    let written = match (rows, frames) {
        (Some(rows), Some(frames)) => {
            let cells: Vec<(Vec<f64>, Vec<f64>)> = rows
                .into_iter()
                .map(|mut r| {
                    let sigma = r.split_off(ncoef);
                    (r, sigma)
                })
                .collect();
            write_frame(frames, &cells, sht, ws, time)
        }
        _ => Ok(()),
    };
    agreed(comm, written)
}

/// How the run's work was split between ranks (`summary.json`'s `split`).
#[derive(Clone, Debug, Default, Serialize)]
pub struct SplitSummary {
    /// Number of MPI ranks.
    pub ranks: usize,
    /// Cells per rank at the end: smallest, mean, largest.
    pub cells_per_rank: [f64; 3],
    /// Seconds per rank in this invocation, largest and mean over the ranks: the per-cell
    /// work (tractions and solves, not waiting for other ranks; with re-balanced cells, its
    /// spread is the imbalance), the coupling (FMM, quadrature setup, self subtraction, ghost exchange, near
    /// corrections), output (gathers and writing), re-balancing (gathering centres, moving
    /// cells).
    pub solve_s: [f64; 2],
    /// Seconds of the coupling (all its parts), largest and mean.
    pub coupling_s: [f64; 2],
    /// Seconds in the FMM (build and evaluation), largest and mean; part of `coupling_s`.
    pub fmm_s: [f64; 2],
    /// Seconds exchanging ghost cells, largest and mean; part of `coupling_s`.
    pub ghost_exchange_s: [f64; 2],
    /// Seconds of the near-singular corrections, largest and mean; part of `coupling_s`.
    pub near_s: [f64; 2],
    /// Seconds of output (gathers and writing), largest and mean.
    pub output_s: [f64; 2],
    /// Seconds re-balancing (gathering centres, moving cells), largest and mean.
    pub rebalance_s: [f64; 2],
    /// Bytes a rank sent per step (largest and mean over ranks): in the FMM, of ghost cells,
    /// of moving cells.
    pub fmm_bytes_per_step: [f64; 2],
    /// Bytes of ghost cells a rank sent per step, largest and mean.
    pub ghost_bytes_per_step: [f64; 2],
    /// Bytes of moving cells a rank sent per step, largest and mean.
    pub migration_bytes_per_step: [f64; 2],
    /// Ghost cells a rank received per step (largest and mean).
    pub ghost_cells_per_step: [f64; 2],
    /// Imbalance of the solve time at the end: largest over mean, minus 1.
    pub solve_imbalance: f64,
    /// The re-balances of this invocation.
    pub rebalances: Vec<Rebalance>,
}

/// One re-balance: when, why, and what it did.
#[derive(Clone, Debug, Serialize)]
pub struct Rebalance {
    /// Taken before this step.
    pub step: usize,
    /// Why the cells were moved (JSON `"imbalance"` or `"locality"`).
    pub reason: Reason,
    /// Cost imbalance before (largest rank over mean, minus 1).
    pub imbalance_before: f64,
    /// Cost imbalance after, of the fresh split.
    pub imbalance_after: f64,
    /// Fraction of the cells the fresh split put on another rank.
    pub stale_fraction: f64,
    /// Cells moved to another rank.
    pub cells_moved: usize,
}

/// Per-rank counters of one invocation.
#[derive(Clone, Copy, Debug, Default)]
struct RankClock {
    output_s: f64,
    rebalance_s: f64,
    migration_bytes: u64,
}

/// Check the split (every `every` steps, after step `step`) and move the cells when it went
/// stale (collective).
#[allow(clippy::too_many_arguments)]
fn rebalance(
    comm: &dyn Communicator,
    susp: &mut Suspension,
    p: usize,
    setups: &[CellSetup],
    owners: &mut Vec<usize>,
    (step, every, max_imbalance): (usize, usize, f64),
    clock: &mut RankClock,
    log: &mut Vec<Rebalance>,
) -> Result<(), CellRunError> {
    let k = comm.size();
    if k == 1 || step % every != 0 {
        return Ok(());
    }
    let t = Instant::now();
    let (centres, costs) =
        cells_partition::gather_inputs(comm, susp).map_err(CellRunError::Comm)?;
    let fresh = cells_partition::split(&centres, &costs, k);
    let before = cells_partition::imbalance(owners, &costs, k);
    let stale = owners.iter().zip(&fresh).filter(|(a, b)| a != b).count();
    let stale_fraction = stale as f64 / owners.len().max(1) as f64;
    let reason = if stale == 0 {
        None
    } else if before > max_imbalance {
        Some(Reason::Imbalance)
    } else if stale_fraction > cells_partition::MAX_STALE {
        Some(Reason::Locality)
    } else {
        None
    };
    if let Some(reason) = reason {
        let bytes = cells_partition::migrate(comm, susp, p, setups, &fresh)
            .map_err(|e| step_error(step + 1, f64::NAN, e))?;
        clock.migration_bytes += bytes;
        log.push(Rebalance {
            step: step + 1,
            reason,
            imbalance_before: before,
            imbalance_after: cells_partition::imbalance(&fresh, &costs, k),
            stale_fraction,
            cells_moved: stale,
        });
        *owners = fresh;
    }
    clock.rebalance_s += t.elapsed().as_secs_f64();
    Ok(())
}

/// Run `scene` (whose text is `scene_text`), writing into `out`, on one process.
pub fn run(
    scene: &CellScene,
    scene_text: &str,
    out: &Path,
    options: &RunOptions,
) -> Result<CellRunSummary, CellRunError> {
    Ok(run_on(&SerialComm, scene, scene_text, out, options)?
        .expect("rank 0 of one rank has the summary"))
}

/// [`run`] over the ranks of `comm` (collective: every rank calls it with the same scene).
/// The cells are split between the ranks ([`cells_partition`]); rank 0 gathers what is
/// written (frames, checkpoints, the summary, all the same files as on one rank) and returns
/// the summary; the other ranks return `None`. A failure is returned on every rank.
pub fn run_on(
    comm: &dyn Communicator,
    scene: &CellScene,
    scene_text: &str,
    out: &Path,
    options: &RunOptions,
) -> Result<Option<CellRunSummary>, CellRunError> {
    let p = scene.numerics.order;
    let q = scene.numerics.upsample * p;
    let dt = scene.numerics.dt;
    let steps = (scene.numerics.t_end / dt).round().max(1.0) as usize;
    let (k_ranks, root) = (comm.size(), comm.rank() == 0);
    let nc = scene.cells.len();
    let setups = setups(scene)?;
    let sht = ShTransform::new(p).map_err(VesicleError::from)?;
    let mut ws = sht.workspace();
    let (ncoef, n) = (3 * sht.n_coefs(), sht.n_points());
    let double_layer = nc > 1 && scene.cells.iter().any(|c| c.viscosity_ratio != 1.0);
    let mut calc = SurfaceCalculus::new(p)?;
    // Where the run starts: the scene, or the checkpoint (read by every rank).
    let resumed = if options.resume {
        let loaded = cells_checkpoint::load(out, nc, ncoef, n, double_layer);
        Some(agreed(comm, loaded)?)
    } else {
        None
    };
    let mut owners = match &resumed {
        Some((_, _, Some(split))) if split.ranks == k_ranks => split.owners.clone(),
        Some((_, states, _)) => {
            let centres: Vec<_> = states
                .iter()
                .map(|s| cells_partition::centre(&s.coefs))
                .collect();
            let costs: Vec<_> = states
                .iter()
                .map(|s| cells_partition::cost(s.iterations))
                .collect();
            cells_partition::split(&centres, &costs, k_ranks)
        }
        None => {
            let centres: Vec<_> = setups
                .iter()
                .map(|s| cells_partition::centre(&s.coefs))
                .collect();
            cells_partition::split(&centres, &vec![cells_partition::cost(0); nc], k_ranks)
        }
    };
    let mine: Vec<usize> = (0..nc).filter(|&i| owners[i] == comm.rank()).collect();
    let mut susp = agreed(comm, build_part(scene, &setups, &mine))?;
    let formats = FrameFormats {
        npy: scene.output.npy,
        hdf5: scene.output.hdf5,
        vtp: scene.output.vtk,
    };
    let (mut prog, mut frames) = match resumed {
        Some((prog, states, _)) => {
            let restored = (0..susp.len()).try_for_each(|i| {
                let id = susp.ids()[i];
                susp.set_cell_state(i, &states[id]).map_err(|e| {
                    CellRunError::Resume(format!(
                        "{}: cell {}: {}",
                        out.join(CHECKPOINT).display(),
                        id + 1,
                        e.source
                    ))
                })
            });
            agreed(comm, restored)?;
            let frames = root
                .then(|| FrameWriter::resume(out, formats, &prog.frame_times))
                .transpose()
                .map_err(CellRunError::from);
            (prog, agreed(comm, frames)?)
        }
        None => {
            let mut prog = Progress::start(dt);
            let t0 = Instant::now();
            let opened = if root {
                (|| -> Result<_, CellRunError> {
                    for s in &setups {
                        let (x, a, v, inc) = observe(&mut calc, &s.coefs)?;
                        prog.start_obs.push([x[0], x[1], x[2], a, v, inc]);
                    }
                    write_atomic(&out.join(SCENE_COPY), scene_text.as_bytes())?;
                    Ok(Some(FrameWriter::new(out, formats)?))
                })()
            } else {
                Ok(None)
            };
            let mut frames = agreed(comm, opened)?;
            gathered_frame(comm, &susp, frames.as_mut(), &sht, &mut ws, 0.0)?;
            prog.output_s += t0.elapsed().as_secs_f64();
            if let Some(f) = &frames {
                prog.frame_times = f.times().to_vec();
            }
            (prog, frames)
        }
    };
    let adaptive = adaptive_control(scene)?;
    if adaptive.is_some() {
        // A resumed adaptive run continues with the step it had chosen.
        susp.set_dt(prog.dt)
            .map_err(|e| step_error(prog.step, prog.time, e))?;
    }
    let bar = progress_bar(
        options.quiet || !root,
        adaptive.is_some(),
        steps,
        &prog,
        scene,
    );
    let flow = scene.flow;
    let start = Instant::now();
    let wall0 = prog.wall_s;
    // Centres of this rank's cells before the last step (global index, centre).
    let mut before_last: Vec<(usize, [f64; 3])> = Vec::new();
    let first = prog.step + 1;
    let mut stopped = false;
    let mut k = prog.step;
    let mut clock = RankClock::default();
    let mut log = Vec::new();
    // Double-layer assemblies and own-preconditioner builds of cells that left this rank
    // (their steppers went with them).
    let mut left = [0usize; 2];
    let counts = |s: &Suspension| {
        s.steppers().iter().fold([0usize; 2], |[d, b], s| {
            [
                d + s.double_layer_assemblies,
                b + s.own_preconditioner_builds,
            ]
        })
    };
    // The run ends at t_end up to round-off in the sum of adaptive steps.
    let t_done = scene.numerics.t_end * (1.0 - 1e-12);
    // Whether step `k`, reaching time `t`, ends the run.
    let ends_run = |k: usize, t: f64| match &adaptive {
        None => k >= steps,
        Some(_) => t >= t_done,
    };
    loop {
        if ends_run(k, prog.time) {
            break;
        }
        let held = counts(&susp);
        rebalance(
            comm,
            &mut susp,
            p,
            &setups,
            &mut owners,
            (
                k,
                scene.numerics.rebalance_every,
                scene.numerics.max_imbalance,
            ),
            &mut clock,
            &mut log,
        )?;
        let kept = counts(&susp);
        for ((l, h), k) in left.iter_mut().zip(held).zip(kept) {
            *l += h - k.min(h);
        }
        k += 1;
        let dt_try = match &adaptive {
            None => dt,
            Some(_) => prog.dt.min(scene.numerics.t_end - prog.time),
        };
        if ends_run(k, prog.time + dt_try) {
            before_last.clear();
            for (&id, c) in susp.ids().iter().zip(susp.coefs()) {
                before_last.push((id, observe(&mut calc, c)?.0));
            }
        }
        let t = Instant::now();
        let origin = flow_origin(comm, &susp, &flow)?;
        let acc = accepted_step(
            comm,
            &mut susp,
            &|x| flow.velocity_about(x, origin),
            &[],
            (k, prog.time, scene.numerics.t_end),
            dt_try,
            adaptive.as_ref(),
        )?;
        prog.rejected += acc.rejected;
        prog.error_sum += acc.error;
        if acc.above_tolerance {
            prog.above_tolerance += 1;
        }
        if let Some(next) = acc.next_dt {
            prog.dt = next;
        }
        let (report, dt_try) = (acc.report, acc.dt);
        prog.step_s += t.elapsed().as_secs_f64();
        prog.time = match &adaptive {
            None => k as f64 * dt,
            Some(_) => prog.time + dt_try,
        };
        prog.last_dt = dt_try;
        prog.dt_used[0] = prog.dt_used[0].min(dt_try);
        prog.dt_used[1] = prog.dt_used[1].max(dt_try);
        let finite = susp
            .ids()
            .iter()
            .zip(susp.coefs())
            .find_map(|(&id, c)| Some((id, c.iter().position(|c| !c.is_finite())?)))
            .map_or(Ok(()), |(id, j)| {
                Err(CellStepError {
                    cell: Some(id),
                    source: TimestepError::Vesicle(format!(
                        "non-finite coefficient {j} after the step (the last checkpoint, \
                         step {}, is kept)",
                        prog.step
                    )),
                })
            });
        agree_cells(comm, finite).map_err(|e| step_error(k, prog.time, e))?;
        let its = report.cells.iter().map(|r| r.gmres.iterations);
        let mut it = [its.clone().max().unwrap_or(0) as f64];
        let mut it_sum = [its.sum::<usize>() as u64];
        comm.all_max(&mut it).map_err(CellRunError::Comm)?;
        comm.all_sum_u64(&mut it_sum).map_err(CellRunError::Comm)?;
        let it = it[0] as usize;
        prog.iters_sum += it_sum[0] as usize;
        prog.iters_max = prog.iters_max.max(it);
        if let Some(st) = susp.coupling_stats() {
            prog.min_gap = prog.min_gap.min(st.min_gap);
        }
        match &adaptive {
            None => {
                bar.set_message(format!("t {:.3} dt {dt} gmres {it}", prog.time));
                bar.set_position(k as u64);
            }
            Some(_) => {
                bar.set_message(format!(
                    "step {k} t {:.3} dt {:.3e} gmres {it} rejected {}",
                    prog.time, dt_try, prog.rejected
                ));
                bar.set_position((1000.0 * prog.time / scene.numerics.t_end) as u64);
            }
        }
        prog.step = k;
        // A Ctrl-C (or SIGTERM from mpirun) on any rank stops every rank after this step.
        let mut interrupted = [f64::from(u8::from(
            options
                .stop
                .as_ref()
                .is_some_and(|s| s.load(Ordering::Relaxed)),
        ))];
        comm.all_max(&mut interrupted).map_err(CellRunError::Comm)?;
        let interrupted = interrupted[0] > 0.0;
        let limited = options.max_steps.is_some_and(|m| k + 1 - first >= m);
        let last = ends_run(k, prog.time);
        stopped = !last && (interrupted || limited);
        let t0 = Instant::now();
        if last || (k as u64).is_multiple_of(scene.output_every) {
            gathered_frame(comm, &susp, frames.as_mut(), &sht, &mut ws, prog.time)?;
            if let Some(f) = &frames {
                prog.frame_times = f.times().to_vec();
            }
        }
        if stopped || last || (k as u64).is_multiple_of(scene.output.checkpoint_every) {
            prog.wall_s = wall0 + start.elapsed().as_secs_f64();
            let states = gather_states(comm, &susp, ncoef, n)?;
            let saved = match states {
                Some(states) => cells_checkpoint::save(
                    out,
                    &states,
                    &prog,
                    &Split {
                        ranks: k_ranks,
                        owners: owners.clone(),
                    },
                    double_layer,
                ),
                None => Ok(()),
            };
            agreed(comm, saved)?;
        }
        let spent = t0.elapsed().as_secs_f64();
        prog.output_s += spent;
        clock.output_s += spent;
        if stopped {
            break;
        }
    }
    bar.finish_and_clear();
    if !stopped {
        let finished = frames.take().map_or(Ok(()), |f| f.finish());
        agreed(comm, finished.map_err(CellRunError::from))?;
    }
    prog.wall_s = wall0 + start.elapsed().as_secs_f64();
    // Per cell: centre, area, volume, inclination, the centre before the last step, the
    // Taylor deformation and the tank-treading rate.
    let local = (0..susp.len())
        .map(|i| -> Result<(usize, Vec<f64>), CellRunError> {
            let id = susp.ids()[i];
            let g = calc.geometry(&susp.coefs()[i])?;
            let (x, a, v, inc) = observe_geometry(&g);
            let d = g.taylor_deformation([0.0, 0.0, 1.0]);
            let tt = susp.steppers()[i]
                .velocity()
                .map(|u| g.tank_treading_rate(u, [0.0, 0.0, -1.0]))
                .transpose()?
                .unwrap_or(f64::NAN);
            let b = before_last
                .iter()
                .find(|(j, _)| *j == id)
                .map_or([f64::NAN; 3], |(_, b)| *b);
            Ok((
                id,
                vec![x[0], x[1], x[2], a, v, inc, b[0], b[1], b[2], d, tt],
            ))
        })
        .collect::<Result<Vec<_>, _>>();
    let local = agreed(comm, local)?;
    let rows = gather_rows(comm, local, nc, 11)?;
    let split = split_summary(comm, &susp, &clock, &log, k + 1 - first)?;
    let stats = susp.coupling_stats().unwrap_or_default();
    let now = counts(&susp);
    let mut dl = [(left[0] + now[0]) as u64, (left[1] + now[1]) as u64];
    comm.all_sum_u64(&mut dl).map_err(CellRunError::Comm)?;
    let Some(rows) = rows else {
        return Ok(None);
    };
    let mut per_cell = Vec::with_capacity(nc);
    for (i, r) in rows.iter().enumerate() {
        let s0 = prog.start_obs[i];
        let centroid = [r[0], r[1], r[2]];
        per_cell.push(CellSummary {
            area_drift: (r[3] - s0[3]) / s0[3],
            volume_drift: (r[4] - s0[4]) / s0[4],
            centroid,
            centroid_velocity: std::array::from_fn(|d| (centroid[d] - r[6 + d]) / prog.last_dt),
            inclination_deg: r[5],
            taylor_deformation: r[9],
            tank_treading_rate: r[10],
        });
    }
    let worst = |f: fn(&CellSummary) -> f64| {
        per_cell
            .iter()
            .map(f)
            .fold(0.0, |a: f64, b| if b.abs() > a.abs() { b } else { a })
    };
    let mean3 = |f: fn(&CellSummary) -> [f64; 3]| {
        let mut m = [0.0; 3];
        for c in &per_cell {
            for (md, v) in m.iter_mut().zip(f(c)) {
                *md += v / nc as f64;
            }
        }
        m
    };
    let threads = rayon::current_num_threads() * k_ranks;
    let done = prog.step;
    let summary = CellRunSummary {
        cells: nc,
        order: p,
        upsampled_order: q,
        dt,
        steps: done,
        final_time: prog.time,
        completed: ends_run(done, prog.time),
        adaptive: adaptive.map(|a| AdaptiveSummary {
            tolerance: a.tolerance,
            dt_min: a.dt_min,
            dt_max: a.dt_max,
            rejected_steps: prog.rejected,
            steps_above_tolerance: prog.above_tolerance,
            dt_smallest: prog.dt_used[0],
            dt_largest: prog.dt_used[1],
            dt_last: prog.last_dt,
        }),
        area_volume_error_sum: prog.error_sum,
        scheme: match scene.numerics.scheme {
            Scheme::Euler => "euler",
            Scheme::Bdf2 => "bdf2",
        },
        gmres_tol: scene.numerics.gmres_tol,
        fmm_digits: (nc > 1).then_some(scene.numerics.fmm_digits),
        near_field: susp.near_field_decision(),
        effects: run_effects(scene, &susp),
        wall_s: prog.wall_s,
        step_s: prog.step_s,
        coupling_s: stats.setup_s + stats.fmm_s + stats.self_s + stats.exchange_s + stats.near_s,
        output_s: prog.output_s,
        threads,
        cell_steps_per_core_second: (done * nc) as f64 / (prog.step_s * threads as f64).max(1e-12),
        gmres_iterations_mean: prog.iters_sum as f64 / (done * nc).max(1) as f64,
        gmres_iterations_max: prog.iters_max,
        counters: Counters {
            fmm_builds: stats.fmm_builds,
            repulsion_points: stats.repulsion_points,
            double_layer_assemblies: dl[0] as usize,
            preconditioner_builds: dl[1] as usize,
            near_points: stats.near_points,
            near_pairs: stats.near_pairs,
            double_layer_fmm_builds: stats.double_layer_fmm_builds,
        },
        area_drift: worst(|c| c.area_drift),
        volume_drift: worst(|c| c.volume_drift),
        centroid: mean3(|c| c.centroid),
        centroid_velocity: mean3(|c| c.centroid_velocity),
        inclination_deg: if nc == 1 {
            per_cell[0].inclination_deg
        } else {
            per_cell.iter().map(|c| c.inclination_deg).sum::<f64>() / nc as f64
        },
        min_gap: prog.min_gap.is_finite().then_some(prog.min_gap),
        per_cell,
        frames: prog.frame_times.len(),
        split,
    };
    let json = serde_json::to_string_pretty(&summary).expect("summary serialises");
    write_atomic(&out.join("summary.json"), json.as_bytes())?;
    Ok(Some(summary))
}

/// The progress bar (hidden when `hidden`).
fn progress_bar(
    hidden: bool,
    adaptive: bool,
    steps: usize,
    prog: &Progress,
    scene: &CellScene,
) -> ProgressBar {
    if hidden {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new(if adaptive { 1000 } else { steps as u64 });
    b.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] step {pos}/{len} {msg} ETA {eta}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    b.set_position(if adaptive {
        (1000.0 * prog.time / scene.numerics.t_end) as u64
    } else {
        prog.step as u64
    });
    b
}

/// The ranks' clocks and counters, gathered and summarised (collective; the summary is
/// meaningful on rank 0).
fn split_summary(
    comm: &dyn Communicator,
    susp: &Suspension,
    clock: &RankClock,
    log: &[Rebalance],
    steps: usize,
) -> Result<SplitSummary, CellRunError> {
    let st = susp.coupling_stats().unwrap_or_default();
    let coupling = st.setup_s + st.fmm_s + st.self_s + st.exchange_s + st.near_s;
    let per_step = |v: f64| v / steps.max(1) as f64;
    let mine = [
        susp.len() as f64,
        susp.solve_seconds(),
        coupling,
        st.fmm_s,
        st.exchange_s,
        st.near_s,
        clock.output_s,
        clock.rebalance_s,
        per_step(st.fmm_bytes as f64),
        per_step(st.ghost_bytes as f64),
        per_step(clock.migration_bytes as f64),
        per_step(st.ghost_cells as f64),
    ];
    let s = spread(comm, &mine).map_err(CellRunError::Comm)?;
    let max_mean = |j: usize| [s[j].max, s[j].mean];
    let solve = max_mean(1);
    Ok(SplitSummary {
        ranks: comm.size(),
        cells_per_rank: [s[0].min, s[0].mean, s[0].max],
        solve_s: solve,
        coupling_s: max_mean(2),
        fmm_s: max_mean(3),
        ghost_exchange_s: max_mean(4),
        near_s: max_mean(5),
        output_s: max_mean(6),
        rebalance_s: max_mean(7),
        fmm_bytes_per_step: max_mean(8),
        ghost_bytes_per_step: max_mean(9),
        migration_bytes_per_step: max_mean(10),
        ghost_cells_per_step: max_mean(11),
        solve_imbalance: if solve[1] > 0.0 {
            solve[0] / solve[1] - 1.0
        } else {
            0.0
        },
        rebalances: log.to_vec(),
    })
}

/// The built-in demo scene of `mobo run` without a scene file: one red blood cell in simple
/// shear (about half a minute on 2 cores).
pub const DEMO_SCENE: &str = r#"
[fluid]
viscosity = 1.0

[flow]
kind = "shear"
rate = 1.0

[[cells]]
shape = "rbc"
radius = 1.0
bending_modulus = 0.1
orientation = [0, 0, 1, 30]

[numerics]
order = 8
dt = 0.05
t_end = 10.0
gmres_tol = 1e-8

[output]
every = 20
"#;

/// `MemAvailable` of `/proc/meminfo` in bytes (`None` where there is none).
fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

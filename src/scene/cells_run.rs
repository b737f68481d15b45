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

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

use super::cells::{CellScene, Effect, Flow, Scheme};
use crate::io::checkpoint::Checkpoint;
use crate::io::frames::{CellFrame, FrameFormats, FrameWriter};
use crate::io::{write_atomic, IoError};
use crate::sph_harmonics::{ShTransform, ShWorkspace};
use crate::timestep::adaptive::AdaptiveDt;
use crate::timestep::coupling::CouplingParams;
use crate::timestep::semi_implicit::{OperatorStorage, TimeScheme, VesicleParams};
use crate::timestep::suspension::{CellSetup, CellStepError, Suspension};
use crate::timestep::{GmresParams, TimestepError};
use crate::vesicle::far_side::FarSideParams;
use crate::vesicle::geometry::SurfaceCalculus;
use crate::vesicle::reparam::ReparamParams;
use crate::vesicle::skalak::SkalakParams;
use crate::vesicle::VesicleError;

/// Errors of a cell run.
#[derive(Debug, thiserror::Error)]
pub enum CellRunError {
    /// The step failed (solver, geometry), with the step number and the cell (1-based).
    #[error("step {step} (t = {time}){}: {source}", .cell.map(|c| format!(", cell {c}")).unwrap_or_default())]
    Step {
        step: usize,
        time: f64,
        cell: Option<usize>,
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
}

/// Per-cell observables at the end of the run.
#[derive(Clone, Debug, Serialize)]
pub struct CellSummary {
    pub area_drift: f64,
    pub volume_drift: f64,
    pub centroid: [f64; 3],
    pub centroid_velocity: [f64; 3],
    pub inclination_deg: f64,
}

/// What `summary.json` holds. The top-level drifts are the largest over the cells; centroid,
/// velocity and inclination are those of the mean over the cells (of cell 0 for one cell);
/// `per_cell` has every cell's.
#[derive(Clone, Debug, Serialize)]
pub struct CellRunSummary {
    pub cells: usize,
    pub order: usize,
    pub upsampled_order: usize,
    /// The (first) time step.
    pub dt: f64,
    pub steps: usize,
    pub final_time: f64,
    /// Whether the run reached `t_end` (false: stopped early with a checkpoint).
    pub completed: bool,
    /// The adaptive time step's record (`null`: fixed `dt`).
    pub adaptive: Option<AdaptiveSummary>,
    /// The sum over the steps of the area/volume error estimate (the error the steps
    /// committed before the drift correction restored area and volume).
    pub area_volume_error_sum: f64,
    pub scheme: &'static str,
    pub gmres_tol: f64,
    pub fmm_digits: Option<u32>,
    pub effects: Vec<Effect>,
    pub wall_s: f64,
    pub step_s: f64,
    pub coupling_s: f64,
    pub output_s: f64,
    pub threads: usize,
    pub cell_steps_per_core_second: f64,
    pub gmres_iterations_mean: f64,
    pub gmres_iterations_max: usize,
    /// Counters of what was built (checked by the tests: a one-cell scene builds no FMM).
    pub counters: Counters,
    pub area_drift: f64,
    pub volume_drift: f64,
    pub centroid: [f64; 3],
    pub centroid_velocity: [f64; 3],
    pub inclination_deg: f64,
    /// Smallest distance between a grid point of one cell and another cell's surface seen in
    /// the run (`null`: no point ever came within a near zone).
    pub min_gap: Option<f64>,
    pub per_cell: Vec<CellSummary>,
    pub frames: usize,
}

/// What the adaptive time step did.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct AdaptiveSummary {
    /// Relative area/volume error allowed over the run.
    pub tolerance: f64,
    /// Bounds of `dt`.
    pub dt_min: f64,
    pub dt_max: f64,
    /// Steps rejected (their area/volume error too large, or their solve failed) and repeated
    /// with a smaller `dt`.
    pub rejected_steps: usize,
    /// Steps accepted at `dt_min` although their error exceeded what they may commit.
    pub steps_above_tolerance: usize,
    /// Smallest, largest and last step taken.
    pub dt_smallest: f64,
    pub dt_largest: f64,
    pub dt_last: f64,
}

/// What the run built and how often.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Counters {
    pub fmm_builds: usize,
    /// Point–cell pairs pushed apart by the contact repulsion.
    pub repulsion_points: usize,
    /// Double-layer operators assembled (cells with a viscosity contrast, once per step; in this
    /// invocation).
    pub double_layer_assemblies: usize,
    pub near_points: usize,
    pub near_pairs: usize,
    /// Stresslet FMMs built for the inter-cell double layer (several cells, some `λ ≠ 1`: one
    /// per step from the second on; 0 otherwise).
    pub double_layer_fmm_builds: usize,
}

/// One cell's observables from its coefficients.
fn observe(
    calc: &mut SurfaceCalculus,
    coefs: &[f64],
) -> Result<([f64; 3], f64, f64, f64), CellRunError> {
    let g = calc.geometry(coefs)?;
    let (_, axes) = g.principal_axes();
    Ok((
        g.centroid(),
        g.area(),
        g.volume(),
        (axes[0][1] / axes[0][0]).atan().to_degrees(),
    ))
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

/// Everything a run carries from step to step besides the cells' own state.
#[derive(Clone, Debug, Default)]
struct Progress {
    step: usize,
    frame_times: Vec<f64>,
    iters_sum: usize,
    iters_max: usize,
    step_s: f64,
    output_s: f64,
    wall_s: f64,
    min_gap: f64,
    /// Per cell: centroid (3), area, volume, inclination at the start of the run.
    start_obs: Vec<[f64; 6]>,
    /// Time reached.
    time: f64,
    /// The next step's size (adaptive `dt`).
    dt: f64,
    /// The size of the last step taken.
    last_dt: f64,
    /// Smallest and largest step taken.
    dt_used: [f64; 2],
    /// Steps rejected by the adaptive `dt` (repeated smaller).
    rejected: usize,
    /// Accepted steps whose error exceeded what they may commit (taken at `dt_min`).
    above_tolerance: usize,
    /// Sum over the steps of the area/volume error estimate.
    error_sum: f64,
}

impl Progress {
    /// A run that starts at `t = 0` with the step `dt`.
    fn start(dt: f64) -> Self {
        Progress {
            min_gap: f64::INFINITY,
            dt,
            last_dt: dt,
            dt_used: [f64::INFINITY, 0.0],
            ..Default::default()
        }
    }
}

fn checkpoint_error(out: &Path, what: String) -> CellRunError {
    CellRunError::Resume(format!("{}: {what}", out.join(CHECKPOINT).display()))
}

fn save_checkpoint(out: &Path, susp: &Suspension, prog: &Progress) -> Result<(), CellRunError> {
    let nc = susp.len();
    let mut ck = Checkpoint::new(serde_json::json!({
        "format": "mobo cell-run checkpoint",
        "step": prog.step,
        "iters_sum": prog.iters_sum,
        "iters_max": prog.iters_max,
        "cells": nc,
    }));
    let coefs: Vec<f64> = susp.coefs().iter().flatten().copied().collect();
    let ncoef = coefs.len() / nc;
    ck.push("coefs", vec![nc, ncoef], coefs);
    let sigma: Vec<f64> = susp
        .steppers()
        .iter()
        .flat_map(|s| s.sigma.iter().copied())
        .collect();
    let n = sigma.len() / nc;
    ck.push("sigma", vec![nc, n], sigma);
    let targets: Vec<f64> = susp
        .steppers()
        .iter()
        .flat_map(|s| {
            let (a, v) = s.drift_targets().unwrap_or((f64::NAN, f64::NAN));
            [a, v]
        })
        .collect();
    ck.push("drift_targets", vec![nc, 2], targets);
    // BDF2 history: Xⁿ⁻¹ (NaN rows where there is none) and the inter-cell velocities.
    let prev: Vec<f64> = susp
        .steppers()
        .iter()
        .flat_map(|s| match s.previous_coefs() {
            Some(c) => c.to_vec(),
            None => vec![f64::NAN; ncoef],
        })
        .collect();
    ck.push("previous_coefs", vec![nc, ncoef], prev);
    // Skalak references, relabelled with the grid by the reparametrisation (NaN rows for cells
    // without shear elasticity).
    let refs: Vec<f64> = susp
        .steppers()
        .iter()
        .flat_map(|s| match s.skalak_reference() {
            Some(r) => r.to_vec(),
            None => vec![f64::NAN; ncoef],
        })
        .collect();
    ck.push("skalak_references", vec![nc, ncoef], refs);
    for (name, v) in [
        ("inter_cell_velocities", susp.inter_cell_velocities()),
        (
            "previous_inter_cell_velocities",
            susp.previous_inter_cell_velocities(),
        ),
    ] {
        let flat: Vec<f64> = v.iter().flatten().copied().collect();
        ck.push(name, vec![v.len(), flat.len() / v.len().max(1)], flat);
    }
    // Membrane velocities of the last solve: the explicit double-layer densities of the next
    // step (only where the inter-cell double layer is built; NaN rows for none yet).
    if susp.has_inter_cell_double_layer() {
        let n3 = 3 * n;
        let u: Vec<f64> = susp
            .steppers()
            .iter()
            .flat_map(|s| match s.velocity() {
                Some(u) => u.to_vec(),
                None => vec![f64::NAN; n3],
            })
            .collect();
        ck.push("membrane_velocities", vec![nc, n3], u);
    }
    ck.push(
        "start_observables",
        vec![nc, 6],
        prog.start_obs.iter().flatten().copied().collect(),
    );
    ck.push(
        "frame_times",
        vec![prog.frame_times.len()],
        prog.frame_times.clone(),
    );
    ck.push(
        "clocks",
        vec![4],
        vec![prog.step_s, prog.output_s, prog.wall_s, prog.min_gap],
    );
    ck.push(
        "time_steps",
        vec![8],
        vec![
            prog.time,
            prog.dt,
            prog.last_dt,
            prog.dt_used[0],
            prog.dt_used[1],
            prog.rejected as f64,
            prog.above_tolerance as f64,
            prog.error_sum,
        ],
    );
    let previous_dt: Vec<f64> = susp
        .steppers()
        .iter()
        .map(|s| s.previous_dt().unwrap_or(f64::NAN))
        .collect();
    ck.push("previous_dt", vec![nc], previous_dt);
    ck.write(&out.join(CHECKPOINT))?;
    Ok(())
}

fn load_checkpoint(out: &Path, susp: &mut Suspension) -> Result<Progress, CellRunError> {
    let ck = Checkpoint::read(&out.join(CHECKPOINT))?;
    let nc = susp.len();
    let get = |name: &str, len: usize| -> Result<&[f64], CellRunError> {
        let a = ck
            .get(name)
            .ok_or_else(|| checkpoint_error(out, format!("no array \"{name}\"")))?;
        if a.data.len() != len {
            return Err(checkpoint_error(
                out,
                format!(
                    "array \"{name}\" has {} values, the scene needs {len} (is this the same scene?)",
                    a.data.len()
                ),
            ));
        }
        Ok(&a.data)
    };
    let ncoef = susp.coefs()[0].len();
    let n = susp.steppers()[0].sigma.len();
    let coefs = get("coefs", nc * ncoef)?;
    let sigma = get("sigma", nc * n)?;
    let targets = get("drift_targets", nc * 2)?;
    let start = get("start_observables", nc * 6)?;
    let clocks = get("clocks", 4)?;
    let frame_times = ck
        .get("frame_times")
        .ok_or_else(|| checkpoint_error(out, "no array \"frame_times\"".into()))?
        .data
        .clone();
    let prev = get("previous_coefs", nc * ncoef)?;
    let time_steps = get("time_steps", 8)?;
    let previous_dt = get("previous_dt", nc)?;
    for (i, &pdt) in previous_dt.iter().enumerate() {
        susp.steppers_mut()[i]
            .set_previous_dt(pdt.is_finite().then_some(pdt))
            .map_err(|e| checkpoint_error(out, format!("previous_dt of cell {}: {e}", i + 1)))?;
    }
    let velocities = |name: &str| -> Result<Vec<Vec<f64>>, CellRunError> {
        let a = ck
            .get(name)
            .ok_or_else(|| checkpoint_error(out, format!("no array \"{name}\"")))?;
        let rows = a.shape.first().copied().unwrap_or(0);
        if rows == 0 {
            return Ok(Vec::new());
        }
        if rows != nc || a.data.len() != nc * 3 * n {
            return Err(checkpoint_error(
                out,
                format!(
                    "array \"{name}\" has shape {:?}, expected [{nc}, {}]",
                    a.shape,
                    3 * n
                ),
            ));
        }
        Ok(a.data.chunks_exact(3 * n).map(|c| c.to_vec()).collect())
    };
    let current = velocities("inter_cell_velocities")?;
    let previous = velocities("previous_inter_cell_velocities")?;
    susp.set_inter_cell_velocities(current, previous);
    // Absent from checkpoints of runs without an inter-cell double layer.
    if susp.has_inter_cell_double_layer() {
        let u = get("membrane_velocities", nc * 3 * n)?;
        for i in 0..nc {
            let row = &u[i * 3 * n..(i + 1) * 3 * n];
            susp.steppers_mut()[i]
                .set_velocity(row.iter().all(|v| v.is_finite()).then_some(row))
                .map_err(|e| {
                    checkpoint_error(out, format!("membrane_velocities of cell {}: {e}", i + 1))
                })?;
        }
    }
    // Absent from checkpoints written before the references were relabelled: those keep the
    // initial reference.
    if ck.get("skalak_references").is_some() {
        let refs = get("skalak_references", nc * ncoef)?;
        for i in 0..nc {
            let row = &refs[i * ncoef..(i + 1) * ncoef];
            let st = &mut susp.steppers_mut()[i];
            if st.skalak_reference().is_some() && row.iter().all(|v| v.is_finite()) {
                st.set_skalak_reference(row).map_err(|e| {
                    checkpoint_error(out, format!("skalak_references of cell {}: {e}", i + 1))
                })?;
            }
        }
    }
    for i in 0..nc {
        let row = &prev[i * ncoef..(i + 1) * ncoef];
        susp.steppers_mut()[i]
            .set_previous_coefs(row.iter().all(|v| v.is_finite()).then_some(row))
            .map_err(|e| checkpoint_error(out, format!("previous_coefs of cell {}: {e}", i + 1)))?;
    }
    for i in 0..nc {
        susp.coefs_mut()[i].copy_from_slice(&coefs[i * ncoef..(i + 1) * ncoef]);
        let st = &mut susp.steppers_mut()[i];
        st.sigma.copy_from_slice(&sigma[i * n..(i + 1) * n]);
        let (a, v) = (targets[2 * i], targets[2 * i + 1]);
        st.set_drift_targets((a.is_finite() && v.is_finite()).then_some((a, v)));
    }
    let meta = |key: &str| -> Result<usize, CellRunError> {
        ck.meta[key]
            .as_u64()
            .map(|v| v as usize)
            .ok_or_else(|| checkpoint_error(out, format!("header has no \"{key}\"")))
    };
    Ok(Progress {
        step: meta("step")?,
        frame_times,
        iters_sum: meta("iters_sum")?,
        iters_max: meta("iters_max")?,
        step_s: clocks[0],
        output_s: clocks[1],
        wall_s: clocks[2],
        min_gap: clocks[3],
        start_obs: start
            .chunks_exact(6)
            .map(|c| std::array::from_fn(|k| c[k]))
            .collect(),
        time: time_steps[0],
        dt: time_steps[1],
        last_dt: time_steps[2],
        dt_used: [time_steps[3], time_steps[4]],
        rejected: time_steps[5] as usize,
        above_tolerance: time_steps[6] as usize,
        error_sum: time_steps[7],
    })
    .and_then(|p| {
        if p.dt.is_finite() && p.dt > 0.0 && p.time.is_finite() {
            Ok(p)
        } else {
            Err(checkpoint_error(
                out,
                format!("time_steps: time {} and dt {} are not usable", p.time, p.dt),
            ))
        }
    })
}

fn write_frame(
    frames: &mut FrameWriter,
    susp: &Suspension,
    sht: &ShTransform,
    ws: &mut ShWorkspace,
    time: f64,
) -> Result<(), CellRunError> {
    let n = sht.n_points();
    let mut x = vec![0.0; 3 * n * susp.len()];
    for (i, c) in susp.coefs().iter().enumerate() {
        sht.inverse(c, &mut x[3 * n * i..3 * n * (i + 1)], ws)
            .map_err(VesicleError::from)?;
    }
    let cells: Vec<CellFrame<'_>> = susp
        .coefs()
        .iter()
        .zip(susp.steppers())
        .enumerate()
        .map(|(i, (c, st))| CellFrame {
            order: sht.order(),
            coefs: c,
            positions: &x[3 * n * i..3 * n * (i + 1)],
            tension: &st.sigma,
        })
        .collect();
    let index = frames.times().len();
    frames.write_frame(index, time, &cells)?;
    Ok(())
}

/// The cells of `scene` as a [`Suspension`] ready to step (the settings `mobo run` uses:
/// drift correction and reparametrisation every step, GMRES restart 200). Library users and
/// studies (`mobo report`) step it themselves.
pub fn build(scene: &CellScene) -> Result<Suspension, CellRunError> {
    let p = scene.numerics.order;
    let q = scene.numerics.upsample * p;
    let dt = scene.numerics.dt;
    let nc = scene.cells.len();
    let mut setups = Vec::with_capacity(nc);
    for cell in &scene.cells {
        let coefs = cell.surface(p)?.coefs().to_vec();
        let params = VesicleParams {
            bending_modulus: cell.bending_modulus,
            viscosity: scene.viscosity,
            force: cell.force,
            dt,
            upsampled_order: q,
            gmres: GmresParams {
                tol: scene.numerics.gmres_tol,
                restart: 200,
                max_iters: 5000,
                ..Default::default()
            },
            correct_drift: true,
            reparametrize: Some(ReparamParams {
                max_iterations: 10,
                ..Default::default()
            }),
            preconditioner: true,
            scheme: match scene.numerics.scheme {
                Scheme::Euler => TimeScheme::Euler,
                Scheme::Bdf2 => TimeScheme::Bdf2,
            },
            viscosity_ratio: cell.viscosity_ratio,
        };
        let skalak = (cell.shear_modulus > 0.0).then(|| {
            (
                SkalakParams {
                    shear_modulus: cell.shear_modulus,
                    dilation_ratio: cell.skalak_c,
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
    let rate = match scene.flow {
        Flow::None => 0.0,
        Flow::Shear { rate } | Flow::Extensional { rate } => rate.abs(),
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
    let coupling = CouplingParams {
        viscosity: scene.viscosity,
        fmm_digits: scene.numerics.fmm_digits,
        repulsion_range: scene.numerics.repulsion_range,
        repulsion_strength: scene.numerics.repulsion_strength.unwrap_or(auto_strength),
        ..Default::default()
    };
    let mut susp = Suspension::new(p, setups, coupling).map_err(|e| step_error(0, 0.0, e))?;
    let storage = scene.numerics.operator_storage.unwrap_or_else(|| {
        let contrast = scene.cells.iter().any(|c| c.viscosity_ratio != 1.0);
        let budget = available_memory().map_or(8 << 30, |m| m / 10 * 6);
        OperatorStorage::for_budget(susp.steppers().len(), p, 1 + usize::from(contrast), budget)
    });
    for s in susp.steppers_mut() {
        s.set_operator_storage(storage);
    }
    if !scene.numerics.far_side_split {
        let off = FarSideParams {
            enabled: false,
            ..FarSideParams::default()
        };
        for (c, s) in susp.steppers_mut().iter_mut().enumerate() {
            s.set_far_side_params(off).map_err(|source| {
                step_error(
                    0,
                    0.0,
                    CellStepError {
                        cell: Some(c),
                        source,
                    },
                )
            })?;
        }
    }
    Ok(susp)
}

/// A failed step `step` (that was to reach `time`) as a run error, the cell numbered from 1.
fn step_error(step: usize, time: f64, e: CellStepError) -> CellRunError {
    CellRunError::Step {
        step,
        time,
        cell: e.cell.map(|c| c + 1),
        source: Box::new(e.source),
    }
}

/// Run `scene` (whose text is `scene_text`), writing into `out`.
pub fn run(
    scene: &CellScene,
    scene_text: &str,
    out: &Path,
    options: &RunOptions,
) -> Result<CellRunSummary, CellRunError> {
    let p = scene.numerics.order;
    let q = scene.numerics.upsample * p;
    let dt = scene.numerics.dt;
    let steps = (scene.numerics.t_end / dt).round().max(1.0) as usize;
    let nc = scene.cells.len();
    let mut susp = build(scene)?;
    let mut calc = SurfaceCalculus::new(p)?;
    let sht = ShTransform::new(p).map_err(VesicleError::from)?;
    let mut ws = sht.workspace();
    let formats = FrameFormats {
        npy: scene.output.npy,
        hdf5: scene.output.hdf5,
        vtp: scene.output.vtk,
    };
    let (mut prog, mut frames) = if options.resume {
        let prog = load_checkpoint(out, &mut susp)?;
        let frames = FrameWriter::resume(out, formats, &prog.frame_times)?;
        (prog, frames)
    } else {
        let mut prog = Progress::start(dt);
        for c in susp.coefs() {
            let (x, a, v, inc) = observe(&mut calc, c)?;
            prog.start_obs.push([x[0], x[1], x[2], a, v, inc]);
        }
        write_atomic(&out.join(SCENE_COPY), scene_text.as_bytes())?;
        let mut frames = FrameWriter::new(out, formats)?;
        let t0 = Instant::now();
        write_frame(&mut frames, &susp, &sht, &mut ws, 0.0)?;
        prog.output_s += t0.elapsed().as_secs_f64();
        prog.frame_times = frames.times().to_vec();
        (prog, frames)
    };
    let adaptive = if scene.numerics.adaptive_dt {
        let order = match scene.numerics.scheme {
            Scheme::Euler => 1,
            Scheme::Bdf2 => 2,
        };
        Some(
            AdaptiveDt::new(
                scene.numerics.dt_tolerance,
                scene.numerics.t_end,
                order,
                dt,
                scene.numerics.dt_min,
                scene.numerics.dt_max,
            )
            .map_err(|e| CellRunError::Step {
                step: 0,
                time: 0.0,
                cell: None,
                source: Box::new(e),
            })?,
        )
    } else {
        None
    };
    if adaptive.is_some() {
        // A resumed adaptive run continues with the step it had chosen.
        susp.set_dt(prog.dt)
            .map_err(|e| step_error(prog.step, prog.time, e))?;
    }
    let bar = if options.quiet {
        ProgressBar::hidden()
    } else {
        let b = ProgressBar::new(if adaptive.is_some() {
            1000
        } else {
            steps as u64
        });
        b.set_style(
            ProgressStyle::with_template(
                "{elapsed_precise} [{bar:30}] step {pos}/{len} {msg} ETA {eta}",
            )
            .expect("valid template")
            .progress_chars("=> "),
        );
        b.set_position(if adaptive.is_some() {
            (1000.0 * prog.time / scene.numerics.t_end) as u64
        } else {
            prog.step as u64
        });
        b
    };
    let flow = scene.flow;
    let start = Instant::now();
    let wall0 = prog.wall_s;
    let mut before_last: Vec<[f64; 3]> = Vec::new();
    let first = prog.step + 1;
    let mut stopped = false;
    let mut k = prog.step;
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
        k += 1;
        let mut dt_try = match &adaptive {
            None => dt,
            Some(_) => prog.dt.min(scene.numerics.t_end - prog.time),
        };
        if ends_run(k, prog.time + dt_try) {
            before_last.clear();
            for c in susp.coefs() {
                before_last.push(observe(&mut calc, c)?.0);
            }
        }
        let t = Instant::now();
        let snapshot = adaptive.as_ref().map(|_| susp.snapshot());
        let report = loop {
            if adaptive.is_some() {
                susp.set_dt(dt_try)
                    .map_err(|e| step_error(k, prog.time + dt_try, e))?;
            }
            let report = match susp.step(&|x| flow.velocity(x)) {
                Ok(r) => r,
                Err(e) => {
                    // A solve that failed (stagnated, out of iterations) is retried smaller
                    // with adaptive dt, from the snapshot, down to dt_min.
                    let retry = match (&adaptive, &snapshot) {
                        (Some(ctl), Some(snap)) if e.source.report().is_some() => {
                            ctl.after_failure(dt_try).map(|d| (d, snap))
                        }
                        _ => None,
                    };
                    let Some((smaller, snap)) = retry else {
                        return Err(step_error(k, prog.time + dt_try, e));
                    };
                    prog.rejected += 1;
                    susp.restore(snap)
                        .map_err(|e| step_error(k, prog.time + dt_try, e))?;
                    dt_try = smaller.min(scene.numerics.t_end - prog.time);
                    continue;
                }
            };
            let (error, _) = report.area_volume_error();
            let (Some(ctl), Some(snap)) = (&adaptive, &snapshot) else {
                prog.error_sum += error;
                break report;
            };
            let d = ctl.decide(dt_try, error);
            if d.accept {
                prog.error_sum += error;
                if error > ctl.allowed(dt_try) {
                    prog.above_tolerance += 1;
                }
                prog.dt = d.dt;
                break report;
            }
            prog.rejected += 1;
            susp.restore(snap)
                .map_err(|e| step_error(k, prog.time + dt_try, e))?;
            dt_try = d.dt.min(scene.numerics.t_end - prog.time);
        };
        prog.step_s += t.elapsed().as_secs_f64();
        prog.time = match &adaptive {
            None => k as f64 * dt,
            Some(_) => prog.time + dt_try,
        };
        prog.last_dt = dt_try;
        prog.dt_used[0] = prog.dt_used[0].min(dt_try);
        prog.dt_used[1] = prog.dt_used[1].max(dt_try);
        for (i, c) in susp.coefs().iter().enumerate() {
            if let Some(j) = c.iter().position(|c| !c.is_finite()) {
                return Err(CellRunError::Step {
                    step: k,
                    time: prog.time,
                    cell: Some(i + 1),
                    source: Box::new(TimestepError::Vesicle(format!(
                        "non-finite coefficient {j} after the step (the last checkpoint, \
                         step {}, is kept)",
                        prog.step
                    ))),
                });
            }
        }
        let it = report
            .cells
            .iter()
            .map(|r| r.gmres.iterations)
            .max()
            .unwrap_or(0);
        prog.iters_sum += report
            .cells
            .iter()
            .map(|r| r.gmres.iterations)
            .sum::<usize>();
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
        let interrupted = options
            .stop
            .as_ref()
            .is_some_and(|s| s.load(Ordering::Relaxed));
        let limited = options.max_steps.is_some_and(|m| k + 1 - first >= m);
        let last = ends_run(k, prog.time);
        stopped = !last && (interrupted || limited);
        let t0 = Instant::now();
        if last || k as u64 % scene.output_every == 0 {
            write_frame(&mut frames, &susp, &sht, &mut ws, prog.time)?;
            prog.frame_times = frames.times().to_vec();
        }
        if stopped || last || k as u64 % scene.output.checkpoint_every == 0 {
            prog.wall_s = wall0 + start.elapsed().as_secs_f64();
            save_checkpoint(out, &susp, &prog)?;
        }
        prog.output_s += t0.elapsed().as_secs_f64();
        if stopped {
            break;
        }
    }
    bar.finish_and_clear();
    if !stopped {
        frames.finish()?;
    }
    prog.wall_s = wall0 + start.elapsed().as_secs_f64();
    let mut per_cell = Vec::with_capacity(nc);
    for (i, c) in susp.coefs().iter().enumerate() {
        let (centroid, area, volume, inclination) = observe(&mut calc, c)?;
        let s0 = prog.start_obs[i];
        let velocity = match before_last.get(i) {
            Some(b) => std::array::from_fn(|d| (centroid[d] - b[d]) / prog.last_dt),
            None => [f64::NAN; 3],
        };
        per_cell.push(CellSummary {
            area_drift: (area - s0[3]) / s0[3],
            volume_drift: (volume - s0[4]) / s0[4],
            centroid,
            centroid_velocity: velocity,
            inclination_deg: inclination,
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
    let stats = susp.coupling_stats().unwrap_or_default();
    let threads = rayon::current_num_threads();
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
        effects: scene.effects.clone(),
        wall_s: prog.wall_s,
        step_s: prog.step_s,
        coupling_s: stats.setup_s + stats.fmm_s + stats.self_s + stats.near_s,
        output_s: prog.output_s,
        threads,
        cell_steps_per_core_second: (done * nc) as f64 / (prog.step_s * threads as f64).max(1e-12),
        gmres_iterations_mean: prog.iters_sum as f64 / (done * nc).max(1) as f64,
        gmres_iterations_max: prog.iters_max,
        counters: Counters {
            fmm_builds: stats.fmm_builds,
            repulsion_points: stats.repulsion_points,
            double_layer_assemblies: susp
                .steppers()
                .iter()
                .map(|s| s.double_layer_assemblies)
                .sum(),
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
    };
    let json = serde_json::to_string_pretty(&summary).expect("summary serialises");
    write_atomic(&out.join("summary.json"), json.as_bytes())?;
    Ok(summary)
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

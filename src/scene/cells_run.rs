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
//! (Skalak, explicit, stress-free at the initial shape), viscosity ratio 1, the first-order
//! scheme. Other scenes are refused with a message that says what is missing.

use std::path::Path;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

use super::cells::{CellScene, Effect, Scheme};
use crate::io::{npy, write_atomic, IoError};
use crate::sph_harmonics::ShTransform;
use crate::timestep::coupling::CouplingParams;
use crate::timestep::semi_implicit::VesicleParams;
use crate::timestep::suspension::{CellSetup, CellStepError, Suspension};
use crate::timestep::{GmresParams, TimestepError};
use crate::vesicle::geometry::SurfaceCalculus;
use crate::vesicle::reparam::ReparamParams;
use crate::vesicle::skalak::SkalakParams;
use crate::vesicle::VesicleError;

/// Errors of a cell run.
#[derive(Debug, thiserror::Error)]
pub enum CellRunError {
    /// The scene asks for something not built yet.
    #[error("not supported yet: {0}")]
    Unsupported(String),
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
    pub dt: f64,
    pub steps: usize,
    pub final_time: f64,
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

/// What the run built and how often.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Counters {
    pub fmm_builds: usize,
    pub near_points: usize,
    pub near_pairs: usize,
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

/// Run `scene`, writing into `out`.
pub fn run(scene: &CellScene, out: &Path, quiet: bool) -> Result<CellRunSummary, CellRunError> {
    for (i, cell) in scene.cells.iter().enumerate() {
        if cell.viscosity_ratio != 1.0 {
            return Err(CellRunError::Unsupported(format!(
                "cell {} (line {}): viscosity_ratio ≠ 1 (the double-layer step is not built yet)",
                i + 1,
                cell.line
            )));
        }
    }
    if scene.numerics.scheme != Scheme::Euler {
        return Err(CellRunError::Unsupported("scheme = \"bdf2\"".into()));
    }
    if scene.numerics.adaptive_dt {
        return Err(CellRunError::Unsupported("adaptive_dt = true".into()));
    }
    let p = scene.numerics.order;
    let q = scene.numerics.upsample * p;
    let dt = scene.numerics.dt;
    let steps = (scene.numerics.t_end / dt).round().max(1.0) as usize;
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
            },
            correct_drift: true,
            reparametrize: Some(ReparamParams {
                max_iterations: 10,
                ..Default::default()
            }),
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
    let step_err = |step: usize, e: CellStepError| CellRunError::Step {
        step,
        time: step as f64 * dt,
        cell: e.cell.map(|c| c + 1),
        source: Box::new(e.source),
    };
    let coupling = CouplingParams {
        viscosity: scene.viscosity,
        fmm_digits: scene.numerics.fmm_digits,
        ..Default::default()
    };
    let mut susp = Suspension::new(p, setups, coupling).map_err(|e| step_err(0, e))?;
    let mut calc = SurfaceCalculus::new(p)?;
    let sht = ShTransform::new(p).map_err(VesicleError::from)?;
    let mut ws = sht.workspace();
    let mut start_obs = Vec::with_capacity(nc);
    for c in susp.coefs() {
        start_obs.push(observe(&mut calc, c)?);
    }
    let frames_dir = out.join("frames");
    std::fs::create_dir_all(&frames_dir).map_err(|source| IoError::File {
        path: frames_dir.clone(),
        source,
    })?;
    let mut times = Vec::new();
    let mut output_s = 0.0;
    let mut save =
        |k: usize, susp: &Suspension, times: &mut Vec<f64>| -> Result<(), CellRunError> {
            let t0 = Instant::now();
            let n = sht.n_points();
            let ncoef = sht.n_coefs();
            let mut coefs = Vec::with_capacity(3 * ncoef * nc);
            let mut x = vec![0.0; 3 * n * nc];
            let mut sigma = Vec::with_capacity(n * nc);
            for (i, (c, st)) in susp.coefs().iter().zip(susp.steppers()).enumerate() {
                coefs.extend_from_slice(c);
                sht.inverse(c, &mut x[3 * n * i..3 * n * (i + 1)], &mut ws)
                    .map_err(VesicleError::from)?;
                sigma.extend_from_slice(&st.sigma);
            }
            let f = times.len();
            npy::write_f64(
                &frames_dir.join(format!("frame_{f:05}_coefs.npy")),
                &[nc, 3, ncoef],
                &coefs,
            )?;
            npy::write_f64(
                &frames_dir.join(format!("frame_{f:05}_positions.npy")),
                &[nc, 3, n],
                &x,
            )?;
            npy::write_f64(
                &frames_dir.join(format!("frame_{f:05}_tension.npy")),
                &[nc, n],
                &sigma,
            )?;
            times.push(k as f64 * dt);
            npy::write_f64(&frames_dir.join("times.npy"), &[times.len()], times)?;
            output_s += t0.elapsed().as_secs_f64();
            Ok(())
        };
    save(0, &susp, &mut times)?;
    let bar = if quiet {
        ProgressBar::hidden()
    } else {
        let b = ProgressBar::new(steps as u64);
        b.set_style(
            ProgressStyle::with_template(
                "{elapsed_precise} [{bar:30}] step {pos}/{len} {msg} ETA {eta}",
            )
            .expect("valid template")
            .progress_chars("=> "),
        );
        b
    };
    let flow = scene.flow;
    let start = Instant::now();
    let mut step_s = 0.0;
    let (mut iters_sum, mut iters_max) = (0usize, 0usize);
    let mut before_last: Vec<[f64; 3]> = start_obs.iter().map(|o| o.0).collect();
    let mut min_gap = f64::INFINITY;
    for k in 1..=steps {
        if k == steps {
            for (b, c) in before_last.iter_mut().zip(susp.coefs()) {
                *b = observe(&mut calc, c)?.0;
            }
        }
        let t = Instant::now();
        let report = susp
            .step(&|x| flow.velocity(x))
            .map_err(|e| step_err(k, e))?;
        step_s += t.elapsed().as_secs_f64();
        for (i, c) in susp.coefs().iter().enumerate() {
            if let Some(j) = c.iter().position(|c| !c.is_finite()) {
                return Err(CellRunError::Step {
                    step: k,
                    time: k as f64 * dt,
                    cell: Some(i + 1),
                    source: Box::new(TimestepError::Vesicle(format!(
                        "non-finite coefficient {j} after the step"
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
        iters_sum += report
            .cells
            .iter()
            .map(|r| r.gmres.iterations)
            .sum::<usize>();
        iters_max = iters_max.max(it);
        if let Some(st) = susp.coupling_stats() {
            min_gap = min_gap.min(st.min_gap);
        }
        bar.set_message(format!("t {:.3} dt {dt} gmres {it}", k as f64 * dt));
        bar.inc(1);
        if k == steps || k as u64 % scene.output_every == 0 {
            save(k, &susp, &mut times)?;
        }
    }
    bar.finish_and_clear();
    let wall = start.elapsed().as_secs_f64();
    let mut per_cell = Vec::with_capacity(nc);
    for (i, c) in susp.coefs().iter().enumerate() {
        let (centroid, area, volume, inclination) = observe(&mut calc, c)?;
        let (_, a0, v0, _) = start_obs[i];
        per_cell.push(CellSummary {
            area_drift: (area - a0) / a0,
            volume_drift: (volume - v0) / v0,
            centroid,
            centroid_velocity: std::array::from_fn(|d| (centroid[d] - before_last[i][d]) / dt),
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
    let summary = CellRunSummary {
        cells: nc,
        order: p,
        upsampled_order: q,
        dt,
        steps,
        final_time: steps as f64 * dt,
        scheme: "euler",
        gmres_tol: scene.numerics.gmres_tol,
        fmm_digits: (nc > 1).then_some(scene.numerics.fmm_digits),
        effects: scene.effects.clone(),
        wall_s: wall,
        step_s,
        coupling_s: stats.setup_s + stats.fmm_s + stats.self_s + stats.near_s,
        output_s,
        threads,
        cell_steps_per_core_second: (steps * nc) as f64 / (step_s * threads as f64).max(1e-12),
        gmres_iterations_mean: iters_sum as f64 / (steps * nc) as f64,
        gmres_iterations_max: iters_max,
        counters: Counters {
            fmm_builds: stats.fmm_builds,
            near_points: stats.near_points,
            near_pairs: stats.near_pairs,
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
        min_gap: min_gap.is_finite().then_some(min_gap),
        per_cell,
        frames: times.len(),
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

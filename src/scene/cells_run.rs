//! Running a cell scene (`mobo run`): the semi-implicit steps, saved frames and a summary.
//!
//! Writes into the output directory, each file atomically (written, then renamed):
//! * `frames/frame_NNNNN_coefs.npy` (`3 × n_coefs`: x, y, z SH coefficients),
//!   `frames/frame_NNNNN_positions.npy` (`3 × n_points` grid positions),
//!   `frames/frame_NNNNN_tension.npy` (`n_points`), `frames/times.npy` (time of every frame);
//! * `summary.json`: effects built and why, settings, steps, timings, GMRES iterations, area
//!   and volume drift, centroid and its velocity, inclination angle, final time.
//!
//! Implemented so far: scenes of **one** cell with viscosity ratio 1, no shear elasticity, the
//! first-order scheme. Other scenes are refused with a message that says what is missing.

use std::path::Path;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

use super::cells::{CellScene, Effect, Scheme};
use crate::io::{npy, write_atomic, IoError};
use crate::sph_harmonics::ShTransform;
use crate::timestep::semi_implicit::{VesicleParams, VesicleStepper};
use crate::timestep::{GmresParams, TimestepError};
use crate::vesicle::geometry::SurfaceCalculus;
use crate::vesicle::reparam::ReparamParams;
use crate::vesicle::VesicleError;

/// Errors of a cell run.
#[derive(Debug, thiserror::Error)]
pub enum CellRunError {
    /// The scene asks for something not built yet.
    #[error("not supported yet: {0}")]
    Unsupported(String),
    /// The step failed (solver, geometry), with the step number.
    #[error("step {step} (t = {time}): {source}")]
    Step {
        step: usize,
        time: f64,
        source: TimestepError,
    },
    /// Building a cell failed.
    #[error("{0}")]
    Cell(#[from] VesicleError),
    /// Output could not be written.
    #[error("{0}")]
    Io(#[from] IoError),
}

/// What `summary.json` holds.
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
    pub effects: Vec<Effect>,
    pub wall_s: f64,
    pub step_s: f64,
    pub output_s: f64,
    pub cell_steps_per_core_second: f64,
    pub gmres_iterations_mean: f64,
    pub gmres_iterations_max: usize,
    pub area_drift: f64,
    pub volume_drift: f64,
    pub centroid: [f64; 3],
    pub centroid_velocity: [f64; 3],
    pub inclination_deg: f64,
    pub frames: usize,
}

/// Run `scene`, writing into `out`.
pub fn run(scene: &CellScene, out: &Path, quiet: bool) -> Result<CellRunSummary, CellRunError> {
    if scene.cells.len() != 1 {
        return Err(CellRunError::Unsupported(format!(
            "{} cells: coupling cells through the FMM is not built yet; mobo run handles one cell",
            scene.cells.len()
        )));
    }
    let cell = &scene.cells[0];
    if cell.viscosity_ratio != 1.0 {
        return Err(CellRunError::Unsupported(
            "viscosity_ratio ≠ 1 (the double-layer step is not built yet)".into(),
        ));
    }
    if cell.shear_modulus > 0.0 {
        return Err(CellRunError::Unsupported(
            "shear_modulus > 0 (Skalak forces exist but are not in the step yet)".into(),
        ));
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
        preconditioner: true,
        scheme: crate::timestep::semi_implicit::TimeScheme::Euler,
        viscosity_ratio: 1.0,
    };
    let surface = cell.surface(p)?;
    let mut coefs = surface.coefs().to_vec();
    let step_err = |step: usize, source: TimestepError| CellRunError::Step {
        step,
        time: step as f64 * dt,
        source,
    };
    let mut stepper = VesicleStepper::new(p, params).map_err(|e| step_err(0, e))?;
    let mut calc = SurfaceCalculus::new(p)?;
    let sht = ShTransform::new(p).map_err(VesicleError::from)?;
    let mut ws = sht.workspace();
    let g0 = calc.geometry(&coefs)?;
    let (a0, v0) = (g0.area(), g0.volume());
    let frames_dir = out.join("frames");
    std::fs::create_dir_all(&frames_dir).map_err(|source| IoError::File {
        path: frames_dir.clone(),
        source,
    })?;
    let mut times = Vec::new();
    let mut output_s = 0.0;
    let mut save = |k: usize,
                    coefs: &[f64],
                    sigma: &[f64],
                    times: &mut Vec<f64>|
     -> Result<(), CellRunError> {
        let t0 = Instant::now();
        let n = sht.n_points();
        let mut x = vec![0.0; 3 * n];
        sht.inverse(coefs, &mut x, &mut ws)
            .map_err(VesicleError::from)?;
        let f = times.len();
        npy::write_f64(
            &frames_dir.join(format!("frame_{f:05}_coefs.npy")),
            &[3, coefs.len() / 3],
            coefs,
        )?;
        npy::write_f64(
            &frames_dir.join(format!("frame_{f:05}_positions.npy")),
            &[3, n],
            &x,
        )?;
        npy::write_f64(
            &frames_dir.join(format!("frame_{f:05}_tension.npy")),
            &[n],
            sigma,
        )?;
        times.push(k as f64 * dt);
        npy::write_f64(&frames_dir.join("times.npy"), &[times.len()], times)?;
        output_s += t0.elapsed().as_secs_f64();
        Ok(())
    };
    save(0, &coefs, &stepper.sigma, &mut times)?;
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
    let mut before_last = g0.centroid();
    for k in 1..=steps {
        if k == steps {
            before_last = calc.geometry(&coefs)?.centroid();
        }
        let t = Instant::now();
        let report = stepper
            .step(&mut coefs, &|x| flow.velocity(x))
            .map_err(|e| step_err(k, e))?;
        step_s += t.elapsed().as_secs_f64();
        if let Some(j) = coefs.iter().position(|c| !c.is_finite()) {
            return Err(step_err(
                k,
                TimestepError::Vesicle(format!("non-finite coefficient {j} after the step")),
            ));
        }
        let it = report.gmres.iterations;
        iters_sum += it;
        iters_max = iters_max.max(it);
        bar.set_message(format!("t {:.3} dt {dt} gmres {it}", k as f64 * dt));
        bar.inc(1);
        if k == steps || k as u64 % scene.output_every == 0 {
            save(k, &coefs, &stepper.sigma, &mut times)?;
        }
    }
    bar.finish_and_clear();
    let g = calc.geometry(&coefs)?;
    let (_, axes) = g.principal_axes();
    let c = g.centroid();
    let velocity: [f64; 3] = std::array::from_fn(|d| (c[d] - before_last[d]) / dt);
    let wall = start.elapsed().as_secs_f64();
    let summary = CellRunSummary {
        cells: 1,
        order: p,
        upsampled_order: q,
        dt,
        steps,
        final_time: steps as f64 * dt,
        scheme: "euler",
        gmres_tol: scene.numerics.gmres_tol,
        effects: scene.effects.clone(),
        wall_s: wall,
        step_s,
        output_s,
        cell_steps_per_core_second: steps as f64 / step_s.max(1e-12),
        gmres_iterations_mean: iters_sum as f64 / steps as f64,
        gmres_iterations_max: iters_max,
        area_drift: (g.area() - a0) / a0,
        volume_drift: (g.volume() - v0) / v0,
        centroid: c,
        centroid_velocity: velocity,
        inclination_deg: (axes[0][1] / axes[0][0]).atan().to_degrees(),
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

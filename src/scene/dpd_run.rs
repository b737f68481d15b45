//! Running a DPD scene (`mobo dpd`): steps, observables, the velocity profile, the viscosity
//! fit, checkpoints and a summary.
//!
//! Writes into the output directory (each file atomically):
//! * `scene.toml`: the scene as given (`mobo dpd --resume DIR` reads it back);
//! * `observables.csv`: every `save_every` steps `step, t, kbt, pressure, px, py, pz`;
//! * `profile.csv`: `z, vx, density` per bin over the averaged steps (and `vx_fit`, the fitted
//!   reverse-Poiseuille profile, for that flow);
//! * `checkpoint.bin`: the whole state (particles in their stored order, forces, step, the
//!   profile sampler, the observables), every `save_every` steps and at the end; a resumed
//!   run continues bit for bit;
//! * `summary.json`: effects and why, settings, timings, particle-steps per second, drifts,
//!   and for periodic Poiseuille flow `"viscosity": {"value", "stderr", …}`.

use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use serde_json::json;

pub use super::brownian_run::Effect;
use super::dpd::DpdScene;
use crate::dpd::pair_force::Particles;
use crate::dpd::poiseuille::{
    kinetic_theory_viscosity, FlowGeometry, KineticViscosity, ProfileSampler, ViscosityFit,
};
use crate::dpd::system::{BodyForce, DpdSystem, DpdTimings};
use crate::dpd::walls::Wall;
use crate::dpd::DpdError;
use crate::io::checkpoint::Checkpoint;
use crate::io::{write_atomic, IoError};

/// The copy of the scene in the output directory.
pub const SCENE_COPY: &str = "scene.toml";
/// The checkpoint file in the output directory.
pub const CHECKPOINT: &str = "checkpoint.bin";

/// Errors of a DPD run.
#[derive(Debug, thiserror::Error)]
pub enum DpdRunError {
    /// The dynamics failed.
    #[error("{0}")]
    Dynamics(#[from] DpdError),
    /// Output could not be written or a checkpoint read.
    #[error("{0}")]
    Io(#[from] IoError),
    /// A checkpoint that does not belong to this scene.
    #[error("{file}: {why}")]
    Checkpoint {
        /// The checkpoint file.
        file: String,
        /// What does not fit (wrong kind, a missing or malformed array, another scene).
        why: String,
    },
}

/// How to run.
#[derive(Clone, Debug, Default)]
pub struct DpdRunOptions {
    /// No progress bar.
    pub quiet: bool,
    /// Continue from `DIR/checkpoint.bin`.
    pub resume: bool,
    /// Stop after this many steps in this invocation (with a checkpoint).
    pub max_steps: Option<u64>,
    /// Set to stop after the current step (with a checkpoint).
    pub stop: Option<Arc<AtomicBool>>,
}

/// The fitted viscosity in `summary.json`.
#[derive(Clone, Debug, Serialize)]
pub struct ViscositySummary {
    /// `η = n g / 2c` from the block-averaged profile.
    pub value: f64,
    /// Standard error over the blocks.
    pub stderr: f64,
    /// Blocks averaged (`[dpd] blocks`).
    pub blocks: usize,
    /// Profile samples averaged, all blocks together.
    pub samples: usize,
    /// Steps between samples.
    pub sample_every: u64,
    /// Steps discarded before averaging.
    pub equilibration_steps: u64,
    /// The fraction of each half-channel fitted (`dpd::poiseuille::FIT_WINDOW`).
    pub fit_window: f64,
    /// Steps averaged over (`samples × sample_every`).
    pub averaged_steps: u64,
    /// The kinetic-theory estimate (Marsh; Groot & Warren) for comparison.
    pub kinetic_theory: KineticViscosity,
}

/// What `summary.json` holds.
#[derive(Clone, Debug, Serialize)]
pub struct DpdSummary {
    /// Always `"dpd"`.
    pub kind: &'static str,
    /// Whether the run reached `steps` (false: stopped early with a checkpoint, to be resumed).
    pub completed: bool,
    /// Particles, frozen wall particles included.
    pub particles: usize,
    /// Steps taken so far (all invocations of a resumed run).
    pub steps: u64,
    /// Steps the scene asks for (`[dpd] steps`, or `t_end / dt`).
    pub steps_requested: u64,
    /// Time step.
    pub dt: f64,
    /// Time reached, `steps · dt`.
    pub final_time: f64,
    /// Box side lengths (JSON key `box`).
    #[serde(rename = "box")]
    pub box_len: [f64; 3],
    /// Number density of the fluid: moving particles over the fluid's volume (with walls),
    /// or all particles over the box volume.
    pub density: f64,
    /// Conservative (repulsion) amplitude `a`.
    pub a: f64,
    /// Dissipative coefficient `γ`.
    pub gamma: f64,
    /// Thermal energy `k_BT` of the thermostat.
    pub kbt: f64,
    /// Cut-off radius `r_c`.
    pub rc: f64,
    /// Kernel exponent `k` (`w_R = w^k`, `w_D = w^{2k}`).
    pub power: f64,
    /// Particle mass.
    pub mass: f64,
    /// Seed of the noise and of the initial state.
    pub seed: u64,
    /// The body force (JSON `"None"`, `{"Constant": [gx, gy, gz]}` or
    /// `{"ReversePoiseuille": {"force": g}}`).
    pub flow: BodyForce,
    /// The effects built and why ([`effects`]).
    pub effects: Vec<Effect>,
    /// Wall seconds of the steps (all invocations of a resumed run).
    pub wall_s: f64,
    /// Wall milliseconds per step in this invocation (NaN when it took no step).
    pub ms_per_step: f64,
    /// Particles (all of them) times steps per wall second in this invocation.
    pub particle_steps_per_second: f64,
    /// Threads of the rayon pool.
    pub threads: usize,
    /// Seconds per phase (this invocation).
    pub timings: DpdTimings,
    /// Mean kinetic temperature over the observables rows after equilibration (includes the
    /// mean flow's kinetic energy in a driven flow).
    pub temperature: f64,
    /// The temperature of the velocities about the mean flow profile: `temperature` less the
    /// mean flow's part `m ⟨u_x²⟩/3` from the sampled profile (`null` without a profile).
    pub thermal_temperature: Option<f64>,
    /// Mean virial pressure over the same rows.
    pub pressure: f64,
    /// `max_t |P(t) − P(0)|` per particle, in units of the thermal momentum `√(m k_BT)`
    /// (a body force changes `P` only when it does not sum to zero).
    pub momentum_drift: f64,
    /// Particles found inside a wall after the bounce-back (`null` without walls; membranes
    /// are not built yet).
    pub leaked_particles: Option<u64>,
    /// Bounce-backs off the walls (`null` without walls).
    pub bounces: Option<u64>,
    /// Moving (fluid) particles; the rest are frozen wall particles.
    pub fluid_particles: usize,
    /// Periodic Poiseuille flow: the viscosity fitted to the velocity profile.
    pub viscosity: Option<ViscositySummary>,
}

/// The effects a scene calls for.
pub fn effects(scene: &DpdScene) -> Vec<Effect> {
    let p = &scene.params.pair;
    vec![
        Effect {
            name: "conservative force",
            enabled: p.a > 0.0,
            reason: format!("a = {}", p.a),
        },
        Effect {
            name: "thermostat (dissipative + random forces)",
            enabled: p.gamma > 0.0,
            reason: format!(
                "gamma = {}, kbt = {}, kernel exponent k = {}",
                p.gamma, p.kbt, p.power
            ),
        },
        Effect {
            name: "periodic Poiseuille body force",
            enabled: matches!(scene.body, BodyForce::ReversePoiseuille { .. }),
            reason: match scene.body {
                BodyForce::ReversePoiseuille { force } => format!(
                    "flow = \"periodic_poiseuille\", force = {force}: viscosity fitted to the profile"
                ),
                _ => "flow = \"none\"".into(),
            },
        },
        Effect {
            name: "membranes",
            enabled: false,
            reason: "cells in the DPD fluid are not built yet (the membrane model is in dpd::membrane)".into(),
        },
        Effect {
            name: "walls",
            enabled: scene.wall.is_some(),
            reason: match scene.wall {
                None => "no walls: periodic in every direction".into(),
                Some(w) => format!(
                    "{w:?}: frozen particles (a layer of r_c, equilibrated {} steps) and bounce-back",
                    scene.wall_warmup
                ),
            },
        },
        Effect {
            name: "body force (plane/pipe Poiseuille)",
            enabled: matches!(scene.body, BodyForce::Constant(_)),
            reason: match scene.body {
                BodyForce::Constant(g) => format!(
                    "flow = \"poiseuille\", force = {}: viscosity fitted to the profile between the walls",
                    g[0]
                ),
                _ => "no constant body force".into(),
            },
        },
    ]
}

/// What the profile sampler bins and fits for this scene.
fn flow_geometry(scene: &DpdScene) -> FlowGeometry {
    match scene.wall {
        None => FlowGeometry::Periodic,
        Some(Wall::Planes { lo, hi }) => FlowGeometry::Channel { lo, hi },
        Some(Wall::Cylinder { radius, center }) => FlowGeometry::Pipe { center, radius },
    }
}

/// Observables kept between checkpoints: one row per `save_every` steps.
const OBS_COLS: usize = 7;

/// Run (or resume) a scene, writing into `out`.
pub fn run(
    scene: &DpdScene,
    scene_text: &str,
    out: &Path,
    opts: &DpdRunOptions,
) -> Result<DpdSummary, DpdRunError> {
    let ckpt_path = out.join(CHECKPOINT);
    let (mut sys, mut sampler, mut rows, mut wall_before, p0) = if opts.resume {
        restore(scene, &ckpt_path)?
    } else {
        write_atomic(&out.join(SCENE_COPY), scene_text.as_bytes())?;
        let sys = match scene.wall {
            None => DpdSystem::random_fluid(scene.params, scene.density, scene.body)?,
            Some(w) => DpdSystem::with_wall(
                scene.params,
                scene.density,
                scene.body,
                w,
                scene.wall_warmup,
            )?,
        };
        let sampler = ProfileSampler::with_geometry(
            flow_geometry(scene),
            scene.params.box_len,
            scene.bins,
            scene.block_samples().max(1) as usize,
        );
        let p0 = sys.momentum();
        let mut rows = Vec::new();
        push_row(&mut rows, &sys);
        (sys, sampler, rows, 0.0, p0)
    };
    let bar = if opts.quiet {
        ProgressBar::hidden()
    } else {
        let b = ProgressBar::new(scene.steps);
        b.set_style(
            ProgressStyle::with_template(
                "{elapsed_precise} [{bar:40}] step {pos}/{len} ({per_sec}, eta {eta}) {msg}",
            )
            .expect("static template")
            .progress_chars("=> "),
        );
        b.set_position(sys.step);
        b
    };
    let sample_end = scene.equilibrate + scene.block_samples() * scene.blocks * scene.sample_every;
    let start = Instant::now();
    let first = sys.step;
    let mut completed = true;
    while sys.step < scene.steps {
        if opts.max_steps.is_some_and(|m| sys.step - first >= m)
            || opts
                .stop
                .as_ref()
                .is_some_and(|s| s.load(Ordering::Relaxed))
        {
            completed = false;
            break;
        }
        sys.step()?;
        let s = sys.step;
        if s > scene.equilibrate
            && s <= sample_end
            && (s - scene.equilibrate).is_multiple_of(scene.sample_every)
        {
            sampler.sample(&sys);
        }
        if s % scene.save_every == 0 || s == scene.steps {
            push_row(&mut rows, &sys);
            bar.set_position(s);
            bar.set_message(format!("k_BT = {:.4}", sys.kinetic_temperature()));
            if s < scene.steps {
                let wall = wall_before + start.elapsed().as_secs_f64();
                checkpoint(&sys, &sampler, &rows, wall, p0).write(&ckpt_path)?;
            }
        }
    }
    bar.finish_and_clear();
    let done = sys.step - first;
    let this_wall = start.elapsed().as_secs_f64();
    wall_before += this_wall;
    if !completed {
        push_row(&mut rows, &sys);
    }
    checkpoint(&sys, &sampler, &rows, wall_before, p0).write(&ckpt_path)?;
    let fit = driving_force(scene).and_then(|g| sampler.viscosity(sys.density(), g));
    let flow_kt = sampler.flow_temperature(scene.params.mass);
    let summary = summarise(
        scene,
        &sys,
        fit.as_ref(),
        flow_kt,
        &rows,
        wall_before,
        p0,
        completed,
        done,
        this_wall,
    );
    write_outputs(scene, out, &sampler, fit.as_ref(), &rows, &summary)?;
    Ok(summary)
}

/// The body force per particle whose profile gives the viscosity (`None`: no such flow).
fn driving_force(scene: &DpdScene) -> Option<f64> {
    match scene.body {
        BodyForce::ReversePoiseuille { force } => Some(force),
        BodyForce::Constant(g) if scene.wall.is_some() => Some(g[0]),
        _ => None,
    }
}

fn push_row(rows: &mut Vec<f64>, sys: &DpdSystem) {
    let p = sys.momentum();
    rows.extend([
        sys.step as f64,
        sys.time(),
        sys.kinetic_temperature(),
        sys.pressure(),
        p[0],
        p[1],
        p[2],
    ]);
}

#[allow(clippy::too_many_arguments)]
fn summarise(
    scene: &DpdScene,
    sys: &DpdSystem,
    fit: Option<&ViscosityFit>,
    flow_kt: Option<f64>,
    rows: &[f64],
    wall: f64,
    p0: [f64; 3],
    completed: bool,
    done: u64,
    this_wall: f64,
) -> DpdSummary {
    let prm = &scene.params;
    let n = sys.len();
    let after: Vec<&[f64]> = rows
        .chunks_exact(OBS_COLS)
        .filter(|r| r[0] as u64 > scene.equilibrate || scene.equilibrate == 0)
        .collect();
    let mean = |c: usize| {
        if after.is_empty() {
            f64::NAN
        } else {
            after.iter().map(|r| r[c]).sum::<f64>() / after.len() as f64
        }
    };
    let thermal = (prm.mass * prm.pair.kbt.max(f64::MIN_POSITIVE)).sqrt();
    let drift = rows
        .chunks_exact(OBS_COLS)
        .map(|r| (0..3).map(|k| (r[4 + k] - p0[k]).abs()).fold(0.0, f64::max))
        .fold(0.0, f64::max)
        / (n as f64 * thermal);
    let viscosity = fit.map(|fit| ViscositySummary {
        value: fit.value,
        stderr: fit.stderr,
        blocks: fit.blocks,
        samples: fit.samples,
        sample_every: scene.sample_every,
        equilibration_steps: scene.equilibrate,
        fit_window: fit.window,
        averaged_steps: fit.samples as u64 * scene.sample_every,
        kinetic_theory: kinetic_theory_viscosity(
            sys.density(),
            prm.pair.gamma,
            prm.pair.kbt,
            prm.pair.rc,
            prm.pair.power,
            prm.mass,
        ),
    });
    let per_step = if done > 0 {
        this_wall / done as f64
    } else {
        f64::NAN
    };
    DpdSummary {
        kind: "dpd",
        completed,
        particles: n,
        steps: sys.step,
        steps_requested: scene.steps,
        dt: prm.dt,
        final_time: sys.time(),
        box_len: prm.box_len,
        density: sys.density(),
        a: prm.pair.a,
        gamma: prm.pair.gamma,
        kbt: prm.pair.kbt,
        rc: prm.pair.rc,
        power: prm.pair.power,
        mass: prm.mass,
        seed: prm.seed,
        flow: scene.body,
        effects: effects(scene),
        wall_s: wall,
        ms_per_step: per_step * 1e3,
        particle_steps_per_second: n as f64 / per_step,
        threads: rayon::current_num_threads(),
        timings: sys.timings,
        temperature: mean(2),
        thermal_temperature: flow_kt.map(|t| mean(2) - t),
        pressure: mean(3),
        momentum_drift: drift,
        leaked_particles: scene.wall.map(|_| sys.leaked),
        bounces: scene.wall.map(|_| sys.bounces),
        fluid_particles: sys.n_moving(),
        viscosity,
    }
}

fn write_outputs(
    scene: &DpdScene,
    out: &Path,
    sampler: &ProfileSampler,
    fit: Option<&ViscosityFit>,
    rows: &[f64],
    summary: &DpdSummary,
) -> Result<(), DpdRunError> {
    let mut csv = String::from("step,t,kbt,pressure,px,py,pz\n");
    for r in rows.chunks_exact(OBS_COLS) {
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{}",
            r[0] as u64, r[1], r[2], r[3], r[4], r[5], r[6]
        );
    }
    write_atomic(&out.join("observables.csv"), csv.as_bytes())?;
    if !sampler.blocks.is_empty() {
        let coord = match scene.wall {
            Some(Wall::Cylinder { .. }) => "r",
            _ => "z",
        };
        let fitted = if fit.is_some() { ",vx_fit" } else { "" };
        let mut csv = format!("{coord},vx,density{fitted}\n");
        for (b, (z, v, d)) in sampler.profile().into_iter().enumerate() {
            match fit {
                Some(f) => {
                    let _ = writeln!(csv, "{z},{v},{d},{}", sampler.fitted(f, b));
                }
                None => {
                    let _ = writeln!(csv, "{z},{v},{d}");
                }
            }
        }
        write_atomic(&out.join("profile.csv"), csv.as_bytes())?;
    }
    let json = serde_json::to_string_pretty(summary).expect("summary serialises");
    write_atomic(&out.join("summary.json"), json.as_bytes())?;
    Ok(())
}

/// The checkpoint of the whole run state.
fn checkpoint(
    sys: &DpdSystem,
    sampler: &ProfileSampler,
    rows: &[f64],
    wall: f64,
    p0: [f64; 3],
) -> Checkpoint {
    let n = sys.len();
    let mut c = Checkpoint::new(json!({
        "kind": "dpd",
        "step": sys.step,
        "particles": n,
        "bins": sampler.bins,
    }));
    let p = &sys.particles;
    for (name, v) in [
        ("x", &p.x),
        ("y", &p.y),
        ("z", &p.z),
        ("vx", &p.vx),
        ("vy", &p.vy),
        ("vz", &p.vz),
        ("fx", &sys.fx),
        ("fy", &sys.fy),
        ("fz", &sys.fz),
    ] {
        c.push(name, vec![n], v.clone());
    }
    c.push("id", vec![n], p.id.iter().map(|&i| i as f64).collect());
    c.push("moves", vec![n], p.moves.clone());
    c.push(
        "walls",
        vec![2],
        vec![sys.bounces as f64, sys.leaked as f64],
    );
    c.push("step", vec![], vec![sys.step as f64]);
    c.push("wall_s", vec![], vec![wall]);
    c.push("momentum0", vec![3], p0.to_vec());
    c.push(
        "observables",
        vec![rows.len() / OBS_COLS, OBS_COLS],
        rows.to_vec(),
    );
    let (state, shape) = sampler.state();
    c.push("profile_sampler", shape, state);
    c
}

type Restored = (DpdSystem, ProfileSampler, Vec<f64>, f64, [f64; 3]);

fn restore(scene: &DpdScene, path: &Path) -> Result<Restored, DpdRunError> {
    let c = Checkpoint::read(path)?;
    let file = path.display().to_string();
    let bad = |why: String| DpdRunError::Checkpoint {
        file: file.clone(),
        why,
    };
    if c.meta.get("kind").and_then(|k| k.as_str()) != Some("dpd") {
        return Err(bad("not a DPD checkpoint".into()));
    }
    let get = |name: &str| {
        c.get(name)
            .map(|a| a.data.clone())
            .ok_or_else(|| bad(format!("array '{name}' missing")))
    };
    let ids = get("id")?;
    if ids
        .iter()
        .any(|&v| !(v >= 0.0 && v < u32::MAX as f64 && v.fract() == 0.0))
    {
        return Err(bad("particle ids are not integers below 2³²".into()));
    }
    let particles = Particles {
        x: get("x")?,
        y: get("y")?,
        z: get("z")?,
        vx: get("vx")?,
        vy: get("vy")?,
        vz: get("vz")?,
        id: ids.iter().map(|&v| v as u32).collect(),
        moves: get("moves")?,
    };
    let step = get("step")?.first().copied().unwrap_or(f64::NAN);
    if !(step >= 0.0 && step.fract() == 0.0) {
        return Err(bad(format!("step {step} is not a count")));
    }
    let forces = [get("fx")?, get("fy")?, get("fz")?];
    let mut sys = DpdSystem::restore(
        scene.params,
        scene.body,
        particles,
        scene.wall,
        forces,
        step as u64,
    )
    .map_err(|e| bad(format!("does not fit the scene: {e}")))?;
    let counts = get("walls")?;
    if counts.len() != 2 {
        return Err(bad("array 'walls' has the wrong shape".into()));
    }
    (sys.bounces, sys.leaked) = (counts[0] as u64, counts[1] as u64);
    let sampler_state = c
        .get("profile_sampler")
        .ok_or_else(|| bad("array 'profile_sampler' missing".into()))?;
    let sampler = ProfileSampler::from_state(
        flow_geometry(scene),
        scene.params.box_len,
        &sampler_state.data,
        &sampler_state.shape,
    )
    .ok_or_else(|| bad("profile sampler state does not parse".into()))?;
    let rows = get("observables")?;
    let wall = get("wall_s")?.first().copied().unwrap_or(0.0);
    let p0 = get("momentum0")?;
    if p0.len() != 3 || rows.len() % OBS_COLS != 0 {
        return Err(bad("momentum0 or observables have the wrong shape".into()));
    }
    Ok((sys, sampler, rows, wall, [p0[0], p0[1], p0[2]]))
}

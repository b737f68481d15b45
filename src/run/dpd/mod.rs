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
//!   and for periodic Poiseuille flow `"viscosity": {"value", "stderr", …}`;
//! * with cells (`[[dpd.cells]]`): `membranes_SSSSSSSS.vtp` every `save_every` steps (all
//!   membranes, with `cell` and `velocity` point data) and `membranes.pvd` listing them, and
//!   `"membranes"` in the summary (bounces, leaked solvent, each cell's centre, velocity,
//!   area and volume change).

use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use serde_json::json;

pub use super::brownian::Effect;
use crate::dpd::pair_force::Particles;
use crate::dpd::poiseuille::{
    kinetic_theory_viscosity, FlowGeometry, KineticViscosity, ProfileSampler, ViscosityFit,
};
use crate::dpd::suspension::{
    CellState, CellTimings, CouplingParams, DpdSuspension, SuspensionState,
};
use crate::dpd::system::{BodyForce, DpdSystem, DpdTimings, PairForces};
use crate::dpd::walls::Wall;
use crate::dpd::DpdError;
use crate::gpu::{GpuChoice, GpuDecision, GpuError, GpuPrecision};
use crate::io::checkpoint::Checkpoint;
use crate::io::vtk::{write_polydata, write_pvd, DataArray, DataValues, PolyMesh, PvdEntry};
use crate::io::{write_atomic, IoError};
use crate::scene::dpd::DpdScene;

mod checkpoint;
mod model;
mod summary;

use checkpoint::*;
use model::*;
pub use model::{build_fluid, build_suspension, WallWarmup, AUTO_MIN_PARTICLES};
use summary::*;
pub use summary::{CellSummary, DpdSummary, MembraneSummary, ShearRate, ViscositySummary};

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

/// Most steps the GPU runs between looks at the stop flag (Ctrl-C, a scheduler's SIGTERM):
/// under a second at 10⁶ particles on an H200.
const MAX_BATCH_STEPS: u64 = 500;

/// When a run's host must see the state: profile samples at `equilibrate + k·sample_every`
/// up to `sample_end`, rows and checkpoints at multiples of `save_every`, the end at `steps`,
/// and this invocation's stop at `limit`.
#[derive(Clone, Copy, Debug)]
struct Events {
    steps: u64,
    save_every: u64,
    equilibrate: u64,
    sample_every: u64,
    sample_end: u64,
    limit: Option<u64>,
}

impl Events {
    /// Whether the profile is sampled after step `t`.
    fn samples_at(&self, t: u64) -> bool {
        t > self.equilibrate
            && t <= self.sample_end
            && (t - self.equilibrate).is_multiple_of(self.sample_every)
    }

    /// Whether an observables row (and a checkpoint, or the end) comes after step `t`.
    fn saves_at(&self, t: u64) -> bool {
        t.is_multiple_of(self.save_every) || t == self.steps
    }

    /// Steps from `s` to the next step at which the host needs the state (a sample, a save, or
    /// the `limit`), at most [`MAX_BATCH_STEPS`].
    fn steps_to_next(&self, s: u64) -> u64 {
        let mut next = self
            .steps
            .min((s / self.save_every + 1) * self.save_every)
            .min(s + MAX_BATCH_STEPS);
        if let Some(l) = self.limit.filter(|&l| l > s) {
            next = next.min(l);
        }
        if s < self.sample_end {
            let (e, every) = (self.equilibrate, self.sample_every);
            let t = if s < e + every {
                e + every
            } else {
                s + every - (s - e) % every
            };
            if t <= self.sample_end {
                next = next.min(t);
            }
        }
        next.saturating_sub(s).max(1)
    }
}

/// Write the membranes of step `step` (`membranes_SSSSSSSS.vtp`) and the collection of every
/// such frame in `out` (`membranes.pvd`).
fn write_membranes(out: &Path, sim: &DpdSuspension) -> Result<(), DpdRunError> {
    let step = sim.fluid.step;
    let mut mesh = PolyMesh::default();
    let (mut cell, mut vel) = (Vec::new(), Vec::new());
    for (k, c) in sim.cells().iter().enumerate() {
        let base = mesh.points.len();
        mesh.points.extend_from_slice(c.positions());
        mesh.triangles.extend(
            c.membrane()
                .topology()
                .triangles()
                .iter()
                .map(|t| t.map(|i| i + base)),
        );
        cell.extend(std::iter::repeat_n(k as i32, c.positions().len()));
        vel.extend(c.velocities().iter().flatten().copied());
    }
    mesh.point_data.push(DataArray::ints("cell", cell));
    mesh.point_data.push(DataArray {
        name: "velocity".into(),
        components: 3,
        values: DataValues::Float64(vel),
    });
    write_polydata(&out.join(format!("membranes_{step:08}.vtp")), &mesh)?;
    // The collection: every frame in the directory up to this step (a resumed run's earlier
    // frames included, later ones of an abandoned run left out).
    let dt = sim.fluid.params.dt;
    let mut frames: Vec<(u64, String)> = std::fs::read_dir(out)
        .map_err(|source| IoError::File {
            path: out.to_path_buf(),
            source,
        })?
        .filter_map(|e| {
            let name = e.ok()?.file_name().into_string().ok()?;
            let s: u64 = name
                .strip_prefix("membranes_")?
                .strip_suffix(".vtp")?
                .parse()
                .ok()?;
            (s <= step).then_some((s, name))
        })
        .collect();
    frames.sort();
    let entries: Vec<PvdEntry> = frames
        .into_iter()
        .map(|(s, file)| PvdEntry {
            time: s as f64 * dt,
            file,
        })
        .collect();
    write_pvd(&out.join("membranes.pvd"), &entries)?;
    Ok(())
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
                BodyForce::ReversePoiseuille { force } if scene.cells.is_empty() => format!(
                    "flow = \"periodic_poiseuille\", force = {force}: viscosity fitted to the profile"
                ),
                BodyForce::ReversePoiseuille { force } => format!(
                    "flow = \"periodic_poiseuille\", force = {force}: no viscosity fit (the \
                     cells disturb the profile; profile.csv has it)"
                ),
                _ => "flow = \"none\"".into(),
            },
        },
        Effect {
            name: "membranes",
            enabled: !scene.cells.is_empty(),
            reason: if scene.cells.is_empty() {
                "no [[dpd.cells]]".into()
            } else {
                let c = &scene.coupling;
                format!(
                    "{} cell(s), {} vertices: Fedosov membranes from moduli, solvent coupling \
                     gamma_out = {}, gamma_in = {}, k = {}, bounce-back off the moving \
                     triangles, leaks counted every {} steps{}",
                    scene.cells.len(),
                    scene.cells.iter().map(|c| c.spec.vertices.len()).sum::<usize>(),
                    c.gamma_out,
                    c.gamma_in,
                    c.power,
                    c.check_every,
                    if c.inner_extra_gamma > 0.0 {
                        format!(", inner fluid extra gamma {}", c.inner_extra_gamma)
                    } else {
                        String::new()
                    }
                )
            },
        },
        Effect {
            name: "cells of the cell scene ([[cells]])",
            enabled: scene.from_cells.is_some(),
            reason: match &scene.from_cells {
                None => "no [dpd.from_cells]".into(),
                Some(m) => format!(
                    "{} cell(s) mapped by [dpd.from_cells]: x → {:?} + {}·R x (R = {:?}), \
                     G_s → μ0 = G_s·{}/{}², κ_b → κ = κ_b·{}, forces ·{}/{}; the cell scene's \
                     flow is not mapped",
                    m.cells,
                    m.origin,
                    m.length,
                    m.rotation,
                    m.energy,
                    m.length,
                    m.energy,
                    m.energy,
                    m.length
                ),
            },
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
            name: "sliding walls (Couette flow)",
            enabled: scene.wall_speed != 0.0,
            reason: match scene.wall {
                Some(Wall::Planes { lo, hi }) if scene.wall_speed != 0.0 => format!(
                    "flow = \"couette\", wall_speed = ±{}: nominal shear rate {:.4} (2U/gap), \
                     the rate in the channel fitted to the profile",
                    scene.wall_speed,
                    2.0 * scene.wall_speed / (hi - lo)
                ),
                _ => "walls at rest (or none)".into(),
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
    // Where this invocation warmed up the walls (none when it resumes).
    let mut wall_warmup = None;
    let (model, mut sampler, mut rows, mut wall_before, p0, earlier) = if opts.resume {
        restore(scene, &ckpt_path)?
    } else {
        write_atomic(&out.join(SCENE_COPY), scene_text.as_bytes())?;
        let (model, warmup) = build_model(scene)?;
        wall_warmup = warmup;
        if let Some(sim) = model.cells() {
            write_membranes(out, sim)?;
        }
        let sampler = ProfileSampler::with_geometry(
            flow_geometry(scene),
            scene.params.box_len,
            scene.bins,
            scene.block_samples().max(1) as usize,
        );
        let p0 = model.momentum();
        let mut rows = Vec::new();
        push_row(&mut rows, &model);
        (model, sampler, rows, 0.0, p0, None)
    };
    let (mut model, mut fluid_step) = place_fluid(scene, model)?;
    // Where this invocation steps the fluid, as the checkpoint records it; a resumed run that
    // moves between CPU and GPU, or changes precision, says so in the summary's reason.
    let placed = format!(
        "{}{}",
        fluid_step.device,
        fluid_step
            .precision
            .map_or(String::new(), |p| format!(" {}", p.name()))
    );
    if let Some(before) = earlier.filter(|b| *b != placed) {
        fluid_step.reason = format!(
            "{} (this invocation; the steps before the resume ran on {before})",
            fluid_step.reason
        );
    }
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
        b.set_position(model.fluid().step);
        b
    };
    let first = model.fluid().step;
    let events = Events {
        steps: scene.steps,
        save_every: scene.save_every,
        equilibrate: scene.equilibrate,
        sample_every: scene.sample_every,
        sample_end: scene.equilibrate + scene.block_samples() * scene.blocks * scene.sample_every,
        limit: opts.max_steps.map(|m| first + m),
    };
    let start = Instant::now();
    let mut completed = true;
    while model.step_count() < scene.steps {
        if opts
            .max_steps
            .is_some_and(|m| model.step_count() - first >= m)
            || opts
                .stop
                .as_ref()
                .is_some_and(|s| s.load(Ordering::Relaxed))
        {
            completed = false;
            break;
        }
        let chunk = if model.batches() {
            events.steps_to_next(model.step_count())
        } else {
            1
        };
        model.advance(chunk)?;
        let s = model.step_count();
        if events.samples_at(s) {
            model.sample(&mut sampler)?;
        }
        if events.saves_at(s) {
            model.sync()?;
            push_row(&mut rows, &model);
            bar.set_position(s);
            bar.set_message(format!("k_BT = {:.4}", model.fluid().kinetic_temperature()));
            if let Some(sim) = model.cells() {
                write_membranes(out, sim)?;
            }
            if s < scene.steps {
                let wall = wall_before + start.elapsed().as_secs_f64();
                checkpoint(&model, &sampler, &rows, wall, p0, &placed).write(&ckpt_path)?;
            }
        }
    }
    bar.finish_and_clear();
    model.sync()?;
    let done = model.fluid().step - first;
    let this_wall = start.elapsed().as_secs_f64();
    wall_before += this_wall;
    // A stop between saves adds a row at its step; one at a save has it already.
    let last_row_step = rows.chunks_exact(OBS_COLS).last().map(|r| r[0] as u64);
    if !completed && last_row_step != Some(model.step_count()) {
        push_row(&mut rows, &model);
    }
    checkpoint(&model, &sampler, &rows, wall_before, p0, &placed).write(&ckpt_path)?;
    // With cells in the flow the profile is not the fluid's alone: no viscosity is fitted.
    let fit = driving_force(scene)
        .filter(|_| scene.cells.is_empty())
        .and_then(|g| sampler.viscosity(model.fluid().density(), g));
    let flow_kt = sampler.flow_temperature(scene.params.mass);
    let shear = shear_rate(scene, &sampler);
    let mut summary = summarise(
        scene,
        &model,
        fluid_step,
        shear,
        fit.as_ref(),
        flow_kt,
        &rows,
        wall_before,
        p0,
        completed,
        done,
        this_wall,
    );
    summary.wall_warmup = wall_warmup;
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

fn push_row(rows: &mut Vec<f64>, model: &Model) {
    let p = model.momentum();
    let sys = model.fluid();
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The batches end exactly at the next step the per-step loop would act on (or after
    /// `MAX_BATCH_STEPS`): checked against a step-by-step scan over many schedules.
    #[test]
    fn batches_end_at_the_next_event() {
        let mut checked = 0;
        for steps in [1u64, 7, 100, 1234] {
            for save_every in [1u64, 10, 33, 1000] {
                for (equilibrate, sample_every) in [(0u64, 1u64), (5, 3), (20, 10), (0, 7)] {
                    for blocks_end in [0u64, 50, 2000] {
                        let sample_end = blocks_end.min(steps);
                        for limit in [None, Some(9), Some(600)] {
                            let ev = Events {
                                steps,
                                save_every,
                                equilibrate,
                                sample_every,
                                sample_end,
                                limit,
                            };
                            for s in 0..steps {
                                let at = |t: u64| {
                                    ev.samples_at(t) || ev.saves_at(t) || Some(t) == ev.limit
                                };
                                let naive = (s + 1..=steps)
                                    .find(|&t| at(t))
                                    .map_or(steps - s, |t| t - s)
                                    .min(MAX_BATCH_STEPS);
                                assert_eq!(ev.steps_to_next(s), naive, "{ev:?} at {s}");
                                checked += 1;
                            }
                        }
                    }
                }
            }
        }
        assert!(checked > 100_000);
    }
}

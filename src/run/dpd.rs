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
    /// Where the fluid's steps ran and why (`[dpd] gpu`): `{"device": "cpu" | "gpu", "adapter",
    /// "precision", "reason"}`.
    pub fluid_step: GpuDecision,
    /// Where this invocation warmed up the walls' fluid before freezing them (the GPU where
    /// `[dpd] gpu` takes it for a fluid of that size), and how long it took (`null` without
    /// walls or when the run resumed).
    pub wall_warmup: Option<WallWarmup>,
    /// Wall seconds of the steps (all invocations of a resumed run).
    pub wall_s: f64,
    /// Wall milliseconds per step in this invocation (NaN when it took no step).
    pub ms_per_step: f64,
    /// Particles (all of them) times steps per wall second in this invocation.
    pub particle_steps_per_second: f64,
    /// Threads of the rayon pool.
    pub threads: usize,
    /// Seconds per phase (this invocation; the CPU path's phases: all zero when the fluid ran
    /// on the GPU, whose time is in `wall_s`).
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
    /// Particles found inside a wall after the bounce-back (`null` without walls; leaks
    /// through membranes are in `membranes`).
    pub leaked_particles: Option<u64>,
    /// Bounce-backs off the walls (`null` without walls).
    pub bounces: Option<u64>,
    /// Moving (fluid) particles; the rest are frozen wall particles.
    pub fluid_particles: usize,
    /// Periodic or walled Poiseuille flow of the fluid alone: the viscosity fitted to the velocity
    /// profile (`null` with cells, which disturb the profile).
    pub viscosity: Option<ViscositySummary>,
    /// Couette flow: the shear rate fitted to the profile (`null` otherwise).
    pub shear_rate: Option<ShearRate>,
    /// Cells in the fluid (`null` without `[[dpd.cells]]`).
    pub membranes: Option<MembraneSummary>,
}

/// The shear rate of a Couette flow.
#[derive(Clone, Debug, Serialize)]
pub struct ShearRate {
    /// Slope of `u_x(z)` fitted by least squares to the bins in the middle 70 % of the channel.
    pub fitted: f64,
    /// `2U/gap`, the rate without slip at the walls.
    pub nominal: f64,
}

/// The shear rate fitted to the middle 70 % of the channel's profile (Couette flow only).
fn shear_rate(scene: &DpdScene, sampler: &ProfileSampler) -> Option<ShearRate> {
    let Some(Wall::Planes { lo, hi }) = scene.wall else {
        return None;
    };
    if scene.wall_speed == 0.0 || sampler.blocks.is_empty() {
        return None;
    }
    let (mid, half) = (0.5 * (lo + hi), 0.35 * (hi - lo));
    let pts: Vec<(f64, f64)> = sampler
        .profile()
        .into_iter()
        .filter(|(z, _, _)| (z - mid).abs() <= half)
        .map(|(z, v, _)| (z, v))
        .collect();
    let n = pts.len() as f64;
    if n < 2.0 {
        return None;
    }
    let (mz, mv) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let szz: f64 = pts.iter().map(|p| (p.0 - mz).powi(2)).sum();
    let szv: f64 = pts.iter().map(|p| (p.0 - mz) * (p.1 - mv)).sum();
    Some(ShearRate {
        fitted: szv / szz,
        nominal: 2.0 * scene.wall_speed / (hi - lo),
    })
}

/// The cells of a run in `summary.json`.
#[derive(Clone, Debug, Serialize)]
pub struct MembraneSummary {
    /// Number of cells.
    pub cells: usize,
    /// Membrane vertices, all cells.
    pub vertices: usize,
    /// The coupling to the solvent.
    pub coupling: CouplingParams,
    /// Bounce-backs of solvent off membranes.
    pub bounces: u64,
    /// The most solvent particles found on the wrong side of a membrane at any count (every
    /// `coupling.check_every` steps).
    pub leaked_particles: u64,
    /// Solvent on the wrong side at the last count.
    pub leaked_at_last_count: u64,
    /// Kinetic temperature of the vertices now (each cell's mean velocity removed).
    pub vertex_temperature: f64,
    /// Wall seconds of the cells' part of the steps in this invocation, by phase (the fluid's
    /// are in `timings`).
    pub timings: CellTimings,
    /// Per cell.
    pub per_cell: Vec<CellSummary>,
}

/// One cell in `summary.json`.
#[derive(Clone, Debug, Serialize)]
pub struct CellSummary {
    /// Shape as given.
    pub shape: String,
    /// Volume-equivalent radius as given.
    pub radius: f64,
    /// Vertices.
    pub vertices: usize,
    /// Solvent particles inside it.
    pub inner_solvent: usize,
    /// Mean vertex position (unwrapped).
    pub centroid: [f64; 3],
    /// Mean vertex velocity.
    pub velocity: [f64; 3],
    /// External force.
    pub force: [f64; 3],
    /// Area now over the reference area, minus one.
    pub area_change: f64,
    /// Volume now over the reference volume, minus one.
    pub volume_change: f64,
    /// Taylor deformation `D = (L − B)/(L + B)` of the equivalent ellipsoid in the shear
    /// plane `x`–`z` ([`crate::dpd::suspension::FluidCell::shear_plane_deformation`]); the
    /// thermal fluctuations of the membrane make it positive even at rest.
    pub taylor_deformation: f64,
    /// Inclination of the long axis in the `x`–`z` plane, from `x` towards `z`, degrees.
    pub inclination_deg: f64,
}

/// What a run steps: the fluid alone, or cells in it, or the fluid on the GPU.
enum Model {
    Fluid(Box<DpdSystem>),
    /// Cells in the fluid; with a pair-force backend (the GPU's) the solvent's pair forces are
    /// computed there, the rest of the step on the CPU.
    Cells(Box<DpdSuspension>, Option<Box<dyn PairForces>>),
    /// The fluid stepped on the GPU; the host system holds the state as last synced (at every
    /// observables row and checkpoint, and at the end); a profile sample is binned on the
    /// device and reads back only the bins' partial sums.
    #[cfg(feature = "gpu")]
    Gpu(Box<DpdSystem>, Box<crate::dpd::gpu_fluid::GpuFluid>),
}

impl Model {
    fn fluid(&self) -> &DpdSystem {
        match self {
            Model::Fluid(f) => f,
            Model::Cells(s, _) => &s.fluid,
            #[cfg(feature = "gpu")]
            Model::Gpu(f, _) => f,
        }
    }

    /// `steps` steps (on the GPU, the host's copy is brought up to date by [`Self::sync`]).
    fn advance(&mut self, steps: u64) -> Result<(), DpdError> {
        match self {
            Model::Fluid(f) => (0..steps).try_for_each(|_| f.step()),
            Model::Cells(s, pairs) => (0..steps).try_for_each(|_| {
                s.step_with(pairs.as_mut().map(|p| &mut **p as &mut dyn PairForces))
            }),
            #[cfg(feature = "gpu")]
            Model::Gpu(_, dev) => dev.advance(steps),
        }
    }

    /// Steps done.
    fn step_count(&self) -> u64 {
        match self {
            #[cfg(feature = "gpu")]
            Model::Gpu(_, dev) => dev.step(),
            _ => self.fluid().step,
        }
    }

    /// Bring the host's copy of the state up to date (the GPU's fluid; a no-op otherwise).
    fn sync(&mut self) -> Result<(), DpdError> {
        match self {
            #[cfg(feature = "gpu")]
            Model::Gpu(f, dev) if f.step != dev.step() => dev.sync(f),
            _ => Ok(()),
        }
    }

    /// Add the current velocity profile to `sampler` (on the GPU, binned there).
    fn sample(&mut self, sampler: &mut ProfileSampler) -> Result<(), DpdError> {
        match self {
            #[cfg(feature = "gpu")]
            Model::Gpu(_, dev) => dev.sample_profile(sampler),
            _ => {
                sampler.sample(self.fluid());
                Ok(())
            }
        }
    }

    /// Whether steps go in batches up to the next step the host must see (the GPU), rather
    /// than one at a time.
    fn batches(&self) -> bool {
        match self {
            Model::Fluid(_) | Model::Cells(..) => false,
            #[cfg(feature = "gpu")]
            Model::Gpu(..) => true,
        }
    }

    /// Total momentum (solvent and vertices).
    fn momentum(&self) -> [f64; 3] {
        match self {
            Model::Cells(s, _) => s.momentum(),
            _ => self.fluid().momentum(),
        }
    }

    fn cells(&self) -> Option<&DpdSuspension> {
        match self {
            Model::Cells(s, _) => Some(s),
            _ => None,
        }
    }
}

/// Smallest fluid `gpu = "auto"` steps on the GPU. At 10⁵ particles the H200 took 0.09 ms per
/// step against 5.5 ms on 16 CPU threads (benches/RESULTS.md); below about 2·10⁴ the launches
/// and the read-back at every sample (every 10 steps by default) are a large share of a step.
/// With cells (only the solvent's pair forces on the GPU, the state crossing the bus every
/// step) the same threshold holds on the H200 machine: one RBC in 18 480 particles ran hardly
/// faster with the GPU than on 16 CPU threads (3.28 and 3.58 ms per step in `f32` and `f64`
/// against 3.45), and 2.3× faster than on one thread; in 811 008 particles the GPU was 1.6×
/// faster in `f32` than 16 threads (benches/RESULTS.md).
pub const AUTO_MIN_PARTICLES: usize = 20_000;

/// Where the fluid's steps run (`[dpd] gpu`), and why: the model as built, or its fluid moved
/// onto the GPU.
fn place_fluid(scene: &DpdScene, model: Model) -> Result<(Model, GpuDecision), DpdRunError> {
    if scene.gpu == GpuChoice::Off {
        return Ok((model, GpuDecision::cpu(None, "GPU not asked for".into())));
    }
    open_gpu(scene, model)
}

#[cfg(not(feature = "gpu"))]
fn open_gpu(scene: &DpdScene, model: Model) -> Result<(Model, GpuDecision), DpdRunError> {
    match scene.gpu {
        GpuChoice::On => Err(DpdError::Gpu(GpuError::NotBuilt).into()),
        _ => Ok((
            model,
            GpuDecision::cpu(None, "built without the gpu feature".into()),
        )),
    }
}

#[cfg(feature = "gpu")]
fn open_gpu(scene: &DpdScene, model: Model) -> Result<(Model, GpuDecision), DpdRunError> {
    use crate::dpd::gpu_fluid::GpuFluid;
    use crate::dpd::gpu_pairs::GpuPairForces;
    let (gpu, prec, mut reason) = match choose_gpu(scene, model.fluid().len())? {
        Ok(chosen) => chosen,
        Err((adapter, why)) => return Ok((model, GpuDecision::cpu(adapter, why))),
    };
    let adapter = Some(gpu.describe());
    let model = match model {
        Model::Fluid(sys) => {
            let dev = GpuFluid::new(gpu, &sys, prec)?;
            Model::Gpu(sys, Box::new(dev))
        }
        Model::Cells(sim, _) => {
            let pairs = GpuPairForces::new(gpu, &sim.fluid, prec)?;
            reason.push_str(
                "; with cells only the solvent's pair forces run there (the membranes, the \
                 bounce-back off them and the solvent-vertex pairs on the CPU)",
            );
            Model::Cells(sim, Some(Box::new(pairs)))
        }
        Model::Gpu(..) => unreachable!("the model is placed once"),
    };
    Ok((
        model,
        GpuDecision {
            device: "gpu".into(),
            adapter,
            precision: Some(prec),
            reason,
        },
    ))
}

/// The adapter, precision and reason for stepping a fluid of `n` particles on the GPU, or,
/// where `gpu = "auto"` declines, the adapter looked at and why not. Errors where `gpu = true`
/// cannot be served.
#[cfg(feature = "gpu")]
#[allow(clippy::type_complexity)]
fn choose_gpu(
    scene: &DpdScene,
    n: usize,
) -> Result<
    Result<(std::sync::Arc<crate::gpu::Gpu>, GpuPrecision, String), (Option<String>, String)>,
    DpdRunError,
> {
    use crate::gpu::Gpu;
    let auto = scene.gpu == GpuChoice::Auto;
    let gpu = match Gpu::shared() {
        Ok(g) => g,
        Err(e) if auto => return Ok(Err((None, e.to_string()))),
        Err(e) => return Err(DpdError::Gpu(e).into()),
    };
    let adapter = Some(gpu.describe());
    if auto && !gpu.is_hardware() {
        let why = "the adapter is not a hardware GPU (a CPU rasteriser would only compete with the CPU loops)";
        return Ok(Err((adapter, why.into())));
    }
    if auto && n < AUTO_MIN_PARTICLES {
        let why = format!("{n} particles, below the {AUTO_MIN_PARTICLES} where the GPU gains");
        return Ok(Err((adapter, why)));
    }
    let prec = scene.gpu_precision;
    if prec == GpuPrecision::F64 && !gpu.has_f64() {
        if auto {
            let why = "f64 asked for and the adapter has no f64 shaders".to_string();
            return Ok(Err((adapter, why)));
        }
        return Err(DpdError::Gpu(GpuError::NoF64(gpu.describe())).into());
    }
    let reason = match scene.gpu {
        GpuChoice::On => "gpu = true".to_string(),
        _ => format!("a hardware GPU and {n} particles (auto takes at least {AUTO_MIN_PARTICLES})"),
    };
    Ok(Ok((gpu, prec, reason)))
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

/// The fluid of a new run, with the scene's cells put into it, and where the walls' warm-up
/// ran (on the GPU where the scene's fluid may go there: [`warmup_gpu`]).
fn build_model(scene: &DpdScene) -> Result<(Model, Option<WallWarmup>), DpdRunError> {
    let (sys, warmup) = build_fluid_warmed(scene, warmup_gpu(scene)?)?;
    if scene.cells.is_empty() {
        return Ok((Model::Fluid(Box::new(sys)), warmup));
    }
    let sim = put_cells(scene, sys)?;
    Ok((Model::Cells(Box::new(sim), None), warmup))
}

/// Where the walls' warm-up ran, in this invocation (JSON `wall_warmup`).
#[derive(Clone, Debug, Serialize)]
pub struct WallWarmup {
    /// Steps of the periodic fluid before the wall particles froze (`[dpd] wall_warmup`).
    pub steps: u64,
    /// `"cpu"` or `"gpu"`.
    pub device: String,
    /// The GPU's precision (`null` on the CPU).
    pub precision: Option<GpuPrecision>,
    /// Wall seconds of the warm-up (the GPU's include uploading and reading back the fluid).
    pub seconds: f64,
}

/// A warm-up of the walls' fluid on the GPU: its precision, and the run itself (the steps of
/// the periodic fluid, its state read back into it).
struct GpuWarmup {
    precision: GpuPrecision,
    run: Box<WarmupRun>,
}

/// Steps a periodic fluid `steps` times, leaving its state in it.
type WarmupRun = dyn FnOnce(&mut DpdSystem, u64) -> Result<(), DpdError>;

/// The GPU warm-up of the walls' fluid: where `[dpd] gpu` would take the GPU for the periodic
/// fluid of the warm-up (its `round(ρV)` particles, more than the walled fluid keeps), the
/// same adapter and precision; `None` for the CPU.
#[cfg(feature = "gpu")]
fn warmup_gpu(scene: &DpdScene) -> Result<Option<GpuWarmup>, DpdRunError> {
    if scene.gpu == GpuChoice::Off || scene.wall.is_none() || scene.wall_warmup == 0 {
        return Ok(None);
    }
    let n = (scene.density * scene.params.volume()).round() as usize;
    Ok(choose_gpu(scene, n)?
        .ok()
        .map(|(gpu, precision, _)| GpuWarmup {
            precision,
            run: Box::new(move |bulk: &mut DpdSystem, steps: u64| {
                let mut dev = crate::dpd::gpu_fluid::GpuFluid::new(gpu, bulk, precision)?;
                dev.advance(steps)?;
                dev.sync(bulk)
            }),
        }))
}

#[cfg(not(feature = "gpu"))]
fn warmup_gpu(_scene: &DpdScene) -> Result<Option<GpuWarmup>, DpdRunError> {
    Ok(None)
}

/// [`build_fluid`] with the walls' warm-up on `gpu` (the CPU if `None`), and where it ran
/// (`None` without walls).
fn build_fluid_warmed(
    scene: &DpdScene,
    gpu: Option<GpuWarmup>,
) -> Result<(DpdSystem, Option<WallWarmup>), DpdRunError> {
    let (mut sys, warmup) = match scene.wall {
        None => (
            DpdSystem::random_fluid(scene.params, scene.density, scene.body)?,
            None,
        ),
        Some(w) => {
            let t0 = Instant::now();
            let precision = gpu.as_ref().map(|g| g.precision);
            let sys = DpdSystem::with_wall_warmed_by(
                scene.params,
                scene.density,
                scene.body,
                w,
                scene.wall_warmup,
                |bulk, steps| match gpu {
                    None => (0..steps).try_for_each(|_| bulk.step()),
                    Some(g) => (g.run)(bulk, steps),
                },
            )?;
            let warmup = WallWarmup {
                steps: scene.wall_warmup,
                device: if precision.is_some() { "gpu" } else { "cpu" }.into(),
                precision,
                seconds: t0.elapsed().as_secs_f64(),
            };
            (sys, Some(warmup))
        }
    };
    if scene.wall_speed != 0.0 {
        sys.start_couette(scene.wall_speed)?;
    }
    Ok((sys, warmup))
}

/// The fluid of a scene as `mobo dpd` starts it (random particles, or the walls warmed up on
/// the CPU; the walls sliding for Couette flow), without its cells.
///
/// # Errors
/// [`DpdRunError::Dynamics`] for parameters the fluid refuses.
pub fn build_fluid(scene: &DpdScene) -> Result<DpdSystem, DpdRunError> {
    Ok(build_fluid_warmed(scene, None)?.0)
}

/// The scene's fluid ([`build_fluid`]) with its cells (`[[dpd.cells]]` or the cells mapped by
/// `[dpd.from_cells]`) and their external forces, as `mobo dpd` starts it: for a program that
/// steps a DPD scene itself and reads the cells between steps.
///
/// ```no_run
/// use mobo::{run, scene::dpd};
/// let scene = dpd::load(std::path::Path::new("examples/scenes/capsule_shear_bie_and_dpd.toml"))?;
/// let mut sim = run::dpd::build_suspension(&scene)?;
/// for _ in 0..100 {
///     sim.step()?;
/// }
/// let (d, inclination) = sim.cells()[0].shear_plane_deformation();
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
///
/// # Errors
/// [`DpdRunError::Dynamics`] for parameters the fluid or a membrane refuses.
pub fn build_suspension(scene: &DpdScene) -> Result<DpdSuspension, DpdRunError> {
    put_cells(scene, build_fluid(scene)?)
}

/// The scene's cells and their external forces put into `sys`.
fn put_cells(scene: &DpdScene, sys: DpdSystem) -> Result<DpdSuspension, DpdRunError> {
    let specs = scene.cells.iter().map(|c| c.spec.clone()).collect();
    let mut sim = DpdSuspension::new(sys, specs, scene.coupling)?;
    for (k, c) in scene.cells.iter().enumerate() {
        if c.force != [0.0; 3] {
            sim.set_external_force(k, c.force)?;
        }
    }
    Ok(sim)
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

fn membrane_summary(scene: &DpdScene, sim: &DpdSuspension) -> MembraneSummary {
    MembraneSummary {
        cells: sim.cells().len(),
        vertices: sim.cells().iter().map(|c| c.positions().len()).sum(),
        coupling: *sim.coupling(),
        bounces: sim.bounces(),
        leaked_particles: sim.max_leaked(),
        leaked_at_last_count: sim.leaked(),
        vertex_temperature: sim.vertex_temperature(),
        timings: sim.timings(),
        per_cell: sim
            .cells()
            .iter()
            .zip(&scene.cells)
            .enumerate()
            .map(|(k, (c, sc))| {
                let (da, dv) = c.area_volume_change().unwrap_or((f64::NAN, f64::NAN));
                let (deformation, inclination) = c.shear_plane_deformation();
                CellSummary {
                    shape: sc.shape.clone(),
                    radius: sc.radius,
                    vertices: c.positions().len(),
                    inner_solvent: sim.inner_count(k),
                    centroid: c.centroid(),
                    velocity: c.mean_velocity(),
                    force: c.external_force(),
                    area_change: da,
                    volume_change: dv,
                    taylor_deformation: deformation,
                    inclination_deg: inclination,
                }
            })
            .collect(),
    }
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

#[allow(clippy::too_many_arguments)]
fn summarise(
    scene: &DpdScene,
    model: &Model,
    fluid_step: GpuDecision,
    shear: Option<ShearRate>,
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
    let sys = model.fluid();
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
        fluid_step,
        wall_warmup: None,
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
        shear_rate: shear,
        membranes: model.cells().map(|sim| membrane_summary(scene, sim)),
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
    model: &Model,
    sampler: &ProfileSampler,
    rows: &[f64],
    wall: f64,
    p0: [f64; 3],
    placed: &str,
) -> Checkpoint {
    let sys = model.fluid();
    let n = sys.len();
    let mut c = Checkpoint::new(json!({
        "kind": "dpd",
        "step": sys.step,
        "particles": n,
        "bins": sampler.bins,
        "fluid_step": placed,
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
    if let Some(sim) = model.cells() {
        let st = sim.state();
        let flat = |v: &[[f64; 3]]| v.iter().flatten().copied().collect::<Vec<f64>>();
        for (k, cs) in st.cells.iter().enumerate() {
            let nv = cs.x.len();
            c.push(format!("cell{k}_x"), vec![nv, 3], flat(&cs.x));
            c.push(format!("cell{k}_v"), vec![nv, 3], flat(&cs.v));
            c.push(format!("cell{k}_f"), vec![nv, 3], flat(&cs.f));
            c.push(format!("cell{k}_external"), vec![3], cs.external.to_vec());
        }
        c.push(
            "owner",
            vec![st.owner.len()],
            st.owner.iter().map(|&o| o as f64).collect(),
        );
        c.push(
            "membrane_counters",
            vec![3],
            st.counters.iter().map(|&v| v as f64).collect(),
        );
    }
    c
}

/// A restored run: the model, the sampler, the observables rows, the wall time so far, the
/// initial momentum, and where the earlier invocations stepped the fluid (`None`: not recorded).
type Restored = (
    Model,
    ProfileSampler,
    Vec<f64>,
    f64,
    [f64; 3],
    Option<String>,
);

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
    // The frozen particles' velocities are in the checkpoint; the bounce-back needs the speed.
    sys.wall_speed = scene.wall_speed;
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
    let model = if scene.cells.is_empty() {
        Model::Fluid(Box::new(sys))
    } else {
        let triples = |name: &str, n: usize| -> Result<Vec<[f64; 3]>, DpdRunError> {
            let v = get(name)?;
            if v.len() != 3 * n {
                return Err(bad(format!(
                    "array '{name}' has {} values, the scene's cell needs {}",
                    v.len(),
                    3 * n
                )));
            }
            Ok(v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
        };
        let mut cells = Vec::with_capacity(scene.cells.len());
        for (k, sc) in scene.cells.iter().enumerate() {
            let nv = sc.spec.vertices.len();
            let ext = triples(&format!("cell{k}_external"), 1)?;
            cells.push(CellState {
                x: triples(&format!("cell{k}_x"), nv)?,
                v: triples(&format!("cell{k}_v"), nv)?,
                f: triples(&format!("cell{k}_f"), nv)?,
                external: ext[0],
            });
        }
        let owner = get("owner")?;
        if owner
            .iter()
            .any(|&o| !(o >= 0.0 && o <= u32::MAX as f64 && o.fract() == 0.0))
        {
            return Err(bad(
                "array 'owner' holds values that are not cell indices".into()
            ));
        }
        let counters = get("membrane_counters")?;
        if counters.len() != 3 {
            return Err(bad("array 'membrane_counters' has the wrong shape".into()));
        }
        let state = SuspensionState {
            cells,
            owner: owner.iter().map(|&o| o as u32).collect(),
            counters: [counters[0] as u64, counters[1] as u64, counters[2] as u64],
        };
        let specs = scene.cells.iter().map(|c| c.spec.clone()).collect();
        Model::Cells(
            Box::new(
                DpdSuspension::restore(sys, specs, scene.coupling, state)
                    .map_err(|e| bad(format!("does not fit the scene: {e}")))?,
            ),
            None,
        )
    };
    let earlier = c
        .meta
        .get("fluid_step")
        .and_then(|v| v.as_str())
        .map(str::to_string);
    Ok((model, sampler, rows, wall, [p0[0], p0[1], p0[2]], earlier))
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

//! What a DPD run steps ([`Model`]): the fluid alone, cells in it, or the fluid on the GPU;
//! where its steps run (`[dpd] gpu`), and how a new run's fluid and cells are built.

use super::*;

/// What a run steps: the fluid alone, or cells in it, or the fluid on the GPU.
pub(super) enum Model {
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
    pub(super) fn fluid(&self) -> &DpdSystem {
        match self {
            Model::Fluid(f) => f,
            Model::Cells(s, _) => &s.fluid,
            #[cfg(feature = "gpu")]
            Model::Gpu(f, _) => f,
        }
    }

    /// `steps` steps (on the GPU, the host's copy is brought up to date by [`Self::sync`]).
    pub(super) fn advance(&mut self, steps: u64) -> Result<(), DpdError> {
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
    pub(super) fn step_count(&self) -> u64 {
        match self {
            #[cfg(feature = "gpu")]
            Model::Gpu(_, dev) => dev.step(),
            _ => self.fluid().step,
        }
    }

    /// Bring the host's copy of the state up to date (the GPU's fluid; a no-op otherwise).
    pub(super) fn sync(&mut self) -> Result<(), DpdError> {
        match self {
            #[cfg(feature = "gpu")]
            Model::Gpu(f, dev) if f.step != dev.step() => dev.sync(f),
            _ => Ok(()),
        }
    }

    /// Add the current velocity profile to `sampler` (on the GPU, binned there).
    pub(super) fn sample(&mut self, sampler: &mut ProfileSampler) -> Result<(), DpdError> {
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
    pub(super) fn batches(&self) -> bool {
        match self {
            Model::Fluid(_) | Model::Cells(..) => false,
            #[cfg(feature = "gpu")]
            Model::Gpu(..) => true,
        }
    }

    /// Total momentum (solvent and vertices).
    pub(super) fn momentum(&self) -> [f64; 3] {
        match self {
            Model::Cells(s, _) => s.momentum(),
            _ => self.fluid().momentum(),
        }
    }

    pub(super) fn cells(&self) -> Option<&DpdSuspension> {
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
pub(super) fn place_fluid(
    scene: &DpdScene,
    model: Model,
) -> Result<(Model, GpuDecision), DpdRunError> {
    if scene.gpu == GpuChoice::Off {
        return Ok((model, GpuDecision::cpu(None, "GPU not asked for".into())));
    }
    open_gpu(scene, model)
}

#[cfg(not(feature = "gpu"))]
pub(super) fn open_gpu(
    scene: &DpdScene,
    model: Model,
) -> Result<(Model, GpuDecision), DpdRunError> {
    match scene.gpu {
        GpuChoice::On => Err(DpdError::Gpu(GpuError::NotBuilt).into()),
        _ => Ok((
            model,
            GpuDecision::cpu(None, "built without the gpu feature".into()),
        )),
    }
}

#[cfg(feature = "gpu")]
pub(super) fn open_gpu(
    scene: &DpdScene,
    model: Model,
) -> Result<(Model, GpuDecision), DpdRunError> {
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
pub(super) fn choose_gpu(
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

/// The fluid of a new run, with the scene's cells put into it, and where the walls' warm-up
/// ran (on the GPU where the scene's fluid may go there: [`warmup_gpu`]).
pub(super) fn build_model(scene: &DpdScene) -> Result<(Model, Option<WallWarmup>), DpdRunError> {
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
pub(super) struct GpuWarmup {
    precision: GpuPrecision,
    run: Box<WarmupRun>,
}

/// Steps a periodic fluid `steps` times, leaving its state in it.
pub(super) type WarmupRun = dyn FnOnce(&mut DpdSystem, u64) -> Result<(), DpdError>;

/// The GPU warm-up of the walls' fluid: where `[dpd] gpu` would take the GPU for the periodic
/// fluid of the warm-up (its `round(ρV)` particles, more than the walled fluid keeps), the
/// same adapter and precision; `None` for the CPU.
#[cfg(feature = "gpu")]
pub(super) fn warmup_gpu(scene: &DpdScene) -> Result<Option<GpuWarmup>, DpdRunError> {
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
pub(super) fn warmup_gpu(_scene: &DpdScene) -> Result<Option<GpuWarmup>, DpdRunError> {
    Ok(None)
}

/// [`build_fluid`] with the walls' warm-up on `gpu` (the CPU if `None`), and where it ran
/// (`None` without walls).
pub(super) fn build_fluid_warmed(
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
pub(super) fn put_cells(scene: &DpdScene, sys: DpdSystem) -> Result<DpdSuspension, DpdRunError> {
    let specs = scene.cells.iter().map(|c| c.spec.clone()).collect();
    let mut sim = DpdSuspension::new(sys, specs, scene.coupling)?;
    for (k, c) in scene.cells.iter().enumerate() {
        if c.force != [0.0; 3] {
            sim.set_external_force(k, c.force)?;
        }
    }
    Ok(sim)
}

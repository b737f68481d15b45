//! What a DPD run reports in `summary.json`: the fitted viscosity, the shear rate of a Couette
//! flow, the membranes, and the settings, timings and drifts of the run.

use super::*;

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
pub(super) fn shear_rate(scene: &DpdScene, sampler: &ProfileSampler) -> Option<ShearRate> {
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

pub(super) fn membrane_summary(scene: &DpdScene, sim: &DpdSuspension) -> MembraneSummary {
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

#[allow(clippy::too_many_arguments)]
pub(super) fn summarise(
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

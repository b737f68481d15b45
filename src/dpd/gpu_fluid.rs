//! The DPD fluid stepped on the GPU (feature `gpu`).
//!
//! [`GpuFluid`] takes a [`DpdSystem`] (periodic, or with a plane or cylinder wall of frozen
//! particles, resting or sliding; for cells in the fluid only the solvent's pair forces go to
//! the GPU: [`super::gpu_pairs`]), uploads it, and
//! advances it on the device with the same step as [`DpdSystem::step`] (see `crate::gpu::dpd`
//! for the passes):
//! velocity-Verlet, cell lists rebuilt every step, the pair force
//! `F_ij = [a w − γ w_R² (v_ij·e) + σ w_R ξ_ij/√dt] e` with the same counter-based noise
//! `ξ_ij(seed, step, min id, max id)`, the same body forces, the same bounce-back off the wall
//! (bisection for the crossing, velocity reversed relative to the wall). [`GpuFluid::sync`] writes the
//! device's state back into the host system, for observables, sampling and checkpoints; CPU
//! steps can continue from it.
//!
//! In `f64` one step agrees with the CPU's to rounding (the sums run in another order), and
//! trajectories stay together until the chaos of the many-body dynamics amplifies that rounding.
//! In `f32` (the precision of GPU DPD codes such as Mirheo) the statistics agree: temperature,
//! pressure, viscosity (docs/dpd_gpu_validation.md). With walls in `f32`, a particle within about
//! `10⁻⁶` of the wall surface can round into it on upload; its next drift then counts it as a
//! leak (`leaked`), which the runs so far never showed. Runs on one device are reproducible bit for bit (each cell's particles
//! are ordered by id, so every sum has a fixed order).
//!
//! # Example
//! ```no_run
//! use mobo::dpd::gpu_fluid::GpuFluid;
//! use mobo::dpd::pair_force::PairParams;
//! use mobo::dpd::system::{BodyForce, DpdParams, DpdSystem};
//! use mobo::gpu::{Gpu, GpuPrecision};
//!
//! let pair = PairParams { a: 25.0, gamma: 4.5, kbt: 1.0, rc: 1.0, power: 1.0 };
//! let params = DpdParams { box_len: [32.0; 3], pair, dt: 0.01, mass: 1.0, seed: 1 };
//! let mut fluid = DpdSystem::random_fluid(params, 3.0, BodyForce::None)?;
//! let mut gpu = GpuFluid::new(Gpu::shared()?, &fluid, GpuPrecision::F32)?;
//! gpu.advance(1000)?;
//! gpu.sync(&mut fluid)?;
//! println!("k_BT = {:.3} after {} steps", fluid.kinetic_temperature(), fluid.step);
//! # Ok::<(), mobo::dpd::DpdError>(())
//! ```

use std::sync::Arc;

use super::cell_list::CellGrid;
use super::pair_force::Particles;
use super::poiseuille::{FlowGeometry, ProfileSampler};
use super::rng::mix64;
use super::system::{BodyForce, DpdSystem};
use super::walls::Wall;
use super::DpdError;
use crate::gpu::dpd::{DpdFluidPass, DpdFluidSpec, WallSpec};
use crate::gpu::dpd_profile::ProfileSpec;
use crate::gpu::{Gpu, GpuError, GpuPrecision};

/// A DPD fluid resident on the GPU.
pub struct GpuFluid {
    pass: DpdFluidPass,
    step: u64,
    /// The host system's bounce and leak counts when the fluid was uploaded.
    bounces0: u64,
    leaked0: u64,
}

impl GpuFluid {
    /// Upload `sys` (its particles, their current forces, the wall and its speed, and the step
    /// count).
    pub fn new(gpu: Arc<Gpu>, sys: &DpdSystem, precision: GpuPrecision) -> Result<Self, DpdError> {
        let spec = fluid_spec(sys)?;
        let p = &sys.particles;
        let zip3 = |a: &[f64], b: &[f64], c: &[f64]| -> Vec<[f64; 3]> {
            a.iter()
                .zip(b)
                .zip(c)
                .map(|((&a, &b), &c)| [a, b, c])
                .collect()
        };
        let pass = DpdFluidPass::new(
            gpu,
            precision,
            &spec,
            &zip3(&p.x, &p.y, &p.z),
            &zip3(&p.vx, &p.vy, &p.vz),
            &zip3(&sys.fx, &sys.fy, &sys.fz),
            &p.id,
            &p.moves,
            sys.step,
        )?;
        Ok(GpuFluid {
            pass,
            step: sys.step,
            bounces0: sys.bounces,
            leaked0: sys.leaked,
        })
    }

    /// Particles.
    pub fn len(&self) -> usize {
        self.pass.len()
    }

    /// Whether there are none (never).
    pub fn is_empty(&self) -> bool {
        self.pass.is_empty()
    }

    /// The precision the device computes in.
    pub fn precision(&self) -> GpuPrecision {
        self.pass.precision()
    }

    /// `"NVIDIA H100 … (Vulkan)"`.
    pub fn adapter(&self) -> String {
        self.pass.gpu().describe()
    }

    /// Run `steps` steps on the device.
    pub fn advance(&mut self, steps: u64) -> Result<(), DpdError> {
        self.pass.advance(steps)?;
        self.step += steps;
        Ok(())
    }

    /// Steps done (on the device; the host system has the count of the last sync).
    pub fn step(&self) -> u64 {
        self.step
    }

    /// Add the device's current state to a velocity-profile sampler. The particles are binned
    /// on the device (`crate::gpu::dpd_profile`); only each bin's `Σ v_x` and count per chunk
    /// of 1024 particles come back.
    pub fn sample_profile(&mut self, sampler: &mut ProfileSampler) -> Result<(), DpdError> {
        let spec = ProfileSpec {
            bins: u32::try_from(sampler.bins).map_err(|_| {
                DpdError::Gpu(GpuError::Shape(format!("{} profile bins", sampler.bins)))
            })?,
            scale: sampler.bin_scale(),
            radial_center: match sampler.geometry {
                FlowGeometry::Pipe { center, .. } => Some(center),
                _ => None,
            },
        };
        let sums = self.pass.profile_sums(&spec)?;
        if let Some(id) = sums.unstable {
            return Err(DpdError::Unstable {
                step: self.step,
                particle: id as usize,
                position: [f64::NAN; 3],
            });
        }
        sampler
            .add_binned(&sums.sum_v, &sums.count)
            .expect("the spec has the sampler's bins");
        Ok(())
    }

    /// The force pass alone, `reps` times over the current state, for timing the pass against
    /// the whole step: positions and velocities stay, the forces are overwritten (with those
    /// of the end-of-step velocities), so do not step on after it.
    pub fn forces_only(&mut self, reps: u64) -> Result<(), DpdError> {
        Ok(self.pass.forces_only(reps)?)
    }

    /// Write the device's state into `sys` (the system this fluid was made from): particles,
    /// forces, step count and virial (the virial of the device's last force evaluation: 0
    /// before its first step). An error if a particle left the box by more than a box length
    /// in one step or became non-finite ([`DpdError::Unstable`]: `step` is the device's step
    /// count at the sync, at or after the step it happened; the position is the particle's at
    /// the last sync).
    pub fn sync(&self, sys: &mut DpdSystem) -> Result<(), DpdError> {
        let st = self.pass.read()?;
        if let Some(id) = st.unstable {
            return Err(unstable(sys, st.step, id));
        }
        let col = |v: &[[f64; 3]], k: usize| v.iter().map(|c| c[k]).collect::<Vec<f64>>();
        let particles = Particles {
            x: col(&st.x, 0),
            y: col(&st.x, 1),
            z: col(&st.x, 2),
            vx: col(&st.v, 0),
            vy: col(&st.v, 1),
            vz: col(&st.v, 2),
            id: st.id,
            moves: st.moves,
        };
        let virial = st.virial.iter().sum();
        sys.bounces = self.bounces0 + st.bounces;
        sys.leaked = self.leaked0 + st.leaked;
        sys.load_state(
            particles,
            [col(&st.f, 0), col(&st.f, 1), col(&st.f, 2)],
            st.step,
            virial,
        );
        Ok(())
    }
}

/// The fluid's parameters as the GPU passes take them: its pair force, cell grid, noise key,
/// body force and wall.
pub(crate) fn fluid_spec(sys: &DpdSystem) -> Result<DpdFluidSpec, DpdError> {
    let prm = &sys.params;
    let grid = CellGrid::new(prm.box_len, prm.pair.rc)?;
    let (reverse, body) = match sys.body {
        BodyForce::None => (0.0, [0.0; 3]),
        BodyForce::Constant(g) => (0.0, g),
        BodyForce::ReversePoiseuille { force } => (force, [0.0; 3]),
    };
    Ok(DpdFluidSpec {
        box_len: prm.box_len,
        dims: grid.dims.map(|d| d as u32),
        a: prm.pair.a,
        gamma: prm.pair.gamma,
        sigma: prm.pair.sigma(),
        rc: prm.pair.rc,
        power: prm.pair.power,
        dt: prm.dt,
        mass: prm.mass,
        key0: mix64(prm.seed ^ super::rng::SEED_MIX),
        body,
        reverse_poiseuille: reverse,
        wall: sys.wall.map(|w| match w {
            Wall::Planes { lo, hi } => WallSpec::Planes { lo, hi },
            Wall::Cylinder { radius, center } => WallSpec::Cylinder { radius, center },
        }),
        wall_speed: sys.wall_speed,
    })
}

/// The instability of particle `id` found at device step `step`, with its position at the
/// host's last sync (the device has already set the bad coordinates to 0).
fn unstable(sys: &DpdSystem, step: u64, id: u32) -> DpdError {
    let p = &sys.particles;
    let position =
        p.id.iter()
            .position(|&i| i == id)
            .map_or([f64::NAN; 3], |k| [p.x[k], p.y[k], p.z[k]]);
    DpdError::Unstable {
        step,
        particle: id as usize,
        position,
    }
}

//! A DPD fluid in a periodic box: state, time step and observables.
//!
//! The step is velocity-Verlet (Groot & Warren 1997 with `λ = ½`):
//!
//! ```text
//! v ← v + (dt/2m) F;   x ← x + dt v;   F ← F(x, v);   v ← v + (dt/2m) F,
//! ```
//!
//! the dissipative force seeing the half-step velocity. After the drift the particles are
//! wrapped into the box, binned and sorted by cell ([`super::cell_list`]); the pair forces
//! follow ([`super::pair_force::cell_forces`]), then the body force. The pair noise of the
//! force evaluation that ends step `s` is keyed on `(seed, s)`, so a run restarted from a
//! checkpoint (which stores positions, velocities, forces and ids in their current order)
//! continues bit for bit.

use super::cell_list::{CellGrid, CellList};
use super::pair_force::{cell_forces, PairParams, Particles};
use super::rng::{normal, step_key, stream, unit_interval};
use super::walls::Wall;
use super::{require, DpdError};

/// A body force on every particle.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub enum BodyForce {
    /// None.
    None,
    /// The same force on every particle.
    Constant([f64; 3]),
    /// The periodic (reverse) Poiseuille force of Backer et al. (2005): `+g x̂` on particles
    /// with `z < L_z/2`, `−g x̂` on the others. Two counter-flowing Poiseuille profiles form,
    /// `u_x(z) = (n g / 2η) z (L_z/2 − z)` in the lower half (`n` the number density).
    ReversePoiseuille {
        /// The magnitude `g` of the force per particle.
        force: f64,
    },
}

/// Where the solvent's pair forces are computed: by default the CPU loops
/// ([`cell_forces`], the reference), or elsewhere through this seam, such as a GPU
/// (`crate::dpd::gpu_pairs::GpuPairForces`, feature `gpu`), for the steps of cells in the fluid
/// ([`super::suspension::DpdSuspension::step_with`]).
pub trait PairForces {
    /// Set `f` to the pair forces (conservative, dissipative and random, no body force) of
    /// the particles `p`, sorted by `cells`, with the pair noise of step `step`
    /// (`step_key(seed, step)`), and return the virial `Σ_{i<j} r_ij·F^C_ij`.
    fn pair_forces(
        &mut self,
        pair: &PairParams,
        p: &Particles,
        cells: &CellList,
        step: u64,
        f: [&mut [f64]; 3],
    ) -> Result<f64, DpdError>;
}

/// Fluid parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DpdParams {
    /// Box side lengths (periodic in every direction).
    pub box_len: [f64; 3],
    /// The pair force.
    pub pair: PairParams,
    /// Time step.
    pub dt: f64,
    /// Particle mass.
    pub mass: f64,
    /// Seed of the noise and of the initial state.
    pub seed: u64,
}

impl DpdParams {
    /// Check the parameters.
    pub fn validate(&self) -> Result<(), DpdError> {
        self.pair.validate()?;
        require(
            self.dt.is_finite() && self.dt > 0.0,
            "dt",
            self.dt,
            "must be positive",
        )?;
        require(
            self.mass.is_finite() && self.mass > 0.0,
            "mass",
            self.mass,
            "must be positive",
        )?;
        CellGrid::new(self.box_len, self.pair.rc).map(|_| ())
    }

    /// Box volume.
    pub fn volume(&self) -> f64 {
        self.box_len.iter().product()
    }
}

/// Wall-clock seconds per phase, summed over steps.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct DpdTimings {
    /// Kicks and drift.
    pub integrate_s: f64,
    /// Binning and sorting by cell.
    pub sort_s: f64,
    /// Pair forces.
    pub forces_s: f64,
}

/// The fluid: parameters, particles (sorted by cell), forces, step counter.
#[derive(Clone, Debug)]
pub struct DpdSystem {
    /// Parameters.
    pub params: DpdParams,
    /// Body force.
    pub body: BodyForce,
    /// Particles, sorted by cell.
    pub particles: Particles,
    /// Forces on the particles at the current positions (pair + body), `x` component.
    pub fx: Vec<f64>,
    /// Forces, `y` component.
    pub fy: Vec<f64>,
    /// Forces, `z` component.
    pub fz: Vec<f64>,
    /// Steps done.
    pub step: u64,
    /// Virial `Σ_{i<j} r_ij·F^C_ij` of the last force evaluation.
    pub virial: f64,
    /// Time per phase.
    pub timings: DpdTimings,
    /// The wall, if any (frozen particles have `moves = 0`).
    pub wall: Option<Wall>,
    /// Bounce-backs off the wall so far.
    pub bounces: u64,
    /// Moving particles found inside the wall after a step's bounce-back (should stay 0).
    pub leaked: u64,
    /// Speed `U` of plane walls sliding along `x` (Couette flow): the upper wall moves at
    /// `+U`, the lower at `−U` ([`Self::start_couette`]); 0 for resting walls.
    pub wall_speed: f64,
    cells: CellList,
    perm: Vec<u32>,
    scratch: [Vec<f64>; 7],
    scratch_id: Vec<u32>,
    virials: Vec<f64>,
}

impl DpdSystem {
    /// A fluid of number density `density`: `round(density·V)` particles placed uniformly at
    /// random, velocities Maxwellian at `k_BT` with the mean removed (all from the seed).
    pub fn random_fluid(
        params: DpdParams,
        density: f64,
        body: BodyForce,
    ) -> Result<Self, DpdError> {
        params.validate()?;
        require(
            density.is_finite() && density > 0.0,
            "density",
            density,
            "must be positive",
        )?;
        let n = (density * params.volume()).round() as usize;
        require(
            n >= 2 && n < u32::MAX as usize,
            "particle count",
            n as f64,
            "density × volume must give between 2 and 2³² particles",
        )?;
        let seed = params.seed;
        let l = params.box_len;
        let u = |tag: u64, i: usize| unit_interval(stream(seed, tag, i as u64));
        let g = |tag: u64, i: usize| {
            normal(
                stream(seed, tag, 2 * i as u64),
                stream(seed, tag, 2 * i as u64 + 1),
            )
        };
        let s = (params.pair.kbt / params.mass).sqrt();
        let mut p = Particles {
            x: (0..n).map(|i| u(1, i) * l[0]).collect(),
            y: (0..n).map(|i| u(2, i) * l[1]).collect(),
            z: (0..n).map(|i| u(3, i) * l[2]).collect(),
            vx: (0..n).map(|i| s * g(4, i)).collect(),
            vy: (0..n).map(|i| s * g(5, i)).collect(),
            vz: (0..n).map(|i| s * g(6, i)).collect(),
            id: (0..n as u32).collect(),
            moves: vec![1.0; n],
        };
        for v in [&mut p.vx, &mut p.vy, &mut p.vz] {
            let mean = v.iter().sum::<f64>() / n as f64;
            v.iter_mut().for_each(|c| *c -= mean);
        }
        Self::from_particles(params, body, p)
    }

    /// A system from given particles (positions inside the box); computes the forces.
    pub fn from_particles(
        params: DpdParams,
        body: BodyForce,
        particles: Particles,
    ) -> Result<Self, DpdError> {
        Self::from_particles_with_wall(params, body, particles, None)
    }

    /// [`Self::from_particles`] with a wall (frozen particles have `moves = 0`).
    pub fn from_particles_with_wall(
        params: DpdParams,
        body: BodyForce,
        particles: Particles,
        wall: Option<Wall>,
    ) -> Result<Self, DpdError> {
        params.validate()?;
        let n = particles.len();
        for (what, len) in [
            ("y", particles.y.len()),
            ("z", particles.z.len()),
            ("vx", particles.vx.len()),
            ("vy", particles.vy.len()),
            ("vz", particles.vz.len()),
            ("id", particles.id.len()),
            ("moves", particles.moves.len()),
        ] {
            if len != n {
                return Err(DpdError::Length {
                    what,
                    len,
                    expected: n,
                });
            }
        }
        let mut sys = DpdSystem {
            cells: CellList::new(CellGrid::new(params.box_len, params.pair.rc)?),
            params,
            body,
            particles,
            fx: vec![0.0; n],
            fy: vec![0.0; n],
            fz: vec![0.0; n],
            step: 0,
            virial: 0.0,
            timings: DpdTimings::default(),
            wall,
            bounces: 0,
            leaked: 0,
            wall_speed: 0.0,
            perm: Vec::new(),
            scratch: Default::default(),
            scratch_id: Vec::new(),
            virials: Vec::new(),
        };
        sys.wrap_and_check(0)?;
        sys.sort();
        sys.compute_forces();
        Ok(sys)
    }

    /// A system restored from a checkpoint: particles in their stored order with their
    /// stored forces (no force evaluation), so stepping continues bit for bit.
    pub fn restore(
        params: DpdParams,
        body: BodyForce,
        particles: Particles,
        wall: Option<Wall>,
        forces: [Vec<f64>; 3],
        step: u64,
    ) -> Result<Self, DpdError> {
        // The force evaluation here also restores the virial (positions only); its forces are
        // replaced by the stored ones, which saw the half-step velocities.
        let mut sys = Self::from_particles_with_wall(params, body, particles, wall)?;
        let n = sys.particles.len();
        for f in &forces {
            if f.len() != n {
                return Err(DpdError::Length {
                    what: "forces",
                    len: f.len(),
                    expected: n,
                });
            }
        }
        // The sort is stable: a stored (already sorted) order is unchanged, but map the stored
        // forces through the permutation in case it was not.
        let [gx, gy, gz] = forces;
        sys.fx = sys.perm.iter().map(|&o| gx[o as usize]).collect();
        sys.fy = sys.perm.iter().map(|&o| gy[o as usize]).collect();
        sys.fz = sys.perm.iter().map(|&o| gz[o as usize]).collect();
        sys.step = step;
        Ok(sys)
    }

    /// Replace the particles, their forces, the step count and the virial with a state
    /// computed elsewhere (the GPU path): the particles are sorted by cell again and the forces
    /// follow them, so CPU steps can continue from the state.
    #[cfg(feature = "gpu")]
    pub(crate) fn load_state(
        &mut self,
        particles: Particles,
        forces: [Vec<f64>; 3],
        step: u64,
        virial: f64,
    ) {
        self.particles = particles;
        self.sort();
        let [gx, gy, gz] = forces;
        self.fx = self.perm.iter().map(|&o| gx[o as usize]).collect();
        self.fy = self.perm.iter().map(|&o| gy[o as usize]).collect();
        self.fz = self.perm.iter().map(|&o| gz[o as usize]).collect();
        self.step = step;
        self.virial = virial;
    }

    /// Number of particles.
    pub fn len(&self) -> usize {
        self.particles.len()
    }

    /// Whether there are no particles.
    pub fn is_empty(&self) -> bool {
        self.particles.is_empty()
    }

    /// Simulated time.
    pub fn time(&self) -> f64 {
        self.step as f64 * self.params.dt
    }

    /// Number density.
    pub fn density(&self) -> f64 {
        match self.wall {
            None => self.len() as f64 / self.params.volume(),
            Some(w) => self.n_moving() as f64 / w.fluid_volume(self.params.box_len),
        }
    }

    /// One velocity-Verlet step.
    pub fn step(&mut self) -> Result<(), DpdError> {
        self.kick_and_drift();
        self.settle()?;
        self.kick();
        Ok(())
    }

    /// The first half of a step: the half kick `v += (dt/2m) F`, the drift `x += dt v` (positions
    /// not yet wrapped into the box) and the step counter. The drift of moving particle `i` was
    /// `dt · v_i` with its current `v_i`.
    pub(crate) fn kick_and_drift(&mut self) {
        let t0 = std::time::Instant::now();
        let h = 0.5 * self.params.dt / self.params.mass;
        let dt = self.params.dt;
        let p = &mut self.particles;
        add_masked3(
            [&mut p.vx, &mut p.vy, &mut p.vz],
            [&self.fx, &self.fy, &self.fz],
            h,
            &p.moves,
        );
        add_masked3(
            [&mut p.x, &mut p.y, &mut p.z],
            [&p.vx, &p.vy, &p.vz],
            dt,
            &p.moves,
        );
        self.step += 1;
        self.timings.integrate_s += t0.elapsed().as_secs_f64();
    }

    /// After the drift: the wall's bounce-back, wrapping into the box, the sort by cell and the
    /// pair and body forces at the new positions (noise of the current step).
    pub(crate) fn settle(&mut self) -> Result<(), DpdError> {
        self.settle_with(None)
    }

    /// [`Self::settle`] with the pair forces from `pairs` (the CPU loops if `None`).
    pub(crate) fn settle_with(
        &mut self,
        pairs: Option<&mut dyn PairForces>,
    ) -> Result<(), DpdError> {
        let t1 = std::time::Instant::now();
        self.bounce_back();
        self.wrap_and_check(self.step)?;
        let t2 = std::time::Instant::now();
        self.sort();
        let t3 = std::time::Instant::now();
        match pairs {
            None => self.compute_forces(),
            Some(pairs) => {
                self.virial = pairs.pair_forces(
                    &self.params.pair,
                    &self.particles,
                    &self.cells,
                    self.step,
                    [&mut self.fx, &mut self.fy, &mut self.fz],
                )?;
                self.add_body_force();
            }
        }
        let t4 = std::time::Instant::now();
        self.timings.integrate_s += (t2 - t1).as_secs_f64();
        self.timings.sort_s += (t3 - t2).as_secs_f64();
        self.timings.forces_s += (t4 - t3).as_secs_f64();
        Ok(())
    }

    /// The second half kick `v += (dt/2m) F` with the forces of [`Self::settle`] (and whatever
    /// a coupled model added to them since).
    pub(crate) fn kick(&mut self) {
        let t0 = std::time::Instant::now();
        let h = 0.5 * self.params.dt / self.params.mass;
        let p = &mut self.particles;
        add_masked3(
            [&mut p.vx, &mut p.vy, &mut p.vz],
            [&self.fx, &self.fy, &self.fz],
            h,
            &p.moves,
        );
        self.timings.integrate_s += t0.elapsed().as_secs_f64();
    }

    /// The cell list of the particles as last sorted (by [`Self::settle`]).
    pub(crate) fn cell_list(&self) -> &CellList {
        &self.cells
    }

    /// The cell list and the particles (sorted by it), with the force arrays to add to: what
    /// a coupled model needs to add pair forces with the solvent.
    pub(crate) fn split_for_coupling(&mut self) -> (&CellList, &Particles, [&mut Vec<f64>; 3]) {
        (
            &self.cells,
            &self.particles,
            [&mut self.fx, &mut self.fy, &mut self.fz],
        )
    }

    /// Bounce the moving particles that drifted into the wall back (see [`super::walls`]),
    /// and count those still inside.
    fn bounce_back(&mut self) {
        let Some(wall) = self.wall else { return };
        let dt = self.params.dt;
        let p = &mut self.particles;
        for i in 0..p.x.len() {
            if p.moves[i] == 0.0 {
                continue;
            }
            let x = [p.x[i], p.y[i], p.z[i]];
            if wall.sdf(x) < 0.0 {
                continue;
            }
            let (x, v) = wall.bounce(x, [p.vx[i], p.vy[i], p.vz[i]], dt);
            // Off a sliding wall the velocity relative to it is reversed: v' = 2 U_w − v.
            let uw = wall_velocity(wall, self.wall_speed, x);
            (p.x[i], p.y[i], p.z[i]) = (x[0], x[1], x[2]);
            (p.vx[i], p.vy[i], p.vz[i]) = (v[0] + 2.0 * uw[0], v[1], v[2]);
            self.bounces += 1;
            if wall.sdf(x) >= 0.0 {
                self.leaked += 1;
            }
        }
    }

    /// Slide plane walls along `x` at `±speed` and start the Couette flow of shear rate about
    /// `2 speed / gap`): the frozen particles above the channel's middle take velocity
    /// `+speed x̂`, those below `−speed x̂` (their positions stay frozen: a translation-invariant
    /// layer of random particles moving along itself looks the same at every instant, up to its
    /// particular arrangement), which the dissipative force drags the fluid with, and
    /// bounce-back reverses a particle's velocity relative to the wall it hits.
    ///
    /// The moving particles are given the steady linear profile `u_x = speed (2z − lo − hi)/gap`
    /// on top of their (thermal) velocities, so that the flow starts developed.
    pub fn start_couette(&mut self, speed: f64) -> Result<(), DpdError> {
        let Some(Wall::Planes { lo, hi }) = self.wall else {
            return Err(DpdError::Parameter {
                name: "wall speed",
                value: speed,
                reason: "sliding walls need plane walls",
            });
        };
        require(speed.is_finite(), "wall speed", speed, "must be finite")?;
        self.wall_speed = speed;
        let mid = 0.5 * (lo + hi);
        let p = &mut self.particles;
        for i in 0..p.len() {
            if p.moves[i] == 0.0 {
                p.vx[i] = if p.z[i] > mid { speed } else { -speed };
            } else {
                p.vx[i] += speed * (2.0 * p.z[i] - lo - hi) / (hi - lo);
            }
        }
        // The dissipative forces of the next half kick see the new velocities.
        self.compute_forces();
        Ok(())
    }

    /// A fluid of density `density` bounded by `wall`: a periodic fluid filling the box is
    /// equilibrated for `warmup` steps, then its particles in the wall layer (`0 ≤ d < r_c`)
    /// are frozen (velocity 0), those deeper in the wall removed, and the rest form the fluid.
    /// Ids are renumbered in the order of the bulk's; the step counter starts at 0.
    pub fn with_wall(
        params: DpdParams,
        density: f64,
        body: BodyForce,
        wall: Wall,
        warmup: u64,
    ) -> Result<Self, DpdError> {
        Self::with_wall_warmed_by(params, density, body, wall, warmup, |bulk, steps| {
            (0..steps).try_for_each(|_| bulk.step())
        })
    }

    /// [`Self::with_wall`] with the `warmup` steps of the periodic fluid run by `warm` (on a
    /// GPU: `crate::dpd::gpu_fluid::GpuFluid`), which must leave the fluid's state after them
    /// in the system it is given.
    pub fn with_wall_warmed_by(
        params: DpdParams,
        density: f64,
        body: BodyForce,
        wall: Wall,
        warmup: u64,
        warm: impl FnOnce(&mut DpdSystem, u64) -> Result<(), DpdError>,
    ) -> Result<Self, DpdError> {
        let mut bulk = Self::random_fluid(params, density, BodyForce::None)?;
        if warmup > 0 {
            warm(&mut bulk, warmup)?;
        }
        let q = &bulk.particles;
        let rc = params.pair.rc;
        let mut p = Particles::default();
        // In the order of the bulk's ids, so that the new ids do not depend on the order the
        // warm-up left the particles in (the CPU's and the GPU's cell lists order a cell's
        // particles differently).
        let mut by_id: Vec<usize> = (0..q.len()).collect();
        by_id.sort_unstable_by_key(|&i| q.id[i]);
        for i in by_id {
            let d = wall.sdf([q.x[i], q.y[i], q.z[i]]);
            if d >= rc {
                continue;
            }
            let m = if d < 0.0 { 1.0 } else { 0.0 };
            p.x.push(q.x[i]);
            p.y.push(q.y[i]);
            p.z.push(q.z[i]);
            p.vx.push(m * q.vx[i]);
            p.vy.push(m * q.vy[i]);
            p.vz.push(m * q.vz[i]);
            p.id.push(p.id.len() as u32);
            p.moves.push(m);
        }
        Self::from_particles_with_wall(params, body, p, Some(wall))
    }

    /// Wrap positions into `[0, L)`; an error if a particle moved more than a box length or
    /// is not finite.
    fn wrap_and_check(&mut self, step: u64) -> Result<(), DpdError> {
        use rayon::prelude::*;
        let l = self.params.box_len;
        let p = &mut self.particles;
        let mut bad = None;
        for (k, x) in [&mut p.x, &mut p.y, &mut p.z].into_iter().enumerate() {
            let lk = l[k];
            // The first particle (in chunk order) that is not finite or moved more than a box.
            let first_bad = x
                .par_chunks_mut(16384)
                .enumerate()
                .filter_map(|(q, chunk)| {
                    let mut found = None;
                    for (m, c) in chunk.iter_mut().enumerate() {
                        if *c < 0.0 {
                            *c += lk;
                        } else if *c >= lk {
                            *c -= lk;
                        }
                        if !(*c >= 0.0 && *c < lk) {
                            if *c == lk {
                                *c = 0.0;
                            } else if found.is_none() {
                                found = Some(q * 16384 + m);
                            }
                        }
                    }
                    found
                })
                .min();
            bad = bad.or(first_bad);
        }
        match bad {
            None => Ok(()),
            Some(i) => Err(DpdError::Unstable {
                step,
                particle: p.id[i] as usize,
                position: [p.x[i], p.y[i], p.z[i]],
            }),
        }
    }

    /// Bin and sort the particles by cell (every per-particle array permuted).
    fn sort(&mut self) {
        let p = &mut self.particles;
        self.cells.sort(&p.x, &p.y, &p.z, &mut self.perm);
        let perm = &self.perm;
        let n = perm.len();
        use rayon::prelude::*;
        [
            &mut p.x,
            &mut p.y,
            &mut p.z,
            &mut p.vx,
            &mut p.vy,
            &mut p.vz,
            &mut p.moves,
        ]
        .into_par_iter()
        .zip(self.scratch.par_iter_mut())
        .for_each(|(arr, s)| {
            s.clear();
            s.extend(perm.iter().map(|&o| arr[o as usize]));
            std::mem::swap(arr, s);
        });
        self.scratch_id.clear();
        self.scratch_id
            .extend(perm.iter().map(|&o| p.id[o as usize]));
        std::mem::swap(&mut p.id, &mut self.scratch_id);
        debug_assert_eq!(p.id.len(), n);
    }

    /// Pair forces (noise of the current step) plus the body force.
    fn compute_forces(&mut self) {
        let key = step_key(self.params.seed, self.step);
        self.virial = cell_forces(
            &self.params.pair,
            &self.particles,
            &self.cells,
            key,
            self.params.dt,
            &mut self.fx,
            &mut self.fy,
            &mut self.fz,
            &mut self.virials,
        );
        self.add_body_force();
    }

    /// Add the body force to the forces of the pair loops.
    fn add_body_force(&mut self) {
        match self.body {
            BodyForce::None => {}
            BodyForce::Constant(g) => {
                self.fx.iter_mut().for_each(|f| *f += g[0]);
                self.fy.iter_mut().for_each(|f| *f += g[1]);
                self.fz.iter_mut().for_each(|f| *f += g[2]);
            }
            BodyForce::ReversePoiseuille { force } => {
                let half = 0.5 * self.params.box_len[2];
                for (f, z) in self.fx.iter_mut().zip(&self.particles.z) {
                    *f += if *z < half { force } else { -force };
                }
            }
        }
    }

    /// Total momentum `m Σ v`.
    pub fn momentum(&self) -> [f64; 3] {
        let p = &self.particles;
        let m = self.params.mass;
        [&p.vx, &p.vy, &p.vz].map(|v| m * v.iter().sum::<f64>())
    }

    /// Number of moving (not frozen) particles.
    pub fn n_moving(&self) -> usize {
        self.particles.moves.iter().filter(|&&m| m != 0.0).count()
    }

    /// Kinetic temperature `m Σ |v − v̄|² / (3N − 3)` over the moving particles (the mean
    /// velocity's 3 degrees of freedom removed).
    pub fn kinetic_temperature(&self) -> f64 {
        let p = &self.particles;
        let n = self.n_moving() as f64;
        let mut s = 0.0;
        for v in [&p.vx, &p.vy, &p.vz] {
            let mean = v.iter().zip(&p.moves).map(|(c, m)| c * m).sum::<f64>() / n;
            s += v
                .iter()
                .zip(&p.moves)
                .map(|(c, m)| m * (c - mean) * (c - mean))
                .sum::<f64>();
        }
        self.params.mass * s / (3.0 * n - 3.0)
    }

    /// Virial pressure `p = n k_BT + Σ_{i<j} r_ij·F^C_ij / 3V` (`k_BT` the kinetic temperature).
    pub fn pressure(&self) -> f64 {
        self.density() * self.kinetic_temperature() + self.virial / (3.0 * self.params.volume())
    }

    /// Positions in the stored (cell-sorted) order.
    pub fn positions(&self) -> Vec<[f64; 3]> {
        let p = &self.particles;
        (0..self.len()).map(|i| [p.x[i], p.y[i], p.z[i]]).collect()
    }

    /// Velocities in the stored order.
    pub fn velocities(&self) -> Vec<[f64; 3]> {
        let p = &self.particles;
        (0..self.len())
            .map(|i| [p.vx[i], p.vy[i], p.vz[i]])
            .collect()
    }

    /// The radial distribution function `g(r)` on `bins` bins of `[0, r_max)` (bin centres
    /// and values): pair counts over the ideal-gas count `n · 4π r² dr · N / 2`. Needs
    /// `r_max ≤ L/3` per axis.
    pub fn radial_distribution(
        &self,
        r_max: f64,
        bins: usize,
    ) -> Result<(Vec<f64>, Vec<f64>), DpdError> {
        require(bins > 0, "bins", bins as f64, "must be positive")?;
        let grid = CellGrid::new(self.params.box_len, r_max)?;
        let mut list = CellList::new(grid);
        let p = &self.particles;
        let mut perm = Vec::new();
        list.sort(&p.x, &p.y, &p.z, &mut perm);
        let xs: Vec<[f64; 3]> = perm
            .iter()
            .map(|&o| [p.x[o as usize], p.y[o as usize], p.z[o as usize]])
            .collect();
        let dr = r_max / bins as f64;
        let mut counts = vec![0u64; bins];
        for c in 0..list.grid.n_cells() {
            let nb = list.grid.neighbours(c);
            for i in list.starts[c]..list.starts[c + 1] {
                for &(nc, s) in &nb {
                    for (j, xj) in xs
                        .iter()
                        .enumerate()
                        .take(list.starts[nc + 1])
                        .skip(list.starts[nc])
                    {
                        if j <= i {
                            continue;
                        }
                        let d = [0, 1, 2].map(|k| xs[i][k] - xj[k] - s[k]);
                        let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                        if r < r_max {
                            counts[((r / dr) as usize).min(bins - 1)] += 1;
                        }
                    }
                }
            }
        }
        let n = xs.len() as f64;
        let rho = self.density();
        let centres: Vec<f64> = (0..bins).map(|b| (b as f64 + 0.5) * dr).collect();
        let g = (0..bins)
            .map(|b| {
                let (r0, r1) = (b as f64 * dr, (b + 1) as f64 * dr);
                let shell = 4.0 / 3.0 * std::f64::consts::PI * (r1.powi(3) - r0.powi(3));
                counts[b] as f64 / (0.5 * n * rho * shell)
            })
            .collect();
        Ok((centres, g))
    }
}

/// The velocity of the wall surface nearest `x`: `±speed x̂` for sliding planes (upper `+`),
/// zero otherwise.
pub(crate) fn wall_velocity(wall: Wall, speed: f64, x: [f64; 3]) -> [f64; 3] {
    match wall {
        Wall::Planes { lo, hi } if speed != 0.0 => {
            let u = if x[2] > 0.5 * (lo + hi) {
                speed
            } else {
                -speed
            };
            [u, 0.0, 0.0]
        }
        _ => [0.0; 3],
    }
}

/// `y_c += s x_c m` per particle, in parallel chunks (`m` = [`Particles::moves`]: frozen
/// particles are neither kicked nor drifted; for the others `· 1.0` is exact).
fn add_masked3(v: [&mut Vec<f64>; 3], f: [&Vec<f64>; 3], h: f64, moves: &[f64]) {
    use rayon::prelude::*;
    const CHUNK: usize = 16384;
    for (v, f) in v.into_iter().zip(f) {
        v.par_chunks_mut(CHUNK)
            .zip(f.par_chunks(CHUNK))
            .zip(moves.par_chunks(CHUNK))
            .for_each(|((v, f), m)| {
                for ((v, f), m) in v.iter_mut().zip(f).zip(m) {
                    *v += h * f * m;
                }
            });
    }
}

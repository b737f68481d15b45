//! Cells in the DPD fluid: membranes whose vertices are particles of the fluid, coupled to the
//! solvent by dissipative and random pair forces, with the solvent bounced back off the moving
//! triangles so that no particle crosses a membrane (Fedosov, Caswell & Karniadakis 2010;
//! Mirheo, Alexeev et al. 2020).
//!
//! # The model
//!
//! * **Vertices** are particles of mass `m_v` stepped by the same velocity-Verlet scheme as the
//!   solvent. Their forces: the membrane's own ([`Membrane::add_forces`] and its viscosity,
//!   [`Membrane::add_viscous_forces`]), the solvent coupling below, the body force of the fluid
//!   (the same force per particle as the solvent), a contact repulsion from the vertices of
//!   other cells ([`super::contact`]) and an optional external force per cell.
//! * **Solvent–vertex pairs** (`r < r_c`, `w = 1 − r/r_c`, `e = (x_v − x_s)/r`) interact by the
//!   dissipative and random parts of the DPD force only:
//!
//!   ```text
//!   F_vs = [ −γ w^{2k} (v_vs·e) + √(2γ k_BT) w^k ξ_vs / √dt ] e,
//!   ```
//!
//!   with `γ = γ_in` for the solvent inside that cell and `γ_out` for the rest (the drag that
//!   gives the no-slip condition; Fedosov's choice of different coefficients inside and out).
//!   `ξ_vs` is keyed on `(seed, step, vertex id, solvent id)` as in the fluid, so the pair
//!   forces conserve momentum exactly and do not depend on thread count or particle order.
//! * **Inner and outer solvent** are told apart at the start (the particles inside each
//!   membrane, by the winding number of [`super::crossing`]). Bounce-back keeps them apart; a
//!   more viscous inner fluid is modelled by an extra dissipative and random pair force between
//!   inner particles of the same cell with coefficient `γ_Δ` (independent noise, so the inner
//!   pairs feel `γ + γ_Δ` with the fluctuation–dissipation theorem intact).
//! * **Bounce-back.** After the drift each solvent particle's path `x − dt v → x` is tested
//!   against the triangles of every membrane, each moving linearly from its position at the
//!   start of the step to its end ([`super::crossing::first_crossing`]). At the earliest
//!   crossing `t` with barycentric coordinates `λ`, the particle collides with the triangle's
//!   point, whose velocity is `u = Σ λ_k v_k` and whose effective mass is `M = m_v/Σλ_k²` (an
//!   impulse `J` spread as `λ_k J` over the vertices changes `u` by `J Σλ²/m_v`). The relative
//!   velocity `w = v − u` is reversed (no slip, no penetration) by the impulse `J = −2μw`,
//!   `μ = mM/(m + M)`: the particle takes `v + J/m`, the vertices `−λ_k J/m_v`, which conserves
//!   momentum *and* kinetic energy. (Reversing `w` against an infinitely heavy triangle,
//!   `v' = 2u − v`, as for walls, would heat the membrane by `2m²|w|²Σλ²/m_v` per bounce.) The
//!   particle then moves away from the triangle's point at the end of the step for the rest
//!   of the step.
//! * **Leaks** are counted every `check_every` steps: a solvent particle on the wrong side of a
//!   membrane (inside a cell it did not start in, or out of its own) is a leak.
//!
//! # Example
//!
//! ```
//! use mobo::dpd::membrane::{Bending, MembraneParams};
//! use mobo::dpd::pair_force::PairParams;
//! use mobo::dpd::suspension::{CellSpec, CouplingParams, DpdSuspension};
//! use mobo::dpd::system::{BodyForce, DpdParams, DpdSystem};
//! use mobo::vesicle::{shapes, CellMesh};
//!
//! let pair = PairParams { a: 25.0, gamma: 4.5, kbt: 1.0, rc: 1.0, power: 1.0 };
//! let params = DpdParams { box_len: [7.0; 3], pair, dt: 0.005, mass: 1.0, seed: 3 };
//! let fluid = DpdSystem::random_fluid(params, 3.0, BodyForce::None)?;
//! // A sphere of radius 1.8 triangulated from its spherical-harmonic surface.
//! let mesh = CellMesh::icosphere(&shapes::sphere(8, 1.8)?, 2)?;
//! let vertices: Vec<[f64; 3]> = mesh.vertices.iter().map(|v| v.map(|c| c + 3.5)).collect();
//! let mut membrane = MembraneParams::new(1.0, 0.05);
//! membrane.ka = 500.0;
//! membrane.kv = 500.0;
//! let cell = CellSpec { vertices, triangles: mesh.triangles.clone(), params: membrane };
//! let mut sim = DpdSuspension::new(fluid, vec![cell], CouplingParams::default())?;
//! for _ in 0..20 {
//!     sim.step()?;
//! }
//! assert_eq!(sim.leaked(), 0);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

// Component loops over 3-vectors read best with the index.
#![allow(clippy::needless_range_loop)]

mod bounces;
mod coupling_forces;

use super::bounce::{particles_near, Collision, SweptMembrane};
use super::contact::{add_contact_forces, bbox, VertexForces, Vertices};
use super::crossing::inside;
use super::fluid_cell::{image_near, mean, wrap};
pub use super::fluid_cell::{meshes_overlap, CellSpec, FluidCell};
use super::membrane::{Membrane, MembraneTopology};
use super::pair_force::{minimum_image, Particles};
use super::rng::{mix64, normal, pair_noise, step_key, stream};
use super::system::{BodyForce, DpdSystem, PairForces};
use super::{require, DpdError};
use rayon::prelude::*;

/// Parameters of the coupling between membranes and solvent.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct CouplingParams {
    /// Dissipative coefficient `γ_out` of pairs of a vertex and a solvent particle outside its
    /// cell.
    pub gamma_out: f64,
    /// Dissipative coefficient `γ_in` of pairs of a vertex and a solvent particle inside its
    /// cell.
    pub gamma_in: f64,
    /// Kernel exponent `k` of the solvent–vertex pairs.
    pub power: f64,
    /// Extra dissipative coefficient `γ_Δ ≥ 0` between inner solvent particles of the same
    /// cell (a more viscous inner fluid); 0 for the same fluid inside and out (scene key and
    /// JSON `inner_gamma`).
    #[serde(rename = "inner_gamma")]
    pub inner_extra_gamma: f64,
    /// Amplitude of the conservative repulsion `a_c w e` between vertices of different cells.
    pub contact_a: f64,
    /// Vertex mass `m_v`.
    pub vertex_mass: f64,
    /// Steps between leak counts (0: never).
    pub check_every: u64,
}

impl Default for CouplingParams {
    /// `γ_in = γ_out = 15`, `k = 1/4` (Fedosov's softer kernel for the membrane pairs), no
    /// viscosity contrast, `a_c = 25`, `m_v = 1`, leaks counted every 100 steps.
    fn default() -> Self {
        Self {
            gamma_out: 15.0,
            gamma_in: 15.0,
            power: 0.25,
            inner_extra_gamma: 0.0,
            contact_a: 25.0,
            vertex_mass: 1.0,
            check_every: 100,
        }
    }
}

impl CouplingParams {
    /// Check every parameter's domain.
    pub fn validate(&self) -> Result<(), DpdError> {
        let nonneg = |v: f64| v >= 0.0 && v.is_finite();
        require(
            nonneg(self.gamma_out),
            "gamma_out",
            self.gamma_out,
            "must be ≥ 0",
        )?;
        require(
            nonneg(self.gamma_in),
            "gamma_in",
            self.gamma_in,
            "must be ≥ 0",
        )?;
        require(
            self.power > 0.0 && self.power.is_finite(),
            "membrane kernel power",
            self.power,
            "must be positive",
        )?;
        require(
            nonneg(self.inner_extra_gamma),
            "inner_extra_gamma",
            self.inner_extra_gamma,
            "must be ≥ 0",
        )?;
        require(
            nonneg(self.contact_a),
            "contact_a",
            self.contact_a,
            "must be ≥ 0",
        )?;
        require(
            self.vertex_mass > 0.0 && self.vertex_mass.is_finite(),
            "vertex mass",
            self.vertex_mass,
            "must be positive",
        )
    }
}

/// The state of one cell for a checkpoint.
#[derive(Clone, Debug, PartialEq)]
pub struct CellState {
    /// Vertex positions (unwrapped).
    pub x: Vec<[f64; 3]>,
    /// Vertex velocities.
    pub v: Vec<[f64; 3]>,
    /// Vertex forces.
    pub f: Vec<[f64; 3]>,
    /// External force on the cell.
    pub external: [f64; 3],
}

/// The state of a suspension beyond its fluid, for a checkpoint.
#[derive(Clone, Debug, PartialEq)]
pub struct SuspensionState {
    /// Per cell.
    pub cells: Vec<CellState>,
    /// The cell each particle id started in (`u32::MAX`: outside every cell).
    pub owner: Vec<u32>,
    /// Bounces, leaked particles at the last count, most leaked at any count.
    pub counters: [u64; 3],
}

/// The counter-force of external forces on cells: `−total`, spread evenly over the moving
/// solvent outside every cell (the fluid a pressure gradient would push; the inner solvent
/// moves with its cell), added to the force arrays.
fn spread_over_outer_solvent(
    p: &Particles,
    owner: &[u32],
    total: [f64; 3],
    [fx, fy, fz]: [&mut Vec<f64>; 3],
) {
    let outer = |i: usize| p.moves[i] != 0.0 && owner[p.id[i] as usize] == OUTSIDE;
    let n = (0..p.len()).filter(|&i| outer(i)).count().max(1) as f64;
    for i in (0..p.len()).filter(|&i| outer(i)) {
        fx[i] -= total[0] / n;
        fy[i] -= total[1] / n;
        fz[i] -= total[2] / n;
    }
}

/// Marker of a solvent particle outside every cell.
const OUTSIDE: u32 = u32::MAX;

/// Vertices per task of the solvent–vertex pairs (a cell of 642 vertices makes 11 tasks).
const VERTEX_BLOCK: usize = 64;

/// Salts of the noise streams of the coupling (distinct from the fluid's pair noise).
const SALT_COUPLING: u64 = 0x5bd1_e995_0000_0001;
const SALT_INNER: u64 = 0x5bd1_e995_0000_0002;
const SALT_MEMBRANE: u64 = 0x5bd1_e995_0000_0003;

/// Wall seconds of the cells' part of the steps (the fluid's own phases are in
/// [`DpdSystem::timings`]), since the suspension was made or restored.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct CellTimings {
    /// The vertices' kicks and drift, the drift check and the bounce-back of vertices off a
    /// wall.
    pub vertices_s: f64,
    /// The bounce-back of the solvent off the membranes.
    pub bounce_s: f64,
    /// The membranes' own forces (elastic, bending, area, volume, viscous), the body and
    /// external forces on the vertices.
    pub membrane_s: f64,
    /// The solvent–vertex pairs, the inner viscosity and the contacts between cells.
    pub coupling_s: f64,
    /// The leak counts (every `check_every` steps).
    pub leaks_s: f64,
}

/// Cells in a DPD fluid (see the module docs).
#[derive(Clone, Debug)]
pub struct DpdSuspension {
    /// The fluid (solvent particles, walls, body force).
    pub fluid: DpdSystem,
    cells: Vec<FluidCell>,
    coupling: CouplingParams,
    /// Cell index of the solvent particle of each id (`OUTSIDE` for the outer solvent).
    owner: Vec<u32>,
    bounces: u64,
    leaked: u64,
    max_leaked: u64,
    /// Per cell, its contributions to the solvent's forces in the current force evaluation
    /// (scratch kept between steps).
    solvent_kicks: Vec<Vec<(u32, [f64; 3])>>,
    /// Seconds per phase of the cells' part of the steps.
    timings: CellTimings,
    /// Per moving particle, in how many cells' bounce-back candidate lists it is (the cell-list
    /// cells around each membrane's swept box) in the current step (scratch kept between
    /// steps).
    bounce_count: Vec<u8>,
}

impl DpdSuspension {
    /// Put `cells` into `fluid` (its solvent fills the whole box, inside the cells too): the
    /// solvent inside each membrane becomes its inner solvent, the vertices start at rest plus
    /// thermal velocities, and the forces of the initial state are computed.
    ///
    /// Errors: invalid parameters or meshes, a cell that with `2 r_c` does not fit in the box,
    /// or cells whose membranes overlap (a vertex of one inside another).
    pub fn new(
        fluid: DpdSystem,
        cells: Vec<CellSpec>,
        coupling: CouplingParams,
    ) -> Result<Self, DpdError> {
        coupling.validate()?;
        let l = fluid.params.box_len;
        let max_id = fluid.particles.id.iter().copied().max().unwrap_or(0);
        let mut id0 = max_id
            .checked_add(1)
            .ok_or_else(|| DpdError::Mesh("no ids left for the membrane vertices".into()))?;
        let kbt = fluid.params.pair.kbt;
        let seed = fluid.params.seed;
        let mut built = Vec::with_capacity(cells.len());
        for (ci, spec) in cells.into_iter().enumerate() {
            let n = spec.vertices.len();
            let topology = MembraneTopology::new(n, &spec.triangles)?;
            let membrane = Membrane::new(topology, spec.params, &spec.vertices)?;
            let (lo, hi) = bbox(&spec.vertices);
            for k in 0..3 {
                if hi[k] - lo[k] + 2.0 * fluid.params.pair.rc > l[k] {
                    return Err(DpdError::Mesh(format!(
                        "cell {ci} spans {:.3} along axis {k}: with 2 r_c it must fit in the \
                         box ({:.3})",
                        hi[k] - lo[k],
                        l[k]
                    )));
                }
            }
            // Thermal velocities with zero mean.
            let s = (kbt / coupling.vertex_mass).sqrt();
            let tag = 1000 + ci as u64;
            let mut v: Vec<[f64; 3]> = (0..n)
                .map(|i| {
                    [0, 1, 2].map(|k| {
                        let j = (6 * i + 2 * k) as u64;
                        s * normal(stream(seed, tag, j), stream(seed, tag, j + 1))
                    })
                })
                .collect();
            let m = mean(&v);
            v.iter_mut().for_each(|p| (0..3).for_each(|k| p[k] -= m[k]));
            built.push(FluidCell {
                membrane,
                x: spec.vertices.clone(),
                v,
                f: vec![[0.0; 3]; n],
                x_old: spec.vertices,
                id0,
                external: [0.0; 3],
            });
            id0 = id0
                .checked_add(n as u32)
                .ok_or_else(|| DpdError::Mesh("too many membrane vertices for u32 ids".into()))?;
        }
        // No vertex of one cell inside another.
        for a in 0..built.len() {
            for b in a + 1..built.len() {
                let (ca, cb) = (&built[a], &built[b]);
                let (ta, tb) = (ca.membrane.topology(), cb.membrane.topology());
                if meshes_overlap(&ca.x, ta.triangles(), &cb.x, tb.triangles(), l) {
                    return Err(DpdError::Mesh(format!(
                        "cells {a} and {b} overlap: a vertex of one is inside the other"
                    )));
                }
            }
        }
        let mut sim = DpdSuspension {
            owner: vec![OUTSIDE; id0 as usize],
            fluid,
            cells: built,
            coupling,
            bounces: 0,
            leaked: 0,
            max_leaked: 0,
            solvent_kicks: Vec::new(),
            timings: CellTimings::default(),
            bounce_count: Vec::new(),
        };
        let owner = sim.sides();
        sim.owner = owner;
        sim.add_coupling_forces()?;
        Ok(sim)
    }

    /// The dynamic state beyond the fluid's, for a checkpoint ([`Self::restore`]).
    pub fn state(&self) -> SuspensionState {
        SuspensionState {
            cells: self
                .cells
                .iter()
                .map(|c| CellState {
                    x: c.x.clone(),
                    v: c.v.clone(),
                    f: c.f.clone(),
                    external: c.external,
                })
                .collect(),
            owner: self.owner.clone(),
            counters: [self.bounces, self.leaked, self.max_leaked],
        }
    }

    /// A suspension restored from a checkpoint: `fluid` restored with its stored forces (which
    /// hold the coupling forces), the cells built from `cells` (their reference geometry) and
    /// set to `state`, no force evaluated, so that stepping continues bit for bit.
    pub fn restore(
        fluid: DpdSystem,
        cells: Vec<CellSpec>,
        coupling: CouplingParams,
        state: SuspensionState,
    ) -> Result<Self, DpdError> {
        coupling.validate()?;
        if state.cells.len() != cells.len() {
            return Err(DpdError::Length {
                what: "checkpointed cells",
                len: state.cells.len(),
                expected: cells.len(),
            });
        }
        let max_id = fluid.particles.id.iter().copied().max().unwrap_or(0);
        let mut id0 = max_id + 1;
        let mut built = Vec::with_capacity(cells.len());
        for (spec, st) in cells.into_iter().zip(state.cells) {
            let n = spec.vertices.len();
            for (what, len) in [
                ("cell positions", st.x.len()),
                ("cell velocities", st.v.len()),
                ("cell forces", st.f.len()),
            ] {
                if len != n {
                    return Err(DpdError::Length {
                        what,
                        len,
                        expected: n,
                    });
                }
            }
            let topology = MembraneTopology::new(n, &spec.triangles)?;
            let membrane = Membrane::new(topology, spec.params, &spec.vertices)?;
            built.push(FluidCell {
                membrane,
                x_old: st.x.clone(),
                x: st.x,
                v: st.v,
                f: st.f,
                id0,
                external: st.external,
            });
            id0 += n as u32;
        }
        if state.owner.len() != id0 as usize {
            return Err(DpdError::Length {
                what: "solvent owners",
                len: state.owner.len(),
                expected: id0 as usize,
            });
        }
        let [bounces, leaked, max_leaked] = state.counters;
        Ok(DpdSuspension {
            fluid,
            cells: built,
            coupling,
            owner: state.owner,
            bounces,
            leaked,
            max_leaked,
            solvent_kicks: Vec::new(),
            timings: CellTimings::default(),
            bounce_count: Vec::new(),
        })
    }

    /// The cells.
    pub fn cells(&self) -> &[FluidCell] {
        &self.cells
    }

    /// The coupling parameters.
    pub fn coupling(&self) -> &CouplingParams {
        &self.coupling
    }

    /// Set the external force on cell `cell` (spread evenly over its vertices; the opposite
    /// force is spread over the moving solvent particles outside every cell, so that the total
    /// momentum is conserved, as by a pressure gradient in a periodic box).
    pub fn set_external_force(&mut self, cell: usize, force: [f64; 3]) -> Result<(), DpdError> {
        let n = self.cells.len();
        let c = self.cells.get_mut(cell).ok_or(DpdError::Length {
            what: "cell index",
            len: cell,
            expected: n,
        })?;
        require(
            force.iter().all(|f| f.is_finite()),
            "external force",
            force[0],
            "must be finite",
        )?;
        // The stored forces (of the next half kick) change by the difference: on the
        // vertices, and its opposite on the moving outer solvent.
        let delta = [0, 1, 2].map(|k| force[k] - c.external[k]);
        c.external = force;
        let nv = c.f.len() as f64;
        for f in &mut c.f {
            for k in 0..3 {
                f[k] += delta[k] / nv;
            }
        }
        let (_, p, f) = self.fluid.split_for_coupling();
        spread_over_outer_solvent(p, &self.owner, delta, f);
        Ok(())
    }

    /// Wall seconds of the cells' part of the steps, by phase.
    pub fn timings(&self) -> CellTimings {
        self.timings
    }

    /// Bounce-backs off membranes so far.
    pub fn bounces(&self) -> u64 {
        self.bounces
    }

    /// Solvent particles on the wrong side of a membrane at the last count.
    pub fn leaked(&self) -> u64 {
        self.leaked
    }

    /// The most solvent particles found on the wrong side at any count.
    pub fn max_leaked(&self) -> u64 {
        self.max_leaked
    }

    /// Number of solvent particles inside cell `cell` (its inner solvent).
    pub fn inner_count(&self, cell: usize) -> usize {
        self.owner.iter().filter(|&&o| o == cell as u32).count()
    }

    /// Total momentum of solvent and vertices.
    pub fn momentum(&self) -> [f64; 3] {
        let mut p = self.fluid.momentum();
        let m = self.coupling.vertex_mass;
        for c in &self.cells {
            for v in &c.v {
                for k in 0..3 {
                    p[k] += m * v[k];
                }
            }
        }
        p
    }

    /// Kinetic temperature of the inner solvent of cell `cell`, `m ⟨|v − v̄|²⟩/3` about its
    /// mean velocity (NaN if it has fewer than two particles).
    pub fn inner_temperature(&self, cell: usize) -> f64 {
        let p = &self.fluid.particles;
        let members: Vec<usize> = (0..p.len())
            .filter(|&i| self.owner[p.id[i] as usize] == cell as u32)
            .collect();
        let n = members.len();
        if n < 2 {
            return f64::NAN;
        }
        let mean =
            [&p.vx, &p.vy, &p.vz].map(|v| members.iter().map(|&i| v[i]).sum::<f64>() / n as f64);
        let s: f64 = members
            .iter()
            .map(|&i| {
                (p.vx[i] - mean[0]).powi(2)
                    + (p.vy[i] - mean[1]).powi(2)
                    + (p.vz[i] - mean[2]).powi(2)
            })
            .sum();
        self.fluid.params.mass * s / (3.0 * (n - 1) as f64)
    }

    /// Kinetic temperature of the vertices, `m_v ⟨|v − v̄_cell|²⟩ / 3` (each cell's mean
    /// velocity removed).
    pub fn vertex_temperature(&self) -> f64 {
        let (mut s, mut n) = (0.0, 0usize);
        for c in &self.cells {
            let vm = c.mean_velocity();
            for v in &c.v {
                s += (0..3).map(|k| (v[k] - vm[k]).powi(2)).sum::<f64>();
            }
            n += c.v.len().saturating_sub(1);
        }
        self.coupling.vertex_mass * s / (3.0 * n.max(1) as f64)
    }

    /// One velocity-Verlet step of solvent and vertices, with the bounce-back off the moving
    /// membranes between the drift and the force evaluation.
    pub fn step(&mut self) -> Result<(), DpdError> {
        self.step_with(None)
    }

    /// [`Self::step`] with the solvent's pair forces from `pairs` (the CPU loops if `None`;
    /// on a GPU: `crate::dpd::gpu_pairs::GpuPairForces`). Everything else (membranes,
    /// bounce-back, the solvent–vertex pairs, contacts, integration) runs on the CPU as in
    /// [`Self::step`].
    pub fn step_with(&mut self, pairs: Option<&mut dyn PairForces>) -> Result<(), DpdError> {
        let dt = self.fluid.params.dt;
        let h = 0.5 * dt / self.coupling.vertex_mass;
        self.fluid.kick_and_drift();
        let t0 = std::time::Instant::now();
        for c in &mut self.cells {
            for ((x, xo), (v, f)) in
                c.x.iter_mut()
                    .zip(c.x_old.iter_mut())
                    .zip(c.v.iter_mut().zip(&c.f))
            {
                *xo = *x;
                for k in 0..3 {
                    v[k] += h * f[k];
                    x[k] += dt * v[k];
                }
            }
        }
        self.check_vertex_drift()?;
        self.bounce_vertices_off_wall();
        let t1 = std::time::Instant::now();
        self.bounce_off_membranes();
        let t2 = std::time::Instant::now();
        self.fluid.settle_with(pairs)?;
        self.add_coupling_forces()?;
        self.fluid.kick();
        let t4 = std::time::Instant::now();
        for c in &mut self.cells {
            for (v, f) in c.v.iter_mut().zip(&c.f) {
                for k in 0..3 {
                    v[k] += h * f[k];
                }
            }
        }
        let every = self.coupling.check_every;
        let t5 = std::time::Instant::now();
        if every > 0 && self.fluid.step.is_multiple_of(every) {
            self.count_leaks();
        }
        let tm = &mut self.timings;
        tm.vertices_s += (t1 - t0).as_secs_f64() + (t5 - t4).as_secs_f64();
        tm.bounce_s += (t2 - t1).as_secs_f64();
        tm.leaks_s += t5.elapsed().as_secs_f64();
        Ok(())
    }

    /// A vertex that is not finite or moved more than a quarter of the box in one step: the
    /// time step is too large for the membrane's forces ([`DpdError::Unstable`]).
    fn check_vertex_drift(&self) -> Result<(), DpdError> {
        let l = self.fluid.params.box_len;
        for c in &self.cells {
            for (vi, (x, xo)) in c.x.iter().zip(&c.x_old).enumerate() {
                if (0..3).any(|k| !x[k].is_finite() || (x[k] - xo[k]).abs() > 0.25 * l[k]) {
                    return Err(DpdError::Unstable {
                        step: self.fluid.step,
                        particle: c.id0 as usize + vi,
                        position: *x,
                    });
                }
            }
        }
        Ok(())
    }

    /// Count the solvent particles on the wrong side of a membrane now.
    pub fn count_leaks(&mut self) -> u64 {
        let sides = self.sides();
        let leaked = sides
            .iter()
            .zip(&self.owner)
            .take(self.owner.len())
            .filter(|(a, b)| a != b)
            .count() as u64;
        self.leaked = leaked;
        self.max_leaked = self.max_leaked.max(leaked);
        leaked
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dpd::bounce::collision_impulse;
    use crate::dpd::membrane::MembraneParams;

    /// The equivalent ellipsoid of a triangulated ellipsoid (axes 3, 2, 1.2, turned about z)
    /// recovers its semi-axes and directions (to the mesh's discretisation error).
    #[test]
    fn equivalent_ellipsoid_of_a_meshed_ellipsoid() {
        let (x, tris) = crate::dpd::membrane::test_support::icosphere(4);
        let (ca, sa) = (0.6f64.cos(), 0.6f64.sin());
        let pts: Vec<[f64; 3]> = x
            .iter()
            .map(|p| {
                let q = [3.0 * p[0], 2.0 * p[1], 1.2 * p[2]];
                [
                    ca * q[0] - sa * q[1] + 5.0,
                    sa * q[0] + ca * q[1] - 1.0,
                    q[2] + 2.0,
                ]
            })
            .collect();
        let topology = MembraneTopology::new(pts.len(), &tris).unwrap();
        let membrane = Membrane::new(topology, MembraneParams::new(1.0, 0.05), &pts).unwrap();
        let n = pts.len();
        let cell = FluidCell {
            membrane,
            x: pts.clone(),
            v: vec![[0.0; 3]; n],
            f: vec![[0.0; 3]; n],
            x_old: pts,
            id0: 0,
            external: [0.0; 3],
        };
        let (semi, axes) = cell.equivalent_ellipsoid();
        for (s, want) in semi.iter().zip([3.0, 2.0, 1.2]) {
            assert!((s - want).abs() < 0.01 * want, "{semi:?}");
        }
        assert!((axes[0][0].abs() - ca).abs() < 1e-3 && (axes[0][1].abs() - sa).abs() < 1e-3);
        assert!(axes[2][2].abs() > 0.999);
    }

    /// The collision conserves momentum and kinetic energy and reverses the relative velocity
    /// of the particle and the triangle's point (the vertices' velocities averaged with `λ`).
    #[test]
    fn collision_conserves_momentum_and_energy() {
        let (ms, mv) = (1.3, 0.7);
        let v = [0.4, -1.1, 0.25];
        let vk = [[0.1, 0.2, -0.3], [-0.5, 0.05, 0.6], [0.3, -0.2, 0.1]];
        for lam in [[0.2, 0.3, 0.5], [1.0, 0.0, 0.0], [0.5, 0.5, 0.0]] {
            let u = [0, 1, 2].map(|k| (0..3).map(|j| lam[j] * vk[j][k]).sum::<f64>());
            let w = [0, 1, 2].map(|k| v[k] - u[k]);
            let jmp = collision_impulse(w, lam, ms, mv);
            let vn = [0, 1, 2].map(|k| v[k] + jmp[k] / ms);
            let vkn: Vec<[f64; 3]> = (0..3)
                .map(|j| [0, 1, 2].map(|k| vk[j][k] - lam[j] * jmp[k] / mv))
                .collect();
            let ke = |v: [f64; 3], m: f64| 0.5 * m * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
            let e0 = ke(v, ms) + vk.iter().map(|&q| ke(q, mv)).sum::<f64>();
            let e1 = ke(vn, ms) + vkn.iter().map(|&q| ke(q, mv)).sum::<f64>();
            assert!((e1 - e0).abs() < 1e-14 * e0, "{lam:?}: energy {e0} → {e1}");
            for k in 0..3 {
                let p0 = ms * v[k] + mv * vk.iter().map(|q| q[k]).sum::<f64>();
                let p1 = ms * vn[k] + mv * vkn.iter().map(|q| q[k]).sum::<f64>();
                assert!((p1 - p0).abs() < 1e-14, "{lam:?}: momentum {p0} → {p1}");
                let un = (0..3).map(|j| lam[j] * vkn[j][k]).sum::<f64>();
                assert!(
                    (vn[k] - un + w[k]).abs() < 1e-14,
                    "{lam:?}: relative velocity"
                );
            }
        }
    }
}

//! A cell scene as a research code drives it: a [`Simulation`] advanced step by step (or to a
//! time), whose cells the caller reads between steps and on which it adds its own forces.
//!
//! `mobo run` ([`super::cells`]) runs a scene to its end and writes files; a study written
//! in Rust instead builds a [`Simulation`] from the same [`CellScene`] and decides itself what
//! to record and when to stop. The steps are the same ([`Suspension::step_with_forces`], with
//! the scene's fixed or adaptive `dt`, repeated smaller when the adaptive control rejects a
//! step). Forces of the caller ([`CellForce`], e.g. [`crate::timestep::cell_force::PatchPair`]
//! for optical tweezers or a closure through [`crate::timestep::cell_force::ForceFn`]) act on
//! each cell through its own single layer and, through the coupling, on the others; the
//! effects list says that they are present. One process (the MPI path is `mobo run`'s).
//!
//! ```
//! use std::path::Path;
//! use mobo::scene::cells::parse;
//! use mobo::run::simulation::Simulation;
//! use mobo::timestep::cell_force::ForceFn;
//!
//! let scene = parse(
//!     Path::new("in code"),
//!     "[[cells]]\nshape = \"sphere\"\n[numerics]\norder = 4\ndt = 0.1\nt_end = 0.2\n",
//! )?;
//! let mut sim = Simulation::new(scene)?;
//! // A uniform traction F/A along z: a total force F = 1 on the unit sphere.
//! sim.add_force(ForceFn::new("pull up", |cell, t| {
//!     let area = cell.geometry.area();
//!     for k in 0..t.n_points() {
//!         t.add(k, [0.0, 0.0, 1.0 / area]);
//!     }
//! }));
//! let z0 = sim.cell(0)?.geometry.centroid()[2];
//! sim.advance_to(0.2, |_, _| {})?;
//! let speed = (sim.cell(0)?.geometry.centroid()[2] - z0) / 0.2;
//! // Stokes drag of a unit sphere in unit viscosity: U = F / (6π).
//! assert!((speed - 1.0 / (6.0 * std::f64::consts::PI)).abs() < 2e-3);
//! assert!(sim.effects().iter().any(|e| e.name == "user_forces" && e.enabled));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use super::cell_step::{accepted_step, adaptive_control, flow_origin, step_error};
use super::{assembly::build, CellRunError};
use crate::comm::SerialComm;
use crate::scene::cells::{CellScene, Effect};
use crate::timestep::adaptive::AdaptiveDt;
use crate::timestep::cell_force::{CellForce, VectorField};
use crate::timestep::suspension::{Suspension, SuspensionReport};
use crate::vesicle::geometry::{Geometry, SurfaceCalculus};

/// What the caller reads of one cell between steps.
#[derive(Clone, Debug)]
pub struct CellObservation {
    /// Order-`p` SH coefficients (x, y, z).
    pub coefs: Vec<f64>,
    /// Geometry on the order-`p` grid: points `x`, normals, curvatures, weights `da`, and
    /// [`Geometry::area`], [`Geometry::volume`], [`Geometry::centroid`],
    /// [`Geometry::principal_axes`].
    pub geometry: Geometry,
    /// Membrane tension of the last step on the grid (zeros before the first).
    pub tension: Vec<f64>,
    /// Membrane velocity of the last solve at the grid points (`None` before the first).
    pub membrane_velocity: Option<VectorField>,
    /// Velocity the other cells induced in the last step at the grid points (`None` for one
    /// cell or before the first step).
    pub inter_cell_velocity: Option<VectorField>,
}

/// A cell scene stepped by the caller.
pub struct Simulation {
    scene: CellScene,
    susp: Suspension,
    forces: Vec<Box<dyn CellForce>>,
    adaptive: Option<AdaptiveDt>,
    calc: SurfaceCalculus,
    time: f64,
    steps: usize,
    /// Time and step count of the last landing (fixed `dt`: `time = base.0 + (steps − base.1) dt`).
    base: (f64, usize),
    /// The `dt` the next step tries.
    dt: f64,
    rejected: usize,
}

impl Simulation {
    /// Build every cell of `scene` (their operators, the coupling of several cells).
    pub fn new(scene: CellScene) -> Result<Self, CellRunError> {
        let susp = build(&scene)?;
        let adaptive = adaptive_control(&scene)?;
        let n = &scene.numerics;
        let calc = SurfaceCalculus::new(n.order)?;
        let dt = n.dt;
        Ok(Simulation {
            scene,
            susp,
            forces: Vec::new(),
            adaptive,
            calc,
            time: 0.0,
            steps: 0,
            base: (0.0, 0),
            dt,
            rejected: 0,
        })
    }

    /// Add a force of the caller's, evaluated on every cell at the start of every later step.
    pub fn add_force(&mut self, force: impl CellForce + 'static) {
        self.forces.push(Box::new(force));
    }

    /// The scene's effects and why, with `user_forces` naming the caller's forces.
    pub fn effects(&self) -> Vec<Effect> {
        let mut e = self.scene.effects.clone();
        e.push(Effect {
            name: "user_forces",
            enabled: !self.forces.is_empty(),
            reason: if self.forces.is_empty() {
                "no forces added by the caller".to_string()
            } else {
                let names: Vec<&str> = self.forces.iter().map(|f| f.name()).collect();
                format!("added by the caller: {}", names.join(", "))
            },
        });
        e
    }

    /// One step (with adaptive `dt`, one accepted step, possibly after smaller retries). The
    /// error names the step, its time and the cell.
    pub fn step(&mut self) -> Result<SuspensionReport, CellRunError> {
        self.step_until(f64::INFINITY)
    }

    /// One step that does not pass `t_stop`. With `t_stop` less than two steps away, the
    /// remainder is split into two equal steps (each at least half of `dt`, which keeps BDF2's
    /// step ratio at most 2) and the second lands on `t_stop` exactly.
    fn step_until(&mut self, t_stop: f64) -> Result<SuspensionReport, CellRunError> {
        let k = self.steps + 1;
        let left = t_stop - self.time;
        let (dt_try, lands) = if left <= self.dt * (1.0 + 1e-9) {
            (left, true)
        } else if left < 2.0 * self.dt {
            (0.5 * left, false)
        } else {
            (self.dt, false)
        };
        let shortened = dt_try != self.dt;
        if self.adaptive.is_none() && shortened {
            self.susp
                .set_dt(dt_try)
                .map_err(|e| step_error(k, self.time + dt_try, e))?;
        }
        let forces: Vec<&dyn CellForce> = self.forces.iter().map(|f| f.as_ref()).collect();
        let flow = self.scene.flow;
        let origin = flow_origin(&SerialComm, &self.susp, &flow)?;
        let acc = accepted_step(
            &SerialComm,
            &mut self.susp,
            &|x| flow.velocity_about(x, origin),
            &forces,
            (k, self.time, t_stop),
            dt_try,
            self.adaptive.as_ref(),
        );
        if self.adaptive.is_none() && shortened {
            // Back to the scene's dt after a shortened step, also when it failed.
            self.susp
                .set_dt(self.dt)
                .map_err(|e| step_error(k, self.time + dt_try, e))?;
        }
        let acc = acc?;
        // Fixed dt: the time is counted in steps since the last landing (no sum of rounded
        // steps); a landing puts it on the time asked exactly.
        self.steps = k;
        if lands && acc.dt == dt_try {
            self.time = t_stop;
            self.base = (t_stop, k);
        } else if self.adaptive.is_none() && !shortened {
            self.time = self.base.0 + (k - self.base.1) as f64 * self.dt;
        } else {
            self.time += acc.dt;
            self.base = (self.time, k);
        }
        self.rejected += acc.rejected;
        if let Some(next) = acc.next_dt {
            // A step shortened only to land does not shrink the next one, unless its error
            // asked for a smaller step than the one it took.
            self.dt = if shortened && next >= acc.dt {
                next.max(self.dt)
            } else {
                next
            };
        }
        Ok(acc.report)
    }

    /// Step until `t` (the last two steps evened out to land on it exactly), calling `observe`
    /// after every step; returns the number of steps taken.
    pub fn advance_to(
        &mut self,
        t: f64,
        mut observe: impl FnMut(&mut Simulation, &SuspensionReport),
    ) -> Result<usize, CellRunError> {
        let first = self.steps;
        while self.time < t {
            let report = self.step_until(t)?;
            observe(self, &report);
        }
        Ok(self.steps - first)
    }

    /// Time reached.
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Steps taken.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Steps rejected by the adaptive control (and repeated smaller).
    pub fn rejected(&self) -> usize {
        self.rejected
    }

    /// The `dt` the next step tries.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// Number of cells.
    pub fn len(&self) -> usize {
        self.susp.len()
    }

    /// Whether there are no cells (never, for a valid scene).
    pub fn is_empty(&self) -> bool {
        self.susp.is_empty()
    }

    /// The scene this simulation runs.
    pub fn scene(&self) -> &CellScene {
        &self.scene
    }

    /// The cells' suspension (steppers, coupling statistics, states).
    pub fn suspension(&self) -> &Suspension {
        &self.susp
    }

    /// Cell `i` as it stands: coefficients, geometry, tension, velocities.
    pub fn cell(&mut self, i: usize) -> Result<CellObservation, CellRunError> {
        if i >= self.susp.len() {
            return Err(CellRunError::NoSuchCell {
                index: i,
                cells: self.susp.len(),
            });
        }
        let state = self.susp.cell_state(i);
        let geometry = self.calc.geometry(&state.coefs)?;
        Ok(CellObservation {
            coefs: state.coefs,
            geometry,
            tension: state.sigma,
            membrane_velocity: state
                .membrane_velocity
                .and_then(VectorField::from_component_major),
            inter_cell_velocity: state.velocity.and_then(VectorField::from_component_major),
        })
    }
}

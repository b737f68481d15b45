//! Consistent densities before the first step of a coupled suspension.
//!
//! A scene gives every cell a surface `X⁰` and nothing else: the tension starts at `σ⁰ = 0`
//! and the membrane velocity `u⁰` (the double-layer density `(1 − λ) u` the other cells
//! feel) is unknown. A cell's own step does not care (its tension is an unknown of the
//! step), but the others feel it through the densities of the last step: the explicit
//! velocity `vⁿ = K ρⁿ` with `ρ = (f(X, σ), (1 − λ) u)`, extrapolated for BDF2 as
//! `2vⁿ − vⁿ⁻¹`. With `ρ⁰ = (f(X⁰, 0), 0)` the first two steps take a velocity that is wrong
//! by `O(1)` (the tension's traction and the double layer are missing), the surfaces move
//! `O(Δt)` wrong, and the whole run is first order in `Δt` wherever the coupling is explicit:
//! beyond the near-implicit zone, or everywhere with the explicit coupling. Measured on 4
//! RBCs at 25 %, λ = 1, p = 12, t = 0.4 against Δt = 0.0025 (docs/hard_cases.md): shape-error
//! orders 1.97 then 0.95; `|ρ¹ − ρ*|` of the first two steps is 4.0, the size of `ρ` itself,
//! at every `Δt`.
//!
//! The start-up ([`Suspension::set_start_up_passes`]) takes the first step and throws it
//! away, keeping only the tension `σ¹` and the membrane velocity `u¹` it found: both are the
//! values at `t = 0` to `O(Δt)`, so `ρ⁰ = (f(X⁰, σ¹), (1 − λ) u¹)` is off by `O(Δt)`, the
//! first two steps' velocities by `O(Δt)` and the surfaces by `O(Δt²)`: BDF2's order. Each
//! pass solves the step with the coupling of the previous pass's densities, so the passes are
//! a fixed-point iteration on `(σ⁰, u⁰)` whose contraction is the coupling's strength; the
//! passes stop when the tension changes by less than [`START_UP_TOLERANCE`] of its largest
//! value. Everything else the passes changed (surfaces, history, preconditioner records,
//! contact moves and counters) goes back to the scene's initial state.
//!
//! It runs once, before the first step of a suspension whose cells have never been coupled (no
//! cell has an inter-cell velocity yet: a restart continues from its checkpoint's densities),
//! and only where something couples (two or more cells, or walls). Over ranks the decision
//! is collective and every rank runs the same passes.

use super::super::contact::ContactStats;
use super::super::near_implicit::JointStats;
use super::{CellForce, CellStepError, Suspension};
use crate::comm::Communicator;

/// The start-up stops when a pass changes the tension by less than this fraction of its
/// largest value.
pub const START_UP_TOLERANCE: f64 = 1e-3;

/// The most start-up passes by default ([`Suspension::set_start_up_passes`]).
pub const START_UP_PASSES: usize = 4;

/// What the start-up did ([`Suspension::start_up_report`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct StartUpReport {
    /// Passes taken (first steps solved and thrown away).
    pub passes: usize,
    /// The last pass's largest change of the tension, relative to its largest value (over all
    /// cells and ranks; the first pass measures the change from `σ⁰ = 0`, i.e. 1).
    pub tension_change: f64,
}

impl Suspension {
    /// At most `passes` start-up passes before the first step (module docs; 0: none, the
    /// first step couples `σ⁰ = 0` and no double layer).
    pub fn set_start_up_passes(&mut self, passes: usize) {
        self.start_up_passes = passes;
    }

    /// The most start-up passes allowed ([`Suspension::set_start_up_passes`]).
    pub fn start_up_passes(&self) -> usize {
        self.start_up_passes
    }

    /// What the start-up did (`None`: it has not run).
    pub fn start_up_report(&self) -> Option<StartUpReport> {
        self.start_up
    }

    /// Whether the next step needs the start-up: something couples and no cell on any rank
    /// has been coupled yet (collective).
    pub(super) fn needs_start_up(&self, comm: &dyn Communicator) -> Result<bool, CellStepError> {
        if self.start_up_passes == 0 || (self.coupling.is_none() && self.walls.is_none()) {
            return Ok(false);
        }
        let coupled = self.cells.iter().any(|c| c.state.velocity.is_some());
        let mut flag = [u64::from(coupled)];
        comm.all_sum_u64(&mut flag)?;
        Ok(flag[0] == 0)
    }

    /// The start-up passes (module docs): each takes the first step from the initial state
    /// with the densities found so far, then goes back, keeping the tension and membrane
    /// velocity it found.
    pub(super) fn start_up(
        &mut self,
        comm: &dyn Communicator,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        time: f64,
        forces: &[&dyn CellForce],
    ) -> Result<(), CellStepError> {
        let initial = self.snapshot();
        let kept: (JointStats, ContactStats) = (self.joint, self.contact_stats);
        let mut found: Vec<(Vec<f64>, Option<Vec<f64>>)> = self
            .cells
            .iter()
            .map(|c| (c.state.sigma.clone(), None))
            .collect();
        let mut report = StartUpReport::default();
        while report.passes < self.start_up_passes {
            self.step_once(comm, u_inf, time, forces)?;
            let mut change = [0.0, 0.0];
            for (c, (sigma, u)) in self.cells.iter().zip(&mut found) {
                for (new, old) in c.state.sigma.iter().zip(sigma.iter()) {
                    change[0] = f64::max(change[0], (new - old).abs());
                    change[1] = f64::max(change[1], new.abs());
                }
                sigma.copy_from_slice(&c.state.sigma);
                *u = c.state.membrane_velocity.clone();
            }
            comm.all_max(&mut change)?;
            self.restore(&initial)?;
            for (c, (sigma, u)) in self.cells.iter_mut().zip(&found) {
                c.state.sigma.copy_from_slice(sigma);
                c.state.membrane_velocity.clone_from(u);
            }
            report.passes += 1;
            report.tension_change = if change[1] > 0.0 {
                change[0] / change[1]
            } else {
                0.0
            };
            if report.tension_change < START_UP_TOLERANCE {
                break;
            }
        }
        (self.joint, self.contact_stats) = kept;
        self.start_up = Some(report);
        Ok(())
    }
}

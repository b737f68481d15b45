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
//! value. Between cells alone the contraction is strong and 2–4 plain passes reach it; against
//! rigid walls, whose response to the cells enters explicitly, a pass contracts by only
//! 0.5–0.6 (13 plain passes in the spherical Couette cell of docs/walls.md). So each pass's
//! output is mixed with the last passes' by Anderson's method
//! ([`crate::timestep::anderson`], depth [`START_UP_ANDERSON_DEPTH`];
//! [`Suspension::set_start_up_anderson_depth`]) before it starts the next pass; the last pass
//! keeps what it found, unmixed. The mixing's inner products are summed in the cells' global
//! order, so the passes are the same on every number of ranks. Everything else the passes changed (surfaces, history, preconditioner records,
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
use crate::timestep::anderson::Anderson;

/// The start-up stops when a pass changes the tension by less than this fraction of its
/// largest value.
pub const START_UP_TOLERANCE: f64 = 1e-3;

/// The most start-up passes by default ([`Suspension::set_start_up_passes`]).
pub const START_UP_PASSES: usize = 8;

/// The depth of Anderson's mixing of the passes by default
/// ([`Suspension::set_start_up_anderson_depth`]).
pub const START_UP_ANDERSON_DEPTH: usize = 3;

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

    /// Mix each pass's densities with the last `depth` passes' by Anderson's method
    /// ([`crate::timestep::anderson`]) before the next pass; 0: plain passes, each starting
    /// from the last one's densities.
    pub fn set_start_up_anderson_depth(&mut self, depth: usize) {
        self.start_up_depth = depth;
    }

    /// The depth of the start-up's mixing ([`Suspension::set_start_up_anderson_depth`]).
    pub fn start_up_anderson_depth(&self) -> usize {
        self.start_up_depth
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
        if self.start_up_passes == 0
            || (self.coupling.is_none() && self.walls.is_none() && self.plane.is_none())
        {
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
        // The densities every cell started the last pass with (`x`) and the ones it found (`g`).
        let mut x: Vec<Vec<f64>> = self.cells.iter().map(|c| c.state.sigma.clone()).collect();
        let mut mixing = Anderson::new(self.start_up_depth);
        let ids: Vec<usize> = self.cells.iter().map(|c| c.id).collect();
        let mut report = StartUpReport::default();
        while report.passes < self.start_up_passes {
            self.step_once(comm, u_inf, time, forces)?;
            let mut change = [0.0, 0.0];
            // What every cell found (`g`), and whether it has a membrane velocity.
            let mut g = Vec::with_capacity(self.cells.len());
            let mut has_u = Vec::with_capacity(self.cells.len());
            for (c, x) in self.cells.iter().zip(&x) {
                for (new, old) in c.state.sigma.iter().zip(x) {
                    change[0] = f64::max(change[0], (new - old).abs());
                    change[1] = f64::max(change[1], new.abs());
                }
                g.push(stack(&c.state.sigma, c.state.membrane_velocity.as_deref()));
                has_u.push(c.state.membrane_velocity.is_some());
            }
            comm.all_max(&mut change)?;
            self.restore(&initial)?;
            report.passes += 1;
            report.tension_change = if change[1] > 0.0 {
                change[0] / change[1]
            } else {
                0.0
            };
            let done =
                report.tension_change < START_UP_TOLERANCE || report.passes == self.start_up_passes;
            // The next pass starts from the mixed densities; the last keeps what it found.
            let x_full: Vec<Vec<f64>> = x
                .iter()
                .zip(&g)
                .map(|(x, g)| {
                    let mut v = x.clone();
                    v.resize(g.len(), 0.0);
                    v
                })
                .collect();
            let next = if done {
                g
            } else {
                mixing.next(&x_full, &g, |rows, width| {
                    sum_in_cell_order(comm, &ids, rows, width)
                })?
            };
            for ((c, next), has_u) in self.cells.iter_mut().zip(&next).zip(&has_u) {
                let n = c.state.sigma.len();
                c.state.sigma.copy_from_slice(&next[..n]);
                c.state.membrane_velocity = has_u.then(|| next[n..].to_vec());
            }
            x = next;
            if done {
                break;
            }
        }
        (self.joint, self.contact_stats) = kept;
        self.start_up = Some(report);
        Ok(())
    }
}

/// A cell's tension followed by its membrane velocity (when it has one): the unknowns of the
/// start-up's fixed point.
fn stack(sigma: &[f64], u: Option<&[f64]>) -> Vec<f64> {
    let mut v = sigma.to_vec();
    v.extend_from_slice(u.unwrap_or(&[]));
    v
}

/// The sums of the cells' rows (each of `width` partial inner products; a rank may hold no
/// cell) over every rank, added in the cells' global order: one rank and many give the same
/// sums bit for bit.
fn sum_in_cell_order(
    comm: &dyn Communicator,
    ids: &[usize],
    rows: Vec<Vec<f64>>,
    width: usize,
) -> Result<Vec<f64>, CellStepError> {
    let mut local = Vec::with_capacity(rows.len() * (width + 1));
    for (id, row) in ids.iter().zip(&rows) {
        local.push(*id as f64);
        local.extend_from_slice(row);
    }
    let gathered = comm.all_gather_f64(&local)?;
    let mut all: Vec<&[f64]> = gathered
        .iter()
        .flat_map(|g| g.chunks_exact(width + 1))
        .collect();
    all.sort_by(|a, b| a[0].total_cmp(&b[0]));
    let mut sums = vec![0.0; width];
    for row in all {
        for (s, v) in sums.iter_mut().zip(&row[1..]) {
            *s += v;
        }
    }
    Ok(sums)
}

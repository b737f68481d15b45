//! Cells recycled through a tube: a finite tube that behaves, for its cells, like a periodic
//! one.
//!
//! A tube wall (`crate::wall::tube_surface`) is closed: Poiseuille's flow enters and leaves
//! through its rounded ends, and cells carried by the flow would gather at the outlet within
//! one transit. Lu, Morse, Rahimian, Stadler & Zorin (SC'19) keep a vessel's hematocrit the
//! same way: a cell that leaves through an outlet is put back at an inlet. Here the tube's
//! straight middle section `x_in ≤ x ≤ x_out` (where its radius is that of a cylinder) is the
//! window: after every step (after the contact projection), a cell whose centre
//! `c_00/√(4π)` has passed `x_out` is translated by `−P = x_in − x_out` along the axis, the
//! window's length, with its previous surface (BDF2's history) and the rest of its state, as
//! the contact projection moves cells. The cell keeps its shape, tension and radial position;
//! the flow in the straight section is the same at both places, so its velocity carries over.
//!
//! A cell is moved only where it lands clear of every other cell and of the walls by at least
//! [`Recycling::clearance`] (the contact solver's measure,
//! [`crate::timestep::contact::ContactSolver::clearance_of`]); otherwise it goes on toward the
//! outlet and is tried again at the next step (counted as deferred). Cells are tried in the
//! order of their global index, each against the others as already moved, and every rank
//! decides the same moves from the gathered surfaces, so the result does not depend on the
//! number of ranks.

use super::super::contact::{ContactParams, ContactSolver};
use super::{CellStepError, Suspension};
use crate::comm::Communicator;
use crate::timestep::TimestepError;

/// Where a tube's cells leave and re-enter ([`Suspension::set_recycling`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Recycling {
    /// The outlet `x_out`: a cell whose centre passes it is moved back by [`Self::period`].
    pub outlet: f64,
    /// The window's length `P = x_out − x_in`.
    pub period: f64,
    /// The smallest gap to other cells and walls at which a moved cell may land.
    pub clearance: f64,
}

/// What the recycling did (cumulative; `summary.json`'s `counters.recycling`).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct RecycleStats {
    /// Cells moved from the outlet back to the inlet.
    pub recycled: usize,
    /// Steps at which a cell past the outlet could not land clear and went on.
    pub deferred: usize,
    /// Seconds spent deciding and moving.
    pub seconds: f64,
}

impl Suspension {
    /// Recycle cells through a tube's window after every step (module docs; `None`: off).
    pub fn set_recycling(&mut self, recycling: Option<Recycling>) {
        self.recycling = recycling;
    }

    /// The recycling set by [`Suspension::set_recycling`].
    pub fn recycling(&self) -> Option<Recycling> {
        self.recycling
    }

    /// What the recycling did.
    pub fn recycle_stats(&self) -> RecycleStats {
        self.recycle_stats
    }

    /// Move the cells past the outlet back by the window's length where they land clear
    /// (collective).
    pub(super) fn recycle(&mut self, comm: &dyn Communicator) -> Result<(), CellStepError> {
        let Some(r) = self.recycling else {
            return Ok(());
        };
        let t0 = std::time::Instant::now();
        let s = (4.0 * std::f64::consts::PI).sqrt();
        let shift = r.period * s;
        let fail = |source| CellStepError { cell: None, source };
        // The surfaces are gathered only at the steps where some rank has a cell past the
        // outlet.
        let mut any = [self
            .cells
            .iter()
            .filter(|c| c.state.coefs[0] / s > r.outlet)
            .count() as u64];
        comm.all_sum_u64(&mut any)
            .map_err(|e| fail(TimestepError::Comm(e)))?;
        let mut moved = Vec::new();
        if any[0] > 0 {
            let (ids, mut coefs) = self.all_surfaces(comm)?;
            let past: Vec<usize> = (0..ids.len())
                .filter(|&k| coefs[k][0] / s > r.outlet)
                .collect();
            // Every cell has the suspension's order: 3 (p + 1)² coefficients.
            let p = ((coefs[0].len() / 3) as f64).sqrt().round() as usize - 1;
            let solver = ContactSolver::new(p, ContactParams::new(r.clearance))
                .map_err(|e| fail(TimestepError::Contact(e)))?;
            let fixed = self
                .walls
                .as_ref()
                .map(|w| w.fixed_surfaces())
                .unwrap_or(&[]);
            for k in past {
                let before = coefs[k][0];
                coefs[k][0] -= shift;
                let views: Vec<&[f64]> = coefs.iter().map(|c| c.as_slice()).collect();
                let gap = solver
                    .clearance_of(&views, k, fixed, 2.0 * r.clearance)
                    .map_err(|e| fail(TimestepError::Contact(e)))?;
                if gap >= r.clearance {
                    moved.push(ids[k]);
                } else {
                    coefs[k][0] = before;
                    self.recycle_stats.deferred += 1;
                }
            }
        }
        for c in &mut self.cells {
            if moved.binary_search(&c.id).is_ok() {
                c.state.coefs[0] -= shift;
                if let Some(prev) = &mut c.state.previous_coefs {
                    prev[0] -= shift;
                }
            }
        }
        self.recycle_stats.recycled += moved.len();
        self.recycle_stats.seconds += t0.elapsed().as_secs_f64();
        Ok(())
    }
}

//! The contact projection at the end of a suspension's step ([`super::super::contact`]): the
//! cells that came closer than `d_min` are moved apart rigidly (translated and turned), each
//! with its whole history ([`super::rigid_move`]), so that the step's extrapolations
//! (`X* = 2Xⁿ − Xⁿ⁻¹`, the BDF2 derivative) see a rigid motion and no spurious velocity.
//!
//! Until the seventeenth session a step only translated cells. In the 45 % Couette shell of
//! docs/hard_cases.md (16 RBCs jammed between a turning inner sphere and the container) a cell
//! came to be wedged at step 505: translations alone had no solution (projected Gauss–Seidel
//! ran 100 000 sweeps a round without meeting the linearised constraints, and the rounds
//! stalled with a gap 6 % short of `d_min`), while with rotations every round of that step and
//! the next converged in about 15 sweeps and one round.
//!
//! Over several ranks every rank gathers every cell's surface and solves the same projection
//! (deterministic: the same moves on every rank), then moves its own cells.

use super::super::contact::{ContactParams, ContactSolver, ContactStats};
use super::super::TimestepError;
use super::{CellStepError, Suspension};
use crate::comm::Communicator;

impl Suspension {
    /// Keep every pair of cells at least `params.distance` apart at the end of every step
    /// (`None`: no contact projection, the default). Cells are translated and turned
    /// (`params.rotations` is set; module docs).
    pub fn set_contacts(
        &mut self,
        p: usize,
        params: Option<ContactParams>,
    ) -> Result<(), CellStepError> {
        self.contacts = match params {
            None => None,
            Some(mut params) => {
                params.rotations = true;
                Some(ContactSolver::new(p, params).map_err(|e| CellStepError {
                    cell: None,
                    source: TimestepError::Contact(e),
                })?)
            }
        };
        Ok(())
    }

    /// What the contact projection did (cumulative; zeros without contacts).
    pub fn contact_stats(&self) -> ContactStats {
        self.contact_stats
    }

    /// Every cell's surface (order-`p` coefficients) on every rank, in the order of the cells'
    /// global indices, with those indices (collective).
    pub(super) fn all_surfaces(
        &self,
        comm: &dyn Communicator,
    ) -> Result<(Vec<usize>, Vec<Vec<f64>>), CellStepError> {
        let blocks: Vec<(usize, [&[f64]; 1])> = self
            .cells
            .iter()
            .map(|c| (c.id, [c.state.coefs.as_slice()]))
            .collect();
        let all = super::gather::gather_by_cell(comm, &blocks)?;
        Ok(all.into_iter().map(|(id, [c])| (id, c)).unzip())
    }

    /// The projection after a step (collective; nothing without contacts, or with one cell
    /// and no walls). Rigid walls are fixed surfaces the cells are kept `d_min` from.
    pub(super) fn resolve_contacts(
        &mut self,
        comm: &dyn Communicator,
    ) -> Result<(), CellStepError> {
        let Some(solver) = &self.contacts else {
            return Ok(());
        };
        let fixed = self
            .walls
            .as_ref()
            .map(|w| w.fixed_surfaces())
            .unwrap_or(&[]);
        let planes: Vec<_> = self.plane.iter().map(|w| w.contact_plane()).collect();
        if self.n_global < 2 && fixed.is_empty() && planes.is_empty() {
            return Ok(());
        }
        let t0 = std::time::Instant::now();
        let fail = |source| CellStepError { cell: None, source };
        let (ids, all) = self.all_surfaces(comm)?;
        let coefs: Vec<&[f64]> = all.iter().map(|c| c.as_slice()).collect();
        let out = solver.resolve_with(&coefs, &planes, fixed).map_err(|e| {
            fail(TimestepError::Contact(match e {
                super::super::contact::ContactError::Unresolved {
                    rounds,
                    gap,
                    d_min,
                    a,
                    b,
                } => super::super::contact::ContactError::Unresolved {
                    rounds,
                    gap,
                    d_min,
                    a: ids[a],
                    b: b.map(|b| ids[b]),
                },
                other => other,
            }))
        })?;
        for c in &mut self.cells {
            let k = ids.binary_search(&c.id).expect("every cell was gathered");
            let m = &out.moves[k];
            if m.is_identity() {
                continue;
            }
            super::rigid_move::move_state(&mut c.state, m);
        }
        let s = &mut self.contact_stats;
        s.steps += 1;
        if out.rounds > 0 {
            s.steps_with_moves += 1;
        }
        s.rounds += out.rounds;
        s.active += out.active;
        s.moves += out.moved;
        s.seconds += t0.elapsed().as_secs_f64();
        s.last_gap = out.gap_after.is_finite().then_some(out.gap_after);
        if let Some(g) = s.last_gap {
            s.smallest_gap = Some(s.smallest_gap.map_or(g, |m| m.min(g)));
        }
        Ok(())
    }
}

//! GMRES's inner products over MPI ranks: each rank holds some rows of every vector, and every
//! rank gets the same sums, so that all of them run the same Arnoldi recurrence.

use std::sync::Mutex;

use super::gmres::{dot, InnerProducts};
use crate::comm::{CommError, Communicator};

/// Inner products summed over the ranks in rank order (the same value on every rank). A
/// failed exchange gives NaN here, which ends this rank's solve, and is kept (an MPI failure
/// is in practice the whole job's).
pub(in crate::timestep) struct RankSums<'a> {
    comm: &'a dyn Communicator,
    failure: Mutex<Option<CommError>>,
}

impl<'a> RankSums<'a> {
    /// Sums over the ranks of `comm`.
    pub(in crate::timestep) fn new(comm: &'a dyn Communicator) -> Self {
        RankSums {
            comm,
            failure: Mutex::new(None),
        }
    }

    /// The first failed exchange, if any.
    pub(in crate::timestep) fn failure(self) -> Option<CommError> {
        self.failure.into_inner().unwrap_or_else(|e| e.into_inner())
    }

    fn total(&self, local: f64) -> f64 {
        match self.comm.all_gather_f64(&[local]) {
            Ok(all) => all.iter().map(|v| v.first().copied().unwrap_or(0.0)).sum(),
            Err(e) => {
                let mut slot = self.failure.lock().unwrap_or_else(|e| e.into_inner());
                slot.get_or_insert(e);
                f64::NAN
            }
        }
    }
}

impl InnerProducts for RankSums<'_> {
    fn dot(&self, a: &[f64], b: &[f64]) -> f64 {
        self.total(dot(a, b))
    }
    fn any(&self, local: bool) -> bool {
        // NaN (a failed exchange) counts as true.
        self.total(if local { 1.0 } else { 0.0 }) != 0.0
    }
}

//! Per-cell blocks of values gathered from every rank, in the cells' global order: what the
//! contact projection (every cell's surface) and the plane wall (every cell's image sources)
//! need on every rank, summed or searched in one order whatever the ranks.

use super::CellStepError;
use crate::comm::Communicator;
use crate::timestep::TimestepError;

/// A cell's block: its global index and its `K` parts.
pub(super) type CellBlock<const K: usize> = (usize, [Vec<f64>; K]);

/// Every rank's `blocks` (each `(global index, parts)`, every cell the same number of parts)
/// on every rank, sorted by global index (collective). Each block travels as its index, the
/// parts' lengths and the parts.
pub(super) fn gather_by_cell<const K: usize>(
    comm: &dyn Communicator,
    blocks: &[(usize, [&[f64]; K])],
) -> Result<Vec<CellBlock<K>>, CellStepError> {
    let mut local = Vec::new();
    for (id, parts) in blocks {
        local.push(*id as f64);
        local.extend(parts.iter().map(|p| p.len() as f64));
        for p in parts {
            local.extend_from_slice(p);
        }
    }
    let gathered = comm.all_gather_f64(&local).map_err(|e| CellStepError {
        cell: None,
        source: TimestepError::Comm(e),
    })?;
    let mut all = Vec::new();
    for part in &gathered {
        let mut at = 0;
        while at < part.len() {
            let id = part[at] as usize;
            let lens: [usize; K] = std::array::from_fn(|k| part[at + 1 + k] as usize);
            at += 1 + K;
            let parts = lens.map(|len| {
                let p = part[at..at + len].to_vec();
                at += len;
                p
            });
            all.push((id, parts));
        }
    }
    all.sort_by_key(|a| a.0);
    Ok(all)
}

//! How the cells of a run are split between MPI ranks, and moved when the split goes stale.
//!
//! **Split.** Cells are ordered along the Morton (Z-order) curve of their centres (the mean
//! of their grid parametrisation, `c₀₀/√(4π)` per component), in the bounding cube of all
//! centres at 21 bits per axis ([`Domain::key`]), ties broken by the cell index, and the curve is cut into `K`
//! consecutive pieces of equal total **cost** (a cell goes to the rank whose share of the cost
//! contains the middle of its own). Consecutive pieces of a space-filling curve are compact
//! in space, which is what the distributed FMM's own partition of points does (it cuts the
//! Morton curve of the points); a cell whose points straddle two ranks' key intervals is
//! owned by the rank that holds its centre. The split is a pure function of the centres, the
//! costs and `K`: every rank computes the same one, and a resumed run recomputes the same.
//!
//! **Cost** of a cell: `ASSEMBLY_COST + i`, with `i` the GMRES iterations of its last solve
//! (deterministic, unlike a clock, so that the split, and with it the run, is reproducible):
//! a step's work is the assembly of the cell's dense operators plus one dense product per
//! iteration; `ASSEMBLY_COST` is that assembly in units of one iteration's product (measured
//! at p = 6 to 12 on this project's machines: the assembly costs about as much as 10–20
//! products; see `docs/scaling.md`).
//!
//! **Re-balance.** Every [`CHECK_EVERY`] steps (scene: `[numerics] rebalance_every`) the ranks gather every cell's centre and cost
//! (5 values a cell) and compute a fresh split; the cells move to it when the current split's
//! cost imbalance (largest rank cost over mean, minus 1) exceeds [`MAX_IMBALANCE`] (scene:
//! `max_imbalance`), or when
//! more than [`MAX_STALE`] of the cells would change rank (the cells have moved along the
//! curve, and ghost exchanges grow with the lost locality). A moving cell travels as its
//! [`CellState`] (one all-to-all), and is rebuilt from its setup on its new rank.

use crate::comm::{CommError, Communicator};
use crate::fmm::box_key::Domain;
use crate::fmm::octree::bounding_box;
use crate::timestep::cell_state::{CellState, CellStateError};
use crate::timestep::suspension::{CellSetup, CellStepError, Suspension};
use crate::timestep::TimestepError;

/// Cost of a cell step besides its GMRES iterations, in iterations.
pub const ASSEMBLY_COST: f64 = 12.0;
/// Cost imbalance above which cells are moved (default; the scene's `[numerics] max_imbalance`).
pub use crate::scene::cells::MAX_IMBALANCE;
/// Steps between checks of the split (default; the scene's `[numerics] rebalance_every`).
pub use crate::scene::cells::REBALANCE_EVERY as CHECK_EVERY;
/// Fraction of cells on a stale rank above which cells are moved.
pub const MAX_STALE: f64 = 0.25;

/// Why the cells were moved.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Reason {
    /// The costs of the ranks drifted apart.
    Imbalance,
    /// The cells moved in space: the split lost its locality.
    Locality,
}

/// Cost of a cell whose last solve took `iterations`.
pub fn cost(iterations: usize) -> f64 {
    ASSEMBLY_COST + iterations as f64
}

/// Mean position of the grid parametrisation of a surface with order-`p` coefficients
/// `coefs` (x, y, z blocks): `c₀₀ Y₀⁰ = c₀₀/√(4π)` per component.
pub fn centre(coefs: &[f64]) -> [f64; 3] {
    let nb = coefs.len() / 3;
    let y00 = 1.0 / (4.0 * std::f64::consts::PI).sqrt();
    [coefs[0] * y00, coefs[nb] * y00, coefs[2 * nb] * y00]
}

/// The owner rank of each cell for `ranks` ranks (see the module docs). Every rank receives
/// at least one cell when there are at least as many cells as ranks.
pub fn split(centres: &[[f64; 3]], costs: &[f64], ranks: usize) -> Vec<usize> {
    let n = centres.len();
    if ranks <= 1 || n == 0 {
        return vec![0; n];
    }
    // The cube of the centres, as the FMM's tree takes it.
    let (lo, hi) = bounding_box(centres);
    let domain = Domain::from_bounds(lo, hi);
    let key = |c: &[f64; 3]| domain.key(*c);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by_key(|&i| (key(&centres[i]), i));
    let total: f64 = costs.iter().sum();
    let mut owners = vec![0; n];
    let mut before = 0.0;
    for (pos, &i) in order.iter().enumerate() {
        let mid = before + 0.5 * costs[i];
        before += costs[i];
        let mut r = ((mid / total) * ranks as f64).floor() as usize;
        // Leave at least one cell for each later rank, take at least one for each earlier.
        r = r.min(ranks - 1).min(pos).max(ranks.saturating_sub(n - pos));
        owners[i] = r;
    }
    // Monotone along the curve (the clamps above keep it so).
    owners
}

/// Largest rank cost over the mean, minus 1.
pub fn imbalance(owners: &[usize], costs: &[f64], ranks: usize) -> f64 {
    let mut per = vec![0.0; ranks.max(1)];
    for (&r, &c) in owners.iter().zip(costs) {
        per[r.min(ranks - 1)] += c;
    }
    let mean = per.iter().sum::<f64>() / per.len() as f64;
    if mean > 0.0 {
        per.iter().fold(0.0, |a: f64, &b| a.max(b)) / mean - 1.0
    } else {
        0.0
    }
}

/// Every cell's centre and cost, in global order, on every rank (collective).
pub fn gather_inputs(
    comm: &dyn Communicator,
    susp: &Suspension,
) -> Result<(Vec<[f64; 3]>, Vec<f64>), CommError> {
    let mut mine = Vec::with_capacity(5 * susp.len());
    for cell in susp.cells() {
        let x = centre(&cell.state.coefs);
        mine.extend_from_slice(&[
            cell.id as f64,
            x[0],
            x[1],
            x[2],
            cost(cell.state.iterations),
        ]);
    }
    let all = comm.all_gather_f64(&mine)?;
    let n = susp.n_global();
    let mut centres = vec![[0.0; 3]; n];
    let mut costs = vec![0.0; n];
    for rec in all.iter().flat_map(|b| b.chunks_exact(5)) {
        let id = rec[0] as usize;
        if id < n {
            centres[id] = [rec[1], rec[2], rec[3]];
            costs[id] = rec[4];
        }
    }
    Ok((centres, costs))
}

/// Move the cells to `owners` (collective): each rank sends the cells it holds that belong
/// elsewhere, as their [`CellState`], and rebuilds those it receives from `setups` (every
/// cell's setup, global order). Returns the bytes this rank sent.
pub fn migrate(
    comm: &dyn Communicator,
    susp: &mut Suspension,
    p: usize,
    setups: &[CellSetup],
    owners: &[usize],
) -> Result<u64, CellStepError> {
    let me = comm.rank();
    let mut send = vec![Vec::new(); comm.size()];
    let mut i = 0;
    while i < susp.len() {
        let id = susp.cells()[i].id;
        let to = owners[id];
        if to == me {
            i += 1;
            continue;
        }
        let (id, state) = susp.take_cell(i);
        send[to].push(id as f64);
        state.encode(&mut send[to]);
    }
    let bytes = send.iter().map(|b| 8 * b.len() as u64).sum();
    let comm_err = |e: CommError| CellStepError {
        cell: None,
        source: TimestepError::Comm(e),
    };
    let received = comm.all_to_all_f64(&send).map_err(comm_err)?;
    let ncoef = setups.first().map_or(0, |s| s.coefs.len());
    let n = 2 * p * (p + 1);
    let record = 1 + CellState::encoded_len(ncoef, n);
    let mut outcome = Ok(());
    for buf in &received {
        for rec in buf.chunks(record) {
            let id = rec[0] as usize;
            let done = setups
                .get(id)
                .ok_or_else(|| {
                    CellStateError(format!(
                        "cell {id} is not one of the run's {} cells",
                        setups.len()
                    ))
                })
                .and_then(|setup| Ok((setup, CellState::decode(&rec[1..], ncoef, n)?)))
                .map_err(|source| CellStepError {
                    cell: Some(id),
                    source: TimestepError::Moved { rank: me, source },
                })
                .and_then(|(setup, state)| susp.insert_cell(p, id, setup, Some(&state)));
            if outcome.is_ok() {
                outcome = done;
            }
        }
    }
    crate::timestep::suspension::agree_cells(comm, outcome)?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_are_contiguous_along_the_curve_balanced_and_leave_no_rank_empty() {
        // A 6 × 6 × 6 lattice of cells; the cells of one octant cost 5× more.
        let mut centres = Vec::new();
        let mut costs = Vec::new();
        for i in 0..6 {
            for j in 0..6 {
                for k in 0..6 {
                    centres.push([i as f64, j as f64, k as f64]);
                    costs.push(if i < 3 && j < 3 && k < 3 { 5.0 } else { 1.0 });
                }
            }
        }
        for ranks in [1, 2, 3, 4, 7, 16] {
            let owners = split(&centres, &costs, ranks);
            let mut count = vec![0; ranks];
            for &r in &owners {
                count[r] += 1;
            }
            assert!(count.iter().all(|&c| c > 0), "{ranks} ranks: {count:?}");
            // Balanced within one cell's cost of the mean share.
            let imb = imbalance(&owners, &costs, ranks);
            let mean = costs.iter().sum::<f64>() / ranks as f64;
            assert!(imb * mean <= 5.0 + 1e-9, "{ranks} ranks: imbalance {imb}");
            // The same input gives the same split.
            assert_eq!(owners, split(&centres, &costs, ranks));
        }
        // Fewer cells than ranks: one each, the rest empty.
        assert_eq!(split(&centres[..3], &costs[..3], 5).len(), 3);
    }

    #[test]
    fn centres_are_the_mean_of_the_parametrisation() {
        // A unit sphere moved to (1, -2, 3): the l = 0 coefficients are √(4π) times the centre.
        let s = (4.0 * std::f64::consts::PI).sqrt();
        let mut c = vec![0.0; 3 * 15];
        c[0] = s;
        c[15] = -2.0 * s;
        c[30] = 3.0 * s;
        let x = centre(&c);
        for (a, b) in x.iter().zip([1.0, -2.0, 3.0]) {
            assert!((a - b).abs() < 1e-14);
        }
    }
}

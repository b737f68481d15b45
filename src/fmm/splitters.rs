//! Where the key line is cut between ranks: the splitters of [`super::dist_tree`].
//!
//! The tree's points are ordered by Morton key; rank `r` owns the keys
//! `splitters[r]..splitters[r + 1]`. [`histogram_splitters`] cuts the points into equal counts
//! per rank by a parallel selection with histograms: `O(K)` integers per rank and round, a
//! few rounds, where the regular sampling it replaced gathered `O(K²)` keys to every rank.
//! [`snap_splitters`] then moves each cut down to the first key of the global leaf that holds
//! it, so that no leaf is cut and the tree does not depend on `K`.

use super::box_key::{BoxKey, Domain, KEY_END};
use super::octree::MAX_DEPTH;
use crate::comm::{CommError, Communicator};

/// Probes per open splitter and round of [`histogram_splitters`].
pub const PROBES: u128 = 15;
/// The ranks' key counts agree to within `1 / SPLIT_TOLERANCE` of a rank's share (0.5 %)
/// before the splitters are moved to leaf boundaries.
pub const SPLIT_TOLERANCE: u64 = 200;

/// The search of one splitter of [`histogram_splitters`]: keys `lo < hi` whose global ranks
/// (keys below them, over all ranks) enclose the splitter's goal rank.
#[derive(Clone, Copy)]
struct Bracket {
    lo: u64,
    lo_rank: u64,
    hi: u64,
    hi_rank: u64,
    goal: u64,
}

/// Splitters of the key line that cut the global sorted keys into `K` pieces of equal count
/// to within `tol` keys: a parallel selection by histograms (histogram sort, Kalé & Krishnan
/// 1993; Solomonik & Kalé, IPDPS 2010). Each splitter keeps a bracket of the key line whose
/// ends' global ranks enclose its goal `b·N/K`; every round probes [`PROBES`] keys evenly
/// spaced inside each open bracket, counts this rank's keys below each probe, sums the counts
/// over ranks (one reduction of at most `(K − 1) · 15` integers) and narrows each bracket to
/// the probes around its goal. A bracket closes when one end's rank is within `tol` of the
/// goal, `tol = N / (K · rel)` (or it holds one key value); that end is the splitter. Each
/// round shrinks a bracket 16-fold in key width and, on locally even keys, in count, so
/// `log₁₆(N / tol)` rounds
/// suffice (3 at `N = 10⁶`, `K = 16`), at most 16 in any case. Every rank gets `O(K)`
/// integers a round, where regular sampling gathered `O(K²)` keys to every rank.
pub fn histogram_splitters(
    comm: &dyn Communicator,
    keys: &[u64],
    rel: u64,
) -> Result<Vec<u64>, CommError> {
    let k = comm.size();
    let mut n = [keys.len() as u64];
    comm.all_sum_u64(&mut n)?;
    let n = n[0];
    if n == 0 {
        let mut out = vec![0u64];
        out.resize(k + 1, KEY_END);
        return Ok(out);
    }
    let tol = (n / (k as u64 * rel.max(1))).max(1);
    let mut brackets: Vec<Bracket> = (1..k)
        .map(|b| Bracket {
            lo: 0,
            lo_rank: 0,
            hi: KEY_END,
            hi_rank: n,
            goal: (n as u128 * b as u128 / k as u128) as u64,
        })
        .collect();
    let closed = |br: &Bracket| {
        br.goal - br.lo_rank <= tol || br.hi_rank - br.goal <= tol || br.hi - br.lo <= 1
    };
    loop {
        let open: Vec<usize> = (0..brackets.len())
            .filter(|&b| !closed(&brackets[b]))
            .collect();
        if open.is_empty() {
            break;
        }
        let probes: Vec<u64> = open
            .iter()
            .flat_map(|&b| {
                let Bracket { lo, hi, .. } = brackets[b];
                let w = (hi - lo) as u128;
                (1..=PROBES).map(move |j| lo + (w * j / (PROBES + 1)) as u64)
            })
            .collect();
        let mut counts: Vec<u64> = probes
            .iter()
            .map(|&p| keys.partition_point(|&x| x < p) as u64)
            .collect();
        comm.all_sum_u64(&mut counts)?;
        for (i, &b) in open.iter().enumerate() {
            let br = &mut brackets[b];
            let at = i * PROBES as usize;
            for (&p, &c) in probes[at..at + PROBES as usize]
                .iter()
                .zip(&counts[at..at + PROBES as usize])
            {
                if c <= br.goal && p > br.lo {
                    br.lo = p;
                    br.lo_rank = c;
                }
                if c >= br.goal && p < br.hi {
                    br.hi = p;
                    br.hi_rank = c;
                    break;
                }
            }
        }
    }
    let mut out = vec![0u64];
    out.extend(brackets.iter().map(|br| {
        if br.goal - br.lo_rank <= br.hi_rank - br.goal {
            br.lo
        } else {
            br.hi
        }
    }));
    out.push(KEY_END);
    Ok(out)
}

/// Move each inner splitter down to the first key of the global leaf that contains it.
pub fn snap_splitters(
    comm: &dyn Communicator,
    domain: &Domain,
    keys: &[u64],
    splitters: &mut [u64],
    leaf_size: usize,
    min_width: f64,
) -> Result<(), CommError> {
    let k = splitters.len() - 1;
    let levels = (MAX_DEPTH + 1) as usize;
    let mut counts = vec![0u64; (k - 1) * levels];
    for b in 1..k {
        for l in 0..levels {
            let bx = BoxKey::containing(splitters[b].min(KEY_END - 1), l as u32);
            let lo = keys.partition_point(|&x| x < bx.morton);
            let hi = keys.partition_point(|&x| x < bx.end());
            counts[(b - 1) * levels + l] = (hi - lo) as u64;
        }
    }
    comm.all_sum_u64(&mut counts)?;
    for b in 1..k {
        if splitters[b] >= KEY_END {
            continue;
        }
        for l in 0..levels {
            let splits = counts[(b - 1) * levels + l] as usize > leaf_size
                && (l as u32) < MAX_DEPTH
                && domain.half(l as u32) >= min_width;
            if !splits {
                splitters[b] = BoxKey::containing(splitters[b], l as u32).morton;
                break;
            }
        }
    }
    Ok(())
}

//! The near field of a point set on itself, each pair of leaves once.
//!
//! When the FMM's targets are its sources (`mobo fmm` without `--targets`, one rank), the
//! near field's U, W and X lists are symmetric: leaf `B` is in leaf `A`'s row exactly when `A`
//! is in `B`'s. For a kernel with `K(x − y) = K(y − x)` both directions of such a pair need each
//! `K(x_i − y_j)` once: `u_i += K_ij q_j` and `u_j += K_ij q_i` (Newton's third law in the
//! N-body codes; [`super::Kernel::eval_mutual_within`]), half the kernel evaluations of the
//! row-by-row pass.
//!
//! [`MutualPairs`] splits a [`NearList`] into the rows' one-way ranges (a leaf with itself, and
//! any range without its mirror) and the mutual pairs of rows, coloured greedily into rounds
//! so that no row appears twice in a round (an edge colouring of the leaves' adjacency graph,
//! at most `2Δ − 1` rounds for `Δ` partners per leaf, about `Δ + 1` in practice): the pairs of
//! one round write disjoint rows and run in parallel, the rounds one after another.

use std::collections::{HashMap, HashSet};
use std::ops::Range;

use super::near_list::NearList;

/// Rounds of a greedy colouring hold at most this many colours; a pair that finds none free
/// (a leaf with more than 64 near partners: deep adaptive trees) stays one-way in both rows.
const MAX_ROUNDS: usize = 128;

/// A [`NearList`] of a point set on itself, split into one-way ranges and mutual row pairs.
/// Built only by [`MutualPairs::build`], which guarantees what the parallel rounds rely on:
/// rows sorted and disjoint, `a < b` in every pair, no row twice in a round.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MutualPairs {
    /// The list it was built from.
    list: NearList,
    /// The same rows as the list, each with the ranges it sums one way.
    one_way: NearList,
    /// Pairs of rows `[a, b]` (`a < b`) whose ranges mirror each other, by round: the pairs of
    /// one round share no row.
    rounds: Vec<Vec<[usize; 2]>>,
}

impl MutualPairs {
    /// Split `list`, whose source ranges index the same points as its target rows (the targets
    /// are the sources, in the same order): a range equal to another row's targets, in a row
    /// whose targets are among that row's ranges, becomes one mutual pair.
    pub fn build(list: &NearList) -> Self {
        let n = list.rows.len();
        let disjoint = list.rows.windows(2).all(|w| w[0].end <= w[1].start);
        if !disjoint {
            // Not a tree's list: everything one way.
            return MutualPairs {
                list: list.clone(),
                one_way: list.clone(),
                rounds: Vec::new(),
            };
        }
        let row_of: HashMap<(usize, usize), usize> = list
            .rows
            .iter()
            .enumerate()
            .map(|(r, t)| ((t.start, t.end), r))
            .collect();
        let has: HashSet<(usize, usize, usize)> = (0..n)
            .flat_map(|r| list.row_ranges(r).iter().map(move |s| (r, s.start, s.end)))
            .collect();
        // Mutual partner of each entry, if any.
        let partner = |r: usize, s: &Range<usize>| -> Option<usize> {
            let &b = row_of.get(&(s.start, s.end))?;
            let t = &list.rows[r];
            (b != r && has.contains(&(b, t.start, t.end))).then_some(b)
        };
        let mut used = vec![0u128; n];
        let mut rounds: Vec<Vec<[usize; 2]>> = Vec::new();
        let mut mutual: HashSet<(usize, usize)> = HashSet::new();
        for a in 0..n {
            for s in list.row_ranges(a) {
                let Some(b) = partner(a, s) else { continue };
                if b < a {
                    continue;
                }
                let free = !(used[a] | used[b]);
                let c = free.trailing_zeros() as usize;
                if c >= MAX_ROUNDS || !mutual.insert((a, b)) {
                    continue;
                }
                used[a] |= 1 << c;
                used[b] |= 1 << c;
                if rounds.len() <= c {
                    rounds.resize(c + 1, Vec::new());
                }
                rounds[c].push([a, b]);
            }
        }
        let mut one_way = NearList {
            rows: list.rows.clone(),
            offsets: vec![0],
            ranges: Vec::new(),
        };
        debug_assert!(
            (0..n).all(|r| {
                let rr = list.row_ranges(r);
                let set: HashSet<(usize, usize)> = rr.iter().map(|s| (s.start, s.end)).collect();
                set.len() == rr.len()
            }),
            "a row sums the same range twice"
        );
        for a in 0..n {
            for s in list.row_ranges(a) {
                let paired = partner(a, s).is_some_and(|b| mutual.contains(&(a.min(b), a.max(b))));
                if !paired {
                    one_way.ranges.push(s.clone());
                }
            }
            one_way.offsets.push(one_way.ranges.len());
        }
        MutualPairs {
            list: list.clone(),
            one_way,
            rounds,
        }
    }

    /// The rows of the list, each with the ranges it sums one way.
    pub fn one_way(&self) -> &NearList {
        &self.one_way
    }

    /// The mutual pairs of rows `[a, b]` (`a < b`), by round; no row twice in a round.
    pub fn rounds(&self) -> &[Vec<[usize; 2]>] {
        &self.rounds
    }

    /// Number of mutual pairs of rows.
    pub fn mutual_pairs(&self) -> usize {
        self.rounds.iter().map(Vec::len).sum()
    }

    /// Whether this split was made for `list` (the same rows and ranges).
    pub fn fits(&self, list: &NearList) -> bool {
        self.list == *list
    }
}

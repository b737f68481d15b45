//! The near field of a tree as one batched list ([`NearList`]): every direct interaction of
//! its leaves, compressed-row, that a [`super::near_field::NearField`] backend evaluates.

use std::ops::Range;

use super::dist_tree::{DistTree, Role};

/// The direct interactions of a tree's leaves, compressed-row: row `r` sums the sources in
/// `ranges[offsets[r]..offsets[r + 1]]` (ranges of the tree's sorted sources) into the targets
/// `rows[r]` (a range of the tree's sorted targets). Rows are disjoint and sorted by target.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NearList {
    /// Target range of each row.
    pub rows: Vec<Range<usize>>,
    /// Start of each row's source ranges in `ranges` (`rows.len() + 1` entries).
    pub offsets: Vec<usize>,
    /// Source ranges of all rows.
    pub ranges: Vec<Range<usize>>,
}

impl NearList {
    /// The near field of `tree`'s owned leaves with targets; `n_surf` is the number of points
    /// of an equivalent surface (the W and X thresholds above).
    pub fn build(tree: &DistTree, n_surf: usize) -> Self {
        let mut leaves: Vec<usize> = (0..tree.boxes.len())
            .filter(|&b| {
                let bx = &tree.boxes[b];
                bx.role == Role::Owned && bx.leaf && !bx.targets.is_empty()
            })
            .collect();
        leaves.sort_by_key(|&b| tree.boxes[b].targets.start);
        let mut list = NearList {
            offsets: vec![0],
            ..Default::default()
        };
        for &b in &leaves {
            let node = &tree.boxes[b];
            let mut push = |s: &Range<usize>| {
                if !s.is_empty() {
                    list.ranges.push(s.clone());
                }
            };
            for &w in &tree.lists.w[b] {
                if Self::w_direct(tree, w) {
                    push(&tree.boxes[w].sources);
                }
            }
            if Self::x_direct(tree, b, n_surf) {
                for &x in &tree.lists.x[b] {
                    push(&tree.boxes[x].sources);
                }
            }
            for &u in &tree.lists.u[b] {
                push(&tree.boxes[u].sources);
            }
            list.rows.push(node.targets.clone());
            list.offsets.push(list.ranges.len());
        }
        list
    }

    /// Whether W-list box `w` acts on a leaf's targets directly (a leaf with at most
    /// [`DistTree::direct_sources`] sources: fewer than the surface points) rather than
    /// through its equivalent density (M2P).
    pub fn w_direct(tree: &DistTree, w: usize) -> bool {
        let wn = &tree.boxes[w];
        wn.leaf && wn.n_sources > 0 && wn.n_sources <= tree.direct_sources
    }

    /// Whether the X list of leaf `b` acts directly on its targets (a leaf with fewer targets
    /// than surface points) rather than through its downward check surface (P2L).
    pub fn x_direct(tree: &DistTree, b: usize, n_surf: usize) -> bool {
        let node = &tree.boxes[b];
        node.leaf && node.n_targets <= n_surf
    }

    /// Source ranges of row `r`.
    pub fn row_ranges(&self, r: usize) -> &[Range<usize>] {
        &self.ranges[self.offsets[r]..self.offsets[r + 1]]
    }

    /// Number of target–source pairs (the work of one evaluation).
    pub fn pairs(&self) -> u64 {
        (0..self.rows.len())
            .map(|r| {
                let ns: usize = self.row_ranges(r).iter().map(|s| s.len()).sum();
                (ns * self.rows[r].len()) as u64
            })
            .sum()
    }
}

//! Adaptive octree on Morton keys with the interaction lists of the FMM.
//!
//! Sources and targets are sorted by the Morton key (21 bits per coordinate, interleaved) of
//! their position in the root cube; every box owns contiguous ranges of both. A box is split
//! while it holds more than `leaf_size` points (sources plus targets) and the maximum depth is
//! not reached; empty children are not created, so clustered clouds (cell surfaces) get deep
//! trees only where points are.
//!
//! Lists (Ying, Biros & Zorin 2004; Greengard's U, V, W, X), with "adjacent" meaning touching:
//!
//! * `U(B)`, `B` a leaf: the leaves adjacent to `B`, `B` included: direct interaction (P2P);
//! * `V(B)`: children of the colleagues of `B`'s parent that are not adjacent to `B`: M2L;
//! * `W(B)`, `B` a leaf: descendants `D` of `B`'s colleagues that are not adjacent to `B` while
//!   their parent is: `D`'s multipole acts on `B`'s targets (M2P);
//! * `X(B)`: the leaves `A` with `B ∈ W(A)`: `A`'s sources act on `B`'s local expansion (P2L).
//!
//! For a target leaf, `U` and `W` of the leaf together with `V` and `X` of it and all its
//! ancestors cover every source exactly once (tested).

/// One box of the tree.
#[derive(Clone, Debug)]
pub struct Node {
    /// Centre of the box.
    pub center: [f64; 3],
    /// Half of the side length.
    pub half: f64,
    /// Depth (root: 0).
    pub level: u32,
    /// Range of sorted sources in this box.
    pub sources: std::ops::Range<usize>,
    /// Range of sorted targets in this box.
    pub targets: std::ops::Range<usize>,
    /// Parent box.
    pub parent: Option<usize>,
    /// Non-empty children.
    pub children: Vec<usize>,
}

impl Node {
    /// Whether the box has no children.
    pub fn is_leaf(&self) -> bool {
        self.children.is_empty()
    }
}

/// Interaction lists of every box (indices into [`Octree::nodes`]).
#[derive(Clone, Debug, Default)]
pub struct Lists {
    /// `U(B)`: adjacent leaves, `B` included (P2P).
    pub u: Vec<Vec<usize>>,
    /// `V(B)`: well-separated children of the parent's colleagues (M2L).
    pub v: Vec<Vec<usize>>,
    /// `W(B)`: non-adjacent descendants of the colleagues whose parent is adjacent (M2P).
    pub w: Vec<Vec<usize>>,
    /// `X(B)`: the leaves `A` with `B ∈ W(A)` (P2L).
    pub x: Vec<Vec<usize>>,
}

impl Lists {
    /// Empty lists for `n` boxes.
    pub fn empty(n: usize) -> Self {
        Lists {
            u: vec![Vec::new(); n],
            v: vec![Vec::new(); n],
            w: vec![Vec::new(); n],
            x: vec![Vec::new(); n],
        }
    }
}

/// The octree over a set of sources and targets.
#[derive(Clone, Debug)]
pub struct Octree {
    /// Boxes; the root is box 0, children come after their parent.
    pub nodes: Vec<Node>,
    /// `sources_sorted[i] = sources[source_perm[i]]`.
    pub source_perm: Vec<usize>,
    /// `targets_sorted[i] = targets[target_perm[i]]`.
    pub target_perm: Vec<usize>,
    /// Sources in Morton order.
    pub sources_sorted: Vec<[f64; 3]>,
    /// Targets in Morton order.
    pub targets_sorted: Vec<[f64; 3]>,
    /// Maximum number of points in a leaf (unless the depth limit is hit).
    pub leaf_size: usize,
}

const BITS: u32 = 21;
/// Deepest level of the tree.
pub const MAX_DEPTH: u32 = BITS;

/// Interleave the low 21 bits of `v` with two zero bits between each.
pub(super) fn spread(v: u64) -> u64 {
    let mut x = v & 0x1f_ffff;
    x = (x | (x << 32)) & 0x1f00000000ffff;
    x = (x | (x << 16)) & 0x1f0000ff0000ff;
    x = (x | (x << 8)) & 0x100f00f00f00f00f;
    x = (x | (x << 4)) & 0x10c30c30c30c30c3;
    x = (x | (x << 2)) & 0x1249249249249249;
    x
}

/// The smallest box `[lo, hi]` holding `points` (`lo = +∞`, `hi = −∞` when there are none).
pub fn bounding_box<'a>(points: impl IntoIterator<Item = &'a [f64; 3]>) -> ([f64; 3], [f64; 3]) {
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}

/// Morton key of a point in the cube `[lo, lo + side)³`.
pub fn morton_key(p: [f64; 3], lo: [f64; 3], side: f64) -> u64 {
    let scale = (1u64 << BITS) as f64 / side;
    let q = |k: usize| (((p[k] - lo[k]) * scale) as i64).clamp(0, (1 << BITS) - 1) as u64;
    (spread(q(0)) << 2) | (spread(q(1)) << 1) | spread(q(2))
}

impl Octree {
    /// Build the tree over `sources` and `targets` (pass the same slice twice when they
    /// coincide).
    pub fn new(sources: &[[f64; 3]], targets: &[[f64; 3]], leaf_size: usize) -> Self {
        Self::with_min_width(sources, targets, leaf_size, 0.0)
    }

    /// As [`Octree::new`], but boxes are not split below side length `min_width` (the RPY FMM
    /// needs boxes at least one bead diameter wide so that every pair in separated boxes is at
    /// distance `≥ 2a`).
    pub fn with_min_width(
        sources: &[[f64; 3]],
        targets: &[[f64; 3]],
        leaf_size: usize,
        min_width: f64,
    ) -> Self {
        let leaf_size = leaf_size.max(1);
        let (mut lo, mut hi) = bounding_box(sources.iter().chain(targets));
        if sources.is_empty() && targets.is_empty() {
            lo = [0.0; 3];
            hi = [1.0; 3];
        }
        let mut side = (0..3).map(|k| hi[k] - lo[k]).fold(0.0f64, f64::max);
        side = if side > 0.0 {
            side * (1.0 + 1e-10)
        } else {
            1.0
        };
        let center = [lo[0] + side / 2.0, lo[1] + side / 2.0, lo[2] + side / 2.0];
        let sort = |pts: &[[f64; 3]]| {
            let mut keyed: Vec<(u64, usize)> = pts
                .iter()
                .enumerate()
                .map(|(i, p)| (morton_key(*p, lo, side), i))
                .collect();
            keyed.sort_unstable();
            keyed
        };
        let ks = sort(sources);
        let kt = sort(targets);
        let mut tree = Octree {
            nodes: vec![Node {
                center,
                half: side / 2.0,
                level: 0,
                sources: 0..sources.len(),
                targets: 0..targets.len(),
                parent: None,
                children: Vec::new(),
            }],
            source_perm: ks.iter().map(|k| k.1).collect(),
            target_perm: kt.iter().map(|k| k.1).collect(),
            sources_sorted: ks.iter().map(|k| sources[k.1]).collect(),
            targets_sorted: kt.iter().map(|k| targets[k.1]).collect(),
            leaf_size,
        };
        let skeys: Vec<u64> = ks.iter().map(|k| k.0).collect();
        let tkeys: Vec<u64> = kt.iter().map(|k| k.0).collect();
        let mut stack = vec![0usize];
        while let Some(b) = stack.pop() {
            let node = &tree.nodes[b];
            let count = node.sources.len() + node.targets.len();
            // Children have side `node.half`.
            if count <= leaf_size || node.level >= MAX_DEPTH || node.half < min_width {
                continue;
            }
            let level = node.level + 1;
            let shift = 3 * (BITS - level);
            let (sr, tr, c, h) = (
                node.sources.clone(),
                node.targets.clone(),
                node.center,
                node.half / 2.0,
            );
            // Split each range by the octant bits of this level (keys are sorted).
            let split = |keys: &[u64], r: std::ops::Range<usize>| -> [std::ops::Range<usize>; 8] {
                let mut out: [std::ops::Range<usize>; 8] = Default::default();
                let mut start = r.start;
                for (o, slot) in out.iter_mut().enumerate() {
                    let end = start
                        + keys[start..r.end].partition_point(|k| ((k >> shift) & 7) as usize <= o);
                    *slot = start..end;
                    start = end;
                }
                out
            };
            let so = split(&skeys, sr);
            let to = split(&tkeys, tr);
            for o in 0..8 {
                if so[o].is_empty() && to[o].is_empty() {
                    continue;
                }
                // Octant bits: x is the highest of the three.
                let off = |bit: usize| if (o >> bit) & 1 == 1 { h } else { -h };
                let child = Node {
                    center: [c[0] + off(2), c[1] + off(1), c[2] + off(0)],
                    half: h,
                    level,
                    sources: so[o].clone(),
                    targets: to[o].clone(),
                    parent: Some(b),
                    children: Vec::new(),
                };
                let id = tree.nodes.len();
                tree.nodes.push(child);
                tree.nodes[b].children.push(id);
                stack.push(id);
            }
        }
        tree
    }

    /// Number of levels (deepest level + 1).
    pub fn depth(&self) -> u32 {
        self.nodes.iter().map(|n| n.level).max().unwrap_or(0) + 1
    }

    /// Whether boxes `a` and `b` touch (share at least a corner) or overlap.
    pub fn adjacent(&self, a: usize, b: usize) -> bool {
        let (na, nb) = (&self.nodes[a], &self.nodes[b]);
        let lim = (na.half + nb.half) * (1.0 + 1e-9);
        (0..3).all(|k| (na.center[k] - nb.center[k]).abs() <= lim)
    }

    /// The U, V, W and X lists of every box.
    pub fn lists(&self) -> Lists {
        let n = self.nodes.len();
        let mut colleagues: Vec<Vec<usize>> = vec![Vec::new(); n];
        colleagues[0] = vec![0];
        // Children come after parents, so one forward pass sees parents first.
        for b in 1..n {
            let p = self.nodes[b].parent.expect("non-root has a parent");
            let mut c = Vec::new();
            for &pc in &colleagues[p] {
                for &ch in &self.nodes[pc].children {
                    if self.adjacent(ch, b) {
                        c.push(ch);
                    }
                }
            }
            colleagues[b] = c;
        }
        let mut lists = Lists::empty(n);
        for b in 1..n {
            let p = self.nodes[b].parent.expect("non-root has a parent");
            for &pc in &colleagues[p] {
                for &ch in &self.nodes[pc].children {
                    if !self.adjacent(ch, b) {
                        lists.v[b].push(ch);
                    }
                }
            }
        }
        for (b, node) in self.nodes.iter().enumerate() {
            if !node.is_leaf() {
                continue;
            }
            // U: leaves adjacent to b, found by descending through adjacent boxes.
            let mut stack = vec![0usize];
            while let Some(a) = stack.pop() {
                if !self.adjacent(a, b) {
                    continue;
                }
                if self.nodes[a].is_leaf() {
                    lists.u[b].push(a);
                } else {
                    stack.extend(&self.nodes[a].children);
                }
            }
            // W: descendants of colleagues, not adjacent to b, whose parent is adjacent.
            for &c in &colleagues[b] {
                if c == b {
                    continue;
                }
                let mut stack: Vec<usize> = self.nodes[c].children.clone();
                while let Some(d) = stack.pop() {
                    if !self.adjacent(d, b) {
                        lists.w[b].push(d);
                    } else if !self.nodes[d].is_leaf() {
                        stack.extend(&self.nodes[d].children);
                    }
                }
            }
        }
        for b in 0..n {
            for i in 0..lists.w[b].len() {
                let d = lists.w[b][i];
                lists.x[d].push(b);
            }
        }
        lists
    }
}

//! The octree of one rank: its share of a global adaptive octree, and the locally essential
//! tree (LET) of what other ranks hold that its boxes interact with.
//!
//! Construction (the scheme of Lashuk et al., SC'09, and PVFMM, Malhotra & Biros 2015, in a
//! simpler form):
//!
//! 1. **Domain.** The root cube is the serial one over the global bounding box (min/max
//!    reductions), so every rank computes the same keys ([`super::box_key`]).
//! 2. **Partition.** Splitters on the key line ([`super::splitters`]) cut the points (sources
//!    and targets together) into equal counts by a parallel selection with histograms
//!    (a few reductions of `O(K)` integers); then each is moved down to the
//!    first key of the leaf of the global tree that contains it: the global point counts of the
//!    boxes on each splitter's chain (one sum reduction of `22·(K−1)` integers) say where the
//!    global tree stops splitting. Points are then sent to their owners (one all-to-all; a
//!    point already on its owner stays). So no leaf is cut, and no rank holds all points.
//! 3. **Local tree.** Each rank refines its points top-down with the serial rule (split while a
//!    box has more than `leaf_size` points); a box whose key interval contains a splitter is
//!    split regardless (its global count is known to exceed `leaf_size`). Boxes inside the
//!    rank's key interval are *owned*; the others are *top* boxes.
//! 4. **Top of the tree.** The owned boxes whose parent is not owned are the rank's *local
//!    roots*. All ranks gather all local roots' records (key, leaf flag, counts) once, at
//!    build, and so hold the same *top* boxes, the roots' common ancestors: `O(K · depth)`
//!    records per rank. Their expansions do not travel to everyone. A top box is shared by the
//!    ranks whose key intervals overlap it (at most two per level for each rank); the first of
//!    them *owns* it. At each evaluation each sharer computes the box's partial upward expansion
//!    from its own points (M2M and the fit are linear); the partials are summed at the owner
//!    over a binomial tree of the sharers, and the owner's sum goes on, over a binomial tree
//!    rooted at the owner, to the ranks that overlap the box's far region (below), the only
//!    ones whose V and W lists can hold it ([`stages`]). Levels 0 and 1 are in no one's lists
//!    and are skipped. So a rank receives the top expansions its lists use (up to 189 per
//!    level for each box it computes), not all `O(K · depth)` local roots. A box of level `ℓ`
//!    has about `K / 8^ℓ + 2` sharers and, at level 2, `O(K)` users: past `K ≈ 64` a single
//!    owner would receive `O(K)` partials and send `O(K)` copies; with the trees it takes
//!    `⌈log₂ m⌉` messages each way for `m` participants (the hypercube stages of PVFMM and
//!    MOBO), in `⌈log₂ K⌉` rounds at most each.
//! 5. **Locally essential tree.** Every owned box `S` with sources is described (key, leaf
//!    flag, counts) to each other rank whose key interval overlaps the 27 boxes around `S`'s
//!    parent, so that the rank's tree holds the structure its lists are found in. What moves at
//!    each evaluation is narrower, the minimal LET of Lashuk et al. (SC'09):
//!    * `S`'s upward expansion goes only to the ranks overlapping its *far region*, the boxes of
//!      `S`'s level around its parent that do not touch `S`. A target `T` with `S` in its V list
//!      is such a box; a leaf `T` with `S` in its W list is coarser, touches `S`'s parent and
//!      not `S`, so it holds such a box.
//!    * A leaf's sources (positions once, densities at each evaluation) go only to the ranks
//!      overlapping the 27 boxes around `S` itself: `S` in the U list of `T` means `T` touches
//!      `S`, and `S` in the X list of `T` means `T`'s parent touches `S`; either way `T` lies in
//!      a box of `S`'s level that touches `S`. A leaf small enough to act on its W lists'
//!      targets directly ([`TreeInput::direct_sources`]) also sends its sources to the ranks
//!      that own a whole neighbour of its parent, the only ones that can own such a target.
//!
//!    A rank computes only boxes that overlap its key interval, so it receives exactly what its
//!    lists use ([`DistTree::let_is_complete`] checks it), from neighbouring ranks only. Before
//!    this split the expansion and the sources both went to the whole region around the parent
//!    (216 boxes of `S`'s level instead of 189 and 27). The pattern is built once; each
//!    evaluation moves only expansions and densities.
//!
//! Lists are found from keys by descending from the root through adjacent boxes, and kept in
//! key order, so the same target box gets the same lists on any number of ranks.

use std::collections::HashMap;
use std::ops::Range;

use super::box_key::{BoxKey, Domain, FINE, KEY_END};
/// Interaction lists, per box of the rank's tree (empty for the boxes it does not compute).
pub use super::octree::Lists;
use super::octree::{bounding_box, MAX_DEPTH};
use super::splitters::{histogram_splitters, snap_splitters, SPLIT_TOLERANCE};
use crate::comm::{CommError, Communicator};

mod links;
mod lists;
mod route;
pub mod stages;

use links::far_region;
use route::distribute;
pub use route::Route;

/// What a rank holds of a box.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// All the box's points are on this rank.
    Owned,
    /// The box holds points of several ranks; every rank computes its upward expansion.
    Top,
    /// Owned by another rank: its upward expansion (and sources, for a leaf) are received.
    Ghost,
}

/// One box of the rank's tree.
#[derive(Clone, Debug)]
pub struct TreeBox {
    /// Level and Morton key.
    pub key: BoxKey,
    /// Centre of the cube.
    pub center: [f64; 3],
    /// Half its edge length.
    pub half: f64,
    /// Whether the box is a leaf of the global tree.
    pub leaf: bool,
    /// Sources in the box, over all ranks.
    pub n_sources: usize,
    /// Targets in the box, over all ranks.
    pub n_targets: usize,
    /// The box's sources in this rank's source arrays (owned boxes and received leaves).
    pub sources: Range<usize>,
    /// The box's targets in this rank's target arrays (owned boxes).
    pub targets: Range<usize>,
    /// Index of the parent in [`DistTree::boxes`] (`None` for the root).
    pub parent: Option<usize>,
    /// Indices of the children present in this rank's tree.
    pub children: Vec<usize>,
    /// What this rank holds of the box.
    pub role: Role,
}

/// The boxes one rank sends to, or receives from, one other rank at each evaluation.
#[derive(Clone, Debug, Default)]
pub struct GhostLink {
    /// The other rank.
    pub rank: usize,
    /// Boxes whose upward expansions travel (indices into [`DistTree::boxes`]).
    pub boxes: Vec<usize>,
    /// Sources whose densities travel (ranges in the rank's source arrays).
    pub sources: Vec<Range<usize>>,
}

/// One stage of the top boxes' exchange ([`DistTree::top_reduce`],
/// [`DistTree::top_broadcast`]): links to the ranks this rank sends to and receives from.
#[derive(Clone, Debug, Default)]
pub struct TopStage {
    /// What this rank sends, one link per receiving rank.
    pub out: Vec<GhostLink>,
    /// What this rank receives, one link per sending rank.
    pub inn: Vec<GhostLink>,
}

impl GhostLink {
    /// Values per evaluation: `ne` per box, `ds` per source.
    pub fn len(&self, ne: usize, ds: usize) -> usize {
        self.boxes.len() * ne + self.sources.iter().map(|r| r.len()).sum::<usize>() * ds
    }
}

/// One rank's tree: owned, top and ghost boxes in key order.
#[derive(Clone, Debug)]
pub struct DistTree {
    /// The root cube, the same on every rank.
    pub domain: Domain,
    /// Boxes sorted by `(level, morton)`.
    pub boxes: Vec<TreeBox>,
    /// Position of each box's key in `boxes`.
    pub index: HashMap<BoxKey, usize>,
    /// `boxes[level_start[l]..level_start[l + 1]]` are the boxes of level `l`.
    pub level_start: Vec<usize>,
    /// Rank `r` owns the keys `splitters[r]..splitters[r + 1]`.
    pub splitters: Vec<u64>,
    /// This rank.
    pub rank: usize,
    /// This rank's sources (owned, in key order), then the received ghost sources.
    pub sources: Vec<[f64; 3]>,
    /// Orientations of `sources`, entry by entry (double-layer kernels).
    pub normals: Option<Vec<[f64; 3]>>,
    /// Number of owned sources (the first entries of `sources`).
    pub n_owned_sources: usize,
    /// This rank's targets in key order.
    pub targets: Vec<[f64; 3]>,
    /// Most points (sources and targets together) in a leaf, unless the leaf is at the
    /// smallest width allowed.
    pub leaf_size: usize,
    /// Leaves with at most this many sources act on their W-list targets directly
    /// ([`TreeInput::direct_sources`]).
    pub direct_sources: usize,
    /// How source densities reach `sources` from the caller's order.
    pub source_route: Route,
    /// How results at `targets` go back to the caller's order.
    pub target_route: Route,
    /// Local roots of every rank, by rank (indices into `boxes`).
    pub roots: Vec<Vec<usize>>,
    /// What this rank sends at each evaluation, one link per receiving rank.
    pub ghosts_out: Vec<GhostLink>,
    /// What this rank receives at each evaluation, one link per sending rank.
    pub ghosts_in: Vec<GhostLink>,
    /// The reduction of the top boxes' partial upward expansions to their owners, stage by
    /// stage (a binomial tree over each box's sharers, [`stages`]): what this rank sends (its
    /// running sums) and receives (partial sums it adds) at each stage.
    pub top_reduce: Vec<TopStage>,
    /// The broadcast of the owned top boxes' whole expansions to the ranks whose lists use
    /// them, stage by stage (a binomial tree from the owner over those ranks, [`stages`]):
    /// what this rank sends (boxes it owns or has received) and receives at each stage.
    pub top_broadcast: Vec<TopStage>,
    /// Interaction lists of the boxes this rank computes.
    pub lists: Lists,
}

fn bits(p: [f64; 3]) -> [u64; 3] {
    p.map(f64::to_bits)
}

fn unbits(v: &[u64]) -> [f64; 3] {
    [
        f64::from_bits(v[0]),
        f64::from_bits(v[1]),
        f64::from_bits(v[2]),
    ]
}

/// A box of the local refinement, before roles are known.
struct LocalBox {
    key: BoxKey,
    sources: Range<usize>,
    targets: Range<usize>,
    leaf: bool,
}

/// Refine this rank's points top-down (the serial rule, plus: boxes that contain a splitter
/// always split).
fn refine(
    domain: &Domain,
    skeys: &[u64],
    tkeys: &[u64],
    splitters: &[u64],
    leaf_size: usize,
    min_width: f64,
) -> Vec<LocalBox> {
    let straddles = |b: &BoxKey| {
        splitters[1..splitters.len() - 1]
            .iter()
            .any(|&s| b.morton < s && s < b.end())
    };
    let mut out = vec![LocalBox {
        key: BoxKey::ROOT,
        sources: 0..skeys.len(),
        targets: 0..tkeys.len(),
        leaf: true,
    }];
    let mut stack = vec![0usize];
    while let Some(b) = stack.pop() {
        let key = out[b].key;
        let count = out[b].sources.len() + out[b].targets.len();
        let split = straddles(&key)
            || (count > leaf_size && key.level < MAX_DEPTH && domain.half(key.level) >= min_width);
        if !split {
            continue;
        }
        out[b].leaf = false;
        let (sr, tr) = (out[b].sources.clone(), out[b].targets.clone());
        let mut s0 = sr.start;
        let mut t0 = tr.start;
        for o in 0..8u64 {
            let child = BoxKey {
                level: key.level + 1,
                morton: key.morton | (o << (3 * (FINE - key.level - 1))),
            };
            let s1 = s0 + skeys[s0..sr.end].partition_point(|&x| x < child.end());
            let t1 = t0 + tkeys[t0..tr.end].partition_point(|&x| x < child.end());
            if s1 > s0 || t1 > t0 {
                out.push(LocalBox {
                    key: child,
                    sources: s0..s1,
                    targets: t0..t1,
                    leaf: true,
                });
                stack.push(out.len() - 1);
            }
            s0 = s1;
            t0 = t1;
        }
    }
    out
}

/// Inputs of [`DistTree::build`].
pub struct TreeInput<'a> {
    /// This rank's source points (caller order).
    pub sources: &'a [[f64; 3]],
    /// Their orientations (double-layer kernels).
    pub normals: Option<&'a [[f64; 3]]>,
    /// This rank's target points (caller order).
    pub targets: &'a [[f64; 3]],
    /// Most points (sources and targets together) in a leaf.
    pub leaf_size: usize,
    /// Boxes are not split below this edge length (RPY: the bead diameter).
    pub min_width: f64,
    /// A leaf with at most this many sources acts on the leaves of its W lists directly, not
    /// through its expansion (the point count of an equivalent surface; 0: never), so its
    /// sources also travel to the ranks that can own such a W-list leaf
    /// ([`crate::fmm::near_field::NearList::w_direct`]).
    pub direct_sources: usize,
}

impl DistTree {
    /// Build this rank's tree and its exchange pattern (collective: all ranks call it).
    pub fn build(comm: &dyn Communicator, input: &TreeInput) -> Result<Self, CommError> {
        let leaf_size = input.leaf_size.max(1);
        let (k, me) = (comm.size(), comm.rank());
        // 1. Domain.
        let (mut lo, mut hi) = bounding_box(input.sources.iter().chain(input.targets));
        comm.all_min(&mut lo)?;
        comm.all_max(&mut hi)?;
        let domain = Domain::from_bounds(lo, hi);
        // 2. Partition.
        let mut keys: Vec<u64> = input
            .sources
            .iter()
            .chain(input.targets)
            .map(|p| domain.key(*p))
            .collect();
        keys.sort_unstable();
        let mut splitters = if k == 1 {
            vec![0, KEY_END]
        } else {
            histogram_splitters(comm, &keys, SPLIT_TOLERANCE)?
        };
        if k > 1 {
            snap_splitters(
                comm,
                &domain,
                &keys,
                &mut splitters,
                leaf_size,
                input.min_width,
            )?;
        }
        drop(keys);
        let src = distribute(comm, &domain, input.sources, input.normals, &splitters)?;
        let tgt = distribute(comm, &domain, input.targets, None, &splitters)?;
        // 3. Local tree.
        let local = refine(
            &domain,
            &src.keys,
            &tgt.keys,
            &splitters,
            leaf_size,
            input.min_width,
        );
        let (mine_lo, mine_hi) = (splitters[me], splitters[me + 1]);
        let owned = |b: &BoxKey| mine_lo <= b.morton && b.end() <= mine_hi;
        let mut tree = DistTree {
            domain,
            boxes: Vec::new(),
            index: HashMap::new(),
            level_start: Vec::new(),
            splitters,
            rank: me,
            n_owned_sources: src.points.len(),
            sources: src.points,
            normals: src.normals,
            targets: tgt.points,
            leaf_size,
            direct_sources: input.direct_sources,
            source_route: src.route,
            target_route: tgt.route,
            roots: vec![Vec::new(); k],
            ghosts_out: Vec::new(),
            ghosts_in: Vec::new(),
            top_reduce: Vec::new(),
            top_broadcast: Vec::new(),
            lists: Lists::default(),
        };
        let mut boxes: HashMap<BoxKey, TreeBox> = HashMap::new();
        let mut my_roots = Vec::new();
        for b in &local {
            if !owned(&b.key) {
                continue;
            }
            if b.key.parent().is_none_or(|p| !owned(&p)) {
                my_roots.push(b.key);
            }
            boxes.insert(
                b.key,
                tree.new_box(
                    b.key,
                    b.leaf,
                    (b.sources.len(), b.targets.len()),
                    Role::Owned,
                ),
            );
            let tb = boxes.get_mut(&b.key).expect("just inserted");
            tb.sources = b.sources.clone();
            tb.targets = b.targets.clone();
        }
        // 4. Top of the tree from every rank's local roots.
        let mut rec = Vec::with_capacity(5 * my_roots.len());
        my_roots.sort();
        for r in &my_roots {
            let b = &boxes[r];
            rec.extend([
                r.level as u64,
                r.morton,
                b.leaf as u64,
                b.n_sources as u64,
                b.n_targets as u64,
            ]);
        }
        let all_roots = comm.all_gather_u64(&rec)?;
        let mut root_keys: Vec<Vec<BoxKey>> = vec![Vec::new(); k];
        for (r, recs) in all_roots.iter().enumerate() {
            for c in recs.chunks_exact(5) {
                let key = BoxKey {
                    level: c[0] as u32,
                    morton: c[1],
                };
                root_keys[r].push(key);
                let (ns, nt) = (c[3] as usize, c[4] as usize);
                if r != me {
                    boxes.insert(key, tree.new_box(key, c[2] == 1, (ns, nt), Role::Ghost));
                }
                let mut a = key.parent();
                while let Some(p) = a {
                    let e = boxes
                        .entry(p)
                        .or_insert_with(|| tree.new_box(p, false, (0, 0), Role::Top));
                    e.n_sources += ns;
                    e.n_targets += nt;
                    a = p.parent();
                }
            }
        }
        // 5. The locally essential tree: send owned boxes with sources to the ranks around
        // their parents.
        let mut sent_keys: Vec<Vec<BoxKey>> = vec![Vec::new(); k];
        let mut send: Vec<Vec<u64>> = vec![Vec::new(); k];
        let mut out_links: Vec<GhostLink> = (0..k)
            .map(|rank| GhostLink {
                rank,
                ..Default::default()
            })
            .collect();
        let mut owned_keys: Vec<BoxKey> = boxes
            .iter()
            .filter(|(_, b)| b.role == Role::Owned && b.n_sources > 0)
            .map(|(key, _)| *key)
            .collect();
        owned_keys.sort();
        for key in &owned_keys {
            let Some(parent) = key.parent() else {
                continue;
            };
            let b = &boxes[key];
            let far = tree.ranks_overlapping(far_region(key));
            let near = if !b.leaf {
                Vec::new()
            } else if b.n_sources <= input.direct_sources {
                // W lists use the sources of a small leaf.
                let mut r = tree.ranks_overlapping(key.neighbourhood());
                r.extend(tree.w_ranks(key));
                r.sort_unstable();
                r.dedup();
                r
            } else {
                tree.ranks_overlapping(key.neighbourhood())
            };
            for r in tree.ranks_overlapping(parent.neighbourhood()) {
                if r == me {
                    continue;
                }
                let expansion = far.binary_search(&r).is_ok();
                let buf = &mut send[r];
                buf.extend([
                    key.level as u64,
                    key.morton,
                    b.leaf as u64,
                    b.n_sources as u64,
                    b.n_targets as u64,
                    expansion as u64,
                ]);
                if expansion {
                    sent_keys[r].push(*key);
                }
                if near.binary_search(&r).is_ok() {
                    buf.push(b.sources.len() as u64);
                    for i in b.sources.clone() {
                        buf.extend(bits(tree.sources[i]));
                        if let Some(n) = &tree.normals {
                            buf.extend(bits(n[i]));
                        }
                    }
                    out_links[r].sources.push(b.sources.clone());
                } else {
                    buf.push(0);
                }
            }
        }
        let recv = comm.all_to_all_u64(&send)?;
        drop(send);
        let w = if tree.normals.is_some() { 6 } else { 3 };
        let mut in_links = Vec::new();
        let mut in_keys: Vec<(usize, Vec<BoxKey>)> = Vec::new();
        for (r, buf) in recv.iter().enumerate() {
            if buf.is_empty() {
                continue;
            }
            let mut link = GhostLink {
                rank: r,
                ..Default::default()
            };
            let mut keys = Vec::new();
            let mut at = 0;
            while at < buf.len() {
                let key = BoxKey {
                    level: buf[at] as u32,
                    morton: buf[at + 1],
                };
                let (leaf, ns, nt) = (buf[at + 2] == 1, buf[at + 3] as usize, buf[at + 4]);
                let expansion = buf[at + 5] == 1;
                let np = buf[at + 6] as usize;
                at += 7;
                let start = tree.sources.len();
                for j in 0..np {
                    let p = &buf[at + j * w..at + (j + 1) * w];
                    tree.sources.push(unbits(&p[..3]));
                    if let Some(n) = &mut tree.normals {
                        n.push(unbits(&p[3..6]));
                    }
                }
                at += w * np;
                let e = boxes
                    .entry(key)
                    .or_insert_with(|| tree.new_box(key, leaf, (ns, nt as usize), Role::Ghost));
                e.leaf = leaf;
                if np > 0 {
                    e.sources = start..start + np;
                    link.sources.push(start..start + np);
                }
                if expansion {
                    keys.push(key);
                }
            }
            in_keys.push((r, keys));
            in_links.push(link);
        }
        // Order the boxes and link parents and children.
        let mut all: Vec<TreeBox> = boxes.into_values().collect();
        all.sort_by_key(|b| b.key);
        tree.index = all.iter().enumerate().map(|(i, b)| (b.key, i)).collect();
        for i in 0..all.len() {
            if let Some(p) = all[i]
                .key
                .parent()
                .and_then(|p| tree.index.get(&p).copied())
            {
                all[i].parent = Some(p);
                all[p].children.push(i);
            }
        }
        let depth = all.iter().map(|b| b.key.level).max().unwrap_or(0) as usize + 1;
        tree.level_start = (0..=depth)
            .map(|l| all.partition_point(|b| (b.key.level as usize) < l))
            .collect();
        tree.boxes = all;
        let idx = |key: &BoxKey| tree.index[key];
        tree.roots = root_keys
            .iter()
            .map(|ks| ks.iter().map(idx).collect())
            .collect();
        for (link, keys) in out_links.iter_mut().zip(&sent_keys) {
            link.boxes = keys.iter().map(idx).collect();
        }
        // A link carries expansions, sources or both; one that carries neither (the rank
        // only learns the structure) is dropped on both sides alike.
        let carries = |l: &GhostLink| !l.boxes.is_empty() || !l.sources.is_empty();
        tree.ghosts_out = out_links.into_iter().filter(carries).collect();
        for (link, (_, keys)) in in_links.iter_mut().zip(&in_keys) {
            link.boxes = keys.iter().map(idx).collect();
        }
        tree.ghosts_in = in_links.into_iter().filter(carries).collect();
        tree.lists = tree.interaction_lists();
        tree.top_links();
        tree.check_links(comm)?;
        Ok(tree)
    }

    fn new_box(&self, key: BoxKey, leaf: bool, counts: (usize, usize), role: Role) -> TreeBox {
        let (center, half) = self.domain.geometry(&key);
        TreeBox {
            key,
            center,
            half,
            leaf,
            n_sources: counts.0,
            n_targets: counts.1,
            sources: 0..0,
            targets: 0..0,
            parent: None,
            children: Vec::new(),
            role,
        }
    }

    /// This rank's caller points (sources and targets) that another rank owns: the points
    /// whose positions, densities and results cross between ranks.
    pub fn points_moved(&self) -> usize {
        self.source_route.n_moved(self.rank) + self.target_route.n_moved(self.rank)
    }

    /// Number of levels.
    pub fn depth(&self) -> u32 {
        (self.level_start.len() - 1) as u32
    }

    /// Whether this rank computes the downward expansion of box `b`: owned boxes and top
    /// boxes overlapping the rank's key interval, with targets.
    pub fn computes_down(&self, b: usize) -> bool {
        let bx = &self.boxes[b];
        bx.n_targets > 0
            && match bx.role {
                Role::Owned => true,
                Role::Top => self.overlaps_mine(&bx.key),
                Role::Ghost => false,
            }
    }
}

//! Which M2L products one level runs, and where each box's spectrum sits.
//!
//! The V list of a box `B` is the children of its parent's colleagues that do not touch `B`
//! ([`super::octree`]). So the V lists of the 8 children of a target parent `P` and the
//! children of one colleague `Q` of `P` form one block of at most 8 × 8 pairs, the same
//! block shape for every `(P, Q)` at the same parent offset `Δp = P − Q`: the child offset of
//! target octant `i` and source octant `j` is `2Δp + c_i − c_j`. Running such a block at once
//! ([`FftM2l::accumulate_siblings`]) keeps the 8 source chunks in the first-level cache while
//! every target's chunk stays in registers over its partners, instead of streaming one
//! source and one target chunk per pair (the sibling blocking of Malhotra & Biros,
//! Commun. Comput. Phys. 2015).
//!
//! Absent children cost a block of zero products, so the plan runs a `(P, Q)` block only where
//! it holds at least [`DENSE_PAIRS`] of the level's V-list pairs (full regions); the other
//! pairs run one by one ([`FftM2l::accumulate_chunk`]). Children of a parent in a block get 8
//! consecutive slots, `base + octant` (zeros where a source child is absent or has no sources);
//! every other box a slot of its own. The sums are the V-list sums exactly: every pair of a
//! block whose children do not touch is in the V list of the target child (the V list is
//! defined by that structure), and the absent ones add zeros or land in target slots no one
//! reads.

use super::dist_tree::DistTree;
use super::m2l_fft::{offset_index, parent_offset_index, FftM2l};

/// The least number of V-list pairs of a `(target parent, source parent)` block for it to run
/// as one 8 × 8 block (of 48 to 63 where all children are present). A block costs its 48–63
/// non-touching pair products at 1.6 (Stokeslet) to 2.5 (Laplace) times the rate of pairs run
/// one by one (measured when a block still ran all 64 with zeros), plus zero-filled slots for
/// absent children, so it pays from about 26–40 pairs. Measured
/// (2026-11-26, `mobo fmm`, 6 digits): on 1000 cell-like spheres of 312 points (Stokeslet, one
/// thread) the evaluation took 12.0–12.6 s at 16, 9.8–10.5 s at 40 and 10.1–11.5 s with pairs
/// only; on 2·10⁵ uniform and sphere-cloud points 40 was as fast as 16 or faster.
pub const DENSE_PAIRS: usize = 40;

/// One 8 × 8 block: target slots `target..target + 8`, source slots `source..source + 8`,
/// parent offset slot `dp` ([`parent_offset_index`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SiblingBlock {
    /// First target slot (octant 0).
    pub target: u32,
    /// First source slot (octant 0).
    pub source: u32,
    /// Parent offset slot.
    pub dp: u8,
}

/// The M2L products of one level.
#[derive(Clone, Debug, Default)]
pub struct M2lPlan {
    /// Slot of each target box of the level (by its index in the selection), `None` without
    /// V-list sources.
    pub target_slot: Vec<Option<u32>>,
    /// Target slots in all.
    pub n_target_slots: usize,
    /// `(slot, box)` of every source box whose spectrum is needed.
    pub sources: Vec<(u32, usize)>,
    /// Source slots in all.
    pub n_source_slots: usize,
    /// The blocks, sorted by target, then parent offset (a target's 8 chunks stay in cache
    /// over its up to 26 blocks).
    pub blocks: Vec<SiblingBlock>,
    /// The pairs run one by one: `(target slot, source slot, compact offset)`, sorted by offset
    /// then target.
    pub pairs: Vec<(u32, u32, u16)>,
}

/// Slots handed out in order of first use: a parent in a block takes 8 (`base + octant` for its
/// children), any other box one. Indexed by box, so no hashing per pair.
struct Slots {
    of_parent: Vec<u32>,
    of_box: Vec<u32>,
    blocked: Vec<bool>,
    next: u32,
}

impl Slots {
    fn new(n_boxes: usize) -> Self {
        Slots {
            of_parent: vec![u32::MAX; n_boxes],
            of_box: vec![u32::MAX; n_boxes],
            blocked: vec![false; n_boxes],
            next: 0,
        }
    }

    /// The slot of box `bx` (octant `octant` of `parent`); whether it was new.
    fn get(&mut self, bx: usize, parent: Option<usize>, octant: usize) -> (u32, bool) {
        let fresh = self.of_box[bx] == u32::MAX;
        if fresh {
            self.of_box[bx] = match parent {
                Some(p) if self.blocked[p] => {
                    if self.of_parent[p] == u32::MAX {
                        self.of_parent[p] = self.next;
                        self.next += 8;
                    }
                    self.of_parent[p] + octant as u32
                }
                _ => {
                    self.next += 1;
                    self.next - 1
                }
            };
        }
        (self.of_box[bx], fresh)
    }
}

impl M2lPlan {
    /// The plan for the target boxes `sel` of one level, blocks where at least `dense` pairs
    /// share a `(target parent, source parent)` (`usize::MAX`: pairs only).
    pub fn new(tree: &DistTree, m2l: &FftM2l, sel: &[usize], dense: usize) -> Self {
        let nb = tree.boxes.len();
        let parent = |b: usize| tree.boxes[b].parent;
        let has_sources = |v: &usize| tree.boxes[*v].n_sources > 0;
        // Per target parent (in order of first use), its source parents and their pair counts
        // (at most the 26 colleagues).
        let mut t_index = vec![u32::MAX; nb];
        let mut groups: Vec<(usize, Vec<(usize, usize)>)> = Vec::new();
        for &bx in sel {
            let Some(tp) = parent(bx) else { continue };
            for v in tree.lists.v[bx].iter().filter(|v| has_sources(v)) {
                let Some(sp) = parent(*v) else { continue };
                if t_index[tp] == u32::MAX {
                    t_index[tp] = groups.len() as u32;
                    groups.push((tp, Vec::new()));
                }
                let list = &mut groups[t_index[tp] as usize].1;
                match list.iter_mut().find(|(p, _)| *p == sp) {
                    Some((_, n)) => *n += 1,
                    None => list.push((sp, 1)),
                }
            }
        }
        let (mut ts, mut ss) = (Slots::new(nb), Slots::new(nb));
        for (tp, list) in &groups {
            for &(sp, n) in list {
                if n >= dense {
                    ts.blocked[*tp] = true;
                    ss.blocked[sp] = true;
                }
            }
        }
        let mut plan = M2lPlan {
            target_slot: vec![None; sel.len()],
            ..Default::default()
        };
        let is_block = |tp: Option<usize>, sp: Option<usize>| match (tp, sp) {
            (Some(tp), Some(sp)) if t_index[tp] != u32::MAX => groups[t_index[tp] as usize]
                .1
                .iter()
                .any(|&(p, n)| p == sp && n >= dense),
            _ => false,
        };
        for (ti, &bx) in sel.iter().enumerate() {
            let tkey = tree.boxes[bx].key;
            for &v in tree.lists.v[bx].iter().filter(|v| has_sources(v)) {
                let skey = tree.boxes[v].key;
                let (t, _) = ts.get(bx, parent(bx), tkey.octant());
                plan.target_slot[ti] = Some(t);
                let (s, fresh) = ss.get(v, parent(v), skey.octant());
                if fresh {
                    plan.sources.push((s, v));
                }
                if !is_block(parent(bx), parent(v)) {
                    let o = m2l.compact_offset(offset_index(tkey.offset_from(&skey)));
                    plan.pairs.push((t, s, o as u16));
                }
            }
        }
        // The blocks, from the groups (every slot of a block's parents is assigned above: a
        // block holds at least one pair).
        for (tp, list) in &groups {
            for &(sp, _) in list.iter().filter(|&&(_, n)| n >= dense) {
                let (tk, sk) = (tree.boxes[*tp].key, tree.boxes[sp].key);
                plan.blocks.push(SiblingBlock {
                    target: ts.of_parent[*tp],
                    source: ss.of_parent[sp],
                    dp: parent_offset_index(tk.offset_from(&sk)) as u8,
                });
            }
        }
        plan.n_target_slots = ts.next as usize;
        plan.n_source_slots = ss.next as usize;
        plan.blocks
            .sort_unstable_by_key(|b| (b.target, b.dp, b.source));
        plan.pairs.sort_unstable_by_key(|&(t, _, o)| (o, t));
        plan
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::comm::SerialComm;
    use crate::fmm::clouds::Cloud;
    use crate::fmm::dist_tree::TreeInput;
    use crate::fmm::kernels::Laplace;
    use crate::fmm::surface::CubeSurface;
    use std::collections::BTreeSet;

    /// The products a plan runs, as `(target box, source box)`: its pairs, and the pairs of
    /// its blocks whose children do not touch, whose target is in the selection and whose
    /// source slot holds a spectrum.
    fn products(
        tree: &DistTree,
        m2l: &FftM2l,
        plan: &M2lPlan,
        sel: &[usize],
    ) -> Vec<(usize, usize)> {
        // Slots in range and one box per slot.
        let mut slots: Vec<u32> = plan.sources.iter().map(|&(s, _)| s).collect();
        let mut tslots: Vec<u32> = plan.target_slot.iter().flatten().copied().collect();
        for (v, n, what) in [
            (&mut slots, plan.n_source_slots, "source"),
            (&mut tslots, plan.n_target_slots, "target"),
        ] {
            let len = v.len();
            v.sort_unstable();
            v.dedup();
            assert_eq!(v.len(), len, "two {what} boxes share a slot");
            assert!(
                v.iter().all(|&s| (s as usize) < n),
                "{what} slot out of range"
            );
        }
        for b in &plan.blocks {
            assert!(b.target as usize + 8 <= plan.n_target_slots);
            assert!(b.source as usize + 8 <= plan.n_source_slots);
        }
        let mut target_of = std::collections::HashMap::new();
        for (i, s) in plan.target_slot.iter().enumerate() {
            if let Some(s) = s {
                target_of.insert(*s, sel[i]);
            }
        }
        let source_of: std::collections::HashMap<u32, usize> =
            plan.sources.iter().copied().collect();
        let mut out = Vec::new();
        for &(t, s, o) in &plan.pairs {
            let (t, s) = (target_of[&t], source_of[&s]);
            let d = tree.boxes[t].key.offset_from(&tree.boxes[s].key);
            assert_eq!(
                o as usize,
                m2l.compact_offset(offset_index(d)),
                "pair offset"
            );
            out.push((t, s));
        }
        for b in &plan.blocks {
            for i in 0..8u32 {
                for j in 0..8u32 {
                    let (Some(&t), Some(&s)) = (
                        target_of.get(&(b.target + i)),
                        source_of.get(&(b.source + j)),
                    ) else {
                        continue;
                    };
                    let (tk, sk) = (tree.boxes[t].key, tree.boxes[s].key);
                    assert_eq!((tk.octant(), sk.octant()), (i as usize, j as usize));
                    let dp = tk.parent().unwrap().offset_from(&sk.parent().unwrap());
                    assert_eq!(b.dp as usize, parent_offset_index(dp), "block offset");
                    if !tk.adjacent(&sk) {
                        out.push((t, s));
                    }
                }
            }
        }
        out
    }

    /// On a uniform and a clustered cloud, with blocks everywhere, by default, and with pairs
    /// only, every level's plan runs each V-list pair with sources exactly once.
    #[test]
    fn a_plan_runs_every_v_list_pair_once() {
        let m2l = FftM2l::new(&Laplace, &CubeSurface::new(4));
        for cloud in [Cloud::Uniform, Cloud::Spheres] {
            let pts = cloud.points(20_000, 1);
            let input = TreeInput {
                sources: &pts,
                normals: None,
                targets: &pts,
                leaf_size: 60,
                min_width: 0.0,
                direct_sources: 0,
            };
            let tree = DistTree::build(&SerialComm, &input).unwrap();
            let (mut blocks, mut pairs) = (0, 0);
            for dense in [1, DENSE_PAIRS, usize::MAX] {
                for level in 2..tree.depth() as usize {
                    let sel: Vec<usize> = (tree.level_start[level]..tree.level_start[level + 1])
                        .filter(|&b| tree.computes_down(b))
                        .collect();
                    let plan = M2lPlan::new(&tree, &m2l, &sel, dense);
                    let mut got = products(&tree, &m2l, &plan, &sel);
                    let n = got.len();
                    got.sort_unstable();
                    got.dedup();
                    assert_eq!(got.len(), n, "{cloud:?} dense {dense}: a pair runs twice");
                    let want: BTreeSet<(usize, usize)> = sel
                        .iter()
                        .flat_map(|&t| {
                            tree.lists.v[t]
                                .iter()
                                .filter(|&&v| tree.boxes[v].n_sources > 0)
                                .map(move |&v| (t, v))
                        })
                        .collect();
                    assert_eq!(
                        got.into_iter().collect::<BTreeSet<_>>(),
                        want,
                        "{cloud:?} level {level} dense {dense}"
                    );
                    if dense == DENSE_PAIRS {
                        blocks += plan.blocks.len();
                        pairs += plan.pairs.len();
                    }
                }
            }
            println!("{cloud:?}: {blocks} blocks, {pairs} pairs by default");
            assert!(blocks > 0, "{cloud:?}: no blocks");
            if cloud == Cloud::Spheres {
                assert!(pairs > 0, "cell surfaces: no pairs run one by one");
            }
        }
    }
}

//! The exchange pattern of a rank's tree: which ranks overlap a region, who owns and shares
//! each top box, the links a rank sends and receives at each evaluation, and the checks that
//! the locally essential tree is complete and the ranks agree on it.

use super::stages::{broadcast_partner, reduce_partner, stage_count, Partner};
use super::*;

/// The far region of `key`: the boxes of its level around its parent (the children of the
/// parent's 27 neighbours) that do not touch it. The targets of `key`'s expansion (its V and W
/// lists' owners) lie in it.
pub(super) fn far_region(key: &BoxKey) -> impl Iterator<Item = BoxKey> + '_ {
    key.parent()
        .into_iter()
        .flat_map(|p| p.neighbourhood())
        .filter_map(|n| n.children())
        .flatten()
        .filter(move |c| !c.adjacent(key))
}

/// The links that carry something.
fn keep(v: Vec<GhostLink>) -> Vec<GhostLink> {
    v.into_iter().filter(|l| !l.boxes.is_empty()).collect()
}

impl DistTree {
    /// Ranks whose key intervals overlap any of `region`'s boxes, sorted.
    pub(super) fn ranks_overlapping(&self, region: impl IntoIterator<Item = BoxKey>) -> Vec<usize> {
        let mut out = Vec::new();
        for n in region {
            let mut r = self.rank_of(n.morton);
            while r + 1 < self.splitters.len() && self.splitters[r] < n.end() {
                if self.splitters[r] < self.splitters[r + 1] {
                    out.push(r);
                }
                r += 1;
            }
        }
        out.sort_unstable();
        out.dedup();
        out
    }

    /// The rank whose key interval holds the finest key `key` (the last of equal splitters:
    /// never an empty interval).
    fn rank_of(&self, key: u64) -> usize {
        self.splitters.partition_point(|&s| s <= key) - 1
    }

    /// The ranks sharing a top box (their key intervals overlap it), the first its owner.
    fn sharers(&self, key: &BoxKey) -> Vec<usize> {
        self.ranks_overlapping([*key])
    }

    /// Whether box `b` is a top box this rank owns (its first sharer).
    fn owns_top(&self, b: usize) -> bool {
        let bx = &self.boxes[b];
        bx.role == Role::Top && self.sharers(&bx.key).first() == Some(&self.rank)
    }

    /// The top boxes whose expansions move at each evaluation (levels from 2, with sources),
    /// in key order on every rank: the partials reduced to each box's owner over a binomial
    /// tree of its sharers, then the whole expansion broadcast from the owner over a binomial
    /// tree of the ranks overlapping the box's far region ([`super::stages`]). Every rank holds
    /// the same top boxes and splitters, so every rank finds the same participants and the
    /// same number of stages.
    pub(super) fn top_links(&mut self) {
        let k = self.splitters.len() - 1;
        let me = self.rank;
        let links = || -> Vec<GhostLink> {
            (0..k)
                .map(|rank| GhostLink {
                    rank,
                    ..Default::default()
                })
                .collect()
        };
        // (participants in tree order, this rank's place among them, box index) of the moving
        // top boxes this rank takes part in, and the stages of the deepest tree over all
        // boxes (the same on every rank).
        let mut reduce: Vec<(Vec<usize>, usize, usize)> = Vec::new();
        let mut broadcast: Vec<(Vec<usize>, usize, usize)> = Vec::new();
        let (mut reduce_stages, mut broadcast_stages) = (0, 0);
        for (b, bx) in self.boxes.iter().enumerate() {
            if bx.role != Role::Top || bx.n_sources == 0 || bx.key.level < 2 {
                continue;
            }
            let sharers = self.sharers(&bx.key);
            let Some(&owner) = sharers.first() else {
                continue;
            };
            // The users in rank order from the owner on, cyclically: the ranks that forward
            // (the tree's first participants) differ from box to box instead of being the
            // lowest ranks of every tree.
            let mut users = vec![owner];
            let mut others: Vec<usize> = self
                .ranks_overlapping(far_region(&bx.key))
                .into_iter()
                .filter(|&r| r != owner)
                .collect();
            others.sort_by_key(|&r| (r + k - owner) % k);
            users.extend(others);
            reduce_stages = reduce_stages.max(stage_count(sharers.len()));
            broadcast_stages = broadcast_stages.max(stage_count(users.len()));
            if let Some(i) = sharers.iter().position(|&r| r == me) {
                reduce.push((sharers, i, b));
            }
            if let Some(i) = users.iter().position(|&r| r == me) {
                broadcast.push((users, i, b));
            }
        }
        let staged = |trees: &[(Vec<usize>, usize, usize)],
                      stages: usize,
                      partner: fn(usize, usize, usize) -> Option<Partner>|
         -> Vec<TopStage> {
            (0..stages)
                .map(|j| {
                    let (mut out, mut inn) = (links(), links());
                    for &(ref parts, i, b) in trees {
                        match partner(i, parts.len(), j) {
                            Some(Partner::SendTo(t)) => out[parts[t]].boxes.push(b),
                            Some(Partner::ReceiveFrom(f)) => inn[parts[f]].boxes.push(b),
                            None => {}
                        }
                    }
                    TopStage {
                        out: keep(out),
                        inn: keep(inn),
                    }
                })
                .collect()
        };
        self.top_reduce = staged(&reduce, reduce_stages, reduce_partner);
        self.top_broadcast = staged(&broadcast, broadcast_stages, broadcast_partner);
    }

    /// Check that every rank expects what its partners will send at each evaluation (the
    /// exchanges: each stage of the top reduction, the LET, each stage of the top broadcast)
    /// and receives all its lists read
    /// ([`DistTree::let_is_complete`]), so that a fault fails the build on every rank with its
    /// reason instead of hanging, mixing messages or reading zeros later.
    pub(super) fn check_links(&self, comm: &dyn Communicator) -> Result<(), CommError> {
        let k = self.splitters.len() - 1;
        let kinds: Vec<(&Vec<GhostLink>, &Vec<GhostLink>)> = self
            .top_reduce
            .iter()
            .map(|s| (&s.out, &s.inn))
            .chain([(&self.ghosts_out, &self.ghosts_in)])
            .chain(self.top_broadcast.iter().map(|s| (&s.out, &s.inn)))
            .collect();
        let counts = |l: &GhostLink| [l.boxes.len() as u64, l.len(0, 1) as u64];
        let mut send = vec![vec![0u64; 2 * kinds.len()]; k];
        let mut expect = vec![vec![0u64; 2 * kinds.len()]; k];
        for (i, (out, inn)) in kinds.iter().enumerate() {
            for l in out.iter() {
                send[l.rank][2 * i..2 * i + 2].copy_from_slice(&counts(l));
            }
            for l in inn.iter() {
                expect[l.rank][2 * i..2 * i + 2].copy_from_slice(&counts(l));
            }
        }
        let got = comm.all_to_all_u64(&send)?;
        let local = match (0..k).find(|&r| got[r] != expect[r]) {
            Some(r) => Err(format!(
                "rank {} expects (boxes, sources) per exchange {:?} from rank {r}, which sends {:?}",
                self.rank, expect[r], got[r]
            )),
            None => self.let_is_complete(),
        };
        comm.agree(local).map_err(|e| match e {
            CommError::Remote { message, .. } => CommError::Disagree(message),
            e => e,
        })
    }

    /// The ranks that may hold `key` in the W list of one of their owned leaves. Such a leaf
    /// `T` is at least as large as `key`'s parent, touches the parent and not `key`, and lies
    /// inside its owner's key interval; so it covers a whole neighbour `N` of the parent that
    /// does not touch `key`, and the owner's interval contains all of `N`'s keys (one rank at
    /// most per `N`).
    pub(super) fn w_ranks(&self, key: &BoxKey) -> Vec<usize> {
        let Some(parent) = key.parent() else {
            return Vec::new();
        };
        let mut out: Vec<usize> = parent
            .neighbourhood()
            .into_iter()
            .filter(|n| !n.adjacent(key))
            .filter_map(|n| {
                let r = self.rank_of(n.morton);
                (r + 1 < self.splitters.len() && n.end() <= self.splitters[r + 1]).then_some(r)
            })
            .collect();
        out.sort_unstable();
        out.dedup();
        out
    }

    /// The far-field work this rank repeats: the M2L pairs (V-list entries) and P2L sources
    /// (X-list entries) of the top boxes it computes and does not own, which their owner and
    /// every other sharer compute too; `(repeated, all)` over the boxes this rank computes.
    pub fn repeated_far_work(&self) -> (u64, u64) {
        let (mut repeated, mut all) = (0u64, 0u64);
        for (b, bx) in self.boxes.iter().enumerate() {
            if !self.computes_down(b) {
                continue;
            }
            let work = (self.lists.v[b].len() + self.lists.x[b].len()) as u64;
            all += work;
            if bx.role == Role::Top && !self.owns_top(b) {
                repeated += work;
            }
        }
        (repeated, all)
    }

    /// Whether the key interval of this rank overlaps box `key`.
    pub fn overlaps_mine(&self, key: &BoxKey) -> bool {
        key.overlaps(self.splitters[self.rank], self.splitters[self.rank + 1])
    }

    /// Whether every box of another rank (ghost) or shared (top) in the lists of the boxes this
    /// rank computes arrives at each evaluation with what the list uses: its whole upward
    /// expansion (V and W lists) or its sources (U and X lists). `Err` names the first box that would be read without its data.
    pub fn let_is_complete(&self) -> Result<(), String> {
        let mut expansion = vec![false; self.boxes.len()];
        for l in &self.ghosts_in {
            for &b in &l.boxes {
                expansion[b] = true;
            }
        }
        for l in self.top_broadcast.iter().flat_map(|s| &s.inn) {
            for &b in &l.boxes {
                expansion[b] = true;
            }
        }
        for (b, e) in expansion.iter_mut().enumerate() {
            *e |= self.owns_top(b);
        }
        let ghost = |b: usize| self.boxes[b].role == Role::Ghost && self.boxes[b].n_sources > 0;
        let elsewhere = |b: usize| self.boxes[b].role != Role::Owned && self.boxes[b].n_sources > 0;
        for t in 0..self.boxes.len() {
            let needs_expansion = self.lists.v[t].iter().chain(&self.lists.w[t]);
            if let Some(&s) = needs_expansion
                .filter(|&&s| elsewhere(s))
                .find(|&&s| !expansion[s])
            {
                return Err(format!(
                    "box {:?} is in a V or W list of {:?} without its expansion",
                    self.boxes[s].key, self.boxes[t].key
                ));
            }
            let direct_w = self.lists.w[t]
                .iter()
                .filter(|&&w| self.boxes[w].leaf && self.boxes[w].n_sources <= self.direct_sources);
            let needs_sources = self.lists.u[t]
                .iter()
                .chain(&self.lists.x[t])
                .chain(direct_w);
            let missing = |&&s: &&usize| self.boxes[s].sources.len() != self.boxes[s].n_sources;
            if let Some(&s) = needs_sources.filter(|&&s| ghost(s)).find(missing) {
                let sb = &self.boxes[s];
                return Err(format!(
                    "rank {}: box {:?} (leaf {}, {} of {} sources here) is in a U, X or direct W \
                     list of {:?} without its sources (splitters {:?})",
                    self.rank,
                    sb.key,
                    sb.leaf,
                    sb.sources.len(),
                    sb.n_sources,
                    self.boxes[t].key,
                    self.splitters
                ));
            }
        }
        Ok(())
    }
}

//! The passes of one evaluation: the upward pass and the exchange of shared and ghost boxes,
//! the downward pass (M2L in [`super::m2l`], P2L, L2L), and the leaves (L2P, M2P, P2P).

use super::m2l::M2lBuffers;
use super::*;

impl Fmm {
    /// After the upward pass over this rank's own boxes and its partial top boxes: the top
    /// boxes' partial expansions summed at their owners, stage by stage over each box's
    /// sharers ([`DistTree::top_reduce`]); the ghost boxes' expansions and leaf densities to
    /// the neighbours that need them (into `up` and the ghost part of `dens`); the owned top
    /// boxes' whole expansions to the ranks whose lists use them, stage by stage
    /// ([`DistTree::top_broadcast`]).
    pub(super) fn share_upward(
        &self,
        comm: &dyn Communicator,
        up: &mut [f64],
        dens: &mut [f64],
    ) -> Result<(), FmmError> {
        let ne = self.ops.n_equiv();
        let ds = self.near.density_dim();
        let tree = &self.tree;
        for stage in &tree.top_reduce {
            let got = exchange_links(comm, &stage.out, &stage.inn, up, dens, ne, ds)?;
            for (l, buf) in stage.inn.iter().zip(&got) {
                for (&bx, v) in l.boxes.iter().zip(buf.chunks_exact(ne)) {
                    for (u, x) in up[bx * ne..(bx + 1) * ne].iter_mut().zip(v) {
                        *u += x;
                    }
                }
            }
        }
        let copies = std::iter::once((&tree.ghosts_out, &tree.ghosts_in))
            .chain(tree.top_broadcast.iter().map(|s| (&s.out, &s.inn)));
        for (out, inn) in copies {
            let got = exchange_links(comm, out, inn, up, dens, ne, ds)?;
            for (l, buf) in inn.iter().zip(&got) {
                let mut at = 0;
                for &bx in &l.boxes {
                    up[bx * ne..(bx + 1) * ne].copy_from_slice(&buf[at..at + ne]);
                    at += ne;
                }
                for r in &l.sources {
                    let n = r.len() * ds;
                    dens[r.start * ds..r.end * ds].copy_from_slice(&buf[at..at + n]);
                    at += n;
                }
            }
        }
        Ok(())
    }

    /// Upward pass over the boxes of one role with sources (owned: from this rank's points;
    /// top: the partial expansions of the top boxes overlapping this rank, from its own local
    /// roots, before any other rank's data has arrived), level by level: P2M and M2M into
    /// upward check potentials, one fit (GEMM) per level.
    pub(super) fn upward(&self, up: &mut [f64], role: Role, clock: &PhaseClock) {
        let ne = self.ops.n_equiv();
        let nc = self.ops.n_check();
        let tree = &self.tree;
        for level in (0..tree.depth() as usize).rev() {
            // A top box that does not overlap this rank has no part of this rank's points.
            let sel: Vec<usize> = (tree.level_start[level]..tree.level_start[level + 1])
                .filter(|&b| {
                    let bx = &tree.boxes[b];
                    bx.role == role
                        && bx.n_sources > 0
                        && (role != Role::Top || tree.overlaps_mine(&bx.key))
                })
                .collect();
            if sel.is_empty() {
                continue;
            }
            let t = Instant::now();
            let mut check = vec![0.0; sel.len() * nc];
            // P2M at the leaves.
            check.par_chunks_mut(nc).zip(&sel).for_each_init(
                || Vec::with_capacity(self.ops.surf.len()),
                |pts, (col, &bx)| {
                    let node = &tree.boxes[bx];
                    if node.leaf && !node.sources.is_empty() {
                        self.ops.surf.place(node.center, node.half, UP_CHECK, pts);
                        self.far_source.eval_block(
                            pts,
                            &self.sources.view(node.sources.clone()),
                            col,
                        );
                    }
                },
            );
            let t = clock.add(0, t);
            // M2M: per octant, one GEMM over the children.
            let mut groups: Vec<Vec<(usize, usize)>> = vec![Vec::new(); 8];
            for (i, &b) in sel.iter().enumerate() {
                for &c in &tree.boxes[b].children {
                    if tree.boxes[c].n_sources > 0 {
                        groups[tree.boxes[c].key.octant()].push((i, c));
                    }
                }
            }
            for (o, g) in groups.iter().enumerate() {
                gather_gemm_scatter(&self.ops.m2m, &self.ops.reflections[o], g, up, &mut check);
            }
            let mut fit = vec![0.0; sel.len() * ne];
            self.ops.up.apply_many(&check, &mut fit);
            for (&b, v) in sel.iter().zip(fit.chunks_exact(ne)) {
                up[b * ne..(b + 1) * ne].copy_from_slice(v);
            }
            clock.add(1, t);
        }
    }

    /// Downward pass: normalised downward equivalent densities of the boxes this rank
    /// computes, indexed by box.
    pub(super) fn downward(&self, up: &[f64], clock: &PhaseClock) -> Vec<f64> {
        let ne = self.ops.n_equiv();
        let nc = self.ops.n_check();
        let tree = &self.tree;
        let mut down = vec![0.0; tree.boxes.len() * ne];
        self.m2l_peak_bytes
            .store(0, std::sync::atomic::Ordering::Relaxed);
        // The M2L's chunked spectra, reused by a level that fits (freed with the pass).
        let mut buffers = M2lBuffers::default();
        for level in 2..tree.depth() as usize {
            let sel: Vec<usize> = (tree.level_start[level]..tree.level_start[level + 1])
                .filter(|&b| tree.computes_down(b))
                .collect();
            if sel.is_empty() {
                continue;
            }
            let mut check = vec![0.0; sel.len() * nc];
            self.m2l_level(&sel, up, &mut check, &mut buffers, clock);
            let t = Instant::now();
            // P2L: X-list sources at the downward check surfaces.
            check.par_chunks_mut(nc).zip(&sel).for_each_init(
                || Vec::with_capacity(self.ops.surf.len()),
                |pts, (col, &bx)| {
                    if tree.lists.x[bx].is_empty()
                        || NearList::x_direct(tree, bx, self.ops.surf.len())
                    {
                        return;
                    }
                    let node = &tree.boxes[bx];
                    self.ops.surf.place(node.center, node.half, INNER, pts);
                    for &x in &tree.lists.x[bx] {
                        let xn = &tree.boxes[x];
                        if !xn.sources.is_empty() {
                            self.far_source.eval_block(
                                pts,
                                &self.sources.view(xn.sources.clone()),
                                col,
                            );
                        }
                    }
                },
            );
            let t = clock.add(4, t);
            // L2L per octant into the check potentials, then the downward fit of the level.
            if level > 2 {
                let mut groups: Vec<Vec<(usize, usize)>> = vec![Vec::new(); 8];
                for (i, &b) in sel.iter().enumerate() {
                    let node = &tree.boxes[b];
                    if let Some(p) = node.parent {
                        groups[node.key.octant()].push((i, p));
                    }
                }
                for (o, g) in groups.iter().enumerate() {
                    gather_gemm_scatter(
                        &self.ops.l2l,
                        &self.ops.reflections[o],
                        g,
                        &down,
                        &mut check,
                    );
                }
            }
            let mut fit = vec![0.0; sel.len() * ne];
            self.ops.down.apply_many(&check, &mut fit);
            for (&b, v) in sel.iter().zip(fit.chunks_exact(ne)) {
                down[b * ne..(b + 1) * ne].copy_from_slice(v);
            }
            clock.add(5, t);
        }
        down
    }

    /// Leaves: L2P and M2P into this rank's targets' values in key order (the near field is
    /// a pass of its own, [`NearField`]).
    pub(super) fn leaves(&self, up: &[f64], down: &[f64], clock: &PhaseClock) -> Vec<f64> {
        let dt = self.near.output_dim();
        let ne = self.ops.n_equiv();
        let tree = &self.tree;
        let mut leaves: Vec<usize> = (0..tree.boxes.len())
            .filter(|&b| {
                let bx = &tree.boxes[b];
                bx.role == Role::Owned && bx.leaf && !bx.targets.is_empty()
            })
            .collect();
        leaves.sort_by_key(|&b| tree.boxes[b].targets.start);
        let mut sorted = vec![0.0; tree.targets.len() * dt];
        let mut chunks = Vec::with_capacity(leaves.len());
        let mut rest = sorted.as_mut_slice();
        let mut at = 0;
        for &b in &leaves {
            let r = tree.boxes[b].targets.clone();
            let (_, tail) = rest.split_at_mut((r.start - at) * dt);
            let (mine, tail) = tail.split_at_mut(r.len() * dt);
            chunks.push(mine);
            rest = tail;
            at = r.end;
        }
        chunks.into_par_iter().zip(leaves.par_iter()).for_each_init(
            || self.scratch(),
            |s, (vals, &bx)| {
                let node = &tree.boxes[bx];
                let tgts = &tree.targets[node.targets.clone()];
                let mut t = Instant::now();
                // L2P
                if node.key.level >= 2 {
                    self.equivalent_to_targets(
                        s,
                        &down[bx * ne..(bx + 1) * ne],
                        bx,
                        DOWN_EQUIV,
                        tgts,
                        vals,
                    );
                }
                t = clock.add(6, t);
                // M2P (the W list's small leaves are in the near field).
                for &w in &tree.lists.w[bx] {
                    let wn = &tree.boxes[w];
                    if wn.n_sources == 0 || NearList::w_direct(tree, w) {
                        continue;
                    }
                    self.equivalent_to_targets(s, &up[w * ne..(w + 1) * ne], w, INNER, tgts, vals);
                }
                clock.add(7, t);
            },
        );
        sorted
    }

    /// Add the field of box `b`'s normalised equivalent density (on its surface of radius
    /// factor `radius`) at `tgts` (L2P, M2P): undo the normalisation, place the surface, evaluate
    /// with the far target kernel.
    fn equivalent_to_targets(
        &self,
        s: &mut Scratch,
        normalised: &[f64],
        b: usize,
        radius: f64,
        tgts: &[[f64; 3]],
        vals: &mut [f64],
    ) {
        let node = &self.tree.boxes[b];
        let de = self.ops.degrees.len();
        let scale = self.ops.scale(node.half);
        let dens = &mut s.dens[..normalised.len()];
        for (o, (v, k)) in dens.iter_mut().zip(normalised.iter().zip((0..de).cycle())) {
            *o = v / scale[k];
        }
        self.ops
            .surf
            .place(node.center, node.half, radius, &mut s.pts);
        s.block.set_points(&s.pts, dens, de);
        self.far_target.eval_block(tgts, &s.block.all(), vals);
    }
}

/// For pairs `(dst, src)`: `out[:, dst] += T_o · x[:, src]` as one GEMM, with `T_o` octant 0's
/// translation `m` reflected onto octant `o` (the reflection applied to the gathered inputs
/// and the scattered outputs; columns of `x` and `out` of length `m.ncols()` and `m.nrows()`).
fn gather_gemm_scatter(
    m: &faer::Mat<f64>,
    reflection: &Reflection,
    pairs: &[(usize, usize)],
    x: &[f64],
    out: &mut [f64],
) {
    if pairs.is_empty() {
        return;
    }
    let (nr, nc) = (m.nrows(), m.ncols());
    let mut xs = vec![0.0; pairs.len() * nc];
    for (k, &(_, s)) in pairs.iter().enumerate() {
        reflection.gather(&x[s * nc..(s + 1) * nc], &mut xs[k * nc..(k + 1) * nc]);
    }
    let mut y = vec![0.0; pairs.len() * nr];
    gemm(m, &xs, &mut y, pairs.len());
    for (k, &(d, _)) in pairs.iter().enumerate() {
        reflection.scatter_add(&y[k * nr..(k + 1) * nr], &mut out[d * nr..(d + 1) * nr]);
    }
}

/// One exchange over `out` (sent) and `inn` (received) links: each link's boxes' expansions
/// from `up`, then its sources' densities from `dens`, in the link's order; one buffer per
/// received link.
fn exchange_links(
    comm: &dyn Communicator,
    out: &[GhostLink],
    inn: &[GhostLink],
    up: &[f64],
    dens: &[f64],
    ne: usize,
    ds: usize,
) -> Result<Vec<Vec<f64>>, FmmError> {
    let bufs: Vec<Vec<f64>> = out
        .iter()
        .map(|l| {
            let mut b = Vec::with_capacity(l.len(ne, ds));
            for &bx in &l.boxes {
                b.extend_from_slice(&up[bx * ne..(bx + 1) * ne]);
            }
            for r in &l.sources {
                b.extend_from_slice(&dens[r.start * ds..r.end * ds]);
            }
            b
        })
        .collect();
    let sends: Vec<(usize, &[f64])> = out
        .iter()
        .zip(&bufs)
        .map(|(l, b)| (l.rank, b.as_slice()))
        .collect();
    let recvs: Vec<(usize, usize)> = inn.iter().map(|l| (l.rank, l.len(ne, ds))).collect();
    Ok(comm.exchange_f64(&sends, &recvs)?)
}

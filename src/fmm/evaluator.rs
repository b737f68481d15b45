//! The fast KIFMM: tree, lists and translation operators built once, evaluated for many
//! densities.
//!
//! Phases of one evaluation (timed separately, see [`FmmTimings`]):
//!
//! 1. **P2M** (leaves) and **M2M**, level by level upwards: upward check potentials fitted by
//!    the factored pseudo-inverse; densities normalised per level ([`super::operators`]).
//! 2. **M2L** by FFT ([`super::m2l_fft`]): spectra of all upward densities, Hadamard products
//!    summed per target box over its V list, one inverse FFT per target box.
//! 3. **P2L** (X list) into the same check potentials, then the downward fit and **L2L** from
//!    the parent, level by level downwards.
//! 4. **L2P**, **M2P** (W list) and **P2P** (U list) at the leaves.
//!
//! Rayon runs the boxes of one level (and the leaves) in parallel; the kernels and translation
//! operators are serial. RPY runs as a Stokeslet FMM whose source and target ends carry the
//! finite-size correction ([`RpyFar`]), with boxes at least `2a` wide.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

use rayon::prelude::*;

use super::blocks::{SourceBlock, SourceView};
use super::kernels::{
    Kernel, Laplace, LaplaceDoubleLayer, Rpy, RpyFar, Stokeslet, StokesletSource, Stresslet,
};
use super::m2l_fft::{offset_index, FftM2l};
use super::octree::{Lists, Octree};
use super::operators::{gemm, octant, Translations, DOWN_EQUIV, INNER, UP_CHECK};
use super::surface::CubeSurface;
use super::FmmError;

type Operators = (Arc<Translations>, Arc<FftM2l>);

/// Translation operators depend only on the equivalent kernel and the order (densities are
/// normalised per level), so they are built once per process and shared.
fn operators_for(kind: FmmKernel, order: usize) -> Result<Operators, FmmError> {
    static CACHE: OnceLock<Mutex<HashMap<(&'static str, usize), Operators>>> = OnceLock::new();
    let equivalent = kind.equivalent();
    let key = (equivalent.name(), order);
    let cache = CACHE.get_or_init(|| Mutex::new(HashMap::new()));
    if let Some(v) = cache.lock().map_err(|_| poisoned())?.get(&key) {
        return Ok(v.clone());
    }
    let (ops, m2l) = rayon::join(
        || Translations::new(equivalent.as_ref(), order, kind.rcond()),
        || FftM2l::new(equivalent.as_ref(), &CubeSurface::new(order)),
    );
    let ops = ops?;
    let v = (Arc::new(ops), Arc::new(m2l));
    cache.lock().map_err(|_| poisoned())?.insert(key, v.clone());
    Ok(v)
}

fn poisoned() -> FmmError {
    FmmError::Shape("FMM operator cache poisoned by a panic in another thread".into())
}

/// The sums `mobo fmm` offers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FmmKernel {
    /// `Σ q/(4π|r|)`.
    Laplace,
    /// `Σ (n·r) q/(4π|r|³)`.
    LaplaceDoubleLayer,
    /// `Σ (1/8π)(I/|r| + r rᵀ/|r|³) f`.
    Stokeslet,
    /// `Σ (3/4π)(r·f)(r·n) r/|r|⁵`.
    Stresslet,
    /// Rotne–Prager–Yamakawa with bead radius `radius`.
    Rpy { radius: f64 },
}

impl FmmKernel {
    /// Parse a command-line name (`laplace`, `laplace-dl`, `stokeslet`, `stresslet`, `rpy`).
    pub fn from_name(name: &str, radius: Option<f64>) -> Result<Self, FmmError> {
        Ok(match name {
            "laplace" => FmmKernel::Laplace,
            "laplace-dl" => FmmKernel::LaplaceDoubleLayer,
            "stokeslet" => FmmKernel::Stokeslet,
            "stresslet" => FmmKernel::Stresslet,
            "rpy" => {
                let a = radius.ok_or_else(|| FmmError::Shape("rpy needs a radius".into()))?;
                if !(a > 0.0 && a.is_finite()) {
                    return Err(FmmError::Shape(format!(
                        "rpy radius must be positive, got {a}"
                    )));
                }
                FmmKernel::Rpy { radius: a }
            }
            other => return Err(FmmError::Shape(format!("unknown kernel '{other}'"))),
        })
    }

    /// The kernel applied between points (P2P, and the direct sum).
    pub fn near(&self) -> Box<dyn Kernel> {
        match *self {
            FmmKernel::Laplace => Box::new(Laplace),
            FmmKernel::LaplaceDoubleLayer => Box::new(LaplaceDoubleLayer),
            FmmKernel::Stokeslet => Box::new(Stokeslet),
            FmmKernel::Stresslet => Box::new(Stresslet),
            FmmKernel::Rpy { radius } => Box::new(Rpy { radius }),
        }
    }

    /// Sources to check surfaces (P2M, P2L).
    fn far_source(&self) -> Box<dyn Kernel> {
        match *self {
            FmmKernel::Rpy { radius } => Box::new(RpyFar { radius }),
            _ => self.near(),
        }
    }

    /// Equivalent densities to check surfaces (M2M, M2L, L2L).
    fn equivalent(&self) -> Box<dyn Kernel> {
        match *self {
            FmmKernel::Laplace | FmmKernel::LaplaceDoubleLayer => Box::new(Laplace),
            FmmKernel::Stokeslet | FmmKernel::Rpy { .. } => Box::new(Stokeslet),
            FmmKernel::Stresslet => Box::new(StokesletSource),
        }
    }

    /// Equivalent densities to targets (L2P, M2P).
    fn far_target(&self) -> Box<dyn Kernel> {
        match *self {
            FmmKernel::Rpy { radius } => Box::new(RpyFar { radius }),
            _ => self.equivalent(),
        }
    }

    /// Relative cut-off of the truncated-SVD fits (measured: Laplace keeps improving to
    /// 1e-13; Stokes kernels are best near 1e-10, round-off in the fits dominates below).
    pub fn rcond(&self) -> f64 {
        match self {
            FmmKernel::Laplace | FmmKernel::LaplaceDoubleLayer => 1e-13,
            _ => 1e-10,
        }
    }

    /// Default leaf size (points per leaf, sources plus targets), balancing P2P against the
    /// translations: measured on 10⁵ and 10⁶ points of the uniform and sphere clouds
    /// (examples/fmm_probe). Larger leaves also keep uniform clouds off half-refined levels,
    /// whose W and X lists cost more than they save.
    pub fn default_leaf_size(&self, order: usize) -> usize {
        100 * order.max(4)
    }
}

/// Wall time of each phase of the last evaluation, in seconds (phases that run inside one
/// parallel loop are split by summed thread time).
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct FmmTimings {
    pub p2m: f64,
    pub m2m: f64,
    pub m2l_fft: f64,
    pub m2l_hadamard: f64,
    pub p2l: f64,
    pub l2l: f64,
    pub l2p: f64,
    pub m2p: f64,
    pub p2p: f64,
    pub total: f64,
}

/// The FMM for one kernel over fixed sources and targets.
pub struct Fmm {
    kind: FmmKernel,
    near: Box<dyn Kernel>,
    far_source: Box<dyn Kernel>,
    far_target: Box<dyn Kernel>,
    /// The tree (points in Morton order inside).
    pub tree: Octree,
    lists: Lists,
    ops: Arc<Translations>,
    m2l: Arc<FftM2l>,
    /// Boxes ordered by level; `pos[b]` is box `b`'s place in it.
    by_level: Vec<usize>,
    pos: Vec<usize>,
    level_start: Vec<usize>,
    sources: SourceBlock,
    /// Order (points per edge of the surfaces).
    pub order: usize,
    /// Seconds spent in [`Fmm::new`].
    pub setup_s: f64,
    /// Phase times of the last [`Fmm::evaluate`].
    pub timings: FmmTimings,
}

/// Per-thread scratch of the leaf phase.
struct Scratch {
    pts: Vec<[f64; 3]>,
    block: SourceBlock,
    dens: Vec<f64>,
}

struct PhaseClock(Vec<AtomicU64>);

impl PhaseClock {
    fn new() -> Self {
        PhaseClock((0..10).map(|_| AtomicU64::new(0)).collect())
    }
    fn add(&self, phase: usize, since: Instant) -> Instant {
        let now = Instant::now();
        self.0[phase].fetch_add((now - since).as_nanos() as u64, Ordering::Relaxed);
        now
    }
    fn get(&self, phase: usize) -> f64 {
        self.0[phase].load(Ordering::Relaxed) as f64 * 1e-9
    }
}

impl Fmm {
    /// Build the tree, lists and operators. `normals` are needed by the double-layer kernels;
    /// `order` is the number of surface points per edge (≥ 2); `leaf_size` the maximum points
    /// (sources plus targets) per leaf.
    pub fn new(
        kind: FmmKernel,
        sources: &[[f64; 3]],
        normals: Option<&[[f64; 3]]>,
        targets: &[[f64; 3]],
        order: usize,
        leaf_size: usize,
    ) -> Result<Self, FmmError> {
        let start = Instant::now();
        if !(2..=20).contains(&order) {
            return Err(FmmError::Shape(format!(
                "FMM order must be between 2 and 20, got {order}"
            )));
        }
        let near = kind.near();
        if near.needs_normals() && normals.map(|n| n.len()) != Some(sources.len()) {
            return Err(FmmError::Shape(format!(
                "{} needs one normal per source",
                near.name()
            )));
        }
        let min_width = match kind {
            FmmKernel::Rpy { radius } => 2.0 * radius,
            _ => 0.0,
        };
        let tree = Octree::with_min_width(sources, targets, leaf_size, min_width);
        let lists = tree.lists();
        let (ops, m2l) = operators_for(kind, order)?;
        let mut by_level: Vec<usize> = (0..tree.nodes.len()).collect();
        by_level.sort_by_key(|&b| tree.nodes[b].level);
        let mut pos = vec![0; by_level.len()];
        for (i, &b) in by_level.iter().enumerate() {
            pos[b] = i;
        }
        let depth = tree.depth() as usize;
        let level_start: Vec<usize> = (0..=depth)
            .map(|l| by_level.partition_point(|&b| (tree.nodes[b].level as usize) < l))
            .collect();
        let sources_sorted = SourceBlock::new(sources, normals, &tree.source_perm);
        Ok(Fmm {
            kind,
            near,
            far_source: kind.far_source(),
            far_target: kind.far_target(),
            tree,
            lists,
            ops,
            m2l,
            by_level,
            pos,
            level_start,
            sources: sources_sorted,
            order,
            setup_s: start.elapsed().as_secs_f64(),
            timings: FmmTimings::default(),
        })
    }

    /// The kernel.
    pub fn kernel(&self) -> FmmKernel {
        self.kind
    }

    fn scratch(&self) -> Scratch {
        let n = self.ops.surf.len();
        let dmax = 4;
        Scratch {
            pts: Vec::with_capacity(n),
            block: SourceBlock::default(),
            dens: vec![0.0; n * dmax],
        }
    }

    fn check_sizes(&self, density: &[f64], out: &[f64]) -> Result<(), FmmError> {
        let (ds, dt) = (self.near.density_dim(), self.near.output_dim());
        let (ns, nt) = (
            self.tree.sources_sorted.len(),
            self.tree.targets_sorted.len(),
        );
        if density.len() != ns * ds {
            return Err(FmmError::Shape(format!(
                "density has {} values, expected {} ({} sources × {})",
                density.len(),
                ns * ds,
                ns,
                ds
            )));
        }
        if out.len() != nt * dt {
            return Err(FmmError::Shape(format!(
                "output has {} values, expected {} ({} targets × {})",
                out.len(),
                nt * dt,
                nt,
                dt
            )));
        }
        Ok(())
    }

    /// The exact sum by direct summation (same kernels, same layout as [`Fmm::evaluate`]).
    pub fn direct(&mut self, density: &[f64], out: &mut [f64]) -> Result<(), FmmError> {
        self.check_sizes(density, out)?;
        let ds = self.near.density_dim();
        let dt = self.near.output_dim();
        self.sources
            .set_density(density, ds, &self.tree.source_perm);
        let view = self.sources.all();
        let near = &self.near;
        let tree = &self.tree;
        let mut sorted = vec![0.0; out.len()];
        sorted
            .par_chunks_mut(64 * dt)
            .zip(tree.targets_sorted.par_chunks(64))
            .for_each(|(o, t)| near.eval_block(t, &view, o));
        for (i, &dst) in tree.target_perm.iter().enumerate() {
            out[dst * dt..(dst + 1) * dt].copy_from_slice(&sorted[i * dt..(i + 1) * dt]);
        }
        Ok(())
    }

    /// Evaluate the sum for `density` (`density_dim` values per source, input order) into `out`
    /// (`output_dim` values per target, input order).
    pub fn evaluate(&mut self, density: &[f64], out: &mut [f64]) -> Result<(), FmmError> {
        self.check_sizes(density, out)?;
        let t0 = Instant::now();
        let ds = self.near.density_dim();
        self.sources
            .set_density(density, ds, &self.tree.source_perm);
        let clock = PhaseClock::new();
        let up = self.upward(&clock);
        let down = self.downward(&up, &clock);
        let sorted = self.leaves(&up, &down, &clock);
        let dt = self.near.output_dim();
        for (i, &dst) in self.tree.target_perm.iter().enumerate() {
            out[dst * dt..(dst + 1) * dt].copy_from_slice(&sorted[i * dt..(i + 1) * dt]);
        }
        self.timings = FmmTimings {
            p2m: clock.get(0),
            m2m: clock.get(1),
            m2l_fft: clock.get(2),
            m2l_hadamard: clock.get(3),
            p2l: clock.get(4),
            l2l: clock.get(5),
            l2p: clock.get(6),
            m2p: clock.get(7),
            p2p: clock.get(8),
            total: t0.elapsed().as_secs_f64(),
        };
        Ok(())
    }

    /// Upward pass: normalised upward equivalent densities, one column of `n_equiv` values per
    /// box in level order. Per level: P2M and M2M into upward check potentials, one fit (GEMM).
    fn upward(&self, clock: &PhaseClock) -> Vec<f64> {
        let ne = self.ops.n_equiv();
        let nc = self.ops.n_check();
        let nb = self.tree.nodes.len();
        let mut up = vec![0.0; nb * ne];
        let depth = self.level_start.len() - 1;
        for level in (0..depth).rev() {
            let (a, b) = (self.level_start[level], self.level_start[level + 1]);
            let (head, rest) = up.split_at_mut(b * ne);
            let cur = &mut head[a * ne..];
            let children = &*rest;
            let t = Instant::now();
            let mut check = vec![0.0; (b - a) * nc];
            // P2M at the leaves of this level.
            check
                .par_chunks_mut(nc)
                .zip(&self.by_level[a..b])
                .for_each_init(
                    || Vec::with_capacity(self.ops.surf.len()),
                    |pts, (col, &bx)| {
                        let node = &self.tree.nodes[bx];
                        if node.is_leaf() && !node.sources.is_empty() {
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
            // M2M: per octant, one GEMM over the children of this level's boxes.
            if level + 1 < depth {
                let mut groups: Vec<Vec<(usize, usize)>> = vec![Vec::new(); 8];
                for i in a..b {
                    let node = &self.tree.nodes[self.by_level[i]];
                    for &c in &node.children {
                        let cn = &self.tree.nodes[c];
                        if !cn.sources.is_empty() {
                            let o = octant(sub(cn.center, node.center));
                            groups[o].push((i - a, self.pos[c] - b));
                        }
                    }
                }
                for (o, g) in groups.iter().enumerate() {
                    gather_gemm_scatter(&self.ops.m2m[o], g, children, &mut check);
                }
            }
            self.ops.up.apply_many(&check, cur);
            clock.add(1, t);
        }
        up
    }

    /// Downward pass: normalised downward equivalent densities by level-ordered position.
    fn downward(&self, up: &[f64], clock: &PhaseClock) -> Vec<f64> {
        let ne = self.ops.n_equiv();
        let de = self.ops.degrees.len();
        let dt = self.near.output_dim();
        let nc = self.ops.n_check();
        let nf2 = self.m2l.spectrum_len(1);
        let nb = self.tree.nodes.len();
        let mut down = vec![0.0; nb * ne];
        let depth = self.level_start.len() - 1;
        for level in 2..depth {
            let (a, b) = (self.level_start[level], self.level_start[level + 1]);
            let nbl = b - a;
            let (head, _) = down.split_at_mut(b * ne);
            let (parents, cur) = head.split_at_mut(a * ne);
            let parents = &*parents;
            // M2L: spectra of this level's upward densities, blocked Hadamard products per
            // frequency chunk, one inverse FFT per target box.
            let mut t = Instant::now();
            let mut spec = vec![0.0; nbl * de * nf2];
            spec.par_chunks_mut(de * nf2)
                .zip(&self.by_level[a..b])
                .for_each_init(
                    || self.m2l.scratch(),
                    |s, (dst, &bx)| {
                        if !self.tree.nodes[bx].sources.is_empty() {
                            let p = self.pos[bx];
                            self.m2l.spectrum(&up[p * ne..(p + 1) * ne], dst, s);
                        }
                    },
                );
            let nch = self.m2l.n_chunks;
            let mut src = vec![0.0; nch * nbl * FftM2l::chunk_len(de)];
            self.m2l.to_chunks(&spec, de, &mut src);
            drop(spec);
            // Pairs (target, source, compact offset), sorted by offset so that each kernel
            // block is reused from cache.
            let mut pairs: Vec<(u32, u32, u16)> = Vec::new();
            for i in a..b {
                let bx = self.by_level[i];
                let node = &self.tree.nodes[bx];
                if node.targets.is_empty() {
                    continue;
                }
                for &v in &self.lists.v[bx] {
                    let vn = &self.tree.nodes[v];
                    if vn.sources.is_empty() {
                        continue;
                    }
                    let d = sub(node.center, vn.center);
                    let w = 2.0 * node.half;
                    let off = [
                        (d[0] / w).round() as i32,
                        (d[1] / w).round() as i32,
                        (d[2] / w).round() as i32,
                    ];
                    let o = self.m2l.compact_offset(offset_index(off));
                    pairs.push(((i - a) as u32, (self.pos[v] - a) as u32, o as u16));
                }
            }
            pairs.sort_unstable_by_key(|&(t, _, o)| (o, t));
            t = clock.add(2, t);
            let (sl, tl) = (FftM2l::chunk_len(de), FftM2l::chunk_len(dt));
            let mut tgt = vec![0.0; nch * nbl * tl];
            tgt.par_chunks_mut(nbl * tl)
                .zip(src.par_chunks(nbl * sl))
                .enumerate()
                .for_each(|(c, (tc, sc))| {
                    for &(ti, si, o) in &pairs {
                        let (ti, si) = (ti as usize, si as usize);
                        self.m2l.accumulate_chunk(
                            c,
                            o as usize,
                            &sc[si * sl..(si + 1) * sl],
                            &mut tc[ti * tl..(ti + 1) * tl],
                        );
                    }
                });
            drop(src);
            t = clock.add(3, t);
            let mut has_v = vec![false; nbl];
            for &(ti, _, _) in &pairs {
                has_v[ti as usize] = true;
            }
            let mut check = vec![0.0; nbl * nc];
            check.par_chunks_mut(nc).enumerate().for_each_init(
                || (self.m2l.scratch(), vec![0.0; self.m2l.spectrum_len(dt)]),
                |(s, sp), (i, col)| {
                    if has_v[i] {
                        self.m2l.from_chunks(&tgt, nbl, i, dt, sp);
                        self.m2l.check_values(sp, col, s);
                    }
                },
            );
            drop(tgt);
            t = clock.add(2, t);
            // P2L: X-list sources at the downward check surfaces.
            check
                .par_chunks_mut(nc)
                .zip(&self.by_level[a..b])
                .for_each_init(
                    || Vec::with_capacity(self.ops.surf.len()),
                    |pts, (col, &bx)| {
                        let node = &self.tree.nodes[bx];
                        if self.lists.x[bx].is_empty() || node.targets.is_empty() {
                            return;
                        }
                        if self.x_direct(bx) {
                            return;
                        }
                        self.ops.surf.place(node.center, node.half, INNER, pts);
                        for &x in &self.lists.x[bx] {
                            let xn = &self.tree.nodes[x];
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
            t = clock.add(4, t);
            // L2L per octant into the check potentials, then the downward fit of the level.
            if level > 2 {
                let mut groups: Vec<Vec<(usize, usize)>> = vec![Vec::new(); 8];
                for i in a..b {
                    let bx = self.by_level[i];
                    let node = &self.tree.nodes[bx];
                    if node.targets.is_empty() {
                        continue;
                    }
                    let par = node.parent.expect("level ≥ 2 has a parent");
                    let o = octant(sub(node.center, self.tree.nodes[par].center));
                    groups[o].push((i - a, self.pos[par]));
                }
                for (o, g) in groups.iter().enumerate() {
                    gather_gemm_scatter(&self.ops.l2l[o], g, parents, &mut check);
                }
            }
            self.ops.down.apply_many(&check, cur);
            clock.add(5, t);
        }
        down
    }

    /// Leaves: L2P, M2P and P2P into the targets' values in Morton order.
    fn leaves(&self, up: &[f64], down: &[f64], clock: &PhaseClock) -> Vec<f64> {
        let dt = self.near.output_dim();
        let ne = self.ops.n_equiv();
        let mut leaves: Vec<usize> = (0..self.tree.nodes.len())
            .filter(|&b| self.tree.nodes[b].is_leaf() && !self.tree.nodes[b].targets.is_empty())
            .collect();
        leaves.sort_by_key(|&b| self.tree.nodes[b].targets.start);
        let mut sorted = vec![0.0; self.tree.targets_sorted.len() * dt];
        let mut chunks = Vec::with_capacity(leaves.len());
        let mut rest = sorted.as_mut_slice();
        let mut at = 0;
        for &b in &leaves {
            let r = self.tree.nodes[b].targets.clone();
            let (_, tail) = rest.split_at_mut((r.start - at) * dt);
            let (mine, tail) = tail.split_at_mut(r.len() * dt);
            chunks.push(mine);
            rest = tail;
            at = r.end;
        }
        chunks.into_par_iter().zip(leaves.par_iter()).for_each_init(
            || self.scratch(),
            |s, (vals, &bx)| {
                let node = &self.tree.nodes[bx];
                let tgts = &self.tree.targets_sorted[node.targets.clone()];
                let mut t = Instant::now();
                // L2P
                if node.level >= 2 {
                    let p = self.pos[bx];
                    self.equivalent_to_targets(
                        s,
                        &down[p * ne..(p + 1) * ne],
                        bx,
                        DOWN_EQUIV,
                        tgts,
                        vals,
                    );
                }
                t = clock.add(6, t);
                // M2P, or P2P where the box has fewer sources than surface points.
                for &w in &self.lists.w[bx] {
                    let wn = &self.tree.nodes[w];
                    if wn.sources.is_empty() {
                        continue;
                    }
                    if wn.sources.len() <= self.ops.surf.len() {
                        self.near
                            .eval_block(tgts, &self.sources.view(wn.sources.clone()), vals);
                        continue;
                    }
                    let p = self.pos[w];
                    self.equivalent_to_targets(s, &up[p * ne..(p + 1) * ne], w, INNER, tgts, vals);
                }
                t = clock.add(7, t);
                // P2P: U list, and the X list of a small leaf (instead of P2L).
                if self.x_direct(bx) {
                    for &x in &self.lists.x[bx] {
                        let xn = &self.tree.nodes[x];
                        self.near
                            .eval_block(tgts, &self.sources.view(xn.sources.clone()), vals);
                    }
                }
                for &u in &self.lists.u[bx] {
                    let un = &self.tree.nodes[u];
                    if !un.sources.is_empty() {
                        let view: SourceView = self.sources.view(un.sources.clone());
                        self.near.eval_block(tgts, &view, vals);
                    }
                }
                clock.add(8, t);
            },
        );
        sorted
    }

    /// Whether the X list of box `b` acts directly on its targets (a leaf with fewer targets
    /// than surface points) rather than through its downward check surface.
    fn x_direct(&self, b: usize) -> bool {
        let node = &self.tree.nodes[b];
        node.is_leaf() && node.targets.len() <= self.ops.surf.len()
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
        let node = &self.tree.nodes[b];
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

/// For pairs `(dst, src)`: `out[:, dst] += m · x[:, src]` as one GEMM (columns of `x` and
/// `out` of length `m.ncols()` and `m.nrows()`).
fn gather_gemm_scatter(m: &faer::Mat<f64>, pairs: &[(usize, usize)], x: &[f64], out: &mut [f64]) {
    if pairs.is_empty() {
        return;
    }
    let (nr, nc) = (m.nrows(), m.ncols());
    let mut xs = vec![0.0; pairs.len() * nc];
    for (k, &(_, s)) in pairs.iter().enumerate() {
        xs[k * nc..(k + 1) * nc].copy_from_slice(&x[s * nc..(s + 1) * nc]);
    }
    let mut y = vec![0.0; pairs.len() * nr];
    gemm(m, &xs, &mut y, pairs.len());
    for (k, &(d, _)) in pairs.iter().enumerate() {
        for (o, v) in out[d * nr..(d + 1) * nr]
            .iter_mut()
            .zip(&y[k * nr..(k + 1) * nr])
        {
            *o += v;
        }
    }
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

//! The fast KIFMM: tree, lists and translation operators built once, evaluated for many
//! densities.
//!
//! Phases of one evaluation (timed separately, see [`FmmTimings`]):
//!
//! 1. **P2M** (leaves) and **M2M**, level by level upwards: upward check potentials fitted by
//!    the factored pseudo-inverse; densities normalised per level ([`super::operators`]).
//! 2. **M2L** by FFT ([`super::m2l_fft`]): spectra of the V-list sources' upward densities,
//!    Hadamard products summed per target box over its V list (8 × 8 blocks of the children of
//!    two neighbouring parents where they are dense, pairs elsewhere: [`super::m2l_plan`]), one
//!    inverse FFT per target box. Which pairs run as blocks depends on the boxes a rank
//!    computes, and the blocks fuse multiply-adds where the CPU has FMA, so values differ
//!    between rank counts and CPUs by round-off (the order of a target's sum).
//! 3. **P2L** (X list) into the same check potentials, then the downward fit and **L2L** from
//!    the parent, level by level downwards.
//! 4. **L2P**, **M2P** (W list) and **P2P** (U list) at the leaves.
//!
//! Rayon runs the boxes of one level (and the leaves) in parallel; the kernels and translation
//! operators are serial. RPY runs as a Stokeslet FMM whose source and target ends carry the
//! finite-size correction ([`super::kernels::RpyFar`]), with boxes at least `2a` wide.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

use rayon::prelude::*;

use super::blocks::SourceBlock;
use super::calibration;
use super::dist_tree::{DistTree, GhostLink, Role, TreeInput};
use super::fit_cache;
pub use super::kernels::FmmKernel;
use super::kernels::Kernel;
use super::m2l_fft::FftM2l;
use super::m2l_plan::{M2lPlan, DENSE_PAIRS};
use super::near_field::{CpuNearField, NearField, NearList, NearPoints};
use super::operators::{gemm, Reflection, Translations, DOWN_EQUIV, INNER, UP_CHECK};
use super::surface::CubeSurface;
use super::FmmError;
use crate::comm::{Communicator, SerialComm};

type Operators = (Arc<Translations>, Arc<FftM2l>);

/// The smallest box width of an RPY tree of bead radius `a` at `order`.
///
/// Boxes at least `2a` wide keep every overlapping pair (`r < 2a`, where the RPY tensor changes
/// form) in the near field. The far field carries the finite-size term `a²/3 ∇²G`, whose
/// relative size near a box is `(a/w)²` and which the Stokeslet equivalent densities fit less
/// well than `G` itself: on a cloud with a dense core of overlapping beads (30 000 points, `a`
/// half the median neighbour distance, 2026-11-25) boxes of `2a` gave 9.9e-9 at order 13,
/// 2.4e-9 at order 15 and 2.0e-9 at order 16 (asked: 1e-8, 1e-9, 1e-10); `4a` gave 3.5e-9,
/// 3.6e-10 and 2.1e-10, `8a` at order 16 2.6e-11. Orders up to 10 (6 digits) met their digits
/// with `2a` (5.2e-7 at order 10). The wider boxes cost no evaluation time there (fewer levels,
/// fuller leaves in the core).
fn rpy_min_box_width(a: f64, order: usize) -> f64 {
    let factor = match order {
        0..=10 => 2.0,
        11..=15 => 4.0,
        _ => 8.0,
    };
    factor * a
}

/// Translation operators depend only on the equivalent kernel and the order (densities are
/// normalised per level), so they are built once per process and shared.
type OperatorCache = Mutex<HashMap<(&'static str, usize), Operators>>;

fn operator_cache() -> &'static OperatorCache {
    static CACHE: OnceLock<OperatorCache> = OnceLock::new();
    CACHE.get_or_init(|| Mutex::new(HashMap::new()))
}

/// Drop the operators this process keeps for every kernel and order it has set up (they are
/// shared by every [`Fmm`] of the same equivalent kernel and order, and kept until then: at
/// order 15 the Stokes operators take about 3 GB). Evaluators that exist keep theirs.
pub fn clear_operator_cache() {
    if let Ok(mut c) = operator_cache().lock() {
        c.clear();
    }
}

fn operators_for(kind: FmmKernel, order: usize) -> Result<Operators, FmmError> {
    let equivalent = kind.equivalent();
    let key = (equivalent.name(), order);
    let cache = operator_cache();
    if let Some(v) = cache.lock().map_err(|_| poisoned())?.get(&key) {
        return Ok(v.clone());
    }
    let disk = fit_cache::dir();
    let (ops, m2l) = rayon::join(
        || Translations::new(equivalent.as_ref(), order, kind.rcond(), disk.as_deref()),
        || FftM2l::new(equivalent.as_ref(), &CubeSurface::new(order)),
    );
    let ops = ops?;
    let v = (Arc::new(ops), Arc::new(m2l));
    cache.lock().map_err(|_| poisoned())?.insert(key, v.clone());
    Ok(v)
}

/// The CPU near field of `tree` allowed `tol` per pair; where the targets are the sources in
/// the same order (one rank, no `--targets`), each pair of leaves once for both directions
/// ([`MutualPairs`](super::near_pairs::MutualPairs)).
fn cpu_near_field(kind: FmmKernel, tree: &DistTree, list: &NearList, tol: f64) -> CpuNearField {
    let near = CpuNearField::within(kind.near(), tol);
    if near_is_mutual(tree) {
        near.with_mutual(list)
    } else {
        near
    }
}

/// Whether `tree`'s sorted targets are its sorted sources.
fn near_is_mutual(tree: &DistTree) -> bool {
    tree.normals.is_none() && tree.sources == tree.targets
}

fn poisoned() -> FmmError {
    FmmError::Shape("FMM operator cache poisoned by a panic in another thread".into())
}

/// Wall time of each phase of the last evaluation, in seconds (phases that run inside one
/// parallel loop are split by summed thread time).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct FmmTimings {
    /// P2M: leaf sources at their upward check surfaces (thread time).
    pub p2m: f64,
    /// M2M and the upward fits of the non-leaf boxes (thread time).
    pub m2m: f64,
    /// M2L: forward FFTs of the upward densities and inverse FFTs into the check potentials.
    pub m2l_fft: f64,
    /// M2L: the Hadamard products summed over the V lists.
    pub m2l_hadamard: f64,
    /// P2L: X-list sources at the downward check surfaces.
    pub p2l: f64,
    /// L2L and the downward fits.
    pub l2l: f64,
    /// L2P: downward equivalent densities at the leaves' targets (thread time).
    pub l2p: f64,
    /// M2P: W-list upward equivalent densities at the leaves' targets (thread time).
    pub m2p: f64,
    /// The near-field pass ([`super::near_field`]): wall seconds of its backend (on the GPU:
    /// uploads, kernel and read-back included).
    pub p2p: f64,
    /// Whether the near field ran beside the CPU's far field (a GPU backend).
    pub near_concurrent: bool,
    /// Wall seconds of the CPU's far field from the ghost exchange on (top of the upward pass,
    /// M2L, downward pass, L2P, M2P): with a concurrent near field, `total` is about
    /// `max(p2p, far_wall)` plus the rest, rather than their sum.
    pub far_wall: f64,
    /// Wall seconds of the whole evaluation, communication included.
    pub total: f64,
}

impl FmmTimings {
    /// Add another evaluation's phases to these (totals over several evaluations; the flag is
    /// set if either ran its near field concurrently).
    pub fn accumulate(&mut self, other: &FmmTimings) {
        self.p2m += other.p2m;
        self.m2m += other.m2m;
        self.m2l_fft += other.m2l_fft;
        self.m2l_hadamard += other.m2l_hadamard;
        self.p2l += other.p2l;
        self.l2l += other.l2l;
        self.l2p += other.l2p;
        self.m2p += other.m2p;
        self.p2p += other.p2p;
        self.near_concurrent |= other.near_concurrent;
        self.far_wall += other.far_wall;
        self.total += other.total;
    }

    /// The phases by name, as `mobo fmm`'s JSON and `summary.json` list them.
    pub fn phases(&self) -> [(&'static str, f64); 9] {
        [
            ("p2m", self.p2m),
            ("m2m", self.m2m),
            ("m2l_fft", self.m2l_fft),
            ("m2l_hadamard", self.m2l_hadamard),
            ("p2l", self.p2l),
            ("l2l", self.l2l),
            ("l2p", self.l2p),
            ("m2p", self.m2p),
            ("p2p", self.p2p),
        ]
    }
}

/// Communication of the last evaluation on this rank.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct FmmComm {
    /// Number of ranks.
    pub ranks: usize,
    /// Bytes this rank sent to other ranks during the evaluation (both parts below).
    pub bytes_sent: u64,
    /// Of these, the locally essential tree (ghost boxes' expansions and leaf densities, point
    /// to point to neighbouring ranks) and the routing of densities and results between the
    /// caller's ranks and the owners: all but the top of the tree.
    pub let_bytes_sent: u64,
    /// Bytes of top-box expansions this rank received: other sharers' partial expansions of the
    /// top boxes it owns, and the whole expansions of the top boxes its lists use
    /// (`8 · ne` per box; see [`super::dist_tree`] for how many).
    pub top_bytes_received: u64,
    /// Seconds spent in communication (included in the phase total).
    pub seconds: f64,
}

/// The FMM for one kernel over fixed sources and targets.
///
/// [`Fmm::new`] builds the tree, its lists and the translation operators once (`order`
/// surface points per box edge, from [`super::order_for_digits`]; at most `leaf_size` sources
/// plus targets per leaf); [`Fmm::evaluate`] then sums any number of densities over the same
/// points. Densities are `density_dim` values per source and results `output_dim` values per
/// target, point-major, in the caller's order. A Laplace sum `u_i = Σ_j q_j / (4π|x_i − y_j|)`
/// over 300 sources and 200 targets, checked against the direct sum ([`super::direct_sum`])
/// and, for one target, against the formula:
///
/// ```
/// use mobo::fmm::{clouds::Cloud, direct_sum, order_for_digits, Fmm, FmmKernel, Laplace, SumInput};
/// let sources = Cloud::Uniform.points(300, 1);
/// let targets = Cloud::Uniform.points(200, 2);
/// let q = Cloud::densities(sources.len(), 3);
/// let order = order_for_digits(FmmKernel::Laplace, 4).unwrap();
/// let mut fmm = Fmm::new(FmmKernel::Laplace, &sources, None, &targets, order, 20).unwrap();
/// let mut u = vec![0.0; targets.len()];
/// fmm.evaluate(&q, &mut u).unwrap();
///
/// let input = SumInput { sources: &sources, density: &q, normals: None, targets: &targets };
/// let mut exact = vec![0.0; targets.len()];
/// direct_sum(&Laplace, &input, &mut exact).unwrap();
/// let l2 = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
/// let diff: Vec<f64> = u.iter().zip(&exact).map(|(a, b)| a - b).collect();
/// assert!(l2(&diff) < 1e-4 * l2(&exact)); // 4 digits asked
///
/// let r = |y: &[f64; 3]| (0..3).map(|k| (targets[0][k] - y[k]).powi(2)).sum::<f64>().sqrt();
/// let u0: f64 = sources.iter().zip(&q).map(|(y, qj)| qj / (4.0 * std::f64::consts::PI * r(y))).sum();
/// assert!((u0 - exact[0]).abs() < 1e-12 * u0.abs().max(1.0));
/// ```
pub struct Fmm {
    kind: FmmKernel,
    near: Box<dyn Kernel>,
    far_source: Box<dyn Kernel>,
    far_target: Box<dyn Kernel>,
    /// This rank's tree: owned, top and ghost boxes (the whole tree on one rank).
    pub tree: DistTree,
    ops: Arc<Translations>,
    m2l: Arc<FftM2l>,
    /// Owned sources, then ghost sources received from other ranks.
    sources: SourceBlock,
    identity: Vec<usize>,
    /// Order (points per edge of the surfaces).
    pub order: usize,
    /// Seconds spent in [`Fmm::new`].
    pub setup_s: f64,
    /// Phase times of the last [`Fmm::evaluate`].
    pub timings: FmmTimings,
    /// Communication of the last evaluation.
    pub comm: FmmComm,
    /// The direct interactions of the leaves, batched (built with the tree).
    near_list: NearList,
    /// The backend that evaluates `near_list` (CPU unless [`Fmm::set_near_field`] chose another).
    near_field: Box<dyn NearField>,
    /// The least V-list pairs of a parent pair for the M2L to run it as an 8 × 8 block.
    m2l_dense_pairs: usize,
    /// The most bytes the M2L's chunked spectra of one level may take at once (sources and
    /// targets): a level that needs more runs in parts ([`M2L_BUFFER_BYTES`]).
    m2l_buffer_bytes: usize,
    /// The largest chunked-spectra footprint of the last evaluation's M2L parts, in bytes.
    m2l_peak_bytes: std::sync::atomic::AtomicUsize,
}

/// The default most bytes of the M2L's chunked spectra at once (2 GiB). A level whose V-list
/// sources and targets need more (at 6 digits, Stokeslet: about 0.4 MB per box, so a level of
/// more than about 5000 boxes) runs in parts of consecutive target boxes, split between
/// sibling groups, each part with the spectra of its own sources: the sources near a split
/// are transformed once per part that needs them. Before it a 10⁴-cell suspension at p = 12
/// (1.2·10⁷ upsampled sources) peaked at 22.6 GiB on a 24 GiB machine (`benches/RESULTS.md`).
pub const M2L_BUFFER_BYTES: usize = 2 << 30;

/// The M2L's source and target spectra by frequency chunk, for one downward pass.
#[derive(Default)]
struct M2lBuffers {
    src: Vec<f64>,
    tgt: Vec<f64>,
}

/// The first `n` values of `v`, zeroed in parallel (`v` grown to `n` if shorter, and kept at
/// its largest length, so a later level that fits reuses it).
fn zeroed(v: &mut Vec<f64>, n: usize) -> &mut [f64] {
    if v.len() < n {
        // Free the old buffer first; the new one comes as untouched zero pages.
        *v = Vec::new();
        *v = vec![0.0; n];
    }
    let head = &mut v[..n];
    head.par_chunks_mut(1 << 16).for_each(|c| c.fill(0.0));
    head
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
    /// Build the tree, lists and operators on one rank. `normals` are needed by the
    /// double-layer kernels; `order` is the number of surface points per edge (≥ 2);
    /// `leaf_size` the maximum points (sources plus targets) per leaf (at least 1).
    ///
    /// # Errors
    /// [`FmmError::Shape`] for an order outside `2..=20`, a leaf size of 0, or missing normals.
    pub fn new(
        kind: FmmKernel,
        sources: &[[f64; 3]],
        normals: Option<&[[f64; 3]]>,
        targets: &[[f64; 3]],
        order: usize,
        leaf_size: usize,
    ) -> Result<Self, FmmError> {
        Self::new_on(
            &SerialComm,
            kind,
            sources,
            normals,
            targets,
            order,
            leaf_size,
        )
    }

    /// As [`Fmm::new`], over the ranks of `comm` (collective: every rank calls it with its own
    /// points). Each rank passes its own sources, normals and targets; the tree is global, and
    /// [`Fmm::evaluate_on`] returns each rank's own targets' values in its input order.
    pub fn new_on(
        comm: &dyn Communicator,
        kind: FmmKernel,
        sources: &[[f64; 3]],
        normals: Option<&[[f64; 3]]>,
        targets: &[[f64; 3]],
        order: usize,
        leaf_size: usize,
    ) -> Result<Self, FmmError> {
        let start = Instant::now();
        let near = kind.near();
        let local = if !(2..=20).contains(&order) {
            Err(format!("FMM order must be between 2 and 20, got {order}"))
        } else if leaf_size == 0 {
            Err("FMM leaf size must be at least 1 point, got 0".to_string())
        } else if near.needs_normals() && normals.map(|n| n.len()) != Some(sources.len()) {
            Err(format!("{} needs one normal per source", near.name()))
        } else {
            Ok(())
        };
        if comm.size() == 1 {
            local.clone().map_err(FmmError::Shape)?;
        }
        comm.agree(local)?;
        let min_width = match kind {
            FmmKernel::Rpy { radius } => rpy_min_box_width(radius, order),
            _ => 0.0,
        };
        let input = TreeInput {
            sources,
            normals: if near.needs_normals() { normals } else { None },
            targets,
            leaf_size,
            min_width,
            direct_sources: CubeSurface::new(order).len(),
        };
        // Operators on a helper thread while this one (which owns the communicator) builds
        // the tree.
        let (tree, ops) = std::thread::scope(|s| {
            let ops = s.spawn(|| operators_for(kind, order));
            let tree = DistTree::build(comm, &input);
            (tree, ops.join())
        });
        let ops = ops.map_err(|_| poisoned())?;
        let (tree, (ops, m2l)) = (tree?, ops?);
        let identity: Vec<usize> = (0..tree.sources.len()).collect();
        let block = SourceBlock::new(&tree.sources, tree.normals.as_deref(), &identity);
        let near_list = NearList::build(&tree, ops.surf.len());
        let near_field = Box::new(cpu_near_field(
            kind,
            &tree,
            &near_list,
            calibration::near_tolerance(kind, order),
        ));
        Ok(Fmm {
            kind,
            near,
            far_source: kind.far_source(),
            far_target: kind.far_target(),
            tree,
            ops,
            m2l,
            sources: block,
            identity,
            order,
            setup_s: start.elapsed().as_secs_f64(),
            timings: FmmTimings::default(),
            comm: FmmComm::default(),
            near_list,
            near_field,
            m2l_dense_pairs: DENSE_PAIRS,
            m2l_buffer_bytes: M2L_BUFFER_BYTES,
            m2l_peak_bytes: Default::default(),
        })
    }

    /// The most bytes the M2L's chunked spectra of one level may take at once (default
    /// [`M2L_BUFFER_BYTES`]); a level that needs more runs in parts. The values do not depend
    /// on it beyond round-off.
    pub fn set_m2l_buffer_bytes(&mut self, bytes: usize) {
        self.m2l_buffer_bytes = bytes;
    }

    /// The largest footprint of the M2L's chunked spectra (one part of one level) in the last
    /// evaluation, in bytes.
    pub fn m2l_peak_bytes(&self) -> usize {
        self.m2l_peak_bytes
            .load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Run the M2L's products as 8 × 8 sibling blocks where a parent pair holds at least
    /// `dense_pairs` V-list pairs (the default, [`DENSE_PAIRS`]), or pair by pair everywhere
    /// with `usize::MAX` (the reference the blocks are tested and measured against).
    pub fn set_m2l_blocking(&mut self, dense_pairs: usize) {
        self.m2l_dense_pairs = dense_pairs.max(1);
    }

    /// The batched near field of this rank's leaves.
    pub fn near_list(&self) -> &NearList {
        &self.near_list
    }

    /// This rank's sorted sources and targets as the near field sees them (positions,
    /// orientations), for building a backend.
    pub fn near_points(&self) -> NearPoints<'_> {
        NearPoints {
            sources: &self.tree.sources,
            normals: self.tree.normals.as_deref(),
            targets: &self.tree.targets,
        }
    }

    /// Evaluate the near field with `backend` from now on (built for this FMM's
    /// [`Fmm::near_list`] and [`Fmm::near_points`]); the CPU backend is the default.
    pub fn set_near_field(&mut self, backend: Box<dyn NearField>) {
        self.near_field = backend;
    }

    /// Evaluate the near field on the CPU allowed a relative error up to `tol` per pair
    /// (`0`: exact to round-off), replacing any other backend. By default an FMM of `order`
    /// allows [`calibration::near_tolerance`]: a tenth of the accuracy the order is calibrated
    /// to, which lets the AVX2/AVX-512 loops refine `1/|r|` by one Newton step instead of two
    /// (AVX-512: Laplace up to 7 digits, Stokeslet up to 6; AVX2: both up to 5).
    pub fn set_cpu_near_tolerance(&mut self, tol: f64) {
        self.near_field = Box::new(cpu_near_field(
            self.kind,
            &self.tree,
            &self.near_list,
            tol.max(0.0),
        ));
    }

    /// What evaluates the near field (`"cpu"`, or the GPU and its precision).
    pub fn near_field_description(&self) -> String {
        self.near_field.describe()
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
            self.tree.source_route.n_caller(),
            self.tree.target_route.n_caller(),
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

    /// The exact sum by direct summation (same kernels, same layout as [`Fmm::evaluate`]);
    /// one rank only.
    pub fn direct(&mut self, density: &[f64], out: &mut [f64]) -> Result<(), FmmError> {
        self.check_sizes(density, out)?;
        let ds = self.near.density_dim();
        let dt = self.near.output_dim();
        let dens = self.tree.source_route.forward(&SerialComm, density, ds)?;
        self.sources.set_density(&dens, ds, &self.identity);
        let view = self.sources.all();
        let near = &self.near;
        let mut sorted = vec![0.0; out.len()];
        sorted
            .par_chunks_mut(64 * dt)
            .zip(self.tree.targets.par_chunks(64))
            .for_each(|(o, t)| near.eval_block(t, &view, o));
        self.tree
            .target_route
            .backward(&SerialComm, &sorted, dt, out)?;
        Ok(())
    }

    /// Evaluate the sum for `density` (`density_dim` values per source, input order) into `out`
    /// (`output_dim` values per target, input order), on one rank.
    pub fn evaluate(&mut self, density: &[f64], out: &mut [f64]) -> Result<(), FmmError> {
        self.evaluate_on(&SerialComm, density, out)
    }

    /// As [`Fmm::evaluate`] over the ranks the FMM was built on (collective): each rank passes
    /// its own sources' densities and gets its own targets' values, in its input order. Only
    /// densities, expansions and results move; the tree and exchange pattern are reused.
    pub fn evaluate_on(
        &mut self,
        comm: &dyn Communicator,
        density: &[f64],
        out: &mut [f64],
    ) -> Result<(), FmmError> {
        let ranks = self.tree.splitters.len() - 1;
        if comm.size() != ranks {
            return Err(FmmError::Shape(format!(
                "FMM built on {ranks} ranks, evaluated on {}",
                comm.size()
            )));
        }
        let local = self.check_sizes(density, out).map_err(|e| e.to_string());
        if ranks == 1 {
            local.clone().map_err(FmmError::Shape)?;
        }
        comm.agree(local)?;
        let t0 = Instant::now();
        let bytes0 = comm.bytes_sent();
        let ds = self.near.density_dim();
        let ne = self.ops.n_equiv();
        let mut comm_s = 0.0;
        let tc = Instant::now();
        let mut dens = self.tree.source_route.forward(comm, density, ds)?;
        comm_s += tc.elapsed().as_secs_f64();
        dens.resize(self.tree.sources.len() * ds, 0.0);
        self.sources.set_density(&dens, ds, &self.identity);
        let clock = PhaseClock::new();
        let mut up = vec![0.0; self.tree.boxes.len() * ne];
        self.upward(&mut up, Role::Owned, &clock);
        // This rank's partial expansions of the top boxes it shares (from its own points only:
        // the other ranks' boxes are still zero), summed by their owners in `share_upward`.
        self.upward(&mut up, Role::Top, &clock);
        let tc = Instant::now();
        self.share_upward(comm, &mut up, &mut dens)?;
        comm_s += tc.elapsed().as_secs_f64();
        let n_owned = self.tree.n_owned_sources;
        for c in 0..ds {
            for (i, v) in self.sources.q[c].iter_mut().enumerate().skip(n_owned) {
                *v = dens[i * ds + c];
            }
        }
        let dt = self.near.output_dim();
        let n_sorted = self.tree.targets.len() * dt;
        let far = |clock: &PhaseClock| {
            let t = Instant::now();
            let down = self.downward(&up, clock);
            let sorted = self.leaves(&up, &down, clock);
            (sorted, t.elapsed().as_secs_f64())
        };
        let near = |out: &mut [f64]| {
            let t = Instant::now();
            let r =
                self.near_field
                    .evaluate(&self.near_list, &self.sources, &self.tree.targets, out);
            r.map(|()| t.elapsed().as_secs_f64())
        };
        let concurrent = self.near_field.concurrent();
        let (sorted, far_wall, near_wall) = if concurrent {
            // The near field on its device while rayon does the far field here (MOBO's overlap).
            std::thread::scope(|s| {
                let gpu = s.spawn(|| {
                    let mut out = vec![0.0; n_sorted];
                    near(&mut out).map(|w| (out, w))
                });
                let (mut sorted, far_wall) = far(&clock);
                let (near_out, near_wall) = gpu
                    .join()
                    .map_err(|_| FmmError::Shape("the near-field thread panicked".into()))??;
                for (o, v) in sorted.iter_mut().zip(&near_out) {
                    *o += v;
                }
                Ok::<_, FmmError>((sorted, far_wall, near_wall))
            })?
        } else {
            let (mut sorted, far_wall) = far(&clock);
            let near_wall = near(&mut sorted)?;
            (sorted, far_wall, near_wall)
        };
        let tc = Instant::now();
        self.tree.target_route.backward(comm, &sorted, dt, out)?;
        comm_s += tc.elapsed().as_secs_f64();
        self.timings = FmmTimings {
            p2m: clock.get(0),
            m2m: clock.get(1),
            m2l_fft: clock.get(2),
            m2l_hadamard: clock.get(3),
            p2l: clock.get(4),
            l2l: clock.get(5),
            l2p: clock.get(6),
            m2p: clock.get(7),
            p2p: near_wall,
            near_concurrent: concurrent,
            far_wall,
            total: t0.elapsed().as_secs_f64(),
        };
        let tree = &self.tree;
        let top_bytes = |links: [&[GhostLink]; 2]| -> u64 {
            let boxes: usize = links
                .iter()
                .flat_map(|l| l.iter())
                .map(|l| l.boxes.len())
                .sum();
            8 * (ne * boxes) as u64
        };
        let top_sent = top_bytes([&tree.top_partials_out, &tree.top_out]);
        let bytes_sent = comm.bytes_sent() - bytes0;
        self.comm = FmmComm {
            ranks,
            bytes_sent,
            let_bytes_sent: bytes_sent.saturating_sub(top_sent),
            top_bytes_received: top_bytes([&tree.top_partials_in, &tree.top_in]),
            seconds: comm_s,
        };
        Ok(())
    }

    /// After the upward pass over this rank's own boxes and its partial top boxes: the top
    /// boxes' partial expansions to their owners, who sum them; the ghost boxes' expansions and
    /// leaf densities to the neighbours that need them (into `up` and the ghost part of
    /// `dens`); the owned top boxes' whole expansions to the ranks whose lists use them.
    fn share_upward(
        &self,
        comm: &dyn Communicator,
        up: &mut [f64],
        dens: &mut [f64],
    ) -> Result<(), FmmError> {
        let ne = self.ops.n_equiv();
        let ds = self.near.density_dim();
        let tree = &self.tree;
        let got = exchange_links(
            comm,
            &tree.top_partials_out,
            &tree.top_partials_in,
            up,
            dens,
            ne,
            ds,
        )?;
        for (l, buf) in tree.top_partials_in.iter().zip(&got) {
            for (&bx, v) in l.boxes.iter().zip(buf.chunks_exact(ne)) {
                for (u, x) in up[bx * ne..(bx + 1) * ne].iter_mut().zip(v) {
                    *u += x;
                }
            }
        }
        for (out, inn) in [
            (&tree.ghosts_out, &tree.ghosts_in),
            (&tree.top_out, &tree.top_in),
        ] {
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
    fn upward(&self, up: &mut [f64], role: Role, clock: &PhaseClock) {
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
    fn downward(&self, up: &[f64], clock: &PhaseClock) -> Vec<f64> {
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

    /// M2L into the check potentials of the target boxes `sel` (one level), in parts whose
    /// chunked spectra fit [`Fmm::set_m2l_buffer_bytes`] ([`Fmm::m2l_parts`]).
    fn m2l_level(
        &self,
        sel: &[usize],
        up: &[f64],
        check: &mut [f64],
        buffers: &mut M2lBuffers,
        clock: &PhaseClock,
    ) {
        let nc = self.ops.n_check();
        let t = Instant::now();
        let parts = self.m2l_parts(sel);
        clock.add(2, t);
        for (range, plan) in parts {
            let rows = &mut check[range.start * nc..range.end * nc];
            self.m2l_part(&plan, up, rows, buffers, clock);
        }
    }

    /// Bytes of the chunked spectra a plan needs (its source and target slots).
    fn m2l_bytes(&self, plan: &M2lPlan) -> usize {
        let de = self.ops.degrees.len();
        let dt = self.near.output_dim();
        let slots = plan.n_source_slots * FftM2l::chunk_len(de)
            + plan.n_target_slots * FftM2l::chunk_len(dt);
        slots * self.m2l.n_chunks * std::mem::size_of::<f64>()
    }

    /// `sel` split into consecutive parts, each with its plan, whose chunked spectra fit the
    /// budget: halves, split at the nearest change of parent after the middle (so a sibling
    /// group stays in one part and its blocks are those of the whole level), until each part
    /// fits or holds one sibling group.
    fn m2l_parts(&self, sel: &[usize]) -> Vec<(std::ops::Range<usize>, M2lPlan)> {
        let parent = |i: usize| self.tree.boxes[sel[i]].parent;
        let mut parts = Vec::new();
        let mut todo = Vec::new();
        todo.push(0..sel.len());
        while let Some(r) = todo.pop() {
            let plan = M2lPlan::new(&self.tree, &self.m2l, &sel[r.clone()], self.m2l_dense_pairs);
            let mut mid = r.start + r.len() / 2;
            while mid < r.end && mid > r.start && parent(mid) == parent(mid - 1) {
                mid += 1;
            }
            // One sibling group (or one box) is not split further.
            if self.m2l_bytes(&plan) <= self.m2l_buffer_bytes || mid == r.end || mid == r.start {
                parts.push((r, plan));
                continue;
            }
            // The first half is taken next, so the parts come in order.
            todo.push(mid..r.end);
            todo.push(r.start..mid);
        }
        parts
    }

    /// The M2L of one part of a level (`check`: its target boxes' rows): spectra of the V-list
    /// sources, blocked Hadamard products per frequency chunk (8 × 8 sibling blocks in uniform
    /// regions, pairs elsewhere: [`M2lPlan`]), one inverse FFT per target box.
    fn m2l_part(
        &self,
        plan: &M2lPlan,
        up: &[f64],
        check: &mut [f64],
        buffers: &mut M2lBuffers,
        clock: &PhaseClock,
    ) {
        let ne = self.ops.n_equiv();
        let de = self.ops.degrees.len();
        let dt = self.near.output_dim();
        let nc = self.ops.n_check();
        let nf2 = self.m2l.spectrum_len(1);
        let mut t = Instant::now();
        if plan.blocks.is_empty() && plan.pairs.is_empty() {
            return;
        }
        self.m2l_peak_bytes
            .fetch_max(self.m2l_bytes(plan), std::sync::atomic::Ordering::Relaxed);
        let (nss, nts) = (plan.n_source_slots, plan.n_target_slots);
        let (sl, tl) = (FftM2l::chunk_len(de), FftM2l::chunk_len(dt));
        let nch = self.m2l.n_chunks;
        // The chunked spectra of sources and targets (zeros where a slot has no box).
        let src = zeroed(&mut buffers.src, nch * nss * sl);
        let tgt = zeroed(&mut buffers.tgt, nch * nts * tl);
        // Spectra of the sources, a batch at a time, scattered into their slots.
        const BATCH: usize = 256;
        let mut batch = vec![0.0; BATCH.min(plan.sources.len()) * de * nf2];
        for part in plan.sources.chunks(BATCH) {
            batch[..part.len() * de * nf2]
                .par_chunks_mut(de * nf2)
                .zip(part)
                .for_each_init(
                    || self.m2l.scratch(),
                    |s, (dst, &(_, bx))| self.m2l.spectrum(&up[bx * ne..(bx + 1) * ne], dst, s),
                );
            let slots: Vec<u32> = part.iter().map(|&(slot, _)| slot).collect();
            self.m2l.to_chunks(&batch, &slots, de, nss, src);
        }
        t = clock.add(2, t);
        // The kernel offsets this level uses, expanded per chunk from their base offsets.
        let mut used = vec![false; self.m2l.n_offsets()];
        let mut dps = [false; 27];
        for b in &plan.blocks {
            dps[b.dp as usize] = true;
        }
        for (dp, _) in dps.iter().enumerate().filter(|(_, &u)| u) {
            self.m2l.mark_siblings(dp, &mut used);
        }
        for &(_, _, o) in &plan.pairs {
            used[o as usize] = true;
        }
        tgt.par_chunks_mut(nts * tl)
            .zip(src.par_chunks(nss * sl))
            .enumerate()
            .for_each_init(
                || vec![0.0; self.m2l.kernel_chunk_len()],
                |kernels, (c, (tc, sc))| {
                    self.m2l.expand_chunk(c, &used, kernels);
                    let kernels = &kernels[..];
                    let tables: Vec<[&[f64]; 27]> = (0..27)
                        .map(|dp| {
                            if dps[dp] {
                                self.m2l.sibling_blocks(kernels, dp)
                            } else {
                                [&[][..]; 27]
                            }
                        })
                        .collect();
                    for b in &plan.blocks {
                        let (t0, s0) = (b.target as usize, b.source as usize);
                        self.m2l.accumulate_siblings(
                            &tables[b.dp as usize],
                            &sc[s0 * sl..(s0 + 8) * sl],
                            &mut tc[t0 * tl..(t0 + 8) * tl],
                        );
                    }
                    for &(ti, si, o) in &plan.pairs {
                        let (ti, si) = (ti as usize, si as usize);
                        self.m2l.accumulate_chunk(
                            kernels,
                            o as usize,
                            &sc[si * sl..(si + 1) * sl],
                            &mut tc[ti * tl..(ti + 1) * tl],
                        );
                    }
                },
            );
        t = clock.add(3, t);
        check.par_chunks_mut(nc).enumerate().for_each_init(
            || (self.m2l.scratch(), vec![0.0; self.m2l.spectrum_len(dt)]),
            |(s, sp), (i, col)| {
                if let Some(slot) = plan.target_slot[i] {
                    self.m2l.from_chunks(tgt, nts, slot as usize, dt, sp);
                    self.m2l.check_values(sp, col, s);
                }
            },
        );
        clock.add(2, t);
    }

    /// Leaves: L2P and M2P into this rank's targets' values in key order (the near field is
    /// a pass of its own, [`NearField`]).
    fn leaves(&self, up: &[f64], down: &[f64], clock: &PhaseClock) -> Vec<f64> {
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

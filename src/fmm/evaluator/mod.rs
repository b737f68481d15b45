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
use super::dist_tree::{DistTree, GhostLink, Role, TopStage, TreeInput};
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

mod m2l;
mod passes;
mod timings;

pub use m2l::M2L_BUFFER_BYTES;
pub use timings::{FmmComm, FmmTimings};

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
    /// Bytes this rank sent in [`Fmm::new_on`] (the cuts, the points to their owners, the
    /// LET's structure; 0 on one rank).
    pub setup_bytes_sent: u64,
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
        let bytes0 = comm.bytes_sent();
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
            setup_bytes_sent: comm.bytes_sent() - bytes0,
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
        let messages0 = comm.messages_sent();
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
        let top_bytes = |side: fn(&TopStage) -> &[GhostLink]| -> u64 {
            let boxes: usize = tree
                .top_reduce
                .iter()
                .chain(&tree.top_broadcast)
                .flat_map(side)
                .map(|l| l.boxes.len())
                .sum();
            8 * (ne * boxes) as u64
        };
        let top_sent = top_bytes(|s| &s.out);
        let bytes_sent = comm.bytes_sent() - bytes0;
        self.comm = FmmComm {
            ranks,
            bytes_sent,
            let_bytes_sent: bytes_sent.saturating_sub(top_sent),
            top_bytes_received: top_bytes(|s| &s.inn),
            messages_sent: comm.messages_sent() - messages0,
            seconds: comm_s,
        };
        Ok(())
    }
}

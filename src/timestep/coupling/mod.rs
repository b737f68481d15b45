//! Hydrodynamic coupling between cells: the velocity each cell's membrane traction (and, with a
//! viscosity contrast, its membrane velocity) induces on the grid points of every *other* cell.
//!
//! For cells `j` with traction `f_j` (order-`p` grid), the velocity at a point `x` of cell `i`
//! is `u_i(x) = Σ_{j≠i} S_j[f_j](x)`, `S_j[f](x) = (1/8πμ) ∫_{Γ_j} (I/r + r⊗r/r³) f dA`.
//! It is evaluated in three parts (Rahimian et al., SC'10 (MOBO), §3; Veerapaneni et al.,
//! J. Comput. Phys. 230 (2011) §4):
//!
//! 1. **All pairs by the FMM**: the smooth quadrature of every cell on its upsampled grid of
//!    order `q` (traction interpolated spectrally, weights `dA_k`), as Stokeslet point forces
//!    `f(y_k) dA_k / μ`, summed at the order-`p` grid points of all cells by [`Fmm`] (one tree
//!    over all points; for small scenes the tree is a single leaf and this is a direct sum).
//! 2. **Minus each cell's own smooth quadrature** at its own points (a direct sum per cell):
//!    a cell's self-interaction is singular and is handled implicitly by the time step.
//! 3. **Near-singular corrections**: a point closer than `δ_j = c_near R_j / √p` to another cell
//!    `j` (`R_j` its equivalent radius) gets, instead of cell `j`'s smooth quadrature, the
//!    near-singular value of [`OffSurface`] (check points along the normal, smooth quadrature at
//!    order `6p`, interpolation to the point). The default `c_near = 2` keeps
//!    the order-`q` quadrature accurate beyond `δ` (`δ/h_q = 4√p/π` grid spacings).
//!
//! **Viscosity contrast** ([`Coupling::velocities_with`]): a cell `j` with `λ_j ≠ 1` adds its
//! double layer `(1 − λ_j) D_j[u_j](x)`, `D[u](x) = (3/4π) ∫ (r·n)(r⊗r)/r⁵ u dA` (`n` outward;
//! the convention of [`LayerKernel::DoubleLayer`]: `D[c] = 0` outside, `−c` inside), to the
//! velocity at points `x` outside it, `u_j` its membrane velocity. The same three parts: one
//! stresslet FMM ([`FmmKernel::Stresslet`], density `(1 − λ_j) u_j dA` on the upsampled grid,
//! orientation the outward normal, sources only on the cells with a density, targets all grid
//! points), minus each such cell's own smooth sum, plus near-singular corrections
//! ([`OffSurface`] with [`LayerKernel::DoubleLayer`]) at the near points found for the single
//! layer, with more, closer check points (`DOUBLE_LAYER_NEAR`). Cells without a density add
//! nothing, and a call without any builds nothing more than the single-layer part (counter
//! [`CouplingStats::double_layer_fmm_builds`]). `u_j` is explicit: the suspension passes each
//! cell's velocity of its previous solve ([`super::cell_state::CellState::membrane_velocity`],
//! see [`super::suspension`]). Accuracy (tests/timestep_contrast.rs, `p = 8`, `q = 2p`, against
//! a direct quadrature of order 160): 9e-12 for separated cells; 2.1e-5 and 1.3e-5 at gaps 0.3
//! and 0.1, limited by the order-`q` quadrature just beyond `δ` (the `1/r²` kernel needs more
//! points there than the Stokeslet; 8.9e-6 at `q = 3p`); a rigid motion gives 6e-14 (separated)
//! and 2e-6 (gap 0.1) of its size.
//!
//! The distance of every near point to the other cell's surface is recorded: the smallest gap
//! is the minimum-distance monitor of the run. Points closer than `d_r` to another cell (or
//! inside it) feel a **contact repulsion** traction along that cell's outward normal,
//! `s (1 − d/d_r)²` (`s (1 − d/d_r)` for an overlap, `d < 0`), returned by
//! [`Coupling::repulsion`] and applied explicitly through the cell's own single layer; it is
//! off by default (`s = 0`) and switched on by the scene runner. This is a penalty, not a
//! contact solver (Lu, Rahimian & Zorin, J. Comput. Phys. 347 (2017) is the method that
//! guarantees no overlap); its range and strength are scene parameters.

use std::collections::HashMap;
use std::sync::Mutex;
use std::time::Instant;

use rayon::prelude::*;

use super::TimestepError;
use crate::comm::{CommError, Communicator, SerialComm};
use crate::fmm::blocks::SourceBlock;
use crate::fmm::gpu_near::{choose, gpu_expected, NearDecision, GPU_LEAF_FACTOR};
use crate::fmm::{order_for_digits, Fmm, FmmError, FmmKernel, Kernel, Stokeslet, Stresslet};
use crate::gpu::GpuChoice;
use crate::sph_harmonics::{ShTransform, ShWorkspace};
use crate::vesicle::layer::LayerKernel;
use crate::vesicle::membrane::Membrane;
use crate::vesicle::near::{NearParams, OffSurface};
use crate::vesicle::VesicleError;

mod fmm_sum;
mod ghosts;
mod near;

use fmm_sum::{fmm_sum, FmmTraffic};

/// Check points of the near-singular double layer: 16 spaced `0.07 δ` (the single layer keeps
/// [`NearParams::default`], 12 spaced `δ/10`). The double layer varies faster with the distance
/// to the surface; measured at `p = 8` on ellipsoids 0.1 apart (tests/timestep_contrast.rs),
/// the largest error of a near point fell from 1.9e-4 (12 spaced `δ/10`) to below the far-field
/// quadrature error (1.3e-5).
const DOUBLE_LAYER_NEAR: NearParams = NearParams {
    near_distance: None,
    check_points: 16,
    check_spacing: 0.07,
    far_order: None,
    self_order: None,
    max_order: None,
    smooth_ratio: None,
};

/// Settings of the inter-cell coupling.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CouplingParams {
    /// Fluid viscosity `μ`.
    pub viscosity: f64,
    /// FMM accuracy in digits (3…10).
    pub fmm_digits: u32,
    /// Near zone `δ = near_factor · R / √p`.
    pub near_factor: f64,
    /// Contact repulsion range as a fraction of the source cell's equivalent radius `R`
    /// (capped at the near zone `δ`); 0 switches the repulsion off.
    pub repulsion_range: f64,
    /// Contact repulsion strength `s` (a traction, force per area): a point at distance
    /// `d < d_r` from another cell feels `s (1 − d/d_r)²` along that cell's outward normal,
    /// and `s (1 + d/d_r)` when it is inside that cell (overlap).
    pub repulsion_strength: f64,
    /// Near field of the FMM on a GPU ([`crate::fmm::gpu_near::choose`]).
    pub gpu: GpuChoice,
}

impl Default for CouplingParams {
    fn default() -> Self {
        CouplingParams {
            viscosity: 1.0,
            fmm_digits: 6,
            near_factor: 2.0,
            repulsion_range: 0.05,
            repulsion_strength: 0.0,
            gpu: GpuChoice::Auto,
        }
    }
}

/// Counters and phase times of the coupling (cumulative over calls).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct CouplingStats {
    /// FMM trees built (one per evaluation: the points move every step).
    pub fmm_builds: usize,
    /// FMM trees built for the inter-cell double layer (cells with a viscosity contrast; none
    /// when every `λ = 1` or no cell has a recorded velocity yet).
    pub double_layer_fmm_builds: usize,
    /// Points that received a near-singular correction.
    pub near_points: usize,
    /// Ordered cell pairs `(target cell, source cell)` with near points.
    pub near_pairs: usize,
    /// Smallest distance of a point of one cell to another cell's surface at the last call
    /// (`∞` when no point is in another cell's near zone; negative: the point is inside the
    /// other cell, an overlap).
    pub min_gap: f64,
    /// Point–cell pairs that felt the contact repulsion (cumulative).
    pub repulsion_points: usize,
    /// Seconds in the quadrature setup (upsampled points, weights, near-zone lists).
    pub setup_s: f64,
    /// Seconds in the FMM (tree build and evaluation).
    pub fmm_s: f64,
    /// Seconds subtracting each cell's own smooth quadrature from the FMM result.
    pub self_s: f64,
    /// Seconds in the near-singular corrections and the contact repulsion.
    pub near_s: f64,
    /// Seconds exchanging ghost cells with other ranks (0 on one rank).
    pub exchange_s: f64,
    /// Ghost cells this rank received (cumulative; 0 on one rank).
    pub ghost_cells: usize,
    /// Bytes of ghost cells this rank sent (cumulative).
    pub ghost_bytes: u64,
    /// Bytes this rank sent in the FMM evaluations (cumulative).
    pub fmm_bytes: u64,
    /// Bytes this rank sent building the FMM trees (cuts, points to their owners, the LET's
    /// structure; cumulative).
    pub fmm_setup_bytes: u64,
    /// This rank's FMM points (sources and targets) that another rank owned (cumulative).
    pub fmm_points_moved: u64,
    /// Seconds building the FMM trees, their lists and exchange patterns (part of `fmm_s`).
    pub fmm_build_s: f64,
    /// Seconds of the FMM evaluations' communication (part of `fmm_s`).
    pub fmm_comm_s: f64,
    /// The FMM evaluations' phases (cumulative; part of `fmm_s`).
    pub fmm_phases: crate::fmm::FmmTimings,
}

impl CouplingStats {
    fn add_fmm_traffic(&mut self, t: FmmTraffic) {
        self.fmm_bytes += t.eval_bytes;
        self.fmm_setup_bytes += t.setup_bytes;
        self.fmm_points_moved += t.points_moved;
        self.fmm_build_s += t.build_s;
        self.fmm_comm_s += t.comm_s;
        self.fmm_phases.accumulate(&t.phases);
    }
}

/// A near-singular correction: target cell, its grid point, the velocity change, the distance
/// of the point to the source cell's surface.
type NearCorrection = (usize, usize, [f64; 3], f64);

/// A contact push: target cell (this rank's index), its grid point, source cell (global
/// index), traction.
type Push = (usize, usize, usize, [f64; 3]);

/// Per-thread engines.
struct Engine {
    membrane: Membrane,
    near: OffSurface,
    /// The near-singular evaluator of the double layer (built on first use, see
    /// `DOUBLE_LAYER_NEAR`).
    near_dl: Option<OffSurface>,
    sht: ShTransform,
    ws: ShWorkspace,
    fq: Vec<f64>,
    /// Upsampled double-layer density.
    fu: Vec<f64>,
    block: SourceBlock,
    /// Sources with orientations (the stresslet of the double layer).
    dl_block: SourceBlock,
}

/// A source cell of the near corrections (own or ghost).
struct SourceCell<'a> {
    id: usize,
    coefs: &'a [f64],
    traction: &'a [f64],
    dl: Option<&'a [f64]>,
    quad: &'a CellQuadrature,
}

/// Per source cell, the corrections at this rank's points; the contact pushes.
struct NearResult {
    corrections: Vec<Vec<NearCorrection>>,
    pushes: Vec<Push>,
}

/// One cell's quadrature: upsampled sources and order-`p` targets.
#[derive(Default)]
struct CellQuadrature {
    sources: Vec<[f64; 3]>,
    /// Outward normals at the sources.
    normals: Vec<[f64; 3]>,
    /// Equivalent radius.
    r_eq: f64,
    /// `f dA / μ`, interleaved (3 per source).
    density: Vec<f64>,
    /// `(1 − λ) u dA`, interleaved (empty: the cell has no double layer).
    dl_density: Vec<f64>,
    targets: Vec<[f64; 3]>,
    centroid: [f64; 3],
    /// Largest distance from the centroid to a grid point.
    radius: f64,
    /// Near-zone distance.
    delta: f64,
}

/// The inter-cell velocity evaluator for cells of order `p` with upsampled quadrature `q`.
pub struct Coupling {
    p: usize,
    params: CouplingParams,
    fmm_order: usize,
    engines: Vec<Mutex<Engine>>,
    cells: Vec<CellQuadrature>,
    /// Contact-repulsion tractions of the last call (per cell, order-`p` grid; empty when
    /// no point was within range).
    repulsion: Vec<Vec<f64>>,
    /// Cumulative counters.
    pub stats: CouplingStats,
    /// Where the last FMM's near field ran and why.
    pub near_field: Option<NearDecision>,
}

fn vesicle(e: VesicleError) -> TimestepError {
    e.into()
}

impl Coupling {
    /// Plan for cells of order `p`, far-field quadrature of order `q ≥ p`.
    pub fn new(p: usize, q: usize, params: CouplingParams) -> Result<Self, TimestepError> {
        if !(params.viscosity.is_finite() && params.viscosity > 0.0) {
            return Err(TimestepError::InvalidParameter {
                name: "viscosity",
                value: format!("{}", params.viscosity),
                reason: "must be positive and finite",
            });
        }
        if !(params.near_factor.is_finite() && params.near_factor > 0.0) {
            return Err(TimestepError::InvalidParameter {
                name: "near_factor",
                value: format!("{}", params.near_factor),
                reason: "must be positive and finite",
            });
        }
        let fmm_order = order_for_digits(FmmKernel::Stokeslet, params.fmm_digits).map_err(|e| {
            TimestepError::InvalidParameter {
                name: "fmm_digits",
                value: format!("{}", params.fmm_digits),
                reason: match e {
                    FmmError::Digits { .. } => "must be between 3 and 10",
                    _ => "no FMM order for it",
                },
            }
        })?;
        let threads = rayon::current_num_threads().max(1);
        let engines = (0..threads)
            .map(|_| -> Result<_, TimestepError> {
                let sht = ShTransform::new(p).map_err(VesicleError::from)?;
                Ok(Mutex::new(Engine {
                    membrane: Membrane::new(p, q)?,
                    near: OffSurface::new(p, NearParams::default())?,
                    near_dl: None,
                    ws: sht.workspace(),
                    sht,
                    fq: Vec::new(),
                    fu: Vec::new(),
                    block: SourceBlock::default(),
                    dl_block: SourceBlock::default(),
                }))
            })
            .collect::<Result<_, _>>()?;
        Ok(Coupling {
            p,
            params,
            fmm_order,
            engines,
            cells: Vec::new(),
            repulsion: Vec::new(),
            stats: CouplingStats {
                min_gap: f64::INFINITY,
                ..Default::default()
            },
            near_field: None,
        })
    }

    fn engine(&self) -> std::sync::MutexGuard<'_, Engine> {
        let i = rayon::current_thread_index().unwrap_or(0) % self.engines.len();
        self.engines[i].lock().expect("coupling engine lock")
    }

    /// The velocity induced on each cell by all the others. `coefs[i]` are cell `i`'s
    /// order-`p` coefficients, `tractions[i]` its traction on the order-`p` grid (`3n`,
    /// component-major); the result is component-major on each cell's order-`p` grid.
    /// Single layers only (every `λ = 1`): see [`Coupling::velocities_with`].
    pub fn velocities(
        &mut self,
        coefs: &[&[f64]],
        tractions: &[&[f64]],
    ) -> Result<Vec<Vec<f64>>, TimestepError> {
        self.velocities_with(coefs, tractions, &[])
    }

    /// [`Coupling::velocities`] plus the double layers of cells with a viscosity contrast:
    /// `double_layer[j]` is `(1 − λ_j) u_j` on cell `j`'s order-`p` grid (`3n`,
    /// component-major; `u_j` its membrane velocity), `None` for a cell without one (`λ_j = 1`
    /// or no velocity yet). An empty list, or one of `None` only, builds nothing beyond the
    /// single-layer part (same work and counters as [`Coupling::velocities`]).
    pub fn velocities_with(
        &mut self,
        coefs: &[&[f64]],
        tractions: &[&[f64]],
        double_layer: &[Option<&[f64]>],
    ) -> Result<Vec<Vec<f64>>, TimestepError> {
        let ids: Vec<usize> = (0..coefs.len()).collect();
        self.velocities_on(&SerialComm, &ids, coefs, tractions, double_layer)
    }

    /// [`Coupling::velocities_with`] over the ranks of `comm` (collective: every rank calls it,
    /// also one that holds no cell). Each rank passes the cells it holds, `ids[i]` the global
    /// index of its cell `i` (distinct over the ranks), and gets the velocity all cells of all
    /// ranks induce on its own. The far field is one distributed FMM ([`Fmm::new_on`]); the
    /// near-singular corrections and the contact repulsion at a rank's points are computed by
    /// that rank from **ghost copies** of the cells of other ranks that come near them (their
    /// coefficients, tractions and double-layer densities, sent only to the ranks whose cells'
    /// bounding box a cell's near zone reaches). Near pairs are found through a cell list
    /// (bins of the largest reach), not over all pairs. Corrections are summed in the order
    /// of the source cells' global indices, so a point's value does not depend on which rank
    /// holds which cell beyond the FMM's own round-off.
    pub fn velocities_on(
        &mut self,
        comm: &dyn Communicator,
        ids: &[usize],
        coefs: &[&[f64]],
        tractions: &[&[f64]],
        double_layer: &[Option<&[f64]>],
    ) -> Result<Vec<Vec<f64>>, TimestepError> {
        let nc = coefs.len();
        agreed(comm, check_inputs(ids, coefs, tractions, double_layer))?;
        let dl_of = |j: usize| double_layer.get(j).copied().flatten();
        let mut any_dl = [u64::from((0..nc).any(|j| dl_of(j).is_some()))];
        comm.all_sum_u64(&mut any_dl).map_err(TimestepError::Comm)?;
        let with_dl = any_dl[0] > 0;
        let t0 = Instant::now();
        // 1. Quadrature of every cell.
        let cells: Result<Vec<CellQuadrature>, TimestepError> = (0..nc)
            .into_par_iter()
            .map(|i| self.quadrature(coefs[i], tractions[i], dl_of(i)))
            .collect();
        self.cells = agreed(comm, cells)?;
        let t1 = Instant::now();
        self.stats.setup_s += (t1 - t0).as_secs_f64();
        // 2. All pairs by the FMM.
        let sources: Vec<[f64; 3]> = self
            .cells
            .iter()
            .flat_map(|c| c.sources.iter().copied())
            .collect();
        let density: Vec<f64> = self
            .cells
            .iter()
            .flat_map(|c| c.density.iter().copied())
            .collect();
        let targets: Vec<[f64; 3]> = self
            .cells
            .iter()
            .flat_map(|c| c.targets.iter().copied())
            .collect();
        let (u_all, traffic) = fmm_sum(
            comm,
            FmmKernel::Stokeslet,
            (&sources, None, &targets),
            &density,
            self.fmm_order,
            (self.params.gpu, self.params.fmm_digits),
            &mut self.near_field,
        )?;
        self.stats.fmm_builds += 1;
        self.stats.add_fmm_traffic(traffic);
        // 2b. The double layers of the cells that have one: one stresslet FMM, sources only on
        //     those cells, the same targets.
        let dl_all = if with_dl {
            let dl_cells = || self.cells.iter().filter(|c| !c.dl_density.is_empty());
            let sources: Vec<[f64; 3]> =
                dl_cells().flat_map(|c| c.sources.iter().copied()).collect();
            let normals: Vec<[f64; 3]> =
                dl_cells().flat_map(|c| c.normals.iter().copied()).collect();
            let density: Vec<f64> = dl_cells()
                .flat_map(|c| c.dl_density.iter().copied())
                .collect();
            let (u, traffic) = fmm_sum(
                comm,
                FmmKernel::Stresslet,
                (&sources, Some(&normals), &targets),
                &density,
                self.fmm_order,
                (self.params.gpu, self.params.fmm_digits),
                &mut self.near_field,
            )?;
            self.stats.double_layer_fmm_builds += 1;
            self.stats.add_fmm_traffic(traffic);
            u
        } else {
            Vec::new()
        };
        let t2 = Instant::now();
        self.stats.fmm_s += (t2 - t1).as_secs_f64();
        // 3. Minus each cell's own smooth quadrature; to component-major per cell.
        let mut out: Vec<Vec<f64>> = (0..nc)
            .into_par_iter()
            .map(|i| self.minus_own(i, &u_all, &dl_all))
            .collect();
        let t3 = Instant::now();
        self.stats.self_s += (t3 - t2).as_secs_f64();
        // 4. Ghost copies of the other ranks' cells whose near zones reach this rank's cells.
        let ghosts = agreed(
            comm,
            self.exchange_ghosts(comm, ids, coefs, tractions, double_layer),
        )?;
        let t4 = Instant::now();
        self.stats.exchange_s += (t4 - t3).as_secs_f64();
        // 5. Near-singular corrections and contact pushes at this rank's points, from every
        //    source cell (own or ghost) in the order of the global indices.
        let mut sources: Vec<SourceCell<'_>> = (0..nc)
            .map(|j| SourceCell {
                id: ids[j],
                coefs: coefs[j],
                traction: tractions[j],
                dl: dl_of(j),
                quad: &self.cells[j],
            })
            .chain(ghosts.iter().map(|g| SourceCell {
                id: g.id,
                coefs: &g.coefs,
                traction: &g.traction,
                dl: g.dl.as_deref(),
                quad: &g.quad,
            }))
            .collect();
        sources.sort_by_key(|s| s.id);
        let near = agreed(comm, self.near_corrections(ids, &sources))?;
        drop(sources);
        self.apply_near(comm, ids, near, &mut out)?;
        // A rank without pushes returns no repulsion; every rank agrees on whether any exists
        // only where it matters (its own cells).
        self.stats.near_s += t4.elapsed().as_secs_f64();
        Ok(out)
    }

    /// The near zone's results applied (collective): each near-singular correction added to
    /// the velocity `out` of this rank's cells (component-major per cell), the contact pushes
    /// kept as the repulsion tractions ([`Coupling::repulsion`]), and the statistics (near
    /// points and pairs, pushes, the smallest gap) reduced over the ranks.
    fn apply_near(
        &mut self,
        comm: &dyn Communicator,
        ids: &[usize],
        near: NearResult,
        out: &mut [Vec<f64>],
    ) -> Result<(), TimestepError> {
        let (nc, np) = (out.len(), self.n_grid());
        let mut min_gap = [f64::INFINITY];
        let mut counts = [0u64; 3];
        for list in &near.corrections {
            let mut pairs = std::collections::BTreeSet::new();
            for &(i, k, du, d) in list {
                for c in 0..3 {
                    out[i][c * np + k] += du[c];
                }
                min_gap[0] = min_gap[0].min(d);
                pairs.insert(i);
                counts[0] += 1;
            }
            counts[1] += pairs.len() as u64;
        }
        let mut rep = near.pushes;
        rep.sort_by_key(|a| (ids[a.0], a.1, a.2));
        counts[2] = rep.len() as u64;
        comm.all_min(&mut min_gap).map_err(TimestepError::Comm)?;
        comm.all_sum_u64(&mut counts).map_err(TimestepError::Comm)?;
        self.stats.near_points += counts[0] as usize;
        self.stats.near_pairs += counts[1] as usize;
        self.stats.repulsion_points += counts[2] as usize;
        self.stats.min_gap = min_gap[0];
        self.repulsion = if rep.is_empty() {
            Vec::new()
        } else {
            let mut r = vec![vec![0.0; 3 * np]; nc];
            for &(i, k, _, f) in &rep {
                for c in 0..3 {
                    r[i][c * np + k] += f[c];
                }
            }
            r
        };
        Ok(())
    }

    /// Grid points per cell (order `p`).
    fn n_grid(&self) -> usize {
        2 * self.p * (self.p + 1)
    }

    /// One cell's quadrature: upsampled sources and densities, order-`p` targets.
    fn quadrature(
        &self,
        coefs: &[f64],
        traction: &[f64],
        dl: Option<&[f64]>,
    ) -> Result<CellQuadrature, TimestepError> {
        let (mu, p, near_factor) = (self.params.viscosity, self.p, self.params.near_factor);
        let mut guard = self.engine();
        let e = &mut *guard;
        e.membrane.set_geometry(coefs).map_err(vesicle)?;
        let nq = e.membrane.n_points_upsampled();
        e.fq.resize(3 * nq, 0.0);
        e.membrane.upsample(traction, &mut e.fq).map_err(vesicle)?;
        if let Some(d) = dl {
            e.fu.resize(3 * nq, 0.0);
            e.membrane.upsample(d, &mut e.fu).map_err(vesicle)?;
        }
        let g = e.membrane.geometry().map_err(vesicle)?;
        let centroid = g.centroid();
        let radius = g.x.iter().map(|x| dist(*x, centroid)).fold(0.0, f64::max);
        let delta = near_factor * g.equivalent_radius() / (p as f64).sqrt();
        let density = weighted_interleaved(&e.fq, &g.da, mu);
        let dl_density = if dl.is_some() {
            weighted_interleaved(&e.fu, &g.da, 1.0)
        } else {
            Vec::new()
        };
        let sources = g.x.clone();
        let normals = g.normal.clone();
        let r_eq = g.equivalent_radius();
        let np = e.sht.n_points();
        let mut xg = vec![0.0; 3 * np];
        e.sht
            .inverse(coefs, &mut xg, &mut e.ws)
            .map_err(VesicleError::from)?;
        // Grid points that coincide with quadrature points up to round-off (the equator and
        // shared meridians when the orders allow) are snapped onto them, so that the kernel's
        // `r = 0` rule drops the pair exactly, in the FMM and in the subtraction alike (a pair
        // at `r ~ 1e-16` would add `~1e16` to both).
        let tol2 = (1e-9 * radius).powi(2);
        let targets = (0..np)
            .map(|k| {
                let x = [xg[k], xg[np + k], xg[2 * np + k]];
                g.x.iter()
                    .find(|y| dist2(x, **y) < tol2)
                    .copied()
                    .unwrap_or(x)
            })
            .collect();
        Ok(CellQuadrature {
            sources,
            normals,
            r_eq,
            density,
            dl_density,
            targets,
            centroid,
            radius,
            delta,
        })
    }

    /// The FMM's values at cell `i`'s points minus the cell's own smooth quadrature,
    /// component-major.
    fn minus_own(&self, i: usize, u_all: &[f64], dl_all: &[f64]) -> Vec<f64> {
        let c = &self.cells[i];
        let np = c.targets.len();
        let mut own = vec![0.0; 3 * np];
        {
            let mut guard = self.engine();
            let e = &mut *guard;
            e.block.set_points(&c.sources, &c.density, 3);
            Stokeslet.eval_block(&c.targets, &e.block.all(), &mut own);
        }
        let base = 3 * i * np;
        let mut u = vec![0.0; 3 * np];
        for k in 0..np {
            for d in 0..3 {
                u[d * np + k] = u_all[base + 3 * k + d] - own[3 * k + d];
            }
        }
        if !dl_all.is_empty() {
            let mut own = vec![0.0; 3 * np];
            if !c.dl_density.is_empty() {
                let mut guard = self.engine();
                let e = &mut *guard;
                set_oriented(&mut e.dl_block, &c.sources, &c.normals, &c.dl_density);
                Stresslet.eval_block(&c.targets, &e.dl_block.all(), &mut own);
            }
            for k in 0..np {
                for d in 0..3 {
                    u[d * np + k] += dl_all[base + 3 * k + d] - own[3 * k + d];
                }
            }
        }
        u
    }
}

impl Coupling {
    /// The contact-repulsion traction on each cell from the last [`Coupling::velocities`]
    /// (order-`p` grid, component-major); `None` when no point was within range.
    pub fn repulsion(&self) -> Option<&[Vec<f64>]> {
        (!self.repulsion.is_empty()).then_some(self.repulsion.as_slice())
    }
}

/// Checks of [`Coupling::velocities_on`]'s arguments (one rank's).
fn check_inputs(
    ids: &[usize],
    coefs: &[&[f64]],
    tractions: &[&[f64]],
    double_layer: &[Option<&[f64]>],
) -> Result<(), TimestepError> {
    let nc = coefs.len();
    for (what, got) in [
        ("tractions (one per cell)", tractions.len()),
        ("cell indices (one per cell)", ids.len()),
    ] {
        if got != nc {
            return Err(TimestepError::DimensionMismatch {
                what,
                expected: nc,
                got,
            });
        }
    }
    if !double_layer.is_empty() && double_layer.len() != nc {
        return Err(TimestepError::DimensionMismatch {
            what: "double-layer densities (one per cell, or none)",
            expected: nc,
            got: double_layer.len(),
        });
    }
    for (j, t) in tractions.iter().enumerate() {
        if let Some(Some(d)) = double_layer.get(j) {
            if d.len() != t.len() {
                return Err(TimestepError::DimensionMismatch {
                    what: "double-layer density",
                    expected: t.len(),
                    got: d.len(),
                });
            }
            if !d.iter().all(|v| v.is_finite()) {
                return Err(TimestepError::NonFinite {
                    what: "double-layer density",
                });
            }
        }
    }
    Ok(())
}

/// [`crate::comm::agreed`] with communication failures as [`TimestepError::Comm`].
fn agreed<T>(comm: &dyn Communicator, local: Result<T, TimestepError>) -> Result<T, TimestepError> {
    crate::comm::agreed(comm, local, TimestepError::Comm)
}

/// `f dA / divisor` at each upsampled point, interleaved (3 per point), from the
/// component-major `f`.
fn weighted_interleaved(f: &[f64], da: &[f64], divisor: f64) -> Vec<f64> {
    let nq = da.len();
    let mut out = Vec::with_capacity(3 * nq);
    for (k, w) in da.iter().enumerate() {
        for c in 0..3 {
            out.push(f[c * nq + k] * w / divisor);
        }
    }
    out
}

/// Sources `p` with orientations `normals` and interleaved 3-vector densities `dens`.
fn set_oriented(b: &mut SourceBlock, p: &[[f64; 3]], normals: &[[f64; 3]], dens: &[f64]) {
    b.set_points(p, dens, 3);
    for (k, comp) in b.n.iter_mut().enumerate() {
        comp.clear();
        comp.extend(normals.iter().map(|v| v[k]));
    }
}

fn dist2(a: [f64; 3], b: [f64; 3]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

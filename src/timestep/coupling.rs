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
//!    order `6p`, interpolation to the point). The default `c_near = 2` (design.md 3.3) keeps
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
//! cell's velocity of its previous solve ([`super::semi_implicit::VesicleStepper::velocity`],
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

use std::sync::Mutex;
use std::time::Instant;

use rayon::prelude::*;

use super::TimestepError;
use crate::fmm::blocks::SourceBlock;
use crate::fmm::{order_for_digits, Fmm, FmmError, FmmKernel, Kernel, Stokeslet, Stresslet};
use crate::sph_harmonics::{ShTransform, ShWorkspace};
use crate::vesicle::layer::LayerKernel;
use crate::vesicle::membrane::Membrane;
use crate::vesicle::near::{NearParams, OffSurface};
use crate::vesicle::VesicleError;

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
}

impl Default for CouplingParams {
    fn default() -> Self {
        CouplingParams {
            viscosity: 1.0,
            fmm_digits: 6,
            near_factor: 2.0,
            repulsion_range: 0.05,
            repulsion_strength: 0.0,
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
    /// Seconds: quadrature setup, FMM (build + evaluation), self subtraction, near corrections.
    pub setup_s: f64,
    pub fmm_s: f64,
    pub self_s: f64,
    pub near_s: f64,
}

/// A near-singular correction: target cell, its grid point, the velocity change, the distance
/// of the point to the source cell's surface.
type NearCorrection = (usize, usize, [f64; 3], f64);

/// A contact push: target cell, its grid point, source cell, traction.
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
        let nc = coefs.len();
        if tractions.len() != nc {
            return Err(TimestepError::DimensionMismatch {
                what: "tractions (one per cell)",
                expected: nc,
                got: tractions.len(),
            });
        }
        if !double_layer.is_empty() && double_layer.len() != nc {
            return Err(TimestepError::DimensionMismatch {
                what: "double-layer densities (one per cell, or none)",
                expected: nc,
                got: double_layer.len(),
            });
        }
        let dl_of = |j: usize| double_layer.get(j).copied().flatten();
        for (j, t) in tractions.iter().enumerate() {
            if let Some(d) = dl_of(j) {
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
        let with_dl = (0..nc).any(|j| dl_of(j).is_some());
        let t0 = Instant::now();
        let mu = self.params.viscosity;
        let (p, near_factor) = (self.p, self.params.near_factor);
        // 1. Quadrature of every cell.
        let cells: Vec<CellQuadrature> = (0..nc)
            .into_par_iter()
            .map(|i| -> Result<CellQuadrature, TimestepError> {
                let mut guard = self.engine();
                let e = &mut *guard;
                e.membrane.set_geometry(coefs[i]).map_err(vesicle)?;
                let nq = e.membrane.n_points_upsampled();
                e.fq.resize(3 * nq, 0.0);
                e.membrane
                    .upsample(tractions[i], &mut e.fq)
                    .map_err(vesicle)?;
                if let Some(d) = dl_of(i) {
                    e.fu.resize(3 * nq, 0.0);
                    e.membrane.upsample(d, &mut e.fu).map_err(vesicle)?;
                }
                let g = e.membrane.geometry().map_err(vesicle)?;
                let centroid = g.centroid();
                let radius = g.x.iter().map(|x| dist(*x, centroid)).fold(0.0, f64::max);
                let delta = near_factor * g.equivalent_radius() / (p as f64).sqrt();
                let density = weighted_interleaved(&e.fq, &g.da, mu);
                let dl_density = if dl_of(i).is_some() {
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
                    .inverse(coefs[i], &mut xg, &mut e.ws)
                    .map_err(VesicleError::from)?;
                // Grid points that coincide with quadrature points up to round-off (the equator
                // and shared meridians when the orders allow) are snapped onto them, so that
                // the kernel's `r = 0` rule drops the pair exactly, in the FMM and in the
                // subtraction alike (a pair at `r ~ 1e-16` would add `~1e16` to both).
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
            })
            .collect::<Result<_, _>>()?;
        self.cells = cells;
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
        let u_all = fmm_sum(
            FmmKernel::Stokeslet,
            &sources,
            None,
            &targets,
            &density,
            self.fmm_order,
        )?;
        self.stats.fmm_builds += 1;
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
            let u = fmm_sum(
                FmmKernel::Stresslet,
                &sources,
                Some(&normals),
                &targets,
                &density,
                self.fmm_order,
            )?;
            self.stats.double_layer_fmm_builds += 1;
            u
        } else {
            Vec::new()
        };
        let t2 = Instant::now();
        self.stats.fmm_s += (t2 - t1).as_secs_f64();
        // 3. Minus each cell's own smooth quadrature; to component-major per cell.
        let np = self.cells.first().map_or(0, |c| c.targets.len());
        let mut out: Vec<Vec<f64>> = (0..nc)
            .into_par_iter()
            .map(|i| {
                let c = &self.cells[i];
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
            })
            .collect();
        let t3 = Instant::now();
        self.stats.self_s += (t3 - t2).as_secs_f64();
        // 4. Near-singular corrections: for each source cell j, the points of other cells in
        //    its near zone.
        // (target cell, point, source cell, traction), sorted before summing: deterministic.
        let repulsion: Mutex<Vec<Push>> = Mutex::new(Vec::new());
        let corrections: Vec<Vec<NearCorrection>> = (0..nc)
            .into_par_iter()
            .map(|j| -> Result<_, TimestepError> {
                let cj = &self.cells[j];
                let reach = cj.radius + cj.delta;
                let mut cand: Vec<(usize, usize)> = Vec::new();
                for (i, ci) in self.cells.iter().enumerate() {
                    if i == j || dist(ci.centroid, cj.centroid) > ci.radius + reach {
                        continue;
                    }
                    for (k, &x) in ci.targets.iter().enumerate() {
                        if dist(x, cj.centroid) <= reach {
                            cand.push((i, k));
                        }
                    }
                }
                if cand.is_empty() {
                    return Ok(Vec::new());
                }
                let mut guard = self.engine();
                let e = &mut *guard;
                e.near.set_surface(coefs[j]).map_err(vesicle)?;
                let mut near: Vec<(usize, usize, f64)> = Vec::new();
                let mut push: Vec<Push> = Vec::new();
                let (range, strength) = (
                    (self.params.repulsion_range * cj.r_eq).min(cj.delta),
                    self.params.repulsion_strength,
                );
                for &(i, k) in &cand {
                    let x = self.cells[i].targets[k];
                    let info = e.near.classify(x).map_err(vesicle)?;
                    let signed = if info.inside {
                        -info.distance
                    } else {
                        info.distance
                    };
                    if info.distance < cj.delta || info.inside {
                        near.push((i, k, signed));
                    }
                    if strength > 0.0 && signed < range {
                        // Along the outward normal of cell j at its nearest quadrature point.
                        let (kn, _) = cj.sources.iter().enumerate().fold(
                            (0, f64::INFINITY),
                            |(kb, db), (kk, y)| {
                                let d = dist2(x, *y);
                                if d < db {
                                    (kk, d)
                                } else {
                                    (kb, db)
                                }
                            },
                        );
                        let mag = if signed >= 0.0 {
                            strength * (1.0 - signed / range).powi(2)
                        } else {
                            strength * (1.0 - signed / range)
                        };
                        push.push((i, k, j, cj.normals[kn].map(|v| v * mag)));
                    }
                }
                if !push.is_empty() {
                    let mut rep = repulsion.lock().expect("repulsion lock");
                    rep.extend(push);
                }
                if near.is_empty() {
                    return Ok(Vec::new());
                }
                let pts: Vec<[f64; 3]> = near
                    .iter()
                    .map(|&(i, k, _)| self.cells[i].targets[k])
                    .collect();
                let mut u_near = vec![0.0; 3 * pts.len()];
                e.near
                    .evaluate(
                        LayerKernel::SingleLayer { viscosity: mu },
                        tractions[j],
                        &pts,
                        &mut u_near,
                    )
                    .map_err(vesicle)?;
                let mut smooth = vec![0.0; 3 * pts.len()];
                e.block.set_points(&cj.sources, &cj.density, 3);
                Stokeslet.eval_block(&pts, &e.block.all(), &mut smooth);
                let m = pts.len();
                if let Some(dl) = dl_of(j) {
                    // The double layer of cell j: near-singular value minus the smooth sum the
                    // FMM counted, at the same points.
                    let mut d_near = vec![0.0; 3 * m];
                    let near_dl = match &mut e.near_dl {
                        Some(o) => o,
                        None => e
                            .near_dl
                            .insert(OffSurface::new(p, DOUBLE_LAYER_NEAR).map_err(vesicle)?),
                    };
                    near_dl.set_surface(coefs[j]).map_err(vesicle)?;
                    near_dl
                        .evaluate(LayerKernel::DoubleLayer, dl, &pts, &mut d_near)
                        .map_err(vesicle)?;
                    let mut d_smooth = vec![0.0; 3 * m];
                    set_oriented(&mut e.dl_block, &cj.sources, &cj.normals, &cj.dl_density);
                    Stresslet.eval_block(&pts, &e.dl_block.all(), &mut d_smooth);
                    for t in 0..m {
                        for c in 0..3 {
                            u_near[c * m + t] += d_near[c * m + t];
                            smooth[3 * t + c] += d_smooth[3 * t + c];
                        }
                    }
                }
                Ok(near
                    .iter()
                    .enumerate()
                    .map(|(t, &(i, k, d))| {
                        let du = std::array::from_fn(|c| u_near[c * m + t] - smooth[3 * t + c]);
                        (i, k, du, d)
                    })
                    .collect())
            })
            .collect::<Result<_, _>>()?;
        let mut min_gap = f64::INFINITY;
        for list in &corrections {
            let mut pairs = std::collections::BTreeSet::new();
            for &(i, k, du, d) in list {
                for c in 0..3 {
                    out[i][c * np + k] += du[c];
                }
                min_gap = min_gap.min(d);
                pairs.insert(i);
                self.stats.near_points += 1;
            }
            self.stats.near_pairs += pairs.len();
        }
        self.stats.min_gap = min_gap;
        let mut rep = repulsion.into_inner().expect("repulsion lock");
        rep.sort_by_key(|a| (a.0, a.1, a.2));
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
        self.stats.repulsion_points += rep.len();
        self.stats.near_s += t3.elapsed().as_secs_f64();
        Ok(out)
    }
}

impl Coupling {
    /// The contact-repulsion traction on each cell from the last [`Coupling::velocities`]
    /// (order-`p` grid, component-major); `None` when no point was within range.
    pub fn repulsion(&self) -> Option<&[Vec<f64>]> {
        (!self.repulsion.is_empty()).then_some(self.repulsion.as_slice())
    }
}

/// One FMM evaluation of `kind` (3-vector densities, interleaved) at `targets`.
fn fmm_sum(
    kind: FmmKernel,
    sources: &[[f64; 3]],
    normals: Option<&[[f64; 3]]>,
    targets: &[[f64; 3]],
    density: &[f64],
    order: usize,
) -> Result<Vec<f64>, TimestepError> {
    let fail = |e: crate::fmm::FmmError| TimestepError::Vesicle(format!("FMM ({kind:?}): {e}"));
    let mut fmm = Fmm::new(
        kind,
        sources,
        normals,
        targets,
        order,
        kind.default_leaf_size(order),
    )
    .map_err(fail)?;
    let mut u = vec![0.0; 3 * targets.len()];
    fmm.evaluate(density, &mut u).map_err(fail)?;
    Ok(u)
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

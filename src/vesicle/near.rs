//! Off-surface evaluation of a cell's layer potentials at arbitrary targets.
//!
//! * **Far** targets (distance to the surface at least the near-zone distance `δ`): the smooth
//!   quadrature on the upsampled grid of order `q_far` (default `6p`), `Σ_j K(x, y_j) f_j dA_j`
//!   with the density upsampled (exactly, it is band-limited at `p`).
//! * **Near** targets (distance `d < δ`): the closest surface point `X* = X(θ*, φ*)` by Newton's
//!   method on `½|X(θ, φ) − x|²` (started from the nearest upsampled grid point); the potential
//!   is sampled at `m` check points `X* + s (δ + k h) n*` (`k = 0..m−1`, `s = ±1` the side of the
//!   target, `h = δ · spacing`) by the smooth quadrature, and at the surface itself by the
//!   on-surface (Graham–Sloan) value interpolated spectrally to `(θ*, φ*)`, plus the jump of the
//!   double layer (`D_out = D_PV + u/2`, `D_in = D_PV − u/2` in the convention of [`super::layer`]);
//!   the Lagrange polynomial through these `m + 1` values in the normal distance is evaluated at
//!   `d` (Veerapaneni et al. 2011, §4; Ying, Biros & Zorin, J. Comput. Phys. 219, 2006).
//! * **Near targets the smooth rule can still resolve** (distance `d ≥ ¾ · 2π R_max / q` for a
//!   refined order `q = 2q_far, 4q_far, …, max_order`, default 256): the smooth
//!   quadrature at the smallest such `q` (its grid and the resampled density built on first use
//!   per surface and density). Its error falls like `exp(−c d/h)` in the distance over the
//!   spacing, while the check-point interpolation is limited by the interval it spans: on two
//!   RBCs at p = 8, 4 % apart, the check points gave 1.1e-2 relative error, the order-192
//!   quadrature 2e-7 (against a direct quadrature at order 256).
//! * Classification: far targets are inside when the solid-angle (Gauss) integral
//!   `(1/4π) ∫ (y − x)·n / |y − x|³ dA` exceeds ½ (taken only where the nearest grid point's
//!   normal does not already say outside); near targets by the side of the normal at `X*`.
//!   A caller evaluating several densities at the same targets on the same surface classifies
//!   once ([`OffSurface::evaluate_classified`]).
//! * Cost: a call first routes every target (far rule, refined rule, or check points), then
//!   sums each rule at all its points in one batch of cache-sized blocks with vectorised
//!   kernels ([`super::smooth_sources`]); a wall's order-6p rule has 10⁵ nodes, and summing it
//!   one target at a time was 5× slower (`cargo bench --bench off_surface`).
//!
//! Defaults: `δ = R_eq / √p` (a wider `~2R/√p`, which at `p = 16` would put inner
//! check points of a sphere beyond its centre), 12 check points spaced `δ/10` (the nodes span
//! `[0, 2.1δ]`), smooth quadrature at `q_far = 6p`. Measured at `p = 16`: on the unit sphere
//! (translating-sphere field, singular at the centre) errors ≤ 5e-8 at distances `0.2, 0.1, 0.01`
//! outside, ≤ 1e-8 inside (with 8 check points spaced `δ/4` the outer error was 7.5e-6: the
//! interpolation interval limits it); on the ellipsoid 1:0.8:0.6 (`S[n] = 0`, `D[c]`) 2.7e-8, where
//! `q_far = 4p` gave 9.3e-7 (the quadrature at the first check point limits it).
//!
//! Check points must stay inside the cell for inner targets: thin parts of a cell (the centre of
//! an RBC, 0.29 thick at unit equivalent radius) need a smaller `δ`, which the smooth quadrature
//! then has to resolve (raise `q_far`); this is not detected automatically.

use std::f64::consts::PI;

use super::geometry::{Geometry, SurfaceCalculus};
use super::layer::{LayerKernel, RotationAlgorithm, SelfInteraction};
use super::point::{closest_point, PointEval};
use super::smooth_layer::largest_cell_diagonal;
use super::smooth_sources::SmoothSources;
use super::{check_len, dot, VesicleError};
use crate::sph_harmonics::basis::{eval_basis, BasisScratch};
use crate::sph_harmonics::{resample_coefs, CoefLayout, Grid, ShTransform, ShWorkspace};

/// Parameters of the off-surface evaluation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NearParams {
    /// Near-zone distance `δ`; `None` gives `R_eq / √p`.
    pub near_distance: Option<f64>,
    /// Number of check points `m ≥ 1`.
    pub check_points: usize,
    /// Spacing of the check points as a fraction of `δ`.
    pub check_spacing: f64,
    /// Order of the smooth (far) quadrature; `None` gives `6p`.
    pub far_order: Option<usize>,
    /// Quadrature order of the on-surface (singular) values; `None` gives `2p`.
    pub self_order: Option<usize>,
    /// Largest order of the refined smooth quadratures for near targets (`q_far · 2^k` and this
    /// order, built on first use); `None` gives 256; below `2q_far`: none.
    pub max_order: Option<usize>,
    /// Smooth sums on the coarsest rule that resolves them, for a large surface (a wall) whose
    /// near zone `δ` spans several of the far rule's spacings `h`: with `Some(r)`, a near target
    /// at distance `d ≥ r h` takes a smooth rule directly instead of the check points, and such
    /// targets and far targets go to the coarsest of the orders `q_far/2, 2q_far/3, q_far` whose
    /// spacing `h q_far / q` is at most the target's distance over `r`. Check points stay on
    /// the far rule: the extrapolation amplifies their errors. `None` (the default): every
    /// smooth sum on the far rule, every near target to the check points (or a refined rule).
    pub smooth_ratio: Option<f64>,
}

impl NearParams {
    /// The defaults, as a constant (for constants built from them).
    pub const DEFAULT: NearParams = NearParams {
        near_distance: None,
        check_points: 12,
        check_spacing: 0.1,
        far_order: None,
        self_order: None,
        max_order: None,
        smooth_ratio: None,
    };
}

impl Default for NearParams {
    fn default() -> Self {
        NearParams::DEFAULT
    }
}

/// Where a target lies relative to the surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TargetInfo {
    /// Inside the closed surface.
    pub inside: bool,
    /// Within the near zone (distance below `δ`).
    pub near: bool,
    /// Distance to the surface (exact for near targets; for far targets the distance to the
    /// nearest upsampled grid point, an upper bound).
    pub distance: f64,
    /// Parameters `(θ*, φ*)` of the closest surface point (near targets; for far targets those
    /// of the nearest upsampled grid point).
    pub closest: (f64, f64),
}

/// Off-surface evaluator for one cell surface of order `p`.
pub struct OffSurface {
    p: usize,
    params: NearParams,
    lay_p: CoefLayout,
    sht_p: ShTransform,
    ws_p: ShWorkspace,
    sht_far: ShTransform,
    ws_far: ShWorkspace,
    calc_far: SurfaceCalculus,
    geom_far: Geometry,
    far_grid: Grid,
    /// The far rule's nodes and density as a block of sources (summed many targets at once).
    far_src: SmoothSources,
    self_layer: SelfInteraction,
    coefs: Vec<f64>,
    has_surface: bool,
    delta: f64,
    point: PointEval,
    basis: Vec<f64>,
    basis_scratch: BasisScratch,
    // Scratch for densities.
    dens_coef: Vec<f64>,
    dens_far_coef: Vec<f64>,
    dens_far: Vec<f64>,
    on_surface: Vec<f64>,
    on_surface_coef: Vec<f64>,
    /// Largest distance between neighbouring upsampled grid points (bound).
    spacing: f64,
    nodes: Vec<f64>,
    vals: Vec<[f64; 3]>,
    /// Refined smooth quadratures (orders `2q_far, 4q_far, …`), built when first needed.
    levels: Vec<Level>,
    /// Points summed on the far rule in one batch (far targets, check points) and the sums
    /// there (three per point).
    batch: Vec<[f64; 3]>,
    batch_vals: Vec<f64>,
    /// Near targets extrapolated from check points in the last call.
    checked: usize,
    /// Largest distance of the surface from its centroid.
    rmax: f64,
}

/// A refined smooth quadrature of order `q` for near targets.
struct Level {
    q: usize,
    sht: ShTransform,
    ws: ShWorkspace,
    calc: SurfaceCalculus,
    geom: Geometry,
    /// Whether `geom` is that of the current surface, and the density that of the last call.
    geometry_set: bool,
    density_set: bool,
    dens_coef: Vec<f64>,
    dens: Vec<f64>,
    /// The rule's nodes and the density as a block of sources.
    src: SmoothSources,
    /// Targets given this rule in the current call, and the sums there.
    batch: Vec<[f64; 3]>,
    batch_vals: Vec<f64>,
}

/// How [`OffSurface`] evaluates one target.
enum Route {
    /// A smooth rule's sum at one of its batch points.
    Smooth(Slot),
    /// Extrapolation from the on-surface value (given) and the `m` check points at the far
    /// rule's batch points from this index on.
    Check([f64; 3], usize),
}

/// A point of a smooth rule's batch: the rule (`None` the far rule, else the level with this
/// index) and the point's index in the rule's batch.
#[derive(Clone, Copy)]
struct Slot(Option<usize>, usize);

/// A near target at distance `d` is given the smooth quadrature of order `q` when
/// `d ≥ RESOLVED · 2π R_max / q` (measured on RBCs at a 4 % gap: relative error 1.8e-5 at 0.76
/// of that spacing bound with `q = 96`).
const RESOLVED: f64 = 0.8;

/// Default largest refined order (an order-256 transform holds about 70 MB of tables).
const DEFAULT_MAX_ORDER: usize = 256;

impl OffSurface {
    /// Evaluator for surfaces of order `p`.
    pub fn new(p: usize, params: NearParams) -> Result<Self, VesicleError> {
        let q_far = params.far_order.unwrap_or(6 * p);
        let q_self = params.self_order.unwrap_or(2 * p);
        if q_far < p {
            return Err(VesicleError::Order { p, q: q_far });
        }
        if params.check_points == 0 {
            return Err(VesicleError::Parameter {
                name: "check points",
                value: 0.0,
                reason: "at least one check point is needed",
            });
        }
        if !(params.check_spacing.is_finite() && params.check_spacing > 0.0) {
            return Err(VesicleError::Parameter {
                name: "check spacing",
                value: params.check_spacing,
                reason: "must be positive and finite",
            });
        }
        if let Some(r) = params.smooth_ratio {
            if !(r.is_finite() && r > 0.0) {
                return Err(VesicleError::Parameter {
                    name: "smooth ratio",
                    value: r,
                    reason: "must be positive and finite",
                });
            }
        }
        if let Some(d) = params.near_distance {
            if !(d.is_finite() && d > 0.0) {
                return Err(VesicleError::Parameter {
                    name: "near distance",
                    value: d,
                    reason: "must be positive and finite",
                });
            }
        }
        let sht_p = ShTransform::new(p)?;
        let sht_far = ShTransform::new(q_far)?;
        let (np, nq) = (sht_p.n_points(), sht_far.n_points());
        Ok(OffSurface {
            p,
            params,
            lay_p: CoefLayout::new(p),
            ws_p: sht_p.workspace(),
            ws_far: sht_far.workspace(),
            calc_far: SurfaceCalculus::new(q_far)?,
            geom_far: Geometry::zeros(q_far),
            far_grid: Grid::new(q_far),
            far_src: SmoothSources::new(),
            self_layer: SelfInteraction::new(p, q_self, RotationAlgorithm::ViaSh)?,
            coefs: vec![0.0; 3 * sht_p.n_coefs()],
            has_surface: false,
            delta: 0.0,
            point: PointEval::new(p),
            basis: vec![0.0; sht_p.n_coefs()],
            basis_scratch: BasisScratch::new(p),
            dens_coef: vec![0.0; 3 * sht_p.n_coefs()],
            dens_far_coef: vec![0.0; 3 * sht_far.n_coefs()],
            dens_far: vec![0.0; 3 * nq],
            on_surface: vec![0.0; 3 * np],
            on_surface_coef: vec![0.0; 3 * sht_p.n_coefs()],
            spacing: 0.0,
            nodes: Vec::with_capacity(params.check_points + 1),
            vals: Vec::with_capacity(params.check_points + 1),
            levels: Vec::new(),
            batch: Vec::new(),
            batch_vals: Vec::new(),
            checked: 0,
            rmax: 0.0,
            sht_p,
            sht_far,
        })
    }

    /// The near-zone distance `δ` of the current surface.
    pub fn near_distance(&self) -> f64 {
        self.delta
    }

    /// How many targets of the last evaluation were extrapolated from check points (the rest
    /// took a smooth rule).
    pub fn check_point_targets(&self) -> usize {
        self.checked
    }

    /// Set the surface (order-`p` coefficients).
    pub fn set_surface(&mut self, coefs: &[f64]) -> Result<(), VesicleError> {
        check_len("surface coefficients", coefs.len(), self.coefs.len())?;
        self.has_surface = false;
        let lay_far = self.sht_far.layout().clone();
        let mut cf = vec![0.0; 3 * lay_far.len()];
        resample_coefs(&self.lay_p, &lay_far, coefs, &mut cf)?;
        self.calc_far.update_geometry(&cf, &mut self.geom_far)?;
        self.far_src.set_geometry(&self.geom_far);
        self.coefs.copy_from_slice(coefs);
        self.delta = self
            .params
            .near_distance
            .unwrap_or_else(|| self.geom_far.equivalent_radius() / (self.p as f64).sqrt());
        // Grid spacing bound: 2π R_max / q_far, R_max the largest distance from the centroid.
        let c = self.geom_far.centroid();
        let rmax = self
            .geom_far
            .x
            .iter()
            .map(|x| ((x[0] - c[0]).powi(2) + (x[1] - c[1]).powi(2) + (x[2] - c[2]).powi(2)).sqrt())
            .fold(0.0, f64::max);
        // A deformed surface's grid can be stretched well beyond a sphere's: the bound is also
        // at least the largest diagonal of a grid cell (neighbours in θ and φ), so that a point
        // within δ of the surface always reaches the closest-point solve below.
        let diag = largest_cell_diagonal(&self.geom_far.x, self.far_grid.order());
        self.spacing = (2.0 * PI * rmax / self.far_grid.order() as f64).max(diag);
        self.rmax = rmax;
        for l in &mut self.levels {
            l.geometry_set = false;
        }
        self.has_surface = true;
        Ok(())
    }

    fn require_surface(&self) -> Result<(), VesicleError> {
        if self.has_surface {
            Ok(())
        } else {
            Err(VesicleError::Missing(
                "the surface (OffSurface::set_surface)",
            ))
        }
    }

    /// Classify a target (see [`TargetInfo`]).
    pub fn classify(&mut self, x: [f64; 3]) -> Result<TargetInfo, VesicleError> {
        self.require_surface()?;
        let g = &self.geom_far;
        let (best, jbest) = self.far_src.nearest(x);
        let start = self.far_grid.angles(jbest);
        let best = best.sqrt();
        // The nearest grid point can be farther than the surface by about one grid spacing.
        if best > self.delta + self.spacing {
            // The solid angle decides, unless the nearest grid point's outward normal says
            // outside (the quadrature of the solid angle can err a grid spacing or two off a
            // stretched surface).
            let r = [
                x[0] - g.x[jbest][0],
                x[1] - g.x[jbest][1],
                x[2] - g.x[jbest][2],
            ];
            return Ok(TargetInfo {
                inside: dot(r, g.normal[jbest]) < 0.0 && self.far_src.solid_angle(x) > 0.5,
                near: false,
                distance: best,
                closest: start,
            });
        }
        let (tp, pd) = closest_point(&mut self.point, &self.lay_p, &self.coefs, x, start);
        let nv = self.point.normal(&self.lay_p, &self.coefs, tp, &pd);
        let r = [x[0] - pd.x[0], x[1] - pd.x[1], x[2] - pd.x[2]];
        let d = dot(r, r).sqrt();
        Ok(TargetInfo {
            inside: dot(r, nv) < 0.0,
            near: d < self.delta,
            distance: d,
            closest: tp,
        })
    }

    /// The order of the refined smooth quadrature that resolves a target at distance `d`
    /// (`None`: none up to `max_order`; the check points are used).
    fn resolving_order(&self, d: f64) -> Option<usize> {
        let q_far = self.far_grid.order();
        let max = self.params.max_order.unwrap_or(DEFAULT_MAX_ORDER);
        let mut q = 2 * q_far;
        while q <= max {
            if d >= RESOLVED * 2.0 * PI * self.rmax / q as f64 {
                return Some(q);
            }
            q = if q < max { (2 * q).min(max) } else { max + 1 };
        }
        None
    }

    /// The rule for a smooth sum at a point at least `t` from the surface that needs
    /// `ratio` spacings: the coarsest of `q_far/2, 2q_far/3` whose spacing is at most `t /
    /// ratio` (`Some(order)`), else the far rule (`None`). Always the far rule without
    /// [`NearParams::smooth_ratio`].
    fn coarse_order(&self, t: f64, ratio: f64) -> Option<usize> {
        self.params.smooth_ratio?;
        let q_far = self.far_grid.order();
        [q_far / 2, 2 * q_far / 3].into_iter().find(|&q| {
            q >= self.p && q < q_far && t * q as f64 >= ratio * self.spacing * q_far as f64
        })
    }

    /// Whether a near target at distance `d` takes a smooth rule directly
    /// ([`NearParams::smooth_ratio`]).
    fn near_but_resolved(&self, d: f64) -> bool {
        self.params
            .smooth_ratio
            .is_some_and(|r| d >= r * self.spacing)
    }

    /// Put `x` in the batch of the rule of order `q` (`None`: the far rule).
    fn push_to(&mut self, q: Option<usize>, x: [f64; 3]) -> Result<Slot, VesicleError> {
        Ok(match q {
            None => {
                self.batch.push(x);
                Slot(None, self.batch.len() - 1)
            }
            Some(q) => {
                let i = self.level(q)?;
                let l = &mut self.levels[i];
                l.batch.push(x);
                Slot(Some(i), l.batch.len() - 1)
            }
        })
    }

    /// The refined quadrature of order `q` with the current surface and density (built,
    /// resampled on first use).
    fn level(&mut self, q: usize) -> Result<usize, VesicleError> {
        let i = match self.levels.iter().position(|l| l.q == q) {
            Some(i) => i,
            None => {
                let sht = ShTransform::new(q)?;
                let (nc, n) = (sht.n_coefs(), sht.n_points());
                self.levels.push(Level {
                    q,
                    ws: sht.workspace(),
                    calc: SurfaceCalculus::new(q)?,
                    geom: Geometry::zeros(q),
                    geometry_set: false,
                    density_set: false,
                    dens_coef: vec![0.0; 3 * nc],
                    dens: vec![0.0; 3 * n],
                    src: SmoothSources::new(),
                    batch: Vec::new(),
                    batch_vals: Vec::new(),
                    sht,
                });
                self.levels.len() - 1
            }
        };
        let l = &mut self.levels[i];
        if !l.geometry_set {
            let mut cf = vec![0.0; 3 * l.sht.n_coefs()];
            resample_coefs(&self.lay_p, l.sht.layout(), &self.coefs, &mut cf)?;
            l.calc.update_geometry(&cf, &mut l.geom)?;
            l.src.set_geometry(&l.geom);
            l.geometry_set = true;
            l.density_set = false;
        }
        if !l.density_set {
            resample_coefs(
                &self.lay_p,
                l.sht.layout(),
                &self.dens_coef,
                &mut l.dens_coef,
            )?;
            l.sht.inverse(&l.dens_coef, &mut l.dens, &mut l.ws)?;
            l.src.set_density(&l.dens)?;
            l.density_set = true;
        }
        Ok(i)
    }
}

impl OffSurface {
    /// The layer potential of `density` (component-major on the order-`p` grid) at arbitrary
    /// targets; `out` is component-major (`3 · targets.len()`). Also returns each target's
    /// classification.
    pub fn evaluate(
        &mut self,
        kernel: LayerKernel,
        density: &[f64],
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<Vec<TargetInfo>, VesicleError> {
        self.evaluate_inner(kernel, density, None, None, targets, out)
    }

    /// [`Self::evaluate`] with each target's classification given (`infos`, as
    /// [`Self::classify`] returned them on this surface), where a caller evaluates several
    /// densities at the same targets on the same surface (the near zones' products, once per
    /// GMRES iteration), and optionally the layer's on-surface values (as
    /// [`Self::evaluate_given_on_surface`] takes them). Returns the classifications.
    pub fn evaluate_classified(
        &mut self,
        kernel: LayerKernel,
        density: &[f64],
        on_surface: Option<&[f64]>,
        targets: &[[f64; 3]],
        infos: &[TargetInfo],
        out: &mut [f64],
    ) -> Result<Vec<TargetInfo>, VesicleError> {
        check_len("target classifications", infos.len(), targets.len())?;
        if let Some(v) = on_surface {
            check_len("on-surface values", v.len(), 3 * self.sht_p.n_points())?;
        }
        self.evaluate_inner(kernel, density, on_surface, Some(infos), targets, out)
    }

    /// [`Self::evaluate`] with the layer's on-surface (principal) values at the grid points
    /// given by the caller (`3 · n_points`, component-major), where a solve already holds them
    /// (a wall's own double layer: `WallSolution::own_double_layer` of `crate::wall`), in place of
    /// the singular quadrature over the whole surface that near targets otherwise cost.
    pub fn evaluate_given_on_surface(
        &mut self,
        kernel: LayerKernel,
        density: &[f64],
        on_surface: &[f64],
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<Vec<TargetInfo>, VesicleError> {
        check_len(
            "on-surface values",
            on_surface.len(),
            3 * self.sht_p.n_points(),
        )?;
        self.evaluate_inner(kernel, density, Some(on_surface), None, targets, out)
    }

    fn evaluate_inner(
        &mut self,
        kernel: LayerKernel,
        density: &[f64],
        given: Option<&[f64]>,
        classified: Option<&[TargetInfo]>,
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<Vec<TargetInfo>, VesicleError> {
        self.require_surface()?;
        let np = self.sht_p.n_points();
        check_len("density", density.len(), 3 * np)?;
        check_len("output", out.len(), 3 * targets.len())?;
        kernel.check()?;
        // Density on the far grid.
        self.sht_p
            .forward(density, &mut self.dens_coef, &mut self.ws_p)?;
        resample_coefs(
            &self.lay_p,
            self.sht_far.layout(),
            &self.dens_coef,
            &mut self.dens_far_coef,
        )?;
        self.sht_far
            .inverse(&self.dens_far_coef, &mut self.dens_far, &mut self.ws_far)?;
        for l in &mut self.levels {
            l.density_set = false;
        }
        let infos: Vec<TargetInfo> = match classified {
            Some(infos) => infos.to_vec(),
            None => targets
                .iter()
                .map(|&x| self.classify(x))
                .collect::<Result<_, _>>()?,
        };
        // On-surface values (only if some near target is left to the check points).
        if infos.iter().any(|i| {
            i.near
                && self.resolving_order(i.distance).is_none()
                && !self.near_but_resolved(i.distance)
        }) {
            match given {
                Some(v) => self.on_surface.copy_from_slice(v),
                None => {
                    self.self_layer
                        .evaluate(kernel, &self.coefs, density, &mut self.on_surface)?
                }
            }
            self.sht_p
                .forward(&self.on_surface, &mut self.on_surface_coef, &mut self.ws_p)?;
        }
        self.far_src.set_density(&self.dens_far)?;
        let nt = targets.len();
        let m = self.params.check_points;
        let h = self.delta * self.params.check_spacing;
        // Route every target, and gather the points each smooth rule sums at.
        self.batch.clear();
        for l in &mut self.levels {
            l.batch.clear();
        }
        let ratio = self.params.smooth_ratio.unwrap_or(f64::INFINITY);
        let mut routes = Vec::with_capacity(nt);
        for (&x, info) in targets.iter().zip(&infos) {
            let refined = if info.near {
                self.resolving_order(info.distance)
            } else {
                None
            };
            let route = if !info.near {
                // A far target's distance is its nearest grid point's, at most a spacing more.
                let q = self.coarse_order(info.distance - self.spacing, ratio);
                Route::Smooth(self.push_to(q, x)?)
            } else if let Some(q) = refined {
                Route::Smooth(self.push_to(Some(q), x)?)
            } else if self.near_but_resolved(info.distance) {
                let q = self.coarse_order(info.distance, ratio);
                Route::Smooth(self.push_to(q, x)?)
            } else {
                let pd = self
                    .point
                    .eval(&self.lay_p, &self.coefs, info.closest.0, info.closest.1);
                let nv = self
                    .point
                    .normal(&self.lay_p, &self.coefs, info.closest, &pd);
                let nn = dot(nv, nv).sqrt();
                let side = if info.inside { -1.0 } else { 1.0 };
                let n = nv.map(|c| side * c / nn);
                // Nodes: the surface (distance 0) and m check points.
                let mut v0 = interpolate(
                    &self.lay_p,
                    &self.on_surface_coef,
                    info.closest,
                    &mut self.basis_scratch,
                    &mut self.basis,
                );
                if kernel == LayerKernel::DoubleLayer {
                    let dens = interpolate(
                        &self.lay_p,
                        &self.dens_coef,
                        info.closest,
                        &mut self.basis_scratch,
                        &mut self.basis,
                    );
                    for c in 0..3 {
                        v0[c] += side * 0.5 * dens[c];
                    }
                }
                // Always the far rule: the extrapolation to the target amplifies the check
                // points' errors (a coarser rule for the farther ones, at the ratio the nearest
                // has, gave 1e-2 at 0.02 from a small tube's wall).
                let first = self.batch.len();
                for k in 0..m {
                    let t = self.delta + k as f64 * h;
                    self.batch.push(std::array::from_fn(|c| pd.x[c] + t * n[c]));
                }
                Route::Check(v0, first)
            };
            routes.push(route);
        }
        self.checked = routes
            .iter()
            .filter(|r| matches!(r, Route::Check(..)))
            .count();
        // The sums, each rule's points in one batch.
        self.batch_vals.clear();
        self.batch_vals.resize(3 * self.batch.len(), 0.0);
        self.far_src
            .add_to(kernel, &self.batch, &mut self.batch_vals)?;
        for l in &mut self.levels {
            l.batch_vals.clear();
            l.batch_vals.resize(3 * l.batch.len(), 0.0);
            if !l.batch.is_empty() {
                l.src.add_to(kernel, &l.batch, &mut l.batch_vals)?;
            }
        }
        let at = |this: &Self, Slot(rule, k): Slot| -> [f64; 3] {
            let vals = match rule {
                None => &this.batch_vals,
                Some(i) => &this.levels[i].batch_vals,
            };
            [vals[3 * k], vals[3 * k + 1], vals[3 * k + 2]]
        };
        for (ti, (route, info)) in routes.iter().zip(&infos).enumerate() {
            let u = match *route {
                Route::Smooth(slot) => at(self, slot),
                Route::Check(v0, first) => {
                    self.nodes.clear();
                    self.vals.clear();
                    self.nodes.push(0.0);
                    self.vals.push(v0);
                    for k in 0..m {
                        self.nodes.push(self.delta + k as f64 * h);
                        let v = at(self, Slot(None, first + k));
                        self.vals.push(v);
                    }
                    lagrange(&self.nodes, &self.vals, info.distance)
                }
            };
            for c in 0..3 {
                out[c * nt + ti] = u[c];
            }
        }
        Ok(infos)
    }
}

/// Evaluate an expansion (3 components of order-`p` coefficients) at `(θ, φ)`.
fn interpolate(
    lay: &CoefLayout,
    coefs: &[f64],
    at: (f64, f64),
    scratch: &mut BasisScratch,
    basis: &mut [f64],
) -> [f64; 3] {
    eval_basis(lay, at.0, at.1, scratch, basis);
    let nc = lay.len();
    std::array::from_fn(|c| {
        coefs[c * nc..(c + 1) * nc]
            .iter()
            .zip(basis.iter())
            .map(|(a, y)| a * y)
            .sum()
    })
}

/// Lagrange interpolation of vector values at `t`.
fn lagrange(nodes: &[f64], vals: &[[f64; 3]], t: f64) -> [f64; 3] {
    let mut out = [0.0; 3];
    for (i, (&ti, v)) in nodes.iter().zip(vals).enumerate() {
        let mut l = 1.0;
        for (k, &tk) in nodes.iter().enumerate() {
            if k != i {
                l *= (t - tk) / (ti - tk);
            }
        }
        for c in 0..3 {
            out[c] += l * v[c];
        }
    }
    out
}

//! The cell's own far side in its singular layer potentials: a partition of unity on the
//! parameter sphere.
//!
//! The Graham–Sloan rule of [`super::layer`] integrates `g(θ, φ) / (2 sin(θ/2))` over the
//! parameter sphere rotated so that the target sits at the north pole. It converges spectrally
//! in `q` when `g` is smooth. A part of the cell that comes back close to the target from the
//! other side of the parameter sphere is a nearly singular feature for that rule: on the
//! biconcave red blood cell the opposite dimple lies 0.29 away from a dimple target (the cell's
//! radius is 1.39), and at `q = 32` the error there is 1e-5 against 3e-8 at the rim.
//!
//! For such targets (*flagged*, below) the integral is split by a window `η` of the geodesic
//! angle `θ` between target and source on the parameter sphere (a partition of unity, as in
//! Bruno & Kunyansky, J. Comput. Phys. 169, 2001, and Ying, Biros & Zorin, J. Comput. Phys.
//! 219, 2006):
//!
//! ```text
//! ∫ K f dA = ∫ η(θ) K f dA + ∫ (1 − η(θ)) K f dA.
//! ```
//!
//! * The window is the smoothstep polynomial `η = I_x(n+1, n+1)`, `x = (1 + cos θ)/2 = 1 − s`,
//!   `s = sin²(θ/2)`, of degree `2n + 1` in `cos θ` (`n` = [`WINDOW_ORDER`] = 5; `I` is the
//!   regularised incomplete beta function, here a finite binomial sum). It is band-limited, so
//!   the local part `η g` stays in the class the Graham–Sloan rule integrates: the rule of order
//!   `q` is exact for `η g` of degree `≤ q + 1`, and `η` takes `2n + 1 = 11` of those degrees.
//!   That is why the split is only used from `q ≥ 24` on ([`FarSideParams::min_q`]).
//! * `1 − η = O(s^{n+1}) = O(θ^{2n+2})` at the target, so the far part's integrand
//!   `(1 − η) K f` vanishes there to order `2n + 1` and is smooth: it is integrated on the
//!   *unrotated* Gauss–Legendre × uniform grid of an order `Q` chosen from the distance to the
//!   far side, with the surface and density resampled there (both are band-limited at `p`).
//!
//! **Flagging.** With `R_max` the largest distance of the surface from its centre and
//! `h = 2π R_max / q` (a bound on the order-`q` grid spacing), target `t` is flagged when
//! `d_far(t) < flag · h`, `d_far` the distance from `x_t` to the points of the order-`q` grid
//! on the half of the parameter sphere opposite to `t` (`θ ≥ π/2`). One order serves all flagged
//! targets of a surface: `Q` = the smallest multiple of 4 with
//! `Q ≥ max(q, order · 2π R_max / min d_far)`, at most [`FarSideParams::max_order`].
//!
//! Defaults (`flag = 2`, `order = 1.5`) measured on the RBC at `p = 16` with a density of
//! degree ≤ 8, largest relative error over 78 targets against `q = 96`
//! (`tests/vesicle_layer.rs`, `convergence_table`), plain rule → split: `q = 24`: 7.5e-5 →
//! 3.5e-6; `q = 32`: 2.2e-5 → 4.5e-7; `q = 48`: 5.2e-7 → 3.3e-8. A larger `flag` splits more
//! targets for more accuracy (`flag = 3`: 1.6e-7 at `q = 32`, 1.4e-9 at `q = 48`) at more cost
//! (at `p = 12`, `q = 24`: 240 of 312 targets split and the assembly 1.5× slower, against 96
//! targets and +6 % with `flag = 2`; `benches/vesicle.rs`).
//!
//! **Dense rows.** The far rows of a flagged target, `Σ_j w_j (1 − η_j) K(x_t − y_j) f(y_j)` with
//! `f = Y_Q E F_p f_p` (forward transform at `p`, zero-padding `E`, synthesis at `Q`), are
//! folded into the order-`p` grid values as `(Y_Qᵀ W k) E F_p`: `Y_Qᵀ W k` is the forward
//! transform of the kernel row `k` at order `Q` times the basis norms `N_l = ∫ Y_l² dΩ`, so one
//! batched transform and one GEMM with the forward matrix `F_p` replace an `n_Q × n_p`
//! resampling matrix.

use std::f64::consts::PI;

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

use super::coefficient_operator::forward_matrix;
use super::layer_kernel::{kernel_entries, LayerKernel};
use super::{cross, dot, get3, VesicleError};
use crate::sph_harmonics::{resample_coefs, Deriv, Grid, ShTransform, ShWorkspace};

/// Order `n` of the window `η = I_x(n+1, n+1)` (degree `2n + 1` in `cos θ`).
pub const WINDOW_ORDER: usize = 5;

/// The entries `(a, b)`, `a ≤ b`, of the (symmetric) kernels: six transforms per target, not nine.
const SYM: [(usize, usize); 6] = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];

/// Targets whose far rows are built in one batch of transforms (keeps the scratch in cache).
const ROW_BATCH: usize = 8;

/// Settings of the far-side split (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FarSideParams {
    /// Use the split at all (with `false`, the plain Graham–Sloan rule everywhere).
    pub enabled: bool,
    /// Flag a target when its far side is closer than `flag · 2π R_max / q`.
    pub flag: f64,
    /// The far order resolves distances down to `order · 2π R_max / Q`.
    pub order: f64,
    /// Upper bound of the far order `Q` (default `2q`).
    pub max_order: Option<usize>,
    /// Smallest quadrature order `q` at which targets are flagged (below it the window's
    /// `2n + 1` degrees cost the local part more than the far side does).
    pub min_q: usize,
}

impl Default for FarSideParams {
    fn default() -> Self {
        FarSideParams {
            enabled: true,
            flag: 2.0,
            order: 1.5,
            max_order: None,
            min_q: 4 * (WINDOW_ORDER + 1),
        }
    }
}

/// `(η, 1 − η)` at `s = sin²(θ/2)`, `θ` the angle to the target on the parameter sphere.
///
/// `1 − η(s) = s^{n+1} P(s)` with `P` of degree `n`, and `η(s) = (1 − η)(1 − s)` by symmetry;
/// the smaller of the two is evaluated from its own factor `s^{n+1}` (or `(1 − s)^{n+1}`), the
/// other as its complement, so neither loses digits where it is small.
#[inline]
pub fn window(s: f64) -> (f64, f64) {
    let c = &*WINDOW_COEFS;
    let tail = |t: f64| {
        let mut acc = 0.0;
        for &ci in c.iter().rev() {
            acc = acc * t + ci;
        }
        acc * t.powi(WINDOW_ORDER as i32 + 1)
    };
    if s <= 0.5 {
        let rest = tail(s);
        (1.0 - rest, rest)
    } else {
        let eta = tail(1.0 - s);
        (eta, 1.0 - eta)
    }
}

/// Monomial coefficients of `P(s)`, `1 − η(s) = s^{n+1} P(s)`: with `k = 2n + 1`,
/// `1 − η = Σ_{j=n+1}^{k} C(k, j) s^j (1 − s)^{k−j}`.
static WINDOW_COEFS: std::sync::LazyLock<[f64; WINDOW_ORDER + 1]> =
    std::sync::LazyLock::new(|| {
        let n = WINDOW_ORDER;
        let k = 2 * n + 1;
        let binom =
            |a: usize, b: usize| (0..b).fold(1.0, |c, i| c * (a - i) as f64 / (i + 1) as f64);
        let mut c = [0.0; WINDOW_ORDER + 1];
        for j in n + 1..=k {
            for i in 0..=k - j {
                let sign = if i % 2 == 0 { 1.0 } else { -1.0 };
                c[j - n - 1 + i] += binom(k, j) * binom(k - j, i) * sign;
            }
        }
        c
    });

/// The surface on the far grid of order `Q`.
struct FarGrid {
    order: usize,
    sht: ShTransform,
    ws: ShWorkspace,
    /// Unit points of the parameter sphere.
    unit: Vec<[f64; 3]>,
    /// `w_i π/Q · |Y_θ × Y_φ| / sin θ`: area weight of every point.
    area: Vec<f64>,
    /// Area per unit solid angle `|Y_θ × Y_φ| / sin θ` (the row kernels are built without the
    /// Gauss weights, which the forward transform applies).
    jac: Vec<f64>,
    /// Positions and unit normals, component-major / per point.
    y: Vec<f64>,
    normal: Vec<[f64; 3]>,
    /// Scratch: the density on this grid.
    dens: Vec<f64>,
}

/// Flags and far grid of one surface; owned by [`super::layer::SelfInteraction`].
pub(crate) struct FarSide {
    params: FarSideParams,
    p: usize,
    q: usize,
    sht_p: ShTransform,
    ws_p: ShWorkspace,
    sht_q: ShTransform,
    ws_q: ShWorkspace,
    unit_p: Vec<[f64; 3]>,
    unit_q: Vec<[f64; 3]>,
    qw_q: Vec<f64>,
    /// `η` at the latitudes of the order-`q` grid of the rotated frame.
    pub(crate) eta_q: Vec<f64>,
    /// Per target of the order-`p` grid: flagged for the current surface.
    pub(crate) flagged: Vec<bool>,
    targets: Vec<usize>,
    far: Option<FarGrid>,
    /// Basis norms `N_l` (order-`p` layout) and forward matrix `F_p` (`n_coef × n_p`), built on
    /// the first dense assembly with flagged targets.
    norms: Vec<f64>,
    forward_p: Vec<f64>,
    // Scratch.
    coef_p: Vec<f64>,
    grid_q: Vec<f64>,
}

impl FarSide {
    pub(crate) fn new(p: usize, q: usize) -> Result<Self, VesicleError> {
        let sht_p = ShTransform::new(p)?;
        let sht_q = ShTransform::new(q)?;
        let grid_q = Grid::new(q);
        let eta_q = grid_q
            .theta
            .iter()
            .map(|&t| window((t / 2.0).sin().powi(2)).0)
            .collect();
        Ok(FarSide {
            params: FarSideParams::default(),
            p,
            q,
            ws_p: sht_p.workspace(),
            ws_q: sht_q.workspace(),
            unit_p: Grid::new(p).unit_points(),
            unit_q: grid_q.unit_points(),
            qw_q: grid_q.quadrature_weights(),
            eta_q,
            flagged: vec![false; sht_p.n_points()],
            targets: Vec::new(),
            far: None,
            norms: Vec::new(),
            forward_p: Vec::new(),
            coef_p: vec![0.0; 3 * sht_p.n_coefs()],
            grid_q: vec![0.0; 3 * sht_q.n_points()],
            sht_p,
            sht_q,
        })
    }

    pub(crate) fn params(&self) -> FarSideParams {
        self.params
    }

    pub(crate) fn set_params(&mut self, params: FarSideParams) -> Result<(), VesicleError> {
        for (name, value) in [
            ("far-side flag", params.flag),
            ("far-side order", params.order),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(VesicleError::Parameter {
                    name,
                    value,
                    reason: "must be finite and non-negative",
                });
            }
        }
        if let Some(m) = params.max_order {
            if m < self.q {
                return Err(VesicleError::Order { p: self.q, q: m });
            }
        }
        self.params = params;
        Ok(())
    }

    /// Flagged targets of the current surface and the far order (0 when none is flagged).
    pub(crate) fn plan(&self) -> (&[usize], usize) {
        (
            &self.targets,
            self.far
                .as_ref()
                .filter(|_| !self.targets.is_empty())
                .map_or(0, |f| f.order),
        )
    }

    /// Flag the targets of the surface with coefficients `x_coef` (order `p`) and grid values
    /// `x_grid`, and resample it on the far grid when any is flagged.
    pub(crate) fn set_surface(
        &mut self,
        x_coef: &[f64],
        x_grid: &[f64],
    ) -> Result<(), VesicleError> {
        self.flagged.fill(false);
        self.targets.clear();
        if !self.params.enabled || self.q < self.params.min_q {
            return Ok(());
        }
        let nq = self.sht_q.n_points();
        let np = self.sht_p.n_points();
        let mut cq = vec![0.0; 3 * self.sht_q.n_coefs()];
        resample_coefs(self.sht_p.layout(), self.sht_q.layout(), x_coef, &mut cq)?;
        self.sht_q.inverse(&cq, &mut self.grid_q, &mut self.ws_q)?;
        // Centre (parameter-sphere mean) and radius.
        let mut c = [0.0; 3];
        let wsum: f64 = self.qw_q.iter().sum();
        for (j, w) in self.qw_q.iter().enumerate() {
            let y = get3(&self.grid_q, nq, j);
            for a in 0..3 {
                c[a] += w * y[a] / wsum;
            }
        }
        let r_max = (0..nq)
            .map(|j| {
                let y = get3(&self.grid_q, nq, j);
                let d = [y[0] - c[0], y[1] - c[1], y[2] - c[2]];
                dot(d, d).sqrt()
            })
            .fold(0.0, f64::max);
        let h = 2.0 * PI * r_max / self.q as f64;
        let mut d_min = f64::INFINITY;
        for t in 0..np {
            let (xt, ut) = (get3(x_grid, np, t), self.unit_p[t]);
            let mut d2 = f64::INFINITY;
            for (j, uj) in self.unit_q.iter().enumerate() {
                if dot(ut, *uj) <= 0.0 {
                    let y = get3(&self.grid_q, nq, j);
                    let r = [xt[0] - y[0], xt[1] - y[1], xt[2] - y[2]];
                    d2 = d2.min(dot(r, r));
                }
            }
            let d = d2.sqrt();
            if d < self.params.flag * h {
                self.flagged[t] = true;
                self.targets.push(t);
                d_min = d_min.min(d);
            }
        }
        if self.targets.is_empty() {
            return Ok(());
        }
        let max_order = self.params.max_order.unwrap_or(2 * self.q);
        let want = (self.params.order * 2.0 * PI * r_max / d_min).ceil() as usize;
        let order = (want.max(self.q).div_ceil(4) * 4).min(max_order);
        if self.far.as_ref().is_none_or(|f| f.order != order) {
            let sht = ShTransform::new(order)?;
            let grid = Grid::new(order);
            let n = sht.n_points();
            self.far = Some(FarGrid {
                order,
                ws: sht.workspace(),
                unit: grid.unit_points(),
                area: vec![0.0; n],
                jac: vec![0.0; n],
                y: vec![0.0; 3 * n],
                normal: vec![[0.0; 3]; n],
                dens: vec![0.0; 3 * n],
                sht,
            });
        }
        let far = self.far.as_mut().expect("built above");
        let n = far.sht.n_points();
        let mut cf = vec![0.0; 3 * far.sht.n_coefs()];
        resample_coefs(self.sht_p.layout(), far.sht.layout(), x_coef, &mut cf)?;
        let (mut yt, mut yp) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
        far.sht.synthesize(
            &cf,
            &[Deriv::Value, Deriv::Theta, Deriv::Phi],
            &mut [&mut far.y, &mut yt, &mut yp],
            &mut far.ws,
        )?;
        let grid = far.sht.grid();
        let qw = grid.quadrature_weights();
        let nlon = grid.n_lon();
        for (j, wq) in qw.iter().enumerate() {
            let nv = cross(get3(&yt, n, j), get3(&yp, n, j));
            let w = dot(nv, nv).sqrt();
            far.jac[j] = w / grid.sin_theta[j / nlon];
            far.area[j] = wq * far.jac[j];
            far.normal[j] = [nv[0] / w, nv[1] / w, nv[2] / w];
        }
        Ok(())
    }

    /// Resample a density (component-major on the order-`p` grid) on the far grid; call before
    /// [`FarSide::add_far`].
    pub(crate) fn set_density(&mut self, density: &[f64]) -> Result<(), VesicleError> {
        let Some(far) = self.far.as_mut().filter(|_| !self.targets.is_empty()) else {
            return Ok(());
        };
        self.sht_p
            .forward(density, &mut self.coef_p, &mut self.ws_p)?;
        let mut cf = vec![0.0; 3 * far.sht.n_coefs()];
        resample_coefs(self.sht_p.layout(), far.sht.layout(), &self.coef_p, &mut cf)?;
        far.sht.inverse(&cf, &mut far.dens, &mut far.ws)?;
        Ok(())
    }

    /// Add the far part `Σ_j (1 − η_j) K(x_t − y_j) f_j dA_j` of flagged target `t` (at `xt`) to
    /// `u`, with the density set by [`FarSide::set_density`].
    pub(crate) fn add_far(&self, kernel: LayerKernel, t: usize, xt: [f64; 3], u: &mut [f64; 3]) {
        let Some(far) = &self.far else { return };
        let n = far.area.len();
        let ut = self.unit_p[t];
        for j in 0..n {
            let uj = far.unit[j];
            let du = [ut[0] - uj[0], ut[1] - uj[1], ut[2] - uj[2]];
            let rest = window(dot(du, du) / 4.0).1;
            if rest == 0.0 {
                continue;
            }
            let y = get3(&far.y, n, j);
            let r = [xt[0] - y[0], xt[1] - y[1], xt[2] - y[2]];
            if dot(r, r) == 0.0 {
                continue;
            }
            let k = kernel_entries(kernel, r, far.normal[j], rest * far.area[j]);
            let f = get3(&far.dens, n, j);
            for (a, ua) in u.iter_mut().enumerate() {
                *ua += k[3 * a] * f[0] + k[3 * a + 1] * f[1] + k[3 * a + 2] * f[2];
            }
        }
    }

    /// Add the far rows of every flagged target to the dense operator `out` (`3n_p × 3n_p`,
    /// column-major, rows and columns component-major); `x_grid` is the surface on the order-`p`
    /// grid.
    pub(crate) fn add_rows(
        &mut self,
        kernel: LayerKernel,
        x_grid: &[f64],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        let np = self.sht_p.n_points();
        let ncp = self.sht_p.n_coefs();
        let n3 = 3 * np;
        if self.forward_p.is_empty() && !self.targets.is_empty() {
            self.forward_p = forward_matrix(&self.sht_p, &mut self.ws_p)?;
        }
        let fwd = std::mem::take(&mut self.forward_p);
        let mut r = Vec::new();
        // The flagged targets are read while `self` lends its transforms: taken, then put back.
        let targets = std::mem::take(&mut self.targets);
        let result = self.coefficient_rows(kernel, x_grid, &targets, |chunk, cp| {
            let nf = SYM.len() * chunk.len();
            r.resize(nf * np, 0.0);
            // R = Cᵀ F_p: row (target, a, b) over the order-p grid.
            matmul(
                MatMut::from_column_major_slice_mut(&mut r, nf, np),
                Accum::Replace,
                MatRef::from_column_major_slice(cp, ncp, nf).transpose(),
                MatRef::from_column_major_slice(&fwd, ncp, np),
                1.0,
                Par::Seq,
            );
            for (ti, &t) in chunk.iter().enumerate() {
                for (e, &(a, b)) in SYM.iter().enumerate() {
                    let f = SYM.len() * ti + e;
                    for c in 0..np {
                        let v = r[c * nf + f];
                        out[(b * np + c) * n3 + a * np + t] += v;
                        if a != b {
                            out[(a * np + c) * n3 + b * np + t] += v;
                        }
                    }
                }
            }
        });
        self.forward_p = fwd;
        self.targets = targets;
        result
    }

    /// Add the far rows of every flagged target in coefficient space: `rows` (`3n_p × 3n_c(p)`,
    /// row-major, row `a·n_p + t`, column `b·n_c + k`; [`super::SelfInteraction::assemble_rows`])
    /// gains `Y_Qᵀ W k E` for the kernel entry `(a, b)` of target `t`, so that
    /// `rows · blockdiag(F_p)` are the grid rows of [`Self::add_rows`].
    ///
    /// Only the targets `t` of `held` enter, at row `a·k + (t − held.start)` with
    /// `k = held.len()` (all targets: the rows above).
    pub(crate) fn add_coefficient_rows(
        &mut self,
        kernel: LayerKernel,
        x_grid: &[f64],
        held: std::ops::Range<usize>,
        rows: &mut [f64],
    ) -> Result<(), VesicleError> {
        let k = held.len();
        let ncp = self.sht_p.n_coefs();
        // The flagged targets are ascending: those held are one run of them (taken while
        // `self` lends its transforms, then put back).
        let targets = std::mem::take(&mut self.targets);
        let run = targets.partition_point(|&t| t < held.start)
            ..targets.partition_point(|&t| t < held.end);
        let result = self.coefficient_rows(kernel, x_grid, &targets[run], |chunk, cp| {
            for (ti, &t) in chunk.iter().enumerate() {
                let t = t - held.start;
                for (e, &(a, b)) in SYM.iter().enumerate() {
                    let c = &cp[(SYM.len() * ti + e) * ncp..(SYM.len() * ti + e + 1) * ncp];
                    let ra = (a * k + t) * 3 * ncp + b * ncp;
                    for (x, v) in rows[ra..ra + ncp].iter_mut().zip(c) {
                        *x += v;
                    }
                    if a != b {
                        let rb = (b * k + t) * 3 * ncp + a * ncp;
                        for (x, v) in rows[rb..rb + ncp].iter_mut().zip(c) {
                            *x += v;
                        }
                    }
                }
            }
        });
        self.targets = targets;
        result
    }

    /// The far rows of the flagged targets in coefficient space, a batch of targets at a time:
    /// `put(targets, C)` with `C` (`n_c(p) × 6·targets`, column `6·i + e` the symmetric
    /// kernel entry `SYM[e]` of `targets[i]`).
    fn coefficient_rows(
        &mut self,
        kernel: LayerKernel,
        x_grid: &[f64],
        targets: &[usize],
        mut put: impl FnMut(&[usize], &[f64]),
    ) -> Result<(), VesicleError> {
        let Some(far) = self.far.as_mut().filter(|_| !targets.is_empty()) else {
            return Ok(());
        };
        let np = self.sht_p.n_points();
        let ncp = self.sht_p.n_coefs();
        if self.norms.is_empty() {
            // N_l = ∫ Y_l² dΩ, by the Gauss rule of order 2p + 1 (exact for the products).
            let big = ShTransform::new(2 * self.p + 1)?;
            let mut ws = big.workspace();
            let mut unit = vec![0.0; ncp];
            let mut cb = vec![0.0; big.n_coefs()];
            let mut g = vec![0.0; big.n_points()];
            let qw = big.grid().quadrature_weights();
            self.norms = (0..ncp)
                .map(|l| {
                    unit.fill(0.0);
                    unit[l] = 1.0;
                    resample_coefs(self.sht_p.layout(), big.layout(), &unit, &mut cb)?;
                    big.inverse(&cb, &mut g, &mut ws)?;
                    Ok(g.iter().zip(&qw).map(|(v, w)| w * v * v).sum())
                })
                .collect::<Result<_, VesicleError>>()?;
        }
        let n = far.area.len();
        let batch = ROW_BATCH.min(targets.len());
        let nf = SYM.len() * batch;
        let mut rows = vec![0.0; nf * n];
        let mut cp = vec![0.0; nf * ncp];
        for chunk in targets.chunks(batch) {
            let nf = SYM.len() * chunk.len();
            for (ti, &t) in chunk.iter().enumerate() {
                let (xt, ut) = (get3(x_grid, np, t), self.unit_p[t]);
                for j in 0..n {
                    let uj = far.unit[j];
                    let du = [ut[0] - uj[0], ut[1] - uj[1], ut[2] - uj[2]];
                    let rest = window(dot(du, du) / 4.0).1;
                    let y = get3(&far.y, n, j);
                    let rv = [xt[0] - y[0], xt[1] - y[1], xt[2] - y[2]];
                    let k = if rest == 0.0 || dot(rv, rv) == 0.0 {
                        [0.0; 9]
                    } else {
                        kernel_entries(kernel, rv, far.normal[j], rest * far.jac[j])
                    };
                    for (e, (a, b)) in SYM.iter().enumerate() {
                        rows[(SYM.len() * ti + e) * n + j] = k[3 * a + b];
                    }
                }
            }
            // Y_Qᵀ W k E: the forward transform at Q truncated to the degrees of order p.
            far.sht.forward_to(
                self.sht_p.layout(),
                &rows[..nf * n],
                &mut cp[..nf * ncp],
                &mut far.ws,
            )?;
            for col in cp[..nf * ncp].chunks_exact_mut(ncp) {
                for (c, nl) in col.iter_mut().zip(&self.norms) {
                    *c *= nl;
                }
            }
            put(chunk, &cp[..nf * ncp]);
        }
        Ok(())
    }
}

//! Translation operators of the KIFMM, built once per kernel and order.
//!
//! A box of centre `c` and half-width `h` has its surfaces at `c + ρ h u` (`u` on the unit
//! cube surface, [`CubeSurface`]): upward equivalent at `ρ = INNER`, upward check at
//! `UP_CHECK`, downward equivalent at `DOWN_EQUIV`, downward check at `INNER`. Equivalent
//! densities are stored **normalised**, `φ̃_b = h^{d_b} φ_b` for a density component `b` on
//! which the equivalent kernel is homogeneous of degree `d_b`; then the field of a box's
//! equivalent density at `c + h x` is `Σ K(x − ρu) φ̃` whatever the level, and every
//! translation below is one matrix for all levels:
//!
//! * fits (check potential → equivalent density): the truncated-SVD pseudo-inverse of
//!   `K(ρ_c u_i − ρ_e u_s)`, kept factored as `(V Σ⁻¹)(Uᵀ ·)` so that rounding in the small
//!   singular directions is not spread over the large ones;
//! * M2M from the child in octant `σ ∈ {±1}³` to the parent's upward check potential:
//!   `K(UP_CHECK u_i − σ/2 − INNER u_s/2) · 2^{d}`, summed over the children and then fitted
//!   with the leaves' P2M potentials of the same level in one GEMM;
//! * L2L from the parent to the child's downward check potential:
//!   `K(σ/2 + INNER u_i/2 − DOWN_EQUIV u_s)`, added to the M2L and P2L potentials before the
//!   downward fit.
//!
//! Keeping the kernel matrices and the fits apart (instead of precomposing `up⁺ · K`) costs
//! the same per evaluation and saves the `O(n³)` products at setup.

use std::path::Path;

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatMut, MatRef, Par};

use super::fit_cache;
use super::kernels::Kernel;
use super::surface::CubeSurface;
use super::FmmError;

/// Radius factor of the upward equivalent and downward check surfaces.
pub const INNER: f64 = 1.05;
/// Radius factor of the upward check surface.
pub const UP_CHECK: f64 = 2.95;
/// Radius factor of the downward equivalent surface: between the downward check surface and
/// the nearest far equivalent points (`4h − INNER·h = 2.95h`).
pub const DOWN_EQUIV: f64 = 2.5;

/// A truncated-SVD pseudo-inverse kept as two factors.
#[derive(Clone, Debug)]
pub struct Pinv {
    /// `V Σ⁻¹` (columns: kept singular directions).
    pub vs: Mat<f64>,
    /// `Uᵀ` restricted to the kept directions.
    pub ut: Mat<f64>,
}

impl Pinv {
    /// Drop singular values below `rcond · σ_max`.
    pub fn new(a: &Mat<f64>, rcond: f64) -> Result<Self, FmmError> {
        let svd = a
            .thin_svd()
            .map_err(|_| FmmError::Svd("check-to-equivalent matrix"))?;
        let (u, s, v) = (svd.U(), svd.S().column_vector(), svd.V());
        let smax = s.iter().fold(0.0f64, |m, &x| m.max(x));
        let k = (0..s.nrows()).filter(|&j| s[j] > rcond * smax).count();
        let vs = Mat::from_fn(v.nrows(), k, |i, j| v[(i, j)] / s[j]);
        let ut = Mat::from_fn(k, u.nrows(), |i, j| u[(j, i)]);
        Ok(Pinv { vs, ut })
    }

    /// Kept rank.
    pub fn rank(&self) -> usize {
        self.ut.nrows()
    }

    /// `out = A⁺ check` (`tmp` holds `rank` values).
    pub fn apply(&self, check: &[f64], tmp: &mut [f64], out: &mut [f64], accum: bool) {
        let k = self.rank();
        matmul(
            MatMut::from_column_major_slice_mut(&mut tmp[..k], k, 1),
            Accum::Replace,
            self.ut.as_ref(),
            MatRef::from_column_major_slice(check, check.len(), 1),
            1.0,
            Par::Seq,
        );
        matmul(
            MatMut::from_column_major_slice_mut(out, self.vs.nrows(), 1),
            if accum { Accum::Add } else { Accum::Replace },
            self.vs.as_ref(),
            MatRef::from_column_major_slice(&tmp[..k], k, 1),
            1.0,
            Par::Seq,
        );
    }

    /// `out = A⁺ C` for the columns of `C` (column-major, `check.len() / n_check` columns),
    /// as two parallel GEMMs.
    pub fn apply_many(&self, check: &[f64], out: &mut [f64]) {
        let (k, nc, ne) = (self.rank(), self.ut.ncols(), self.vs.nrows());
        let cols = check.len() / nc;
        let mut tmp = vec![0.0; k * cols];
        matmul(
            MatMut::from_column_major_slice_mut(&mut tmp, k, cols),
            Accum::Replace,
            self.ut.as_ref(),
            MatRef::from_column_major_slice(check, nc, cols),
            1.0,
            Par::rayon(0),
        );
        matmul(
            MatMut::from_column_major_slice_mut(&mut out[..ne * cols], ne, cols),
            Accum::Replace,
            self.vs.as_ref(),
            MatRef::from_column_major_slice(&tmp, k, cols),
            1.0,
            Par::rayon(0),
        );
    }
}

/// Matrix of `k` from sources `ys` (all density components) to targets `xs` (all outputs):
/// row `i·dt + a`, column `s·de + b`.
pub fn kernel_matrix(k: &dyn Kernel, xs: &[[f64; 3]], ys: &[[f64; 3]]) -> Mat<f64> {
    let (dt, de) = (k.output_dim(), k.density_dim());
    let mut m = Mat::<f64>::zeros(xs.len() * dt, ys.len() * de);
    let mut unit = vec![0.0; de];
    let mut o = vec![0.0; dt];
    for (i, x) in xs.iter().enumerate() {
        for (s, y) in ys.iter().enumerate() {
            let r = [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
            for b in 0..de {
                unit.fill(0.0);
                unit[b] = 1.0;
                o.fill(0.0);
                k.accumulate(r, &unit, [0.0; 3], &mut o);
                for a in 0..dt {
                    m[(i * dt + a, s * de + b)] = o[a];
                }
            }
        }
    }
    m
}

/// Octant index of a child whose centre is at `sign(σ)` from its parent's: bit 2 for x, 1 for
/// y, 0 for z (as in [`super::octree`]).
pub fn octant(sigma: [f64; 3]) -> usize {
    ((sigma[0] > 0.0) as usize) << 2 | ((sigma[1] > 0.0) as usize) << 1 | (sigma[2] > 0.0) as usize
}

fn octant_sign(o: usize) -> [f64; 3] {
    let s = |bit: usize| if (o >> bit) & 1 == 1 { 1.0 } else { -1.0 };
    [s(2), s(1), s(0)]
}

/// The level-independent translations of one equivalent kernel and order.
#[derive(Clone, Debug)]
pub struct Translations {
    /// Surface lattice.
    pub surf: CubeSurface,
    /// Degrees of homogeneity of the equivalent density components.
    pub degrees: Vec<i32>,
    /// Upward fit (UC potential → normalised UE density).
    pub up: Pinv,
    /// Downward fit (DC potential → normalised DE density).
    pub down: Pinv,
    /// Child equivalent density → parent upward check potential, per child octant.
    pub m2m: Vec<Mat<f64>>,
    /// Parent downward equivalent density → child downward check potential, per octant.
    pub l2l: Vec<Mat<f64>>,
}

impl Translations {
    /// Build for equivalent kernel `ke` (homogeneous) at order `p`, truncating the fits at
    /// `rcond`; the fits are loaded from and stored in `cache` when given
    /// ([`super::fit_cache`]).
    pub fn new(
        ke: &dyn Kernel,
        p: usize,
        rcond: f64,
        cache: Option<&Path>,
    ) -> Result<Self, FmmError> {
        let de = ke.density_dim();
        let degrees = (0..de)
            .map(|b| ke.homogeneity(b))
            .collect::<Option<Vec<i32>>>()
            .ok_or_else(|| {
                FmmError::Shape(format!(
                    "equivalent kernel {} is not homogeneous",
                    ke.name()
                ))
            })?;
        let surf = CubeSurface::new(p);
        let scaled = |rho: f64, shift: [f64; 3]| -> Vec<[f64; 3]> {
            surf.points
                .iter()
                .map(|u| {
                    [
                        shift[0] + rho * u[0],
                        shift[1] + rho * u[1],
                        shift[2] + rho * u[2],
                    ]
                })
                .collect()
        };
        let zero = [0.0; 3];
        // Everything a fit depends on, for the cache.
        let key = |what: &str, check: f64, equiv: f64| {
            format!(
                "{what} fit of {} p={p} rcond={rcond:e} check={check:e} equiv={equiv:e}",
                ke.name()
            )
        };
        let fit = |what: &str, check: f64, equiv: f64| -> Result<Pinv, FmmError> {
            let key = key(what, check, equiv);
            if let Some(f) = cache.and_then(|dir| fit_cache::load(dir, &key)) {
                return Ok(f);
            }
            let f = Pinv::new(
                &kernel_matrix(ke, &scaled(check, zero), &scaled(equiv, zero)),
                rcond,
            )?;
            if let Some(dir) = cache {
                fit_cache::store(dir, &key, &f)?;
            }
            Ok(f)
        };
        let (up, down) = rayon::join(
            || fit("upward", UP_CHECK, INNER),
            || fit("downward", INNER, DOWN_EQUIV),
        );
        let (up, down) = (up?, down?);
        let mut m2m = Vec::with_capacity(8);
        let mut l2l = Vec::with_capacity(8);
        for o in 0..8 {
            let s = octant_sign(o);
            let half = [s[0] / 2.0, s[1] / 2.0, s[2] / 2.0];
            let mut k = kernel_matrix(ke, &scaled(UP_CHECK, zero), &scaled(INNER / 2.0, half));
            for col in 0..k.ncols() {
                let f = 2f64.powi(degrees[col % de]);
                for row in 0..k.nrows() {
                    k[(row, col)] *= f;
                }
            }
            m2m.push(k);
            l2l.push(kernel_matrix(
                ke,
                &scaled(INNER / 2.0, half),
                &scaled(DOWN_EQUIV, zero),
            ));
        }
        Ok(Translations {
            surf,
            degrees,
            up,
            down,
            m2m,
            l2l,
        })
    }

    /// Number of equivalent values per box (`points · density_dim`).
    pub fn n_equiv(&self) -> usize {
        self.m2m[0].ncols()
    }

    /// Number of check values per box (`points · output_dim`).
    pub fn n_check(&self) -> usize {
        self.m2m[0].nrows()
    }

    /// `h^{d_b}` for each equivalent density component.
    pub fn scale(&self, h: f64) -> Vec<f64> {
        self.degrees.iter().map(|&d| h.powi(d)).collect()
    }
}

/// `out = m · x` for `cols` column-major columns (parallel GEMM).
pub fn gemm(m: &Mat<f64>, x: &[f64], out: &mut [f64], cols: usize) {
    matmul(
        MatMut::from_column_major_slice_mut(out, m.nrows(), cols),
        Accum::Replace,
        m.as_ref(),
        MatRef::from_column_major_slice(x, m.ncols(), cols),
        1.0,
        Par::rayon(0),
    );
}

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
use rayon::prelude::*;

use super::fit_cache;
use super::kernels::Kernel;
pub use super::pinv::Pinv;
use super::surface::CubeSurface;
use super::FmmError;

/// Radius factor of the upward equivalent and downward check surfaces.
pub const INNER: f64 = 1.05;
/// Radius factor of the upward check surface.
pub const UP_CHECK: f64 = 2.95;
/// Radius factor of the downward equivalent surface: between the downward check surface and
/// the nearest far equivalent points (`4h − INNER·h = 2.95h`).
pub const DOWN_EQUIV: f64 = 2.5;

/// Matrix of `k` from sources `ys` (all density components) to targets `xs` (all outputs):
/// row `i·dt + a`, column `s·de + b`.
pub fn kernel_matrix(k: &dyn Kernel, xs: &[[f64; 3]], ys: &[[f64; 3]]) -> Mat<f64> {
    let (dt, de) = (k.output_dim(), k.density_dim());
    let rows = xs.len() * dt;
    if rows == 0 || ys.is_empty() {
        return Mat::zeros(rows, ys.len() * de);
    }
    // The `de` columns of one source at a time, sources in parallel, written in place (a
    // matrix of 100 MB at order 15: its pages once, not a buffer and a copy).
    let mut m = Mat::<f64>::zeros(rows, ys.len() * de);
    m.par_col_chunks_mut(de)
        .zip(ys.par_iter())
        .for_each(|(mut cols, y)| {
            let mut t = [0.0; 16];
            for (i, x) in xs.iter().enumerate() {
                k.tensor([x[0] - y[0], x[1] - y[1], x[2] - y[2]], &mut t);
                for a in 0..dt {
                    for b in 0..de {
                        cols[(i * dt + a, b)] = t[a * de + b];
                    }
                }
            }
        });
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
    /// Child equivalent density → parent upward check potential for the child in octant 0;
    /// the other octants' are its reflections ([`Translations::reflections`]).
    pub m2m: Mat<f64>,
    /// Parent downward equivalent density → child downward check potential for the child in
    /// octant 0 (the others by reflection).
    pub l2l: Mat<f64>,
    /// Per octant, the reflection that maps octant 0 onto it (identity for octant 0).
    pub reflections: Vec<Reflection>,
}

/// The reflection with bit 2 of `o` negating x, bit 1 y, bit 0 z: it maps octant 0 onto octant
/// `o`, and an offset `|d|` onto `d` when the bits are the signs of `d`.
pub(crate) fn reflection_of(o: usize) -> [f64; 3] {
    let s = |bit: usize| if (o >> bit) & 1 == 1 { -1.0 } else { 1.0 };
    [s(2), s(1), s(0)]
}

/// The component signs of kernel `ke` under the reflection `r` (a diagonal of ±1):
/// `(s_out, s_in)` with `K(Rx) = diag(s_out) K(x) diag(s_in)`, found at a generic point and
/// checked on every entry there; `None` if the kernel is not equivariant under `r`.
pub(crate) fn reflection_signs(ke: &dyn Kernel, r: [f64; 3]) -> Option<(Vec<f64>, Vec<f64>)> {
    let (dt, de) = (ke.output_dim(), ke.density_dim());
    let x = [0.37, -0.61, 0.83];
    let rx = [r[0] * x[0], r[1] * x[1], r[2] * x[2]];
    let tensor = |y: [f64; 3]| -> Vec<f64> {
        let mut k = vec![0.0; dt * de];
        ke.tensor(y, &mut k);
        k
    };
    let (k, kr) = (tensor(x), tensor(rx));
    let sign = |v: f64| if v < 0.0 { -1.0 } else { 1.0 };
    let out_sign: Vec<f64> = (0..dt).map(|a| sign(kr[a * de] * k[a * de])).collect();
    let in_sign: Vec<f64> = (0..de).map(|b| sign(kr[b] * k[b]) * out_sign[0]).collect();
    let scale = k.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for a in 0..dt {
        for b in 0..de {
            let want = out_sign[a] * in_sign[b] * k[a * de + b];
            if (kr[a * de + b] - want).abs() > 1e-12 * scale || k[a * de] == 0.0 || k[b] == 0.0 {
                return None;
            }
        }
    }
    Some((out_sign, in_sign))
}

/// A reflection `R` (a diagonal of ±1) of the cube surface, acting on a box's values as a
/// signed permutation: the surface point `u_k` goes to `u_π(k) = R u_k`, and a kernel
/// equivariant under `R` (`K(Rr) = S_out K(r) S_in`, with `S` diagonal signs per component:
/// `R` for vectors, 1 for scalars) gives, for a translation `T_o` between a box and its child
/// in octant `o = R(0)`,
///
/// ```text
///     T_o[(i,a),(j,b)] = s_out[a] s_in[b] T_0[(π(i),a),(π(j),b)],
/// ```
///
/// so `T_o x` is `T_0` applied to the reflected input, reflected back. Only octant 0's M2M and
/// L2L are formed (8× fewer kernel evaluations and 8× less memory: 1.6 GB → 0.2 GB for the
/// Stokes kernels at order 15).
#[derive(Clone, Debug)]
pub struct Reflection {
    perm: Vec<usize>,
    out_sign: Vec<f64>,
    in_sign: Vec<f64>,
}

impl Reflection {
    /// The reflection mapping octant 0 onto octant `o`, for kernel `ke` on `surf`; an error
    /// if the kernel is not equivariant under it (checked at a generic point).
    pub fn new(ke: &dyn Kernel, surf: &CubeSurface, o: usize) -> Result<Self, FmmError> {
        // Octant 0 is (−, −, −): octant o's signs are its own where its bits are 0.
        let r = reflection_of(o);
        let p = surf.p;
        let index: std::collections::HashMap<[usize; 3], usize> = surf
            .lattice
            .iter()
            .enumerate()
            .map(|(k, &l)| (l, k))
            .collect();
        let perm = surf
            .lattice
            .iter()
            .map(|l| {
                let m: [usize; 3] =
                    std::array::from_fn(|d| if r[d] < 0.0 { p - 1 - l[d] } else { l[d] });
                index[&m]
            })
            .collect();
        let (out_sign, in_sign) = reflection_signs(ke, r).ok_or_else(|| {
            FmmError::Shape(format!(
                "equivalent kernel {} is not equivariant under the reflections of the cube",
                ke.name()
            ))
        })?;
        Ok(Reflection {
            perm,
            out_sign,
            in_sign,
        })
    }

    /// `dst[(k,b)] = s_in[b] x[(π(k),b)]`: a box's input values (`x`, one box) reflected.
    pub fn gather(&self, x: &[f64], dst: &mut [f64]) {
        let de = self.in_sign.len();
        for (k, &pk) in self.perm.iter().enumerate() {
            for b in 0..de {
                dst[k * de + b] = self.in_sign[b] * x[pk * de + b];
            }
        }
    }

    /// `out[(i,a)] += s_out[a] y[(π(i),a)]`: octant 0's output `y` (one box) reflected back
    /// and added.
    pub fn scatter_add(&self, y: &[f64], out: &mut [f64]) {
        let dt = self.out_sign.len();
        for (i, &pi) in self.perm.iter().enumerate() {
            for a in 0..dt {
                out[i * dt + a] += self.out_sign[a] * y[pi * dt + a];
            }
        }
    }

    /// The reflected matrix `T_o` of octant 0's `t` (tests and references).
    pub fn apply_to_matrix(&self, t: &Mat<f64>) -> Mat<f64> {
        let (dt, de) = (self.out_sign.len(), self.in_sign.len());
        Mat::from_fn(t.nrows(), t.ncols(), |row, col| {
            let (i, a, j, b) = (row / dt, row % dt, col / de, col % de);
            self.out_sign[a] * self.in_sign[b] * t[(self.perm[i] * dt + a, self.perm[j] * de + b)]
        })
    }
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
        // Everything a fit depends on, for the cache: also the kernel's values at two fixed
        // points (to the bit), so that a changed kernel or normalisation never loads old fits.
        let fingerprint: Vec<String> = [[0.3, -0.5, 0.7], [1.1, 0.2, -0.4]]
            .iter()
            .flat_map(|&r| {
                let mut t = vec![0.0; ke.output_dim() * ke.density_dim()];
                ke.tensor(r, &mut t);
                t.into_iter().map(|v| format!("{:016x}", v.to_bits()))
            })
            .collect();
        let fingerprint = fingerprint.join("");
        let key = |what: &str, check: f64, equiv: f64| {
            format!(
                "{what} fit of {} p={p} rcond={rcond:e} check={check:e} equiv={equiv:e} kernel={fingerprint}",
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
                // A cache that cannot be written (read-only home, full disk) costs time, not
                // the result: say so once and go on.
                if let Err(e) = fit_cache::store(dir, &key, &f) {
                    fit_cache::warn_once(&e);
                }
            }
            Ok(f)
        };
        let (up, down) = rayon::join(
            || fit("upward", UP_CHECK, INNER),
            || fit("downward", INNER, DOWN_EQUIV),
        );
        let (up, down) = (up?, down?);
        // Octant 0's two translation matrices; the other octants are its reflections.
        let half = {
            let s = octant_sign(0);
            [s[0] / 2.0, s[1] / 2.0, s[2] / 2.0]
        };
        let (mut m2m, l2l) = rayon::join(
            || kernel_matrix(ke, &scaled(UP_CHECK, zero), &scaled(INNER / 2.0, half)),
            || kernel_matrix(ke, &scaled(INNER / 2.0, half), &scaled(DOWN_EQUIV, zero)),
        );
        for col in 0..m2m.ncols() {
            let f = 2f64.powi(degrees[col % de]);
            m2m.col_mut(col).iter_mut().for_each(|v| *v *= f);
        }
        let reflections = (0..8)
            .map(|o| Reflection::new(ke, &surf, o))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Translations {
            surf,
            degrees,
            up,
            down,
            m2m,
            l2l,
            reflections,
        })
    }

    /// Number of equivalent values per box (`points · density_dim`).
    pub fn n_equiv(&self) -> usize {
        self.m2m.ncols()
    }

    /// Number of check values per box (`points · output_dim`).
    pub fn n_check(&self) -> usize {
        self.m2m.nrows()
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fmm::kernels::{Laplace, Stokeslet, StokesletSource};

    /// A cache directory that cannot be created (a path below a regular file: refused even to
    /// root) costs the fits' time, not the setup; a writable one is filled and then used.
    #[test]
    fn an_unwritable_cache_does_not_fail_the_setup() {
        let file = std::env::temp_dir().join(format!("mobo-not-a-dir-{}", std::process::id()));
        std::fs::write(&file, b"x").unwrap();
        let bad = file.join("cache");
        let t = Translations::new(&Laplace, 4, 1e-12, Some(&bad)).unwrap();
        let direct = Translations::new(&Laplace, 4, 1e-12, None).unwrap();
        assert_eq!(t.up.vs, direct.up.vs);
        std::fs::remove_file(&file).unwrap();
        let good = std::env::temp_dir().join(format!("mobo-fit-dir-{}", std::process::id()));
        let first = Translations::new(&Laplace, 4, 1e-12, Some(&good)).unwrap();
        assert_eq!(
            std::fs::read_dir(&good).unwrap().count(),
            2,
            "two fits stored"
        );
        let second = Translations::new(&Laplace, 4, 1e-12, Some(&good)).unwrap();
        assert_eq!((first.down.ut, first.up.vs), (second.down.ut, second.up.vs));
        std::fs::remove_dir_all(&good).unwrap();
    }

    /// Every octant's M2M and L2L from octant 0's by reflection equal the kernel matrices
    /// formed directly, for each equivalent kernel.
    #[test]
    fn reflected_translations_equal_the_direct_matrices() {
        let kernels: [&dyn Kernel; 3] = [&Laplace, &Stokeslet, &StokesletSource];
        for ke in kernels {
            let p = 5;
            let t = Translations::new(ke, p, 1e-12, None).unwrap();
            let surf = &t.surf;
            let scaled = |rho: f64, shift: [f64; 3]| -> Vec<[f64; 3]> {
                surf.points
                    .iter()
                    .map(|u| std::array::from_fn(|d| shift[d] + rho * u[d]))
                    .collect()
            };
            let de = ke.density_dim();
            for o in 0..8 {
                let s = octant_sign(o);
                let half = [s[0] / 2.0, s[1] / 2.0, s[2] / 2.0];
                let mut m2m =
                    kernel_matrix(ke, &scaled(UP_CHECK, [0.0; 3]), &scaled(INNER / 2.0, half));
                for col in 0..m2m.ncols() {
                    let f = 2f64.powi(t.degrees[col % de]);
                    m2m.col_mut(col).iter_mut().for_each(|v| *v *= f);
                }
                let l2l = kernel_matrix(
                    ke,
                    &scaled(INNER / 2.0, half),
                    &scaled(DOWN_EQUIV, [0.0; 3]),
                );
                for (name, direct, base) in [("m2m", &m2m, &t.m2m), ("l2l", &l2l, &t.l2l)] {
                    let refl = t.reflections[o].apply_to_matrix(base);
                    let scale = direct.norm_max();
                    let err = (&refl - direct).norm_max();
                    assert!(
                        err <= 1e-13 * scale,
                        "{} {name} octant {o}: {err:e}",
                        ke.name()
                    );
                    // And the gather/scatter path used by the evaluator on one column.
                    let x: Vec<f64> = (0..base.ncols())
                        .map(|k| ((k * 7 % 13) as f64) - 6.0)
                        .collect();
                    let mut xr = vec![0.0; x.len()];
                    t.reflections[o].gather(&x, &mut xr);
                    let mut y = vec![0.0; base.nrows()];
                    gemm(base, &xr, &mut y, 1);
                    let mut out = vec![0.0; base.nrows()];
                    t.reflections[o].scatter_add(&y, &mut out);
                    let mut want = vec![0.0; base.nrows()];
                    gemm(direct, &x, &mut want, 1);
                    let e = out
                        .iter()
                        .zip(&want)
                        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
                    let w = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                    assert!(
                        e <= 1e-12 * w,
                        "{} {name} octant {o} applied: {e:e}",
                        ke.name()
                    );
                }
            }
        }
    }
}

//! Rotne–Prager–Yamakawa mobility.
//!
//! For beads of radius `a` and `D0 = k_BT/(6πηa)`, the diffusion tensor of the pair `(i, j)`,
//! `r = x_i − x_j`, is (Rotne & Prager 1969; Yamakawa 1970; overlap branch as in Wajnryb et al.
//! 2013):
//!
//! * `r ≥ 2a`: `D_ij = D0 [(3a/4r + a³/2r³) I + (3a/4r − 3a³/2r³) r̂r̂]`,
//! * `r < 2a`: `D_ij = D0 [(1 − 9r/32a) I + (3r/32a) r̂r̂]`,
//! * `D_ii = D0 I`.
//!
//! The functions here return blocks in units of `D0` (dimensionless). The mobility is symmetric
//! positive definite for every configuration, overlaps included, and divergence-free, so the
//! Ermak–McCammon step needs no drift correction.

use faer::Mat;
use rayon::prelude::*;

pub use crate::fmm::kernels::rpy_coefficients;

/// `D_ij / D0` for the separation `r = x_i − x_j ≠ 0`, row-major 3×3.
#[inline]
pub fn rpy_block(r: [f64; 3], a: f64) -> [[f64; 3]; 3] {
    let d2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
    let d = d2.sqrt();
    let (c_i, c_rr) = rpy_coefficients(d, a);
    let mut out = [[0.0; 3]; 3];
    for (k, row) in out.iter_mut().enumerate() {
        for (l, v) in row.iter_mut().enumerate() {
            *v = c_rr * r[k] * r[l] / d2 + if k == l { c_i } else { 0.0 };
        }
    }
    out
}

/// The dense `3N × 3N` mobility `D / D0` of a configuration (`positions` as `[x, y, z]`).
pub fn dense_mobility(positions: &[[f64; 3]], a: f64) -> Mat<f64> {
    let n = positions.len();
    let mut m = Mat::<f64>::zeros(3 * n, 3 * n);
    for i in 0..n {
        for k in 0..3 {
            m[(3 * i + k, 3 * i + k)] = 1.0;
        }
        for j in 0..n {
            if i == j {
                continue;
            }
            let r = sub(positions[i], positions[j]);
            let b = rpy_block(r, a);
            for k in 0..3 {
                for l in 0..3 {
                    m[(3 * i + k, 3 * j + l)] = b[k][l];
                }
            }
        }
    }
    m
}

/// `out = (D/D0) f` by direct summation, `O(N²)`, rayon over targets.
pub fn apply_mobility(positions: &[[f64; 3]], a: f64, f: &[[f64; 3]], out: &mut [[f64; 3]]) {
    out.par_iter_mut().enumerate().for_each(|(i, o)| {
        let mut acc = f[i];
        for (j, (pj, fj)) in positions.iter().zip(f).enumerate() {
            if i == j {
                continue;
            }
            let r = sub(positions[i], *pj);
            let d2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
            let (c_i, c_rr) = rpy_coefficients(d2.sqrt(), a);
            let rf = (r[0] * fj[0] + r[1] * fj[1] + r[2] * fj[2]) / d2;
            for k in 0..3 {
                acc[k] += c_i * fj[k] + c_rr * rf * r[k];
            }
        }
        *o = acc;
    });
}

#[inline]
pub(crate) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

//! Evaluation of the real orthonormal basis (see [`super::layout`]) at arbitrary points.

use std::f64::consts::PI;

use super::layout::CoefLayout;
use super::legendre::{legendre_table, tri_index, tri_len};

/// Scratch for [`eval_basis`].
pub struct BasisScratch {
    legendre: Vec<f64>,
}

impl BasisScratch {
    /// Scratch for order `p`.
    pub fn new(p: usize) -> Self {
        BasisScratch {
            legendre: vec![0.0; tri_len(p)],
        }
    }
}

/// `out[index(n, m)] = Y_n^m(θ, φ)` for every coefficient of `layout`.
pub fn eval_basis(
    layout: &CoefLayout,
    theta: f64,
    phi: f64,
    scratch: &mut BasisScratch,
    out: &mut [f64],
) {
    let p = layout.order();
    let (s, c) = theta.sin_cos();
    legendre_table(p, c, s.abs(), &mut scratch.legendre);
    let inv0 = 1.0 / (2.0 * PI).sqrt();
    let inv = 1.0 / PI.sqrt();
    for n in 0..=p {
        out[layout.cos_block(0) + n] = scratch.legendre[tri_index(p, n, 0)] * inv0;
    }
    for m in 1..=p {
        let (sm, cm) = (m as f64 * phi).sin_cos();
        let cb = layout.cos_block(m);
        let sb = layout.sin_block(m);
        for n in m..=p {
            let pl = scratch.legendre[tri_index(p, n, m)] * inv;
            out[cb + n - m] = pl * cm;
            if let Some(sb) = sb {
                out[sb + n - m] = pl * sm;
            }
        }
    }
}

/// Value of the expansion `Σ a_nm Y_n^m` at `(θ, φ)`.
pub fn evaluate(
    layout: &CoefLayout,
    coefs: &[f64],
    theta: f64,
    phi: f64,
    scratch: &mut BasisScratch,
    basis: &mut [f64],
) -> f64 {
    eval_basis(layout, theta, phi, scratch, basis);
    coefs.iter().zip(basis.iter()).map(|(a, y)| a * y).sum()
}

/// Colatitude and longitude of a (not necessarily unit) Cartesian vector.
pub fn angles_of(v: [f64; 3]) -> (f64, f64) {
    let rho = (v[0] * v[0] + v[1] * v[1]).sqrt();
    (rho.atan2(v[2]), v[1].atan2(v[0]))
}

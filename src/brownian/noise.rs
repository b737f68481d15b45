//! Correlated noise `B̃ξ` with `B̃B̃ᵀ = D̃` (`D̃ = D/D0`): exact references and the TEA-HI seam.
//!
//! * [`cholesky_factor`]: `D̃ = L Lᵀ`, `B̃ = L` (Ermak & McCammon 1978), `O(N³)`: the reference
//!   for small `N`.
//! * [`lanczos_sqrt`]: the Krylov approximation of `D̃^{1/2} ξ` (Chow & Saad, SIAM J. Sci.
//!   Comput. 36, 2014): `m` Lanczos steps with the matrix-free mobility give `V_m`, `T_m` and
//!   `D̃^{1/2}ξ ≈ ‖ξ‖ V_m T_m^{1/2} e₁`, stopped when successive iterates agree to `tol`.
//! * [`symmetric_sqrt`]: `D̃^{1/2}` by eigendecomposition, the oracle for the Lanczos test.
//! * TEA-HI lives in [`super::tea_hi`].

use faer::{Mat, Side};

use super::rpy::{apply_mobility, dense_mobility};
use super::BrownianError;

/// Lower Cholesky factor of `D̃` for a configuration.
pub fn cholesky_factor(positions: &[[f64; 3]], a: f64) -> Result<Mat<f64>, BrownianError> {
    let d = dense_mobility(positions, a);
    let llt = d
        .llt(Side::Lower)
        .map_err(|_| BrownianError::NotPositiveDefinite)?;
    Ok(llt.L().to_owned())
}

/// `D̃^{1/2}` (symmetric square root) by eigendecomposition.
pub fn symmetric_sqrt(m: &Mat<f64>) -> Result<Mat<f64>, BrownianError> {
    let evd = m
        .self_adjoint_eigen(Side::Lower)
        .map_err(|_| BrownianError::NotPositiveDefinite)?;
    let u = evd.U();
    let s = evd.S().column_vector();
    let n = m.nrows();
    let mut out = Mat::<f64>::zeros(n, n);
    for k in 0..n {
        if s[k] < 0.0 {
            return Err(BrownianError::NotPositiveDefinite);
        }
        let r = s[k].sqrt();
        for i in 0..n {
            let ui = u[(i, k)] * r;
            for j in 0..n {
                out[(i, j)] += ui * u[(j, k)];
            }
        }
    }
    Ok(out)
}

/// Result of a Lanczos square root.
#[derive(Clone, Debug)]
pub struct LanczosResult {
    /// `≈ D̃^{1/2} ξ`, per particle.
    pub value: Vec<[f64; 3]>,
    /// Lanczos steps taken.
    pub iterations: usize,
    /// Relative change of the last step.
    pub last_change: f64,
}

/// `D̃^{1/2} ξ` by Lanczos with full reorthogonalisation, matrix-free.
pub fn lanczos_sqrt(
    positions: &[[f64; 3]],
    a: f64,
    xi: &[[f64; 3]],
    tol: f64,
    max_iter: usize,
) -> Result<LanczosResult, BrownianError> {
    let n3 = 3 * positions.len();
    let flat = |v: &[[f64; 3]]| -> Vec<f64> { v.iter().flat_map(|x| x.iter().copied()).collect() };
    let xi_flat = flat(xi);
    let norm = xi_flat.iter().map(|x| x * x).sum::<f64>().sqrt();
    if norm == 0.0 {
        return Ok(LanczosResult {
            value: vec![[0.0; 3]; positions.len()],
            iterations: 0,
            last_change: 0.0,
        });
    }
    let mut basis: Vec<Vec<f64>> = vec![xi_flat.iter().map(|x| x / norm).collect()];
    let (mut alpha, mut beta) = (Vec::<f64>::new(), Vec::<f64>::new());
    let mut prev: Option<Vec<f64>> = None;
    let mut tmp_in = vec![[0.0; 3]; positions.len()];
    let mut tmp_out = vec![[0.0; 3]; positions.len()];
    let max_iter = max_iter.min(n3).max(1);
    let mut last_change = f64::INFINITY;
    for k in 0..max_iter {
        for (t, c) in tmp_in.iter_mut().zip(basis[k].chunks_exact(3)) {
            *t = [c[0], c[1], c[2]];
        }
        apply_mobility(positions, a, &tmp_in, &mut tmp_out);
        let mut w = flat(&tmp_out);
        let ak: f64 = w.iter().zip(&basis[k]).map(|(x, y)| x * y).sum();
        alpha.push(ak);
        // Full reorthogonalisation (twice is enough).
        for _ in 0..2 {
            for v in &basis {
                let c: f64 = w.iter().zip(v).map(|(x, y)| x * y).sum();
                for (x, y) in w.iter_mut().zip(v) {
                    *x -= c * y;
                }
            }
        }
        let bk = w.iter().map(|x| x * x).sum::<f64>().sqrt();
        // Current approximation ‖ξ‖ V T^{1/2} e₁.
        let m = alpha.len();
        let t = Mat::<f64>::from_fn(m, m, |i, j| {
            if i == j {
                alpha[i]
            } else if i + 1 == j || j + 1 == i {
                beta[i.min(j)]
            } else {
                0.0
            }
        });
        let ts = symmetric_sqrt(&t)?;
        let mut y = vec![0.0; n3];
        for (j, v) in basis.iter().enumerate().take(m) {
            let c = norm * ts[(j, 0)];
            for (yy, vv) in y.iter_mut().zip(v) {
                *yy += c * vv;
            }
        }
        if let Some(p) = &prev {
            let dn: f64 = y
                .iter()
                .zip(p)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt();
            let yn: f64 = y.iter().map(|a| a * a).sum::<f64>().sqrt();
            last_change = dn / yn;
        }
        let converged = last_change < tol || bk <= 1e-14 * norm || m == n3;
        if converged || k + 1 == max_iter {
            return Ok(LanczosResult {
                value: y.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
                iterations: m,
                last_change,
            });
        }
        prev = Some(y);
        beta.push(bk);
        basis.push(w.iter().map(|x| x / bk).collect());
    }
    unreachable!("the loop returns at its last iteration")
}

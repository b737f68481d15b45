//! The Gauss–Legendre × uniform grid of order `p`.
//!
//! Latitudes: the `p+1` Gauss–Legendre nodes `x_i = cos θ_i` on `(-1, 1)`, ordered from the
//! north pole southwards (`θ_0 < θ_1 < …`), with weights `w_i` (`Σ w_i = 2`).
//! Longitudes: `2p` uniform angles `φ_k = kπ/p`. Grid values of one function are stored
//! latitude-major: value `(i, k)` at index `i·2p + k`, `2p(p+1)` points in all. No node lies on a
//! pole. The quadrature `∫_{S²} f dA ≈ Σ_{i,k} w_i (π/p) f(θ_i, φ_k)` is exact for spherical
//! harmonics of degree below `2p` (Gauss in `cos θ`, trapezoid in `φ`).

use std::f64::consts::PI;

/// Gauss–Legendre nodes and weights on `[-1, 1]`, nodes in decreasing order (`x_0` closest to 1).
///
/// Newton's iteration on the three-term recurrence for `P_n`, started from Tricomi's
/// asymptotic guess; converges to round-off for the orders used here (`n ≤ a few hundred`).
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut x = vec![0.0; n];
    let mut w = vec![0.0; n];
    let nf = n as f64;
    for i in 0..n.div_ceil(2) {
        // Tricomi's initial guess for the i-th root (descending).
        let theta = PI * (i as f64 + 0.75) / (nf + 0.5);
        let mut z = (1.0 - (nf - 1.0) / (8.0 * nf * nf * nf)) * theta.cos();
        let mut dp = 0.0;
        for _ in 0..100 {
            let (pn, dpn) = legendre_and_derivative(n, z);
            dp = dpn;
            let dz = pn / dpn;
            z -= dz;
            if dz.abs() <= 1e-16 * z.abs().max(1e-300) {
                break;
            }
        }
        let (_, dpn) = legendre_and_derivative(n, z);
        if dpn != 0.0 {
            dp = dpn;
        }
        let wi = 2.0 / ((1.0 - z * z) * dp * dp);
        x[i] = z;
        w[i] = wi;
        x[n - 1 - i] = -z;
        w[n - 1 - i] = wi;
    }
    if n % 2 == 1 {
        x[n / 2] = 0.0;
    }
    (x, w)
}

/// `P_n(z)` and `P_n'(z)` by the three-term recurrence.
fn legendre_and_derivative(n: usize, z: f64) -> (f64, f64) {
    let mut p0 = 1.0;
    let mut p1 = z;
    if n == 0 {
        return (1.0, 0.0);
    }
    for k in 2..=n {
        let kf = k as f64;
        let p2 = ((2.0 * kf - 1.0) * z * p1 - (kf - 1.0) * p0) / kf;
        p0 = p1;
        p1 = p2;
    }
    let nf = n as f64;
    (p1, nf * (z * p1 - p0) / (z * z - 1.0))
}

/// The spherical grid of order `p`.
#[derive(Clone, Debug)]
pub struct Grid {
    p: usize,
    /// `cos θ_i`, `p+1` values, decreasing.
    pub cos_theta: Vec<f64>,
    /// `sin θ_i` (positive).
    pub sin_theta: Vec<f64>,
    /// `θ_i` in `(0, π)`, increasing.
    pub theta: Vec<f64>,
    /// Gauss–Legendre weights in `cos θ`.
    pub gl_weights: Vec<f64>,
    /// `φ_k = kπ/p`, `2p` values.
    pub phi: Vec<f64>,
}

impl Grid {
    /// The grid of order `p ≥ 1`.
    pub fn new(p: usize) -> Self {
        assert!(p >= 1, "spherical grid order must be at least 1");
        let (x, w) = gauss_legendre(p + 1);
        // sin θ from (1-x)(1+x) keeps accuracy near the poles.
        let sin_theta: Vec<f64> = x.iter().map(|&c| ((1.0 - c) * (1.0 + c)).sqrt()).collect();
        let theta = x
            .iter()
            .zip(&sin_theta)
            .map(|(&c, &s)| s.atan2(c))
            .collect();
        let phi = (0..2 * p).map(|k| k as f64 * PI / p as f64).collect();
        Grid {
            p,
            cos_theta: x,
            sin_theta,
            theta,
            gl_weights: w,
            phi,
        }
    }

    /// The order `p`.
    pub fn order(&self) -> usize {
        self.p
    }
    /// Number of latitudes, `p+1`.
    pub fn n_lat(&self) -> usize {
        self.p + 1
    }
    /// Number of longitudes, `2p`.
    pub fn n_lon(&self) -> usize {
        2 * self.p
    }
    /// Number of grid points, `2p(p+1)`.
    pub fn n_points(&self) -> usize {
        2 * self.p * (self.p + 1)
    }
    /// Quadrature weight of every point (area element of the unit sphere included):
    /// `w_i π/p`, latitude-major like grid values.
    pub fn quadrature_weights(&self) -> Vec<f64> {
        let dphi = PI / self.p as f64;
        let mut out = Vec::with_capacity(self.n_points());
        for &w in &self.gl_weights {
            out.extend(std::iter::repeat_n(w * dphi, self.n_lon()));
        }
        out
    }
    /// `(θ, φ)` of point `j` (latitude-major index).
    pub fn angles(&self, j: usize) -> (f64, f64) {
        let nl = self.n_lon();
        (self.theta[j / nl], self.phi[j % nl])
    }
    /// Unit-sphere coordinates of every point, `[x, y, z]` per point.
    pub fn unit_points(&self) -> Vec<[f64; 3]> {
        let mut out = Vec::with_capacity(self.n_points());
        for i in 0..self.n_lat() {
            for &ph in &self.phi {
                let s = self.sin_theta[i];
                out.push([s * ph.cos(), s * ph.sin(), self.cos_theta[i]]);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gauss_legendre_integrates_polynomials_exactly() {
        for n in 1..=70 {
            let (x, w) = gauss_legendre(n);
            for deg in 0..2 * n {
                let got: f64 = x
                    .iter()
                    .zip(&w)
                    .map(|(&x, &w)| w * x.powi(deg as i32))
                    .sum();
                let want = if deg % 2 == 1 {
                    0.0
                } else {
                    2.0 / (deg as f64 + 1.0)
                };
                assert!(
                    (got - want).abs() < 1e-14,
                    "n={n} deg={deg}: {got} vs {want}"
                );
            }
            assert!(x.windows(2).all(|s| s[0] > s[1]));
        }
    }
}

//! Naive reference implementations, written independently of the fast paths, for tests.
//!
//! * Legendre functions: the *unnormalised* recurrence in `n` (`P_m^m = (2m−1)!! sin^m θ`,
//!   `(n−m) P_n^m = (2n−1) x P_{n−1}^m − (n+m−1) P_{n−2}^m`), normalised afterwards by the explicit
//!   product `√((2n+1)/2 · (n−m)!/(n+m)!)` (fine in `f64` up to `p ≈ 80`).
//! * `θ`-derivatives from the ladder relations in `m` (no Condon–Shortley phase):
//!   `dP_n^0/dθ = −P_n^1`, `dP_n^m/dθ = ½[(n+m)(n−m+1) P_n^{m−1} − P_n^{m+1}]`, applied twice for the
//!   second derivative (the fast path uses the recurrence in `n` and Legendre's equation instead).
//! * Transforms by direct summation over basis functions and grid points; the discrete norms of
//!   the forward quadrature are computed, not assumed.
//! * Rotations by evaluating the expansion at rotated points.

use std::f64::consts::PI;

use super::grid::Grid;
use super::layout::CoefLayout;
use super::rotation::{rotate_y, rotate_z};
use super::transform::Deriv;

/// Unnormalised `P_n^m(cos θ)` (no Condon–Shortley phase); zero for `m > n`.
pub fn legendre_unnormalized(n: usize, m: usize, theta: f64) -> f64 {
    if m > n {
        return 0.0;
    }
    let (s, x) = theta.sin_cos();
    let mut pmm = 1.0;
    for k in 1..=m {
        pmm *= (2 * k - 1) as f64 * s;
    }
    if n == m {
        return pmm;
    }
    let mut p0 = pmm;
    let mut p1 = x * (2 * m + 1) as f64 * pmm;
    for l in m + 2..=n {
        let p2 = ((2 * l - 1) as f64 * x * p1 - (l + m - 1) as f64 * p0) / (l - m) as f64;
        p0 = p1;
        p1 = p2;
    }
    p1
}

fn norm(n: usize, m: usize) -> f64 {
    let mut ratio = 1.0;
    for k in (n - m + 1)..=(n + m) {
        ratio /= k as f64;
    }
    ((2 * n + 1) as f64 / 2.0 * ratio).sqrt()
}

/// `d^k P_n^m(cos θ) / dθ^k` (unnormalised) for `k = 0, 1, 2` by the ladder relations.
fn legendre_dtheta(n: usize, m: usize, theta: f64, k: u32) -> f64 {
    if m > n {
        return 0.0;
    }
    if k == 0 {
        return legendre_unnormalized(n, m, theta);
    }
    if m == 0 {
        return -legendre_dtheta(n, 1, theta, k - 1);
    }
    let a = ((n + m) * (n - m + 1)) as f64;
    0.5 * (a * legendre_dtheta(n, m - 1, theta, k - 1) - legendre_dtheta(n, m + 1, theta, k - 1))
}

/// `∂_θ^a ∂_φ^b Y_n^m(θ, φ)` of the real orthonormal basis (`m < 0`: sine functions).
pub fn ylm_derivative(n: usize, m: isize, theta: f64, phi: f64, a: u32, b: u32) -> f64 {
    let am = m.unsigned_abs();
    let radial = norm(n, am) * legendre_dtheta(n, am, theta, a);
    if am == 0 {
        return if b == 0 {
            radial / (2.0 * PI).sqrt()
        } else {
            0.0
        };
    }
    let mf = am as f64;
    let arg = mf * phi;
    // Derivatives of cos(mφ) and sin(mφ).
    let trig = match (m > 0, b % 4) {
        (true, 0) => arg.cos(),
        (true, 1) => -mf * arg.sin(),
        (true, 2) => -mf * mf * arg.cos(),
        (true, _) => mf * mf * mf * arg.sin(),
        (false, 0) => arg.sin(),
        (false, 1) => mf * arg.cos(),
        (false, 2) => -mf * mf * arg.sin(),
        (false, _) => -mf * mf * mf * arg.cos(),
    };
    radial * trig / PI.sqrt()
}

/// `Y_n^m(θ, φ)`.
pub fn ylm(n: usize, m: isize, theta: f64, phi: f64) -> f64 {
    ylm_derivative(n, m, theta, phi, 0, 0)
}

/// Orders of derivative `(θ, φ)` of a [`Deriv`].
pub fn deriv_orders(d: Deriv) -> (u32, u32) {
    match d {
        Deriv::Value => (0, 0),
        Deriv::Theta => (1, 0),
        Deriv::Phi => (0, 1),
        Deriv::ThetaTheta => (2, 0),
        Deriv::ThetaPhi => (1, 1),
        Deriv::PhiPhi => (0, 2),
    }
}

/// The requested derivative of one expansion at arbitrary `(θ, φ)` points, by direct summation.
pub fn synthesize_at(layout: &CoefLayout, coefs: &[f64], pts: &[(f64, f64)], d: Deriv) -> Vec<f64> {
    let (a, b) = deriv_orders(d);
    let modes = layout.modes();
    pts.iter()
        .map(|&(t, f)| {
            modes
                .iter()
                .zip(coefs)
                .map(|(&(n, m), &c)| c * ylm_derivative(n, m, t, f, a, b))
                .sum()
        })
        .collect()
}

/// The requested derivative of one expansion on the grid of order `p`.
pub fn synthesize_grid(layout: &CoefLayout, coefs: &[f64], d: Deriv) -> Vec<f64> {
    let grid = Grid::new(layout.order());
    let pts: Vec<_> = (0..grid.n_points()).map(|j| grid.angles(j)).collect();
    synthesize_at(layout, coefs, &pts, d)
}

/// Forward transform of one function by direct quadrature:
/// `a_nm = Σ_j W_j f_j Y_nm(x_j) / Σ_j W_j Y_nm(x_j)²`.
pub fn forward(layout: &CoefLayout, values: &[f64]) -> Vec<f64> {
    let grid = Grid::new(layout.order());
    let w = grid.quadrature_weights();
    layout
        .modes()
        .iter()
        .map(|&(n, m)| {
            let (mut num, mut den) = (0.0, 0.0);
            for (j, (&f, &wj)) in values.iter().zip(&w).enumerate() {
                let (t, ph) = grid.angles(j);
                let y = ylm(n, m, t, ph);
                num += wj * f * y;
                den += wj * y * y;
            }
            num / den
        })
        .collect()
}

/// Values `f(Q y_j)` on the order-`q` grid, `Q = R_z(φ_k) R_y(θ_i)` for target `(lat, lon)` of
/// the order-`p` grid, by evaluating the expansion at the rotated points.
pub fn rotate(layout: &CoefLayout, coefs: &[f64], lat: usize, lon: usize, q: usize) -> Vec<f64> {
    let src = Grid::new(layout.order());
    let dst = Grid::new(q);
    let (bt, bp) = (src.theta[lat], src.phi[lon]);
    let pts: Vec<(f64, f64)> = dst
        .unit_points()
        .into_iter()
        .map(|y| {
            let v = rotate_z(bp, rotate_y(bt, y));
            let rho = (v[0] * v[0] + v[1] * v[1]).sqrt();
            (rho.atan2(v[2]), v[1].atan2(v[0]))
        })
        .collect();
    synthesize_at(layout, coefs, &pts, Deriv::Value)
}

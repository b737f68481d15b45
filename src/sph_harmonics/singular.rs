//! Graham–Sloan quadrature for on-surface integrals of `1/r`-singular kernels.
//!
//! After the target has been rotated to the north pole (see [`super::rotation`]), an integral
//! `∫ K(x, y) f(y) dA(y)` with `K ~ 1/r` is computed on the grid of order `q` as
//! `Σ_{i,k} ω_i f(θ_i, φ_k) J(θ_i, φ_k) / r(θ_i, φ_k)` (times the kernel's smooth factor), with
//! latitude weights (Graham & Sloan, SIAM J. Numer. Anal. 39, 2002; Veerapaneni et al. 2011)
//!
//! `ω_i = (π/q) w_i (Σ_{n=0}^{q} P_n(cos θ_i)) · 2 sin(θ_i/2)`,
//!
//! where `w_i` are the Gauss–Legendre weights and `J = |X_θ × X_φ| / sin θ` the area element per
//! unit solid angle. The truncated Legendre sum is the degree-`q` part of
//! `1/(2 sin(θ/2)) = Σ_n P_n(cos θ)`, which cancels the chordal `1/r` singularity at the pole; for
//! a density of degree `≤ q` on the unit sphere the rule is exact.

use super::grid::Grid;

/// Graham–Sloan weights of the order-`q` grid.
#[derive(Clone, Debug)]
pub struct GrahamSloan {
    q: usize,
    /// `ω_i`, one per latitude.
    pub latitude_weights: Vec<f64>,
}

impl GrahamSloan {
    /// Weights for the grid of order `q ≥ 1`.
    pub fn new(q: usize) -> Self {
        let grid = Grid::new(q);
        let dphi = std::f64::consts::PI / q as f64;
        let latitude_weights = grid
            .cos_theta
            .iter()
            .zip(&grid.gl_weights)
            .map(|(&x, &w)| {
                // Σ_{n=0}^{q} P_n(x) by the three-term recurrence.
                let (mut p0, mut p1) = (1.0, x);
                let mut sum = 1.0 + if q >= 1 { x } else { 0.0 };
                for n in 2..=q {
                    let nf = n as f64;
                    let p2 = ((2.0 * nf - 1.0) * x * p1 - (nf - 1.0) * p0) / nf;
                    sum += p2;
                    p0 = p1;
                    p1 = p2;
                }
                let half_sin = ((1.0 - x) / 2.0).sqrt();
                dphi * w * sum * 2.0 * half_sin
            })
            .collect();
        GrahamSloan {
            q,
            latitude_weights,
        }
    }
    /// The grid order `q`.
    pub fn order(&self) -> usize {
        self.q
    }
    /// The weight of every grid point, latitude-major (each latitude weight repeated `2q` times).
    pub fn point_weights(&self) -> Vec<f64> {
        self.latitude_weights
            .iter()
            .flat_map(|&w| std::iter::repeat_n(w, 2 * self.q))
            .collect()
    }
}

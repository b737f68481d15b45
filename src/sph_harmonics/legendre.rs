//! Normalised associated Legendre functions and their `θ`-derivatives.
//!
//! `P̄_n^m(x)`, `x = cos θ`, normalised so that `∫_{-1}^{1} (P̄_n^m)² dx = 1`, without the
//! Condon–Shortley phase. Computed by the standard stable recurrences (e.g. Holmes & Featherstone,
//! J. Geodesy 76, 2002):
//!
//! * `P̄_0^0 = 1/√2`, `P̄_m^m = √((2m+1)/(2m)) sin θ P̄_{m-1}^{m-1}`,
//! * `P̄_{m+1}^m = √(2m+3) x P̄_m^m`,
//! * `P̄_n^m = a_{nm} (x P̄_{n-1}^m − b_{nm} P̄_{n-2}^m)`, with
//!   `a_{nm} = √((4n²−1)/(n²−m²))`, `b_{nm} = √(((n−1)²−m²)/(4(n−1)²−1))`.
//!
//! Derivatives (valid away from the poles, where every grid node lies):
//!
//! * `dP̄_n^m/dθ = (n x P̄_n^m − √((2n+1)(n²−m²)/(2n−1)) P̄_{n-1}^m) / sin θ`,
//! * `d²P̄_n^m/dθ² = −cot θ dP̄_n^m/dθ − (n(n+1) − m²/sin²θ) P̄_n^m` (Legendre's equation).

/// Index of `(n, m)` (`0 ≤ m ≤ n ≤ p`) in a triangular table: `m`-major, `n = m..=p` contiguous.
#[inline]
pub fn tri_index(p: usize, n: usize, m: usize) -> usize {
    // Offset of order m: Σ_{k<m} (p+1-k) = m(p+1) − m(m−1)/2.
    m * (p + 1) - m * (m.saturating_sub(1)) / 2 + (n - m)
}

/// Size of the triangular table of order `p`.
#[inline]
pub fn tri_len(p: usize) -> usize {
    (p + 1) * (p + 2) / 2
}

/// Fill `out[tri_index(p, n, m)] = P̄_n^m(cos θ)` for all `0 ≤ m ≤ n ≤ p`.
pub fn legendre_table(p: usize, cos_theta: f64, sin_theta: f64, out: &mut [f64]) {
    assert!(out.len() >= tri_len(p));
    let x = cos_theta;
    let mut pmm = std::f64::consts::FRAC_1_SQRT_2;
    for m in 0..=p {
        if m > 0 {
            let mf = m as f64;
            pmm *= ((2.0 * mf + 1.0) / (2.0 * mf)).sqrt() * sin_theta;
        }
        let base = tri_index(p, m, m);
        out[base] = pmm;
        if m < p {
            out[base + 1] = (2.0 * m as f64 + 3.0).sqrt() * x * pmm;
        }
        let mf = m as f64;
        for n in m + 2..=p {
            let nf = n as f64;
            let a = ((4.0 * nf * nf - 1.0) / (nf * nf - mf * mf)).sqrt();
            let b = (((nf - 1.0) * (nf - 1.0) - mf * mf) / (4.0 * (nf - 1.0) * (nf - 1.0) - 1.0))
                .sqrt();
            out[base + n - m] = a * (x * out[base + n - m - 1] - b * out[base + n - m - 2]);
        }
    }
}

/// `P̄`, `dP̄/dθ` and `d²P̄/dθ²` at one colatitude (not a pole), triangular tables.
pub fn legendre_derivative_tables(
    p: usize,
    cos_theta: f64,
    sin_theta: f64,
    val: &mut [f64],
    d1: &mut [f64],
    d2: &mut [f64],
) {
    legendre_table(p, cos_theta, sin_theta, val);
    let x = cos_theta;
    let s = sin_theta;
    for m in 0..=p {
        let mf = m as f64;
        for n in m..=p {
            let nf = n as f64;
            let idx = tri_index(p, n, m);
            let prev = if n > m {
                val[idx - 1] * ((2.0 * nf + 1.0) * (nf * nf - mf * mf) / (2.0 * nf - 1.0)).sqrt()
            } else {
                0.0
            };
            let dp = (nf * x * val[idx] - prev) / s;
            d1[idx] = dp;
            d2[idx] = -(x / s) * dp - (nf * (nf + 1.0) - mf * mf / (s * s)) * val[idx];
        }
    }
}

/// The recurrences of [`legendre_table`] and [`legendre_derivative_tables`] with their
/// coefficients computed once for an order `p`: no square roots or divisions per entry at
/// evaluation (the tables of a point evaluation are rebuilt at every point, so they are hot in
/// the reparametrisation and the near-zone evaluation).
#[derive(Clone, Debug)]
pub struct LegendreRecurrence {
    p: usize,
    /// `√((2m+1)/(2m))` for `m = 1 … p` (index `m`).
    diag: Vec<f64>,
    /// `√(2m+3)` (index `m`).
    sub: Vec<f64>,
    /// `a_{nm}` and `a_{nm} b_{nm}` per triangular index (zero where unused).
    a: Vec<f64>,
    ab: Vec<f64>,
    /// `√((2n+1)(n²−m²)/(2n−1))` per triangular index (zero for `n = m`).
    prev: Vec<f64>,
}

impl LegendreRecurrence {
    /// Coefficients for order `p`.
    pub fn new(p: usize) -> Self {
        let len = tri_len(p);
        let (mut a, mut ab, mut prev) = (vec![0.0; len], vec![0.0; len], vec![0.0; len]);
        for m in 0..=p {
            let mf = m as f64;
            for n in m..=p {
                let nf = n as f64;
                let idx = tri_index(p, n, m);
                if n >= m + 2 {
                    let an = ((4.0 * nf * nf - 1.0) / (nf * nf - mf * mf)).sqrt();
                    let bn = (((nf - 1.0) * (nf - 1.0) - mf * mf)
                        / (4.0 * (nf - 1.0) * (nf - 1.0) - 1.0))
                        .sqrt();
                    a[idx] = an;
                    ab[idx] = an * bn;
                }
                if n > m {
                    prev[idx] = ((2.0 * nf + 1.0) * (nf * nf - mf * mf) / (2.0 * nf - 1.0)).sqrt();
                }
            }
        }
        LegendreRecurrence {
            p,
            diag: (0..=p)
                .map(|m| {
                    let mf = m.max(1) as f64;
                    ((2.0 * mf + 1.0) / (2.0 * mf)).sqrt()
                })
                .collect(),
            sub: (0..=p).map(|m| (2.0 * m as f64 + 3.0).sqrt()).collect(),
            a,
            ab,
            prev,
        }
    }

    /// The order `p`.
    pub fn order(&self) -> usize {
        self.p
    }

    /// [`legendre_table`] of order `p`.
    pub fn table(&self, cos_theta: f64, sin_theta: f64, out: &mut [f64]) {
        let p = self.p;
        assert!(out.len() >= tri_len(p));
        let x = cos_theta;
        let mut pmm = std::f64::consts::FRAC_1_SQRT_2;
        for m in 0..=p {
            if m > 0 {
                pmm *= self.diag[m] * sin_theta;
            }
            let base = tri_index(p, m, m);
            let row = &mut out[base..base + p + 1 - m];
            row[0] = pmm;
            if m < p {
                row[1] = self.sub[m] * x * pmm;
            }
            let (a, ab) = (
                &self.a[base..base + p + 1 - m],
                &self.ab[base..base + p + 1 - m],
            );
            for k in 2..row.len() {
                row[k] = a[k] * x * row[k - 1] - ab[k] * row[k - 2];
            }
        }
    }

    /// [`legendre_derivative_tables`] of order `p` (not at a pole).
    pub fn derivative_tables(
        &self,
        cos_theta: f64,
        sin_theta: f64,
        val: &mut [f64],
        d1: &mut [f64],
        d2: &mut [f64],
    ) {
        let p = self.p;
        self.table(cos_theta, sin_theta, val);
        let x = cos_theta;
        let inv_s = 1.0 / sin_theta;
        let cot = x * inv_s;
        let inv_s2 = inv_s * inv_s;
        for m in 0..=p {
            let mf = m as f64;
            let m2 = mf * mf * inv_s2;
            let base = tri_index(p, m, m);
            for n in m..=p {
                let nf = n as f64;
                let idx = base + n - m;
                let prev = if n > m {
                    val[idx - 1] * self.prev[idx]
                } else {
                    0.0
                };
                let dp = (nf * x * val[idx] - prev) * inv_s;
                d1[idx] = dp;
                d2[idx] = -cot * dp - (nf * (nf + 1.0) - m2) * val[idx];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The precomputed recurrence against the reference recurrences, at orders 1–40 and
    /// colatitudes across `(0, π)`.
    #[test]
    fn precomputed_recurrence_equals_the_reference() {
        for p in [1usize, 2, 5, 12, 16, 40] {
            let rec = LegendreRecurrence::new(p);
            let n = tri_len(p);
            let (mut v0, mut d10, mut d20) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
            let (mut v1, mut d11, mut d21) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
            for k in 1..20 {
                let theta = k as f64 * std::f64::consts::PI / 20.0 - 0.013;
                let (s, c) = theta.sin_cos();
                legendre_derivative_tables(p, c, s, &mut v0, &mut d10, &mut d20);
                rec.derivative_tables(c, s, &mut v1, &mut d11, &mut d21);
                for (name, a, b) in [("P", &v1, &v0), ("dP", &d11, &d10), ("d2P", &d21, &d20)] {
                    let scale = b.iter().fold(1.0f64, |m, x| m.max(x.abs()));
                    for (i, (x, y)) in a.iter().zip(b.iter()).enumerate() {
                        assert!(
                            (x - y).abs() <= 1e-13 * scale,
                            "{name}, p = {p}, θ = {theta}, entry {i}: {x} vs {y}"
                        );
                    }
                }
            }
        }
    }
}

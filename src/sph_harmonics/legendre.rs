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

//! TEA-HI: the truncated expansion approximation of the correlated noise (Geyer & Winter,
//! J. Chem. Phys. 130, 114905, 2009), in one fused `O(N²)` pass that never stores `D`.
//!
//! With `D̃ = D/D0` (so `D̃_ii = 1`), the noise matrix `B̃ ≈ D̃^{1/2}` is
//!
//! * `ε` = mean of the entries of the off-diagonal particle blocks `D̃_ij`,
//! * `A = (3N−1)ε² − (3N−2)ε`, `β' = (1 − √(1 − A))/A = 1/(1 + √(1 − A))`,
//! * `C_k = [1 + β'² Σ_{l ∉ particle(k)} D̃_kl²]^{−1/2}` for each of the `3N` rows `k`,
//! * `B̃_kk = C_k`, `B̃_kl = C_k β' D̃_kl` (other particles), zero within a particle.
//!
//! The noise `B̃ξ` is `C_k (ξ_k + β' Σ_l D̃_kl ξ_l)`, linear in the row sums `Σ_l D̃_kl ξ_l` and
//! `Σ_l D̃_kl²`, which are accumulated in the same pass as the deterministic `Σ_l D̃_kl F_l` and the
//! sum of all entries for `ε`: four partial sums per row, as in the reference GPU implementation.
//! The Ermak–McCammon displacement is then `Δr = D0 Δt/(k_BT) D̃F + √(2 D0 Δt) B̃ξ`.
//!
//! The pair loop is written over structure-of-arrays coordinates in chunks of four lanes, with an
//! AVX2+FMA version selected at run time and the portable one kept as the reference.

use rayon::prelude::*;

/// Per-row sums of one fused pass.
#[derive(Clone, Debug, Default)]
pub struct FusedSums {
    /// `Σ_j D̃_ij F_j` (self term included), per particle.
    pub drift: Vec<[f64; 3]>,
    /// `Σ_{j≠i} D̃_ij ξ_j`, per particle.
    pub noise_sum: Vec<[f64; 3]>,
    /// `Σ_{j≠i} Σ_l D̃_ij[k][l]²` per row `k` of particle `i`.
    pub square_sum: Vec<[f64; 3]>,
    /// Sum of all entries of the off-diagonal blocks.
    pub entry_sum: f64,
}

/// The TEA-HI coefficients of a configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TeaHiCoefficients {
    /// Mean off-diagonal coupling `ε`.
    pub epsilon: f64,
    /// `β'`.
    pub beta: f64,
}

impl TeaHiCoefficients {
    /// `ε` from the entry sum and `β'` from `ε` for `n` particles. `None` if `A > 1` (the
    /// expansion does not exist: couplings too strong for TEA-HI).
    pub fn from_entry_sum(entry_sum: f64, n: usize) -> Option<Self> {
        if n < 2 {
            return Some(TeaHiCoefficients {
                epsilon: 0.0,
                beta: 0.5,
            });
        }
        let nf = n as f64;
        let epsilon = entry_sum / (9.0 * nf * (nf - 1.0));
        let m = 3.0 * nf;
        let a = (m - 1.0) * epsilon * epsilon - (m - 2.0) * epsilon;
        if a > 1.0 {
            return None;
        }
        Some(TeaHiCoefficients {
            epsilon,
            beta: 1.0 / (1.0 + (1.0 - a).sqrt()),
        })
    }
}

/// Coordinates in structure-of-arrays form.
#[derive(Clone, Debug, Default)]
pub struct Soa {
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub z: Vec<f64>,
}

impl Soa {
    /// From `[x, y, z]` triples.
    pub fn from_points(p: &[[f64; 3]]) -> Self {
        Soa {
            x: p.iter().map(|v| v[0]).collect(),
            y: p.iter().map(|v| v[1]).collect(),
            z: p.iter().map(|v| v[2]).collect(),
        }
    }
    /// Overwrite from `[x, y, z]` triples.
    pub fn fill(&mut self, p: &[[f64; 3]]) {
        self.x.clear();
        self.y.clear();
        self.z.clear();
        for v in p {
            self.x.push(v[0]);
            self.y.push(v[1]);
            self.z.push(v[2]);
        }
    }
}

/// The fused pass: drift, noise sum, square sums and entry sum for every particle.
/// `pos`, `force` and `xi` are structure-of-arrays of the same length.
pub fn fused_pass(pos: &Soa, force: &Soa, xi: &Soa, a: f64, out: &mut FusedSums) {
    let n = pos.x.len();
    out.drift.resize(n, [0.0; 3]);
    out.noise_sum.resize(n, [0.0; 3]);
    out.square_sum.resize(n, [0.0; 3]);
    let entry: f64 = out
        .drift
        .par_iter_mut()
        .zip(out.noise_sum.par_iter_mut())
        .zip(out.square_sum.par_iter_mut())
        .enumerate()
        .map(|(i, ((d, s), q))| {
            let r = row_sums(pos, force, xi, a, i);
            *d = [r[0] + force.x[i], r[1] + force.y[i], r[2] + force.z[i]];
            *s = [r[3], r[4], r[5]];
            *q = [r[6], r[7], r[8]];
            r[9]
        })
        .sum();
    out.entry_sum = entry;
}

/// The ten row sums of particle `i` over all `j ≠ i`:
/// `[D̃F (3), D̃ξ (3), Σ D̃² per row (3), Σ entries]`.
pub fn row_sums(pos: &Soa, force: &Soa, xi: &Soa, a: f64, i: usize) -> [f64; 10] {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the features were detected on this CPU just above.
            return unsafe { row_sums_avx2(pos, force, xi, a, i) };
        }
    }
    row_sums_portable(pos, force, xi, a, i)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn row_sums_avx2(pos: &Soa, force: &Soa, xi: &Soa, a: f64, i: usize) -> [f64; 10] {
    row_sums_portable(pos, force, xi, a, i)
}

/// Portable pair loop (inlined into the AVX2 version, which the compiler vectorises 4-wide).
#[inline(always)]
pub fn row_sums_portable(pos: &Soa, force: &Soa, xi: &Soa, a: f64, i: usize) -> [f64; 10] {
    const L: usize = 4;
    let n = pos.x.len();
    let (xi0, yi0, zi0) = (pos.x[i], pos.y[i], pos.z[i]);
    let mut acc = [[0.0f64; L]; 10];
    let two_a = 2.0 * a;
    let inv_a = 1.0 / a;
    let lane_body = |j: usize, l: usize, acc: &mut [[f64; L]; 10]| {
        let rx = xi0 - pos.x[j];
        let ry = yi0 - pos.y[j];
        let rz = zi0 - pos.z[j];
        let d2 = rx * rx + ry * ry + rz * rz;
        let d = d2.sqrt();
        let inv_d = 1.0 / d;
        // Both branches, selected without a jump.
        let s = a * inv_d;
        let s3 = s * s * s;
        let far = d >= two_a;
        let t = d * inv_a;
        let ci = if far {
            0.75 * s + 0.5 * s3
        } else {
            1.0 - 0.28125 * t
        };
        let crr = if far {
            0.75 * s - 1.5 * s3
        } else {
            0.09375 * t
        };
        let g = crr * inv_d * inv_d;
        let (fx, fy, fz) = (force.x[j], force.y[j], force.z[j]);
        let (ex, ey, ez) = (xi.x[j], xi.y[j], xi.z[j]);
        let rf = g * (rx * fx + ry * fy + rz * fz);
        let re = g * (rx * ex + ry * ey + rz * ez);
        acc[0][l] += ci * fx + rf * rx;
        acc[1][l] += ci * fy + rf * ry;
        acc[2][l] += ci * fz + rf * rz;
        acc[3][l] += ci * ex + re * rx;
        acc[4][l] += ci * ey + re * ry;
        acc[5][l] += ci * ez + re * rz;
        // Block entries M_kl = ci δ_kl + g r_k r_l.
        let (mxx, myy, mzz) = (ci + g * rx * rx, ci + g * ry * ry, ci + g * rz * rz);
        let (mxy, mxz, myz) = (g * rx * ry, g * rx * rz, g * ry * rz);
        acc[6][l] += mxx * mxx + mxy * mxy + mxz * mxz;
        acc[7][l] += mxy * mxy + myy * myy + myz * myz;
        acc[8][l] += mxz * mxz + myz * myz + mzz * mzz;
        acc[9][l] += mxx + myy + mzz + 2.0 * (mxy + mxz + myz);
    };
    // j < i and j > i, in chunks of L lanes; remainders one by one.
    for range in [0..i, i + 1..n] {
        let (start, end) = (range.start, range.end);
        let full = start + (end - start) / L * L;
        let mut j = start;
        while j < full {
            for l in 0..L {
                lane_body(j + l, l, &mut acc);
            }
            j += L;
        }
        for (l, jj) in (full..end).enumerate() {
            lane_body(jj, l, &mut acc);
        }
    }
    let mut out = [0.0; 10];
    for (o, a) in out.iter_mut().zip(&acc) {
        *o = a.iter().sum();
    }
    out
}

/// TEA-HI noise `B̃ξ` (per particle) from the sums of a fused pass made with this `ξ`.
pub fn tea_hi_noise(sums: &FusedSums, xi: &Soa, coef: TeaHiCoefficients, out: &mut [[f64; 3]]) {
    let b = coef.beta;
    for (i, o) in out.iter_mut().enumerate() {
        let x = [xi.x[i], xi.y[i], xi.z[i]];
        for k in 0..3 {
            let c = 1.0 / (1.0 + b * b * sums.square_sum[i][k]).sqrt();
            o[k] = c * (x[k] + b * sums.noise_sum[i][k]);
        }
    }
}

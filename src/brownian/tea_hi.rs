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
//! The pair loop runs over structure-of-arrays coordinates: an AVX2+FMA version (four sources per
//! register) is selected at run time, and the scalar loop is kept as the portable path and the
//! reference it is tested against.

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
    /// Scratch: the rows of the last [`fused_pass`].
    rows: Vec<f64>,
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
    /// `x` coordinates.
    pub x: Vec<f64>,
    /// `y` coordinates.
    pub y: Vec<f64>,
    /// `z` coordinates.
    pub z: Vec<f64>,
}

impl Soa {
    /// From `[x, y, z]` triples.
    pub fn from_points(p: &[[f64; 3]]) -> Self {
        let mut s = Soa::default();
        s.fill(p);
        s
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

/// Particle count from which [`fused_rows`] runs over rayon threads.
pub const PARALLEL_THRESHOLD: usize = 256;

/// Values per row of [`fused_rows`]: `D̃F` (self term included, 3), `Σ D̃ξ` (3), `Σ D̃²` per
/// row (3) and the row's sum of entries (1).
pub const ROW_VALUES: usize = 10;

/// The fused pass over the particles `rows` (a range of `0..n`, all `n` sources for each):
/// [`ROW_VALUES`] values per row, in row order, written to `out` (resized). Every row is a
/// sequential sum over `j`, so the values do not depend on the thread count or on how the
/// rows are split between callers (the MPI ranks of a Brownian run).
pub fn fused_rows(
    pos: &Soa,
    force: &Soa,
    xi: &Soa,
    a: f64,
    rows: std::ops::Range<usize>,
    out: &mut Vec<f64>,
) {
    out.resize(ROW_VALUES * rows.len(), 0.0);
    let row = |i: usize, o: &mut [f64]| {
        let r = row_sums(pos, force, xi, a, i);
        o.copy_from_slice(&r);
        o[0] += force.x[i];
        o[1] += force.y[i];
        o[2] += force.z[i];
    };
    // Below a few hundred particles a parallel dispatch costs more than the pairs.
    if pos.x.len() < PARALLEL_THRESHOLD {
        for (i, o) in rows.zip(out.chunks_exact_mut(ROW_VALUES)) {
            row(i, o);
        }
    } else {
        out.par_chunks_exact_mut(ROW_VALUES)
            .enumerate()
            .for_each(|(k, o)| row(rows.start + k, o));
    }
}

impl FusedSums {
    /// The sums of all `n` particles from the rows of [`fused_rows`] over `0..n` (or their
    /// pieces concatenated in row order); the entry sum adds the rows in order.
    pub fn fill_from_rows(&mut self, rows: &[f64]) {
        let n = rows.len() / ROW_VALUES;
        self.drift.resize(n, [0.0; 3]);
        self.noise_sum.resize(n, [0.0; 3]);
        self.square_sum.resize(n, [0.0; 3]);
        let mut e = 0.0;
        for (i, r) in rows.chunks_exact(ROW_VALUES).enumerate() {
            self.drift[i] = [r[0], r[1], r[2]];
            self.noise_sum[i] = [r[3], r[4], r[5]];
            self.square_sum[i] = [r[6], r[7], r[8]];
            e += r[9];
        }
        self.entry_sum = e;
    }
}

/// The fused pass: drift, noise sum, square sums and entry sum for every particle.
/// `pos`, `force` and `xi` are structure-of-arrays of the same length. The same numbers on
/// any thread count ([`fused_rows`] over all rows, then [`FusedSums::fill_from_rows`]).
pub fn fused_pass(pos: &Soa, force: &Soa, xi: &Soa, a: f64, out: &mut FusedSums) {
    let mut rows = std::mem::take(&mut out.rows);
    fused_rows(pos, force, xi, a, 0..pos.x.len(), &mut rows);
    out.fill_from_rows(&rows);
    out.rows = rows;
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

/// Contribution of the pair `(i, j)`, `j ≠ i`, to the ten row sums of `i` (scalar).
#[inline(always)]
fn pair_scalar(pos: &Soa, force: &Soa, xi: &Soa, a: f64, i: usize, j: usize, acc: &mut [f64; 10]) {
    let rx = pos.x[i] - pos.x[j];
    let ry = pos.y[i] - pos.y[j];
    let rz = pos.z[i] - pos.z[j];
    let d2 = rx * rx + ry * ry + rz * rz;
    let d = d2.sqrt();
    let inv_d = 1.0 / d;
    let (ci, crr) = if d >= 2.0 * a {
        let s = a * inv_d;
        let s3 = s * s * s;
        (0.75 * s + 0.5 * s3, 0.75 * s - 1.5 * s3)
    } else {
        let t = d / a;
        (1.0 - 0.28125 * t, 0.09375 * t)
    };
    let g = crr * inv_d * inv_d;
    let (fx, fy, fz) = (force.x[j], force.y[j], force.z[j]);
    let (ex, ey, ez) = (xi.x[j], xi.y[j], xi.z[j]);
    let rf = g * (rx * fx + ry * fy + rz * fz);
    let re = g * (rx * ex + ry * ey + rz * ez);
    acc[0] += ci * fx + rf * rx;
    acc[1] += ci * fy + rf * ry;
    acc[2] += ci * fz + rf * rz;
    acc[3] += ci * ex + re * rx;
    acc[4] += ci * ey + re * ry;
    acc[5] += ci * ez + re * rz;
    // Block entries M_kl = ci δ_kl + g r_k r_l.
    let (mxx, myy, mzz) = (ci + g * rx * rx, ci + g * ry * ry, ci + g * rz * rz);
    let (mxy, mxz, myz) = (g * rx * ry, g * rx * rz, g * ry * rz);
    acc[6] += mxx * mxx + mxy * mxy + mxz * mxz;
    acc[7] += mxy * mxy + myy * myy + myz * myz;
    acc[8] += mxz * mxz + myz * myz + mzz * mzz;
    acc[9] += mxx + myy + mzz + 2.0 * (mxy + mxz + myz);
}

/// Portable pair loop: the reference for the SIMD version.
pub fn row_sums_portable(pos: &Soa, force: &Soa, xi: &Soa, a: f64, i: usize) -> [f64; 10] {
    let mut acc = [0.0; 10];
    for j in (0..pos.x.len()).filter(|&j| j != i) {
        pair_scalar(pos, force, xi, a, i, j, &mut acc);
    }
    acc
}

/// AVX2+FMA pair loop: four sources per register, both RPY branches computed and blended.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn row_sums_avx2(pos: &Soa, force: &Soa, xi: &Soa, a: f64, i: usize) -> [f64; 10] {
    use std::arch::x86_64::*;
    let n = pos.x.len();
    let set = |v: f64| _mm256_set1_pd(v);
    let (x0, y0, z0) = (set(pos.x[i]), set(pos.y[i]), set(pos.z[i]));
    let (av, two_a, inv_a, one) = (set(a), set(2.0 * a), set(1.0 / a), set(1.0));
    let (c075, c05, c15, c9_32, c3_32, two) = (
        set(0.75),
        set(0.5),
        set(1.5),
        set(0.28125),
        set(0.09375),
        set(2.0),
    );
    let mut acc = [_mm256_setzero_pd(); 10];
    let mut tail = [0.0f64; 10];
    for (start, end) in [(0, i), (i + 1, n)] {
        let full = start + (end - start) / 4 * 4;
        let mut j = start;
        while j < full {
            // SAFETY: j + 3 < end ≤ n, and all arrays have length n.
            let ld = |v: &Vec<f64>| _mm256_loadu_pd(v.as_ptr().add(j));
            let rx = _mm256_sub_pd(x0, ld(&pos.x));
            let ry = _mm256_sub_pd(y0, ld(&pos.y));
            let rz = _mm256_sub_pd(z0, ld(&pos.z));
            let d2 = _mm256_fmadd_pd(rx, rx, _mm256_fmadd_pd(ry, ry, _mm256_mul_pd(rz, rz)));
            let d = _mm256_sqrt_pd(d2);
            let inv_d = _mm256_div_pd(one, d);
            let s = _mm256_mul_pd(av, inv_d);
            let s3 = _mm256_mul_pd(_mm256_mul_pd(s, s), s);
            let t = _mm256_mul_pd(d, inv_a);
            let far = _mm256_cmp_pd::<_CMP_GE_OQ>(d, two_a);
            let ci_far = _mm256_fmadd_pd(c075, s, _mm256_mul_pd(c05, s3));
            let crr_far = _mm256_fmsub_pd(c075, s, _mm256_mul_pd(c15, s3));
            let ci_near = _mm256_fnmadd_pd(c9_32, t, one);
            let crr_near = _mm256_mul_pd(c3_32, t);
            let ci = _mm256_blendv_pd(ci_near, ci_far, far);
            let crr = _mm256_blendv_pd(crr_near, crr_far, far);
            let g = _mm256_mul_pd(crr, _mm256_mul_pd(inv_d, inv_d));
            let (fx, fy, fz) = (ld(&force.x), ld(&force.y), ld(&force.z));
            let (ex, ey, ez) = (ld(&xi.x), ld(&xi.y), ld(&xi.z));
            let dot = |ux, uy, uz| {
                _mm256_fmadd_pd(rx, ux, _mm256_fmadd_pd(ry, uy, _mm256_mul_pd(rz, uz)))
            };
            let rf = _mm256_mul_pd(g, dot(fx, fy, fz));
            let re = _mm256_mul_pd(g, dot(ex, ey, ez));
            let upd = |acc: __m256d, c: __m256d, u: __m256d, w: __m256d, r: __m256d| {
                _mm256_add_pd(acc, _mm256_fmadd_pd(c, u, _mm256_mul_pd(w, r)))
            };
            acc[0] = upd(acc[0], ci, fx, rf, rx);
            acc[1] = upd(acc[1], ci, fy, rf, ry);
            acc[2] = upd(acc[2], ci, fz, rf, rz);
            acc[3] = upd(acc[3], ci, ex, re, rx);
            acc[4] = upd(acc[4], ci, ey, re, ry);
            acc[5] = upd(acc[5], ci, ez, re, rz);
            let gx = _mm256_mul_pd(g, rx);
            let gy = _mm256_mul_pd(g, ry);
            let mxx = _mm256_fmadd_pd(gx, rx, ci);
            let myy = _mm256_fmadd_pd(gy, ry, ci);
            let mzz = _mm256_fmadd_pd(_mm256_mul_pd(g, rz), rz, ci);
            let mxy = _mm256_mul_pd(gx, ry);
            let mxz = _mm256_mul_pd(gx, rz);
            let myz = _mm256_mul_pd(gy, rz);
            let sq3 = |acc: __m256d, p: __m256d, q: __m256d, r: __m256d| {
                _mm256_fmadd_pd(p, p, _mm256_fmadd_pd(q, q, _mm256_fmadd_pd(r, r, acc)))
            };
            acc[6] = sq3(acc[6], mxx, mxy, mxz);
            acc[7] = sq3(acc[7], mxy, myy, myz);
            acc[8] = sq3(acc[8], mxz, myz, mzz);
            let diag = _mm256_add_pd(_mm256_add_pd(mxx, myy), mzz);
            let off = _mm256_add_pd(_mm256_add_pd(mxy, mxz), myz);
            acc[9] = _mm256_add_pd(acc[9], _mm256_fmadd_pd(two, off, diag));
            j += 4;
        }
        for jj in full..end {
            pair_scalar(pos, force, xi, a, i, jj, &mut tail);
        }
    }
    let mut out = tail;
    for (o, v) in out.iter_mut().zip(acc) {
        let mut lanes = [0.0f64; 4];
        _mm256_storeu_pd(lanes.as_mut_ptr(), v);
        *o += lanes.iter().sum::<f64>();
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

use super::{SourceView, EIGHT_PI, FOUR_PI};
use std::arch::x86_64::*;

#[inline(always)]
unsafe fn inv_norm<const N: usize>(d2: __m256d) -> __m256d {
    let lo = _mm256_set1_pd(1e-30);
    let hi = _mm256_set1_pd(1e30);
    let in_range = _mm256_and_pd(
        _mm256_cmp_pd(d2, lo, _CMP_GE_OQ),
        _mm256_cmp_pd(d2, hi, _CMP_LE_OQ),
    );
    let nonzero = _mm256_cmp_pd(d2, _mm256_setzero_pd(), _CMP_GT_OQ);
    if _mm256_movemask_pd(_mm256_xor_pd(in_range, nonzero)) != 0 {
        // Some non-zero lane outside the single-precision range: exact path.
        let exact = _mm256_div_pd(_mm256_set1_pd(1.0), _mm256_sqrt_pd(d2));
        return _mm256_and_pd(exact, nonzero);
    }
    let mut y = _mm256_cvtps_pd(_mm_rsqrt_ps(_mm256_cvtpd_ps(d2)));
    let half = _mm256_set1_pd(0.5);
    let three = _mm256_set1_pd(3.0);
    for _ in 0..N {
        let h = _mm256_mul_pd(half, y);
        y = _mm256_mul_pd(h, _mm256_fnmadd_pd(_mm256_mul_pd(d2, y), y, three));
    }
    _mm256_and_pd(y, in_range)
}

#[inline(always)]
unsafe fn hsum(v: __m256d) -> f64 {
    let lo = _mm256_castpd256_pd128(v);
    let hi = _mm256_extractf128_pd(v, 1);
    let s = _mm_add_pd(lo, hi);
    _mm_cvtsd_f64(_mm_add_sd(s, _mm_unpackhi_pd(s, s)))
}

/// The separations `x − y_j` from a target (broadcast) to the sources `j..j + 4`, and their
/// `1/|r|`.
#[inline(always)]
unsafe fn separations<const N: usize>(
    x: [__m256d; 3],
    s: [&[f64]; 3],
    j: usize,
) -> ([__m256d; 3], __m256d) {
    let d: [__m256d; 3] =
        std::array::from_fn(|c| _mm256_sub_pd(x[c], _mm256_loadu_pd(s[c].as_ptr().add(j))));
    let d2 = _mm256_fmadd_pd(
        d[0],
        d[0],
        _mm256_fmadd_pd(d[1], d[1], _mm256_mul_pd(d[2], d[2])),
    );
    (d, inv_norm::<N>(d2))
}

/// The separations `x − y` from a target to the sources of a tail (from `nb`, padded with
/// `x` itself), and their `1/|r|`.
#[inline(always)]
unsafe fn tail_separations<const N: usize>(
    x: [f64; 3],
    s: [&[f64]; 3],
    nb: usize,
) -> ([__m256d; 3], __m256d) {
    let d: [__m256d; 3] =
        std::array::from_fn(|c| _mm256_sub_pd(_mm256_set1_pd(x[c]), tail(s[c], nb, x[c])));
    let d2 = _mm256_fmadd_pd(
        d[0],
        d[0],
        _mm256_fmadd_pd(d[1], d[1], _mm256_mul_pd(d[2], d[2])),
    );
    (d, inv_norm::<N>(d2))
}

/// The values of `v` from `nb` (fewer than four), padded with `fill` to four lanes: the
/// tail of a loop runs through the same `1/|r|` as its full groups, so a pair's value does
/// not depend on where a block ends (padding the coordinates with the target's own gives
/// `r = 0`, which contributes nothing).
#[inline(always)]
unsafe fn tail(v: &[f64], nb: usize, fill: f64) -> __m256d {
    let mut t = [fill; 4];
    t[..v.len() - nb].copy_from_slice(&v[nb..]);
    _mm256_loadu_pd(t.as_ptr())
}

#[target_feature(enable = "avx2,fma")]
pub unsafe fn laplace<const N: usize>(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let (sx, sy, sz, q) = (&s.x[..n], &s.y[..n], &s.z[..n], &s.q[0][..n]);
    let nb = n - n % 4;
    for (x, o) in t.iter().zip(out.iter_mut()) {
        let (x0, x1, x2) = (
            _mm256_set1_pd(x[0]),
            _mm256_set1_pd(x[1]),
            _mm256_set1_pd(x[2]),
        );
        let mut acc = _mm256_setzero_pd();
        let mut j = 0;
        while j < nb {
            let dx = _mm256_sub_pd(x0, _mm256_loadu_pd(sx.as_ptr().add(j)));
            let dy = _mm256_sub_pd(x1, _mm256_loadu_pd(sy.as_ptr().add(j)));
            let dz = _mm256_sub_pd(x2, _mm256_loadu_pd(sz.as_ptr().add(j)));
            let d2 = _mm256_fmadd_pd(dx, dx, _mm256_fmadd_pd(dy, dy, _mm256_mul_pd(dz, dz)));
            acc = _mm256_fmadd_pd(_mm256_loadu_pd(q.as_ptr().add(j)), inv_norm::<N>(d2), acc);
            j += 4;
        }
        if nb < n {
            let (_, inv) = tail_separations::<N>(*x, [sx, sy, sz], nb);
            acc = _mm256_fmadd_pd(tail(q, nb, 0.0), inv, acc);
        }
        *o += hsum(acc) / FOUR_PI;
    }
}

/// [`super::laplace_mutual_with`]: four sources of `b` per step, the last partial group
/// padded.
#[target_feature(enable = "avx2,fma")]
pub unsafe fn laplace_mutual<const N: usize>(
    a: &SourceView,
    oa: &mut [f64],
    b: &SourceView,
    ob: &mut [f64],
) {
    let n = b.len();
    let (sx, sy, sz, q) = (&b.x[..n], &b.y[..n], &b.z[..n], &b.q[0][..n]);
    let ob = &mut ob[..n];
    let nb = n - n % 4;
    for i in 0..a.len() {
        let x = [a.x[i], a.y[i], a.z[i]];
        let (x0, x1, x2) = (
            _mm256_set1_pd(x[0]),
            _mm256_set1_pd(x[1]),
            _mm256_set1_pd(x[2]),
        );
        let qi = a.q[0][i] / FOUR_PI;
        let qv = _mm256_set1_pd(qi);
        let mut acc = _mm256_setzero_pd();
        let mut j = 0;
        while j < nb {
            let dx = _mm256_sub_pd(x0, _mm256_loadu_pd(sx.as_ptr().add(j)));
            let dy = _mm256_sub_pd(x1, _mm256_loadu_pd(sy.as_ptr().add(j)));
            let dz = _mm256_sub_pd(x2, _mm256_loadu_pd(sz.as_ptr().add(j)));
            let d2 = _mm256_fmadd_pd(dx, dx, _mm256_fmadd_pd(dy, dy, _mm256_mul_pd(dz, dz)));
            let inv = inv_norm::<N>(d2);
            acc = _mm256_fmadd_pd(_mm256_loadu_pd(q.as_ptr().add(j)), inv, acc);
            let o = ob.as_mut_ptr().add(j);
            _mm256_storeu_pd(o, _mm256_fmadd_pd(qv, inv, _mm256_loadu_pd(o)));
            j += 4;
        }
        if nb < n {
            let (_, inv) = tail_separations::<N>(x, [sx, sy, sz], nb);
            acc = _mm256_fmadd_pd(tail(q, nb, 0.0), inv, acc);
            let mut t = [0.0; 4];
            _mm256_storeu_pd(t.as_mut_ptr(), _mm256_mul_pd(qv, inv));
            for (o, v) in ob[nb..].iter_mut().zip(t) {
                *o += v;
            }
        }
        oa[i] += hsum(acc) / FOUR_PI;
    }
}

#[target_feature(enable = "avx2,fma")]
pub unsafe fn stokeslet<const N: usize>(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let (sx, sy, sz) = (&s.x[..n], &s.y[..n], &s.z[..n]);
    let (fx, fy, fz) = (&s.q[0][..n], &s.q[1][..n], &s.q[2][..n]);
    let nb = n - n % 4;
    for (x, o) in t.iter().zip(out.chunks_exact_mut(3)) {
        let (x0, x1, x2) = (
            _mm256_set1_pd(x[0]),
            _mm256_set1_pd(x[1]),
            _mm256_set1_pd(x[2]),
        );
        let (mut ax, mut ay, mut az) = (
            _mm256_setzero_pd(),
            _mm256_setzero_pd(),
            _mm256_setzero_pd(),
        );
        let mut j = 0;
        while j < nb {
            let ([dx, dy, dz], inv) = separations::<N>([x0, x1, x2], [sx, sy, sz], j);
            let (gx, gy, gz) = (
                _mm256_loadu_pd(fx.as_ptr().add(j)),
                _mm256_loadu_pd(fy.as_ptr().add(j)),
                _mm256_loadu_pd(fz.as_ptr().add(j)),
            );
            let rf = _mm256_fmadd_pd(dx, gx, _mm256_fmadd_pd(dy, gy, _mm256_mul_pd(dz, gz)));
            let c = _mm256_mul_pd(rf, _mm256_mul_pd(inv, inv));
            ax = _mm256_fmadd_pd(_mm256_fmadd_pd(c, dx, gx), inv, ax);
            ay = _mm256_fmadd_pd(_mm256_fmadd_pd(c, dy, gy), inv, ay);
            az = _mm256_fmadd_pd(_mm256_fmadd_pd(c, dz, gz), inv, az);
            j += 4;
        }
        if nb < n {
            let ([dx, dy, dz], inv) = tail_separations::<N>(*x, [sx, sy, sz], nb);
            let (gx, gy, gz) = (tail(fx, nb, 0.0), tail(fy, nb, 0.0), tail(fz, nb, 0.0));
            let rf = _mm256_fmadd_pd(dx, gx, _mm256_fmadd_pd(dy, gy, _mm256_mul_pd(dz, gz)));
            let c = _mm256_mul_pd(rf, _mm256_mul_pd(inv, inv));
            ax = _mm256_fmadd_pd(_mm256_fmadd_pd(c, dx, gx), inv, ax);
            ay = _mm256_fmadd_pd(_mm256_fmadd_pd(c, dy, gy), inv, ay);
            az = _mm256_fmadd_pd(_mm256_fmadd_pd(c, dz, gz), inv, az);
        }
        let v = [hsum(ax), hsum(ay), hsum(az)];
        for c in 0..3 {
            o[c] += v[c] / EIGHT_PI;
        }
    }
}

#[target_feature(enable = "avx2,fma")]
pub unsafe fn stresslet<const N: usize>(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let (sx, sy, sz) = (&s.x[..n], &s.y[..n], &s.z[..n]);
    let (fx, fy, fz) = (&s.q[0][..n], &s.q[1][..n], &s.q[2][..n]);
    let (nx, ny, nz) = (&s.n[0][..n], &s.n[1][..n], &s.n[2][..n]);
    let nb = n - n % 4;
    #[inline(always)]
    unsafe fn pair(
        [dx, dy, dz]: [__m256d; 3],
        inv: __m256d,
        g: [__m256d; 3],
        m: [__m256d; 3],
        acc: &mut [__m256d; 3],
    ) {
        let rf = _mm256_fmadd_pd(dx, g[0], _mm256_fmadd_pd(dy, g[1], _mm256_mul_pd(dz, g[2])));
        let rn = _mm256_fmadd_pd(dx, m[0], _mm256_fmadd_pd(dy, m[1], _mm256_mul_pd(dz, m[2])));
        let inv2 = _mm256_mul_pd(inv, inv);
        let c = _mm256_mul_pd(
            _mm256_mul_pd(rf, rn),
            _mm256_mul_pd(_mm256_mul_pd(inv2, inv2), inv),
        );
        acc[0] = _mm256_fmadd_pd(c, dx, acc[0]);
        acc[1] = _mm256_fmadd_pd(c, dy, acc[1]);
        acc[2] = _mm256_fmadd_pd(c, dz, acc[2]);
    }
    for (x, o) in t.iter().zip(out.chunks_exact_mut(3)) {
        let (x0, x1, x2) = (
            _mm256_set1_pd(x[0]),
            _mm256_set1_pd(x[1]),
            _mm256_set1_pd(x[2]),
        );
        let mut acc = [_mm256_setzero_pd(); 3];
        let mut j = 0;
        while j < nb {
            let (d, inv) = separations::<N>([x0, x1, x2], [sx, sy, sz], j);
            let g = [fx, fy, fz].map(|v| _mm256_loadu_pd(v.as_ptr().add(j)));
            let m = [nx, ny, nz].map(|v| _mm256_loadu_pd(v.as_ptr().add(j)));
            pair(d, inv, g, m, &mut acc);
            j += 4;
        }
        if nb < n {
            let (d, inv) = tail_separations::<N>(*x, [sx, sy, sz], nb);
            let g = [fx, fy, fz].map(|v| tail(v, nb, 0.0));
            let m = [nx, ny, nz].map(|v| tail(v, nb, 0.0));
            pair(d, inv, g, m, &mut acc);
        }
        let k = 3.0 / FOUR_PI;
        for c in 0..3 {
            o[c] += k * hsum(acc[c]);
        }
    }
}

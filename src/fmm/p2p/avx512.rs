use super::{SourceView, EIGHT_PI, FOUR_PI};
use std::arch::x86_64::*;

#[inline(always)]
unsafe fn inv_norm<const N: usize>(d2: __m512d) -> __m512d {
    let nonzero = _mm512_cmp_pd_mask::<_CMP_GT_OQ>(d2, _mm512_setzero_pd());
    let half = _mm512_set1_pd(0.5);
    let three = _mm512_set1_pd(3.0);
    let mut y = _mm512_rsqrt14_pd(d2);
    for _ in 0..N {
        y = _mm512_mul_pd(
            _mm512_mul_pd(half, y),
            _mm512_fnmadd_pd(_mm512_mul_pd(d2, y), y, three),
        );
    }
    _mm512_maskz_mov_pd(nonzero, y)
}

/// Lanes `j..min(j + 8, n)`.
#[inline(always)]
fn mask(j: usize, n: usize) -> __mmask8 {
    let k = (n - j).min(8);
    ((1u16 << k) - 1) as __mmask8
}

/// Eight values from `p`, the lanes outside `m` zero (an unmasked load for a full mask).
#[inline(always)]
unsafe fn load(m: __mmask8, p: *const f64) -> __m512d {
    if m == 0xff {
        _mm512_loadu_pd(p)
    } else {
        _mm512_maskz_loadu_pd(m, p)
    }
}

/// The lanes `m` of `v` to `p` (an unmasked store for a full mask: masked stores are slow
/// on some CPUs, AMD Zen 4).
#[inline(always)]
unsafe fn store(m: __mmask8, p: *mut f64, v: __m512d) {
    if m == 0xff {
        _mm512_storeu_pd(p, v)
    } else {
        _mm512_mask_storeu_pd(p, m, v)
    }
}

/// The separations `x − y_j` from a target (broadcast) to the sources `j..j + 8` (lanes in
/// `m`), and their `1/|r|`.
#[inline(always)]
unsafe fn separations<const N: usize>(
    x: [__m512d; 3],
    s: [&[f64]; 3],
    m: __mmask8,
    j: usize,
) -> ([__m512d; 3], __m512d) {
    let d: [__m512d; 3] =
        std::array::from_fn(|c| _mm512_sub_pd(x[c], load(m, s[c].as_ptr().add(j))));
    let d2 = _mm512_fmadd_pd(
        d[0],
        d[0],
        _mm512_fmadd_pd(d[1], d[1], _mm512_mul_pd(d[2], d[2])),
    );
    (d, inv_norm::<N>(d2))
}

#[target_feature(enable = "avx512f")]
pub unsafe fn laplace<const N: usize>(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let (sx, sy, sz, q) = (&s.x[..n], &s.y[..n], &s.z[..n], &s.q[0][..n]);
    for (x, o) in t.iter().zip(out.iter_mut()) {
        let (x0, x1, x2) = (
            _mm512_set1_pd(x[0]),
            _mm512_set1_pd(x[1]),
            _mm512_set1_pd(x[2]),
        );
        let mut acc = _mm512_setzero_pd();
        let mut j = 0;
        while j < n {
            let m = mask(j, n);
            let dx = _mm512_sub_pd(x0, load(m, sx.as_ptr().add(j)));
            let dy = _mm512_sub_pd(x1, load(m, sy.as_ptr().add(j)));
            let dz = _mm512_sub_pd(x2, load(m, sz.as_ptr().add(j)));
            let d2 = _mm512_fmadd_pd(dx, dx, _mm512_fmadd_pd(dy, dy, _mm512_mul_pd(dz, dz)));
            acc = _mm512_fmadd_pd(load(m, q.as_ptr().add(j)), inv_norm::<N>(d2), acc);
            j += 8;
        }
        *o += _mm512_reduce_add_pd(acc) / FOUR_PI;
    }
}

/// [`super::laplace_mutual_with`]: eight sources of `b` per step, the last group masked
/// (masked-off lanes are neither read nor written).
#[target_feature(enable = "avx512f")]
pub unsafe fn laplace_mutual<const N: usize>(
    a: &SourceView,
    oa: &mut [f64],
    b: &SourceView,
    ob: &mut [f64],
) {
    let n = b.len();
    let (sx, sy, sz, q) = (&b.x[..n], &b.y[..n], &b.z[..n], &b.q[0][..n]);
    let ob = &mut ob[..n];
    for i in 0..a.len() {
        let (x0, x1, x2) = (
            _mm512_set1_pd(a.x[i]),
            _mm512_set1_pd(a.y[i]),
            _mm512_set1_pd(a.z[i]),
        );
        let qv = _mm512_set1_pd(a.q[0][i] / FOUR_PI);
        let mut acc = _mm512_setzero_pd();
        let mut j = 0;
        while j < n {
            let m = mask(j, n);
            let dx = _mm512_sub_pd(x0, load(m, sx.as_ptr().add(j)));
            let dy = _mm512_sub_pd(x1, load(m, sy.as_ptr().add(j)));
            let dz = _mm512_sub_pd(x2, load(m, sz.as_ptr().add(j)));
            let d2 = _mm512_fmadd_pd(dx, dx, _mm512_fmadd_pd(dy, dy, _mm512_mul_pd(dz, dz)));
            let inv = inv_norm::<N>(d2);
            acc = _mm512_fmadd_pd(load(m, q.as_ptr().add(j)), inv, acc);
            let o = ob.as_mut_ptr().add(j);
            store(m, o, _mm512_fmadd_pd(qv, inv, load(m, o)));
            j += 8;
        }
        oa[i] += _mm512_reduce_add_pd(acc) / FOUR_PI;
    }
}

#[target_feature(enable = "avx512f")]
pub unsafe fn stokeslet<const N: usize>(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let (sx, sy, sz) = (&s.x[..n], &s.y[..n], &s.z[..n]);
    let (fx, fy, fz) = (&s.q[0][..n], &s.q[1][..n], &s.q[2][..n]);
    for (x, o) in t.iter().zip(out.chunks_exact_mut(3)) {
        let (x0, x1, x2) = (
            _mm512_set1_pd(x[0]),
            _mm512_set1_pd(x[1]),
            _mm512_set1_pd(x[2]),
        );
        let (mut ax, mut ay, mut az) = (
            _mm512_setzero_pd(),
            _mm512_setzero_pd(),
            _mm512_setzero_pd(),
        );
        let mut j = 0;
        while j < n {
            let m = mask(j, n);
            let ([dx, dy, dz], inv) = separations::<N>([x0, x1, x2], [sx, sy, sz], m, j);
            let (gx, gy, gz) = (
                load(m, fx.as_ptr().add(j)),
                load(m, fy.as_ptr().add(j)),
                load(m, fz.as_ptr().add(j)),
            );
            let rf = _mm512_fmadd_pd(dx, gx, _mm512_fmadd_pd(dy, gy, _mm512_mul_pd(dz, gz)));
            let c = _mm512_mul_pd(rf, _mm512_mul_pd(inv, inv));
            ax = _mm512_fmadd_pd(_mm512_fmadd_pd(c, dx, gx), inv, ax);
            ay = _mm512_fmadd_pd(_mm512_fmadd_pd(c, dy, gy), inv, ay);
            az = _mm512_fmadd_pd(_mm512_fmadd_pd(c, dz, gz), inv, az);
            j += 8;
        }
        o[0] += _mm512_reduce_add_pd(ax) / EIGHT_PI;
        o[1] += _mm512_reduce_add_pd(ay) / EIGHT_PI;
        o[2] += _mm512_reduce_add_pd(az) / EIGHT_PI;
    }
}

#[target_feature(enable = "avx512f")]
pub unsafe fn stresslet<const N: usize>(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let (sx, sy, sz) = (&s.x[..n], &s.y[..n], &s.z[..n]);
    let (fx, fy, fz) = (&s.q[0][..n], &s.q[1][..n], &s.q[2][..n]);
    let (nx, ny, nz) = (&s.n[0][..n], &s.n[1][..n], &s.n[2][..n]);
    for (x, o) in t.iter().zip(out.chunks_exact_mut(3)) {
        let (x0, x1, x2) = (
            _mm512_set1_pd(x[0]),
            _mm512_set1_pd(x[1]),
            _mm512_set1_pd(x[2]),
        );
        let (mut ax, mut ay, mut az) = (
            _mm512_setzero_pd(),
            _mm512_setzero_pd(),
            _mm512_setzero_pd(),
        );
        let mut j = 0;
        while j < n {
            let m = mask(j, n);
            let ([dx, dy, dz], inv) = separations::<N>([x0, x1, x2], [sx, sy, sz], m, j);
            let rf = _mm512_fmadd_pd(
                dx,
                load(m, fx.as_ptr().add(j)),
                _mm512_fmadd_pd(
                    dy,
                    load(m, fy.as_ptr().add(j)),
                    _mm512_mul_pd(dz, load(m, fz.as_ptr().add(j))),
                ),
            );
            let rn = _mm512_fmadd_pd(
                dx,
                load(m, nx.as_ptr().add(j)),
                _mm512_fmadd_pd(
                    dy,
                    load(m, ny.as_ptr().add(j)),
                    _mm512_mul_pd(dz, load(m, nz.as_ptr().add(j))),
                ),
            );
            let inv2 = _mm512_mul_pd(inv, inv);
            let c = _mm512_mul_pd(
                _mm512_mul_pd(rf, rn),
                _mm512_mul_pd(_mm512_mul_pd(inv2, inv2), inv),
            );
            ax = _mm512_fmadd_pd(c, dx, ax);
            ay = _mm512_fmadd_pd(c, dy, ay);
            az = _mm512_fmadd_pd(c, dz, az);
            j += 8;
        }
        let k = 3.0 / FOUR_PI;
        o[0] += k * _mm512_reduce_add_pd(ax);
        o[1] += k * _mm512_reduce_add_pd(ay);
        o[2] += k * _mm512_reduce_add_pd(az);
    }
}

//! Batched point-to-point evaluation: every target of a block against a block of sources
//! ([`SourceView`], structure of arrays). This is the near field (P2P) of the FMM and also how
//! the FMM evaluates sources or equivalent densities at check surfaces and targets.
//!
//! Each loop runs over sources innermost, in groups of [`LANES`] with one partial sum per lane
//! (floating-point sums are not reassociated by the compiler, so a single accumulator would
//! keep the loop scalar) and no branch other than selects, so it vectorises; on x86-64 the same
//! body is also compiled for AVX2/FMA and chosen at run time, and the Laplace and Stokeslet
//! loops (the FMM's P2P) have AVX2 and AVX-512 versions by intrinsics ([`Simd`]). Coincident pairs (`r = 0`) are masked out (the singular kernels
//! leave the self term out); RPY adds its self mobility there.

// Index loops over several equally long slices are what the vectoriser wants here.
#![allow(clippy::needless_range_loop)]

use super::blocks::SourceView;

const FOUR_PI: f64 = 4.0 * std::f64::consts::PI;
const EIGHT_PI: f64 = 8.0 * std::f64::consts::PI;

/// `1/|r|`, or 0 at `r = 0`.
#[inline(always)]
fn inv_norm(d2: f64) -> f64 {
    if d2 > 0.0 {
        1.0 / d2.sqrt()
    } else {
        0.0
    }
}

macro_rules! dispatched {
    ($(#[$doc:meta])* $name:ident, $body:ident, ($($arg:ident : $ty:ty),*)) => {
        $(#[$doc])*
        pub fn $name(targets: &[[f64; 3]], s: &SourceView, out: &mut [f64] $(, $arg: $ty)*) {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx2,fma")]
                unsafe fn avx2(t: &[[f64; 3]], s: &SourceView, o: &mut [f64] $(, $arg: $ty)*) {
                    $body(t, s, o $(, $arg)*)
                }
                if std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
                {
                    // SAFETY: the CPU supports AVX2 and FMA (checked just above).
                    unsafe { avx2(targets, s, out $(, $arg)*) };
                    return;
                }
            }
            $body(targets, s, out $(, $arg)*)
        }
    };
}

/// Sources per group of independent partial sums.
pub const LANES: usize = 8;

/// The instruction sets of the hand-vectorised loops ([`laplace`], [`stokeslet`]), chosen at
/// run time: AVX-512 where the CPU has it (eight sources per step), else AVX2/FMA (four), else
/// the portable loops.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Simd {
    /// The portable loops (what the compiler vectorises).
    Portable,
    /// AVX2 and FMA intrinsics.
    Avx2,
    /// AVX-512F intrinsics.
    Avx512,
}

impl Simd {
    /// Whether this CPU runs it.
    pub fn available(self) -> bool {
        match self {
            Simd::Portable => true,
            #[cfg(target_arch = "x86_64")]
            Simd::Avx2 => {
                std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
            }
            #[cfg(target_arch = "x86_64")]
            Simd::Avx512 => std::arch::is_x86_feature_detected!("avx512f"),
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// Relative error bound of `1/|r|` after [`Newton::One`] on this instruction set: the
    /// estimate's error `e` becomes `1.5 e² + O(e³)` (always below the true value), with
    /// `|e| ≤ 2⁻¹⁴` for AVX-512's `rsqrt14` (5.6e-9) and `|e| ≤ 1.5·2⁻¹²` for AVX2's `rsqrt`
    /// (2.0e-7; its conversion to single precision adds at most 3e-8 to `e`, second order after
    /// the step). The portable loops divide exactly: 0.
    pub fn one_newton_error(self) -> f64 {
        match self {
            Simd::Portable => 0.0,
            Simd::Avx2 => 2.1e-7,
            Simd::Avx512 => 5.6e-9,
        }
    }

    /// The widest one this CPU runs.
    pub fn best() -> Self {
        [Simd::Avx512, Simd::Avx2]
            .into_iter()
            .find(|s| s.available())
            .unwrap_or(Simd::Portable)
    }
}

/// How many Newton steps refine the hardware's `1/√d²` estimate in the AVX2 and AVX-512 loops.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Newton {
    /// Two steps: `1/|r|` to round-off (≈ 1e-16 relative), the default.
    Two,
    /// One step: relative error at most [`Simd::one_newton_error`] (5.6e-9 with AVX-512), for
    /// an FMM whose own error is far larger; 25 % fewer cycles per pair in the Laplace loop.
    One,
}

impl Newton {
    /// One step where its error on `simd`, times `powers` (the largest power of `1/|r|` the
    /// kernel takes: errors add up to that factor), stays within `tol`; else two.
    pub fn within(simd: Simd, tol: f64, powers: u32) -> Self {
        if simd != Simd::Portable && f64::from(powers) * simd.one_newton_error() <= tol {
            Newton::One
        } else {
            Newton::Two
        }
    }
}

/// Add `scale · Σ_j pair(j, x − y_j)` to each target's `D` outputs.
#[inline(always)]
fn drive<const D: usize, P: Fn(usize, f64, f64, f64) -> [f64; D]>(
    t: &[[f64; 3]],
    s: &SourceView,
    out: &mut [f64],
    scale: f64,
    pair: P,
) {
    let n = s.len();
    let (sx, sy, sz) = (&s.x[..n], &s.y[..n], &s.z[..n]);
    let nb = n - n % LANES;
    for (x, o) in t.iter().zip(out.chunks_exact_mut(D)) {
        let mut acc = [[0.0; LANES]; D];
        let mut j = 0;
        while j < nb {
            for l in 0..LANES {
                let k = j + l;
                let v = pair(k, x[0] - sx[k], x[1] - sy[k], x[2] - sz[k]);
                for c in 0..D {
                    acc[c][l] += v[c];
                }
            }
            j += LANES;
        }
        let mut tot = [0.0; D];
        for c in 0..D {
            tot[c] = acc[c].iter().sum();
        }
        for k in nb..n {
            let v = pair(k, x[0] - sx[k], x[1] - sy[k], x[2] - sz[k]);
            for c in 0..D {
                tot[c] += v[c];
            }
        }
        for c in 0..D {
            o[c] += scale * tot[c];
        }
    }
}

#[inline(always)]
fn laplace_body(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let q = &s.q[0][..s.len()];
    drive(t, s, out, 1.0 / FOUR_PI, |j, dx, dy, dz| {
        [q[j] * inv_norm(dx * dx + dy * dy + dz * dz)]
    })
}
dispatched!(
    /// Laplace single layer `Σ q/(4π|r|)` (portable loop).
    laplace_portable, laplace_body, ()
);

/// Laplace single layer `Σ q/(4π|r|)`: AVX-512 or AVX2 intrinsics where available.
pub fn laplace(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    laplace_on(Simd::best(), t, s, out);
}

/// [`laplace`] on the instruction set `simd`; `false` (and nothing added) where the CPU does
/// not have it.
pub fn laplace_on(simd: Simd, t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) -> bool {
    laplace_with(simd, Newton::Two, t, s, out)
}

/// [`laplace_on`] with `newton` steps refining `1/|r|` (the portable loop is exact either way).
pub fn laplace_with(
    simd: Simd,
    newton: Newton,
    t: &[[f64; 3]],
    s: &SourceView,
    out: &mut [f64],
) -> bool {
    match newton {
        Newton::Two => variants!(laplace_portable, laplace, 2),
        Newton::One => variants!(laplace_portable, laplace, 1),
    }
    .run(simd, t, s, out)
}

/// Mutual Laplace between two disjoint blocks of the same point set (sources that are also
/// targets): `oa_i += Σ_j q^b_j/(4π|x^a_i − x^b_j|)` and `ob_j += Σ_i q^a_i/(4π|x^a_i − x^b_j|)`,
/// each `1/|r|` computed once for both directions (half the work of two one-way calls).
/// Coincident points give nothing, as in [`laplace`]. `false` (and nothing added) where the
/// CPU does not have `simd`.
pub fn laplace_mutual_with(
    simd: Simd,
    newton: Newton,
    a: &SourceView,
    oa: &mut [f64],
    b: &SourceView,
    ob: &mut [f64],
) -> bool {
    assert!(
        oa.len() == a.len() && ob.len() == b.len(),
        "one output per point"
    );
    if !simd.available() {
        return false;
    }
    match (simd, newton) {
        (Simd::Portable, _) => laplace_mutual_portable(a, oa, b, ob),
        // SAFETY (all below): the CPU supports the instruction set (checked just above).
        #[cfg(target_arch = "x86_64")]
        (Simd::Avx2, Newton::Two) => unsafe { avx2::laplace_mutual::<2>(a, oa, b, ob) },
        #[cfg(target_arch = "x86_64")]
        (Simd::Avx2, Newton::One) => unsafe { avx2::laplace_mutual::<1>(a, oa, b, ob) },
        #[cfg(target_arch = "x86_64")]
        (Simd::Avx512, Newton::Two) => unsafe { avx512::laplace_mutual::<2>(a, oa, b, ob) },
        #[cfg(target_arch = "x86_64")]
        (Simd::Avx512, Newton::One) => unsafe { avx512::laplace_mutual::<1>(a, oa, b, ob) },
        #[cfg(not(target_arch = "x86_64"))]
        _ => return false,
    }
    true
}

/// [`laplace_mutual_with`], portable loop (the reference of the vectorised ones).
pub fn laplace_mutual_portable(a: &SourceView, oa: &mut [f64], b: &SourceView, ob: &mut [f64]) {
    let n = b.len();
    let (sx, sy, sz, q) = (&b.x[..n], &b.y[..n], &b.z[..n], &b.q[0][..n]);
    let ob = &mut ob[..n];
    for i in 0..a.len() {
        let x = [a.x[i], a.y[i], a.z[i]];
        let qi = a.q[0][i] / FOUR_PI;
        let mut acc = 0.0;
        for j in 0..n {
            let (dx, dy, dz) = (x[0] - sx[j], x[1] - sy[j], x[2] - sz[j]);
            let inv = inv_norm(dx * dx + dy * dy + dz * dz);
            acc += q[j] * inv;
            ob[j] += qi * inv;
        }
        oa[i] += acc / FOUR_PI;
    }
}

/// The [`Variants`] of a kernel: its portable loop and its AVX2 and AVX-512 loops with
/// `$steps` Newton steps.
macro_rules! variants {
    ($portable:ident, $simd:ident, $steps:literal) => {
        Variants {
            portable: $portable,
            #[cfg(target_arch = "x86_64")]
            avx2: avx2::$simd::<$steps>,
            #[cfg(target_arch = "x86_64")]
            avx512: avx512::$simd::<$steps>,
        }
    };
}
use variants;

/// One loop on each instruction set.
struct Variants {
    portable: fn(&[[f64; 3]], &SourceView, &mut [f64]),
    #[cfg(target_arch = "x86_64")]
    avx2: unsafe fn(&[[f64; 3]], &SourceView, &mut [f64]),
    #[cfg(target_arch = "x86_64")]
    avx512: unsafe fn(&[[f64; 3]], &SourceView, &mut [f64]),
}

impl Variants {
    /// Run the `simd` one; `false` (and nothing added) where the CPU does not have it.
    fn run(&self, simd: Simd, t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) -> bool {
        if !simd.available() {
            return false;
        }
        match simd {
            Simd::Portable => (self.portable)(t, s, out),
            // SAFETY: the CPU supports the instruction set (checked just above).
            #[cfg(target_arch = "x86_64")]
            Simd::Avx2 => unsafe { (self.avx2)(t, s, out) },
            // SAFETY: as above.
            #[cfg(target_arch = "x86_64")]
            Simd::Avx512 => unsafe { (self.avx512)(t, s, out) },
            #[cfg(not(target_arch = "x86_64"))]
            _ => return false,
        }
        true
    }
}

#[inline(always)]
fn laplace_dl_body(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let (q, nx, ny, nz) = (&s.q[0][..n], &s.n[0][..n], &s.n[1][..n], &s.n[2][..n]);
    drive(t, s, out, 1.0 / FOUR_PI, |j, dx, dy, dz| {
        let inv = inv_norm(dx * dx + dy * dy + dz * dz);
        [q[j] * (nx[j] * dx + ny[j] * dy + nz[j] * dz) * inv * inv * inv]
    })
}
dispatched!(
    /// Laplace double layer `Σ (n·r) q/(4π|r|³)`.
    laplace_dl, laplace_dl_body, ()
);

#[inline(always)]
fn stokeslet_body(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let (fx, fy, fz) = (&s.q[0][..n], &s.q[1][..n], &s.q[2][..n]);
    drive(t, s, out, 1.0 / EIGHT_PI, |j, dx, dy, dz| {
        let inv = inv_norm(dx * dx + dy * dy + dz * dz);
        let rf = (dx * fx[j] + dy * fy[j] + dz * fz[j]) * inv * inv;
        [
            (fx[j] + rf * dx) * inv,
            (fy[j] + rf * dy) * inv,
            (fz[j] + rf * dz) * inv,
        ]
    })
}
dispatched!(
    /// Stokeslet `Σ (1/8π)(I/|r| + r rᵀ/|r|³) f` (portable loop).
    stokeslet_portable, stokeslet_body, ()
);

/// Stokeslet `Σ (1/8π)(I/|r| + r rᵀ/|r|³) f`: AVX-512 or AVX2 intrinsics where available.
pub fn stokeslet(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    stokeslet_on(Simd::best(), t, s, out);
}

/// [`stokeslet`] on the instruction set `simd`; `false` (and nothing added) where the CPU
/// does not have it.
pub fn stokeslet_on(simd: Simd, t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) -> bool {
    stokeslet_with(simd, Newton::Two, t, s, out)
}

/// [`stokeslet_on`] with `newton` steps refining `1/|r|` (the portable loop is exact either
/// way).
pub fn stokeslet_with(
    simd: Simd,
    newton: Newton,
    t: &[[f64; 3]],
    s: &SourceView,
    out: &mut [f64],
) -> bool {
    match newton {
        Newton::Two => variants!(stokeslet_portable, stokeslet, 2),
        Newton::One => variants!(stokeslet_portable, stokeslet, 1),
    }
    .run(simd, t, s, out)
}

#[inline(always)]
fn stokeslet_source_body(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let (fx, fy, fz, m) = (&s.q[0][..n], &s.q[1][..n], &s.q[2][..n], &s.q[3][..n]);
    drive(t, s, out, 1.0 / EIGHT_PI, |j, dx, dy, dz| {
        let inv = inv_norm(dx * dx + dy * dy + dz * dz);
        let inv2 = inv * inv;
        let rf = (dx * fx[j] + dy * fy[j] + dz * fz[j]) * inv2;
        // (1/8π)(f + (r·f) r/r²)/r + (1/4π) m r/r³ = (1/8π)[f/r + (rf + 2m/r²) r/r]
        let c = (rf + 2.0 * m[j] * inv2) * inv;
        [
            fx[j] * inv + c * dx,
            fy[j] * inv + c * dy,
            fz[j] * inv + c * dz,
        ]
    })
}
dispatched!(
    /// Stokeslet plus point source (the equivalent kernel of Stokes double layers).
    stokeslet_source, stokeslet_source_body, ()
);

#[inline(always)]
fn stresslet_body(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let (fx, fy, fz) = (&s.q[0][..n], &s.q[1][..n], &s.q[2][..n]);
    let (nx, ny, nz) = (&s.n[0][..n], &s.n[1][..n], &s.n[2][..n]);
    drive(t, s, out, 3.0 / FOUR_PI, |j, dx, dy, dz| {
        let inv = inv_norm(dx * dx + dy * dy + dz * dz);
        let inv2 = inv * inv;
        let c = (dx * fx[j] + dy * fy[j] + dz * fz[j])
            * (dx * nx[j] + dy * ny[j] + dz * nz[j])
            * inv2
            * inv2
            * inv;
        [c * dx, c * dy, c * dz]
    })
}
dispatched!(
    /// Stresslet `Σ (3/4π)(r·f)(r·n) r/|r|⁵`.
    stresslet, stresslet_body, ()
);

#[inline(always)]
fn rpy_body(t: &[[f64; 3]], s: &SourceView, out: &mut [f64], a: f64) {
    let n = s.len();
    let (fx, fy, fz) = (&s.q[0][..n], &s.q[1][..n], &s.q[2][..n]);
    let m0 = 1.0 / (6.0 * std::f64::consts::PI * a);
    let inv_a = 1.0 / a;
    let two_a2 = 4.0 * a * a;
    let a3 = a * a * a;
    drive(t, s, out, m0, |j, dx, dy, dz| {
        let d2 = dx * dx + dy * dy + dz * dz;
        let inv = inv_norm(d2);
        let d = d2 * inv;
        // M/M0 = f I + g r̂r̂ (rpy_coefficients), written with r instead of r̂.
        let (sa, sa3) = (a * inv, a3 * inv * inv * inv);
        let far = d2 >= two_a2;
        let fcoef = if far {
            0.75 * sa + 0.5 * sa3
        } else {
            1.0 - 9.0 / 32.0 * d * inv_a
        };
        let gcoef = if far {
            0.75 * sa - 1.5 * sa3
        } else {
            3.0 / 32.0 * d * inv_a
        };
        let rf = gcoef * (dx * fx[j] + dy * fy[j] + dz * fz[j]) * inv * inv;
        [
            fcoef * fx[j] + rf * dx,
            fcoef * fy[j] + rf * dy,
            fcoef * fz[j] + rf * dz,
        ]
    })
}
dispatched!(
    /// Rotne–Prager–Yamakawa, both branches, self mobility `M0 f` at `r = 0`.
    rpy, rpy_body, (a: f64)
);

#[inline(always)]
fn rpy_far_body(t: &[[f64; 3]], s: &SourceView, out: &mut [f64], a: f64) {
    let n = s.len();
    let (fx, fy, fz) = (&s.q[0][..n], &s.q[1][..n], &s.q[2][..n]);
    // G + (a²/6)∇²G with ∇²G = (I − 3 r̂r̂)/(4π r³):
    // (1/8π)[(1/r + a²/(3r³)) f + (1/r³ − a²/r⁵)(r·f) r].
    let c2 = a * a / 3.0;
    drive(t, s, out, 1.0 / EIGHT_PI, |j, dx, dy, dz| {
        let inv = inv_norm(dx * dx + dy * dy + dz * dz);
        let inv2 = inv * inv;
        let ci = inv * (1.0 + c2 * inv2);
        let crr = inv * inv2 * (1.0 - 3.0 * c2 * inv2) * (dx * fx[j] + dy * fy[j] + dz * fz[j]);
        [
            ci * fx[j] + crr * dx,
            ci * fy[j] + crr * dy,
            ci * fz[j] + crr * dz,
        ]
    })
}
dispatched!(
    /// Half-corrected RPY far field `(1 + a²/6 ∇²) G`: what one side's finite size adds to a
    /// Stokeslet. Applied on the source side (P2M, P2L) and the target side (M2P, L2P) it gives
    /// the RPY far field `(1 + a²/3 ∇²) G` between beads in separated boxes.
    rpy_far, rpy_far_body, (a: f64)
);

/// Hand-vectorised AVX2/FMA loops, four sources per step (the last partial group padded).
/// `1/|r|` comes from the single-precision estimate `rsqrt` refined by `N` Newton steps
/// `y ← y (3 − d² y²)/2` (two: relative error ≈ 1e-15, as PVFMM does; one:
/// [`super::Simd::one_newton_error`]); lanes with `d²` outside `[1e-30, 1e30]` fall back to
/// `1/√d²`, and `d² = 0` gives 0.
#[cfg(target_arch = "x86_64")]
mod avx2 {
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
                let dx = _mm256_sub_pd(x0, _mm256_loadu_pd(sx.as_ptr().add(j)));
                let dy = _mm256_sub_pd(x1, _mm256_loadu_pd(sy.as_ptr().add(j)));
                let dz = _mm256_sub_pd(x2, _mm256_loadu_pd(sz.as_ptr().add(j)));
                let d2 = _mm256_fmadd_pd(dx, dx, _mm256_fmadd_pd(dy, dy, _mm256_mul_pd(dz, dz)));
                let inv = inv_norm::<N>(d2);
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
}

/// Hand-vectorised AVX-512F loops, eight sources per step, the last partial group by masked
/// loads (masked-off lanes carry zero density). `1/|r|` from the 14-bit estimate
/// `rsqrt14` (double precision, whole exponent range) refined by `N` Newton steps (two: ≈ 1e-16
/// relative; one: [`super::Simd::one_newton_error`]); `d² = 0` gives 0.
#[cfg(target_arch = "x86_64")]
mod avx512 {
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
                let dx = _mm512_sub_pd(x0, load(m, sx.as_ptr().add(j)));
                let dy = _mm512_sub_pd(x1, load(m, sy.as_ptr().add(j)));
                let dz = _mm512_sub_pd(x2, load(m, sz.as_ptr().add(j)));
                let d2 = _mm512_fmadd_pd(dx, dx, _mm512_fmadd_pd(dy, dy, _mm512_mul_pd(dz, dz)));
                let inv = inv_norm::<N>(d2);
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
}

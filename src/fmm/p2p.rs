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
    /// Stresslet `Σ (3/4π)(r·f)(r·n) r/|r|⁵` (portable loop).
    stresslet_portable, stresslet_body, ()
);

/// Stresslet `Σ (3/4π)(r·f)(r·n) r/|r|⁵` (the Stokes double layer's kernel with `f` the
/// density times the area and `n` the normal): AVX-512 or AVX2 intrinsics where available,
/// `1/|r|` to round-off.
pub fn stresslet(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    stresslet_on(Simd::best(), t, s, out);
}

/// [`stresslet`] on the instruction set `simd`; `false` (and nothing added) where the CPU
/// does not have it.
pub fn stresslet_on(simd: Simd, t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) -> bool {
    variants!(stresslet_portable, stresslet, 2).run(simd, t, s, out)
}

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
mod avx2;

/// Hand-vectorised AVX-512F loops, eight sources per step, the last partial group by masked
/// loads (masked-off lanes carry zero density). `1/|r|` from the 14-bit estimate
/// `rsqrt14` (double precision, whole exponent range) refined by `N` Newton steps (two: ≈ 1e-16
/// relative; one: [`super::Simd::one_newton_error`]); `d² = 0` gives 0.
#[cfg(target_arch = "x86_64")]
mod avx512;

//! Batched point-to-point evaluation: every target of a block against a block of sources
//! ([`SourceView`], structure of arrays). This is the near field (P2P) of the FMM and also how
//! the FMM evaluates sources or equivalent densities at check surfaces and targets.
//!
//! Each loop runs over sources innermost with scalar accumulators per target, with no branch
//! other than selects, so it vectorises; on x86-64 the same body is also compiled for AVX2/FMA
//! and chosen at run time. Coincident pairs (`r = 0`) are masked out (the singular kernels
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

#[inline(always)]
fn laplace_body(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let q = &s.q[0][..n];
    let (sx, sy, sz) = (&s.x[..n], &s.y[..n], &s.z[..n]);
    for (x, o) in t.iter().zip(out.iter_mut()) {
        let mut acc = 0.0;
        for j in 0..n {
            let (dx, dy, dz) = (x[0] - sx[j], x[1] - sy[j], x[2] - sz[j]);
            acc += q[j] * inv_norm(dx * dx + dy * dy + dz * dz);
        }
        *o += acc / FOUR_PI;
    }
}
dispatched!(
    /// Laplace single layer `Σ q/(4π|r|)`.
    laplace, laplace_body, ()
);

#[inline(always)]
fn laplace_dl_body(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let (sx, sy, sz) = (&s.x[..n], &s.y[..n], &s.z[..n]);
    let (q, nx, ny, nz) = (&s.q[0][..n], &s.n[0][..n], &s.n[1][..n], &s.n[2][..n]);
    for (x, o) in t.iter().zip(out.iter_mut()) {
        let mut acc = 0.0;
        for j in 0..n {
            let (dx, dy, dz) = (x[0] - sx[j], x[1] - sy[j], x[2] - sz[j]);
            let inv = inv_norm(dx * dx + dy * dy + dz * dz);
            acc += q[j] * (nx[j] * dx + ny[j] * dy + nz[j] * dz) * inv * inv * inv;
        }
        *o += acc / FOUR_PI;
    }
}
dispatched!(
    /// Laplace double layer `Σ (n·r) q/(4π|r|³)`.
    laplace_dl, laplace_dl_body, ()
);

#[inline(always)]
fn stokeslet_body(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let (sx, sy, sz) = (&s.x[..n], &s.y[..n], &s.z[..n]);
    let (fx, fy, fz) = (&s.q[0][..n], &s.q[1][..n], &s.q[2][..n]);
    for (x, o) in t.iter().zip(out.chunks_exact_mut(3)) {
        let (mut ax, mut ay, mut az) = (0.0, 0.0, 0.0);
        for j in 0..n {
            let (dx, dy, dz) = (x[0] - sx[j], x[1] - sy[j], x[2] - sz[j]);
            let inv = inv_norm(dx * dx + dy * dy + dz * dz);
            let rf = (dx * fx[j] + dy * fy[j] + dz * fz[j]) * inv * inv;
            ax += (fx[j] + rf * dx) * inv;
            ay += (fy[j] + rf * dy) * inv;
            az += (fz[j] + rf * dz) * inv;
        }
        o[0] += ax / EIGHT_PI;
        o[1] += ay / EIGHT_PI;
        o[2] += az / EIGHT_PI;
    }
}
dispatched!(
    /// Stokeslet `Σ (1/8π)(I/|r| + r rᵀ/|r|³) f`.
    stokeslet, stokeslet_body, ()
);

#[inline(always)]
fn stokeslet_source_body(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let (sx, sy, sz) = (&s.x[..n], &s.y[..n], &s.z[..n]);
    let (fx, fy, fz, m) = (&s.q[0][..n], &s.q[1][..n], &s.q[2][..n], &s.q[3][..n]);
    for (x, o) in t.iter().zip(out.chunks_exact_mut(3)) {
        let (mut ax, mut ay, mut az) = (0.0, 0.0, 0.0);
        for j in 0..n {
            let (dx, dy, dz) = (x[0] - sx[j], x[1] - sy[j], x[2] - sz[j]);
            let inv = inv_norm(dx * dx + dy * dy + dz * dz);
            let inv2 = inv * inv;
            let rf = (dx * fx[j] + dy * fy[j] + dz * fz[j]) * inv2;
            // (1/8π)(f + (r·f) r/r²)/r + (1/4π) m r/r³ = (1/8π)[f/r + (rf + 2m/r) r/r]
            let c = (rf + 2.0 * m[j] * inv2) * inv;
            ax += fx[j] * inv + c * dx;
            ay += fy[j] * inv + c * dy;
            az += fz[j] * inv + c * dz;
        }
        o[0] += ax / EIGHT_PI;
        o[1] += ay / EIGHT_PI;
        o[2] += az / EIGHT_PI;
    }
}
dispatched!(
    /// Stokeslet plus point source (the equivalent kernel of Stokes double layers).
    stokeslet_source, stokeslet_source_body, ()
);

#[inline(always)]
fn stresslet_body(t: &[[f64; 3]], s: &SourceView, out: &mut [f64]) {
    let n = s.len();
    let (sx, sy, sz) = (&s.x[..n], &s.y[..n], &s.z[..n]);
    let (fx, fy, fz) = (&s.q[0][..n], &s.q[1][..n], &s.q[2][..n]);
    let (nx, ny, nz) = (&s.n[0][..n], &s.n[1][..n], &s.n[2][..n]);
    for (x, o) in t.iter().zip(out.chunks_exact_mut(3)) {
        let (mut ax, mut ay, mut az) = (0.0, 0.0, 0.0);
        for j in 0..n {
            let (dx, dy, dz) = (x[0] - sx[j], x[1] - sy[j], x[2] - sz[j]);
            let inv = inv_norm(dx * dx + dy * dy + dz * dz);
            let inv2 = inv * inv;
            let c = (dx * fx[j] + dy * fy[j] + dz * fz[j])
                * (dx * nx[j] + dy * ny[j] + dz * nz[j])
                * inv2
                * inv2
                * inv;
            ax += c * dx;
            ay += c * dy;
            az += c * dz;
        }
        let k = 3.0 / FOUR_PI;
        o[0] += k * ax;
        o[1] += k * ay;
        o[2] += k * az;
    }
}
dispatched!(
    /// Stresslet `Σ (3/4π)(r·f)(r·n) r/|r|⁵`.
    stresslet, stresslet_body, ()
);

#[inline(always)]
fn rpy_body(t: &[[f64; 3]], s: &SourceView, out: &mut [f64], a: f64) {
    let n = s.len();
    let (sx, sy, sz) = (&s.x[..n], &s.y[..n], &s.z[..n]);
    let (fx, fy, fz) = (&s.q[0][..n], &s.q[1][..n], &s.q[2][..n]);
    let m0 = 1.0 / (6.0 * std::f64::consts::PI * a);
    let inv_a = 1.0 / a;
    let two_a2 = 4.0 * a * a;
    for (x, o) in t.iter().zip(out.chunks_exact_mut(3)) {
        let (mut ax, mut ay, mut az) = (0.0, 0.0, 0.0);
        for j in 0..n {
            let (dx, dy, dz) = (x[0] - sx[j], x[1] - sy[j], x[2] - sz[j]);
            let d2 = dx * dx + dy * dy + dz * dz;
            let inv = inv_norm(d2);
            let d = d2 * inv;
            // M/M0 = f I + g r̂r̂ (rpy_coefficients), written with r instead of r̂.
            let (sa, sa3) = (a * inv, a * a * a * inv * inv * inv);
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
            ax += fcoef * fx[j] + rf * dx;
            ay += fcoef * fy[j] + rf * dy;
            az += fcoef * fz[j] + rf * dz;
        }
        o[0] += m0 * ax;
        o[1] += m0 * ay;
        o[2] += m0 * az;
    }
}
dispatched!(
    /// Rotne–Prager–Yamakawa, both branches, self mobility `M0 f` at `r = 0`.
    rpy, rpy_body, (a: f64)
);

#[inline(always)]
fn rpy_far_body(t: &[[f64; 3]], s: &SourceView, out: &mut [f64], a: f64) {
    let n = s.len();
    let (sx, sy, sz) = (&s.x[..n], &s.y[..n], &s.z[..n]);
    let (fx, fy, fz) = (&s.q[0][..n], &s.q[1][..n], &s.q[2][..n]);
    // G + (a²/6)∇²G with ∇²G = (I − 3 r̂r̂)/(4π r³):
    // (1/8π)[(1/r + a²/(3r³)) f + (1/r³ − a²/r⁵)(r·f) r].
    let c2 = a * a / 3.0;
    for (x, o) in t.iter().zip(out.chunks_exact_mut(3)) {
        let (mut ax, mut ay, mut az) = (0.0, 0.0, 0.0);
        for j in 0..n {
            let (dx, dy, dz) = (x[0] - sx[j], x[1] - sy[j], x[2] - sz[j]);
            let inv = inv_norm(dx * dx + dy * dy + dz * dz);
            let inv2 = inv * inv;
            let ci = inv * (1.0 + c2 * inv2);
            let crr = inv * inv2 * (1.0 - 3.0 * c2 * inv2) * (dx * fx[j] + dy * fy[j] + dz * fz[j]);
            ax += ci * fx[j] + crr * dx;
            ay += ci * fy[j] + crr * dy;
            az += ci * fz[j] + crr * dz;
        }
        o[0] += ax / EIGHT_PI;
        o[1] += ay / EIGHT_PI;
        o[2] += az / EIGHT_PI;
    }
}
dispatched!(
    /// Half-corrected RPY far field `(1 + a²/6 ∇²) G`: what one side's finite size adds to a
    /// Stokeslet. Applied on the source side (P2M, P2L) and the target side (M2P, L2P) it gives
    /// the RPY far field `(1 + a²/3 ∇²) G` between beads in separated boxes.
    rpy_far, rpy_far_body, (a: f64)
);

//! The near-field (P2P) loops against the machine's own FMA peak, one core (issue: `mobo fmm`
//! as a tool; "P2P at ≥ 50 % of its roofline").
//!
//! ```text
//! cargo run --release --example p2p_roofline [-- N REPEATS]
//! ```
//!
//! * **Peak**: 16 independent chains of `a ← a·b + c` on 8-lane (AVX-512) or 4-lane (AVX2)
//!   vectors, counted as 2 flops per lane per FMA: what one core's FMA units deliver.
//! * **P2P**: all `N × N` pairs of `N` uniform points (default 2048, best of `REPEATS`), each
//!   instruction set's loop (`mobo::fmm::p2p::Simd`). Flops per pair are counted from the
//!   loops' arithmetic, an FMA as 2: Laplace 20 (3 differences, `r²` 5, the inverse square root
//!   10: two Newton steps after the hardware estimate, the accumulation 2), Stokeslet 37 (the
//!   same 18, `r·f` 5, `(r·f)/r²` 2, three components 12). The hardware estimate, compares and
//!   masks are not counted (they take issue slots that no flop counts), so the share of the
//!   peak is a lower bound on how busy the units are.
//! * **Laplace, one Newton step** (`Newton::One`, what the FMM runs up to 7 digits): 15 flops
//!   per pair. **Laplace mutual** (`laplace_mutual_with`, a point set on itself: one kernel
//!   evaluation serves both directions): the two halves of the cloud against each other,
//!   `pairs/s` counts both directions (2 per evaluation), flops per evaluation 17 (one Newton
//!   step) or 22 (two): the second direction's FMA on top.
use std::time::Instant;

use mobo::fmm::blocks::SourceBlock;
use mobo::fmm::clouds::Cloud;
use mobo::fmm::p2p::{self, Newton, Simd};

#[cfg(target_arch = "x86_64")]
mod peak {
    use std::arch::x86_64::*;

    /// Flops of `iters` rounds of 16 independent 8-lane FMAs, and the seconds they took.
    #[target_feature(enable = "avx512f")]
    pub unsafe fn avx512(iters: usize) -> (f64, f64) {
        let b = _mm512_set1_pd(0.999_999_9);
        let c = _mm512_set1_pd(1e-9);
        let mut a = [_mm512_set1_pd(1.0); 16];
        let t = std::time::Instant::now();
        for _ in 0..iters {
            for v in a.iter_mut() {
                *v = _mm512_fmadd_pd(*v, b, c);
            }
        }
        let s = t.elapsed().as_secs_f64();
        let mut sum = _mm512_setzero_pd();
        for v in a {
            sum = _mm512_add_pd(sum, v);
        }
        std::hint::black_box(_mm512_reduce_add_pd(sum));
        ((iters * 16 * 8 * 2) as f64, s)
    }

    /// The same with 4-lane AVX2 FMAs.
    #[target_feature(enable = "avx2,fma")]
    pub unsafe fn avx2(iters: usize) -> (f64, f64) {
        let b = _mm256_set1_pd(0.999_999_9);
        let c = _mm256_set1_pd(1e-9);
        let mut a = [_mm256_set1_pd(1.0); 16];
        let t = std::time::Instant::now();
        for _ in 0..iters {
            for v in a.iter_mut() {
                *v = _mm256_fmadd_pd(*v, b, c);
            }
        }
        let s = t.elapsed().as_secs_f64();
        let mut sum = _mm256_setzero_pd();
        for v in a {
            sum = _mm256_add_pd(sum, v);
        }
        let mut out = [0.0; 4];
        _mm256_storeu_pd(out.as_mut_ptr(), sum);
        std::hint::black_box(out);
        ((iters * 16 * 4 * 2) as f64, s)
    }
}

fn best<F: FnMut() -> (f64, f64)>(repeats: usize, mut f: F) -> f64 {
    (0..repeats)
        .map(|_| {
            let (flops, s) = f();
            flops / s
        })
        .fold(0.0, f64::max)
}

fn main() {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let n: usize = a.first().and_then(|s| s.parse().ok()).unwrap_or(2048);
    let repeats: usize = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(5);
    let iters = 50_000_000;
    #[cfg(target_arch = "x86_64")]
    let (peak512, peak256) = (
        is_x86_feature_detected!("avx512f")
            .then(|| best(repeats, || unsafe { peak::avx512(iters) })),
        (is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma"))
            .then(|| best(repeats, || unsafe { peak::avx2(iters) })),
    );
    #[cfg(not(target_arch = "x86_64"))]
    let (peak512, peak256): (Option<f64>, Option<f64>) = (None, None);
    let g = |v: Option<f64>| v.map_or("–".to_string(), |v| format!("{:.1}", v / 1e9));
    println!(
        "FMA peak, one core: AVX-512 {} GFLOP/s, AVX2 {} GFLOP/s\n",
        g(peak512),
        g(peak256)
    );
    let pts = Cloud::Uniform.points(n, 1);
    let order: Vec<usize> = (0..n).collect();
    println!(
        "| kernel | loop | pairs/s (10⁹) | flops/evaluation | GFLOP/s | of the same width's FMA peak |"
    );
    println!("|---|---|---|---|---|---|");
    for (name, dim, flops) in [("Laplace", 1usize, 20.0), ("Stokeslet", 3, 37.0)] {
        let mut src = SourceBlock::new(&pts, None, &order);
        src.set_density(&Cloud::densities(n * dim, 3), dim, &order);
        let mut out = vec![0.0; n * dim];
        let half = n / 2;
        let (ra, rb) = (0..half, half..n);
        // `b`'s outputs at the same address modulo 4096 as its coordinates, as in the FMM
        // (large arrays start at the same page offset): elsewhere, stores to the outputs can
        // falsely alias the next loads of the coordinates (4K aliasing) and halve the rate.
        let mut ob_buf = vec![0.0; n - half + 512];
        let shift = {
            let want = src.x[half..].as_ptr() as usize % 4096;
            let have = ob_buf.as_ptr() as usize % 4096;
            ((want + 4096 - have) % 4096) / 8
        };
        let ob = &mut ob_buf[shift..shift + n - half];
        for simd in [Simd::Portable, Simd::Avx2, Simd::Avx512] {
            if !simd.available() {
                continue;
            }
            // (loop, flops per kernel evaluation, interactions per evaluation)
            let mut loops: Vec<(&str, f64, f64)> = vec![("", flops, 1.0)];
            if dim == 1 && simd != Simd::Portable {
                loops.extend([
                    (" one Newton", 15.0, 1.0),
                    (" mutual", 22.0, 2.0),
                    (" mutual one Newton", 17.0, 2.0),
                ]);
            }
            for (what, flops, per) in loops {
                let newton = if what.contains("one Newton") {
                    Newton::One
                } else {
                    Newton::Two
                };
                let rate = best(repeats, || {
                    let t = Instant::now();
                    let evals = if what.contains("mutual") {
                        let (a, b) = (src.view(ra.clone()), src.view(rb.clone()));
                        p2p::laplace_mutual_with(simd, newton, &a, &mut out[..half], &b, ob);
                        (half * (n - half)) as f64
                    } else {
                        if dim == 1 {
                            p2p::laplace_with(simd, newton, &pts, &src.all(), &mut out);
                        } else {
                            p2p::stokeslet_on(simd, &pts, &src.all(), &mut out);
                        }
                        (n * n) as f64
                    };
                    (evals, t.elapsed().as_secs_f64())
                });
                std::hint::black_box((&out, &*ob));
                let peak = match simd {
                    Simd::Avx512 => peak512,
                    _ => peak256,
                };
                let share = peak.map_or("–".into(), |p| {
                    format!("{:.0} %", 100.0 * rate * flops / p)
                });
                println!(
                    "| {name} | {simd:?}{what} | {:.2} | {flops} | {:.1} | {share} |",
                    per * rate / 1e9,
                    rate * flops / 1e9
                );
            }
        }
    }
}

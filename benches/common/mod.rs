//! Timing helpers shared by the table benches: best-of-N wall time and faer's GEMM rate, the
//! reference every ratio in `benches/RESULTS.md` is taken against.

use std::time::Instant;

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, Par};

/// Best wall time of `f` over at least `min_reps` runs and `min_secs` seconds (at most 50 runs),
/// after one warm-up run.
pub fn best_of<F: FnMut()>(min_reps: usize, min_secs: f64, mut f: F) -> f64 {
    f();
    let start = Instant::now();
    let (mut best, mut n) = (f64::INFINITY, 0);
    while n < min_reps || start.elapsed().as_secs_f64() < min_secs {
        let t = Instant::now();
        f();
        best = best.min(t.elapsed().as_secs_f64());
        n += 1;
        if n >= 50 {
            break;
        }
    }
    best
}

/// faer's `n × n` GEMM rate in GFLOP/s (`2n³` flops).
pub fn gemm_rate(n: usize, par: Par) -> f64 {
    let a = Mat::<f64>::from_fn(n, n, |i, j| ((i * 7 + j * 3) % 11) as f64 - 5.0);
    let b = Mat::<f64>::from_fn(n, n, |i, j| ((i * 5 + j) % 13) as f64 - 6.0);
    let mut c = Mat::<f64>::zeros(n, n);
    let t = best_of(5, 1.0, || {
        matmul(c.as_mut(), Accum::Replace, a.as_ref(), b.as_ref(), 1.0, par);
        std::hint::black_box(&c);
    });
    2.0 * (n * n * n) as f64 / t / 1e9
}

//! Speed of the fused TEA-HI pass against faer's GEMM rate and the exact (Cholesky) step,
//! measured in one run. `cargo bench --bench brownian` (add `-- --full` for N = 10⁵).
//!
//! GFLOP/s counts 104 flops per ordered pair `(i, j)`, the count of the reference GPU
//! implementation (Geyer & Winter); the loop here does about 95 arithmetic operations, one square
//! root and one division per ordered pair.

mod common;

use std::hint::black_box;

use common::{best_of, gemm_rate};
use faer::Par;
use mobo::brownian::noise::cholesky_factor;
use mobo::brownian::tea_hi::{fused_pass, FusedSums, Soa};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

fn config(n: usize, seed: u64) -> Vec<[f64; 3]> {
    // Volume fraction 5%.
    let l = (n as f64 * 4.0 * std::f64::consts::PI / 3.0 / 0.05).cbrt();
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            [
                rng.random_range(0.0..l),
                rng.random_range(0.0..l),
                rng.random_range(0.0..l),
            ]
        })
        .collect()
}

fn main() {
    let full = std::env::args().any(|a| a == "--full");
    let threads = rayon::current_num_threads();
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let g1 = gemm_rate(512, Par::Seq);
    let gp = gemm_rate(512, Par::rayon(threads));
    println!("faer GEMM 512²: {g1:.1} GFLOP/s (1 thread), {gp:.1} GFLOP/s ({threads} threads)\n");
    println!("| N | fused pass 1 thr (ms) | GFLOP/s | / GEMM | fused pass {threads} thr (ms) | GFLOP/s | / GEMM |");
    println!("|---|---|---|---|---|---|---|");
    let mut sizes = vec![1_000usize, 3_000, 10_000, 30_000];
    if full {
        sizes.push(100_000);
    }
    let mut fused_times = Vec::new();
    for &n in &sizes {
        let pos = Soa::from_points(&config(n, 1));
        let f = Soa::from_points(&config(n, 2));
        let xi = Soa::from_points(&config(n, 3));
        let mut sums = FusedSums::default();
        let flops = 104.0 * (n * (n - 1)) as f64;
        let reps = if n >= 30_000 { 1 } else { 3 };
        let t1 = one.install(|| best_of(reps, 0.5, || fused_pass(&pos, &f, &xi, 1.0, &mut sums)));
        let tp = best_of(reps, 0.5, || fused_pass(&pos, &f, &xi, 1.0, &mut sums));
        fused_times.push((n, tp));
        println!(
            "| {n} | {:.2} | {:.1} | {:.0}% | {:.2} | {:.1} | {:.0}% |",
            t1 * 1e3,
            flops / t1 / 1e9,
            100.0 * flops / t1 / 1e9 / g1,
            tp * 1e3,
            flops / tp / 1e9,
            100.0 * flops / tp / 1e9 / gp
        );
    }
    println!("\nExact noise (dense RPY assembly + Cholesky of the 3N × 3N mobility) against the fused pass, {threads} threads:\n");
    println!("| N | Cholesky step (ms) | fused TEA-HI pass (ms) | Cholesky / TEA-HI |");
    println!("|---|---|---|---|");
    for n in [250usize, 500, 1000, 2000] {
        let p = config(n, 4);
        let tc = best_of(2, 0.5, || {
            black_box(cholesky_factor(&p, 1.0).unwrap());
        });
        let pos = Soa::from_points(&p);
        let mut sums = FusedSums::default();
        let tf = best_of(3, 0.3, || fused_pass(&pos, &pos, &pos, 1.0, &mut sums));
        println!(
            "| {n} | {:.2} | {:.3} | {:.0} |",
            tc * 1e3,
            tf * 1e3,
            tc / tf
        );
    }
    println!("\nThe FMM path (O(N)) for the deterministic part arrives with the FMM issue; no crossover is measured yet.");
}

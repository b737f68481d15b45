//! Self-interaction operators of a cell: assembly per cell with both rotation algorithms and
//! application batched over cells, beside faer's GEMM rate measured in the same run.
//!
//! `cargo bench --bench vesicle [-- CELLS]` (default 1000 cells at p = 6,
//! scaled down at larger p to stay within ~1.5 GB of operators). One thread.
//!
//! Flop counts: assembly counts the two GEMMs per latitude, the rotation of the surface for all
//! `2p` targets (`2 n_q n_p · 6p`) and the kernel rows times `B_i` (`2 · 18p · n_q · n_p`); the
//! per-target transforms, kernel evaluation and scatter are overhead on top of that count.
//! Application counts `2 (3n_p)²` per cell and right-hand side. With one right-hand side it is a
//! GEMV, bounded by the memory bandwidth (2 flops per 8-byte entry); the bench measures the read
//! bandwidth in the same run and reports the GEMV rate against that roofline as well as against
//! GEMM, and the same operators applied to 4 and 16 right-hand sides at once.

use std::time::Instant;

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, Par};
use mobo::vesicle::far_side::FarSideParams;
use mobo::vesicle::{shapes, LayerKernel, RotationAlgorithm, SelfInteraction};

fn gemm_rate(m: usize, k: usize, n: usize) -> f64 {
    let a = Mat::<f64>::from_fn(m, k, |i, j| ((i * 7 + j * 3) % 11) as f64 - 5.0);
    let b = Mat::<f64>::from_fn(k, n, |i, j| ((i * 5 + j) % 13) as f64 - 6.0);
    let mut c = Mat::<f64>::zeros(m, n);
    let flops = 2.0 * (m * k * n) as f64;
    let reps = ((2e9 / flops) as usize).clamp(1, 10_000);
    matmul(
        c.as_mut(),
        Accum::Replace,
        a.as_ref(),
        b.as_ref(),
        1.0,
        Par::Seq,
    );
    let t = Instant::now();
    for _ in 0..reps {
        matmul(
            c.as_mut(),
            Accum::Replace,
            a.as_ref(),
            b.as_ref(),
            1.0,
            Par::Seq,
        );
    }
    flops * reps as f64 / t.elapsed().as_secs_f64() / 1e9
}

fn main() {
    let cells_arg: Option<usize> = std::env::args()
        .skip(1)
        .find(|a| !a.starts_with('-'))
        .and_then(|s| s.parse().ok());
    println!(
        "faer GEMM 512² (1 thread): {:.1} GFLOP/s\n",
        gemm_rate(512, 512, 512)
    );
    println!("| p | q | algorithm | assembly (ms) | GFLOP/s | GEMM rate same shape | / GEMM | without far-side split (ms) | far side split off |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let mut ops = Vec::new();
    for p in [6usize, 12, 16] {
        let q = 2 * p;
        let np = 2 * p * (p + 1);
        let nq = 2 * q * (q + 1);
        let n3 = 3 * np;
        let rbc = shapes::rbc(p).expect("RBC");
        let flops =
            (p + 1) as f64 * (2.0 * (nq * np * 6 * p) as f64 + 2.0 * (18 * p * nq * np) as f64);
        let ref_rate = gemm_rate(18 * p, nq, np);
        for algo in [RotationAlgorithm::Direct, RotationAlgorithm::ViaSh] {
            let mut si = SelfInteraction::new(p, q, algo).expect("self-interaction");
            let mut a = vec![0.0; n3 * n3];
            let kernel = LayerKernel::SingleLayer { viscosity: 1.0 };
            si.assemble(kernel, rbc.coefs(), &mut a).expect("assemble");
            let reps = if p <= 6 { 20 } else { 3 };
            let t = Instant::now();
            for _ in 0..reps {
                si.assemble(kernel, rbc.coefs(), &mut a).expect("assemble");
            }
            let dt = t.elapsed().as_secs_f64() / reps as f64;
            let rate = flops / dt / 1e9;
            let (flagged, far_q) = si.far_side_plan();
            let flagged = flagged.len();
            // The same without the far-side split (the plain Graham–Sloan rule).
            si.set_far_side_params(FarSideParams {
                enabled: false,
                ..FarSideParams::default()
            })
            .expect("params");
            si.assemble(kernel, rbc.coefs(), &mut a).expect("assemble");
            let t = Instant::now();
            for _ in 0..reps {
                si.assemble(kernel, rbc.coefs(), &mut a).expect("assemble");
            }
            let dt_plain = t.elapsed().as_secs_f64() / reps as f64;
            si.set_far_side_params(FarSideParams::default())
                .expect("params");
            si.assemble(kernel, rbc.coefs(), &mut a).expect("assemble");
            println!(
                "| {p} | {q} | {algo:?} | {:.1} | {rate:.1} | {ref_rate:.1} | {:.0}% | {:.1} | {flagged} of {np}, Q = {far_q} |",
                dt * 1e3,
                100.0 * rate / ref_rate,
                dt_plain * 1e3,
            );
            if algo == RotationAlgorithm::Direct {
                ops.push((p, a));
            }
        }
    }
    // Application. One right-hand side per operator is a GEMV: 2 flops per 8-byte entry, so
    // its rate is bounded by the memory bandwidth, 2/8 · B ("roofline"), not by the GEMM rate.
    // Measured beside it: the same operators applied to k = 4 and 16 right-hand sides at once.
    let bandwidth = read_bandwidth();
    let roofline = bandwidth / 4.0;
    let gemm = gemm_rate(512, 512, 512);
    println!(
        "\nread bandwidth (1 thread, 512 MB): {bandwidth:.1} GB/s -> GEMV roofline {roofline:.2} GFLOP/s \
         ({:.0}% of GEMM {gemm:.1} GFLOP/s)",
        100.0 * roofline / gemm
    );
    println!(
        "\n| p | cells | MB per operator | k = 1: ms | GFLOP/s | / roofline | / GEMM | k = 4: GFLOP/s | k = 16: GFLOP/s | / GEMM |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for (p, a) in &ops {
        let n3 = 3 * 2 * p * (p + 1);
        let bytes = n3 * n3 * 8;
        let cells = cells_arg
            .unwrap_or(1000)
            .min((1.5e9 / bytes as f64) as usize)
            .max(1);
        // Every cell gets its own copy of the operator (as in a simulation) and its own density.
        let operators: Vec<Mat<f64>> = (0..cells)
            .map(|c| Mat::from_fn(n3, n3, |i, j| a[j * n3 + i] * (1.0 + 1e-3 * c as f64)))
            .collect();
        let mut rates = Vec::new();
        let mut ms = 0.0;
        for k in [1usize, 4, 16] {
            let dens = Mat::<f64>::from_fn(n3, k * cells, |i, j| ((i + 3 * j) % 7) as f64 - 3.0);
            let mut out = Mat::<f64>::zeros(n3, k * cells);
            let t = Instant::now();
            for (c, op) in operators.iter().enumerate() {
                matmul(
                    out.as_mut().subcols_mut(c * k, k),
                    Accum::Replace,
                    op.as_ref(),
                    dens.as_ref().subcols(c * k, k),
                    1.0,
                    Par::Seq,
                );
            }
            let dt = t.elapsed().as_secs_f64();
            if k == 1 {
                ms = dt * 1e3;
            }
            rates.push(2.0 * (n3 * n3 * k * cells) as f64 / dt / 1e9);
        }
        println!(
            "| {p} | {cells} | {:.2} | {ms:.1} | {:.2} | {:.0}% | {:.0}% | {:.1} | {:.1} | {:.0}% |",
            bytes as f64 / 1e6,
            rates[0],
            100.0 * rates[0] / roofline,
            100.0 * rates[0] / gemm,
            rates[1],
            rates[2],
            100.0 * rates[2] / gemm,
        );
    }
}

/// Read bandwidth of one thread in GB/s: the best of three sums over a 512 MB array.
fn read_bandwidth() -> f64 {
    let v: Vec<f64> = (0..64 << 20).map(|i| (i % 5) as f64).collect();
    let mut best = 0.0f64;
    for _ in 0..3 {
        let t = Instant::now();
        // Four independent accumulators so that the adds do not serialise.
        let mut s = [0.0f64; 4];
        for c in v.chunks_exact(4) {
            for (a, x) in s.iter_mut().zip(c) {
                *a += x;
            }
        }
        let dt = t.elapsed().as_secs_f64();
        std::hint::black_box(s);
        best = best.max((v.len() * 8) as f64 / dt / 1e9);
    }
    best
}

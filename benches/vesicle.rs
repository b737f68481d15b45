//! Self-interaction operators of a cell: assembly per cell with both rotation algorithms and
//! application batched over cells, beside faer's GEMM rate measured in the same run.
//!
//! `cargo bench --bench vesicle [-- CELLS]` (default 1000 cells at p = 6,
//! scaled down at larger p to stay within ~1.5 GB of operators). One thread.
//!
//! Assembly: `SelfInteraction::assemble` (the rows in coefficient space) against MOBO's GEMM with
//! the rotation matrices (`assemble_by_rotation_matrices`, both rotations) in the same run, each
//! also as "GEMM-equivalent" work (seconds × faer's one-thread GEMM rate of this run).
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
    println!("| p | q | method | assembly (ms) | × GEMM rate (GFLOP) | without far-side split (ms) | far side split off | vs rotation matrices (Direct) |");
    println!("|---|---|---|---|---|---|---|---|");
    let gemm = gemm_rate(512, 512, 512);
    let mut ops = Vec::new();
    for p in [6usize, 12, 16] {
        let q = 2 * p;
        let np = 2 * p * (p + 1);
        let n3 = 3 * np;
        let rbc = shapes::rbc(p).expect("RBC");
        let mut reference = f64::NAN;
        for (name, algo, by_matrices) in [
            ("rotation matrices, Direct", RotationAlgorithm::Direct, true),
            ("rotation matrices, ViaSh", RotationAlgorithm::ViaSh, true),
            ("coefficient rows", RotationAlgorithm::Direct, false),
        ] {
            let mut si = SelfInteraction::new(p, q, algo).expect("self-interaction");
            let mut a = vec![0.0; n3 * n3];
            let kernel = LayerKernel::SingleLayer { viscosity: 1.0 };
            let mut run = |si: &mut SelfInteraction, a: &mut [f64]| {
                if by_matrices {
                    si.assemble_by_rotation_matrices(kernel, rbc.coefs(), a)
                } else {
                    si.assemble(kernel, rbc.coefs(), a)
                }
                .expect("assemble")
            };
            run(&mut si, &mut a);
            let reps = if p <= 6 { 20 } else { 3 };
            let time =
                |si: &mut SelfInteraction,
                 a: &mut [f64],
                 run: &mut dyn FnMut(&mut SelfInteraction, &mut [f64])| {
                    let t = Instant::now();
                    for _ in 0..reps {
                        run(si, a);
                    }
                    t.elapsed().as_secs_f64() / reps as f64
                };
            let dt = time(&mut si, &mut a, &mut run);
            if by_matrices && algo == RotationAlgorithm::Direct {
                reference = dt;
            }
            let (flagged, far_q) = si.far_side_plan();
            let flagged = flagged.len();
            // The same without the far-side split (the plain Graham–Sloan rule).
            si.set_far_side_params(FarSideParams {
                enabled: false,
                ..FarSideParams::default()
            })
            .expect("params");
            run(&mut si, &mut a);
            let dt_plain = time(&mut si, &mut a, &mut run);
            si.set_far_side_params(FarSideParams::default())
                .expect("params");
            run(&mut si, &mut a);
            println!(
                "| {p} | {q} | {name} | {:.1} | {:.2} | {:.1} | {flagged} of {np}, Q = {far_q} | {:.2}× |",
                dt * 1e3,
                dt * gemm,
                dt_plain * 1e3,
                reference / dt,
            );
            if !by_matrices {
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

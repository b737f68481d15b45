//! Self-interaction operators of a cell: assembly per cell with both rotation algorithms and
//! application batched over cells, beside faer's GEMM rate measured in the same run.
//!
//! `cargo bench --bench vesicle [-- CELLS]` (default 1000 cells at p = 6,
//! scaled down at larger p to stay within ~1.5 GB of operators). One thread.
//!
//! Flop counts: assembly counts the two GEMMs per latitude, the rotation of the surface for all
//! `2p` targets (`2 n_q n_p · 6p`) and the kernel rows times `B_i` (`2 · 18p · n_q · n_p`); the
//! per-target transforms, kernel evaluation and scatter are overhead on top of that count.
//! Application counts `2 (3n_p)²` per cell (one GEMV per cell and right-hand side).

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
    println!("\n| p | cells | apply all (ms) | GFLOP/s | MB per operator |");
    println!("|---|---|---|---|---|");
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
        let dens = Mat::<f64>::from_fn(n3, cells, |i, j| ((i + 3 * j) % 7) as f64 - 3.0);
        let mut out = Mat::<f64>::zeros(n3, cells);
        let t = Instant::now();
        for (c, op) in operators.iter().enumerate() {
            matmul(
                out.as_mut().col_mut(c).as_mat_mut(),
                Accum::Replace,
                op.as_ref(),
                dens.as_ref().col(c).as_mat(),
                1.0,
                Par::Seq,
            );
        }
        let dt = t.elapsed().as_secs_f64();
        let flops = 2.0 * (n3 * n3) as f64 * cells as f64;
        println!(
            "| {p} | {cells} | {:.1} | {:.2} | {:.2} |",
            dt * 1e3,
            flops / dt / 1e9,
            bytes as f64 / 1e6
        );
    }
}

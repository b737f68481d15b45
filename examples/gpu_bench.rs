//! GPU against CPU in one run, printing Markdown rows (scripts/gpu_bench.sh collects them):
//!
//! * `gpu_bench p2p N` — pairs per second of every kernel: the GPU kernel alone (all pairs of N
//!   uniform points, best of several launches, both precisions where offered) and the CPU's
//!   AVX2 loop over all rayon threads on the same points (a 4096-target slice);
//! * `gpu_bench fmm KERNEL CLOUD N DIGITS MODE [LEAF_FACTOR]` — one FMM on N points with its
//!   near field on `cpu`, `gpu` (f64 where offered) or `gpu32`: setup, best of `REPS` (default
//!   3) evaluations, the phases, and the error against direct sums at 200 sampled targets.
//!
//! * `gpu_bench tea-hi N` — the TEA-HI fused pass (all pairs of N beads): the GPU pass alone
//!   against the CPU's AVX2 pass over all rayon threads (a 2048-row slice).
//!
//! `cargo run --release --features gpu --example gpu_bench -- p2p 65536`
use std::time::Instant;

use mobo::fmm::blocks::SourceBlock;
use mobo::fmm::clouds::Cloud;
use mobo::fmm::gpu_near::{choose, gpu_kernel};
use mobo::fmm::{order_for_digits, Fmm, FmmKernel};
use mobo::gpu::p2p::{PairPoints, PairSum};
use mobo::gpu::{Gpu, GpuChoice, GpuPrecision};
use rayon::prelude::*;

const KERNELS: [FmmKernel; 5] = [
    FmmKernel::Laplace,
    FmmKernel::LaplaceDoubleLayer,
    FmmKernel::Stokeslet,
    FmmKernel::Stresslet,
    FmmKernel::Rpy { radius: 0.002 },
];

fn p2p(n: usize) {
    let gpu = Gpu::shared().expect("a GPU adapter");
    eprintln!("adapter: {}", gpu.describe());
    let pts = Cloud::Uniform.points(n, 1);
    let nrm = Cloud::unit_vectors(n, 2);
    let identity: Vec<usize> = (0..n).collect();
    println!("| kernel | flops/pair | CPU pairs/s ({} threads) | GPU f32 pairs/s | GPU f32 GFLOP/s | GPU f64 pairs/s | GPU f64 GFLOP/s | GPU f32 / CPU |", rayon::current_num_threads());
    println!("|---|---|---|---|---|---|---|---|");
    for kind in KERNELS {
        let near = kind.near();
        let ds = near.density_dim();
        let dens = Cloud::densities(n * ds, 3);
        let mut block = SourceBlock::new(&pts, Some(&nrm), &identity);
        block.set_density(&dens, ds, &identity);
        // CPU: a slice of targets against all sources, chunks of 64 targets over the threads.
        let nt = 4096.min(n);
        let mut out = vec![0.0; nt * near.output_dim()];
        let view = block.all();
        let mut best_cpu = f64::INFINITY;
        for _ in 0..3 {
            let t = Instant::now();
            out.par_chunks_mut(64 * near.output_dim())
                .zip(pts[..nt].par_chunks(64))
                .for_each(|(o, tg)| near.eval_block(tg, &view, o));
            best_cpu = best_cpu.min(t.elapsed().as_secs_f64());
        }
        let cpu_rate = (nt * n) as f64 / best_cpu;
        let gk = gpu_kernel(kind);
        let mut rates = Vec::new();
        for prec in [GpuPrecision::F32, GpuPrecision::F64] {
            if prec == GpuPrecision::F64 && !gpu.has_f64() {
                rates.push(None);
                continue;
            }
            let sum = PairSum::all_pairs(
                gpu.clone(),
                gk,
                prec,
                PairPoints {
                    sources: &pts,
                    normals: Some(&nrm),
                    targets: &pts,
                },
            )
            .expect("pair sum");
            let q: Vec<&[f64]> = block.q[..ds].iter().map(|c| c.as_slice()).collect();
            let mut o = vec![0.0; n * near.output_dim()];
            sum.evaluate(&q, &mut o).expect("evaluate");
            let mut best = f64::INFINITY;
            for _ in 0..3 {
                best = best.min(sum.time_kernel(3).expect("time"));
            }
            rates.push(Some(sum.pairs() as f64 / best));
        }
        let f = gk.flops_per_pair();
        let cell =
            |r: Option<f64>, scale: f64| r.map_or("—".into(), |r| format!("{:.3e}", r * scale));
        println!(
            "| {} | {f} | {cpu_rate:.3e} | {} | {} | {} | {} | {} |",
            near.name(),
            cell(rates[0], 1.0),
            cell(rates[0], f * 1e-9),
            cell(rates[1], 1.0),
            cell(rates[1], f * 1e-9),
            rates[0].map_or("—".into(), |r| format!("{:.1}", r / cpu_rate)),
        );
    }
}

fn comps(s: &mobo::brownian::tea_hi::Soa) -> [&[f64]; 3] {
    [&s.x, &s.y, &s.z]
}

/// The TEA-HI fused pass: GPU (pass alone) against the CPU's AVX2 pass on all threads.
fn tea_hi(n: usize) {
    use mobo::brownian::tea_hi::{fused_rows, Soa};
    use mobo::gpu::tea_hi::{GpuTeaHi, FLOPS_PER_PAIR};
    let gpu = Gpu::shared().expect("a GPU adapter");
    // Beads of radius 0.5 at unit number density: both RPY branches occur.
    let side = (n as f64).cbrt();
    let pts: Vec<[f64; 3]> = Cloud::Uniform
        .points(n, 1)
        .iter()
        .map(|p| p.map(|c| c * side))
        .collect();
    let a = 0.5;
    let pos = Soa::from_points(&pts);
    let v = |seed| {
        let d = Cloud::densities(3 * n, seed);
        Soa::from_points(
            &d.chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect::<Vec<_>>(),
        )
    };
    let (force, xi) = (v(2), v(3));
    let nt = 2048.min(n);
    let mut rows = Vec::new();
    let mut best_cpu = f64::INFINITY;
    for _ in 0..3 {
        let t = Instant::now();
        fused_rows(&pos, &force, &xi, a, 0..nt, &mut rows);
        best_cpu = best_cpu.min(t.elapsed().as_secs_f64());
    }
    let cpu_rate = (nt * n) as f64 / best_cpu;
    let mut cells = Vec::new();
    for prec in [GpuPrecision::F32, GpuPrecision::F64] {
        if prec == GpuPrecision::F64 && !gpu.has_f64() {
            cells.push("— | —".to_string());
            continue;
        }
        let pass = GpuTeaHi::new(gpu.clone(), prec, n).expect("pass");
        pass.rows(comps(&pos), comps(&force), comps(&xi), a, 0..n, &mut rows)
            .expect("rows");
        let mut best = f64::INFINITY;
        for _ in 0..3 {
            best = best.min(pass.time_pass(3).expect("time"));
        }
        let rate = (n * n) as f64 / best;
        cells.push(format!("{rate:.3e} | {:.2}", rate * FLOPS_PER_PAIR * 1e-12));
    }
    println!("| pass | N | flops/pair | CPU pairs/s ({} threads) | GPU f32 pairs/s | f32 TFLOP/s | GPU f64 pairs/s | f64 TFLOP/s |", rayon::current_num_threads());
    println!("|---|---|---|---|---|---|---|---|");
    println!(
        "| TEA-HI | {n} | {FLOPS_PER_PAIR} | {cpu_rate:.3e} | {} | {} |",
        cells[0], cells[1]
    );
}

fn fmm(kernel: &str, cloud: &str, n: usize, digits: u32, mode: &str, leaf_factor: f64) {
    let kind = FmmKernel::from_name(kernel, Some(0.0005)).expect("kernel");
    let cloud = Cloud::from_name(cloud).expect("cloud");
    let pts = cloud.points(n, 1);
    let nrm = Cloud::unit_vectors(n, 2);
    let near = kind.near();
    let dens = Cloud::densities(n * near.density_dim(), 3);
    let order = order_for_digits(kind, digits).expect("digits");
    let leaf = (kind.default_leaf_size(order) as f64 * leaf_factor) as usize;
    let t0 = Instant::now();
    let mut fmm = Fmm::new(kind, &pts, Some(&nrm), &pts, order, leaf).expect("fmm");
    let decision = match mode {
        "cpu" => None,
        "gpu" => Some(choose(&mut fmm, GpuChoice::On, None, Some(digits)).expect("gpu")),
        "gpu32" => Some(
            choose(
                &mut fmm,
                GpuChoice::On,
                Some(GpuPrecision::F32),
                Some(digits),
            )
            .expect("gpu"),
        ),
        other => panic!("mode {other}"),
    };
    let setup = t0.elapsed().as_secs_f64();
    let mut u = vec![0.0; n * near.output_dim()];
    let mut best = f64::INFINITY;
    let mut timings = fmm.timings;
    let reps: usize = std::env::var("REPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(3);
    for _ in 0..reps.max(1) {
        u.fill(0.0);
        let t = Instant::now();
        fmm.evaluate(&dens, &mut u).expect("evaluate");
        let e = t.elapsed().as_secs_f64();
        if e < best {
            best = e;
            timings = fmm.timings;
        }
    }
    let m = 200.min(n);
    let idx: Vec<usize> = (0..m).map(|i| i * n / m).collect();
    let tg: Vec<[f64; 3]> = idx.iter().map(|&i| pts[i]).collect();
    let mut exact = Fmm::new(kind, &pts, Some(&nrm), &tg, 2, n + m).expect("direct");
    let mut want = vec![0.0; m * near.output_dim()];
    exact.direct(&dens, &mut want).expect("direct");
    let od = near.output_dim();
    let (mut num, mut den) = (0.0, 0.0);
    for (s, &i) in idx.iter().enumerate() {
        for c in 0..od {
            num += (u[i * od + c] - want[s * od + c]).powi(2);
            den += want[s * od + c].powi(2);
        }
    }
    println!(
        "| {} | {} | {n} | {digits} | {order} | {leaf} | {} | {} | {:.1e} | {setup:.2} | {best:.3} | {:.3} | {:.3} | {:.2e} |",
        near.name(),
        cloud.name(),
        rayon::current_num_threads(),
        decision.map_or("cpu".to_string(), |d| format!("gpu {}", d.precision.map_or("", |p| p.name()))),
        (num / den).sqrt(),
        timings.p2p,
        timings.far_wall,
        fmm.near_list().pairs() as f64,
    );
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    match a.get(1).map(String::as_str) {
        Some("p2p") => p2p(a.get(2).map_or(65536, |s| s.parse().expect("N"))),
        Some("tea-hi") => tea_hi(a.get(2).map_or(65536, |s| s.parse().expect("N"))),
        Some("fmm") if a.len() >= 7 => fmm(
            &a[2],
            &a[3],
            a[4].parse().expect("N"),
            a[5].parse().expect("DIGITS"),
            &a[6],
            a.get(7).map_or(1.0, |s| s.parse().expect("LEAF_FACTOR")),
        ),
        _ => eprintln!("usage: gpu_bench p2p N | gpu_bench tea-hi N | gpu_bench fmm KERNEL CLOUD N DIGITS cpu|gpu|gpu32 [LEAF_FACTOR]"),
    }
}

//! The DPD fluid on the GPU against the CPU on the same machine, in one run: particle-steps per
//! second of the whole step (cell lists rebuilt every step) in `f32` and `f64`, the force pass's
//! share, the CPU's step on all cores, one `f64` step checked against the CPU's, and the
//! temperature each GPU run holds. Prints Markdown rows for `benches/RESULTS.md`.
//!
//! ```sh
//! cargo run --release --features gpu --example dpd_gpu_bench -- 32:3 32:8 64:3
//! ```
//! Each argument is `L:ρ` (a cubic box of side `L`, number density `ρ`). Environment:
//! `STEPS` (timed GPU steps, default 500), `CPU_STEPS` (timed CPU steps, default 10), `POWER`
//! (kernel exponent, default 1), `PRECISIONS` (`f32,f64`).

use std::time::Instant;

use mobo::dpd::gpu_fluid::GpuFluid;
use mobo::dpd::pair_force::PairParams;
use mobo::dpd::system::{BodyForce, DpdParams, DpdSystem};
use mobo::gpu::{Gpu, GpuPrecision};

fn env<T: std::str::FromStr>(k: &str, d: T) -> T {
    std::env::var(k)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(d)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let steps: u64 = env("STEPS", 500);
    let cpu_steps: u64 = env("CPU_STEPS", 10);
    let power: f64 = env("POWER", 1.0);
    let precs: String = env("PRECISIONS", "f32,f64".to_string());
    let gpu = Gpu::shared()?;
    println!(
        "GPU: {}; CPU: {} threads; k = {power}; {steps} GPU steps and {cpu_steps} CPU steps timed",
        gpu.describe(),
        rayon::current_num_threads()
    );
    println!();
    println!("| box | ρ | particles | CPU step (ms) | CPU particle-steps/s | precision | GPU step (ms) | force pass (ms) | GPU particle-steps/s | GPU / CPU | k_BT after | f64 step vs CPU (max ΔF/max F) |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    let args: Vec<String> = std::env::args().skip(1).collect();
    let cases = if args.is_empty() {
        vec!["32:3".to_string()]
    } else {
        args
    };
    for case in cases {
        let (l, rho) = case.split_once(':').ok_or("arguments are L:rho")?;
        let (l, rho): (f64, f64) = (l.parse()?, rho.parse()?);
        let pair = PairParams {
            a: 25.0,
            gamma: 4.5,
            kbt: 1.0,
            rc: 1.0,
            power,
        };
        let params = DpdParams {
            box_len: [l; 3],
            pair,
            dt: 0.01,
            mass: 1.0,
            seed: 7,
        };
        let mut start = DpdSystem::random_fluid(params, rho, BodyForce::None)?;
        // Settle the random start (its overlaps) on the GPU in f32 before timing anything.
        {
            let mut dev = GpuFluid::new(gpu.clone(), &start, GpuPrecision::F32)?;
            dev.advance(200)?;
            dev.sync(&mut start)?;
        }
        let n = start.len();
        let mut cpu = start.clone();
        cpu.step()?;
        let t0 = Instant::now();
        for _ in 0..cpu_steps {
            cpu.step()?;
        }
        let cpu_s = t0.elapsed().as_secs_f64() / cpu_steps as f64;
        for prec in precs.split(',') {
            let prec = match prec.trim() {
                "f64" if gpu.has_f64() => GpuPrecision::F64,
                "f64" => continue,
                _ => GpuPrecision::F32,
            };
            let mut host = start.clone();
            let mut dev = GpuFluid::new(gpu.clone(), &host, prec)?;
            // f64: one step against the CPU's step of the same state.
            let check = if prec == GpuPrecision::F64 {
                let mut one = start.clone();
                one.step()?;
                dev.advance(1)?;
                let mut h = start.clone();
                dev.sync(&mut h)?;
                let force = |s: &DpdSystem| {
                    let mut m = std::collections::HashMap::new();
                    for i in 0..s.len() {
                        m.insert(s.particles.id[i], [s.fx[i], s.fy[i], s.fz[i]]);
                    }
                    m
                };
                let (a, b) = (force(&one), force(&h));
                let fmax = a.values().flatten().fold(0.0f64, |m, f| m.max(f.abs()));
                let d = a
                    .iter()
                    .map(|(id, f)| (0..3).map(|k| (f[k] - b[id][k]).abs()).fold(0.0, f64::max))
                    .fold(0.0, f64::max);
                format!("{:.1e}", d / fmax)
            } else {
                "–".to_string()
            };
            dev.advance(20)?;
            let t0 = Instant::now();
            dev.advance(steps)?;
            let gpu_s = t0.elapsed().as_secs_f64() / steps as f64;
            dev.sync(&mut host)?;
            let kt = host.kinetic_temperature();
            let mut pass = GpuFluid::new(gpu.clone(), &host, prec)?;
            pass.advance(1)?;
            let t0 = Instant::now();
            pass.forces_only(steps)?;
            let force_s = t0.elapsed().as_secs_f64() / steps as f64;
            println!(
                "| {l}³ | {rho} | {n} | {:.2} | {:.3e} | {} | {:.3} | {:.3} | {:.3e} | {:.1}× | {kt:.4} | {check} |",
                cpu_s * 1e3,
                n as f64 / cpu_s,
                prec.name(),
                gpu_s * 1e3,
                force_s * 1e3,
                n as f64 / gpu_s,
                cpu_s / gpu_s,
            );
        }
    }
    Ok(())
}

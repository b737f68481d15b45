//! Whole time steps of red-blood-cell suspensions in shear: cell-steps per core-second, the
//! share of each phase, GMRES iterations, memory, beside the machine's GEMM rate (faer, one
//! thread) measured in the same run and MOBO's published rate (about 6–7 cell-steps per
//! core-second at p = 6, Rahimian et al., SC'10).
//!
//! ```text
//! cargo bench --bench step [-- 6x1 6x100 6x1000 12x1 12x100]    # CONFIG = ORDERxCELLS
//! scripts/bench_step.sh                                           # the same, logged
//! ```
//!
//! Each configuration runs in a child process of this binary (so that its peak RSS, VmHWM of
//! /proc/self/status, is its own) with `RAYON_NUM_THREADS` threads (default 1: the rate is
//! per core without contention from the other sessions of a shared machine). The scene: RBCs
//! (Skalak, κ = 0.1, G_s = 1) placed at random in a cube at cell volume fraction 5 % (one
//! cell: at the origin), simple shear γ̇ = 1, dt = 0.05, GMRES tol 1e-8, upsampling 2, FMM 6
//! digits: the settings of `mobo run`. One untimed warm-up step (the first step starts GMRES
//! from σ = 0, sets the drift targets and, with several cells, pays the FMM's one-time operator
//! precomputation), then timed steps (`STEP_BENCH_STEPS`, default: at least 2, then until 15 s
//! of CPU time or 20 steps).
//!
//! Phases: "coupling" is the inter-cell coupling as `Suspension::coupling_stats` times it
//! (quadrature setup, FMM build + evaluation, self subtraction, near-singular corrections);
//! "cells" is the rest of the step (per-cell tractions for the coupling, operator assembly,
//! GMRES, reparametrisation, drift correction). No output is written (I/O: none). The part of
//! it spent assembling the dense self-interaction operators (once per cell and step) is
//! estimated from a separate timing of `SelfInteraction::assemble_rows` on an RBC at the same
//! `(p, 2p)`, times the cell-steps, over the CPU time of the steps (in parentheses, % of CPU).
//! "core-s" is the CPU time of the process (user + system, /proc/self/stat) over the timed
//! steps, so cell-steps per core-second is cells × steps / core-s; the GEMM-equivalent flops
//! per cell-step are the CPU seconds per cell-step times the GEMM rate of the same run (the
//! machine-independent cost the step-speed targets are stated in).

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, Par};
use mobo::run::assembly::build;
use mobo::scene::cells::parse;
use mobo::vesicle::{shapes, LayerKernel, RotationAlgorithm, SelfInteraction};

/// MOBO's rate at p = 6 (Rahimian et al., SC'10: about 6–7 cell-steps per core-second).
const MOBO_P6: f64 = 6.5;
/// Cell volume fraction of the random suspensions.
const VOLUME_FRACTION: f64 = 0.05;

/// faer's GEMM rate (one thread) in GFLOP/s per wall second and per CPU second: on a shared
/// machine the wall rate drops when the core is time-sliced, the CPU rate is the one to set
/// beside the per-core-second rates of the steps.
fn gemm_rate(m: usize, k: usize, n: usize) -> (f64, f64) {
    let a = Mat::<f64>::from_fn(m, k, |i, j| ((i * 7 + j * 3) % 11) as f64 - 5.0);
    let b = Mat::<f64>::from_fn(k, n, |i, j| ((i * 5 + j) % 13) as f64 - 6.0);
    let mut c = Mat::<f64>::zeros(m, n);
    let flops = 2.0 * (m * k * n) as f64;
    let reps = ((2e10 / flops) as usize).clamp(1, 100_000);
    let run = |c: &mut Mat<f64>| {
        matmul(
            c.as_mut(),
            Accum::Replace,
            a.as_ref(),
            b.as_ref(),
            1.0,
            Par::Seq,
        )
    };
    run(&mut c);
    let cpu0 = cpu_seconds();
    let t = Instant::now();
    for _ in 0..reps {
        run(&mut c);
    }
    let total = flops * reps as f64 / 1e9;
    (
        total / t.elapsed().as_secs_f64(),
        total / (cpu_seconds() - cpu0),
    )
}

/// Field `key` (kB) of /proc/self/status, in MB.
fn status_mb(key: &str) -> f64 {
    let s = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    s.lines()
        .find(|l| l.starts_with(key))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// CPU seconds (user + system) of this process, all threads.
fn cpu_seconds() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command name (which is in parentheses): state is field 3, utime 14,
    // stime 15; USER_HZ is 100 on Linux x86.
    let rest = s.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| {
        f.get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(f64::NAN)
    };
    (tick(11) + tick(12)) / 100.0
}

fn scene_text(p: usize, cells: usize) -> String {
    let cells_section = if cells == 1 {
        "[[cells]]\nshape = \"rbc\"\norientation = [0, 0, 1, 30]\nbending_modulus = 0.1\n\
         shear_modulus = 1.0\n"
            .to_string()
    } else {
        let side = (cells as f64 * 4.0 / 3.0 * std::f64::consts::PI / VOLUME_FRACTION).cbrt();
        let h = side / 2.0;
        format!(
            "[[cells]]\nshape = \"rbc\"\nbending_modulus = 0.1\nshear_modulus = 1.0\n\
             count = {cells}\nplacement = \"random\"\nseed = 11\n\
             region = [[{m}, {m}, {m}], [{h}, {h}, {h}]]\n",
            m = -h
        )
    };
    // STEP_BENCH_PRECONDITIONER: "sphere" (the default) or "cell" ([numerics] preconditioner).
    let preconditioner =
        std::env::var("STEP_BENCH_PRECONDITIONER").unwrap_or_else(|_| "sphere".into());
    format!(
        "[flow]\nkind = \"shear\"\nrate = 1.0\n\n{cells_section}\n[numerics]\norder = {p}\n\
         upsample = 2\nfmm_digits = 6\ngmres_tol = 1e-8\ndt = 0.05\n\
         preconditioner = \"{preconditioner}\"\n"
    )
}

/// CPU seconds of one assembly of the dense single-layer operator of an RBC at `(p, 2p)` (what
/// every cell does once per step: its rows over coefficients, as the grid storage keeps it),
/// the mean of a few after a warm-up.
fn assembly_seconds(p: usize) -> f64 {
    let rbc = shapes::rbc(p).expect("RBC");
    let n3 = 3 * 2 * p * (p + 1);
    let mut si = SelfInteraction::new(p, 2 * p, RotationAlgorithm::Direct).expect("layer");
    let mut a = vec![0.0; n3 * 3 * ((p + 1) * (p + 1) - 1)];
    let kernel = LayerKernel::SingleLayer { viscosity: 1.0 };
    si.assemble_rows(kernel, rbc.coefs(), &mut a)
        .expect("assemble");
    let reps = if p <= 8 { 20 } else { 3 };
    let c0 = cpu_seconds();
    for _ in 0..reps {
        si.assemble_rows(kernel, rbc.coefs(), &mut a)
            .expect("assemble");
    }
    (cpu_seconds() - c0) / reps as f64
}

/// One configuration, in this process; prints one `RESULT` line of JSON.
fn run_one(p: usize, cells: usize) {
    let rss0 = status_mb("VmRSS:");
    let scene = parse(Path::new("bench"), &scene_text(p, cells)).expect("scene");
    let t = Instant::now();
    let mut susp = build(&scene).expect("build");
    let build_s = t.elapsed().as_secs_f64();
    let rss_built = status_mb("VmRSS:");
    // Progress on stderr (a long configuration that is stopped still tells how far it got).
    eprintln!("p = {p}, {cells} cells: built in {build_s:.1} s, RSS {rss_built:.0} MB");
    let flow = scene.flow;
    let t = Instant::now();
    let r = susp.step(&|x| flow.velocity(x)).expect("warm-up step");
    let warm_s = t.elapsed().as_secs_f64();
    eprintln!(
        "warm-up step {warm_s:.1} s, RSS {:.0} MB, peak {:.0} MB",
        status_mb("VmRSS:"),
        status_mb("VmHWM:")
    );
    let warm_iters: usize = r.cells.iter().map(|c| c.gmres.iterations).sum();
    let fixed: Option<usize> = std::env::var("STEP_BENCH_STEPS")
        .ok()
        .and_then(|s| s.parse().ok());
    let c0 = susp.coupling_stats().unwrap_or_default();
    let builds0 = susp.own_preconditioner_builds();
    let cpu0 = cpu_seconds();
    let t = Instant::now();
    let mut iters = 0usize;
    let mut iters_max = 0usize;
    let mut unconverged = 0usize;
    let mut steps = 0usize;
    loop {
        let r = susp.step(&|x| flow.velocity(x)).expect("step");
        steps += 1;
        eprintln!(
            "step {steps}: {:.1} s wall so far, peak RSS {:.0} MB",
            t.elapsed().as_secs_f64(),
            status_mb("VmHWM:")
        );
        for c in &r.cells {
            iters += c.gmres.iterations;
            iters_max = iters_max.max(c.gmres.iterations);
            unconverged += usize::from(!c.gmres.converged);
        }
        let done = match fixed {
            Some(n) => steps >= n,
            None => steps >= 20 || (steps >= 2 && cpu_seconds() - cpu0 > 15.0),
        };
        if done {
            break;
        }
    }
    let wall = t.elapsed().as_secs_f64();
    let cpu = cpu_seconds() - cpu0;
    let c1 = susp.coupling_stats().unwrap_or_default();
    let json = serde_json::json!({
        "p": p,
        "cells": cells,
        "threads": rayon::current_num_threads(),
        "steps": steps,
        "build_s": build_s,
        "warmup_s": warm_s,
        "warmup_iters": warm_iters as f64 / cells as f64,
        "wall_s": wall,
        "cpu_s": cpu,
        "setup_s": c1.setup_s - c0.setup_s,
        "fmm_s": c1.fmm_s - c0.fmm_s,
        "self_s": c1.self_s - c0.self_s,
        "near_s": c1.near_s - c0.near_s,
        "near_points": c1.near_points - c0.near_points,
        "min_gap": if c1.min_gap.is_finite() { c1.min_gap } else { -1.0 },
        "iters": iters as f64 / (steps * cells) as f64,
        "iters_max": iters_max,
        "own_builds": (susp.own_preconditioner_builds() - builds0) as f64 / (steps * cells) as f64,
        "unconverged": unconverged,
        "rss0_mb": rss0,
        "rss_built_mb": rss_built,
        "hwm_mb": status_mb("VmHWM:"),
        "assembly_s": assembly_seconds(p),
    });
    println!("RESULT {json}");
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if let Some(i) = args.iter().position(|a| a == "--one") {
        let p = args[i + 1].parse().expect("order");
        let cells = args[i + 2].parse().expect("cells");
        run_one(p, cells);
        return;
    }
    let mut configs: Vec<(usize, usize)> = args
        .iter()
        .filter(|a| !a.starts_with('-'))
        .filter_map(|a| {
            let (p, c) = a.split_once('x')?;
            Some((p.parse().ok()?, c.parse().ok()?))
        })
        .collect();
    if configs.is_empty() {
        configs = vec![(6, 1), (6, 100), (6, 1000), (12, 1), (12, 100)];
    }
    let threads = std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "1".into());
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_default();
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    println!("machine: {cpu}, {cores} cores visible; RAYON_NUM_THREADS = {threads}");
    let (gemm_wall, gemm_cpu) = gemm_rate(512, 512, 512);
    println!(
        "faer GEMM 512² (1 thread): {gemm_cpu:.1} GFLOP/s per CPU second ({gemm_wall:.1} per \
         wall second)"
    );
    println!(
        "MOBO (SC'10): about {MOBO_P6} cell-steps per core-second at p = 6; target: ≥ 200 at \
         p = 6 for 1000 cells\n"
    );
    println!(
        "| p | cells | threads | timed steps | s per step (wall / CPU) | cell-steps per core-s \
         | GEMM-equivalent flops per cell-step | vs MOBO p=6 \
         | coupling % (setup/FMM/self/near) | cells % (of it: operator assembly) | GMRES it per cell-step (warm-up) \
         | build s | RSS after build MB per cell | peak RSS MB |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let exe = std::env::current_exe().expect("own path");
    for (p, cells) in configs {
        let out = Command::new(&exe)
            .args(["--one", &p.to_string(), &cells.to_string()])
            .env("RAYON_NUM_THREADS", &threads)
            // The child's progress and errors go straight to our stderr.
            .stderr(std::process::Stdio::inherit())
            .output()
            .expect("child");
        let text = String::from_utf8_lossy(&out.stdout);
        let Some(line) = text.lines().find_map(|l| l.strip_prefix("RESULT ")) else {
            println!(
                "| {p} | {cells} | failed: {} (its stderr above) |",
                out.status
            );
            continue;
        };
        let v: serde_json::Value = serde_json::from_str(line).expect("json");
        let f = |k: &str| v[k].as_f64().unwrap_or(f64::NAN);
        let steps = f("steps");
        let wall = f("wall_s");
        let rate = cells as f64 * steps / f("cpu_s");
        let coupling = f("setup_s") + f("fmm_s") + f("self_s") + f("near_s");
        let pc = |x: f64| 100.0 * x / wall;
        println!(
            "| {p} | {cells} | {} | {steps} | {:.3} / {:.3} | {rate:.1} | {:.2e} | {:.2}× | {:.1} ({:.1}/{:.1}/{:.1}/{:.1}) \
             | {:.1} ({:.0}) | {:.1} ({:.1}) | {:.2} | {:.2} | {:.0} |",
            v["threads"],
            wall / steps,
            f("cpu_s") / steps,
            // CPU seconds per cell-step × the GEMM rate of this run (issue 20's measure).
            gemm_cpu * 1e9 / rate,
            rate / MOBO_P6,
            pc(coupling),
            pc(f("setup_s")),
            pc(f("fmm_s")),
            pc(f("self_s")),
            pc(f("near_s")),
            pc(wall - coupling),
            100.0 * f("assembly_s") * cells as f64 * steps / f("cpu_s"),
            f("iters"),
            f("warmup_iters"),
            f("build_s"),
            (f("rss_built_mb") - f("rss0_mb")) / cells as f64,
            f("hwm_mb"),
        );
        eprintln!("{line}");
    }
}

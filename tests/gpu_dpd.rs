//! The DPD fluid stepped on the GPU (feature `gpu`) against the CPU's step, which is the
//! reference: one step and short trajectories in `f64` to rounding, the temperature and the
//! momentum of `f32` runs, bitwise reproducibility, the instability report and the refusals.
//!
//! Without a GPU these run on Mesa's lavapipe (scripts/test.sh installs it). Where no adapter
//! exists they skip with a message, except in CI (`CI=true`), where that is a failure.
#![cfg(feature = "gpu")]

mod common;

use std::collections::HashMap;
use std::sync::Arc;

use mobo::dpd::gpu_fluid::GpuFluid;
use mobo::dpd::pair_force::PairParams;
use mobo::dpd::system::{BodyForce, DpdParams, DpdSystem};
use mobo::dpd::DpdError;
use mobo::gpu::{Gpu, GpuPrecision};

use common::{checkpoint_bits, mobo, ok, summary, tmpdir, write, DPD_PARTICLE_ARRAYS};

fn gpu() -> Option<Arc<Gpu>> {
    common::gpu_or_skip("the GPU DPD tests")
}

fn fluid(box_len: [f64; 3], power: f64, body: BodyForce, seed: u64) -> DpdSystem {
    let pair = PairParams {
        a: 25.0,
        gamma: 4.5,
        kbt: 1.0,
        rc: 1.0,
        power,
    };
    let params = DpdParams {
        box_len,
        pair,
        dt: 0.01,
        mass: 1.0,
        seed,
    };
    DpdSystem::random_fluid(params, 3.0, body).unwrap()
}

/// `f32`, and `f64` where the adapter has it.
fn precisions(g: &Gpu) -> Vec<GpuPrecision> {
    let mut precs = vec![GpuPrecision::F32];
    if g.has_f64() {
        precs.push(GpuPrecision::F64);
    }
    precs
}

/// Per-id (position, velocity, force) of a system.
fn by_id(s: &DpdSystem) -> HashMap<u32, [[f64; 3]; 3]> {
    let p = &s.particles;
    (0..s.len())
        .map(|i| {
            (
                p.id[i],
                [
                    [p.x[i], p.y[i], p.z[i]],
                    [p.vx[i], p.vy[i], p.vz[i]],
                    [s.fx[i], s.fy[i], s.fz[i]],
                ],
            )
        })
        .collect()
}

/// Largest differences of positions (periodic), velocities and forces between two systems,
/// matched by id.
fn max_diff(a: &DpdSystem, b: &DpdSystem) -> [f64; 3] {
    let (ma, mb) = (by_id(a), by_id(b));
    assert_eq!(ma.len(), mb.len());
    let l = a.params.box_len;
    let mut d = [0.0f64; 3];
    for (id, x) in &ma {
        let y = &mb[id];
        for k in 0..3 {
            let dx = x[0][k] - y[0][k];
            d[0] = d[0].max((dx - l[k] * (dx / l[k]).round()).abs());
            d[1] = d[1].max((x[1][k] - y[1][k]).abs());
            d[2] = d[2].max((x[2][k] - y[2][k]).abs());
        }
    }
    d
}

#[test]
fn f64_steps_match_the_cpu_to_rounding() {
    let Some(g) = gpu() else { return };
    if !g.has_f64() {
        eprintln!("no f64 shaders on {}: skipped", g.describe());
        return;
    }
    // Both kernel exponents the examples use, a box that is not a cube (periodic shifts on every
    // axis, 5 × 6 × 7 cells), and the reverse-Poiseuille body force.
    for (power, body) in [
        (1.0, BodyForce::None),
        (0.25, BodyForce::ReversePoiseuille { force: 0.3 }),
        (0.5, BodyForce::Constant([0.1, -0.2, 0.05])),
    ] {
        let mut cpu = fluid([5.0, 6.5, 7.2], power, body, 11);
        let mut host = cpu.clone();
        let mut dev = GpuFluid::new(g.clone(), &host, GpuPrecision::F64).unwrap();
        // One step: forces of the same positions and noise, summed in another order.
        cpu.step().unwrap();
        dev.advance(1).unwrap();
        dev.sync(&mut host).unwrap();
        assert_eq!(host.step, 1);
        let d = max_diff(&cpu, &host);
        let fscale = cpu.fx.iter().map(|f| f.abs()).fold(0.0, f64::max);
        eprintln!("k = {power}: one step, max differences x {:.1e} v {:.1e} F {:.1e} (|F| up to {fscale:.1})", d[0], d[1], d[2]);
        assert!(d[0] < 1e-13 && d[1] < 1e-12, "k = {power}: {d:?}");
        assert!(
            d[2] < 1e-12 * fscale,
            "k = {power}: forces differ by {}",
            d[2]
        );
        assert!(
            (cpu.virial - host.virial).abs() < 1e-10 * cpu.virial.abs(),
            "virial {} vs {}",
            cpu.virial,
            host.virial
        );
        // 20 more steps: the rounding grows with the dynamics' chaos, slowly at first.
        for _ in 0..20 {
            cpu.step().unwrap();
        }
        dev.advance(20).unwrap();
        dev.sync(&mut host).unwrap();
        let d = max_diff(&cpu, &host);
        eprintln!(
            "k = {power}: 21 steps, max differences x {:.1e} v {:.1e} F {:.1e}",
            d[0], d[1], d[2]
        );
        assert!(d[0] < 1e-9 && d[1] < 1e-7, "k = {power}: {d:?}");
        // The synced state continues on the CPU as the CPU's own does.
        cpu.step().unwrap();
        host.step().unwrap();
        let d2 = max_diff(&cpu, &host);
        assert!(d2[0] < 1e-9, "CPU step after the sync: {d2:?}");
    }
}

#[test]
fn f64_steps_with_walls_match_the_cpu_to_rounding() {
    let Some(g) = gpu() else { return };
    if !g.has_f64() {
        eprintln!("no f64 shaders on {}: skipped", g.describe());
        return;
    }
    use mobo::dpd::walls::Wall;
    let base = fluid([6.0, 8.0, 8.0], 1.0, BodyForce::None, 4).params;
    // A channel driven by a body force, a sliding channel (Couette), and a pipe.
    let cases: [(&str, Wall, BodyForce, f64); 3] = [
        (
            "channel",
            Wall::channel(5.0, 8.0, 1.0).unwrap(),
            BodyForce::Constant([0.5, 0.0, 0.0]),
            0.0,
        ),
        (
            "couette",
            Wall::channel(5.0, 8.0, 1.0).unwrap(),
            BodyForce::None,
            1.5,
        ),
        (
            "pipe",
            Wall::pipe(2.5, 8.0, 8.0, 1.0).unwrap(),
            BodyForce::Constant([0.5, 0.0, 0.0]),
            0.0,
        ),
    ];
    for (name, wall, body, speed) in cases {
        let mut cpu = DpdSystem::with_wall(base, 3.0, body, wall, 20).unwrap();
        if speed != 0.0 {
            cpu.start_couette(speed).unwrap();
        }
        let frozen = cpu.particles.moves.iter().filter(|&&m| m == 0.0).count();
        assert!(frozen > 0, "{name}: frozen wall particles");
        let mut host = cpu.clone();
        let mut dev = GpuFluid::new(g.clone(), &host, GpuPrecision::F64).unwrap();
        for steps in [1u64, 20] {
            for _ in 0..steps {
                cpu.step().unwrap();
            }
            dev.advance(steps).unwrap();
            dev.sync(&mut host).unwrap();
            let d = max_diff(&cpu, &host);
            eprintln!(
                "{name}: {} steps, {} bounces (CPU {}), max differences x {:.1e} v {:.1e} F {:.1e}",
                cpu.step, host.bounces, cpu.bounces, d[0], d[1], d[2]
            );
            let fscale = cpu.fx.iter().map(|f| f.abs()).fold(0.0, f64::max);
            // One step: rounding (the same bounds as the periodic fluid's); 21 steps: the
            // rounding grown by the dynamics.
            let (bx, bv, bf) = if steps == 1 {
                (1e-13, 1e-12, 1e-12 * fscale)
            } else {
                (1e-11, 1e-10, 1e-9 * fscale)
            };
            assert!(d[0] < bx && d[1] < bv && d[2] < bf, "{name}: {d:?}");
            assert!(
                (cpu.virial - host.virial).abs() < 1e-9 * cpu.virial.abs(),
                "{name}: virial {} vs {}",
                cpu.virial,
                host.virial
            );
            assert_eq!(host.bounces, cpu.bounces, "{name}: bounce-backs");
            assert_eq!((host.leaked, cpu.leaked), (0, 0), "{name}: leaks");
            assert_eq!(host.n_moving(), cpu.n_moving());
        }
        // The frozen particles have not moved, and in Couette flow keep their wall's speed.
        let (a, b) = (by_id(&cpu), by_id(&host));
        for (i, m) in cpu.particles.id.iter().zip(&cpu.particles.moves) {
            if *m == 0.0 {
                assert_eq!(a[i][0], b[i][0], "{name}: frozen particle {i} moved");
                assert_eq!(a[i][1], b[i][1], "{name}: frozen particle {i}'s velocity");
            }
        }
        assert!(cpu.bounces > 0, "{name}: the test must bounce particles");
        // The synced state continues on the CPU as the CPU's own does.
        cpu.step().unwrap();
        host.step().unwrap();
        assert!(
            max_diff(&cpu, &host)[0] < 1e-11,
            "{name}: CPU step after the sync"
        );
    }
}

#[test]
fn f32_wall_flows_keep_their_walls() {
    let Some(g) = gpu() else { return };
    use mobo::dpd::walls::Wall;
    let base = fluid([6.0, 8.0, 8.0], 1.0, BodyForce::None, 6).params;
    for (name, wall, speed) in [
        ("channel", Wall::channel(5.0, 8.0, 1.0).unwrap(), 0.0),
        ("couette", Wall::channel(5.0, 8.0, 1.0).unwrap(), 1.5),
        ("pipe", Wall::pipe(2.5, 8.0, 8.0, 1.0).unwrap(), 0.0),
    ] {
        let body = if speed == 0.0 {
            BodyForce::Constant([0.5, 0.0, 0.0])
        } else {
            BodyForce::None
        };
        let mut host = DpdSystem::with_wall(base, 3.0, body, wall, 20).unwrap();
        if speed != 0.0 {
            host.start_couette(speed).unwrap();
        }
        let before = by_id(&host);
        let mut dev = GpuFluid::new(g.clone(), &host, GpuPrecision::F32).unwrap();
        dev.advance(200).unwrap();
        dev.sync(&mut host).unwrap();
        assert!(host.bounces > 0, "{name}: no bounce-backs");
        assert_eq!(host.leaked, 0, "{name}: leaks");
        let after = by_id(&host);
        let p = &host.particles;
        for k in 0..host.len() {
            let x = [p.x[k], p.y[k], p.z[k]];
            if p.moves[k] == 0.0 {
                // Frozen: position and velocity as uploaded, to f32 rounding.
                let (b, a) = (&before[&p.id[k]], &after[&p.id[k]]);
                for c in 0..3 {
                    assert!((a[0][c] - b[0][c]).abs() < 1e-5, "{name}: frozen moved");
                    assert!((a[1][c] - b[1][c]).abs() < 1e-5, "{name}: frozen velocity");
                }
            } else {
                assert!(
                    wall.sdf(x) < 0.0,
                    "{name}: particle {} in the wall",
                    p.id[k]
                );
            }
        }
        if speed != 0.0 {
            // The sliding walls drag the fluid: mean u_x above the middle is positive.
            let mid = 4.0;
            let (mut s, mut n) = (0.0, 0.0);
            for k in 0..host.len() {
                if p.moves[k] != 0.0 && p.z[k] > mid + 1.0 {
                    s += p.vx[k];
                    n += 1.0;
                }
            }
            assert!(
                s / n > 0.2 * speed,
                "{name}: upper half's mean u_x {}",
                s / n
            );
        }
    }
}

#[test]
fn runs_are_reproducible_and_conserve_momentum() {
    let Some(g) = gpu() else { return };
    let precs = precisions(&g);
    for prec in precs {
        let start = fluid([6.0, 6.0, 6.0], 1.0, BodyForce::None, 5);
        let p0 = start.momentum();
        let run = || {
            let mut host = start.clone();
            let mut dev = GpuFluid::new(g.clone(), &host, prec).unwrap();
            dev.advance(60).unwrap();
            dev.sync(&mut host).unwrap();
            host
        };
        let (a, b) = (run(), run());
        assert_eq!(a.particles, b.particles, "{prec:?}: two runs differ");
        assert_eq!((&a.fx, &a.fy, &a.fz), (&b.fx, &b.fy, &b.fz));
        // Pair forces are antisymmetric to rounding: the total momentum stays, to the
        // precision's rounding of N velocities of thermal size (~1).
        let tol = match prec {
            GpuPrecision::F32 => 1e-5 * a.len() as f64,
            GpuPrecision::F64 => 1e-12 * a.len() as f64,
        };
        let p = a.momentum();
        for k in 0..3 {
            assert!(
                (p[k] - p0[k]).abs() < tol,
                "{prec:?}: momentum {p:?} from {p0:?}"
            );
        }
    }
}

#[test]
fn f32_fluid_holds_its_temperature_and_pressure() {
    let Some(g) = gpu() else { return };
    // 648 particles; the CPU's f64 run of the same fluid gives the reference averages.
    let start = fluid([6.0, 6.0, 6.0], 1.0, BodyForce::None, 9);
    let average = |gpu_run: bool| {
        let mut host = start.clone();
        let mut dev = GpuFluid::new(g.clone(), &host, GpuPrecision::F32).unwrap();
        let (mut t, mut p, mut m) = (0.0, 0.0, 0.0);
        for block in 0..70 {
            if gpu_run {
                dev.advance(10).unwrap();
                dev.sync(&mut host).unwrap();
            } else {
                for _ in 0..10 {
                    host.step().unwrap();
                }
            }
            if block >= 30 {
                t += host.kinetic_temperature();
                p += host.pressure();
                m += 1.0;
            }
        }
        (t / m, p / m)
    };
    let (t_gpu, p_gpu) = average(true);
    let (t_cpu, p_cpu) = average(false);
    eprintln!("f32 GPU: k_BT {t_gpu:.4}, p {p_gpu:.3}; f64 CPU: k_BT {t_cpu:.4}, p {p_cpu:.3}");
    // 300 steps settle the random start (its overlaps heat the fluid: k_BT ≈ 1.10 after 100
    // steps, in both runs). Statistical error of 40 samples of 648 particles: about 1 % in
    // k_BT, 0.5 % in p.
    assert!((t_gpu - 1.0).abs() < 0.04, "k_BT {t_gpu}");
    assert!((t_gpu - t_cpu).abs() < 0.04, "k_BT {t_gpu} vs {t_cpu}");
    assert!((p_gpu - p_cpu).abs() < 0.03 * p_cpu, "p {p_gpu} vs {p_cpu}");
}

#[test]
fn an_unstable_run_is_reported_and_refusals_are_clear() {
    let Some(g) = gpu() else { return };
    // a = 10⁶ with dt = 0.01 throws overlapping particles out of the box within a step or two.
    let pair = PairParams {
        a: 1e6,
        gamma: 4.5,
        kbt: 1.0,
        rc: 1.0,
        power: 1.0,
    };
    let params = DpdParams {
        box_len: [4.0; 3],
        pair,
        dt: 0.01,
        mass: 1.0,
        seed: 3,
    };
    let mut host = DpdSystem::random_fluid(params, 3.0, BodyForce::None).unwrap();
    let mut dev = GpuFluid::new(g.clone(), &host, GpuPrecision::F32).unwrap();
    dev.advance(5).unwrap();
    match dev.sync(&mut host) {
        Err(DpdError::Unstable { step, .. }) => assert_eq!(step, 5),
        other => panic!("expected Unstable, got {other:?}"),
    }
    // Kernel exponents other than 1, 1/2, 1/4 need pow, which f64 WGSL lacks.
    if g.has_f64() {
        let s = fluid([4.0; 3], 0.3, BodyForce::None, 1);
        let e = GpuFluid::new(g.clone(), &s, GpuPrecision::F64)
            .err()
            .expect("k = 0.3 in f64 must be refused");
        assert!(e.to_string().contains("k = 0.3"), "{e}");
        // f32 takes it.
        assert!(GpuFluid::new(g.clone(), &s, GpuPrecision::F32).is_ok());
    }
}

/// A small periodic-Poiseuille scene (864 particles).
const SCENE: &str = r#"[dpd]
box = [6.0, 6.0, 8.0]
density = 3.0
a = 25.0
gamma = 4.5
kbt = 1.0
dt = 0.01
steps = 100
seed = 3
flow = "periodic_poiseuille"
force = 0.2
equilibrate = 20
sample_every = 5
blocks = 4
bins = 16
save_every = 40
"#;

#[test]
fn mobo_dpd_on_the_gpu_in_f64_follows_the_cpu_run() {
    let Some(g) = gpu() else { return };
    if !g.has_f64() {
        return;
    }
    let dir = tmpdir("gpu-dpd-scene");
    // The periodic scene, and a channel between frozen walls driven by a body force.
    let channel = SCENE
        .replace("flow = \"periodic_poiseuille\"", "flow = \"poiseuille\"")
        .replace(
            "seed = 3",
            "seed = 3\nwalls = { kind = \"planes\", gap = 6.0 }\nwall_warmup = 20",
        );
    for (kind, text) in [("periodic", SCENE.to_string()), ("channel", channel)] {
        let run = |name: &str, extra: &str| {
            let scene = write(
                &dir,
                &format!("{kind}-{name}.toml"),
                &format!("{text}{extra}"),
            );
            let out = dir.join(format!("{kind}-{name}"));
            ok(
                &mobo(&["dpd", &scene, "--out", out.to_str().unwrap(), "--quiet"]),
                name,
            );
            out
        };
        let cpu = run("cpu", "gpu = false\n");
        let dev = run("gpu", "gpu = true\ngpu_precision = \"f64\"\n");
        let (sc, sg) = (summary(&cpu), summary(&dev));
        assert_eq!(sc["fluid_step"]["device"], "cpu");
        assert_eq!(sg["fluid_step"]["device"], "gpu", "{}", sg["fluid_step"]);
        assert_eq!(sg["fluid_step"]["precision"], "f64");
        assert_eq!(sg["steps"], 100);
        // Observables rows (step, t, k_BT, pressure, momentum): the same run to rounding grown
        // over 100 steps of chaotic dynamics.
        common::assert_observables_close(&cpu, &dev, 1e-8, kind);
        // The profile sampled every 5 steps between syncs (moving particles only), and the
        // viscosity fitted to it; the walls' bounce-backs.
        let (vc, vg) = (
            sc["viscosity"]["value"].as_f64().unwrap(),
            sg["viscosity"]["value"].as_f64().unwrap(),
        );
        assert!(
            (vc - vg).abs() < 1e-8 * vc.abs(),
            "{kind}: viscosity {vc} vs {vg}"
        );
        let (tc, tg) = (
            sc["thermal_temperature"].as_f64().unwrap(),
            sg["thermal_temperature"].as_f64().unwrap(),
        );
        // Every bin of the profile enters it (frozen wall particles must not).
        assert!(
            (tc - tg).abs() < 1e-8 * tc,
            "{kind}: thermal k_BT {tc} vs {tg}"
        );
        assert_eq!(sc["bounces"], sg["bounces"], "{kind}");
        assert_eq!(sc["fluid_particles"], sg["fluid_particles"], "{kind}");
        if kind == "channel" {
            // The walls' warm-up ran where the fluid runs, and to rounding the same.
            assert_eq!(sc["wall_warmup"]["device"], "cpu");
            assert_eq!(sg["wall_warmup"]["device"], "gpu", "{}", sg["wall_warmup"]);
            assert!(sg["bounces"].as_u64().unwrap() > 0);
            assert_eq!(sg["leaked_particles"], 0);
        }
    }
}

#[test]
fn mobo_dpd_on_the_gpu_resumes_bit_for_bit_and_auto_says_why() {
    let Some(_g) = gpu() else { return };
    let dir = tmpdir("gpu-dpd-resume");
    // A box height that f32 cannot hold (8.3 rounds up to 8.3000002 in f32): the device's box
    // is the f32 below, so no synced position lands in [L, L_f32) for the host to re-wrap.
    let odd = SCENE.replace("box = [6.0, 6.0, 8.0]", "box = [6.0, 6.0, 8.3]");
    let scene = write(&dir, "s.toml", &format!("{odd}gpu = true\n"));
    let whole = dir.join("whole");
    ok(
        &mobo(&["dpd", &scene, "--out", whole.to_str().unwrap(), "--quiet"]),
        "whole",
    );
    let part = dir.join("part");
    ok(
        &mobo(&[
            "dpd",
            &scene,
            "--out",
            part.to_str().unwrap(),
            "--quiet",
            "--max-steps",
            "53",
        ]),
        "first part",
    );
    assert_eq!(summary(&part)["steps"], 53);
    ok(
        &mobo(&["dpd", "--resume", part.to_str().unwrap(), "--quiet"]),
        "resume",
    );
    assert_eq!(summary(&part)["fluid_step"]["precision"], "f32");
    assert_eq!(
        checkpoint_bits(&whole, &DPD_PARTICLE_ARRAYS),
        checkpoint_bits(&part, &DPD_PARTICLE_ARRAYS),
        "the resumed GPU run differs from the whole one"
    );
    // A Couette channel on the GPU, stopped and resumed: bit for bit too (the wall speed and
    // the bounce counts come back from the checkpoint).
    let couette = SCENE
        .replace("flow = \"periodic_poiseuille\"", "flow = \"couette\"")
        .replace("force = 0.2\n", "")
        .replace(
            "seed = 3",
            "seed = 3\nwalls = { kind = \"planes\", gap = 6.0 }\nwall_warmup = 20\nwall_speed = 0.5",
        );
    let cs = write(&dir, "couette.toml", &format!("{couette}gpu = true\n"));
    let (cw, cp) = (dir.join("couette-whole"), dir.join("couette-part"));
    ok(
        &mobo(&["dpd", &cs, "--out", cw.to_str().unwrap(), "--quiet"]),
        "couette whole",
    );
    ok(
        &mobo(&[
            "dpd",
            &cs,
            "--out",
            cp.to_str().unwrap(),
            "--quiet",
            "--max-steps",
            "47",
        ]),
        "couette part",
    );
    ok(
        &mobo(&["dpd", "--resume", cp.to_str().unwrap(), "--quiet"]),
        "couette resume",
    );
    assert_eq!(
        checkpoint_bits(&cw, &DPD_PARTICLE_ARRAYS),
        checkpoint_bits(&cp, &DPD_PARTICLE_ARRAYS),
        "the resumed GPU Couette run differs from the whole one"
    );
    assert_eq!(summary(&cw)["bounces"], summary(&cp)["bounces"]);
    assert!(summary(&cw)["bounces"].as_u64().unwrap() > 0);
    // A run started on the CPU and resumed on the GPU says so.
    let cpu_scene = write(&dir, "c.toml", &format!("{SCENE}gpu = false\n"));
    let moved = dir.join("moved");
    ok(
        &mobo(&[
            "dpd",
            &cpu_scene,
            "--out",
            moved.to_str().unwrap(),
            "--quiet",
            "--max-steps",
            "30",
        ]),
        "CPU part",
    );
    let copy = moved.join("scene.toml");
    let text = std::fs::read_to_string(&copy).unwrap();
    std::fs::write(&copy, text.replace("gpu = false", "gpu = true")).unwrap();
    ok(
        &mobo(&["dpd", "--resume", moved.to_str().unwrap(), "--quiet"]),
        "resume on the GPU",
    );
    let s = summary(&moved);
    assert_eq!(s["fluid_step"]["device"], "gpu");
    let why = s["fluid_step"]["reason"].as_str().unwrap();
    assert!(why.contains("before the resume ran on cpu"), "{why}");
    // auto: 864 particles stay on the CPU, with the reason.
    let auto = write(&dir, "auto.toml", SCENE);
    let out = dir.join("auto");
    ok(
        &mobo(&["dpd", &auto, "--out", out.to_str().unwrap(), "--quiet"]),
        "auto",
    );
    let s = summary(&out);
    assert_eq!(s["fluid_step"]["device"], "cpu");
    let why = s["fluid_step"]["reason"].as_str().unwrap();
    assert!(
        why.contains("not a hardware GPU") || why.contains("below the"),
        "{why}"
    );
}

/// The raw sums of a sampler's current block: per bin `Σ v_x` and counts
/// (`ProfileSampler::state`'s layout).
fn block_sums(s: &mobo::dpd::poiseuille::ProfileSampler) -> (Vec<f64>, Vec<f64>) {
    let (v, _) = s.state();
    let b = s.bins;
    (v[5..5 + b].to_vec(), v[5 + b..5 + 2 * b].to_vec())
}

#[test]
fn the_profile_binned_on_the_device_matches_the_hosts_binning() {
    use mobo::dpd::poiseuille::{FlowGeometry, ProfileSampler};
    use mobo::dpd::walls::Wall;
    let Some(g) = gpu() else { return };
    let precs = precisions(&g);
    // 1152 + wall particles: more than one chunk of 1024, the last one partial.
    let base = fluid([6.0, 8.0, 8.0], 1.0, BodyForce::None, 7).params;
    let body = BodyForce::Constant([0.5, 0.0, 0.0]);
    let cases = [
        (
            "periodic",
            None,
            FlowGeometry::Periodic,
            BodyForce::ReversePoiseuille { force: 0.5 },
        ),
        (
            "channel",
            Some(Wall::channel(5.0, 8.0, 1.0).unwrap()),
            FlowGeometry::Channel { lo: 1.5, hi: 6.5 },
            body,
        ),
        (
            "pipe",
            Some(Wall::pipe(2.5, 8.0, 8.0, 1.0).unwrap()),
            FlowGeometry::Pipe {
                center: [4.0, 4.0],
                radius: 2.5,
            },
            body,
        ),
    ];
    for prec in precs {
        for (name, wall, geometry, body) in cases {
            let mut host = match wall {
                None => fluid(base.box_len, 1.0, body, 7),
                Some(w) => DpdSystem::with_wall(base, 3.0, body, w, 20).unwrap(),
            };
            let mut dev = GpuFluid::new(g.clone(), &host, prec).unwrap();
            dev.advance(30).unwrap();
            dev.sync(&mut host).unwrap();
            let moving = host.n_moving() as f64;
            // 10 bins; and 300, more bins than the pass has threads.
            for bins in [10, 300] {
                let mut on_device = ProfileSampler::with_geometry(geometry, base.box_len, bins, 9);
                let mut on_host = on_device.clone();
                dev.sample_profile(&mut on_device).unwrap();
                on_host.sample(&host);
                let ((sd, cd), (sh, ch)) = (block_sums(&on_device), block_sums(&on_host));
                assert_eq!(cd.iter().sum::<f64>(), moving, "{name} {prec:?}: counted");
                assert_eq!(ch.iter().sum::<f64>(), moving);
                let misbinned: f64 = cd.iter().zip(&ch).map(|(a, b)| (a - b).abs()).sum();
                let total = |s: &[f64]| s.iter().sum::<f64>();
                let vmax = host.particles.vx.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                eprintln!(
                    "{name} {prec:?} {bins} bins: Σv device {:.9} host {:.9}, {misbinned} count differences",
                    total(&sd),
                    total(&sh)
                );
                match prec {
                    GpuPrecision::F64 => {
                        // The same bins (in a pipe the device's square root may round the
                        // radius of a particle at a bin edge the other way); the sums to
                        // rounding.
                        let radial = matches!(geometry, FlowGeometry::Pipe { .. });
                        if radial {
                            assert!(misbinned <= 2.0, "{name}: {misbinned} count differences");
                        } else {
                            assert_eq!(cd, ch, "{name}: counts");
                        }
                        if misbinned == 0.0 {
                            for (a, b) in sd.iter().zip(&sh) {
                                assert!((a - b).abs() < 1e-12 * moving * vmax, "{name}: {a} {b}");
                            }
                        }
                    }
                    GpuPrecision::F32 => {
                        // The coordinate in f32 may put a particle at a bin's edge next door
                        // (each such particle changes two counts); the sum over all bins is
                        // the total momentum to f32 rounding.
                        assert!(misbinned <= 4.0, "{name}: {misbinned} count differences");
                        assert!(
                            (total(&sd) - total(&sh)).abs() < 1e-5 * moving * vmax,
                            "{name}: Σ v_x"
                        );
                        if misbinned == 0.0 {
                            for ((a, b), c) in sd.iter().zip(&sh).zip(&cd) {
                                assert!((a - b).abs() < 1e-5 * c.max(1.0) * vmax, "{name}");
                            }
                        }
                    }
                }
            }
        }
    }
}

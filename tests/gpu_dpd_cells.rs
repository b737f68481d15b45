//! Cells in the DPD fluid with the solvent's pair forces on the GPU
//! (`mobo::dpd::gpu_pairs::GpuPairForces`, feature `gpu`) against the CPU's step, the
//! reference: in `f64` the solvent, the vertices, the bounce-backs and the leak count follow
//! the CPU's to rounding, periodic and between walls; in `f32` a run keeps its cell tight and
//! its momentum.
//!
//! Without a GPU these run on Mesa's lavapipe (scripts/test.sh installs it); where no adapter
//! exists they skip with a message, except in CI (`CI=true`).
#![cfg(feature = "gpu")]

mod common;

use std::collections::HashMap;

use mobo::dpd::gpu_pairs::GpuPairForces;
use mobo::dpd::membrane::MembraneParams;
use mobo::dpd::pair_force::PairParams;
use mobo::dpd::suspension::{CellSpec, CouplingParams, DpdSuspension};
use mobo::dpd::system::{BodyForce, DpdParams, DpdSystem};
use mobo::dpd::walls::Wall;
use mobo::gpu::GpuPrecision;
use mobo::vesicle::{shapes, CellMesh};

fn params(box_len: [f64; 3], seed: u64) -> DpdParams {
    let pair = PairParams {
        a: 25.0,
        gamma: 4.5,
        kbt: 1.0,
        rc: 1.0,
        power: 0.25,
    };
    DpdParams {
        box_len,
        pair,
        dt: 0.005,
        mass: 1.0,
        seed,
    }
}

/// A sphere of radius 1.8 (320 triangles) centred at `centre` in `fluid`.
fn with_sphere(fluid: DpdSystem, centre: [f64; 3]) -> DpdSuspension {
    let mesh = CellMesh::icosphere(&shapes::sphere(8, 1.8).unwrap(), 2).unwrap();
    let vertices = mesh
        .vertices
        .iter()
        .map(|v| [0, 1, 2].map(|k| v[k] + centre[k]))
        .collect();
    let mut membrane = MembraneParams::new(1.0, 0.05);
    membrane.ka = 500.0;
    membrane.kv = 500.0;
    let cell = CellSpec {
        vertices,
        triangles: mesh.triangles.clone(),
        params: membrane,
    };
    let coupling = CouplingParams {
        inner_extra_gamma: 2.0,
        ..CouplingParams::default()
    };
    DpdSuspension::new(fluid, vec![cell], coupling).unwrap()
}

/// The periodic box and the channel between plane walls (with a body force), each with one
/// cell.
fn suspensions() -> Vec<(&'static str, DpdSuspension)> {
    let periodic =
        DpdSystem::random_fluid(params([7.0, 7.5, 8.0], 5), 3.0, BodyForce::None).unwrap();
    let channel = DpdSystem::with_wall(
        params([7.0, 7.0, 9.0], 6),
        3.0,
        BodyForce::Constant([0.2, 0.0, 0.0]),
        Wall::Planes { lo: 1.0, hi: 8.0 },
        20,
    )
    .unwrap();
    vec![
        ("periodic", with_sphere(periodic, [3.5, 3.7, 4.0])),
        ("channel", with_sphere(channel, [3.5, 3.5, 4.5])),
    ]
}

/// Largest differences of the solvent's positions (periodic) and velocities, matched by id,
/// and of the vertices' positions and velocities.
fn max_diff(a: &DpdSuspension, b: &DpdSuspension) -> [f64; 4] {
    let l = a.fluid.params.box_len;
    let index = |s: &DpdSystem| -> HashMap<u32, usize> {
        s.particles
            .id
            .iter()
            .enumerate()
            .map(|(i, &id)| (id, i))
            .collect()
    };
    let (pa, pb) = (&a.fluid.particles, &b.fluid.particles);
    let ib = index(&b.fluid);
    let mut d = [0.0f64; 4];
    for i in 0..pa.len() {
        let j = ib[&pa.id[i]];
        let xa = [pa.x[i], pa.y[i], pa.z[i]];
        let xb = [pb.x[j], pb.y[j], pb.z[j]];
        let va = [pa.vx[i], pa.vy[i], pa.vz[i]];
        let vb = [pb.vx[j], pb.vy[j], pb.vz[j]];
        for k in 0..3 {
            let dx = xa[k] - xb[k];
            d[0] = d[0].max((dx - l[k] * (dx / l[k]).round()).abs());
            d[1] = d[1].max((va[k] - vb[k]).abs());
        }
    }
    for (ca, cb) in a.cells().iter().zip(b.cells()) {
        for (x, y) in ca.positions().iter().zip(cb.positions()) {
            (0..3).for_each(|k| d[2] = d[2].max((x[k] - y[k]).abs()));
        }
        for (x, y) in ca.velocities().iter().zip(cb.velocities()) {
            (0..3).for_each(|k| d[3] = d[3].max((x[k] - y[k]).abs()));
        }
    }
    d
}

#[test]
fn f64_pair_forces_on_the_gpu_step_cells_as_the_cpu() {
    let Some(g) = common::gpu_or_skip("the GPU tests of cells in the DPD fluid") else {
        return;
    };
    if !g.has_f64() {
        eprintln!("no f64 shaders on {}: skipped", g.describe());
        return;
    }
    for (name, mut cpu) in suspensions() {
        let mut dev = cpu.clone();
        let mut pairs = GpuPairForces::new(g.clone(), &dev.fluid, GpuPrecision::F64).unwrap();
        cpu.step().unwrap();
        dev.step_with(Some(&mut pairs)).unwrap();
        let d = max_diff(&cpu, &dev);
        eprintln!(
            "{name}: one step, solvent x {:.1e} v {:.1e}, vertices x {:.1e} v {:.1e}",
            d[0], d[1], d[2], d[3]
        );
        assert!(d.iter().all(|&e| e < 1e-12), "{name}, one step: {d:?}");
        assert!(
            (cpu.fluid.virial - dev.fluid.virial).abs() < 1e-10 * cpu.fluid.virial.abs(),
            "{name}: virial {} against {}",
            cpu.fluid.virial,
            dev.fluid.virial
        );
        for _ in 0..30 {
            cpu.step().unwrap();
            dev.step_with(Some(&mut pairs)).unwrap();
        }
        let d = max_diff(&cpu, &dev);
        eprintln!(
            "{name}: 31 steps, solvent x {:.1e} v {:.1e}, vertices x {:.1e} v {:.1e}; {} bounces off the membrane",
            d[0], d[1], d[2], d[3], cpu.bounces()
        );
        assert!(d[0] < 1e-9 && d[2] < 1e-9, "{name}, 31 steps: {d:?}");
        assert!(d[1] < 1e-7 && d[3] < 1e-7, "{name}, 31 steps: {d:?}");
        assert!(cpu.bounces() > 0, "{name}: no bounce-back tested");
        assert_eq!(cpu.bounces(), dev.bounces(), "{name}: bounces");
        assert_eq!(cpu.fluid.bounces, dev.fluid.bounces, "{name}: wall bounces");
        assert_eq!(cpu.count_leaks(), 0, "{name}: CPU leaks");
        assert_eq!(dev.count_leaks(), 0, "{name}: GPU leaks");
    }
}

#[test]
fn f32_pair_forces_keep_the_cell_tight_and_the_momentum() {
    let Some(g) = common::gpu_or_skip("the GPU tests of cells in the DPD fluid") else {
        return;
    };
    let (_, mut sim) = suspensions().remove(0);
    let mut pairs = GpuPairForces::new(g, &sim.fluid, GpuPrecision::F32).unwrap();
    assert_eq!(pairs.precision(), GpuPrecision::F32);
    let p0 = sim.momentum();
    let inner0 = sim.inner_count(0);
    for _ in 0..200 {
        sim.step_with(Some(&mut pairs)).unwrap();
    }
    assert_eq!(sim.count_leaks(), 0);
    assert_eq!(sim.inner_count(0), inner0);
    let p = sim.momentum();
    let n = (sim.fluid.len() + sim.cells()[0].positions().len()) as f64;
    // f32 pair forces cancel to rounding of |F| ~ 10² per pair: a drift of the mean velocity
    // far below the thermal speed 1 over 200 steps.
    for k in 0..3 {
        assert!(
            ((p[k] - p0[k]) / n).abs() < 1e-4,
            "mean momentum drifted by {:?}",
            [0, 1, 2].map(|k| (p[k] - p0[k]) / n)
        );
    }
    let t = sim.fluid.kinetic_temperature();
    assert!((t - 1.0).abs() < 0.05, "solvent k_BT {t}");
}

/// A channel between walls sliding at ±0.5 with one sphere in it, 60 steps.
const SCENE: &str = r#"[dpd]
box = [8.0, 8.0, 10.0]
density = 3.0
a = 25.0
gamma = 4.5
kbt = 1.0
power = 0.25
dt = 0.005
steps = 60
seed = 4
walls = { kind = "planes", gap = 8.0 }
wall_warmup = 20
flow = "couette"
wall_speed = 0.5
save_every = 20

[[dpd.cells]]
shape = "sphere"
radius = 1.8
center = [4.0, 4.0, 5.0]
subdivisions = 2
shear_modulus = 20.0
bending_rigidity = 2.0
"#;

#[test]
fn mobo_dpd_with_cells_on_the_gpu_in_f64_follows_the_cpu_run() {
    let Some(g) = common::gpu_or_skip("the GPU tests of cells in the DPD fluid") else {
        return;
    };
    if !g.has_f64() {
        eprintln!("no f64 shaders on {}: skipped", g.describe());
        return;
    }
    let dir = common::tmpdir("gpu-dpd-cells-scene");
    let run = |name: &str, extra: &str| {
        let text = SCENE.replace("save_every = 20\n", &format!("save_every = 20\n{extra}"));
        let scene = common::write(&dir, &format!("{name}.toml"), &text);
        let out = dir.join(name);
        common::ok(
            &common::mobo(&["dpd", &scene, "--out", out.to_str().unwrap(), "--quiet"]),
            name,
        );
        out
    };
    let cpu = run("cpu", "gpu = false\n");
    let dev = run("gpu", "gpu = true\ngpu_precision = \"f64\"\n");
    let (sc, sg) = (common::summary(&cpu), common::summary(&dev));
    assert_eq!(sc["fluid_step"]["device"], "cpu");
    assert_eq!(sg["fluid_step"]["device"], "gpu", "{}", sg["fluid_step"]);
    assert!(
        sg["fluid_step"]["reason"]
            .as_str()
            .unwrap()
            .contains("pair forces"),
        "{}",
        sg["fluid_step"]
    );
    // The walls' warm-up ran where the fluid runs.
    assert_eq!(sc["wall_warmup"]["device"], "cpu");
    assert_eq!(sg["wall_warmup"]["device"], "gpu", "{}", sg["wall_warmup"]);
    assert_eq!(sg["wall_warmup"]["steps"], 20);
    // Observables rows and the cell's shape: the same run to rounding grown over 80 steps.
    common::assert_observables_close(&cpu, &dev, 1e-8, "cells on the GPU against the CPU");
    assert_eq!(sc["bounces"], sg["bounces"]);
    assert_eq!(sc["fluid_particles"], sg["fluid_particles"]);
    let (mc, mg) = (&sc["membranes"], &sg["membranes"]);
    assert_eq!(mc["bounces"], mg["bounces"], "{mc} vs {mg}");
    assert!(mg["bounces"].as_u64().unwrap() > 0, "{mg}");
    assert_eq!(mg["leaked_particles"], 0, "{mg}");
    for key in ["taylor_deformation", "area_change", "volume_change"] {
        let (c, g) = (
            mc["per_cell"][0][key].as_f64().unwrap(),
            mg["per_cell"][0][key].as_f64().unwrap(),
        );
        assert!((c - g).abs() < 1e-8, "{key}: {c} vs {g}");
    }
}

//! Cells in the DPD fluid (`mobo::dpd::suspension`): exact momentum conservation with the
//! bounce-back impulses, no solvent crossing a membrane, the vertices at the fluid's
//! temperature (equipartition), and the drag of a cell pulled through the fluid against
//! Stokes' law with Hasimoto's periodic correction.
//!
//! `cargo test --release --test dpd_cells -- --ignored --nocapture` runs the full drag
//! measurement (scripts/dpd_cell_drag.sh writes docs/dpd_cells.md from it).

use mobo::dpd::membrane::{BendingModel, MembraneParams, Moduli};
use mobo::dpd::pair_force::PairParams;
use mobo::dpd::suspension::{CellSpec, CouplingParams, DpdSuspension};
use mobo::dpd::system::{BodyForce, DpdParams, DpdSystem};
use mobo::vesicle::{shapes, CellMesh};

/// The standard fluid (a = 25, γ = 4.5, ρ = 3, k_BT = 1) in a cube of side `side`.
fn fluid(side: f64, dt: f64, seed: u64) -> DpdSystem {
    let pair = PairParams {
        a: 25.0,
        gamma: 4.5,
        kbt: 1.0,
        rc: 1.0,
        power: 1.0,
    };
    let params = DpdParams {
        box_len: [side; 3],
        pair,
        dt,
        mass: 1.0,
        seed,
    };
    DpdSystem::random_fluid(params, 3.0, BodyForce::None).unwrap()
}

/// A spherical capsule of radius `radius` centred at `centre`: the icosphere of `subdivisions`
/// on the spherical-harmonic sphere, with a stiff membrane (μ0 = 100, κ = 20 k_BT, Fedosov's
/// area and volume coefficients).
fn sphere_cell(radius: f64, centre: [f64; 3], subdivisions: u32) -> CellSpec {
    let mesh = CellMesh::icosphere(&shapes::sphere(8, radius).unwrap(), subdivisions).unwrap();
    let lengths = mesh.edge_lengths();
    let l0 = lengths.iter().sum::<f64>() / lengths.len() as f64;
    let params = MembraneParams::from_moduli(&Moduli::new(
        100.0,
        20.0,
        BendingModel::Juelicher { c0: 2.0 / radius },
        l0,
    ))
    .unwrap();
    CellSpec {
        vertices: mesh
            .vertices
            .iter()
            .map(|v| [v[0] + centre[0], v[1] + centre[1], v[2] + centre[2]])
            .collect(),
        triangles: mesh.triangles.clone(),
        params,
    }
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// Momentum is conserved to rounding: every pair force is antisymmetric and every bounce-back
/// impulse is returned to the triangle's vertices. The test sees bounces (it can fail).
#[test]
fn momentum_is_conserved_with_bounce_back() {
    let mut sim = DpdSuspension::new(
        fluid(8.0, 0.005, 11),
        vec![sphere_cell(2.0, [4.0; 3], 2)],
        CouplingParams {
            check_every: 50,
            ..CouplingParams::default()
        },
    )
    .unwrap();
    let p0 = sim.momentum();
    for _ in 0..300 {
        sim.step().unwrap();
    }
    let p1 = sim.momentum();
    let scale = (sim.fluid.len() as f64).sqrt(); // thermal momentum scale, m √N k_BT
    let drift = norm([p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]]);
    println!(
        "momentum drift {drift:.3e} over 300 steps, {} bounces",
        sim.bounces()
    );
    assert!(sim.bounces() > 100, "only {} bounces", sim.bounces());
    assert!(drift < 1e-10 * scale, "momentum drift {drift:e}");
}

/// No solvent particle ends on the wrong side of the membrane, counted at every step, while
/// the cell is pushed through the fluid (so that the triangles move and bounce particles).
#[test]
fn no_solvent_crosses_a_moving_membrane() {
    let mut sim = DpdSuspension::new(
        fluid(8.0, 0.005, 5),
        vec![sphere_cell(2.0, [4.0; 3], 2)],
        CouplingParams {
            check_every: 1,
            ..CouplingParams::default()
        },
    )
    .unwrap();
    let inner = sim.inner_count(0);
    // ρ × (4/3)π R³ ≈ 100 inner particles.
    assert!((70..140).contains(&inner), "inner solvent {inner}");
    sim.set_external_force(0, [60.0, 0.0, 0.0]).unwrap();
    let x0 = sim.cells()[0].centroid();
    for _ in 0..600 {
        sim.step().unwrap();
        assert_eq!(sim.leaked(), 0, "step {}", sim.fluid.step);
    }
    let x1 = sim.cells()[0].centroid();
    println!(
        "moved {:.3} along x, {} bounces, inner {inner}",
        x1[0] - x0[0],
        sim.bounces()
    );
    assert!(
        x1[0] - x0[0] > 0.2,
        "the pulled cell did not move: {x0:?} → {x1:?}"
    );
    assert!(sim.bounces() > 100, "only {} bounces", sim.bounces());
    assert_eq!(sim.inner_count(0), inner);
}

/// Equipartition: the vertices, coupled to the solvent by dissipative and random forces and
/// to each other by the membrane's viscosity, reach the fluid's temperature.
#[test]
fn vertices_reach_the_fluid_temperature() {
    let mut sim = DpdSuspension::new(
        fluid(8.0, 0.005, 9),
        vec![sphere_cell(2.0, [4.0; 3], 2)],
        CouplingParams::default(),
    )
    .unwrap();
    for _ in 0..400 {
        sim.step().unwrap();
    }
    let (mut tv, mut tf) = (0.0, 0.0);
    let n = 1600;
    for _ in 0..n {
        sim.step().unwrap();
        tv += sim.vertex_temperature();
        tf += sim.fluid.kinetic_temperature();
    }
    let (tv, tf) = (tv / n as f64, tf / n as f64);
    println!(
        "vertex k_BT {tv:.4}, solvent {tf:.4}, leaked {}",
        sim.max_leaked()
    );
    // Statistical error of these means: about 1 % (the fluid alone in this box reads
    // 0.997–1.023 over windows of this length).
    assert!((tf - 1.0).abs() < 0.035, "solvent k_BT {tf}");
    assert!((tv - 1.0).abs() < 0.035, "vertex k_BT {tv}");
    assert_eq!(sim.max_leaked(), 0);
}

/// A more viscous cytoplasm (`inner_gamma`: extra dissipative pairs among the inner solvent,
/// with their own noise) keeps the fluctuation–dissipation balance: the inner solvent stays at
/// the fluid's temperature with γ_Δ = 40 (nine times the fluid's γ; a noise amplitude off by
/// 10 % would move it by 20 %). Its viscosity is not measured here.
#[test]
fn inner_viscosity_keeps_the_inner_solvent_at_k_bt() {
    let run = |inner_gamma: f64| {
        let mut sim = DpdSuspension::new(
            fluid(8.0, 0.005, 21),
            vec![sphere_cell(2.0, [4.0; 3], 2)],
            CouplingParams {
                inner_extra_gamma: inner_gamma,
                ..CouplingParams::default()
            },
        )
        .unwrap();
        for _ in 0..300 {
            sim.step().unwrap();
        }
        let n = 1200;
        let mut t = 0.0;
        for _ in 0..n {
            sim.step().unwrap();
            t += sim.inner_temperature(0);
        }
        (t / n as f64, sim.max_leaked())
    };
    let (t0, l0) = run(0.0);
    let (t40, l40) = run(40.0);
    println!("inner k_BT: {t0:.4} without, {t40:.4} with inner_gamma = 40");
    assert!((t0 - 1.0).abs() < 0.05, "inner k_BT {t0}");
    assert!(
        (t40 - 1.0).abs() < 0.05,
        "inner k_BT {t40} with inner_gamma = 40"
    );
    assert_eq!((l0, l40), (0, 0));
}

/// The cells' loops run in parallel (their own forces, the solvent–vertex pairs, the inner
/// viscosity, the bounce-back, the leak count), each cell's contributions to the solvent added
/// in cell order: three cells with a viscous interior (two 0.3 apart, in contact; the third
/// 1.4–1.5 from them, so solvent particles lie near several membranes), stepped on 1 and on 3
/// threads, end in the same state bit for bit (solvent, vertices, counters).
#[test]
fn cells_give_the_same_run_on_any_thread_count() {
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let cells = vec![
                sphere_cell(1.5, [3.0, 3.0, 3.0], 2),
                sphere_cell(1.5, [6.3, 3.2, 3.1], 2),
                sphere_cell(1.5, [4.5, 6.4, 5.5], 2),
            ];
            let mut sim = DpdSuspension::new(
                fluid(10.0, 0.005, 31),
                cells,
                CouplingParams {
                    inner_extra_gamma: 20.0,
                    check_every: 5,
                    ..CouplingParams::default()
                },
            )
            .unwrap();
            sim.set_external_force(1, [2.0, 0.0, 0.0]).unwrap();
            for _ in 0..60 {
                sim.step().unwrap();
            }
            let p = &sim.fluid.particles;
            (
                [
                    p.x.clone(),
                    p.y.clone(),
                    p.z.clone(),
                    p.vx.clone(),
                    p.vy.clone(),
                    p.vz.clone(),
                ],
                sim.state(),
            )
        })
    };
    let (fluid1, cells1) = run(1);
    let (fluid3, cells3) = run(3);
    assert!(
        cells1.counters[0] > 0,
        "no bounce in the run: {:?}",
        cells1.counters
    );
    assert_eq!(fluid1, fluid3, "solvent differs between 1 and 3 threads");
    assert_eq!(cells1, cells3, "cells differ between 1 and 3 threads");
}

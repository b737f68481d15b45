//! A cell scene built and stepped through the library instead of `mobo run`: two spheres
//! sedimenting side by side and a tilted red blood cell sedimenting above them (three cells
//! coupled through the Stokeslet FMM), typed in code as a [`SceneSpec`], validated by
//! [`SceneSpec::build`] (the checks of a scene file, with errors that name the key), turned
//! into a [`Suspension`] by [`mobo::run::assembly::build`] and advanced with
//! [`Suspension::step`]. Every step prints, per cell, the centroid, the tilt of the axis of
//! largest moment of inertia (an RBC's axis of symmetry) from z (arbitrary for the spheres),
//! the relative area drift and the GMRES iterations.
//!
//! ```text
//! cargo run --release --example library_scene [-- STEPS [ORDER]]
//! ```
//!
//! Defaults: 10 steps at p = 8 (a few seconds). The same loop is what a study would write to
//! record its own observables (here: the sedimentation speed of the pair, `1/(6π) ≈ 0.053`
//! for one sphere alone, about 20% more for the pair at 4 radii apart, a little more with the
//! RBC sinking above them). [`mobo::Simulation`] runs the same steps with the scene's
//! adaptive `dt` and the caller's own forces.

use mobo::run::assembly::build;
use mobo::scene::spec::{
    CellGroupSpec, FlowKind, FlowSpec, FluidSpec, NumericsSpec, SceneSpec, ShapeKind,
};
use mobo::timestep::suspension::Suspension;
use mobo::vesicle::SurfaceCalculus;

/// The scene at SH order `order`: a red blood cell with Skalak shear elasticity tilted by 30°
/// about x above two spheres, all three pulled down (−z) by a unit force.
fn scene(order: usize) -> SceneSpec {
    let pulled = |shape, center: [f64; 3]| CellGroupSpec {
        center: Some(center),
        force: Some([0.0, 0.0, -1.0]),
        bending_modulus: Some(0.1),
        ..CellGroupSpec::new(shape)
    };
    SceneSpec {
        fluid: Some(FluidSpec { viscosity: 1.0 }),
        flow: Some(FlowSpec {
            kind: FlowKind::None,
            ..Default::default()
        }),
        cells: vec![
            CellGroupSpec {
                orientation: Some([1.0, 0.0, 0.0, 30.0]),
                shear_modulus: Some(1.0),
                ..pulled(ShapeKind::Rbc, [0.0, 0.0, 5.0])
            },
            pulled(ShapeKind::Sphere, [-2.0, 0.0, 0.0]),
            pulled(ShapeKind::Sphere, [2.0, 0.0, 0.0]),
        ],
        numerics: Some(NumericsSpec {
            order: Some(order),
            dt: Some(0.05),
            t_end: Some(1.0),
            gmres_tol: Some(1e-8),
            fmm_digits: Some(5),
            ..Default::default()
        }),
        ..Default::default()
    }
}

/// Centroid, area, tilt (degrees from z of the axis of largest moment of inertia) of one cell.
fn observe(calc: &mut SurfaceCalculus, coefs: &[f64]) -> ([f64; 3], f64, f64) {
    let g = calc.geometry(coefs).expect("geometry");
    let (_, axes) = g.principal_axes();
    let tilt = axes[2][2].abs().min(1.0).acos().to_degrees();
    (g.centroid(), g.area(), tilt)
}

fn main() {
    let mut args = std::env::args().skip(1);
    let steps: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(10);
    let order: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(8);
    let scene = scene(order).build().unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(2)
    });
    for e in scene.effects.iter().filter(|e| e.enabled) {
        println!("effect: {} ({})", e.name, e.reason);
    }
    let mut susp: Suspension = build(&scene).unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(1)
    });
    let mut calc = SurfaceCalculus::new(scene.numerics.order).expect("surface calculus");
    let area0: Vec<f64> = susp
        .coefs()
        .iter()
        .map(|c| observe(&mut calc, c).1)
        .collect();
    let flow = scene.flow;
    let dt = scene.numerics.dt;
    println!(
        "{} cells, p = {}, dt = {dt}, {steps} steps",
        susp.len(),
        scene.numerics.order
    );
    println!("step  cell  centroid (x, y, z)              tilt (deg)  area drift  GMRES");
    let mut z_prev: Vec<f64> = susp
        .coefs()
        .iter()
        .map(|c| observe(&mut calc, c).0[2])
        .collect();
    for k in 1..=steps {
        let report = susp.step(&|x| flow.velocity(x)).unwrap_or_else(|e| {
            eprintln!("step {k}: {e}");
            std::process::exit(1)
        });
        for (i, c) in susp.coefs().iter().enumerate() {
            let (x, a, inc) = observe(&mut calc, c);
            println!(
                "{k:4}  {i:4}  ({:8.4}, {:8.4}, {:8.4})  {inc:10.2}  {:10.2e}  {:5}",
                x[0],
                x[1],
                x[2],
                (a - area0[i]) / area0[i],
                report.cells[i].gmres.iterations
            );
            if k == steps && i > 0 {
                println!(
                    "      sphere {i} sinks at {:.5} (one sphere alone: 1/(6π) = {:.5})",
                    (z_prev[i] - x[2]) / dt,
                    1.0 / (6.0 * std::f64::consts::PI)
                );
            }
            z_prev[i] = x[2];
        }
    }
    if let Some(st) = susp.coupling_stats() {
        println!(
            "coupling: {} FMM builds, {} near points, min gap {:.3}, {:.3} s (setup {:.3}, FMM \
             {:.3}, self {:.3}, near {:.3})",
            st.fmm_builds,
            st.near_points,
            st.min_gap,
            st.setup_s + st.fmm_s + st.self_s + st.near_s,
            st.setup_s,
            st.fmm_s,
            st.self_s,
            st.near_s
        );
    }
}

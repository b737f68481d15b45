//! The library path of `examples/library_scene.rs` (a scene parsed from TOML, built into a
//! `Suspension` and stepped by hand), with short settings and physical checks: the example
//! scene of two spheres sedimenting side by side sinks faster than one sphere alone, by the
//! two-sphere mobility; a red blood cell in shear keeps its area and its GMRES solves converge.

use std::f64::consts::PI;
use std::path::Path;

use mobo::run::assembly::build;
use mobo::scene::cells::{load, parse};
use mobo::vesicle::SurfaceCalculus;

/// Centroid velocities (per cell) over the `steps`-th step of `scene`.
fn velocities(scene: &mobo::scene::cells::CellScene, steps: usize) -> Vec<[f64; 3]> {
    let mut susp = build(scene).unwrap();
    let mut calc = SurfaceCalculus::new(scene.numerics.order).unwrap();
    let flow = scene.flow;
    let mut before = Vec::new();
    for k in 1..=steps {
        if k == steps {
            before = susp
                .coefs()
                .iter()
                .map(|c| calc.geometry(c).unwrap().centroid())
                .collect();
        }
        let r = susp.step(&|x| flow.velocity(x)).unwrap();
        assert!(r.cells.iter().all(|c| c.gmres.converged), "{r:?}");
    }
    susp.coefs()
        .iter()
        .zip(&before)
        .map(|(c, b)| {
            let x = calc.geometry(c).unwrap().centroid();
            std::array::from_fn(|d| (x[d] - b[d]) / scene.numerics.dt)
        })
        .collect()
}

#[test]
fn two_sedimenting_spheres_scene_sinks_faster_than_one_sphere() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/scenes/two_sedimenting_spheres.toml");
    let mut pair = load(&path).unwrap();
    assert_eq!(pair.cells.len(), 2);
    pair.numerics.t_end = 2.0 * pair.numerics.dt;
    let d = (pair.cells[1].center[0] - pair.cells[0].center[0]).abs();
    let a = pair.cells[0].radius;
    // The same sphere alone (same order, dt, tolerance).
    let mut alone = pair.clone();
    alone.cells.truncate(1);
    let u1 = velocities(&alone, 2)[0];
    let u0 = pair.cells[0].force[2].abs() / (6.0 * PI * a);
    println!("one sphere: {u1:?}, F/6πμa = {u0}");
    assert!((-u1[2] - u0).abs() < 1e-3 * u0, "{u1:?} vs {u0}");
    let v = velocities(&pair, 2);
    let s = a / d;
    // Side by side: 1 + 3a/4d + a³/2d³ (Rotne–Prager); the exact two-sphere mobility of rigid
    // spheres differs by O(a⁶/d⁶) (≈ 2e-4 here; Batchelor 1976), the vesicles' deformation and
    // the quadrature by less.
    let rp = 1.0 + 0.75 * s + 0.5 * s.powi(3);
    for u in &v {
        let ratio = u[2] / u1[2];
        println!("pair: {u:?}, U/U_alone = {ratio:.5}, 1 + 3a/4d + a³/2d³ = {rp:.5}");
        assert!(ratio > 1.1, "the pair does not sink faster: {ratio}");
        assert!((ratio - rp).abs() < 1e-3, "{ratio} vs {rp}");
        // Side by side, the spheres neither approach nor separate nor leave the plane y = 0.
        assert!(u[0].abs() < 1e-4 * u0 && u[1].abs() < 1e-4 * u0, "{u:?}");
    }
    // Mirror symmetry of the pair.
    assert!((v[0][2] - v[1][2]).abs() < 1e-8 * u0, "{v:?}");
}

#[test]
fn rbc_in_shear_through_the_library_keeps_its_area() {
    let scene = parse(
        Path::new("rbc (test)"),
        r#"
[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "rbc"
orientation = [0, 0, 1, 30]
bending_modulus = 0.1
shear_modulus = 1.0
[numerics]
order = 6
dt = 0.05
"#,
    )
    .unwrap();
    let mut susp = build(&scene).unwrap();
    assert!(
        susp.coupling_stats().is_none(),
        "one cell builds no coupling"
    );
    let mut calc = SurfaceCalculus::new(6).unwrap();
    let g0 = calc.geometry(&susp.cells()[0].state.coefs).unwrap();
    let (a0, c0) = (g0.area(), g0.centroid());
    let flow = scene.flow;
    for _ in 0..5 {
        let r = susp.step(&|x| flow.velocity(x)).unwrap();
        assert!(r.cells[0].gmres.converged);
        assert!(r.cells[0].gmres.iterations > 0);
    }
    let g = calc.geometry(&susp.cells()[0].state.coefs).unwrap();
    let drift = (g.area() - a0) / a0;
    println!("area drift {drift:.2e}, centroid {:?}", g.centroid());
    assert!(drift.abs() < 1e-6, "{drift}");
    // A cell centred on the zero-velocity plane of the shear stays there (up to the
    // discretisation).
    let c = g.centroid();
    assert!(
        (0..3).all(|d| (c[d] - c0[d]).abs() < 1e-3),
        "{c:?} vs {c0:?}"
    );
}

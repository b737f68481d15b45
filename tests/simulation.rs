//! The library's stepping API (`scene::simulation::Simulation`) with forces of the caller's:
//! a user traction equal to the scene's body force gives the same run (the own cell and,
//! through the coupling, its neighbour), the optical-tweezers patch pair puts exactly `±F` on
//! the two ends and stretches a cell (at constant area) without moving it, `advance_to` lands on the time asked,
//! and a force that returns NaN stops the step with the cell named.

use std::path::Path;

use mobo::run::simulation::Simulation;
use mobo::scene::cells::parse;
use mobo::timestep::cell_force::{CellForce, CellView, ForceFn, PatchPair, VectorField};
use mobo::vesicle::geometry::SurfaceCalculus;

fn scene(text: &str) -> mobo::scene::cells::CellScene {
    parse(Path::new("test scene"), text).expect("valid scene")
}

const PAIR: &str = r#"
[flow]
kind = "shear"
rate = 0.5

[[cells]]
shape = "sphere"
center = [-1.6, 0.0, 0.0]
FORCE

[[cells]]
shape = "rbc"
center = [1.6, 0.0, 0.4]
shear_modulus = 0.5

[numerics]
order = 6
dt = 0.05
t_end = 0.15
fmm_digits = 6
gmres_tol = 1e-8
"#;

#[test]
fn a_user_traction_is_the_body_force_for_the_cell_and_its_neighbour() {
    let with_body = scene(&PAIR.replace("FORCE", "force = [0.0, 0.0, -2.0]"));
    let plain = scene(&PAIR.replace("FORCE", ""));
    let mut a = Simulation::new(with_body).unwrap();
    let mut b = Simulation::new(plain).unwrap();
    b.add_force(ForceFn::new(
        "sink cell 0",
        |cell: &CellView, t: &mut VectorField| {
            if cell.id == 0 {
                let area = cell.geometry.area();
                for k in 0..t.n_points() {
                    t.add(k, [0.0, 0.0, -2.0 / area]);
                }
            }
        },
    ));
    let rbc0 = b.cell(1).unwrap().geometry.centroid();
    let (na, nb) = (
        a.advance_to(0.15, |_, _| {}).unwrap(),
        b.advance_to(0.15, |_, _| {}).unwrap(),
    );
    assert_eq!((na, nb), (3, 3));
    let mut moved = 0.0f64;
    for i in 0..2 {
        let (ca, cb) = (a.cell(i).unwrap().coefs, b.cell(i).unwrap().coefs);
        let diff = ca
            .iter()
            .zip(&cb)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(
            diff < 1e-9,
            "cell {i}: user force vs body force differ by {diff:e}"
        );
    }
    // The neighbour felt the sinking sphere: its centroid's z-velocity differs from the run
    // without any force (compared against that run, not assumed).
    let mut free = Simulation::new(scene(&PAIR.replace("FORCE", ""))).unwrap();
    free.advance_to(0.15, |_, _| {}).unwrap();
    let (zb, zf) = (
        b.cell(1).unwrap().geometry.centroid()[2],
        free.cell(1).unwrap().geometry.centroid()[2],
    );
    moved = moved.max((zb - zf).abs());
    assert!(
        moved > 1e-3,
        "the RBC did not feel the force on the sphere: {moved:e}"
    );
    assert!((rbc0[2] - zf).abs() < 1.0, "sanity");
}

#[test]
fn tweezers_put_plus_and_minus_f_on_the_ends_and_stretch_without_moving() {
    let text = r#"
[flow]
kind = "none"

[[cells]]
shape = "rbc"
shear_modulus = 0.2
bending_modulus = 0.05

[numerics]
order = 8
dt = 0.05
t_end = 1.0
"#;
    let mut sim = Simulation::new(scene(text)).unwrap();
    let pull = PatchPair {
        cell: 0,
        axis: [1.0, 0.0, 0.0],
        fraction: 0.05,
        force: 0.3,
    };
    // The load on the grid: ∫ t dA is +F x̂ on one patch, −F x̂ on the other.
    let c0 = sim.cell(0).unwrap();
    let g = &c0.geometry;
    let n = g.n_points();
    let mut t = VectorField::zeros(n);
    pull.add_traction(
        &CellView {
            id: 0,
            time: 0.0,
            coefs: &c0.coefs,
            geometry: g,
        },
        &mut t,
    );
    let side = pull.patches(g);
    for (sign, want) in [(1i8, 0.3), (-1, -0.3)] {
        let fx: f64 = (0..n)
            .filter(|&j| side[j] == sign)
            .map(|j| t.point(j)[0] * g.da[j])
            .sum();
        let fy: f64 = (0..n)
            .filter(|&j| side[j] == sign)
            .map(|j| t.point(j)[1] * g.da[j])
            .sum();
        assert!(
            (fx - want).abs() < 1e-12 && fy.abs() < 1e-14,
            "patch {sign}: {fx} {fy}"
        );
        assert!(
            side.iter().filter(|&&s| s == sign).count() >= 2,
            "patch {sign} is empty"
        );
    }
    // Another cell's index: no traction.
    let mut none = VectorField::zeros(n);
    let other = PatchPair {
        cell: 1,
        ..pull.clone()
    };
    other.add_traction(
        &CellView {
            id: 0,
            time: 0.0,
            coefs: &c0.coefs,
            geometry: g,
        },
        &mut none,
    );
    assert!(none.as_component_major().iter().all(|&v| v == 0.0));

    let extent = |g: &mobo::vesicle::geometry::Geometry, d: usize| {
        let (lo, hi) =
            g.x.iter()
                .fold((f64::MAX, f64::MIN), |(l, h), x| (l.min(x[d]), h.max(x[d])));
        hi - lo
    };
    let (ax0, x0, a0) = (extent(g, 0), g.centroid(), g.area());
    sim.add_force(pull);
    let mut calls = 0;
    sim.advance_to(1.0, |_, _| calls += 1).unwrap();
    assert_eq!(calls, 20);
    let g1 = sim.cell(0).unwrap().geometry;
    let (ax1, x1) = (extent(&g1, 0), g1.centroid());
    assert!(ax1 > ax0 * 1.01, "axial {ax0} -> {ax1}");
    // The membrane stays locally inextensible under the load.
    assert!(
        (g1.area() - a0).abs() < 1e-6 * a0,
        "area {a0} -> {}",
        g1.area()
    );
    let drift = (0..3).map(|d| (x1[d] - x0[d]).abs()).fold(0.0, f64::max);
    assert!(
        drift < 1e-6,
        "a force-free pull moved the centroid by {drift:e}"
    );
    let e = sim.effects();
    let user = e.iter().find(|e| e.name == "user_forces").unwrap();
    assert!(
        user.enabled && user.reason.contains("optical tweezers"),
        "{}",
        user.reason
    );
    // The geometry the observer reads agrees with an independent transform of the coefficients.
    let mut calc = SurfaceCalculus::new(8).unwrap();
    let c = sim.cell(0).unwrap();
    assert!((calc.geometry(&c.coefs).unwrap().area() - c.geometry.area()).abs() < 1e-14);
}

#[test]
fn advance_to_lands_on_the_time_asked() {
    let text = "[[cells]]\nshape = \"sphere\"\n[numerics]\norder = 4\ndt = 0.03\nt_end = 1.0\n";
    let mut sim = Simulation::new(scene(text)).unwrap();
    let mut times = Vec::new();
    let steps = sim.advance_to(0.1, |s, _| times.push(s.time())).unwrap();
    assert_eq!(steps, 4);
    assert!((sim.time() - 0.1).abs() < 1e-12, "{}", sim.time());
    // 0.03, 0.06, then the remaining 0.04 as two steps of 0.02 (BDF2's ratio stays ≤ 2).
    assert!((times[1] - 0.06).abs() < 1e-12 && (times[2] - 0.08).abs() < 1e-12);
    assert_eq!(sim.dt(), 0.03);
    assert!(sim
        .effects()
        .iter()
        .any(|e| e.name == "user_forces" && !e.enabled));
    // A second call goes on from there with the scene's dt.
    sim.advance_to(0.16, |_, _| {}).unwrap();
    assert_eq!(sim.steps(), 6);
}

#[test]
fn a_force_returning_nan_stops_the_step_with_the_cell_named() {
    let text = "[[cells]]\nshape = \"sphere\"\n[numerics]\norder = 4\ndt = 0.05\nt_end = 1.0\n";
    let mut sim = Simulation::new(scene(text)).unwrap();
    sim.add_force(ForceFn::new(
        "broken",
        |_: &CellView, t: &mut VectorField| t.set(0, [f64::NAN, 0.0, 0.0]),
    ));
    let e = sim.step().expect_err("NaN traction").to_string();
    assert!(
        e.contains("step 1") && e.contains("cell 0") && e.contains("user force"),
        "{e}"
    );
    // A force that panics: the step fails with its name and message, the worker survives and
    // the next simulation steps.
    let mut sim = Simulation::new(scene(text)).unwrap();
    sim.add_force(ForceFn::new(
        "panics",
        |_: &CellView, _: &mut VectorField| panic!("index out of the caller's range"),
    ));
    let e = sim.step().expect_err("a panicking force").to_string();
    assert!(
        e.contains("step 1")
            && e.contains("user force \"panics\" panicked")
            && e.contains("index out of the caller's range"),
        "{e}"
    );
    let mut sim = Simulation::new(scene(text)).unwrap();
    sim.step().expect("a step without the force");
}

#[test]
fn bad_tweezers_and_cell_indices_are_errors_not_panics() {
    let text = "[[cells]]\nshape = \"sphere\"\n[numerics]\norder = 4\ndt = 0.05\nt_end = 1.0\n";
    let mut sim = Simulation::new(scene(text)).unwrap();
    let e = sim.cell(3).unwrap_err().to_string();
    assert!(e.contains("no cell 3") && e.contains("1 cells"), "{e}");
    for bad in [f64::NAN, 0.0, 0.7] {
        let mut sim = Simulation::new(scene(text)).unwrap();
        sim.add_force(PatchPair {
            cell: 0,
            axis: [1.0, 0.0, 0.0],
            fraction: bad,
            force: 1.0,
        });
        let e = sim.step().expect_err("invalid patch pair").to_string();
        assert!(
            e.contains("cell 0") && e.contains("user force"),
            "fraction {bad}: {e}"
        );
    }
}

#[test]
fn smooth_tweezers_carry_plus_and_minus_f_and_move_continuously_with_the_surface() {
    use mobo::timestep::cell_force::SmoothPatchPair;
    use mobo::vesicle::shapes;
    let p = 12;
    let smooth = SmoothPatchPair {
        pair: PatchPair {
            cell: 0,
            axis: [1.0, 0.0, 0.0],
            fraction: 0.025,
            force: 0.7,
        },
        width: 0.1,
    };
    let mut calc = SurfaceCalculus::new(p).unwrap();
    let load = |coefs: &[f64], calc: &mut SurfaceCalculus| {
        let g = calc.geometry(coefs).unwrap();
        let n = g.n_points();
        let mut t = VectorField::zeros(n);
        smooth.add_traction(
            &CellView {
                id: 0,
                time: 0.0,
                coefs,
                geometry: &g,
            },
            &mut t,
        );
        (g, t.into_component_major())
    };
    let rbc = shapes::rbc(p).unwrap();
    let (g, t) = load(rbc.coefs(), &mut calc);
    let n = g.n_points();
    // Each patch carries its share of the area and ±F along x; nothing across.
    for (w, sign) in smooth.weights(&g).iter().zip([1.0, -1.0]) {
        let share: f64 = w.iter().zip(&g.da).map(|(a, b)| a * b).sum();
        assert!((share / g.area() - 0.025).abs() < 1e-9, "{share}");
        let on = |c: usize| -> f64 {
            (0..n)
                .filter(|&j| w[j] > 0.0)
                .map(|j| t[c * n + j] * g.da[j])
                .sum()
        };
        assert!((on(0) - sign * 0.7).abs() < 1e-12, "{}", on(0));
        assert!(on(1).abs() < 1e-14 && on(2).abs() < 1e-14);
    }
    // Turned by 1e-4 rad about z, the load changes by O(1e-4) of its size: no point jumps in
    // or out of a patch (the hard PatchPair would move whole grid points' loads).
    let mut turned = rbc.clone();
    let a = 1e-4f64;
    turned
        .rotate([
            [a.cos(), -a.sin(), 0.0],
            [a.sin(), a.cos(), 0.0],
            [0.0, 0.0, 1.0],
        ])
        .unwrap();
    let (_, t2) = load(turned.coefs(), &mut calc);
    let scale = t.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let change = t
        .iter()
        .zip(&t2)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
    println!(
        "largest traction change {:.2e} of the largest traction",
        change / scale
    );
    assert!(change < 1e-3 * scale, "{change} vs {scale}");
}

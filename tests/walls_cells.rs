//! Cells between rigid walls (`[[walls]]`, `timestep::wall_coupling`): a spherical vesicle
//! settling at the centre of a spherical container against the exact drag of a rigid sphere
//! there (an inextensible sphere can only move rigidly), scene validation, and `mobo run`.

mod common;

use std::f64::consts::PI;
use std::path::Path;

use common::{mobo, ok, summary, tmpdir, write};
use mobo::run::assembly::build;
use mobo::scene::cells::parse;
use mobo::scene::spec::SceneSpec;

fn settling_scene(container_radius: f64, p: usize, steps: usize) -> String {
    format!(
        r#"
[[cells]]
shape = "sphere"
radius = 1.0
force = [0.0, 0.0, -1.0]
bending_modulus = 0.05

[[walls]]
kind = "container"
shape = "sphere"
radius = {container_radius}
order = 16

[numerics]
order = {p}
dt = 0.01
t_end = {}
scheme = "euler"

[output]
every = {steps}
vtk = false
"#,
        0.01 * steps as f64
    )
}

/// The exact drag factor of a sphere of radius `λR` at the centre of a container of radius
/// `R` (Williams 1915; Haberman & Sayre 1958).
fn williams(l: f64) -> f64 {
    (1.0 - l.powi(5)) / (1.0 - 2.25 * l + 2.5 * l.powi(3) - 2.25 * l.powi(5) + l.powi(6))
}

/// A spherical vesicle (radius 1) pulled by `F = 1` at the centre of a container of radius 2
/// settles at `F / 6πμaK(½)`, `K = 7.294` (the wall's response enters each step from the
/// tractions at its start; the tension it causes settles within a few steps: the first step's
/// speed is 8 % off, the fifth's 1.5e-9). Without the container it would settle 7.3 times as
/// fast.
#[test]
fn a_sphere_settles_in_a_spherical_container_at_the_exact_rate() {
    let text = settling_scene(2.0, 8, 12);
    let scene = parse(Path::new("settling.toml"), &text).unwrap();
    let mut susp = build(&scene).unwrap();
    let centroid = |s: &mobo::timestep::suspension::Suspension| {
        let c = &s.cells()[0];
        c.stepper
            .with_geometry(&c.state.coefs, |g| g.centroid())
            .unwrap()
    };
    let mut z = vec![centroid(&susp)[2]];
    for _ in 0..12 {
        susp.step(&|_| [0.0; 3]).unwrap();
        z.push(centroid(&susp)[2]);
    }
    let want = -1.0 / (6.0 * PI * williams(0.5));
    let speeds: Vec<f64> = z.windows(2).map(|w| (w[1] - w[0]) / 0.01).collect();
    println!("settling speeds: {speeds:?}; exact {want}");
    // Measured: 2.5e-6 at the fourth step, 1.5e-9 at the fifth, then the drift off the centre (0.1 % of the gap
    // in 12 steps) adds its quadratic effect, 6e-7 at step 12.
    for (k, v) in speeds.iter().enumerate().skip(4) {
        let rel = (v - want).abs() / want.abs();
        assert!(rel < 2e-6, "step {k}: {v} against {want} ({rel:.2e})");
    }
    // The first step has no tension yet: the free-space-like traction 8 % off.
    assert!((speeds[0] - want).abs() / want.abs() > 1e-2);
    let stats = susp.wall_stats();
    assert_eq!((stats.walls, stats.solves), (1, 12));
}

fn scene_error(text: &str) -> String {
    parse(Path::new("walls.toml"), text)
        .unwrap_err()
        .to_string()
}

/// Bad `[[walls]]` entries and cells outside the fluid are refused with the file, the line and
/// the reason.
#[test]
fn bad_walls_are_refused_with_the_place_and_reason() {
    let cell = "[[cells]]\nshape = \"sphere\"\n";
    let wall = |body: &str| format!("{cell}[[walls]]\n{body}\n");
    for (body, line, needle) in [
        (
            "kind = \"pipe\"\nshape = \"sphere\"\nradius = 3.0",
            4,
            "kind must be",
        ),
        (
            "kind = \"container\"\nshape = \"cube\"\nradius = 3.0",
            5,
            "shape must be",
        ),
        (
            "kind = \"container\"\nshape = \"sphere\"",
            5,
            "needs radius",
        ),
        (
            "kind = \"container\"\nshape = \"sphere\"\nradius = -1.0",
            6,
            "positive",
        ),
        (
            "kind = \"container\"\nshape = \"ellipsoid\"\naxes = [3.0, 0.0, 2.0]",
            6,
            "semi-axes",
        ),
        (
            "kind = \"container\"\nshape = \"sphere\"\nradius = 3.0\norder = 2",
            7,
            "order must be",
        ),
        (
            "kind = \"container\"\nshape = \"sphere\"\nradius = 3.0\nvelocity = [1.0, 0.0, 0.0]",
            7,
            "unknown field",
        ),
        (
            "kind = \"container\"\nshape = \"sphere\"\nradius = 0.95",
            2,
            "outside wall 0",
        ),
        (
            "kind = \"body\"\nshape = \"sphere\"\nradius = 0.5\ncenter = [1.2, 0.0, 0.0]",
            2,
            "inside wall 0",
        ),
    ] {
        let e = scene_error(&wall(body));
        assert!(e.starts_with(&format!("walls.toml:{line}:")), "{body}: {e}");
        assert!(e.contains(needle), "{body}: {e}");
    }
    let two = format!(
        "{cell}[[walls]]\nkind = \"container\"\nshape = \"sphere\"\nradius = 3.0\n\
         [[walls]]\nkind = \"container\"\nshape = \"sphere\"\nradius = 4.0\n"
    );
    let e = scene_error(&two);
    assert!(e.contains("second container"), "{e}");
}

/// The typed spec says the same as the file, and round-trips through TOML.
#[test]
fn the_spec_describes_walls_like_the_file() {
    let text = settling_scene(2.0, 8, 4);
    let spec = SceneSpec::from_toml(&text).unwrap();
    assert_eq!(spec.walls.len(), 1);
    assert_eq!(
        SceneSpec::from_toml(&spec.to_toml().unwrap()).unwrap(),
        spec
    );
    let built = spec.build().unwrap();
    let parsed = parse(Path::new("s.toml"), &text).unwrap();
    assert_eq!(built.walls.len(), 1);
    assert_eq!(built.walls[0].shape, parsed.walls[0].shape);
    assert_eq!(built.walls[0].order, 16);
    let mut bad = spec.clone();
    bad.walls[0].radius = Some(0.9);
    let e = bad.build().unwrap_err().to_string();
    assert!(e.contains("walls[0]") || e.contains("wall 0"), "{e}");
}

/// `mobo run` with a wall: the summary counts the wall's solves and names the effect.
#[test]
fn mobo_run_reports_the_walls() {
    let dir = tmpdir("walls-run");
    let scene = write(&dir, "settling.toml", &settling_scene(2.0, 6, 5));
    let out = dir.join("out");
    let o = mobo(&["run", &scene, "--out", out.to_str().unwrap(), "--quiet"]);
    ok(&o, "mobo run with a wall");
    let s = summary(&out);
    assert_eq!(s["completed"], true);
    assert_eq!(s["counters"]["walls"]["walls"], 1);
    assert_eq!(s["counters"]["walls"]["solves"], 5);
    let effects = s["effects"].as_array().unwrap();
    assert!(
        effects
            .iter()
            .any(|e| e["name"] == "walls" && e["enabled"] == true),
        "{effects:?}"
    );
}

/// A vesicle pushed hard against a fixed body by a force: the contact projection keeps it
/// `contact_distance` from the wall at the end of every step (the walls' gap monitor, the
/// near-zone evaluator's closest points at the next step's start, agrees), and the cell is
/// moved. Measured: 2 moves in 40 steps, smallest gap 0.2011 by both. (With `d_min = 0.1`
/// the wall's lubrication alone holds the cell at 0.162 after 40 steps, without a move.)
#[test]
fn contacts_keep_a_pushed_cell_off_a_wall() {
    let text = r#"
[[cells]]
shape = "prolate"
reduced_volume = 0.9
radius = 1.0
force = [30.0, 0.0, 0.0]
bending_modulus = 0.05

[[walls]]
kind = "body"
shape = "sphere"
radius = 1.0
center = [2.1, 0.1, 0.0]
order = 12

[numerics]
order = 8
dt = 0.02
t_end = 1.0
scheme = "euler"
contact_distance = 0.2
"#;
    let scene = parse(Path::new("pushed.toml"), text).unwrap();
    let mut susp = build(&scene).unwrap();
    for k in 0..40 {
        susp.step(&|_| [0.0; 3])
            .unwrap_or_else(|e| panic!("step {k}: {e:?}"));
    }
    let contacts = susp.contact_stats();
    let walls = susp.wall_stats();
    println!("contacts {contacts:?}\nwalls {walls:?}");
    assert!(
        contacts.moves > 0,
        "the force pushed the cell into the wall's range"
    );
    let least = contacts.smallest_gap.unwrap();
    assert!(least >= 0.2, "a step ended {least} from the wall");
    // The wall monitor sees the cell's grid points at the start of each step's wall solve.
    let seen = walls.smallest_gap.unwrap();
    assert!(seen >= 0.2 - 1e-3, "the wall monitor saw {seen}");
}

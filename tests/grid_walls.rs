//! Walls given by the user as points on the spherical grid (`[[walls]] shape = "grid"`, a
//! `positions` file and an optional `velocity` file): the exact settling rate in a container
//! whose grid has its poles where the built-in sphere's has none, a wall moved by its velocity
//! file as a built-in turning wall, a stopped run resumed from the files copied beside its
//! scene, and bad files refused with the place and the reason.

mod common;

use std::path::Path;

use common::{centroid, frame_bits, settles_at_williams_rate, tmpdir, write};
use mobo::io::npy::write_f64;
use mobo::run::assembly::build;
use mobo::scene::cells::parse;
use mobo::sph_harmonics::Grid;

/// Write `f(θ, φ)` at the points of the spherical grid of order `p` as `dir/name`, shape
/// `(p + 1, 2p, 3)`.
fn grid_file(dir: &Path, name: &str, p: usize, f: impl Fn(f64, f64) -> [f64; 3]) -> String {
    let g = Grid::new(p);
    let mut data = Vec::new();
    for &t in &g.theta {
        for &ph in &g.phi {
            data.extend(f(t, ph));
        }
    }
    let path = dir.join(name);
    write_f64(&path, &[p + 1, 2 * p, 3], &data).unwrap();
    path.to_str().unwrap().to_string()
}

/// A sphere of radius 1 pulled by `F = 1` along −z in a container of radius 2 (`walls`: the
/// `[[walls]]` entry's keys after `kind = "container"`).
fn settling(walls: &str, steps: usize) -> String {
    format!(
        r#"
[[cells]]
shape = "sphere"
radius = 1.0
force = [0.0, 0.0, -1.0]
bending_modulus = 0.05

[[walls]]
kind = "container"
{walls}

[numerics]
order = 8
dt = 0.01
t_end = {}
scheme = "euler"

[output]
every = 1
vtk = false
"#,
        0.01 * steps as f64
    )
}

/// The container of radius 2 given as grid points whose poles lie on the x axis (the sphere
/// falls along z, across the grid's latitudes rather than along its axis): the vesicle settles
/// at Williams' exact rate, as in the built-in sphere (`tests/walls_cells.rs`).
#[test]
fn a_grid_container_with_its_poles_on_x_gives_the_exact_settling_rate() {
    let dir = tmpdir("grid-wall-settling");
    grid_file(&dir, "container.npy", 16, |t, f| {
        [
            2.0 * t.cos(),
            2.0 * t.sin() * f.cos(),
            2.0 * t.sin() * f.sin(),
        ]
    });
    let text = settling("shape = \"grid\"\npositions = \"container.npy\"", 6);
    let scene = parse(&dir.join("settling.toml"), &text).unwrap();
    assert_eq!(scene.walls[0].order, 16);
    settles_at_williams_rate(&scene, 6, 0.5);
}

/// A container of radius 2 whose velocity file holds `Ω × x` (Ω = (0, 0, 0.5)) at its grid
/// points moves a cell off its centre as the built-in sphere with `angular_velocity` does: the
/// same grid, the same boundary data, the same steps.
#[test]
fn a_grid_walls_velocity_file_moves_it_as_a_turning_wall() {
    let dir = tmpdir("grid-wall-turning");
    let p = 16;
    grid_file(&dir, "sphere.npy", p, |t, f| {
        [
            2.0 * t.sin() * f.cos(),
            2.0 * t.sin() * f.sin(),
            2.0 * t.cos(),
        ]
    });
    grid_file(&dir, "turning.npy", p, |t, f| {
        let x = [2.0 * t.sin() * f.cos(), 2.0 * t.sin() * f.sin()];
        [-0.5 * x[1], 0.5 * x[0], 0.0]
    });
    let cell = "[[cells]]\nshape = \"sphere\"";
    let off = "[[cells]]\nshape = \"sphere\"\ncenter = [0.8, 0.0, 0.0]";
    let run = |walls: &str| {
        let text = settling(walls, 4)
            .replacen(cell, off, 1)
            .replace("radius = 1.0", "radius = 0.5")
            .replace("force = [0.0, 0.0, -1.0]", "force = [0.0, 0.0, 0.0]");
        let scene = parse(&dir.join("turning.toml"), &text).unwrap();
        let mut susp = build(&scene).unwrap();
        for _ in 0..4 {
            susp.step(&|_| [0.0; 3]).unwrap();
        }
        centroid(&susp)
    };
    let given = run("shape = \"grid\"\npositions = \"sphere.npy\"\nvelocity = \"turning.npy\"");
    let built_in =
        run("shape = \"sphere\"\nradius = 2.0\norder = 16\nangular_velocity = [0.0, 0.0, 0.5]");
    println!("turned by the velocity file {given:?}, by angular_velocity {built_in:?}");
    // The cell is carried round by the turning wall (it moves in y).
    assert!(given[1] > 1e-3, "{given:?}");
    for a in 0..3 {
        assert!(
            (given[a] - built_in[a]).abs() < 1e-12,
            "{given:?} against {built_in:?}"
        );
    }
}

/// `mobo run` copies the grid wall's file beside its scene copy and names it there: a run
/// stopped after 2 steps resumes with the original file gone, and its frames equal an
/// uninterrupted run's bit for bit.
#[test]
fn a_run_with_a_grid_wall_resumes_from_the_copied_file() {
    let dir = tmpdir("grid-wall-resume");
    let positions = |name: &str| {
        grid_file(&dir, name, 12, |t, f| {
            [
                2.5 * t.sin() * f.cos(),
                2.0 * t.sin() * f.sin(),
                2.0 * t.cos(),
            ]
        })
    };
    positions("whole.npy");
    positions("part.npy");
    let scene = |file: &str| settling(&format!("shape = \"grid\"\npositions = \"{file}\""), 4);
    let whole_scene = write(&dir, "whole.toml", &scene("whole.npy"));
    let (whole, part) = (dir.join("whole"), dir.join("part"));
    let o = common::mobo(&[
        "run",
        &whole_scene,
        "--out",
        whole.to_str().unwrap(),
        "--quiet",
    ]);
    common::ok(&o, "uninterrupted");
    let copy = std::fs::read_to_string(whole.join("scene.toml")).unwrap();
    assert!(
        copy.contains("positions = \"walls/wall_0_positions.npy\""),
        "{copy}"
    );
    assert!(whole.join("walls/wall_0_positions.npy").exists());
    // Stopped after 2 steps, the original file removed, resumed.
    let part_scene = write(&dir, "part.toml", &scene("part.npy"));
    let o = common::mobo(&[
        "run",
        &part_scene,
        "--out",
        part.to_str().unwrap(),
        "--quiet",
        "--max-steps",
        "2",
    ]);
    common::ok(&o, "stopped");
    std::fs::remove_file(dir.join("part.npy")).unwrap();
    let o = common::mobo(&["run", "--resume", part.to_str().unwrap(), "--quiet"]);
    common::ok(&o, "resumed");
    assert_eq!(frame_bits(&whole, true), frame_bits(&part, true));
}

/// Bad grid walls are refused with the scene file, the line and the reason.
#[test]
fn bad_grid_walls_are_refused_with_the_place_and_the_reason() {
    let dir = tmpdir("grid-wall-bad");
    let sphere = |t: f64, f: f64| {
        [
            2.0 * t.sin() * f.cos(),
            2.0 * t.sin() * f.sin(),
            2.0 * t.cos(),
        ]
    };
    grid_file(&dir, "good.npy", 8, sphere);
    grid_file(&dir, "velocity12.npy", 12, |_, _| [0.0; 3]);
    // The longitudes reversed: the normals point inwards.
    grid_file(&dir, "inside_out.npy", 8, |t, f| sphere(t, -f));
    write_f64(&dir.join("flat.npy"), &[9, 15, 3], &vec![1.0; 9 * 15 * 3]).unwrap();
    let mut nan = vec![1.0; 9 * 16 * 3];
    nan[3 * 17 + 2] = f64::NAN;
    write_f64(&dir.join("nan.npy"), &[9, 16, 3], &nan).unwrap();
    let cases = [
        ("shape = \"grid\"", "a grid wall needs positions"),
        (
            "shape = \"grid\"\npositions = \"missing.npy\"",
            "missing.npy",
        ),
        (
            "shape = \"grid\"\npositions = \"flat.npy\"",
            "expected (p + 1, 2p, 3)",
        ),
        (
            "shape = \"grid\"\npositions = \"nan.npy\"",
            "value [1, 1, 2] is NaN",
        ),
        (
            "shape = \"grid\"\npositions = \"inside_out.npy\"",
            "inward-oriented",
        ),
        (
            "shape = \"grid\"\npositions = \"good.npy\"\nvelocity = \"velocity12.npy\"",
            "order 12, positions on that of order 8",
        ),
        (
            "shape = \"grid\"\npositions = \"good.npy\"\nradius = 2.0",
            "radius is not for a grid wall",
        ),
        (
            "shape = \"grid\"\npositions = \"good.npy\"\nangular_velocity = [0.0, 0.0, 1.0]",
            "angular_velocity is not for a grid wall",
        ),
        (
            "shape = \"sphere\"\nradius = 2.0\npositions = \"good.npy\"",
            "positions is for a grid wall",
        ),
    ];
    for (walls, want) in cases {
        let text = settling(walls, 1);
        let e = parse(&dir.join("bad.toml"), &text).unwrap_err().to_string();
        println!("{e}");
        assert!(e.contains("bad.toml") && e.contains(want), "{walls}: {e}");
        // The place: the line of the offending key, within the [[walls]] entry.
        assert!(
            e.contains(":9:") || e.contains(":10:") || e.contains(":11:") || e.contains(":12:"),
            "{e}"
        );
    }
    // A good grid wall reads.
    let scene = parse(
        &dir.join("good.toml"),
        &settling("shape = \"grid\"\npositions = \"good.npy\"", 1),
    )
    .unwrap();
    assert_eq!(scene.walls[0].order, 8);
}

/// With `[units] system = "SI"` a grid wall's files are in metres and metres per second: a
/// sphere of twice the first cell's radius turning at `0.5 G/(μa)` reads as the dimensionless
/// sphere of radius 2 with the velocity `0.5 e_z × x`.
#[test]
fn a_grid_wall_in_si_units_is_scaled_like_every_length() {
    let dir = tmpdir("grid-wall-si");
    let (a, mu, g) = (2.8e-6, 1.2e-3, 6e-6);
    let t = mu * a / g;
    let p = 8;
    let point = |th: f64, f: f64| [th.sin() * f.cos(), th.sin() * f.sin(), th.cos()];
    grid_file(&dir, "si.npy", p, |th, f| point(th, f).map(|v| 2.0 * a * v));
    grid_file(&dir, "si_u.npy", p, |th, f| {
        let x = point(th, f).map(|v| 2.0 * a * v);
        [-0.5 / t * x[1], 0.5 / t * x[0], 0.0]
    });
    let text = format!(
        "[units]\nsystem = \"SI\"\n[fluid]\nviscosity = {mu}\n[[cells]]\nshape = \"sphere\"\n\
         radius = {a}\nshear_modulus = {g}\nbending_modulus = 2e-19\n[[walls]]\n\
         kind = \"container\"\nshape = \"grid\"\npositions = \"si.npy\"\nvelocity = \"si_u.npy\"\n\
         [numerics]\norder = 6\ndt = {}\nt_end = {}\n",
        0.01 * t,
        0.01 * t
    );
    let scene = parse(&dir.join("si.toml"), &text).unwrap();
    let w = &scene.walls[0];
    let want = mobo::vesicle::shapes::sphere(p, 2.0).unwrap();
    let worst = w
        .surface()
        .unwrap()
        .coefs()
        .iter()
        .zip(want.coefs())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-12, "surface off by {worst:.2e}");
    let u = w.grid_velocity().unwrap().unwrap();
    let grid = Grid::new(p);
    let n = u.len() / 3;
    assert_eq!(n, 2 * p * (p + 1));
    for j in 0..n {
        let (th, f) = grid.angles(j);
        let x = point(th, f).map(|v| 2.0 * v);
        let want = [-0.5 * x[1], 0.5 * x[0], 0.0];
        for c in 0..3 {
            assert!(
                (u[c * n + j] - want[c]).abs() < 1e-12,
                "point {j}: {}",
                u[c * n + j]
            );
        }
    }
}

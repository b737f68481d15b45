//! `[output] velocity_plane`: the flow's velocity on a plane grid at every frame
//! (`mobo::run` writes it with `Suspension::velocity_at`).
//!
//! * A spherical vesicle (inextensible: it moves rigidly) pulled by a force `F = 6πμaU` in a
//!   quiescent fluid, viscosity ratio 5: outside, Stokes' field of a translating sphere; inside,
//!   the uniform `U` (which needs the interior value `u/λ` of the representation).
//! * A run stopped and resumed writes the same plane files, bit for bit.
//! * Bad planes are refused with the place and the reason.
//!
//! With walls (`NaN` outside the fluid, the walls' part inside a cell): `tests/walls_cells.rs`.

use std::path::Path;

mod common;
use common::{mobo, ok, stop_and_resume, tmpdir, write};

use mobo::io::npy::read_f64;
use mobo::scene::cells::parse;

const PULLED_SPHERE: &str = r#"
[[cells]]
shape = "sphere"
radius = 1.0
viscosity_ratio = 5.0
force = [18.84955592153876, 0.0, 0.0]

[numerics]
order = 8
dt = 0.01
t_end = T_END
scheme = "euler"

[output]
every = 1
velocity_plane = { origin = [-2.0, -2.0, 0.0], u = [4.0, 0.0, 0.0], v = [0.0, 4.0, 0.0], points = [41, 41] }
"#;

/// Stokes' flow past a sphere of radius 1 at `c` translating with `U = (1, 0, 0)`, and `U`
/// inside it.
fn stokes(x: [f64; 3], c: [f64; 3]) -> [f64; 3] {
    let r = [x[0] - c[0], x[1] - c[1], x[2] - c[2]];
    let d = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    if d < 1.0 {
        return [1.0, 0.0, 0.0];
    }
    std::array::from_fn(|a| {
        let u = if a == 0 { 1.0 } else { 0.0 };
        0.75 * (u / d + r[0] * r[a] / d.powi(3))
            + 0.25 * (u / d.powi(3) - 3.0 * r[0] * r[a] / d.powi(5))
    })
}

#[test]
fn a_pulled_spherical_vesicle_gives_stokes_field_outside_and_its_speed_inside() {
    let dir = tmpdir("plane-stokes");
    let scene = write(&dir, "pulled.toml", &PULLED_SPHERE.replace("T_END", "0.02"));
    let out = dir.join("out");
    ok(
        &mobo(&["run", &scene, "--out", out.to_str().unwrap(), "--quiet"]),
        "mobo run",
    );
    let (shape, points) = read_f64(&out.join("frames/plane_points.npy")).unwrap();
    assert_eq!(shape, vec![41, 41, 3]);
    assert_eq!(points[..3], [-2.0, -2.0, 0.0]);
    assert_eq!(points[3 * 40..3 * 41], [2.0, -2.0, 0.0]);
    let (shape, u) = read_f64(&out.join("frames/frame_00002_plane_velocity.npy")).unwrap();
    assert_eq!(shape, vec![41, 41, 3]);
    // The sphere's centre after two steps of U = 1 (its constant coefficient).
    let (_, coefs) = read_f64(&out.join("frames/frame_00002_coefs.npy")).unwrap();
    let nc = coefs.len() / 3;
    let y00 = (4.0 * std::f64::consts::PI).sqrt();
    let c = [coefs[0] / y00, coefs[nc] / y00, coefs[2 * nc] / y00];
    assert!((c[0] - 0.02).abs() < 1e-9, "{c:?}");
    let (mut inside, mut far, mut all) = (0.0_f64, 0.0_f64, 0.0_f64);
    for (x, v) in points.chunks_exact(3).zip(u.chunks_exact(3)) {
        let x = [x[0], x[1], x[2]];
        let want = stokes(x, c);
        let err = (0..3).map(|a| (v[a] - want[a]).powi(2)).sum::<f64>().sqrt();
        let d = ((x[0] - c[0]).powi(2) + x[1].powi(2) + x[2].powi(2)).sqrt();
        if d < 0.8 {
            inside = inside.max(err);
        } else if d > 1.2 {
            far = far.max(err);
        }
        all = all.max(err);
    }
    println!("inside {inside:.1e}, beyond 0.2 of the surface {far:.1e}, everywhere {all:.1e}");
    // Measured at p = 8: 7e-14 inside, 1e-13 beyond 0.2 of the membrane, 1.5e-5 within 0.05
    // of it.
    assert!(inside < 1e-10, "{inside}");
    assert!(far < 1e-9, "{far}");
    assert!(all < 1e-4, "{all}");
    // ParaView: one plane mesh per frame and their collection.
    for f in 0..3 {
        assert!(out.join(format!("vtk/frame_{f:05}_plane.vtp")).is_file());
    }
    let pvd = std::fs::read_to_string(out.join("vtk/plane.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet").count(), 3, "{pvd}");
    let vtp = std::fs::read_to_string(out.join("vtk/frame_00002_plane.vtp")).unwrap();
    assert!(vtp.contains("Name=\"velocity\"") && vtp.contains("NumberOfComponents=\"3\""));
    assert!(
        vtp.contains("NumberOfPolys=\"3200\""),
        "two triangles per grid cell"
    );
    // VTK's ASCII reader takes no NaN: a mask instead.
    assert!(vtp.contains("Name=\"in_fluid\"") && !vtp.contains("NaN"));
}

#[test]
fn a_stopped_and_resumed_run_writes_the_same_plane_frames() {
    let dir = tmpdir("plane-resume");
    // Small and quick: p = 4, 11 × 11 points.
    let text = PULLED_SPHERE
        .replace("T_END", "0.04")
        .replace("order = 8", "order = 4")
        .replace("points = [41, 41]", "points = [11, 11]");
    let scene = write(&dir, "pulled.toml", &text);
    let full = dir.join("full");
    ok(
        &mobo(&["run", &scene, "--out", full.to_str().unwrap(), "--quiet"]),
        "the whole run",
    );
    let part = dir.join("part");
    stop_and_resume(&scene, &part, 2);
    let bits = |out: &Path| -> Vec<Vec<u64>> {
        (0..5)
            .map(|f| {
                let p = out.join(format!("frames/frame_{f:05}_plane_velocity.npy"));
                read_f64(&p)
                    .unwrap()
                    .1
                    .iter()
                    .map(|v| v.to_bits())
                    .collect()
            })
            .collect()
    };
    assert_eq!(bits(&part), bits(&full));
    assert!(!part.join("frames/frame_00005_plane_velocity.npy").exists());
    let pvd = std::fs::read_to_string(part.join("vtk/plane.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet").count(), 5, "{pvd}");
}

#[test]
fn bad_planes_are_refused_with_the_place_and_the_reason() {
    let err = |plane: &str| {
        let text = PULLED_SPHERE.replace("T_END", "0.02").replace(
            "velocity_plane = { origin = [-2.0, -2.0, 0.0], u = [4.0, 0.0, 0.0], v = [0.0, 4.0, 0.0], points = [41, 41] }",
            &format!("velocity_plane = {plane}"),
        );
        parse(Path::new("plane.toml"), &text)
            .unwrap_err()
            .to_string()
    };
    let e = err("{ origin = [0, 0, 0], u = [1.0, 0, 0], v = [2.0, 0, 0], points = [4, 4] }");
    assert!(e.contains("plane.toml:") && e.contains("parallel"), "{e}");
    let e = err("{ origin = [0, 0, 0], u = [1.0, 0, 0], v = [0, 1.0, 0], points = [1, 4] }");
    assert!(e.contains("points") && e.contains("at least 2"), "{e}");
    let e = err("{ origin = [0, 0, 0], u = [0.0, 0, 0], v = [0, 1.0, 0], points = [4, 4] }");
    assert!(e.contains("velocity_plane u") && e.contains("zero"), "{e}");
    let e = err("{ origin = [0, 0, 0], u = [1.0, 0, 0], v = [0, 1.0, 0], points = [4, 4], w = 1 }");
    assert!(e.contains("w"), "{e}");
    let e = err("{ origin = [0, 0, 0], u = [1.0, 0, 0], v = [0, 1.0, 0], points = [2000, 2000] }");
    assert!(e.contains("1000000"), "{e}");
    let e = err("{ origin = [0, 0, 0], u = [1.0, 0, 0], v = [0, 1.0, 0], points = [4, 4] }\nnpy = false\nvtk = false");
    assert!(e.contains("needs npy = true or vtk = true"), "{e}");
}

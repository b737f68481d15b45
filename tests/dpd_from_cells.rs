//! One scene file for both solvers: `mobo run` reads its `[[cells]]` and ignores `[dpd]`;
//! `mobo dpd` maps the same `[[cells]]` into the fluid by `[dpd.from_cells]`. Checked against
//! `[[dpd.cells]]` entries written by hand with the documented map, against the cell scene's
//! own surfaces (volume, centroid, orientation), with located errors for what cannot be
//! mapped, and by running the example scene both ways, shortened.

mod common;

use std::path::Path;

use common::{mobo, ok, summary, tmpdir};
use mobo::dpd::membrane::MembraneParams;
use mobo::dpd::pair_force::minimum_image;
use mobo::scene::{cells, dpd};

/// The cell scene: an RBC tilted 60° about x and a Skalak capsule (C = 1) with a body force.
const CELLS: &str = r#"[fluid]
viscosity = 1.0

[flow]
kind = "shear"
rate = 1.0

[[cells]]
shape = "rbc"
radius = 1.0
center = [-1.5, 0.0, 0.25]
orientation = [1, 0, 0, 60]
shear_modulus = 10.0
bending_modulus = 0.125

[[cells]]
shape = "sphere"
radius = 1.0
center = [1.5, 0.5, 0.0]
membrane = "capsule"
shear_modulus = 10.0
skalak_c = 1.0
bending_modulus = 0.125
force = [0.5, 0.0, 0.0]

[numerics]
order = 8
dt = 0.01
t_end = 0.02
"#;

/// `mobo dpd`'s part: a box of 30 × 20 × 24, the cell scene turned 90° about x and scaled
/// by 3 (so μ0 = 10 · 18 / 9 = 20, κ = 0.125 · 18 = 2.25).
const DPD: &str = r#"
[dpd]
box = [30.0, 20.0, 24.0]
density = 3.0
a = 25.0
gamma = 4.5
kbt = 1.0
dt = 0.005
steps = 20
seed = 2
save_every = 10

[dpd.from_cells]
length = 3.0
energy = 18.0
rotate = [1, 0, 0, 90]
subdivisions = 2
gamma_t = 0.0
"#;

fn both() -> String {
    format!("{CELLS}{DPD}")
}

fn err_of(text: &str) -> String {
    dpd::parse(Path::new("s.toml"), text)
        .unwrap_err()
        .to_string()
}

/// `R_x(90°) v`: y → z, z → −y.
fn turn(v: [f64; 3]) -> [f64; 3] {
    [v[0], -v[2], v[1]]
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * b.abs().max(1e-300)
}

/// The same parameters up to round-off (the mesh's mean edge length enters the springs).
fn assert_same_params(got: &MembraneParams, want: &MembraneParams) {
    let pairs = [
        (got.kbt, want.kbt),
        (got.persistence_length, want.persistence_length),
        (got.x0, want.x0),
        (got.m, want.m),
        (got.kd, want.kd),
        (got.ka, want.ka),
        (got.kv, want.kv),
        (got.gamma_t, want.gamma_t),
        (got.gamma_c, want.gamma_c),
    ];
    for (i, (g, w)) in pairs.iter().enumerate() {
        assert!(close(*g, *w, 1e-12), "field {i}: {g} against {w}");
    }
    assert_eq!(
        format!("{:?}", got.bending),
        format!("{:?}", want.bending),
        "bending"
    );
}

#[test]
fn the_cell_scene_maps_into_the_fluid_as_documented() {
    let text = both();
    // `mobo run` reads the same file (the [dpd] section aside).
    let bie = cells::parse(Path::new("s.toml"), &text).unwrap();
    assert_eq!(bie.cells.len(), 2);
    let bie_alone = cells::parse(Path::new("s.toml"), CELLS).unwrap();
    assert_eq!(bie, bie_alone);
    let scene = dpd::parse(Path::new("s.toml"), &text).unwrap();
    assert_eq!(scene.cells.len(), 2);
    let m = scene.from_cells.expect("mapping recorded");
    assert_eq!((m.length, m.energy, m.cells), (3.0, 18.0, 2));
    assert_eq!(m.origin, [15.0, 10.0, 12.0]);
    let origin = m.origin;

    // The capsule against a [[dpd.cells]] sphere written with the documented map: μ0 = G_s E /
    // s² = 20, κ = κ_b E = 2.25, area modulus G_s (1 + 2C) E / s² = 60 = 2μ0 + k_a + k_d with
    // k_a = k_d = 10, centre origin + s R c, force F E / s along R x.
    let c = turn([1.5, 0.5, 0.0]).map(|v| 3.0 * v);
    let by_hand = format!(
        r#"{DPD}
[[dpd.cells]]
shape = "sphere"
radius = 3.0
center = [{}, {}, {}]
subdivisions = 2
shear_modulus = 20.0
bending_rigidity = 2.25
ka = 10.0
kd = 10.0
gamma_t = 0.0
force = [3.0, 0.0, 0.0]
"#,
        origin[0] + c[0],
        origin[1] + c[1],
        origin[2] + c[2]
    )
    .replace("[dpd.from_cells]\nlength = 3.0\nenergy = 18.0\nrotate = [1, 0, 0, 90]\nsubdivisions = 2\ngamma_t = 0.0\n", "");
    let hand = dpd::parse(Path::new("hand.toml"), &by_hand).unwrap();
    assert!(hand.from_cells.is_none());
    let (mapped, want) = (&scene.cells[1], &hand.cells[0]);
    assert_eq!(mapped.shape, "sphere");
    assert!(close(mapped.radius, 3.0, 1e-15));
    assert_eq!(mapped.force, want.force);
    assert_same_params(&mapped.spec.params, &want.spec.params);
    assert_eq!(mapped.spec.triangles, want.spec.triangles);
    // The same mesh turned by R about the centre (the surface is turned, its parametrisation
    // kept).
    let centre = [0, 1, 2].map(|k| origin[k] + c[k]);
    for (a, b) in mapped.spec.vertices.iter().zip(&want.spec.vertices) {
        let r = turn([0, 1, 2].map(|k| b[k] - centre[k]));
        let b_turned = [0, 1, 2].map(|k| centre[k] + r[k]);
        let d = minimum_image(*a, b_turned, [30.0, 20.0, 24.0]);
        assert!(
            d.iter().all(|v| v.abs() < 1e-12),
            "{a:?} against {b_turned:?}"
        );
    }

    // The RBC (a vesicle: Fedosov's area penalties kept) against its cell-scene surface:
    // volume, centroid and the axis of symmetry, turned and scaled.
    let rbc = &scene.cells[0];
    assert_eq!(rbc.shape, "rbc");
    let x = &rbc.spec.vertices;
    let mut vol = 0.0;
    let mut cen = [0.0; 3];
    for t in &rbc.spec.triangles {
        let p = t.map(|j| x[j]);
        let v6 = p[0][0] * (p[1][1] * p[2][2] - p[1][2] * p[2][1])
            - p[0][1] * (p[1][0] * p[2][2] - p[1][2] * p[2][0])
            + p[0][2] * (p[1][0] * p[2][1] - p[1][1] * p[2][0]);
        vol += v6 / 6.0;
        for k in 0..3 {
            cen[k] += v6 / 24.0 * (p[0][k] + p[1][k] + p[2][k]);
        }
    }
    let cen = cen.map(|v| v / vol);
    let exact = 4.0 / 3.0 * std::f64::consts::PI * 27.0;
    // The mesh of 162 vertices inscribes the surface: its volume a few per cent short.
    assert!(
        vol < exact && vol > 0.93 * exact,
        "volume {vol} against {exact}"
    );
    let want_c = turn([-1.5, 0.0, 0.25]).map(|v| 3.0 * v);
    for k in 0..3 {
        assert!(
            (cen[k] - origin[k] - want_c[k]).abs() < 0.05,
            "centroid {cen:?}, want {want_c:?} + origin"
        );
    }
    // The symmetry axis: z turned 60° about x (to (0, −sin 60°, cos 60°)), then 90° about x.
    let axis = turn([0.0, -(60f64.to_radians().sin()), 60f64.to_radians().cos()]);
    // The thinnest direction of the vertex cloud (its smallest second moment).
    let mut mom = [[0.0; 3]; 3];
    for p in x {
        let d = [0, 1, 2].map(|k| p[k] - cen[k]);
        for i in 0..3 {
            for j in 0..3 {
                mom[i][j] += d[i] * d[j];
            }
        }
    }
    let thin = (0..3)
        .map(|i| {
            // Second moment along unit vectors near the expected axis: the axis itself must be
            // the thinnest of the three principal candidates below.
            let u = match i {
                0 => axis,
                1 => [1.0, 0.0, 0.0],
                _ => {
                    let a = axis;
                    let b = [1.0, 0.0, 0.0];
                    [
                        a[1] * b[2] - a[2] * b[1],
                        a[2] * b[0] - a[0] * b[2],
                        a[0] * b[1] - a[1] * b[0],
                    ]
                }
            };
            (0..3)
                .map(|r| (0..3).map(|s| u[r] * mom[r][s] * u[s]).sum::<f64>())
                .sum::<f64>()
        })
        .collect::<Vec<f64>>();
    assert!(
        thin[0] < 0.3 * thin[1] && thin[0] < 0.3 * thin[2],
        "moments along the axis and across: {thin:?}"
    );
    // Vesicle: Fedosov's defaults for k_a, k_d, k_v (Moduli::new), the mapped μ0 and κ.
    assert_eq!((rbc.spec.params.ka, rbc.spec.params.kd), (4900.0, 100.0));
    assert_eq!(
        format!("{:?}", rbc.spec.params.bending),
        "Juelicher { kappa: 2.25, c0: 0.0 }"
    );
}

#[test]
fn what_cannot_be_mapped_is_refused_with_its_place() {
    let text = both();
    // [[cells]] without [dpd.from_cells]: refused, not dropped.
    let e = err_of(&text.replace(
        "[dpd.from_cells]\nlength = 3.0\nenergy = 18.0\nrotate = [1, 0, 0, 90]\nsubdivisions = 2\ngamma_t = 0.0\n",
        "",
    ));
    assert!(
        e.starts_with("s.toml:8:") && e.contains("[dpd.from_cells]"),
        "{e}"
    );
    // A fluid membrane (no shear modulus).
    let e = err_of(&text.replacen("shear_modulus = 10.0", "shear_modulus = 0.0", 1));
    assert!(
        e.starts_with("s.toml:9:") && e.contains("fluid membrane"),
        "{e}"
    );
    // A viscosity contrast without an inner fluid for it.
    let e = err_of(&text.replace("skalak_c = 1.0", "skalak_c = 1.0\nviscosity_ratio = 5.0"));
    assert!(
        e.starts_with("s.toml:17:") && e.contains("inner_gamma"),
        "{e}"
    );
    // A capsule whose area modulus is below the network's own 2μ0.
    let e = err_of(&text.replace("skalak_c = 1.0", "skalak_c = 0.2"));
    assert!(e.contains("below the spring"), "{e}");
    // Bad map values, at their keys.
    let e = err_of(&text.replace("length = 3.0", "length = -3.0"));
    assert!(e.starts_with("s.toml:43:") && e.contains("length"), "{e}");
    let e = err_of(&text.replace("rotate = [1, 0, 0, 90]", "rotate = [0, 0, 0, 90]"));
    assert!(e.contains("rotate"), "{e}");
    // A cell scene error surfaces as mobo run would give it.
    let e = err_of(&text.replacen("shape = \"rbc\"", "shape = \"cube\"", 1));
    assert!(e.starts_with("s.toml:9:") && e.contains("cube"), "{e}");
    // Two mapped cells too close in the fluid (cells 0.5 apart in the cell scene but the
    // mesh of the fluid's sphere pushed into the RBC by a [[dpd.cells]] entry at the RBC).
    let rbc_at = turn([-1.5, 0.0, 0.25]).map(|v| 3.0 * v);
    let e = err_of(&format!(
        "{text}\n[[dpd.cells]]\nshape = \"sphere\"\nradius = 1.0\ncenter = [{}, {}, {}]\nshear_modulus = 100.0\nbending_rigidity = 20.0\n",
        15.0 + rbc_at[0],
        10.0 + rbc_at[1],
        12.0 + rbc_at[2]
    ));
    assert!(e.contains("overlaps [[dpd.cells]] entry 1"), "{e}");
}

/// The example scene, shortened, by both solvers: the capsule's deformation and inclination
/// come out of both summaries.
#[test]
fn the_example_runs_both_ways() {
    let dir = tmpdir("both-ways");
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("examples/scenes/capsule_shear_bie_and_dpd.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let short = text
        .replace("t_end = 5.0", "t_end = 0.2")
        .replace("steps = 40000", "steps = 100")
        .replace("save_every = 2000", "save_every = 50")
        .replace("wall_warmup = 300", "wall_warmup = 20");
    assert_ne!(short, text, "the shortening must apply");
    let scene = dir.join("scene.toml");
    std::fs::write(&scene, &short).unwrap();
    for (cmd, out) in [("run", "bie"), ("dpd", "dpd")] {
        let o = mobo(&[
            cmd,
            scene.to_str().unwrap(),
            "--out",
            dir.join(out).to_str().unwrap(),
            "--quiet",
        ]);
        ok(&o, cmd);
    }
    let bie = summary(&dir.join("bie"));
    let d_bie = bie["per_cell"][0]["taylor_deformation"].as_f64().unwrap();
    // At t = 0.2 (a fifth of a strain unit) the sphere has begun to deform.
    assert!(d_bie > 1e-3 && d_bie < 0.2, "{bie}");
    let dpd = summary(&dir.join("dpd"));
    let cell = &dpd["membranes"]["per_cell"][0];
    let d = cell["taylor_deformation"].as_f64().unwrap();
    assert!((0.0..0.3).contains(&d), "{cell}");
    assert!(cell["inclination_deg"].as_f64().unwrap().abs() <= 90.0);
    let effects = dpd["effects"].to_string();
    assert!(effects.contains("mapped by [dpd.from_cells]"), "{effects}");
}

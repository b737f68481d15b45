//! `mobo dpd` with cells (`[[dpd.cells]]`): located errors for bad cell entries, a run's
//! membrane files and summary, bit-for-bit restart with the membranes' state, and the example
//! scene (an RBC in periodic Poiseuille flow) shortened.

mod common;

use std::path::Path;

use common::{checkpoint_bits, mobo, ok, summary, tmpdir, DPD_PARTICLE_ARRAYS};
use mobo::scene::dpd::parse;

/// A sphere of radius 2 pulled along x through the standard fluid in a box of 8.
const BASE: &str = r#"[dpd]
box = 8.0
density = 3.0
a = 25.0
gamma = 4.5
kbt = 1.0
dt = 0.005
steps = 120
seed = 4
save_every = 40

[[dpd.cells]]
shape = "sphere"
radius = 2.0
center = [4.0, 4.0, 4.0]
subdivisions = 2
shear_modulus = 100.0
bending_rigidity = 20.0
force = [30.0, 0.0, 0.0]

[dpd.coupling]
check_every = 10
"#;

fn err_of(text: &str) -> String {
    parse(Path::new("s.toml"), text).unwrap_err().to_string()
}

#[test]
fn bad_cell_entries_name_the_line_and_the_problem() {
    let s = parse(Path::new("s.toml"), BASE).unwrap();
    assert_eq!(s.cells.len(), 1);
    assert_eq!(s.cells[0].spec.vertices.len(), 162);
    assert_eq!(s.coupling.check_every, 10);
    let e = err_of(&BASE.replace("shape = \"sphere\"", "shape = \"cube\""));
    assert!(
        e.starts_with("s.toml:13:") && e.contains("unknown shape \"cube\""),
        "{e}"
    );
    let e = err_of(&BASE.replace("center = [4.0, 4.0, 4.0]", "center = [4.0, 9.0, 4.0]"));
    assert!(
        e.starts_with("s.toml:15:") && e.contains("not inside the box"),
        "{e}"
    );
    let e = err_of(&BASE.replace("shape = \"sphere\"", "shape = \"prolate\""));
    assert!(e.contains("needs reduced_volume"), "{e}");
    let e = err_of(&BASE.replace("subdivisions = 2", "subdivisions = 9"));
    assert!(e.starts_with("s.toml:16:") && e.contains("1 to 6"), "{e}");
    let e = err_of(&BASE.replace("shear_modulus = 100.0", "shear_modulus = -1.0"));
    assert!(
        e.starts_with("s.toml:17:") && e.contains("shear_modulus"),
        "{e}"
    );
    let e = err_of(&BASE.replace(
        "bending_rigidity = 20.0",
        "bending_rigidity = 20.0\nspring = 3",
    ));
    assert!(e.contains("spring"), "{e}");
    let e = err_of(&BASE.replace("check_every = 10", "gamma_out = -2.0"));
    assert!(
        e.contains("[dpd.coupling]") && e.contains("gamma_out"),
        "{e}"
    );
    // Two overlapping cells, and a cell too large for the box.
    let e = err_of(&format!(
        "{BASE}\n[[dpd.cells]]\nshape = \"sphere\"\nradius = 2.0\ncenter = [5.0, 4.0, 4.0]\n\
         shear_modulus = 100.0\nbending_rigidity = 20.0\n"
    ));
    assert!(
        e.contains("entry 2") && e.contains("overlaps entry 1"),
        "{e}"
    );
    let e = err_of(&BASE.replace("radius = 2.0", "radius = 3.5"));
    assert!(
        e.starts_with("s.toml:14:") && e.contains("must fit in the box"),
        "{e}"
    );
}

fn arrays(dir: &Path) -> Vec<(String, Vec<u64>)> {
    let names: Vec<&str> = DPD_PARTICLE_ARRAYS
        .iter()
        .copied()
        .chain([
            "cell0_x",
            "cell0_v",
            "cell0_f",
            "owner",
            "membrane_counters",
        ])
        .collect();
    checkpoint_bits(dir, &names)
}

#[test]
fn a_cell_run_writes_membranes_and_resumes_bit_for_bit() {
    let dir = tmpdir("restart");
    let scene = dir.join("s.toml");
    std::fs::write(&scene, BASE).unwrap();
    let s = scene.to_str().unwrap();
    let whole = dir.join("whole");
    ok(
        &mobo(&["dpd", s, "--out", whole.to_str().unwrap(), "--quiet"]),
        "whole run",
    );
    for f in [
        "summary.json",
        "membranes.pvd",
        "membranes_00000000.vtp",
        "membranes_00000040.vtp",
        "membranes_00000120.vtp",
    ] {
        assert!(whole.join(f).is_file(), "{f} missing");
    }
    let pvd = std::fs::read_to_string(whole.join("membranes.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet").count(), 4, "{pvd}");
    let sum = summary(&whole);
    let m = &sum["membranes"];
    assert_eq!(m["cells"].as_u64(), Some(1));
    assert_eq!(m["vertices"].as_u64(), Some(162));
    assert_eq!(m["leaked_particles"].as_u64(), Some(0));
    assert!(m["bounces"].as_u64().unwrap() > 0, "{m}");
    let cell = &m["per_cell"][0];
    // (Whether it moves is tested in tests/dpd_cells.rs over a longer run: in 120 steps the
    // thermal motion of the cell is larger than the drift.)
    assert_eq!(cell["force"][0].as_f64(), Some(30.0));
    assert!(
        cell["volume_change"].as_f64().unwrap().abs() < 0.02,
        "{cell}"
    );
    let inner = cell["inner_solvent"].as_u64().unwrap();
    assert!((70..140).contains(&inner), "inner solvent {inner}");
    // The total momentum (solvent and vertices) is conserved: the pull is balanced on the
    // outer solvent.
    assert!(sum["momentum_drift"].as_f64().unwrap() < 1e-12, "{sum}");
    let effects = sum["effects"].as_array().unwrap();
    let membranes = effects
        .iter()
        .find(|e| e["name"] == "membranes")
        .expect("membranes effect");
    assert_eq!(membranes["enabled"], true);

    let part = dir.join("part");
    let o = mobo(&[
        "dpd",
        s,
        "--out",
        part.to_str().unwrap(),
        "--quiet",
        "--max-steps",
        "50",
    ]);
    ok(&o, "first part");
    ok(
        &mobo(&["dpd", "--resume", part.to_str().unwrap(), "--quiet"]),
        "resume",
    );
    assert_eq!(
        arrays(&part),
        arrays(&whole),
        "resumed run differs from the whole run"
    );
    let pvd_part = std::fs::read_to_string(part.join("membranes.pvd")).unwrap();
    assert_eq!(pvd_part, pvd);
}

#[test]
fn the_rbc_example_scene_runs_shortened() {
    let dir = tmpdir("example");
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/scenes/dpd_rbc_poiseuille.toml"),
    )
    .unwrap();
    assert!(parse(Path::new("dpd_rbc_poiseuille.toml"), &text).is_ok());
    let short = text
        .replace("steps = 6000", "steps = 300")
        .replace("equilibrate = 1000", "equilibrate = 100")
        .replace("save_every = 500", "save_every = 100");
    let scene = dir.join("dpd_rbc_poiseuille.toml");
    std::fs::write(&scene, short).unwrap();
    let out = dir.join("out");
    ok(
        &mobo(&[
            "dpd",
            scene.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--quiet",
        ]),
        "example",
    );
    let sum = summary(&out);
    let m = &sum["membranes"];
    assert_eq!(m["vertices"].as_u64(), Some(642));
    assert_eq!(m["leaked_particles"].as_u64(), Some(0), "{m}");
    let cell = &m["per_cell"][0];
    // Carried by the flow (+x in the lower half).
    assert!(cell["velocity"][0].as_f64().unwrap() > 0.0, "{cell}");
    for key in ["area_change", "volume_change"] {
        assert!(cell[key].as_f64().unwrap().abs() < 0.02, "{key}: {cell}");
    }
    // The cell disturbs the profile: no viscosity is fitted to it.
    assert!(sum["viscosity"].is_null(), "{}", sum["viscosity"]);
    let tv = m["vertex_temperature"].as_f64().unwrap();
    assert!((tv - 1.0).abs() < 0.25, "vertex temperature {tv}");
}

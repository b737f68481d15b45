//! `[brownian]` scenes and `mobo brownian`: every example scene runs; bad scenes give errors that
//! name the file, the place and the problem, with a non-zero exit and no panic.

mod common;
use common::*;

use std::path::Path;

use mobo::scene::brownian::parse;

const GOOD: &str = r#"
[brownian]
radius = 1.0
kT = 1.0
viscosity = 0.05305164769729845
dt = 1e-3
steps = 50
seed = 3
noise = "tea-hi"
save_every = 10

[brownian.system]
kind = "chain"
beads = 5
bond_length = 2.0
bond_stiffness = 50.0
repulsion = 50.0
"#;

/// Read an `.npy` file written by mobo: check the header independently and return shape + data.
fn read_npy(path: &Path) -> (Vec<usize>, Vec<f64>) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
    let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    assert_eq!((10 + hlen) % 64, 0, "header not aligned");
    let header = std::str::from_utf8(&bytes[10..10 + hlen]).unwrap();
    assert!(header.contains("'descr': '<f8'") && header.contains("'fortran_order': False"));
    let shape_txt = header
        .split("'shape': (")
        .nth(1)
        .unwrap()
        .split(')')
        .next()
        .unwrap();
    let shape: Vec<usize> = shape_txt
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    let data: Vec<f64> = bytes[10 + hlen..]
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect();
    assert_eq!(shape.iter().product::<usize>(), data.len());
    (shape, data)
}

#[test]
fn every_example_scene_runs() {
    let ran = run_example_scenes("[brownian]", "brownian", |_, out| {
        let summary = std::fs::read_to_string(out.join("summary.json")).unwrap();
        assert!(summary.contains("\"effects\""));
        let (shape, data) = read_npy(&out.join("trajectory.npy"));
        assert_eq!(shape.len(), 3);
        assert!(data.iter().all(|v| v.is_finite()));
    });
    assert!(ran >= 2, "expected the Brownian example scenes");
}

#[test]
fn run_writes_consistent_outputs() {
    let dir = tmpdir("run");
    let scene = dir.join("chain.toml");
    std::fs::write(&scene, GOOD).unwrap();
    let out = dir.join("out");
    let o = mobo(&[
        "brownian",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (shape, data) = read_npy(&out.join("trajectory.npy"));
    assert_eq!(shape, vec![6, 5, 3]); // frames 0, 10, …, 50
                                      // Frame 0 is the straight chain along x with spacing 2.
    assert_eq!(&data[..6], &[0.0, 0.0, 0.0, 2.0, 0.0, 0.0]);
    let csv = std::fs::read_to_string(out.join("observables.csv")).unwrap();
    assert_eq!(csv.lines().count(), 7);
    let summary = std::fs::read_to_string(out.join("summary.json")).unwrap();
    assert!(
        summary.contains("\"beads\": 5") && summary.contains("\"tea_hi_beta\""),
        "{summary}"
    );
    // No temporary files left behind.
    for e in std::fs::read_dir(&out).unwrap() {
        let name = e.unwrap().file_name().into_string().unwrap();
        assert!(!name.contains(".tmp"), "leftover {name}");
    }
    // Same seed, same trajectory.
    let out2 = dir.join("out2");
    mobo(&[
        "brownian",
        scene.to_str().unwrap(),
        "--out",
        out2.to_str().unwrap(),
        "--quiet",
    ]);
    assert_eq!(read_npy(&out2.join("trajectory.npy")).1, data);
}

#[test]
fn scene_errors_name_file_place_and_problem() {
    let file = Path::new("bad.toml");
    let cases: Vec<(String, &str)> = vec![
        (
            GOOD.replace("seed = 3", "seed = 3\nspeed = 4"),
            "bad.toml:9:1: unknown field `speed`",
        ),
        (GOOD.replace("steps = 50", "steps = \"many\""), "bad.toml:7"),
        (GOOD.replace("dt = 1e-3", "dt = -1e-3"), "dt"),
        (
            GOOD.replace("noise = \"tea-hi\"", "noise = \"pink\""),
            "pink",
        ),
        (GOOD.replace("kind = \"chain\"", "kind = \"star\""), "star"),
        (GOOD.replace("beads = 5\n", ""), "beads"),
        (
            GOOD.replace("kind = \"chain\"", "kind = \"random\"\nbox = 1.0")
                .replace("beads = 5", "beads = 500"),
            "non-overlapping",
        ),
        ("[brownian\nradius = 1".to_string(), "bad.toml:1"),
    ];
    for (text, expect) in cases {
        let err = parse(file, &text).expect_err(expect).to_string();
        assert!(err.contains(expect), "error {err:?} lacks {expect:?}");
        assert!(
            err.starts_with("bad.toml"),
            "error {err:?} does not name the file"
        );
    }
    assert!(parse(file, GOOD).is_ok());
}

#[test]
fn cli_scene_errors_exit_nonzero_without_panic() {
    let dir = tmpdir("err");
    let bad = dir.join("bad.toml");
    std::fs::write(
        &bad,
        GOOD.replace("radius = 1.0", "radius = 1.0\nradius_typo = 2"),
    )
    .unwrap();
    let missing = dir.join("missing.toml");
    for path in [&bad, &missing] {
        let o = mobo(&["brownian", path.to_str().unwrap(), "--quiet"]);
        assert!(!o.status.success());
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains(path.file_name().unwrap().to_str().unwrap()),
            "{err}"
        );
        assert!(!err.contains("panicked"), "{err}");
    }
}

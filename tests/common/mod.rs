//! Helpers shared by the tests that run the `mobo` binary.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Command, Output};

/// Run the `mobo` binary with `args`.
pub fn mobo(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mobo"))
        .args(args)
        .output()
        .expect("run mobo")
}

/// `mobo run SCENE --out PART --quiet --max-steps STEPS`, then `mobo run --resume PART --quiet`,
/// each asserted to succeed: the stopped-and-resumed run of the resume tests.
pub fn stop_and_resume(scene: &str, part: &std::path::Path, steps: usize) {
    let part = part.to_str().unwrap();
    let steps = steps.to_string();
    let o = mobo(&[
        "run",
        scene,
        "--out",
        part,
        "--quiet",
        "--max-steps",
        &steps,
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = mobo(&["run", "--resume", part, "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Assert that a `mobo` run succeeded, showing its output if not.
pub fn ok(o: &Output, what: &str) {
    assert!(
        o.status.success(),
        "{what}: {}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// A fresh, empty temporary directory named after the test and this process.
pub fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mobo-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Run `mobo SUBCOMMAND SCENE --out DIR --quiet` on every scene in `examples/scenes` whose text
/// contains `marker`, assert success, and hand `(scene, output dir)` to `check`. Returns how
/// many scenes ran.
pub fn run_example_scenes(
    marker: &str,
    subcommand: &str,
    mut check: impl FnMut(&std::path::Path, &std::path::Path),
) -> usize {
    let scenes = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/scenes");
    let mut ran = 0;
    for entry in std::fs::read_dir(&scenes).unwrap() {
        let path = entry.unwrap().path();
        // Scenes only: a grid wall's .npy files sit beside them.
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        if !text.contains(marker) {
            continue;
        }
        let out = tmpdir(&format!("{subcommand}-example-{ran}"));
        let o = mobo(&[
            subcommand,
            path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--quiet",
        ]);
        assert!(
            o.status.success(),
            "{}: {}",
            path.display(),
            String::from_utf8_lossy(&o.stderr)
        );
        check(&path, &out);
        ran += 1;
    }
    ran
}

/// Write `text` to `dir/name`; the path as a string.
pub fn write(dir: &std::path::Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.to_str().unwrap().to_string()
}

/// The `summary.json` of a run in `dir`.
pub fn summary(dir: &std::path::Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap()
}

/// The bits of every saved frame's coefficients (and tension, if `tension`) in `out/frames`,
/// for bit-for-bit comparisons of runs.
pub fn frame_bits(out: &std::path::Path, tension: bool) -> Vec<Vec<u64>> {
    let mut all = Vec::new();
    for f in 0.. {
        let path = out.join(format!("frames/frame_{f:05}_coefs.npy"));
        if !path.exists() {
            break;
        }
        let (_, mut c) = mobo::io::npy::read_f64(&path).unwrap();
        if tension {
            let tp = out.join(format!("frames/frame_{f:05}_tension.npy"));
            c.extend(mobo::io::npy::read_f64(&tp).unwrap().1);
        }
        all.push(c.iter().map(|v| v.to_bits()).collect());
    }
    all
}

pub mod quadrature;

/// The rotation by `angle` about the unit `axis` (Rodrigues).
pub fn rotation(axis: [f64; 3], angle: f64) -> [[f64; 3]; 3] {
    let (s, c) = angle.sin_cos();
    let [x, y, z] = axis;
    [
        [
            c + x * x * (1.0 - c),
            x * y * (1.0 - c) - z * s,
            x * z * (1.0 - c) + y * s,
        ],
        [
            y * x * (1.0 - c) + z * s,
            c + y * y * (1.0 - c),
            y * z * (1.0 - c) - x * s,
        ],
        [
            z * x * (1.0 - c) - y * s,
            z * y * (1.0 - c) + x * s,
            c + z * z * (1.0 - c),
        ],
    ]
}

/// The particle arrays of a `mobo dpd` checkpoint (positions, velocities, forces, ids).
pub const DPD_PARTICLE_ARRAYS: [&str; 10] =
    ["x", "y", "z", "vx", "vy", "vz", "fx", "fy", "fz", "id"];

/// The bits of the named arrays of `dir/checkpoint.bin`, for bit-for-bit comparisons of runs.
pub fn checkpoint_bits(dir: &std::path::Path, names: &[&str]) -> Vec<(String, Vec<u64>)> {
    let c = mobo::io::checkpoint::Checkpoint::read(&dir.join("checkpoint.bin")).unwrap();
    names
        .iter()
        .map(|n| {
            let a = c.get(n).unwrap_or_else(|| panic!("array {n}"));
            (n.to_string(), a.data.iter().map(|v| v.to_bits()).collect())
        })
        .collect()
}

/// The shared GPU adapter, or `None` with a message that `what` is skipped; in CI (`CI=true`)
/// a missing adapter is a failure.
#[cfg(feature = "gpu")]
pub fn gpu_or_skip(what: &str) -> Option<std::sync::Arc<mobo::gpu::Gpu>> {
    match mobo::gpu::Gpu::shared() {
        Ok(g) => Some(g),
        Err(e) if std::env::var("CI").as_deref() == Ok("true") => {
            panic!("CI=true and no GPU adapter: {e}")
        }
        Err(e) => {
            eprintln!("skipping {what}: {e}");
            None
        }
    }
}

/// The rows of `DIR/observables.csv` (header skipped).
pub fn observables(dir: &std::path::Path) -> Vec<Vec<f64>> {
    std::fs::read_to_string(dir.join("observables.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.trim().parse().unwrap()).collect())
        .collect()
}

/// Assert that two runs wrote the same number of observables rows, every value within
/// `tol · (1 + |a|)` of the other run's.
pub fn assert_observables_close(a: &std::path::Path, b: &std::path::Path, tol: f64, what: &str) {
    let (oa, ob) = (observables(a), observables(b));
    assert_eq!(oa.len(), ob.len(), "{what}: rows");
    for (ra, rb) in oa.iter().zip(&ob) {
        for (x, y) in ra.iter().zip(rb) {
            assert!(
                (x - y).abs() <= tol * (1.0 + x.abs()),
                "{what}: {ra:?} vs {rb:?}"
            );
        }
    }
}

/// The centroid of the suspension's first cell.
pub fn centroid(s: &mobo::timestep::suspension::Suspension) -> [f64; 3] {
    let c = &s.cells()[0];
    c.stepper
        .with_geometry(&c.state.coefs, |g| g.centroid())
        .unwrap()
}

/// The exact drag factor of a sphere of radius `λR` at the centre of a container of radius
/// `R` (Williams 1915; Haberman & Sayre 1958).
pub fn williams(l: f64) -> f64 {
    (1.0 - l.powi(5)) / (1.0 - 2.25 * l + 2.5 * l.powi(3) - 2.25 * l.powi(5) + l.powi(6))
}

/// Step the scene's first cell, a sphere pulled by `F = 1` along −z at the centre of a
/// spherical container (radius ratio `l`), `steps` steps of 0.01, and assert its settling
/// speed against Williams' exact rate `F / 6πμaK(l)` (μ = a = 1): within 1e-5 at the first step
/// (the start-up's tension is off by O(Δt)) and 2e-6 after. Returns the suspension.
pub fn settles_at_williams_rate(
    scene: &mobo::scene::cells::CellScene,
    steps: usize,
    l: f64,
) -> mobo::timestep::suspension::Suspension {
    let mut susp = mobo::run::assembly::build(scene).unwrap();
    let mut z = vec![centroid(&susp)[2]];
    for _ in 0..steps {
        susp.step(&|_| [0.0; 3]).unwrap();
        z.push(centroid(&susp)[2]);
    }
    let want = -1.0 / (6.0 * std::f64::consts::PI * williams(l));
    let speeds: Vec<f64> = z.windows(2).map(|w| (w[1] - w[0]) / 0.01).collect();
    println!("settling speeds: {speeds:?}; exact {want}");
    for (k, v) in speeds.iter().enumerate() {
        let rel = (v - want).abs() / want.abs();
        let tol = if k == 0 { 1e-5 } else { 2e-6 };
        assert!(rel < tol, "step {k}: {v} against {want} ({rel:.2e})");
    }
    susp
}

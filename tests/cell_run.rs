//! `mobo run` on cell scenes: a sedimenting spherical vesicle moves at `F/(6πμa)`, a vesicle in
//! shear writes its frames and summary, scenes that need what is not built yet are refused
//! with a clear message, and stopped runs resume bit for bit (also with a viscosity contrast
//! between cells, whose explicit double layer carries the membrane velocities over).

mod common;
use common::{frame_bits, mobo, run_example_scenes, stop_and_resume, summary, tmpdir, write};

#[test]
fn a_sedimenting_vesicle_scene_moves_at_the_stokes_speed() {
    let dir = tmpdir("run-sed");
    let scene = write(
        &dir,
        "sed.toml",
        r#"
[fluid]
viscosity = 2.0
[[cells]]
shape = "sphere"
radius = 0.8
force = [0.0, 0.0, -3.0]
[numerics]
order = 8
dt = 0.1
t_end = 0.3
gmres_tol = 1e-11
"#,
    );
    let out = dir.join("out");
    let o = mobo(&["run", &scene, "--out", out.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&out);
    let v = s["centroid_velocity"][2].as_f64().unwrap();
    let want = -3.0 / (6.0 * std::f64::consts::PI * 2.0 * 0.8);
    assert!((v - want).abs() < 1e-4 * want.abs(), "{v} vs {want}");
    let on: Vec<&str> = s["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["enabled"].as_bool().unwrap())
        .map(|e| e["name"].as_str().unwrap())
        .collect();
    assert_eq!(on, vec!["body_force"], "only the body force is built");
    assert_eq!(
        s["counters"]["fmm_builds"].as_u64(),
        Some(0),
        "one cell builds no FMM"
    );
}

#[test]
fn a_viscosity_contrast_builds_the_double_layer_and_still_sediments_at_the_stokes_speed() {
    let dir = tmpdir("run-lambda");
    let scene = write(
        &dir,
        "lambda.toml",
        r#"
[[cells]]
shape = "sphere"
force = [0.0, 0.0, -1.0]
viscosity_ratio = 5.0
[numerics]
order = 8
dt = 0.1
t_end = 0.3
gmres_tol = 1e-11
[output]
vtk = false
"#,
    );
    let out = dir.join("out");
    let o = mobo(&["run", &scene, "--out", out.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&out);
    assert_eq!(s["counters"]["double_layer_assemblies"].as_u64(), Some(3));
    let v = s["centroid_velocity"][2].as_f64().unwrap();
    let want = -1.0 / (6.0 * std::f64::consts::PI);
    assert!((v - want).abs() < 1e-4 * want.abs(), "{v} vs {want}");
    let on: Vec<&str> = s["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["enabled"].as_bool().unwrap())
        .map(|e| e["name"].as_str().unwrap())
        .collect();
    assert!(on.contains(&"double_layer"), "{on:?}");
}

#[test]
fn a_vesicle_in_shear_writes_frames_and_a_summary() {
    let dir = tmpdir("run-shear");
    let scene = write(
        &dir,
        "shear.toml",
        r#"
[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "prolate"
reduced_volume = 0.9
bending_modulus = 1.0
[numerics]
order = 6
dt = 0.1
t_end = 2.0
[output]
every = 5
"#,
    );
    let out = dir.join("out");
    let o = mobo(&["run", &scene, "--out", out.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&out);
    assert_eq!(s["steps"].as_u64(), Some(20));
    assert_eq!(s["frames"].as_u64(), Some(5));
    for key in [
        "area_drift",
        "volume_drift",
        "gmres_iterations_mean",
        "inclination_deg",
        "wall_s",
        "step_s",
        "final_time",
    ] {
        assert!(s[key].is_number(), "{key} missing: {s}");
    }
    assert!(s["area_drift"].as_f64().unwrap().abs() < 1e-6);
    let (shape, times) = mobo::io::npy::read_f64(&out.join("frames/times.npy")).unwrap();
    assert_eq!(shape, vec![5]);
    assert_eq!(times, vec![0.0, 0.5, 1.0, 1.5, 2.0]);
    let (shape, _) =
        mobo::io::npy::read_f64(&out.join("frames/frame_00004_positions.npy")).unwrap();
    assert_eq!(shape, vec![1, 3, 2 * 6 * 7]);
    let (shape, _) = mobo::io::npy::read_f64(&out.join("frames/frame_00004_tension.npy")).unwrap();
    assert_eq!(shape, vec![1, 2 * 6 * 7]);
}

#[test]
fn bad_scenes_are_refused_clearly() {
    let dir = tmpdir("run-refuse");
    let cases = [("[[cells]]\nshape = \"sphere\"\nradius = -2\n", "bad.toml:3")];
    for (text, want) in cases {
        let scene = write(&dir, "bad.toml", text);
        let o = mobo(&[
            "run",
            &scene,
            "--out",
            dir.join("o").to_str().unwrap(),
            "--quiet",
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{text} succeeded");
        assert!(err.contains(want), "{want} not in: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
}

#[test]
fn every_example_cell_scene_runs() {
    let ran = run_example_scenes("[[cells]]", "run", |path, out| {
        let s = summary(out);
        // A capsule's area changes with its strain: its volume is the invariant.
        let capsule = std::fs::read_to_string(path)
            .unwrap()
            .contains("membrane = \"capsule\"");
        let drift = if capsule {
            "volume_drift"
        } else {
            "area_drift"
        };
        assert!(
            s[drift].as_f64().unwrap().abs() < 1e-6,
            "{}: {s}",
            path.display()
        );
    });
    assert!(ran >= 2, "only {ran} cell scenes found");
}

#[test]
fn mobo_without_arguments_runs_the_demo_scene() {
    let dir = tmpdir("run-demo");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_mobo"))
        .current_dir(&dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&dir.join("out/demo"));
    assert_eq!(s["steps"].as_u64(), Some(200));
    assert!(s["area_drift"].as_f64().unwrap().abs() < 1e-6);
    let inc = s["inclination_deg"].as_f64().unwrap();
    assert!(inc > 0.0 && inc < 45.0, "{inc}");
}

const TWO_CELLS: &str = r#"
[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "prolate"
reduced_volume = 0.9
bending_modulus = 0.5
center = [-1.3, 0.4, 0.0]
[[cells]]
shape = "sphere"
center = [1.3, -0.4, 0.0]
bending_modulus = 0.5
[numerics]
order = 6
dt = 0.05
t_end = 1.2
scheme = "bdf2"
[output]
every = 4
vtk = false
"#;

/// [`TWO_CELLS`] with `λ = 5` for both cells.
fn two_cells_lambda_5() -> String {
    let text = TWO_CELLS
        .replace(
            "bending_modulus = 0.5\ncenter = [-1.3",
            "bending_modulus = 0.5\nviscosity_ratio = 5.0\ncenter = [-1.3",
        )
        .replace(
            "center = [1.3, -0.4, 0.0]\nbending_modulus = 0.5",
            "center = [1.3, -0.4, 0.0]\nbending_modulus = 0.5\nviscosity_ratio = 5.0",
        );
    assert_eq!(text.matches("viscosity_ratio = 5.0").count(), 2);
    text
}

fn frames_of(out: &std::path::Path) -> Vec<Vec<u64>> {
    frame_bits(out, true)
}

#[test]
fn a_stopped_or_interrupted_run_resumes_to_bit_identical_results() {
    let dir = tmpdir("run-resume");
    let scene = write(&dir, "two.toml", TWO_CELLS);
    let full = dir.join("full");
    let o = mobo(&["run", &scene, "--out", full.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&full);
    assert_eq!(s["steps"].as_u64(), Some(24));
    // The start-up's passes (first steps solved and thrown away) evaluate the coupling too.
    let passes = s["counters"]["start_up"]["passes"].as_u64().unwrap();
    assert!(passes >= 1, "{}", s["counters"]);
    assert_eq!(
        s["counters"]["fmm_builds"].as_u64(),
        Some(24 + passes),
        "two cells: one FMM per step and per start-up pass"
    );
    assert_eq!(
        s["counters"]["double_layer_fmm_builds"].as_u64(),
        Some(0),
        "λ = 1: no inter-cell double layer"
    );
    let want = frames_of(&full);
    assert_eq!(want.len(), 7);

    // Stopped by --max-steps, then resumed.
    let part = dir.join("part");
    let o = mobo(&[
        "run",
        &scene,
        "--out",
        part.to_str().unwrap(),
        "--quiet",
        "--max-steps",
        "10",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&part);
    assert_eq!(s["completed"].as_bool(), Some(false));
    assert_eq!(s["steps"].as_u64(), Some(10));
    assert!(String::from_utf8_lossy(&o.stdout).contains("--resume"));
    let o = mobo(&["run", "--resume", part.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(summary(&part)["completed"].as_bool(), Some(true));
    assert_eq!(
        frames_of(&part),
        want,
        "stop at 10 + resume = one run, bit for bit"
    );

    // Interrupted by SIGINT (Ctrl-C) once the first checkpoint exists, then resumed.
    let intr = dir.join("intr");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_mobo"))
        .args(["run", &scene, "--out", intr.to_str().unwrap(), "--quiet"])
        .spawn()
        .unwrap();
    let ck = intr.join("checkpoint.bin");
    let t0 = std::time::Instant::now();
    while !ck.exists() && t0.elapsed().as_secs() < 60 {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let kill = std::process::Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let status = child.wait().unwrap();
    let s = summary(&intr);
    if s["completed"].as_bool() == Some(false) {
        assert_eq!(status.code(), Some(130), "interrupted runs exit with 130");
        let o = mobo(&["run", "--resume", intr.to_str().unwrap(), "--quiet"]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    } else {
        // The run finished before the signal arrived; nothing to resume.
        assert!(status.success());
    }
    assert_eq!(
        frames_of(&intr),
        want,
        "interrupt + resume = one run, bit for bit"
    );

    // A stored scene whose fixed dt was edited is refused, naming the file and both dts.
    let edited = dir.join("edited");
    std::fs::create_dir_all(&edited).unwrap();
    for f in ["checkpoint.bin", "scene.toml"] {
        std::fs::copy(part.join(f), edited.join(f)).unwrap();
    }
    let text = std::fs::read_to_string(edited.join("scene.toml")).unwrap();
    assert!(text.contains("dt = 0.05"), "{text}");
    std::fs::write(
        edited.join("scene.toml"),
        text.replace("dt = 0.05", "dt = 0.025"),
    )
    .unwrap();
    let o = mobo(&["run", "--resume", edited.to_str().unwrap(), "--quiet"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("scene.toml") && err.contains("0.025") && err.contains("0.05"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");

    // A damaged checkpoint is refused with a message naming it.
    let bytes = std::fs::read(part.join("checkpoint.bin")).unwrap();
    std::fs::write(part.join("checkpoint.bin"), &bytes[..bytes.len() / 2]).unwrap();
    let o = mobo(&["run", "--resume", part.to_str().unwrap(), "--quiet"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("checkpoint.bin") && err.contains("truncated"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
}

/// Two cells with `λ = 5`: the inter-cell double layer takes each cell's membrane velocity of
/// the previous step, which the checkpoint carries, so a resumed run is still bit-identical.
#[test]
fn a_run_with_a_viscosity_contrast_between_cells_resumes_to_bit_identical_results() {
    let dir = tmpdir("run-resume-lambda");
    let text = two_cells_lambda_5().replace("t_end = 1.2", "t_end = 0.6");
    assert_eq!(text.matches("viscosity_ratio = 5.0").count(), 2);
    let scene = write(&dir, "two.toml", &text);
    let full = dir.join("full");
    let o = mobo(&["run", &scene, "--out", full.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&full);
    assert_eq!(s["steps"].as_u64(), Some(12));
    let passes = s["counters"]["start_up"]["passes"].as_u64().unwrap();
    assert!(passes >= 2, "{}", s["counters"]);
    assert_eq!(s["counters"]["fmm_builds"].as_u64(), Some(12 + passes));
    assert_eq!(
        s["counters"]["double_layer_fmm_builds"].as_u64(),
        Some(12 + passes - 1),
        "a stresslet FMM every step and every start-up pass but the first (no membrane \
         velocity before it)"
    );
    let on: Vec<&str> = s["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["enabled"].as_bool().unwrap())
        .map(|e| e["name"].as_str().unwrap())
        .collect();
    assert!(on.contains(&"inter_cell_double_layer"), "{on:?}");
    let want = frames_of(&full);

    let part = dir.join("part");
    stop_and_resume(&scene, &part, 5);
    let s = summary(&part);
    assert_eq!(s["completed"].as_bool(), Some(true));
    assert_eq!(
        s["counters"]["double_layer_fmm_builds"].as_u64(),
        Some(7),
        "the resumed invocation has the velocities from its first step on"
    );
    assert_eq!(
        frames_of(&part),
        want,
        "stop at 5 + resume = one run, bit for bit"
    );
}

/// With the near-implicit coupling (`[numerics] coupling = "near_implicit"`) the two close
/// cells with `λ = 5` are solved as one system each step; the extrapolation of their coupling
/// densities needs last step's, which the checkpoint carries: stop + resume = one run, bit for
/// bit.
#[test]
fn a_near_implicit_run_resumes_to_bit_identical_results() {
    let dir = tmpdir("run-resume-near-implicit");
    let text = two_cells_lambda_5().replace(
        "t_end = 1.2\nscheme = \"bdf2\"",
        "t_end = 0.4\nscheme = \"bdf2\"\ncoupling = \"near_implicit\"",
    );
    assert!(text.contains("coupling = \"near_implicit\""));
    let scene = write(&dir, "two.toml", &text);
    let full = dir.join("full");
    let o = mobo(&["run", &scene, "--out", full.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&full);
    assert_eq!(s["steps"].as_u64(), Some(8));
    let joint = &s["counters"]["near_implicit"];
    // Close at the start (the shear then moves them apart): joint solves in the first steps,
    // around the stop at step 3.
    assert!(
        joint["clusters"].as_u64().unwrap() >= 3,
        "the close cells were solved jointly: {joint}"
    );
    assert_eq!(joint["largest"].as_u64(), Some(2), "{joint}");
    let want = frames_of(&full);
    let part = dir.join("part");
    stop_and_resume(&scene, &part, 3);
    assert_eq!(
        frames_of(&part),
        want,
        "stop at 3 + resume = one run, bit for bit"
    );
}

#[test]
fn an_unknown_coupling_is_refused_with_its_place() {
    let dir = tmpdir("run-bad-coupling");
    let text = TWO_CELLS.replace(
        "scheme = \"bdf2\"",
        "scheme = \"bdf2\"\ncoupling = \"implicit\"",
    );
    let scene = write(&dir, "two.toml", &text);
    let o = mobo(&["run", &scene, "--out", dir.join("o").to_str().unwrap()]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("two.toml") && err.contains("coupling") && err.contains("\"implicit\""),
        "{err}"
    );
}

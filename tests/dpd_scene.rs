//! `mobo dpd`: scene errors that name the file, the place and the problem; a run's files;
//! bit-for-bit restart from a checkpoint; the example scene.

mod common;

use std::path::Path;

use common::{checkpoint_bits, mobo, ok, summary, tmpdir, DPD_PARTICLE_ARRAYS};
use mobo::scene::dpd::parse;

const BASE: &str = r#"[dpd]
box = [5.0, 5.0, 8.0]
density = 3.0
a = 25.0
gamma = 4.5
kbt = 1.0
dt = 0.02
steps = 120
seed = 3
flow = "periodic_poiseuille"
force = 0.2
equilibrate = 20
sample_every = 5
blocks = 4
bins = 16
save_every = 40
"#;

fn err_of(text: &str) -> String {
    parse(Path::new("s.toml"), text).unwrap_err().to_string()
}

#[test]
fn bad_scenes_name_the_file_the_line_and_the_problem() {
    assert!(parse(Path::new("s.toml"), BASE).is_ok());
    let e = err_of(&format!("{BASE}gpu = \"maybe\"\n"));
    assert!(
        e.starts_with("s.toml:17:") && e.contains("\"auto\", true or false"),
        "{e}"
    );
    let e = err_of(&format!("{BASE}gpu_precision = \"f16\"\n"));
    assert!(
        e.starts_with("s.toml:17:") && e.contains("\"f32\" or \"f64\""),
        "{e}"
    );
    let e = err_of(&format!("{BASE}power = 0.3\ngpu_precision = \"f64\"\n"));
    assert!(e.contains("gpu_precision") && e.contains("0.3"), "{e}");
    let walled = BASE
        .replace("flow = \"periodic_poiseuille\"", "flow = \"poiseuille\"")
        .replace(
            "seed = 3",
            "seed = 3\nwalls = { kind = \"planes\", gap = 5.0 }",
        );
    assert!(parse(Path::new("s.toml"), &format!("{walled}gpu = true\n")).is_ok());
    let with_cell = format!(
        "{BASE}gpu = true\n[[dpd.cells]]\nshape = \"sphere\"\nradius = 1.5\n\
         center = [2.5, 2.5, 4.0]\nsubdivisions = 1\nshear_modulus = 10.0\n\
         bending_rigidity = 5.0\n"
    );
    // Cells with the GPU are taken (the solvent's pair forces go there).
    let with_cell = with_cell.replace("radius = 1.5", "radius = 1.2");
    assert!(parse(Path::new("s.toml"), &with_cell).is_ok());
    let e = err_of(&BASE.replace("gamma = 4.5", "gamma = -1.0"));
    assert!(e.starts_with("s.toml:5:") && e.contains("gamma"), "{e}");
    let e = err_of(&BASE.replace("seed = 3", "seed = 3\nviscosity = 2.0"));
    assert!(
        e.starts_with("s.toml:10:") && e.contains("viscosity"),
        "{e}"
    );
    let e = err_of(&BASE.replace("box = [5.0, 5.0, 8.0]", "box = [5.0, 2.0, 8.0]"));
    assert!(
        e.contains("box") && e.contains("side y") && e.contains("3 rc"),
        "{e}"
    );
    let e = err_of(&BASE.replace("steps = 120", "steps = 120\nt_end = 3.0"));
    assert!(e.contains("either steps or t_end"), "{e}");
    let e = err_of(&BASE.replace("flow = \"periodic_poiseuille\"", "flow = \"vortex\""));
    assert!(e.contains("unknown flow \"vortex\""), "{e}");
    let e = err_of(&BASE.replace("force = 0.2\n", ""));
    assert!(e.contains("force") && e.contains("required"), "{e}");
    let e = err_of(&BASE.replace(
        "seed = 3",
        "seed = 3\nwalls = { kind = \"planes\", gap = 4.0 }",
    ));
    assert!(
        e.contains("periodic_poiseuille needs a periodic box"),
        "{e}"
    );
    let walled = BASE.replace("flow = \"periodic_poiseuille\"", "flow = \"poiseuille\"");
    let e = err_of(&walled);
    assert!(e.contains("poiseuille is driven between walls"), "{e}");
    let e = err_of(&walled.replace(
        "seed = 3",
        "seed = 3\nwalls = { kind = \"planes\", gap = 7.0 }",
    ));
    assert!(e.contains("walls") && e.contains("gap + 2 rc"), "{e}");
    let e = err_of(&walled.replace(
        "seed = 3",
        "seed = 3\nwalls = { kind = \"tube\", radius = 1.0 }",
    ));
    assert!(e.contains("unknown kind \"tube\""), "{e}");
    let e = err_of(&walled.replace("seed = 3", "seed = 3\nwalls = { kind = \"cylinder\" }"));
    assert!(e.contains("needs radius"), "{e}");
    assert!(parse(
        Path::new("s.toml"),
        &walled.replace(
            "seed = 3",
            "seed = 3\nwalls = { kind = \"planes\", gap = 5.0 }"
        )
    )
    .is_ok());
    let e = err_of(&BASE.replace("bins = 16", "bins = 8"));
    assert!(e.contains("bins") && e.contains("at least 12"), "{e}");
    // A size that allocates has a bound: a located error, not an aborted allocation.
    let e = err_of(&BASE.replace("bins = 16", "bins = 99999999999"));
    assert!(
        e.contains("bins") && e.contains("between 2 and 1000000"),
        "{e}"
    );
    let e = err_of(&BASE.replace("equilibrate = 20", "equilibrate = 500"));
    assert!(e.contains("equilibrate"), "{e}");
    let e = err_of(&BASE.replace("density = 3.0", "density = \"dense\""));
    assert!(e.starts_with("s.toml:3:"), "{e}");
}

fn arrays(dir: &Path) -> Vec<(String, Vec<u64>)> {
    let names: Vec<&str> = DPD_PARTICLE_ARRAYS
        .iter()
        .copied()
        .chain(["profile_sampler"])
        .collect();
    checkpoint_bits(dir, &names)
}

#[test]
fn a_run_writes_its_files_and_a_resumed_run_continues_bit_for_bit() {
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
        "observables.csv",
        "profile.csv",
        "scene.toml",
        "checkpoint.bin",
    ] {
        assert!(whole.join(f).is_file(), "{f} missing");
    }
    let sum = summary(&whole);
    assert_eq!(sum["particles"].as_u64(), Some(600));
    assert_eq!(sum["steps"].as_u64(), Some(120));
    assert!(sum["particle_steps_per_second"].as_f64().unwrap() > 0.0);
    assert!(sum["viscosity"]["value"].as_f64().unwrap().is_finite());
    assert!(sum["viscosity"]["stderr"].as_f64().unwrap() > 0.0);
    assert_eq!(sum["viscosity"]["equilibration_steps"].as_u64(), Some(20));
    // The body force sums to zero only when the halves hold equal numbers of particles.
    assert!(sum["momentum_drift"].as_f64().unwrap().is_finite());
    let profile = std::fs::read_to_string(whole.join("profile.csv")).unwrap();
    assert_eq!(profile.lines().count(), 17, "{profile}");
    assert!(profile.starts_with("z,vx,density,vx_fit"));

    // Stop after 50 steps, then resume twice (the second resume has nothing left to do but
    // must not change the state).
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
    assert!(String::from_utf8_lossy(&o.stdout).contains("stopped at step 50"));
    ok(
        &mobo(&["dpd", "--resume", part.to_str().unwrap(), "--quiet"]),
        "resume",
    );
    assert_eq!(
        arrays(&part),
        arrays(&whole),
        "resumed run differs from the whole run"
    );
    let a = std::fs::read_to_string(part.join("observables.csv")).unwrap();
    let b = std::fs::read_to_string(whole.join("observables.csv")).unwrap();
    // Rows at the same steps are identical (the stopped run adds one row at step 50).
    let rows = |t: &str| -> Vec<String> {
        t.lines()
            .filter(|l| {
                l.split(',')
                    .next()
                    .is_some_and(|s| s.parse::<u64>().is_ok_and(|s| s % 40 == 0 || s == 120))
            })
            .map(String::from)
            .collect()
    };
    assert_eq!(rows(&a), rows(&b));
    // A stop at a save step (40) adds no row of its own: the resumed run's observables are the
    // whole run's, byte for byte.
    let at_save = dir.join("at_save");
    ok(
        &mobo(&[
            "dpd",
            s,
            "--out",
            at_save.to_str().unwrap(),
            "--quiet",
            "--max-steps",
            "40",
        ]),
        "stopped at a save",
    );
    ok(
        &mobo(&["dpd", "--resume", at_save.to_str().unwrap(), "--quiet"]),
        "resume from a save",
    );
    assert_eq!(
        std::fs::read_to_string(at_save.join("observables.csv")).unwrap(),
        b,
        "a stop at a save step duplicated its row"
    );
}

#[test]
fn bad_input_exits_non_zero_with_a_located_message() {
    let dir = tmpdir("bad");
    let scene = dir.join("bad.toml");
    std::fs::write(&scene, BASE.replace("dt = 0.02", "dt = 0")).unwrap();
    let o = mobo(&[
        "dpd",
        scene.to_str().unwrap(),
        "--quiet",
        "--out",
        dir.join("o").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("bad.toml:7:") && err.contains("dt"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    // A damaged checkpoint: named, no panic.
    let run = dir.join("run");
    let missing = dir.join("missing.toml");
    let o = mobo(&["dpd", missing.to_str().unwrap(), "--quiet"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("missing.toml") && err.contains("cannot read"),
        "{err}"
    );
    std::fs::create_dir_all(&run).unwrap();
    std::fs::write(run.join("scene.toml"), BASE).unwrap();
    std::fs::write(run.join("checkpoint.bin"), b"MOBOCKPT garbage").unwrap();
    let o = mobo(&["dpd", "--resume", run.to_str().unwrap(), "--quiet"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("checkpoint.bin") && !err.contains("panicked"),
        "{err}"
    );
}

#[test]
fn the_example_scene_runs_shortened() {
    let dir = tmpdir("example");
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/scenes/dpd_poiseuille.toml"),
    )
    .unwrap();
    assert!(parse(Path::new("dpd_poiseuille.toml"), &text).is_ok());
    let short = text
        .replace("steps = 20000", "steps = 300")
        .replace("equilibrate = 4000", "equilibrate = 100");
    let scene = dir.join("dpd_poiseuille.toml");
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
    assert_eq!(sum["particles"].as_u64(), Some(6000));
    assert!(sum["viscosity"].is_object());
    // The kinetic temperature includes the driven flow; about the profile it is near k_BT
    // (this short run is still cooling from the random placement: 1.03 at step 300; the full
    // 20 000 steps give 1.056, the rest being viscous heating and the profile's variation
    // within a bin).
    let thermal = sum["thermal_temperature"].as_f64().unwrap();
    assert!(
        (thermal - 1.0).abs() < 0.06,
        "thermal temperature {thermal}"
    );
    assert!(sum["temperature"].as_f64().unwrap() > thermal);
}

#[test]
fn a_channel_run_reports_walls_and_resumes_bit_for_bit() {
    let dir = tmpdir("walls");
    let text = BASE
        .replace("flow = \"periodic_poiseuille\"", "flow = \"poiseuille\"")
        .replace(
            "seed = 3",
            "seed = 3\nwalls = { kind = \"planes\", gap = 5.0 }\nwall_warmup = 30",
        );
    let scene = dir.join("c.toml");
    std::fs::write(&scene, &text).unwrap();
    let s = scene.to_str().unwrap();
    let whole = dir.join("whole");
    ok(
        &mobo(&["dpd", s, "--out", whole.to_str().unwrap(), "--quiet"]),
        "channel run",
    );
    let sum = summary(&whole);
    assert_eq!(sum["leaked_particles"].as_u64(), Some(0));
    assert!(sum["bounces"].as_u64().unwrap() > 0);
    let fluid = sum["fluid_particles"].as_u64().unwrap();
    assert!(fluid < sum["particles"].as_u64().unwrap());
    // 5 × 5 × 5 of fluid at density 3, within the randomness of the placement.
    assert!((300..450).contains(&fluid), "{fluid} fluid particles");
    assert!(sum["viscosity"]["value"].as_f64().unwrap().is_finite());
    let walls = sum["effects"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["name"] == "walls")
        .unwrap();
    assert_eq!(walls["enabled"].as_bool(), Some(true));
    let part = dir.join("part");
    ok(
        &mobo(&[
            "dpd",
            s,
            "--out",
            part.to_str().unwrap(),
            "--quiet",
            "--max-steps",
            "70",
        ]),
        "part",
    );
    ok(
        &mobo(&["dpd", "--resume", part.to_str().unwrap(), "--quiet"]),
        "resume",
    );
    assert_eq!(arrays(&part), arrays(&whole));
}

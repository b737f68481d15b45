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

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

//! The `mobo` binary: help, version, demo, and errors for bad arguments (non-zero exit, no panic).

mod common;
use common::*;

#[test]
fn help_and_version() {
    let out = mobo(&["--help"]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("demo") && text.contains("bench-sht"),
        "{text}"
    );
    let out = mobo(&["--version"]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains(env!("CARGO_PKG_VERSION")));
}

#[test]
fn demo_reports_rbc_reduced_volume() {
    let out = mobo(&["demo", "--order", "12"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let v: f64 = text
        .split("reduced volume ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no reduced volume in:\n{text}"));
    // Design value of the biconcave RBC shape: v ≈ 0.644.
    assert!((v - 0.644).abs() < 1e-3, "reduced volume {v}");
}

#[test]
fn bench_sht_prints_one_json_line() {
    let out = mobo(&[
        "bench-sht",
        "--order",
        "6",
        "--surfaces",
        "10",
        "--reps",
        "1",
    ]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.trim();
    assert!(
        line.starts_with('{') && line.ends_with('}') && line.lines().count() == 1,
        "{line}"
    );
    for key in [
        "\"p\":6",
        "\"surfaces\":10",
        "\"forward_s\":",
        "\"inverse_s\":",
    ] {
        assert!(line.contains(key), "{key} missing in {line}");
    }
}

#[test]
fn bad_arguments_fail_cleanly() {
    for args in [
        &["demo", "--order", "0"][..],
        &["demo", "--order", "abc"],
        &["bench-sht", "--order", "0"],
        &["bench-sht", "--surfaces", "0"],
        &["no-such-command"],
    ] {
        let out = mobo(args);
        assert!(!out.status.success(), "{args:?} succeeded");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
        assert!(!err.trim().is_empty(), "{args:?} gave no message");
    }
}

//! The accuracy study (`mobo::report::accuracy`, `mobo report accuracy`): on a small one-cell
//! study the errors fall as each knob is tightened, the CSV / Markdown / PNG are written, a
//! small budget leaves values out (and says so), and bad input is refused with a message.

mod common;
use common::{mobo, tmpdir};

use mobo::report::accuracy::{run_study, to_csv, to_markdown, write_report, Knob, StudyOptions};
use mobo::scene::cells::parse;

const ONE_RBC: &str = r#"
[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "rbc"
radius = 1.0
bending_modulus = 0.1
orientation = [0, 1, 0, 30]
"#;

fn errors(study: &mobo::report::accuracy::Study, knob: Knob) -> Vec<(f64, f64)> {
    let mut v: Vec<(f64, f64)> = study
        .rows
        .iter()
        .filter(|r| r.knob == Some(knob))
        .map(|r| {
            assert!(
                r.failure.is_none(),
                "{:?} = {} failed: {:?}",
                knob,
                r.value,
                r.failure
            );
            (r.value, r.shape_error)
        })
        .collect();
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    v
}

/// One RBC in shear, reference p = 8, upsample 2, 8 steps to t = 0.4: the shape error falls
/// with p (4 → 6) and with the GMRES tolerance (1e-2 → 1e-8), the coarser dt has the larger
/// error, and every error is finite and positive.
#[test]
fn errors_fall_as_each_knob_is_tightened() {
    let scene = parse(std::path::Path::new("one-rbc"), ONE_RBC).unwrap();
    // No budget to run out of: what this test checks must not depend on how loaded the
    // machine is (under a parallel build the estimates passed 600 s and left values out; the
    // budget itself is the next test's).
    let opts = StudyOptions {
        budget_s: 1e9,
        t_end: 0.4,
        progress: false,
        levels: vec![(8, 2, 8)],
    };
    let study = run_study(&scene, "one RBC", &opts).unwrap();
    assert_eq!(study.reference.settings.order, 8);
    assert!(study.skipped.is_empty(), "{:?}", study.skipped);
    let p = errors(&study, Knob::Order);
    assert_eq!(p.len(), 2, "{p:?}");
    assert!(p[1].1 < p[0].1 / 3.0, "p: {p:?}");
    let tol = errors(&study, Knob::GmresTol);
    assert!(tol.len() >= 3, "{tol:?}");
    assert!(tol[0].1 < tol[tol.len() - 1].1, "gmres tol: {tol:?}");
    let dt = errors(&study, Knob::DtEuler);
    assert!(!dt.is_empty());
    for r in &study.rows {
        assert!(r.shape_error.is_finite() && r.shape_error > 0.0, "{r:?}");
        assert!(
            r.surface_error.is_finite() && r.surface_error > 0.0,
            "{r:?}"
        );
        assert!(
            r.tension_error.is_finite() && r.velocity_error.is_finite(),
            "{r:?}"
        );
        assert!(r.step_s > 0.0);
    }
    // One cell: no FMM knob, and the report says so.
    assert!(study.rows.iter().all(|r| r.knob != Some(Knob::FmmDigits)));
    assert!(study.notes.iter().any(|n| n.contains("fmm digits")));
    assert!(study.rows.iter().any(|r| r.pareto));

    let csv = to_csv(&study);
    assert_eq!(csv.lines().count(), study.rows.len() + 2);
    assert!(csv.lines().nth(1).unwrap().starts_with("reference,"));
    let md = to_markdown(&study, Some("accuracy.png"));
    assert!(md.contains("one RBC") && md.contains("![error against time per step]"));

    let dir = tmpdir("report-accuracy");
    match write_report(&study, &dir) {
        Ok(files) => {
            assert_eq!(files.len(), 3);
            let png = std::fs::read(dir.join("accuracy.png")).unwrap();
            assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
            assert!(
                png.len() > 10_000,
                "PNG suspiciously small: {} bytes",
                png.len()
            );
            assert!(std::fs::read_to_string(dir.join("accuracy.csv")).unwrap() == csv);
        }
        Err(mobo::report::ReportError::Font { tried }) => {
            panic!("no font for the plot (install fonts-dejavu-core): tried {tried}")
        }
        Err(e) => panic!("{e}"),
    }
}

/// A budget too small for the knob runs: the study still finishes with the reference, lists
/// what it left out, and stays near the budget.
#[test]
fn a_small_budget_leaves_values_out_and_says_so() {
    let scene = parse(std::path::Path::new("one-rbc"), ONE_RBC).unwrap();
    let opts = StudyOptions {
        budget_s: 0.5,
        t_end: 0.4,
        progress: false,
        levels: vec![(6, 2, 8)],
    };
    let study = run_study(&scene, "one RBC", &opts).unwrap();
    assert!(!study.skipped.is_empty());
    let md = to_markdown(&study, None);
    assert!(md.contains("Left out to fit the budget"), "{md}");
}

#[test]
fn bad_report_arguments_are_refused_with_a_message() {
    let o = mobo(&["report", "accuracy", "--budget-minutes", "0"]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("--budget-minutes"), "{e}");
    assert!(!e.contains("panicked"), "{e}");
    let o = mobo(&["report", "accuracy", "--scene", "/nonexistent/scene.toml"]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("/nonexistent/scene.toml"), "{e}");
    assert!(!e.contains("panicked"), "{e}");
}

/// With two cells the study also varies the coupling mode (the other one than the scene's) and
/// the contact projection's `d_min`; each run records the settings it ran with (about 40 s on
/// 2 cores with the FMM operators to compute; a few seconds once they are cached).
#[test]
fn two_cells_add_the_coupling_and_contact_distance_knobs() {
    let text = r#"
[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "rbc"
center = [-1.3, 0.0, 0.0]
orientation = [0, 1, 0, 90]
bending_modulus = 0.1
viscosity_ratio = 5.0
[[cells]]
shape = "rbc"
center = [1.3, 0.2, 0.0]
orientation = [0, 1, 0, 90]
bending_modulus = 0.1
viscosity_ratio = 5.0
[numerics]
coupling = "explicit"
"#;
    let scene = parse(std::path::Path::new("two-rbcs"), text).unwrap();
    let opts = StudyOptions {
        budget_s: 600.0,
        t_end: 0.04,
        progress: false,
        levels: vec![(6, 1, 4)],
    };
    let study = run_study(&scene, "two RBCs", &opts).unwrap();
    let of = |k: Knob| -> Vec<&mobo::report::accuracy::RunRow> {
        study.rows.iter().filter(|r| r.knob == Some(k)).collect()
    };
    let coupling = of(Knob::Coupling);
    assert_eq!(coupling.len(), 1, "one other coupling mode");
    assert!(coupling[0].failure.is_none(), "{:?}", coupling[0].failure);
    assert_eq!(
        coupling[0].settings.coupling,
        mobo::timestep::near_implicit::CouplingMode::NearImplicit
    );
    // The near-implicit step changes the answer, but only by about the reference's own error.
    assert!(coupling[0].surface_error > 0.0 && coupling[0].surface_error < 1e-2);
    let contact = of(Knob::ContactDistance);
    let mut ds: Vec<f64> = contact
        .iter()
        .map(|r| r.settings.contact_distance.unwrap())
        .collect();
    ds.sort_by(f64::total_cmp);
    assert_eq!(ds, vec![0.02, 0.05, 0.1]);
    assert!(contact.iter().all(|r| r.failure.is_none()));
    // The coupling error compares the first step's coupling velocity, computed from the same
    // initial state whatever the step size: the reparametrisation that relabels a cell's copy
    // after the step (by a move that depends on Δt) must not enter it.
    for row in of(Knob::DtBdf2).iter().chain(&of(Knob::DtEuler)) {
        if row.failure.is_none() {
            let e = row.coupling_error.expect("two cells have a coupling error");
            assert!(e < 1e-12, "Δt = {}: coupling error {e:e}", row.settings.dt);
        }
    }
    let md = to_markdown(&study, None);
    assert!(
        md.contains("coupling (0 explicit, 1 near-implicit)"),
        "{md}"
    );
}

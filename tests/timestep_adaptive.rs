//! Adaptive time step (`[numerics] adaptive_dt = true`): the variable-step BDF2 formula keeps
//! second order under a varying step, the controller recovers from a first step far too large
//! (rejections), a tighter tolerance gives a smaller error against a fine fixed-step reference
//! at the cost of more steps, and an adaptive run stopped and resumed equals one uninterrupted
//! run bit for bit.

mod common;
use common::{frame_bits, mobo, summary, tmpdir, write};

use mobo::timestep::semi_implicit::{TimeScheme, VesicleParams};
use mobo::timestep::vesicle_stepper::VesicleStepper;
use mobo::timestep::GmresParams;
use mobo::vesicle::geometry::SurfaceCalculus;
use mobo::vesicle::shapes;

const P: usize = 6;

fn stepper(scheme: TimeScheme, dt: f64) -> VesicleStepper {
    VesicleStepper::new(
        P,
        VesicleParams {
            bending_modulus: 1.0,
            viscosity: 1.0,
            force: [0.0; 3],
            dt,
            upsampled_order: 2 * P,
            gmres: GmresParams {
                tol: 1e-13,
                restart: 100,
                max_iters: 1000,
                ..Default::default()
            },
            correct_drift: false,
            reparametrize: None,
            preconditioner: true,
            scheme,
            viscosity_ratio: 1.0,
            inextensible: true,
            elastic_stepping: None,
        },
    )
    .unwrap()
}

/// Advance `start` (no flow) through the steps `dts`; the principal moments of inertia at the end.
fn moments(scheme: TimeScheme, start: &[f64], dts: &[f64]) -> [f64; 3] {
    let mut st = stepper(scheme, dts[0]);
    let mut c = start.to_vec();
    for &dt in dts {
        st.set_dt(dt).unwrap();
        let r = st.step(&mut c, &|_| [0.0; 3]).unwrap();
        assert!(r.gmres.converged);
        assert!(r.area_volume_error.is_finite());
    }
    let mut calc = SurfaceCalculus::new(P).unwrap();
    calc.geometry(&c).unwrap().principal_axes().0
}

#[test]
fn variable_step_bdf2_stays_second_order() {
    // The ellipsoid 1.2 : 1 : 0.8 relaxed past its stiff transient (as in timestep_order.rs),
    // then advanced to T = 0.5 with steps alternating 1.25 h and 0.75 h (ω = 0.6 and 5/3).
    // With the constant-step coefficients under a varying step the scheme is first order;
    // the variable-step formula keeps the second.
    let ellipsoid = shapes::ellipsoid(P, [1.2, 1.0, 0.8]).unwrap();
    let mut st = stepper(TimeScheme::Bdf2, 5e-4);
    let mut start = ellipsoid.coefs().to_vec();
    for _ in 0..400 {
        st.step(&mut start, &|_| [0.0; 3]).unwrap();
    }
    let t = 0.5;
    let reference = moments(TimeScheme::Bdf2, &start, &vec![t / 640.0; 640]);
    let mut errs = Vec::new();
    println!("| steps | error (principal moments) | order |");
    for n in [10usize, 20, 40] {
        let h = t / n as f64;
        let dts: Vec<f64> = (0..n)
            .map(|k| if k % 2 == 0 { 1.25 * h } else { 0.75 * h })
            .collect();
        let m = moments(TimeScheme::Bdf2, &start, &dts);
        let e = (0..3)
            .map(|i| (m[i] - reference[i]).abs())
            .fold(0.0, f64::max);
        let order = errs.last().map(|p: &f64| (p / e).log2());
        println!("| {n} | {e:.3e} | {order:?} |");
        errs.push(e);
    }
    let order = (errs[0] / errs[2]).log2() / 2.0;
    assert!(
        order > 1.8,
        "variable-step BDF2 order {order:.2} ({errs:?})"
    );
}

/// The last frame's coefficients.
fn last_coefs(out: &std::path::Path) -> Vec<f64> {
    let mut last = None;
    for f in 0.. {
        let path = out.join(format!("frames/frame_{f:05}_coefs.npy"));
        if !path.exists() {
            break;
        }
        last = Some(mobo::io::npy::read_f64(&path).unwrap().1);
    }
    last.expect("frames written")
}

/// A prolate vesicle relaxing in shear (order 6), Euler; `numerics` is appended.
fn relaxing_scene(numerics: &str) -> String {
    format!(
        r#"
[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "ellipsoid"
axes = [1.3, 1.0, 0.75]
bending_modulus = 1.0
[numerics]
order = 6
t_end = 1.0
gmres_tol = 1e-10
{numerics}
[output]
every = 100000
vtk = false
"#
    )
}

fn run_scene(dir: &std::path::Path, name: &str, text: &str) -> (serde_json::Value, [f64; 3]) {
    let scene = write(dir, &format!("{name}.toml"), text);
    let out = dir.join(name);
    let o = mobo(&["run", &scene, "--out", out.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let c = last_coefs(&out);
    let mut calc = SurfaceCalculus::new(6).unwrap();
    let m = calc.geometry(&c).unwrap().principal_axes().0;
    (summary(&out), m)
}

#[test]
fn the_controller_rejects_a_step_too_large_and_meets_a_tighter_tolerance_with_more_steps() {
    let dir = tmpdir("adaptive-tol");
    let (_, reference) = run_scene(&dir, "ref", &relaxing_scene("dt = 0.0005"));
    let mut results = Vec::new();
    for tol in [1e-2, 1e-3] {
        // dt = 0.5 is far too large for the first steps of the relaxation (κ = 1, R = 1).
        let (s, m) = run_scene(
            &dir,
            &format!("tol{tol}"),
            &relaxing_scene(&format!(
                "dt = 0.5\nadaptive_dt = true\ndt_tolerance = {tol}\ndt_min = 1e-5\n"
            )),
        );
        assert_eq!(s["completed"].as_bool(), Some(true));
        assert!((s["final_time"].as_f64().unwrap() - 1.0).abs() < 1e-9);
        let a = &s["adaptive"];
        let rejected = a["rejected_steps"].as_u64().unwrap();
        assert!(rejected >= 1, "dt = 0.5 must be rejected first: {a}");
        assert_eq!(a["steps_above_tolerance"].as_u64(), Some(0), "{a}");
        // The committed error estimate stays within the tolerance.
        let sum = s["area_volume_error_sum"].as_f64().unwrap();
        assert!(
            sum <= tol,
            "estimated error {sum} above the tolerance {tol}"
        );
        // The step adapts: small in the stiff start, larger later.
        let (lo, hi) = (
            a["dt_smallest"].as_f64().unwrap(),
            a["dt_largest"].as_f64().unwrap(),
        );
        assert!(hi > 2.0 * lo, "dt from {lo} to {hi}");
        let err = (0..3)
            .map(|i| (m[i] - reference[i]).abs() / reference[i])
            .fold(0.0, f64::max);
        let steps = s["steps"].as_u64().unwrap();
        println!("tolerance {tol:e}: {steps} steps, {rejected} rejected, dt {lo:.2e} … {hi:.2e}, shape error {err:.2e}");
        // Here the shape error follows the tolerance (measured: 4.8e-3 at 1e-2, 4.3e-4 at 1e-3).
        assert!(
            err < tol,
            "shape error {err:.2e} above the tolerance {tol:e}"
        );
        results.push((steps, err));
    }
    assert!(
        results[1].0 > results[0].0,
        "a tighter tolerance takes more steps"
    );
    assert!(
        results[1].1 < 0.5 * results[0].1,
        "a tighter tolerance gives a smaller error: {results:?}"
    );
}

const TWO_CELLS_ADAPTIVE: &str = r#"
[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "prolate"
reduced_volume = 0.9
center = [-1.8, 0.4, 0.0]
bending_modulus = 0.5
[[cells]]
shape = "prolate"
reduced_volume = 0.9
center = [1.8, -0.4, 0.0]
bending_modulus = 0.5
[numerics]
order = 6
dt = 0.2
t_end = 1.0
scheme = "bdf2"
adaptive_dt = true
dt_tolerance = 1e-2
[output]
every = 3
vtk = false
"#;

fn frames_of(out: &std::path::Path) -> Vec<Vec<u64>> {
    let mut all = frame_bits(out, false);
    let (_, t) = mobo::io::npy::read_f64(&out.join("frames/times.npy")).unwrap();
    all.push(t.iter().map(|v| v.to_bits()).collect());
    all
}

#[test]
fn an_adaptive_run_stopped_and_resumed_equals_one_run_bit_for_bit() {
    let dir = tmpdir("adaptive-resume");
    let scene = write(&dir, "two.toml", TWO_CELLS_ADAPTIVE);
    let full = dir.join("full");
    let o = mobo(&["run", &scene, "--out", full.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&full);
    let steps = s["steps"].as_u64().unwrap();
    assert!(steps >= 6, "{s}");
    let a = &s["adaptive"];
    assert!(
        a["dt_smallest"].as_f64() != a["dt_largest"].as_f64(),
        "the step changed during the run: {a}"
    );
    let want = frames_of(&full);
    let part = dir.join("part");
    let o = mobo(&[
        "run",
        &scene,
        "--out",
        part.to_str().unwrap(),
        "--quiet",
        "--max-steps",
        &(steps / 2).to_string(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(summary(&part)["completed"].as_bool(), Some(false));
    let o = mobo(&["run", "--resume", part.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s2 = summary(&part);
    assert_eq!(s2["completed"].as_bool(), Some(true));
    assert_eq!(s2["steps"].as_u64(), Some(steps));
    assert_eq!(s2["adaptive"], s["adaptive"]);
    assert_eq!(
        frames_of(&part),
        want,
        "stop + resume = one run, bit for bit"
    );
}

#[test]
fn adaptive_bounds_are_checked_in_the_scene() {
    let dir = tmpdir("adaptive-bad");
    for (text, want) in [
        (
            "[[cells]]\nshape = \"sphere\"\n[numerics]\ndt = 0.1\nadaptive_dt = true\ndt_min = 0.5\n",
            "must lie between dt_min",
        ),
        (
            "[[cells]]\nshape = \"sphere\"\n[numerics]\nadaptive_dt = true\ndt_tolerance = 2.0\n",
            "dt_tolerance must be below 1",
        ),
    ] {
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
        assert!(err.contains(want) && err.contains("bad.toml:"), "{want} not in: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
}

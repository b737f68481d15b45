//! The tank-treading rate of a membrane (`mobo::vesicle::tank_treading`) in both solvers: the
//! boundary-integral cell's against the exact rotation of a sphere in shear, and the DPD
//! membrane's vertex-snapshot estimate on the RBC example scene.
mod common;

use std::path::Path;

use common::{mobo, ok, summary, tmpdir, write};
use mobo::{run, scene::dpd};

/// A spherical vesicle (reduced volume 1: it cannot deform) in the shear `u = (γ̇y, 0, 0)`
/// turns as a rigid sphere in Stokes flow, at `γ̇/2` clockwise about `z` (its membrane's
/// material with it): `summary.json`'s `tank_treading_rate`, for two shear rates and signs.
#[test]
fn a_sphere_in_shear_turns_at_half_the_shear_rate() {
    let dir = tmpdir("tank-treading-sphere");
    for rate in [1.0, -2.0] {
        let scene = write(
            &dir,
            "sphere.toml",
            &format!(
                "[flow]\nkind = \"shear\"\nrate = {rate}\n\n[[cells]]\nshape = \"sphere\"\n\
                 radius = 1.0\ncenter = [0.3, -0.2, 0.1]\nbending_modulus = 0.1\n\n\
                 [numerics]\norder = 8\ndt = 0.001\nt_end = 0.003\ngmres_tol = 1e-11\n"
            ),
        );
        let out = dir.join(format!("out{rate}"));
        let o = mobo(&["run", &scene, "--out", out.to_str().unwrap(), "--quiet"]);
        ok(&o, "mobo run");
        let s = summary(&out);
        let tt = s["per_cell"][0]["tank_treading_rate"].as_f64().unwrap();
        // Clockwise-positive: the sign of the shear rate. The step's own error (measured:
        // 5e-5 of γ̇ at dt = 0.01, 1.4e-6 at dt = 0.001, p = 8 and 12 alike) is the tolerance.
        assert!(
            (tt - 0.5 * rate).abs() < 1e-5 * rate.abs(),
            "rate {rate}: tank-treading rate {tt}"
        );
    }
}

/// The RBC example scene, shortened, by both solvers: the boundary-integral RBC (its disk in
/// the shear plane) tank-treads a little slower than a rigid sphere would turn; the DPD cell
/// built by `run::dpd::build_suspension` gives a phase advance over its steps, its vertex
/// areas add up to its area, and a snapshot of the wrong size is refused.
#[test]
fn the_rbc_example_runs_both_ways_with_its_tank_treading_rate() {
    let dir = tmpdir("tank-treading-rbc");
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/scenes/rbc_shear_bie_and_dpd.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let short = text
        .replace("order = 12", "order = 8")
        .replace("t_end = 4.0", "t_end = 0.5")
        .replace("steps = 60000", "steps = 200")
        .replace("save_every = 5000", "save_every = 100")
        .replace("wall_warmup = 300", "wall_warmup = 20");
    assert_ne!(short, text, "the shortening must apply");
    let scene = write(&dir, "rbc.toml", &short);
    let out = dir.join("bie");
    ok(
        &mobo(&["run", &scene, "--out", out.to_str().unwrap(), "--quiet"]),
        "mobo run",
    );
    let cell = &summary(&out)["per_cell"][0];
    let tt = cell["tank_treading_rate"].as_f64().unwrap();
    // The elongated disk's membrane turns slower than the sphere's γ̇/2 (0.494 at p = 12,
    // docs/dpd_vs_bie.md), and not much slower.
    assert!(tt > 0.45 && tt < 0.5, "{cell}");

    let scene = dpd::load(Path::new(&scene)).unwrap();
    let mut sim = run::dpd::build_suspension(&scene).unwrap();
    let c = &sim.cells()[0];
    let area: f64 = c.vertex_areas().iter().sum();
    let (da, _) = c.area_volume_change().unwrap();
    let area0 = c.membrane().area0();
    assert!(
        (area - area0 * (1.0 + da)).abs() < 1e-12 * area,
        "{area} vs {}",
        area0 * (1.0 + da)
    );
    let before = c.positions().to_vec();
    assert_eq!(c.phase_advance(&before, [0.0, 1.0, 0.0]).unwrap(), 0.0);
    assert!(c.phase_advance(&before[1..], [0.0, 1.0, 0.0]).is_err());
    for _ in 0..100 {
        sim.step().unwrap();
    }
    // Over 100 steps (t = 0.2, a strain of 0.02) the membrane turns by a few hundredths of a
    // radian at most, with the vorticity (+y), blurred by thermal motion.
    let adv = sim.cells()[0]
        .phase_advance(&before, [0.0, 1.0, 0.0])
        .unwrap();
    assert!(adv.is_finite() && adv.abs() < 0.1, "{adv}");
}

//! Capsules (`VesicleParams::inextensible = false`): elastic membranes without the
//! inextensibility constraint, neo-Hookean and Skalak laws, in simple shear
//! `u = (γ̇y, 0, 0)` with `γ̇ = μ = a = 1` and `Ca = μγ̇a/E_s`, `E_s = 3G_s`.
//!
//! * The small-deformation limit of Barthès-Biesel & Rallison (1981): `D = (5/4) Ca_G
//!   (2 + ν_s)/(1 + ν_s) = (25/4) Ca` for both laws (`ν_s = 1/2`; Skalak with `C = 1`), and
//!   independent of the viscosity ratio.
//! * The published steady Taylor deformation at one `Ca` (Ramanujan & Pozrikidis 1998, the
//!   table of design 5: `D = 0.150` at `Ca = 0.025`), within 5%.
//! * The linearly implicit elasticity against forward Euler: the same flow at a small step,
//!   stable where forward Euler is not.
//! * A capsule scene through `Simulation` gives the stepper's run, and bad capsule keys are
//!   refused with the key named; two coupled capsules stopped and resumed by `mobo run` give the
//!   uninterrupted run bit for bit.
//! * Two capsules passing each other in shear: the centroids' trajectory against Lac, Morel &
//!   Barthès-Biesel (2007), prestressed membranes (`prestress`).
//!
//! The full table (both laws, `Ca` 0.0125–0.2, `p = 12`) is `scripts/capsule_shear.sh`
//! (docs/capsules.md).

use std::path::Path;

mod common;
use common::{frame_bits, mobo, stop_and_resume, summary, tmpdir, write};

use mobo::run::simulation::Simulation;
use mobo::scene::cells::parse;
use mobo::timestep::semi_implicit::{ElasticStepping, TimeScheme, VesicleParams};
use mobo::timestep::vesicle_stepper::VesicleStepper;
use mobo::timestep::GmresParams;
use mobo::vesicle::geometry::SurfaceCalculus;
use mobo::vesicle::shapes;
use mobo::vesicle::skalak::SkalakParams;

fn params(p: usize, dt: f64, scheme: TimeScheme) -> VesicleParams {
    VesicleParams {
        bending_modulus: 0.0,
        viscosity: 1.0,
        force: [0.0; 3],
        dt,
        upsampled_order: 2 * p,
        gmres: GmresParams {
            tol: 1e-9,
            restart: 100,
            max_iters: 1000,
            ..Default::default()
        },
        correct_drift: true,
        reparametrize: None,
        preconditioner: false,
        scheme,
        viscosity_ratio: 1.0,
        inextensible: false,
        elastic_stepping: None,
    }
}

/// Taylor deformation in the shear plane after `steps` steps of a unit sphere (and the
/// largest relative volume change of a BDF2 step, before the correction, and the mean GMRES
/// iterations), or the time at which it blew up.
fn run(
    law: SkalakParams,
    p: usize,
    dt: f64,
    steps: usize,
    explicit: bool,
) -> Result<(f64, f64, f64), f64> {
    run_with(law, 1.0, p, dt, steps, explicit)
}

/// [`run`] with the viscosity ratio `λ`.
fn run_with(
    law: SkalakParams,
    lambda: f64,
    p: usize,
    dt: f64,
    steps: usize,
    explicit: bool,
) -> Result<(f64, f64, f64), f64> {
    let sphere = shapes::sphere(p, 1.0).unwrap();
    let prm = VesicleParams {
        viscosity_ratio: lambda,
        elastic_stepping: explicit.then_some(ElasticStepping::Explicit),
        ..params(p, dt, TimeScheme::Bdf2)
    };
    let mut st = VesicleStepper::new(p, prm).unwrap();
    st.set_skalak(law, sphere.coefs()).unwrap();
    let mut coefs = sphere.coefs().to_vec();
    let mut calc = SurfaceCalculus::new(p).unwrap();
    let shear = |x: [f64; 3]| [x[1], 0.0, 0.0];
    let (mut worst, mut iters) = (0.0f64, 0usize);
    for k in 1..=steps {
        let t = k as f64 * dt;
        let r = st.step(&mut coefs, &shear).map_err(|_| t)?;
        if k > 1 {
            // (the first step of a BDF2 run is Euler)
            worst = worst.max(r.area_volume_error);
        }
        iters += r.gmres.iterations;
        let d = calc
            .geometry(&coefs)
            .map_err(|_| t)?
            .taylor_deformation([0.0, 0.0, 1.0]);
        if !(d.is_finite() && d < 0.9) {
            return Err(t);
        }
    }
    let d = calc
        .geometry(&coefs)
        .unwrap()
        .taylor_deformation([0.0, 0.0, 1.0]);
    Ok((d, worst, iters as f64 / steps as f64))
}

#[test]
fn small_deformation_reaches_the_barthes_biesel_rallison_limit_for_both_laws() {
    let ca = 0.003125;
    let gs = 1.0 / (3.0 * ca);
    let limit = 25.0 / 4.0 * ca;
    for law in [SkalakParams::neo_hookean(gs), SkalakParams::skalak(gs, 1.0)] {
        let (d, dv, iters) = run(law, 6, 0.04, 75, false).unwrap();
        println!(
            "{:?}: D = {d:.6}, (25/4) Ca = {limit:.6}, ratio {:.4}, step volume error {dv:.1e}, \
             {iters:.1} iterations per step",
            law.law,
            d / limit
        );
        // p = 8 gives 1.0005 (NH) and 0.9990 (Skalak); O(Ca²) terms are below 0.2% here.
        assert!(
            (d / limit - 1.0).abs() < 0.01,
            "{:?}: {d} vs {limit}",
            law.law
        );
        // Volume is kept by the flow; BDF2 loses O(Δt³) per step to the rotation.
        assert!(dv < 1e-4, "{dv}");
    }
    // To first order D does not depend on the viscosity ratio (Barthès-Biesel & Rallison):
    // λ = 4 through the double layer of the capsule's own step. It takes longer to settle
    // (the membrane relaxes on the time scale (1 + λ)μa/G_s).
    let (d, _, _) = run_with(SkalakParams::neo_hookean(gs), 4.0, 6, 0.04, 75, false).unwrap();
    println!("neo-Hookean, λ = 4: D = {d:.6}, ratio {:.4}", d / limit);
    assert!((d / limit - 1.0).abs() < 0.02, "λ = 4: {d} vs {limit}");
}

#[test]
fn neo_hookean_capsule_reaches_the_published_deformation_at_ca_0_025() {
    let ca = 0.025;
    let (d, _, _) = run(
        SkalakParams::neo_hookean(1.0 / (3.0 * ca)),
        6,
        0.04,
        100,
        false,
    )
    .unwrap();
    // Ramanujan & Pozrikidis (1998): 0.150. p = 8 and 12 give 0.1548 (docs/capsules.md).
    let published = 0.150;
    println!(
        "D = {d:.5} against {published} ({:+.1}%)",
        100.0 * (d / published - 1.0)
    );
    assert!((d / published - 1.0).abs() < 0.05, "{d}");
    // Skalak (C = 1) hardens under strain: less deformed than neo-Hookean at the same Ca.
    let (dsk, _, _) = run(
        SkalakParams::skalak(1.0 / (3.0 * ca), 1.0),
        6,
        0.04,
        100,
        false,
    )
    .unwrap();
    println!("Skalak C = 1: D = {dsk:.5}");
    assert!(dsk < 0.97 * d && dsk > 0.85 * d, "{dsk} vs {d}");
}

#[test]
fn implicit_elasticity_is_the_explicit_flow_and_stable_where_forward_euler_is_not() {
    let ca = 0.0125;
    let law = SkalakParams::neo_hookean(1.0 / (3.0 * ca));
    // A step small enough for forward Euler: both give the same shape (first order in Δt).
    let (di, _, _) = run(law, 6, 0.0025, 80, false).unwrap();
    let (de, _, _) = run(law, 6, 0.0025, 80, true).unwrap();
    println!("t = 0.2: implicit D = {di:.6}, explicit D = {de:.6}");
    assert!((di - de).abs() < 1e-4 * di, "{di} vs {de}");
    // Eight times that step: forward Euler blows up, the linearly implicit step does not.
    let explicit = run(law, 8, 0.02, 50, true);
    println!("explicit at dt = 0.02: {explicit:?}");
    assert!(explicit.is_err(), "forward Euler should be unstable here");
    let (d, _, _) = run(law, 8, 0.02, 50, false).unwrap();
    assert!(d > 0.07 && d < 0.08, "{d}");
}

const CAPSULE: &str = r#"
[flow]
kind = "shear"
rate = 1.0

[[cells]]
shape = "sphere"
shear_modulus = 13.333333333333334
KEYS

[numerics]
order = 6
dt = 0.04
t_end = 1.2
scheme = "bdf2"
gmres_tol = 1e-9
"#;

#[test]
fn a_capsule_scene_is_the_stepper_run_and_bad_keys_are_named() {
    let good = "membrane = \"capsule\"\nelastic_law = \"neo_hookean\"";
    let scene = parse(Path::new("capsule.toml"), &CAPSULE.replace("KEYS", good)).unwrap();
    let effects = mobo::scene::cells::effects(&scene.cells, &scene.flow);
    let capsule = effects.iter().find(|e| e.name == "capsule").unwrap();
    assert!(capsule.enabled, "{}", capsule.reason);
    let mut sim = Simulation::new(scene).unwrap();
    sim.advance_to(1.2, |_, _| {}).unwrap();
    let d_scene = sim
        .cell(0)
        .unwrap()
        .geometry
        .taylor_deformation([0.0, 0.0, 1.0]);
    let (d, _, _) = run(SkalakParams::neo_hookean(1.0 / 0.075), 6, 0.04, 30, false).unwrap();
    println!("scene D = {d_scene:.6}, stepper D = {d:.6}");
    // The scene's GMRES restart differs (200 against 100): the same step to the tolerance.
    assert!((d_scene - d).abs() < 1e-6, "{d_scene} vs {d}");

    let err = |keys: &str| {
        parse(Path::new("capsule.toml"), &CAPSULE.replace("KEYS", keys))
            .unwrap_err()
            .to_string()
    };
    let e = err("membrane = \"balloon\"\nelastic_law = \"neo_hookean\"");
    assert!(e.contains("membrane") && e.contains("balloon"), "{e}");
    let e = err("membrane = \"capsule\"\nelastic_law = \"hooke\"");
    assert!(
        e.contains("elastic_law") && e.contains("neo_hookean"),
        "{e}"
    );
    let zero = CAPSULE.replace("shear_modulus = 13.333333333333334", "shear_modulus = 0.0");
    let e = parse(Path::new("capsule.toml"), &zero.replace("KEYS", good))
        .unwrap_err()
        .to_string();
    assert!(e.contains("capsule") && e.contains("shear_modulus"), "{e}");
    assert!(e.contains("capsule.toml"), "{e}");
    // Keys that would be ignored are refused, and adaptive dt cannot see a capsule's error.
    let e = err("membrane = \"capsule\"\nelastic_law = \"neo_hookean\"\nprestress = 1.5");
    assert!(e.contains("prestress") && e.contains("[0, 1)"), "{e}");
    let e = parse(
        Path::new("v.toml"),
        "[[cells]]\nshape = \"sphere\"\nprestress = 0.05\n",
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("prestress") && e.contains("shear_modulus"),
        "{e}"
    );
    let e = err("membrane = \"capsule\"\nelastic_law = \"neo_hookean\"\nskalak_c = 2.0");
    assert!(e.contains("skalak_c") && e.contains("neo_hookean"), "{e}");
    let vesicle = "[[cells]]\nshape = \"sphere\"\nelastic_law = \"skalak\"\n";
    let e = parse(Path::new("v.toml"), vesicle).unwrap_err().to_string();
    assert!(
        e.contains("elastic_law") && e.contains("shear_modulus"),
        "{e}"
    );
    let adaptive = CAPSULE
        .replace("KEYS", good)
        .replace("scheme = \"bdf2\"", "scheme = \"bdf2\"\nadaptive_dt = true");
    let e = parse(Path::new("capsule.toml"), &adaptive)
        .unwrap_err()
        .to_string();
    assert!(e.contains("adaptive_dt") && e.contains("capsule"), "{e}");
}

/// An inextensible RBC with a stiff Skalak membrane in shear, `Δt` steps to `t`: the largest
/// GMRES iteration count and the final coefficients, or the time of the failure.
fn rbc_run(
    p: usize,
    dt: f64,
    steps: usize,
    stepping: ElasticStepping,
) -> Result<(usize, Vec<f64>), f64> {
    rbc_run_with(p, dt, steps, stepping, TimeScheme::Euler, true)
}

/// [`rbc_run`] with a scheme, with or without the reparametrisation.
fn rbc_run_with(
    p: usize,
    dt: f64,
    steps: usize,
    stepping: ElasticStepping,
    scheme: TimeScheme,
    reparametrize: bool,
) -> Result<(usize, Vec<f64>), f64> {
    let rbc = shapes::rbc(p).unwrap();
    let prm = VesicleParams {
        bending_modulus: 0.05,
        correct_drift: true,
        reparametrize: reparametrize.then(|| mobo::vesicle::reparam::ReparamParams {
            max_iterations: 10,
            ..Default::default()
        }),
        preconditioner: true,
        inextensible: true,
        elastic_stepping: Some(stepping),
        ..params(p, dt, scheme)
    };
    let mut st = VesicleStepper::new(p, prm).unwrap();
    st.set_skalak(SkalakParams::skalak(20.0, 10.0), rbc.coefs())
        .unwrap();
    let mut coefs = rbc.coefs().to_vec();
    let shear = |x: [f64; 3]| [x[1], 0.0, 0.0];
    let mut most = 0;
    for k in 1..=steps {
        let r = st.step(&mut coefs, &shear).map_err(|_| k as f64 * dt)?;
        most = most.max(r.gmres.iterations);
        if !coefs.iter().all(|c| c.is_finite() && c.abs() < 10.0) {
            return Err(k as f64 * dt);
        }
    }
    Ok((most, coefs))
}

#[test]
fn inextensible_cells_take_the_skalak_force_implicitly_on_request() {
    let p = 6;
    // Small steps: the explicit and the linearly implicit elasticity are two first-order
    // schemes of the same flow, so their difference at t = 0.05 halves with the step.
    let diffs: Vec<f64> = [0.002, 0.001, 0.0005]
        .iter()
        .map(|&dt| {
            let steps = (0.05 / dt) as usize;
            let (_, a) = rbc_run(p, dt, steps, ElasticStepping::Explicit).unwrap();
            let (_, b) = rbc_run(p, dt, steps, ElasticStepping::LinearlyImplicit).unwrap();
            a.iter()
                .zip(&b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max)
        })
        .collect();
    println!("largest coefficient differences at dt = 0.002, 0.001, 0.0005: {diffs:?}");
    for w in diffs.windows(2) {
        let ratio = w[0] / w[1];
        assert!((1.7..2.3).contains(&ratio), "{diffs:?}");
    }
    // BDF2 (the δ = X − X* shift with X̂ ≠ X*): second order each, so the difference falls
    // fourfold per halving (without the reparametrisation, which alone caps BDF2's order: with
    // it the difference falls only twofold, see the module docs of the step).
    let diffs2: Vec<f64> = [0.002, 0.001, 0.0005]
        .iter()
        .map(|&dt| {
            let steps = (0.05 / dt) as usize;
            let run = |e| {
                rbc_run_with(p, dt, steps, e, TimeScheme::Bdf2, false)
                    .unwrap()
                    .1
            };
            let (a, b) = (
                run(ElasticStepping::Explicit),
                run(ElasticStepping::LinearlyImplicit),
            );
            a.iter()
                .zip(&b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max)
        })
        .collect();
    println!("BDF2: {diffs2:?}");
    for w in diffs2.windows(2) {
        let ratio = w[0] / w[1];
        assert!((3.5..4.5).contains(&ratio), "{diffs2:?}");
    }
    // Twenty times the largest of those steps.
    let explicit = rbc_run(p, 0.04, 25, ElasticStepping::Explicit);
    let implicit = rbc_run(p, 0.04, 25, ElasticStepping::LinearlyImplicit);
    println!(
        "dt = 0.04: explicit {:?}, implicit {:?}",
        explicit.as_ref().map(|r| r.0),
        implicit.as_ref().map(|r| r.0)
    );
    assert!(explicit.is_err(), "explicit Skalak should be unstable here");
    assert!(implicit.is_ok(), "{implicit:?}");
}

const TWO_CAPSULES: &str = r#"
[flow]
kind = "shear"
rate = 1.0

[[cells]]
shape = "sphere"
center = [-1.2, 0.3, 0.0]
membrane = "capsule"
elastic_law = "neo_hookean"
shear_modulus = 5.0

[[cells]]
shape = "ellipsoid"
axes = [1.0, 0.8, 0.7]
center = [1.2, -0.3, 0.0]
membrane = "capsule"
shear_modulus = 5.0
skalak_c = 2.0

[numerics]
order = 6
dt = 0.05
t_end = 0.5
scheme = "bdf2"

[output]
every = 2
vtk = false
"#;

#[test]
fn two_capsules_stopped_and_resumed_give_the_uninterrupted_run_bit_for_bit() {
    let dir = tmpdir("capsule-resume");
    let scene = write(&dir, "two_capsules.toml", TWO_CAPSULES);
    let full = dir.join("full");
    let o = mobo(&["run", &scene, "--out", full.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&full);
    assert_eq!(s["steps"].as_u64(), Some(10));
    // The capsules stretch (area change), the volume is restored every step.
    let area = s["area_drift"].as_f64().unwrap();
    let volume = s["volume_drift"].as_f64().unwrap();
    println!("area change {area:.2e}, volume drift {volume:.2e}");
    assert!(area.abs() > 1e-4, "{area}");
    assert!(volume.abs() < 1e-12, "{volume}");
    let part = dir.join("part");
    stop_and_resume(&scene, &part, 4);
    assert_eq!(summary(&part)["completed"].as_bool(), Some(true));
    assert_eq!(
        frame_bits(&part, true),
        frame_bits(&full, true),
        "stop at 4 + resume = one run, bit for bit"
    );
}

/// Two identical neo-Hookean capsules passing each other in simple shear, the case of Lac,
/// Morel & Barthès-Biesel (J. Fluid Mech. 573, 2007, fig. 4b): `Ca = μγ̇a/G_s = 0.45`,
/// prestress `α = 0.05`, `λ = 1`, centres `(∓4a, ±0.25a, 0)` (`Δx₀/2a = −4`,
/// `Δy₀/2a = 0.25`). The case's parameters come from Huet's reproduction of the figure
/// (Basilisk sandbox `huet/tests/lagrangian_caps/caps_interception.c`), whose front-tracking
/// run matched it to 0.02–0.05a; the figure's points, digitised by Huet (`lac_fig4b.csv`), are
/// `LAC_FIG_4B` below as (`Δx/2a`, `Δy/2a`) of the centroids.
const LAC_PAIR: &str = r#"
[flow]
kind = "shear"
rate = 1.0

[[cells]]
shape = "sphere"
center = [-4.0, 0.25, 0.0]
membrane = "capsule"
elastic_law = "neo_hookean"
shear_modulus = 2.2222222222222223
bending_modulus = 0.0
prestress = 0.05

[[cells]]
shape = "sphere"
center = [4.0, -0.25, 0.0]
membrane = "capsule"
elastic_law = "neo_hookean"
shear_modulus = 2.2222222222222223
bending_modulus = 0.0
prestress = 0.05

[numerics]
order = ORDER
dt = DT
t_end = 30.0
scheme = "bdf2"
coupling = "near_implicit"
"#;

/// Lac et al. (2007) fig. 4b, digitised: (`Δx/2a`, `Δy/2a`) of the centroids.
const LAC_FIG_4B: [(f64, f64); 16] = [
    (-3.9910, 0.2520),
    (-3.0165, 0.2480),
    (-2.2045, 0.2440),
    (-1.4286, 0.2520),
    (-0.9053, 0.3327),
    (-0.5083, 0.4819),
    (-0.1113, 0.6250),
    (0.4301, 0.7198),
    (1.0526, 0.6835),
    (1.5489, 0.6129),
    (2.1263, 0.5706),
    (2.9203, 0.5544),
    (3.6421, 0.5464),
    (4.2917, 0.5464),
    (4.9414, 0.5464),
    (5.6812, 0.5464),
];

/// The centroids' separation (`Δx/2a`, `Δy/2a`) of the Lac pair at order `p` and step `dt`,
/// every `every` steps until `Δx/2a` passes the figure's last point.
fn lac_pair_trajectory(p: usize, dt: f64, every: usize) -> Vec<(f64, f64)> {
    let text = LAC_PAIR
        .replace("ORDER", &p.to_string())
        .replace("DT", &dt.to_string());
    let mut sim = Simulation::new(parse(Path::new("lac_pair.toml"), &text).unwrap()).unwrap();
    let mut out = vec![];
    loop {
        let a = sim.cell(0).unwrap().geometry.centroid();
        let b = sim.cell(1).unwrap().geometry.centroid();
        let sep = ((a[0] - b[0]) / 2.0, (a[1] - b[1]) / 2.0);
        out.push(sep);
        if sep.0 > LAC_FIG_4B[15].0 + 0.1 {
            return out;
        }
        assert!(sim.time() < 30.0, "the capsules did not pass: {sep:?}");
        for _ in 0..every {
            sim.step().unwrap();
        }
    }
}

/// `Δy/2a` of `trajectory` at `Δx/2a = x` (linear between samples; `Δx` grows along it).
fn separation_at(trajectory: &[(f64, f64)], x: f64) -> f64 {
    let k = trajectory.iter().position(|s| s.0 >= x).unwrap();
    let ((x0, y0), (x1, y1)) = (trajectory[k - 1], trajectory[k]);
    y0 + (y1 - y0) * (x - x0) / (x1 - x0)
}

/// What the trajectory says against the figure: the final separation and the largest one
/// (relative differences) and the largest difference at the figure's points (in `2a`).
fn against_lac(trajectory: &[(f64, f64)]) -> (f64, f64, f64) {
    let last = LAC_FIG_4B[15];
    let final_rel = separation_at(trajectory, last.0) / last.1 - 1.0;
    let largest = trajectory.iter().map(|s| s.1).fold(0.0, f64::max);
    let largest_rel = largest / 0.7198 - 1.0;
    let worst = LAC_FIG_4B
        .iter()
        .map(|&(x, y)| (separation_at(trajectory, x) - y).abs())
        .fold(0.0, f64::max);
    (final_rel, largest_rel, worst)
}

#[test]
fn two_capsules_in_shear_pass_each_other_as_lac_morel_and_barthes_biesel_found() {
    // Coarse and quick: p = 6, Δt = 0.04 (docs/capsules.md has p = 8 and 12).
    let trajectory = lac_pair_trajectory(6, 0.04, 2);
    let (final_rel, largest_rel, worst) = against_lac(&trajectory);
    println!(
        "final Δy {:+.1} %, largest Δy {:+.1} %, worst point {worst:.3} (2a)",
        100.0 * final_rel,
        100.0 * largest_rel
    );
    // The issue's band is 10 % on the final separation; measured +2.1 % (largest +1.2 %,
    // worst point 0.017).
    assert!(final_rel.abs() < 0.05, "{final_rel}");
    assert!(largest_rel.abs() < 0.05, "{largest_rel}");
    assert!(worst < 0.04, "{worst}");
    // Without the interaction the offset would stay 0.25: the pair moved apart by ~0.3 (2a).
    assert!(separation_at(&trajectory, 5.0) > 0.5);
}

/// The same pair at p = 8 and 12 (`cargo test --release --test capsule -- --ignored`), the
/// numbers of docs/capsules.md.
#[test]
#[ignore]
fn two_capsules_in_shear_against_lac_at_higher_orders() {
    for (p, dt) in [(6, 0.04), (8, 0.02), (12, 0.01)] {
        let trajectory = lac_pair_trajectory(p, dt, (0.08 / dt) as usize);
        let (final_rel, largest_rel, worst) = against_lac(&trajectory);
        let peak = trajectory
            .iter()
            .fold((0.0, 0.0), |m, s| if s.1 > m.1 { *s } else { m });
        println!(
            "p = {p}, dt = {dt}: final Δy/2a {:.4} ({:+.1} %), largest {:.4} at Δx/2a {:.2} \
             ({:+.1} %), worst point {worst:.3}",
            separation_at(&trajectory, LAC_FIG_4B[15].0),
            100.0 * final_rel,
            peak.1,
            peak.0,
            100.0 * largest_rel
        );
        assert!(final_rel.abs() < 0.05 && worst < 0.05);
    }
}

//! Hard cases: scenes that stress the numerics, each run with per-step checks and a pass
//! criterion; short versions run by default (release: about a minute or two on 2 cores), long
//! versions are `#[ignore]`d and run by `scripts/hard_cases.sh`, which writes the measured
//! numbers to `docs/hard_cases.md`.
//!
//! Every case steps a [`Suspension`] built by `run::assembly::build` (the settings of `mobo run`) and
//! checks after each step: finite SH coefficients and tension, area and volume drift of every
//! cell against the start, the speed of every centroid against a bound, and (where asked) that
//! no grid point of one cell lies inside another cell (`OffSurface::classify`, exact closest
//! point in the near zone) and the smallest such distance. A failed check stops the case with
//! a message naming the case, step, time, cell and quantity.
//!
//! Each test prints one `| case | ... |` line with its measured numbers.

use mobo::run::assembly::build;
use mobo::scene::cells::{parse, CellScene};
use mobo::timestep::coupling::{Coupling, CouplingParams};

mod common;
use common::quadrature::{max_rel, reference};
use mobo::sph_harmonics::Grid;
use mobo::timestep::suspension::Suspension;
use mobo::vesicle::{NearParams, OffSurface, SurfaceCalculus};
use std::path::Path;

fn scene(text: &str) -> CellScene {
    parse(std::path::Path::new("<hard case>"), text).expect("valid hard-case scene")
}

/// What to check besides finiteness and drift.
#[derive(Clone, Copy)]
struct Checks {
    /// Largest allowed area or volume drift (relative to the start).
    drift: f64,
    /// Largest allowed centroid speed.
    speed: f64,
    /// Check overlap and gaps every this many steps (`None`: never).
    contact_every: Option<usize>,
}

/// What a case measured.
#[derive(Clone, Debug, Default)]
struct Outcome {
    steps: usize,
    max_area_drift: f64,
    max_volume_drift: f64,
    max_speed: f64,
    /// Smallest distance of a grid point of one cell to another cell's surface (checked steps).
    min_gap: f64,
    /// Smallest gap reported by the coupling's near-zone monitor.
    coupling_min_gap: f64,
    /// Grid quality: largest `max J / min J` (J = area element per unit solid angle) seen.
    max_grid_ratio: f64,
    initial_grid_ratio: f64,
    wall_s: f64,
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// `max J / min J` over the grid, `J = W / sin θ`.
fn grid_ratio(calc: &mut SurfaceCalculus, coefs: &[f64]) -> f64 {
    let g = calc.geometry(coefs).expect("geometry");
    let grid = Grid::new(calc.order());
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for (j, w) in g.w.iter().enumerate() {
        let j_elem = w / grid.angles(j).0.sin();
        lo = lo.min(j_elem);
        hi = hi.max(j_elem);
    }
    hi / lo
}

/// Smallest distance of a grid point of one cell to another's surface; `Err` on overlap.
fn contact<C: AsRef<[f64]>>(
    coefs: &[C],
    p: usize,
    case: &str,
    k: usize,
    t: f64,
) -> Result<f64, String> {
    let mut calc = SurfaceCalculus::new(p).unwrap();
    let mut near = OffSurface::new(p, NearParams::default()).unwrap();
    let centroids: Vec<[f64; 3]> = coefs
        .iter()
        .map(|c| calc.geometry(c.as_ref()).unwrap().centroid())
        .collect();
    let mut gap = f64::INFINITY;
    for (j, cj) in coefs.iter().enumerate() {
        near.set_surface(cj.as_ref()).unwrap();
        for (i, ci) in coefs.iter().enumerate() {
            // Far pairs (centroids more than 4 radii apart) cannot touch.
            if i == j || norm(std::array::from_fn(|d| centroids[i][d] - centroids[j][d])) > 4.0 {
                continue;
            }
            let g = calc.geometry(ci.as_ref()).unwrap();
            for (q, x) in g.x.iter().enumerate() {
                let info = near.classify(*x).unwrap();
                if info.inside {
                    return Err(format!(
                        "{case}: step {k} (t = {t:.4}), cell {}: overlap, grid point {q} lies \
                         inside cell {} (distance {:.3e})",
                        i, j, info.distance
                    ));
                }
                gap = gap.min(info.distance);
            }
        }
    }
    Ok(gap)
}

/// Step `susp` `steps` times in `scene`'s flow with the checks; the error names case, step,
/// cell and quantity.
fn run_case(
    case: &str,
    scene: &CellScene,
    susp: &mut Suspension,
    steps: usize,
    checks: Checks,
) -> Result<Outcome, String> {
    let start = std::time::Instant::now();
    let p = scene.numerics.order;
    let dt = scene.numerics.dt;
    let mut calc = SurfaceCalculus::new(p).unwrap();
    let mut start_obs = Vec::new();
    let mut centroids = Vec::new();
    let mut out = Outcome {
        min_gap: f64::INFINITY,
        coupling_min_gap: f64::INFINITY,
        ..Default::default()
    };
    for c in susp.coefs() {
        let g = calc.geometry(c).unwrap();
        start_obs.push((g.area(), g.volume()));
        centroids.push(g.centroid());
        out.initial_grid_ratio = out.initial_grid_ratio.max(grid_ratio(&mut calc, c));
    }
    out.max_grid_ratio = out.initial_grid_ratio;
    let flow = scene.flow;
    for k in 1..=steps {
        let t = k as f64 * dt;
        susp.step(&|x| flow.velocity(x)).map_err(|e| {
            format!(
                "{case}: step {k} (t = {t:.4}), cell {}: the step failed: {}",
                e.cell.map_or("-".into(), |c| c.to_string()),
                e.source
            )
        })?;
        out.steps = k;
        for (i, c) in susp.coefs().iter().enumerate() {
            if let Some(j) = c.iter().position(|v| !v.is_finite()) {
                return Err(format!(
                    "{case}: step {k} (t = {t:.4}), cell {}: non-finite SH coefficient {j}",
                    i
                ));
            }
            if let Some(j) = susp.cells()[i]
                .state
                .sigma
                .iter()
                .position(|v| !v.is_finite())
            {
                return Err(format!(
                    "{case}: step {k} (t = {t:.4}), cell {}: non-finite tension at grid point {j}",
                    i
                ));
            }
            let g = calc
                .geometry(c)
                .map_err(|e| format!("{case}: step {k} (t = {t:.4}), cell {}: geometry: {e}", i))?;
            let (a0, v0) = start_obs[i];
            let da = ((g.area() - a0) / a0).abs();
            let dv = ((g.volume() - v0) / v0).abs();
            out.max_area_drift = out.max_area_drift.max(da);
            out.max_volume_drift = out.max_volume_drift.max(dv);
            for (what, d) in [("area drift", da), ("volume drift", dv)] {
                if d > checks.drift {
                    return Err(format!(
                        "{case}: step {k} (t = {t:.4}), cell {}: {what} {d:.3e} above {:.1e}",
                        i, checks.drift
                    ));
                }
            }
            let x = g.centroid();
            let speed = norm(std::array::from_fn(|d| (x[d] - centroids[i][d]) / dt));
            centroids[i] = x;
            out.max_speed = out.max_speed.max(speed);
            if speed > checks.speed {
                return Err(format!(
                    "{case}: step {k} (t = {t:.4}), cell {}: centroid speed {speed:.3e} above {:.3e}",
                    i,
                    checks.speed
                ));
            }
            out.max_grid_ratio = out.max_grid_ratio.max(grid_ratio(&mut calc, c));
        }
        if let Some(st) = susp.coupling_stats() {
            out.coupling_min_gap = out.coupling_min_gap.min(st.min_gap);
        }
        if let Some(every) = checks.contact_every {
            if k % every == 0 || k == steps {
                out.min_gap = out.min_gap.min(contact(&susp.coefs(), p, case, k, t)?);
            }
        }
    }
    out.wall_s = start.elapsed().as_secs_f64();
    Ok(out)
}

fn report(case: &str, o: &Outcome, extra: &str) {
    println!(
        "| {case} | {} | {:.2e} | {:.2e} | {:.3} | {} | {:.3} → {:.3} | {:.1} | {extra} |",
        o.steps,
        o.max_area_drift,
        o.max_volume_drift,
        o.max_speed,
        if o.min_gap.is_finite() {
            format!("{:.4}", o.min_gap)
        } else {
            "–".into()
        },
        o.initial_grid_ratio,
        o.max_grid_ratio,
        o.wall_s
    );
}

// ---------------------------------------------------------------------------------------------
// Near contact.

const TWO_RBCS: &str = r#"
[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "rbc"
radius = 1.0
bending_modulus = 0.1
center = [-5.0, 0.0, 0.0]
orientation = [1, 0, 0, 90]
[[cells]]
shape = "rbc"
radius = 1.0
bending_modulus = 0.1
center = [5.0, 0.0, 0.0]
orientation = [1, 0, 0, 90]
[numerics]
order = 8
dt = 0.02
t_end = 1.0
gmres_tol = 1e-10
# The near-contact cases start 0.03 apart: no contact projection (its default d_min is 0.05).
contact_distance = 0
"#;

/// Two RBCs, discs in the x–z plane, stacked in the shear direction y with the top one shifted
/// back in x: the shear slides them across each other. The y offset is chosen (bisection on the
/// measured gap) so that the surfaces start `gap` apart.
fn near_contact_scene(p: usize, gap: f64) -> CellScene {
    let mut sc = scene(TWO_RBCS);
    sc.numerics.order = p;
    let measure = |h: f64| {
        let mut s = sc.clone();
        s.cells[0].center = [-0.8, h, 0.0];
        s.cells[1].center = [0.8, -h, 0.0];
        let coefs: Vec<Vec<f64>> = s
            .cells
            .iter()
            .map(|c| c.surface(p).unwrap().coefs().to_vec())
            .collect();
        contact(&coefs, p, "placement", 0, 0.0).map_or(-1.0, |g| g)
    };
    let (mut lo, mut hi) = (0.3, 1.5);
    for _ in 0..20 {
        let mid = 0.5 * (lo + hi);
        if measure(mid) < gap {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    sc.cells[0].center = [-0.8, hi, 0.0];
    sc.cells[1].center = [0.8, -hi, 0.0];
    sc
}

fn near_contact(case: &str, steps: usize) {
    let gap0 = 0.03;
    let sc = near_contact_scene(8, gap0);
    let mut susp = build(&sc).unwrap();
    let g0 = contact(&susp.coefs(), 8, case, 0, 0.0).unwrap();
    assert!(
        g0 < 0.05,
        "{case}: initial gap {g0} not below 5% of the radius"
    );
    let checks = Checks {
        drift: 1e-3,
        // Shear speed at the cells' extent (|y| ≲ 2) with room for the relative motion.
        speed: 4.0,
        contact_every: Some(1),
    };
    let o = run_case(case, &sc, &mut susp, steps, checks).unwrap_or_else(|e| panic!("{e}"));
    report(case, &o, &format!("initial gap {g0:.4}"));
}

#[test]
fn near_contact_two_rbcs_in_shear_short() {
    near_contact("near contact (short, 25 steps)", 25);
}

#[test]
#[ignore = "long version (scripts/hard_cases.sh)"]
fn near_contact_two_rbcs_in_shear_long() {
    near_contact("near contact (long, 150 steps)", 150);
}

/// Near-singular accuracy at a gap of 3% of the radius, against a higher-resolution evaluation
/// of the same physics: the two RBCs are placed 0.03 apart and stepped once (p = 8, solved
/// tension); then the inter-cell velocity the coupling computes from their membrane tractions
/// (FMM over the order-16 quadrature + near-singular corrections, as in every step) is compared
/// with a direct smooth quadrature of the same tractions at order `Q` (spacing `h` a fraction
/// of the gap; `Q = 320` against `Q = 384` shows how far the reference itself is converged).
/// The same coupling without near-singular corrections is measured too: the correction is what
/// makes the near-contact velocity right. Measured: 5.9e-6 relative to the largest velocity
/// (7.7e-2 without corrections); it was 1.1e-2 with the check-point interpolation alone, before
/// `OffSurface` got its refined quadratures. What is left is the order-16 (`upsample = 2`)
/// quadrature just outside the near zone, the near evaluation itself is at 2e-7.
///
/// (Comparing whole runs at p = 8 and p = 16 instead mixes in how differently the two orders
/// resolve the RBC's bending traction: measured 65% apart at this gap and 17% at gap 0.5.)
#[test]
fn near_contact_coupling_against_a_fine_quadrature() {
    let p = 8;
    let sc = near_contact_scene(p, 0.03);
    let mut susp = build(&sc).unwrap();
    let flow = sc.flow;
    susp.step(&|x| flow.velocity(x)).unwrap();
    let coefs: Vec<Vec<f64>> = susp.coefs().iter().map(|c| c.to_vec()).collect();
    let gap = contact(&susp.coefs(), p, "near-contact coupling", 1, sc.numerics.dt).unwrap();
    let n = susp.steppers()[0].n_points();
    let f: Vec<Vec<f64>> = (0..coefs.len())
        .map(|i| {
            let mut f = vec![0.0; 3 * n];
            let cell = &susp.cells()[i];
            assert_eq!(cell.state.coefs, coefs[i]);
            cell.stepper.traction(&cell.state, &mut f).unwrap();
            f
        })
        .collect();
    let mu = sc.viscosity;
    let cref: Vec<&[f64]> = coefs.iter().map(|c| c.as_slice()).collect();
    let fref: Vec<&[f64]> = f.iter().map(|c| c.as_slice()).collect();
    let coupled = |near_factor: f64| {
        let mut c = Coupling::new(
            p,
            sc.numerics.upsample * p,
            CouplingParams {
                viscosity: mu,
                // Beyond the scene's 6 digits, so that the FMM does not hide the near-singular
                // error (the FMM's own accuracy is tested in fmm_accuracy.rs).
                fmm_digits: 9,
                near_factor,
                ..Default::default()
            },
        )
        .unwrap();
        let u = c.velocities(&cref, &fref).unwrap();
        (u, c.stats.near_points)
    };
    let (u, near_points) = coupled(CouplingParams::default().near_factor);
    let (u_plain, none) = coupled(1e-9);
    assert_eq!(none, 0);
    let fine = reference(p, 320, &coefs, &f, mu);
    let finer = reference(p, 384, &coefs, &f, mu);
    let (e_ref, e, e_plain) = (
        max_rel(&fine, &finer),
        max_rel(&u, &finer),
        max_rel(&u_plain, &finer),
    );
    println!(
        "| near-contact coupling | gap {gap:.4} after one step, {near_points} near points: error \
         {e:.2e} with near-singular corrections, {e_plain:.2e} without; reference Q = 320 vs 384 \
         {e_ref:.1e} |"
    );
    assert!(gap < 0.05, "gap {gap}");
    assert!(near_points > 0);
    assert!(
        e_ref < 0.1 * e.max(1e-8),
        "reference not converged: {e_ref:.2e} vs {e:.2e}"
    );
    assert!(e < 1e-5, "near-contact inter-cell velocity error {e:.2e}");
    assert!(
        e_plain > 10.0 * e,
        "the corrections matter: {e_plain:.2e} vs {e:.2e}"
    );
}

// ---------------------------------------------------------------------------------------------
// High shear rate at the largest stable dt.

const ONE_RBC: &str = r#"
[flow]
kind = "shear"
rate = 10.0
[[cells]]
shape = "rbc"
radius = 1.0
bending_modulus = 0.1
orientation = [0, 1, 0, 30]
[numerics]
order = 8
dt = 0.05
t_end = 1.0
gmres_tol = 1e-8
"#;

/// Capillary number 10× the demo's (shear rate 10 instead of 1, same bending modulus): the
/// largest dt in 0.025·2^k (up to 1.6) that runs 0.5 strain units within the checks is found (the
/// first failure is reported), then the cell
/// is run over 5 strain units (short) at that dt: no blow-up, drift below 1e-3.
fn high_shear(case: &str, strain: f64) {
    let base = scene(ONE_RBC);
    let rate = 10.0;
    let checks = Checks {
        drift: 1e-3,
        speed: 10.0 * rate,
        contact_every: None,
    };
    // Largest dt = 0.025·2^k (k = 0..6) that runs 0.5 strain units within the checks.
    let mut tried = Vec::new();
    let mut stable = None;
    for k in 0..7 {
        let dt = 0.025 * f64::from(1u32 << k);
        let mut sc = base.clone();
        sc.numerics.dt = dt;
        let mut susp = build(&sc).unwrap();
        let steps = ((0.5 / rate) / dt).ceil() as usize;
        match run_case(case, &sc, &mut susp, steps.max(2), checks) {
            Ok(_) => stable = Some(dt),
            Err(e) => {
                tried.push(format!("dt = {dt}: {e}"));
                break;
            }
        }
    }
    let stable = stable.unwrap_or_else(|| panic!("{case}: no stable dt: {tried:?}"));
    let mut sc = base.clone();
    sc.numerics.dt = stable;
    let mut susp = build(&sc).unwrap();
    let steps = ((strain / rate) / stable).round() as usize;
    let o = run_case(case, &sc, &mut susp, steps, checks).unwrap_or_else(|e| panic!("{e}"));
    report(
        case,
        &o,
        &format!(
            "largest stable dt {stable} (next refused: {})",
            if tried.is_empty() {
                "none up to 1.6".to_string()
            } else {
                tried.join("; ").replace('|', "/")
            }
        ),
    );
}

#[test]
fn high_shear_rate_at_largest_stable_dt_short() {
    high_shear("high shear γ̇ = 10 (short, 5 strain units)", 5.0);
}

#[test]
#[ignore = "long version (scripts/hard_cases.sh)"]
fn high_shear_rate_at_largest_stable_dt_long() {
    high_shear("high shear γ̇ = 10 (long, 50 strain units)", 50.0);
}

// ---------------------------------------------------------------------------------------------
// Long run of a vesicle in shear.

const VESICLE: &str = r#"
[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "prolate"
reduced_volume = 0.9
radius = 1.0
bending_modulus = 0.1
orientation = [0, 0, 1, 30]
[numerics]
order = 6
dt = 0.05
t_end = 1.0
gmres_tol = 1e-8
"#;

/// A prolate vesicle (v = 0.9, p = 6, dt = 0.05) in shear: no NaN, drift below 1e-3, and the
/// reparametrisation keeps the grid: `max J / min J` never above twice its initial value.
fn long_vesicle(case: &str, steps: usize) {
    let sc = scene(VESICLE);
    let mut susp = build(&sc).unwrap();
    let checks = Checks {
        drift: 1e-3,
        speed: 5.0,
        contact_every: None,
    };
    let o = run_case(case, &sc, &mut susp, steps, checks).unwrap_or_else(|e| panic!("{e}"));
    report(case, &o, "");
    assert!(
        o.max_grid_ratio <= 2.0 * o.initial_grid_ratio,
        "{case}: grid quality max J / min J grew from {:.3} to {:.3}",
        o.initial_grid_ratio,
        o.max_grid_ratio
    );
}

#[test]
fn long_vesicle_in_shear_short() {
    long_vesicle("vesicle in shear (short, 500 steps)", 500);
}

#[test]
#[ignore = "long version (scripts/hard_cases.sh): 10^4 steps"]
fn long_vesicle_in_shear_long() {
    long_vesicle("vesicle in shear (long, 10000 steps)", 10_000);
}

// ---------------------------------------------------------------------------------------------
// Deflated shapes and viscosity contrast.

/// An oblate vesicle of reduced volume 0.6 and an RBC (v ≈ 0.64), each alone in shear
/// (p = 8, dt = 0.05): no blow-up, drift below 1e-3, reduced volume kept within 1e-3.
fn deflated(case: &str, shape: &str, steps: usize) {
    let text = VESICLE
        .replace("shape = \"prolate\"", shape)
        .replace("reduced_volume = 0.9\n", "")
        .replace("order = 6", "order = 8");
    let sc = scene(&text);
    let mut susp = build(&sc).unwrap();
    let mut calc = SurfaceCalculus::new(8).unwrap();
    let v0 = calc
        .geometry(&susp.cells()[0].state.coefs)
        .unwrap()
        .reduced_volume();
    let checks = Checks {
        drift: 1e-3,
        speed: 5.0,
        contact_every: None,
    };
    let o = run_case(case, &sc, &mut susp, steps, checks).unwrap_or_else(|e| panic!("{e}"));
    let v1 = calc
        .geometry(&susp.cells()[0].state.coefs)
        .unwrap()
        .reduced_volume();
    report(case, &o, &format!("reduced volume {v0:.4} → {v1:.4}"));
    assert!(
        (v1 - v0).abs() < 1e-3,
        "{case}: reduced volume moved from {v0} to {v1}"
    );
}

#[test]
fn deflated_shapes_short() {
    deflated(
        "oblate v = 0.6 (short, 40 steps)",
        "shape = \"oblate\"\nreduced_volume = 0.6",
        40,
    );
    deflated("RBC v ≈ 0.64 (short, 40 steps)", "shape = \"rbc\"", 40);
}

#[test]
#[ignore = "long version (scripts/hard_cases.sh)"]
fn deflated_shapes_long() {
    deflated(
        "oblate v = 0.6 (long, 400 steps)",
        "shape = \"oblate\"\nreduced_volume = 0.6",
        400,
    );
    deflated("RBC v ≈ 0.64 (long, 400 steps)", "shape = \"rbc\"", 400);
}

/// Viscosity contrast λ = 10: a prolate vesicle (v = 0.9) with its long axis in the shear
/// plane tumbles (its inclination turns through ±90° and on, clockwise) instead of
/// tank-treading at a fixed angle.
///
/// `VESICLE`'s own orientation, a turn about the vorticity axis `z`, leaves the prolate's axis
/// along `z`: the in-plane angle of that axis is then the ratio of two round-off values, and an
/// earlier version of this test, which measured it, passed or failed with the rounding of the
/// build. Here the axis is turned into the shear plane at 30° from the flow, so the angle is
/// well defined (the long axis's moment stays below the other two by a factor of two). The
/// motion is resolved in time: at dt = 0.05 and 0.025 the inclination agrees to about 1° over
/// a whole tumble (period ≈ 12 shear times).
#[test]
fn viscosity_contrast_ten_tumbles() {
    let text = VESICLE
        .replace(
            "bending_modulus = 0.1",
            "bending_modulus = 0.1\nviscosity_ratio = 10.0",
        )
        .replace(
            "orientation = [0, 0, 1, 30]",
            "orientation = [-0.5, 0.8660254037844386, 0, 90]",
        );
    let sc = scene(&text);
    let mut susp = build(&sc).unwrap_or_else(|e| panic!("{e}"));
    let checks = Checks {
        drift: 1e-3,
        speed: 5.0,
        contact_every: None,
    };
    let mut calc = SurfaceCalculus::new(6).unwrap();
    let inclination = |calc: &mut SurfaceCalculus, coefs: &[f64]| {
        let (moments, axes) = calc.geometry(coefs).unwrap().principal_axes();
        assert!(
            moments[0] < 0.75 * moments[1] && axes[0][2].abs() < 0.1,
            "λ = 10: the long axis is not well defined or not in the shear plane (moments \
             {moments:?}, axis {:?})",
            axes[0]
        );
        (axes[0][1] / axes[0][0]).atan().to_degrees()
    };
    let start = inclination(&mut calc, &susp.cells()[0].state.coefs);
    assert!((start - 30.0).abs() < 1.0, "initial inclination {start}°");
    // The inclination unwrapped (modulo 180°): its total turn after 12 shear times.
    let (mut last, mut turned) = (start, 0.0);
    let (mut min, mut max) = (f64::INFINITY, f64::NEG_INFINITY);
    for _ in 0..48 {
        run_case("λ = 10", &sc, &mut susp, 5, checks).unwrap_or_else(|e| panic!("{e}"));
        let a = inclination(&mut calc, &susp.cells()[0].state.coefs);
        let mut d = a - last;
        if d > 90.0 {
            d -= 180.0;
        } else if d < -90.0 {
            d += 180.0;
        }
        turned += d;
        last = a;
        min = min.min(a);
        max = max.max(a);
    }
    assert!(
        min < -45.0 && max > 45.0,
        "λ = 10: inclination stayed in [{min:.1}, {max:.1}]°, no tumbling"
    );
    assert!(
        turned < -120.0,
        "λ = 10: the long axis turned by {turned:.1}° in 12 shear times (a tumble turns it \
         clockwise through 180° per period)"
    );
}

// ---------------------------------------------------------------------------------------------
// Dense suspension.

/// RBCs (discs in the x–y plane) on an `nx × ny × nz` lattice with spacing (3.0, 3.0, 1.3) in
/// shear: the cells fill `N · 4π/3 / (N · 3.0 · 3.0 · 1.3)` = 36% of their lattice cells. No
/// overlap, drift below 1e-3, bounded speed.
fn dense(case: &str, n: [usize; 3], p: usize, steps: usize) {
    let spacing = [3.0, 3.0, 1.3];
    let mut text = String::from("[flow]\nkind = \"shear\"\nrate = 1.0\n");
    let count = n[0] * n[1] * n[2];
    for i in 0..count {
        text.push_str(&format!(
            "[[cells]]\nshape = \"rbc\"\nradius = 1.0\nbending_modulus = 0.1\ncenter = [{}, 0, 0]\n",
            10.0 * i as f64
        ));
    }
    text.push_str(&format!(
        "[numerics]\norder = {p}\ndt = 0.05\nt_end = 1.0\ngmres_tol = 1e-8\n"
    ));
    let mut sc = scene(&text);
    // Placed after parsing: the scene's bounding-sphere check would refuse this packing.
    let mut c = 0;
    for i in 0..n[0] {
        for j in 0..n[1] {
            for k in 0..n[2] {
                sc.cells[c].center = [
                    (i as f64 - 0.5 * (n[0] - 1) as f64) * spacing[0],
                    (j as f64 - 0.5 * (n[1] - 1) as f64) * spacing[1],
                    (k as f64 - 0.5 * (n[2] - 1) as f64) * spacing[2],
                ];
                c += 1;
            }
        }
    }
    let fraction = (4.0 * std::f64::consts::PI / 3.0) / (spacing[0] * spacing[1] * spacing[2]);
    assert!(fraction >= 0.2);
    let mut susp = build(&sc).unwrap();
    let ymax = 0.5 * (n[1] - 1) as f64 * spacing[1] + 1.5;
    let checks = Checks {
        drift: 1e-3,
        speed: 2.0 * ymax,
        contact_every: Some(5),
    };
    let o = run_case(case, &sc, &mut susp, steps, checks).unwrap_or_else(|e| panic!("{e}"));
    report(
        case,
        &o,
        &format!("{count} cells, volume fraction {:.0}%", 100.0 * fraction),
    );
}

#[test]
fn dense_suspension_short() {
    dense("dense 2×1×2 (short, 10 steps)", [2, 1, 2], 6, 10);
}

#[test]
#[ignore = "long version (scripts/hard_cases.sh)"]
fn dense_suspension_long() {
    dense("dense 3×3×3 (long, 40 steps)", [3, 3, 3], 6, 40);
}

// ---------------------------------------------------------------------------------------------
// NaN/Inf guard through `mobo run`.

/// A scene that diverges: an RBC whose shear elasticity (explicit in the scheme) is far too
/// stiff for the time step. `mobo run` must stop with an error that names the step, the cell
/// and the quantity, exit non-zero, and keep a readable last checkpoint from an earlier step.
#[test]
fn divergence_names_step_cell_quantity_and_keeps_the_checkpoint() {
    let dir = std::env::temp_dir().join(format!("mobo-hard-diverge-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("diverge.toml");
    std::fs::write(&scene, DIVERGING).unwrap();
    let out = dir.join("out");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_mobo"))
        .args(["run", scene.to_str().unwrap(), "--out"])
        .arg(&out)
        .arg("--quiet")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "the diverging run succeeded: {stderr}");
    assert!(
        !stderr.contains("panicked"),
        "a panic instead of an error: {stderr}"
    );
    // "step N (t = T), cell C: <quantity> ..."
    let at = stderr
        .find("step ")
        .unwrap_or_else(|| panic!("no step in: {stderr}"));
    let rest = &stderr[at + 5..];
    let step: usize = rest
        .split(|c: char| !c.is_ascii_digit())
        .next()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no step number in: {stderr}"));
    assert!(rest.contains("(t = "), "no time in: {stderr}");
    assert!(rest.contains(", cell 0: "), "no cell in: {stderr}");
    let quantity = rest.split(", cell 0: ").nth(1).unwrap_or("");
    assert!(
        [
            "coefficient",
            "tension",
            "gmres",
            "GMRES",
            "residual",
            "geometry",
            "area",
            "volume"
        ]
        .iter()
        .any(|q| quantity.contains(q)),
        "no quantity named in: {stderr}"
    );
    let ck = mobo::io::checkpoint::Checkpoint::read(&out.join("checkpoint.bin"))
        .unwrap_or_else(|e| panic!("the last checkpoint is not readable: {e}"));
    let ck_step = ck.meta["step"].as_u64().expect("checkpoint step") as usize;
    assert!(
        ck_step < step,
        "checkpoint step {ck_step} not before the failing step {step}"
    );
    let coefs = ck
        .arrays
        .iter()
        .find(|a| a.name == "coefs")
        .expect("coefs in the checkpoint");
    assert!(coefs.data.iter().all(|v| v.is_finite()));
    // What the failed run says: summary.json with the error and the last good step, and
    // observables.csv up to it.
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["completed"].as_bool(), Some(false), "{summary}");
    assert!(summary["error"]
        .as_str()
        .unwrap()
        .contains(&format!("step {step}")));
    assert_eq!(summary["last_good_step"].as_u64(), Some(step as u64 - 1));
    assert_eq!(
        summary["last_checkpoint_step"].as_u64(),
        Some(ck_step as u64)
    );
    let table = std::fs::read_to_string(out.join("observables.csv")).unwrap();
    let rows: Vec<&str> = table.lines().skip(1).collect();
    assert_eq!(rows.len(), step - 1, "{table}");
    assert!(rows.last().unwrap().starts_with(&format!("{},", step - 1)));
    println!(
        "| divergence guard | failed at step {step}, checkpoint at step {ck_step} | {} |",
        stderr.trim()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

const DIVERGING: &str = r#"
[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "rbc"
radius = 1.0
bending_modulus = 0.1
shear_modulus = 1e4
orientation = [0, 1, 0, 30]
[numerics]
order = 6
dt = 0.5
t_end = 50.0
gmres_tol = 1e-8
[output]
every = 1
npy = false
vtk = false
checkpoint_every = 1
"#;

// ---------------------------------------------------------------------------------------------
// Blood-like suspension: viscosity ratio 5 at 17 %.

/// `n³` RBCs (Skalak, shear modulus 1, bending 0.1) on a cubic lattice of spacing 2.9 (volume
/// fraction 17 %), turned 0.4° about (0.3, 1, 0.5), viscosity ratio `lambda`, in shear, BDF2 at
/// `Δt = 0.01`, coupled as `coupling` says.
fn blood_lattice(n: usize, p: usize, lambda: f64, coupling: &str, steps: usize) -> CellScene {
    let text = format!(
        r#"
[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "rbc"
radius = 1.0
count = {}
placement = "lattice"
spacing = 2.9
orientation = [0.3, 1.0, 0.5, 0.4]
bending_modulus = 0.1
shear_modulus = 1.0
viscosity_ratio = {lambda}
[numerics]
order = {p}
dt = 0.01
t_end = {}
scheme = "bdf2"
coupling = "{coupling}"
"#,
        n * n * n,
        0.01 * steps as f64
    );
    scene(&text)
}

/// The failure a blood case guards against: `scene` (explicit coupling) stops within `steps`
/// steps under loose checks (drift 1e-2, speed 100); the error is printed.
fn explicit_fails(case: &str, scene: &CellScene, steps: usize) {
    let mut susp = build(scene).unwrap();
    let loose = Checks {
        drift: 1e-2,
        speed: 100.0,
        contact_every: None,
    };
    let failed = run_case(case, scene, &mut susp, steps, loose);
    assert!(
        failed.is_err(),
        "{case}: the explicit coupling ran {steps} steps: the case no longer shows its failure"
    );
    println!("explicit coupling: {}", failed.unwrap_err());
}

fn blood_case(case: &str, n: usize, p: usize, lambda: f64, steps: usize) {
    let sc = blood_lattice(n, p, lambda, "near_implicit", steps);
    let mut susp = build(&sc).unwrap();
    let checks = Checks {
        drift: 1e-5,
        speed: 2.0 * 2.9 * n as f64,
        contact_every: Some(10),
    };
    let o = run_case(case, &sc, &mut susp, steps, checks).unwrap_or_else(|e| panic!("{e}"));
    let joint = susp.joint_stats();
    assert!(
        joint.clusters >= steps && joint.largest >= 2,
        "{case}: the near cells were not solved jointly: {joint:?}"
    );
    assert!(o.min_gap > 0.0, "{case}: surfaces crossed ({})", o.min_gap);
    report(
        case,
        &o,
        &format!(
            "{} cells, 17 %, λ = {lambda}, near-implicit: {:.1} joint GMRES iterations a step, \
             largest cluster {}",
            n * n * n,
            joint.iterations as f64 / steps as f64,
            joint.largest
        ),
    );
}

/// The failure this case guards against: with the explicit coupling, 8 RBCs at 17 % and
/// `λ = 5` stop within 40 steps (step 31, a cell's surface turned inside out: BDF2's
/// extrapolation of the near double layer has a gain above one); the near-implicit coupling
/// runs them on with drift below 1e-5 and no contact. (Run by `scripts/hard_cases.sh`: the
/// default suite has the denser `dense_packed_blood_at_30_percent_short` in its place.)
#[test]
#[ignore = "replaced in the default suite by dense_packed_blood_at_30_percent_short"]
fn blood_lambda_5_at_17_percent_short() {
    explicit_fails(
        "blood, explicit",
        &blood_lattice(2, 6, 5.0, "explicit", 40),
        40,
    );
    blood_case("blood 2×2×2, λ = 5, p = 6 (short, 50 steps)", 2, 6, 5.0, 50);
}

#[test]
#[ignore = "long version (scripts/hard_cases.sh): 27 cells, 2000 steps"]
fn blood_lambda_5_and_10_at_17_percent_long() {
    for lambda in [5.0, 10.0] {
        blood_case(
            &format!("blood 3×3×3, λ = {lambda}, p = 8 (long, 2000 steps)"),
            3,
            8,
            lambda,
            2000,
        );
    }
}

/// BDF2's order with the near-implicit coupling: the near-contact pair (two RBCs, bending 0.1,
/// sliding past each other in shear) with `λ = 5`, stepped to `t = 0.4` at
/// `Δt = 0.04 … 0.005` against `Δt = 0.0025`; the error is the largest centroid difference over
/// both cells (the grid's parametrisation depends on how many reparametrisations ran, so
/// coefficients are not compared). Prints one table per case: surfaces 0.8 and 0.1 apart, the
/// near-implicit and the explicit coupling (which fails 0.1 apart), with and without the
/// reparametrisation of every step, at p = 6 and 12. Passes when the near-implicit order
/// between the two largest steps is at least 1.7 in the cases where the grid is not
/// reparametrised, and at p = 12 with it. Measured 2026-12-04 (docs/hard_cases.md): without
/// reparametrisation, 0.1 apart, p = 6: 1.98, 1.99, 2.22; with it the reparametrisation's re-fit
/// of the moved grid at order p changes the shape at every call, which is first order at
/// p = 6 (1.22, 1.08, 1.13) and caps it as for one cell at p = 12 (1.95, 1.78, 1.39).
#[test]
#[ignore = "study (scripts/hard_cases.sh): BDF2 order of the near-implicit coupling"]
fn near_implicit_bdf2_order_in_a_pair_with_lambda_5() {
    use mobo::run::assembly::{build_part, setups};
    use mobo::timestep::near_implicit::CouplingMode;
    let study = |p: usize, gap: f64, coupling: CouplingMode, regrid: bool| -> Vec<f64> {
        let base = near_contact_scene(p, gap);
        let run = |dt: f64| -> Vec<Vec<f64>> {
            let mut sc = base.clone();
            sc.numerics.dt = dt;
            sc.numerics.t_end = 0.4;
            sc.numerics.scheme = mobo::scene::cells::Scheme::Bdf2;
            sc.numerics.gmres_tol = 1e-9;
            sc.numerics.coupling = coupling;
            // The RBCs have shear elasticity: relaxed only when asked (`[numerics] grid`).
            if regrid {
                sc.numerics.grid = mobo::scene::cells::GridMotion::Relaxed;
            }
            for c in &mut sc.cells {
                c.viscosity_ratio = 5.0;
            }
            let mut cells = setups(&sc).unwrap();
            if !regrid {
                for c in &mut cells {
                    c.params.reparametrize = None;
                }
            }
            let mut susp = build_part(&sc, &cells, &[0, 1]).unwrap();
            let steps = (0.4 / dt).round() as usize;
            for _ in 0..steps {
                susp.step(&|x| sc.flow.velocity(x)).unwrap();
            }
            if coupling == CouplingMode::NearImplicit {
                assert!(susp.joint_stats().clusters > 0, "the pair was never near");
            }
            let mut calc = SurfaceCalculus::new(p).unwrap();
            susp.coefs()
                .iter()
                .map(|c| calc.geometry(c).unwrap().centroid().to_vec())
                .collect()
        };
        let reference = run(0.0025);
        let dts = [0.04, 0.02, 0.01, 0.005];
        let errors: Vec<f64> = dts
            .iter()
            .map(|&dt| {
                run(dt)
                    .iter()
                    .zip(&reference)
                    .flat_map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs()))
                    .fold(0.0, f64::max)
            })
            .collect();
        println!("\np = {p}, gap {gap}, {coupling:?} coupling, λ = 5, reparametrised: {regrid}");
        println!("| Δt | centroid error against Δt = 0.0025 | order |");
        println!("|---|---|---|");
        for (k, (&dt, &e)) in dts.iter().zip(&errors).enumerate() {
            let order = if k == 0 {
                "–".to_string()
            } else {
                format!("{:.2}", (errors[k - 1] / e).log2())
            };
            println!("| {dt} | {e:.3e} | {order} |");
        }
        errors
    };
    let first = |e: &[f64]| (e[0] / e[1]).log2();
    let mut second_order = Vec::new();
    for gap in [0.8, 0.1] {
        second_order.push((gap, false, study(6, gap, CouplingMode::NearImplicit, false)));
        study(6, gap, CouplingMode::NearImplicit, true);
    }
    study(6, 0.8, CouplingMode::Explicit, true);
    study(6, 0.8, CouplingMode::Explicit, false);
    second_order.push((0.1, true, study(12, 0.1, CouplingMode::NearImplicit, true)));
    for (gap, regrid, e) in second_order {
        let order = first(&e);
        assert!(
            order >= 1.7,
            "gap {gap}, reparametrised {regrid}: order {order:.2} between Δt = 0.04 and 0.02"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Dense blood: packed RBCs at 30 % and 45 %, viscosity ratio 5, contacts.

/// `count` RBCs (Skalak, shear modulus 1, bending 0.1, `λ = 5`) packed at volume fraction `phi`
/// with surfaces `gap` apart (`placement = "packed"`), in shear, BDF2 at `Δt = 0.01`, coupled as
/// `coupling` says, the contact projection keeping `gap` at the end of every step.
fn packed_blood(
    count: usize,
    phi: f64,
    gap: f64,
    p: usize,
    coupling: &str,
    steps: usize,
) -> CellScene {
    let text = format!(
        r#"
[flow]
kind = "shear"
rate = 1.0
[[cells]]
shape = "rbc"
count = {count}
placement = "packed"
volume_fraction = {phi}
min_gap = {gap}
seed = 7
bending_modulus = 0.1
shear_modulus = 1.0
viscosity_ratio = 5.0
[numerics]
order = {p}
dt = 0.01
t_end = {}
scheme = "bdf2"
coupling = "{coupling}"
contact_distance = {gap}
"#,
        0.01 * steps as f64
    );
    scene(&text)
}

/// The packed suspension stepped with the near-implicit coupling and contacts: no overlap at
/// the checked steps (independent closest points), the contact projection's end-of-step gap
/// never below `gap`, drift within `drift`.
fn dense_blood_case(
    case: &str,
    count: usize,
    phi: f64,
    gap: f64,
    p: usize,
    steps: usize,
    drift: f64,
) {
    let sc = packed_blood(count, phi, gap, p, "near_implicit", steps);
    let mut susp = build(&sc).unwrap();
    let checks = Checks {
        drift,
        speed: 50.0,
        contact_every: Some(10),
    };
    let o = run_case(case, &sc, &mut susp, steps, checks).unwrap_or_else(|e| panic!("{e}"));
    let contacts = susp.contact_stats();
    assert_eq!(
        contacts.steps, steps,
        "{case}: the projection ran every step"
    );
    let least = contacts.smallest_gap.unwrap_or(f64::INFINITY);
    assert!(
        least >= gap,
        "{case}: a step ended {least} apart (d_min {gap})"
    );
    assert!(o.min_gap > 0.0, "{case}: surfaces crossed ({})", o.min_gap);
    let joint = susp.joint_stats();
    report(
        case,
        &o,
        &format!(
            "{count} cells packed at {:.0} %, λ = 5, near-implicit + contacts (d_min {gap}): \
             {:.1} joint GMRES iterations a step, largest cluster {}, contact moves in {} of {} \
             steps ({} cell moves), smallest end-of-step gap {least:.4}, contacts {:.1} % of the \
             time",
            100.0 * phi,
            joint.iterations as f64 / steps as f64,
            joint.largest,
            contacts.steps_with_moves,
            steps,
            contacts.moves,
            100.0 * contacts.seconds / o.wall_s.max(1e-9)
        ),
    );
}

/// 8 RBCs packed at 30 %, `λ = 5`, p = 6: the explicit coupling fails within 40 steps; the
/// near-implicit coupling with contacts runs 40 steps with no step ending closer than 0.05.
#[test]
fn dense_packed_blood_at_30_percent_short() {
    explicit_fails(
        "dense 30 %, explicit",
        &packed_blood(8, 0.3, 0.05, 6, "explicit", 40),
        40,
    );
    dense_blood_case(
        "dense 8 RBCs, 30 %, λ = 5, p = 6 (short, 40 steps)",
        8,
        0.3,
        0.05,
        6,
        40,
        1e-5,
    );
}

/// The dense set of `docs/hard_cases.md`: 16 RBCs at 30 % (gaps 0.05) and at 45 % (gaps 0.02: 16
/// cells jam at about 42 % with 0.05, the cube's faces taking a large share), p = 8.
#[test]
#[ignore = "long version (scripts/hard_cases.sh): 16 cells at 30 % and 45 %, 300 steps each"]
fn dense_packed_blood_at_30_and_45_percent_long() {
    dense_blood_case(
        "dense 16 RBCs, 30 %, λ = 5, p = 8 (long)",
        16,
        0.3,
        0.05,
        8,
        300,
        1e-5,
    );
    dense_blood_case(
        "dense 16 RBCs, 45 %, λ = 5, p = 8 (long)",
        16,
        0.45,
        0.02,
        8,
        300,
        1e-5,
    );
}

/// `mobo run --resume` of `tests/data/<checkpoint>` with `scene` in the folder `out`: the
/// process's output and its `observables.csv` (empty when none was written).
fn resume_data_checkpoint(
    out: &Path,
    checkpoint: &str,
    scene: &str,
) -> (std::process::Output, String) {
    std::fs::create_dir_all(out).unwrap();
    let data = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(checkpoint);
    std::fs::copy(data, out.join("checkpoint.bin")).unwrap();
    std::fs::write(out.join("scene.toml"), scene).unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_mobo"))
        .args(["run", "--quiet", "--resume"])
        .arg(out)
        .output()
        .unwrap();
    let table = std::fs::read_to_string(out.join("observables.csv")).unwrap_or_default();
    (o, table)
}

/// A red blood cell pressed out of shape by its neighbours in a dense suspension, alone in
/// shear (`tests/data/rbc_pressed_p8.ckpt`: cell 11 of the 27-cell lattice at 17 %, `λ = 5`,
/// p = 8, at step 690; docs/hard_cases.md). With its grid relaxed after every step, the
/// relabelling of its Skalak reference by a re-fit at order 8 feeds the explicit elastic force,
/// and the cell blows up within the 40 steps (inside the 27-cell run at step 706; alone at step
/// 705 while the local area relaxation closed its whole gap every step, at 713 with its rate of
/// 10 per time unit). With its grid on its material points (`[numerics] grid = "auto"`, the
/// default for a cell with shear elasticity) it runs on, its area/volume error before
/// correction at the level of the steps before (4.2e-4 with the whole gap closed every step,
/// 7.7e-5 with the rate).
#[test]
fn pressed_rbc_runs_with_its_grid_on_its_material_points() {
    let dir = std::env::temp_dir().join(format!("mobo-hard-pressed-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let scene = |grid: &str| {
        format!(
            "[flow]\nkind = \"shear\"\nrate = 1.0\n[[cells]]\nshape = \"rbc\"\n\
             bending_modulus = 0.1\nshear_modulus = 1.0\nviscosity_ratio = 5.0\n[numerics]\n\
             order = 8\ndt = 0.01\nt_end = 7.3\nscheme = \"bdf2\"\ngrid = \"{grid}\"\n\
             [output]\nevery = 1000\nnpy = false\nvtk = false\n"
        )
    };
    let run = |grid: &str| {
        let (o, table) =
            resume_data_checkpoint(&dir.join(grid), "rbc_pressed_p8.ckpt", &scene(grid));
        // Step and area/volume error before correction of every step taken here.
        let rows: Vec<(usize, f64)> = table
            .lines()
            .skip(1)
            .map(|l| {
                let f: Vec<&str> = l.split(',').collect();
                (f[0].parse().unwrap(), f[6].parse().unwrap())
            })
            .collect();
        (o, rows)
    };
    let (relaxed, _) = run("relaxed");
    let stderr = String::from_utf8_lossy(&relaxed.stderr);
    assert!(!relaxed.status.success(), "the relaxed grid ran through");
    assert!(
        stderr.contains("enclosed volume") && !stderr.contains("panicked"),
        "{stderr}"
    );
    let failed_at: usize = stderr
        .split("step ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no step in: {stderr}"));
    assert!((691..=730).contains(&failed_at), "{stderr}");
    let (auto, rows) = run("auto");
    assert!(
        auto.status.success(),
        "{}",
        String::from_utf8_lossy(&auto.stderr)
    );
    assert_eq!(rows.len(), 40, "steps 691-730");
    let worst = rows.iter().map(|r| r.1).fold(0.0, f64::max);
    assert!(
        worst < 1e-3,
        "area/volume error before correction {worst:.2e}"
    );
    println!(
        "| pressed RBC, p = 8, λ = 5 | relaxed grid fails at step {failed_at} | material grid: \
         40 steps, largest area/volume error before correction {worst:.2e} |"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Three RBCs of a row of the 27-cell lattice at 17 % with `λ = 10`, pressed to gaps of 0.056
/// and 0.061 (`tests/data/rbc_row_lambda10_p8.ckpt`, step 300; docs/hard_cases.md). Without a
/// contact distance (`contact_distance = 0`) a mode that alternates between steps closes the
/// gaps and a cell turns inside out within 15 steps (the 27 cells did so at step 310). With the
/// scene's default (`d_min = 0.4 R/p = 0.05`, `scene::dense_defaults`) the row runs on and
/// every end-of-step gap is at least `d_min` (measured: fails at step 314; 20 steps, smallest
/// end-of-step gap 0.0526). About 70 s beside the suite's 20 minutes: ignored.
#[test]
#[ignore]
fn pressed_row_at_lambda_10_runs_with_the_default_contacts() {
    let dir = std::env::temp_dir().join(format!("mobo-hard-row10-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let scene = |extra: &str| {
        format!(
            "[flow]\nkind = \"shear\"\nrate = 1.0\n[[cells]]\nshape = \"rbc\"\ncount = 3\n\
             placement = \"lattice\"\nspacing = 2.9\nbending_modulus = 0.1\n\
             shear_modulus = 1.0\nviscosity_ratio = 10.0\n[numerics]\norder = 8\ndt = 0.01\n\
             t_end = 3.2\nscheme = \"bdf2\"\n{extra}\n[output]\nevery = 1000\nnpy = false\n\
             vtk = false\n"
        )
    };
    let run = |name: &str, extra: &str| {
        let (o, table) =
            resume_data_checkpoint(&dir.join(name), "rbc_row_lambda10_p8.ckpt", &scene(extra));
        // Step and end-of-step gap (empty without contacts) of every step taken here.
        let rows: Vec<(usize, Option<f64>)> = table
            .lines()
            .skip(1)
            .map(|l| {
                let f: Vec<&str> = l.split(',').collect();
                (f[0].parse().unwrap(), f[7].parse().ok())
            })
            .collect();
        (o, rows)
    };
    let (bare, _) = run("none", "contact_distance = 0");
    let stderr = String::from_utf8_lossy(&bare.stderr);
    assert!(
        !bare.status.success(),
        "the row without contacts ran through"
    );
    assert!(
        stderr.contains("enclosed volume") || stderr.contains("non-finite"),
        "{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    let (with, rows) = run("default", "");
    assert!(
        with.status.success(),
        "{}",
        String::from_utf8_lossy(&with.stderr)
    );
    assert_eq!(rows.len(), 20, "steps 301-320");
    let smallest = rows
        .iter()
        .map(|r| r.1.expect("contacts on by default: an end gap every step"))
        .fold(f64::INFINITY, f64::min);
    assert!(smallest >= 0.05 - 1e-6, "end-of-step gap {smallest}");
    println!(
        "| RBC row, p = 8, λ = 10 | no contacts: fails ({}) | default contacts: 20 steps, \
         smallest end-of-step gap {smallest:.4} |",
        stderr.lines().last().unwrap_or("")
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The start-up before the first step (`timestep::suspension`'s start-up): a pair coupled
/// explicitly (two RBCs with `λ = 5`, 0.8 apart, sliding past each other in shear, p = 6, the
/// grid on its material points) is second order in `Δt` only when the first step couples a
/// consistent tension and double layer. Centroid errors at `t = 0.4` against `Δt = 0.0025`,
/// with the default start-up and with none (`σ⁰ = 0`, no double layer in the first step).
#[test]
fn start_up_makes_an_explicit_pair_second_order() {
    use mobo::run::assembly::{build_part, setups};
    use mobo::timestep::near_implicit::CouplingMode;
    let base = near_contact_scene(6, 0.8);
    let run = |dt: f64, passes: usize| -> (Vec<Vec<f64>>, Option<usize>) {
        let mut sc = base.clone();
        sc.numerics.dt = dt;
        sc.numerics.t_end = 0.4;
        sc.numerics.scheme = mobo::scene::cells::Scheme::Bdf2;
        sc.numerics.gmres_tol = 1e-10;
        sc.numerics.coupling = CouplingMode::Explicit;
        sc.numerics.start_up_passes = passes;
        for c in &mut sc.cells {
            c.viscosity_ratio = 5.0;
        }
        let mut cells = setups(&sc).unwrap();
        for c in &mut cells {
            c.params.reparametrize = None;
        }
        let mut susp = build_part(&sc, &cells, &[0, 1]).unwrap();
        for _ in 0..(0.4 / dt).round() as usize {
            susp.step(&|x| sc.flow.velocity(x)).unwrap();
        }
        let mut calc = SurfaceCalculus::new(6).unwrap();
        let centroids = susp
            .coefs()
            .iter()
            .map(|c| calc.geometry(c).unwrap().centroid().to_vec())
            .collect();
        (centroids, susp.start_up_report().map(|r| r.passes))
    };
    let dts = [0.04, 0.02, 0.01];
    let mut orders = Vec::new();
    for passes in [mobo::timestep::suspension::START_UP_PASSES, 0] {
        let (reference, _) = run(0.0025, passes);
        let mut errors = Vec::new();
        let mut used = Vec::new();
        for &dt in &dts {
            let (c, p) = run(dt, passes);
            used.push(p);
            errors.push(
                c.iter()
                    .zip(&reference)
                    .flat_map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs()))
                    .fold(0.0, f64::max),
            );
        }
        let o: Vec<f64> = errors.windows(2).map(|w| (w[0] / w[1]).log2()).collect();
        println!(
            "| start-up passes ≤ {passes} (used {used:?}) | errors {} | orders {o:.2?} |",
            errors
                .iter()
                .map(|e| format!("{e:.3e}"))
                .collect::<Vec<_>>()
                .join(", ")
        );
        orders.push(o);
    }
    assert!(
        orders[0].iter().all(|&o| o >= 1.8),
        "with the start-up: orders {:?}",
        orders[0]
    );
    assert!(
        orders[1].iter().all(|&o| o < 1.5),
        "without the start-up the pair was expected first order: orders {:?}",
        orders[1]
    );
}

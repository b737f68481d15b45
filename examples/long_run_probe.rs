//! Long-run diagnostics of one cell's semi-implicit steps (issue: GMRES iterations growing over
//! long runs). Prints, every `EVERY` steps: time, GMRES iterations (mean and max over the
//! window), area/volume drift, grid quality (max/min of the area element per solid angle
//! `J = W / sin θ`), the share of the shape's and the tension's spectral energy in the top
//! quarter of the degrees, and the largest |σ|.
//!
//! `cargo run --release --example long_run_probe -- SHAPE P DT STEPS [EVERY]`
//! with SHAPE one of `v0.85` (prolate of that reduced volume), `rbc` (biconcave, Skalak from
//! `MOBO_SHEAR_MODULUS`, default 0), and the environment:
//! `MOBO_FLOW` = `shear` (default) | `ext`, `MOBO_KAPPA` (default 0.05), `MOBO_NO_AREA_RELAX`
//! (no local area relaxation of a Skalak cell), `MOBO_TILT` (degrees
//! about x, default 0), `MOBO_SEED_ASYM` (an asymmetric seed `x → x + ε x²`), `MOBO_SCHEME` = `euler` | `bdf2`, `MOBO_NO_REPARAM`, `MOBO_RESTART`, `MOBO_TOL` (GMRES),
//! `MOBO_PRECONDITIONER` = `cell` (each cell's own operator inverted, as `mobo run` does by
//! default) | `sphere` (the default here: the library stepper's).
use mobo::sph_harmonics::CoefLayout;
use mobo::timestep::semi_implicit::{Preconditioning, TimeScheme, VesicleParams};
use mobo::timestep::vesicle_stepper::VesicleStepper;
use mobo::timestep::GmresParams;
use mobo::vesicle::geometry::SurfaceCalculus;
use mobo::vesicle::reparam::ReparamParams;
use mobo::vesicle::shapes::{self, Spheroid, Surface};
use mobo::vesicle::skalak::SkalakParams;

fn env_f64(name: &str, default: f64) -> f64 {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

/// Share of `Σ c²` in degrees above `3p/4`, summed over the functions of `coefs`.
fn high_share(lay: &CoefLayout, coefs: &[f64]) -> f64 {
    let deg = lay.degrees();
    let p = lay.order();
    let (mut hi, mut all) = (0.0, 0.0);
    for chunk in coefs.chunks_exact(lay.len()) {
        for (c, &n) in chunk.iter().zip(&deg) {
            // Degree 0 of a coordinate is the position of the cell, not its shape.
            if n == 0 {
                continue;
            }
            all += c * c;
            if 4 * n > 3 * p {
                hi += c * c;
            }
        }
    }
    if all > 0.0 {
        hi / all
    } else {
        0.0
    }
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let shape = a.get(1).map_or("v0.85", |s| s.as_str()).to_string();
    let p: usize = a.get(2).map_or(12, |s| s.parse().unwrap());
    let dt: f64 = a.get(3).map_or(0.02, |s| s.parse().unwrap());
    let steps: usize = a.get(4).map_or(400, |s| s.parse().unwrap());
    let every: usize = a.get(5).map_or(25, |s| s.parse().unwrap());
    let kappa = env_f64("MOBO_KAPPA", 0.05);
    let tilt = env_f64("MOBO_TILT", 0.0).to_radians();
    let gs = env_f64("MOBO_SHEAR_MODULUS", 0.0);
    let ext = std::env::var("MOBO_FLOW").is_ok_and(|f| f == "ext");
    let rot = std::env::var("MOBO_FLOW").is_ok_and(|f| f == "rot");
    let mut s = if shape == "rbc" {
        shapes::rbc(p).unwrap()
    } else {
        let v: f64 = shape.trim_start_matches('v').parse().unwrap();
        shapes::reduced_volume_spheroid(p, v, Spheroid::Prolate, 1.0).unwrap()
    };
    let (st, ct) = tilt.sin_cos();
    s.rotate([[1.0, 0.0, 0.0], [0.0, ct, -st], [0.0, st, ct]])
        .unwrap();
    let mut calc = SurfaceCalculus::new(p).unwrap();
    // `MOBO_SEED_ASYM = ε`: an asymmetric seed along the extension axis, `x → x + ε x²`
    // (one end pushed out, the other in), to test whether a growing mode is the dumbbell's.
    let seed = env_f64("MOBO_SEED_ASYM", 0.0);
    if seed != 0.0 {
        let sht = mobo::sph_harmonics::ShTransform::new(p).unwrap();
        let mut grid = s.grid_positions(&sht).unwrap();
        for x in &mut grid[..sht.n_points()] {
            *x += seed * *x * *x;
        }
        s = Surface::from_grid(&sht, &grid).unwrap();
    }
    let mut coefs = s.coefs().to_vec();
    let g0 = calc.geometry(&coefs).unwrap();
    let (a0, v0) = (g0.area(), g0.volume());
    // The capillary number of the flow, `Ca = μ ε̇ R₀³/κ` (rate 1, viscosity 1, `R₀` the
    // equivalent radius), and the reduced volume: the two parameters of a vesicle's shape
    // transitions in extension.
    println!(
        "# R0 = {:.4}, reduced volume = {:.4}, Ca = {:.2}",
        g0.equivalent_radius(),
        g0.reduced_volume(),
        g0.equivalent_radius().powi(3) / kappa
    );
    let params = VesicleParams {
        bending_modulus: kappa,
        viscosity: 1.0,
        force: [0.0; 3],
        dt,
        upsampled_order: 2 * p,
        gmres: GmresParams {
            tol: env_f64("MOBO_TOL", 1e-8),
            restart: env_f64("MOBO_RESTART", 200.0) as usize,
            max_iters: 5000,
            ..Default::default()
        },
        correct_drift: true,
        reparametrize: std::env::var("MOBO_NO_REPARAM")
            .is_err()
            .then(|| ReparamParams {
                max_iterations: 10,
                ..Default::default()
            }),
        preconditioner: true,
        scheme: if std::env::var("MOBO_SCHEME").is_ok_and(|s| s == "bdf2") {
            TimeScheme::Bdf2
        } else {
            TimeScheme::Euler
        },
        viscosity_ratio: 1.0,
        inextensible: true,
        elastic_stepping: None,
    };
    let mut stepper = VesicleStepper::new(p, params).unwrap();
    if std::env::var("MOBO_PRECONDITIONER").is_ok_and(|v| v == "cell") {
        stepper.set_preconditioning(Preconditioning::CELL);
    }
    if std::env::var("MOBO_NO_AREA_RELAX").is_ok() {
        stepper.set_local_area_relaxation(false);
    }
    if gs > 0.0 {
        stepper
            .set_skalak(SkalakParams::skalak(gs, 10.0), &coefs)
            .unwrap();
    }
    // Planar extension has its stagnation point at the origin, and a cell there is in an
    // unstable equilibrium: displaced by `c` along x it moves at `u_∞(c) = c`, so the
    // roundoff asymmetry of its position grows as `e^{ε̇ t}` (measured: the centroid goes
    // 4e-12 → 6.7e5 over t = 8 … 48, a rigid translation that reads as a "tangential"
    // velocity on an x-elongated cell), until the absolute position swamps the shape's
    // precision. As in experiments (a stagnation point held on the vesicle by feedback), the
    // extensional flow is centred on the cell's centroid at every step; `MOBO_FIXED_ORIGIN`
    // keeps the origin (the old behaviour).
    let comove = ext && std::env::var("MOBO_FIXED_ORIGIN").is_err();
    let base_flow = move |x: [f64; 3]| {
        if rot {
            [0.0, -0.5 * x[2], 0.5 * x[1]]
        } else if ext {
            [x[0], -x[1], 0.0]
        } else {
            [x[1], 0.0, 0.0]
        }
    };
    let lay = CoefLayout::new(p);
    let sht = mobo::sph_harmonics::ShTransform::new(p).unwrap();
    let mut ws = sht.workspace();
    let mut sig_c = vec![0.0; lay.len()];
    println!("# t  iters_mean iters_max  area_drift volume_drift  J_ratio  skew  shape_hi  sigma_hi  max|sigma|  wall_s  |u_n|_rms |u_t|_rms  |dX/dt|_rms  L_long angle_x skew3  [Skalak: ref_area_drift ref_volume_drift ref_hi max_I1 max|J-1|]");
    let (mut sum, mut max) = (0usize, 0usize);
    let start = std::time::Instant::now();
    // Summary: iterations per window of 100 steps against the first window, drifts, grid.
    let (mut win_sum, mut first_mean, mut worst_ratio, mut last_mean) = (0usize, None, 1.0f64, 0.0);
    let (mut max_area, mut max_volume, mut max_step_err) = (0.0f64, 0.0f64, 0.0f64);
    let j_ratio = |g: &mobo::vesicle::geometry::Geometry, sin_theta: &[f64]| {
        let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
        for (j, w) in g.w.iter().enumerate() {
            let v = w / sin_theta[j / (2 * p)];
            lo = lo.min(v);
            hi = hi.max(v);
        }
        hi / lo
    };
    let j_start = j_ratio(&g0, &calc.transform().grid().sin_theta.clone());
    let mut j_max = j_start;
    let case = std::env::var("MOBO_CASE").unwrap_or_else(|_| shape.clone());
    for k in 1..=steps {
        let coefs_old = coefs.clone();
        let centre = if comove {
            calc.geometry(&coefs).unwrap().centroid()
        } else {
            [0.0; 3]
        };
        let flow =
            move |x: [f64; 3]| base_flow([x[0] - centre[0], x[1] - centre[1], x[2] - centre[2]]);
        let r = match stepper.step(&mut coefs, &flow) {
            Ok(r) => r,
            Err(e) => {
                println!("# step {k} (t = {:.3}) failed: {e}", k as f64 * dt);
                println!(
                    "| {case} | {p} | {dt} | {steps} | {:.1} | {:.1} | – | – | – | – | – | – | {:.0} | FAIL at step {k}: {} |",
                    k as f64 * dt,
                    first_mean.unwrap_or(f64::NAN),
                    start.elapsed().as_secs_f64(),
                    e.to_string().lines().next().unwrap_or("")
                );
                std::process::exit(1);
            }
        };
        sum += r.gmres.iterations;
        max = max.max(r.gmres.iterations);
        win_sum += r.gmres.iterations;
        max_step_err = max_step_err.max(r.area_volume_error);
        {
            let g = calc.geometry(&coefs).unwrap();
            max_area = max_area.max(((g.area() - a0) / a0).abs());
            max_volume = max_volume.max(((g.volume() - v0) / v0).abs());
            let st = calc.transform().grid().sin_theta.clone();
            j_max = j_max.max(j_ratio(&g, &st));
        }
        if k % 100 == 0 {
            let m = win_sum as f64 / 100.0;
            let f = *first_mean.get_or_insert(m);
            worst_ratio = worst_ratio.max(m / f);
            last_mean = m;
            win_sum = 0;
        }
        if k % every == 0 {
            let g = calc.geometry(&coefs).unwrap();
            let grid = calc.transform().grid();
            let nlon = 2 * p;
            let (mut jmin, mut jmax, mut skew) = (f64::INFINITY, 0.0f64, 0.0f64);
            for (j, w) in g.w.iter().enumerate() {
                let jj = w / grid.sin_theta[j / nlon];
                jmin = jmin.min(jj);
                jmax = jmax.max(jj);
                skew = skew.max((g.f[j] / (g.e[j] * g.g[j]).sqrt()).abs());
            }
            sht.forward(&stepper.state().sigma, &mut sig_c, &mut ws)
                .unwrap();
            let smax = stepper
                .state()
                .sigma
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()));
            // The membrane velocity of the last solve, split into normal and tangential parts
            // (root mean square over the grid points).
            // The displacement the step actually made (after the reparametrisation and the
            // drift correction), as a velocity: rms over the grid.
            let disp = {
                let diff: Vec<f64> = coefs
                    .iter()
                    .zip(&coefs_old)
                    .map(|(a, b)| (a - b) / dt)
                    .collect();
                let mut grid = vec![0.0; 3 * g.normal.len()];
                sht.inverse(&diff, &mut grid, &mut ws).unwrap();
                (grid.iter().map(|v| v * v).sum::<f64>() / g.normal.len() as f64).sqrt()
            };
            let (mut un2, mut ut2) = (0.0, 0.0);
            if let Some(u) = stepper.velocity() {
                let n = g.normal.len();
                for (j, nv) in g.normal.iter().enumerate() {
                    let uj = [u[j], u[n + j], u[2 * n + j]];
                    let un = uj[0] * nv[0] + uj[1] * nv[1] + uj[2] * nv[2];
                    un2 += un * un;
                    ut2 += uj.iter().map(|c| c * c).sum::<f64>() - un * un;
                }
                un2 /= n as f64;
                ut2 /= n as f64;
            }
            // The Skalak reference is the first surface relabelled: its area and volume are
            // invariants, its high-degree share should stay that of the first shape, and the
            // strain invariants I1 = A^ij a_ij - 2 and J = sqrt(det a / det A) measure the
            // membrane's stretch against it at the same grid points.
            let skalak_cols = match stepper.skalak_reference() {
                Some(r) => {
                    let gr = calc.geometry(r).unwrap();
                    let (mut i1max, mut jdev) = (0.0f64, 0.0f64);
                    for j in 0..gr.e.len() {
                        let (ea, fa, ga) = (gr.e[j], gr.f[j], gr.g[j]);
                        let det_ref = ea * ga - fa * fa;
                        let det = g.e[j] * g.g[j] - g.f[j] * g.f[j];
                        let i1 = (ga * g.e[j] - 2.0 * fa * g.f[j] + ea * g.g[j]) / det_ref - 2.0;
                        i1max = i1max.max(i1);
                        jdev = jdev.max(((det / det_ref).sqrt() - 1.0).abs());
                    }
                    format!(
                        " {:10.2e} {:10.2e} {:9.2e} {:9.3e} {:9.2e}",
                        (gr.area() - a0) / a0,
                        (gr.volume() - v0) / v0,
                        high_share(&lay, r),
                        i1max,
                        jdev
                    )
                }
                None => String::new(),
            };
            // The shape's long axis (of the equivalent ellipsoid): its semi-axis, its angle to
            // x (the extension axis), and the skewness of the solid along it,
            // `(1/V)∫(r·e)³dV / ((1/V)∫(r·e)²dV)^{3/2}` (zero for a shape symmetric about its
            // centroid; the asymmetric "dumbbell" mode of a vesicle in extension makes it grow).
            let shape_cols = {
                let (semi, axes) = g.equivalent_ellipsoid();
                let i = (0..3).max_by(|&a, &b| semi[a].total_cmp(&semi[b])).unwrap();
                let e = axes[i];
                let skew3 = g.axial_skewness(e);
                format!(
                    " {:7.4} {:7.2} {:10.3e}",
                    semi[i],
                    e[0].abs().min(1.0).acos().to_degrees(),
                    skew3
                )
            };
            println!(
                "{:8.3} {:7.1} {:5} {:10.2e} {:10.2e} {:8.3} {:6.3} {:9.2e} {:9.2e} {:9.3e} {:7.1} {:9.2e} {:9.2e} {:9.2e}{shape_cols}{skalak_cols}",
                k as f64 * dt,
                sum as f64 / every as f64,
                max,
                (g.area() - a0) / a0,
                (g.volume() - v0) / v0,
                jmax / jmin,
                skew,
                high_share(&lay, &coefs),
                high_share(&lay, &sig_c),
                smax,
                start.elapsed().as_secs_f64(),
                un2.sqrt(),
                ut2.max(0.0).sqrt(),
                disp
            );
            sum = 0;
            max = 0;
        }
    }
    let first = first_mean.unwrap_or(f64::NAN);
    let ok = worst_ratio <= 2.0 && max_area < 1e-6 && max_volume < 1e-6;
    println!(
        "| {case} | {p} | {dt} | {steps} | {:.1} | {first:.1} | {last_mean:.1} | {worst_ratio:.2} | {max_area:.1e} | {max_volume:.1e} | {max_step_err:.1e} | {j_start:.2} → {j_max:.2} | {:.0} | {} |",
        steps as f64 * dt,
        start.elapsed().as_secs_f64(),
        if ok { "pass" } else { "FAIL" }
    );
}

//! The preconditioner from the sphere (design 3.5): exact on a sphere (GMRES converges in at
//! most three iterations), the same step with and without it (to the GMRES tolerance), and a
//! large drop of the iteration count on an ellipsoid, a reduced-volume-0.9 prolate vesicle and
//! the red blood cell at p = 6, 8, 12 (table printed with `--nocapture`).

use std::time::Instant;

use mobo::timestep::semi_implicit::{StepReport, TimeScheme, VesicleParams};
use mobo::timestep::vesicle_stepper::VesicleStepper;
use mobo::timestep::GmresParams;
use mobo::vesicle::shapes::{self, Spheroid, Surface};

fn params(p: usize, dt: f64, tol: f64, preconditioner: bool) -> VesicleParams {
    VesicleParams {
        bending_modulus: 1.0,
        viscosity: 1.0,
        force: [0.3, -0.2, -1.0],
        dt,
        upsampled_order: 2 * p,
        gmres: GmresParams {
            tol,
            restart: 300,
            max_iters: 3000,
            ..Default::default()
        },
        correct_drift: false,
        reparametrize: None,
        preconditioner,
        scheme: TimeScheme::Euler,
        viscosity_ratio: 1.0,
        inextensible: true,
        elastic_stepping: None,
    }
}

fn shear(x: [f64; 3]) -> [f64; 3] {
    [x[1], 0.0, 0.0]
}

/// One step of `surface`; the new coefficients, the report and the step time (the first step
/// builds the preconditioner: a second, timed, step is taken from the same state).
fn one_step(p: usize, surface: &Surface, prm: VesicleParams) -> (Vec<f64>, StepReport, f64, f64) {
    let mut st = VesicleStepper::new(p, prm).unwrap();
    let mut c = surface.coefs().to_vec();
    let t = Instant::now();
    let r = st.step(&mut c, &shear).unwrap();
    let first = t.elapsed().as_secs_f64();
    assert!(r.gmres.converged);
    assert_eq!(r.preconditioner_built, prm.preconditioner);
    // Again from the same state (preconditioner kept): the step time without the build.
    st.state_mut().sigma.fill(0.0);
    let mut c2 = surface.coefs().to_vec();
    let t = Instant::now();
    let r2 = st.step(&mut c2, &shear).unwrap();
    let second = t.elapsed().as_secs_f64();
    assert!(!r2.preconditioner_built);
    assert_eq!(r2.gmres.iterations, r.gmres.iterations);
    (c, r, first, second)
}

#[test]
fn on_a_sphere_gmres_converges_in_at_most_three_iterations() {
    for p in [6, 8, 12] {
        let s = shapes::sphere(p, 1.3).unwrap();
        let (c, r, _, _) = one_step(p, &s, params(p, 0.1, 1e-11, true));
        let (c0, r0, _, _) = one_step(p, &s, params(p, 0.1, 1e-11, false));
        println!(
            "p = {p}: sphere, {} iterations preconditioned, {} without",
            r.gmres.iterations, r0.gmres.iterations
        );
        assert!(r.gmres.iterations <= 3, "{} iterations", r.gmres.iterations);
        block_structure(p);
        assert!(
            r0.gmres.iterations > 3,
            "{} iterations",
            r0.gmres.iterations
        );
        let d = c
            .iter()
            .zip(&c0)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(d < 1e-9, "p = {p}: steps differ by {d:.2e}");
    }
}

#[test]
fn preconditioned_and_plain_steps_agree() {
    let p = 8;
    let s = shapes::ellipsoid(p, [1.2, 1.0, 0.8]).unwrap();
    let tol = 1e-11;
    let (c1, r1, _, _) = one_step(p, &s, params(p, 0.1, tol, true));
    let (c0, r0, _, _) = one_step(p, &s, params(p, 0.1, tol, false));
    let scale = c0.iter().map(|v| v.abs()).fold(0.0, f64::max);
    let d = c1
        .iter()
        .zip(&c0)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max)
        / scale;
    println!(
        "ellipsoid p = {p}: {} vs {} iterations, relative difference {d:.2e}",
        r1.gmres.iterations, r0.gmres.iterations
    );
    // Both residuals are below tol ‖b‖ (‖b‖ ~ ‖X‖); the operator's conditioning lets the
    // difference be a few orders above tol.
    assert!(d < 1e-8, "relative difference {d:.2e}");
    assert!(r1.gmres.relative_residual <= tol && r0.gmres.relative_residual <= tol);
}

#[test]
fn iteration_counts_drop_on_nonspherical_cells() {
    let tol = 1e-9;
    let dt = 0.1;
    println!("| shape | p | iterations plain | preconditioned | ratio | step plain (s) | step preconditioned (s) | first step incl. build (s) |");
    println!("|---|---|---|---|---|---|---|---|");
    let mut rows = Vec::new();
    for p in [6usize, 8, 12] {
        let shapes: [(&str, Surface); 3] = [
            (
                "ellipsoid 1.2:1:0.8",
                shapes::ellipsoid(p, [1.2, 1.0, 0.8]).unwrap(),
            ),
            (
                "prolate v = 0.9",
                shapes::reduced_volume_spheroid(p, 0.9, Spheroid::Prolate, 1.0).unwrap(),
            ),
            ("RBC", shapes::rbc(p).unwrap()),
        ];
        let ellipsoid = shapes[0].1.clone();
        for (name, s, lambda) in shapes.iter().map(|(n, s)| (n.to_string(), s, 1.0)).chain([(
            "ellipsoid, λ = 5".to_string(),
            &ellipsoid,
            5.0,
        )]) {
            let prm = |pc| VesicleParams {
                viscosity_ratio: lambda,
                inextensible: true,
                elastic_stepping: None,
                ..params(p, dt, tol, pc)
            };
            let (_, r0, _, t0) = one_step(p, s, prm(false));
            let (_, r1, b1, t1) = one_step(p, s, prm(true));
            let (i0, i1) = (r0.gmres.iterations, r1.gmres.iterations);
            let ratio = i0 as f64 / i1 as f64;
            println!("| {name} | {p} | {i0} | {i1} | {ratio:.1} | {t0:.3} | {t1:.3} | {b1:.3} |");
            rows.push((name, p, i0, i1, ratio));
        }
    }
    for (name, p, i0, i1, ratio) in rows {
        let want = if p <= 6 { 2.0 } else { 3.0 };
        assert!(ratio >= want, "{name}, p = {p}: {i0} -> {i1}");
    }
}

/// The sphere's operator in the rotated coefficient basis splits into small blocks (one per
/// total order |M| and reflection parity, ≈ 4(p + 1 − |M|) coefficients each), with the entries
/// left out at rounding level.
fn block_structure(p: usize) {
    use mobo::timestep::sphere_preconditioner::{SpherePreconditioner, StepCoefficients};
    use mobo::vesicle::layer::{RotationAlgorithm, SelfInteraction};
    use mobo::vesicle::membrane::Membrane;
    let mut m = Membrane::new(p, 2 * p).unwrap();
    let mut l = SelfInteraction::new(p, 2 * p, RotationAlgorithm::Direct).unwrap();
    for lambda in [1.0, 5.0] {
        let c = StepCoefficients::new(lambda, 0.1, 1.0, 1.0);
        let pc = SpherePreconditioner::build(&mut m, &mut l, 1.3, c).unwrap();
        let sizes = pc.block_sizes();
        let total: usize = sizes.iter().sum();
        let largest = *sizes.iter().max().unwrap();
        println!(
            "p = {p}, λ = {lambda}: {} blocks, largest {largest} of {total}, dropped {:.1e}, {} kB",
            sizes.len(),
            pc.dropped_relative(),
            pc.memory_bytes() / 1024
        );
        assert!(pc.dropped_relative() < 1e-11, "{}", pc.dropped_relative());
        assert!(largest <= 8 * (p + 2), "largest block {largest}");
        assert_eq!(total, 4 * ((p + 1) * (p + 1) - 1));
    }
}

/// Cells of one sphere share one preconditioner (`sphere_preconditioner::shared`): the same
/// key gives the same object, built once; another radius, `τ` or far-side setting gives its
/// own. A shared preconditioner is the one a cell would build: two builds of one key apply
/// bit for bit alike, from many threads at once (each application takes its own scratch).
#[test]
fn cells_of_one_sphere_share_its_preconditioner() {
    use mobo::timestep::sphere_preconditioner::{shared, SpherePreconditioner, StepCoefficients};
    use mobo::timestep::Preconditioner;
    use mobo::vesicle::far_side::FarSideParams;
    use mobo::vesicle::layer::{RotationAlgorithm, SelfInteraction};
    use mobo::vesicle::membrane::Membrane;
    use std::sync::Arc;
    let p = 6;
    let mut m = Membrane::new(p, 2 * p).unwrap();
    let mut l = SelfInteraction::new(p, 2 * p, RotationAlgorithm::Direct).unwrap();
    // A radius and τ no other test uses, so that this test builds the first.
    let c = StepCoefficients::new(1.0, 0.0123, 1.0, 1.0);
    let (a, built_a) = shared(&mut m, &mut l, 1.2345, c).unwrap();
    let (b, built_b) = shared(&mut m, &mut l, 1.2345, c).unwrap();
    assert!(built_a && !built_b, "built {built_a} then {built_b}");
    assert!(Arc::ptr_eq(&a, &b));
    let (other_radius, built) = shared(&mut m, &mut l, 1.2346, c).unwrap();
    assert!(built && !Arc::ptr_eq(&a, &other_radius));
    let c2 = StepCoefficients::new(1.0, 0.0124, 1.0, 1.0);
    let (other_tau, built) = shared(&mut m, &mut l, 1.2345, c2).unwrap();
    assert!(built && !Arc::ptr_eq(&a, &other_tau));
    let off = FarSideParams {
        enabled: !l.far_side_params().enabled,
        ..l.far_side_params()
    };
    let mut l_off = SelfInteraction::new(p, 2 * p, RotationAlgorithm::Direct).unwrap();
    l_off.set_far_side_params(off).unwrap();
    let (other_split, built) = shared(&mut m, &mut l_off, 1.2345, c).unwrap();
    assert!(built && !Arc::ptr_eq(&a, &other_split));
    // The shared one against a private build of the same key, applied on 4 threads at once.
    let own = SpherePreconditioner::build(&mut m, &mut l, 1.2345, c).unwrap();
    let n = a.nrows();
    let v: Vec<f64> = (0..n)
        .map(|i| ((i * 7919) % 1000) as f64 / 500.0 - 1.0)
        .collect();
    let mut want = vec![0.0; n];
    own.apply(&v, &mut want);
    std::thread::scope(|s| {
        for _ in 0..4 {
            s.spawn(|| {
                for _ in 0..20 {
                    let mut z = vec![0.0; n];
                    a.apply(&v, &mut z);
                    assert_eq!(z, want);
                }
            });
        }
    });
}

//! The semi-implicit vesicle step: a sedimenting spherical vesicle moves at `F/(6πμa)`; a
//! prolate vesicle relaxing at a large time step keeps its area and volume and loses bending
//! energy monotonically.

use mobo::timestep::semi_implicit::{explicit_is_stable, ExplicitStepper, VesicleParams};
use mobo::timestep::vesicle_stepper::VesicleStepper;
use mobo::timestep::GmresParams;
use mobo::vesicle::geometry::SurfaceCalculus;
use mobo::vesicle::membrane::Membrane;
use mobo::vesicle::reparam::ReparamParams;
use mobo::vesicle::shapes::{self, Spheroid};

fn params(p: usize, force: [f64; 3], dt: f64) -> VesicleParams {
    VesicleParams {
        bending_modulus: 0.1,
        viscosity: 1.0,
        force,
        dt,
        upsampled_order: 2 * p,
        gmres: GmresParams {
            tol: 1e-11,
            restart: 200,
            max_iters: 2000,
            ..Default::default()
        },
        correct_drift: false,
        reparametrize: None,
        preconditioner: false,
        scheme: mobo::timestep::semi_implicit::TimeScheme::Euler,
        viscosity_ratio: 1.0,
        inextensible: true,
        elastic_stepping: None,
    }
}

#[test]
fn a_spherical_vesicle_sediments_at_the_stokes_speed() {
    let p = 12;
    let (a, mu) = (1.3, 1.0);
    let f = [0.2, -0.1, -1.0];
    let dt = 0.05;
    let mut s = shapes::sphere(p, a).unwrap();
    let mut calc = SurfaceCalculus::new(p).unwrap();
    let c0 = calc.geometry(s.coefs()).unwrap().centroid();
    let mut step = VesicleStepper::new(p, params(p, f, dt)).unwrap();
    let mut coefs = s.coefs().to_vec();
    let steps = 3;
    for _ in 0..steps {
        let r = step.step(&mut coefs, &|_| [0.0; 3]).unwrap();
        assert!(r.gmres.converged);
    }
    s.coefs_mut().copy_from_slice(&coefs);
    let c1 = calc.geometry(s.coefs()).unwrap().centroid();
    let v: Vec<f64> = (0..3)
        .map(|k| (c1[k] - c0[k]) / (steps as f64 * dt))
        .collect();
    let want: Vec<f64> = f
        .iter()
        .map(|fk| fk / (6.0 * std::f64::consts::PI * mu * a))
        .collect();
    let err = (0..3).map(|k| (v[k] - want[k]).powi(2)).sum::<f64>().sqrt()
        / want.iter().map(|w| w * w).sum::<f64>().sqrt();
    println!("velocity {v:?}, F/(6πμa) = {want:?}, relative error {err:.2e}");
    assert!(err < 1e-4, "relative error {err:.2e}");
    // The shape stays a sphere of radius a.
    let g = calc.geometry(s.coefs()).unwrap();
    let v = g.volume();
    assert!(
        (v / (4.0 / 3.0 * std::f64::consts::PI * a.powi(3)) - 1.0).abs() < 1e-8,
        "{v}"
    );
}

#[test]
fn a_prolate_vesicle_relaxes_at_a_large_step_keeping_area_and_volume() {
    let p = 8;
    let s = shapes::reduced_volume_spheroid(p, 0.9, Spheroid::Prolate, 1.0).unwrap();
    let mut calc = SurfaceCalculus::new(p).unwrap();
    let g0 = calc.geometry(s.coefs()).unwrap();
    let (a0, v0) = (g0.area(), g0.volume());
    let energy = |c: &[f64]| {
        let mut m = Membrane::new(p, 2 * p).unwrap();
        m.set_geometry(c).unwrap();
        m.bending_energy(0.1).unwrap()
    };
    let dt = 0.5;
    let mut step = VesicleStepper::new(p, params(p, [0.0; 3], dt)).unwrap();
    let mut coefs = s.coefs().to_vec();
    let mut last = energy(&coefs);
    let e0 = last;
    for k in 0..10 {
        let r = step.step(&mut coefs, &|_| [0.0; 3]).unwrap();
        assert!(r.gmres.converged, "step {k}");
        println!("step {k}: {} GMRES iterations", r.gmres.iterations);
        let e = energy(&coefs);
        assert!(
            e <= last * (1.0 + 1e-10),
            "bending energy rose at step {k}: {last} -> {e}"
        );
        last = e;
    }
    let g = calc.geometry(&coefs).unwrap();
    let (da, dv) = ((g.area() - a0).abs() / a0, (g.volume() - v0).abs() / v0);
    println!("energy {e0:.5} -> {last:.5}, area drift {da:.2e}, volume drift {dv:.2e}");
    assert!(last < 0.99 * e0, "no relaxation: {e0} -> {last}");
    assert!(
        da < 1e-3 && dv < 1e-3,
        "area drift {da:.2e}, volume drift {dv:.2e}"
    );
}

/// The same vesicle and step advanced explicitly (`X ← X + Δt S f_b(X)`, no constraint) is
/// unstable: the time step of the implicit test is above the explicit stiffness limit.
#[test]
fn the_same_step_taken_explicitly_blows_up() {
    let p = 8;
    let s = shapes::reduced_volume_spheroid(p, 0.9, Spheroid::Prolate, 1.0).unwrap();
    let mut st = ExplicitStepper::new(p, 2 * p, 0.1, 1.0, 0.5).unwrap();
    assert!(!explicit_is_stable(
        &mut st,
        s.coefs(),
        30,
        10.0,
        &|_| [0.0; 3]
    ));
    // ... while a step 50 times smaller is stable over the same time.
    let mut st = ExplicitStepper::new(p, 2 * p, 0.1, 1.0, 0.01).unwrap();
    assert!(explicit_is_stable(
        &mut st,
        s.coefs(),
        100,
        10.0,
        &|_| [0.0; 3]
    ));
}

/// Inclination angle (degrees) of the longest inertia axis in the flow (x–y) plane. The axis
/// must lie in that plane: otherwise the angle would be the ratio of two small components (of
/// round-off size for an axis along the vorticity), not an inclination.
fn inclination(calc: &mut SurfaceCalculus, coefs: &[f64]) -> f64 {
    let (_, axes) = calc.geometry(coefs).unwrap().principal_axes();
    assert!(
        axes[0][2].abs() < 0.1,
        "the long axis {:?} left the shear plane",
        axes[0]
    );
    (axes[0][1] / axes[0][0]).atan().to_degrees()
}

/// The rotation that takes a spheroid's axis of symmetry (`z`) into the shear plane at `deg`
/// degrees from the flow direction `x`. (A turn about `z`, the vorticity axis, would leave it
/// along `z`.)
fn axis_in_shear_plane(deg: f64) -> [[f64; 3]; 3] {
    let t = deg.to_radians();
    // Columns: x → z, y → (sin t, −cos t, 0), z → (cos t, sin t, 0); a proper rotation.
    [
        [0.0, t.sin(), t.cos()],
        [0.0, -t.cos(), t.sin()],
        [1.0, 0.0, 0.0],
    ]
}

fn shear_run(p: usize, v: f64, dt: f64, steps: usize, kappa: f64) -> (f64, f64, f64, Vec<f64>) {
    let mut s = shapes::reduced_volume_spheroid(p, v, Spheroid::Prolate, 1.0).unwrap();
    s.rotate(axis_in_shear_plane(80.0)).unwrap();
    let mut calc = SurfaceCalculus::new(p).unwrap();
    let g0 = calc.geometry(s.coefs()).unwrap();
    let (a0, v0) = (g0.area(), g0.volume());
    let mut prm = params(p, [0.0; 3], dt);
    prm.correct_drift = true;
    prm.reparametrize = Some(ReparamParams {
        max_iterations: 10,
        ..Default::default()
    });
    prm.bending_modulus = kappa;
    prm.gmres.tol = 1e-7;
    let mut st = VesicleStepper::new(p, prm).unwrap();
    let mut coefs = s.coefs().to_vec();
    let mut angles = Vec::new();
    for k in 0..steps {
        st.step(&mut coefs, &|x| [x[1], 0.0, 0.0]).unwrap();
        assert!(coefs.iter().all(|c| c.is_finite()), "NaN at step {k}");
        if (k + 1) % (steps / 10) == 0 {
            angles.push(inclination(&mut calc, &coefs));
        }
    }
    let g = calc.geometry(&coefs).unwrap();
    (
        (g.area() - a0).abs() / a0,
        (g.volume() - v0).abs() / v0,
        *angles.last().unwrap(),
        angles,
    )
}

/// A vesicle of reduced volume 0.9 in shear (capillary number μγ̇R³/κ = 1): 2000 steps at
/// `Δt = 0.15`, ten times the largest stable explicit step; area and volume
/// stay within 1e-3, the inclination settles between 0° and 45°, and a more nearly spherical
/// vesicle (v = 0.97) tank-treads closer to 45°.
#[test]
fn a_vesicle_in_shear_tank_treads_stably_at_a_large_step() {
    const KAPPA: f64 = 1.0;
    // Forward Euler of this vesicle is stable at Δt = 0.014 and diverges at 0.015
    // (examples/explicit_limit.rs, checked again below): Δt = 0.15 is ten times the limit.
    // (Without reparametrisation the grid degenerates within 2000 steps at this Δt.)
    const DT: f64 = 0.15;
    const DT_EXPLICIT: f64 = 0.015;
    let p = 6;
    let (da, dv, angle, angles) = shear_run(p, 0.9, DT, 2000, KAPPA);
    println!("v = 0.9: angles {angles:.2?}, area drift {da:.1e}, volume drift {dv:.1e}");
    assert!(da < 1e-3 && dv < 1e-3, "drift {da:.1e} {dv:.1e}");
    assert!(angle > 0.0 && angle < 45.0, "inclination {angle}");
    let n = angles.len();
    assert!(
        (angles[n - 1] - angles[n - 2]).abs() < 0.1,
        "not steady: {angles:?}"
    );
    let (_, _, angle97, _) = shear_run(p, 0.97, DT, 400, KAPPA);
    println!("v = 0.97: inclination {angle97:.2}°");
    assert!(angle97 > angle && angle97 < 45.0, "{angle97} vs {angle}");
    // Forward Euler diverges at Δt = 0.015 and is stable at 0.014 (over 2 time units).
    let s = shapes::reduced_volume_spheroid(p, 0.9, Spheroid::Prolate, 1.0).unwrap();
    let shear = |x: [f64; 3]| [x[1], 0.0, 0.0];
    let mut st = ExplicitStepper::new(p, 2 * p, KAPPA, 1.0, DT_EXPLICIT).unwrap();
    assert!(!explicit_is_stable(&mut st, s.coefs(), 134, 10.0, &shear));
    let mut st = ExplicitStepper::new(p, 2 * p, KAPPA, 1.0, 0.014).unwrap();
    assert!(explicit_is_stable(&mut st, s.coefs(), 143, 10.0, &shear));
}

/// Viscosity contrast: an inextensible spherical membrane translates rigidly, and a rigid
/// translation `U` has `D[U] = −U/2`, so `((1+λ)/2) U − (1−λ) D[U] = U = S[f]` for every `λ`: a
/// sedimenting spherical vesicle with λ = 5 still moves at `F/(6πμa)`.
#[test]
fn a_spherical_vesicle_with_viscosity_contrast_sediments_at_the_stokes_speed() {
    let p = 8;
    let (a, mu) = (1.3, 1.0);
    let f = [0.2, -0.1, -1.0];
    let dt = 0.05;
    let want: Vec<f64> = f
        .iter()
        .map(|fk| fk / (6.0 * std::f64::consts::PI * mu * a))
        .collect();
    use mobo::timestep::semi_implicit::TimeScheme::{Bdf2, Euler};
    for (lambda, precond, scheme) in [
        (1.0, false, Euler),
        (5.0, false, Euler),
        (5.0, true, Euler),
        (0.2, true, Euler),
        (5.0, true, Bdf2),
    ] {
        let s = shapes::sphere(p, a).unwrap();
        let mut calc = SurfaceCalculus::new(p).unwrap();
        let c0 = calc.geometry(s.coefs()).unwrap().centroid();
        let mut prm = params(p, f, dt);
        prm.viscosity_ratio = lambda;
        prm.preconditioner = precond;
        prm.scheme = scheme;
        let mut step = VesicleStepper::new(p, prm).unwrap();
        let mut coefs = s.coefs().to_vec();
        let steps = 3;
        let mut iters = Vec::new();
        for _ in 0..steps {
            let r = step.step(&mut coefs, &|_| [0.0; 3]).unwrap();
            assert!(r.gmres.converged);
            iters.push(r.gmres.iterations);
        }
        let c1 = calc.geometry(&coefs).unwrap().centroid();
        let v: Vec<f64> = (0..3)
            .map(|k| (c1[k] - c0[k]) / (steps as f64 * dt))
            .collect();
        let err = (0..3).map(|k| (v[k] - want[k]).powi(2)).sum::<f64>().sqrt()
            / want.iter().map(|w| w * w).sum::<f64>().sqrt();
        println!(
            "λ = {lambda}, preconditioner {precond}, {scheme:?}: relative velocity error \
             {err:.2e}, GMRES iterations {iters:?}"
        );
        assert!(err < 1e-6, "λ = {lambda}: relative error {err:.2e}");
    }
}

/// Steady inclination (degrees) of a vesicle in shear with viscosity ratio `lambda`, and the
/// inclination sampled every `every` steps.
fn shear_lambda(p: usize, v: f64, lambda: f64, dt: f64, steps: usize, every: usize) -> Vec<f64> {
    let mut s = shapes::reduced_volume_spheroid(p, v, Spheroid::Prolate, 1.0).unwrap();
    s.rotate(axis_in_shear_plane(45.0)).unwrap();
    let mut calc = SurfaceCalculus::new(p).unwrap();
    let mut prm = params(p, [0.0; 3], dt);
    prm.correct_drift = true;
    prm.reparametrize = Some(ReparamParams {
        max_iterations: 10,
        ..Default::default()
    });
    prm.bending_modulus = 1.0;
    prm.gmres.tol = 1e-7;
    prm.preconditioner = true;
    prm.viscosity_ratio = lambda;
    let mut st = VesicleStepper::new(p, prm).unwrap();
    let mut coefs = s.coefs().to_vec();
    let mut angles = Vec::new();
    for k in 0..steps {
        st.step(&mut coefs, &|x| [x[1], 0.0, 0.0]).unwrap();
        assert!(coefs.iter().all(|c| c.is_finite()), "NaN at step {k}");
        if (k + 1) % every == 0 {
            angles.push(inclination(&mut calc, &coefs));
        }
    }
    angles
}

/// Keller & Skalak (J. Fluid Mech. 120, 1982) and the vesicle literature (Biben & Misbah, PRE 67
/// 2003; Kaoui et al., PRE 80 2009; Biben, Farutin & Misbah, PRE 83 2011): the tank-treading
/// inclination decreases as the viscosity ratio grows and vanishes at a critical `λ_c(v)`,
/// beyond which the vesicle tumbles (for `v = 0.9`, `λ_c` is of order 3–6 in 3D). At
/// capillary number 1: λ = 1 and λ = 3 tank-tread at steady angles, the second clearly lower;
/// at λ = 10 the vesicle leaves tank-treading and tumbles: its long axis turns past the
/// vertical (the inclination, in (−90°, 90°), jumps from below −45° to above 45°) more than once.
#[test]
fn the_inclination_in_shear_decreases_with_the_viscosity_ratio() {
    let (p, v, dt) = (6, 0.9, 0.1);
    let a1 = shear_lambda(p, v, 1.0, dt, 500, 50);
    let a3 = shear_lambda(p, v, 3.0, dt, 500, 50);
    let a10 = shear_lambda(p, v, 10.0, dt, 500, 5);
    println!("λ = 1: {a1:.2?}\nλ = 3: {a3:.2?}\nλ = 10: {a10:.1?}");
    let last = |a: &[f64]| a[a.len() - 1];
    let steady = |a: &[f64]| (a[a.len() - 1] - a[a.len() - 2]).abs() < 0.2;
    assert!(steady(&a1) && steady(&a3), "not steady: {a1:?} {a3:?}");
    assert!(last(&a1) > 0.0 && last(&a1) < 45.0, "{a1:?}");
    assert!(last(&a3) > 0.0, "{a3:?}");
    assert!(
        last(&a3) < last(&a1) - 3.0,
        "{} vs {}",
        last(&a3),
        last(&a1)
    );
    let flips = a10
        .windows(2)
        .filter(|w| w[0] < -45.0 && w[1] > 45.0)
        .count();
    println!("λ = 10: {flips} flips in 50 strain units");
    assert!(flips >= 2, "no tumbling at λ = 10: {a10:?}");
}

/// The dense self-interaction operators kept in coefficient space (`P A`, the default), on
/// the grid (`A`), or not at all (matrix-free products) give the same steps: an inclined prolate with Skalak elasticity, a viscosity
/// contrast (single and double layer), BDF2, reparametrisation and drift correction.
#[test]
fn coefficient_and_grid_operator_storage_take_the_same_steps() {
    use mobo::timestep::semi_implicit::{OperatorStorage, TimeScheme};
    use mobo::vesicle::skalak::SkalakParams;
    let p = 8;
    let mut s = shapes::reduced_volume_spheroid(p, 0.85, Spheroid::Prolate, 1.0).unwrap();
    let t = 60f64.to_radians();
    s.rotate([
        [t.cos(), -t.sin(), 0.0],
        [t.sin(), t.cos(), 0.0],
        [0.0, 0.0, 1.0],
    ])
    .unwrap();
    let reference = shapes::reduced_volume_spheroid(p, 0.95, Spheroid::Prolate, 1.0).unwrap();
    let run = |storage: OperatorStorage| {
        let mut prm = params(p, [0.0, 0.0, -0.5], 0.05);
        prm.viscosity_ratio = 4.0;
        prm.scheme = TimeScheme::Bdf2;
        prm.correct_drift = true;
        prm.preconditioner = true;
        prm.reparametrize = Some(ReparamParams::default());
        let mut st = VesicleStepper::new(p, prm).unwrap();
        st.set_skalak(SkalakParams::skalak(0.5, 10.0), reference.coefs())
            .unwrap();
        st.set_operator_storage(storage);
        assert_eq!(st.operator_storage(), storage);
        let mut c = s.coefs().to_vec();
        let mut iters = Vec::new();
        for _ in 0..4 {
            let r = st.step(&mut c, &|x| [x[1], 0.0, 0.0]).unwrap();
            assert!(r.gmres.converged);
            iters.push(r.gmres.iterations);
        }
        (c, st.state().sigma.clone(), iters, st.memory_bytes())
    };
    let (cc, sc, ic, mc) = run(OperatorStorage::Coefficients);
    let (cg, sg, ig, mg) = run(OperatorStorage::Grid);
    let (cm, sm, im, mm) = run(OperatorStorage::MatrixFree);
    let rel = |a: &[f64], b: &[f64]| {
        let d = a
            .iter()
            .zip(b)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        d / b.iter().fold(0.0f64, |m, y| m.max(y.abs()))
    };
    let (ec, es) = (rel(&cc, &cg), rel(&sc, &sg));
    println!(
        "coefficients vs grid: surface {ec:.1e}, tension {es:.1e}; GMRES iterations {ic:?} vs \
         {ig:?}; cell state {mc} vs {mg} bytes"
    );
    // GMRES stops at a relative residual of 1e-11 in both; the difference is of that order.
    assert!(ec < 1e-9, "surface differs by {ec:.1e}");
    assert!(es < 1e-7, "tension differs by {es:.1e}");
    // Coefficient space keeps two compressed operators per cell; the grid's live in the step
    // engine (one set per thread), so the cell keeps none.
    let kept = OperatorStorage::Coefficients.bytes_per_cell(p, 2);
    assert!(
        (mg as f64) <= mc as f64 - 0.9 * kept as f64,
        "{mg} vs {mc} bytes"
    );
    // Matrix-free: the grid operator's products, applied per iteration; no dense operator.
    let (em, esm) = (rel(&cm, &cg), rel(&sm, &sg));
    println!("matrix-free vs grid: surface {em:.1e}, tension {esm:.1e}; GMRES {im:?}; {mm} bytes");
    assert!(em < 1e-9, "surface differs by {em:.1e}");
    assert!(esm < 1e-7, "tension differs by {esm:.1e}");
    assert!((mm as f64) < 0.1 * mc as f64, "{mm} vs {mc} bytes");
}

/// Grid storage lends each step the step engine's operator buffers (one set per thread): two
/// cells stepped in turn on one thread, each step assembling into the buffers the other cell's
/// step filled (one with a viscosity contrast, so a double layer too), take bit for bit the
/// steps each takes alone, and a cell keeps no operator between its steps.
#[test]
fn grid_operators_lent_per_step_leave_nothing_between_cells() {
    use mobo::timestep::semi_implicit::{OperatorStorage, TimeScheme};
    let p = 6;
    let prolate = shapes::reduced_volume_spheroid(p, 0.85, Spheroid::Prolate, 1.0).unwrap();
    let oblate = shapes::reduced_volume_spheroid(p, 0.9, Spheroid::Oblate, 1.2).unwrap();
    let stepper = |ratio: f64| {
        let mut prm = params(p, [0.0, 0.0, -0.5], 0.05);
        prm.viscosity_ratio = ratio;
        prm.scheme = TimeScheme::Bdf2;
        prm.correct_drift = true;
        let mut st = VesicleStepper::new(p, prm).unwrap();
        st.set_operator_storage(OperatorStorage::Grid);
        st
    };
    let shear = |x: [f64; 3]| [x[1], 0.0, 0.0];
    let alone = |ratio: f64, c0: &[f64]| {
        let mut st = stepper(ratio);
        let mut c = c0.to_vec();
        for _ in 0..3 {
            st.step(&mut c, &shear).unwrap();
        }
        (c, st.state().sigma.clone())
    };
    let (a_alone, b_alone) = (alone(4.0, prolate.coefs()), alone(1.0, oblate.coefs()));
    let (mut sa, mut sb) = (stepper(4.0), stepper(1.0));
    let (mut ca, mut cb) = (prolate.coefs().to_vec(), oblate.coefs().to_vec());
    for _ in 0..3 {
        sa.step(&mut ca, &shear).unwrap();
        sb.step(&mut cb, &shear).unwrap();
    }
    assert_eq!(
        (&ca, &sa.state().sigma),
        (&a_alone.0, &a_alone.1),
        "contrast cell"
    );
    assert_eq!(
        (&cb, &sb.state().sigma),
        (&b_alone.0, &b_alone.1),
        "cell without contrast"
    );
    let one = OperatorStorage::Grid.bytes_per_thread(p, 1);
    for (name, st) in [("contrast", &sa), ("no contrast", &sb)] {
        println!(
            "{name}: cell state {} bytes, one grid operator {one}",
            st.memory_bytes()
        );
        assert!(
            st.memory_bytes() < one,
            "{name}: {} bytes",
            st.memory_bytes()
        );
    }
}

//! The semi-implicit vesicle step: a sedimenting spherical vesicle moves at `F/(6πμa)`; a
//! prolate vesicle relaxing at a large time step keeps its area and volume and loses bending
//! energy monotonically.

use mobo::timestep::semi_implicit::{VesicleParams, VesicleStepper};
use mobo::timestep::GmresParams;
use mobo::vesicle::geometry::SurfaceCalculus;
use mobo::vesicle::membrane::Membrane;
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
        },
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
    use mobo::sph_harmonics::ShTransform;
    use mobo::vesicle::layer::{LayerKernel, RotationAlgorithm, SelfInteraction};
    let p = 8;
    let s = shapes::reduced_volume_spheroid(p, 0.9, Spheroid::Prolate, 1.0).unwrap();
    let sht = ShTransform::new(p).unwrap();
    let mut ws = sht.workspace();
    let n = sht.n_points();
    let mut m = Membrane::new(p, 2 * p).unwrap();
    let mut layer = SelfInteraction::new(p, 2 * p, RotationAlgorithm::Direct).unwrap();
    let mut coefs = s.coefs().to_vec();
    let (mut x, mut fb, mut u) = (vec![0.0; 3 * n], vec![0.0; 3 * n], vec![0.0; 3 * n]);
    m.set_geometry(&coefs).unwrap();
    let e0 = m.bending_energy(0.1).unwrap();
    let mut e = e0;
    for _ in 0..30 {
        m.set_geometry(&coefs).unwrap();
        m.bending_force(0.1, &mut fb).unwrap();
        layer
            .evaluate(
                LayerKernel::SingleLayer { viscosity: 1.0 },
                &coefs,
                &fb,
                &mut u,
            )
            .unwrap();
        sht.inverse(&coefs, &mut x, &mut ws).unwrap();
        for (xi, ui) in x.iter_mut().zip(&u) {
            *xi += 0.5 * ui;
        }
        sht.forward(&x, &mut coefs, &mut ws).unwrap();
        match m.set_geometry(&coefs).and_then(|_| m.bending_energy(0.1)) {
            Ok(v) if v.is_finite() => e = v,
            _ => {
                e = f64::INFINITY;
                break;
            }
        }
        if e > 100.0 * e0 {
            break;
        }
    }
    println!("explicit: bending energy {e0:.4} -> {e:.4e}");
    assert!(
        e > 10.0 * e0,
        "explicit stepping stayed stable: {e0} -> {e}"
    );
}

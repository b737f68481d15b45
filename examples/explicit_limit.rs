//! Largest stable explicit time step of a vesicle in shear (bending through the single layer,
//! forward Euler): `cargo run --release --example explicit_limit -- P KAPPA [DT ...]`.
use mobo::sph_harmonics::ShTransform;
use mobo::vesicle::layer::{LayerKernel, RotationAlgorithm, SelfInteraction};
use mobo::vesicle::membrane::Membrane;
use mobo::vesicle::shapes::{self, Spheroid};

fn stable(p: usize, kappa: f64, dt: f64) -> bool {
    let s = shapes::reduced_volume_spheroid(p, 0.9, Spheroid::Prolate, 1.0).unwrap();
    let sht = ShTransform::new(p).unwrap();
    let mut ws = sht.workspace();
    let n = sht.n_points();
    let mut m = Membrane::new(p, 2 * p).unwrap();
    let mut layer = SelfInteraction::new(p, 2 * p, RotationAlgorithm::Direct).unwrap();
    let mut coefs = s.coefs().to_vec();
    let (mut x, mut fb, mut u) = (vec![0.0; 3 * n], vec![0.0; 3 * n], vec![0.0; 3 * n]);
    m.set_geometry(&coefs).unwrap();
    let e0 = m.bending_energy(kappa).unwrap();
    let steps = (2.0 / dt) as usize;
    for _ in 0..steps {
        if m.set_geometry(&coefs).is_err() || m.bending_force(kappa, &mut fb).is_err() {
            return false;
        }
        layer
            .evaluate(
                LayerKernel::SingleLayer { viscosity: 1.0 },
                &coefs,
                &fb,
                &mut u,
            )
            .unwrap();
        sht.inverse(&coefs, &mut x, &mut ws).unwrap();
        for j in 0..n {
            let y = x[n + j];
            x[j] += dt * (u[j] + y);
            x[n + j] += dt * u[n + j];
            x[2 * n + j] += dt * u[2 * n + j];
        }
        sht.forward(&x, &mut coefs, &mut ws).unwrap();
        match m.set_geometry(&coefs).and_then(|_| m.bending_energy(kappa)) {
            Ok(v) if v.is_finite() && v < 10.0 * e0 => {}
            _ => return false,
        }
    }
    true
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let p: usize = a[1].parse().unwrap();
    let kappa: f64 = a[2].parse().unwrap();
    let dts: Vec<f64> = if a.len() > 3 {
        a[3..].iter().map(|s| s.parse().unwrap()).collect()
    } else {
        vec![0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2]
    };
    for dt in dts {
        println!(
            "p {p} kappa {kappa} dt {dt}: stable {}",
            stable(p, kappa, dt)
        );
    }
}

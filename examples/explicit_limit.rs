//! Largest stable explicit time step of a prolate vesicle (reduced volume 0.9) in shear
//! (bending through the single layer, forward Euler, 2 time units):
//! `cargo run --release --example explicit_limit -- P KAPPA [DT ...]`.
use mobo::timestep::semi_implicit::{explicit_is_stable, ExplicitStepper};
use mobo::vesicle::shapes::{self, Spheroid};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let p: usize = a[1].parse().unwrap();
    let kappa: f64 = a[2].parse().unwrap();
    let dts: Vec<f64> = if a.len() > 3 {
        a[3..].iter().map(|s| s.parse().unwrap()).collect()
    } else {
        vec![0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2]
    };
    let s = shapes::reduced_volume_spheroid(p, 0.9, Spheroid::Prolate, 1.0).unwrap();
    for dt in dts {
        let mut st = ExplicitStepper::new(p, 2 * p, kappa, 1.0, dt).unwrap();
        let steps = (2.0 / dt) as usize;
        let ok = explicit_is_stable(&mut st, s.coefs(), steps, 10.0, &|x| [x[1], 0.0, 0.0]);
        println!("p {p} kappa {kappa} dt {dt}: stable {ok}");
    }
}

//! A prolate vesicle (reduced volume 0.9) in simple shear, semi-implicit steps:
//! `cargo run --release --example vesicle_shear -- [P] [DT] [STEPS]`. Prints time, inclination
//! angle of the longest inertia axis in the flow plane, area and volume drift, GMRES iterations.
use mobo::timestep::semi_implicit::VesicleParams;
use mobo::timestep::vesicle_stepper::VesicleStepper;
use mobo::timestep::GmresParams;
use mobo::vesicle::geometry::SurfaceCalculus;
use mobo::vesicle::reparam::ReparamParams;
use mobo::vesicle::shapes::{self, Spheroid};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let p: usize = a.get(1).map_or(8, |s| s.parse().unwrap());
    let dt: f64 = a.get(2).map_or(0.05, |s| s.parse().unwrap());
    let steps: usize = a.get(3).map_or(400, |s| s.parse().unwrap());
    let kappa: f64 = a.get(4).map_or(0.1, |s| s.parse().unwrap());
    let mut s = shapes::reduced_volume_spheroid(p, 0.9, Spheroid::Prolate, 1.0).unwrap();
    // Start inclined at 80° in the x–y plane.
    let t = 80f64.to_radians();
    s.rotate([
        [t.cos(), -t.sin(), 0.0],
        [t.sin(), t.cos(), 0.0],
        [0.0, 0.0, 1.0],
    ])
    .unwrap();
    let mut calc = SurfaceCalculus::new(p).unwrap();
    let g0 = calc.geometry(s.coefs()).unwrap();
    let (a0, v0) = (g0.area(), g0.volume());
    let params = VesicleParams {
        bending_modulus: kappa,
        viscosity: 1.0,
        force: [0.0; 3],
        dt,
        upsampled_order: 2 * p,
        gmres: GmresParams {
            tol: 1e-9,
            restart: 100,
            max_iters: 2000,
            ..Default::default()
        },
        correct_drift: std::env::var("MOBO_NO_DRIFT_CORRECTION").is_err(),
        reparametrize: std::env::var("MOBO_NO_REPARAM")
            .is_err()
            .then(|| ReparamParams {
                max_iterations: 10,
                ..Default::default()
            }),
        preconditioner: std::env::var("MOBO_NO_PRECONDITIONER").is_err(),
        scheme: mobo::timestep::semi_implicit::TimeScheme::Euler,
        viscosity_ratio: 1.0,
        inextensible: true,
        elastic_stepping: None,
    };
    let mut st = VesicleStepper::new(p, params).unwrap();
    let mut coefs = s.coefs().to_vec();
    let shear = |x: [f64; 3]| [x[1], 0.0, 0.0];
    for k in 1..=steps {
        let r = st.step(&mut coefs, &shear).unwrap();
        if k % (steps / 20).max(1) == 0 {
            let g = calc.geometry(&coefs).unwrap();
            let (_, axes) = g.principal_axes();
            let ax = axes[0];
            let angle = (ax[1] / ax[0]).atan().to_degrees();
            println!(
                "t {:7.3}  angle {:7.2}°  area drift {:.2e}  volume drift {:.2e}  gmres {}",
                k as f64 * dt,
                angle,
                (g.area() - a0) / a0,
                (g.volume() - v0) / v0,
                r.gmres.iterations
            );
        }
    }
}

//! GMRES iterations per step against shape and SH order (issue: whole steps cheaper, item
//! "iterations roughly independent of p and of the shape"): one cell in shear (rate 1, bending
//! modulus 0.05, dt 0.02, Euler, GMRES tolerance 1e-8, the sphere preconditioner turned with
//! the grid, drift correction and reparametrisation as in `mobo run`), for a sphere, prolates of
//! reduced volume 0.95 and 0.85, the biconcave RBC and the RBC with Skalak shear elasticity
//! (G_s = 0.2), at each order. Prints the iterations of the first step and the mean and largest
//! over the next STEPS, as a Markdown table.
//!
//! `PRECONDITIONER=cell:K` uses each cell's own operator instead of the sphere's, rebuilt after a
//! step of more than `K` iterations (`cell` alone: `K` = 8); the table then also gives the builds.
//!
//! ```text
//! cargo run --release --example gmres_by_shape [-- ORDERS STEPS]      (defaults: 6,8,12,16 20)
//! ```
use mobo::timestep::semi_implicit::{Preconditioning, TimeScheme, VesicleParams};
use mobo::timestep::vesicle_stepper::VesicleStepper;
use mobo::timestep::GmresParams;
use mobo::vesicle::reparam::ReparamParams;
use mobo::vesicle::shapes::{self, Spheroid};
use mobo::vesicle::skalak::SkalakParams;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let orders: Vec<usize> = a
        .first()
        .map_or("6,8,12,16", |s| s.as_str())
        .split(',')
        .map(|s| s.parse())
        .collect::<Result<_, _>>()?;
    let steps: usize = a.get(1).map_or(Ok(20), |s| s.parse())?;
    let preconditioning = match std::env::var("PRECONDITIONER").as_deref() {
        Err(_) | Ok("sphere") => Preconditioning::Sphere,
        Ok("cell") => Preconditioning::CELL,
        Ok(s) => match s.strip_prefix("cell:").map(str::parse) {
            Some(Ok(k)) => Preconditioning::Cell { rebuild_after: k },
            _ => return Err(format!("PRECONDITIONER={s}: expected sphere, cell or cell:K").into()),
        },
    };
    println!("preconditioner: {preconditioning:?}\n");
    println!(
        "| shape | p | first step | mean of the next {steps} | largest | s per step | builds |"
    );
    println!("|---|---|---|---|---|---|---|");
    for name in [
        "sphere",
        "prolate 0.95",
        "prolate 0.85",
        "RBC",
        "RBC Skalak",
    ] {
        for &p in &orders {
            let surface = match name {
                "sphere" => shapes::sphere(p, 1.0)?,
                "prolate 0.95" => shapes::reduced_volume_spheroid(p, 0.95, Spheroid::Prolate, 1.0)?,
                "prolate 0.85" => shapes::reduced_volume_spheroid(p, 0.85, Spheroid::Prolate, 1.0)?,
                _ => shapes::rbc(p)?,
            };
            let params = VesicleParams {
                bending_modulus: 0.05,
                viscosity: 1.0,
                force: [0.0; 3],
                dt: 0.02,
                upsampled_order: 2 * p,
                gmres: GmresParams::default(),
                correct_drift: true,
                reparametrize: Some(ReparamParams::default()),
                preconditioner: true,
                scheme: TimeScheme::Euler,
                viscosity_ratio: 1.0,
                inextensible: true,
                elastic_stepping: None,
            };
            let mut st = VesicleStepper::new(p, params)?;
            st.set_preconditioning(preconditioning);
            let mut c = surface.coefs().to_vec();
            if name == "RBC Skalak" {
                st.set_skalak(SkalakParams::skalak(0.2, 10.0), &c)?;
            }
            let shear = |x: [f64; 3]| [x[1], 0.0, 0.0];
            let first = st.step(&mut c, &shear)?.gmres.iterations;
            let t = std::time::Instant::now();
            let its: Vec<usize> = (0..steps)
                .map(|_| st.step(&mut c, &shear).map(|r| r.gmres.iterations))
                .collect::<Result<_, _>>()?;
            let secs = t.elapsed().as_secs_f64() / steps as f64;
            let mean = its.iter().sum::<usize>() as f64 / steps as f64;
            let max = its.iter().max().copied().unwrap_or(0);
            let builds = st.own_preconditioner_builds();
            println!("| {name} | {p} | {first} | {mean:.1} | {max} | {secs:.3} | {builds} |");
        }
    }
    Ok(())
}

//! The coupling's FMM error: the inter-cell velocities of the step benchmark's suspension (RBCs
//! placed at random at 5 % volume fraction) with a smooth traction, at 6 FMM digits (the
//! default) against 10 digits, max-norm relative, and the time of each. Also what
//! benches/RESULTS.md quotes for the coupling's leaf size.
//!   cargo run --release --example coupling_fmm_error -- P CELLS   (default 6 300)
use mobo::scene::cells;
use mobo::sph_harmonics::ShTransform;
use mobo::timestep::coupling::{Coupling, CouplingParams};
use std::path::Path;

fn main() {
    let p: usize = std::env::args()
        .nth(1)
        .map(|s| s.parse().unwrap())
        .unwrap_or(6);
    let n: usize = std::env::args()
        .nth(2)
        .map(|s| s.parse().unwrap())
        .unwrap_or(300);
    let side = (n as f64 * 4.0 / 3.0 * std::f64::consts::PI / 0.05).cbrt();
    let h = side / 2.0;
    let text = format!(
        "[flow]\nkind = \"shear\"\nrate = 1.0\n[[cells]]\nshape = \"rbc\"\nbending_modulus = 0.1\nshear_modulus = 1.0\ncount = {n}\nplacement = \"random\"\nseed = 11\nregion = [[{m}, {m}, {m}], [{h}, {h}, {h}]]\n[numerics]\norder = {p}\n",
        m = -h
    );
    let scene = cells::parse(Path::new("s.toml"), &text).unwrap();
    let sht = ShTransform::new(p).unwrap();
    let np = sht.n_points();
    let coefs: Vec<Vec<f64>> = scene
        .cells
        .iter()
        .map(|c| c.surface(p).unwrap().coefs().to_vec())
        .collect();
    let tractions: Vec<Vec<f64>> = coefs
        .iter()
        .map(|c| {
            let mut x = vec![0.0; 3 * np];
            sht.inverse(c, &mut x, &mut sht.workspace()).unwrap();
            (0..3 * np)
                .map(|i| ((i as f64) * 0.37 + x[i % np] * 1.3).sin())
                .collect()
        })
        .collect();
    let cr: Vec<&[f64]> = coefs.iter().map(|c| c.as_slice()).collect();
    let tr: Vec<&[f64]> = tractions.iter().map(|c| c.as_slice()).collect();
    let run = |d: u32| {
        let mut c = Coupling::new(
            p,
            2 * p,
            CouplingParams {
                fmm_digits: d,
                ..Default::default()
            },
        )
        .unwrap();
        let t = std::time::Instant::now();
        let u = c.velocities(&cr, &tr).unwrap();
        (u.concat(), t.elapsed().as_secs_f64())
    };
    let (u6, t6) = run(6);
    let (u10, t10) = run(10);
    let scale = u10.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let err = u6
        .iter()
        .zip(&u10)
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    println!("p {p} cells {n}: max|u6 - u10| / max|u10| = {:.3e} (6 digits {t6:.2} s, 10 digits {t10:.2} s)", err / scale);
}

//! Accuracy and time of the reference KIFMM against direct sums:
//! `cargo run --release --example kifmm_probe -- N`.
use mobo::fmm::kernels::StokesletSource;
use mobo::fmm::kifmm::Kifmm;
use mobo::fmm::{direct_sum, Kernel, Laplace, LaplaceDoubleLayer, Stokeslet, Stresslet, SumInput};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::time::Instant;

fn run<KS: Kernel, KE: Kernel>(ks: &KS, ke: &KE, pts: &[[f64; 3]], nrm: &[[f64; 3]], order: usize) {
    let mut rng = StdRng::seed_from_u64(9);
    let dens: Vec<f64> = (0..pts.len() * ks.density_dim())
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let t0 = Instant::now();
    let fmm = Kifmm::new(ks, ke, pts, Some(nrm), pts, order, 60).unwrap();
    let setup = t0.elapsed().as_secs_f64();
    let mut u = vec![0.0; pts.len() * ks.output_dim()];
    let t1 = Instant::now();
    fmm.evaluate(&dens, &mut u).unwrap();
    let ev = t1.elapsed().as_secs_f64();
    let mut want = vec![0.0; u.len()];
    direct_sum(
        ks,
        &SumInput {
            sources: pts,
            density: &dens,
            normals: Some(nrm),
            targets: pts,
        },
        &mut want,
    )
    .unwrap();
    let err = (u
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        / want.iter().map(|b| b * b).sum::<f64>())
    .sqrt();
    println!(
        "{:>10} p={order:2}: rel L2 error {err:.2e}, setup {setup:.2}s, eval {ev:.2}s",
        ks.name()
    );
}

fn main() {
    let n: usize = std::env::args().nth(1).map_or(3000, |s| s.parse().unwrap());
    let mut rng = StdRng::seed_from_u64(1);
    let pts: Vec<[f64; 3]> = (0..n)
        .map(|_| [rng.random(), rng.random(), rng.random()])
        .collect();
    let nrm: Vec<[f64; 3]> = (0..n)
        .map(|_| {
            [
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            ]
        })
        .collect();
    for p in [4, 6, 8, 10] {
        run(&Laplace, &Laplace, &pts, &nrm, p);
    }
    run(&LaplaceDoubleLayer, &Laplace, &pts, &nrm, 6);
    run(&Stokeslet, &Stokeslet, &pts, &nrm, 6);
    run(&Stresslet, &StokesletSource, &pts, &nrm, 6);
    run(&Stokeslet, &Stokeslet, &pts, &nrm, 8);
}

//! The reference KIFMM against direct sums on uniform, clustered and cell-surface clouds.

use mobo::fmm::clouds::Cloud;
use mobo::fmm::kernels::StokesletSource;
use mobo::fmm::kifmm::Kifmm;
use mobo::fmm::{direct_sum, Kernel, Laplace, LaplaceDoubleLayer, Stokeslet, Stresslet, SumInput};

fn cloud(kind: &str, n: usize, seed: u64) -> Vec<[f64; 3]> {
    Cloud::from_name(kind).expect("known cloud").points(n, seed)
}

fn rel_l2(a: &[f64], b: &[f64]) -> f64 {
    (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>()
        / b.iter().map(|y| y * y).sum::<f64>())
    .sqrt()
}

fn error<KS: Kernel, KE: Kernel>(
    ks: &KS,
    ke: &KE,
    pts: &[[f64; 3]],
    tgt: &[[f64; 3]],
    order: usize,
) -> f64 {
    let dens = Cloud::densities(pts.len() * ks.density_dim(), 4);
    let nrm = cloud("uniform", pts.len(), 5);
    let fmm = Kifmm::new(ks, ke, pts, Some(&nrm), tgt, order, 50).unwrap();
    let mut u = vec![0.0; tgt.len() * ks.output_dim()];
    fmm.evaluate(&dens, &mut u).unwrap();
    let mut want = vec![0.0; u.len()];
    let input = SumInput {
        sources: pts,
        density: &dens,
        normals: Some(&nrm),
        targets: tgt,
    };
    direct_sum(ks, &input, &mut want).unwrap();
    rel_l2(&u, &want)
}

#[test]
fn laplace_reaches_three_and_six_digits_on_every_cloud() {
    for kind in ["uniform", "blobs", "spheres"] {
        let pts = cloud(kind, 1500, 1);
        let e4 = error(&Laplace, &Laplace, &pts, &pts, 4);
        let e8 = error(&Laplace, &Laplace, &pts, &pts, 8);
        println!("{kind}: p=4 {e4:.2e}, p=8 {e8:.2e}");
        assert!(e4 < 1e-3, "{kind} p=4: {e4}");
        assert!(e8 < 1e-6, "{kind} p=8: {e8}");
    }
}

#[test]
fn double_layer_and_stokes_kernels_reach_three_digits() {
    for kind in ["uniform", "spheres"] {
        let pts = cloud(kind, 1200, 2);
        let tgt = cloud("uniform", 300, 3);
        let cases = [
            (
                "laplace-dl",
                error(&LaplaceDoubleLayer, &Laplace, &pts, &tgt, 6),
            ),
            ("stokeslet", error(&Stokeslet, &Stokeslet, &pts, &pts, 6)),
            (
                "stresslet",
                error(&Stresslet, &StokesletSource, &pts, &pts, 6),
            ),
        ];
        for (name, e) in cases {
            println!("{kind} {name}: p=6 {e:.2e}");
            assert!(e < 1e-3, "{kind} {name}: {e}");
        }
    }
}

#[test]
fn error_decreases_with_order_and_reuse_matches_fresh_build() {
    let pts = cloud("uniform", 1000, 6);
    let errs: Vec<f64> = [3, 4, 6, 8]
        .iter()
        .map(|&p| error(&Stokeslet, &Stokeslet, &pts, &pts, p))
        .collect();
    println!("Stokeslet error vs order 3/4/6/8: {errs:?}");
    assert!(errs.windows(2).all(|w| w[1] < w[0]), "{errs:?}");
    // One tree, two densities: same as separate builds.
    let fmm = Kifmm::new(&Laplace, &Laplace, &pts, None, &pts, 5, 40).unwrap();
    let d1: Vec<f64> = (0..pts.len()).map(|i| (i as f64).sin()).collect();
    let d2: Vec<f64> = (0..pts.len()).map(|i| (i as f64 * 0.3).cos()).collect();
    let (mut a, mut b, mut c) = (
        vec![0.0; pts.len()],
        vec![0.0; pts.len()],
        vec![0.0; pts.len()],
    );
    fmm.evaluate(&d1, &mut a).unwrap();
    fmm.evaluate(&d2, &mut b).unwrap();
    Kifmm::new(&Laplace, &Laplace, &pts, None, &pts, 5, 40)
        .unwrap()
        .evaluate(&d2, &mut c)
        .unwrap();
    assert_eq!(b, c);
    assert_ne!(a, b);
}

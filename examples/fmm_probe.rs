//! Accuracy and time of the FMM against direct sums on sampled targets:
//! `cargo run --release --example fmm_probe -- KERNEL CLOUD N ORDER [LEAF]`.
use mobo::fmm::clouds::Cloud;
use mobo::fmm::{Fmm, FmmKernel};
use std::time::Instant;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let kernel = FmmKernel::from_name(&a[1], Some(0.002)).unwrap();
    let cloud = Cloud::from_name(&a[2]).unwrap();
    let n: usize = a[3].parse().unwrap();
    let order: usize = a[4].parse().unwrap();
    let leaf: usize = a
        .get(5)
        .map_or(kernel.default_leaf_size(order), |s| s.parse().unwrap());
    let pts = cloud.points(n, 1);
    let nrm = Cloud::unit_vectors(n, 2);
    let k = kernel.near();
    let dens = Cloud::densities(n * k.density_dim(), 3);
    let t0 = Instant::now();
    let mut fmm = Fmm::new(kernel, &pts, Some(&nrm), &pts, order, leaf).unwrap();
    let setup = t0.elapsed().as_secs_f64();
    let mut u = vec![0.0; n * k.output_dim()];
    fmm.evaluate(&dens, &mut u).unwrap();
    let tm = fmm.timings;
    // Direct sum on 200 sampled targets.
    let m = 200.min(n);
    let idx: Vec<usize> = (0..m).map(|i| i * n / m).collect();
    let tg: Vec<[f64; 3]> = idx.iter().map(|&i| pts[i]).collect();
    let mut exact = Fmm::new(kernel, &pts, Some(&nrm), &tg, 2, n + m).unwrap();
    let mut want = vec![0.0; m * k.output_dim()];
    exact.direct(&dens, &mut want).unwrap();
    let od = k.output_dim();
    let (mut num, mut den) = (0.0, 0.0);
    for (s, &i) in idx.iter().enumerate() {
        for c in 0..od {
            num += (u[i * od + c] - want[s * od + c]).powi(2);
            den += want[s * od + c].powi(2);
        }
    }
    println!(
        "{} {} n={n} p={order} leaf={leaf} depth={} boxes={}: err {:.2e} setup {setup:.2}s eval {:.3}s",
        a[1],
        a[2],
        fmm.tree.depth(),
        fmm.tree.boxes.len(),
        (num / den).sqrt(),
        tm.total
    );
    println!("  {tm:?}");
}

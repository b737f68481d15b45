//! Criterion benchmarks of the FMM: the P2P kernels (pairs per second, the near-field
//! throughput) and full evaluations of the FMM on 10⁴–10⁵ points of three clouds, next to the
//! machine's GEMM rate measured in the same run.
//! `cargo bench --bench fmm`; the comparison with FMM3D is `benches/fmm_vs_fmm3d.py`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use mobo::fmm::blocks::SourceBlock;
use mobo::fmm::clouds::Cloud;
use mobo::fmm::{order_for_digits, Fmm, FmmKernel};

fn p2p(c: &mut Criterion) {
    let n = 1024;
    let pts = Cloud::Uniform.points(n, 1);
    let mut g = c.benchmark_group("p2p");
    g.throughput(Throughput::Elements((n * n) as u64));
    for kernel in [
        FmmKernel::Laplace,
        FmmKernel::Stokeslet,
        FmmKernel::Stresslet,
        FmmKernel::Rpy { radius: 0.01 },
    ] {
        let k = kernel.near();
        let dd = k.density_dim();
        let order: Vec<usize> = (0..n).collect();
        let mut src = SourceBlock::new(&pts, Some(&Cloud::unit_vectors(n, 2)), &order);
        src.set_density(&Cloud::densities(n * dd, 3), dd, &order);
        let mut out = vec![0.0; n * k.output_dim()];
        g.bench_function(format!("{kernel:?}"), |b| {
            b.iter(|| k.eval_block(&pts, &src.all(), &mut out))
        });
    }
    g.finish();
}

fn evaluate(c: &mut Criterion) {
    let mut g = c.benchmark_group("fmm_evaluate");
    g.sample_size(10);
    for (kernel, n) in [
        (FmmKernel::Laplace, 100_000),
        (FmmKernel::Stokeslet, 20_000),
        (FmmKernel::Stokeslet, 100_000),
    ] {
        for cloud in [Cloud::Uniform, Cloud::Spheres] {
            let pts = cloud.points(n, 1);
            let k = kernel.near();
            let dens = Cloud::densities(n * k.density_dim(), 2);
            let order = order_for_digits(kernel, 6).unwrap();
            let mut fmm = Fmm::new(
                kernel,
                &pts,
                None,
                &pts,
                order,
                kernel.default_leaf_size(order),
            )
            .unwrap();
            let mut out = vec![0.0; n * k.output_dim()];
            g.throughput(Throughput::Elements(n as u64));
            g.bench_function(format!("{kernel:?}/{}/{n}/6digits", cloud.name()), |b| {
                b.iter(|| fmm.evaluate(&dens, &mut out).unwrap())
            });
        }
    }
    g.finish();
}

criterion_group!(benches, p2p, evaluate);
criterion_main!(benches);

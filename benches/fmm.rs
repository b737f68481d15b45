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

/// The Laplace and Stokeslet P2P loops on each instruction set this CPU has (one core,
/// 1024 × 1024 pairs): `cargo bench --bench fmm -- p2p_simd`.
fn p2p_simd(c: &mut Criterion) {
    use mobo::fmm::p2p::{self, Simd};
    let n = 1024;
    let pts = Cloud::Uniform.points(n, 1);
    let order: Vec<usize> = (0..n).collect();
    let mut g = c.benchmark_group("p2p_simd");
    g.throughput(Throughput::Elements((n * n) as u64));
    for simd in [Simd::Portable, Simd::Avx2, Simd::Avx512] {
        if !simd.available() {
            continue;
        }
        for dd in [1, 3] {
            let mut src = SourceBlock::new(&pts, None, &order);
            src.set_density(&Cloud::densities(n * dd, 3), dd, &order);
            let mut out = vec![0.0; n * dd];
            let name = if dd == 1 { "Laplace" } else { "Stokeslet" };
            g.bench_function(format!("{name}/{simd:?}"), |b| {
                b.iter(|| {
                    if dd == 1 {
                        p2p::laplace_on(simd, &pts, &src.all(), &mut out)
                    } else {
                        p2p::stokeslet_on(simd, &pts, &src.all(), &mut out)
                    }
                })
            });
        }
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

/// `cargo bench --features gpu --bench fmm -- gpu`: pairs per second of every kernel on the GPU
/// (the kernel alone, all pairs of 16384 points, f32 and f64 where offered) next to the CPU's AVX2
/// loop on the same points in the same run, and the FMM on 10⁵ points at 3 and 6 digits with
/// and without the GPU near field. The 10⁶-point runs and the rates as a fraction of peak are
/// `scripts/gpu_bench.sh`.
#[cfg(feature = "gpu")]
fn gpu(c: &mut Criterion) {
    use mobo::fmm::gpu_near::{choose, gpu_kernel, GPU_LEAF_FACTOR};
    use mobo::gpu::p2p::{PairPoints, PairSum};
    use mobo::gpu::{Gpu, GpuChoice, GpuPrecision};
    use std::time::Duration;
    let Ok(dev) = Gpu::shared() else {
        eprintln!("no GPU adapter: the gpu benchmarks are skipped");
        return;
    };
    let n = 16384;
    let pts = Cloud::Uniform.points(n, 1);
    let nrm = Cloud::unit_vectors(n, 2);
    let order: Vec<usize> = (0..n).collect();
    let mut g = c.benchmark_group("gpu_p2p");
    g.sample_size(10);
    for kernel in [
        FmmKernel::Laplace,
        FmmKernel::LaplaceDoubleLayer,
        FmmKernel::Stokeslet,
        FmmKernel::Stresslet,
        FmmKernel::Rpy { radius: 0.002 },
    ] {
        let k = kernel.near();
        let dd = k.density_dim();
        let mut src = SourceBlock::new(&pts, Some(&nrm), &order);
        src.set_density(&Cloud::densities(n * dd, 3), dd, &order);
        // The CPU loop on 1024 targets against all sources, on this thread.
        let nt = 1024;
        let mut out = vec![0.0; nt * k.output_dim()];
        g.throughput(Throughput::Elements((nt * n) as u64));
        g.bench_function(format!("cpu/{kernel:?}"), |b| {
            b.iter(|| k.eval_block(&pts[..nt], &src.all(), &mut out))
        });
        for prec in [GpuPrecision::F32, GpuPrecision::F64] {
            if prec == GpuPrecision::F64 && !dev.has_f64() {
                continue;
            }
            let points = PairPoints {
                sources: &pts,
                normals: Some(&nrm),
                targets: &pts,
            };
            let sum = PairSum::all_pairs(dev.clone(), gpu_kernel(kernel), prec, points).unwrap();
            let q: Vec<&[f64]> = src.q[..dd].iter().map(|c| c.as_slice()).collect();
            let mut o = vec![0.0; n * k.output_dim()];
            sum.evaluate(&q, &mut o).unwrap();
            g.throughput(Throughput::Elements((n * n) as u64));
            g.bench_function(format!("gpu_{}/{kernel:?}", prec.name()), |b| {
                b.iter_custom(|iters| {
                    Duration::from_secs_f64(sum.time_kernel(iters as usize).unwrap() * iters as f64)
                })
            });
        }
    }
    g.finish();
    let mut g = c.benchmark_group("gpu_fmm");
    g.sample_size(10);
    let n = 100_000;
    let pts = Cloud::Spheres.points(n, 1);
    for kernel in [FmmKernel::Laplace, FmmKernel::Stokeslet] {
        let k = kernel.near();
        let dens = Cloud::densities(n * k.density_dim(), 2);
        for digits in [3, 6] {
            let order = order_for_digits(kernel, digits).unwrap();
            for on_gpu in [false, true] {
                let leaf =
                    kernel.default_leaf_size(order) * if on_gpu { GPU_LEAF_FACTOR } else { 1 };
                let mut fmm = Fmm::new(kernel, &pts, None, &pts, order, leaf).unwrap();
                if on_gpu {
                    choose(&mut fmm, GpuChoice::On, None, Some(digits)).unwrap();
                }
                let mut out = vec![0.0; n * k.output_dim()];
                g.throughput(Throughput::Elements(n as u64));
                let name = if on_gpu { "gpu" } else { "cpu" };
                g.bench_function(format!("{kernel:?}/{digits}digits/{name}"), |b| {
                    b.iter(|| fmm.evaluate(&dens, &mut out).unwrap())
                });
            }
        }
    }
    g.finish();
}

#[cfg(not(feature = "gpu"))]
fn gpu(_c: &mut Criterion) {
    eprintln!("built without the gpu feature: the gpu benchmarks are skipped");
}

criterion_group!(benches, p2p, p2p_simd, evaluate, gpu);
criterion_main!(benches);

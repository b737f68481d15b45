//! Criterion benches of the spherical-harmonic transforms and rotations.
//!
//! Throughput is given in "elements" = flops: for transforms, the Legendre GEMM flops (so the
//! reported Gelem/s is the GEMM part's GFLOP/s over the whole wall time, FFTs included); for the
//! `gemm` group, faer's own 512² GEMM (`2n³` flops), measured in the same run as the reference.
//! For a table with ratios, run `cargo bench --bench sph_table`.

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, Par};
use mobo::sph_harmonics::{Deriv, DirectRotation, ShRotation, ShTransform};

fn gemm(c: &mut Criterion) {
    let mut g = c.benchmark_group("gemm");
    g.sample_size(20).measurement_time(Duration::from_secs(3));
    let n = 512;
    let a = Mat::<f64>::from_fn(n, n, |i, j| ((i + 2 * j) % 7) as f64);
    let b = Mat::<f64>::from_fn(n, n, |i, j| ((3 * i + j) % 5) as f64);
    let mut out = Mat::<f64>::zeros(n, n);
    g.throughput(Throughput::Elements(2 * (n * n * n) as u64));
    g.bench_function("faer_512_seq", |bch| {
        bch.iter(|| {
            matmul(
                out.as_mut(),
                Accum::Replace,
                a.as_ref(),
                b.as_ref(),
                1.0,
                Par::Seq,
            )
        })
    });
    g.finish();
}

fn transforms(c: &mut Criterion) {
    let mut g = c.benchmark_group("sht");
    g.sample_size(10).measurement_time(Duration::from_secs(3));
    for p in [6, 12, 16, 32] {
        let sht = ShTransform::new(p).unwrap();
        let mut ws = sht.workspace();
        for surfaces in [1usize, 100, 10_000] {
            let nf = 3 * surfaces;
            let mut grid: Vec<f64> = (0..nf * sht.n_points())
                .map(|i| ((i % 89) as f64).cos())
                .collect();
            let mut coefs = vec![0.0; nf * sht.n_coefs()];
            let id = format!("p{p}/surfaces{surfaces}");
            g.throughput(Throughput::Elements((2.0 * sht.legendre_flops(nf)) as u64));
            g.bench_function(BenchmarkId::new("forward+inverse", &id), |b| {
                b.iter(|| {
                    sht.forward(&grid, &mut coefs, &mut ws).unwrap();
                    sht.inverse(&coefs, &mut grid, &mut ws).unwrap();
                })
            });
            let mut dt = vec![0.0; grid.len()];
            let mut dp = vec![0.0; grid.len()];
            // ∂θ needs one GEMM pass with the derivative matrices, ∂φ one with the values.
            g.throughput(Throughput::Elements((2.0 * sht.legendre_flops(nf)) as u64));
            g.bench_function(BenchmarkId::new("first_derivatives", &id), |b| {
                b.iter(|| {
                    sht.synthesize(
                        &coefs,
                        &[Deriv::Theta, Deriv::Phi],
                        &mut [&mut dt, &mut dp],
                        &mut ws,
                    )
                    .unwrap()
                })
            });
        }
    }
    g.finish();
}

fn rotations(c: &mut Criterion) {
    let mut g = c.benchmark_group("rotation");
    g.sample_size(10).measurement_time(Duration::from_secs(3));
    for p in [6, 12, 16] {
        let q = 2 * p;
        let sht = ShTransform::new(p).unwrap();
        let nf = 3;
        let coefs: Vec<f64> = (0..nf * sht.n_coefs()).map(|i| (i as f64).sin()).collect();
        let mut grid = vec![0.0; nf * sht.n_points()];
        sht.inverse(&coefs, &mut grid, &mut sht.workspace())
            .unwrap();
        let mut out = vec![0.0; nf * 2 * q * (q + 1)];
        let targets: Vec<(usize, usize)> = (0..=p)
            .flat_map(|i| (0..2 * p).map(move |k| (i, k)))
            .collect();
        let mut direct = DirectRotation::new(p, q).unwrap();
        let flops = 2 * 2 * q * (q + 1) * sht.n_points() * nf * targets.len();
        g.throughput(Throughput::Elements(flops as u64));
        g.bench_function(
            BenchmarkId::new("direct_all_targets", format!("p{p}/q{q}")),
            |b| {
                b.iter(|| {
                    for &(i, k) in &targets {
                        direct.apply(i, k, &grid, &mut out).unwrap();
                    }
                    black_box(&out);
                })
            },
        );
        let mut via = ShRotation::new(p, q).unwrap();
        g.throughput(Throughput::Elements(targets.len() as u64));
        g.bench_function(
            BenchmarkId::new("via_sh_all_targets", format!("p{p}/q{q}")),
            |b| {
                b.iter(|| {
                    for &(i, k) in &targets {
                        via.apply(i, k, &coefs, &mut out).unwrap();
                    }
                    black_box(&out);
                })
            },
        );
    }
    g.finish();
}

criterion_group!(benches, gemm, transforms, rotations);
criterion_main!(benches);

//! A wall's layer potential at a cell's points: the smooth sums over its upsampled rule, one
//! target at a time (the loop `OffSurface` used until 2026-12-06) against the block sums of
//! `SmoothSources` (structure of arrays, cache-sized blocks, vectorised kernels), and the whole
//! off-surface evaluation of a tube wall at a capsule's grid points, beside faer's GEMM rate
//! measured in the same run.
//!
//! `cargo bench --bench off_surface`. One thread (rayon's pool is built with one).
//!
//! The scene is the capsule-in-a-tube case of docs/walls.md: a tube of radius 1.111 and length
//! 12 at order 44 (far rule of order 264: 140 185 nodes), the double layer of a smooth density,
//! the targets the 144 grid points of a unit sphere on its axis (a/R = 0.9). A stresslet pair
//! is counted as 30 flops (the GEMM-equivalent column: pairs × 30 / GEMM rate).

mod common;

use std::hint::black_box;

use common::{best_of, gemm_rate};
use faer::Par;
use mobo::sph_harmonics::{resample_coefs, CoefLayout, ShTransform};
use mobo::vesicle::smooth_sources::SmoothSources;
use mobo::vesicle::{shapes, Geometry, LayerKernel, NearParams, OffSurface, SurfaceCalculus};
use mobo::wall::tube_surface;

const FLOPS_PER_PAIR: f64 = 30.0;

/// The per-target loop over an array of structures (the reference).
fn one_at_a_time(g: &Geometry, dens: &[f64], x: [f64; 3]) -> [f64; 3] {
    let nq = g.n_points();
    let mut u = [0.0; 3];
    for j in 0..nq {
        let r = [x[0] - g.x[j][0], x[1] - g.x[j][1], x[2] - g.x[j][2]];
        let r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
        let f = [dens[j], dens[nq + j], dens[2 * nq + j]];
        let rinv = 1.0 / r2.sqrt();
        let n = g.normal[j];
        let s = (r[0] * n[0] + r[1] * n[1] + r[2] * n[2])
            * (r[0] * f[0] + r[1] * f[1] + r[2] * f[2])
            * rinv.powi(5)
            * g.da[j];
        for c in 0..3 {
            u[c] += s * r[c];
        }
    }
    u.map(|v| v * 3.0 / (4.0 * std::f64::consts::PI))
}

fn main() {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("one-thread pool");
    pool.install(run);
}

fn run() {
    let gemm = gemm_rate(512, Par::Seq);
    println!("faer GEMM 512² (1 thread): {gemm:.1} GFLOP/s\n");
    let (pw, radius, length) = (44, 1.0 / 0.9, 12.0);
    let tube = tube_surface(pw, radius, length).expect("tube");
    let q = 6 * pw;
    let mut coefs_q = vec![0.0; 3 * CoefLayout::new(q).len()];
    resample_coefs(
        &CoefLayout::new(pw),
        &CoefLayout::new(q),
        tube.coefs(),
        &mut coefs_q,
    )
    .expect("resample");
    let mut g = Geometry::zeros(q);
    SurfaceCalculus::new(q)
        .expect("calculus")
        .update_geometry(&coefs_q, &mut g)
        .expect("geometry");
    let nq = g.n_points();
    // A smooth density: Poiseuille-like along the axis, varying around it.
    let dens_of = |x: [f64; 3]| [1.0 - (x[1] * x[1] + x[2] * x[2]), 0.1 * x[0], 0.05 * x[2]];
    let mut dens = vec![0.0; 3 * nq];
    for (j, x) in g.x.iter().enumerate() {
        let d = dens_of(*x);
        for c in 0..3 {
            dens[c * nq + j] = d[c];
        }
    }
    let cell = shapes::sphere(8, 1.0).expect("sphere");
    let sht8 = ShTransform::new(8).expect("sht");
    let pos = cell.grid_positions(&sht8).expect("positions");
    let np = sht8.n_points();
    let targets: Vec<[f64; 3]> = (0..np)
        .map(|i| [pos[i], pos[np + i], pos[2 * np + i]])
        .collect();
    // Each target with the 12 check points of a near target: 13 points per target.
    let many: Vec<[f64; 3]> = (0..13)
        .flat_map(|k| {
            targets
                .iter()
                .map(move |x| x.map(|c| c * (1.0 - 0.005 * k as f64)))
        })
        .collect();
    let pairs = (many.len() * nq) as f64;

    let mut want = vec![[0.0; 3]; many.len()];
    let t_ref = best_of(3, 0.0, || {
        for (w, &x) in want.iter_mut().zip(&many) {
            *w = one_at_a_time(&g, &dens, x);
        }
        black_box(&want);
    });
    let mut src = SmoothSources::new();
    src.set_geometry(&g);
    src.set_density(&dens).expect("density");
    let mut got = vec![0.0; 3 * many.len()];
    let t_blk = best_of(3, 0.0, || {
        got.fill(0.0);
        src.add_to(LayerKernel::DoubleLayer, &many, &mut got)
            .expect("block sums");
        black_box(&got);
    });
    let mut err: f64 = 0.0;
    let size = want
        .iter()
        .flat_map(|w| w.iter())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    for (i, w) in want.iter().enumerate() {
        for c in 0..3 {
            err = err.max((got[3 * i + c] - w[c]).abs() / size);
        }
    }
    println!(
        "Smooth sums of a tube wall's double layer (order {q} rule: {nq} nodes) at {} points:\n",
        many.len()
    );
    println!("| loop | seconds | pairs/s | GFLOP/s (30 a pair) | × GEMM |");
    println!("|---|---|---|---|---|");
    for (name, t) in [
        ("one target at a time (array of structures)", t_ref),
        ("SmoothSources blocks (structure of arrays, SIMD)", t_blk),
    ] {
        let rate = pairs / t;
        println!(
            "| {name} | {t:.3} | {:.3e} | {:.1} | {:.2} |",
            rate,
            rate * FLOPS_PER_PAIR / 1e9,
            rate * FLOPS_PER_PAIR / 1e9 / gemm
        );
    }
    println!(
        "\nspeed-up {:.1}x; largest difference {err:.1e} of the largest value\n",
        t_ref / t_blk
    );

    // The whole off-surface evaluation at the sphere's grid points.
    let mut near = OffSurface::new(pw, NearParams::default()).expect("off-surface");
    near.set_surface(tube.coefs()).expect("surface");
    let shtw = ShTransform::new(pw).expect("sht");
    let gw = tube.grid_positions(&shtw).expect("positions");
    let nw = shtw.n_points();
    let mut dw = vec![0.0; 3 * nw];
    for j in 0..nw {
        let d = dens_of([gw[j], gw[nw + j], gw[2 * nw + j]]);
        for c in 0..3 {
            dw[c * nw + j] = d[c];
        }
    }
    // The on-surface values a wall's solve holds (`WallSolution::own_double_layer`; their
    // values do not change the cost, so zeros stand in for them here).
    let on_surface = vec![0.0; 3 * nw];
    let mut out = vec![0.0; 3 * targets.len()];
    let mut infos = vec![];
    let t_eval = best_of(3, 0.0, || {
        infos = near
            .evaluate_given_on_surface(
                LayerKernel::DoubleLayer,
                &dw,
                &on_surface,
                &targets,
                &mut out,
            )
            .expect("evaluate");
    });
    let n_near = infos.iter().filter(|i| i.near).count();
    println!(
        "OffSurface::evaluate_given_on_surface (as a tube flow's step calls it), the tube's \
         double layer at the {} grid points of the sphere ({n_near} within the near zone \
         δ = {:.3}): {:.3} s",
        targets.len(),
        near.near_distance(),
        t_eval
    );
}

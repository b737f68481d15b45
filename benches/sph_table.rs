//! Table of spherical-harmonic transform speed against faer's GEMM rate, measured in one run.
//!
//! `cargo bench --bench sph_table` (add `-- --quick` for fewer sizes). Prints a Markdown table:
//! for each order `p` and batch size (surfaces × 3 components), the time of forward + inverse,
//! the Legendre GEMM flops divided by that whole time ("end-to-end GFLOP/s", FFTs and data
//! movement included), the same flops divided by the time of the GEMM calls alone, and the ratio
//! to faer's 512² GEMM rate measured in the same process, on 1 thread and on all threads.

mod common;

use std::hint::black_box;

use common::{best_of, gemm_rate};
use faer::Par;
use mobo::sph_harmonics::{Deriv, DirectRotation, ShRotation, ShTransform};

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let threads = rayon::current_num_threads();
    let g1 = gemm_rate(512, Par::Seq);
    let gp = gemm_rate(512, Par::rayon(threads));
    println!("faer GEMM 512²: {g1:.1} GFLOP/s (1 thread), {gp:.1} GFLOP/s ({threads} threads)\n");
    println!("| p | surfaces | fwd+inv 1 thr (ms) | end-to-end GFLOP/s | / GEMM | fwd+inv {threads} thr (ms) | GFLOP/s | / GEMM | derivs (θ,φ) 1 thr (ms) |");
    println!("|---|---|---|---|---|---|---|---|---|");
    let orders: &[usize] = if quick { &[6, 16] } else { &[6, 12, 16, 32] };
    let counts: &[usize] = if quick {
        &[1, 10_000]
    } else {
        &[1, 100, 10_000]
    };
    for &p in orders {
        let sht = ShTransform::new(p).unwrap();
        for &ns in counts {
            let nf = 3 * ns;
            let mut grid: Vec<f64> = (0..nf * sht.n_points())
                .map(|i| ((i % 97) as f64).sin())
                .collect();
            let mut coefs = vec![0.0; nf * sht.n_coefs()];
            let mut ws = sht.workspace();
            let flops = 2.0 * sht.legendre_flops(nf);
            let reps = if ns >= 10_000 { 5 } else { 20 };
            let t1 = best_of(reps, 0.5, || {
                sht.forward(&grid, &mut coefs, &mut ws).unwrap();
                sht.inverse(&coefs, &mut grid, &mut ws).unwrap();
            });
            let tp = best_of(reps, 0.5, || {
                sht.forward_par(&grid, &mut coefs).unwrap();
                sht.inverse_par(&coefs, &mut grid).unwrap();
            });
            let mut dt = vec![0.0; grid.len()];
            let mut dp = vec![0.0; grid.len()];
            let td = best_of(reps, 0.5, || {
                sht.synthesize(
                    &coefs,
                    &[Deriv::Theta, Deriv::Phi],
                    &mut [&mut dt, &mut dp],
                    &mut ws,
                )
                .unwrap();
            });
            let r1 = flops / t1 / 1e9;
            let rp = flops / tp / 1e9;
            println!(
                "| {p} | {ns} | {:.3} | {r1:.1} | {:.0}% | {:.3} | {rp:.1} | {:.0}% | {:.3} |",
                t1 * 1e3,
                100.0 * r1 / g1,
                tp * 1e3,
                100.0 * rp / gp,
                td * 1e3
            );
        }
    }
    println!(
        "\nRotations to the pole, all 2p(p+1) targets of one surface × 3 components, 1 thread:\n"
    );
    println!("| p | q | direct (ms) | direct GFLOP/s | direct memory (MB) | via SH (ms) | via SH memory (MB) |");
    println!("|---|---|---|---|---|---|---|");
    let rot_orders: &[usize] = if quick { &[6, 12] } else { &[6, 12, 16] };
    for &p in rot_orders {
        let q = 2 * p;
        let sht = ShTransform::new(p).unwrap();
        let nf = 3;
        let coefs: Vec<f64> = (0..nf * sht.n_coefs()).map(|i| (i as f64).cos()).collect();
        let mut grid = vec![0.0; nf * sht.n_points()];
        sht.inverse(&coefs, &mut grid, &mut sht.workspace())
            .unwrap();
        let nq = 2 * q * (q + 1);
        let mut out = vec![0.0; nf * nq];
        let mut direct = DirectRotation::new(p, q).unwrap();
        let mut via = ShRotation::new(p, q).unwrap();
        let targets: Vec<(usize, usize)> = (0..=p)
            .flat_map(|i| (0..2 * p).map(move |k| (i, k)))
            .collect();
        let td = best_of(3, 0.5, || {
            for &(i, k) in &targets {
                direct.apply(i, k, &grid, &mut out).unwrap();
            }
            black_box(&out);
        });
        let ts = best_of(3, 0.5, || {
            for &(i, k) in &targets {
                via.apply(i, k, &coefs, &mut out).unwrap();
            }
            black_box(&out);
        });
        let dflops = 2.0 * (nq * sht.n_points() * nf * targets.len()) as f64;
        println!(
            "| {p} | {q} | {:.2} | {:.1} | {:.1} | {:.2} | {:.2} |",
            td * 1e3,
            dflops / td / 1e9,
            direct.memory_bytes() as f64 / 1e6,
            ts * 1e3,
            via.memory_bytes() as f64 / 1e6
        );
    }
}

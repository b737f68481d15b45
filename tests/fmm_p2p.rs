//! The batched P2P loops (AVX2 intrinsics where the CPU has them, portable loops otherwise)
//! against the pair-by-pair kernels, including coincident points (left out, or RPY's self
//! term), overlapping RPY pairs, and separations outside single precision's range (where the
//! `rsqrt` estimate falls back to `1/√d²`).

use mobo::check::assert_close;
use mobo::fmm::blocks::SourceBlock;
use mobo::fmm::clouds::Cloud;
use mobo::fmm::kernels::{RpyFar, StokesletSource};
use mobo::fmm::p2p::Simd;
use mobo::fmm::{p2p, Kernel, Laplace, LaplaceDoubleLayer, Rpy, Stokeslet, Stresslet};

/// Pair-by-pair sum with `Kernel::accumulate` / `coincident` (the reference).
fn pairwise(k: &dyn Kernel, t: &[[f64; 3]], s: &[[f64; 3]], n: &[[f64; 3]], q: &[f64]) -> Vec<f64> {
    let (dd, od) = (k.density_dim(), k.output_dim());
    let mut out = vec![0.0; t.len() * od];
    for (x, o) in t.iter().zip(out.chunks_exact_mut(od)) {
        for (j, y) in s.iter().enumerate() {
            let r = [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
            let d = &q[j * dd..(j + 1) * dd];
            if r == [0.0; 3] {
                k.coincident(d, o);
            } else {
                k.accumulate(r, d, n[j], o);
            }
        }
    }
    out
}

type Points = Vec<[f64; 3]>;

fn cases(scale: f64) -> (Points, Points, Points) {
    // 37 sources (not a multiple of the vector width), 11 targets of which 5 coincide with
    // sources.
    let s: Vec<[f64; 3]> = Cloud::Blobs
        .points(37, 1)
        .iter()
        .map(|p| [p[0] * scale, p[1] * scale, p[2] * scale])
        .collect();
    let mut t: Vec<[f64; 3]> = Cloud::Uniform
        .points(6, 2)
        .iter()
        .map(|p| [p[0] * scale, p[1] * scale, p[2] * scale])
        .collect();
    t.extend_from_slice(&s[..5]);
    (s, t, Cloud::unit_vectors(37, 3))
}

#[test]
fn block_loops_match_pairwise_kernels() {
    for scale in [1.0, 1e-17, 1e17] {
        let (s, t, n) = cases(scale);
        let order: Vec<usize> = (0..s.len()).collect();
        let a = 0.05 * scale;
        let kernels: Vec<Box<dyn Kernel>> = vec![
            Box::new(Laplace),
            Box::new(LaplaceDoubleLayer),
            Box::new(Stokeslet),
            Box::new(StokesletSource),
            Box::new(Stresslet),
            Box::new(Rpy { radius: a }),
            Box::new(RpyFar { radius: a }),
        ];
        for k in &kernels {
            let dd = k.density_dim();
            let q = Cloud::densities(s.len() * dd, 4);
            let mut blk = SourceBlock::new(&s, Some(&n), &order);
            blk.set_density(&q, dd, &order);
            let want = pairwise(k.as_ref(), &t, &s, &n, &q);
            let mut got = vec![0.0; want.len()];
            k.eval_block(&t, &blk.all(), &mut got);
            assert_close(&format!("{} scale {scale:e}", k.name()), &got, &want, 1e-13);
        }
        // The portable loops behind the AVX2 ones.
        let q1 = Cloud::densities(s.len(), 5);
        let q3 = Cloud::densities(3 * s.len(), 6);
        let mut b1 = SourceBlock::new(&s, None, &order);
        b1.set_density(&q1, 1, &order);
        let mut b3 = SourceBlock::new(&s, None, &order);
        b3.set_density(&q3, 3, &order);
        let (mut x, mut y) = (vec![0.0; t.len()], vec![0.0; t.len()]);
        p2p::laplace(&t, &b1.all(), &mut x);
        p2p::laplace_portable(&t, &b1.all(), &mut y);
        assert_close(&format!("laplace avx2/portable {scale:e}"), &x, &y, 1e-13);
        let (mut x, mut y) = (vec![0.0; 3 * t.len()], vec![0.0; 3 * t.len()]);
        p2p::stokeslet(&t, &b3.all(), &mut x);
        p2p::stokeslet_portable(&t, &b3.all(), &mut y);
        assert_close(&format!("stokeslet avx2/portable {scale:e}"), &x, &y, 1e-13);
    }
}

/// Every instruction set this CPU has (portable, AVX2, AVX-512) against the pair-by-pair sum
/// (Laplace, Stokeslet, stresslet),
/// for every source count from 0 to 19 (all remainders of four- and eight-wide steps) and at
/// scales outside single precision's range; the ones the CPU lacks say so.
#[test]
fn every_instruction_set_matches_the_pairwise_sum() {
    let sets = [Simd::Portable, Simd::Avx2, Simd::Avx512];
    let available: Vec<Simd> = sets.into_iter().filter(|s| s.available()).collect();
    println!(
        "instruction sets here: {available:?} (best {:?})",
        Simd::best()
    );
    for scale in [1.0, 1e-17, 1e17] {
        let (s_all, t, n_all) = cases(scale);
        for ns in 0..20 {
            let s = &s_all[..ns];
            let n = &n_all[..ns];
            let order: Vec<usize> = (0..ns).collect();
            for k in [&Laplace as &dyn Kernel, &Stokeslet, &Stresslet] {
                let dd = k.density_dim();
                let q = Cloud::densities(ns * dd, 7);
                let normals = k.needs_normals().then_some(n);
                let mut blk = SourceBlock::new(s, normals, &order);
                blk.set_density(&q, dd, &order);
                let want = pairwise(k, &t, s, n, &q);
                for simd in sets {
                    let mut got = vec![0.0; want.len()];
                    let ran = match k.name() {
                        "laplace" => p2p::laplace_on(simd, &t, &blk.all(), &mut got),
                        "stokeslet" => p2p::stokeslet_on(simd, &t, &blk.all(), &mut got),
                        _ => p2p::stresslet_on(simd, &t, &blk.all(), &mut got),
                    };
                    assert_eq!(ran, simd.available(), "{simd:?}");
                    if ran {
                        let what = format!("{} {simd:?} {ns} sources, scale {scale:e}", k.name());
                        assert_close(&what, &got, &want, 1e-13);
                    } else {
                        assert!(
                            got.iter().all(|v| *v == 0.0),
                            "{simd:?} wrote without running"
                        );
                    }
                }
            }
        }
    }
}

/// One Newton step ([`p2p::Newton::One`]) on every instruction set this CPU has: each target's
/// error against the pair-by-pair sum stays within the stated bound times the sum of the
/// pairs' magnitudes (`powers ·` [`Simd::one_newton_error`] `· Σ_j |K_j q_j|`), at scales
/// outside single precision's range and with coincident points; and on AVX-512 and AVX2 the
/// relaxed loop does differ from the exact one (the step is really skipped).
#[test]
fn one_newton_step_stays_within_its_bound() {
    use p2p::Newton;
    for scale in [1.0, 1e-17, 1e17] {
        // 300 sources, 40 targets (5 coincide with sources).
        let s: Vec<[f64; 3]> = Cloud::Blobs
            .points(300, 11)
            .iter()
            .map(|p| [p[0] * scale, p[1] * scale, p[2] * scale])
            .collect();
        let mut t: Vec<[f64; 3]> = Cloud::Uniform
            .points(35, 12)
            .iter()
            .map(|p| [p[0] * scale, p[1] * scale, p[2] * scale])
            .collect();
        t.extend_from_slice(&s[..5]);
        let order: Vec<usize> = (0..s.len()).collect();
        let none = vec![[0.0; 3]; s.len()];
        for (k, dd, powers) in [
            (&Laplace as &dyn Kernel, 1, 1),
            (&Stokeslet as &dyn Kernel, 3, 3),
        ] {
            let q = Cloud::densities(s.len() * dd, 13);
            let mut blk = SourceBlock::new(&s, None, &order);
            blk.set_density(&q, dd, &order);
            let want = pairwise(k, &t, &s, &none, &q);
            // Σ_j |K(x − y_j)| |q_j| per target: the Laplace kernel with |q| bounds each output
            // of either kernel up to the factor 2/(8π) · 4π = 1 for the Stokeslet.
            let qa: Vec<f64> = (0..s.len())
                .map(|j| q[j * dd..(j + 1) * dd].iter().map(|v| v.abs()).sum())
                .collect();
            let envelope = pairwise(&Laplace, &t, &s, &none, &qa);
            for simd in [Simd::Portable, Simd::Avx2, Simd::Avx512] {
                if !simd.available() {
                    continue;
                }
                let (mut relaxed, mut exact) = (vec![0.0; want.len()], vec![0.0; want.len()]);
                if dd == 1 {
                    p2p::laplace_with(simd, Newton::One, &t, &blk.all(), &mut relaxed);
                    p2p::laplace_with(simd, Newton::Two, &t, &blk.all(), &mut exact);
                } else {
                    p2p::stokeslet_with(simd, Newton::One, &t, &blk.all(), &mut relaxed);
                    p2p::stokeslet_with(simd, Newton::Two, &t, &blk.all(), &mut exact);
                }
                let bound = f64::from(powers) * simd.one_newton_error();
                let mut worst: f64 = 0.0;
                for (i, (g, w)) in relaxed.iter().zip(&want).enumerate() {
                    let env = envelope[i / k.output_dim()];
                    let err = (g - w).abs();
                    assert!(
                        err <= (bound + 1e-13) * env,
                        "{} {simd:?} scale {scale:e} target {i}: error {err:e} > {bound:e} · {env:e}",
                        k.name()
                    );
                    worst = worst.max(err / env);
                }
                assert_close(
                    &format!("{} {simd:?} two steps", k.name()),
                    &exact,
                    &want,
                    1e-13,
                );
                if simd != Simd::Portable && scale == 1.0 {
                    assert!(
                        worst > 1e-12,
                        "{} {simd:?}: the one-step loop matches the exact one to {worst:e}",
                        k.name()
                    );
                }
                println!(
                    "{} {simd:?} scale {scale:e}: worst {worst:.2e} (bound {bound:.1e})",
                    k.name()
                );
            }
        }
    }
}

/// The near field's tolerance follows the order's calibrated digits, and one Newton step is
/// chosen only where it fits.
#[test]
fn near_tolerance_follows_the_calibration() {
    use mobo::fmm::calibration::{digits_for_order, near_tolerance};
    use mobo::fmm::{order_for_digits, FmmKernel};
    use p2p::Newton;
    for kind in [FmmKernel::Laplace, FmmKernel::Stokeslet] {
        for d in 3..=10 {
            let o = order_for_digits(kind, d).unwrap();
            assert_eq!(digits_for_order(kind, o), d, "{kind:?} order {o}");
        }
        assert_eq!(digits_for_order(kind, 2), 2);
        assert_eq!(near_tolerance(kind, 20), 0.0);
    }
    let tol = |k, d| near_tolerance(k, order_for_digits(k, d).unwrap());
    assert_eq!(tol(FmmKernel::Laplace, 6), 1e-7);
    // (instruction set, kernel, digits, powers of 1/|r|, steps chosen)
    for (simd, kind, digits, powers, want) in [
        (Simd::Avx512, FmmKernel::Laplace, 7, 1, Newton::One),
        (Simd::Avx512, FmmKernel::Laplace, 8, 1, Newton::Two),
        (Simd::Avx512, FmmKernel::Stokeslet, 6, 3, Newton::One),
        (Simd::Avx512, FmmKernel::Stokeslet, 7, 3, Newton::Two),
        (Simd::Avx2, FmmKernel::Laplace, 5, 1, Newton::One),
        (Simd::Avx2, FmmKernel::Laplace, 6, 1, Newton::Two),
    ] {
        let got = Newton::within(simd, tol(kind, digits), powers);
        assert_eq!(got, want, "{simd:?} {kind:?} at {digits} digits");
    }
    assert_eq!(Newton::within(Simd::Portable, 1.0, 1), Newton::Two);
}

/// The bound of [`Simd::one_newton_error`] pair by pair: 4000 pairs at separations over twelve
/// decades (each as 8 copies of one source, a full vector step), each within the bound, and
/// the worst of them within a factor 10 of it (the bound is not slack).
#[test]
fn one_newton_error_bound_holds_per_pair() {
    use p2p::Newton;
    let pts = Cloud::Uniform.points(4000, 21);
    for simd in [Simd::Avx2, Simd::Avx512] {
        if !simd.available() {
            continue;
        }
        let mut worst: f64 = 0.0;
        for (i, p) in pts.iter().enumerate() {
            let scale = 10f64.powf(-6.0 + 12.0 * (i as f64 / pts.len() as f64));
            let y = [[p[0] * scale, p[1] * scale, p[2] * scale]; 8];
            let order: Vec<usize> = (0..8).collect();
            let mut blk = SourceBlock::new(&y, None, &order);
            blk.set_density(&[0.125; 8], 1, &order);
            let mut got = [0.0];
            p2p::laplace_with(simd, Newton::One, &[[0.0; 3]], &blk.all(), &mut got);
            let d = (y[0][0].powi(2) + y[0][1].powi(2) + y[0][2].powi(2)).sqrt();
            let want = 1.0 / (4.0 * std::f64::consts::PI * d);
            let err = (got[0] - want).abs() / want;
            assert!(
                err <= simd.one_newton_error(),
                "{simd:?} |r| = {d:e}: {err:e}"
            );
            worst = worst.max(err);
        }
        println!(
            "{simd:?}: worst per pair {worst:.2e}, bound {:.1e}",
            simd.one_newton_error()
        );
        assert!(worst > 0.1 * simd.one_newton_error(), "{simd:?}: {worst:e}");
    }
}

//! Brownian dynamics with HI against independent references.

use faer::Mat;
use mobo::brownian::noise::{cholesky_factor, lanczos_sqrt, symmetric_sqrt};
use mobo::brownian::rpy::{apply_mobility, dense_mobility, rpy_block};
use mobo::brownian::tea_hi::{
    fused_pass, fused_rows, tea_hi_noise, FusedSums, Soa, TeaHiCoefficients, ROW_VALUES,
};
use mobo::brownian::{
    BrownianParams, BrownianSimulation, ForceField, NoiseModel, SubcellularElement,
};
use mobo::check::{assert_close, rel_max_error};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// RPY written independently: the Oseen-like far field from the textbook form with `a²`
/// correction, `(1/(8πηr))[(1 + 2a²/3r²) I + (1 − 2a²/r²) r̂r̂]`, times `6πηa`; the overlap form
/// `(1 − 9r/32a) I + (3r/32a) r̂r̂`.
fn rpy_textbook(r: [f64; 3], a: f64) -> [[f64; 3]; 3] {
    let d = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    let u = [r[0] / d, r[1] / d, r[2] / d];
    let (ci, cu) = if d >= 2.0 * a {
        let pre = 6.0 * std::f64::consts::PI * a / (8.0 * std::f64::consts::PI * d);
        (
            pre * (1.0 + 2.0 * a * a / (3.0 * d * d)),
            pre * (1.0 - 2.0 * a * a / (d * d)),
        )
    } else {
        (1.0 - 9.0 * d / (32.0 * a), 3.0 * d / (32.0 * a))
    };
    let mut m = [[0.0; 3]; 3];
    for k in 0..3 {
        for l in 0..3 {
            m[k][l] = cu * u[k] * u[l] + if k == l { ci } else { 0.0 };
        }
    }
    m
}

fn random_config(n: usize, box_len: f64, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            [
                rng.random_range(0.0..box_len),
                rng.random_range(0.0..box_len),
                rng.random_range(0.0..box_len),
            ]
        })
        .collect()
}

#[test]
fn rpy_blocks_match_textbook_formula_in_both_branches() {
    let a = 1.3;
    let mut rng = StdRng::seed_from_u64(1);
    for _ in 0..2000 {
        let d = rng.random_range(0.01..10.0);
        let dir = [
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0f64),
        ];
        let n = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
        let r = [d * dir[0] / n, d * dir[1] / n, d * dir[2] / n];
        let got: Vec<f64> = rpy_block(r, a).iter().flatten().copied().collect();
        let want: Vec<f64> = rpy_textbook(r, a).iter().flatten().copied().collect();
        assert_close(&format!("RPY block at r = {d}"), &got, &want, 1e-14);
    }
    // Continuity at r = 2a (both branches give (1/2, 0)... up to the far-field values).
    let below: Vec<f64> = rpy_block([2.0 * a * (1.0 - 1e-12), 0.0, 0.0], a)
        .iter()
        .flatten()
        .copied()
        .collect();
    let above: Vec<f64> = rpy_block([2.0 * a, 0.0, 0.0], a)
        .iter()
        .flatten()
        .copied()
        .collect();
    assert!(
        rel_max_error(&below, &above) < 1e-11,
        "{below:?} vs {above:?}"
    );
    // The values there: f = 3/8 + 1/16 = 7/16, g = 3/8 − 3/16 = 3/16.
    assert!((above[4] - 7.0 / 16.0).abs() < 1e-15 && (above[0] - 10.0 / 16.0).abs() < 1e-15);
}

#[test]
fn mobility_is_symmetric_positive_definite_with_overlaps() {
    for (n, box_len) in [(2, 1.0), (5, 2.0), (20, 4.0), (50, 5.0), (50, 40.0)] {
        for seed in 0..5 {
            let pos = random_config(n, box_len, seed);
            let d = dense_mobility(&pos, 1.0);
            for i in 0..3 * n {
                for j in 0..3 * n {
                    assert!((d[(i, j)] - d[(j, i)]).abs() < 1e-15);
                }
            }
            let evd = d.self_adjoint_eigen(faer::Side::Lower).unwrap();
            let min = evd
                .S()
                .column_vector()
                .iter()
                .fold(f64::INFINITY, |m, &v| m.min(v));
            assert!(
                min > 0.0,
                "min eigenvalue {min} for n={n} box={box_len} seed={seed}"
            );
            let l = cholesky_factor(&pos, 1.0).unwrap();
            let llt = &l * l.transpose();
            let diff = (&llt - &d).norm_max();
            assert!(diff < 1e-13, "L Lᵀ − D = {diff}");
        }
    }
}

#[test]
fn matrix_free_mobility_matches_dense() {
    let pos = random_config(40, 6.0, 3);
    let f = random_config(40, 1.0, 4);
    let mut out = vec![[0.0; 3]; 40];
    apply_mobility(&pos, 1.0, &f, &mut out);
    let d = dense_mobility(&pos, 1.0);
    let fv = Mat::<f64>::from_fn(120, 1, |i, _| f[i / 3][i % 3]);
    let want = &d * &fv;
    let got: Vec<f64> = out.iter().flatten().copied().collect();
    let want: Vec<f64> = (0..120).map(|i| want[(i, 0)]).collect();
    assert_close("matrix-free mobility", &got, &want, 1e-14);
}

/// TEA-HI assembled naively from the dense mobility, straight from the formulas.
fn tea_hi_dense(d: &Mat<f64>, n: usize) -> (Mat<f64>, TeaHiCoefficients) {
    let mut sum = 0.0;
    for i in 0..3 * n {
        for j in 0..3 * n {
            if i / 3 != j / 3 {
                sum += d[(i, j)];
            }
        }
    }
    let eps = sum / (9.0 * (n * (n - 1)) as f64);
    let m = 3.0 * n as f64;
    let a = (m - 1.0) * eps * eps - (m - 2.0) * eps;
    let beta = (1.0 - (1.0 - a).sqrt()) / a;
    let mut b = Mat::<f64>::zeros(3 * n, 3 * n);
    for i in 0..3 * n {
        let mut s = 0.0;
        for j in 0..3 * n {
            if i / 3 != j / 3 {
                s += d[(i, j)] * d[(i, j)];
            }
        }
        let c = 1.0 / (1.0 + beta * beta * s).sqrt();
        for j in 0..3 * n {
            b[(i, j)] = if i == j {
                c
            } else if i / 3 != j / 3 {
                c * beta * d[(i, j)]
            } else {
                0.0
            };
        }
    }
    (b, TeaHiCoefficients { epsilon: eps, beta })
}

#[test]
fn fused_tea_hi_pass_matches_naive_formulas() {
    for (n, box_len, seed) in [(2, 3.0, 1), (7, 5.0, 2), (33, 8.0, 3), (101, 30.0, 4)] {
        let pos = random_config(n, box_len, seed);
        let f = random_config(n, 2.0, seed + 10);
        let xi = random_config(n, 2.0, seed + 20);
        let mut sums = FusedSums::default();
        let xs = Soa::from_points(&xi);
        fused_pass(
            &Soa::from_points(&pos),
            &Soa::from_points(&f),
            &xs,
            1.0,
            &mut sums,
        );
        let coef = TeaHiCoefficients::from_entry_sum(sums.entry_sum, n).unwrap();
        let d = dense_mobility(&pos, 1.0);
        let (b, coef_ref) = tea_hi_dense(&d, n);
        // ε is a sum with cancellations: compare absolutely (entries are O(1)).
        assert!(
            (coef.epsilon - coef_ref.epsilon).abs() < 1e-13,
            "{coef:?} vs {coef_ref:?}"
        );
        assert!((coef.beta - coef_ref.beta).abs() < 1e-13);
        let mut noise = vec![[0.0; 3]; n];
        tea_hi_noise(&sums, &xs, coef, &mut noise);
        let xv = Mat::<f64>::from_fn(3 * n, 1, |i, _| xi[i / 3][i % 3]);
        let fv = Mat::<f64>::from_fn(3 * n, 1, |i, _| f[i / 3][i % 3]);
        let want_noise = &b * &xv;
        let want_drift = &d * &fv;
        let got: Vec<f64> = noise.iter().flatten().copied().collect();
        let want: Vec<f64> = (0..3 * n).map(|i| want_noise[(i, 0)]).collect();
        assert_close(&format!("TEA-HI noise n={n}"), &got, &want, 1e-12);
        let got: Vec<f64> = sums.drift.iter().flatten().copied().collect();
        let want: Vec<f64> = (0..3 * n).map(|i| want_drift[(i, 0)]).collect();
        assert_close(&format!("fused drift n={n}"), &got, &want, 1e-12);
    }
}

/// Relative Frobenius error of the TEA-HI covariance `B̃B̃ᵀ` against `D̃`, and the coupling
/// strength `κ = max_k (Σ_{l ∉ particle(k)} D̃_kl²)^{1/2}` that controls it.
fn tea_hi_covariance_error(pos: &[[f64; 3]]) -> (f64, f64) {
    let n = pos.len();
    let d = dense_mobility(pos, 1.0);
    let (b, _) = tea_hi_dense(&d, n);
    let cov = &b * b.transpose();
    let mut kappa = 0.0f64;
    for i in 0..3 * n {
        let s: f64 = (0..3 * n)
            .filter(|j| j / 3 != i / 3)
            .map(|j| d[(i, j)] * d[(i, j)])
            .sum();
        kappa = kappa.max(s.sqrt());
    }
    ((&cov - &d).norm_l2() / d.norm_l2(), kappa)
}

#[test]
fn tea_hi_covariance_is_close_to_exact_for_weak_coupling() {
    // Volume fraction φ = N (4π/3) a³ / L³. TEA-HI is exact to first order in the coupling; its
    // error is second order in the summed coupling κ of a row, which grows with N at fixed φ.
    println!(
        "| N | volume fraction | max row coupling κ | ‖B̃B̃ᵀ − D̃‖_F / ‖D̃‖_F |\n|---|---|---|---|"
    );
    for n in [2usize, 5, 10, 20, 50, 100] {
        for phi in [0.001, 0.01, 0.05] {
            let box_len = (n as f64 * 4.0 * std::f64::consts::PI / 3.0 / phi).cbrt();
            for s in 0..2 {
                let (e, kappa) = tea_hi_covariance_error(&random_config(n, box_len, s));
                println!("| {n} | {phi} | {kappa:.3} | {e:.2e} |");
                if kappa < 0.25 {
                    assert!(
                        e < 0.05,
                        "TEA-HI covariance error {e} at N={n}, φ={phi}, κ={kappa}"
                    );
                }
                // Second order: the error stays below κ².
                assert!(
                    e < kappa * kappa,
                    "error {e} above κ² = {} (N={n}, φ={phi})",
                    kappa * kappa
                );
            }
        }
    }
}

#[test]
fn lanczos_matches_symmetric_square_root() {
    for (n, box_len) in [(3, 3.0), (30, 6.0), (60, 10.0)] {
        let pos = random_config(n, box_len, 9);
        let xi = random_config(n, 1.0, 10);
        let r = lanczos_sqrt(&pos, 1.0, &xi, 1e-10, 3 * n).unwrap();
        let s = symmetric_sqrt(&dense_mobility(&pos, 1.0)).unwrap();
        let xv = Mat::<f64>::from_fn(3 * n, 1, |i, _| xi[i / 3][i % 3]);
        let want = &s * &xv;
        let got: Vec<f64> = r.value.iter().flatten().copied().collect();
        let want: Vec<f64> = (0..3 * n).map(|i| want[(i, 0)]).collect();
        assert_close(
            &format!("Lanczos n={n} ({} its)", r.iterations),
            &got,
            &want,
            1e-8,
        );
        assert!(r.iterations < 3 * n || n == 3);
    }
}

/// The sub-cellular-element potential of the force tests.
fn sce() -> SubcellularElement {
    SubcellularElement {
        u0: 0.7,
        rho: 2.0,
        r_eq: 1.8,
        cutoff: 4.0,
    }
}

#[test]
fn forces_are_minus_energy_gradient() {
    let pos = vec![
        [0.0, 0.0, 0.0],
        [1.7, 0.2, 0.1],
        [3.1, 1.0, -0.4],
        [2.0, 2.5, 0.3],
    ];
    let ff = ForceField {
        bonds: vec![(0, 1), (1, 2), (2, 3)],
        bond_stiffness: 50.0,
        bond_length: 2.0,
        repulsion: 30.0,
        radius: 1.0,
        sce: Some(sce()),
        external: [0.1, -0.2, 0.3],
    };
    let mut f = vec![[0.0; 3]; pos.len()];
    ff.forces(&pos, &mut f);
    let h = 1e-6;
    let mut fd = Vec::new();
    for i in 0..pos.len() {
        for k in 0..3 {
            let mut p = pos.clone();
            p[i][k] += h;
            let ep = ff.energy(&p);
            p[i][k] -= 2.0 * h;
            let em = ff.energy(&p);
            fd.push(-(ep - em) / (2.0 * h));
        }
    }
    let got: Vec<f64> = f.iter().flatten().copied().collect();
    assert_close("forces vs −∇U", &got, &fd, 1e-7);
}

fn params(noise: NoiseModel, seed: u64) -> BrownianParams {
    BrownianParams {
        radius: 1.0,
        kt: 1.0,
        viscosity: 1.0 / (6.0 * std::f64::consts::PI),
        dt: 1e-3,
        noise,
        seed,
    }
}

fn dimer(d: f64) -> ForceField {
    ForceField {
        bonds: vec![(0, 1)],
        bond_stiffness: 50.0,
        bond_length: d,
        repulsion: 50.0,
        radius: 1.0,
        ..Default::default()
    }
}

/// D_CM from the mean squared COM increment per step (its trace is orientation-independent).
fn dimer_dcm(d: f64, noise: NoiseModel, steps: usize, seed: u64) -> f64 {
    let mut sim =
        BrownianSimulation::new(params(noise, seed), vec![[0.0; 3], [d, 0.0, 0.0]], dimer(d))
            .unwrap();
    for _ in 0..1000 {
        sim.step().unwrap();
    }
    let mut acc = 0.0;
    let mut prev = mobo::brownian::observables::center_of_mass(&sim.positions);
    for _ in 0..steps {
        sim.step().unwrap();
        let c = mobo::brownian::observables::center_of_mass(&sim.positions);
        acc += (0..3).map(|k| (c[k] - prev[k]).powi(2)).sum::<f64>();
        prev = c;
    }
    acc / (6.0 * steps as f64 * sim.params.dt)
}

#[test]
fn dimer_centre_of_mass_diffusion() {
    // D_CM = (D0/2)(1 + a/d) with exact noise; 60 000 steps give ~0.5% statistical error.
    for d in [2.0, 4.0, 10.0] {
        let want = 0.5 * (1.0 + 1.0 / d);
        let got = dimer_dcm(d, NoiseModel::Cholesky, 60_000, 11);
        assert!(
            (got / want - 1.0).abs() < 0.05,
            "exact noise d={d}: {got} vs {want}"
        );
        let tea = dimer_dcm(d, NoiseModel::TeaHi, 60_000, 12);
        println!("d = {d}: D_CM exact {got:.4}, TEA-HI {tea:.4}, theory {want:.4}");
        assert!(
            (tea / want - 1.0).abs() < 0.10,
            "TEA-HI d={d}: {tea} vs {want}"
        );
    }
    // Free draining: D0/2.
    let fd = dimer_dcm(4.0, NoiseModel::FreeDraining, 60_000, 13);
    assert!((fd / 0.5 - 1.0).abs() < 0.05, "free draining {fd}");
}

#[test]
fn runs_are_reproducible_from_the_seed() {
    let run = |seed| {
        let mut sim = BrownianSimulation::new(
            params(NoiseModel::TeaHi, seed),
            random_config(10, 10.0, 5),
            ForceField {
                repulsion: 50.0,
                radius: 1.0,
                ..Default::default()
            },
        )
        .unwrap();
        for _ in 0..200 {
            sim.step().unwrap();
        }
        sim.positions
    };
    assert_eq!(run(3), run(3));
    assert_ne!(run(3), run(4));
}

#[test]
fn bad_parameters_are_errors() {
    let mut p = params(NoiseModel::TeaHi, 1);
    p.dt = -1.0;
    assert!(BrownianSimulation::new(p, vec![[0.0; 3]], ForceField::default()).is_err());
    let p = params(NoiseModel::TeaHi, 1);
    assert!(BrownianSimulation::new(p, vec![[f64::NAN, 0.0, 0.0]], ForceField::default()).is_err());
}

#[test]
fn simd_pair_loop_matches_scalar_reference() {
    use mobo::brownian::tea_hi::{row_sums, row_sums_portable};
    // Sizes that leave every remainder 0..3, dense enough for both RPY branches.
    for n in [2usize, 3, 4, 5, 6, 7, 9, 17, 64, 131] {
        let pos = Soa::from_points(&random_config(n, (n as f64).cbrt() * 2.5, n as u64));
        let f = Soa::from_points(&random_config(n, 2.0, 1 + n as u64));
        let xi = Soa::from_points(&random_config(n, 2.0, 2 + n as u64));
        for i in 0..n {
            let got = row_sums(&pos, &f, &xi, 1.0, i);
            let want = row_sums_portable(&pos, &f, &xi, 1.0, i);
            assert_close(&format!("row sums n={n} i={i}"), &got, &want, 1e-13);
        }
    }
}

/// The row split of the MPI runs: the fused pass and the pair forces over blocks of rows,
/// concatenated, are the whole pass bit for bit, on one thread and on several (below and
/// above the parallel threshold).
#[test]
fn rows_split_in_blocks_give_the_whole_pass_bit_for_bit() {
    for (n, seed) in [(37, 1), (300, 2)] {
        let pos = random_config(n, 25.0, seed);
        let f = Soa::from_points(&random_config(n, 2.0, seed + 10));
        let xi = Soa::from_points(&random_config(n, 2.0, seed + 20));
        let p = Soa::from_points(&pos);
        let mut whole = FusedSums::default();
        fused_pass(&p, &f, &xi, 1.0, &mut whole);
        let one_thread = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let mut serial = FusedSums::default();
        one_thread.install(|| fused_pass(&p, &f, &xi, 1.0, &mut serial));
        assert_eq!(serial.drift, whole.drift, "n = {n}: thread count");
        assert_eq!(serial.entry_sum.to_bits(), whole.entry_sum.to_bits());
        for k in [2, 3, 5] {
            let mut rows = Vec::new();
            let mut part = Vec::new();
            for r in 0..k {
                fused_rows(&p, &f, &xi, 1.0, mobo::comm::block_rows(n, r, k), &mut part);
                rows.extend_from_slice(&part);
            }
            assert_eq!(rows.len(), ROW_VALUES * n);
            let mut split = FusedSums::default();
            split.fill_from_rows(&rows);
            assert_eq!(split.drift, whole.drift, "n = {n}, {k} blocks");
            assert_eq!(split.noise_sum, whole.noise_sum);
            assert_eq!(split.square_sum, whole.square_sum);
            assert_eq!(split.entry_sum.to_bits(), whole.entry_sum.to_bits());
        }
        // Pair forces by rows, against the whole and against a symmetric pair loop.
        let ff = ForceField {
            repulsion: 30.0,
            radius: 1.0,
            sce: Some(sce()),
            ..Default::default()
        };
        let mut all = vec![[0.0; 3]; n];
        ff.pair_forces(&pos, 0..n, &mut all);
        let mut sym = vec![[0.0; 3]; n];
        for i in 0..n {
            for j in i + 1..n {
                let r: [f64; 3] = std::array::from_fn(|c| pos[i][c] - pos[j][c]);
                let d = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
                // −dU/dr along r̂ from the energy of the pair, by central differences.
                let e = |x: f64| ff.energy(&[[0.0; 3], [x, 0.0, 0.0]]);
                let f = -(e(d + 1e-6) - e(d - 1e-6)) / 2e-6;
                for c in 0..3 {
                    sym[i][c] += f * r[c] / d;
                    sym[j][c] -= f * r[c] / d;
                }
            }
        }
        let got: Vec<f64> = all.iter().flatten().copied().collect();
        let want: Vec<f64> = sym.iter().flatten().copied().collect();
        assert!(
            got.iter().any(|&v| v != 0.0),
            "n = {n}: no pair is in range"
        );
        assert_close("pair forces vs −∇U pairwise", &got, &want, 1e-6);
        let mut pieces = Vec::new();
        for r in 0..3 {
            let rows = mobo::comm::block_rows(n, r, 3);
            let mut part = vec![[0.0; 3]; rows.len()];
            ff.pair_forces(&pos, rows, &mut part);
            pieces.extend(part);
        }
        assert_eq!(pieces, all, "n = {n}: pair forces by blocks");
    }
}

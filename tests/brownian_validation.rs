//! Physical validation of Brownian dynamics with HI: the RPY dimer (centre-of-mass diffusion and
//! orientational relaxation) and bead-spring polymer scaling.
//!
//! The long versions are ignored; `scripts/brownian_validation.sh` runs them in release mode and
//! writes the tables to `docs/brownian_validation.md`.

use mobo::brownian::observables::{center_of_mass, orientation, radius_of_gyration_sq};
use mobo::brownian::{BrownianParams, BrownianSimulation, ForceField, NoiseModel};
use rayon::prelude::*;

fn params(noise: NoiseModel, seed: u64, dt: f64) -> BrownianParams {
    BrownianParams {
        radius: 1.0,
        kt: 1.0,
        viscosity: 1.0 / (6.0 * std::f64::consts::PI), // D0 = 1
        dt,
        noise,
        seed,
    }
}

/// Theory: `τ = d²/[4D0(1 − 3a/4d − a³/2d³)]`, `D_CM = (D0/2)(1 + a/d)`.
fn tau_theory(d: f64) -> f64 {
    d * d / (4.0 * (1.0 - 0.75 / d - 0.5 / (d * d * d)))
}

/// Per stream: Σ|ΔR_cm|², orientation MSD at the lag, steps, and `(t, C(t))` samples.
type StreamResult = (f64, f64, usize, Vec<(f64, f64)>);

struct DimerStats {
    dcm: f64,
    tau_short: f64,
    tau_fit: f64,
}

/// Ensemble of `streams` independent dimers (one per seed), each run for `steps` steps after
/// equilibration. `τ` from the orientation MSD at lag `τ_theory/10` (exact for a rigid rotor:
/// `⟨|u(t) − u(0)|²⟩ = 2(1 − e^{−t/τ})`) and, for comparison, from a least-squares fit of
/// `−ln C(t)` on `t ≤ τ_theory`.
fn dimer_stats(d: f64, noise: NoiseModel, steps: usize, streams: u64) -> DimerStats {
    let dt = 1e-3;
    let tau0 = tau_theory(d);
    let lag = ((tau0 / 10.0) / dt).round().max(1.0) as usize;
    let sample = (lag / 10).max(1);
    let results: Vec<StreamResult> = (0..streams)
        .into_par_iter()
        .map(|s| {
            let ff = ForceField {
                bonds: vec![(0, 1)],
                bond_stiffness: 50.0,
                bond_length: d,
                repulsion: 50.0,
                radius: 1.0,
                ..Default::default()
            };
            let mut sim = BrownianSimulation::new(
                params(noise, 1000 + s, dt),
                vec![[0.0; 3], [d, 0.0, 0.0]],
                ff,
            )
            .unwrap();
            for _ in 0..2000 {
                sim.step().unwrap();
            }
            let mut com_sq = 0.0;
            let mut prev = center_of_mass(&sim.positions);
            let mut us = Vec::with_capacity(steps / sample + 1);
            for k in 0..steps {
                sim.step().unwrap();
                let c = center_of_mass(&sim.positions);
                com_sq += (0..3).map(|i| (c[i] - prev[i]).powi(2)).sum::<f64>();
                prev = c;
                if k % sample == 0 {
                    us.push(orientation(&sim.positions));
                }
            }
            let l = lag / sample;
            let msd_u: f64 = (0..us.len() - l)
                .map(|t| {
                    (0..3)
                        .map(|i| (us[t + l][i] - us[t][i]).powi(2))
                        .sum::<f64>()
                })
                .sum::<f64>()
                / (us.len() - l) as f64;
            // C(t) at lags up to τ0 for the fit.
            let max_lag = ((tau0 / dt) as usize / sample).min(us.len() / 4).max(2);
            let corr: Vec<(f64, f64)> = (1..=10)
                .map(|j| j * max_lag / 10)
                .filter(|&m| m > 0)
                .map(|m| {
                    let c = (0..us.len() - m)
                        .map(|t| (0..3).map(|i| us[t + m][i] * us[t][i]).sum::<f64>())
                        .sum::<f64>()
                        / (us.len() - m) as f64;
                    ((m * sample) as f64 * dt, c)
                })
                .collect();
            (com_sq, msd_u, steps, corr)
        })
        .collect();
    let total_steps: usize = results.iter().map(|r| r.2).sum();
    let dcm = results.iter().map(|r| r.0).sum::<f64>() / (6.0 * total_steps as f64 * dt);
    let msd_u = results.iter().map(|r| r.1).sum::<f64>() / results.len() as f64;
    // The lag actually used is a whole number of samples.
    let t = ((lag / sample) * sample) as f64 * dt;
    let tau_short = -t / (1.0 - msd_u / 2.0).ln();
    // Fit −ln C = t/τ through the origin, averaging C over streams.
    let npts = results[0].3.len();
    let (mut num, mut den) = (0.0, 0.0);
    for k in 0..npts {
        let tk = results[0].3[k].0;
        let c = results.iter().map(|r| r.3[k].1).sum::<f64>() / results.len() as f64;
        if c > 0.0 {
            num += tk * tk;
            den += tk * -c.ln();
        }
    }
    DimerStats {
        dcm,
        tau_short,
        tau_fit: num / den,
    }
}

#[test]
fn dimer_orientational_relaxation_quick() {
    // d = 3: τ = 3.08; 2 × 400 000 steps give ~2600 lag windows of τ/10 (≈ 3% statistical error).
    let d = 3.0;
    let s = dimer_stats(d, NoiseModel::Cholesky, 400_000, 2);
    let tau = tau_theory(d);
    assert!(
        (s.tau_short / tau - 1.0).abs() < 0.10,
        "τ = {} vs theory {tau}",
        s.tau_short
    );
    assert!(
        (s.dcm / (0.5 * (1.0 + 1.0 / d)) - 1.0).abs() < 0.05,
        "D_CM = {}",
        s.dcm
    );
}

#[test]
#[ignore]
fn dimer_table() {
    println!();
    println!("| d/a | noise | D_CM | theory | ratio | τ (short-time) | τ (fit of C(t)) | theory | ratio (short-time) |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for d in [2.0, 3.0, 5.0, 10.0, 20.0] {
        let tau = tau_theory(d);
        // About 3000 lag windows per stream (lag = τ/10).
        let steps = ((3000.0 * tau / 10.0) / 1e-3) as usize;
        for (name, noise) in [
            ("exact", NoiseModel::Cholesky),
            ("TEA-HI", NoiseModel::TeaHi),
        ] {
            let s = dimer_stats(d, noise, steps.max(200_000), 2);
            let dcm0 = 0.5 * (1.0 + 1.0 / d);
            println!(
                "| {d} | {name} | {:.4} | {dcm0:.4} | {:.3} | {:.3} | {:.3} | {tau:.3} | {:.3} |",
                s.dcm,
                s.dcm / dcm0,
                s.tau_short,
                s.tau_fit,
                s.tau_short / tau
            );
            if name == "exact" {
                assert!((s.dcm / dcm0 - 1.0).abs() < 0.05, "D_CM at d={d}");
                assert!((s.tau_short / tau - 1.0).abs() < 0.05, "τ at d={d}");
            }
        }
    }
}

/// A self-avoiding random walk of `n` beads with bond length `b` (no two beads closer than `b`),
/// grown bead by bead with random directions.
fn self_avoiding_walk(n: usize, b: f64, seed: u64) -> Vec<[f64; 3]> {
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};
    let mut rng = StdRng::seed_from_u64(seed);
    'restart: loop {
        let mut pos = vec![[0.0f64; 3]];
        while pos.len() < n {
            let last = *pos.last().unwrap();
            let mut placed = false;
            for _ in 0..1000 {
                let v = [
                    rng.random_range(-1.0..1.0f64),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                ];
                let r = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                if !(1e-3..=1.0).contains(&r) {
                    continue;
                }
                let p = [
                    last[0] + b * v[0] / r,
                    last[1] + b * v[1] / r,
                    last[2] + b * v[2] / r,
                ];
                if pos
                    .iter()
                    .all(|q| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>() >= 0.999 * b * b)
                {
                    pos.push(p);
                    placed = true;
                    break;
                }
            }
            if !placed {
                continue 'restart;
            }
        }
        return pos;
    }
}

#[test]
#[ignore]
fn polymer_scaling_exponent() {
    // Bead-spring chains with excluded volume (overlap repulsion), TEA-HI noise. Chains start as
    // self-avoiding random walks (a straight start relaxes too slowly and biases ν upwards).
    let sizes = [10usize, 14, 20, 28, 40];
    println!();
    println!("| beads N | steps per stream | ⟨R_g²⟩ | std. error |\n|---|---|---|---|");
    let mut pts = Vec::new();
    for &n in &sizes {
        let steps = 2_000_000 + 100_000 * n;
        let samples: Vec<Vec<f64>> = (0..2u64)
            .into_par_iter()
            .map(|s| {
                let ff = ForceField {
                    bonds: (0..n - 1).map(|i| (i, i + 1)).collect(),
                    bond_stiffness: 50.0,
                    bond_length: 2.0,
                    repulsion: 50.0,
                    radius: 1.0,
                    ..Default::default()
                };
                let pos = self_avoiding_walk(n, 2.0, 500 + s);
                let mut sim =
                    BrownianSimulation::new(params(NoiseModel::TeaHi, 77 + s, 1e-3), pos, ff)
                        .unwrap();
                let mut rg = Vec::new();
                for k in 0..steps {
                    sim.step().unwrap();
                    if k > steps / 5 && k % 1000 == 0 {
                        rg.push(radius_of_gyration_sq(&sim.positions));
                    }
                }
                rg
            })
            .collect();
        // Block averages (10 blocks per stream) for the error bar.
        let blocks: Vec<f64> = samples
            .iter()
            .flat_map(|v| {
                v.chunks(v.len() / 10)
                    .map(|c| c.iter().sum::<f64>() / c.len() as f64)
            })
            .collect();
        let mean = blocks.iter().sum::<f64>() / blocks.len() as f64;
        let var =
            blocks.iter().map(|b| (b - mean).powi(2)).sum::<f64>() / (blocks.len() - 1) as f64;
        let se = (var / blocks.len() as f64).sqrt();
        println!("| {n} | {steps} | {mean:.3} | {se:.3} |");
        pts.push(((n as f64 - 1.0).ln(), mean.ln()));
    }
    let m = pts.len() as f64;
    let (sx, sy) = pts.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
    let (mx, my) = (sx / m, sy / m);
    let slope = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum::<f64>()
        / pts.iter().map(|p| (p.0 - mx).powi(2)).sum::<f64>();
    let nu = slope / 2.0;
    println!("\nfit ⟨R_g²⟩ ∝ (N−1)^(2ν): ν = {nu:.3} (self-avoiding walk: 0.588)");
    for w in pts.windows(2) {
        println!(
            "local exponent between ln(N−1) = {:.2} and {:.2}: ν = {:.3}",
            w[0].0,
            w[1].0,
            (w[1].1 - w[0].1) / (w[1].0 - w[0].0) / 2.0
        );
    }
    // For information: with the leading correction to scaling, ⟨R_g²⟩ = A (N−1)^{2ν}(1 + B (N−1)^{−Δ}),
    // Δ = 0.528 (3D self-avoiding walk), scanning B and fitting A, ν by least squares.
    let mut best = (f64::INFINITY, 0.0, 0.0);
    for k in 0..=6000 {
        let b = -3.0 + k as f64 * 1e-3;
        let ys: Vec<(f64, f64)> = pts
            .iter()
            .map(|p| (p.0, p.1 - (1.0 + b * (-0.528 * p.0).exp()).ln()))
            .collect();
        if ys.iter().any(|p| !p.1.is_finite()) {
            continue;
        }
        let (sx, sy) = ys.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
        let (mx, my) = (sx / m, sy / m);
        let sl = ys.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum::<f64>()
            / ys.iter().map(|p| (p.0 - mx).powi(2)).sum::<f64>();
        let res: f64 = ys
            .iter()
            .map(|p| (p.1 - my - sl * (p.0 - mx)).powi(2))
            .sum();
        if res < best.0 {
            best = (res, sl / 2.0, b);
        }
    }
    println!("with the correction to scaling (Δ = 0.528): ν = {:.3}, B = {:.2} (3 parameters from {} points: indicative only)", best.1, best.2, pts.len());
    assert!((nu - 0.588).abs() < 0.05, "ν = {nu}");
}

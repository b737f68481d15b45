//! DPD fluid validation at full length (ignored; `scripts/dpd_validation.sh` runs it in release
//! mode and writes `docs/dpd_validation.md`): for several `(a, γ, ρ, k, k_BT)`, the kinetic
//! temperature, the virial pressure against published simulation values where they exist,
//! and the viscosity from periodic Poiseuille flow against the kinetic-theory estimate.

use mobo::dpd::pair_force::PairParams;
use mobo::dpd::poiseuille::{kinetic_theory_viscosity, ProfileSampler};
use mobo::dpd::system::{BodyForce, DpdParams, DpdSystem};

struct Case {
    a: f64,
    gamma: f64,
    rho: f64,
    power: f64,
    kbt: f64,
    /// Published pressure (Allen & Tildesley's DPD example, Lowe thermostat), if any.
    published_p: Option<f64>,
}

fn params(c: &Case, box_len: [f64; 3], seed: u64) -> DpdParams {
    DpdParams {
        box_len,
        pair: PairParams {
            a: c.a,
            gamma: c.gamma,
            kbt: c.kbt,
            rc: 1.0,
            power: c.power,
        },
        dt: if c.gamma > 10.0 { 0.005 } else { 0.01 },
        mass: 1.0,
        seed,
    }
}

#[test]
#[ignore = "long: run by scripts/dpd_validation.sh (about 10 minutes in release mode)"]
fn viscosity_pressure_and_temperature_over_parameter_sets() {
    let cases = [
        Case {
            a: 25.0,
            gamma: 4.5,
            rho: 3.0,
            power: 1.0,
            kbt: 1.0,
            published_p: Some(23.637),
        },
        Case {
            a: 18.75,
            gamma: 4.5,
            rho: 4.0,
            power: 1.0,
            kbt: 1.0,
            published_p: Some(32.622),
        },
        Case {
            a: 12.5,
            gamma: 4.5,
            rho: 3.0,
            power: 1.0,
            kbt: 0.5,
            published_p: Some(11.814),
        },
        Case {
            a: 0.0,
            gamma: 4.5,
            rho: 3.0,
            power: 1.0,
            kbt: 1.0,
            published_p: Some(3.0),
        },
        Case {
            a: 25.0,
            gamma: 20.0,
            rho: 3.0,
            power: 1.0,
            kbt: 1.0,
            published_p: None,
        },
        Case {
            a: 25.0,
            gamma: 4.5,
            rho: 3.0,
            power: 0.25,
            kbt: 1.0,
            published_p: None,
        },
        Case {
            a: 25.0,
            gamma: 4.5,
            rho: 3.0,
            power: 0.5,
            kbt: 1.0,
            published_p: None,
        },
    ];
    println!("| a | γ | ρ | k | k_BT | measured k_BT | pressure | published p | η (Poiseuille) | η kinetic theory | η / η_kin |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let mut failures = Vec::new();
    for (m, c) in cases.iter().enumerate() {
        // Equilibrium: temperature and pressure.
        let mut eq =
            DpdSystem::random_fluid(params(c, [10.0; 3], 100 + m as u64), c.rho, BodyForce::None)
                .unwrap();
        for _ in 0..1000 {
            eq.step().unwrap();
        }
        let (mut t, mut p) = (0.0, 0.0);
        let samples = 4000;
        for _ in 0..samples {
            eq.step().unwrap();
            t += eq.kinetic_temperature();
            p += eq.pressure();
        }
        let (t, p) = (t / samples as f64, p / samples as f64);
        // Periodic Poiseuille: force chosen for a peak velocity ≈ 0.4 √(k_BT/m) by the estimate.
        let lz = 20.0;
        let kin = kinetic_theory_viscosity(c.rho, c.gamma, c.kbt, 1.0, c.power, 1.0).total;
        let g = 2.0 * kin * 0.4 * c.kbt.sqrt() / (c.rho * (lz / 4.0) * (lz / 4.0));
        let mut sys = DpdSystem::random_fluid(
            params(c, [10.0, 10.0, lz], 200 + m as u64),
            c.rho,
            BodyForce::ReversePoiseuille { force: g },
        )
        .unwrap();
        for _ in 0..4000 {
            sys.step().unwrap();
        }
        let mut sampler = ProfileSampler::new(lz, 20, 160);
        for s in 1..=16000 {
            sys.step().unwrap();
            if s % 10 == 0 {
                sampler.sample(&sys);
            }
        }
        let fit = sampler.viscosity(sys.density(), g).unwrap();
        let ratio = fit.value / kin;
        println!(
            "| {} | {} | {} | {} | {} | {:.4} | {:.3} | {} | {:.3} ± {:.3} | {:.3} | {:.2} |",
            c.a,
            c.gamma,
            c.rho,
            c.power,
            c.kbt,
            t,
            p,
            c.published_p.map_or("–".into(), |v| format!("{v}")),
            fit.value,
            fit.stderr,
            kin,
            ratio
        );
        if (t / c.kbt - 1.0).abs() > 0.01 {
            failures.push(format!("case {m}: k_BT {t} vs {}", c.kbt));
        }
        if let Some(pp) = c.published_p {
            if (p / pp - 1.0).abs() > 0.01 {
                failures.push(format!("case {m}: pressure {p} vs published {pp}"));
            }
        }
        // Kinetic theory is an estimate, not a reference: measured ratios run from 0.96
        // (standard fluid) to 1.6 (γ = 20), as the literature reports (Pagonabarraga et al.
        // 1998; Marsh et al. 1997 for the ideal gas). What must hold: the fit is resolved
        // (standard error below 8 %) and the ratio is in the band measured here.
        if !(0.8..=1.8).contains(&ratio) || fit.stderr > 0.08 * fit.value {
            failures.push(format!(
                "case {m}: η / η_kin = {ratio}, stderr {}",
                fit.stderr
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}

//! The DPD fluid against independent references: the cell-list forces against the all-pairs
//! sum, the thermostat against the set temperature, the virial pressure against Groot &
//! Warren's equation of state and against the pressure integral of the measured g(r), the
//! viscosity from periodic Poiseuille flow against kinetic theory, and reproducibility across
//! thread counts.

use mobo::check::assert_close;
use mobo::dpd::pair_force::{all_pairs_forces, PairParams};
use mobo::dpd::poiseuille::kinetic_theory_viscosity;
use mobo::dpd::rng::step_key;
use mobo::dpd::system::{BodyForce, DpdParams, DpdSystem};

fn params(box_len: [f64; 3], a: f64, gamma: f64, power: f64, dt: f64, seed: u64) -> DpdParams {
    DpdParams {
        box_len,
        pair: PairParams {
            a,
            gamma,
            kbt: 1.0,
            rc: 1.0,
            power,
        },
        dt,
        mass: 1.0,
        seed,
    }
}

#[test]
fn cell_list_forces_match_the_all_pairs_sum_for_every_kernel_exponent() {
    for (k, power) in [0.25, 0.5, 1.0, 1.5].into_iter().enumerate() {
        let prm = params([4.0, 5.0, 3.5], 25.0, 4.5, power, 0.01, 3 + k as u64);
        let sys = DpdSystem::random_fluid(prm, 3.0, BodyForce::None).unwrap();
        let x = sys.positions();
        let v = sys.velocities();
        let want = all_pairs_forces(
            &prm.pair,
            prm.box_len,
            &x,
            &v,
            &sys.particles.id,
            step_key(prm.seed, 0),
            prm.dt,
        );
        let got: Vec<f64> = (0..sys.len())
            .flat_map(|i| [sys.fx[i], sys.fy[i], sys.fz[i]])
            .collect();
        let want: Vec<f64> = want.into_iter().flatten().collect();
        assert_close(
            &format!("cell-list forces, k = {power}"),
            &got,
            &want,
            1e-12,
        );
        // Pair forces are antisymmetric: they sum to zero.
        let n = sys.len() as f64;
        let scale = got.iter().map(|f| f.abs()).sum::<f64>() / n;
        for c in 0..3 {
            let s: f64 = got.iter().skip(c).step_by(3).sum();
            assert!(s.abs() < 1e-10 * scale * n, "net force {s}");
        }
    }
}

#[test]
fn trajectories_do_not_depend_on_the_thread_count() {
    let prm = params([6.0, 6.0, 6.0], 25.0, 4.5, 1.0, 0.02, 11);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut s = DpdSystem::random_fluid(prm, 3.0, BodyForce::None).unwrap();
            for _ in 0..30 {
                s.step().unwrap();
            }
            (s.positions(), s.velocities(), s.particles.id.clone())
        })
    };
    assert_eq!(run(1), run(3));
}

/// Mean kinetic temperature and virial pressure over `steps` after `warm` steps.
fn equilibrium(sys: &mut DpdSystem, warm: usize, steps: usize) -> (f64, f64) {
    for _ in 0..warm {
        sys.step().unwrap();
    }
    let (mut t, mut p) = (0.0, 0.0);
    for _ in 0..steps {
        sys.step().unwrap();
        t += sys.kinetic_temperature();
        p += sys.pressure();
    }
    (t / steps as f64, p / steps as f64)
}

#[test]
fn thermostat_holds_the_temperature_and_pressure_follows_the_equation_of_state() {
    // ρ = 3, a = 25, γ = 4.5, dt = 0.01: k_BT within 1 %. Pressure: the published simulation
    // value at (k_BT, ρ, a) = (1, 3, 25) is 23.637 ± 0.002 (Allen & Tildesley's DPD example
    // with the Lowe thermostat, which has no time-step error in k_BT); Liyana-Arachchi et al.'s
    // (2015) equation of state gives 23.587. Groot & Warren's p = ρk_BT + αaρ², α = 0.101,
    // gives 25.7: that fit is 8 % high at ρ = 3 (the effective α here is ≈ 0.092), so it is
    // reported, not asserted.
    let prm = params([7.0, 7.0, 7.0], 25.0, 4.5, 1.0, 0.01, 5);
    let mut sys = DpdSystem::random_fluid(prm, 3.0, BodyForce::None).unwrap();
    let p0 = sys.momentum();
    let (kt, p) = equilibrium(&mut sys, 300, 1500);
    assert!((kt - 1.0).abs() < 0.01, "k_BT = {kt}");
    let published = 23.637;
    assert!(
        (p / published - 1.0).abs() < 0.01,
        "pressure {p} vs published {published}"
    );
    let alpha = (p - 3.0 * kt) / (25.0 * 9.0);
    assert!(
        (alpha - 0.101).abs() < 0.015,
        "effective α = {alpha} vs Groot–Warren's 0.101"
    );
    // Momentum is conserved up to rounding.
    let p1 = sys.momentum();
    for c in 0..3 {
        assert!(
            (p1[c] - p0[c]).abs() < 1e-9 * sys.len() as f64,
            "momentum drift {:?}",
            p1
        );
    }
    // g(r): 1 at large r, and the pressure integral of g reproduces the virial pressure
    // p = n k_BT + (2π n²/3) ∫ r³ a w(r) g(r) dr (a consistency check of two estimators).
    let (r, g) = sys.radial_distribution(2.3, 230).unwrap();
    let tail: Vec<f64> = r
        .iter()
        .zip(&g)
        .filter(|(r, _)| **r > 1.5)
        .map(|(_, g)| *g)
        .collect();
    let mean_tail = tail.iter().sum::<f64>() / tail.len() as f64;
    assert!(
        (mean_tail - 1.0).abs() < 0.02,
        "g(r) beyond 1.5 r_c: {mean_tail}"
    );
    let n = sys.density();
    let dr = r[1] - r[0];
    let integral: f64 = r
        .iter()
        .zip(&g)
        .filter(|(r, _)| **r < 1.0)
        .map(|(r, g)| r.powi(3) * 25.0 * (1.0 - r) * g * dr)
        .sum();
    let p_g = n * sys.kinetic_temperature() + 2.0 * std::f64::consts::PI * n * n / 3.0 * integral;
    assert!(
        (p_g / sys.pressure() - 1.0).abs() < 0.02,
        "g(r) pressure {p_g} vs virial {}",
        sys.pressure()
    );
}

#[test]
fn poiseuille_viscosity_agrees_with_kinetic_theory_within_its_known_deviation() {
    use mobo::dpd::poiseuille::ProfileSampler;
    let (a, gamma, rho, g) = (25.0, 4.5, 3.0, 0.1);
    let lz = 16.0;
    let prm = params([6.0, 6.0, lz], a, gamma, 1.0, 0.02, 21);
    let mut sys =
        DpdSystem::random_fluid(prm, rho, BodyForce::ReversePoiseuille { force: g }).unwrap();
    for _ in 0..1000 {
        sys.step().unwrap();
    }
    let mut sampler = ProfileSampler::new(lz, 16, 50);
    for s in 1..=4000 {
        sys.step().unwrap();
        if s % 10 == 0 {
            sampler.sample(&sys);
        }
    }
    let fit = sampler.viscosity(sys.density(), g).unwrap();
    let kin = kinetic_theory_viscosity(rho, gamma, 1.0, 1.0, 1.0, 1.0).total;
    println!(
        "viscosity {} ± {} (kinetic theory {kin})",
        fit.value, fit.stderr
    );
    assert!(fit.stderr < 0.1 * fit.value, "stderr {}", fit.stderr);
    assert!(
        (fit.value / kin - 1.0).abs() < 0.3,
        "η = {} vs kinetic {kin}",
        fit.value
    );
}

/// Poiseuille flow between walls: no particle gets into the wall, the no-slip condition holds
/// to within 20 % of the centre velocity, and the viscosity fitted to the profile in the
/// middle of the channel (or pipe) agrees with the periodic-Poiseuille value of the same fluid
/// (0.917 ± 0.037, docs/dpd_validation.md) within 20 % — two independent flows, one with
/// frozen-particle walls and bounce-back, one without any wall. Measured: channel 0.85 ± 0.07,
/// pipe (R = 3.5 r_c) 0.78 ± 0.05; longer runs (docs/dpd.md) show the apparent viscosity
/// falling with confinement: −1 % for a gap of 12 r_c, −7 % and −14 % for pipes of radius 6
/// and 3.5 r_c.
fn wall_flow(
    wall_of: impl Fn(&DpdParams) -> mobo::dpd::walls::Wall,
    box_len: [f64; 3],
    g: f64,
    warm: usize,
) -> (f64, f64, f64) {
    use mobo::dpd::poiseuille::{FlowGeometry, ProfileSampler};
    use mobo::dpd::walls::Wall;
    let prm = params(box_len, 25.0, 4.5, 1.0, 0.01, 31);
    let wall = wall_of(&prm);
    let mut sys =
        DpdSystem::with_wall(prm, 3.0, BodyForce::Constant([g, 0.0, 0.0]), wall, 200).unwrap();
    let geometry = match wall {
        Wall::Planes { lo, hi } => FlowGeometry::Channel { lo, hi },
        Wall::Cylinder { radius, center } => FlowGeometry::Pipe { center, radius },
    };
    // The flow starts from rest: wait ~3 decay times of its slowest mode (h²/π²ν, a²/j₀²ν).
    for _ in 0..warm {
        sys.step().unwrap();
    }
    let mut sampler = ProfileSampler::with_geometry(geometry, box_len, 20, 60);
    for s in 1..=4800 {
        sys.step().unwrap();
        if s % 10 == 0 {
            sampler.sample(&sys);
        }
    }
    assert_eq!(sys.leaked, 0, "particles left inside the wall");
    let p = &sys.particles;
    for i in 0..sys.len() {
        if p.moves[i] != 0.0 {
            assert!(
                wall.sdf([p.x[i], p.y[i], p.z[i]]) < 0.0,
                "particle {i} in the wall"
            );
        }
    }
    assert!(sys.bounces > 0);
    let fit = sampler.viscosity(sys.density(), g).unwrap();
    // Slip: the fitted parabola at the wall relative to its centre value.
    let edge = match wall {
        Wall::Planes { lo, hi } => 0.5 * (hi - lo),
        Wall::Cylinder { radius, .. } => radius,
    };
    let slip = (fit.offset + fit.curvature * edge * edge) / fit.offset;
    println!(
        "{wall:?}: η = {:.3} ± {:.3}, wall slip u(wall)/u(0) = {slip:.3}, n = {:.3}",
        fit.value,
        fit.stderr,
        sys.density()
    );
    (fit.value, fit.stderr, slip)
}

#[test]
fn plane_poiseuille_between_walls_gives_the_periodic_viscosity() {
    let (eta, se, slip) = wall_flow(
        |p| mobo::dpd::walls::Wall::channel(6.0, p.box_len[2], 1.0).unwrap(),
        [6.0, 6.0, 8.0],
        0.04,
        4000,
    );
    assert!(se < 0.1 * eta, "stderr {se}");
    assert!(
        (eta / 0.917 - 1.0).abs() < 0.2,
        "η between walls {eta} vs periodic 0.917"
    );
    assert!(slip.abs() < 0.2, "slip {slip}");
}

#[test]
fn pipe_poiseuille_gives_the_periodic_viscosity() {
    let (eta, se, slip) = wall_flow(
        |p| mobo::dpd::walls::Wall::pipe(3.5, p.box_len[1], p.box_len[2], 1.0).unwrap(),
        [5.0, 9.0, 9.0],
        0.12,
        3000,
    );
    assert!(se < 0.1 * eta, "stderr {se}");
    assert!(
        (eta / 0.917 - 1.0).abs() < 0.2,
        "η in the pipe {eta} vs periodic 0.917"
    );
    assert!(slip.abs() < 0.25, "slip {slip}");
}

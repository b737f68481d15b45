//! Cells coupled through the FMM: the inter-cell velocity against a high-order direct
//! quadrature (far apart and near contact), and two sedimenting spherical vesicles against the
//! two-sphere mobility (speed-up `1 + 3a/2d` in line, `1 + 3a/4d` side by side).

use std::f64::consts::PI;

mod common;
use common::quadrature::{max_rel, reference};

use mobo::sph_harmonics::ShTransform;
use mobo::timestep::coupling::{Coupling, CouplingParams};
use mobo::timestep::semi_implicit::{TimeScheme, VesicleParams};
use mobo::timestep::suspension::{CellSetup, Suspension};
use mobo::timestep::GmresParams;
use mobo::vesicle::shapes::{ellipsoid, sphere};
use mobo::vesicle::SurfaceCalculus;

/// A smooth traction on the order-`p` grid of the surface `coefs`.
fn traction(p: usize, coefs: &[f64], seed: f64) -> Vec<f64> {
    let sht = ShTransform::new(p).unwrap();
    let n = sht.n_points();
    let mut x = vec![0.0; 3 * n];
    sht.inverse(coefs, &mut x, &mut sht.workspace()).unwrap();
    let mut f = vec![0.0; 3 * n];
    for j in 0..n {
        let (a, b, c) = (x[j], x[n + j], x[2 * n + j]);
        f[j] = (a + seed * b).sin() + 0.3;
        f[n + j] = (c - seed).cos() * a;
        f[2 * n + j] = a * b + seed * c;
    }
    f
}

fn ellipsoids(p: usize, gap: f64) -> Vec<Vec<f64>> {
    // Axes 1:0.8:0.6; the second cell is rotated and placed `gap` beyond the first along x.
    let mut a = ellipsoid(p, [1.0, 0.8, 0.6]).unwrap();
    a.translate([0.0, 0.1, -0.05]);
    let mut b = ellipsoid(p, [0.6, 0.8, 1.0]).unwrap();
    b.translate([1.0 + gap + 0.6, 0.0, 0.0]);
    let mut c = sphere(p, 0.7).unwrap();
    c.translate([0.2, 2.5 + gap, 0.3]);
    vec![a.coefs().to_vec(), b.coefs().to_vec(), c.coefs().to_vec()]
}

fn coupling_error(p: usize, gap: f64, digits: u32) -> (f64, usize) {
    let coefs = ellipsoids(p, gap);
    let f: Vec<Vec<f64>> = coefs
        .iter()
        .enumerate()
        .map(|(i, c)| traction(p, c, 0.7 * i as f64 + 0.2))
        .collect();
    let mu = 1.3;
    let mut cpl = Coupling::new(
        p,
        2 * p,
        CouplingParams {
            viscosity: mu,
            fmm_digits: digits,
            ..Default::default()
        },
    )
    .unwrap();
    let cref: Vec<&[f64]> = coefs.iter().map(|c| c.as_slice()).collect();
    let fref: Vec<&[f64]> = f.iter().map(|c| c.as_slice()).collect();
    let u = cpl.velocities(&cref, &fref).unwrap();
    let want = reference(p, 160, &coefs, &f, mu);
    assert_eq!(cpl.stats.fmm_builds, 1);
    (max_rel(&u, &want), cpl.stats.near_points)
}

#[test]
fn inter_cell_velocity_of_separated_cells_matches_a_fine_direct_quadrature() {
    let (err, near) = coupling_error(8, 1.5, 7);
    println!("gap 1.5: max relative error {err:.2e}, {near} near points");
    assert_eq!(near, 0, "no point is near at gap 1.5");
    assert!(err < 1e-6, "{err}");
}

#[test]
fn inter_cell_velocity_near_contact_is_corrected_to_the_fine_quadrature() {
    for gap in [0.3, 0.1] {
        let (err, near) = coupling_error(8, gap, 7);
        println!("gap {gap}: max relative error {err:.2e}, {near} near points");
        assert!(near > 0, "points within the near zone at gap {gap}");
        assert!(err < 1e-5, "gap {gap}: {err}");
    }
}

/// Centroid velocities of spherical vesicles of radius `a` under force `F = (0, 0, −1)`,
/// centres at `centres`, after one step.
fn sedimentation(p: usize, a: f64, centres: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let dt = 0.01;
    let cells = centres
        .iter()
        .map(|&c| {
            let mut s = sphere(p, a).unwrap();
            s.translate(c);
            CellSetup {
                coefs: s.coefs().to_vec(),
                params: VesicleParams {
                    bending_modulus: 1.0,
                    viscosity: 1.0,
                    force: [0.0, 0.0, -1.0],
                    dt,
                    upsampled_order: 2 * p,
                    gmres: GmresParams {
                        tol: 1e-12,
                        restart: 200,
                        max_iters: 2000,
                        ..Default::default()
                    },
                    correct_drift: false,
                    reparametrize: None,
                    preconditioner: true,
                    scheme: TimeScheme::Euler,
                    viscosity_ratio: 1.0,
                    inextensible: true,
                    elastic_stepping: None,
                },
                skalak: None,
            }
        })
        .collect();
    let mut susp = Suspension::new(
        p,
        cells,
        CouplingParams {
            fmm_digits: 7,
            ..Default::default()
        },
    )
    .unwrap();
    let mut calc = SurfaceCalculus::new(p).unwrap();
    let before: Vec<[f64; 3]> = susp
        .coefs()
        .iter()
        .map(|c| calc.geometry(c).unwrap().centroid())
        .collect();
    susp.step(&|_| [0.0; 3]).unwrap();
    susp.coefs()
        .iter()
        .zip(&before)
        .map(|(c, b)| {
            let x = calc.geometry(c).unwrap().centroid();
            std::array::from_fn(|d| (x[d] - b[d]) / dt)
        })
        .collect()
}

#[test]
fn two_sedimenting_spheres_speed_up_as_the_two_sphere_mobility_says() {
    let (p, a) = (8, 1.0);
    let u0 = 1.0 / (6.0 * PI * a);
    for d in [5.0, 10.0] {
        let s = a / d;
        // In line (along gravity): 1 + 3a/2d − a³/d³ (+ O(a⁴/d⁴)).
        let v = sedimentation(p, a, &[[0.0, 0.0, 0.0], [0.0, 0.0, d]]);
        let lead = 1.0 + 1.5 * s;
        let rp = lead - s.powi(3);
        for u in &v {
            let ratio = -u[2] / u0;
            println!("in line d = {d}: U/U0 = {ratio:.6} (1 + 3a/2d = {lead:.6}, RPY {rp:.6})");
            assert!(
                (ratio - lead).abs() < 2.0 * s.powi(3),
                "in line d = {d}: {ratio}"
            );
            assert!(
                (ratio - rp).abs() < 5.0 * s.powi(4),
                "in line d = {d}: {ratio} vs {rp}"
            );
            assert!(u[0].abs() < 1e-6 * u0 && u[1].abs() < 1e-6 * u0);
        }
        // Side by side: 1 + 3a/4d + a³/2d³.
        let v = sedimentation(p, a, &[[0.0, 0.0, 0.0], [d, 0.0, 0.0]]);
        let lead = 1.0 + 0.75 * s;
        let rp = lead + 0.5 * s.powi(3);
        for u in &v {
            let ratio = -u[2] / u0;
            println!(
                "side by side d = {d}: U/U0 = {ratio:.6} (1 + 3a/4d = {lead:.6}, RPY {rp:.6})"
            );
            assert!(
                (ratio - lead).abs() < 2.0 * s.powi(3),
                "side by side d = {d}: {ratio}"
            );
            assert!(
                (ratio - rp).abs() < 5.0 * s.powi(4),
                "side by side d = {d}: {ratio} vs {rp}"
            );
        }
    }
}

/// Two prolate vesicles (reduced volume 0.9, equivalent radius 0.8, side by side) driven into each other by
/// opposite forces: the smallest distance of a grid point of one to the other's surface over
/// `steps` steps. (Exact spheres are avoided: a sphere in the straining flow of a close
/// neighbour makes the step's system singular in the mean tension, which GMRES reports as a
/// breakdown.)
fn head_on(strength: f64, steps: usize) -> (f64, f64, usize) {
    let (p, dt) = (6, 0.05);
    let cells = [(-0.72, 4.0), (0.72, -4.0)]
        .iter()
        .map(|&(x, fx)| {
            let mut s = mobo::vesicle::shapes::reduced_volume_spheroid(
                p,
                0.9,
                mobo::vesicle::Spheroid::Prolate,
                0.8,
            )
            .unwrap();
            s.place_centroid([x, 0.0, 0.0]).unwrap();
            CellSetup {
                coefs: s.coefs().to_vec(),
                params: VesicleParams {
                    bending_modulus: 0.1,
                    viscosity: 1.0,
                    force: [fx, 0.0, 0.0],
                    dt,
                    upsampled_order: 2 * p,
                    gmres: GmresParams {
                        tol: 1e-8,
                        restart: 200,
                        max_iters: 2000,
                        ..Default::default()
                    },
                    correct_drift: true,
                    reparametrize: None,
                    preconditioner: true,
                    scheme: TimeScheme::Euler,
                    viscosity_ratio: 1.0,
                    inextensible: true,
                    elastic_stepping: None,
                },
                skalak: None,
            }
        })
        .collect();
    let mut susp = Suspension::new(
        p,
        cells,
        CouplingParams {
            repulsion_strength: strength,
            repulsion_range: 0.3,
            ..Default::default()
        },
    )
    .unwrap();
    let mut gap = f64::INFINITY;
    for k in 0..steps {
        let r = susp.step(&|_| [0.0; 3]).unwrap();
        let st = susp.coupling_stats().unwrap();
        gap = gap.min(st.min_gap);
        if std::env::var("MOBO_DEBUG").is_ok() {
            let mut calc = SurfaceCalculus::new(6).unwrap();
            let x0 = calc
                .geometry(&susp.cells()[0].state.coefs)
                .unwrap()
                .centroid()[0];
            let sig = susp.cells()[0]
                .state
                .sigma
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()));
            println!(
                "s {strength} step {k}: gap {:.4} x0 {x0:.4} |σ| {sig:.3e} gmres {} res {:.1e}",
                st.min_gap, r.cells[0].gmres.iterations, r.cells[0].gmres.relative_residual
            );
        }
    }
    let st = susp.coupling_stats().unwrap();
    (gap, st.min_gap, st.repulsion_points)
}

#[test]
fn contact_repulsion_keeps_cells_apart_that_are_driven_together() {
    // Traction scale of the driving force: |F| / 4πR² ≈ 0.5; repulsion at 10× that, within
    // 0.3 R = 0.24 (the cells start 0.16 apart and flatten against each other).
    let steps = 40;
    let (free_min, free, n0) = head_on(0.0, steps);
    let (held_min, held, n1) = head_on(5.0, steps);
    println!(
        "gap after {steps} steps: no repulsion {free:.4} (min {free_min:.4}), \
         repulsion {held:.4} (min {held_min:.4}, {n1} pushes)"
    );
    assert_eq!(n0, 0);
    assert!(n1 > 0, "the repulsion acted");
    assert!(free_min > 0.0 && held_min > 0.0, "no overlap");
    assert!(
        held > free + 0.02,
        "the repulsion pushes the cells apart: {held} vs {free}"
    );
}

//! Membrane forces against virtual work (central differences of the energies), closed forms on
//! spheres, and the identities that tie tension and divergence together.

use std::f64::consts::PI;

use mobo::check::{assert_close, assert_close_floor};
use mobo::sph_harmonics::{resample_coefs, CoefLayout, Grid, ShTransform};
use mobo::vesicle::{shapes, Membrane, SkalakParams, Surface, SurfaceCalculus, VesicleError};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// Coefficients (order `p`, `x, y, z`) of a random vector field of degree `≤ nmax` with
/// coefficients decaying like `(1+n)^{-2}`, scaled to max-norm `amp` on the grid.
fn random_field_coefs(p: usize, nmax: usize, seed: u64, amp: f64) -> Vec<f64> {
    let low = CoefLayout::new(nmax);
    let mut rng = StdRng::seed_from_u64(seed);
    let a: Vec<f64> = (0..3)
        .flat_map(|_| low.degrees())
        .map(|n| rng.random_range(-1.0..1.0) / (1.0 + n as f64).powi(2))
        .collect();
    let sht = ShTransform::new(p).unwrap();
    let mut c = vec![0.0; 3 * sht.n_coefs()];
    resample_coefs(&low, sht.layout(), &a, &mut c).unwrap();
    let g = grid_of(&sht, &c);
    let m = g.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    c.iter().map(|v| v * amp / m).collect()
}

/// Grid values of a batch of coefficient vectors.
fn grid_of(sht: &ShTransform, c: &[f64]) -> Vec<f64> {
    let mut g = vec![0.0; c.len() / sht.n_coefs() * sht.n_points()];
    sht.inverse(c, &mut g, &mut sht.workspace()).unwrap();
    g
}

fn axpy(x: &[f64], h: f64, d: &[f64]) -> Vec<f64> {
    x.iter().zip(d).map(|(a, b)| a + h * b).collect()
}

/// `Σ_j f_j·v_j da_j` for component-major fields on a grid with weights `da`.
fn work(f: &[f64], v: &[f64], da: &[f64]) -> f64 {
    let np = da.len();
    (0..np)
        .map(|j| (0..3).map(|c| f[c * np + j] * v[c * np + j]).sum::<f64>() * da[j])
        .sum()
}

/// Virtual work `∫ f·δX dA = −dE/dε` by central differences.
///
/// Step analysis: the central difference `D(h) = (E(h) − E(−h))/2h` has truncation error
/// `T(h) ≈ |D(h) − D(2h)|/3 = c h²` and round-off error `R(h) ≈ 2ν/h`, with `ν` the noise of one
/// energy evaluation, measured as 4× the largest residual of a straight-line fit to `E` at five
/// steps `≤ 2e-9` (where the energy is linear far below round-off). `c` is estimated at
/// `h₀ = 1e-3`, the step is the minimiser `h = (ν/c)^{1/3}` of `T + R`, and both `T(h)` (measured
/// again) and `R(h)` must be below `2e-7 |D|`. Then the virtual work of the force on the
/// upsampled grid must match to `tol_q`, and that of the filtered force to `tol_p`.
#[allow(clippy::too_many_arguments)]
fn check_virtual_work(
    name: &str,
    m: &mut Membrane,
    x: &[f64],
    dx: &[f64],
    energy: &dyn Fn(&mut Membrane) -> f64,
    force_fine: &dyn Fn(&mut Membrane, &mut [f64]),
    force: &dyn Fn(&mut Membrane, &mut [f64]),
    tol_q: f64,
    tol_p: f64,
) {
    let p = m.order();
    let q = m.upsampled_order();
    let sht_p = ShTransform::new(p).unwrap();
    let mut e_at = |h: f64| {
        m.set_geometry(&axpy(x, h, dx)).unwrap();
        energy(m)
    };
    let tiny: Vec<f64> = (-2..=2).map(|k| k as f64 * 1e-9).collect();
    let et: Vec<f64> = tiny.iter().map(|&h| e_at(h)).collect();
    let slope = tiny.iter().zip(&et).map(|(h, e)| h * e).sum::<f64>()
        / tiny.iter().map(|h| h * h).sum::<f64>();
    let mean = et.iter().sum::<f64>() / 5.0;
    let noise = 4.0
        * tiny
            .iter()
            .zip(&et)
            .map(|(h, e)| (e - mean - slope * h).abs())
            .fold(f64::EPSILON * mean.abs(), f64::max);
    let mut central = |h: f64| (e_at(h) - e_at(-h)) / (2.0 * h);
    let h0 = 1e-3;
    let c = ((central(h0) - central(2.0 * h0)).abs() / 3.0 / (h0 * h0)).max(1e-300);
    let h = (noise / c).cbrt().clamp(1e-6, 1e-2);
    let d1 = central(h);
    let trunc = (d1 - central(2.0 * h)).abs() / 3.0;
    let roundoff = 2.0 * noise / h;
    assert!(
        trunc < 2e-7 * d1.abs() && roundoff < 2e-7 * d1.abs(),
        "{name}: no step h meets the error budget: h = {h:.2e}, truncation {trunc:.2e}, \
         round-off {roundoff:.2e}, |dE| = {:.3e}",
        d1.abs()
    );
    // Upsampled force at q against δX upsampled (exact: δX is band-limited at p).
    m.set_geometry(x).unwrap();
    let dx_p = grid_of(&sht_p, dx);
    let mut dx_q = vec![0.0; 3 * m.n_points_upsampled()];
    m.upsample(&dx_p, &mut dx_q).unwrap();
    let mut f_q = vec![0.0; dx_q.len()];
    force_fine(m, &mut f_q);
    let da_q = m.geometry().unwrap().da.clone();
    let w_q = work(&f_q, &dx_q, &da_q);
    // Filtered force on the order-p grid: its density per solid angle f_p J_p = P_p(f J) is
    // band-limited at p, so the pairing ∫ f_p·δX dA = ∫ (f_p J_p)·δX dΩ is evaluated exactly by
    // upsampling f_p J_p to q (the order-p grid rule would alias the m = 2p products).
    let mut f_p = vec![0.0; dx_p.len()];
    force(m, &mut f_p);
    let g_p = SurfaceCalculus::new(p).unwrap().geometry(x).unwrap();
    let w_lat_p = Grid::new(p).quadrature_weights();
    let np = w_lat_p.len();
    for c in 0..3 {
        for j in 0..np {
            f_p[c * np + j] *= g_p.da[j] / w_lat_p[j];
        }
    }
    let mut fj_q = vec![0.0; dx_q.len()];
    m.upsample(&f_p, &mut fj_q).unwrap();
    let w_p = work(&fj_q, &dx_q, &Grid::new(q).quadrature_weights());
    let e_q = assert_close(
        &format!("{name}: virtual work at q = {q}"),
        &[-w_q],
        &[d1],
        tol_q,
    );
    let e_p = assert_close(
        &format!("{name}: virtual work, filtered force at p = {p}"),
        &[-w_p],
        &[d1],
        tol_p,
    );
    println!(
        "{name}, p={p} q={q}: dE = {d1:.10e}; error at q {e_q:.2e}, filtered at p {e_p:.2e} \
         (h = {h:.1e}: FD truncation {:.1e}, round-off {:.1e})",
        trunc / d1.abs(),
        roundoff / d1.abs()
    );
}

/// Upsampled orders and virtual-work tolerances at `p = 16`: the default `q = 2p` (the discrete
/// bending energy and force of the RBC agree to 1.3e-6 there, Skalak to 3.8e-7, everything else
/// to ~1e-8) and `q = 3p` (the 1e-6; measured ≤ 1e-8, the level of the difference
/// quotient's own error).
const Q_TOLERANCES: [(usize, f64); 2] = [(32, 1e-5), (48, 1e-6)];

fn shapes_under_test(p: usize) -> Vec<(&'static str, Surface)> {
    let mut bumpy = shapes::sphere(p, 1.0).unwrap();
    let d = random_field_coefs(p, 4, 99, 0.3);
    bumpy
        .coefs_mut()
        .iter_mut()
        .zip(&d)
        .for_each(|(a, b)| *a += b);
    vec![
        ("ellipsoid", shapes::ellipsoid(p, [1.0, 0.8, 0.6]).unwrap()),
        ("RBC", shapes::rbc(p).unwrap()),
        ("bumpy sphere", bumpy),
    ]
}

#[test]
fn bending_force_by_virtual_work() {
    let (p, kappa) = (16, 0.7);
    for (name, s) in shapes_under_test(p) {
        for (q, tol_q) in Q_TOLERANCES {
            let mut m = Membrane::new(p, q).unwrap();
            let dx = random_field_coefs(p, p, 1, 1.0);
            check_virtual_work(
                &format!("bending, {name}"),
                &mut m,
                s.coefs(),
                &dx,
                &|m| m.bending_energy(kappa).unwrap(),
                &|m, f| m.bending_force_upsampled(kappa, f).unwrap(),
                &|m, f| m.bending_force(kappa, f).unwrap(),
                tol_q,
                tol_q,
            );
        }
    }
}

#[test]
fn tension_force_by_virtual_work() {
    let p = 16;
    let sht = ShTransform::new(p).unwrap();
    // σ = 1.3 + a random expansion of degree ≤ 6 (fixed at material points).
    let low = CoefLayout::new(6);
    let mut rng = StdRng::seed_from_u64(5);
    let a: Vec<f64> = low
        .degrees()
        .iter()
        .map(|&n| 0.5 * rng.random_range(-1.0..1.0) / (1.0 + n as f64))
        .collect();
    let mut c = vec![0.0; sht.n_coefs()];
    resample_coefs(&low, sht.layout(), &a, &mut c).unwrap();
    let sigma: Vec<f64> = grid_of(&sht, &c).iter().map(|v| v + 1.3).collect();
    for (name, s) in shapes_under_test(p) {
        for (q, tol_q) in Q_TOLERANCES {
            let mut m = Membrane::new(p, q).unwrap();
            let dx = random_field_coefs(p, p, 2, 1.0);
            check_virtual_work(
                &format!("tension, {name}"),
                &mut m,
                s.coefs(),
                &dx,
                &|m| m.tension_energy(&sigma).unwrap(),
                &|m, f| m.tension_force_upsampled(&sigma, f).unwrap(),
                &|m, f| m.tension_force(&sigma, f).unwrap(),
                tol_q,
                tol_q,
            );
        }
    }
}

#[test]
fn skalak_force_by_virtual_work() {
    let p = 16;
    for par in [
        SkalakParams::skalak(1.5, 10.0),
        SkalakParams::neo_hookean(1.5),
    ] {
        for (name, s) in shapes_under_test(p) {
            for (q, tol_q) in Q_TOLERANCES {
                let mut m = Membrane::new(p, q).unwrap();
                m.set_reference(s.coefs()).unwrap();
                // A deformed state: the reference plus a smooth displacement.
                let x = axpy(s.coefs(), 1.0, &random_field_coefs(p, 5, 3, 0.1));
                let dx = random_field_coefs(p, p, 4, 1.0);
                check_virtual_work(
                    &format!("{:?}, {name}", par.law),
                    &mut m,
                    &x,
                    &dx,
                    &|m| m.skalak_energy(&par).unwrap(),
                    &|m, f| m.skalak_force_upsampled(&par, f).unwrap(),
                    &|m, f| m.skalak_force(&par, f).unwrap(),
                    tol_q,
                    tol_q,
                );
            }
        }
    }
}

#[test]
fn sphere_forces_in_closed_form() {
    let (p, r, kappa, sigma) = (12, 1.3, 0.8, 2.1);
    let mut s = shapes::sphere(p, r).unwrap();
    s.translate([0.2, -0.4, 1.0]);
    let mut m = Membrane::with_default_upsampling(p).unwrap();
    m.set_geometry(s.coefs()).unwrap();
    let np = m.n_points();
    let mut f = vec![0.0; 3 * np];
    // Bending force of a sphere vanishes (H² = K, Δ_s H = 0); scale κ/R³.
    m.bending_force(kappa, &mut f).unwrap();
    assert_close_floor(
        "sphere bending force",
        &f,
        &vec![0.0; 3 * np],
        // Round-off: two derivatives of H, each amplified ~q² near the poles (q = 24).
        1e-13 * 24.0 * 24.0,
        kappa / r.powi(3),
    );
    assert_close(
        "sphere bending energy",
        &[m.bending_energy(kappa).unwrap()],
        &[8.0 * PI * kappa],
        1e-13,
    );
    // Uniform tension: Laplace's law f = 2σH n = −(2σ/R) n.
    let sht = ShTransform::new(p).unwrap();
    let g = SurfaceCalculus::new(p)
        .unwrap()
        .geometry(s.coefs())
        .unwrap();
    let want: Vec<f64> = (0..3)
        .flat_map(|c| g.normal.iter().map(move |n| -2.0 * sigma / r * n[c]))
        .collect();
    m.tension_force(&vec![sigma; np], &mut f).unwrap();
    assert_close("Laplace's law", &f, &want, 1e-12);
    // Skalak, uniform inflation λ of the reference sphere: isotropic tension
    // τ = (G_s/λ²)[λ²(λ² − 1) + Cλ⁴(λ⁴ − 1)], force −(2τ/R) n.
    let par = SkalakParams::skalak(1.2, 3.0);
    let lam: f64 = 1.1;
    let s0 = shapes::sphere(p, r / lam).unwrap();
    m.set_reference(s0.coefs()).unwrap();
    let s1 = shapes::sphere(p, r).unwrap();
    m.set_geometry(s1.coefs()).unwrap();
    m.skalak_force(&par, &mut f).unwrap();
    let l2 = lam * lam;
    let tau =
        par.shear_modulus / l2 * (l2 * (l2 - 1.0) + par.dilation_ratio * l2 * l2 * (l2 * l2 - 1.0));
    let g1 = SurfaceCalculus::new(p)
        .unwrap()
        .geometry(s1.coefs())
        .unwrap();
    let want: Vec<f64> = (0..3)
        .flat_map(|c| g1.normal.iter().map(move |n| -2.0 * tau / r * n[c]))
        .collect();
    assert_close("Skalak inflated sphere", &f, &want, 1e-12);
    // Skalak energy: W_s with I₁ = 2(λ² − 1), I₂ = λ⁴ − 1, over the reference area.
    let (i1, i2) = (2.0 * (l2 - 1.0), l2 * l2 - 1.0);
    let ws =
        0.25 * par.shear_modulus * (i1 * i1 + 2.0 * i1 - 2.0 * i2 + par.dilation_ratio * i2 * i2);
    let a0 = 4.0 * PI * (r / lam).powi(2);
    assert_close(
        "Skalak energy",
        &[m.skalak_energy(&par).unwrap()],
        &[ws * a0],
        1e-13,
    );
    // Neo-Hookean, the same inflation: τ = (G_s/λ²)(λ² − 1/λ⁴), W_s = (G_s/2)(2λ² + 1/λ⁴ − 3).
    let nh = SkalakParams::neo_hookean(1.2);
    m.skalak_force(&nh, &mut f).unwrap();
    let tau = nh.shear_modulus / l2 * (l2 - 1.0 / (l2 * l2));
    let want: Vec<f64> = (0..3)
        .flat_map(|c| g1.normal.iter().map(move |n| -2.0 * tau / r * n[c]))
        .collect();
    assert_close("neo-Hookean inflated sphere", &f, &want, 1e-12);
    let ws = 0.5 * nh.shear_modulus * (2.0 * l2 + 1.0 / (l2 * l2) - 3.0);
    assert_close(
        "neo-Hookean energy",
        &[m.skalak_energy(&nh).unwrap()],
        &[ws * a0],
        1e-13,
    );
    let _ = sht;
}

#[test]
fn skalak_force_vanishes_for_rigid_motions_of_the_reference() {
    let p = 12;
    let par = SkalakParams::skalak(1.0, 50.0);
    let rbc = shapes::rbc(p).unwrap();
    let mut m = Membrane::with_default_upsampling(p).unwrap();
    m.set_reference(rbc.coefs()).unwrap();
    let mut moved = rbc.clone();
    let (c, s) = (0.6f64, 0.8f64);
    moved
        .rotate([[c, -s, 0.0], [s * c, c * c, -s], [s * s, s * c, c]])
        .unwrap();
    moved.translate([1.0, 2.0, 3.0]);
    let np = m.n_points();
    let mut f = vec![0.0; 3 * np];
    for surf in [&rbc, &moved] {
        m.set_geometry(surf.coefs()).unwrap();
        m.skalak_force(&par, &mut f).unwrap();
        assert_close_floor(
            "Skalak force of a rigid motion",
            &f,
            &vec![0.0; 3 * np],
            1e-11,
            par.shear_modulus,
        );
        // W_s is linear in I₁, I₂ near the reference: round-off of the metric, times the area.
        assert!(m.skalak_energy(&par).unwrap().abs() < 1e-12 * par.shear_modulus * 20.0);
    }
}

#[test]
fn linearised_bending_operator_matches_the_force_and_is_linear() {
    let (p, kappa) = (12, 1.0);
    let sht = ShTransform::new(p).unwrap();
    let np = sht.n_points();
    for (name, s) in shapes_under_test(p) {
        let mut m = Membrane::with_default_upsampling(p).unwrap();
        m.set_geometry(s.coefs()).unwrap();
        let x = grid_of(&sht, s.coefs());
        let (mut f, mut l) = (vec![0.0; 3 * np], vec![0.0; 3 * np]);
        m.bending_force(kappa, &mut f).unwrap();
        m.bending_linear(kappa, &x, &mut l).unwrap();
        let e = assert_close(&format!("{name}: linear bending at Y = X"), &l, &f, 1e-10);
        println!("{name}: linearised bending at Y = X vs force: {e:.2e}");
        let y1 = grid_of(&sht, &random_field_coefs(p, p, 7, 1.0));
        let y2 = grid_of(&sht, &random_field_coefs(p, p, 8, 1.0));
        let (mut l1, mut l2, mut l12) = (vec![0.0; 3 * np], vec![0.0; 3 * np], vec![0.0; 3 * np]);
        m.bending_linear(kappa, &y1, &mut l1).unwrap();
        m.bending_linear(kappa, &y2, &mut l2).unwrap();
        m.bending_linear(kappa, &axpy(&y1, -2.5, &y2), &mut l12)
            .unwrap();
        assert_close(
            &format!("{name}: linearity"),
            &l12,
            &axpy(&l1, -2.5, &l2),
            1e-11,
        );
    }
}

#[test]
fn surface_divergence_rates_of_area_and_adjointness_with_tension() {
    let p = 16;
    let sht = ShTransform::new(p).unwrap();
    let np = sht.n_points();
    for (name, s) in shapes_under_test(p) {
        let mut m = Membrane::with_default_upsampling(p).unwrap();
        m.set_geometry(s.coefs()).unwrap();
        let g = SurfaceCalculus::new(p)
            .unwrap()
            .geometry(s.coefs())
            .unwrap();
        // Rigid motion: no divergence.
        let (om, u0) = ([0.2, -1.0, 0.4], [1.0, 2.0, -0.5]);
        let rigid: Vec<f64> = (0..3)
            .flat_map(|c| {
                g.x.iter().map(move |x| {
                    let w = [
                        om[1] * x[2] - om[2] * x[1],
                        om[2] * x[0] - om[0] * x[2],
                        om[0] * x[1] - om[1] * x[0],
                    ];
                    u0[c] + w[c]
                })
            })
            .collect();
        let mut div = vec![0.0; np];
        m.surface_divergence(&rigid, &mut div).unwrap();
        assert_close_floor(
            &format!("{name}: ∇_s·(rigid)"),
            &div,
            &vec![0.0; np],
            1e-11,
            1.0,
        );
        // d/dε A(X + εu) = ∫ ∇_s·u dA, by central differences (step analysis as above).
        let uc = random_field_coefs(p, p, 21, 1.0);
        let u = grid_of(&sht, &uc);
        m.surface_divergence(&u, &mut div).unwrap();
        let rate = g.integrate(&div);
        let area = |h: f64| {
            SurfaceCalculus::new(2 * p)
                .unwrap()
                .geometry(
                    Surface::from_coefs(p, axpy(s.coefs(), h, &uc))
                        .unwrap()
                        .resampled(2 * p)
                        .unwrap()
                        .coefs(),
                )
                .unwrap()
                .area()
        };
        let h = 1e-4;
        let fd = (area(h) - area(-h)) / (2.0 * h);
        let fd2 = (area(2.0 * h) - area(-2.0 * h)) / (4.0 * h);
        assert!((fd - fd2).abs() / 3.0 < 1e-8 * fd.abs());
        let e = assert_close(&format!("{name}: dA/dε"), &[rate], &[fd], 1e-6);
        println!("{name}: dA/dε = {fd:.10e}, ∫∇_s·u dA error {e:.2e}");
        // Adjointness: ∫ σ ∇_s·u dA = −∫ f_σ·u dA for a non-constant σ.
        let sigma: Vec<f64> =
            g.x.iter()
                .map(|x| 1.0 + 0.3 * x[0] - 0.2 * x[1] * x[2])
                .collect();
        let mut fs = vec![0.0; 3 * np];
        m.tension_force(&sigma, &mut fs).unwrap();
        m.surface_divergence(&u, &mut div).unwrap();
        let lhs: f64 = g.integrate(
            &sigma
                .iter()
                .zip(&div)
                .map(|(a, b)| a * b)
                .collect::<Vec<_>>(),
        );
        let rhs = -work(&fs, &u, &g.da);
        let e = assert_close(&format!("{name}: adjointness"), &[lhs], &[rhs], 1e-6);
        println!("{name}: ∫σ∇·u = {lhs:.10e}, adjointness error {e:.2e}");
    }
}

#[test]
fn bad_input_is_an_error() {
    assert!(matches!(
        Membrane::new(8, 4),
        Err(VesicleError::Order { .. })
    ));
    let mut m = Membrane::new(6, 12).unwrap();
    let np = m.n_points();
    let mut f = vec![0.0; 3 * np];
    assert!(matches!(
        m.bending_force(1.0, &mut f),
        Err(VesicleError::Missing(_))
    ));
    assert!(matches!(
        m.bending_energy(1.0),
        Err(VesicleError::Missing(_))
    ));
    let s = shapes::rbc(6).unwrap();
    m.set_geometry(s.coefs()).unwrap();
    assert!(matches!(
        m.bending_force(-1.0, &mut f),
        Err(VesicleError::Parameter { .. })
    ));
    assert!(matches!(
        m.bending_force(f64::NAN, &mut f),
        Err(VesicleError::Parameter { .. })
    ));
    assert!(matches!(
        m.bending_force(1.0, &mut f[..5]),
        Err(VesicleError::Length { .. })
    ));
    assert!(matches!(
        m.tension_force(&[1.0; 3], &mut f),
        Err(VesicleError::Length { .. })
    ));
    let par = SkalakParams::skalak(1.0, 1.0);
    assert!(matches!(
        m.skalak_force(&par, &mut f),
        Err(VesicleError::Missing(_))
    ));
    m.set_reference(s.coefs()).unwrap();
    let bad = SkalakParams::skalak(-1.0, 1.0);
    assert!(matches!(
        m.skalak_force(&bad, &mut f),
        Err(VesicleError::Parameter { .. })
    ));
    assert!(matches!(
        m.set_geometry(&[0.0; 4]),
        Err(VesicleError::Length { .. })
    ));
    // A failed update leaves no stale geometry behind.
    assert!(m.set_geometry(&vec![0.0; s.coefs().len()]).is_err());
    assert!(matches!(
        m.bending_force(1.0, &mut f),
        Err(VesicleError::Missing(_))
    ));
}

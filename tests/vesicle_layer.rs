//! On-surface Stokes layer potentials: exact sphere identities, convergence of the Graham–Sloan
//! rule against a high-order reference, the dense operator against matrix-free evaluation, and
//! off-surface (near-singular) evaluation against the Stokes solutions of a moving sphere.

use std::f64::consts::PI;

use mobo::check::{assert_close, rel_max_error};
use mobo::sph_harmonics::{resample_coefs, CoefLayout, ShTransform};
use mobo::vesicle::far_side::{window, FarSideParams, WINDOW_ORDER};
use mobo::vesicle::{
    shapes, LayerKernel, NearParams, OffSurface, RotationAlgorithm, SelfInteraction, Surface,
    SurfaceCalculus, VesicleError,
};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

const ALGOS: [RotationAlgorithm; 2] = [RotationAlgorithm::Direct, RotationAlgorithm::ViaSh];

/// Grid values (order `p`, component-major) of a random vector field of degree `≤ nmax`.
fn random_density(p: usize, nmax: usize, seed: u64) -> Vec<f64> {
    let low = CoefLayout::new(nmax);
    let mut rng = StdRng::seed_from_u64(seed);
    let a: Vec<f64> = (0..3)
        .flat_map(|_| low.degrees())
        .map(|n| rng.random_range(-1.0..1.0) / (1.0 + n as f64))
        .collect();
    let sht = ShTransform::new(p).unwrap();
    let mut c = vec![0.0; 3 * sht.n_coefs()];
    resample_coefs(&low, sht.layout(), &a, &mut c).unwrap();
    let mut g = vec![0.0; 3 * sht.n_points()];
    sht.inverse(&c, &mut g, &mut sht.workspace()).unwrap();
    g
}

#[test]
fn sphere_identities_hold_to_round_off() {
    let (a, mu, centre) = (1.3, 0.7, [0.5, -0.25, 2.0]);
    let omega = [0.3, -1.1, 0.6];
    let f0 = [0.4, 1.0, -0.7];
    for p in [6, 8, 12] {
        for q in [p, 2 * p] {
            for algo in ALGOS {
                let mut s = shapes::sphere(p, a).unwrap();
                s.translate(centre);
                let g = SurfaceCalculus::new(p)
                    .unwrap()
                    .geometry(s.coefs())
                    .unwrap();
                let np = g.n_points();
                let mut si = SelfInteraction::new(p, q, algo).unwrap();
                let sl = LayerKernel::SingleLayer { viscosity: mu };
                let mut u = vec![0.0; 3 * np];
                let tag = format!("p={p} q={q} {algo:?}");
                // Rigid rotation: the traction 3μ Ω×n (torque 8πμa³Ω) gives u = Ω × (x − c).
                let f: Vec<f64> = (0..3)
                    .flat_map(|c| {
                        g.normal.iter().map(move |n| {
                            let w = [
                                omega[1] * n[2] - omega[2] * n[1],
                                omega[2] * n[0] - omega[0] * n[2],
                                omega[0] * n[1] - omega[1] * n[0],
                            ];
                            3.0 * mu * w[c]
                        })
                    })
                    .collect();
                si.evaluate(sl, s.coefs(), &f, &mut u).unwrap();
                let want: Vec<f64> = (0..3)
                    .flat_map(|c| {
                        g.x.iter().map(move |x| {
                            let r = [x[0] - centre[0], x[1] - centre[1], x[2] - centre[2]];
                            let w = [
                                omega[1] * r[2] - omega[2] * r[1],
                                omega[2] * r[0] - omega[0] * r[2],
                                omega[0] * r[1] - omega[1] * r[0],
                            ];
                            w[c]
                        })
                    })
                    .collect();
                assert_close(&format!("S[3μΩ×n] = Ω×x, {tag}"), &u, &want, 1e-12);
                // Uniform traction: u = 2af/3μ.
                let f: Vec<f64> = (0..3).flat_map(|c| vec![f0[c]; np]).collect();
                si.evaluate(sl, s.coefs(), &f, &mut u).unwrap();
                let want: Vec<f64> = f.iter().map(|v| 2.0 * a * v / (3.0 * mu)).collect();
                assert_close(&format!("S[f] = 2af/3μ, {tag}"), &u, &want, 1e-12);
                // Double layer of a constant: −½.
                si.evaluate(LayerKernel::DoubleLayer, s.coefs(), &f, &mut u)
                    .unwrap();
                let want: Vec<f64> = f.iter().map(|v| -0.5 * v).collect();
                assert_close(&format!("D[c] = −c/2, {tag}"), &u, &want, 1e-12);
            }
        }
    }
}

/// Layer potential of a density at the given targets with quadrature order `q`.
fn layer_at(
    s: &Surface,
    q: usize,
    kernel: LayerKernel,
    density: &[f64],
    targets: &[usize],
) -> Vec<f64> {
    layer_with(s, q, FarSideParams::default(), kernel, density, targets)
}

/// [`layer_at`] with the given far-side settings.
fn layer_with(
    s: &Surface,
    q: usize,
    far: FarSideParams,
    kernel: LayerKernel,
    density: &[f64],
    targets: &[usize],
) -> Vec<f64> {
    let mut si = SelfInteraction::new(s.order(), q, RotationAlgorithm::ViaSh).unwrap();
    si.set_far_side_params(far).unwrap();
    let mut u = vec![0.0; 3 * targets.len()];
    si.evaluate_at(kernel, s.coefs(), density, targets, &mut u)
        .unwrap();
    u
}

/// Ellipsoid 1:0.8:0.6 (exact at `p = 8`), reference `q = 48`. The error at `q = 16` depends on
/// the density: for a linear density (degree 1) it is below the issue's `2e-8` (measured 9.8e-9);
/// for a random density of degree ≤ 6 it is 2.9e-7 at `q = 16` and 2.5e-10 at `q = 24`.
#[test]
fn ellipsoid_single_layer_converges() {
    let p = 8;
    let s = shapes::ellipsoid(p, [1.0, 0.8, 0.6]).unwrap();
    let targets: Vec<usize> = (0..2 * p * (p + 1)).collect();
    let sl = LayerKernel::SingleLayer { viscosity: 1.0 };
    for (nmax, q, tol) in [(1, 16, 2e-8), (6, 16, 5e-7), (6, 24, 1e-9)] {
        let f = random_density(p, nmax, 3);
        let reference = layer_at(&s, 48, sl, &f, &targets);
        let e = assert_close(
            &format!("ellipsoid single layer, density degree ≤ {nmax}, q = {q}"),
            &layer_at(&s, q, sl, &f, &targets),
            &reference,
            tol,
        );
        println!("ellipsoid single layer, density degree ≤ {nmax}, q = {q} vs 48: {e:.2e}");
    }
    let f = random_density(p, 6, 3);
    let e = assert_close(
        "ellipsoid double layer, q = 24",
        &layer_at(&s, 24, LayerKernel::DoubleLayer, &f, &targets),
        &layer_at(&s, 48, LayerKernel::DoubleLayer, &f, &targets),
        1e-9,
    );
    println!("ellipsoid double layer, density degree ≤ 6, q = 24 vs 48: {e:.2e}");
}

/// RBC (`p = 16`) with a random density of degree ≤ 8, reference `q = 96`. The issue asks for
/// `1e-6` at `q = 32`. The plain Graham–Sloan rule gives 1e-5 there, all of it at the dimples,
/// where the opposite dimple (0.29 away) is a nearly singular feature for the order-32 rule; the
/// far-side split of `vesicle::far_side` takes it to 2.8e-7
/// (`q = 48`: 3.6e-7 → 2.4e-8).
#[test]
fn rbc_single_layer_converges() {
    let p = 16;
    let s = shapes::rbc(p).unwrap();
    let f = random_density(p, 8, 4);
    // A spread of targets: every latitude (poles and equator included), three longitudes each.
    let targets: Vec<usize> = (0..=p)
        .flat_map(|i| [0, 7, 20].map(|k| i * 2 * p + k))
        .collect();
    let sl = LayerKernel::SingleLayer { viscosity: 1.0 };
    let reference = layer_at(&s, 96, sl, &f, &targets);
    for (q, tol) in [(32, 1e-6), (48, 1e-7)] {
        let e = assert_close(
            &format!("RBC single layer, q = {q}"),
            &layer_at(&s, q, sl, &f, &targets),
            &reference,
            tol,
        );
        let plain = rel_max_error(&layer_with(&s, q, plain(), sl, &f, &targets), &reference);
        println!(
            "RBC single layer, p = 16, q = {q} vs q = 96: {e:.2e} (plain Graham–Sloan {plain:.2e})"
        );
        assert!(
            e < plain / 10.0,
            "the far-side split should gain at least 10x at q = {q}: {e:.2e} vs {plain:.2e}"
        );
    }
}

/// Far-side split off: the plain Graham–Sloan rule.
fn plain() -> FarSideParams {
    FarSideParams {
        enabled: false,
        ..FarSideParams::default()
    }
}

/// The window of the far-side split: `η + (1 − η) = 1`, `η(0) = 1`, `η(π) = 0`, symmetric
/// (`η(π − θ) = 1 − η(θ)`), `1 − η = O(θ^{2n+2})` at the target, and a polynomial of degree
/// `2n + 1` in `cos θ` (its Legendre coefficients beyond that degree vanish).
#[test]
fn far_side_window_is_a_band_limited_partition_of_unity() {
    let n = WINDOW_ORDER;
    for i in 0..=100 {
        let theta = PI * i as f64 / 100.0;
        let s = (theta / 2.0).sin().powi(2);
        let (eta, rest) = window(s);
        // Sums of 6 terms with binomials up to 462: a few ulps.
        assert!(
            (eta + rest - 1.0).abs() < 1e-14,
            "η + (1 − η) at θ = {theta}"
        );
        let (eta2, _) = window(1.0 - s);
        assert!((eta2 - rest).abs() < 1e-14, "symmetry at θ = {theta}");
    }
    assert_eq!(window(0.0), (1.0, 0.0));
    assert_eq!(window(1.0), (0.0, 1.0));
    // 1 − η ≈ C(2n+1, n+1) s^{n+1} as s → 0.
    let lead = (0..=n).fold(1.0, |c, i| c * (2 * n + 1 - i) as f64 / (i + 1) as f64);
    for s in [1e-2, 1e-3, 1e-4] {
        let ratio = window(s).1 / (lead * s.powi(n as i32 + 1));
        assert!(
            (ratio - 1.0).abs() < 20.0 * s,
            "1 − η at s = {s}: ratio {ratio}"
        );
    }
    // Legendre coefficients ∫ η P_l d(cos θ) by Gauss–Legendre (exact for the degrees here).
    let (x, w) = mobo::sph_harmonics::grid::gauss_legendre(40);
    for l in 0..=2 * n + 6 {
        let c: f64 = x
            .iter()
            .zip(&w)
            .map(|(&xi, &wi)| wi * window((1.0 - xi) / 2.0).0 * legendre(l, xi))
            .sum();
        if l > 2 * n + 1 {
            assert!(c.abs() < 1e-14, "Legendre coefficient {l} of η: {c:.2e}");
        } else if l == 2 * n + 1 {
            assert!(c.abs() > 1e-8, "η should have degree exactly 2n + 1");
        }
    }
}

/// `P_l(x)` by the three-term recurrence.
fn legendre(l: usize, x: f64) -> f64 {
    let (mut p0, mut p1) = (1.0, x);
    if l == 0 {
        return 1.0;
    }
    for k in 1..l {
        let p2 = ((2 * k + 1) as f64 * x * p1 - k as f64 * p0) / (k + 1) as f64;
        p0 = p1;
        p1 = p2;
    }
    p1
}

/// With the split forced on every target of a sphere (flag factor 1e3), the exact identities
/// still hold: the local part `η g` is a polynomial of degree ≤ q + 1 there (exact under the
/// Graham–Sloan rule), so only the far part's smooth quadrature is left to err.
#[test]
fn forced_far_side_split_keeps_the_sphere_identities() {
    let (p, q, a, mu) = (8, 24, 1.3, 0.7);
    let s = shapes::sphere(p, a).unwrap();
    let np = 2 * p * (p + 1);
    let f0 = [0.4, 1.0, -0.7];
    let f: Vec<f64> = (0..3).flat_map(|c| vec![f0[c]; np]).collect();
    for algo in ALGOS {
        let mut si = SelfInteraction::new(p, q, algo).unwrap();
        si.set_far_side_params(FarSideParams {
            flag: 1e3,
            max_order: Some(64),
            ..FarSideParams::default()
        })
        .unwrap();
        let mut u = vec![0.0; 3 * np];
        si.evaluate(
            LayerKernel::SingleLayer { viscosity: mu },
            s.coefs(),
            &f,
            &mut u,
        )
        .unwrap();
        let (flagged, far_q) = si.far_side_plan();
        assert_eq!(flagged.len(), np, "every target is split");
        let want: Vec<f64> = f.iter().map(|v| 2.0 * a * v / (3.0 * mu)).collect();
        let e1 = assert_close(&format!("split S[f] = 2af/3μ, {algo:?}"), &u, &want, 1e-10);
        si.evaluate(LayerKernel::DoubleLayer, s.coefs(), &f, &mut u)
            .unwrap();
        let want: Vec<f64> = f.iter().map(|v| -0.5 * v).collect();
        let e2 = assert_close(&format!("split D[c] = −c/2, {algo:?}"), &u, &want, 1e-10);
        println!("forced split on a sphere, {algo:?}, far order {far_q}: S {e1:.1e}, D {e2:.1e}");
    }
}

/// The convergence table of the issue: error of the on-surface single layer against `q`.
/// `cargo test --release --test vesicle_layer -- --ignored --nocapture convergence_table`
#[test]
#[ignore]
fn convergence_table() {
    let sl = LayerKernel::SingleLayer { viscosity: 1.0 };
    let cases = [
        (
            "ellipsoid 1:0.8:0.6, p=8",
            shapes::ellipsoid(8, [1.0, 0.8, 0.6]).unwrap(),
            6,
        ),
        ("RBC, p=16", shapes::rbc(16).unwrap(), 8),
    ];
    for (name, s, nmax) in cases {
        let p = s.order();
        let f = random_density(p, nmax, 5);
        let targets: Vec<usize> = (0..2 * p * (p + 1)).step_by(7).collect();
        let reference = layer_at(&s, 96, sl, &f, &targets);
        println!(
            "\n{name} (reference q = 96, {} targets)\n| q | rel. max error | plain Graham–Sloan |\n|---|---|---|",
            targets.len()
        );
        for q in [8, 12, 16, 24, 32, 48, 64] {
            if q < p {
                continue;
            }
            let e = rel_max_error(&layer_at(&s, q, sl, &f, &targets), &reference);
            let plain = rel_max_error(&layer_with(&s, q, plain(), sl, &f, &targets), &reference);
            println!("| {q} | {e:.2e} | {plain:.2e} |");
        }
    }
}

#[test]
fn dense_operator_equals_matrix_free_evaluation_for_both_rotations() {
    // p = 6, q = 12: plain Graham–Sloan; p = 8, q = 24: the dimple targets are split; q = p + 3
    // and q = p (no upsampling: the assembly by rotation matrices) are checked too.
    for (p, q) in [(6, 12), (8, 24), (7, 10), (6, 7), (5, 5)] {
        dense_equals_matrix_free(p, q);
    }
}

fn dense_equals_matrix_free(p: usize, q: usize) {
    let s = shapes::rbc(p).unwrap();
    let np = 2 * p * (p + 1);
    let n3 = 3 * np;
    let f = random_density(p, p, 9);
    for kernel in [
        LayerKernel::SingleLayer { viscosity: 1.5 },
        LayerKernel::DoubleLayer,
    ] {
        let mut ops = Vec::new();
        for algo in ALGOS {
            let mut si = SelfInteraction::new(p, q, algo).unwrap();
            let mut a = vec![0.0; n3 * n3];
            si.assemble(kernel, s.coefs(), &mut a).unwrap();
            let split = si.far_side_plan().0.len();
            assert_eq!(
                split > 0,
                q >= 24,
                "far-side split at p = {p}, q = {q}: {split}"
            );
            // The coefficient-space rows against MOBO's GEMM with the rotation matrices.
            let mut by_matrices = vec![0.0; n3 * n3];
            si.assemble_by_rotation_matrices(kernel, s.coefs(), &mut by_matrices)
                .unwrap();
            let e = assert_close(
                &format!("{kernel:?} {algo:?}, p = {p}, q = {q}: assembly in coefficient space vs by rotation matrices"),
                &a,
                &by_matrices,
                1e-12,
            );
            println!("{kernel:?} {algo:?}, p = {p}, q = {q}: coefficient rows vs rotation matrices {e:.2e}");
            // The rows over coefficients times F are the operator (q > p), else an error.
            let nc = ShTransform::new(p).unwrap().n_coefs();
            let mut rows = vec![0.0; 9 * np * nc];
            if q > p {
                si.assemble_rows(kernel, s.coefs(), &mut rows).unwrap();
                let sht = ShTransform::new(p).unwrap();
                let mut ws = sht.workspace();
                let mut fc = vec![0.0; 3 * nc];
                sht.forward(&f, &mut fc, &mut ws).unwrap();
                let by_rows: Vec<f64> = (0..n3)
                    .map(|r| (0..3 * nc).map(|c| rows[r * 3 * nc + c] * fc[c]).sum())
                    .collect();
                let want: Vec<f64> = (0..n3)
                    .map(|r| (0..n3).map(|c| a[c * n3 + r] * f[c]).sum())
                    .collect();
                assert_close(
                    &format!("{kernel:?} {algo:?}, p = {p}: P F f vs A f"),
                    &by_rows,
                    &want,
                    1e-13,
                );
            } else {
                assert!(matches!(
                    si.assemble_rows(kernel, s.coefs(), &mut rows),
                    Err(VesicleError::NotUpsampled { p: 5 })
                ));
            }
            let mut direct = vec![0.0; n3];
            si.evaluate(kernel, s.coefs(), &f, &mut direct).unwrap();
            let applied: Vec<f64> = (0..n3)
                .map(|r| (0..n3).map(|c| a[c * n3 + r] * f[c]).sum())
                .collect();
            // The operator is built with the coefficient-space rotation; the direct rotation's
            // matrix-free path rounds differently (~1e-13 for the double layer).
            let tol = match algo {
                RotationAlgorithm::ViaSh => 1e-13,
                RotationAlgorithm::Direct => 5e-13,
            };
            let e = assert_close(
                &format!("{kernel:?} {algo:?}, p = {p}: A·f vs matrix-free"),
                &applied,
                &direct,
                tol,
            );
            println!("{kernel:?} {algo:?}, p = {p}, q = {q} ({split} split): operator vs matrix-free {e:.2e}");
            ops.push(a);
        }
        let e = assert_close(
            &format!("{kernel:?}: Direct vs ViaSh operator"),
            &ops[0],
            &ops[1],
            1e-12,
        );
        println!("{kernel:?}: Direct vs ViaSh operator {e:.2e}");
    }
}

/// Targets at distance `d` inside and outside a sphere (radius `a`, centre `c`) along a few
/// generic directions; returns (points, inside flags).
fn sphere_targets(a: f64, c: [f64; 3], d: f64) -> (Vec<[f64; 3]>, Vec<bool>) {
    let mut rng = StdRng::seed_from_u64(17);
    let mut pts = Vec::new();
    let mut inside = Vec::new();
    for _ in 0..6 {
        let v: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        for (sign, ins) in [(1.0, false), (-1.0, true)] {
            let r = a + sign * d;
            pts.push(std::array::from_fn(|k| c[k] + r * v[k] / n));
            inside.push(ins);
        }
    }
    (pts, inside)
}

#[test]
fn off_surface_sphere_translating_and_rotating() {
    let (p, a, mu, c) = (16, 1.0, 1.0, [0.3, -0.2, 0.5]);
    let mut s = shapes::sphere(p, a).unwrap();
    s.translate(c);
    let g = SurfaceCalculus::new(p)
        .unwrap()
        .geometry(s.coefs())
        .unwrap();
    let np = g.n_points();
    let mut off = OffSurface::new(p, NearParams::default()).unwrap();
    off.set_surface(s.coefs()).unwrap();
    let f0 = [0.4, 1.0, -0.7];
    let omega = [0.3, -1.1, 0.6];
    let sl = LayerKernel::SingleLayer { viscosity: mu };
    let traction: Vec<f64> = (0..3).flat_map(|k| vec![f0[k]; np]).collect();
    let rot_traction: Vec<f64> = (0..3)
        .flat_map(|k| {
            g.normal.iter().map(move |n| {
                let w = cross(omega, *n);
                3.0 * mu * w[k]
            })
        })
        .collect();
    let force: [f64; 3] = f0.map(|v| 4.0 * PI * a * a * v);
    for d in [0.5 * a, 0.1 * a, 0.01 * a] {
        let (pts, inside) = sphere_targets(a, c, d);
        let nt = pts.len();
        let mut u = vec![0.0; 3 * nt];
        // Translating sphere: uniform inside, Stokeslet + source doublet outside.
        let infos = off.evaluate(sl, &traction, &pts, &mut u).unwrap();
        for (info, &ins) in infos.iter().zip(&inside) {
            assert_eq!(info.inside, ins, "classification at d = {d}");
            assert_eq!(info.near, d < off.near_distance());
        }
        let mut want = vec![0.0; 3 * nt];
        for (t, x) in pts.iter().enumerate() {
            let r: [f64; 3] = std::array::from_fn(|k| x[k] - c[k]);
            let v = if inside[t] {
                f0.map(|v| 2.0 * a * v / (3.0 * mu))
            } else {
                let rn = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
                let rf = r[0] * force[0] + r[1] * force[1] + r[2] * force[2];
                std::array::from_fn(|k| {
                    (force[k] / rn
                        + rf * r[k] / rn.powi(3)
                        + a * a / 3.0 * (force[k] / rn.powi(3) - 3.0 * rf * r[k] / rn.powi(5)))
                        / (8.0 * PI * mu)
                })
            };
            for k in 0..3 {
                want[k * nt + t] = v[k];
            }
        }
        let e = assert_close(&format!("translating sphere, d = {d}"), &u, &want, 1e-6);
        // Rotating sphere: rigid inside, Ω×r a³/|r|³ outside.
        off.evaluate(sl, &rot_traction, &pts, &mut u).unwrap();
        for (t, x) in pts.iter().enumerate() {
            let r: [f64; 3] = std::array::from_fn(|k| x[k] - c[k]);
            let rn = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
            let fac = if inside[t] { 1.0 } else { (a / rn).powi(3) };
            let w = cross(omega, r);
            for k in 0..3 {
                want[k * nt + t] = fac * w[k];
            }
        }
        let er = assert_close(&format!("rotating sphere, d = {d}"), &u, &want, 1e-6);
        // Double layer of a constant: −c inside, 0 outside.
        off.evaluate(LayerKernel::DoubleLayer, &traction, &pts, &mut u)
            .unwrap();
        for t in 0..nt {
            for k in 0..3 {
                want[k * nt + t] = if inside[t] { -f0[k] } else { 0.0 };
            }
        }
        let ed = mobo::check::assert_close_floor(
            &format!("double layer of a constant, d = {d}"),
            &u,
            &want,
            1e-6,
            1.0,
        );
        println!("off-surface, d = {d}: translating {e:.2e}, rotating {er:.2e}, D[c] {ed:.2e}");
    }
}

/// Identities that hold on every closed surface: `S[n] = 0` (the Stokeslet is divergence-free)
/// on and off the surface, and `D[c] = −c` inside, `0` outside, `−c/2` on the surface; checked on
/// the ellipsoid 1:0.8:0.6 and the RBC near the surface, inside and outside.
///
/// The RBC is thin at its centre (the two dimples are 0.29 apart): on-surface integrals there
/// are near-singular through the opposite face, so `D[c] = −c/2` converges slowly in `q`
/// (4.7e-4 at `q = 32`, 3.3e-5 at 48, 1.4e-6 at 64; worst at the dimples) and the check points of
/// the default near zone (`δ = 0.25`) would cross the cell there. The RBC test therefore uses
/// `q = 64` for the on-surface values and targets off the rim region; `S[n]` is limited to 1.2e-5
/// by the representation of `n` (not band-limited) at `p = 16`.
#[test]
fn off_surface_identities_on_non_spherical_cells() {
    let p = 16;
    for (name, s, q_self, points, tol) in [
        (
            "ellipsoid",
            shapes::ellipsoid(p, [1.0, 0.8, 0.6]).unwrap(),
            2 * p,
            [5, 61, 150, 300, 401],
            1e-7,
        ),
        (
            "RBC",
            shapes::rbc(p).unwrap(),
            4 * p,
            [163, 234, 273, 313, 353],
            2e-5,
        ),
    ] {
        let g = SurfaceCalculus::new(p)
            .unwrap()
            .geometry(s.coefs())
            .unwrap();
        let np = g.n_points();
        let normal: Vec<f64> = (0..3)
            .flat_map(|c| g.normal.iter().map(move |n| n[c]))
            .collect();
        let cvec = [0.4, 1.0, -0.7];
        let constant: Vec<f64> = (0..3).flat_map(|c| vec![cvec[c]; np]).collect();
        let sl = LayerKernel::SingleLayer { viscosity: 1.0 };
        // On the surface.
        let mut si = SelfInteraction::new(p, q_self, RotationAlgorithm::ViaSh).unwrap();
        let mut u = vec![0.0; 3 * np];
        si.evaluate(sl, s.coefs(), &normal, &mut u).unwrap();
        let e_s = mobo::check::assert_close_floor(
            &format!("{name}: S[n] = 0 on the surface"),
            &u,
            &vec![0.0; 3 * np],
            tol,
            1.0,
        );
        si.evaluate(LayerKernel::DoubleLayer, s.coefs(), &constant, &mut u)
            .unwrap();
        let want: Vec<f64> = constant.iter().map(|v| -0.5 * v).collect();
        let e_d = assert_close(
            &format!("{name}: D[c] = −c/2 on the surface"),
            &u,
            &want,
            tol,
        );
        // Off the surface, along the normals of a few grid points.
        let params = NearParams {
            self_order: Some(q_self),
            ..Default::default()
        };
        let mut off = OffSurface::new(p, params).unwrap();
        off.set_surface(s.coefs()).unwrap();
        let delta = off.near_distance();
        let mut worst: f64 = 0.0;
        for d in [0.5 * delta, 0.1 * delta, 0.01 * delta] {
            let mut pts = Vec::new();
            let mut inside = Vec::new();
            for j in points {
                for (sign, ins) in [(1.0, false), (-1.0, true)] {
                    pts.push(std::array::from_fn(|c| {
                        g.x[j][c] + sign * d * g.normal[j][c]
                    }));
                    inside.push(ins);
                }
            }
            let nt = pts.len();
            let mut u = vec![0.0; 3 * nt];
            let infos = off.evaluate(sl, &normal, &pts, &mut u).unwrap();
            for (info, &ins) in infos.iter().zip(&inside) {
                assert_eq!(info.inside, ins, "{name}: classification at d = {d}");
                assert!(info.near && (info.distance - d).abs() < 1e-10 * (1.0 + d));
            }
            worst = worst.max(mobo::check::assert_close_floor(
                &format!("{name}: S[n] = 0 at d = {d}"),
                &u,
                &vec![0.0; 3 * nt],
                tol,
                1.0,
            ));
            off.evaluate(LayerKernel::DoubleLayer, &constant, &pts, &mut u)
                .unwrap();
            let mut want = vec![0.0; 3 * nt];
            for t in 0..nt {
                for c in 0..3 {
                    want[c * nt + t] = if inside[t] { -cvec[c] } else { 0.0 };
                }
            }
            worst = worst.max(mobo::check::assert_close_floor(
                &format!("{name}: D[c] at d = {d}"),
                &u,
                &want,
                tol,
                1.0,
            ));
        }
        println!(
            "{name}: on-surface S[n] {e_s:.2e}, D[c] {e_d:.2e}; near the surface worst {worst:.2e}"
        );
    }
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[test]
fn bad_input_is_an_error() {
    assert!(matches!(
        SelfInteraction::new(8, 6, RotationAlgorithm::ViaSh),
        Err(VesicleError::Order { .. })
    ));
    let mut si = SelfInteraction::new(4, 4, RotationAlgorithm::Direct).unwrap();
    let s = shapes::sphere(4, 1.0).unwrap();
    let np = si.n_points();
    let mut u = vec![0.0; 3 * np];
    let f = vec![0.0; 3 * np];
    let bad = LayerKernel::SingleLayer { viscosity: 0.0 };
    assert!(matches!(
        si.evaluate(bad, s.coefs(), &f, &mut u),
        Err(VesicleError::Parameter { .. })
    ));
    let sl = LayerKernel::SingleLayer { viscosity: 1.0 };
    assert!(si.evaluate(sl, s.coefs(), &f[..5], &mut u).is_err());
    assert!(si.evaluate(sl, &s.coefs()[..3], &f, &mut u).is_err());
    let mut u1 = vec![0.0; 3];
    assert!(si.evaluate_at(sl, s.coefs(), &f, &[np], &mut u1).is_err());
    assert!(si.assemble(sl, s.coefs(), &mut u).is_err());
    // Off-surface evaluation.
    let zero = NearParams {
        check_points: 0,
        ..Default::default()
    };
    assert!(matches!(
        OffSurface::new(4, zero),
        Err(VesicleError::Parameter { .. })
    ));
    let neg = NearParams {
        near_distance: Some(-1.0),
        ..Default::default()
    };
    assert!(OffSurface::new(4, neg).is_err());
    let mut off = OffSurface::new(4, NearParams::default()).unwrap();
    let mut u1 = vec![0.0; 3];
    assert!(matches!(
        off.evaluate(sl, &f, &[[2.0, 0.0, 0.0]], &mut u1),
        Err(VesicleError::Missing(_))
    ));
    off.set_surface(s.coefs()).unwrap();
    assert!(off
        .evaluate(sl, &f[..4], &[[2.0, 0.0, 0.0]], &mut u1)
        .is_err());
    assert!(off.evaluate(bad, &f, &[[2.0, 0.0, 0.0]], &mut u1).is_err());
}

/// The coefficient-space operator `A_c = F A I`: the grid operator reads its density through the
/// projection `P = I F` (`A x = A P x` for any grid vector, band-limited or not), and
/// `I A_c F x` equals `P (A x)` computed with the transforms, for both kernels.
#[test]
fn coefficient_space_operator_is_the_projected_grid_operator() {
    use mobo::vesicle::CoefficientOperator;
    let (p, q) = (8, 16);
    let s = shapes::rbc(p).unwrap();
    let sht = ShTransform::new(p).unwrap();
    let mut ws = sht.workspace();
    let (n, nc) = (sht.n_points(), sht.n_coefs());
    let mut comp = CoefficientOperator::new(&sht).unwrap();
    assert_eq!((comp.n_points(), comp.n_coefs()), (n, nc));
    let mut si = SelfInteraction::new(p, q, RotationAlgorithm::Direct).unwrap();
    let mut rng = StdRng::seed_from_u64(11);
    // Random grid values: not band-limited.
    let x: Vec<f64> = (0..3 * n).map(|_| rng.random_range(-1.0..1.0)).collect();
    let project = |v: &[f64], ws: &mut mobo::sph_harmonics::ShWorkspace| {
        let mut c = vec![0.0; 3 * nc];
        sht.forward(v, &mut c, ws).unwrap();
        let mut g = vec![0.0; 3 * n];
        sht.inverse(&c, &mut g, ws).unwrap();
        g
    };
    let matvec = |a: &[f64], v: &[f64], m: usize| -> Vec<f64> {
        (0..m)
            .map(|i| (0..m).map(|j| a[j * m + i] * v[j]).sum())
            .collect()
    };
    for kernel in [
        LayerKernel::SingleLayer { viscosity: 0.8 },
        LayerKernel::DoubleLayer,
    ] {
        let mut a = vec![0.0; 9 * n * n];
        si.assemble(kernel, s.coefs(), &mut a).unwrap();
        let mut ac = vec![0.0; 9 * nc * nc];
        comp.compress(&a, &mut ac).unwrap();
        // The same from the rows over coefficients: A_c = F P.
        let mut rows = vec![0.0; 9 * n * nc];
        si.assemble_rows(kernel, s.coefs(), &mut rows).unwrap();
        let mut ac_rows = vec![0.0; 9 * nc * nc];
        comp.compress_rows(&rows, &mut ac_rows).unwrap();
        assert_close(&format!("{kernel:?}: F P vs F A I"), &ac_rows, &ac, 1e-12);
        let ax = matvec(&a, &x, 3 * n);
        let px = project(&x, &mut ws);
        let apx = matvec(&a, &px, 3 * n);
        let e_in = rel_max_error(&apx, &ax);
        // I A_c F x against P (A x).
        let mut xc = vec![0.0; 3 * nc];
        sht.forward(&x, &mut xc, &mut ws).unwrap();
        let yc = matvec(&ac, &xc, 3 * nc);
        let mut y = vec![0.0; 3 * n];
        sht.inverse(&yc, &mut y, &mut ws).unwrap();
        let pax = project(&ax, &mut ws);
        let e_out = rel_max_error(&y, &pax);
        // The projection removes a part of A x of the size of the discretisation error.
        let e_proj = rel_max_error(&pax, &ax);
        println!("{kernel:?}: |A x − A P x| {e_in:.1e}, |I A_c F x − P A x| {e_out:.1e}, |P A x − A x| {e_proj:.1e}");
        assert!(e_in < 1e-12, "{kernel:?}: A ≠ A P ({e_in:.1e})");
        assert!(e_out < 1e-12, "{kernel:?}: compression ({e_out:.1e})");
        assert!(
            e_proj > 1e-6,
            "{kernel:?}: the output projection does something"
        );
    }
    let mut short = vec![0.0; 10];
    assert!(comp.compress(&vec![0.0; 9 * n * n], &mut short).is_err());
}

/// The batched matrix-free product equals the dense operator's product to round-off, for both
/// rotations and both kernels, on an RBC whose dimples are split off (far side).
#[test]
fn batched_matrix_free_product_equals_the_dense_operator() {
    let (p, q) = (8, 24);
    let s = shapes::rbc(p).unwrap();
    let n = ShTransform::new(p).unwrap().n_points();
    let f = random_density(p, p, 5);
    for algo in ALGOS {
        let mut si = SelfInteraction::new(p, q, algo).unwrap();
        for kernel in [
            LayerKernel::SingleLayer { viscosity: 1.3 },
            LayerKernel::DoubleLayer,
        ] {
            let mut a = vec![0.0; 9 * n * n];
            si.assemble(kernel, s.coefs(), &mut a).unwrap();
            assert!(!si.far_side_plan().0.is_empty(), "targets split");
            let want: Vec<f64> = (0..3 * n)
                .map(|i| (0..3 * n).map(|j| a[j * 3 * n + i] * f[j]).sum())
                .collect();
            let mut got = vec![0.0; 3 * n];
            si.apply(kernel, s.coefs(), &f, &mut got).unwrap();
            assert_close(&format!("{algo:?} {kernel:?}"), &got, &want, 1e-13);
        }
    }
    let mut si = SelfInteraction::new(p, q, RotationAlgorithm::Direct).unwrap();
    let mut short = vec![0.0; 5];
    assert!(si
        .apply(LayerKernel::DoubleLayer, s.coefs(), &f, &mut short)
        .is_err());
}

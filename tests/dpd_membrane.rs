//! The DPD membrane (Fedosov, Caswell & Karniadakis 2010) on RBC meshes: forces against central
//! differences of the energies, momentum conservation, membrane viscosity, the moduli mapping,
//! relaxation, and optical-tweezers stretching against Mills et al. (2004).
//!
//! `cargo test --release --test dpd_membrane -- --ignored` (scripts/dpd_rbc_stretch.sh) runs the
//! full stretching table and writes docs/dpd_rbc_stretch.md.

use std::time::Instant;

use mobo::dpd::membrane::{
    mesh_quality, relax_on_surface, sphere_spontaneous_angle, Bending, BendingModel, Membrane,
    MembraneParams, MembraneTopology, MeshQuality, Moduli, RelaxReport, Term,
};
use mobo::dpd::DpdError;
use mobo::vesicle::{shapes, CellMesh};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

fn rbc_mesh(subdivisions: u32) -> CellMesh {
    CellMesh::icosphere(&shapes::rbc(16).unwrap(), subdivisions).unwrap()
}

/// The biconcave RBC of `shapes::rbc` (Evans & Fung 1972, units of the equivalent radius) as a
/// curve in the meridian plane, `ρ(θ) = α sin θ`, `z(θ) = ½α P(sin θ) cos θ` with
/// `P(s) = 0.207 + 2.003 s² − 1.123 s⁴`, `θ ∈ [0, π]`: `(ρ, z, ρ', z', ρ'', z'')`.
fn rbc_meridian(theta: f64) -> [f64; 6] {
    let a = shapes::RBC_ALPHA;
    let (s, c) = theta.sin_cos();
    let s2 = s * s;
    let p = 0.207 + 2.003 * s2 - 1.123 * s2 * s2;
    // dP/dθ = Q(s) c, Q(s) = 4.006 s − 4.492 s³, Q'(s) = 4.006 − 13.476 s².
    let q = 4.006 * s - 4.492 * s * s2;
    let dq = 4.006 - 13.476 * s2;
    let f = p * c;
    let df = q * c * c - p * s;
    let ddf = dq * c * c * c - 3.0 * q * s * c - p * c;
    [
        a * s,
        0.5 * a * f,
        a * c,
        0.5 * a * df,
        -a * s,
        0.5 * a * ddf,
    ]
}

/// Closest point of the RBC surface of [`rbc_meridian`] to `x`: the closest point of the
/// meridian curve to `(ρ, z)` (the best of 64 samples in θ, then Newton on the squared
/// distance, kept in `[0, π]`), rotated back to the azimuth of `x`.
fn rbc_closest(x: [f64; 3]) -> [f64; 3] {
    use std::f64::consts::PI;
    let rho = x[0].hypot(x[1]);
    let z = x[2];
    let d2 = |t: f64| {
        let m = rbc_meridian(t);
        (m[0] - rho).powi(2) + (m[1] - z).powi(2)
    };
    let n = 64;
    let mut theta = (0..=n)
        .map(|k| PI * k as f64 / n as f64)
        .min_by(|&a, &b| d2(a).total_cmp(&d2(b)))
        .unwrap();
    for _ in 0..50 {
        let m = rbc_meridian(theta);
        let (dr, dz) = (m[0] - rho, m[1] - z);
        let g = dr * m[2] + dz * m[3];
        let h = m[2] * m[2] + dr * m[4] + m[3] * m[3] + dz * m[5];
        if h <= 0.0 {
            break;
        }
        let next = (theta - g / h).clamp(0.0, PI);
        let done = (next - theta).abs() < 1e-15;
        theta = next;
        if done {
            break;
        }
    }
    let m = rbc_meridian(theta);
    let phi = x[1].atan2(x[0]);
    [m[0] * phi.cos(), m[0] * phi.sin(), m[1]]
}

/// [`rbc_mesh`] relaxed on the RBC surface towards equal edge lengths
/// ([`relax_on_surface`], `iterations` steps of 0.2).
/// Relaxation steps for the RBC meshes.
const RELAX_ITERATIONS: usize = 10_000;

fn relaxed_rbc_mesh(subdivisions: u32, iterations: usize) -> (CellMesh, RelaxReport) {
    let mut mesh = rbc_mesh(subdivisions);
    let topo = MembraneTopology::new(mesh.vertices.len(), &mesh.triangles).unwrap();
    let report = relax_on_surface(&mut mesh.vertices, &topo, rbc_closest, iterations, 0.2).unwrap();
    (mesh, report)
}

fn jittered(x: &[[f64; 3]], amp: f64, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = StdRng::seed_from_u64(seed);
    x.iter()
        .map(|p| p.map(|c| c + amp * rng.random_range(-1.0..1.0)))
        .collect()
}

fn mean_edge(mesh: &CellMesh) -> f64 {
    let l = mesh.edge_lengths();
    l.iter().sum::<f64>() / l.len() as f64
}

/// Parameters in units of the equivalent radius and `k_BT = 1`: μ0 = 100 with Fedosov's
/// `k_a = 4900, k_d = 100, k_v = 5000`, and bending rigidity `kappa`.
fn reduced_params_kappa(l0: f64, bending: BendingModel, kappa: f64) -> MembraneParams {
    MembraneParams::from_moduli(&Moduli::new(100.0, kappa, bending, l0)).unwrap()
}

/// [`reduced_params_kappa`] with a large bending rigidity κ = 50 (bending forces comparable
/// to the others: a stringent test of the bending gradients).
fn reduced_params(l0: f64, bending: BendingModel) -> MembraneParams {
    reduced_params_kappa(l0, bending, 50.0)
}

fn bending_models() -> [BendingModel; 2] {
    [
        BendingModel::KantorNelson { theta0: 0.12 },
        BendingModel::Juelicher { c0: 0.8 },
    ]
}

fn max_norm(f: &[[f64; 3]]) -> f64 {
    f.iter()
        .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
        .fold(0.0, f64::max)
}

#[test]
fn topology_of_rbc_meshes() {
    for k in 0..4 {
        let mesh = rbc_mesh(k);
        let topo = MembraneTopology::new(mesh.vertices.len(), &mesh.triangles).unwrap();
        assert_eq!(topo.euler_characteristic(), 2);
        assert_eq!(topo.edges(), &mesh.edges[..]);
        assert_eq!(3 * topo.triangles().len(), 2 * topo.edges().len());
        let total: usize = (0..mesh.vertices.len())
            .map(|v| topo.vertex_edges(v).len())
            .sum();
        assert_eq!(total, 2 * topo.edges().len());
    }
    // An open mesh (one triangle removed) and a flipped triangle are errors.
    let mesh = rbc_mesh(1);
    let err = MembraneTopology::new(mesh.vertices.len(), &mesh.triangles[1..]).unwrap_err();
    assert!(
        matches!(err, DpdError::Mesh(ref s) if s.contains("not closed")),
        "{err}"
    );
    let mut t = mesh.triangles.clone();
    t[3].swap(0, 1);
    assert!(matches!(
        MembraneTopology::new(mesh.vertices.len(), &t),
        Err(DpdError::Mesh(_))
    ));
    // Wrong buffer lengths are errors, not panics.
    let topo = MembraneTopology::new(mesh.vertices.len(), &mesh.triangles).unwrap();
    let m = Membrane::new(
        topo,
        reduced_params(mean_edge(&mesh), bending_models()[0]),
        &mesh.vertices,
    )
    .unwrap();
    let mut f = vec![[0.0; 3]; 3];
    assert!(matches!(
        m.add_forces(&mesh.vertices, &mut f),
        Err(DpdError::Length { .. })
    ));
    assert!(matches!(
        m.energy(&mesh.vertices[1..]),
        Err(DpdError::Length { .. })
    ));
}

/// The icosphere mapped by `shapes::rbc(16)` lies on the closed-form RBC surface (so
/// [`rbc_closest`] projects onto the same surface); relaxation on it makes the edges nearly
/// equal, keeps the vertices on the surface, every triangle facing outwards, and the area and
/// volume.
#[test]
fn relaxed_rbc_mesh_is_nearly_equilateral() {
    let mesh = rbc_mesh(3);
    for p in &mesh.vertices {
        let q = rbc_closest(*p);
        let d = (0..3).map(|c| (p[c] - q[c]).powi(2)).sum::<f64>().sqrt();
        assert!(d < 1e-9, "{p:?} is {d} off the closed-form surface");
    }
    let (relaxed, r) = relaxed_rbc_mesh(3, RELAX_ITERATIONS);
    assert!(r.last_max_move < 1e-9 && r.rejected == 0, "{r:?}");
    println!("{r:#?}");
    assert!(r.after.edge_cv < 0.5 * r.before.edge_cv, "{r:?}");
    assert!(r.after.edge_ratio() > 0.6, "{r:?}");
    assert!(r.after.min_quality > r.before.min_quality, "{r:?}");
    for p in &relaxed.vertices {
        let q = rbc_closest(*p);
        let d = (0..3).map(|c| (p[c] - q[c]).powi(2)).sum::<f64>().sqrt();
        assert!(d < 1e-9, "{p:?} is {d} off the surface");
    }
    let nv = mesh.vertices.len();
    let params = MembraneParams::new(1.0, 1.0);
    let before = Membrane::new(
        MembraneTopology::new(nv, &mesh.triangles).unwrap(),
        params,
        &mesh.vertices,
    )
    .unwrap();
    let after = Membrane::new(
        MembraneTopology::new(nv, &relaxed.triangles).unwrap(),
        params,
        &relaxed.vertices,
    )
    .unwrap();
    assert_eq!(relaxed.triangles, mesh.triangles);
    assert!((after.area0() / before.area0() - 1.0).abs() < 0.01);
    assert!((after.volume0() / before.volume0() - 1.0).abs() < 0.01);
    // No triangle turned over: each normal agrees with the mean normal of its vertices in
    // the unrelaxed mesh.
    let mut vn = vec![[0.0; 3]; nv];
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let normal = |x: &[[f64; 3]], [a, b, c]: [usize; 3]| {
        let u: [f64; 3] = std::array::from_fn(|k| x[b][k] - x[a][k]);
        let w: [f64; 3] = std::array::from_fn(|k| x[c][k] - x[a][k]);
        cross(u, w)
    };
    for &t in &mesh.triangles {
        let n = normal(&mesh.vertices, t);
        for v in t {
            (0..3).for_each(|k| vn[v][k] += n[k]);
        }
    }
    for &t in &relaxed.triangles {
        let n = normal(&relaxed.vertices, t);
        let m: [f64; 3] = std::array::from_fn(|k| t.iter().map(|&v| vn[v][k]).sum());
        assert!((0..3).map(|k| n[k] * m[k]).sum::<f64>() > 0.0);
    }
}

/// Every conservative term against central differences of its energy on a jittered RBC mesh
/// (every coordinate of every vertex), relative to the largest force of the term.
#[test]
fn forces_are_minus_energy_gradients_on_a_jittered_rbc() {
    let mesh = rbc_mesh(2);
    let l0 = mean_edge(&mesh);
    for bending in bending_models() {
        let topo = MembraneTopology::new(mesh.vertices.len(), &mesh.triangles).unwrap();
        let m = Membrane::new(topo, reduced_params(l0, bending), &mesh.vertices).unwrap();
        let y = jittered(&mesh.vertices, 0.15 * l0, 5);
        for term in Term::ALL {
            let mut f = vec![[0.0; 3]; y.len()];
            m.add_term_forces(term, &y, &mut f).unwrap();
            let fmax = max_norm(&f);
            assert!(fmax > 0.0, "{term:?} has no force on a jittered mesh");
            let h = 1e-6 * l0;
            let mut worst: f64 = 0.0;
            let mut yp = y.clone();
            for v in 0..y.len() {
                for c in 0..3 {
                    yp[v][c] = y[v][c] + h;
                    let ep = m.energy(&yp).unwrap().term(term);
                    yp[v][c] = y[v][c] - h;
                    let em = m.energy(&yp).unwrap().term(term);
                    yp[v][c] = y[v][c];
                    let fd = -(ep - em) / (2.0 * h);
                    worst = worst.max((fd - f[v][c]).abs() / fmax);
                }
            }
            println!("FD {bending:?} {term:?}: max |F| = {fmax:.3e}, max rel error {worst:.2e}");
            assert!(worst < 1e-6, "{bending:?} {term:?}: {worst:e}");
        }
        // The total is the sum of the terms.
        let e = m.energy(&y).unwrap();
        let s = e.spring + e.bending + e.local_area + e.global_area + e.volume;
        assert!((e.total - s).abs() <= 1e-12 * e.total.abs());
    }
}

/// Each term conserves momentum and angular momentum: its forces sum to zero, with no torque.
#[test]
fn forces_have_zero_sum_and_zero_torque() {
    let mesh = rbc_mesh(2);
    let l0 = mean_edge(&mesh);
    for bending in bending_models() {
        let topo = MembraneTopology::new(mesh.vertices.len(), &mesh.triangles).unwrap();
        let m = Membrane::new(topo, reduced_params(l0, bending), &mesh.vertices).unwrap();
        // Away from the origin, so that the torque is a real test.
        let y: Vec<[f64; 3]> = jittered(&mesh.vertices, 0.15 * l0, 9)
            .iter()
            .map(|p| [p[0] + 3.0, p[1] - 2.0, p[2] + 1.0])
            .collect();
        for term in Term::ALL {
            let mut f = vec![[0.0; 3]; y.len()];
            m.add_term_forces(term, &y, &mut f).unwrap();
            let fmax = max_norm(&f);
            let mut sum = [0.0; 3];
            let mut torque = [0.0; 3];
            for (p, q) in y.iter().zip(&f) {
                for c in 0..3 {
                    sum[c] += q[c];
                }
                torque[0] += p[1] * q[2] - p[2] * q[1];
                torque[1] += p[2] * q[0] - p[0] * q[2];
                torque[2] += p[0] * q[1] - p[1] * q[0];
            }
            let s = max_norm(&[sum]) / fmax;
            let t = max_norm(&[torque]) / fmax;
            println!("{bending:?} {term:?}: |ΣF|/max|F| = {s:.1e}, |Στ|/max|F| = {t:.1e}");
            assert!(s < 1e-12 && t < 1e-11, "{term:?}: {s:e} {t:e}");
        }
    }
}

/// The viscous pair forces cancel (momentum conservation) and, without noise, dissipate.
#[test]
fn viscous_forces_are_antisymmetric_and_dissipative() {
    let mesh = rbc_mesh(2);
    let l0 = mean_edge(&mesh);
    let topo = MembraneTopology::new(mesh.vertices.len(), &mesh.triangles).unwrap();
    let mut params = reduced_params(l0, bending_models()[0]);
    let mut m = Membrane::new(topo, params, &mesh.vertices).unwrap();
    let y = jittered(&mesh.vertices, 0.1 * l0, 1);
    let v = jittered(&vec![[0.0; 3]; y.len()], 1.0, 2);
    let mut f = vec![[0.0; 3]; y.len()];
    m.add_viscous_forces(&y, &v, 17, 42, 1e-3, &mut f).unwrap();
    let fmax = max_norm(&f);
    let sum = f
        .iter()
        .fold([0.0; 3], |s, q| [s[0] + q[0], s[1] + q[1], s[2] + q[2]]);
    assert!(max_norm(&[sum]) < 1e-12 * fmax * y.len() as f64, "{sum:?}");
    // Same (seed, step): the same forces; another step: others.
    let mut g = vec![[0.0; 3]; y.len()];
    m.add_viscous_forces(&y, &v, 17, 42, 1e-3, &mut g).unwrap();
    assert_eq!(f, g);
    let mut g = vec![[0.0; 3]; y.len()];
    m.add_viscous_forces(&y, &v, 18, 42, 1e-3, &mut g).unwrap();
    assert_ne!(f, g);
    // Without noise: Σ v·F ≤ 0, and a rigid motion feels no force.
    params.kbt = 0.0;
    m.set_params(params).unwrap();
    let mut f = vec![[0.0; 3]; y.len()];
    m.add_viscous_forces(&y, &v, 0, 0, 1e-3, &mut f).unwrap();
    let power: f64 = v
        .iter()
        .zip(&f)
        .map(|(a, b)| a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
        .sum();
    assert!(power < 0.0);
    // A uniform translation feels no force (a rigid rotation does, through γ_T: the model of
    // Fedosov 2010 is not rotation invariant in its γ_T term).
    let rigid = vec![[1.0, -2.0, 0.5]; y.len()];
    let mut f = vec![[0.0; 3]; y.len()];
    m.add_viscous_forces(&y, &rigid, 0, 0, 1e-3, &mut f)
        .unwrap();
    assert!(max_norm(&f) < 1e-12 * params.gamma_c.max(params.gamma_t) * 10.0);
}

/// `from_moduli` gives back μ0 by Fedosov's relation (eq. 16, evaluated literally here) and κ.
#[test]
fn from_moduli_round_trip() {
    let mesh = rbc_mesh(3);
    let l0 = mean_edge(&mesh);
    for (x0, m) in [(1.0 / 2.2, 2.0), (0.4, 2.0), (0.5, 1.0), (0.45, 3.0)] {
        let mu0 = 6.3;
        let kbt = 0.0041;
        let p = MembraneParams::from_moduli(&Moduli {
            shear_modulus: mu0,
            bending_rigidity: 0.24,
            bending: BendingModel::KantorNelson { theta0: 0.0 },
            ka: 308.7,
            kd: 6.3,
            kv: 315.0,
            kbt,
            x0,
            m,
            mean_edge_length: l0,
            gamma_t: 1.0,
            gamma_c: None,
        })
        .unwrap();
        let lmax = l0 / x0;
        let kp = l0.powf(m) * kbt / p.persistence_length * (0.25 / (1.0 - x0).powi(2) - 0.25 + x0);
        let s3 = 3f64.sqrt();
        let fedosov = s3 * kbt / (4.0 * p.persistence_length * lmax * x0)
            * (x0 / (2.0 * (1.0 - x0).powi(3)) - 0.25 / (1.0 - x0).powi(2) + 0.25)
            + s3 * kp * (m + 1.0) / (4.0 * l0.powf(m + 1.0));
        assert!((fedosov - mu0).abs() < 1e-12 * mu0, "{fedosov}");
        assert!((p.kp(l0) - kp).abs() < 1e-12 * kp);
        let Bending::KantorNelson { kb, .. } = p.bending else {
            panic!("bending model")
        };
        assert!((kb - 2.0 * 0.24 / s3).abs() < 1e-15);
        assert!((p.gamma_c - 1.0 / 3.0).abs() < 1e-15);
        let k = p.area_compression_modulus(l0);
        assert!((k - (2.0 * mu0 + 308.7 + 6.3)).abs() < 1e-9);
        assert!((p.youngs_modulus(l0) - 4.0 * k * mu0 / (k + mu0)).abs() < 1e-9);
    }
}

/// FIRE minimisation (Bitzek et al. 2006) of the membrane energy plus constant external forces.
/// Steps are limited to `max_move` per vertex. Returns the number of steps and the final max force residual.
fn fire(
    m: &Membrane,
    x: &mut [[f64; 3]],
    fext: &[[f64; 3]],
    dt0: f64,
    max_move: f64,
    tol: f64,
    max_steps: usize,
) -> (usize, f64) {
    let n = x.len();
    let mut v = vec![[0.0; 3]; n];
    let mut f = vec![[0.0; 3]; n];
    let (dt_max, mut dt, mut alpha, mut n_pos) = (10.0 * dt0, dt0, 0.1, 0usize);
    let mut residual = f64::INFINITY;
    for step in 0..max_steps {
        f.copy_from_slice(fext);
        m.add_forces(x, &mut f).unwrap();
        residual = max_norm(&f);
        if residual < tol {
            return (step, residual);
        }
        let power: f64 = (0..n)
            .map(|i| (0..3).map(|c| v[i][c] * f[i][c]).sum::<f64>())
            .sum();
        if power > 0.0 {
            let vn = v.iter().flatten().map(|a| a * a).sum::<f64>().sqrt();
            let fnorm = f.iter().flatten().map(|a| a * a).sum::<f64>().sqrt();
            for i in 0..n {
                for c in 0..3 {
                    v[i][c] = (1.0 - alpha) * v[i][c] + alpha * vn * f[i][c] / fnorm;
                }
            }
            n_pos += 1;
            if n_pos > 5 {
                dt = (dt * 1.1).min(dt_max);
                alpha *= 0.99;
            }
        } else {
            v.iter_mut().for_each(|a| *a = [0.0; 3]);
            dt *= 0.5;
            alpha = 0.1;
            n_pos = 0;
        }
        for i in 0..n {
            for c in 0..3 {
                v[i][c] += dt * f[i][c];
            }
        }
        // No vertex moves more than `max_move` in a step.
        let vmax = max_norm(&v);
        let h = if vmax * dt > max_move {
            max_move / vmax
        } else {
            dt
        };
        for i in 0..n {
            for c in 0..3 {
                x[i][c] += h * v[i][c];
            }
        }
    }
    (max_steps, residual)
}

/// An RBC perturbed (jitter and a 3 % anisotropic stretch) and relaxed by damped dynamics
/// (FIRE, 2000 steps) recovers its area and volume to 1 %. The bending rigidity has the ratio of
/// a real RBC, `μ0 R²/κ ≈ 400` (κ = 0.25 with μ0 = 100, R = 1).
#[test]
fn relaxed_rbc_keeps_area_and_volume() {
    let mesh = rbc_mesh(2);
    let l0 = mean_edge(&mesh);
    for bending in bending_models() {
        let topo = MembraneTopology::new(mesh.vertices.len(), &mesh.triangles).unwrap();
        let params = reduced_params_kappa(l0, bending, 0.25);
        let m = Membrane::new(topo, params, &mesh.vertices).unwrap();
        let mut x: Vec<[f64; 3]> = jittered(&mesh.vertices, 0.1 * l0, 3)
            .iter()
            .map(|p| [1.03 * p[0], 0.99 * p[1], 1.02 * p[2]])
            .collect();
        let e_start = m.energy(&x).unwrap().total;
        let a_start = m.area(&x).unwrap() / m.area0() - 1.0;
        let v_start = m.volume(&x).unwrap() / m.volume0() - 1.0;
        let zero = vec![[0.0; 3]; x.len()];
        let (steps, residual) = fire(&m, &mut x, &zero, 2e-3, 0.02 * l0, 1e-6, 2000);
        let e_end = m.energy(&x).unwrap().total;
        let da = m.area(&x).unwrap() / m.area0() - 1.0;
        let dv = m.volume(&x).unwrap() / m.volume0() - 1.0;
        println!(
            "relax {bending:?}: {steps} steps, residual {residual:.2e}, E {e_start:.3e} -> \
             {e_end:.3e}, ΔA/A0 {a_start:.2e} -> {da:.2e}, ΔV/V0 {v_start:.2e} -> {dv:.2e}"
        );
        assert!(e_end < e_start);
        assert!(da.abs() < 0.01 && dv.abs() < 0.01, "{da} {dv}");
    }
}

/// Result of one optical-tweezers stretch.
struct Stretch {
    force: f64,
    axial: f64,
    transverse: f64,
    transverse_y: f64,
    steps: usize,
    residual: f64,
    area_change: f64,
    volume_change: f64,
}

/// Mills et al. (2004), optical tweezers: (force pN, axial µm, transverse µm).
const MILLS: [(f64, f64, f64); 3] = [(0.0, 7.78, 7.78), (88.0, 13.07, 4.78), (193.0, 15.29, 4.27)];

/// The model parameters of a stretching run; [`StretchModel::FEDOSOV`] is the validation's.
/// `k_a`, `k_d` and `k_v` are Fedosov's reduced values in units of μ0 (see [`stretch`]), so they
/// scale with `mu0`; the multipliers change them beyond that.
#[derive(Clone, Copy, Debug)]
struct StretchModel {
    /// μ0 in µN/m (pN/µm).
    mu0: f64,
    /// Multipliers of κ = 2.4e-19 J, of the sphere's θ0, of k_a, k_d and k_v.
    kappa: f64,
    theta0: f64,
    ka: f64,
    kd: f64,
    kv: f64,
    /// `l_max / l0`.
    extension: f64,
    /// Fraction of the vertices in each force patch.
    patch: f64,
}

impl StretchModel {
    const FEDOSOV: StretchModel = StretchModel {
        mu0: 6.3,
        kappa: 1.0,
        theta0: 1.0,
        ka: 1.0,
        kd: 1.0,
        kv: 1.0,
        extension: 2.2,
        patch: 0.02,
    };
}

/// Stretch the RBC (diameter 7.82 µm, units µm and pN) with opposite forces `±F` spread over the
/// 2 % of vertices with the largest and smallest `x`; relax with FIRE; measure the diameters.
///
/// Moduli: μ0 = 6.3 µN/m = 6.3 pN/µm, κ = 2.4e-19 J = 0.24 pN·µm, k_BT = 4.087e-21 J (296 K).
/// Fedosov's reduced `k_a = 4900, k_d = 100, k_v = 5000` are taken in units where μ0 = 100 and
/// lengths are in µm: `k_a = 49 μ0`, `k_d = μ0`, `k_v = 50 μ0 / µm`. Kantor–Nelson bending with
/// the spontaneous angle of a sphere of `N_v` vertices.
///
/// `relax`: relax the mesh ([`relaxed_rbc_mesh`]) before scaling it, and take the relaxed mesh
/// as the reference state. Returns the rows, the vertices per patch, the mean edge length and
/// the mesh statistics (after scaling).
fn stretch(
    subdivisions: u32,
    forces: &[f64],
    tol: f64,
    relax: bool,
) -> (Vec<Stretch>, usize, f64, MeshQuality) {
    stretch_model(subdivisions, forces, tol, relax, &StretchModel::FEDOSOV)
}

fn stretch_model(
    subdivisions: u32,
    forces: &[f64],
    tol: f64,
    relax: bool,
    model: &StretchModel,
) -> (Vec<Stretch>, usize, f64, MeshQuality) {
    let mut mesh = if relax {
        let (mesh, report) = relaxed_rbc_mesh(subdivisions, RELAX_ITERATIONS);
        println!("relaxation: {report:?}");
        mesh
    } else {
        rbc_mesh(subdivisions)
    };
    let d0 = 2.0
        * mesh
            .vertices
            .iter()
            .map(|p| (p[0] * p[0] + p[1] * p[1]).sqrt())
            .fold(0.0, f64::max);
    let s = 7.82 / d0;
    mesh.vertices.iter_mut().for_each(|p| *p = p.map(|c| c * s));
    let nv = mesh.vertices.len();
    let l0 = mean_edge(&mesh);
    let mu0 = model.mu0;
    let params = MembraneParams::from_moduli(&Moduli {
        shear_modulus: mu0,
        bending_rigidity: 0.24 * model.kappa,
        bending: BendingModel::KantorNelson {
            theta0: sphere_spontaneous_angle(nv) * model.theta0,
        },
        ka: 4900.0 * mu0 / 100.0 * model.ka,
        kd: 100.0 * mu0 / 100.0 * model.kd,
        kv: 5000.0 * mu0 / 100.0 * model.kv,
        kbt: 1.380649e-23 * 296.0 * 1e18,
        x0: 1.0 / model.extension,
        m: 2.0,
        mean_edge_length: l0,
        gamma_t: 0.0,
        gamma_c: None,
    })
    .unwrap();
    let topo = MembraneTopology::new(nv, &mesh.triangles).unwrap();
    let quality = mesh_quality(&mesh.vertices, &topo).unwrap();
    let m = Membrane::new(topo, params, &mesh.vertices).unwrap();
    let n_patch = ((model.patch * nv as f64).round() as usize).max(1);
    let mut order: Vec<usize> = (0..nv).collect();
    order.sort_by(|&a, &b| mesh.vertices[a][0].total_cmp(&mesh.vertices[b][0]));
    let mut out = Vec::new();
    let mut x = mesh.vertices.clone();
    for &force in forces {
        let mut fext = vec![[0.0; 3]; nv];
        for &v in &order[..n_patch] {
            fext[v][0] = -force / n_patch as f64;
        }
        for &v in &order[nv - n_patch..] {
            fext[v][0] = force / n_patch as f64;
        }
        // Continue from the previous (smaller-force) equilibrium.
        let (steps, residual) = fire(&m, &mut x, &fext, 0.01, 0.02 * l0, tol, 400_000);
        let c = x
            .iter()
            .fold([0.0; 3], |s, p| [s[0] + p[0], s[1] + p[1], s[2] + p[2]]);
        let c = c.map(|v| v / nv as f64);
        let (xmin, xmax) = x
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p[0]), b.max(p[0])));
        let (ymin, ymax) = x
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p[1]), b.max(p[1])));
        let rmax = x
            .iter()
            .map(|p| ((p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt())
            .fold(0.0, f64::max);
        out.push(Stretch {
            force,
            axial: xmax - xmin,
            transverse: 2.0 * rmax,
            transverse_y: ymax - ymin,
            steps,
            residual,
            area_change: m.area(&x).unwrap() / m.area0() - 1.0,
            volume_change: m.volume(&x).unwrap() / m.volume0() - 1.0,
        });
    }
    (out, n_patch, l0, quality)
}

fn print_stretch(rows: &[Stretch]) {
    for r in rows {
        println!(
            "F = {:6.1} pN: D_A = {:.3} µm, D_T = {:.3} µm (y extent {:.3}), {} FIRE steps, \
             residual {:.1e} pN, ΔA/A0 {:+.2e}, ΔV/V0 {:+.2e}",
            r.force,
            r.axial,
            r.transverse,
            r.transverse_y,
            r.steps,
            r.residual,
            r.area_change,
            r.volume_change
        );
    }
}

fn mills(force: f64) -> (f64, f64) {
    let r = MILLS.iter().find(|r| r.0 == force).unwrap();
    (r.1, r.2)
}

/// Fast version: 0, 88 and 193 pN on the 642-vertex mesh, unrelaxed and relaxed (a few
/// seconds). Unrelaxed: Mills et al. within 10 % except the transverse diameter at 88 pN, which
/// comes out 11–12 % wide (5.33 µm against 4.78 µm; the same at 2562 vertices), asserted at
/// 13 %. Relaxed (nearly equilateral, [`relaxed_rbc_mesh`]): the axial diameter within 10 %
/// but the transverse diameter wider still, +23 % at 88 pN (5.90 µm) and +14 % at 193 pN
/// (4.86 µm), the same at 2562 vertices: asserted at 25 % and 16 % so that a change shows.
#[test]
fn rbc_stretching_against_mills() {
    for relax in [false, true] {
        let t = Instant::now();
        let (rows, n_patch, _, q) = stretch(3, &[0.0, 88.0, 193.0], 1e-3, relax);
        println!("relaxed: {relax}, {q:?}");
        print_stretch(&rows);
        println!(
            "{n_patch} vertices per patch, {:.1} s",
            t.elapsed().as_secs_f64()
        );
        for r in &rows {
            let (da, dt) = mills(r.force);
            let tol_t = match (relax, r.force as i64) {
                (false, 88) => 0.13,
                (true, 88) => 0.25,
                (true, 193) => 0.16,
                _ => 0.1,
            };
            assert!(r.residual < 1e-3, "not converged: {}", r.residual);
            assert!((r.axial / da - 1.0).abs() < 0.1, "D_A {} vs {da}", r.axial);
            assert!(
                (r.transverse / dt - 1.0).abs() < tol_t,
                "relaxed {relax}: D_T {} vs {dt}",
                r.transverse
            );
            assert!(r.area_change.abs() < 0.01 && r.volume_change.abs() < 0.01);
        }
    }
}

/// The full table (0, 25…200 pN), written to docs/dpd_rbc_stretch.md: the unrelaxed icosphere
/// ("before") and the relaxed mesh ([`relaxed_rbc_mesh`]), each at 642 and 2562 vertices.
#[test]
#[ignore = "slow: run by scripts/dpd_rbc_stretch.sh in release"]
fn rbc_stretching_table() {
    let forces = [0.0, 25.0, 50.0, 88.0, 100.0, 150.0, 193.0];
    let tol = 1e-5;
    let mut md = String::new();
    md.push_str("# RBC stretching against Mills et al. (2004)\n\n");
    let profile = if cfg!(debug_assertions) {
        "the dev profile (`cargo test --test dpd_membrane -- --ignored`)"
    } else {
        "release (`scripts/dpd_rbc_stretch.sh`)"
    };
    md.push_str(&format!(
        "Written by the ignored test `rbc_stretching_table` of tests/dpd_membrane.rs, built in \
         {profile}, 2026-11-25, on the 2-core development machine. Model: \
         `mobo::dpd::membrane` (Fedosov, Caswell & Karniadakis 2010), see \
         docs/dpd_membrane.md.\n\n"
    ));
    md.push_str(&format!(
        "Settings: RBC of `shapes::rbc(16)` on the icosphere, scaled to a diameter of 7.82 µm; \
         μ0 = 6.3 µN/m, κ = 2.4e-19 J (Kantor–Nelson, θ0 of the sphere with the same number \
         of vertices), k_BT at 296 K, x0 = 1/2.2, m = 2 (stress-free springs), k_a = 4900, \
         k_d = 100, k_v = 5000 in units where μ0 = 100 and lengths are µm (k_a = 49 μ0, \
         k_d = μ0, k_v = 50 μ0/µm); each force spread evenly over the 2 % of vertices with the \
         largest and the 2 % with the smallest x; FIRE to a max force residual of {tol:e} pN, \
         each force starting from the previous equilibrium. D_A: extent along x; D_T: twice \
         the largest distance of a vertex from the x axis through the centroid (in parentheses \
         the extent along y, the in-plane diameter of the microscope image). Errors against \
         Mills et al. (2004): 7.78/7.78 µm at 0 pN, 13.07/4.78 at 88 pN, 15.29/4.27 at \
         193 pN.\n\n\
         Meshes: *unrelaxed*, the icosphere mapped onto the surface through its parameter \
         sphere (`CellMesh::icosphere`); *relaxed*, the same triangulation after \
         `relax_on_surface` (tangential springs towards the mean edge length, step 0.2, up to \
         {RELAX_ITERATIONS} iterations, stopping when no vertex moves by 1e-12 edge lengths; \
         after each step the vertices are put back on the closed-form biconcave surface by a \
         closest-point projection). The reference (stress-free) state is the mesh as used. \
         Edge statistics after scaling; quality q = 4√3 A/(l1² + l2² + l3²) (1 for an \
         equilateral triangle). What the comparison shows: docs/dpd_membrane.md \
         (Validation).\n\n"
    ));
    for (subdivisions, relax) in [(3, false), (3, true), (4, false), (4, true)] {
        let t = Instant::now();
        let (rows, n_patch, l0, q) = stretch(subdivisions, &forces, tol, relax);
        let secs = t.elapsed().as_secs_f64();
        print_stretch(&rows);
        let nv = 10 * 4usize.pow(subdivisions) + 2;
        let which = if relax {
            "relaxed"
        } else {
            "unrelaxed (before)"
        };
        md.push_str(&format!(
            "## {nv} vertices (icosphere subdivision {subdivisions}), {which}\n\nEdges \
             {:.3}–{:.3} µm (min/max {:.2}), mean {l0:.3} µm, spread (std/mean) {:.1} %; triangle \
             quality min {:.3}, mean {:.3}; {n_patch} vertices per patch; {secs:.1} s (mesh \
             preparation and all forces).\n\n",
            q.min_edge,
            q.max_edge,
            q.edge_ratio(),
            100.0 * q.edge_cv,
            q.min_quality,
            q.mean_quality
        ));
        md.push_str(
            "| F (pN) | D_A (µm) | Mills D_A | error | D_T (µm) | Mills D_T | error | ΔA/A0 | \
             ΔV/V0 | FIRE steps |\n|---|---|---|---|---|---|---|---|---|---|\n",
        );
        for r in &rows {
            let mills = MILLS.iter().find(|m| m.0 == r.force);
            let (ma, ea, mt, et) = match mills {
                Some(&(_, a, t)) => (
                    format!("{a:.2}"),
                    format!("{:+.1} %", 100.0 * (r.axial / a - 1.0)),
                    format!("{t:.2}"),
                    format!("{:+.1} %", 100.0 * (r.transverse / t - 1.0)),
                ),
                None => ("–".into(), "–".into(), "–".into(), "–".into()),
            };
            md.push_str(&format!(
                "| {:.0} | {:.2} | {ma} | {ea} | {:.2} ({:.2}) | {mt} | {et} | {:+.1e} | \
                 {:+.1e} | {} |\n",
                r.force,
                r.axial,
                r.transverse,
                r.transverse_y,
                r.area_change,
                r.volume_change,
                r.steps
            ));
        }
        md.push('\n');
        for r in &rows {
            assert!(r.residual < tol, "not converged at {} pN", r.force);
        }
    }
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/docs/dpd_rbc_stretch.md");
    std::fs::write(path, md).unwrap();
}

/// How the diameters depend on the model's parameters: each varied alone from the validation's
/// (Fedosov's μ0 = 6.3 µN/m, ...), at 0, 88 and 193 pN on the 642-vertex mesh, unrelaxed and
/// relaxed, and with the volume penalty weakened or removed; written to
/// docs/dpd_rbc_stretch_sensitivity.md. About four minutes (dev profile, 2-core AVX2 VM).
#[test]
#[ignore = "a parameter study: cargo test --test dpd_membrane -- --ignored rbc_stretching_sensitivity"]
fn rbc_stretching_sensitivity() {
    let f = StretchModel::FEDOSOV;
    let variants: Vec<(String, StretchModel)> = vec![
        ("as validated (Fedosov 2010)".into(), f),
        // k_a, k_d and k_v keep their ratios to μ0 (Fedosov's reduced units).
        ("μ0 = 4.8".into(), StretchModel { mu0: 4.8, ..f }),
        (
            "μ0 = 5.3 (Mills et al.'s own fit)".into(),
            StretchModel { mu0: 5.3, ..f },
        ),
        ("μ0 = 5.6".into(), StretchModel { mu0: 5.6, ..f }),
        ("μ0 = 5.9".into(), StretchModel { mu0: 5.9, ..f }),
        ("κ × 0.01".into(), StretchModel { kappa: 0.01, ..f }),
        ("κ × 3".into(), StretchModel { kappa: 3.0, ..f }),
        ("θ0 = 0".into(), StretchModel { theta0: 0.0, ..f }),
        ("k_d = 0".into(), StretchModel { kd: 0.0, ..f }),
        ("k_d × 0.3".into(), StretchModel { kd: 0.3, ..f }),
        ("k_d × 10".into(), StretchModel { kd: 10.0, ..f }),
        (
            "k_a, k_d × 0.1".into(),
            StretchModel {
                ka: 0.1,
                kd: 0.1,
                ..f
            },
        ),
        (
            "l_max/l0 = 1.8".into(),
            StretchModel {
                extension: 1.8,
                ..f
            },
        ),
        (
            "l_max/l0 = 3".into(),
            StretchModel {
                extension: 3.0,
                ..f
            },
        ),
        ("patches of 5 %".into(), StretchModel { patch: 0.05, ..f }),
        // The enclosed volume free: no cytosol holding the cell's cross-section open.
        ("k_v × 0.1".into(), StretchModel { kv: 0.1, ..f }),
        (
            "k_v = 0 (volume free)".into(),
            StretchModel { kv: 0.0, ..f },
        ),
    ];
    let mut md = String::from(
        "# RBC stretching: how the diameters depend on the model's parameters\n\n\
         Written by the ignored test `rbc_stretching_sensitivity` of tests/dpd_membrane.rs \
         (`cargo test --test dpd_membrane -- --ignored rbc_stretching_sensitivity`). The \
         settings of docs/dpd_rbc_stretch.md (642 vertices; FIRE to a residual of 1e-3 pN), \
         with one parameter changed at a time (the μ0 rows keep k_a, k_d and k_v in their ratios \
         to μ0, as Fedosov's reduced units have them). Entries: the error of D_A / D_T against \
         Mills et al. (2004) at 0, 88 and 193 pN; **bold** where it is above 10 %; the last \
         column is the change of the enclosed volume at 193 pN.\n\n\
         | variant | mesh | 0 pN | 88 pN | 193 pN | all within 10 % | ΔV/V0 at 193 pN |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for (name, model) in &variants {
        for relax in [false, true] {
            let (rows, ..) = stretch_model(3, &[0.0, 88.0, 193.0], 1e-3, relax, model);
            let mut cells = Vec::new();
            let mut all = true;
            for r in &rows {
                if r.residual >= 1e-3 {
                    all = false;
                    cells.push(format!("not converged (residual {:.1e} pN)", r.residual));
                    continue;
                }
                let (da, dt) = mills(r.force);
                let e = [r.axial / da - 1.0, r.transverse / dt - 1.0];
                let show = |x: f64| {
                    let s = format!("{:+.1} %", 100.0 * x);
                    if x.abs() > 0.1 {
                        format!("**{s}**")
                    } else {
                        s
                    }
                };
                all &= e.iter().all(|x| x.abs() <= 0.1);
                cells.push(format!("{} / {}", show(e[0]), show(e[1])));
            }
            let mesh = if relax { "relaxed" } else { "unrelaxed" };
            let line = format!(
                "| {name} | {mesh} | {} | {} | {:+.1} % |\n",
                cells.join(" | "),
                if all { "yes" } else { "no" },
                100.0 * rows.last().map_or(0.0, |r| r.volume_change)
            );
            print!("{line}");
            md.push_str(&line);
        }
    }
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/docs/dpd_rbc_stretch_sensitivity.md"
    );
    std::fs::write(path, md).unwrap();
}

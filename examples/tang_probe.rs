//! Diagnostic of the growing tangential membrane velocity in extensional flow (probe22).
//!
//! `tang_probe P DT STEPS EVERY` with env: MOBO_FLOW (ext|shear), MOBO_KAPPA, MOBO_V (0.7),
//! MOBO_LOAD / MOBO_SAVE (state file), MOBO_SAVE_STEP, MOBO_NO_REPARAM, MOBO_TOL,
//! MOBO_SEED (add a small symmetry-breaking tangential perturbation at start), MOBO_T0.
use mobo::timestep::semi_implicit::{TimeScheme, VesicleParams};
use mobo::timestep::vesicle_stepper::VesicleStepper;
use mobo::timestep::GmresParams;
use mobo::vesicle::geometry::SurfaceCalculus;
use mobo::vesicle::reparam::ReparamParams;
use mobo::vesicle::shapes::{self, Spheroid};

fn env_f64(name: &str, default: f64) -> f64 {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

fn save(path: &str, t: f64, coefs: &[f64], sigma: &[f64]) {
    let mut s = format!("{t:e}\n{}\n", coefs.len());
    for c in coefs {
        s += &format!("{c:e}\n");
    }
    s += &format!("{}\n", sigma.len());
    for c in sigma {
        s += &format!("{c:e}\n");
    }
    std::fs::write(path, s).unwrap();
}

fn load(path: &str) -> (f64, Vec<f64>, Vec<f64>) {
    let s = std::fs::read_to_string(path).unwrap();
    let mut it = s.lines();
    let t: f64 = it.next().unwrap().parse().unwrap();
    let nc: usize = it.next().unwrap().parse().unwrap();
    let c: Vec<f64> = (0..nc)
        .map(|_| it.next().unwrap().parse().unwrap())
        .collect();
    let ns: usize = it.next().unwrap().parse().unwrap();
    let sg: Vec<f64> = (0..ns)
        .map(|_| it.next().unwrap().parse().unwrap())
        .collect();
    (t, c, sg)
}

/// Reflection maps on the grid: (point permutation, sign per component).
fn reflections(p: usize) -> Vec<(Vec<usize>, [f64; 3])> {
    let nlon = 2 * p;
    let nlat = p + 1;
    let mk = |f: &dyn Fn(usize, usize) -> (usize, usize)| -> Vec<usize> {
        let mut v = vec![0; nlat * nlon];
        for i in 0..nlat {
            for k in 0..nlon {
                let (ii, kk) = f(i, k);
                v[i * nlon + k] = ii * nlon + kk;
            }
        }
        v
    };
    vec![
        (mk(&|i, k| (i, (p + nlon - k) % nlon)), [-1.0, 1.0, 1.0]),
        (mk(&|i, k| (i, (nlon - k) % nlon)), [1.0, -1.0, 1.0]),
        (mk(&|i, k| (p - i, k)), [1.0, 1.0, -1.0]),
    ]
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let p: usize = a[1].parse().unwrap();
    let dt: f64 = a[2].parse().unwrap();
    let steps: usize = a[3].parse().unwrap();
    let every: usize = a[4].parse().unwrap();
    let kappa = env_f64("MOBO_KAPPA", 0.05);
    let v = env_f64("MOBO_V", 0.7);
    let ext = !std::env::var("MOBO_FLOW").is_ok_and(|f| f == "shear");
    let save_step: usize = env_f64("MOBO_SAVE_STEP", 0.0) as usize;
    let seed = env_f64("MOBO_SEED", 0.0);
    let n = 2 * p * (p + 1);
    let sht = mobo::sph_harmonics::ShTransform::new(p).unwrap();
    let mut ws = sht.workspace();
    let (mut t0, mut coefs, sigma0) = match std::env::var("MOBO_LOAD") {
        Ok(f) => {
            let (t, c, s) = load(&f);
            (t, c, Some(s))
        }
        Err(_) => (
            0.0,
            shapes::reduced_volume_spheroid(p, v, Spheroid::Prolate, 1.0)
                .unwrap()
                .coefs()
                .to_vec(),
            None,
        ),
    };
    t0 = env_f64("MOBO_T0", t0);
    // A state saved at another order is resampled (zero-padded or truncated).
    let ncp = mobo::sph_harmonics::CoefLayout::new(p).len();
    if coefs.len() != 3 * ncp {
        let from = (((coefs.len() / 3 + 1) as f64).sqrt().round() as usize) - 1;
        let mut c = vec![0.0; 3 * ncp];
        mobo::sph_harmonics::resample::resample_coefs(
            &mobo::sph_harmonics::CoefLayout::new(from),
            &mobo::sph_harmonics::CoefLayout::new(p),
            &coefs,
            &mut c,
        )
        .unwrap();
        coefs = c;
    }
    let mut calc = SurfaceCalculus::new(p).unwrap();
    if seed != 0.0 {
        // tangential symmetry-breaking perturbation: rotate grid labels by a small field
        // d = seed * (e_z × x) projected tangentially, times (1 + x) to break all reflections.
        let g = calc.geometry(&coefs).unwrap();
        let mut xg = vec![0.0; 3 * n];
        sht.inverse(&coefs, &mut xg, &mut ws).unwrap();
        for j in 0..n {
            let x = g.x[j];
            let d0 = [
                -(x[1]) * (1.0 + x[0] + x[2]),
                x[0] * (1.0 + x[1]),
                0.3 * x[0],
            ];
            let nv = g.normal[j];
            let dn = d0[0] * nv[0] + d0[1] * nv[1] + d0[2] * nv[2];
            for c in 0..3 {
                xg[c * n + j] += seed * (d0[c] - dn * nv[c]);
            }
        }
        sht.forward(&xg, &mut coefs, &mut ws).unwrap();
    }
    let params = VesicleParams {
        bending_modulus: kappa,
        viscosity: 1.0,
        force: [0.0; 3],
        dt,
        upsampled_order: 2 * p,
        gmres: GmresParams {
            tol: env_f64("MOBO_TOL", 1e-8),
            restart: 200,
            max_iters: 5000,
            ..Default::default()
        },
        correct_drift: true,
        reparametrize: std::env::var("MOBO_NO_REPARAM")
            .is_err()
            .then(|| ReparamParams {
                max_iterations: 10,
                ..Default::default()
            }),
        preconditioner: true,
        scheme: TimeScheme::Euler,
        viscosity_ratio: 1.0,
        inextensible: true,
        elastic_stepping: None,
    };
    let mut stepper = VesicleStepper::new(p, params).unwrap();
    if let Some(s) = sigma0 {
        if s.len() == n {
            stepper.state_mut().sigma.copy_from_slice(&s);
        }
    }
    if let Ok(s) = std::env::var("MOBO_TARGET") {
        // area,volume of the original run
        let v: Vec<f64> = s.split(',').map(|x| x.parse().unwrap()).collect();
        stepper.set_drift_targets(Some((v[0], v[1])));
    } else {
        let g = calc
            .geometry(
                shapes::reduced_volume_spheroid(p, v, Spheroid::Prolate, 1.0)
                    .unwrap()
                    .coefs(),
            )
            .unwrap();
        stepper.set_drift_targets(Some((g.area(), g.volume())));
    }
    let (a0, v0) = stepper.drift_targets().unwrap();
    let flow = move |x: [f64; 3]| {
        if ext {
            [x[0], -x[1], 0.0]
        } else {
            [x[1], 0.0, 0.0]
        }
    };
    let refl = reflections(p);
    let comove = std::env::var("MOBO_COMOVE").is_ok();
    let lay = mobo::sph_harmonics::CoefLayout::new(p);
    let degs = lay.degrees();
    let nc = lay.len();
    println!("# t iters area_drift Jratio |u_n| |u_t| |dX/dt| rot_fit(w) |resid| divrms curlrms antisym(x,y,z) sigma_antisym(x,y,z) deg_peak hi_share axes");
    let start = std::time::Instant::now();
    let mut iters = 0usize;
    for k in 1..=steps {
        let coefs_old = coefs.clone();
        // MOBO_COMOVE: the stagnation point of the background flow follows the cell's centroid
        // (u∞(x − c), c measured before the step).
        let cshift = if comove {
            calc.geometry(&coefs).unwrap().centroid()
        } else {
            [0.0; 3]
        };
        let flow = |x: [f64; 3]| flow([x[0] - cshift[0], x[1] - cshift[1], x[2] - cshift[2]]);
        let r = match stepper.step(&mut coefs, &flow) {
            Ok(r) => r,
            Err(e) => {
                println!("# step {k} t={:.3} failed: {e}", t0 + k as f64 * dt);
                std::process::exit(1);
            }
        };
        iters += r.gmres.iterations;
        if save_step == k {
            if let Ok(f) = std::env::var("MOBO_SAVE") {
                save(&f, t0 + k as f64 * dt, &coefs, &stepper.state().sigma);
            }
        }
        if k % every != 0 {
            continue;
        }
        let t = t0 + k as f64 * dt;
        let g = calc.geometry(&coefs).unwrap();
        let grid = calc.transform().grid();
        let (mut jmin, mut jmax) = (f64::INFINITY, 0.0f64);
        for (j, w) in g.w.iter().enumerate() {
            let jj = w / grid.sin_theta[j / (2 * p)];
            jmin = jmin.min(jj);
            jmax = jmax.max(jj);
        }
        let disp = {
            let diff: Vec<f64> = coefs
                .iter()
                .zip(&coefs_old)
                .map(|(a, b)| (a - b) / dt)
                .collect();
            let mut gr = vec![0.0; 3 * n];
            sht.inverse(&diff, &mut gr, &mut ws).unwrap();
            (gr.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt()
        };
        let u = stepper.velocity().unwrap().to_vec();
        // Tangential part.
        let mut ut = vec![0.0; 3 * n];
        let (mut un2, mut ut2, mut wsum) = (0.0, 0.0, 0.0);
        for j in 0..n {
            let nv = g.normal[j];
            let uj = [u[j], u[n + j], u[2 * n + j]];
            let un = uj[0] * nv[0] + uj[1] * nv[1] + uj[2] * nv[2];
            for c in 0..3 {
                ut[c * n + j] = uj[c] - un * nv[c];
            }
            let w = g.da[j];
            un2 += w * un * un;
            ut2 += w * (0..3).map(|c| ut[c * n + j].powi(2)).sum::<f64>();
            wsum += w;
        }
        let rms = |s: f64| (s / wsum).sqrt();
        // Rigid-rotation fit of u_t: minimise Σ w |u_t − P(ω × (x − c))|².
        let cen = g.centroid();
        let mut m = [[0.0; 3]; 3];
        let mut rhs = [0.0; 3];
        let mut basis = vec![[[0.0; 3]; 3]; n];
        for j in 0..n {
            let x = [g.x[j][0] - cen[0], g.x[j][1] - cen[1], g.x[j][2] - cen[2]];
            let nv = g.normal[j];
            for (a, b) in basis[j].iter_mut().enumerate() {
                let mut e = [0.0; 3];
                e[a] = 1.0;
                let c = [
                    e[1] * x[2] - e[2] * x[1],
                    e[2] * x[0] - e[0] * x[2],
                    e[0] * x[1] - e[1] * x[0],
                ];
                let cn = c[0] * nv[0] + c[1] * nv[1] + c[2] * nv[2];
                *b = [c[0] - cn * nv[0], c[1] - cn * nv[1], c[2] - cn * nv[2]];
            }
            let w = g.da[j];
            for a in 0..3 {
                for b in 0..3 {
                    m[a][b] += w * (0..3).map(|c| basis[j][a][c] * basis[j][b][c]).sum::<f64>();
                }
                rhs[a] += w * (0..3).map(|c| basis[j][a][c] * ut[c * n + j]).sum::<f64>();
            }
        }
        let om = solve3(m, rhs);
        let mut res2 = 0.0;
        for j in 0..n {
            let w = g.da[j];
            for c in 0..3 {
                let f = (0..3).map(|a| om[a] * basis[j][a][c]).sum::<f64>();
                res2 += w * (ut[c * n + j] - f).powi(2);
            }
        }
        // Divergence and surface curl (div of n × u_t) of u_t.
        let mut dv = vec![0.0; n];
        calc.divergence(&g, &ut, &mut dv).unwrap();
        let mut nxu = vec![0.0; 3 * n];
        for j in 0..n {
            let nv = g.normal[j];
            let uj = [ut[j], ut[n + j], ut[2 * n + j]];
            nxu[j] = nv[1] * uj[2] - nv[2] * uj[1];
            nxu[n + j] = nv[2] * uj[0] - nv[0] * uj[2];
            nxu[2 * n + j] = nv[0] * uj[1] - nv[1] * uj[0];
        }
        let mut cu = vec![0.0; n];
        calc.divergence(&g, &nxu, &mut cu).unwrap();
        let drms = rms(g.integrate(&dv.iter().map(|x| x * x).collect::<Vec<_>>()));
        let crms = rms(g.integrate(&cu.iter().map(|x| x * x).collect::<Vec<_>>()));
        // Antisymmetric share under each reflection (velocity field as a vector field).
        let mut anti = [0.0; 3];
        let mut santi = [0.0; 3];
        for (r, (perm, sg)) in refl.iter().enumerate() {
            let (mut a2, mut t2, mut sa2, mut st2) = (0.0, 0.0, 0.0, 0.0);
            for j in 0..n {
                let jj = perm[j];
                for c in 0..3 {
                    let d = 0.5 * (ut[c * n + j] - sg[c] * ut[c * n + jj]);
                    a2 += d * d;
                    t2 += ut[c * n + j].powi(2);
                }
                let s = &stepper.state().sigma;
                let d = 0.5 * (s[j] - s[jj]);
                sa2 += d * d;
                st2 += s[j] * s[j];
            }
            anti[r] = (a2 / t2).sqrt();
            santi[r] = (sa2 / st2).sqrt();
        }
        // Degree spectrum of u_t (Cartesian components).
        let mut utc = vec![0.0; 3 * nc];
        sht.forward(&ut, &mut utc, &mut ws).unwrap();
        let mut spec = vec![0.0; p + 1];
        for ch in utc.chunks_exact(nc) {
            for (c, &d) in ch.iter().zip(&degs) {
                spec[d] += c * c;
            }
        }
        let tot: f64 = spec.iter().sum();
        let peak = (0..=p)
            .max_by(|&a, &b| spec[a].partial_cmp(&spec[b]).unwrap())
            .unwrap();
        let hi: f64 = spec
            .iter()
            .enumerate()
            .filter(|(d, _)| 4 * d > 3 * p)
            .map(|(_, s)| s)
            .sum::<f64>()
            / tot;
        let (ax, _) = g.principal_axes();
        // x-asymmetry of the shape about its centroid: (tip⁺ − tip⁻) and ∫(x−c)³dA / A.
        let cc = g.centroid();
        let (mut xmax, mut xmin) = (f64::NEG_INFINITY, f64::INFINITY);
        for xj in &g.x {
            xmax = xmax.max(xj[0] - cc[0]);
            xmin = xmin.min(xj[0] - cc[0]);
        }
        let m3 = g.integrate(
            &g.x.iter()
                .map(|x| (x[0] - cc[0]).powi(3))
                .collect::<Vec<_>>(),
        ) / g.area();
        print!("tips={:+.2e} m3={:+.2e} ", xmax + xmin, m3);
        let sp: Vec<String> = spec.iter().map(|s| format!("{:.0e}", (s / tot))).collect();
        println!(
            "{t:7.2} c=[{:+.2e},{:+.2e},{:+.2e}] {:5.1} {:9.1e} {:6.3} {:8.2e} {:8.2e} {:8.2e} w=[{:+.2e},{:+.2e},{:+.2e}] {:8.2e} {:8.2e} {:8.2e} [{:.2},{:.2},{:.2}] [{:.2},{:.2},{:.2}] {peak} {hi:.1e} [{:.3},{:.3},{:.3}] {:.0}s spec={}",
            g.centroid()[0], g.centroid()[1], g.centroid()[2],
            iters as f64 / every as f64,
            (g.area() - a0) / a0,
            jmax / jmin,
            rms(un2),
            rms(ut2),
            disp,
            om[0], om[1], om[2],
            rms(res2),
            drms,
            crms,
            anti[0], anti[1], anti[2],
            santi[0], santi[1], santi[2],
            ax[0], ax[1], ax[2],
            start.elapsed().as_secs_f64(),
            sp.join(",")
        );
        let _ = v0;
        iters = 0;
    }
    if let Ok(f) = std::env::var("MOBO_SAVE") {
        if save_step == 0 {
            save(&f, t0 + steps as f64 * dt, &coefs, &stepper.state().sigma);
        }
    }
}

fn solve3(m: [[f64; 3]; 3], b: [f64; 3]) -> [f64; 3] {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(m);
    let mut x = [0.0; 3];
    for i in 0..3 {
        let mut mi = m;
        for r in 0..3 {
            mi[r][i] = b[r];
        }
        x[i] = det(mi) / d;
    }
    x
}

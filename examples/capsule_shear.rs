//! A spherical capsule in simple shear `u = (γ̇y, 0, 0)` (γ̇ = μ = a = 1) until its Taylor
//! deformation is steady: `cargo run --release --example capsule_shear -- LAW CA [P] [DT] [T_END]`
//! with `LAW` = `nh` (neo-Hookean) or `sk` (Skalak, `C = 1`), `CA = μγ̇a/E_s` with the surface
//! Young modulus `E_s = 3G_s` (the convention of Ramanujan & Pozrikidis 1998). Prints
//! `t D iterations area/area₀ volume drift` and a final line with the steady `D` (the first time
//! `D` varies by less than `5·10⁻⁴ D` over one time unit) and `D` at `T_END`. BDF2 with the volume restored after each step by default; `MOBO_EULER=1`,
//! `MOBO_NO_DRIFT_CORRECTION=1`, `MOBO_EXPLICIT=1` (explicit elasticity) change that.
use mobo::timestep::semi_implicit::{ElasticStepping, TimeScheme, VesicleParams};
use mobo::timestep::vesicle_stepper::VesicleStepper;
use mobo::timestep::GmresParams;
use mobo::vesicle::geometry::SurfaceCalculus;
use mobo::vesicle::shapes;
use mobo::vesicle::skalak::SkalakParams;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let law = a.first().map_or("nh", |s| s.as_str());
    let ca: f64 = a.get(1).map_or(Ok(0.05), |s| s.parse())?;
    let p: usize = a.get(2).map_or(Ok(12), |s| s.parse())?;
    let dt: f64 = a.get(3).map_or(Ok(0.01), |s| s.parse())?;
    let t_end: f64 = a.get(4).map_or(Ok(6.0), |s| s.parse())?;
    let gs = 1.0 / (3.0 * ca);
    let elastic = match law {
        "nh" => SkalakParams::neo_hookean(gs),
        "sk" => SkalakParams::skalak(gs, 1.0),
        other => return Err(format!("unknown law {other}: nh or sk").into()),
    };
    let sphere = shapes::sphere(p, 1.0)?;
    let params = VesicleParams {
        bending_modulus: 0.0,
        viscosity: 1.0,
        force: [0.0; 3],
        dt,
        upsampled_order: 2 * p,
        gmres: GmresParams {
            tol: 1e-9,
            restart: 100,
            max_iters: 2000,
            ..Default::default()
        },
        correct_drift: std::env::var("MOBO_NO_DRIFT_CORRECTION").is_err(),
        reparametrize: None,
        preconditioner: false,
        scheme: if std::env::var("MOBO_EULER").is_ok() {
            TimeScheme::Euler
        } else {
            TimeScheme::Bdf2
        },
        viscosity_ratio: 1.0,
        inextensible: false,
        elastic_stepping: std::env::var("MOBO_EXPLICIT")
            .is_ok()
            .then_some(ElasticStepping::Explicit),
    };
    let mut st = VesicleStepper::new(p, params)?;
    st.set_skalak(elastic, sphere.coefs())?;
    let mut coefs = sphere.coefs().to_vec();
    let mut calc = SurfaceCalculus::new(p)?;
    let g0 = calc.geometry(&coefs)?;
    let (a0, v0) = (g0.area(), g0.volume());
    let shear = |x: [f64; 3]| [x[1], 0.0, 0.0];
    let steps = (t_end / dt).round() as usize;
    let every = (steps / 30).max(1);
    // D(t) once per 0.05 time units; "steady" once D varies by less than 5·10⁻⁴ D over one
    // time unit (small Ca: the plateau before the equatorial buckling of Lac et al. 2004).
    let mut history: Vec<f64> = Vec::new();
    let sample = ((0.05 / dt).round() as usize).max(1);
    let window = (1.0 / (sample as f64 * dt)).round() as usize;
    let mut steady: Option<(f64, f64)> = None;
    let t0 = std::time::Instant::now();
    let mut iters = 0usize;
    for k in 1..=steps {
        let r = st.step(&mut coefs, &shear)?;
        iters += r.gmres.iterations;
        let g = calc.geometry(&coefs)?;
        let d = g.taylor_deformation([0.0, 0.0, 1.0]);
        let t = k as f64 * dt;
        if k % sample == 0 {
            history.push(d);
            if steady.is_none() && history.len() > window {
                let w = &history[history.len() - window - 1..];
                let (lo, hi) = w
                    .iter()
                    .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
                if hi - lo < 5e-4 * d {
                    steady = Some((t, d));
                }
            }
        }
        if !d.is_finite() || d > 0.95 {
            return Err(format!("unstable at t = {t}: D = {d}").into());
        }
        if k % every == 0 {
            println!(
                "{t:.3} {d:.5} {} {:.5} {:.2e}",
                r.gmres.iterations,
                g.area() / a0,
                (g.volume() - v0) / v0
            );
        }
    }
    let end = history.last().copied().unwrap_or(f64::NAN);
    match steady {
        Some((ts, ds)) => print!("steady D {ds:.5} at t {ts:.2}, "),
        None => print!("not steady, "),
    }
    // Inclination of the longest axis in the shear plane (x towards the gradient y), degrees.
    let (semi, axes) = calc.geometry(&coefs)?.equivalent_ellipsoid();
    let long = (0..3)
        .filter(|&k| axes[k][2].abs() < 0.7)
        .max_by(|&i, &j| semi[i].total_cmp(&semi[j]))
        .unwrap_or(0);
    let theta = mobo::linalg3::axis_inclination_deg(axes[long], 0, 1);
    println!(
        "D(t_end) {end:.5}, inclination {theta:.1} deg ({law}, Ca {ca}, p {p}, dt {dt}; {:.1} \
         iterations per step, {:.1} s)",
        iters as f64 / steps as f64,
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

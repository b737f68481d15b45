//! One cell in shear, run from one scene file by either solver, with the observables of a
//! side-by-side comparison sampled over time (docs/dpd_vs_bie.md):
//!
//! ```text
//! cargo run --release --example shear_both_ways -- SCENE.toml bie|dpd [EVERY] [SETTLE]
//! ```
//!
//! * `bie`: the scene's `[[cells]]` as `mobo run` steps them (`scene::Simulation`), unbounded
//!   shear `u = (γ̇y, 0, 0)`; vorticity axis `−z`.
//! * `dpd`: the scene's `[dpd]` fluid with the same `[[cells]]` mapped by `[dpd.from_cells]`
//!   (`run::dpd::build_suspension`), Couette flow between walls normal to `z`; vorticity
//!   axis `+y`. The shear rate is fitted to the fluid's velocities in the middle 70 % of the
//!   channel at every sample.
//!
//! Every `EVERY` steps (default 25 for `bie`, 100 for `dpd`) it prints
//! `t strain D inclination tank_treading_rate/γ̇ γ̇ |n·ω̂|` of cell 0: the Taylor deformation
//! and the inclination (degrees, from the flow direction towards the gradient) of the equivalent
//! ellipsoid in the shear plane, and the membrane's mean phase rate about the vorticity axis
//! (`mobo::vesicle::tank_treading`; the boundary-integral cell from its membrane velocity, the DPD cell
//! from its vertices' phase advance since the last sample), and the cosine of the angle
//! between the vorticity and the shortest axis of the equivalent ellipsoid (a disk's normal:
//! 1 with the disk in the shear plane, 0 with its axis in it). The last line averages them over
//! the samples after the strain `SETTLE` (default 5), with the standard error of 10 blocks
//! (the tank-treading rate as the ratio of its mean to the shear rate's mean),
//! the inclination's range (a swinging cell oscillates), the drifts, and the CPU cost per unit
//! of strain. `RAYON_NUM_THREADS` sets the threads.
use std::path::Path;

use mobo::run::simulation::Simulation;
use mobo::scene::cells::{self, Flow};
use mobo::{run, scene::dpd};

/// One sample: time, strain, D, inclination (degrees), tank-treading rate, shear rate, and
/// `|n·ω̂|`, `n` the shortest axis of the equivalent ellipsoid (a disk's normal).
type Sample = [f64; 7];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let (Some(file), Some(model)) = (a.first(), a.get(1)) else {
        return Err("usage: shear_both_ways SCENE.toml bie|dpd [EVERY] [SETTLE]".into());
    };
    let every: Option<usize> = a.get(2).map(|s| s.parse()).transpose()?;
    let settle: f64 = a.get(3).map_or(Ok(5.0), |s| s.parse())?;
    let file = Path::new(file);
    let t0 = cpu_seconds();
    let (samples, extra) = match model.as_str() {
        "bie" => bie(file, every.unwrap_or(25))?,
        "dpd" => run_dpd(file, every.unwrap_or(100))?,
        other => return Err(format!("unknown model {other}: bie or dpd").into()),
    };
    let cpu = cpu_seconds() - t0;
    let after: Vec<&Sample> = samples.iter().filter(|s| s[1] >= settle).collect();
    let strain = samples.last().map_or(0.0, |s| s[1]);
    let col = |k: usize| after.iter().map(|s| s[k]).collect::<Vec<_>>();
    let (incl_lo, incl_hi) = col(3)
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    let (n_lo, n_hi) = col(6)
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    println!(
        "{model}: D = {:.4} ± {:.4}, inclination {:.1} ± {:.1} deg (range {incl_lo:.1} to \
         {incl_hi:.1}), tank-treading rate / shear rate = {:.4} ± {:.4}, |n·ω̂| = {:.3} (range \
         {n_lo:.3} to {n_hi:.3}) ({} samples after strain {settle}, to strain {strain:.1}); \
         {extra}; {cpu:.0} CPU s, {:.1} CPU s per unit strain",
        mean(&col(2)),
        stderr(&col(2)),
        mean(&col(3)),
        stderr(&col(3)),
        mean(&col(4)) / mean(&col(5)),
        stderr(&col(4)) / mean(&col(5)),
        mean(&col(6)),
        after.len(),
        cpu / strain
    );
    Ok(())
}

/// The boundary-integral run: `mobo run`'s cells, stepped to the scene's `t_end`.
fn bie(file: &Path, every: usize) -> Result<(Vec<Sample>, String), Box<dyn std::error::Error>> {
    let scene = cells::load(file)?;
    let rate = match scene.flow {
        Flow::Shear { rate } => rate,
        _ => return Err(format!("{}: [flow] must be shear", file.display()).into()),
    };
    let t_end = scene.numerics.t_end;
    let mut sim = Simulation::new(scene)?;
    let first = sim.cell(0)?.geometry;
    let (a0, v0) = (first.area(), first.volume());
    let mut out = Vec::new();
    let mut iters = 0usize;
    while sim.time() < t_end - 1e-9 {
        let r = sim.step()?;
        iters += r.cells.iter().map(|c| c.gmres.iterations).sum::<usize>();
        if sim.steps() % every == 0 {
            let c = sim.cell(0)?;
            let g = &c.geometry;
            let (semi, axes) = g.equivalent_ellipsoid();
            let (l, b, ax) = mobo::linalg3::shear_plane_semi_axes(semi, axes, [0.0, 0.0, 1.0]);
            let tt = c
                .membrane_velocity
                .as_ref()
                .map(|u| g.tank_treading_rate(u.as_component_major(), [0.0, 0.0, -rate.signum()]))
                .transpose()?
                .unwrap_or(f64::NAN);
            let s = [
                sim.time(),
                rate.abs() * sim.time(),
                (l - b) / (l + b),
                mobo::linalg3::axis_inclination_deg(ax, 0, 1),
                tt,
                rate.abs(),
                axes[2][2].abs(),
            ];
            print_sample(&s);
            out.push(s);
        }
    }
    let g = sim.cell(0)?.geometry;
    Ok((
        out,
        format!(
            "{:.1} GMRES iterations per step, area drift {:.1e}, volume drift {:.1e}",
            iters as f64 / sim.steps().max(1) as f64,
            g.area() / a0 - 1.0,
            g.volume() / v0 - 1.0
        ),
    ))
}

/// The DPD run: the scene's fluid and its mapped cells, stepped the scene's steps.
fn run_dpd(file: &Path, every: usize) -> Result<(Vec<Sample>, String), Box<dyn std::error::Error>> {
    let scene = dpd::load(file)?;
    let Some(mobo::dpd::walls::Wall::Planes { lo, hi }) = scene.wall else {
        return Err(format!("{}: [dpd] needs plane walls (Couette flow)", file.display()).into());
    };
    if scene.cells.is_empty() {
        return Err(format!("{}: [dpd] has no cells", file.display()).into());
    }
    let mut sim = run::dpd::build_suspension(&scene)?;
    let (mid, half) = (0.5 * (lo + hi), 0.35 * (hi - lo));
    let mut before = sim.cells()[0].positions().to_vec();
    let (mut t_before, mut strain) = (sim.fluid.time(), 0.0);
    let mut out = Vec::new();
    for s in 1..=scene.steps {
        sim.step()?;
        if s % every as u64 != 0 {
            continue;
        }
        // Shear rate: least squares of v_x(z) over the moving particles in the middle 70 %.
        let p = &sim.fluid.particles;
        let (mut szz, mut szv, mut sz, mut sv, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..p.len() {
            let z = p.z[i] - mid;
            if p.moves[i] == 0.0 || z.abs() > half {
                continue;
            }
            szz += z * z;
            szv += z * p.vx[i];
            sz += z;
            sv += p.vx[i];
            n += 1.0;
        }
        let rate = (szv - sz * sv / n) / (szz - sz * sz / n);
        let t = sim.fluid.time();
        let dt = t - t_before;
        strain += rate * dt;
        let cell = &sim.cells()[0];
        let (d, incl) = cell.shear_plane_deformation();
        let tt = cell.phase_advance(&before, [0.0, 1.0, 0.0])? / dt;
        let normal = cell.equivalent_ellipsoid().1[2];
        let sample = [t, strain, d, incl, tt, rate, normal[1].abs()];
        print_sample(&sample);
        out.push(sample);
        before.clear();
        before.extend_from_slice(cell.positions());
        t_before = t;
    }
    let (da, dv) = sim.cells()[0].area_volume_change()?;
    Ok((
        out,
        format!(
            "mean shear rate {:.4} (2U/gap {:.4}), area {da:+.4}, volume {dv:+.4}, solvent \
             leaked {}",
            strain / (sim.fluid.time()).max(f64::MIN_POSITIVE),
            2.0 * scene.wall_speed / (hi - lo),
            sim.max_leaked()
        ),
    ))
}

fn print_sample(s: &Sample) {
    println!(
        "{:.3} {:.3} {:.5} {:.2} {:.5} {:.5} {:.3}",
        s[0],
        s[1],
        s[2],
        s[3],
        s[4] / s[5],
        s[5],
        s[6]
    );
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Standard error of the mean of 10 consecutive blocks.
fn stderr(v: &[f64]) -> f64 {
    let per = (v.len() / 10).max(1);
    let b: Vec<f64> = v.chunks(per).take(10).map(mean).collect();
    if b.len() < 2 {
        return f64::NAN;
    }
    let m = mean(&b);
    (b.iter().map(|x| (x - m).powi(2)).sum::<f64>() / ((b.len() - 1) * b.len()) as f64).sqrt()
}

/// CPU seconds of this process (all threads).
fn cpu_seconds() -> f64 {
    std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            let f: Vec<&str> = s.rsplit(')').next()?.split_whitespace().collect();
            let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
            Some(ticks / 100.0)
        })
        .unwrap_or(f64::NAN)
}

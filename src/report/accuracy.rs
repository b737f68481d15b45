//! The accuracy-versus-time study (`mobo report accuracy`).
//!
//! **What is measured.** A cell scene (by default [`super::STUDY_SCENE`], two red blood cells
//! in shear) is run to a fixed final time `T` once at a high-accuracy *reference* setting, and
//! then once per value of each knob with every other knob held at the reference:
//!
//! * `order` — SH order `p` (the grid has `2p(p+1)` points per cell);
//! * `upsample` — quadrature order `q = upsample · p` of the singular and coupling quadrature;
//! * `fmm_digits` — FMM accuracy of the inter-cell velocity;
//! * `gmres_tol` — relative residual of each step's Krylov solve;
//! * `dt` — time step (`T/dt` steps), per scheme (Euler and BDF2; the reference is BDF2);
//! * `coupling` — with several cells, the other coupling mode than the scene's (`explicit`: last
//!   step's densities; `near_implicit`: near cells in one solve), shown as 0 and 1;
//! * `contact distance` — with several cells, the contact projection's `d_min` at 0.02, 0.05
//!   and 0.1 (the reference keeps the scene's: `[numerics] contact_distance`, or its default
//!   `0.4 R_min/p`, [`crate::scene::dense_defaults`]).
//!
//! Each run is compared with the reference at `T`:
//!
//! * **shape error**: both runs' SH coefficients are resampled to the higher of the two orders
//!   and evaluated at the same grid points (same parameter points); the largest distance
//!   between corresponding points, over all points and cells, divided by the cell's
//!   equivalent radius;
//! * **surface distance**: the Hausdorff distance between the two final surfaces (largest
//!   distance of a grid point of either to the other surface, exact closest points), over the
//!   radius. Unlike the shape error it does not see tangential motion of the grid points
//!   (reparametrisation acts once per step, so it differs between dt values). The plot and the
//!   Pareto front use this measure;
//! * **velocity error**: centroid velocity over the last step, `|v − v_ref| / |v_ref|`, largest
//!   over the cells;
//! * **tension error**: the tension resampled the same way, `max |σ − σ_ref| / max |σ_ref|`;
//! * **coupling error**: the velocity the other cells induce on each cell in the *first* step
//!   (FMM plus near-singular corrections), `max |u − u_ref| / max |u_ref|`; only where the run
//!   has the reference's grid (same `p`), since it is compared point by point.
//!
//! **Cost** is the wall time of the steps alone (`Suspension::step`), the mean over the steps
//! after the first (the first carries one-time set-up: the FMM operator tables of a digits
//! setting are computed once per process), measured in the same process, one run after the
//! other, with the machine's rayon threads.
//!
//! **Budget.** Two probe steps at each candidate reference level (cheapest first, a level
//! is tried only while the previous probe predicts it fits) estimate the reference's cost; the
//! highest level whose reference fits a twelfth of the budget is taken.
//! Knob values are then run cheapest-first, round-robin over the knobs, each only if its
//! estimated cost (the reference's, scaled by `((p·upsample)/(p_ref·upsample_ref))³` and the
//! number of steps) fits in what is left; values left out are listed as skipped. A run that
//! fails (solver error, non-finite values) is recorded with its message, not hidden.

use std::path::Path;
use std::time::Instant;

pub use super::study::{Knob, RunRow, Settings, Study};
pub use super::tables::{to_csv, to_markdown, write_report};
use super::ReportError;
use crate::run::{assembly::build, CellRunError};
use crate::scene::cells::{self, CellScene, Scheme};
use crate::sph_harmonics::layout::CoefLayout;
use crate::sph_harmonics::{resample_coefs, ShTransform};
use crate::timestep::near_implicit::CouplingMode;
use crate::vesicle::geometry::SurfaceCalculus;
use crate::vesicle::{NearParams, OffSurface};

/// Options of the study.
#[derive(Clone, Debug)]
pub struct StudyOptions {
    /// Wall-time budget in seconds for all runs together.
    pub budget_s: f64,
    /// Final time `T` at which the runs are compared.
    pub t_end: f64,
    /// Progress lines on stderr.
    pub progress: bool,
    /// Candidate reference levels `(order, upsample, steps to T)`, cheapest first.
    pub levels: Vec<(usize, usize, usize)>,
}

impl Default for StudyOptions {
    fn default() -> Self {
        Self {
            budget_s: 600.0,
            t_end: 1.0,
            progress: true,
            levels: REFERENCE_LEVELS.to_vec(),
        }
    }
}

/// The default candidate references: order, upsampling and number of steps to `T` (the FMM digits and
/// GMRES tolerance of the reference are always the tightest).
pub const REFERENCE_LEVELS: [(usize, usize, usize); 4] =
    [(8, 2, 16), (8, 3, 32), (10, 3, 32), (12, 3, 32)];
/// The reference must fit this fraction of the budget (about a dozen runs cost as much).
const REFERENCE_SHARE: f64 = 1.0 / 12.0;
const REFERENCE_FMM_DIGITS: u32 = 10;
const REFERENCE_GMRES_TOL: f64 = 1e-12;

/// What one run left at the final time.
struct Final {
    order: usize,
    coefs: Vec<Vec<f64>>,
    sigma: Vec<Vec<f64>>,
    velocity: Vec<[f64; 3]>,
    coupling: Option<Vec<Vec<f64>>>,
    steps: usize,
    step_s: f64,
    gmres_mean: f64,
    wall_s: f64,
}

fn run_error(label: &str, e: CellRunError) -> ReportError {
    ReportError::Run {
        run: label.to_string(),
        source: Box::new(e),
    }
}

/// Run `scene` with `settings` to `t_end` (or only `max_steps` steps), timing the steps.
fn simulate(
    scene: &CellScene,
    settings: &Settings,
    t_end: f64,
    max_steps: Option<usize>,
    label: &str,
) -> Result<Final, ReportError> {
    let start = Instant::now();
    let mut sc = scene.clone();
    settings.apply(&mut sc, t_end);
    let mut susp = build(&sc).map_err(|e| run_error(label, e))?;
    let steps = (t_end / settings.dt).round().max(1.0) as usize;
    let steps = max_steps.map_or(steps, |m| m.min(steps));
    let mut calc = SurfaceCalculus::new(settings.order)
        .map_err(|e| run_error(label, CellRunError::from(e)))?;
    let flow = sc.flow;
    let mut times = Vec::with_capacity(steps);
    let mut iters = 0usize;
    let mut coupling = None;
    susp.record_coupling(susp.len() > 1);
    let mut before: Vec<[f64; 3]> = Vec::new();
    for k in 1..=steps {
        if k == steps {
            before.clear();
            for cell in susp.cells() {
                let g = calc
                    .geometry(&cell.state.coefs)
                    .map_err(|e| run_error(label, CellRunError::from(e)))?;
                before.push(g.centroid());
            }
        }
        let t = Instant::now();
        let report = susp.step(&|x| flow.velocity(x)).map_err(|e| {
            run_error(
                label,
                CellRunError::Step {
                    step: k,
                    time: k as f64 * settings.dt,
                    cell: e.cell,
                    source: Box::new(e.source),
                },
            )
        })?;
        times.push(t.elapsed().as_secs_f64());
        iters += report
            .cells
            .iter()
            .map(|r| r.gmres.iterations)
            .sum::<usize>();
        for (i, cell) in susp.cells().iter().enumerate() {
            if cell.state.coefs.iter().any(|v| !v.is_finite()) {
                return Err(ReportError::NonFinite {
                    run: label.to_string(),
                    step: k,
                    cell: i,
                    quantity: "SH coefficient",
                });
            }
        }
        for (i, cell) in susp.cells().iter().enumerate() {
            if cell.state.sigma.iter().any(|v| !v.is_finite()) {
                return Err(ReportError::NonFinite {
                    run: label.to_string(),
                    step: k,
                    cell: i,
                    quantity: "tension",
                });
            }
        }
        if k == 1 && susp.len() > 1 {
            // As computed at the start of the step, before the reparametrisation relabelled
            // the cells' copies onto a grid that depends on the step taken.
            coupling = susp.recorded_coupling().map(<[Vec<f64>]>::to_vec);
            susp.record_coupling(false);
        }
    }
    let mut velocity = Vec::with_capacity(susp.len());
    for (i, cell) in susp.cells().iter().enumerate() {
        let g = calc
            .geometry(&cell.state.coefs)
            .map_err(|e| run_error(label, CellRunError::from(e)))?;
        let x = g.centroid();
        velocity.push(std::array::from_fn(|d| (x[d] - before[i][d]) / settings.dt));
    }
    Ok(Final {
        order: settings.order,
        coefs: susp.cells().iter().map(|c| c.state.coefs.clone()).collect(),
        sigma: susp.cells().iter().map(|c| c.state.sigma.clone()).collect(),
        velocity,
        coupling,
        steps,
        // The first step carries one-time set-up (FMM operator tables, cached per process):
        // left out of the mean when there are more steps.
        step_s: if times.len() > 1 {
            times[1..].iter().sum::<f64>() / (times.len() - 1) as f64
        } else {
            times[0]
        },
        gmres_mean: iters as f64 / (steps * susp.len()).max(1) as f64,
        wall_s: start.elapsed().as_secs_f64(),
    })
}

/// Grid values at order `to` of `nf` functions given by coefficients at order `from`.
fn values_at(coefs: &[f64], from: usize, to: usize) -> Result<Vec<f64>, ReportError> {
    let sph = |e: crate::sph_harmonics::SphError| ReportError::Invalid(format!("resampling: {e}"));
    let (lf, lt) = (CoefLayout::new(from), CoefLayout::new(to));
    let nf = coefs.len() / lf.len();
    let mut up = vec![0.0; nf * lt.len()];
    resample_coefs(&lf, &lt, coefs, &mut up).map_err(sph)?;
    let sht = ShTransform::new(to).map_err(sph)?;
    let mut ws = sht.workspace();
    let mut grid = vec![0.0; nf * sht.n_points()];
    sht.inverse(&up, &mut grid, &mut ws).map_err(sph)?;
    Ok(grid)
}

/// Coefficients at order `p` of grid values at order `p`.
fn coefs_of(grid: &[f64], p: usize) -> Result<Vec<f64>, ReportError> {
    let sph = |e: crate::sph_harmonics::SphError| ReportError::Invalid(format!("transform: {e}"));
    let sht = ShTransform::new(p).map_err(sph)?;
    let mut ws = sht.workspace();
    let nf = grid.len() / sht.n_points();
    let mut c = vec![0.0; nf * sht.n_coefs()];
    sht.forward(grid, &mut c, &mut ws).map_err(sph)?;
    Ok(c)
}

/// Shape, velocity, tension and coupling errors of `run` against `reference`.
fn compare(run: &Final, reference: &Final, radii: &[f64]) -> Result<Errors, ReportError> {
    let r = run.order.max(reference.order);
    let mut shape: f64 = 0.0;
    let mut surface: f64 = 0.0;
    let mut tension: f64 = 0.0;
    let mut velocity: f64 = 0.0;
    for (i, &radius) in radii.iter().enumerate().take(run.coefs.len()) {
        let a = values_at(&run.coefs[i], run.order, r)?;
        let b = values_at(&reference.coefs[i], reference.order, r)?;
        let np = a.len() / 3;
        for j in 0..np {
            let d2: f64 = (0..3)
                .map(|c| (a[c * np + j] - b[c * np + j]).powi(2))
                .sum();
            shape = shape.max(d2.sqrt() / radius);
        }
        surface = surface.max(surface_distance(run, reference, i, r)? / radius);
        let sa = values_at(&coefs_of(&run.sigma[i], run.order)?, run.order, r)?;
        let sb = values_at(
            &coefs_of(&reference.sigma[i], reference.order)?,
            reference.order,
            r,
        )?;
        let diff = sa
            .iter()
            .zip(&sb)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        let scale = sb.iter().map(|x| x.abs()).fold(0.0, f64::max);
        tension = tension.max(diff / scale);
        let (v, w) = (run.velocity[i], reference.velocity[i]);
        let dv: f64 = (0..3).map(|d| (v[d] - w[d]).powi(2)).sum::<f64>().sqrt();
        let nw: f64 = w.iter().map(|x| x * x).sum::<f64>().sqrt();
        velocity = velocity.max(dv / nw);
    }
    let coupling = match (&run.coupling, &reference.coupling) {
        (Some(a), Some(b)) if run.order == reference.order => {
            let mut diff: f64 = 0.0;
            let mut scale: f64 = 0.0;
            for (u, w) in a.iter().zip(b) {
                for (x, y) in u.iter().zip(w) {
                    diff = diff.max((x - y).abs());
                    scale = scale.max(y.abs());
                }
            }
            Some(diff / scale)
        }
        _ => None,
    };
    Ok(Errors {
        shape,
        surface,
        velocity,
        tension,
        coupling,
    })
}

/// Errors of one run against the reference (see the module docs).
struct Errors {
    shape: f64,
    surface: f64,
    velocity: f64,
    tension: f64,
    coupling: Option<f64>,
}

/// Symmetric (Hausdorff) distance between cell `i`'s final surfaces in `a` and `b`, both at
/// order `r`: the largest distance of a grid point of one to the other surface (exact closest
/// point within the near zone, `OffSurface::classify`), either way round. Independent of how
/// the points are parametrised.
fn surface_distance(a: &Final, b: &Final, i: usize, r: usize) -> Result<f64, ReportError> {
    let vesicle =
        |e: crate::vesicle::VesicleError| ReportError::Invalid(format!("surface distance: {e}"));
    let up = |f: &Final| -> Result<Vec<f64>, ReportError> {
        let (lf, lt) = (CoefLayout::new(f.order), CoefLayout::new(r));
        let mut c = vec![0.0; 3 * lt.len()];
        resample_coefs(&lf, &lt, &f.coefs[i], &mut c)
            .map_err(|e| ReportError::Invalid(format!("resampling: {e}")))?;
        Ok(c)
    };
    let (ca, cb) = (up(a)?, up(b)?);
    let mut calc = SurfaceCalculus::new(r).map_err(vesicle)?;
    let mut near = OffSurface::new(r, NearParams::default()).map_err(vesicle)?;
    let mut d: f64 = 0.0;
    for (from, to) in [(&ca, &cb), (&cb, &ca)] {
        near.set_surface(to).map_err(vesicle)?;
        let g = calc.geometry(from).map_err(vesicle)?;
        for x in &g.x {
            d = d.max(near.classify(*x).map_err(vesicle)?.distance);
        }
    }
    Ok(d)
}

/// The values each knob takes (cheapest first) for a reference.
fn knob_values(knob: Knob, reference: &Settings, t_end: f64) -> Vec<f64> {
    match knob {
        Knob::Order => [4usize, 6, 8, 10]
            .into_iter()
            .filter(|&p| p < reference.order)
            .map(|p| p as f64)
            .collect(),
        Knob::Upsample => (1..reference.upsample).map(|u| u as f64).collect(),
        Knob::FmmDigits => [3u32, 4, 6, 8]
            .into_iter()
            .filter(|&d| d < reference.fmm_digits)
            .map(f64::from)
            .collect(),
        Knob::GmresTol => vec![1e-2, 1e-4, 1e-6, 1e-8],
        Knob::DtEuler | Knob::DtBdf2 => {
            let n_ref = (t_end / reference.dt).round() as usize;
            let mut v: Vec<f64> = [4usize, 8, 16]
                .into_iter()
                .filter(|&n| n < n_ref)
                .map(|n| t_end / n as f64)
                .collect();
            // The reference's own dt with the other scheme (with its own scheme it would be the
            // reference again).
            let scheme = if knob == Knob::DtBdf2 {
                Scheme::Bdf2
            } else {
                Scheme::Euler
            };
            if scheme != reference.scheme {
                v.push(reference.dt);
            }
            v
        }
        Knob::Coupling => vec![match reference.coupling {
            CouplingMode::Explicit => 1.0,
            CouplingMode::NearImplicit => 0.0,
        }],
        Knob::ContactDistance => [0.02, 0.05, 0.1]
            .into_iter()
            .filter(|&d| Some(d) != reference.contact_distance)
            .collect(),
    }
}

fn with_knob(reference: &Settings, knob: Knob, value: f64) -> Settings {
    let mut s = *reference;
    match knob {
        Knob::Order => s.order = value as usize,
        Knob::Upsample => s.upsample = value as usize,
        Knob::FmmDigits => s.fmm_digits = value as u32,
        Knob::GmresTol => s.gmres_tol = value,
        Knob::DtEuler => {
            s.dt = value;
            s.scheme = Scheme::Euler;
        }
        Knob::DtBdf2 => {
            s.dt = value;
            s.scheme = Scheme::Bdf2;
        }
        Knob::Coupling => {
            s.coupling = if value == 1.0 {
                CouplingMode::NearImplicit
            } else {
                CouplingMode::Explicit
            }
        }
        Knob::ContactDistance => s.contact_distance = Some(value),
    }
    s
}

/// Mark the Pareto front of (time per step, surface distance) among the successful rows: a row is
/// on it when no other row is both faster and more accurate (ties count as not dominated).
fn mark_pareto(rows: &mut [RunRow]) {
    let pts: Vec<(f64, f64)> = rows.iter().map(|r| (r.step_s, r.surface_error)).collect();
    for (i, r) in rows.iter_mut().enumerate() {
        let (t, e) = pts[i];
        r.pareto = r.failure.is_none()
            && e.is_finite()
            && !pts.iter().enumerate().any(|(j, &(tj, ej))| {
                j != i && ej.is_finite() && tj <= t && ej <= e && (tj < t || ej < e)
            });
    }
}

fn say(progress: bool, msg: impl AsRef<str>) {
    if progress {
        eprintln!("[report] {}", msg.as_ref());
    }
}

/// Run the study on `scene` (named `scene_name` in the report).
pub fn run_study(
    scene: &CellScene,
    scene_name: &str,
    opts: &StudyOptions,
) -> Result<Study, ReportError> {
    if scene.cells.is_empty() {
        return Err(ReportError::Invalid(format!(
            "{scene_name}: the study needs at least one cell"
        )));
    }
    if opts.levels.is_empty() || opts.levels.iter().any(|l| l.0 < 2 || l.1 < 1 || l.2 < 1) {
        return Err(ReportError::Invalid(format!(
            "reference levels {:?}: need at least one, each with order ≥ 2, upsample ≥ 1, steps ≥ 1",
            opts.levels
        )));
    }
    if !(opts.budget_s > 0.0 && opts.t_end > 0.0) {
        return Err(ReportError::Invalid(format!(
            "budget ({} s) and final time ({}) must be positive",
            opts.budget_s, opts.t_end
        )));
    }
    let start = Instant::now();
    let left = |start: &Instant| opts.budget_s - start.elapsed().as_secs_f64();
    let radii: Vec<f64> = scene.cells.iter().map(|c| c.radius).collect();
    let mut notes = Vec::new();

    let ref_scheme = Scheme::Bdf2;

    // Reference level: probe levels from the cheapest up, while the next is predicted to fit.
    let mut chosen = None;
    let mut last: Option<(f64, f64)> = None;
    for &(p, up, n) in opts.levels.iter() {
        let size = (p * up) as f64;
        if let Some((step_s, prev)) = last {
            let predicted = step_s * (size / prev).powi(3) * n as f64;
            if predicted > left(&start) * REFERENCE_SHARE {
                say(
                    opts.progress,
                    format!(
                        "reference p = {p}, upsample = {up} predicted {predicted:.0} s: not tried"
                    ),
                );
                break;
            }
        }
        let s = Settings {
            order: p,
            upsample: up,
            fmm_digits: REFERENCE_FMM_DIGITS,
            gmres_tol: REFERENCE_GMRES_TOL,
            dt: opts.t_end / n as f64,
            scheme: ref_scheme,
            coupling: scene.numerics.coupling,
            contact_distance: scene.numerics.contact_distance,
        };
        let label = format!("probe p = {p}, upsample = {up}");
        let probe = simulate(scene, &s, opts.t_end, Some(2), &label)?;
        let est = probe.step_s * n as f64;
        say(
            opts.progress,
            format!(
                "probe: p = {p}, upsample = {up}: {:.2} s per step, reference about {est:.0} s",
                probe.step_s
            ),
        );
        if est > left(&start) * REFERENCE_SHARE && chosen.is_some() {
            break;
        }
        chosen = Some(s);
        last = Some((probe.step_s, size));
    }
    if let Some(s) = chosen {
        let top = opts.levels.last().map(|l| (l.0, l.1));
        if Some((s.order, s.upsample)) != top {
            notes.push(format!(
                "Reference level p = {}, upsample = {} chosen so that it takes at most 1/12 of \
                 the budget of {:.0} s (higher levels were predicted or probed above that).",
                s.order, s.upsample, opts.budget_s
            ));
        }
    }
    let reference_settings = chosen.expect("a level is always chosen");
    say(
        opts.progress,
        format!("reference: {}", reference_settings.describe()),
    );
    let reference = simulate(scene, &reference_settings, opts.t_end, None, "reference")?;
    say(
        opts.progress,
        format!(
            "reference done: {} steps, {:.3} s per step, {:.1} s",
            reference.steps, reference.step_s, reference.wall_s
        ),
    );
    let ref_row = RunRow {
        knob: None,
        value: f64::NAN,
        settings: reference_settings,
        steps: reference.steps,
        step_s: reference.step_s,
        gmres_mean: reference.gmres_mean,
        shape_error: 0.0,
        surface_error: 0.0,
        velocity_error: 0.0,
        tension_error: 0.0,
        coupling_error: None,
        pareto: false,
        failure: None,
    };

    // The plan: cheapest value of every knob first, round-robin.
    let mut knobs = vec![Knob::Order, Knob::Upsample];
    if scene.cells.len() > 1 {
        knobs.push(Knob::FmmDigits);
    } else {
        notes.push(
            "One cell: no FMM is built and nothing is coupled or in contact; the fmm digits, \
             coupling and contact distance knobs are left out."
                .into(),
        );
    }
    knobs.push(Knob::GmresTol);
    knobs.push(Knob::DtEuler);
    knobs.push(Knob::DtBdf2);
    if scene.cells.len() > 1 {
        knobs.push(Knob::Coupling);
        knobs.push(Knob::ContactDistance);
    }
    let lists: Vec<Vec<f64>> = knobs
        .iter()
        .map(|&k| knob_values(k, &reference_settings, opts.t_end))
        .collect();
    let mut plan = Vec::new();
    let longest = lists.iter().map(Vec::len).max().unwrap_or(0);
    for i in 0..longest {
        for (k, l) in knobs.iter().zip(&lists) {
            if let Some(&v) = l.get(i) {
                plan.push((*k, v));
            }
        }
    }
    let cost = |s: &Settings| {
        let size = (s.order * s.upsample) as f64
            / (reference_settings.order * reference_settings.upsample) as f64;
        let steps = (opts.t_end / s.dt).round().max(1.0);
        reference.step_s * size.powi(3) * steps
            + (reference.wall_s - reference.step_s * reference.steps as f64)
    };
    let mut rows = Vec::new();
    let mut skipped = Vec::new();
    let total = plan.len();
    for (n, (knob, value)) in plan.into_iter().enumerate() {
        let s = with_knob(&reference_settings, knob, value);
        let est = cost(&s);
        let label = format!("{} = {value}", knob.name());
        if est > left(&start) {
            say(
                opts.progress,
                format!(
                    "[{}/{total}] skip {label}: estimated {est:.0} s, {:.0} s left",
                    n + 1,
                    left(&start)
                ),
            );
            skipped.push((knob, value, format!("budget (estimated {est:.0} s)")));
            continue;
        }
        say(
            opts.progress,
            format!("[{}/{total}] {label} (estimated {est:.0} s)", n + 1),
        );
        let row = match simulate(scene, &s, opts.t_end, None, &label) {
            Ok(f) => {
                let er = compare(&f, &reference, &radii)?;
                say(
                    opts.progress,
                    format!(
                        "    {:.3} s/step, shape error {:.2e} (surface distance {:.2e}), velocity {:.2e}, tension {:.2e}",
                        f.step_s, er.shape, er.surface, er.velocity, er.tension
                    ),
                );
                RunRow {
                    knob: Some(knob),
                    value,
                    settings: s,
                    steps: f.steps,
                    step_s: f.step_s,
                    gmres_mean: f.gmres_mean,
                    shape_error: er.shape,
                    surface_error: er.surface,
                    velocity_error: er.velocity,
                    tension_error: er.tension,
                    coupling_error: er.coupling,
                    pareto: false,
                    failure: None,
                }
            }
            Err(e) => {
                say(opts.progress, format!("    failed: {e}"));
                RunRow {
                    knob: Some(knob),
                    value,
                    settings: s,
                    steps: 0,
                    step_s: f64::NAN,
                    gmres_mean: f64::NAN,
                    shape_error: f64::NAN,
                    surface_error: f64::NAN,
                    velocity_error: f64::NAN,
                    tension_error: f64::NAN,
                    coupling_error: None,
                    pareto: false,
                    failure: Some(e.to_string()),
                }
            }
        };
        rows.push(row);
    }
    // Keep the table ordered by knob, then value.
    rows.sort_by(|a, b| {
        let ka = knobs.iter().position(|k| Some(*k) == a.knob);
        let kb = knobs.iter().position(|k| Some(*k) == b.knob);
        ka.cmp(&kb).then(a.step_s.total_cmp(&b.step_s))
    });
    mark_pareto(&mut rows);
    Ok(Study {
        scene_name: scene_name.to_string(),
        cells: scene.cells.len(),
        t_end: opts.t_end,
        reference: ref_row,
        rows,
        skipped,
        notes,
        budget_s: opts.budget_s,
        wall_s: start.elapsed().as_secs_f64(),
        threads: rayon::current_num_threads(),
    })
}

/// The built-in study scene, parsed.
pub fn study_scene() -> Result<CellScene, ReportError> {
    Ok(cells::parse(
        Path::new("<built-in study scene>"),
        super::STUDY_SCENE,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The coupling knob tries the other mode, the contact knob three distances other than the
    /// reference's, and the settings reach the scene a run is built from.
    #[test]
    fn coupling_and_contact_knobs_set_what_the_run_uses() {
        let reference = Settings {
            order: 8,
            upsample: 2,
            fmm_digits: 8,
            gmres_tol: 1e-10,
            dt: 0.01,
            scheme: Scheme::Bdf2,
            coupling: CouplingMode::Explicit,
            contact_distance: Some(0.05),
        };
        assert_eq!(knob_values(Knob::Coupling, &reference, 0.1), vec![1.0]);
        assert_eq!(
            knob_values(Knob::ContactDistance, &reference, 0.1),
            vec![0.02, 0.1]
        );
        let s = with_knob(&reference, Knob::Coupling, 1.0);
        assert_eq!(s.coupling, CouplingMode::NearImplicit);
        let back = Settings {
            coupling: CouplingMode::NearImplicit,
            ..reference
        };
        assert_eq!(knob_values(Knob::Coupling, &back, 0.1), vec![0.0]);
        let s = with_knob(&reference, Knob::ContactDistance, 0.1);
        assert_eq!(s.contact_distance, Some(0.1));
        let mut scene = study_scene().unwrap();
        s.apply(&mut scene, 0.3);
        assert_eq!(scene.numerics.contact_distance, Some(0.1));
        assert_eq!(scene.numerics.coupling, CouplingMode::Explicit);
        assert!(s.describe().contains("contact_distance = 0.1"));
    }
}

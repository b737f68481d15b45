//! One accepted step of a suspension, shared by `mobo run` ([`super::cells`]) and the
//! library's [`super::simulation::Simulation`]: with a fixed `dt` the step is taken once; with
//! an adaptive `dt` ([`AdaptiveDt`]) a step whose area/volume error is too large, or whose solve
//! failed (stagnated, out of iterations), is repeated smaller from a snapshot of the cells,
//! down to `dt_min`, before the error is returned.

use super::partition::centre;
use super::CellRunError;
use crate::comm::Communicator;
use crate::scene::cells::{CellScene, Flow, Scheme};
use crate::timestep::adaptive::AdaptiveDt;
use crate::timestep::cell_force::CellForce;
use crate::timestep::suspension::{CellStepError, Suspension, SuspensionReport};

/// What [`accepted_step`] did.
#[derive(Debug)]
pub(crate) struct Accepted {
    /// The accepted step's report.
    pub report: SuspensionReport,
    /// The `dt` of the accepted step.
    pub dt: f64,
    /// Its area/volume error estimate, the largest over all ranks (NaN counts as infinite).
    pub error: f64,
    /// Tries rejected before it.
    pub rejected: usize,
    /// Adaptive: the `dt` proposed for the next step.
    pub next_dt: Option<f64>,
    /// Adaptive: whether the accepted error was above the per-step allowance (accepted at
    /// `dt_min`).
    pub above_tolerance: bool,
}

/// A failed step `step` (that was to reach `time`) as a run error (cells are numbered from 0,
/// in scene order, as everywhere in the API and the messages).
pub(crate) fn step_error(step: usize, time: f64, e: CellStepError) -> CellRunError {
    CellRunError::Step {
        step,
        time,
        cell: e.cell,
        source: Box::new(e.source),
    }
}

/// The adaptive step control of `scene` (`None` with a fixed `dt`): its tolerance over
/// `t_end`, the scheme's order, the first `dt` and its bounds.
pub(crate) fn adaptive_control(scene: &CellScene) -> Result<Option<AdaptiveDt>, CellRunError> {
    let n = &scene.numerics;
    if !n.adaptive_dt {
        return Ok(None);
    }
    let order = match n.scheme {
        Scheme::Euler => 1,
        Scheme::Bdf2 => 2,
    };
    AdaptiveDt::new(n.dt_tolerance, n.t_end, order, n.dt, n.dt_min, n.dt_max)
        .map(Some)
        .map_err(|e| CellRunError::Step {
            step: 0,
            time: 0.0,
            cell: None,
            source: Box::new(e),
        })
}

/// Step `step` of `susp` from `time`, first tried at `dt_try`, with the caller's `forces`;
/// adaptive steps never pass `t_end` (collective over `comm`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn accepted_step(
    comm: &dyn Communicator,
    susp: &mut Suspension,
    u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
    forces: &[&dyn CellForce],
    (step, time, t_end): (usize, f64, f64),
    mut dt_try: f64,
    adaptive: Option<&AdaptiveDt>,
) -> Result<Accepted, CellRunError> {
    let snapshot = adaptive.map(|_| susp.snapshot());
    let mut rejected = 0;
    loop {
        if adaptive.is_some() {
            susp.set_dt(dt_try)
                .map_err(|e| step_error(step, time + dt_try, e))?;
        }
        let report = match susp.step_with_forces(comm, u_inf, time, forces) {
            Ok(r) => r,
            Err(e) => {
                let retry = match (adaptive, &snapshot) {
                    (Some(ctl), Some(snap)) if e.source.is_solver_failure() => {
                        ctl.after_failure(dt_try).map(|d| (d, snap))
                    }
                    _ => None,
                };
                let Some((smaller, snap)) = retry else {
                    return Err(step_error(step, time + dt_try, e));
                };
                rejected += 1;
                susp.restore(snap)
                    .map_err(|e| step_error(step, time + dt_try, e))?;
                dt_try = smaller.min(t_end - time);
                continue;
            }
        };
        // The largest error over all ranks (a NaN counts as infinite).
        let (local, _) = report.area_volume_error();
        let mut error = [if local.is_nan() { f64::INFINITY } else { local }];
        comm.all_max(&mut error).map_err(CellRunError::Comm)?;
        let error = error[0];
        let (Some(ctl), Some(snap)) = (adaptive, &snapshot) else {
            return Ok(Accepted {
                report,
                dt: dt_try,
                error,
                rejected,
                next_dt: None,
                above_tolerance: false,
            });
        };
        let d = ctl.decide(dt_try, error);
        if d.accept {
            return Ok(Accepted {
                report,
                dt: dt_try,
                error,
                rejected,
                next_dt: Some(d.dt),
                above_tolerance: error > ctl.allowed(dt_try),
            });
        }
        rejected += 1;
        susp.restore(snap)
            .map_err(|e| step_error(step, time + dt_try, e))?;
        dt_try = d.dt.min(t_end - time);
    }
}

/// The origin of the flow's frame for the next step (collective over `comm`): for a flow that
/// follows the cells ([`Flow::follows_cells`]), the midpoint of the bounding box of every
/// cell's centre (the degree-0 coefficients), the same on every rank; else `0`.
pub(crate) fn flow_origin(
    comm: &dyn Communicator,
    susp: &Suspension,
    flow: &Flow,
) -> Result<[f64; 3], CellRunError> {
    if !flow.follows_cells() {
        return Ok([0.0; 3]);
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for c in susp.cells() {
        let x = centre(&c.state.coefs);
        for d in 0..3 {
            lo[d] = lo[d].min(x[d]);
            hi[d] = hi[d].max(x[d]);
        }
    }
    comm.all_min(&mut lo).map_err(CellRunError::Comm)?;
    comm.all_max(&mut hi).map_err(CellRunError::Comm)?;
    Ok(std::array::from_fn(|d| {
        if lo[d].is_finite() && hi[d].is_finite() {
            0.5 * (lo[d] + hi[d])
        } else {
            0.0
        }
    }))
}

/// The cells' extra dissipation `P − P₀` in the scene's flow (about `origin`,
/// [`flow_origin`]) and, for a tube or channel flow, the relative apparent viscosity of the
/// vessel's straight part ([`Suspension::extra_dissipation`]; collective). Both `None` without
/// a flow or before the first step.
/// * A tube: its straight section of length `L` (where its radius is within
///   [`crate::scene::cells::TUBE_WINDOW_TOLERANCE`] of `R`), `1 + (P − P₀)/(Q G L)` with
///   `Q G = 2πμU²` (`Q = πR²U/2`, `G = 4μU/R²`).
/// * A channel: the plates' flat area `A` (where they are within the same tolerance of `±H`,
///   [`crate::wall::flat_area`]), `1 + (P − P₀)/(q G A)` with `q G = 8μU²/3H` (the flow rate
///   per unit width `q = 4UH/3`, `G = 2μU/H²`): the power plane Poiseuille flow dissipates
///   over that area.
pub(crate) fn rheology(
    comm: &dyn Communicator,
    susp: &Suspension,
    scene: &CellScene,
    origin: [f64; 3],
) -> Result<(Option<f64>, Option<f64>), CellStepError> {
    let (flow, mu) = (scene.flow, scene.viscosity);
    if flow == Flow::None {
        return Ok((None, None));
    }
    let d = susp.extra_dissipation(comm, &|x| flow.velocity_about(x, origin), &|x| {
        flow.stress(x, mu)
    })?;
    let tolerance = crate::scene::cells::TUBE_WINDOW_TOLERANCE;
    let container = scene
        .walls
        .iter()
        .find(|w| {
            w.kind == crate::wall::WallKind::Container
                && matches!(
                    w.shape,
                    crate::scene::walls::WallShape::Tube { .. }
                        | crate::scene::walls::WallShape::Channel { .. }
                )
        })
        .map(|w| &w.shape);
    let relative = match (flow, d, container) {
        // P₀ = Q G L over the tube's straight section: Q = πR²U/2, G = 4μU/R².
        (
            Flow::Tube { speed, .. },
            Some(d),
            Some(&crate::scene::walls::WallShape::Tube { length, .. }),
        ) if speed != 0.0 => {
            let l = crate::wall::straight_length(length, tolerance);
            Some(1.0 + d / (2.0 * std::f64::consts::PI * mu * speed * speed * l))
        }
        // P₀ = q G A over the plates' flat area: q = 4UH/3 a unit width, G = 2μU/H².
        (
            Flow::Channel { speed, half_height },
            Some(d),
            Some(&crate::scene::walls::WallShape::Channel { length, width, .. }),
        ) if speed != 0.0 => {
            let a = crate::wall::flat_area(length, width, tolerance);
            Some(1.0 + d * 3.0 * half_height / (8.0 * mu * speed * speed * a))
        }
        _ => None,
    };
    Ok((d, relative))
}

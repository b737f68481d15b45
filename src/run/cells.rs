//! Running a cell scene (`mobo run`): the semi-implicit steps, saved frames and a summary.
//!
//! Writes into the output directory, each file atomically (written, then renamed):
//! * `frames/frame_NNNNN_coefs.npy` (`3 × n_coefs`: x, y, z SH coefficients),
//!   `frames/frame_NNNNN_positions.npy` (`3 × n_points` grid positions),
//!   `frames/frame_NNNNN_tension.npy` (`n_points`), `frames/times.npy` (time of every frame);
//! * `summary.json`: effects built and why, settings, steps, timings, GMRES iterations, area
//!   and volume drift, centroid and its velocity, inclination angle, final time.
//!
//! Any number of cells (coupled through the FMM when there are two or more), shear elasticity
//! (Skalak, explicit, stress-free at the initial shape), the first-order and the BDF2 scheme,
//! a viscosity contrast (with several cells, the double layer of each cell with `λ ≠ 1` is
//! felt by the others through a second, stresslet FMM, with its membrane velocity from the
//! previous step; see [`crate::timestep::coupling`]), a fixed or an adaptive `dt`
//! ([`crate::timestep::adaptive`]: steps whose area/volume error is too large are repeated
//! smaller). Scenes that ask for what is not built are refused with a message
//! that says what is missing.
//!
//! **Over MPI ranks** ([`run_on`]): every rank reads the scene and builds every cell's setup,
//! holds a share of the cells ([`super::partition`]) and steps them
//! ([`Suspension::step_on`]); rank 0 gathers the coefficients and tensions for each frame and
//! every cell's state for each checkpoint and writes the same files as one rank (the memory
//! at rank 0 is that of every cell's state during a checkpoint, `docs/scaling.md`). A
//! checkpoint records the split: resumed on as many ranks it continues bit for bit; on another
//! number it is split afresh and continues to round-off. A failure on any rank (a cell's step,
//! an output file) is returned on every rank; a stop request on any rank stops all after the
//! step, with a checkpoint.

mod finish;

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};

use super::assembly::{available_memory, build_part_share, run_effects, setups};
use super::cell_step::{accepted_step, adaptive_control, flow_origin, rheology, step_error};
use super::checkpoint::{self, Progress, Split};
use super::error::{agreed, CellRunError};
use super::observables::{FailedRunSummary, Observables, StepRow};
use super::output::{gather_rows, gather_states, gathered_frame, write_walls_vtp};
use super::partition::{self, Reason};
use super::plane::PlaneOutput;
use super::scene_copy::write_scene_copy;
use super::summary::{
    split_summary, AdaptiveSummary, CellRunSummary, CellSummary, Counters, RankClock, Rebalance,
};
use crate::comm::{Communicator, SerialComm};
use crate::io::frames::{FrameFormats, FrameWriter};
use crate::io::write_atomic;
use crate::scene::cells::{CellScene, Scheme};
use crate::sph_harmonics::{ShTransform, ShWorkspace};
use crate::timestep::adaptive::AdaptiveDt;
use crate::timestep::suspension::{agree_cells, CellSetup, CellStepError, Suspension};
use crate::timestep::TimestepError;
use crate::vesicle::geometry::{Geometry, SurfaceCalculus};
use crate::vesicle::VesicleError;
use crate::wall::RowShare;

/// One cell's observables from its coefficients.
fn observe(
    calc: &mut SurfaceCalculus,
    coefs: &[f64],
) -> Result<([f64; 3], f64, f64, f64), CellRunError> {
    Ok(observe_geometry(&calc.geometry(coefs)?))
}

/// One cell's observables from its geometry: centroid, area, volume, inclination (degrees).
fn observe_geometry(g: &Geometry) -> ([f64; 3], f64, f64, f64) {
    let (_, axes) = g.principal_axes();
    (
        g.centroid(),
        g.area(),
        g.volume(),
        (axes[0][1] / axes[0][0]).atan().to_degrees(),
    )
}

/// How a run is started and when it stops early.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// No progress bar.
    pub quiet: bool,
    /// Continue from `out/checkpoint.bin` (written by an earlier run of the same scene).
    pub resume: bool,
    /// Stop after this many steps of this invocation (with a checkpoint), e.g. to fit a job's
    /// wall-time limit; the run is then continued with `resume`.
    pub max_steps: Option<usize>,
    /// Set (e.g. by a Ctrl-C handler) to stop cleanly after the current step, with a
    /// checkpoint.
    pub stop: Option<Arc<AtomicBool>>,
}

pub use super::checkpoint::CHECKPOINT;
/// The copy of the scene in the output directory (what `--resume` runs).
pub const SCENE_COPY: &str = "scene.toml";

/// Check the split (every `every` steps, after step `step`) and move the cells when it went
/// stale (collective).
#[allow(clippy::too_many_arguments)]
fn rebalance(
    comm: &dyn Communicator,
    susp: &mut Suspension,
    p: usize,
    setups: &[CellSetup],
    owners: &mut Vec<usize>,
    (step, every, max_imbalance): (usize, usize, f64),
    clock: &mut RankClock,
    log: &mut Vec<Rebalance>,
) -> Result<(), CellRunError> {
    let k = comm.size();
    if k == 1 || step % every != 0 {
        return Ok(());
    }
    let t = Instant::now();
    let (centres, costs) = partition::gather_inputs(comm, susp).map_err(CellRunError::Comm)?;
    let fresh = partition::split(&centres, &costs, k);
    let before = partition::imbalance(owners, &costs, k);
    let stale = owners.iter().zip(&fresh).filter(|(a, b)| a != b).count();
    let stale_fraction = stale as f64 / owners.len().max(1) as f64;
    let reason = if stale == 0 {
        None
    } else if before > max_imbalance {
        Some(Reason::Imbalance)
    } else if stale_fraction > partition::MAX_STALE {
        Some(Reason::Locality)
    } else {
        None
    };
    if let Some(reason) = reason {
        let bytes = partition::migrate(comm, susp, p, setups, &fresh)
            .map_err(|e| step_error(step + 1, f64::NAN, e))?;
        clock.migration_bytes += bytes;
        log.push(Rebalance {
            step: step + 1,
            reason,
            imbalance_before: before,
            imbalance_after: partition::imbalance(&fresh, &costs, k),
            stale_fraction,
            cells_moved: stale,
        });
        *owners = fresh;
    }
    clock.rebalance_s += t.elapsed().as_secs_f64();
    Ok(())
}

/// Run `scene` (whose text is `scene_text`), writing into `out`, on one process.
pub fn run(
    scene: &CellScene,
    scene_text: &str,
    out: &Path,
    options: &RunOptions,
) -> Result<CellRunSummary, CellRunError> {
    Ok(run_on(&SerialComm, scene, scene_text, out, options)?
        .expect("rank 0 of one rank has the summary"))
}

/// [`run`] over the ranks of `comm` (collective: every rank calls it with the same scene).
/// The cells are split between the ranks ([`partition`]); rank 0 gathers what is
/// written (frames, checkpoints, the summary, all the same files as on one rank) and returns
/// the summary; the other ranks return `None`. A failure is returned on every rank.
///
/// The run goes in phases (`CellRun`): it starts (from the scene or the checkpoint), steps
/// until `t_end` or a stop, writes frames and checkpoints as it goes, and writes its summary.
pub fn run_on(
    comm: &dyn Communicator,
    scene: &CellScene,
    scene_text: &str,
    out: &Path,
    options: &RunOptions,
) -> Result<Option<CellRunSummary>, CellRunError> {
    let mut run = CellRun::start(comm, scene, scene_text, out, options)?;
    let bar = progress_bar(
        options.quiet || comm.rank() != 0,
        run.adaptive.is_some(),
        run.steps(),
        &run.prog,
        scene,
    );
    let mut stopped = false;
    while !run.ends_run(run.k, run.prog.time) {
        let last;
        (last, stopped) = match run.step(&bar) {
            Ok(s) => s,
            Err(e) => {
                bar.finish_and_clear();
                run.record_failure(&e);
                return Err(e);
            }
        };
        run.write_outputs(last, stopped)?;
        if stopped {
            break;
        }
    }
    bar.finish_and_clear();
    run.finish(stopped)
}

/// A cell run in progress on one rank: what [`run_on`] carries from one step to the next.
struct CellRun<'a> {
    comm: &'a dyn Communicator,
    scene: &'a CellScene,
    out: &'a Path,
    options: &'a RunOptions,
    /// Every cell's setup, in scene order (moved cells are rebuilt from them).
    setups: Vec<CellSetup>,
    sht: ShTransform,
    ws: ShWorkspace,
    calc: SurfaceCalculus,
    /// Whether the cells feel each other's double layer (a checkpoint keeps the velocities).
    double_layer: bool,
    /// The rank of every cell.
    owners: Vec<usize>,
    susp: Suspension,
    prog: Progress,
    frames: Option<FrameWriter>,
    /// The velocity plane's output (`[output] velocity_plane`).
    plane: Option<PlaneOutput>,
    adaptive: Option<AdaptiveDt>,
    /// Centres of this rank's cells before the last step (global index, centre).
    before_last: Vec<(usize, [f64; 3])>,
    /// The first step of this invocation.
    first: usize,
    /// The last step taken.
    k: usize,
    clock: RankClock,
    log: Vec<Rebalance>,
    /// Double-layer assemblies and own-preconditioner builds of cells that left this rank
    /// (their steppers went with them).
    left: [usize; 2],
    start: Instant,
    wall0: f64,
    /// The per-step record (`observables.csv`; kept at rank 0), and the step of the last
    /// checkpoint written or resumed from.
    observed: Observables,
    last_checkpoint: Option<usize>,
}

/// Fixed steps of `scene` (`t_end / dt`).
fn fixed_steps(scene: &CellScene) -> usize {
    (scene.numerics.t_end / scene.numerics.dt).round().max(1.0) as usize
}

/// Whether step `k`, reaching time `t`, ends a run of `scene`: its fixed steps, or with an
/// adaptive `dt` its `t_end` up to round-off in the sum of the steps.
fn ends_run(scene: &CellScene, adaptive: bool, k: usize, t: f64) -> bool {
    if adaptive {
        t >= scene.numerics.t_end * (1.0 - 1e-12)
    } else {
        k >= fixed_steps(scene)
    }
}

/// Double-layer assemblies and own-preconditioner builds of the cells held in `s`.
fn counts(s: &Suspension) -> [usize; 2] {
    s.cells().iter().fold([0usize; 2], |[d, b], c| {
        [
            d + c.stepper.double_layer_assemblies,
            b + c.stepper.own_preconditioner_builds,
        ]
    })
}

impl<'a> CellRun<'a> {
    /// Start: the cells split over the ranks and built, from the scene (frame 0 written) or
    /// from the checkpoint in `out` (every rank reads it).
    fn start(
        comm: &'a dyn Communicator,
        scene: &'a CellScene,
        scene_text: &str,
        out: &'a Path,
        options: &'a RunOptions,
    ) -> Result<Self, CellRunError> {
        let p = scene.numerics.order;
        let dt = scene.numerics.dt;
        let (k_ranks, root) = (comm.size(), comm.rank() == 0);
        let nc = scene.cells.len();
        let setups = setups(scene)?;
        let sht = ShTransform::new(p).map_err(VesicleError::from)?;
        let mut ws = sht.workspace();
        let (ncoef, n) = (3 * sht.n_coefs(), sht.n_points());
        let double_layer = nc > 1 && scene.cells.iter().any(|c| c.viscosity_ratio != 1.0);
        let mut calc = SurfaceCalculus::new(p)?;
        // Where the run starts: the scene, or the checkpoint (read by every rank).
        let resumed = if options.resume {
            let loaded = checkpoint::load(out, nc, ncoef, n, double_layer);
            let loaded = agreed(comm, loaded)?;
            // A fixed-dt run's time is step × dt and BDF2's history assumes one dt: the
            // stored scene must keep the checkpoint's (every rank reads the same files).
            let dt = scene.numerics.dt;
            if !scene.numerics.adaptive_dt && loaded.0.dt != dt {
                return Err(CellRunError::Resume(format!(
                    "{}: [numerics] dt = {dt}, but the checkpoint was written with dt = {}: a \
                     run with a fixed dt resumes with the same dt (its time is step × dt); \
                     start a new run from a frame to change it",
                    out.join("scene.toml").display(),
                    loaded.0.dt
                )));
            }
            Some(loaded)
        } else {
            None
        };
        let owners = match &resumed {
            Some((_, _, Some(split))) if split.ranks == k_ranks => split.owners.clone(),
            Some((_, states, _)) => {
                let centres: Vec<_> = states.iter().map(|s| partition::centre(&s.coefs)).collect();
                let costs: Vec<_> = states
                    .iter()
                    .map(|s| partition::cost(s.iterations))
                    .collect();
                partition::split(&centres, &costs, k_ranks)
            }
            None => {
                let centres: Vec<_> = setups.iter().map(|s| partition::centre(&s.coefs)).collect();
                partition::split(&centres, &vec![partition::cost(0); nc], k_ranks)
            }
        };
        let mine: Vec<usize> = (0..nc).filter(|&i| owners[i] == comm.rank()).collect();
        // The walls' system split over the ranks, or every rank's whole ([numerics] wall_solve).
        let wall_unknowns: u64 = scene
            .walls
            .iter()
            .map(|w| 3 * (w.order as u64 + 1) * 2 * w.order as u64)
            .sum();
        let whole_bytes = 8 * wall_unknowns * wall_unknowns;
        // Every rank decides on its own free memory; split where any rank would.
        let mut split = [f64::from(u8::from(scene.numerics.wall_solve.splits(
            comm.size(),
            whole_bytes,
            available_memory(),
        )))];
        comm.all_max(&mut split).map_err(CellRunError::Comm)?;
        let walls_share = if split[0] > 0.0 {
            RowShare {
                rank: comm.rank(),
                ranks: comm.size(),
            }
        } else {
            RowShare::WHOLE
        };
        let mut susp = agreed(comm, build_part_share(scene, &setups, &mine, walls_share))?;
        let formats = FrameFormats {
            npy: scene.output.npy,
            hdf5: scene.output.hdf5,
            vtp: scene.output.vtk,
        };
        let (prog, frames, plane) = match resumed {
            Some((prog, states, _)) => {
                let restored = (0..susp.len()).try_for_each(|i| {
                    let id = susp.cells()[i].id;
                    susp.set_cell_state(i, &states[id]).map_err(|e| {
                        CellRunError::Resume(format!(
                            "{}: cell {}: {}",
                            out.join(CHECKPOINT).display(),
                            id,
                            e.source
                        ))
                    })
                });
                agreed(comm, restored)?;
                let frames = root
                    .then(|| FrameWriter::resume(out, formats, &prog.frame_times))
                    .transpose()
                    .map_err(CellRunError::from);
                let frames = agreed(comm, frames)?;
                let plane = PlaneOutput::open(comm, scene, out, &prog.frame_times)?;
                (prog, frames, plane)
            }
            None => {
                let mut prog = Progress::start(dt);
                let t0 = Instant::now();
                let opened = if root {
                    (|| -> Result<_, CellRunError> {
                        for s in &setups {
                            let (x, a, v, inc) = observe(&mut calc, &s.coefs)?;
                            prog.start_obs.push([x[0], x[1], x[2], a, v, inc]);
                        }
                        write_scene_copy(scene, scene_text, out, SCENE_COPY)?;
                        Ok(Some(FrameWriter::new(out, formats)?))
                    })()
                } else {
                    Ok(None)
                };
                let mut frames = agreed(comm, opened)?;
                let mut plane = PlaneOutput::open(comm, scene, out, &[])?;
                if let Some(pl) = &mut plane {
                    pl.write(comm, scene, &mut susp, (0, 0, 0.0))?;
                }
                gathered_frame(comm, &susp, frames.as_mut(), &sht, &mut ws, 0.0)?;
                prog.output_s += t0.elapsed().as_secs_f64();
                if let Some(f) = &frames {
                    prog.frame_times = f.times().to_vec();
                }
                (prog, frames, plane)
            }
        };
        // The walls in ParaView (after the frame writer, which clears an earlier run's).
        let walls_vtp = if root {
            write_walls_vtp(scene, out)
        } else {
            Ok(())
        };
        agreed(comm, walls_vtp)?;
        let adaptive = adaptive_control(scene)?;
        if adaptive.is_some() {
            // A resumed adaptive run continues with the step it had chosen.
            susp.set_dt(prog.dt)
                .map_err(|e| step_error(prog.step, prog.time, e))?;
        }
        let (first, k, wall0) = (prog.step + 1, prog.step, prog.wall_s);
        let observed = if root && options.resume {
            Observables::resume(out, prog.step)
        } else {
            Ok(Observables::default())
        };
        let observed = agreed(comm, observed)?;
        let last_checkpoint = options.resume.then_some(prog.step);
        Ok(CellRun {
            comm,
            scene,
            out,
            options,
            setups,
            sht,
            ws,
            calc,
            double_layer,
            owners,
            susp,
            prog,
            frames,
            plane,
            adaptive,
            before_last: Vec::new(),
            first,
            k,
            clock: RankClock::default(),
            log: Vec::new(),
            left: [0; 2],
            start: Instant::now(),
            wall0,
            observed,
            last_checkpoint,
        })
    }

    /// Fixed steps of the scene (`t_end / dt`).
    fn steps(&self) -> usize {
        fixed_steps(self.scene)
    }

    /// Whether step `k`, reaching time `t`, ends the run ([`ends_run`]).
    fn ends_run(&self, k: usize, t: f64) -> bool {
        ends_run(self.scene, self.adaptive.is_some(), k, t)
    }

    /// One accepted step (the split checked first, the cells moved if it went stale), its
    /// checks and statistics. Returns whether it was the last, and whether the run stops
    /// after it (a stop request on any rank, or `max_steps`).
    fn step(&mut self, bar: &ProgressBar) -> Result<(bool, bool), CellRunError> {
        let (comm, scene, options) = (self.comm, self.scene, self.options);
        let (p, dt, first) = (scene.numerics.order, scene.numerics.dt, self.first);
        let flow = scene.flow;
        let mut k = self.k;
        let adaptive_on = self.adaptive.is_some();
        let ends_run = |k: usize, t: f64| ends_run(scene, adaptive_on, k, t);
        let CellRun {
            setups,
            calc,
            owners,
            susp,
            prog,
            adaptive,
            before_last,
            clock,
            log,
            left,
            observed,
            ..
        } = self;
        let held = counts(susp);
        rebalance(
            comm,
            susp,
            p,
            setups,
            owners,
            (
                k,
                scene.numerics.rebalance_every,
                scene.numerics.max_imbalance,
            ),
            clock,
            log,
        )?;
        let kept = counts(susp);
        for ((l, h), k) in left.iter_mut().zip(held).zip(kept) {
            *l += h - k.min(h);
        }
        k += 1;
        let dt_try = match &adaptive {
            None => dt,
            Some(_) => prog.dt.min(scene.numerics.t_end - prog.time),
        };
        if ends_run(k, prog.time + dt_try) {
            before_last.clear();
            for c in susp.cells() {
                before_last.push((c.id, observe(calc, &c.state.coefs)?.0));
            }
        }
        let t = Instant::now();
        let origin = flow_origin(comm, susp, &flow)?;
        let acc = accepted_step(
            comm,
            susp,
            &|x| flow.velocity_about(x, origin),
            &[],
            (k, prog.time, scene.numerics.t_end),
            dt_try,
            adaptive.as_ref(),
        )?;
        prog.rejected += acc.rejected;
        prog.error_sum += acc.error;
        if acc.above_tolerance {
            prog.above_tolerance += 1;
        }
        if let Some(next) = acc.next_dt {
            prog.dt = next;
        }
        let (report, dt_try) = (acc.report, acc.dt);
        prog.step_s += t.elapsed().as_secs_f64();
        prog.time = match &adaptive {
            None => k as f64 * dt,
            Some(_) => prog.time + dt_try,
        };
        prog.last_dt = dt_try;
        prog.dt_used[0] = prog.dt_used[0].min(dt_try);
        prog.dt_used[1] = prog.dt_used[1].max(dt_try);
        let finite = susp
            .cells()
            .iter()
            .find_map(|c| Some((c.id, c.state.coefs.iter().position(|c| !c.is_finite())?)))
            .map_or(Ok(()), |(id, j)| {
                Err(CellStepError {
                    cell: Some(id),
                    source: TimestepError::Vesicle(format!(
                        "non-finite coefficient {j} after the step (the last checkpoint, \
                         step {}, is kept)",
                        prog.step
                    )),
                })
            });
        agree_cells(comm, finite).map_err(|e| step_error(k, prog.time, e))?;
        let its = report.cells.iter().map(|r| r.gmres.iterations);
        let mut it = [its.clone().max().unwrap_or(0) as f64];
        let mut it_sum = [its.sum::<usize>() as u64];
        comm.all_max(&mut it).map_err(CellRunError::Comm)?;
        comm.all_sum_u64(&mut it_sum).map_err(CellRunError::Comm)?;
        let it = it[0] as usize;
        prog.iters_sum += it_sum[0] as usize;
        prog.iters_max = prog.iters_max.max(it);
        let (extra_dissipation, relative_viscosity) =
            rheology(comm, susp, scene, origin).map_err(|e| step_error(k, prog.time, e))?;
        let step_gap = susp.coupling_stats().map(|st| st.min_gap);
        if let Some(g) = step_gap {
            prog.min_gap = prog.min_gap.min(g);
        }
        observed.push(StepRow {
            step: k,
            time: prog.time,
            dt: dt_try,
            gmres_max: it,
            gmres_mean: it_sum[0] as f64 / scene.cells.len() as f64,
            min_gap: step_gap.filter(|g| g.is_finite()),
            area_volume_error: acc.error,
            end_gap: susp.contact_stats().last_gap,
            extra_dissipation,
            relative_viscosity,
        });
        match &adaptive {
            None => {
                bar.set_message(format!("t {:.3} dt {dt} gmres {it}", prog.time));
                bar.set_position(k as u64);
            }
            Some(_) => {
                bar.set_message(format!(
                    "step {k} t {:.3} dt {:.3e} gmres {it} rejected {}",
                    prog.time, dt_try, prog.rejected
                ));
                bar.set_position((1000.0 * prog.time / scene.numerics.t_end) as u64);
            }
        }
        prog.step = k;
        // A Ctrl-C (or SIGTERM from mpirun) on any rank stops every rank after this step.
        let mut interrupted = [f64::from(u8::from(
            options
                .stop
                .as_ref()
                .is_some_and(|s| s.load(Ordering::Relaxed)),
        ))];
        comm.all_max(&mut interrupted).map_err(CellRunError::Comm)?;
        let interrupted = interrupted[0] > 0.0;
        let limited = options.max_steps.is_some_and(|m| k + 1 - first >= m);
        let last = ends_run(k, prog.time);
        let stopped = !last && (interrupted || limited);
        self.k = k;
        Ok((last, stopped))
    }

    /// The frame and the checkpoint due after step `self.k` (always after the last step and
    /// at a stop), gathered at rank 0.
    fn write_outputs(&mut self, last: bool, stopped: bool) -> Result<(), CellRunError> {
        let (comm, scene, out, k) = (self.comm, self.scene, self.out, self.k);
        let (k_ranks, ncoef, n) = (comm.size(), 3 * self.sht.n_coefs(), self.sht.n_points());
        let (wall0, start, double_layer) = (self.wall0, self.start, self.double_layer);
        let CellRun {
            susp,
            frames,
            plane,
            sht,
            ws,
            prog,
            owners,
            clock,
            observed,
            last_checkpoint,
            ..
        } = self;
        let t0 = Instant::now();
        if last || (k as u64).is_multiple_of(scene.output_every) {
            if let Some(pl) = plane {
                pl.write(comm, scene, susp, (prog.frame_times.len(), k, prog.time))?;
            }
            gathered_frame(comm, susp, frames.as_mut(), sht, ws, prog.time)?;
            if let Some(f) = &frames {
                prog.frame_times = f.times().to_vec();
            }
        }
        if stopped || last || (k as u64).is_multiple_of(scene.output.checkpoint_every) {
            prog.wall_s = wall0 + start.elapsed().as_secs_f64();
            let states = gather_states(comm, susp, ncoef, n)?;
            let saved = match states {
                Some(states) => checkpoint::save(
                    out,
                    &states,
                    prog,
                    &Split {
                        ranks: k_ranks,
                        owners: owners.clone(),
                    },
                    double_layer,
                )
                .and_then(|_| observed.write(out)),
                None => Ok(()),
            };
            agreed(comm, saved)?;
            *last_checkpoint = Some(k);
        }
        let spent = t0.elapsed().as_secs_f64();
        prog.output_s += spent;
        clock.output_s += spent;
        Ok(())
    }
}

/// The progress bar (hidden when `hidden`).
fn progress_bar(
    hidden: bool,
    adaptive: bool,
    steps: usize,
    prog: &Progress,
    scene: &CellScene,
) -> ProgressBar {
    if hidden {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new(if adaptive { 1000 } else { steps as u64 });
    b.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] step {pos}/{len} {msg} ETA {eta}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    b.set_position(if adaptive {
        (1000.0 * prog.time / scene.numerics.t_end) as u64
    } else {
        prog.step as u64
    });
    b
}

/// The built-in demo scene of `mobo run` without a scene file: one red blood cell in simple
/// shear (about half a minute on 2 cores).
pub const DEMO_SCENE: &str = r#"
[fluid]
viscosity = 1.0

[flow]
kind = "shear"
rate = 1.0

[[cells]]
shape = "rbc"
radius = 1.0
bending_modulus = 0.1
orientation = [0, 0, 1, 30]

[numerics]
order = 8
dt = 0.05
t_end = 10.0
gmres_tol = 1e-8

[output]
every = 20
"#;

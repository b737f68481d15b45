//! The end of a cell run: `summary.json` of a finished run (gathered at rank 0), and what a
//! failed step leaves (`summary.json` saying so, `observables.csv` up to the last good step).

use super::*;

impl<'a> CellRun<'a> {
    /// After a failed step (rank 0): `summary.json` saying so and `observables.csv` up to the
    /// last good step (see [`crate::run::observables`]); the last checkpoint stays as it was. A
    /// file that cannot be written is reported on stderr (the step's error is what the run
    /// returns).
    pub(super) fn record_failure(&self, error: &CellRunError) {
        if self.comm.rank() != 0 {
            return;
        }
        let scene = self.scene;
        let summary = FailedRunSummary {
            completed: false,
            error: error.to_string(),
            last_good_step: self.prog.step,
            last_good_time: self.prog.time,
            last_checkpoint_step: self.last_checkpoint,
            cells: scene.cells.len(),
            order: scene.numerics.order,
            dt: scene.numerics.dt,
            scheme: scheme_name(scene.numerics.scheme),
            coupling: scene.numerics.coupling.name(),
            last_observables: self.observed.last().copied(),
            wall_s: self.start.elapsed().as_secs_f64(),
        };
        let json = serde_json::to_string_pretty(&summary).expect("summary serialises");
        let written = self.observed.write(self.out).and_then(|_| {
            write_atomic(&self.out.join("summary.json"), json.as_bytes())?;
            Ok(())
        });
        if let Err(e) = written {
            eprintln!("mobo: the failed run's summary could not be written: {e}");
        }
    }

    /// The end of the run: the frames closed (unless stopped), every cell observed, the
    /// summary gathered at rank 0 and written there (`None` on the other ranks).
    pub(super) fn finish(mut self, stopped: bool) -> Result<Option<CellRunSummary>, CellRunError> {
        let (comm, scene, out, k, first) = (self.comm, self.scene, self.out, self.k, self.first);
        let (p, dt, k_ranks, nc) = (
            scene.numerics.order,
            scene.numerics.dt,
            comm.size(),
            scene.cells.len(),
        );
        let q = scene.numerics.upsample * p;
        let completed = self.ends_run(self.prog.step, self.prog.time);
        let (wall0, start) = (self.wall0, self.start);
        let CellRun {
            susp,
            frames,
            prog,
            calc,
            before_last,
            clock,
            log,
            left,
            adaptive,
            ..
        } = &mut self;
        let adaptive = adaptive.take();
        if !stopped {
            let finished = frames.take().map_or(Ok(()), |f| f.finish());
            agreed(comm, finished.map_err(CellRunError::from))?;
        }
        prog.wall_s = wall0 + start.elapsed().as_secs_f64();
        // Per cell: centre, area, volume, inclination, the centre before the last step, the
        // Taylor deformation and the tank-treading rate.
        let local = (0..susp.len())
            .map(|i| -> Result<(usize, Vec<f64>), CellRunError> {
                let cell = &susp.cells()[i];
                let id = cell.id;
                let g = calc.geometry(&cell.state.coefs)?;
                let (x, a, v, inc) = observe_geometry(&g);
                let d = g.taylor_deformation([0.0, 0.0, 1.0]);
                let tt = cell
                    .state
                    .membrane_velocity
                    .as_deref()
                    .map(|u| g.tank_treading_rate(u, [0.0, 0.0, -1.0]))
                    .transpose()?
                    .unwrap_or(f64::NAN);
                let b = before_last
                    .iter()
                    .find(|(j, _)| *j == id)
                    .map_or([f64::NAN; 3], |(_, b)| *b);
                Ok((
                    id,
                    vec![x[0], x[1], x[2], a, v, inc, b[0], b[1], b[2], d, tt],
                ))
            })
            .collect::<Result<Vec<_>, _>>();
        let local = agreed(comm, local)?;
        let rows = gather_rows(comm, local, nc, 11)?;
        let split = split_summary(comm, susp, clock, log, k + 1 - first)?;
        let stats = susp.coupling_stats().unwrap_or_default();
        let now = counts(susp);
        let mut dl = [(left[0] + now[0]) as u64, (left[1] + now[1]) as u64];
        comm.all_sum_u64(&mut dl).map_err(CellRunError::Comm)?;
        let Some(rows) = rows else {
            return Ok(None);
        };
        let mut per_cell = Vec::with_capacity(nc);
        for (i, r) in rows.iter().enumerate() {
            let s0 = prog.start_obs[i];
            let centroid = [r[0], r[1], r[2]];
            per_cell.push(CellSummary {
                area_drift: (r[3] - s0[3]) / s0[3],
                volume_drift: (r[4] - s0[4]) / s0[4],
                centroid,
                centroid_velocity: std::array::from_fn(|d| (centroid[d] - r[6 + d]) / prog.last_dt),
                inclination_deg: r[5],
                taylor_deformation: r[9],
                tank_treading_rate: r[10],
            });
        }
        let worst = |f: fn(&CellSummary) -> f64| {
            per_cell
                .iter()
                .map(f)
                .fold(0.0, |a: f64, b| if b.abs() > a.abs() { b } else { a })
        };
        let mean3 = |f: fn(&CellSummary) -> [f64; 3]| {
            let mut m = [0.0; 3];
            for c in &per_cell {
                for (md, v) in m.iter_mut().zip(f(c)) {
                    *md += v / nc as f64;
                }
            }
            m
        };
        let threads = rayon::current_num_threads() * k_ranks;
        let done = prog.step;
        let summary = CellRunSummary {
            packings: scene.packings.clone(),
            cells: nc,
            order: p,
            upsampled_order: q,
            dt,
            steps: done,
            final_time: prog.time,
            completed,
            adaptive: adaptive.map(|a| AdaptiveSummary {
                tolerance: a.tolerance,
                dt_min: a.dt_min,
                dt_max: a.dt_max,
                rejected_steps: prog.rejected,
                steps_above_tolerance: prog.above_tolerance,
                dt_smallest: prog.dt_used[0],
                dt_largest: prog.dt_used[1],
                dt_last: prog.last_dt,
            }),
            area_volume_error_sum: prog.error_sum,
            scheme: scheme_name(scene.numerics.scheme),
            coupling: scene.numerics.coupling.name(),
            implicit_zone: (scene.numerics.coupling
                == crate::timestep::near_implicit::CouplingMode::NearImplicit)
                .then_some(scene.numerics.implicit_zone),
            contact_distance: scene.numerics.contact_distance,
            gmres_tol: scene.numerics.gmres_tol,
            fmm_digits: (nc > 1).then_some(scene.numerics.fmm_digits),
            near_field: susp.near_field_decision(),
            effects: run_effects(scene, susp),
            wall_s: prog.wall_s,
            step_s: prog.step_s,
            coupling_s: stats.setup_s
                + stats.fmm_s
                + stats.self_s
                + stats.exchange_s
                + stats.near_s,
            output_s: prog.output_s,
            threads,
            cell_steps_per_core_second: (done * nc) as f64
                / (prog.step_s * threads as f64).max(1e-12),
            gmres_iterations_mean: prog.iters_sum as f64 / (done * nc).max(1) as f64,
            gmres_iterations_max: prog.iters_max,
            counters: Counters {
                fmm_builds: stats.fmm_builds,
                repulsion_points: stats.repulsion_points,
                double_layer_assemblies: dl[0] as usize,
                preconditioner_builds: dl[1] as usize,
                near_points: stats.near_points,
                near_pairs: stats.near_pairs,
                double_layer_fmm_builds: stats.double_layer_fmm_builds,
                near_implicit: susp.joint_stats(),
                contacts: susp.contact_stats(),
                walls: susp.wall_stats(),
                plane_wall: susp.plane().map(|w| w.stats()),
                start_up: susp.start_up_report(),
                recycling: susp.recycling().map(|_| susp.recycle_stats()),
            },
            units: scene.units,
            dimensionless: scene.groups(),
            area_drift: worst(|c| c.area_drift),
            volume_drift: worst(|c| c.volume_drift),
            centroid: mean3(|c| c.centroid),
            centroid_velocity: mean3(|c| c.centroid_velocity),
            inclination_deg: if nc == 1 {
                per_cell[0].inclination_deg
            } else {
                per_cell.iter().map(|c| c.inclination_deg).sum::<f64>() / nc as f64
            },
            min_gap: prog.min_gap.is_finite().then_some(prog.min_gap),
            per_cell,
            frames: prog.frame_times.len(),
            split,
        };
        let json = serde_json::to_string_pretty(&summary).expect("summary serialises");
        write_atomic(&out.join("summary.json"), json.as_bytes())?;
        Ok(Some(summary))
    }
}

/// A scheme as the scene key writes it.
fn scheme_name(scheme: Scheme) -> &'static str {
    match scheme {
        Scheme::Euler => "euler",
        Scheme::Bdf2 => "bdf2",
    }
}

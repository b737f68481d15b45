//! The checkpoint of a cell run (`out/checkpoint.bin`): the run's progress and every cell's
//! [`CellState`], in global cell order, whatever the number of ranks that wrote it (rank 0
//! gathers the states and writes; every rank reads it back and keeps its own cells).
//!
//! Arrays (rows are cells; a row of NaN is an absent optional value): `coefs`, `sigma`,
//! `drift_targets` (area, volume), `previous_coefs`, `previous_dt`, `skalak_references`,
//! `inter_cell_velocities` and `previous_inter_cell_velocities` (shape `[0, 0]` when no cell
//! has one), `membrane_velocities` (runs with an inter-cell double layer), `iterations` (GMRES
//! iterations of each cell's last solve), `owners` (the rank of each cell, with the header's
//! `ranks`: a run resumed on as many ranks keeps the split and so continues bit for bit), and
//! the run's `start_observables`, `frame_times`, `clocks`, `time_steps`; each cell's own
//! preconditioner as what it was built from, `preconditioner_surfaces`,
//! `preconditioner_steps` (`τ`, iterations of its last step) and `preconditioner_references`
//! (the Skalak reference of its Jacobian); `skalak_originals` and `skalak_label_maps` (the
//! material labels the Skalak reference is composed from). Checkpoints written before `iterations`, `owners`
//! or the preconditioner records existed are read (iterations 0, a fresh split, no own
//! preconditioners).

use std::path::Path;

use super::CellRunError;
use crate::io::checkpoint::Checkpoint;
use crate::timestep::cell_state::{CellState, PreconditionerRecord};
use crate::vesicle::material_labels::MaterialLabels;

/// The checkpoint file in the output directory.
pub const CHECKPOINT: &str = "checkpoint.bin";

/// Everything a run carries from step to step besides the cells' own state.
#[derive(Clone, Debug, Default)]
pub(crate) struct Progress {
    pub step: usize,
    pub frame_times: Vec<f64>,
    pub iters_sum: usize,
    pub iters_max: usize,
    pub step_s: f64,
    pub output_s: f64,
    pub wall_s: f64,
    pub min_gap: f64,
    /// Per cell: centroid (3), area, volume, inclination at the start of the run.
    pub start_obs: Vec<[f64; 6]>,
    /// Time reached.
    pub time: f64,
    /// The next step's size (adaptive `dt`).
    pub dt: f64,
    /// The size of the last step taken.
    pub last_dt: f64,
    /// Smallest and largest step taken.
    pub dt_used: [f64; 2],
    /// Steps rejected by the adaptive `dt` (repeated smaller).
    pub rejected: usize,
    /// Accepted steps whose error exceeded what they may commit (taken at `dt_min`).
    pub above_tolerance: usize,
    /// Sum over the steps of the area/volume error estimate.
    pub error_sum: f64,
}

impl Progress {
    /// A run that starts at `t = 0` with the step `dt`.
    pub fn start(dt: f64) -> Self {
        Progress {
            min_gap: f64::INFINITY,
            dt,
            last_dt: dt,
            dt_used: [f64::INFINITY, 0.0],
            ..Default::default()
        }
    }
}

/// The split of the cells between ranks saved with a checkpoint.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Split {
    pub ranks: usize,
    pub owners: Vec<usize>,
}

fn checkpoint_error(out: &Path, what: String) -> CellRunError {
    CellRunError::Resume(format!("{}: {what}", out.join(CHECKPOINT).display()))
}

/// Rows of an optional per-cell field (`None` rows as NaN); `[0, 0]` when no cell has one.
fn optional_rows(ck: &mut Checkpoint, name: &str, rows: Vec<Option<&[f64]>>, width: usize) {
    if rows.iter().all(|r| r.is_none()) {
        ck.push(name, vec![0, 0], Vec::new());
        return;
    }
    let nc = rows.len();
    let mut flat = Vec::with_capacity(nc * width);
    for r in rows {
        match r {
            Some(v) => flat.extend_from_slice(v),
            None => flat.extend(std::iter::repeat_n(f64::NAN, width)),
        }
    }
    ck.push(name, vec![nc, width], flat);
}

/// Write the checkpoint of a run at `prog` with the cells `states` (global order).
pub(crate) fn save(
    out: &Path,
    states: &[CellState],
    prog: &Progress,
    split: &Split,
    double_layer: bool,
) -> Result<(), CellRunError> {
    let nc = states.len();
    let ncoef = states.first().map_or(0, |s| s.coefs.len());
    let n = states.first().map_or(0, |s| s.sigma.len());
    let mut ck = Checkpoint::new(serde_json::json!({
        "format": "mobo cell-run checkpoint",
        "step": prog.step,
        "iters_sum": prog.iters_sum,
        "iters_max": prog.iters_max,
        "cells": nc,
        "ranks": split.ranks,
    }));
    let rows = |f: &dyn Fn(&CellState) -> Vec<f64>| states.iter().flat_map(f).collect::<Vec<_>>();
    ck.push("coefs", vec![nc, ncoef], rows(&|s| s.coefs.clone()));
    ck.push("sigma", vec![nc, n], rows(&|s| s.sigma.clone()));
    ck.push(
        "drift_targets",
        vec![nc, 2],
        rows(&|s| {
            let (a, v) = s.drift_targets.unwrap_or((f64::NAN, f64::NAN));
            vec![a, v]
        }),
    );
    let nan_row = |v: &Option<Vec<f64>>, len: usize| v.clone().unwrap_or(vec![f64::NAN; len]);
    ck.push(
        "previous_coefs",
        vec![nc, ncoef],
        rows(&|s| nan_row(&s.previous_coefs, ncoef)),
    );
    ck.push(
        "skalak_references",
        vec![nc, ncoef],
        rows(&|s| nan_row(&s.skalak_reference, ncoef)),
    );
    optional_rows(
        &mut ck,
        "inter_cell_velocities",
        states.iter().map(|s| s.velocity.as_deref()).collect(),
        3 * n,
    );
    optional_rows(
        &mut ck,
        "previous_inter_cell_velocities",
        states
            .iter()
            .map(|s| s.previous_velocity.as_deref())
            .collect(),
        3 * n,
    );
    if states.iter().any(|s| s.previous_density.is_some()) {
        optional_rows(
            &mut ck,
            "previous_coupling_densities",
            states
                .iter()
                .map(|s| s.previous_density.as_deref())
                .collect(),
            6 * n,
        );
    }
    // Membrane velocities of the last solve: the explicit double-layer densities of the next
    // step (only where the inter-cell double layer is built; NaN rows for none yet).
    if double_layer {
        ck.push(
            "membrane_velocities",
            vec![nc, 3 * n],
            rows(&|s| nan_row(&s.membrane_velocity, 3 * n)),
        );
    }
    ck.push(
        "iterations",
        vec![nc],
        states.iter().map(|s| s.iterations as f64).collect(),
    );
    ck.push(
        "owners",
        vec![nc],
        split.owners.iter().map(|&r| r as f64).collect(),
    );
    ck.push(
        "start_observables",
        vec![prog.start_obs.len(), 6],
        prog.start_obs.iter().flatten().copied().collect(),
    );
    ck.push(
        "frame_times",
        vec![prog.frame_times.len()],
        prog.frame_times.clone(),
    );
    ck.push(
        "clocks",
        vec![4],
        vec![prog.step_s, prog.output_s, prog.wall_s, prog.min_gap],
    );
    ck.push(
        "time_steps",
        vec![8],
        vec![
            prog.time,
            prog.dt,
            prog.last_dt,
            prog.dt_used[0],
            prog.dt_used[1],
            prog.rejected as f64,
            prog.above_tolerance as f64,
            prog.error_sum,
        ],
    );
    ck.push(
        "previous_dt",
        vec![nc],
        states
            .iter()
            .map(|s| s.previous_dt.unwrap_or(f64::NAN))
            .collect(),
    );
    // Each cell's own preconditioner, as what it was built from (rebuilt on load).
    let records: Vec<_> = states.iter().map(|s| s.preconditioner.as_ref()).collect();
    optional_rows(
        &mut ck,
        "preconditioner_surfaces",
        records.iter().map(|r| r.map(|r| &r.surface[..])).collect(),
        ncoef,
    );
    let steps: Vec<Option<[f64; 2]>> = records
        .iter()
        .map(|r| r.map(|r| [r.tau, r.last_iterations as f64]))
        .collect();
    optional_rows(
        &mut ck,
        "preconditioner_steps",
        steps.iter().map(|r| r.as_ref().map(|v| &v[..])).collect(),
        2,
    );
    optional_rows(
        &mut ck,
        "preconditioner_references",
        records
            .iter()
            .map(|r| r.and_then(|r| r.jacobian_reference.as_deref()))
            .collect(),
        ncoef,
    );
    let labels: Vec<_> = states.iter().map(|s| s.material_labels.as_ref()).collect();
    optional_rows(
        &mut ck,
        "skalak_originals",
        labels.iter().map(|l| l.map(|l| &l.original[..])).collect(),
        ncoef,
    );
    optional_rows(
        &mut ck,
        "skalak_label_maps",
        labels.iter().map(|l| l.map(|l| &l.map[..])).collect(),
        ncoef,
    );
    ck.write(&out.join(CHECKPOINT))?;
    Ok(())
}

/// Read the checkpoint of a run of `nc` cells of `ncoef` coefficients and `n` grid points:
/// the progress, every cell's state (global order) and the split that wrote it (`None` for a
/// checkpoint without one).
pub(crate) fn load(
    out: &Path,
    nc: usize,
    ncoef: usize,
    n: usize,
    double_layer: bool,
) -> Result<(Progress, Vec<CellState>, Option<Split>), CellRunError> {
    let ck = Checkpoint::read(&out.join(CHECKPOINT))?;
    let get = |name: &str, len: usize| -> Result<&[f64], CellRunError> {
        let a = ck
            .get(name)
            .ok_or_else(|| checkpoint_error(out, format!("no array \"{name}\"")))?;
        if a.data.len() != len {
            return Err(checkpoint_error(
                out,
                format!(
                    "array \"{name}\" has {} values, the scene needs {len} (is this the same scene?)",
                    a.data.len()
                ),
            ));
        }
        Ok(&a.data)
    };
    let coefs = get("coefs", nc * ncoef)?;
    let sigma = get("sigma", nc * n)?;
    let targets = get("drift_targets", nc * 2)?;
    let start = get("start_observables", nc * 6)?;
    let clocks = get("clocks", 4)?;
    let frame_times = ck
        .get("frame_times")
        .ok_or_else(|| checkpoint_error(out, "no array \"frame_times\"".into()))?
        .data
        .clone();
    let prev = get("previous_coefs", nc * ncoef)?;
    let time_steps = get("time_steps", 8)?;
    let previous_dt = get("previous_dt", nc)?;
    // Optional rows: `[0, 0]` (none) or one row per cell.
    let optional = |name: &str, width: usize| -> Result<Vec<Option<Vec<f64>>>, CellRunError> {
        let Some(a) = ck.get(name) else {
            return Ok(vec![None; nc]);
        };
        if a.shape.first().copied().unwrap_or(0) == 0 {
            return Ok(vec![None; nc]);
        }
        if a.data.len() != nc * width {
            return Err(checkpoint_error(
                out,
                format!(
                    "array \"{name}\" has shape {:?}, expected [{nc}, {width}]",
                    a.shape
                ),
            ));
        }
        Ok(a.data
            .chunks_exact(width)
            .map(|r| r.iter().all(|v| v.is_finite()).then(|| r.to_vec()))
            .collect())
    };
    if ck.get("inter_cell_velocities").is_none() {
        return Err(checkpoint_error(
            out,
            "no array \"inter_cell_velocities\"".into(),
        ));
    }
    let velocity = optional("inter_cell_velocities", 3 * n)?;
    let previous_velocity = optional("previous_inter_cell_velocities", 3 * n)?;
    // Absent from checkpoints of the explicit coupling (and from those written before the
    // near-implicit one).
    let previous_density = optional("previous_coupling_densities", 6 * n)?;
    let membrane = if double_layer {
        get("membrane_velocities", nc * 3 * n)?;
        optional("membrane_velocities", 3 * n)?
    } else {
        vec![None; nc]
    };
    // Absent from checkpoints written before the references were relabelled: those keep the
    // initial reference.
    let references = optional("skalak_references", ncoef)?;
    let iterations = match ck.get("iterations") {
        Some(_) => get("iterations", nc)?.to_vec(),
        None => vec![0.0; nc],
    };
    // Absent from checkpoints written before cells had their own preconditioners.
    let pc_surfaces = optional("preconditioner_surfaces", ncoef)?;
    let pc_steps = optional("preconditioner_steps", 2)?;
    let pc_references = optional("preconditioner_references", ncoef)?;
    // Absent from checkpoints written before the material labels: the labels then start
    // afresh from the relabelled reference.
    let originals = optional("skalak_originals", ncoef)?;
    let label_maps = optional("skalak_label_maps", ncoef)?;
    let mut records = Vec::with_capacity(nc);
    for (i, (surface, steps)) in pc_surfaces.into_iter().zip(&pc_steps).enumerate() {
        records.push(match (surface, steps) {
            (None, None) => None,
            (Some(surface), Some(st))
                if st[0] > 0.0 && st[0].is_finite() && st[1] >= 0.0 && st[1].fract() == 0.0 =>
            {
                Some(PreconditionerRecord {
                    surface,
                    tau: st[0],
                    jacobian_reference: pc_references[i].clone(),
                    last_iterations: st[1] as usize,
                })
            }
            _ => {
                return Err(checkpoint_error(
                    out,
                    format!(
                        "the preconditioner record of cell {} is incomplete, or its τ is not \
                         positive, or its iterations not a count",
                        i + 1
                    ),
                ))
            }
        });
    }
    let row = |a: &[f64], i: usize, w: usize| a[i * w..(i + 1) * w].to_vec();
    let finite_row = |a: &[f64], i: usize, w: usize| {
        let r = row(a, i, w);
        r.iter().all(|v| v.is_finite()).then_some(r)
    };
    let mut states = Vec::with_capacity(nc);
    for i in 0..nc {
        let (a, v) = (targets[2 * i], targets[2 * i + 1]);
        let its = iterations[i];
        if !(its >= 0.0 && its.fract() == 0.0) {
            return Err(checkpoint_error(
                out,
                format!("iterations of cell {i}: {its} is not a count"),
            ));
        }
        states.push(CellState {
            coefs: row(coefs, i, ncoef),
            sigma: row(sigma, i, n),
            drift_targets: (a.is_finite() && v.is_finite()).then_some((a, v)),
            previous_coefs: finite_row(prev, i, ncoef),
            previous_dt: previous_dt[i].is_finite().then_some(previous_dt[i]),
            membrane_velocity: membrane[i].clone(),
            skalak_reference: references[i].clone(),
            material_labels: match (&originals[i], &label_maps[i]) {
                (Some(original), Some(map)) => Some(MaterialLabels {
                    original: original.clone(),
                    map: map.clone(),
                }),
                (None, None) => None,
                _ => {
                    return Err(checkpoint_error(
                        out,
                        format!(
                            "cell {} has a Skalak reference's first surface without its label \
                             map, or a map without the surface",
                            i + 1
                        ),
                    ))
                }
            },
            velocity: velocity[i].clone(),
            previous_velocity: previous_velocity[i].clone(),
            iterations: its as usize,
            preconditioner: records[i].take(),
            previous_density: previous_density[i].clone(),
        });
    }
    let split = match (ck.meta["ranks"].as_u64(), ck.get("owners")) {
        (Some(ranks), Some(_)) => {
            let owners = get("owners", nc)?;
            if owners
                .iter()
                .any(|&r| !(r >= 0.0 && r.fract() == 0.0 && r < ranks as f64))
            {
                return Err(checkpoint_error(
                    out,
                    format!("array \"owners\" names a rank outside 0..{ranks}"),
                ));
            }
            Some(Split {
                ranks: ranks as usize,
                owners: owners.iter().map(|&r| r as usize).collect(),
            })
        }
        _ => None,
    };
    let meta = |key: &str| -> Result<usize, CellRunError> {
        ck.meta[key]
            .as_u64()
            .map(|v| v as usize)
            .ok_or_else(|| checkpoint_error(out, format!("header has no \"{key}\"")))
    };
    let prog = Progress {
        step: meta("step")?,
        frame_times,
        iters_sum: meta("iters_sum")?,
        iters_max: meta("iters_max")?,
        step_s: clocks[0],
        output_s: clocks[1],
        wall_s: clocks[2],
        min_gap: clocks[3],
        start_obs: start
            .chunks_exact(6)
            .map(|c| std::array::from_fn(|k| c[k]))
            .collect(),
        time: time_steps[0],
        dt: time_steps[1],
        last_dt: time_steps[2],
        dt_used: [time_steps[3], time_steps[4]],
        rejected: time_steps[5] as usize,
        above_tolerance: time_steps[6] as usize,
        error_sum: time_steps[7],
    };
    if !(prog.dt.is_finite() && prog.dt > 0.0 && prog.time.is_finite()) {
        return Err(checkpoint_error(
            out,
            format!(
                "time_steps: time {} and dt {} are not usable",
                prog.time, prog.dt
            ),
        ));
    }
    Ok((prog, states, split))
}

//! The per-step record of a cell run, `DIR/observables.csv`, and what a failed run leaves.
//!
//! One row per accepted step: `step, time, dt, gmres_max, gmres_mean, min_gap,
//! area_volume_error, end_gap, extra_dissipation, relative_viscosity`. `gmres_max` and `gmres_mean` are the step's GMRES iterations over the
//! cells, `min_gap` the smallest distance of a grid point to another cell's surface seen by
//! the coupling's near-zone monitor (empty when no point was near another cell, and for one
//! cell), `area_volume_error` the step's relative area/volume change before the drift
//! correction (the adaptive step's error estimate), `end_gap` the smallest surface gap at the end
//! of the step as the contact projection measured it (`[numerics] contact_distance` set; empty
//! otherwise, and when no gap is below `3 d_min`), `extra_dissipation` the power the cells add
//! to the background flow's, `P − P₀` by the reciprocal theorem
//! ([`crate::timestep::suspension::Suspension::extra_dissipation`]; empty without a flow), and
//! `relative_viscosity` the apparent viscosity of a tube flow's straight section
//! `μ_app/μ = 1 + (P − P₀)/(Q G L)` (flow rate `Q`, pressure gradient `G`, the section's length
//! `L`), or of a channel flow's flat part, `1 + (P − P₀)/(q G A)` (flow rate per unit width
//! `q`, the plates' flat area `A`); empty for other flows. Tables of the 7 or 8 columns before
//! these are read as ones without them. The file is rewritten atomically with every checkpoint and when a run fails; a resumed run keeps the rows up to its checkpoint.
//!
//! When a step fails, `summary.json` says so (`completed = false`, the error, the last good
//! step and time, the step of the last checkpoint, which is kept, and the last row), and
//! `observables.csv` holds every step up to the failure.

use std::path::Path;

use serde::Serialize;

use super::error::CellRunError;
use crate::io::write_atomic;

/// The file's name in the output directory.
pub const FILE: &str = "observables.csv";

const HEADER: &str = "step,time,dt,gmres_max,gmres_mean,min_gap,area_volume_error,end_gap,\
                      extra_dissipation,relative_viscosity";

/// The header of the tables written before `extra_dissipation`.
const HEADER_8: &str = "step,time,dt,gmres_max,gmres_mean,min_gap,area_volume_error,end_gap";

/// The header of the tables written before `end_gap`.
const HEADER_7: &str = "step,time,dt,gmres_max,gmres_mean,min_gap,area_volume_error";

/// One accepted step.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct StepRow {
    /// Step number (from 1).
    pub step: usize,
    /// Time reached.
    pub time: f64,
    /// The step's size.
    pub dt: f64,
    /// Largest GMRES iterations over the cells.
    pub gmres_max: usize,
    /// Mean GMRES iterations over the cells.
    pub gmres_mean: f64,
    /// Smallest gap seen by the near-zone monitor (`None`: no near point).
    pub min_gap: Option<f64>,
    /// Relative area/volume change of the step before the drift correction.
    pub area_volume_error: f64,
    /// Smallest surface gap at the end of the step measured by the contact projection
    /// (`None`: no projection, or no gap below `3 d_min`).
    pub end_gap: Option<f64>,
    /// The cells' extra dissipation `P − P₀` in the background flow (`None`: no flow).
    pub extra_dissipation: Option<f64>,
    /// A tube flow's relative apparent viscosity over its straight section (`None`: another
    /// flow).
    pub relative_viscosity: Option<f64>,
}

/// The rows so far.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Observables {
    rows: Vec<StepRow>,
}

/// A table that cannot be read back (only a resume reads it).
fn io_error(path: &Path, message: String) -> CellRunError {
    CellRunError::Resume(format!("{}: {message}", path.display()))
}

impl Observables {
    /// The rows of `out/observables.csv` up to step `up_to` (a resumed run); none when the
    /// file is absent. A file that is not this table is an error naming its line.
    pub fn resume(out: &Path, up_to: usize) -> Result<Self, CellRunError> {
        let path = out.join(FILE);
        let text = match std::fs::read_to_string(&path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Self::default()),
            Err(e) => return Err(io_error(&path, e.to_string())),
        };
        let mut lines = text.lines().enumerate();
        let columns = match lines.next() {
            Some((_, h)) if h == HEADER => 10,
            Some((_, h)) if h == HEADER_8 => 8,
            Some((_, h)) if h == HEADER_7 => 7,
            _ => {
                return Err(io_error(
                    &path,
                    format!("line 1: expected the header \"{HEADER}\""),
                ))
            }
        };
        let mut rows = Vec::new();
        for (i, line) in lines {
            let f: Vec<&str> = line.split(',').collect();
            let bad = || {
                io_error(
                    &path,
                    format!("line {}: not a row of {columns} numbers: {line}", i + 1),
                )
            };
            if f.len() != columns {
                return Err(bad());
            }
            let num = |s: &str| s.parse::<f64>().map_err(|_| bad());
            let count = |s: &str| s.parse::<usize>().map_err(|_| bad());
            let optional = |k: usize| match f.get(k) {
                Some(g) if !g.is_empty() => num(g).map(Some),
                _ => Ok(None),
            };
            let row = StepRow {
                step: count(f[0])?,
                time: num(f[1])?,
                dt: num(f[2])?,
                gmres_max: count(f[3])?,
                gmres_mean: num(f[4])?,
                min_gap: if f[5].is_empty() {
                    None
                } else {
                    Some(num(f[5])?)
                },
                area_volume_error: num(f[6])?,
                end_gap: optional(7)?,
                extra_dissipation: optional(8)?,
                relative_viscosity: optional(9)?,
            };
            if row.step <= up_to {
                rows.push(row);
            }
        }
        Ok(Observables { rows })
    }

    /// Add a step's row.
    pub fn push(&mut self, row: StepRow) {
        self.rows.push(row);
    }

    /// The last row.
    pub fn last(&self) -> Option<&StepRow> {
        self.rows.last()
    }

    /// The table as CSV text (floats in Rust's shortest round-trip form).
    pub fn to_csv(&self) -> String {
        let mut s = String::with_capacity(64 * (self.rows.len() + 1));
        s.push_str(HEADER);
        s.push('\n');
        for r in &self.rows {
            let opt = |v: Option<f64>| v.map(|g| format!("{g:?}")).unwrap_or_default();
            s.push_str(&format!(
                "{},{:?},{:?},{},{:?},{},{:?},{},{},{}\n",
                r.step,
                r.time,
                r.dt,
                r.gmres_max,
                r.gmres_mean,
                opt(r.min_gap),
                r.area_volume_error,
                opt(r.end_gap),
                opt(r.extra_dissipation),
                opt(r.relative_viscosity)
            ));
        }
        s
    }

    /// Write `out/observables.csv` atomically.
    pub fn write(&self, out: &Path) -> Result<(), CellRunError> {
        write_atomic(&out.join(FILE), self.to_csv().as_bytes())?;
        Ok(())
    }
}

/// `summary.json` of a run whose step failed.
#[derive(Clone, Debug, Serialize)]
pub struct FailedRunSummary {
    /// Always `false`.
    pub completed: bool,
    /// The error, as `mobo run` prints it.
    pub error: String,
    /// The last step that succeeded (0: the first step failed).
    pub last_good_step: usize,
    /// The time it reached.
    pub last_good_time: f64,
    /// The step of the last checkpoint written (kept: `mobo run --resume` continues from it;
    /// `None`: none yet).
    pub last_checkpoint_step: Option<usize>,
    /// Cells of the run.
    pub cells: usize,
    /// SH order.
    pub order: usize,
    /// The scene's `Δt`.
    pub dt: f64,
    /// `"euler"` or `"bdf2"`.
    pub scheme: &'static str,
    /// `"explicit"` or `"near_implicit"`.
    pub coupling: &'static str,
    /// The last step's row of `observables.csv` (which holds every step up to the failure).
    pub last_observables: Option<StepRow>,
    /// Wall seconds of this invocation up to the failure.
    pub wall_s: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_round_trip_and_a_resume_keeps_those_up_to_its_step() {
        let dir = std::env::temp_dir().join(format!("mobo-observables-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut o = Observables::default();
        for k in 1..=4 {
            o.push(StepRow {
                step: k,
                time: 0.1 * k as f64,
                dt: 0.1,
                gmres_max: k + 2,
                gmres_mean: 2.5,
                min_gap: (k % 2 == 0).then_some(0.01 / k as f64),
                area_volume_error: 1e-9 * k as f64,
                end_gap: (k % 3 == 0).then_some(0.02 * k as f64),
                extra_dissipation: (k > 1).then_some(0.3 * k as f64),
                relative_viscosity: (k > 2).then_some(1.0 + 0.1 * k as f64),
            });
        }
        o.write(&dir).unwrap();
        assert_eq!(Observables::resume(&dir, 10).unwrap(), o);
        let kept = Observables::resume(&dir, 2).unwrap();
        assert_eq!(kept.rows, o.rows[..2].to_vec());
        // A table written before end_gap reads with no end gaps.
        std::fs::write(
            dir.join(FILE),
            format!("{HEADER_7}\n1,0.1,0.1,3,2.5,,1e-9\n"),
        )
        .unwrap();
        let old = Observables::resume(&dir, 10).unwrap();
        assert_eq!(old.rows.len(), 1);
        assert_eq!((old.rows[0].end_gap, old.rows[0].gmres_max), (None, 3));
        // One written before extra_dissipation, with no dissipation.
        std::fs::write(
            dir.join(FILE),
            format!("{HEADER_8}\n1,0.1,0.1,3,2.5,,1e-9,0.04\n"),
        )
        .unwrap();
        let old = Observables::resume(&dir, 10).unwrap();
        assert_eq!(
            (old.rows[0].end_gap, old.rows[0].extra_dissipation),
            (Some(0.04), None)
        );
        // A damaged file names its line.
        std::fs::write(dir.join(FILE), format!("{HEADER}\n1,0.1,0.1,3\n")).unwrap();
        let e = Observables::resume(&dir, 10).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains(FILE), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(
            Observables::resume(&dir, 3).unwrap(),
            Observables::default()
        );
    }
}

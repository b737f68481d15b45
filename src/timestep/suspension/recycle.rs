//! Cells recycled through a tube: a finite tube that behaves, for its cells, like a periodic
//! one.
//!
//! A tube wall (`crate::wall::tube_surface`) is closed: Poiseuille's flow enters and leaves
//! through its rounded ends, and cells carried by the flow would gather at the outlet within
//! one transit. Lu, Morse, Rahimian, Stadler & Zorin (SC'19) keep a vessel's hematocrit the
//! same way: a cell that leaves through an outlet is put back at an inlet. Here the tube's
//! straight middle section `x_in ≤ x ≤ x_out` (where its radius is that of a cylinder) is the
//! window: after every step (after the contact projection), a cell whose centre
//! `c_00/√(4π)` has passed `x_out` is translated by `−P = x_in − x_out` along the axis, the
//! window's length, with its previous surface (BDF2's history) and the rest of its state, as
//! the contact projection moves cells. The cell keeps its shape, tension and radial position;
//! the flow in the straight section is the same at both places, so its velocity carries over.
//!
//! A cell is moved where it lands clear of every other cell and of the walls by at least
//! [`Recycling::clearance`] (the contact solver's measure,
//! [`crate::timestep::contact::ContactSolver::first_clear_or_best`]). Where its periodic image
//! is taken (by a cell that entered upstream meanwhile), the landing is tried turned about the
//! tube's axis by `±30°, ±60°, …, 180°` in that order ([`LANDING_TURNS`]): the tube and
//! Poiseuille's flow are axisymmetric, so a cell turned about the axis is the same cell in the
//! same flow at another azimuth. Where no turn is that clear but the best one leaves the
//! surfaces apart (a positive gap) and the suspension has a contact projection, the cell lands
//! there and the projection runs again at once, restoring `d_min` (counted as `projected`): two
//! cells that travel side by side closer than the clearance reach the outlet one after the
//! other, and the second's image lies that close to the first's. Where neither, the same is
//! tried further upstream in steps of 0.5 ([`landing_backs`], in the solver's length unit, the
//! cells' radius) up to 1.5 beyond the inlet, into the entrance of the tube's rounded inlet
//! end, where the flow is still nearly Poiseuille's and carries the cell into the window (the
//! run is not periodic: a cell near the outlet does not feel the cells near the inlet, so its
//! image can come to overlap one of them; and a cell deferred into the outlet's end has its
//! image deep in the window). The turn moves its whole state: the surface and BDF2's previous surface
//! (every mode's vector turned), the velocities and densities kept on its grid (every point's
//! vector turned), while its tension and Skalak reference (the reference metric, unchanged by a
//! rigid motion) stay; its own preconditioner is rebuilt. Where no place will do, the cell
//! goes on toward the outlet and is tried again at the next step (counted as deferred).
//! Cells are tried in the order of their global index, each against the others as already
//! moved, and every rank decides the same moves from the gathered surfaces, so the result does
//! not depend on the number of ranks.

use super::super::cell_state::CellState;
use super::super::contact::{ContactParams, ContactSolver, Move};
use super::{CellStepError, Suspension};
use crate::comm::Communicator;
use crate::timestep::TimestepError;

/// The turns about the tube's axis at which a recycled cell may land, in the order tried (in
/// units of 30°): its periodic image first, then ever larger turns either way.
pub const LANDING_TURNS: [i32; 12] = [0, 1, -1, 2, -2, 3, -3, 4, -4, 5, -5, 6];

/// The step between the distances further upstream than its periodic image a recycled cell
/// may land ([`landing_backs`]; each with every turn of [`LANDING_TURNS`]).
pub const LANDING_BACK_STEP: f64 = 0.5;

/// How far upstream of the inlet a recycled cell may land (in the solver's length unit).
pub const LANDING_BEYOND_INLET: f64 = 1.5;

/// The distances further upstream than its periodic image tried for a cell whose centre has
/// passed the outlet by `past`: `0, 0.5, 1, …` while the place stays within
/// [`LANDING_BEYOND_INLET`] of the inlet (so a cell carried deep into the outlet's end can
/// still come back at the inlet).
pub fn landing_backs(past: f64) -> impl Iterator<Item = f64> {
    let n = ((past.max(0.0) + LANDING_BEYOND_INLET) / LANDING_BACK_STEP).floor() as usize;
    (0..=n).map(|k| k as f64 * LANDING_BACK_STEP)
}

/// Where a tube's cells leave and re-enter ([`Suspension::set_recycling`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Recycling {
    /// The outlet `x_out`: a cell whose centre passes it is moved back by [`Self::period`].
    pub outlet: f64,
    /// The window's length `P = x_out − x_in`.
    pub period: f64,
    /// The smallest gap to other cells and walls at which a moved cell may land.
    pub clearance: f64,
    /// A point of the tube's axis, which is parallel to `x` (the centre of the tube).
    pub axis: [f64; 3],
}

impl Recycling {
    /// The move that lands a cell past the outlet turned by `turn` × 30° about the axis and
    /// `back` further upstream than its periodic image.
    pub fn landing(&self, turn: i32, back: f64) -> Move {
        let (s, c) = (f64::from(turn) * std::f64::consts::PI / 6.0).sin_cos();
        Move {
            centre: self.axis,
            rotation: [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]],
            translation: [-self.period - back, 0.0, 0.0],
        }
    }
}

/// What the recycling did (cumulative; `summary.json`'s `counters.recycling`).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct RecycleStats {
    /// Cells moved from the outlet back to the inlet.
    pub recycled: usize,
    /// Steps at which a cell past the outlet could not land clear and went on.
    pub deferred: usize,
    /// Cells that landed turned about the axis (their periodic image was taken).
    pub turned: usize,
    /// Cells that landed upstream of their periodic image (no turn of it was clear).
    pub upstream: usize,
    /// Cells that landed closer than the clearance, after which the contact projection ran.
    pub projected: usize,
    /// Seconds spent deciding and moving.
    pub seconds: f64,
}

impl Suspension {
    /// Recycle cells through a tube's window after every step (module docs; `None`: off).
    pub fn set_recycling(&mut self, recycling: Option<Recycling>) {
        self.recycling = recycling;
    }

    /// The recycling set by [`Suspension::set_recycling`].
    pub fn recycling(&self) -> Option<Recycling> {
        self.recycling
    }

    /// What the recycling did.
    pub fn recycle_stats(&self) -> RecycleStats {
        self.recycle_stats
    }

    /// Move the cells past the outlet back by the window's length where they land clear
    /// (collective).
    pub(super) fn recycle(&mut self, comm: &dyn Communicator) -> Result<(), CellStepError> {
        let Some(r) = self.recycling else {
            return Ok(());
        };
        let t0 = std::time::Instant::now();
        let s = (4.0 * std::f64::consts::PI).sqrt();
        let fail = |source| CellStepError { cell: None, source };
        // The surfaces are gathered only at the steps where some rank has a cell past the
        // outlet.
        let mut any = [self
            .cells
            .iter()
            .filter(|c| c.state.coefs[0] / s > r.outlet)
            .count() as u64];
        comm.all_sum_u64(&mut any)
            .map_err(|e| fail(TimestepError::Comm(e)))?;
        let mut moved = Vec::new();
        // Whether a cell landed closer than the clearance (every rank decides the same).
        let mut project = false;
        if any[0] > 0 {
            let (ids, mut coefs) = self.all_surfaces(comm)?;
            let past: Vec<usize> = (0..ids.len())
                .filter(|&k| coefs[k][0] / s > r.outlet)
                .collect();
            // Every cell has the suspension's order: 3 (p + 1)² coefficients.
            let p = ((coefs[0].len() / 3) as f64).sqrt().round() as usize - 1;
            let solver = ContactSolver::new(p, ContactParams::new(r.clearance))
                .map_err(|e| fail(TimestepError::Contact(e)))?;
            let fixed = self
                .walls
                .as_ref()
                .map(|w| w.fixed_surfaces())
                .unwrap_or(&[]);
            // Every cell's distance surface once; a landed or deferred cell's is set to where
            // it stays.
            let views: Vec<&[f64]> = coefs.iter().map(|c| c.as_slice()).collect();
            let mut prepared = solver
                .prepare(&views)
                .map_err(|e| fail(TimestepError::Contact(e)))?;
            for k in past {
                // Each distance upstream with every turn: the first clear place, else (with
                // a projection) the best that leaves the surfaces apart.
                let mut landed = false;
                for back in landing_backs(coefs[k][0] / s - r.outlet) {
                    let places: Vec<Vec<f64>> = LANDING_TURNS
                        .iter()
                        .map(|&t| {
                            let mut c = coefs[k].clone();
                            r.landing(t, back).apply(&mut c);
                            c
                        })
                        .collect();
                    let (i, gap) = solver
                        .first_clear_or_best(
                            &mut prepared,
                            k,
                            &places,
                            fixed,
                            r.clearance,
                            2.0 * r.clearance,
                        )
                        .map_err(|e| fail(TimestepError::Contact(e)))?;
                    let pressed = gap < r.clearance;
                    if pressed && !(gap > 0.0 && self.contacts.is_some()) {
                        continue;
                    }
                    coefs[k].clone_from(&places[i]);
                    moved.push((ids[k], (LANDING_TURNS[i], back)));
                    if pressed {
                        self.recycle_stats.projected += 1;
                        project = true;
                    }
                    landed = true;
                    break;
                }
                if !landed {
                    self.recycle_stats.deferred += 1;
                }
                solver
                    .set(&mut prepared, k, &coefs[k])
                    .map_err(|e| fail(TimestepError::Contact(e)))?;
            }
        }
        for c in &mut self.cells {
            if let Some(&(_, (turn, back))) = moved.iter().find(|m| m.0 == c.id) {
                land(&mut c.state, &r.landing(turn, back));
            }
        }
        self.recycle_stats.turned += moved.iter().filter(|m| m.1 .0 != 0).count();
        self.recycle_stats.upstream += moved.iter().filter(|m| m.1 .1 > 0.0).count();
        if project {
            self.resolve_contacts(comm)?;
        }
        self.recycle_stats.recycled += moved.len();
        self.recycle_stats.seconds += t0.elapsed().as_secs_f64();
        Ok(())
    }
}

/// Move a cell's state by the rigid `m` (a landing, [`Recycling::landing`]):
/// [`super::rigid_move::move_state`], with its own preconditioner dropped when `m` turns it.
fn land(state: &mut CellState, m: &Move) {
    super::rigid_move::move_state(state, m);
    if m.turns() {
        state.preconditioner = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vesicle::shapes;

    /// Just past the outlet the places reach 1.5 upstream of the image; 2.5 past it, 4.0
    /// (still 1.5 beyond the inlet).
    #[test]
    fn landing_places_reach_back_beyond_the_inlet() {
        let backs = |past: f64| landing_backs(past).collect::<Vec<f64>>();
        assert_eq!(backs(0.03), [0.0, 0.5, 1.0, 1.5]);
        assert_eq!(backs(-0.1), [0.0, 0.5, 1.0, 1.5]);
        assert_eq!(backs(2.5).len(), 9);
        assert_eq!(backs(2.5).last(), Some(&4.0));
    }

    /// A landing turned by 90° about the axis moves a sphere at `(x, 1.5, 0)` (axis through
    /// `(0, 0.2, −0.1)`: `(1.3, 0.1)` from it) to `(x − P, 0.2 − 0.1, −0.1 + 1.3)`, its previous
    /// surface alike, turns
    /// every grid vector `(a, b, c) ↦ (a, −c, b)`, keeps the tension and drops the
    /// preconditioner; the unturned landing only translates, bit for bit as `c_00 −= P √(4π)`.
    #[test]
    fn a_turned_landing_moves_the_whole_state() {
        let p = 4;
        let mut s = shapes::sphere(p, 1.0).unwrap();
        s.translate([3.0, 1.5, 0.0]);
        let n = 10;
        let field: Vec<f64> = (0..3 * n)
            .map(|k| (k / n + 1) as f64 + 0.01 * k as f64)
            .collect();
        let state = CellState {
            coefs: s.coefs().to_vec(),
            sigma: vec![0.7; n],
            drift_targets: None,
            previous_coefs: Some(s.coefs().to_vec()),
            previous_dt: Some(0.01),
            membrane_velocity: Some(field.clone()),
            skalak_reference: None,
            material_labels: None,
            velocity: Some(field.clone()),
            previous_velocity: Some(field.clone()),
            iterations: 3,
            preconditioner: Some(crate::timestep::cell_state::PreconditionerRecord {
                surface: s.coefs().to_vec(),
                tau: 0.01,
                jacobian_reference: None,
                last_iterations: 2,
            }),
            previous_density: Some([field.clone(), field.clone()].concat()),
        };
        let r = Recycling {
            outlet: 2.0,
            period: 5.0,
            clearance: 0.1,
            axis: [0.0, 0.2, -0.1],
        };
        let sq = (4.0 * std::f64::consts::PI).sqrt();
        let nc = state.coefs.len() / 3;
        let centre = |c: &[f64]| [c[0] / sq, c[nc] / sq, c[2 * nc] / sq];
        let mut turned = state.clone();
        land(&mut turned, &r.landing(3, 0.0));
        for c in [&turned.coefs, turned.previous_coefs.as_ref().unwrap()] {
            let got = centre(c);
            let want = [-2.0, 0.2 - 0.1, -0.1 + 1.3];
            assert!((0..3).all(|k| (got[k] - want[k]).abs() < 1e-12), "{got:?}");
        }
        let turn = |v: &[f64]| -> Vec<f64> {
            let mut out = v.to_vec();
            for j in 0..n {
                out[n + j] = -v[2 * n + j];
                out[2 * n + j] = v[n + j];
            }
            out
        };
        let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12);
        for v in [
            &turned.membrane_velocity,
            &turned.velocity,
            &turned.previous_velocity,
        ] {
            assert!(close(v.as_ref().unwrap(), &turn(&field)));
        }
        let d = turned.previous_density.as_ref().unwrap();
        assert!(close(&d[..3 * n], &turn(&field)) && close(&d[3 * n..], &turn(&field)));
        assert_eq!(turned.sigma, state.sigma);
        assert!(turned.preconditioner.is_none());
        // Unturned: a translation of the constant modes only, the rest as it was.
        let mut moved = state.clone();
        land(&mut moved, &r.landing(0, 0.0));
        let mut want = state.clone();
        want.coefs[0] -= 5.0 * sq;
        want.previous_coefs.as_mut().unwrap()[0] -= 5.0 * sq;
        assert_eq!(moved, want);
    }
}

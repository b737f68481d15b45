//! Rigid walls in a suspension's step ([`super::super::wall_coupling`]): after the inter-cell
//! velocity, the walls are solved for the cells' tractions and double layers at the start of
//! the step, and their velocity at each cell's grid points is added to that cell's explicit
//! velocity (so BDF2 extrapolates it with the rest).

use super::super::wall_coupling::{WallCoupling, WallStats};
use super::super::TimestepError;
use super::{CellStepError, Suspension};
use crate::comm::Communicator;

impl Suspension {
    /// Put the cells between rigid walls (`None`: free space, the default).
    pub fn set_walls(&mut self, walls: Option<WallCoupling>) {
        self.walls = walls;
    }

    /// The walls, if any.
    pub fn walls(&self) -> Option<&WallCoupling> {
        self.walls.as_ref()
    }

    /// What the walls did (zeros without walls).
    pub fn wall_stats(&self) -> WallStats {
        self.walls.as_ref().map(|w| w.stats()).unwrap_or_default()
    }

    /// Add the walls' velocity to every cell's explicit velocity (nothing without walls).
    pub(super) fn add_wall_velocities(
        &mut self,
        comm: &dyn Communicator,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        tractions: &[Vec<f64>],
        double_layers: &[Option<Vec<f64>>],
    ) -> Result<(), CellStepError> {
        let Some(walls) = &mut self.walls else {
            return Ok(());
        };
        let fail = |source| CellStepError { cell: None, source };
        if comm.size() > 1 {
            return Err(fail(TimestepError::InvalidParameter {
                name: "walls",
                value: format!("{} ranks", comm.size()),
                reason: "cells between walls run on one rank for now",
            }));
        }
        let Some(first) = self.cells.first() else {
            return Ok(());
        };
        let p = first.stepper.order();
        let mut points = Vec::with_capacity(self.cells.len());
        for c in &self.cells {
            points.push(
                c.stepper
                    .with_geometry(&c.state.coefs, |g| g.x.clone())
                    .map_err(|source| CellStepError {
                        cell: Some(c.id),
                        source,
                    })?,
            );
        }
        let coefs: Vec<&[f64]> = self.cells.iter().map(|c| &c.state.coefs[..]).collect();
        let fref: Vec<&[f64]> = tractions.iter().map(|f| f.as_slice()).collect();
        let dref: Vec<Option<&[f64]>> = double_layers.iter().map(|d| d.as_deref()).collect();
        let velocities = walls
            .velocities(p, u_inf, &coefs, &points, &fref, &dref)
            .map_err(fail)?;
        for (c, v) in self.cells.iter_mut().zip(velocities) {
            match &mut c.state.velocity {
                Some(u) => {
                    for (a, b) in u.iter_mut().zip(&v) {
                        *a += b;
                    }
                }
                None => c.state.velocity = Some(v),
            }
        }
        Ok(())
    }
}

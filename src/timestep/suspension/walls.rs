//! Rigid walls in a suspension's step ([`super::super::wall_coupling`]): after the inter-cell
//! velocity, the walls are solved for the cells' tractions and double layers at the start of
//! the step, and their velocity at each cell's grid points is added to that cell's explicit
//! velocity (so BDF2 extrapolates it with the rest). Over MPI ranks each rank sums its own
//! cells' layers at the walls, the sums are added over the ranks in rank order
//! ([`crate::comm::sum_in_rank_order`]: `3 N_wall` values a rank each way, whatever the number
//! of cells), and every rank solves the same wall system.

use super::super::image_quadrature::ImageLayers;
use super::super::plane_coupling::{ImageCell, PlaneCoupling, PlaneStats};
use super::super::wall_coupling::{WallCoupling, WallStats};
use super::super::TimestepError;
use super::{agree_cells, CellStepError, Suspension};
use crate::comm::{sum_in_rank_order, Communicator};
use crate::vesicle::Geometry;

impl Suspension {
    /// Put the cells between rigid walls (`None`: free space, the default).
    pub fn set_walls(&mut self, walls: Option<WallCoupling>) {
        self.walls = walls;
    }

    /// The walls, if any.
    pub fn walls(&self) -> Option<&WallCoupling> {
        self.walls.as_ref()
    }

    /// Put the cells beside a plane wall (`None`: none, the default).
    pub fn set_plane(&mut self, plane: Option<PlaneCoupling>) {
        self.near_pairs.set_plane(plane.as_ref().map(|p| *p.wall()));
        self.plane = plane;
    }

    /// The plane wall, if any.
    pub fn plane(&self) -> Option<&PlaneCoupling> {
        self.plane.as_ref()
    }

    /// What the plane wall did (zeros without one).
    pub fn plane_stats(&self) -> PlaneStats {
        self.plane.as_ref().map(|w| w.stats()).unwrap_or_default()
    }

    /// Add the plane wall's velocity (the images of every cell's single and double layers) to
    /// every cell's explicit velocity (nothing without a plane; collective over the ranks of
    /// `comm`).
    pub(super) fn add_plane_velocities(
        &mut self,
        comm: &dyn Communicator,
        tractions: &[Vec<f64>],
        double_layers: &[Option<Vec<f64>>],
    ) -> Result<(), CellStepError> {
        let Some(plane) = &mut self.plane else {
            return Ok(());
        };
        // This rank's cells' point forces and double-layer sources, by global index, with
        // what the refinement near the mirror builds finer rules from: the order, surface,
        // traction and double-layer density.
        let mut local = Vec::new();
        let mut mine = Ok(());
        let mut points = Vec::with_capacity(self.cells.len());
        for (slot, c) in self.cells.iter().enumerate() {
            let p = c.stepper.order();
            let layers = ImageLayers {
                coefs: &c.state.coefs,
                traction: &tractions[slot],
                double_layer: double_layers[slot].as_deref(),
            };
            let got = plane.cell_sources(slot, p, layers).and_then(|s| {
                let x = c.stepper.with_geometry(&c.state.coefs, |g| g.x.clone())?;
                Ok((s, x))
            });
            match got {
                Ok((sources, x)) => {
                    local.push((slot, c.id, [p as f64], sources));
                    points.push(x);
                }
                Err(source) => {
                    mine = Err(CellStepError {
                        cell: Some(c.id),
                        source,
                    });
                    break;
                }
            }
        }
        agree_cells(comm, mine)?;
        let fail = |source| CellStepError { cell: None, source };
        let blocks: Vec<(usize, [&[f64]; 6])> = local
            .iter()
            .map(|(slot, id, p, (single, double))| {
                (
                    *id,
                    [
                        single.as_slice(),
                        double.as_slice(),
                        p.as_slice(),
                        self.cells[*slot].state.coefs.as_slice(),
                        tractions[*slot].as_slice(),
                        double_layers[*slot].as_deref().unwrap_or(&[]),
                    ],
                )
            })
            .collect();
        let all = super::gather::gather_by_cell(comm, &blocks)?;
        let single: Vec<f64> = all.iter().flat_map(|a| a.1[0].iter().copied()).collect();
        let double: Vec<f64> = all.iter().flat_map(|a| a.1[1].iter().copied()).collect();
        let mut near = Vec::with_capacity(all.len());
        let (mut s0, mut d0) = (0, 0);
        for (_, [s, d, p, coefs, traction, g]) in &all {
            let (s1, d1) = (s0 + s.len() / 6, d0 + d.len() / 9);
            near.push(ImageCell {
                p: p.first().map_or(0, |&v| v as usize),
                layers: ImageLayers {
                    coefs,
                    traction,
                    double_layer: (!g.is_empty()).then_some(g.as_slice()),
                },
                single: s0..s1,
                double: d0..d1,
            });
            (s0, d0) = (s1, d1);
        }
        // The same sources on every rank; a cell on the plane fails on its rank.
        let velocities = agree_cells(
            comm,
            plane
                .velocities(&single, &double, &near, &points)
                .map_err(fail),
        )?;
        self.add_explicit_velocities(velocities);
        Ok(())
    }

    /// What the walls did (zeros without walls).
    pub fn wall_stats(&self) -> WallStats {
        self.walls.as_ref().map(|w| w.stats()).unwrap_or_default()
    }

    /// Add the walls' velocity to every cell's explicit velocity (nothing without walls;
    /// collective over the ranks of `comm`).
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
        let sent = comm.bytes_sent();
        let nw = walls.n_wall_points();
        // Each cell's geometry, once: its normals and weights for the double layer's flux, its
        // grid points as the targets of the walls' velocity.
        let geometries: Result<Vec<Geometry>, CellStepError> = self
            .cells
            .iter()
            .map(|c| {
                c.stepper
                    .with_geometry(&c.state.coefs, |g| g.clone())
                    .map_err(|source| CellStepError {
                        cell: Some(c.id),
                        source,
                    })
            })
            .collect();
        let geometries = agree_cells(comm, geometries)?;
        // This rank's cells at the walls, summed in the order of their global indices (on one
        // rank the one-process order), then over the ranks in rank order.
        let mut order: Vec<usize> = (0..self.cells.len()).collect();
        order.sort_by_key(|&slot| self.cells[slot].id);
        let mut partial = vec![0.0; 3 * nw];
        let mut mine = Ok(());
        for slot in order {
            let c = &self.cells[slot];
            let at = walls.cell_at_walls(
                slot,
                &c.state.coefs,
                &geometries[slot],
                &tractions[slot],
                double_layers[slot].as_deref(),
            );
            match at {
                Ok(v) => {
                    for (t, x) in partial.iter_mut().zip(&v) {
                        *t += x;
                    }
                }
                Err(source) => {
                    mine = Err(CellStepError {
                        cell: Some(c.id),
                        source,
                    });
                    break;
                }
            }
        }
        agree_cells(comm, mine)?;
        let total = sum_in_rank_order(comm, &partial).map_err(|e| fail(TimestepError::Comm(e)))?;
        let points: Vec<Vec<[f64; 3]>> = geometries.into_iter().map(|g| g.x).collect();
        // The same data and system on every rank: a failure is every rank's.
        let velocities = walls.velocities(comm, u_inf, &total, &points);
        walls.count_exchange(comm.bytes_sent() - sent);
        let velocities = velocities.map_err(fail)?;
        self.add_explicit_velocities(velocities);
        Ok(())
    }

    /// Add `velocities` (per cell held here, in order) to each cell's explicit velocity.
    fn add_explicit_velocities(&mut self, velocities: Vec<Vec<f64>>) {
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
    }
}

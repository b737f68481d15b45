//! Cells between rigid walls: the walls' velocity at the cells, once per step.
//!
//! With walls ([`crate::wall`]) the velocity in the fluid is
//! `u = u_∞ + Σ_cells (S_j[f_j] + (1 − λ_j) D_j[u_j]) + u_walls`, and the walls' double-layer
//! densities make `u` equal the walls' own velocity `U_w` on them:
//!
//! ```text
//! A ψ = U_w − u_∞(x_w) − Σ_j (S_j[f_j] + (1 − λ_j) D_j[u_j])(x_w)
//! ```
//!
//! (`A` the completed wall operator, factored once). [`WallCoupling::velocities`] evaluates the
//! cells' layers at the wall points (each cell's smooth quadrature at order `3p` where its
//! bounding sphere is far enough for it, [`SmoothLayer`]; the off-surface evaluation of
//! [`crate::vesicle::near`] elsewhere: near-singular close to the cell), solves, and evaluates
//! `u_walls` at every cell's grid points the same way ([`WallField`]). The
//! suspension adds it to the inter-cell velocity, so it enters a step the way that velocity
//! does: explicitly, from the densities at the start of the step, extrapolated by BDF2.
//!
//! The walls' part is a direct evaluation, `O(N_wall · N_cells · q²)` a step, on one rank; the
//! FMM does not carry the walls yet.

use std::time::Instant;

use super::contact::FixedSurface;
use super::TimestepError;
use crate::vesicle::smooth_layer::{Side, SmoothLayer};
use crate::vesicle::{LayerKernel, NearParams, OffSurface};
use crate::wall::{
    scatter_add, Wall, WallError, WallField, WallKind, WallParams, WallSolution, WallSystem,
};

/// What the walls did (cumulative).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct WallStats {
    /// Walls.
    pub walls: usize,
    /// Unknowns of the wall system.
    pub unknowns: usize,
    /// Seconds to assemble and factor the wall system.
    pub setup_seconds: f64,
    /// Wall solves (one a step).
    pub solves: usize,
    /// Seconds in the steps' wall work (cells at the walls, solve, walls at the cells).
    pub seconds: f64,
    /// Of which: the cells' layers at the wall points.
    pub cells_at_walls_seconds: f64,
    /// Of which: the walls' velocity at the cells' grid points.
    pub walls_at_cells_seconds: f64,
    /// Largest wall velocity at a cell point in the last step.
    pub last_speed: f64,
    /// The smallest distance of a cell's grid point to a wall in the last step, and over the
    /// run (`None`: no cell point came within a wall's near zone).
    pub last_gap: Option<f64>,
    /// Over the run.
    pub smallest_gap: Option<f64>,
}

fn wall_error(e: WallError) -> TimestepError {
    TimestepError::Wall(e.to_string())
}

/// The walls of a suspension: their factored operator, their prescribed velocity, and the
/// evaluators of the cells' layers at the walls and of the walls' velocity at the cells.
pub struct WallCoupling {
    system: WallSystem,
    field: WallField,
    /// `U_w` on every wall's grid (component-major per wall, walls in order).
    velocity: Vec<f64>,
    /// Every wall's grid points, in the order of `velocity`'s components.
    points: Vec<[f64; 3]>,
    viscosity: f64,
    /// One off-surface evaluator and one coarse smooth rule per cell slot, built on first use.
    cells: Vec<(OffSurface, SmoothLayer)>,
    last: Option<WallSolution>,
    stats: WallStats,
    /// The walls as fixed surfaces of the contact projection.
    fixed: Vec<FixedSurface>,
}

impl WallCoupling {
    /// Walls moving with `velocity` (per wall, component-major on its grid; `None`: at rest),
    /// in a fluid of viscosity `viscosity`.
    pub fn new(
        walls: Vec<Wall>,
        velocity: Option<Vec<f64>>,
        viscosity: f64,
        params: WallParams,
    ) -> Result<Self, TimestepError> {
        if !(viscosity.is_finite() && viscosity > 0.0) {
            return Err(TimestepError::InvalidParameter {
                name: "viscosity",
                value: format!("{viscosity}"),
                reason: "must be positive and finite",
            });
        }
        let t0 = Instant::now();
        let system = WallSystem::new(walls, params).map_err(wall_error)?;
        let field = WallField::new(&system, NearParams::default()).map_err(wall_error)?;
        let n = system.n_unknowns();
        let velocity = velocity.unwrap_or_else(|| vec![0.0; n]);
        if velocity.len() != n {
            return Err(TimestepError::DimensionMismatch {
                what: "wall velocity",
                expected: n,
                got: velocity.len(),
            });
        }
        let points = system
            .walls()
            .iter()
            .flat_map(|w| w.geometry().x.iter().copied())
            .collect();
        let stats = WallStats {
            walls: system.walls().len(),
            unknowns: n,
            setup_seconds: t0.elapsed().as_secs_f64(),
            ..WallStats::default()
        };
        let fixed = system
            .walls()
            .iter()
            .map(|w| {
                FixedSurface::new(
                    w.order(),
                    w.surface().coefs(),
                    w.kind() == WallKind::Container,
                )
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(WallCoupling {
            fixed,
            system,
            field,
            velocity,
            points,
            viscosity,
            cells: vec![],
            last: None,
            stats,
        })
    }

    /// The wall system.
    pub fn system(&self) -> &WallSystem {
        &self.system
    }
    /// The walls as fixed surfaces of the contact projection ([`FixedSurface`]).
    pub fn fixed_surfaces(&self) -> &[FixedSurface] {
        &self.fixed
    }
    /// What the walls did.
    pub fn stats(&self) -> WallStats {
        self.stats
    }
    /// The last step's solution (the walls' densities and the bodies' forces).
    pub fn last_solution(&self) -> Option<&WallSolution> {
        self.last.as_ref()
    }

    /// The walls' velocity at every cell's grid points (`3n` each, component-major), for cells
    /// of order `p` with surfaces `coefs`, grid points `points`, tractions `tractions` and
    /// double-layer densities `(1 − λ_j) u_j` (`None`: no contrast), in the background flow
    /// `u_inf`.
    pub fn velocities(
        &mut self,
        p: usize,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        coefs: &[&[f64]],
        points: &[Vec<[f64; 3]>],
        tractions: &[&[f64]],
        double_layers: &[Option<&[f64]>],
    ) -> Result<Vec<Vec<f64>>, TimestepError> {
        let t0 = Instant::now();
        let nw = self.points.len();
        // The data: U_w − u_∞ − the cells' layers, walls' component-major blocks.
        let mut cells_at_walls = vec![0.0; 3 * nw];
        let mut buf = vec![];
        while self.cells.len() < coefs.len() {
            self.cells.push((
                OffSurface::new(p, NearParams::default())?,
                SmoothLayer::new(p, 3 * p, 3.0)?,
            ));
        }
        let sl = LayerKernel::SingleLayer {
            viscosity: self.viscosity,
        };
        let mut far = vec![];
        let mut near = vec![];
        for (j, c) in coefs.iter().enumerate() {
            let (s, coarse) = &mut self.cells[j];
            coarse.set_surface(c)?;
            far.clear();
            near.clear();
            for (i, &x) in self.points.iter().enumerate() {
                match coarse.side(x) {
                    Side::FarOutside => far.push(i),
                    _ => near.push(i),
                }
            }
            if !far.is_empty() {
                let xs: Vec<[f64; 3]> = far.iter().map(|&i| self.points[i]).collect();
                buf.clear();
                buf.resize(3 * xs.len(), 0.0);
                coarse.set_density(tractions[j])?;
                coarse.add_to(sl, &xs, &mut buf)?;
                if let Some(g) = double_layers[j] {
                    coarse.set_density(g)?;
                    coarse.add_to(LayerKernel::DoubleLayer, &xs, &mut buf)?;
                }
                scatter_add(&buf, &far, &mut cells_at_walls, nw);
            }
            if !near.is_empty() {
                let xs: Vec<[f64; 3]> = near.iter().map(|&i| self.points[i]).collect();
                let mut v = vec![0.0; 3 * xs.len()];
                s.set_surface(c)?;
                s.evaluate(sl, tractions[j], &xs, &mut v)?;
                scatter_add(&v, &near, &mut cells_at_walls, nw);
                if let Some(g) = double_layers[j] {
                    s.evaluate(LayerKernel::DoubleLayer, g, &xs, &mut v)?;
                    scatter_add(&v, &near, &mut cells_at_walls, nw);
                }
            }
        }
        let t1 = Instant::now();
        self.stats.cells_at_walls_seconds += (t1 - t0).as_secs_f64();
        let mut data = self.velocity.clone();
        let mut offset = 0;
        for w in self.system.walls() {
            let n = w.n_points();
            for (j, &x) in w.geometry().x.iter().enumerate() {
                let u = u_inf(x);
                for a in 0..3 {
                    // cells_at_walls is component-major over all wall points.
                    data[offset + a * n + j] -= u[a] + cells_at_walls[a * nw + offset / 3 + j];
                }
            }
            offset += 3 * n;
        }
        let solution = self.system.solve(&data).map_err(wall_error)?;
        let t2 = Instant::now();
        let mut out = Vec::with_capacity(points.len());
        let mut speed: f64 = 0.0;
        let mut gap = f64::INFINITY;
        for x in points {
            let mut u = vec![0.0; 3 * x.len()];
            gap = gap.min(
                self.field
                    .velocity(&solution, x, &mut u)
                    .map_err(wall_error)?,
            );
            let n = x.len();
            for i in 0..n {
                let s = (0..3).map(|a| u[a * n + i].powi(2)).sum::<f64>().sqrt();
                speed = speed.max(s);
            }
            out.push(u);
        }
        self.stats.walls_at_cells_seconds += t2.elapsed().as_secs_f64();
        self.last = Some(solution);
        self.stats.solves += 1;
        self.stats.seconds += t0.elapsed().as_secs_f64();
        self.stats.last_speed = speed;
        self.stats.last_gap = gap.is_finite().then_some(gap);
        if gap.is_finite() {
            self.stats.smallest_gap = Some(self.stats.smallest_gap.map_or(gap, |g| g.min(gap)));
        }
        Ok(out)
    }
}

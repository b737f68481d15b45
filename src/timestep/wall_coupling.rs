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
//! cells' layers at the wall points (each cell's off-surface evaluation of
//! [`crate::vesicle::near`]: smooth quadrature far from it, near-singular close to it), solves,
//! and evaluates `u_walls` at every cell's grid points (near-singular close to a wall). The
//! suspension adds it to the inter-cell velocity, so it enters a step the way that velocity
//! does: explicitly, from the densities at the start of the step, extrapolated by BDF2.
//!
//! The walls' part is a direct evaluation, `O(N_wall · N_cells · q²)` a step, on one rank; the
//! FMM does not carry the walls yet.

use std::time::Instant;

use super::TimestepError;
use crate::vesicle::{LayerKernel, NearParams, OffSurface};
use crate::wall::{Wall, WallError, WallField, WallParams, WallSolution, WallSystem};

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
    /// Largest wall velocity at a cell point in the last step.
    pub last_speed: f64,
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
    /// One off-surface evaluator per cell slot, built on first use.
    cells: Vec<OffSurface>,
    last: Option<WallSolution>,
    stats: WallStats,
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
        Ok(WallCoupling {
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
        let mut buf = vec![0.0; 3 * nw];
        while self.cells.len() < coefs.len() {
            self.cells.push(OffSurface::new(p, NearParams::default())?);
        }
        for (j, c) in coefs.iter().enumerate() {
            let s = &mut self.cells[j];
            s.set_surface(c)?;
            s.evaluate(
                LayerKernel::SingleLayer {
                    viscosity: self.viscosity,
                },
                tractions[j],
                &self.points,
                &mut buf,
            )?;
            add(&mut cells_at_walls, &buf);
            if let Some(g) = double_layers[j] {
                s.evaluate(LayerKernel::DoubleLayer, g, &self.points, &mut buf)?;
                add(&mut cells_at_walls, &buf);
            }
        }
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
        let mut out = Vec::with_capacity(points.len());
        let mut speed: f64 = 0.0;
        for x in points {
            let mut u = vec![0.0; 3 * x.len()];
            self.field
                .velocity(&solution, x, &mut u)
                .map_err(wall_error)?;
            let n = x.len();
            for i in 0..n {
                let s = (0..3).map(|a| u[a * n + i].powi(2)).sum::<f64>().sqrt();
                speed = speed.max(s);
            }
            out.push(u);
        }
        self.last = Some(solution);
        self.stats.solves += 1;
        self.stats.seconds += t0.elapsed().as_secs_f64();
        self.stats.last_speed = speed;
        Ok(out)
    }
}

fn add(acc: &mut [f64], v: &[f64]) {
    for (a, b) in acc.iter_mut().zip(v) {
        *a += b;
    }
}

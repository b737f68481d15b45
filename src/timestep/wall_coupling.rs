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
//! bounding sphere, or failing that the distance from its nodes, is far enough for it,
//! [`SmoothLayer`]; the off-surface evaluation of
//! [`crate::vesicle::near`] elsewhere: near-singular close to the cell), solves, and evaluates
//! `u_walls` at every cell's grid points the same way ([`WallField`]). The
//! suspension adds it to the inter-cell velocity, so it enters a step the way that velocity
//! does: explicitly, from the densities at the start of the step, extrapolated by BDF2.
//!
//! The walls' part is a direct evaluation, `O(N_wall · N_cells · q²)` a step; the FMM does not
//! carry the walls yet. Over MPI ranks each rank evaluates its own cells at the walls and sums
//! them in the order of their global indices; the ranks' sums are added in rank order
//! ([`crate::comm::sum_in_rank_order`], `3 N_wall` values a rank each way and step, whatever
//! the number of cells; until the sixteenth session every rank gathered every cell's `3 N_wall`
//! values). So the data equal one rank's to round-off, not bit for bit. Each rank solves and
//! evaluates the walls at its own cells. The solve is either every rank's own direct solve of
//! the whole (replicated) system, or, with the system split over the ranks
//! ([`WallCoupling::new_share`], `[numerics] wall_solve`), one GMRES over the ranks on the rows
//! each holds ([`super::wall_rows_solve`]), started from the last step's densities.

use std::time::Instant;

use super::contact::FixedSurface;
use super::gmres::GmresWorkspace;
use super::wall_rows_solve::solve_over_ranks;
use super::TimestepError;
use crate::comm::Communicator;
use crate::vesicle::smooth_layer::{Side, SmoothLayer};
use crate::vesicle::{Geometry, LayerKernel, NearParams, OffSurface, TargetInfo};
use crate::wall::{
    scatter_add, RowShare, Wall, WallField, WallKind, WallParams, WallSolution, WallSystem,
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
    /// The largest net normal flux `|∫ g·n dA| / ∫ |g| dA` of a cell's double-layer density
    /// `g = (1 − λ) u` removed before it met the walls (see [`without_net_flux`]).
    pub largest_cell_flux: f64,
    /// The largest net flux `|∫ u·n dA| / ∫ |u| dA` of the cells' velocity `u` through the
    /// container that its quadrature measured and that was removed. A closed wall around the
    /// cells sees none; a value above about 1e-3 says the wall's grid does not resolve the
    /// cells' flow next to it (raise the wall's `order`).
    pub largest_wall_flux: f64,
    /// Ranks the walls' system is split over (each holding its rows; 1: every rank holds the
    /// whole system and its factors).
    #[serde(default = "one")]
    pub split_ranks: usize,
    /// Bytes of the walls' operator held on this rank (the rows and their block's factors when
    /// split, the whole factors otherwise).
    #[serde(default)]
    pub operator_bytes: usize,
    /// GMRES iterations of the split solves, over the run (0 when not split).
    #[serde(default)]
    pub split_iterations: usize,
    /// Bytes this rank sent to others for the walls, over the run: the cells' layers at the
    /// wall points summed over the ranks, and the split solves' exchanges (0 on one rank).
    #[serde(default)]
    pub exchange_bytes: u64,
}

fn one() -> usize {
    1
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
    /// The split solve's Krylov storage (unused when the system is whole).
    ws: GmresWorkspace,
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
        Self::new_share(walls, velocity, viscosity, params, RowShare::WHOLE)
    }

    /// [`Self::new`] with the walls' system split over ranks: this rank holds the rows of
    /// `share` ([`WallSystem::new_share`]), and every solve is collective over the ranks the
    /// steps pass ([`super::wall_rows_solve`]). [`RowShare::WHOLE`] is [`Self::new`].
    pub fn new_share(
        walls: Vec<Wall>,
        velocity: Option<Vec<f64>>,
        viscosity: f64,
        params: WallParams,
        share: RowShare,
    ) -> Result<Self, TimestepError> {
        if !(viscosity.is_finite() && viscosity > 0.0) {
            return Err(TimestepError::InvalidParameter {
                name: "viscosity",
                value: format!("{viscosity}"),
                reason: "must be positive and finite",
            });
        }
        let t0 = Instant::now();
        let system = WallSystem::new_share(walls, params, share).map_err(TimestepError::from)?;
        let field = WallField::new(&system, crate::wall::NEAR_ZONE).map_err(TimestepError::from)?;
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
            split_ranks: share.ranks,
            operator_bytes: system.rows().map_or(8 * n * n, |r| r.bytes()),
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
            ws: GmresWorkspace::default(),
        })
    }

    /// The densities for the boundary velocity `data` (of size `scale`): one direct solve of a
    /// whole system, or a solve over the ranks of `comm` of a split one (collective).
    fn solve(
        &mut self,
        comm: &dyn Communicator,
        data: &[f64],
        scale: f64,
    ) -> Result<WallSolution, TimestepError> {
        if self.system.rows().is_none() {
            return self
                .system
                .solve_formed(data, scale)
                .map_err(TimestepError::from);
        }
        let guess = self.last.as_ref().map(|s| s.densities());
        let (solution, iterations) =
            solve_over_ranks(comm, &self.system, data, scale, guess, &mut self.ws)?;
        self.stats.split_iterations += iterations;
        Ok(solution)
    }

    /// Count `bytes` sent to other ranks for the walls ([`WallStats::exchange_bytes`]).
    pub(super) fn count_exchange(&mut self, bytes: u64) {
        self.stats.exchange_bytes += bytes;
    }

    /// Grid points over all walls.
    pub fn n_wall_points(&self) -> usize {
        self.points.len()
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

    /// Cell `slot`'s layers at every wall point (component-major over all wall points, walls
    /// in order, `3 N_wall`): `S[f](x_w) + D[g](x_w)` for a cell with surface `coefs` (its
    /// geometry `geom` on the grid of its order `p`), traction `traction` and double-layer
    /// density `g = (1 − λ) u` (`None`: no contrast). `slot` picks the evaluators kept for that
    /// cell position.
    pub fn cell_at_walls(
        &mut self,
        slot: usize,
        coefs: &[f64],
        geom: &Geometry,
        traction: &[f64],
        double_layer: Option<&[f64]>,
    ) -> Result<Vec<f64>, TimestepError> {
        let t0 = Instant::now();
        let nw = self.points.len();
        let p = geom.order();
        while self.cells.len() <= slot {
            self.cells.push((
                OffSurface::new(p, NearParams::default())?,
                SmoothLayer::new(p, 3 * p, 3.0)?,
            ));
        }
        let sl = LayerKernel::SingleLayer {
            viscosity: self.viscosity,
        };
        let mut out = vec![0.0; 3 * nw];
        let coarse = &mut self.cells[slot].1;
        coarse.set_surface(coefs)?;
        let (mut far, mut near) = (vec![], vec![]);
        // The bounding sphere first; a point it leaves unresolved (a red cell's flat faces
        // hold wall points well within the sphere but far from the membrane) by the distance
        // from the coarse rule's nodes (`SmoothLayer::side_by_distance`).
        for (i, &x) in self.points.iter().enumerate() {
            let side = match coarse.side(x) {
                Side::Unresolved => coarse.side_by_distance(x),
                side => side,
            };
            match side {
                Side::FarOutside => far.push(i),
                _ => near.push(i),
            }
        }
        // The double layer's density without its net normal flux (see `without_net_flux`).
        let double_layer = match double_layer {
            Some(g) => {
                let (g, relative) = without_net_flux(geom, g);
                self.stats.largest_cell_flux = self.stats.largest_cell_flux.max(relative);
                Some(g)
            }
            None => None,
        };
        let (s, coarse) = &mut self.cells[slot];
        let layers = CellLayers {
            coefs,
            single_layer: sl,
            traction,
            double_layer: double_layer.as_deref(),
        };
        layers.add_at(coarse, s, &self.points, (&far, &near), &mut out)?;
        self.stats.cells_at_walls_seconds += t0.elapsed().as_secs_f64();
        self.stats.seconds += t0.elapsed().as_secs_f64();
        Ok(out)
    }

    /// The data of the wall system: `U_w − u_∞ − u_cells` on every wall's grid (the walls'
    /// layout, component-major per wall), with `u_cells` the cells' velocity there in the same
    /// layout (`None`: no cells); and `∫ (|U_w| + |u_∞| + |u_cells|) dA` over the container,
    /// the size of the fields it is formed from ([`crate::wall::WallSystem::solve_formed`]).
    fn boundary_data(
        &self,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        cells: Option<&[f64]>,
    ) -> (Vec<f64>, f64) {
        let mut data = self.velocity.clone();
        let mut offset = 0;
        let mut scale = 0.0;
        for w in self.system.walls() {
            let n = w.n_points();
            let da = &w.geometry().da;
            for (j, &x) in w.geometry().x.iter().enumerate() {
                let mut sizes = [0.0; 3];
                for (a, u) in u_inf(x).into_iter().enumerate() {
                    let i = offset + a * n + j;
                    let c = cells.map_or(0.0, |c| c[i]);
                    sizes[0] += data[i] * data[i];
                    sizes[1] += u * u;
                    sizes[2] += c * c;
                    data[i] -= u + c;
                }
                if w.kind() == WallKind::Container {
                    scale += sizes.iter().map(|s| s.sqrt()).sum::<f64>() * da[j];
                }
            }
            offset += 3 * n;
        }
        (data, scale)
    }

    /// Solve the walls for the cells' layers at the wall points summed over every cell
    /// (`cells_at_walls`, as [`Self::cell_at_walls`] gives them) in the background flow `u_inf`,
    /// and return the walls' velocity at the grid points `points` of each cell held here
    /// (`3n` each, component-major).
    pub fn velocities(
        &mut self,
        comm: &dyn Communicator,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        cells_at_walls: &[f64],
        points: &[Vec<[f64; 3]>],
    ) -> Result<Vec<Vec<f64>>, TimestepError> {
        let t0 = Instant::now();
        let nw = self.points.len();
        if cells_at_walls.len() != 3 * nw {
            return Err(TimestepError::DimensionMismatch {
                what: "cells' velocity at the walls",
                expected: 3 * nw,
                got: cells_at_walls.len(),
            });
        }
        // The cells' part in the layout of the walls' unknowns (component-major per wall).
        let mut cells = vec![0.0; 3 * nw];
        let mut offset = 0;
        for w in self.system.walls() {
            let n = w.n_points();
            for a in 0..3 {
                for j in 0..n {
                    cells[offset + a * n + j] = cells_at_walls[a * nw + offset / 3 + j];
                }
            }
            offset += 3 * n;
        }
        let (mut data, scale) = self.boundary_data(u_inf, Some(&cells));
        let mut offset = 0;
        for w in self.system.walls() {
            let n = w.n_points();
            let mine = &cells[offset..offset + 3 * n];
            if w.kind() == WallKind::Container {
                // The cells' velocity carries no net flux through a closed wall around them;
                // what the wall's quadrature measures is its under-resolution of cells close
                // to it. Remove it (the completion would), and report it.
                let g = w.geometry();
                let (flux, size) = g.normal_flux(mine);
                let area = g.area();
                for j in 0..n {
                    for a in 0..3 {
                        data[offset + a * n + j] += g.normal[j][a] * flux / area;
                    }
                }
                if size > 0.0 {
                    self.stats.largest_wall_flux =
                        self.stats.largest_wall_flux.max(flux.abs() / size);
                }
            }
            offset += 3 * n;
        }
        let solution = self.solve(comm, &data, scale)?;
        let t2 = Instant::now();
        // Every cell's points in one evaluation (the walls' densities resampled once; each
        // target's sum does not depend on the others).
        let all: Vec<[f64; 3]> = points.iter().flatten().copied().collect();
        let nt = all.len();
        let mut u = vec![0.0; 3 * nt];
        let gap = self
            .field
            .velocity(&solution, &all, &mut u)
            .map_err(TimestepError::from)?;
        let mut out = Vec::with_capacity(points.len());
        let mut speed: f64 = 0.0;
        let mut first = 0;
        for x in points {
            let n = x.len();
            let mut v = vec![0.0; 3 * n];
            for a in 0..3 {
                v[a * n..(a + 1) * n].copy_from_slice(&u[a * nt + first..a * nt + first + n]);
            }
            for i in 0..n {
                let s = (0..3).map(|a| v[a * n + i].powi(2)).sum::<f64>().sqrt();
                speed = speed.max(s);
            }
            out.push(v);
            first += n;
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

impl WallCoupling {
    /// The walls' velocity at `targets` (component-major, `3 · targets.len()`, zero outside the
    /// fluid) and whether each target is in the fluid, for output (a velocity plane): the walls'
    /// solution of the last step (for the cells' layers at its start and the background flow
    /// `u_inf`), or before the first step the solution for `u_inf` alone. The statistics are
    /// not touched.
    pub fn field_at(
        &mut self,
        comm: &dyn Communicator,
        u_inf: &(dyn Fn([f64; 3]) -> [f64; 3] + Sync),
        targets: &[[f64; 3]],
    ) -> Result<(Vec<f64>, Vec<bool>), TimestepError> {
        let fluid = self.field.in_fluid(targets).map_err(TimestepError::from)?;
        let index: Vec<usize> = (0..targets.len()).filter(|&i| fluid[i]).collect();
        let inner: Vec<[f64; 3]> = index.iter().map(|&i| targets[i]).collect();
        let background;
        let solution = match &self.last {
            Some(s) => s,
            None => {
                let (data, scale) = self.boundary_data(u_inf, None);
                background = self.solve(comm, &data, scale)?;
                &background
            }
        };
        let mut v = vec![0.0; 3 * inner.len()];
        self.field
            .velocity(solution, &inner, &mut v)
            .map_err(TimestepError::from)?;
        let mut out = vec![0.0; 3 * targets.len()];
        scatter_add(&v, &index, &mut out, targets.len());
        Ok((out, fluid))
    }
}

/// One cell's layers `S[f] + D[g]` for evaluation off its surface: its coefficients, the
/// single-layer kernel, the traction `f` and the double-layer density `g` (`None`: none).
pub(crate) struct CellLayers<'a> {
    pub(crate) coefs: &'a [f64],
    pub(crate) single_layer: LayerKernel,
    pub(crate) traction: &'a [f64],
    pub(crate) double_layer: Option<&'a [f64]>,
}

impl CellLayers<'_> {
    /// Add the layers at `targets[far]` by the smooth rule `coarse` (its surface already set to
    /// this cell) and at `targets[close]` by the near-zone evaluator `near` (its surface set
    /// here) to `out` (component-major over all targets); the near targets' classification,
    /// in the order of `close`.
    pub(crate) fn add_at(
        &self,
        coarse: &mut SmoothLayer,
        near: &mut OffSurface,
        targets: &[[f64; 3]],
        (far, close): (&[usize], &[usize]),
        out: &mut [f64],
    ) -> Result<Vec<TargetInfo>, crate::vesicle::VesicleError> {
        let nt = targets.len();
        if !far.is_empty() {
            let xs: Vec<[f64; 3]> = far.iter().map(|&i| targets[i]).collect();
            let mut buf = vec![0.0; 3 * xs.len()];
            coarse.set_density(self.traction)?;
            coarse.add_to(self.single_layer, &xs, &mut buf)?;
            if let Some(g) = self.double_layer {
                coarse.set_density(g)?;
                coarse.add_to(LayerKernel::DoubleLayer, &xs, &mut buf)?;
            }
            scatter_add(&buf, far, out, nt);
        }
        if close.is_empty() {
            return Ok(vec![]);
        }
        let xs: Vec<[f64; 3]> = close.iter().map(|&i| targets[i]).collect();
        let mut v = vec![0.0; 3 * xs.len()];
        near.set_surface(self.coefs)?;
        let infos = near.evaluate(self.single_layer, self.traction, &xs, &mut v)?;
        scatter_add(&v, close, out, nt);
        if let Some(g) = self.double_layer {
            near.evaluate(LayerKernel::DoubleLayer, g, &xs, &mut v)?;
            scatter_add(&v, close, out, nt);
        }
        Ok(infos)
    }
}

/// `g − n (∫ g·n dA)/A` and `|∫ g·n dA| / ∫ |g| dA`: a cell's double-layer density without its
/// net normal flux. The density is `(1 − λ) u` with `u` the membrane velocity of the cell's last
/// step, whose normal flux carries the step's volume correction (measured: `∫u·n` up to 0.2 on
/// an RBC of volume 4.2 at p = 6). In free space that flux is a small source seen by the other
/// cells; inside a closed container it has nowhere to go and the wall system, which needs data
/// without net flux, would refuse it. An incompressible membrane motion has none, so it is
/// removed at the cell.
pub fn without_net_flux(geom: &Geometry, g: &[f64]) -> (Vec<f64>, f64) {
    let n = geom.n_points();
    let (flux, size) = geom.normal_flux(g);
    let area = geom.area();
    let mut out = g.to_vec();
    for j in 0..n {
        for a in 0..3 {
            out[a * n + j] -= geom.normal[j][a] * flux / area;
        }
    }
    (out, if size > 0.0 { flux.abs() / size } else { 0.0 })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vesicle::{shapes, SurfaceCalculus};

    /// The projection leaves no net normal flux, changes `g` only along the normal, and leaves
    /// a density without flux (a rigid motion) as it was.
    #[test]
    fn without_net_flux_removes_only_the_normal_mean() {
        let p = 6;
        let geom = SurfaceCalculus::new(p)
            .unwrap()
            .geometry(shapes::rbc(p).unwrap().coefs())
            .unwrap();
        let n = geom.n_points();
        let g: Vec<f64> = (0..3 * n).map(|i| ((i * 13) % 7) as f64 - 2.5).collect();
        let (h, relative) = without_net_flux(&geom, &g);
        assert!(relative > 1e-3, "the test density has a flux ({relative})");
        let (h2, after) = without_net_flux(&geom, &h);
        assert!(after < 1e-14, "{after}");
        crate::check::assert_close("projected twice", &h2, &h, 1e-14);
        for j in 0..n {
            let d: [f64; 3] = std::array::from_fn(|a| h[a * n + j] - g[a * n + j]);
            let nm = geom.normal[j];
            let cross = [
                d[1] * nm[2] - d[2] * nm[1],
                d[2] * nm[0] - d[0] * nm[2],
                d[0] * nm[1] - d[1] * nm[0],
            ];
            assert!(cross.iter().all(|c| c.abs() < 1e-13), "a tangential change");
        }
        let rigid: Vec<f64> = (0..3 * n).map(|i| [0.3, -1.0, 0.2][i / n]).collect();
        let (r, flux) = without_net_flux(&geom, &rigid);
        assert!(flux < 1e-12);
        crate::check::assert_close("rigid motion", &r, &rigid, 1e-12);
    }
}

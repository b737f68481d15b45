//! Cells beside a plane wall: the wall's velocity at the cells, by the images of their single
//! layers, once per step.
//!
//! With a plane wall at rest ([`PlaneWall`]: Blake's image system) the velocity in the fluid is
//! `u = u_∞ + Σ_cells S^B_j[f_j]`, `S^B` the single layer with Blake's tensor. Its free-space
//! part is what a suspension computes anyway (each cell's own step and the inter-cell
//! coupling); [`PlaneCoupling`] adds the rest,
//!
//! ```text
//! u_wall(x) = (1/8πμ) Σ_j ∫_{Γ_j} G^img(x, y) f_j(y) dA(y),
//! ```
//!
//! at every cell's grid points, by each cell's smooth quadrature upsampled to order
//! [`IMAGE_ORDER_FACTOR`]`·p` ([`SmoothLayer`]). The image of a cell at height `h` lies `2h`
//! from it, so the rule resolves it while `2h` exceeds a few spacings of that grid
//! (`tests/plane_wall.rs` measures the error against Brenner's drag down to `h = 0.1` radii).
//! It enters a step as the walls' velocity does: explicitly, from the tractions at the start of
//! the step, extrapolated by BDF2. The background flow `u_∞` must vanish on the plane (a
//! shear flow along it, or none): the scene checks it.
//!
//! **What is not there.** A cell with a viscosity contrast (`λ ≠ 1`) would also need the image
//! of its double layer, which is not built: the scene refuses the pair. The images are a direct
//! sum, `O(N_points · N_sources)` over all cells (not through the FMM). Over MPI ranks every
//! rank gathers every cell's point forces (six numbers per node of the upsampled grid) and sums
//! them in the order of the cells' global indices, so any number of ranks gives one rank's bits.

use std::time::Instant;

use super::contact::Wall as ContactPlane;
use super::TimestepError;
use crate::vesicle::smooth_layer::{PointForce, SmoothLayer};
use crate::wall::PlaneWall;

/// The order of the images' quadrature over the cell's order `p`.
pub const IMAGE_ORDER_FACTOR: usize = 3;

/// What the plane wall did (cumulative).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PlaneStats {
    /// Evaluations of the images (one a step).
    pub evaluations: usize,
    /// Seconds in them.
    pub seconds: f64,
    /// Point forces over all cells in the last evaluation.
    pub sources: usize,
    /// The smallest height of a cell's grid point above the plane in the last step, and over
    /// the run.
    pub last_gap: Option<f64>,
    /// Over the run.
    pub smallest_gap: Option<f64>,
}

/// A plane wall beside the cells of a suspension.
pub struct PlaneCoupling {
    wall: PlaneWall,
    viscosity: f64,
    /// One smooth rule per cell slot, built on first use.
    rules: Vec<SmoothLayer>,
    /// Every cell's point forces of the last evaluation (wall's frame, cells in global order).
    last: Vec<PointForce>,
    stats: PlaneStats,
}

impl PlaneCoupling {
    /// The plane `wall` beside cells in a fluid of viscosity `viscosity`.
    pub fn new(wall: PlaneWall, viscosity: f64) -> Result<Self, TimestepError> {
        if !(viscosity.is_finite() && viscosity > 0.0) {
            return Err(TimestepError::InvalidParameter {
                name: "viscosity",
                value: format!("{viscosity}"),
                reason: "must be positive and finite",
            });
        }
        Ok(PlaneCoupling {
            wall,
            viscosity,
            rules: vec![],
            last: vec![],
            stats: PlaneStats::default(),
        })
    }

    /// The wall.
    pub fn wall(&self) -> &PlaneWall {
        &self.wall
    }

    /// The wall as a plane of the contact projection (cells kept `d_min` above it).
    pub fn contact_plane(&self) -> ContactPlane {
        ContactPlane {
            normal: self.wall.normal(),
            offset: self.wall.offset(),
        }
    }

    /// What the wall did.
    pub fn stats(&self) -> PlaneStats {
        self.stats
    }

    /// Cell `slot`'s point forces for the images: the nodes of its surface `coefs` (order `p`)
    /// upsampled to order `3p` and its traction `traction` there times the weights, in the
    /// wall's frame, flattened as `[y₁, y₂, y₃, F₁, F₂, F₃]` per node.
    pub fn cell_sources(
        &mut self,
        slot: usize,
        p: usize,
        coefs: &[f64],
        traction: &[f64],
    ) -> Result<Vec<f64>, TimestepError> {
        let t0 = Instant::now();
        while self.rules.len() <= slot {
            self.rules
                .push(SmoothLayer::new(p, IMAGE_ORDER_FACTOR * p, 3.0)?);
        }
        if self.rules[slot].order() != p {
            self.rules[slot] = SmoothLayer::new(p, IMAGE_ORDER_FACTOR * p, 3.0)?;
        }
        let rule = &mut self.rules[slot];
        rule.set_surface(coefs)?;
        rule.set_density(traction)?;
        let mut out = Vec::new();
        for (y, f) in rule.weighted_points()? {
            out.extend(self.wall.to_local(y));
            out.extend(self.wall.vector_to_local(f));
        }
        self.stats.seconds += t0.elapsed().as_secs_f64();
        Ok(out)
    }

    /// The images of the point forces `sources` (every cell's [`Self::cell_sources`],
    /// concatenated in the cells' global order) at the grid points `points` of each cell held
    /// here (`3n` each, component-major). A grid point on or below the plane is an error.
    pub fn velocities(
        &mut self,
        sources: &[f64],
        points: &[Vec<[f64; 3]>],
    ) -> Result<Vec<Vec<f64>>, TimestepError> {
        let t0 = Instant::now();
        if !sources.len().is_multiple_of(6) {
            return Err(TimestepError::DimensionMismatch {
                what: "plane wall's point forces",
                expected: 6 * (sources.len() / 6),
                got: sources.len(),
            });
        }
        self.last = sources
            .chunks_exact(6)
            .map(|c| ([c[0], c[1], c[2]], [c[3], c[4], c[5]]))
            .collect();
        let mut gap = f64::INFINITY;
        for x in points.iter().flatten() {
            gap = gap.min(self.wall.height(*x));
        }
        if points.iter().any(|x| !x.is_empty()) && (gap <= 0.0 || gap.is_nan()) {
            return Err(TimestepError::Wall(format!(
                "a cell reached the plane wall (a grid point {gap:.3e} above it); keep cells \
                 off it with [numerics] contact_distance"
            )));
        }
        let mut out = Vec::with_capacity(points.len());
        for x in points {
            let mut u = vec![0.0; 3 * x.len()];
            self.wall
                .add_images(self.viscosity, &self.last, x, &mut u)
                .map_err(|e| TimestepError::Wall(e.to_string()))?;
            out.push(u);
        }
        let s = &mut self.stats;
        s.evaluations += 1;
        s.sources = self.last.len();
        s.seconds += t0.elapsed().as_secs_f64();
        if gap.is_finite() {
            s.last_gap = Some(gap);
            s.smallest_gap = Some(s.smallest_gap.map_or(gap, |g| g.min(gap)));
        }
        Ok(out)
    }

    /// The wall's velocity (the images of the last evaluation's point forces; zero before the
    /// first) at `targets` (component-major, zero below the plane) and whether each target
    /// is in the fluid, for output. The statistics are not touched.
    pub fn field_at(&self, targets: &[[f64; 3]]) -> Result<(Vec<f64>, Vec<bool>), TimestepError> {
        let fluid: Vec<bool> = targets.iter().map(|&x| self.wall.height(x) > 0.0).collect();
        let inner: Vec<[f64; 3]> = targets
            .iter()
            .zip(&fluid)
            .filter(|(_, &f)| f)
            .map(|(&x, _)| x)
            .collect();
        let mut v = vec![0.0; 3 * inner.len()];
        self.wall
            .add_images(self.viscosity, &self.last, &inner, &mut v)
            .map_err(|e| TimestepError::Wall(e.to_string()))?;
        let index: Vec<usize> = (0..targets.len()).filter(|&i| fluid[i]).collect();
        let mut out = vec![0.0; 3 * targets.len()];
        crate::wall::scatter_add(&v, &index, &mut out, targets.len());
        Ok((out, fluid))
    }
}

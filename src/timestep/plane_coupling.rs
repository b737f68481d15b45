//! Cells beside a plane wall: the wall's velocity at the cells, by the images of their layers,
//! once per step.
//!
//! With a plane wall at rest ([`PlaneWall`]: Blake's image system) the velocity in the fluid is
//! `u = u_∞ + Σ_cells (S^B_j[f_j] + (1 − λ_j) D^B_j[u_j])`, the layers with Blake's tensor.
//! Its free-space part is what a suspension computes anyway (each cell's own step and the
//! inter-cell coupling); [`PlaneCoupling`] adds the rest, the images,
//!
//! ```text
//! u_wall(x) = (1/8πμ) Σ_j ∫_{Γ_j} G^img(x, y) f_j(y) dA(y) + (1 − λ_j) D^img_j[u_j](x),
//! ```
//!
//! at every cell's grid points, by each cell's smooth quadrature upsampled to order `3p`
//! ([`crate::vesicle::smooth_layer::SmoothLayer`]). The image of a cell at height `h` lies
//! `2h` from it, so that rule resolves it while `2h` exceeds a few spacings of its grid; where a
//! target is closer to a cell's mirror, that cell's images there are taken on a finer rule of
//! the ladder `6p, 12p, 24p` ([`super::image_quadrature`]), so a cell at the contact
//! projection's gap from the plane feels its own image to about `1e-12`
//! (`tests/plane_wall.rs`, which also checks Brenner's drag).
//! It enters a step as the walls' velocity does: explicitly, from the tractions at the start of
//! the step, extrapolated by BDF2. The background flow `u_∞` must vanish on the plane (a
//! shear flow along it, or none): the scene checks it.
//!
//! A cell with a viscosity contrast (`λ ≠ 1`) adds the image of its double layer `(1 − λ)
//! D[u]` ([`PlaneWall::add_double_layer_images`]), with `u` its last membrane velocity, as the
//! inter-cell coupling takes it. For output ([`PlaneCoupling::add_cell_images`]) the images are those of
//! each cell's present layers, like the rest of the field.
//!
//! **What is not there.** The images are a direct sum, `O(N_points · N_sources)` over all
//! cells (not through the FMM). Over MPI ranks every rank gathers every cell's sources (six
//! numbers per node of the upsampled grid, nine more with a double layer) and its surface,
//! traction and double-layer density (for the refinement, [`ImageCell`]), and sums them in the
//! order of the cells' global indices, so any number of ranks gives one rank's bits.

use std::time::Instant;

use super::contact::Wall as ContactPlane;
use super::image_quadrature::{add_layer_images, DoubleLayerSource, ImageLayers, ImageQuadrature};
use super::TimestepError;
use crate::vesicle::smooth_layer::PointForce;
use crate::wall::PlaneWall;

/// What the plane wall did (cumulative).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PlaneStats {
    /// Evaluations of the images (one a step).
    pub evaluations: usize,
    /// Seconds in them.
    pub seconds: f64,
    /// Point forces over all cells in the last evaluation.
    pub sources: usize,
    /// Cells whose images were refined near their mirror in the last evaluation
    /// ([`super::image_quadrature`]).
    #[serde(default)]
    pub refined_cells: usize,
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
    /// One ladder of rules per cell slot, built on first use.
    rules: Vec<ImageQuadrature>,
    /// Ladders for the refinement of any cell's images, one per surface order.
    refine: Vec<ImageQuadrature>,
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
            refine: vec![],
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

    /// Cell `slot`'s sources for the images: the nodes of its surface (order `p`) upsampled to
    /// order `3p`, in the wall's frame. First its traction there times the weights, flattened
    /// as `[y₁, y₂, y₃, F₁, F₂, F₃]` per node; then, for a cell with a viscosity contrast, its
    /// double-layer density `g = (1 − λ) u` times the weights and the normal, `[y, g dA, n]`
    /// per node (empty without).
    pub fn cell_sources(
        &mut self,
        slot: usize,
        p: usize,
        cell: ImageLayers<'_>,
    ) -> Result<(Vec<f64>, Vec<f64>), TimestepError> {
        let t0 = Instant::now();
        let sources = self.sources(slot, p, cell);
        self.stats.seconds += t0.elapsed().as_secs_f64();
        sources
    }

    /// [`Self::cell_sources`] without the timing.
    fn sources(
        &mut self,
        slot: usize,
        p: usize,
        cell: ImageLayers<'_>,
    ) -> Result<(Vec<f64>, Vec<f64>), TimestepError> {
        let (single, double) = self.slot_sources(slot, p, cell)?;
        Ok((
            single
                .iter()
                .flat_map(|(y, f)| y.iter().chain(f))
                .copied()
                .collect(),
            double.iter().flatten().flatten().copied().collect(),
        ))
    }

    /// The coarse sources ([`ImageQuadrature::sources`], level 0) on the ladder kept for
    /// cell `slot` (built for order `p` on first use).
    fn slot_sources(
        &mut self,
        slot: usize,
        p: usize,
        cell: ImageLayers<'_>,
    ) -> Result<(Vec<PointForce>, Vec<DoubleLayerSource>), TimestepError> {
        let wall = self.wall;
        self.slot_rules(slot, p).sources(0, &wall, cell)
    }

    /// The ladder kept for cell `slot`, of order `p`.
    fn slot_rules(&mut self, slot: usize, p: usize) -> &mut ImageQuadrature {
        while self.rules.len() <= slot {
            self.rules.push(ImageQuadrature::new(p));
        }
        if self.rules[slot].order() != p {
            self.rules[slot] = ImageQuadrature::new(p);
        }
        &mut self.rules[slot]
    }

    /// The images of the sources `single` and `double` (every cell's [`Self::cell_sources`],
    /// each concatenated in the cells' global order) at the grid points `points` of each cell
    /// held here (`3n` each, component-major), refined where a target is close to the mirror
    /// of a cell of `near` ([`super::image_quadrature`]: every cell's data, in the same order,
    /// with where its sources are in `single` and `double`). A grid point on or below the plane
    /// is an error.
    pub fn velocities(
        &mut self,
        single: &[f64],
        double: &[f64],
        near: &[ImageCell<'_>],
        points: &[Vec<[f64; 3]>],
    ) -> Result<Vec<Vec<f64>>, TimestepError> {
        let t0 = Instant::now();
        for (what, v, k) in [("single-layer", single, 6), ("double-layer", double, 9)] {
            if !v.len().is_multiple_of(k) {
                return Err(TimestepError::Wall(format!(
                    "the plane wall's {what} sources have {} values, not a multiple of {k}",
                    v.len()
                )));
            }
        }
        let (single, double) = unflatten(single, double);
        for c in near {
            if c.single.end > single.len() || c.double.end > double.len() {
                return Err(TimestepError::Wall(format!(
                    "a cell's image sources reach past the gathered ones ({:?} of {}, {:?} of {})",
                    c.single,
                    single.len(),
                    c.double,
                    double.len()
                )));
            }
        }
        let mut gap = f64::INFINITY;
        for x in points.iter().flatten() {
            gap = gap.min(self.wall.height(*x));
        }
        // (No points: the gap stays infinite.)
        if gap <= 0.0 || gap.is_nan() {
            return Err(TimestepError::Wall(format!(
                "a cell reached the plane wall (a grid point {gap:.3e} above it); keep cells \
                 off it with [numerics] contact_distance"
            )));
        }
        let mut out = Vec::with_capacity(points.len());
        for x in points {
            let mut u = vec![0.0; 3 * x.len()];
            add_layer_images(&self.wall, self.viscosity, &single, &double, x, &mut u)?;
            out.push(u);
        }
        // Every held cell's points as one target list, so that each near cell's finer rules
        // are built once.
        let all: Vec<[f64; 3]> = points.iter().flatten().copied().collect();
        let nt = all.len();
        let mut refined = 0;
        for c in near {
            let coarse = (&single[c.single.clone()], &double[c.double.clone()]);
            let k = match self.refine.iter().position(|r| r.order() == c.p) {
                Some(k) => k,
                None => {
                    self.refine.push(ImageQuadrature::new(c.p));
                    self.refine.len() - 1
                }
            };
            let mut v = vec![0.0; 3 * nt];
            let (wall, viscosity) = (self.wall, self.viscosity);
            if !self.refine[k].add_refinement(&wall, viscosity, c.layers, coarse, &all, &mut v)? {
                continue;
            }
            refined += 1;
            let mut at = 0;
            for (x, u) in points.iter().zip(&mut out) {
                let n = x.len();
                for a in 0..3 {
                    for t in 0..n {
                        u[a * n + t] += v[a * nt + at + t];
                    }
                }
                at += n;
            }
        }
        let s = &mut self.stats;
        s.evaluations += 1;
        s.sources = single.len();
        s.refined_cells = refined;
        s.seconds += t0.elapsed().as_secs_f64();
        if gap.is_finite() {
            s.last_gap = Some(gap);
            s.smallest_gap = Some(s.smallest_gap.map_or(gap, |g| g.min(gap)));
        }
        Ok(out)
    }

    /// Add the images of one cell's present layers (as [`Self::cell_sources`] takes them) at
    /// the `targets` above the plane to `out` (component-major over all targets; those on or
    /// below the plane are left alone), for output, refined near the mirror
    /// ([`ImageQuadrature::add`]). `slot` picks the rules kept for that cell; the statistics
    /// are not touched.
    pub fn add_cell_images(
        &mut self,
        slot: usize,
        p: usize,
        cell: ImageLayers<'_>,
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<(), TimestepError> {
        let index: Vec<usize> = (0..targets.len())
            .filter(|&i| self.wall.height(targets[i]) > 0.0)
            .collect();
        let inner: Vec<[f64; 3]> = index.iter().map(|&i| targets[i]).collect();
        let mut v = vec![0.0; 3 * inner.len()];
        let (wall, viscosity) = (self.wall, self.viscosity);
        self.slot_rules(slot, p)
            .add(&wall, viscosity, cell, &inner, &mut v)?;
        crate::wall::scatter_add(&v, &index, out, targets.len());
        Ok(())
    }
}

/// One cell as [`PlaneCoupling::velocities`] refines its images: its order and layers, and
/// where its coarse sources are among the gathered ones (counted in sources, not values).
#[derive(Clone, Debug)]
pub struct ImageCell<'a> {
    /// Surface order.
    pub p: usize,
    /// Its surface, traction and double-layer density.
    pub layers: ImageLayers<'a>,
    /// Its point forces among the single-layer sources.
    pub single: std::ops::Range<usize>,
    /// Its double-layer sources among those.
    pub double: std::ops::Range<usize>,
}

/// The sources of [`PlaneCoupling::cell_sources`] as point forces and double-layer triples.
fn unflatten(single: &[f64], double: &[f64]) -> (Vec<PointForce>, Vec<DoubleLayerSource>) {
    let v = |c: &[f64]| [c[0], c[1], c[2]];
    (
        single.chunks_exact(6).map(|c| (v(c), v(&c[3..]))).collect(),
        double
            .chunks_exact(9)
            .map(|c| [v(c), v(&c[3..]), v(&c[6..])])
            .collect(),
    )
}

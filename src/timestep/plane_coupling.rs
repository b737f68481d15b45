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
//! at every cell's grid points, by each cell's smooth quadrature upsampled to order
//! [`IMAGE_ORDER_FACTOR`]`·p` ([`SmoothLayer`]). The image of a cell at height `h` lies `2h`
//! from it, so the rule resolves it while `2h` exceeds a few spacings of that grid
//! (`tests/plane_wall.rs` checks Brenner's drag down to a gap of half a radius).
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
//! numbers per node of the upsampled grid, nine more with a double layer) and sums them in the
//! order of the cells' global indices, so any number of ranks gives one rank's bits.

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

    /// Cell `slot`'s sources for the images: the nodes of its surface `coefs` (order `p`)
    /// upsampled to order `3p`, in the wall's frame. First its traction `traction` there times
    /// the weights, flattened as `[y₁, y₂, y₃, F₁, F₂, F₃]` per node; then, for a cell with a
    /// viscosity contrast, its double-layer density `g = (1 − λ) u` times the weights and the
    /// normal, `[y, g dA, n]` per node (empty without).
    pub fn cell_sources(
        &mut self,
        slot: usize,
        p: usize,
        coefs: &[f64],
        traction: &[f64],
        double_layer: Option<&[f64]>,
    ) -> Result<(Vec<f64>, Vec<f64>), TimestepError> {
        let t0 = Instant::now();
        let sources = self.sources(slot, p, coefs, traction, double_layer);
        self.stats.seconds += t0.elapsed().as_secs_f64();
        sources
    }

    /// [`Self::cell_sources`] without the timing.
    fn sources(
        &mut self,
        slot: usize,
        p: usize,
        coefs: &[f64],
        traction: &[f64],
        double_layer: Option<&[f64]>,
    ) -> Result<(Vec<f64>, Vec<f64>), TimestepError> {
        let (single, double) = self.slot_sources(slot, p, coefs, traction, double_layer)?;
        Ok((
            single
                .iter()
                .flat_map(|(y, f)| y.iter().chain(f))
                .copied()
                .collect(),
            double.iter().flatten().flatten().copied().collect(),
        ))
    }

    /// [`layer_sources`] on the rule kept for cell `slot` (built for order `p` on first use).
    fn slot_sources(
        &mut self,
        slot: usize,
        p: usize,
        coefs: &[f64],
        traction: &[f64],
        double_layer: Option<&[f64]>,
    ) -> Result<(Vec<PointForce>, Vec<DoubleLayerSource>), TimestepError> {
        while self.rules.len() <= slot {
            self.rules.push(image_rule(p)?);
        }
        if self.rules[slot].order() != p {
            self.rules[slot] = image_rule(p)?;
        }
        layer_sources(
            &self.wall,
            &mut self.rules[slot],
            coefs,
            traction,
            double_layer,
        )
    }

    /// The images of the sources `single` and `double` (every cell's [`Self::cell_sources`],
    /// each concatenated in the cells' global order) at the grid points `points` of each cell
    /// held here (`3n` each, component-major). A grid point on or below the plane is an error.
    pub fn velocities(
        &mut self,
        single: &[f64],
        double: &[f64],
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
        let s = &mut self.stats;
        s.evaluations += 1;
        s.sources = single.len();
        s.seconds += t0.elapsed().as_secs_f64();
        if gap.is_finite() {
            s.last_gap = Some(gap);
            s.smallest_gap = Some(s.smallest_gap.map_or(gap, |g| g.min(gap)));
        }
        Ok(out)
    }

    /// Add the images of one cell's layers, from its present surface `coefs`, traction and
    /// double-layer density (as [`Self::cell_sources`] takes them), at the `targets` above the
    /// plane to `out` (component-major over all targets; those on or below the plane are left
    /// alone), for output. `slot` picks the rule kept for that cell; the statistics are not
    /// touched.
    #[allow(clippy::too_many_arguments)]
    pub fn add_cell_images(
        &mut self,
        slot: usize,
        p: usize,
        coefs: &[f64],
        traction: &[f64],
        double_layer: Option<&[f64]>,
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<(), TimestepError> {
        let (single, double) = self.slot_sources(slot, p, coefs, traction, double_layer)?;
        let index: Vec<usize> = (0..targets.len())
            .filter(|&i| self.wall.height(targets[i]) > 0.0)
            .collect();
        let inner: Vec<[f64; 3]> = index.iter().map(|&i| targets[i]).collect();
        let mut v = vec![0.0; 3 * inner.len()];
        add_layer_images(&self.wall, self.viscosity, &single, &double, &inner, &mut v)?;
        crate::wall::scatter_add(&v, &index, out, targets.len());
        Ok(())
    }
}

/// A double-layer source of the images: `(y, g dA, n)` in the wall's frame.
pub(super) type DoubleLayerSource = [[f64; 3]; 3];

/// The smooth rule of the images of cells of order `p`: order [`IMAGE_ORDER_FACTOR`]`·p`.
pub(super) fn image_rule(p: usize) -> Result<SmoothLayer, TimestepError> {
    Ok(SmoothLayer::new(p, IMAGE_ORDER_FACTOR * p, 3.0)?)
}

/// One cell's sources for the images, in the wall's frame: the nodes of its surface `coefs`
/// on `rule`'s upsampled grid with its `traction` times the weights (point forces), and, where
/// `double_layer` is given, `(y, g dA, n)` per node (empty without).
pub(super) fn layer_sources(
    wall: &PlaneWall,
    rule: &mut SmoothLayer,
    coefs: &[f64],
    traction: &[f64],
    double_layer: Option<&[f64]>,
) -> Result<(Vec<PointForce>, Vec<DoubleLayerSource>), TimestepError> {
    rule.set_surface(coefs)?;
    rule.set_density(traction)?;
    let single = rule
        .weighted_points()?
        .into_iter()
        .map(|(y, f)| (wall.to_local(y), wall.vector_to_local(f)))
        .collect();
    let mut double = Vec::new();
    if let Some(g) = double_layer {
        rule.set_density(g)?;
        for ((y, g), n) in rule.weighted_points()?.into_iter().zip(rule.normals()) {
            double.push([
                wall.to_local(y),
                wall.vector_to_local(g),
                wall.vector_to_local(*n),
            ]);
        }
    }
    Ok((single, double))
}

/// Add the images in `wall` (fluid of viscosity `viscosity`) of the point forces `single` and
/// the double-layer sources `double` ([`layer_sources`]) at `targets` to `out`
/// (component-major).
pub(super) fn add_layer_images(
    wall: &PlaneWall,
    viscosity: f64,
    single: &[PointForce],
    double: &[DoubleLayerSource],
    targets: &[[f64; 3]],
    out: &mut [f64],
) -> Result<(), TimestepError> {
    let fail = |e: crate::wall::WallError| TimestepError::Wall(e.to_string());
    wall.add_images(viscosity, single, targets, out)
        .map_err(fail)?;
    if !double.is_empty() {
        wall.add_double_layer_images(double, targets, out)
            .map_err(fail)?;
    }
    Ok(())
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

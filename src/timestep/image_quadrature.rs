//! The images of one cell's layers in a plane wall, with the quadrature refined where the
//! image comes close.
//!
//! The image of a cell at height `h` above a plane wall ([`PlaneWall`], Blake's system) is its
//! mirror below the plane: the image kernel at a target `x` (height `h_x`) from a source node
//! `y` (height `h_y`) is singular at `y* = y − 2h_y n`, and `|x − y*| ≥ h_x + h_y`. The smooth
//! quadrature of the cell's surface upsampled to order `q` ([`SmoothLayer`]) loses digits like
//! `exp(−c d/h_q)` in that distance `d` over its spacing `h_q ≈ 2π R_max/q`. So a cell that
//! touches the plane at the contact projection's gap (`d_min = 0.05` at `p = 8`) sees its own
//! image from `d ≈ 0.1`, and the order-`3p` rule alone is off by 6 % of the image there (an RBC
//! edge-on, single and double layer; `tests/plane_wall.rs`).
//!
//! Each target takes the coarsest rule of the ladder `q = m p`, `m ∈` [`IMAGE_LEVELS`], that
//! resolves a lower bound `d` of its distance to the cell's mirror,
//!
//! ```text
//!     ratio · 2π R_max / (m p) ≤ d,      ratio = IMAGE_RESOLVE_RATIO,
//!     d = max(h_x + h_low, min_i |x − y_i*| − π R_max / 3p),
//! ```
//!
//! (`h_low` the cell's lowest coarse node less half a spacing, `y_i*` the mirrors of the coarse
//! nodes), and the finest rule where none does. This is the refinement by levels that the
//! near-zone evaluator of cells makes ([`crate::vesicle::near`]), on the mirror surface. At
//! `p = 8` the finest level, `24p`, resolves `d ≥ 0.09` to the ratio, and `d = 0.1` to about
//! `1e-12` (measured): the default `d_min = 0.4 R/p` keeps `d ≥ 0.8 R/p`, and the finest
//! spacing scales as `1/p` too. The RBC above comes to 7e-10 of its image (the test).
//!
//! The cost is in the kernel (the double layer's image above all), at the targets of the finer
//! levels times their nodes (`2(q + 1)²`), so the step takes the refinement where the whole
//! density acts, in its explicit images ([`super::plane_coupling`]), and the coarse rule for
//! the joint solve's correction ([`super::near_images`]).

use std::f64::consts::PI;

use super::TimestepError;
use crate::vesicle::smooth_layer::{PointForce, SmoothLayer};
use crate::wall::PlaneWall;

/// A double-layer source of the images: `(y, g dA, n)` in the wall's frame.
pub type DoubleLayerSource = [[f64; 3]; 3];

/// One cell's layers as its images take them.
#[derive(Clone, Copy, Debug)]
pub struct ImageLayers<'a> {
    /// Surface coefficients (order `p`).
    pub coefs: &'a [f64],
    /// Traction on the order-`p` grid (component-major).
    pub traction: &'a [f64],
    /// `(1 − λ) u` on the grid, for a cell with a viscosity contrast.
    pub double_layer: Option<&'a [f64]>,
}

/// The ladder of the images' quadrature orders over the cell's order `p`; the first is the
/// coarse rule every target far enough from the mirror takes.
pub const IMAGE_LEVELS: [usize; 4] = [3, 6, 12, 24];

/// A rule of order `q` resolves targets at least `ratio · 2π R_max / q` from the mirror
/// surface. With 2 the RBC of `tests/plane_wall.rs` comes to 7.1e-10 of its image, with 3 to
/// 6.1e-10 at 1.4 times the cost of the explicit images, with 1.5 to 3.8e-9.
pub const IMAGE_RESOLVE_RATIO: f64 = 2.0;

/// How far one cell's mirror reaches, from its nodes on the coarse rule (the wall's frame).
#[derive(Clone, Debug, PartialEq)]
pub struct ImageReach {
    /// The cell's surface order.
    p: usize,
    /// The coarse nodes' mirror points `y* = (y₁, y₂, −y₃)`.
    mirror: Vec<[f64; 3]>,
    /// Their mean, and their largest distance from it.
    mirror_centre: [f64; 3],
    mirror_radius: f64,
    /// How far a point of the surface may lie from the nearest node.
    margin: f64,
    /// A lower bound of the cell's height above the plane.
    low: f64,
    /// `R_max` of the bound `2π R_max / q` on a rule's spacing.
    r_max: f64,
}

impl ImageReach {
    /// The reach of a cell of order `p` from its point forces on the coarse rule (`3p`), given
    /// in the wall's frame ([`ImageQuadrature::sources`]).
    pub fn of_sources(p: usize, coarse: &[PointForce]) -> Self {
        let n = coarse.len().max(1) as f64;
        let mut c = [0.0; 3];
        let mut low = f64::INFINITY;
        for (y, _) in coarse {
            for a in 0..3 {
                c[a] += y[a] / n;
            }
            low = low.min(y[2]);
        }
        let mut r: f64 = 0.0;
        for (y, _) in coarse {
            r = r.max(
                ((y[0] - c[0]).powi(2) + (y[1] - c[1]).powi(2) + (y[2] - c[2]).powi(2)).sqrt(),
            );
        }
        let q = (IMAGE_LEVELS[0] * p) as f64;
        let r_max = r + PI * r / q;
        // A point of the surface lies within about half a grid cell's diagonal of a node:
        // `π R_max / q` covers it. Near its lowest point a smooth surface is flat, so half
        // that covers the lowest point's miss.
        let margin = PI * r_max / q;
        ImageReach {
            p,
            mirror: coarse.iter().map(|(y, _)| [y[0], y[1], -y[2]]).collect(),
            mirror_centre: [c[0], c[1], -c[2]],
            mirror_radius: r,
            margin,
            low: (low - 0.5 * margin).max(0.0),
            r_max,
        }
    }

    /// A lower bound of the distance from `x` (the wall's frame, above the plane) to the
    /// cell's mirror: the larger of `h_x + h_low` and the nearest mirror node's distance less
    /// the margin.
    pub fn distance(&self, x: [f64; 3]) -> f64 {
        let nearest = self
            .mirror
            .iter()
            .map(|y| (x[0] - y[0]).powi(2) + (x[1] - y[1]).powi(2) + (x[2] - y[2]).powi(2))
            .fold(f64::INFINITY, f64::min)
            .sqrt();
        (x[2] + self.low).max(nearest - self.margin)
    }

    /// The level (index into [`IMAGE_LEVELS`]) a target `x` (the wall's frame) takes.
    pub fn level(&self, x: [f64; 3]) -> usize {
        // A bound no larger than [`Self::distance`] (every mirror node lies within
        // `mirror_radius` of their mean), in O(1): where it already takes the coarse rule, so
        // does the distance, and the scan of the nodes is skipped.
        let c = self.mirror_centre;
        let to_centre =
            ((x[0] - c[0]).powi(2) + (x[1] - c[1]).powi(2) + (x[2] - c[2]).powi(2)).sqrt();
        let cheap = (x[2] + self.low).max(to_centre - self.mirror_radius - self.margin);
        if self.level_at(cheap) == 0 {
            return 0;
        }
        self.level_at(self.distance(x))
    }

    /// The level a lower bound `d` of the distance to the mirror asks.
    fn level_at(&self, d: f64) -> usize {
        IMAGE_LEVELS
            .iter()
            .position(|&m| IMAGE_RESOLVE_RATIO * 2.0 * PI * self.r_max / (m * self.p) as f64 <= d)
            .unwrap_or(IMAGE_LEVELS.len() - 1)
    }

    /// Whether a target on the plane right under the cell's lowest point would need a finer
    /// rule than the coarse one (if not, no target above the plane does).
    pub fn refines(&self) -> bool {
        IMAGE_RESOLVE_RATIO * 2.0 * PI * self.r_max / (IMAGE_LEVELS[0] * self.p) as f64 > self.low
    }
}

/// The rules of the ladder for cells of order `p`, built on first use and kept.
pub struct ImageQuadrature {
    p: usize,
    rules: Vec<Option<SmoothLayer>>,
}

impl ImageQuadrature {
    /// The ladder for cells of order `p`.
    pub fn new(p: usize) -> Self {
        ImageQuadrature {
            p,
            rules: (0..IMAGE_LEVELS.len()).map(|_| None).collect(),
        }
    }

    /// The surface order it serves.
    pub fn order(&self) -> usize {
        self.p
    }

    /// The rule of level `level`.
    pub fn rule(&mut self, level: usize) -> Result<&mut SmoothLayer, TimestepError> {
        let p = self.p;
        let slot = &mut self.rules[level];
        if slot.is_none() {
            *slot = Some(SmoothLayer::new(p, IMAGE_LEVELS[level] * p, 3.0)?);
        }
        Ok(slot.as_mut().expect("built above"))
    }

    /// The sources of one cell on the rule of `level`, in the wall's frame
    /// (its nodes and weighted traction; for a double layer `(y, g dA, n)` per node).
    pub fn sources(
        &mut self,
        level: usize,
        wall: &PlaneWall,
        cell: ImageLayers<'_>,
    ) -> Result<(Vec<PointForce>, Vec<DoubleLayerSource>), TimestepError> {
        layer_sources(wall, self.rule(level)?, cell)
    }

    /// Add the images of one cell's layers at `targets` (above the plane) to `out`
    /// (component-major), each target on the level its distance to the mirror asks (module
    /// docs).
    pub fn add(
        &mut self,
        wall: &PlaneWall,
        viscosity: f64,
        cell: ImageLayers<'_>,
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<(), TimestepError> {
        let (single, double) = self.sources(0, wall, cell)?;
        let reach = ImageReach::of_sources(self.p, &single);
        let levels: Vec<usize> = targets
            .iter()
            .map(|&x| reach.level(wall.to_local(x)))
            .collect();
        add_on_level(wall, viscosity, &single, &double, targets, &levels, 0, out)?;
        for level in 1..IMAGE_LEVELS.len() {
            if levels.contains(&level) {
                let (s, d) = self.sources(level, wall, cell)?;
                add_on_level(wall, viscosity, &s, &d, targets, &levels, level, out)?;
            }
        }
        Ok(())
    }

    /// Add the images of one cell's layers at `targets` on the coarse rule alone (order `3p`,
    /// the rule of the joint solve's images, [`super::near_images`]).
    pub fn add_coarse(
        &mut self,
        wall: &PlaneWall,
        viscosity: f64,
        cell: ImageLayers<'_>,
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<(), TimestepError> {
        let (single, double) = self.sources(0, wall, cell)?;
        add_layer_images(wall, viscosity, &single, &double, targets, out)
    }

    /// Add `fine − coarse` at the `targets` whose level is finer than the coarse one, for a
    /// caller that has summed the coarse sources `coarse` (this cell's, as
    /// [`Self::sources`] gives them at level 0) at every target already. Each finer rule is
    /// built once per call, so callers pass all their targets at once. Whether the cell is
    /// close enough to the plane for any target to need it ([`ImageReach::refines`]).
    pub fn add_refinement(
        &mut self,
        wall: &PlaneWall,
        viscosity: f64,
        cell: ImageLayers<'_>,
        coarse: (&[PointForce], &[DoubleLayerSource]),
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<bool, TimestepError> {
        let reach = ImageReach::of_sources(self.p, coarse.0);
        if !reach.refines() {
            return Ok(false);
        }
        let levels: Vec<usize> = targets
            .iter()
            .map(|&x| reach.level(wall.to_local(x)))
            .collect();
        if levels.iter().all(|&l| l == 0) {
            return Ok(true);
        }
        let index: Vec<usize> = (0..targets.len()).filter(|&t| levels[t] > 0).collect();
        let near: Vec<[f64; 3]> = index.iter().map(|&t| targets[t]).collect();
        let near_levels: Vec<usize> = index.iter().map(|&t| levels[t]).collect();
        let mut v = vec![0.0; 3 * near.len()];
        for level in 1..IMAGE_LEVELS.len() {
            if near_levels.contains(&level) {
                let (s, d) = self.sources(level, wall, cell)?;
                add_on_level(wall, viscosity, &s, &d, &near, &near_levels, level, &mut v)?;
            }
        }
        let mut coarse_v = vec![0.0; 3 * near.len()];
        add_layer_images(wall, viscosity, coarse.0, coarse.1, &near, &mut coarse_v)?;
        for (a, b) in v.iter_mut().zip(&coarse_v) {
            *a -= b;
        }
        crate::wall::scatter_add(&v, &index, out, targets.len());
        Ok(true)
    }
}

/// Add the images of `single` and `double` at the targets whose level is `level`.
#[allow(clippy::too_many_arguments)]
fn add_on_level(
    wall: &PlaneWall,
    viscosity: f64,
    single: &[PointForce],
    double: &[DoubleLayerSource],
    targets: &[[f64; 3]],
    levels: &[usize],
    level: usize,
    out: &mut [f64],
) -> Result<(), TimestepError> {
    if levels.iter().all(|&l| l == level) {
        return add_layer_images(wall, viscosity, single, double, targets, out);
    }
    let index: Vec<usize> = (0..targets.len()).filter(|&t| levels[t] == level).collect();
    if index.is_empty() {
        return Ok(());
    }
    let some: Vec<[f64; 3]> = index.iter().map(|&t| targets[t]).collect();
    let mut v = vec![0.0; 3 * some.len()];
    add_layer_images(wall, viscosity, single, double, &some, &mut v)?;
    crate::wall::scatter_add(&v, &index, out, targets.len());
    Ok(())
}

/// One cell's sources for the images, in the wall's frame: the nodes of its surface on
/// `rule`'s upsampled grid with its traction times the weights (point forces), and, where it
/// has a double-layer density, `(y, g dA, n)` per node (empty without).
fn layer_sources(
    wall: &PlaneWall,
    rule: &mut SmoothLayer,
    cell: ImageLayers<'_>,
) -> Result<(Vec<PointForce>, Vec<DoubleLayerSource>), TimestepError> {
    rule.set_surface(cell.coefs)?;
    rule.set_density(cell.traction)?;
    let single = rule
        .weighted_points()?
        .into_iter()
        .map(|(y, f)| (wall.to_local(y), wall.vector_to_local(f)))
        .collect();
    let mut double = Vec::new();
    if let Some(g) = cell.double_layer {
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
    wall.add_images(viscosity, single, targets, out)?;
    if !double.is_empty() {
        wall.add_double_layer_images(double, targets, out)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ladder goes finer as a target comes down to the plane, and a cell high above it
    /// needs only the coarse rule.
    #[test]
    fn the_level_falls_with_the_distance_to_the_mirror() {
        let at = |h: f64| -> Vec<PointForce> {
            (0..64)
                .map(|k| {
                    let a = k as f64 * 0.1;
                    ([a.cos(), a.sin(), h + 1.0 - a.cos()], [0.0; 3])
                })
                .collect()
        };
        let high = ImageReach::of_sources(8, &at(5.0));
        assert!(!high.refines());
        let low = ImageReach::of_sources(8, &at(0.05));
        assert!(low.refines());
        // Straight down onto the plane under the lowest node, and far off to the side.
        let levels: Vec<usize> = [3.0, 1.0, 0.5, 0.2, 0.05, 0.0]
            .iter()
            .map(|&h| low.level([1.0, 0.0, h]))
            .collect();
        assert_eq!(low.level([30.0, 0.0, 0.01]), 0);
        assert!(levels.windows(2).all(|w| w[0] <= w[1]), "{levels:?}");
        assert_eq!(levels[0], 0);
        assert_eq!(*levels.last().unwrap(), IMAGE_LEVELS.len() - 1);
    }
}

//! The walls' velocity at points in the fluid.
//!
//! `u(x) = Σ_k D_k[ψ_k](x) + Σ_bodies (1/8π)[G(x − c_k) a_k + b_k × r/r³]`. Each double layer
//! is the smooth quadrature at order `3p` ([`SmoothLayer`]) at the targets its bounding-sphere
//! test, or failing that its nodes' distance, resolves (about 1e-10), and the off-surface
//! evaluation of [`crate::vesicle::near`] (smooth quadrature at `6p`, check-point extrapolation
//! or refined quadrature close to the wall; in a run, [`NEAR_ZONE`]'s direct sums where the far
//! rule resolves a near target) at the rest; either says which side of the wall a target is on.

use super::{check_len, WallError, WallKind, WallSolution, WallSystem};
use crate::vesicle::smooth_layer::{Side, SmoothLayer};
use crate::vesicle::{LayerKernel, NearParams, OffSurface};

/// The order of the coarse smooth rule over a wall of order `p`, and the distance ratio it
/// resolves (see [`SmoothLayer`]).
const COARSE_FACTOR: usize = 3;
const COARSE_RATIO: f64 = 3.0;

/// The walls' near-zone settings in a run: the defaults, with near targets 2.5 far-rule
/// spacings or more from the wall summed directly, and those and the far targets on the
/// coarsest rule that resolves them ([`NearParams::smooth_ratio`]). A wall's near zone spans
/// several spacings (on the 20 µm tube at order 40, `δ` = 0.88 and the order-240 spacing bound
/// 0.21), so many of a cell's points close to a wall need no check points. `cargo bench --bench
/// wall_near_zone`: on that tube the largest error over 400 points 0.05–1.3 from the wall is
/// 8.4e-9 of the largest value with these settings and with the defaults (both against the
/// order-480 rule). No refined rules (`max_order: Some(0)`): the defaults give a near target of a
/// wall of order ≤ 21 (`2 · 6p ≤ 256`) the refined order-12p rule where its spacing criterion
/// holds, accurate to about 1e-5 (4.5e-5 of the field 0.1 from a tube of order 20, against
/// 6.9e-9 with check points; docs/walls.md).
pub const NEAR_ZONE: NearParams = NearParams {
    smooth_ratio: Some(2.5),
    max_order: Some(0),
    ..NearParams::DEFAULT
};

/// Evaluator of the walls' velocity at arbitrary points in the fluid.
pub struct WallField {
    surfaces: Vec<OffSurface>,
    coarse: Vec<SmoothLayer>,
    kinds: Vec<WallKind>,
    n_points: Vec<usize>,
    buf: Vec<f64>,
    /// Targets the coarse rule took in the last [`WallField::velocity`], over all walls.
    coarse_targets: usize,
}

impl WallField {
    /// An evaluator for the walls of `system`, with the near-zone settings `params`.
    pub fn new(system: &WallSystem, params: NearParams) -> Result<Self, WallError> {
        let mut surfaces = vec![];
        let mut coarse = vec![];
        for w in system.walls() {
            let mut s = OffSurface::new(w.order(), params)?;
            s.set_surface(w.surface().coefs())?;
            surfaces.push(s);
            let mut c = SmoothLayer::new(w.order(), COARSE_FACTOR * w.order(), COARSE_RATIO)?;
            c.set_surface(w.surface().coefs())?;
            coarse.push(c);
        }
        Ok(WallField {
            surfaces,
            coarse,
            kinds: system.walls().iter().map(|w| w.kind()).collect(),
            n_points: system.walls().iter().map(|w| w.n_points()).collect(),
            buf: vec![],
            coarse_targets: 0,
        })
    }

    /// The velocity of `solution` at `targets`; `out` is component-major (`3 · targets.len()`).
    /// Returns the smallest distance of a target to a wall among the targets the coarse rule
    /// left to the near-zone evaluator (exact within its near zone, an upper bound beyond;
    /// infinite when every target was far).
    ///
    /// # Errors
    /// [`WallError::NotInFluid`] for a target inside a body or outside the container.
    pub fn velocity(
        &mut self,
        solution: &WallSolution,
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<f64, WallError> {
        let nt = targets.len();
        let mut closest = f64::INFINITY;
        check_len("wall velocity output", out.len(), 3 * nt)?;
        out.fill(0.0);
        self.buf.resize(3 * nt, 0.0);
        let mut near_targets = vec![];
        let mut near_index = vec![];
        let mut far_targets = vec![];
        let mut far_index = vec![];
        self.coarse_targets = 0;
        for k in 0..self.surfaces.len() {
            let density = solution.density(k);
            check_len("wall density", density.len(), 3 * self.n_points[k])?;
            let kind = self.kinds[k];
            let wrong_side = |i: usize| {
                Err(WallError::NotInFluid {
                    index: i,
                    point: targets[i],
                    reason: match kind {
                        WallKind::Container => format!("outside the container, wall {k}"),
                        WallKind::Body => format!("inside body {k}"),
                    },
                })
            };
            near_targets.clear();
            near_index.clear();
            far_targets.clear();
            far_index.clear();
            for (i, &x) in targets.iter().enumerate() {
                let side = match self.coarse[k].side(x) {
                    // The bounding spheres leave every point of a long wall unresolved; its
                    // nodes may still bound the point's distance above the resolved one.
                    Side::Unresolved => match self.coarse[k].side_by_distance(x) {
                        // The near-zone evaluator decides (and names) a point on the wrong side.
                        Side::FarInside if kind == WallKind::Body => Side::Unresolved,
                        Side::FarOutside if kind == WallKind::Container => Side::Unresolved,
                        s => s,
                    },
                    s => s,
                };
                match (side, kind) {
                    (Side::FarOutside, WallKind::Body) | (Side::FarInside, WallKind::Container) => {
                        far_targets.push(x);
                        far_index.push(i);
                    }
                    (Side::Unresolved, _) => {
                        near_targets.push(x);
                        near_index.push(i);
                    }
                    _ => return wrong_side(i),
                }
            }
            self.coarse_targets += far_targets.len();
            if !far_targets.is_empty() {
                let c = &mut self.coarse[k];
                c.set_density(density)?;
                self.buf.clear();
                self.buf.resize(3 * far_targets.len(), 0.0);
                c.add_to(LayerKernel::DoubleLayer, &far_targets, &mut self.buf)?;
                scatter_add(&self.buf, &far_index, out, nt);
            }
            if !near_targets.is_empty() {
                self.buf.clear();
                self.buf.resize(3 * near_targets.len(), 0.0);
                let infos = match solution.own_double_layer(k) {
                    Some(on_surface) => self.surfaces[k].evaluate_given_on_surface(
                        LayerKernel::DoubleLayer,
                        density,
                        on_surface,
                        &near_targets,
                        &mut self.buf,
                    )?,
                    None => self.surfaces[k].evaluate(
                        LayerKernel::DoubleLayer,
                        density,
                        &near_targets,
                        &mut self.buf,
                    )?,
                };
                for (j, info) in infos.iter().enumerate() {
                    closest = closest.min(info.distance);
                    let wrong = match kind {
                        WallKind::Container => !info.inside,
                        WallKind::Body => info.inside,
                    };
                    if wrong {
                        return wrong_side(near_index[j]);
                    }
                }
                scatter_add(&self.buf, &near_index, out, nt);
            }
        }
        for (i, &x) in targets.iter().enumerate() {
            let u = solution.completion_at(x);
            for a in 0..3 {
                out[a * nt + i] += u[a];
            }
        }
        Ok(closest)
    }
}

impl WallField {
    /// How many targets the coarse rule took in the last [`WallField::velocity`] (counted once
    /// per wall), the rest going to the near-zone evaluator.
    pub fn coarse_targets(&self) -> usize {
        self.coarse_targets
    }

    /// Whether each target is in the fluid (inside the container, outside every body): the
    /// bounding spheres decide where they can, the closest surface point's normal (or the
    /// solid angle, see [`OffSurface::classify`]) elsewhere.
    pub fn in_fluid(&mut self, targets: &[[f64; 3]]) -> Result<Vec<bool>, WallError> {
        let mut fluid = vec![true; targets.len()];
        for k in 0..self.surfaces.len() {
            let container = self.kinds[k] == WallKind::Container;
            for (i, &x) in targets.iter().enumerate() {
                if !fluid[i] {
                    continue;
                }
                let inside = match self.coarse[k].side(x) {
                    Side::FarInside => true,
                    Side::FarOutside => false,
                    Side::Unresolved => self.surfaces[k].classify(x)?.inside,
                };
                fluid[i] = inside == container;
            }
        }
        Ok(fluid)
    }
}

/// Add `v` (component-major over `index.len()` targets) to `out` (component-major over `nt`)
/// at the targets `index`.
pub fn scatter_add(v: &[f64], index: &[usize], out: &mut [f64], nt: usize) {
    let m = index.len();
    for (j, &i) in index.iter().enumerate() {
        for a in 0..3 {
            out[a * nt + i] += v[a * m + j];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wall::{tube_surface, Wall, WallParams};

    /// Points of a tube that its bounding sphere leaves unresolved, but whose distance from
    /// the wall's nodes resolves them, take the coarse rule, and get the value the near-zone
    /// evaluator gives every point (about 1e-10 apart); the points near the wall keep the
    /// near-zone evaluator.
    #[test]
    fn points_deep_in_a_tube_take_the_coarse_rule_to_the_near_zone_value() {
        // The coarse rule resolves `3 · 2π R_max / 3p` = 1.4 at order 24, R_max the half-length.
        let (radius, length) = (3.0, 10.0);
        let wall = Wall::new(
            WallKind::Container,
            tube_surface(24, radius, length).unwrap(),
        )
        .unwrap();
        // Poiseuille's profile on the whole wall, the inflow and outflow at the ends.
        let n = wall.n_points();
        let mut u = vec![0.0; 3 * n];
        for (j, x) in wall.geometry().x.iter().enumerate() {
            u[j] = 1.0 - (x[1] * x[1] + x[2] * x[2]) / (radius * radius);
        }
        let system = WallSystem::new(vec![wall], WallParams::default()).unwrap();
        let solution = system.solve(&u).unwrap();
        let mut field = WallField::new(&system, NearParams::default()).unwrap();
        let mut targets = vec![];
        for i in 0..=12 {
            for j in 0..7 {
                let (r, phi) = (2.85 * i as f64 / 12.0, 0.9 * j as f64);
                targets.push([-3.0 + j as f64, r * phi.cos(), r * phi.sin()]);
            }
        }
        let coarse = &field.coarse[0];
        let by_sphere = targets
            .iter()
            .filter(|&&x| coarse.side(x) != Side::Unresolved)
            .count();
        let by_nodes = targets
            .iter()
            .filter(|&&x| coarse.side_by_distance(x) == Side::FarInside)
            .count();
        assert!(
            by_nodes >= 2 * by_sphere && 3 * by_nodes > targets.len() && by_nodes < targets.len(),
            "{by_nodes} of {} points resolved by the nodes, {by_sphere} by the sphere",
            targets.len()
        );
        let nt = targets.len();
        let mut got = vec![0.0; 3 * nt];
        field.velocity(&solution, &targets, &mut got).unwrap();
        assert_eq!(field.coarse_targets(), by_nodes);
        // Every point through the near-zone evaluator, as before the nodes' test.
        let mut want = vec![0.0; 3 * nt];
        field.surfaces[0]
            .evaluate_given_on_surface(
                LayerKernel::DoubleLayer,
                solution.density(0),
                solution.own_double_layer(0).unwrap(),
                &targets,
                &mut want,
            )
            .unwrap();
        for (i, &x) in targets.iter().enumerate() {
            let c = solution.completion_at(x);
            for a in 0..3 {
                want[a * nt + i] += c[a];
            }
        }
        let size = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let diff = got
            .iter()
            .zip(&want)
            .fold(0.0f64, |m, (g, w)| m.max((g - w).abs()))
            / size;
        println!(
            "{by_nodes} of {nt} points resolved by the nodes ({by_sphere} by the sphere); \
             largest difference {diff:.2e}"
        );
        assert!(
            diff < 1e-9,
            "coarse rule off the near-zone value by {diff:.2e}"
        );
    }
}

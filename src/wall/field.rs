//! The walls' velocity at points in the fluid.
//!
//! `u(x) = Σ_k D_k[ψ_k](x) + Σ_bodies (1/8π)[G(x − c_k) a_k + b_k × r/r³]`. Each double layer
//! is the smooth quadrature at order `3p` ([`SmoothLayer`]) at the targets its bounding-sphere
//! test resolves (about 1e-10), and the off-surface evaluation of [`crate::vesicle::near`]
//! (smooth quadrature at `6p`, check-point extrapolation or refined quadrature close to the
//! wall) at the rest; either says which side of the wall a target is on.

use super::{check_len, WallError, WallKind, WallSolution, WallSystem};
use crate::vesicle::smooth_layer::{Side, SmoothLayer};
use crate::vesicle::{LayerKernel, NearParams, OffSurface};

/// The order of the coarse smooth rule over a wall of order `p`, and the distance ratio it
/// resolves (see [`SmoothLayer`]).
const COARSE_FACTOR: usize = 3;
const COARSE_RATIO: f64 = 3.0;

/// Evaluator of the walls' velocity at arbitrary points in the fluid.
pub struct WallField {
    surfaces: Vec<OffSurface>,
    coarse: Vec<SmoothLayer>,
    kinds: Vec<WallKind>,
    n_points: Vec<usize>,
    buf: Vec<f64>,
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
                match (self.coarse[k].side(x), kind) {
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

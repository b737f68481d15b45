//! The walls' velocity at points in the fluid.
//!
//! `u(x) = Σ_k D_k[ψ_k](x) + Σ_bodies (1/8π)[G(x − c_k) a_k + b_k × r/r³]`, each double layer
//! by the off-surface evaluation of [`crate::vesicle::near`] (smooth quadrature far away,
//! check-point extrapolation or refined quadrature close to the wall), which also says which
//! side of each wall a target is on.

use super::{check_len, WallError, WallKind, WallSolution, WallSystem};
use crate::vesicle::{LayerKernel, NearParams, OffSurface};

/// Evaluator of the walls' velocity at arbitrary points in the fluid.
pub struct WallField {
    surfaces: Vec<OffSurface>,
    kinds: Vec<WallKind>,
    n_points: Vec<usize>,
    buf: Vec<f64>,
}

impl WallField {
    /// An evaluator for the walls of `system`, with the near-zone settings `params`.
    pub fn new(system: &WallSystem, params: NearParams) -> Result<Self, WallError> {
        let mut surfaces = vec![];
        for w in system.walls() {
            let mut s = OffSurface::new(w.order(), params)?;
            s.set_surface(w.surface().coefs())?;
            surfaces.push(s);
        }
        Ok(WallField {
            surfaces,
            kinds: system.walls().iter().map(|w| w.kind()).collect(),
            n_points: system.walls().iter().map(|w| w.n_points()).collect(),
            buf: vec![],
        })
    }

    /// The velocity of `solution` at `targets`; `out` is component-major (`3 · targets.len()`).
    ///
    /// # Errors
    /// [`WallError::NotInFluid`] for a target inside a body or outside the container.
    pub fn velocity(
        &mut self,
        solution: &WallSolution,
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<(), WallError> {
        let nt = targets.len();
        check_len("wall velocity output", out.len(), 3 * nt)?;
        out.fill(0.0);
        self.buf.resize(3 * nt, 0.0);
        for (k, s) in self.surfaces.iter_mut().enumerate() {
            let density = solution.density(k);
            check_len("wall density", density.len(), 3 * self.n_points[k])?;
            let infos = s.evaluate(LayerKernel::DoubleLayer, density, targets, &mut self.buf)?;
            for (i, info) in infos.iter().enumerate() {
                let wrong = match self.kinds[k] {
                    WallKind::Container => !info.inside,
                    WallKind::Body => info.inside,
                };
                if wrong {
                    return Err(WallError::NotInFluid {
                        index: i,
                        point: targets[i],
                        reason: match self.kinds[k] {
                            WallKind::Container => format!("outside the container, wall {k}"),
                            WallKind::Body => format!("inside body {k}"),
                        },
                    });
                }
            }
            for (o, b) in out.iter_mut().zip(&self.buf) {
                *o += b;
            }
        }
        for (i, &x) in targets.iter().enumerate() {
            let u = solution.completion_at(x);
            for a in 0..3 {
                out[a * nt + i] += u[a];
            }
        }
        Ok(())
    }
}

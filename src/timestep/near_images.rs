//! The images of near cells in a plane wall, inside the joint solve of the near-implicit
//! coupling ([`super::near_implicit`]).
//!
//! Beside a plane wall ([`crate::wall::PlaneWall`], Blake's images) every cell feels the
//! images of every cell's layers, its own included. [`super::plane_coupling`] adds them to a
//! step's explicit velocity `v*` from the densities at its start (extrapolated by BDF2). For a
//! cell close to the wall its own image is strong: a rigid sphere pulled onto the plane `z = 0`
//! from `h = 1.1276` radii (a gap of an eighth of a radius) moves 149 % faster than Brenner's
//! rate in the first step, and the error falls by only a factor of about 0.8 a step
//! (`tests/plane_wall.rs`), because the images lag one step behind the traction they
//! answer. In the near-implicit step the images of a cell `j` at the targets `x` of cell `i`
//! within the *image's* zone (`x` within `r_j + δ_j` of the mirror of `j`'s centroid,
//! `i = j` included; [`super::near_pairs::NearZones::images`]) enter the joint system as the
//! near-zone operator does:
//!
//! ```text
//!     v_i = v*_i + Σ_j (K*_ij + I_ij) (ρ_j^{n+1} − ρ_j*),
//!     I_ij (f_j, g_j)(x) = S^img_j[f_j](x) + D^img_j[g_j](x),
//! ```
//!
//! so the images answer the traction of the step itself. This module evaluates `I_ij`: the
//! images of one cell's layers at given points, by the coarse rule of the explicit images
//! (order `3p`, [`super::image_quadrature::ImageQuadrature::add_coarse`]). The explicit images
//! `v*` are refined near the mirror ([`super::plane_coupling`]); `I_ij` is not, because it
//! multiplies only the change of the densities within a step. Measured on three RBCs with
//! `λ = 5` pulled onto the plane in shear (gaps down to 0.105, p = 8, 60 steps): refining
//! `I_ij` too moves the points by 4.8e-6, where refining `v*` moved them by 3.1e-3, and costs
//! 1.7× the step time.

use std::sync::Mutex;

use super::image_quadrature::{ImageLayers, ImageQuadrature};
use super::TimestepError;
use crate::wall::PlaneWall;

/// The images of cells of order `p` in a plane wall, as the joint solve applies them: smooth
/// rules pooled between calls.
pub struct NearImages {
    wall: PlaneWall,
    viscosity: f64,
    p: usize,
    /// Ladders of rules (only the coarse rule is used), one per thread at work.
    pool: Mutex<Vec<ImageQuadrature>>,
}

impl NearImages {
    /// The images in `wall` of cells of order `p` in a fluid of viscosity `viscosity`.
    pub fn new(wall: PlaneWall, viscosity: f64, p: usize) -> Self {
        NearImages {
            wall,
            viscosity,
            p,
            pool: Mutex::new(Vec::new()),
        }
    }

    /// The wall.
    pub fn wall(&self) -> &PlaneWall {
        &self.wall
    }

    /// The mirror point of `x` in the plane.
    pub fn mirror(&self, x: [f64; 3]) -> [f64; 3] {
        let h = self.wall.height(x);
        let n = self.wall.normal();
        std::array::from_fn(|a| x[a] - 2.0 * h * n[a])
    }

    /// Add the images of one cell's layers, its surface `surface` (order-`p` coefficients),
    /// traction `f` and double-layer density `g` (`None`: none), at `points` to `out`
    /// (component-major, `3 · points.len()`).
    pub fn add(
        &self,
        surface: &[f64],
        f: &[f64],
        g: Option<&[f64]>,
        points: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<(), TimestepError> {
        let free = self.pool.lock().unwrap_or_else(|e| e.into_inner()).pop();
        let mut rule = free.unwrap_or_else(|| ImageQuadrature::new(self.p));
        let cell = ImageLayers {
            coefs: surface,
            traction: f,
            double_layer: g,
        };
        let done = rule.add_coarse(&self.wall, self.viscosity, cell, points, out);
        self.pool
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(rule);
        done
    }
}

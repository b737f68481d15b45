//! Tension force and the surface divergence of a velocity (local inextensibility).
//!
//! `E_σ = ∫ σ dA` with `σ` a fixed function of the material point `(θ, φ)`;
//! `f_σ = ∇_s σ + 2σH n` (so that `∫ f_σ·δX dA = −δE_σ`, because `δ dA = ∇_s·δX dA` and
//! `∇_s·n = −2H` in the convention `H = −1/R` on a sphere). Both maps are linear in their field
//! and use the frozen geometry of the [`Membrane`].

use super::membrane::Membrane;
use super::{check_len, VesicleError};

impl Membrane {
    /// `E_σ = ∫ σ dA` for `σ` on the order-`p` grid (upsampled, quadrature at `q`).
    pub fn tension_energy(&mut self, sigma: &[f64]) -> Result<f64, VesicleError> {
        self.require_geometry()?;
        check_len("tension", sigma.len(), self.n_points())?;
        let mut s = std::mem::take(&mut self.s2);
        let r = self.upsample(sigma, &mut s);
        let e = self.geom.integrate(&s);
        self.s2 = s;
        r.map(|_| e)
    }

    /// Tension force `∇_s σ + 2σH n` on the order-`p` grid (filtered), `σ` on the order-`p` grid.
    pub fn tension_force(&mut self, sigma: &[f64], out: &mut [f64]) -> Result<(), VesicleError> {
        self.tension_fine(sigma)?;
        self.emit_vector(out, true)
    }

    /// Tension force on the order-`q` grid, unfiltered.
    pub fn tension_force_upsampled(
        &mut self,
        sigma: &[f64],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        self.tension_fine(sigma)?;
        self.emit_vector(out, false)
    }

    fn tension_fine(&mut self, sigma: &[f64]) -> Result<(), VesicleError> {
        self.require_geometry()?;
        check_len("tension", sigma.len(), self.n_points())?;
        let nq = self.n_points_upsampled();
        let mut s = std::mem::take(&mut self.s2);
        let mut a = std::mem::take(&mut self.a);
        let r = self
            .upsample(sigma, &mut s)
            .and_then(|_| self.calc.gradient(&self.geom, &s, &mut a));
        if r.is_ok() {
            let g = &self.geom;
            for j in 0..nq {
                let t = 2.0 * s[j] * g.h[j];
                for c in 0..3 {
                    a[c * nq + j] += t * g.normal[j][c];
                }
            }
        }
        self.s2 = s;
        self.a = a;
        r
    }

    /// Surface divergence `∇_s·u` of a velocity on the order-`p` grid (component-major); the
    /// result, computed at `q` and filtered by [`Membrane::filter_density`] (so that
    /// `∫ σ ∇_s·u dA` is preserved for `σ` of degree `≤ p`), is on the order-`p` grid.
    pub fn surface_divergence(&mut self, u: &[f64], out: &mut [f64]) -> Result<(), VesicleError> {
        self.require_geometry()?;
        check_len("velocity", u.len(), 3 * self.n_points())?;
        check_len("divergence output", out.len(), self.n_points())?;
        let mut b = std::mem::take(&mut self.b);
        let mut s = std::mem::take(&mut self.s1);
        let r = self
            .upsample(u, &mut b)
            .and_then(|_| self.calc.divergence(&self.geom, &b, &mut s))
            .and_then(|_| self.filter_density(&mut s, out));
        self.b = b;
        self.s1 = s;
        r
    }
}

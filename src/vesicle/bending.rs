//! Helfrich bending force (see the [module docs](super) for the energy and sign convention).
//!
//! `E_b = (κ_b/2) ∫ (2H)² dA`, `f_b = −2κ_b (Δ_s H + 2H(H² − K)) n`, with `H` the average of the
//! principal curvatures (`−1/R` on a sphere). The linearised operator at frozen geometry replaces
//! `H` inside `Δ_s H` and the prefactor `2H` by `H_Y = ½ n·Δ_s Y` (Veerapaneni et al. 2011, §3):
//! `Y ↦ −2κ_b (Δ_s H_Y + 2H_Y(H² − K)) n`, which equals `f_b` at `Y = X` because `Δ_s X = 2H n`.

use super::membrane::Membrane;
use super::{check_len, dot, VesicleError};

fn check_kappa(kappa: f64) -> Result<(), VesicleError> {
    if kappa.is_finite() && kappa >= 0.0 {
        Ok(())
    } else {
        Err(VesicleError::Parameter {
            name: "bending modulus",
            value: kappa,
            reason: "must be finite and non-negative",
        })
    }
}

impl Membrane {
    /// Bending energy `(κ_b/2) ∫ (2H)² dA` of the frozen geometry (quadrature at order `q`).
    pub fn bending_energy(&self, kappa: f64) -> Result<f64, VesicleError> {
        check_kappa(kappa)?;
        let g = self.geometry()?;
        Ok(2.0 * kappa * g.h.iter().zip(&g.da).map(|(h, w)| h * h * w).sum::<f64>())
    }

    /// Bending force density on the order-`p` grid (computed at `q`, filtered), component-major.
    pub fn bending_force(&mut self, kappa: f64, out: &mut [f64]) -> Result<(), VesicleError> {
        self.bending_fine(kappa)?;
        self.emit_vector(out, true)
    }

    /// Bending force density on the order-`q` grid, unfiltered.
    pub fn bending_force_upsampled(
        &mut self,
        kappa: f64,
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        self.bending_fine(kappa)?;
        self.emit_vector(out, false)
    }

    /// `f_b` at order `q` into `self.a`.
    fn bending_fine(&mut self, kappa: f64) -> Result<(), VesicleError> {
        check_kappa(kappa)?;
        self.require_geometry()?;
        let nq = self.n_points_upsampled();
        self.calc
            .laplace_beltrami(&self.geom, &self.geom.h, &mut self.s1)?;
        let g = &self.geom;
        for j in 0..nq {
            let h = g.h[j];
            let s = -2.0 * kappa * (self.s1[j] + 2.0 * h * (h * h - g.k[j]));
            for c in 0..3 {
                self.a[c * nq + j] = s * g.normal[j][c];
            }
        }
        Ok(())
    }

    /// The bending operator linearised at the frozen geometry applied to `Y` (order-`p` grid
    /// positions, component-major); the result is on the order-`p` grid (filtered).
    pub fn bending_linear(
        &mut self,
        kappa: f64,
        y: &[f64],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        check_kappa(kappa)?;
        self.require_geometry()?;
        check_len("positions Y", y.len(), 3 * self.n_points())?;
        let nq = self.n_points_upsampled();
        let mut b = std::mem::take(&mut self.b);
        let mut a = std::mem::take(&mut self.a);
        let r = (|| {
            self.upsample(y, &mut b)?;
            self.calc.laplace_beltrami_vec(&self.geom, &b, &mut a)?;
            // H_Y = ½ n·Δ_s Y
            for j in 0..nq {
                let l = [a[j], a[nq + j], a[2 * nq + j]];
                self.s2[j] = 0.5 * dot(self.geom.normal[j], l);
            }
            self.calc
                .laplace_beltrami(&self.geom, &self.s2, &mut self.s1)?;
            let g = &self.geom;
            for j in 0..nq {
                let h = g.h[j];
                let s = -2.0 * kappa * (self.s1[j] + 2.0 * self.s2[j] * (h * h - g.k[j]));
                for c in 0..3 {
                    a[c * nq + j] = s * g.normal[j][c];
                }
            }
            Ok::<(), VesicleError>(())
        })();
        self.a = a;
        self.b = b;
        r?;
        self.emit_vector(out, true)
    }
}

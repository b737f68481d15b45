//! The Stokes kernels of the layer potentials ([`LayerKernel`]) and their nine entries at one
//! source–target pair (`kernel_entries`), shared by the singular quadrature of
//! [`super::layer`] and the far-side split of [`super::far_side`].

use std::f64::consts::PI;

use super::{dot, VesicleError};

/// The kernel of a layer potential.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LayerKernel {
    /// Stokes single layer with viscosity `μ`.
    SingleLayer {
        /// `μ`.
        viscosity: f64,
    },
    /// Stokes double layer `(3/4π) ∫ (r·n)(r⊗r)/r⁵ u dA`.
    DoubleLayer,
}

impl LayerKernel {
    /// Error unless the parameters are valid (a positive, finite viscosity).
    pub(crate) fn check(&self) -> Result<(), VesicleError> {
        if let LayerKernel::SingleLayer { viscosity } = *self {
            if !(viscosity.is_finite() && viscosity > 0.0) {
                return Err(VesicleError::Parameter {
                    name: "viscosity",
                    value: viscosity,
                    reason: "must be positive and finite",
                });
            }
        }
        Ok(())
    }
}

/// The nine entries `K_ab` (row-major, `3a + b`) of a layer kernel at `r = x − y` with the unit
/// normal `n` at `y`, times the weight `wt`: single layer `wt (δ_ab/r + r_a r_b/r³) / 8πμ`, double
/// layer `wt (3/4π) (r·n) r_a r_b / r⁵`.
#[inline]
pub(crate) fn kernel_entries(kernel: LayerKernel, r: [f64; 3], n: [f64; 3], wt: f64) -> [f64; 9] {
    let r2 = dot(r, r);
    let rinv = 1.0 / r2.sqrt();
    let mut col = [0.0; 9];
    match kernel {
        LayerKernel::SingleLayer { viscosity } => {
            let c = wt / (8.0 * PI * viscosity) * rinv;
            let c3 = c / r2;
            for a in 0..3 {
                for b in 0..3 {
                    col[3 * a + b] = c3 * r[a] * r[b] + if a == b { c } else { 0.0 };
                }
            }
        }
        LayerKernel::DoubleLayer => {
            let c = 3.0 / (4.0 * PI) * wt * dot(r, n) * rinv.powi(5);
            for a in 0..3 {
                for b in 0..3 {
                    col[3 * a + b] = c * r[a] * r[b];
                }
            }
        }
    }
    col
}

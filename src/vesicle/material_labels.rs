//! Material labels: which point of a fixed reference surface each grid point of a membrane is.
//!
//! A stress-free reference `X_ref` (of the Skalak law) must stay attached to the material when
//! the reparametrisation moves the grid along the membrane. Relabelling the reference's own
//! coefficients at every move, `X_ref ← F[X_ref(θ + δθ, φ + δφ)]`, re-fits the composed surface
//! at order `p` each time, and the re-fits accumulate as a change of the reference *shape*
//! (measured, an RBC in shear at p = 12: its area drifted by 2.4 % and its high-degree share
//! grew 100-fold over 3800 steps, until the elastic stress it implied stopped the run).
//!
//! Here the reference keeps its first coefficients `x̂_ref` and each grid point carries a label
//! `ξ(θ, φ)`, a direction on the unit sphere of the reference's parameters (three expansions,
//! the identity `ξ = (sin θ cos φ, sin θ sin φ, cos θ)` at the start, of degree 1). The
//! reparametrisation relabels `ξ` instead of `X_ref`, and the reference in the current
//! parametrisation is composed afresh,
//!
//! ```text
//!     X_ref(θ, φ) = F[ Σ x̂_ref Y(ϑ(ξ), ϕ(ξ)) ]   (ϑ, ϕ the angles of ξ(θ_j, φ_j) at every grid point),
//! ```
//!
//! so the reference's shape is its first shape up to one re-fit, whatever the number of moves;
//! what the moves' re-fits can still change is which material point a label names (a
//! tangential slip), never the reference's area or volume.

use super::point::PointEval;
use super::{check_len, VesicleError};
use crate::sph_harmonics::{ShTransform, ShWorkspace};

/// A fixed reference surface and the label map of the current grid (both order-`p`
/// coefficients, three functions each).
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialLabels {
    /// `x̂_ref`: the reference in its own parametrisation.
    pub original: Vec<f64>,
    /// `ξ`: the label of every point of the current parametrisation.
    pub map: Vec<f64>,
}

impl MaterialLabels {
    /// Labels of a grid that is the reference's own (the identity map).
    pub fn identity(
        sht: &ShTransform,
        ws: &mut ShWorkspace,
        original: &[f64],
    ) -> Result<Self, VesicleError> {
        check_len("reference surface", original.len(), 3 * sht.n_coefs())?;
        let n = sht.n_points();
        let mut grid = vec![0.0; 3 * n];
        for (j, u) in sht.grid().unit_points().iter().enumerate() {
            for c in 0..3 {
                grid[c * n + j] = u[c];
            }
        }
        let mut map = vec![0.0; 3 * sht.n_coefs()];
        sht.forward(&grid, &mut map, ws)?;
        Ok(MaterialLabels {
            original: original.to_vec(),
            map,
        })
    }

    /// The reference in the current parametrisation, `F[X_ref(angles of ξ)]` (module docs),
    /// into `out` (order-`p` coefficients).
    pub fn compose(
        &self,
        sht: &ShTransform,
        ws: &mut ShWorkspace,
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        let nc = sht.n_coefs();
        for (what, len) in [
            ("reference surface", self.original.len()),
            ("label map", self.map.len()),
            ("composed reference", out.len()),
        ] {
            check_len(what, len, 3 * nc)?;
        }
        let n = sht.n_points();
        let mut labels = vec![0.0; 3 * n];
        sht.inverse(&self.map, &mut labels, ws)?;
        let lay = sht.layout();
        let mut pe = PointEval::new(lay.order());
        let mut grid = vec![0.0; 3 * n];
        for j in 0..n {
            let (x, y, z) = (labels[j], labels[n + j], labels[2 * n + j]);
            let r = (x * x + y * y + z * z).sqrt();
            if !(r.is_finite() && r > 0.0) {
                return Err(VesicleError::Parameter {
                    name: "material label",
                    value: r,
                    reason: "must be a nonzero direction",
                });
            }
            let (theta, phi) = ((x * x + y * y).sqrt().atan2(z), y.atan2(x));
            let at = pe.eval_values(lay, &self.original, theta, phi);
            for (c, xc) in at.into_iter().enumerate() {
                grid[c * n + j] = xc;
            }
        }
        sht.forward(&grid, out, ws)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Coefficients of `A u(θ, φ)` for a 3×3 matrix `A` (`u` the unit grid direction): of
    /// degree 1, so exact at any order.
    fn linear_map(sht: &ShTransform, ws: &mut ShWorkspace, a: [[f64; 3]; 3]) -> Vec<f64> {
        let n = sht.n_points();
        let mut grid = vec![0.0; 3 * n];
        for (j, u) in sht.grid().unit_points().iter().enumerate() {
            for (c, row) in a.iter().enumerate() {
                grid[c * n + j] = row[0] * u[0] + row[1] * u[1] + row[2] * u[2];
            }
        }
        let mut coefs = vec![0.0; 3 * sht.n_coefs()];
        sht.forward(&grid, &mut coefs, ws).unwrap();
        coefs
    }

    fn max_diff(a: &[f64], b: &[f64]) -> f64 {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max)
    }

    #[test]
    fn identity_labels_compose_the_reference_itself() {
        let p = 8;
        let sht = ShTransform::new(p).unwrap();
        let mut ws = sht.workspace();
        let rbc = crate::vesicle::shapes::rbc(p).unwrap();
        let labels = MaterialLabels::identity(&sht, &mut ws, rbc.coefs()).unwrap();
        let mut out = vec![0.0; rbc.coefs().len()];
        labels.compose(&sht, &mut ws, &mut out).unwrap();
        let err = max_diff(&out, rbc.coefs());
        assert!(err < 1e-13, "{err:.2e}");
    }

    #[test]
    fn turned_labels_compose_the_turned_reference_exactly() {
        // The ellipsoid X_ref(ξ) = D ξ, D = diag(a, b, c), under labels ξ = R u (R a rotation):
        // the composed reference is D R u, of degree 1, so the one re-fit is exact.
        let p = 6;
        let sht = ShTransform::new(p).unwrap();
        let mut ws = sht.workspace();
        let d = [[1.3, 0.0, 0.0], [0.0, 0.9, 0.0], [0.0, 0.0, 0.6]];
        let (s, c) = 0.7f64.sin_cos();
        let (s2, c2) = 0.4f64.sin_cos();
        // R = R_x(0.4) R_z(0.7).
        let rz = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]];
        let rx = [[1.0, 0.0, 0.0], [0.0, c2, -s2], [0.0, s2, c2]];
        let mul = |a: [[f64; 3]; 3], b: [[f64; 3]; 3]| -> [[f64; 3]; 3] {
            std::array::from_fn(|i| {
                std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum())
            })
        };
        let r = mul(rx, rz);
        let labels = MaterialLabels {
            original: linear_map(&sht, &mut ws, d),
            map: linear_map(&sht, &mut ws, r),
        };
        let mut out = vec![0.0; 3 * sht.n_coefs()];
        labels.compose(&sht, &mut ws, &mut out).unwrap();
        let want = linear_map(&sht, &mut ws, mul(d, r));
        let err = max_diff(&out, &want);
        assert!(err < 1e-13, "{err:.2e}");
    }

    #[test]
    fn bad_sizes_and_labels_are_errors() {
        let sht = ShTransform::new(4).unwrap();
        let mut ws = sht.workspace();
        assert!(MaterialLabels::identity(&sht, &mut ws, &[0.0; 5]).is_err());
        let nc = 3 * sht.n_coefs();
        let labels = MaterialLabels {
            original: vec![0.0; nc],
            map: vec![0.0; nc],
        };
        let mut out = vec![0.0; nc];
        // A zero label has no direction.
        assert!(labels.compose(&sht, &mut ws, &mut out).is_err());
        assert!(labels.compose(&sht, &mut ws, &mut out[..3]).is_err());
    }
}

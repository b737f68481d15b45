//! The orientation of a cell's parametrisation, and the sphere preconditioner turned with it.
//!
//! The sphere preconditioner ([`super::sphere_preconditioner`]) inverts the step operator of a
//! sphere whose grid point of direction `ξ_j` (a point of the unit sphere) has the outward
//! normal `ξ_j`. The step operator acts on positions and velocities in Cartesian components,
//! and every part of it is equivariant under rotations: if a cell and its parametrisation turn
//! together by `R` (a tumbling cell, or a grid carried by the membrane's rotation), its
//! operator becomes `Q A Qᵀ`, with `Q` rotating the three Cartesian components of every grid
//! point by `R` (tensions are scalars), while the sphere's operator stays `A_R`. The mismatch
//! grows with the angle: GMRES iterations per step grow steadily, and a step fails once the
//! grid has turned by a right angle or so (one prolate vesicle, reduced volume 0.85, in a
//! rigid rotation at p = 12: 55 → 143 iterations per step over one radian).
//!
//! The fix is to turn the preconditioner with the grid, `M_R⁻¹ = Q M⁻¹ Qᵀ`, which is exact
//! again for a turned sphere. `R` is measured afresh at every step, with no state to carry or
//! checkpoint, as the rotation closest to mapping the grid directions onto the cell's normals:
//! the maximiser of `Σ_j w_j n_j · R ξ_j` (weights `w_j` the area elements), the orthogonal
//! polar factor of `H = Σ_j w_j n_j ξ_jᵀ` (the Kabsch problem): `R = H (HᵀH)^{−1/2}`.

use std::sync::Mutex;

use super::operator::Preconditioner;
use crate::vesicle::geometry::{symmetric_eigen3, Geometry};

/// A 3 × 3 rotation, rows first.
pub type Rotation = [[f64; 3]; 3];

/// The identity rotation.
pub const IDENTITY: Rotation = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// The rotation `R` that best maps the grid directions `directions` (unit vectors, one per grid
/// point) onto the normals of `geom` (same grid), weighted by the area elements: the
/// orthogonal polar factor of `H = Σ w_j n_j ξ_jᵀ`. Falls back to the identity when `H` is
/// singular or its polar factor a reflection (no surface a step produces).
pub fn grid_rotation(geom: &Geometry, directions: &[[f64; 3]]) -> Rotation {
    let mut h = [[0.0; 3]; 3];
    for ((n, xi), w) in geom.normal.iter().zip(directions).zip(&geom.da) {
        for a in 0..3 {
            for b in 0..3 {
                h[a][b] += w * n[a] * xi[b];
            }
        }
    }
    polar_rotation(h).unwrap_or(IDENTITY)
}

/// `R Sᵀ`: the turn from the frame `s` to the frame `r` (a preconditioner built when the grid's
/// frame was `s`, used when it is `r`).
pub fn relative_rotation(r: &Rotation, s: &Rotation) -> Rotation {
    let mut out = [[0.0; 3]; 3];
    for (a, row) in out.iter_mut().enumerate() {
        for (b, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| r[a][k] * s[b][k]).sum();
        }
    }
    out
}

/// The orthogonal polar factor `H (HᵀH)^{−1/2}` of `h`, if `h` is well conditioned and its
/// determinant positive.
pub fn polar_rotation(h: [[f64; 3]; 3]) -> Option<Rotation> {
    let mut hth = [[0.0; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            hth[a][b] = (0..3).map(|k| h[k][a] * h[k][b]).sum();
        }
    }
    let (vals, vecs) = symmetric_eigen3(hth);
    // Singular (or NaN): the smallest eigenvalue not safely positive.
    let well_conditioned = vals[2].is_finite() && vals[0] > 1e-12 * vals[2];
    if !well_conditioned {
        return None;
    }
    // (HᵀH)^{−1/2} = Σ v vᵀ / √λ.
    let mut inv_sqrt = [[0.0; 3]; 3];
    for (l, v) in vals.iter().zip(&vecs) {
        let s = 1.0 / l.sqrt();
        for a in 0..3 {
            for b in 0..3 {
                inv_sqrt[a][b] += s * v[a] * v[b];
            }
        }
    }
    let mut r = [[0.0; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            r[a][b] = (0..3).map(|k| h[a][k] * inv_sqrt[k][b]).sum();
        }
    }
    let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
        - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
        + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
    (det > 0.0).then_some(r)
}

/// `M_R⁻¹ = Q M⁻¹ Qᵀ`: a preconditioner on `[X; σ]` (`3n` positions component-major, then `n`
/// tensions) whose position components are turned by `R` (see the module docs).
pub struct RotatedPreconditioner<'a, M: Preconditioner> {
    inner: &'a M,
    rotation: Rotation,
    n: usize,
    scratch: Mutex<Vec<f64>>,
}

impl<'a, M: Preconditioner> RotatedPreconditioner<'a, M> {
    /// `inner` turned by `rotation`, for `n` grid points (`inner` of size `4n`).
    pub fn new(inner: &'a M, rotation: Rotation, n: usize) -> Self {
        RotatedPreconditioner {
            inner,
            rotation,
            n,
            scratch: Mutex::new(vec![0.0; 4 * n]),
        }
    }
}

/// `out_j ← R v_j` (or `Rᵀ v_j` when `transpose`) for the `n` points of the three
/// component-major blocks of `v`.
fn rotate_points(r: &Rotation, transpose: bool, n: usize, v: &[f64], out: &mut [f64]) {
    for j in 0..n {
        let x = [v[j], v[n + j], v[2 * n + j]];
        for a in 0..3 {
            out[a * n + j] = (0..3)
                .map(|b| if transpose { r[b][a] } else { r[a][b] } * x[b])
                .sum();
        }
    }
}

impl<M: Preconditioner> Preconditioner for RotatedPreconditioner<'_, M> {
    fn nrows(&self) -> usize {
        4 * self.n
    }

    fn apply(&self, x: &[f64], y: &mut [f64]) {
        let n = self.n;
        let mut w = self.scratch.lock().expect("preconditioner scratch");
        rotate_points(&self.rotation, true, n, &x[..3 * n], &mut w[..3 * n]);
        w[3 * n..].copy_from_slice(&x[3 * n..]);
        self.inner.apply(&w, y);
        w[..3 * n].copy_from_slice(&y[..3 * n]);
        rotate_points(&self.rotation, false, n, &w[..3 * n], &mut y[..3 * n]);
    }
}

//! The smooth quadrature of a wall's double layer at targets away from it.
//!
//! The density `ψ` lives on the order-`p` grid of the source wall. It is band-limited, so its
//! values on the order-`q` grid are `Ψ = P ψ` exactly, with the interpolation matrix
//! `P = Y_q R F_p` (`n_q × n_p`: forward transform at `p`, copy of the coefficients,
//! synthesis at `q`). The double layer at a target `x` is then
//!
//! ```text
//! D[ψ](x) ≈ Σ_i K(x − y_i, n_i) dA_i Ψ_i = Σ_j (Σ_i K(x − y_i, n_i) dA_i P_ij) ψ_j,
//! ```
//!
//! so a block of the wall operator is the kernel matrix on the upsampled grid times `P`, one
//! GEMM per pair of components. The rule's error falls like `exp(−2π d/h)` in the target's
//! distance `d` over the spacing `h ≈ π R_max / q` of the upsampled grid; [`resolving_order`]
//! picks the smallest order with `d ≥ ratio · 2π R_max / q`.

use std::f64::consts::PI;

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

use super::{Wall, WallError};
use crate::sph_harmonics::{resample_coefs, ShTransform};
use crate::vesicle::layer_kernel::kernel_entries;
use crate::vesicle::{LayerKernel, SurfaceCalculus};

/// A wall's surface on the order-`q` grid and the interpolation from its order-`p` grid.
pub(super) struct Upsampled {
    q: usize,
    x: Vec<[f64; 3]>,
    normal: Vec<[f64; 3]>,
    da: Vec<f64>,
    /// `P` (`n_q × n_p`, column-major).
    interp: Vec<f64>,
    n_p: usize,
}

impl Upsampled {
    /// The wall upsampled to order `q ≥ p`.
    pub(super) fn new(wall: &Wall, q: usize) -> Result<Self, WallError> {
        let p = wall.order();
        let sht_p = ShTransform::new(p)?;
        let sht_q = ShTransform::new(q)?;
        let (n_p, n_q) = (sht_p.n_points(), sht_q.n_points());
        let (c_p, c_q) = (sht_p.n_coefs(), sht_q.n_coefs());
        // The surface at order q.
        let mut coefs_q = vec![0.0; 3 * c_q];
        resample_coefs(
            sht_p.layout(),
            sht_q.layout(),
            wall.surface().coefs(),
            &mut coefs_q,
        )?;
        let geom = SurfaceCalculus::new(q)?.geometry(&coefs_q)?;
        // P: the n_p unit grid functions, forward at p, copied, synthesised at q.
        let mut unit = vec![0.0; n_p * n_p];
        for j in 0..n_p {
            unit[j * n_p + j] = 1.0;
        }
        let mut cp = vec![0.0; n_p * c_p];
        sht_p.forward(&unit, &mut cp, &mut sht_p.workspace())?;
        drop(unit);
        let mut cq = vec![0.0; n_p * c_q];
        resample_coefs(sht_p.layout(), sht_q.layout(), &cp, &mut cq)?;
        drop(cp);
        let mut interp = vec![0.0; n_p * n_q];
        sht_q.inverse(&cq, &mut interp, &mut sht_q.workspace())?;
        Ok(Upsampled {
            q,
            x: geom.x,
            normal: geom.normal,
            da: geom.da,
            interp,
            n_p,
        })
    }

    /// The order `q`.
    pub(super) fn order(&self) -> usize {
        self.q
    }

    /// The double layer's block at `targets`: `out` (`3 n_t × 3 n_p`) gets rows `(a, t)` at
    /// `a n_t + t` and columns `(b, j)` at `b n_p + j`, `out[(a, t), (b, j)] =
    /// Σ_i K_ab(x_t − y_i, n_i) dA_i P_ij`. Targets are taken in chunks so that the kernel
    /// matrix stays small.
    pub(super) fn double_layer_block(&self, targets: &[[f64; 3]], mut out: MatMut<'_, f64>) {
        const CHUNK: usize = 64;
        let n_q = self.x.len();
        let n_t = targets.len();
        let n_p = self.n_p;
        debug_assert_eq!((out.nrows(), out.ncols()), (3 * n_t, 3 * n_p));
        let interp = MatRef::from_column_major_slice(&self.interp, n_q, n_p);
        // Kernel matrix of a chunk, (3 ct) × (3 n_q), column-major, row a ct + t, col b n_q + i.
        let mut kern = vec![0.0; 3 * CHUNK * 3 * n_q];
        for t0 in (0..n_t).step_by(CHUNK) {
            let ct = CHUNK.min(n_t - t0);
            let ld = 3 * ct;
            let kern = &mut kern[..ld * 3 * n_q];
            for i in 0..n_q {
                let (y, n, w) = (self.x[i], self.normal[i], self.da[i]);
                for tl in 0..ct {
                    let x = targets[t0 + tl];
                    let r = [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
                    let k = kernel_entries(LayerKernel::DoubleLayer, r, n, w);
                    for a in 0..3 {
                        for b in 0..3 {
                            kern[(b * n_q + i) * ld + a * ct + tl] = k[3 * a + b];
                        }
                    }
                }
            }
            let kern = MatRef::from_column_major_slice(kern, ld, 3 * n_q);
            for a in 0..3 {
                for b in 0..3 {
                    matmul(
                        out.as_mut().submatrix_mut(a * n_t + t0, b * n_p, ct, n_p),
                        Accum::Replace,
                        kern.submatrix(a * ct, b * n_q, ct, n_q),
                        interp,
                        1.0,
                        Par::Seq,
                    );
                }
            }
        }
    }

    /// The same block entry by entry (the reference of the tests).
    #[cfg(test)]
    pub(super) fn double_layer_block_naive(&self, targets: &[[f64; 3]]) -> Vec<f64> {
        let (n_q, n_t, n_p) = (self.x.len(), targets.len(), self.n_p);
        let rows = 3 * n_t;
        let mut out = vec![0.0; rows * 3 * n_p];
        for (t, &x) in targets.iter().enumerate() {
            for j in 0..n_p {
                let mut s = [0.0; 9];
                for i in 0..n_q {
                    let y = self.x[i];
                    let r = [x[0] - y[0], x[1] - y[1], x[2] - y[2]];
                    let k = kernel_entries(
                        LayerKernel::DoubleLayer,
                        r,
                        self.normal[i],
                        self.da[i] * self.interp[j * n_q + i],
                    );
                    for (sv, kv) in s.iter_mut().zip(k) {
                        *sv += kv;
                    }
                }
                for a in 0..3 {
                    for b in 0..3 {
                        out[(b * n_p + j) * rows + a * n_t + t] = s[3 * a + b];
                    }
                }
            }
        }
        out
    }
}

/// The smallest order among `p·{2, 3, 4, 6, 8, 12, 16, …}` up to `max_order` whose spacing
/// bound `2π R_max / q` is at most `distance / ratio`; `None` when even `max_order` is too
/// coarse.
pub(super) fn resolving_order(
    p: usize,
    rmax: f64,
    distance: f64,
    ratio: f64,
    max_order: usize,
) -> Option<usize> {
    let mut candidates = vec![];
    let mut m = 2;
    while m * p <= max_order {
        candidates.push(m * p);
        m = if m < 4 { m + 1 } else { m + m / 2 };
    }
    if candidates.last() != Some(&max_order) && max_order >= 2 * p {
        candidates.push(max_order);
    }
    candidates
        .into_iter()
        .find(|&q| ratio * 2.0 * PI * rmax / q as f64 <= distance)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::assert_close;
    use crate::vesicle::shapes;
    use crate::wall::WallKind;

    /// The GEMM assembly of a block equals the entry-by-entry sum, and applied to a constant
    /// density gives the double layer of a constant: `−c` inside the surface, 0 outside.
    #[test]
    fn block_by_gemm_equals_the_naive_sum_and_the_constant_identity() {
        let p = 6;
        let wall = Wall::new(
            WallKind::Body,
            shapes::ellipsoid(p, [1.0, 0.8, 0.6]).unwrap(),
        )
        .unwrap();
        let up = Upsampled::new(&wall, 4 * p).unwrap();
        let targets = [[0.1, -0.2, 0.05], [2.0, 0.3, -0.4], [0.0, 1.9, 1.2]];
        let n_p = wall.n_points();
        let mut fast = vec![0.0; 9 * n_p * 3];
        up.double_layer_block(
            &targets,
            MatMut::from_column_major_slice_mut(&mut fast, 9, 3 * n_p),
        );
        let naive = up.double_layer_block_naive(&targets);
        assert_close("block by GEMM", &fast, &naive, 1e-13);
        // D[c] with c = e_x: row sums over the x columns.
        for (t, want) in [(0, -1.0), (1, 0.0), (2, 0.0)] {
            let got: f64 = (0..n_p).map(|j| fast[j * 9 + t]).sum();
            assert!((got - want).abs() < 1e-6, "target {t}: D[e_x]_x = {got}");
        }
    }

    #[test]
    fn resolving_order_grows_as_the_distance_falls() {
        assert_eq!(resolving_order(8, 1.0, 10.0, 2.5, 128), Some(16));
        let q = resolving_order(8, 1.0, 0.5, 2.5, 128).unwrap();
        assert!(2.5 * 2.0 * PI / q as f64 <= 0.5 && q <= 128);
        assert_eq!(resolving_order(8, 1.0, 0.01, 2.5, 128), None);
    }
}

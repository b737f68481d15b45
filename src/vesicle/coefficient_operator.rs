//! Self-interaction operators in coefficient space: the dense grid operator of a layer
//! potential compressed to spherical-harmonic coefficients (MOBO's storage; Rahimian et al.,
//! SC'10).
//!
//! With `F` the order-`p` forward transform (`n_c × n` per component, `n = 2p(p+1)` grid
//! values, `n_c = (p+1)² − 1` coefficients) and `I` the inverse transform (`n × n_c`),
//! `P = I F` projects grid values onto band-limited functions. The dense operator `A`
//! (`3n × 3n`) of [`super::SelfInteraction::assemble`] factors through `F` on its input side:
//! the rotation that feeds the quadrature interpolates the density spectrally (the direct
//! rotation's matrices are `M_i = E_i F`), so `A = A P` exactly. Projecting its output as well
//! gives the coefficient-space operator
//!
//! ```text
//!     A_c = F A I        (3n_c × 3n_c),        applied as   P A x = I (A_c (F x)),
//! ```
//!
//! `(n_c/n)² ≈ 0.29` of the entries (2.0 MB instead of 7.0 MB per operator at `p = 12`), so a
//! memory-bound application streams 3.4× fewer bytes, for two transforms (`O(p³)`) around it.
//!
//! `P A x` differs from `A x` by the part of the output that is not band-limited at order `p`.
//! In the semi-implicit step ([`crate::timestep::semi_implicit`]) that part is irrelevant: every
//! other operator of the step (bending, tension, surface divergence, the double layer) reads its
//! input through `P`, and the new surface is the forward transform of the solution, so the
//! band-limited part of the solution is the same with `A` and with `P A` (the rest only solves
//! `a (I − P) x = (I − P) b`, which nothing reads back).

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

use super::{check_len, VesicleError};
use crate::sph_harmonics::{ShTransform, ShWorkspace};

/// The transforms of order `p` as matrices and the scratch of a compression: compresses grid
/// operators `A` to `A_c = F A I`.
pub struct CoefficientOperator {
    n: usize,
    nc: usize,
    /// `F`, `n_c × n`, column-major (column `j`: the coefficients of grid value `j`).
    forward: Vec<f64>,
    /// `I`, `n × n_c`, column-major (column `k`: basis function `k` on the grid).
    inverse: Vec<f64>,
    /// `A · blockdiag(I)`, `3n × 3n_c`.
    half: Vec<f64>,
}

impl CoefficientOperator {
    /// The transforms of `sht` (order `p`) as matrices.
    pub fn new(sht: &ShTransform) -> Result<Self, VesicleError> {
        let (n, nc) = (sht.n_points(), sht.n_coefs());
        let mut ws = sht.workspace();
        let forward = forward_matrix(sht, &mut ws)?;
        let mut eye_c = vec![0.0; nc * nc];
        for k in 0..nc {
            eye_c[k * nc + k] = 1.0;
        }
        let mut inverse = vec![0.0; n * nc];
        sht.inverse(&eye_c, &mut inverse, &mut ws)?;
        Ok(CoefficientOperator {
            n,
            nc,
            forward,
            inverse,
            half: vec![0.0; 9 * n * nc],
        })
    }

    /// Grid values per component, `n`.
    pub fn n_points(&self) -> usize {
        self.n
    }

    /// Coefficients per component, `n_c`.
    pub fn n_coefs(&self) -> usize {
        self.nc
    }

    /// `out = F A I` (`3n_c × 3n_c`, column-major, components major) of the grid operator `a`
    /// (`3n × 3n`, column-major, as [`super::SelfInteraction::assemble`] writes it).
    pub fn compress(&mut self, a: &[f64], out: &mut [f64]) -> Result<(), VesicleError> {
        let (n, nc) = (self.n, self.nc);
        check_len("grid operator", a.len(), 9 * n * n)?;
        check_len("coefficient-space operator", out.len(), 9 * nc * nc)?;
        let a = MatRef::from_column_major_slice(a, 3 * n, 3 * n);
        let inv = MatRef::from_column_major_slice(&self.inverse, n, nc);
        {
            let mut half = MatMut::from_column_major_slice_mut(&mut self.half, 3 * n, 3 * nc);
            for b in 0..3 {
                matmul(
                    half.as_mut().submatrix_mut(0, b * nc, 3 * n, nc),
                    Accum::Replace,
                    a.submatrix(0, b * n, 3 * n, n),
                    inv,
                    1.0,
                    Par::Seq,
                );
            }
        }
        let half = MatRef::from_column_major_slice(&self.half, 3 * n, 3 * nc);
        self.forward_blocks(half, out);
        Ok(())
    }

    /// `out = F A I` from the rows `P` of `A = P F` ([`super::SelfInteraction::assemble_rows`]:
    /// `3n × 3n_c`, row-major): since `F I` is the identity on coefficients, `A_c = F P`, three
    /// GEMMs of `n_c × n × 3n_c` and no grid operator.
    pub fn compress_rows(&self, rows: &[f64], out: &mut [f64]) -> Result<(), VesicleError> {
        let (n, nc) = (self.n, self.nc);
        check_len("operator rows", rows.len(), 9 * n * nc)?;
        check_len("coefficient-space operator", out.len(), 9 * nc * nc)?;
        self.forward_blocks(MatRef::from_row_major_slice(rows, 3 * n, 3 * nc), out);
        Ok(())
    }

    /// `out = blockdiag(F, F, F) · m` (`3n_c × 3n_c`, column-major) for `m` of `3n × 3n_c`.
    fn forward_blocks(&self, m: MatRef<'_, f64>, out: &mut [f64]) {
        let (n, nc) = (self.n, self.nc);
        let fwd = MatRef::from_column_major_slice(&self.forward, nc, n);
        let mut out = MatMut::from_column_major_slice_mut(out, 3 * nc, 3 * nc);
        for c in 0..3 {
            matmul(
                out.as_mut().submatrix_mut(c * nc, 0, nc, 3 * nc),
                Accum::Replace,
                fwd,
                m.submatrix(c * n, 0, n, 3 * nc),
                1.0,
                Par::Seq,
            );
        }
    }
}

/// The forward transform `F` of `sht` as a matrix (`n_c × n`, column-major: column `j` holds
/// the coefficients of grid value `j`).
pub(crate) fn forward_matrix(
    sht: &ShTransform,
    ws: &mut ShWorkspace,
) -> Result<Vec<f64>, VesicleError> {
    let (n, nc) = (sht.n_points(), sht.n_coefs());
    let mut eye = vec![0.0; n * n];
    for j in 0..n {
        eye[j * n + j] = 1.0;
    }
    let mut forward = vec![0.0; nc * n];
    sht.forward(&eye, &mut forward, ws)?;
    Ok(forward)
}

/// `y ← y + β K x` for a dense square operator `k` (`m × m`, column-major: a coefficient-space
/// `A_c` or a grid operator) and vectors `x`, `y` of length `m` (one GEMV).
pub fn add_product(k: &[f64], x: &[f64], y: &mut [f64], beta: f64) {
    let m = x.len();
    matmul(
        MatMut::from_column_major_slice_mut(y, m, 1),
        Accum::Add,
        MatRef::from_column_major_slice(k, m, m),
        MatRef::from_column_major_slice(x, m, 1),
        beta,
        Par::Seq,
    );
}

//! The truncated-SVD pseudo-inverse of the KIFMM's fits (check potential → equivalent
//! density), kept as its two factors `(V Σ⁻¹)(Uᵀ ·)` so that rounding in the small singular
//! directions is not spread over the large ones ([`super::operators`] builds them,
//! [`super::fit_cache`] stores them).

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatMut, MatRef, Par};

use super::FmmError;

/// A truncated-SVD pseudo-inverse kept as two factors.
#[derive(Clone, Debug)]
pub struct Pinv {
    /// `V Σ⁻¹` (columns: kept singular directions).
    pub vs: Mat<f64>,
    /// `Uᵀ` restricted to the kept directions.
    pub ut: Mat<f64>,
}

impl Pinv {
    /// Drop singular values below `rcond · σ_max`.
    pub fn new(a: &Mat<f64>, rcond: f64) -> Result<Self, FmmError> {
        let svd = a
            .thin_svd()
            .map_err(|_| FmmError::Svd("check-to-equivalent matrix"))?;
        let (u, s, v) = (svd.U(), svd.S().column_vector(), svd.V());
        let smax = s.iter().fold(0.0f64, |m, &x| m.max(x));
        let k = (0..s.nrows()).filter(|&j| s[j] > rcond * smax).count();
        let vs = Mat::from_fn(v.nrows(), k, |i, j| v[(i, j)] / s[j]);
        let ut = Mat::from_fn(k, u.nrows(), |i, j| u[(j, i)]);
        Ok(Pinv { vs, ut })
    }

    /// Kept rank.
    pub fn rank(&self) -> usize {
        self.ut.nrows()
    }

    /// `out = A⁺ check` (`tmp` holds `rank` values).
    pub fn apply(&self, check: &[f64], tmp: &mut [f64], out: &mut [f64], accum: bool) {
        let k = self.rank();
        matmul(
            MatMut::from_column_major_slice_mut(&mut tmp[..k], k, 1),
            Accum::Replace,
            self.ut.as_ref(),
            MatRef::from_column_major_slice(check, check.len(), 1),
            1.0,
            Par::Seq,
        );
        matmul(
            MatMut::from_column_major_slice_mut(out, self.vs.nrows(), 1),
            if accum { Accum::Add } else { Accum::Replace },
            self.vs.as_ref(),
            MatRef::from_column_major_slice(&tmp[..k], k, 1),
            1.0,
            Par::Seq,
        );
    }

    /// `out = A⁺ C` for the columns of `C` (column-major, `check.len() / n_check` columns),
    /// as two parallel GEMMs.
    pub fn apply_many(&self, check: &[f64], out: &mut [f64]) {
        let (k, nc, ne) = (self.rank(), self.ut.ncols(), self.vs.nrows());
        let cols = check.len() / nc;
        let mut tmp = vec![0.0; k * cols];
        matmul(
            MatMut::from_column_major_slice_mut(&mut tmp, k, cols),
            Accum::Replace,
            self.ut.as_ref(),
            MatRef::from_column_major_slice(check, nc, cols),
            1.0,
            Par::rayon(0),
        );
        matmul(
            MatMut::from_column_major_slice_mut(&mut out[..ne * cols], ne, cols),
            Accum::Replace,
            self.vs.as_ref(),
            MatRef::from_column_major_slice(&tmp, k, cols),
            1.0,
            Par::rayon(0),
        );
    }
}

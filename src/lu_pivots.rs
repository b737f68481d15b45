//! The invertibility test of a dense LU factor, shared by the walls' operator
//! ([`crate::wall`]) and the cells' step operators and preconditioners ([`crate::timestep`]).
//!
//! For `P A = L U` (partial pivoting, `L` unit lower triangular) the test is the pivot ratio
//!
//! ```text
//!     r = min_i |U_ii| / max_i |U_ii|,
//! ```
//!
//! a cheap proxy of the reciprocal condition number (`1/κ(A) ≤ r` up to the growth of `L`): a
//! ratio at round-off, `r ≤ n ε`, means that the factor's solves amplify round-off by at least
//! `1/r` and the matrix is treated as singular.
//!
//! ```
//! use faer::mat;
//! use mobo::lu_pivots::{accepts, pivot_ratio, roundoff_floor};
//!
//! let a = mat![[4.0, 1.0], [2.0, 3.0]];
//! let lu = a.partial_piv_lu();
//! let r = pivot_ratio(lu.U());
//! assert!((r - 2.5 / 4.0).abs() < 1e-15); // pivots 4 and 3 − 2·1/4
//! assert!(accepts(r, roundoff_floor(2)));
//! ```

use faer::MatRef;

/// `min_i |U_ii| / max_i |U_ii|` over the diagonal of the upper factor `u` (0 when every pivot
/// is zero; NaN when a pivot is NaN, which [`accepts`] refuses).
pub fn pivot_ratio(u: MatRef<'_, f64>) -> f64 {
    let (mut lo, mut hi) = (f64::INFINITY, 0.0_f64);
    for i in 0..u.nrows().min(u.ncols()) {
        let d = u[(i, i)].abs();
        if d.is_nan() {
            return f64::NAN;
        }
        lo = lo.min(d);
        hi = hi.max(d);
    }
    if hi > 0.0 {
        lo / hi
    } else {
        0.0
    }
}

/// Whether a factor of pivot ratio `ratio` is accepted as invertible: above `floor` (a NaN
/// ratio is not).
pub fn accepts(ratio: f64, floor: f64) -> bool {
    ratio > floor
}

/// The round-off floor `n ε` of an `n × n` factor.
pub fn roundoff_floor(n: usize) -> f64 {
    n as f64 * f64::EPSILON
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Mat;

    #[test]
    fn the_ratio_of_a_triangular_matrix_is_that_of_its_diagonal() {
        // An upper triangular matrix is its own U (no row is swapped when the diagonal
        // dominates its column below, here zero).
        let a = Mat::<f64>::from_fn(4, 4, |i, j| match (i, j) {
            _ if i == j => [2.0, -8.0, 0.5, 1.0][i],
            _ if i < j => 0.3,
            _ => 0.0,
        });
        let lu = a.partial_piv_lu();
        assert_eq!(pivot_ratio(lu.U()), 0.5 / 8.0);
        assert!(accepts(pivot_ratio(lu.U()), roundoff_floor(4)));
    }

    #[test]
    fn a_singular_matrix_is_refused() {
        // Rank 2: the third row is (first − second)/2, and every multiplier of the elimination
        // (1/2, 1/4, then −1/2) is exact in binary, so the last pivot is exactly zero.
        let rows = [[8.0, 1.0, 2.0], [4.0, 3.0, 1.0], [2.0, -1.0, 0.5]];
        let a = Mat::<f64>::from_fn(3, 3, |i, j| rows[i][j]);
        let lu = a.partial_piv_lu();
        let r = pivot_ratio(lu.U());
        assert_eq!(r, 0.0);
        assert!(!accepts(r, roundoff_floor(3)));
        assert_eq!(pivot_ratio(Mat::<f64>::zeros(2, 2).as_ref()), 0.0);
        assert!(!accepts(f64::NAN, 0.0));
        let nan_pivot =
            Mat::<f64>::from_fn(2, 2, |i, j| if i == j { [1.0, f64::NAN][i] } else { 0.0 });
        assert!(pivot_ratio(nan_pivot.as_ref()).is_nan());
    }
}

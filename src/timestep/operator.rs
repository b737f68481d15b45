//! Linear operators `y = A x` and preconditioners `z = M⁻¹ v` for the Krylov solver.

use crate::lu_pivots;
use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatMut, MatRef, Par};

use super::TimestepError;

/// A linear map `x ↦ y = A x` on `ℝⁿ` (matrix-free).
///
/// Implementations must write every entry of `y` (its previous content is arbitrary) and may
/// assume `x.len() == self.ncols()` and `y.len() == self.nrows()`; the solvers check the sizes
/// before calling [`LinearOperator::apply`].
pub trait LinearOperator: Sync {
    /// Number of rows of `A` (length of `y`).
    fn nrows(&self) -> usize;
    /// Number of columns of `A` (length of `x`); square by default.
    fn ncols(&self) -> usize {
        self.nrows()
    }
    /// `y ← A x`.
    fn apply(&self, x: &[f64], y: &mut [f64]);
    /// `Y ← A X` for `k` columns stored one after the other (`X`: `k · ncols` values, `Y`:
    /// `k · nrows`). By default one [`LinearOperator::apply`] per column; operators with dense
    /// parts override it with one matrix product for all columns.
    fn apply_batch(&self, x: &[f64], y: &mut [f64], k: usize) {
        for (xc, yc) in x
            .chunks_exact(self.ncols())
            .zip(y.chunks_exact_mut(self.nrows()))
            .take(k)
        {
            self.apply(xc, yc);
        }
    }
}

/// `y = A x` by a dense matrix-vector product (faer, with its global parallelism setting).
impl LinearOperator for MatRef<'_, f64> {
    fn nrows(&self) -> usize {
        MatRef::nrows(self)
    }
    fn ncols(&self) -> usize {
        MatRef::ncols(self)
    }
    fn apply(&self, x: &[f64], y: &mut [f64]) {
        let xm = MatRef::from_column_major_slice(x, x.len(), 1);
        let ym = MatMut::from_column_major_slice_mut(y, self.nrows(), 1);
        matmul(
            ym,
            Accum::Replace,
            *self,
            xm,
            1.0,
            faer::get_global_parallelism(),
        );
    }
}

impl LinearOperator for Mat<f64> {
    fn nrows(&self) -> usize {
        Mat::nrows(self)
    }
    fn ncols(&self) -> usize {
        Mat::ncols(self)
    }
    fn apply(&self, x: &[f64], y: &mut [f64]) {
        self.as_ref().apply(x, y)
    }
}

impl<T: LinearOperator + ?Sized> LinearOperator for &T {
    fn nrows(&self) -> usize {
        (**self).nrows()
    }
    fn ncols(&self) -> usize {
        (**self).ncols()
    }
    fn apply(&self, x: &[f64], y: &mut [f64]) {
        (**self).apply(x, y)
    }
    fn apply_batch(&self, x: &[f64], y: &mut [f64], k: usize) {
        (**self).apply_batch(x, y, k)
    }
}

/// A square operator of size `n` given by a closure `f(x, y)` that writes `y = A x`.
///
/// ```
/// use mobo::timestep::{FnOperator, LinearOperator};
/// // y = 2 x
/// let op = FnOperator::new(3, |x: &[f64], y: &mut [f64]| {
///     for (yi, xi) in y.iter_mut().zip(x) {
///         *yi = 2.0 * xi;
///     }
/// });
/// let mut y = [0.0; 3];
/// op.apply(&[1.0, 2.0, 3.0], &mut y);
/// assert_eq!(y, [2.0, 4.0, 6.0]);
/// ```
#[derive(Clone, Copy, Debug)]
pub struct FnOperator<F> {
    n: usize,
    f: F,
}

impl<F: Fn(&[f64], &mut [f64]) + Sync> FnOperator<F> {
    /// Wrap `f` as an `n × n` operator.
    pub fn new(n: usize, f: F) -> Self {
        Self { n, f }
    }
}

impl<F: Fn(&[f64], &mut [f64]) + Sync> LinearOperator for FnOperator<F> {
    fn nrows(&self) -> usize {
        self.n
    }
    fn apply(&self, x: &[f64], y: &mut [f64]) {
        (self.f)(x, y)
    }
}

/// A preconditioner: applies `z = M⁻¹ v` for some `M ≈ A`.
///
/// As for [`LinearOperator`], implementations must write every entry of `z` and may assume both
/// slices have length [`Preconditioner::nrows`]; the solvers check sizes first.
pub trait Preconditioner: Sync {
    /// Size `n` of the (square) preconditioner.
    fn nrows(&self) -> usize;
    /// `z ← M⁻¹ v`.
    fn apply(&self, v: &[f64], z: &mut [f64]);
}

impl<T: Preconditioner + ?Sized> Preconditioner for &T {
    fn nrows(&self) -> usize {
        (**self).nrows()
    }
    fn apply(&self, v: &[f64], z: &mut [f64]) {
        (**self).apply(v, z)
    }
}

/// A preconditioner of size `n` given by a closure `f(v, z)` that writes `z = M⁻¹ v` (for
/// matrix-free preconditioners, e.g. one diagonal in spherical-harmonic coefficients).
///
/// ```
/// use mobo::timestep::{FnPreconditioner, Preconditioner};
/// // Jacobi for diag(2, 4): z = v ./ d
/// let d = [2.0, 4.0];
/// let m = FnPreconditioner::new(2, |v: &[f64], z: &mut [f64]| {
///     for ((zi, vi), di) in z.iter_mut().zip(v).zip(&d) {
///         *zi = vi / di;
///     }
/// });
/// let mut z = [0.0; 2];
/// m.apply(&[1.0, 1.0], &mut z);
/// assert_eq!(z, [0.5, 0.25]);
/// ```
#[derive(Clone, Copy, Debug)]
pub struct FnPreconditioner<F> {
    n: usize,
    f: F,
}

impl<F: Fn(&[f64], &mut [f64]) + Sync> FnPreconditioner<F> {
    /// Wrap `f` as an `n × n` preconditioner.
    pub fn new(n: usize, f: F) -> Self {
        Self { n, f }
    }
}

impl<F: Fn(&[f64], &mut [f64]) + Sync> Preconditioner for FnPreconditioner<F> {
    fn nrows(&self) -> usize {
        self.n
    }
    fn apply(&self, v: &[f64], z: &mut [f64]) {
        (self.f)(v, z)
    }
}

/// No preconditioning, `M = I` of size `n`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Identity {
    n: usize,
}

impl Identity {
    /// The identity on `ℝⁿ`.
    pub fn new(n: usize) -> Self {
        Self { n }
    }
}

impl Preconditioner for Identity {
    fn nrows(&self) -> usize {
        self.n
    }
    fn apply(&self, v: &[f64], z: &mut [f64]) {
        z.copy_from_slice(v);
    }
}

/// One LU-factored block: `P B = L U`, stored as the forward row permutation and the packed
/// factors (unit lower `L` and upper `U`).
#[derive(Clone, Debug)]
struct LuBlock {
    /// `(P v)_i = v[perm[i]]`.
    perm: Vec<usize>,
    l: Mat<f64>,
    u: Mat<f64>,
}

impl LuBlock {
    /// `z ← B⁻¹ v = U⁻¹ L⁻¹ P v`, no allocation.
    fn solve(&self, v: &[f64], z: &mut [f64]) {
        for (zi, &pi) in z.iter_mut().zip(&self.perm) {
            *zi = v[pi];
        }
        let n = z.len();
        let mut zm = MatMut::from_column_major_slice_mut(z, n, 1);
        faer::linalg::triangular_solve::solve_unit_lower_triangular_in_place(
            self.l.as_ref(),
            zm.as_mut(),
            Par::Seq,
        );
        faer::linalg::triangular_solve::solve_upper_triangular_in_place(
            self.u.as_ref(),
            zm,
            Par::Seq,
        );
    }
}

/// Block-diagonal preconditioner `M = diag(B₁, …, B_K)` with dense square blocks of any sizes,
/// `n = Σ_k n_k`.
///
/// Each block is factored once, `P_k B_k = L_k U_k` (LU with partial pivoting,
/// [`Mat::partial_piv_lu`]); [`Preconditioner::apply`] solves `B_k z_k = v_k` for every block by
/// one permutation and two triangular solves (`O(n_k²)` flops), the blocks in parallel (rayon,
/// recursive halving; no allocation).
///
/// ```
/// use faer::Mat;
/// use mobo::timestep::{BlockDiagonal, Preconditioner};
/// let b1 = Mat::from_fn(2, 2, |i, j| if i == j { 2.0 } else { 1.0 });
/// let b2 = Mat::from_fn(1, 1, |_, _| 4.0);
/// let m = BlockDiagonal::new(&[b1.as_ref(), b2.as_ref()]).unwrap();
/// let mut z = [0.0; 3];
/// m.apply(&[3.0, 3.0, 8.0], &mut z); // [[2,1],[1,2]] z₁ = (3,3), 4 z₂ = 8
/// assert!((z[0] - 1.0).abs() < 1e-15 && (z[1] - 1.0).abs() < 1e-15 && z[2] == 2.0);
/// ```
#[derive(Clone, Debug)]
pub struct BlockDiagonal {
    blocks: Vec<LuBlock>,
    /// `offsets[k]` is the first row of block `k`; `offsets[K] = n`.
    offsets: Vec<usize>,
}

impl BlockDiagonal {
    /// Factor the blocks `B₁, …, B_K` (in this order along the diagonal).
    ///
    /// # Errors
    /// [`TimestepError::NotSquare`] for a non-square or empty block,
    /// [`TimestepError::NonFinite`] for NaN or infinite entries, and
    /// [`TimestepError::SingularBlock`] when a block's pivots satisfy
    /// `min |U_ii| ≤ n_k ε max |U_ii|` (singular to working precision).
    pub fn new(blocks: &[MatRef<'_, f64>]) -> Result<Self, TimestepError> {
        let mut out = Vec::with_capacity(blocks.len());
        let mut offsets = Vec::with_capacity(blocks.len() + 1);
        offsets.push(0);
        for (index, b) in blocks.iter().enumerate() {
            let (nr, nc) = (b.nrows(), b.ncols());
            if nr != nc || nr == 0 {
                return Err(TimestepError::NotSquare {
                    what: format!("preconditioner block {index}"),
                    nrows: nr,
                    ncols: nc,
                });
            }
            for j in 0..nc {
                for i in 0..nr {
                    if !b[(i, j)].is_finite() {
                        return Err(TimestepError::NonFinite {
                            what: "preconditioner block",
                        });
                    }
                }
            }
            let lu = b.partial_piv_lu();
            let pivot_ratio = lu_pivots::pivot_ratio(lu.U());
            if !lu_pivots::accepts(pivot_ratio, lu_pivots::roundoff_floor(nr)) {
                return Err(TimestepError::SingularBlock {
                    index,
                    size: nr,
                    pivot_ratio,
                });
            }
            let perm = lu.P().arrays().0.to_vec();
            out.push(LuBlock {
                perm,
                l: lu.L().to_owned(),
                u: lu.U().to_owned(),
            });
            offsets.push(offsets[index] + nr);
        }
        Ok(Self {
            blocks: out,
            offsets,
        })
    }

    /// Take the diagonal blocks of sizes `sizes` (in order) from the square matrix `a` and factor
    /// them, as [`BlockDiagonal::new`]. `Σ sizes` must equal the size of `a`.
    ///
    /// # Errors
    /// As [`BlockDiagonal::new`], plus [`TimestepError::DimensionMismatch`] when the sizes do not
    /// add up to `a.nrows()` and [`TimestepError::NotSquare`] when `a` is not square.
    pub fn from_diagonal_of(a: MatRef<'_, f64>, sizes: &[usize]) -> Result<Self, TimestepError> {
        if a.nrows() != a.ncols() {
            return Err(TimestepError::NotSquare {
                what: "matrix".into(),
                nrows: a.nrows(),
                ncols: a.ncols(),
            });
        }
        let total: usize = sizes.iter().sum();
        if total != a.nrows() {
            return Err(TimestepError::DimensionMismatch {
                what: "sum of block sizes",
                expected: a.nrows(),
                got: total,
            });
        }
        let mut views = Vec::with_capacity(sizes.len());
        let mut o = 0;
        for &s in sizes {
            views.push(a.submatrix(o, o, s, s));
            o += s;
        }
        Self::new(&views)
    }

    /// Number of blocks `K`.
    pub fn num_blocks(&self) -> usize {
        self.blocks.len()
    }

    /// Sizes `n_k` of the blocks.
    pub fn block_sizes(&self) -> impl Iterator<Item = usize> + '_ {
        self.offsets.windows(2).map(|w| w[1] - w[0])
    }

    /// Blocks `lo..hi`, whose rows start at `offsets[lo]`, applied to `v`, `z` (already sliced to
    /// those rows), halving the range in parallel.
    fn apply_range(&self, lo: usize, hi: usize, v: &[f64], z: &mut [f64]) {
        match hi - lo {
            0 => {}
            1 => self.blocks[lo].solve(v, z),
            _ => {
                let mid = lo + (hi - lo) / 2;
                let split = self.offsets[mid] - self.offsets[lo];
                let (v1, v2) = v.split_at(split);
                let (z1, z2) = z.split_at_mut(split);
                rayon::join(
                    || self.apply_range(lo, mid, v1, z1),
                    || self.apply_range(mid, hi, v2, z2),
                );
            }
        }
    }
}

impl Preconditioner for BlockDiagonal {
    fn nrows(&self) -> usize {
        *self.offsets.last().unwrap_or(&0)
    }
    fn apply(&self, v: &[f64], z: &mut [f64]) {
        self.apply_range(0, self.blocks.len(), v, z);
    }
}

//! The preconditioner from the cell itself: the exact inverse of a cell's own step operator, in
//! spherical-harmonic coefficient space, built at one step and reused while it stays close.
//!
//! ## Why
//!
//! The sphere preconditioner ([`super::sphere_preconditioner`]) inverts the step operator of the
//! sphere of the cell's area. Its error grows with the cell's distance from that sphere: one cell
//! in shear at `p = 12` takes 9 GMRES iterations per step as a sphere, 18 as a prolate of reduced
//! volume 0.85 and 22 as an RBC, and more as `p` grows (the RBC: 17 at `p = 6`, 26 at `p = 16`;
//! `examples/gmres_by_shape`). The cell's own operator has none of that error.
//!
//! ## What is built
//!
//! The step operator `A` of [`super::semi_implicit`] acts on `z = [X; σ]` (grid values, `3n`
//! positions and `n` tensions). With `F` the forward transform (grid → the `n_c` coefficients
//! of each of the four fields) and `F⁻¹` the synthesis, the coefficient-space operator
//!
//! ```text
//!     A_bb = F A F⁻¹        (4n_c × 4n_c)
//! ```
//!
//! is built column by column (the operator applied to the synthesis of each unit coefficient
//! vector, all columns synthesised and analysed as one batch of transforms) and inverted by LU
//! with partial pivoting. On the complement of the coefficient space (`ker F`, the grid
//! functions no coefficient sees) the step operator is `a I` on positions and zero on tensions
//! (the bending, tension and divergence operators and the double layer see only `F X`, `F σ`),
//! so, as for the sphere,
//!
//! ```text
//!     M⁻¹ v = F⁻¹ A_bb⁻¹ F v + [ (v_X − F⁻¹F v_X)/a ; v_σ − F⁻¹F v_σ ].
//! ```
//!
//! At the step it was built for, `A M⁻¹ = I + N` with `N` mapping into the complement and
//! `N² = 0` (the single layer of a band-limited density has content above degree `p`), so GMRES
//! needs at most two iterations. At later steps the cell has moved on and `A M⁻¹ = I + E` with
//! `E` of the size of the change of the operator since the build. The part of that change that
//! is a rotation of the cell with its grid (a tumbling cell, a grid carried round by the
//! membrane) is removed by turning the preconditioner with the grid, as the sphere's is
//! ([`super::grid_frame`]); the stepper rebuilds when the iterations say it has gone stale
//! ([`super::semi_implicit::Preconditioning::Cell`]).
//!
//! **Cost.** Build: `4n_c` applications of the step operator (the work of `4n_c` GMRES
//! iterations), two batched transforms of `16 n_c` fields, and one LU of order `4n_c` and its
//! inverse (`p = 12`: order 672, about 0.6 GFLOP together). Memory: the dense inverse, `(4n_c)²` doubles (3.6 MB at
//! `p = 12`, 0.3 MB at `p = 6`). One application: three transforms of four fields and one
//! product with the inverse (`2 (4n_c)²` flops).
//!
//! A nearly spherical cell has a nearly singular operator (a constant tension does nothing on
//! a sphere); [`CellPreconditioner::build`] then fails with [`TimestepError::SingularBlock`]
//! and the stepper falls back to the sphere preconditioner, which handles that direction.

use std::sync::Mutex;

use crate::lu_pivots;
use faer::linalg::matmul::matmul;
use faer::linalg::solvers::DenseSolveCore;
use faer::{Accum, Mat, MatMut, MatRef, Par};

use super::sphere_preconditioner::add_grid_complement;
use super::{LinearOperator, Preconditioner, TimestepError};
use crate::sph_harmonics::{ShTransform, ShWorkspace};
use crate::vesicle::VesicleError;

/// Smallest ratio of LU pivots (smallest over largest magnitude) accepted as invertible:
/// below it the cell is too close to a sphere for its own operator to be inverted stably.
const MIN_PIVOT_RATIO: f64 = 1e-10;

/// The inverse of one cell's step operator in coefficient space (see the module docs).
pub struct CellPreconditioner {
    /// `A_bb⁻¹`, `4n_c × 4n_c`.
    inverse: Mat<f64>,
    /// `a`, the operator's identity coefficient on positions.
    identity: f64,
    /// Grid points per field.
    n: usize,
    /// Smallest over largest LU pivot magnitude of `A_bb`.
    pivot_ratio: f64,
}

/// Scratch of one application: `F v`, `A_bb⁻¹ F v`, `F⁻¹ F v` and a transform workspace.
pub struct CellPreconditionerScratch {
    ws: ShWorkspace,
    c: Vec<f64>,
    y: Vec<f64>,
    pv: Vec<f64>,
}

impl CellPreconditionerScratch {
    /// Scratch for applications with transform `sht` (order `p`).
    pub fn new(sht: &ShTransform) -> Self {
        let m = 4 * sht.n_coefs();
        CellPreconditionerScratch {
            ws: sht.workspace(),
            c: vec![0.0; m],
            y: vec![0.0; m],
            pv: vec![0.0; 4 * sht.n_points()],
        }
    }
}

/// Bytes of the dense inverse of a cell of order `p`, `(4n_c)²` doubles.
pub fn bytes_per_cell(p: usize) -> usize {
    let nc = crate::sph_harmonics::CoefLayout::new(p).len();
    8 * 16 * nc * nc
}

impl CellPreconditioner {
    /// Build the inverse of `op` (the step operator on `[X; σ]`, `4n × 4n` with `n` the points
    /// of `sht`'s grid) whose identity coefficient on positions is `identity` (`a = (1+λ)/2`).
    ///
    /// # Errors
    /// [`TimestepError::DimensionMismatch`] when `op` is not `4n × 4n`,
    /// [`TimestepError::InvalidParameter`] for a non-positive `identity`,
    /// [`TimestepError::NonFinite`] when the operator gives non-finite values,
    /// [`TimestepError::SingularBlock`] (index 0, the whole operator) when `A_bb` is too close
    /// to singular (a nearly spherical cell).
    pub fn build(
        op: &dyn LinearOperator,
        sht: &ShTransform,
        identity: f64,
    ) -> Result<Self, TimestepError> {
        let (n, nc) = (sht.n_points(), sht.n_coefs());
        let m = 4 * nc;
        if op.nrows() != 4 * n || op.ncols() != 4 * n {
            return Err(TimestepError::DimensionMismatch {
                what: "step operator",
                expected: 4 * n,
                got: op.nrows(),
            });
        }
        if !(identity.is_finite() && identity > 0.0) {
            return Err(TimestepError::InvalidParameter {
                name: "identity coefficient",
                value: format!("{identity}"),
                reason: "must be positive and finite",
            });
        }
        let mut ws = sht.workspace();
        // F⁻¹ e_j for every unit coefficient vector e_j, as one batch of 4·m fields.
        let mut units = vec![0.0; m * m];
        for j in 0..m {
            units[j * m + j] = 1.0;
        }
        let mut inputs = vec![0.0; 4 * n * m];
        sht.inverse(&units, &mut inputs, &mut ws)
            .map_err(VesicleError::from)?;
        drop(units);
        let mut outputs = vec![0.0; 4 * n * m];
        op.apply_batch(&inputs, &mut outputs, m);
        drop(inputs);
        if !outputs.iter().all(|v| v.is_finite()) {
            return Err(TimestepError::NonFinite {
                what: "cell step operator",
            });
        }
        // A_bb = F (A F⁻¹): column j is the analysis of the output of column j.
        let mut abb = vec![0.0; m * m];
        sht.forward(&outputs, &mut abb, &mut ws)
            .map_err(VesicleError::from)?;
        drop(outputs);
        let abb = MatRef::from_column_major_slice(&abb, m, m);
        let lu = abb.partial_piv_lu();
        let pivot_ratio = lu_pivots::pivot_ratio(lu.U());
        if !lu_pivots::accepts(pivot_ratio, MIN_PIVOT_RATIO) {
            return Err(TimestepError::SingularBlock {
                index: 0,
                size: m,
                pivot_ratio,
            });
        }
        Ok(CellPreconditioner {
            inverse: lu.inverse(),
            identity,
            n,
            pivot_ratio,
        })
    }

    /// Smallest over largest LU pivot magnitude of the coefficient-space operator (a measure of
    /// how far the cell is from the sphere's singular direction).
    pub fn pivot_ratio(&self) -> f64 {
        self.pivot_ratio
    }

    /// Bytes held (the dense inverse).
    pub fn memory_bytes(&self) -> usize {
        8 * self.inverse.nrows() * self.inverse.ncols()
    }

    /// Size `4n` of the grid system it preconditions.
    pub fn nrows(&self) -> usize {
        4 * self.n
    }

    /// `z ← M⁻¹ v` with transform `sht` (the one it was built with) and `scratch`.
    ///
    /// # Errors
    /// [`TimestepError::DimensionMismatch`] for vectors or a transform of another size.
    pub fn apply_with(
        &self,
        sht: &ShTransform,
        scratch: &mut CellPreconditionerScratch,
        v: &[f64],
        z: &mut [f64],
    ) -> Result<(), TimestepError> {
        let n = self.n;
        let m = self.inverse.nrows();
        for (what, len) in [
            ("preconditioner input", v.len()),
            ("preconditioner output", z.len()),
        ] {
            if len != 4 * n {
                return Err(TimestepError::DimensionMismatch {
                    what,
                    expected: 4 * n,
                    got: len,
                });
            }
        }
        if sht.n_points() != n || scratch.c.len() != m {
            return Err(TimestepError::DimensionMismatch {
                what: "preconditioner transform",
                expected: n,
                got: sht.n_points(),
            });
        }
        let CellPreconditionerScratch { ws, c, y, pv } = scratch;
        sht.forward(v, c, ws).map_err(VesicleError::from)?;
        sht.inverse(c, pv, ws).map_err(VesicleError::from)?;
        matmul(
            MatMut::from_column_major_slice_mut(y, m, 1),
            Accum::Replace,
            self.inverse.as_ref(),
            MatRef::from_column_major_slice(c, m, 1),
            1.0,
            Par::Seq,
        );
        sht.inverse(y, z, ws).map_err(VesicleError::from)?;
        add_grid_complement(v, pv, self.identity, z);
        Ok(())
    }
}

/// A [`CellPreconditioner`] with its transform and scratch, as a [`Preconditioner`] for
/// [`super::gmres`]. A failed application (it cannot fail for the sizes the solver checks)
/// writes NaN, which the solver reports as a non-finite output.
pub struct CellPreconditionerOp<'a> {
    pc: &'a CellPreconditioner,
    sht: &'a ShTransform,
    scratch: Mutex<CellPreconditionerScratch>,
}

impl<'a> CellPreconditionerOp<'a> {
    /// Wrap `pc` with the transform it was built with.
    pub fn new(pc: &'a CellPreconditioner, sht: &'a ShTransform) -> Self {
        CellPreconditionerOp {
            pc,
            sht,
            scratch: Mutex::new(CellPreconditionerScratch::new(sht)),
        }
    }
}

impl Preconditioner for CellPreconditionerOp<'_> {
    fn nrows(&self) -> usize {
        self.pc.nrows()
    }

    fn apply(&self, v: &[f64], z: &mut [f64]) {
        let mut s = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        if self.pc.apply_with(self.sht, &mut s, v, z).is_err() {
            z.fill(f64::NAN);
        }
    }
}

//! The near field of a tree as one batched list, and the backends that evaluate it.
//!
//! When a tree is built, every direct interaction of its leaves — the U list (adjacent
//! leaves), the W list's leaves with fewer sources than surface points (cheaper directly than
//! through their equivalent densities), and the X list of leaves with fewer targets than
//! surface points (instead of P2L) — is collected into a [`NearList`]: one row per target leaf
//! with its target range and the source ranges it sums, compressed-row. The near field is then
//!
//! `u(x_i) += Σ_{ranges r of row(i)} Σ_{j ∈ r} K(x_i − y_j) q_j`,
//!
//! a pass of its own, separate from L2P and M2P, that a [`NearField`] backend evaluates: the
//! CPU backend ([`CpuNearField`], the reference, the AVX2/portable loops of [`super::p2p`]
//! over rayon) or the GPU backend of `crate::gpu` (feature `gpu`). The backend is chosen once
//! per FMM plan ([`super::Fmm::set_near_field`]), not per call.

use rayon::prelude::*;

use super::blocks::SourceBlock;

use super::kernels::Kernel;
pub use super::near_list::NearList;
use super::near_pairs::MutualPairs;
use super::FmmError;

/// A rank's sorted points as the near field sees them.
#[derive(Clone, Copy, Debug)]
pub struct NearPoints<'a> {
    /// Source positions (owned, then ghost sources), in key order.
    pub sources: &'a [[f64; 3]],
    /// Source orientations (double-layer kernels).
    pub normals: Option<&'a [[f64; 3]]>,
    /// Target positions, in key order.
    pub targets: &'a [[f64; 3]],
}

/// A backend that evaluates a [`NearList`] for the current densities.
pub trait NearField: Sync {
    /// What runs the pass, for summaries (`"cpu"`, `"gpu f64 (NVIDIA H100 …)"`).
    fn describe(&self) -> String;
    /// Whether the pass runs beside the CPU's far field (on another device) rather than on the
    /// same cores after it.
    fn concurrent(&self) -> bool;
    /// Add the near field of `sources` (positions as built, densities as set) to `out`
    /// (`output_dim` values per sorted target).
    fn evaluate(
        &self,
        list: &NearList,
        sources: &SourceBlock,
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<(), FmmError>;
}

/// The CPU near field: the serial kernels of [`super::p2p`] over the rows, rows in parallel;
/// with a [`MutualPairs`] split (targets that are the sources, a symmetric kernel), each pair of
/// leaves once for both directions.
pub struct CpuNearField {
    kernel: Box<dyn Kernel>,
    tol: f64,
    mutual: Option<MutualPairs>,
}

impl CpuNearField {
    /// The CPU backend for `kernel` (the FMM's near kernel), exact to round-off.
    pub fn new(kernel: Box<dyn Kernel>) -> Self {
        Self::within(kernel, 0.0)
    }

    /// The CPU backend allowed a relative error up to `tol` per pair
    /// ([`Kernel::eval_block_within`]); the FMM passes a tenth of its own calibrated accuracy
    /// ([`super::calibration::near_tolerance`]).
    pub fn within(kernel: Box<dyn Kernel>, tol: f64) -> Self {
        CpuNearField {
            kernel,
            tol,
            mutual: None,
        }
    }

    /// Evaluate the mutual pairs of `list` ([`MutualPairs`]) once for both directions: `list`
    /// is the one this backend will be given, and its targets are its sources in the same
    /// order. Nothing is built for a kernel without a mutual loop ([`Kernel::has_mutual`]);
    /// another list is evaluated row by row.
    pub fn with_mutual(mut self, list: &NearList) -> Self {
        self.mutual = self.kernel.has_mutual().then(|| MutualPairs::build(list));
        self
    }
}

impl NearField for CpuNearField {
    fn describe(&self) -> String {
        "cpu".into()
    }

    fn concurrent(&self) -> bool {
        false
    }

    fn evaluate(
        &self,
        list: &NearList,
        sources: &SourceBlock,
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<(), FmmError> {
        let dt = self.kernel.output_dim();
        let mutual = self.mutual.as_ref().filter(|m| m.fits(list));
        let one_way = mutual.map_or(list, |m| m.one_way());
        for_each_row(one_way, out, dt, |r, vals| {
            let tgts = &targets[one_way.rows[r].clone()];
            for s in one_way.row_ranges(r) {
                self.kernel
                    .eval_block_within(tgts, &sources.view(s.clone()), vals, self.tol);
            }
        });
        if let Some(m) = mutual {
            self.mutual_rounds(m, sources, targets, out, dt)?;
        }
        Ok(())
    }
}

/// `out`'s start, shared by the tasks of one round of mutual pairs.
struct RowsPtr(*mut f64);
// SAFETY: the tasks holding it write disjoint rows (see `mutual_rounds`).
unsafe impl Sync for RowsPtr {}

impl CpuNearField {
    /// The rounds of mutual pairs, one after another, each round's pairs in parallel.
    fn mutual_rounds(
        &self,
        m: &MutualPairs,
        sources: &SourceBlock,
        targets: &[[f64; 3]],
        out: &mut [f64],
        dt: usize,
    ) -> Result<(), FmmError> {
        let rows = &m.one_way().rows;
        // Rows are sorted and disjoint (`MutualPairs::build` keeps no pair otherwise): the
        // last one ending inside `out` puts every row inside it.
        if rows.last().is_some_and(|r| r.end * dt > out.len()) {
            return Err(FmmError::Shape("near-field rows beyond the output".into()));
        }
        let base = RowsPtr(out.as_mut_ptr());
        let base = &base;
        for round in m.rounds() {
            round.par_iter().for_each(|&[a, b]| {
                let (ra, rb) = (rows[a].clone(), rows[b].clone());
                // SAFETY: rows are disjoint ranges within `out` (sorted and disjoint by
                // `MutualPairs::build`, checked above to end inside it), `a < b`, and the
                // pairs of one round share no row (the split's fields are private to its
                // builder), so no two tasks of the round touch the same values.
                let (oa, ob) = unsafe {
                    (
                        std::slice::from_raw_parts_mut(base.0.add(ra.start * dt), ra.len() * dt),
                        std::slice::from_raw_parts_mut(base.0.add(rb.start * dt), rb.len() * dt),
                    )
                };
                let (va, vb) = (sources.view(ra.clone()), sources.view(rb.clone()));
                if !self.kernel.eval_mutual_within(&va, oa, &vb, ob, self.tol) {
                    // No mutual loop after all: both directions one way.
                    let (ta, tb) = (&targets[ra], &targets[rb]);
                    self.kernel.eval_block_within(ta, &vb, oa, self.tol);
                    self.kernel.eval_block_within(tb, &va, ob, self.tol);
                }
            });
        }
        Ok(())
    }
}

/// Run `f(row, values of the row's targets)` over the rows in parallel (`dt` values per
/// target of `out`, in sorted target order).
pub fn for_each_row<F: Fn(usize, &mut [f64]) + Sync>(
    list: &NearList,
    out: &mut [f64],
    dt: usize,
    f: F,
) {
    let mut chunks = Vec::with_capacity(list.rows.len());
    let mut rest = out;
    let mut at = 0;
    for r in &list.rows {
        let (_, tail) = rest.split_at_mut((r.start - at) * dt);
        let (mine, tail) = tail.split_at_mut(r.len() * dt);
        chunks.push(mine);
        rest = tail;
        at = r.end;
    }
    chunks
        .into_par_iter()
        .enumerate()
        .for_each(|(r, vals)| f(r, vals));
}

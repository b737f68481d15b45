//! One FMM sum of the coupling over the ranks, and what it sent.

use super::*;

/// What one FMM sum of the coupling sent.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct FmmTraffic {
    pub(super) eval_bytes: u64,
    pub(super) setup_bytes: u64,
    pub(super) points_moved: u64,
    pub(super) build_s: f64,
    pub(super) comm_s: f64,
    pub(super) phases: crate::fmm::FmmTimings,
}

/// How much larger the coupling's FMM leaves are than the kernel's default
/// ([`FmmKernel::default_leaf_size`], tuned on clouds whose targets are their sources). Here
/// the targets are a fifth of the points (the order-`p` grids against the upsampled
/// quadrature) and cluster on the cells' surfaces, so a leaf's direct sums cost less per point
/// and the translations of a deep tree do not pay. Measured with the step benchmark (RBCs,
/// 5 % volume fraction, one thread, seconds of one FMM; 2026-11-27, AMD EPYC, another job on
/// the second core): p = 6, 300 cells: 2.0 at ×1, 1.5–1.65 at ×2.5, 1.1–1.2 at ×4, 1.1 at
/// ×6, 1.0–1.15 at ×10; p = 6, 1000 cells: 5.9–6.4 at ×1, 4.1 at ×3, 3.9 at ×4, 4.6–5.0 at ×5,
/// 8.8 at ×8 (a level lost: the direct sums take over); p = 12, 100 cells: 2.4 at ×1, 1.8 at
/// ×4. The accuracy is the FMM's order's, not the leaves' (benches/RESULTS.md).
const COUPLING_LEAF_FACTOR: usize = 4;

/// Sources, their normals (double layers) and targets of one FMM sum.
type SumPoints<'a> = (&'a [[f64; 3]], Option<&'a [[f64; 3]]>, &'a [[f64; 3]]);

/// One FMM evaluation of `kind` (3-vector densities, interleaved) at the targets, over the
/// ranks of `comm` (each passes its own points), its near field where `gpu` (with the digits
/// asked for) puts it, recorded in `decision`; also what this rank sent.
pub(super) fn fmm_sum(
    comm: &dyn Communicator,
    kind: FmmKernel,
    (sources, normals, targets): SumPoints,
    density: &[f64],
    order: usize,
    (gpu, digits): (GpuChoice, u32),
    decision: &mut Option<NearDecision>,
) -> Result<(Vec<f64>, FmmTraffic), TimestepError> {
    let fail = |e: FmmError| match e {
        FmmError::Comm(c) => TimestepError::Comm(c),
        e => TimestepError::Vesicle(format!("FMM ({kind:?}): {e}")),
    };
    let leaf = kind.default_leaf_size(order)
        * if gpu_expected(gpu) {
            GPU_LEAF_FACTOR.max(COUPLING_LEAF_FACTOR)
        } else {
            COUPLING_LEAF_FACTOR
        };
    let mut fmm = Fmm::new_on(comm, kind, sources, normals, targets, order, leaf).map_err(fail)?;
    *decision = Some(choose(&mut fmm, gpu, None, Some(digits)).map_err(fail)?);
    let mut u = vec![0.0; 3 * targets.len()];
    fmm.evaluate_on(comm, density, &mut u).map_err(fail)?;
    Ok((
        u,
        FmmTraffic {
            eval_bytes: fmm.comm.bytes_sent,
            setup_bytes: fmm.setup_bytes_sent,
            points_moved: fmm.tree.points_moved() as u64,
            build_s: fmm.setup_s,
            comm_s: fmm.comm.seconds,
            phases: fmm.timings,
        },
    ))
}

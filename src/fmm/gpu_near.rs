//! The FMM's near field on the GPU ([`crate::gpu`]), and the choice between GPU and CPU.
//!
//! [`choose`] decides once per plan, and says why: with [`GpuChoice::Auto`] the GPU is used
//! where the `gpu` feature is built, an adapter is a hardware GPU (not a CPU rasteriser such as
//! lavapipe), its precision serves the digits asked for ([`GpuPrecision::max_digits`]) and the
//! near field has at least [`AUTO_MIN_PAIRS`] pairs; [`GpuChoice::On`] uses any adapter and
//! fails with a clear error where there is none; [`GpuChoice::Off`] keeps the CPU.

use super::{Fmm, FmmError, FmmKernel};
use crate::gpu::{GpuChoice, GpuDecision, GpuError, GpuKernel, GpuPrecision};

/// Smallest near field (target–source pairs) that `auto` sends to the GPU: about 20 ms of the
/// CPU's AVX2 Stokeslet loop on two cores, well above the fixed cost of a launch and a
/// read-back.
pub const AUTO_MIN_PAIRS: u64 = 20_000_000;

/// How much larger leaves are when the near field runs on a GPU: larger leaves move work from
/// the CPU's far field to the GPU's near field. Measured on an H100 with 16 CPU threads
/// (Stokeslet, 6 digits, 10⁶ points on spheres): evaluation 4.87 s at the CPU's leaf size,
/// 3.19 s at ×4, and in a later run 1.53 s (×4), 1.55 s (×8), 1.67 s (×16) (benches/RESULTS.md).
pub const GPU_LEAF_FACTOR: usize = 4;

/// Whether `choice` will put the near field on a GPU if the problem is large enough (`true`,
/// or `auto` with a hardware adapter in a build with the `gpu` feature): callers then build the
/// tree with leaves [`GPU_LEAF_FACTOR`] times larger.
pub fn gpu_expected(choice: GpuChoice) -> bool {
    match choice {
        GpuChoice::Off => false,
        GpuChoice::On => true,
        GpuChoice::Auto => hardware_gpu(),
    }
}

#[cfg(feature = "gpu")]
fn hardware_gpu() -> bool {
    crate::gpu::Gpu::shared().is_ok_and(|g| g.is_hardware())
}

#[cfg(not(feature = "gpu"))]
fn hardware_gpu() -> bool {
    false
}

/// Where the near field runs and why.
pub type NearDecision = GpuDecision;

/// The GPU kernel of an FMM kernel's near field.
pub fn gpu_kernel(kind: FmmKernel) -> GpuKernel {
    match kind {
        FmmKernel::Laplace => GpuKernel::Laplace,
        FmmKernel::LaplaceDoubleLayer => GpuKernel::LaplaceDoubleLayer,
        FmmKernel::Stokeslet => GpuKernel::Stokeslet,
        FmmKernel::Stresslet => GpuKernel::Stresslet,
        FmmKernel::Rpy { radius } => GpuKernel::Rpy { radius },
    }
}

/// Decide where `fmm`'s near field runs for a request of `digits` (None: unknown, treated as
/// needing `f64`) and set its backend accordingly. `precision` forces a GPU precision.
pub fn choose(
    fmm: &mut Fmm,
    choice: GpuChoice,
    precision: Option<GpuPrecision>,
    digits: Option<u32>,
) -> Result<NearDecision, FmmError> {
    if choice == GpuChoice::Off {
        return Ok(GpuDecision::cpu(None, "GPU not asked for".into()));
    }
    attach(fmm, choice, precision, digits)
}

#[cfg(not(feature = "gpu"))]
fn attach(
    _fmm: &mut Fmm,
    choice: GpuChoice,
    _precision: Option<GpuPrecision>,
    _digits: Option<u32>,
) -> Result<NearDecision, FmmError> {
    match choice {
        GpuChoice::On => Err(GpuError::NotBuilt.into()),
        _ => Ok(GpuDecision::cpu(
            None,
            "built without the gpu feature".into(),
        )),
    }
}

#[cfg(feature = "gpu")]
fn attach(
    fmm: &mut Fmm,
    choice: GpuChoice,
    precision: Option<GpuPrecision>,
    digits: Option<u32>,
) -> Result<NearDecision, FmmError> {
    use crate::gpu::p2p::{PairPoints, PairSum, RowList};
    use crate::gpu::Gpu;
    let auto = choice == GpuChoice::Auto;
    let gpu = match Gpu::shared() {
        Ok(g) => g,
        Err(e) if auto => return Ok(GpuDecision::cpu(None, e.to_string())),
        Err(e) => return Err(e.into()),
    };
    let adapter = Some(gpu.describe());
    if auto && !gpu.is_hardware() {
        return Ok(GpuDecision::cpu(
            adapter,
            "the adapter is not a hardware GPU (a CPU rasteriser would only compete with the CPU loops)".into(),
        ));
    }
    let want = digits.unwrap_or(u32::MAX);
    let prec = match precision {
        Some(GpuPrecision::F64) if !gpu.has_f64() => {
            return Err(GpuError::NoF64(gpu.describe()).into())
        }
        Some(p) => p,
        None if gpu.has_f64() => GpuPrecision::F64,
        None => GpuPrecision::F32,
    };
    if want > prec.max_digits() {
        let why = format!(
            "{} digits asked for; the GPU's {} near field serves at most {}",
            want,
            prec.name(),
            prec.max_digits()
        );
        if auto {
            return Ok(GpuDecision::cpu(adapter, why));
        }
        return Err(GpuError::Shape(why).into());
    }
    let pairs = fmm.near_list().pairs();
    if auto && pairs < AUTO_MIN_PAIRS {
        return Ok(GpuDecision::cpu(
            adapter,
            format!("near field of {pairs} pairs, below the {AUTO_MIN_PAIRS} where the GPU gains"),
        ));
    }
    let list = fmm.near_list();
    let points = fmm.near_points();
    let kernel = gpu_kernel(fmm.kernel());
    let sum = PairSum::new(
        gpu.clone(),
        kernel,
        prec,
        PairPoints {
            sources: points.sources,
            normals: points.normals,
            targets: points.targets,
        },
        RowList {
            rows: &list.rows,
            offsets: &list.offsets,
            ranges: &list.ranges,
        },
    )?;
    fmm.set_near_field(Box::new(backend::GpuNearField { sum }));
    Ok(GpuDecision {
        device: "gpu".into(),
        adapter,
        precision: Some(prec),
        reason: if auto {
            format!(
                "hardware GPU, {} precision serves the request, {pairs} near pairs",
                prec.name()
            )
        } else {
            "GPU asked for".into()
        },
    })
}

#[cfg(feature = "gpu")]
mod backend {
    use super::super::blocks::SourceBlock;
    use super::super::near_field::{NearField, NearList};
    use super::super::FmmError;
    use crate::gpu::p2p::PairSum;

    /// The near field as a [`PairSum`] on the GPU (sources and list resident there).
    pub struct GpuNearField {
        pub sum: PairSum,
    }

    impl NearField for GpuNearField {
        fn describe(&self) -> String {
            format!(
                "gpu {} ({})",
                self.sum.precision().name(),
                self.sum.gpu().describe()
            )
        }

        fn concurrent(&self) -> bool {
            true
        }

        fn evaluate(
            &self,
            _list: &NearList,
            sources: &SourceBlock,
            _targets: &[[f64; 3]],
            out: &mut [f64],
        ) -> Result<(), FmmError> {
            let q: Vec<&[f64]> = sources.q.iter().map(|c| c.as_slice()).collect();
            let ds = self.sum.density_dim();
            self.sum.evaluate(&q[..ds], out)?;
            Ok(())
        }
    }
}

//! The TEA-HI fused pass on a GPU ([`crate::gpu::tea_hi`]), and the choice between GPU and CPU.
//!
//! [`choose`] decides once per run and says why, as the FMM's near field does
//! (`crate::fmm::gpu_near`): `auto` takes a hardware GPU for at least [`AUTO_MIN_BEADS`] beads,
//! `true` any adapter (an error without one), `false` the CPU. The GPU pass computes the same
//! ten row sums as [`super::tea_hi::fused_rows`] (the reference), in `f64` where the adapter
//! offers it.
// Without the feature `crate::gpu::tea_hi` does not exist: the link above cannot resolve.
#![cfg_attr(not(feature = "gpu"), allow(rustdoc::broken_intra_doc_links))]

use super::tea_hi::Soa;
use super::BrownianError;
use crate::gpu::{GpuChoice, GpuDecision, GpuError, GpuPrecision};

/// Smallest system `auto` sends to the GPU: below it the CPU's pass (about 4·10⁶ pairs, a few
/// ms on two cores) is as fast as a launch, upload and read-back.
pub const AUTO_MIN_BEADS: usize = 2000;

/// The pass on the device.
pub struct GpuPass {
    #[cfg(feature = "gpu")]
    pass: crate::gpu::tea_hi::GpuTeaHi,
    #[cfg(not(feature = "gpu"))]
    never: std::convert::Infallible,
}

#[cfg(feature = "gpu")]
fn comps(s: &Soa) -> [&[f64]; 3] {
    [&s.x, &s.y, &s.z]
}

impl GpuPass {
    /// The rows `rows` of the fused pass, with the self term, in `fused_rows`' layout.
    pub fn rows(
        &self,
        pos: &Soa,
        force: &Soa,
        xi: &Soa,
        a: f64,
        rows: std::ops::Range<usize>,
        out: &mut Vec<f64>,
    ) -> Result<(), BrownianError> {
        #[cfg(feature = "gpu")]
        {
            self.pass
                .rows(comps(pos), comps(force), comps(xi), a, rows.clone(), out)?;
            for (o, i) in out.chunks_exact_mut(super::tea_hi::ROW_VALUES).zip(rows) {
                o[0] += force.x[i];
                o[1] += force.y[i];
                o[2] += force.z[i];
            }
            Ok(())
        }
        #[cfg(not(feature = "gpu"))]
        {
            let _ = (pos, force, xi, a, rows, out);
            match self.never {}
        }
    }
}

/// Decide where the fused pass of `n` beads runs (`precision` forces a GPU precision).
pub fn choose(
    choice: GpuChoice,
    precision: Option<GpuPrecision>,
    n: usize,
) -> Result<(Option<GpuPass>, GpuDecision), BrownianError> {
    if choice == GpuChoice::Off {
        return Ok((None, GpuDecision::cpu(None, "GPU not asked for".into())));
    }
    open(choice, precision, n)
}

#[cfg(not(feature = "gpu"))]
fn open(
    choice: GpuChoice,
    _precision: Option<GpuPrecision>,
    _n: usize,
) -> Result<(Option<GpuPass>, GpuDecision), BrownianError> {
    match choice {
        GpuChoice::On => Err(GpuError::NotBuilt.into()),
        _ => Ok((
            None,
            GpuDecision::cpu(None, "built without the gpu feature".into()),
        )),
    }
}

#[cfg(feature = "gpu")]
fn open(
    choice: GpuChoice,
    precision: Option<GpuPrecision>,
    n: usize,
) -> Result<(Option<GpuPass>, GpuDecision), BrownianError> {
    use crate::gpu::tea_hi::GpuTeaHi;
    use crate::gpu::Gpu;
    let auto = choice == GpuChoice::Auto;
    let gpu = match Gpu::shared() {
        Ok(g) => g,
        Err(e) if auto => return Ok((None, GpuDecision::cpu(None, e.to_string()))),
        Err(e) => return Err(e.into()),
    };
    let adapter = Some(gpu.describe());
    if auto && !gpu.is_hardware() {
        let why = "the adapter is not a hardware GPU (a CPU rasteriser would only compete with the CPU loops)";
        return Ok((None, GpuDecision::cpu(adapter, why.into())));
    }
    if auto && n < AUTO_MIN_BEADS {
        let why = format!("{n} beads, below the {AUTO_MIN_BEADS} where the GPU gains");
        return Ok((None, GpuDecision::cpu(adapter, why)));
    }
    let prec = match precision {
        Some(GpuPrecision::F64) if !gpu.has_f64() => {
            return Err(GpuError::NoF64(gpu.describe()).into())
        }
        Some(p) => p,
        None if gpu.has_f64() => GpuPrecision::F64,
        None => GpuPrecision::F32,
    };
    let pass = GpuTeaHi::new(gpu, prec, n)?;
    let reason = if auto {
        format!("hardware GPU, {n} beads")
    } else {
        "GPU asked for".into()
    };
    Ok((
        Some(GpuPass { pass }),
        GpuDecision {
            device: "gpu".into(),
            adapter,
            precision: Some(prec),
            reason,
        },
    ))
}

//! The GPU through wgpu (feature `gpu`): one device per process, batched pair sums on it, and
//! the DPD fluid's whole step ([`dpd`], driven by `crate::dpd::gpu_fluid`).
//!
//! [`Gpu::shared`] opens the first adapter wgpu offers (set `WGPU_BACKEND=vulkan` to skip the
//! others; on a machine without a GPU, Mesa's lavapipe is a Vulkan adapter on the CPU) once per
//! process. [`PairSum`](p2p::PairSum) (feature `gpu`) evaluates
//!
//! `u(x_i) = s · Σ_{ranges r of row(i)} Σ_{j ∈ r} K(x_i − y_j) q_j`
//!
//! for the kernels of [`GpuKernel`], over a compressed-row list of target rows and source
//! ranges (the near field of an FMM, or one row of all pairs for a direct sum): sources,
//! targets and the list are uploaded once and stay on the device; only densities and results
//! move per evaluation. Each workgroup of [`WORKGROUP`] threads takes up to
//! `WORKGROUP · TARGETS_PER_THREAD` targets of one row and walks the row's sources in tiles
//! staged through workgroup memory.
//!
//! **Precision.** WGSL has `f64` only where the adapter offers `SHADER_F64` (NVIDIA, lavapipe),
//! and then only add, multiply, divide, square root and FMA are trustworthy — the kernels need
//! nothing else. In `f64` the GPU computes the same sums as the CPU loops, in another order.
//! In `f32` positions travel as unevaluated `hi + lo` pairs of `f32`, so that the difference
//! `x − y` of two close points is accurate to `f32` rounding of the difference itself (not of
//! the coordinates); each tile's partial sum is added into a compensated (`hi`, `lo`)
//! accumulator, so the error does not grow with the number of tiles. What that leaves is the
//! `f32` rounding of each pair's value: about `1e-7` relative per pair, which
//! [`GpuPrecision::max_digits`] turns into the digit requests the `f32` path may serve.
// Without the feature the GPU types do not exist: the links above to them cannot resolve.
#![cfg_attr(not(feature = "gpu"), allow(rustdoc::broken_intra_doc_links))]

#[cfg(feature = "gpu")]
mod context;
#[cfg(feature = "gpu")]
pub mod dpd;
#[cfg(feature = "gpu")]
pub mod dpd_pairs;
#[cfg(feature = "gpu")]
pub mod dpd_profile;
#[cfg(feature = "gpu")]
mod dpd_shader;
#[cfg(feature = "gpu")]
pub mod p2p;
#[cfg(feature = "gpu")]
mod shader;
#[cfg(feature = "gpu")]
pub mod tea_hi;

#[cfg(feature = "gpu")]
pub use context::Gpu;

/// Threads per workgroup (sources per tile). With two targets per thread, 64 to 256 threads
/// gave the same Stokeslet rate within 3 % on an H100 (benches/RESULTS.md); 256 was fastest.
pub const WORKGROUP: u32 = 256;

/// Targets each thread keeps in registers (a work item holds `WORKGROUP · TARGETS_PER_THREAD`
/// targets of one row): every source read from workgroup memory serves that many pairs.
pub const TARGETS_PER_THREAD: u32 = 2;

/// Errors of the GPU backend.
#[derive(Clone, Debug, thiserror::Error, PartialEq, Eq)]
pub enum GpuError {
    /// This binary was built without the `gpu` feature.
    #[error("this build of mobo has no GPU support (rebuild with `--features gpu`)")]
    NotBuilt,
    /// wgpu found no adapter.
    #[error("no GPU adapter found ({0}); on Linux install a Vulkan driver (e.g. apt mesa-vulkan-drivers libvulkan1)")]
    NoAdapter(String),
    /// The adapter refused a device.
    #[error("the GPU adapter {adapter} refused a device: {reason}")]
    Device {
        /// The adapter's name.
        adapter: String,
        /// wgpu's message.
        reason: String,
    },
    /// `f64` was asked for and the adapter has no `SHADER_F64`.
    #[error("the GPU adapter {0} has no f64 shaders (SHADER_F64)")]
    NoF64(String),
    /// A problem larger than the device's buffers.
    #[error(
        "{what} needs {bytes} bytes, more than the GPU's largest storage binding ({limit} bytes)"
    )]
    TooLarge {
        /// The buffer, in words.
        what: String,
        /// Bytes it needs.
        bytes: u64,
        /// The device's largest storage binding, in bytes.
        limit: u64,
    },
    /// The shader or pipeline failed to build (a bug: the message says where).
    #[error("GPU shader: {0}")]
    Shader(String),
    /// A submission or read-back failed.
    #[error("GPU execution: {0}")]
    Execution(String),
    /// Inputs whose sizes do not fit.
    #[error("GPU input: {0}")]
    Shape(String),
    /// A problem the GPU path does not take (the CPU does).
    #[error("not on the GPU: {0}")]
    Unsupported(String),
    /// More workgroups than a dispatch may have.
    #[error("{what} need more than the device's {limit} workgroups per dispatch dimension")]
    TooManyGroups {
        /// What is dispatched, in words.
        what: String,
        /// The device's limit per dimension.
        limit: u32,
    },
}

/// Floating-point precision of the GPU kernels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum GpuPrecision {
    /// 32-bit arithmetic with compensated (`hi`, `lo`) coordinates and sums.
    F32,
    /// 64-bit arithmetic (needs `SHADER_F64`).
    F64,
}

impl GpuPrecision {
    /// The largest digit request a sum in this precision may serve. `f64`: all. `f32`: the
    /// measured relative error of the compensated `f32` near field on the three test clouds is
    /// below `3e-7` for every kernel (tests/gpu.rs asserts `1e-6`), so an FMM asked for `d`
    /// digits (error `≤ 10^-d`) keeps a margin of 10 for `d ≤ 5`.
    pub fn max_digits(self) -> u32 {
        match self {
            GpuPrecision::F32 => 5,
            GpuPrecision::F64 => u32::MAX,
        }
    }

    /// Whether the DPD shaders take kernel exponent `k` in this precision: any `k` in `f32`
    /// (`pow`); 1, 1/2 and 1/4 in `f64`, by square roots (WGSL has no `f64` transcendentals).
    pub fn takes_kernel_exponent(self, k: f64) -> bool {
        self == GpuPrecision::F32 || [1.0, 0.5, 0.25].contains(&k)
    }

    /// `"f32"` or `"f64"`.
    pub fn name(self) -> &'static str {
        match self {
            GpuPrecision::F32 => "f32",
            GpuPrecision::F64 => "f64",
        }
    }
}

/// The kernels the GPU evaluates (the near kernels of the FMM and the RPY mobility).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GpuKernel {
    /// `Σ q/(4π|r|)`.
    Laplace,
    /// `Σ (n·r) q/(4π|r|³)`.
    LaplaceDoubleLayer,
    /// `Σ (1/8π)(I/|r| + r rᵀ/|r|³) f`.
    Stokeslet,
    /// `Σ (3/4π)(r·f)(r·n) r/|r|⁵`.
    Stresslet,
    /// Rotne–Prager–Yamakawa mobility with bead radius `radius`, both branches, self mobility
    /// `f/(6πa)` at `r = 0`.
    Rpy {
        /// Bead radius `a`.
        radius: f64,
    },
}

impl GpuKernel {
    /// Density components per source.
    pub fn density_dim(&self) -> usize {
        match self {
            GpuKernel::Laplace | GpuKernel::LaplaceDoubleLayer => 1,
            _ => 3,
        }
    }

    /// Output components per target.
    pub fn output_dim(&self) -> usize {
        self.density_dim()
    }

    /// Whether sources carry an orientation.
    pub fn needs_normals(&self) -> bool {
        matches!(self, GpuKernel::LaplaceDoubleLayer | GpuKernel::Stresslet)
    }

    /// The constant factor applied (in `f64`, on the host) to the raw sums.
    pub fn scale(&self) -> f64 {
        use std::f64::consts::PI;
        match *self {
            GpuKernel::Laplace | GpuKernel::LaplaceDoubleLayer => 1.0 / (4.0 * PI),
            GpuKernel::Stokeslet => 1.0 / (8.0 * PI),
            GpuKernel::Stresslet => 3.0 / (4.0 * PI),
            GpuKernel::Rpy { radius } => 1.0 / (6.0 * PI * radius),
        }
    }

    /// Floating-point operations per pair, counted on the formula as N-body codes count them
    /// for rates (GPU Gems 3, ch. 31: add, multiply 1 each, FMA 2, `1/√` 4): difference 3,
    /// `|r|²` 5, `1/|r|` 4, accumulation 1 per component, plus the kernel's own products —
    /// Laplace 1, Laplace double layer 9, Stokeslet 16 (`1/r²`, `r·f`, `f + c r`, `·1/r`),
    /// stresslet 18, RPY 33 (both branches' coefficients and the select). The `hi + lo`
    /// differences of the `f32` path are precision overhead and not counted.
    pub fn flops_per_pair(&self) -> f64 {
        match self {
            GpuKernel::Laplace => 14.0,
            GpuKernel::LaplaceDoubleLayer => 22.0,
            GpuKernel::Stokeslet => 31.0,
            GpuKernel::Stresslet => 33.0,
            GpuKernel::Rpy { .. } => 48.0,
        }
    }

    /// Short name.
    pub fn name(&self) -> &'static str {
        match self {
            GpuKernel::Laplace => "laplace",
            GpuKernel::LaplaceDoubleLayer => "laplace-dl",
            GpuKernel::Stokeslet => "stokeslet",
            GpuKernel::Stresslet => "stresslet",
            GpuKernel::Rpy { .. } => "rpy",
        }
    }
}

/// Where a pass runs and why (the `near_field` / `pair_pass` entries of the JSON summaries).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct GpuDecision {
    /// `"cpu"` or `"gpu"`.
    pub device: String,
    /// The adapter, where a GPU was looked at.
    pub adapter: Option<String>,
    /// Precision of the GPU kernels, where the GPU runs.
    pub precision: Option<GpuPrecision>,
    /// Why.
    pub reason: String,
}

impl GpuDecision {
    /// The CPU, for `reason`.
    pub fn cpu(adapter: Option<String>, reason: String) -> Self {
        GpuDecision {
            device: "cpu".into(),
            adapter,
            precision: None,
            reason,
        }
    }
}

/// Whether to use the GPU: `auto` (where an adapter exists and the problem is large enough to
/// gain), always (an error without an adapter), or never.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum GpuChoice {
    /// Where an adapter exists and the problem is large enough to gain.
    #[default]
    Auto,
    /// Always (an error without an adapter).
    On,
    /// Never.
    Off,
}

impl GpuChoice {
    /// Parse `"auto"`, `"true"`/`"on"`, `"false"`/`"off"`.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "auto" => Some(GpuChoice::Auto),
            "true" | "on" | "yes" => Some(GpuChoice::On),
            "false" | "off" | "no" => Some(GpuChoice::Off),
            _ => None,
        }
    }
}

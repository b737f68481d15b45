//! The velocity profile of the DPD fluid binned on the GPU: per bin `Σ v_x` and the particle
//! count, so a sample reads back a few hundred kilobytes instead of the whole state.
//!
//! A profile sample of `crate::dpd::poiseuille::ProfileSampler` bins each moving particle by
//! `b = min(⌊c · B/L⌋, B − 1)`, with `c` the particle's `z` (periodic Poiseuille, channels) or
//! its distance `√((y − y_c)² + (z − z_c)²)` from a pipe's axis, and adds `v_x` to bin `b`.
//! Here one workgroup of [`PROFILE_WG`] threads takes a chunk of [`PROFILE_CHUNK`] particles in
//! the device's (cell) order: each thread bins [`PROFILE_CHUNK`]` / `[`PROFILE_WG`] of them into
//! workgroup memory, then thread `b` sums bin `b` over the chunk in slot order. The chunks'
//! partial sums are read back and added on the host in `f64`, chunk by chunk. Every sum has a
//! fixed order (the particles' order is fixed, see [`super::dpd`]), so a sample is the same bit
//! for bit on every run on one device, and a resumed run continues the whole run's profile.
//!
//! In `f64` the bins and sums are the host's to rounding (the sums run in another order). In
//! `f32` the coordinate is computed in `f32`, so a particle within an `f32` rounding of a bin's
//! edge may fall in its neighbour, and each chunk's partial sum carries an `f32` rounding
//! (relative `~10⁻⁷`, far below the profile's thermal noise).

use super::{GpuError, GpuPrecision};

/// Threads per workgroup of the profile pass.
pub const PROFILE_WG: u32 = 256;
/// Particles per workgroup (chunk) of the profile pass.
pub const PROFILE_CHUNK: u32 = 1024;

/// What a profile bins: `B` bins of `c · scale`, `c` the height `z` or the distance from a
/// pipe's axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProfileSpec {
    /// Number of bins `B` (at least 1).
    pub bins: u32,
    /// `B / L`: bins per unit of the binned coordinate.
    pub scale: f64,
    /// The pipe's axis `(y_c, z_c)` when binning by radius; `None` bins by `z`.
    pub radial_center: Option<[f64; 2]>,
}

/// One sample of the profile: per bin `Σ v_x` over the moving particles, their count, and the
/// smallest id of a particle that went unstable (the control word of the step passes).
#[derive(Clone, Debug, PartialEq)]
pub struct ProfileSums {
    /// `Σ v_x` per bin.
    pub sum_v: Vec<f64>,
    /// Moving particles per bin.
    pub count: Vec<u64>,
    /// See [`super::dpd::DpdFluidState::unstable`].
    pub unstable: Option<u32>,
}

/// Number of `u32` in the profile pass's uniform block.
pub(crate) const PPAR_LEN: usize = 4;

/// The pass's WGSL: bindings 0 `pos`, 1 `vel` (read), 2 the chunks' sums, 3 their counts,
/// 4 the uniform `(n, bins, radial, groups along x)`, 5 the reals `(scale, y_c, z_c)`.
pub(crate) fn source(p: GpuPrecision) -> String {
    let per_thread = PROFILE_CHUNK / PROFILE_WG;
    format!(
        r#"alias R = {real};
struct PPar {{ n: u32, bins: u32, radial: u32, groups: u32 }}
@group(0) @binding(0) var<storage, read> pos: array<vec4<R>>;
@group(0) @binding(1) var<storage, read> vel: array<vec4<R>>;
@group(0) @binding(2) var<storage, read_write> sums: array<R>;
@group(0) @binding(3) var<storage, read_write> counts: array<u32>;
@group(0) @binding(4) var<uniform> ppar: PPar;
@group(0) @binding(5) var<storage, read> preal: array<R>;
var<workgroup> bin_of: array<u32, {PROFILE_CHUNK}>;
var<workgroup> val: array<R, {PROFILE_CHUNK}>;
@compute @workgroup_size({PROFILE_WG})
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {{
    let g = wid.y * ppar.groups + wid.x;
    let chunks = (ppar.n + {PROFILE_CHUNK}u - 1u) / {PROFILE_CHUNK}u;
    if (g >= chunks) {{ return; }}
    for (var k = 0u; k < {per_thread}u; k++) {{
        let s = k * {PROFILE_WG}u + li;
        let i = g * {PROFILE_CHUNK}u + s;
        var b = 0xffffffffu;
        var v = R(0.0);
        if (i < ppar.n) {{
            let p = pos[i];
            // pos.w = 0: a frozen wall particle, not part of the profile.
            if (p.w != R(0.0)) {{
                var c = p.z;
                if (ppar.radial != 0u) {{
                    let dy = p.y - preal[1];
                    let dz = p.z - preal[2];
                    c = sqrt(dy * dy + dz * dz);
                }}
                b = min(u32(max(c * preal[0], R(0.0))), ppar.bins - 1u);
                v = vel[i].x;
            }}
        }}
        bin_of[s] = b;
        val[s] = v;
    }}
    workgroupBarrier();
    for (var b = li; b < ppar.bins; b += {PROFILE_WG}u) {{
        var s = R(0.0);
        var c = 0u;
        for (var k = 0u; k < {PROFILE_CHUNK}u; k++) {{
            if (bin_of[k] == b) {{
                s += val[k];
                c += 1u;
            }}
        }}
        sums[g * ppar.bins + b] = s;
        counts[g * ppar.bins + b] = c;
    }}
}}
"#,
        real = p.name()
    )
}

/// Bytes of workgroup memory the pass declares.
pub(crate) fn workgroup_bytes(p: GpuPrecision) -> u32 {
    let real = match p {
        GpuPrecision::F32 => 4,
        GpuPrecision::F64 => 8,
    };
    PROFILE_CHUNK * (4 + real)
}

/// Add the chunks' partial sums (`chunks × bins`, chunk-major) into per-bin totals, in chunk
/// order.
pub(crate) fn reduce(sums: &[f64], counts: &[u32], bins: usize) -> (Vec<f64>, Vec<u64>) {
    let mut s = vec![0.0; bins];
    let mut c = vec![0u64; bins];
    for (chunk_s, chunk_c) in sums.chunks_exact(bins).zip(counts.chunks_exact(bins)) {
        for b in 0..bins {
            s[b] += chunk_s[b];
            c[b] += chunk_c[b] as u64;
        }
    }
    (s, c)
}

/// Check a spec: at least one bin, a finite positive scale, a finite centre.
pub(crate) fn check(spec: &ProfileSpec) -> Result<(), GpuError> {
    let centre_ok = spec
        .radial_center
        .is_none_or(|c| c.iter().all(|x| x.is_finite()));
    if spec.bins == 0 || !(spec.scale.is_finite() && spec.scale > 0.0) || !centre_ok {
        return Err(GpuError::Shape(format!(
            "profile of {} bins at {} bins per unit length (centre {:?}): at least one bin, \
             a finite positive scale and a finite centre",
            spec.bins, spec.scale, spec.radial_center
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reduce_adds_chunks_in_order() {
        let sums = [1.0, 2.0, 3.0, 10.0, 20.0, 30.0];
        let counts = [1, 0, 2, 3, 4, 5];
        let (s, c) = reduce(&sums, &counts, 3);
        assert_eq!(s, vec![11.0, 22.0, 33.0]);
        assert_eq!(c, vec![4, 4, 7]);
    }

    #[test]
    fn bad_specs_are_refused() {
        let ok = ProfileSpec {
            bins: 10,
            scale: 1.0,
            radial_center: Some([1.0, 2.0]),
        };
        assert!(check(&ok).is_ok());
        for bad in [
            ProfileSpec { bins: 0, ..ok },
            ProfileSpec { scale: 0.0, ..ok },
            ProfileSpec {
                scale: f64::NAN,
                ..ok
            },
            ProfileSpec {
                radial_center: Some([f64::INFINITY, 0.0]),
                ..ok
            },
        ] {
            assert!(check(&bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn the_workgroup_memory_fits_the_webgpu_minimum() {
        // 16 KiB is the smallest `max_compute_workgroup_storage_size` WebGPU allows.
        for p in [GpuPrecision::F32, GpuPrecision::F64] {
            assert!(workgroup_bytes(p) <= 16384);
        }
    }
}

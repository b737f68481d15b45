//! WGSL source of the pair-sum kernels, generated per kernel and precision.
//!
//! Bindings: `src` (positions; in `f32` two `vec4` per point, `hi` then `lo`), `dens` (four
//! density components per source), `nrm` (orientations, double-layer kernels only), `tgt`
//! (target positions, same layout as `src`), `plan` (work items `(row, first target, count)`,
//! then the row offsets, then the source ranges `(start, end)`), `out` (`f64`: three values per
//! target; `f32`: three `hi` then three `lo`), `consts` (the RPY radius) and `params`.

use super::{GpuKernel, GpuPrecision};

/// Bindings a kernel's shader uses (the pipeline's layout is derived from the shader, so the
/// bind group names exactly these).
pub fn uses_normals(k: GpuKernel) -> bool {
    k.needs_normals()
}

/// Whether the shader reads `consts`.
pub fn uses_consts(k: GpuKernel) -> bool {
    matches!(k, GpuKernel::Rpy { .. })
}

/// The body of `fn pair(d, q, n) -> vec3<R>`: the kernel without its constant factor.
/// `inv` is `1/|d|`, or 0 at `d = 0` (the self term is left out of singular kernels).
fn pair_body(k: GpuKernel, p: GpuPrecision) -> String {
    let inv = match p {
        // f64 has no inverseSqrt worth trusting (transcendentals are not offered for f64).
        GpuPrecision::F64 => "let inv = select(R(0.0), R(1.0) / sqrt(d2), d2 > R(0.0));",
        GpuPrecision::F32 => "let inv = select(R(0.0), inverseSqrt(d2), d2 > R(0.0));",
    };
    let body = match k {
        GpuKernel::Laplace => "return vec3<R>(q.x * inv, R(0.0), R(0.0));".to_string(),
        GpuKernel::LaplaceDoubleLayer => {
            "return vec3<R>(q.x * dot(n.xyz, d) * inv * inv * inv, R(0.0), R(0.0));".to_string()
        }
        GpuKernel::Stokeslet => "let rf = dot(d, q.xyz) * inv * inv;
    return (q.xyz + rf * d) * inv;"
            .to_string(),
        GpuKernel::Stresslet => "let inv2 = inv * inv;
    let c = dot(d, q.xyz) * dot(d, n.xyz) * inv2 * inv2 * inv;
    return c * d;"
            .to_string(),
        GpuKernel::Rpy { .. } => "let a = consts[0];
    let dist = d2 * inv;
    let sa = a * inv;
    let sa3 = sa * sa * sa;
    let far = d2 >= R(4.0) * a * a;
    let fc = select(R(1.0) - R(0.28125) * dist / a, R(0.75) * sa + R(0.5) * sa3, far);
    let gc = select(R(0.09375) * dist / a, R(0.75) * sa - R(1.5) * sa3, far);
    let rf = gc * dot(d, q.xyz) * inv * inv;
    return fc * q.xyz + rf * d;"
            .to_string(),
    };
    format!("{inv}\n    {body}")
}

/// The complete shader.
pub fn source(k: GpuKernel, p: GpuPrecision, wg: u32, tpt: u32) -> String {
    let real = p.name();
    let normals = uses_normals(k);
    let pair = pair_body(k, p);
    let nrm_decl = if normals {
        "@group(0) @binding(2) var<storage, read> nrm: array<vec4<R>>;\nvar<workgroup> sn: array<vec4<R>, WG>;"
    } else {
        ""
    };
    let consts_decl = if uses_consts(k) {
        "@group(0) @binding(6) var<storage, read> consts: array<R>;"
    } else {
        ""
    };
    let nrm_load = if normals { "sn[li] = nrm[j];" } else { "" };
    let nrm_use = if normals { "sn[k]" } else { "vec4<R>(R(0.0))" };
    // Per precision: how positions are read and differenced, and how partial sums are kept.
    let (lo_decl, tgt_read, src_load, src_regs, diff, fold, write) = match p {
        GpuPrecision::F64 => (
            "",
            "xh[t] = tgt[ti].xyz;",
            "sp[li] = src[j];",
            "let yh = sp[k].xyz;",
            "let d = xh[t] - yh;",
            "total[t] += acc[t]; acc[t] = vec3<R>(R(0.0));",
            "out[3u * ti] = total[t].x; out[3u * ti + 1u] = total[t].y; out[3u * ti + 2u] = total[t].z;",
        ),
        GpuPrecision::F32 => (
            "var<workgroup> sl: array<vec4<R>, WG>;",
            "xh[t] = tgt[2u * ti].xyz; xl[t] = tgt[2u * ti + 1u].xyz;",
            "sp[li] = src[2u * j]; sl[li] = src[2u * j + 1u];",
            "let yh = sp[k].xyz; let yl = sl[k].xyz;",
            // Sterbenz: xh − yh is exact for close points; the lo parts carry the rest.
            "let d = (xh[t] - yh) + (xl[t] - yl);",
            // Two-sum of the running total and the tile's partial sum; errors gathered in lo.
            "let s = total[t] + acc[t]; let bb = s - total[t]; \
             lo[t] += (total[t] - (s - bb)) + (acc[t] - bb); total[t] = s; acc[t] = vec3<R>(R(0.0));",
            "out[6u * ti] = total[t].x; out[6u * ti + 1u] = total[t].y; out[6u * ti + 2u] = total[t].z; \
             out[6u * ti + 3u] = lo[t].x; out[6u * ti + 4u] = lo[t].y; out[6u * ti + 5u] = lo[t].z;",
        ),
    };
    format!(
        r#"alias R = {real};
const WG: u32 = {wg}u;
const TPT: u32 = {tpt}u;

struct Params {{
    n_items: u32,
    groups_x: u32,
    offsets_at: u32,
    ranges_at: u32,
}}

@group(0) @binding(0) var<storage, read> src: array<vec4<R>>;
@group(0) @binding(1) var<storage, read> dens: array<vec4<R>>;
@group(0) @binding(3) var<storage, read> tgt: array<vec4<R>>;
@group(0) @binding(4) var<storage, read> plan: array<u32>;
@group(0) @binding(5) var<storage, read_write> out: array<R>;
@group(0) @binding(7) var<uniform> params: Params;
{nrm_decl}
{consts_decl}

var<workgroup> sp: array<vec4<R>, WG>;
var<workgroup> sq: array<vec4<R>, WG>;
{lo_decl}

fn pair(d: vec3<R>, q: vec4<R>, n: vec4<R>) -> vec3<R> {{
    let d2 = dot(d, d);
    {pair}
}}

@compute @workgroup_size({wg})
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {{
    let item = wid.y * params.groups_x + wid.x;
    if (item >= params.n_items) {{
        return;
    }}
    let row = plan[3u * item];
    let t0 = plan[3u * item + 1u];
    let tn = plan[3u * item + 2u];
    // Thread li takes targets li, li + WG, ... of the item (clamped: extra lanes recompute the
    // last target and do not write).
    var xh: array<vec3<R>, TPT>;
    var xl: array<vec3<R>, TPT>;
    var acc: array<vec3<R>, TPT>;
    var total: array<vec3<R>, TPT>;
    var lo: array<vec3<R>, TPT>;
    for (var t = 0u; t < TPT; t++) {{
        let ti = t0 + min(li + t * WG, tn - 1u);
        {tgt_read}
        acc[t] = vec3<R>(R(0.0));
        total[t] = vec3<R>(R(0.0));
        lo[t] = vec3<R>(R(0.0));
    }}
    let r0 = plan[params.offsets_at + row];
    let r1 = plan[params.offsets_at + row + 1u];
    for (var r = r0; r < r1; r++) {{
        let s0 = plan[params.ranges_at + 2u * r];
        let s1 = plan[params.ranges_at + 2u * r + 1u];
        for (var base = s0; base < s1; base += WG) {{
            let j = base + li;
            if (j < s1) {{
                {src_load}
                sq[li] = dens[j];
                {nrm_load}
            }}
            workgroupBarrier();
            let m = min(WG, s1 - base);
            for (var k = 0u; k < m; k++) {{
                {src_regs}
                let q = sq[k];
                let n = {nrm_use};
                for (var t = 0u; t < TPT; t++) {{
                    {diff}
                    acc[t] += pair(d, q, n);
                }}
            }}
            for (var t = 0u; t < TPT; t++) {{
                {fold}
            }}
            workgroupBarrier();
        }}
    }}
    for (var t = 0u; t < TPT; t++) {{
        if (li + t * WG < tn) {{
            let ti = t0 + li + t * WG;
            {write}
        }}
    }}
}}
"#
    )
}

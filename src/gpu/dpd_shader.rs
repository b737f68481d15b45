//! WGSL source of the DPD fluid's step on the GPU, generated per precision and kernel exponent.
//!
//! One step is nine passes over resident buffers (see [`super::dpd::DpdFluidPass`]):
//!
//! | pass | one thread per | does |
//! |---|---|---|
//! | `drift` | particle | `v += (dt/2m) F`, `x += dt v` (moving particles), bounce-back off the wall, wrap into the box, bin: `arrival = count[c]++` |
//! | `scan_local` | 4 cells | exclusive prefix of the counts within blocks of 1024 cells; counts reset |
//! | `scan_blocks` | block (one workgroup) | exclusive prefix of the block totals; the step counter `+1` |
//! | `scan_add` | cell | `start[c] += blocks[c / 1024]` |
//! | `scatter` | particle | `order[start[c] + arrival] = i` |
//! | `sort_cells` | cell | the cell's slots sorted by particle id (a deterministic order) |
//! | `gather` | slot | positions, velocities and ids permuted into cell order |
//! | `forces` | particle | pair forces over the 27 neighbour cells, body force, virial share |
//! | `kick` | particle | `v += (dt/2m) F` (moving particles) |
//!
//! The pair noise is the CPU's ([`crate::dpd::rng`]): SplitMix64 on 64-bit words, done here on
//! pairs of `u32` (WGSL has no 64-bit integers), so a pair draws the same 64 bits on the GPU as
//! on the CPU. In `f64` the unit-variance number is the CPU's formula on the same 53 bits (the
//! final multiply-add may be fused, a last-bit difference); in `f32` it is built from the top 24
//! bits.

use super::GpuPrecision;

/// Threads per workgroup of the per-particle and per-cell passes.
pub const WG: u32 = 128;

/// Threads of the scan passes; each takes [`SCAN_PER_THREAD`] cells, a block is
/// [`SCAN_BLOCK`] cells.
pub const SCAN_WG: u32 = 256;
/// Cells per thread of `scan_local`.
pub const SCAN_PER_THREAD: u32 = 4;
/// Cells per block of `scan_local`.
pub const SCAN_BLOCK: u32 = SCAN_WG * SCAN_PER_THREAD;

/// Indices into the real parameters (`rpar`).
pub mod rpar {
    /// Box lengths (3).
    pub const BOX: usize = 0;
    /// Inverse cell sides (3).
    pub const INV_CELL: usize = 3;
    /// `a`.
    pub const A: usize = 6;
    /// `γ`.
    pub const GAMMA: usize = 7;
    /// `σ`.
    pub const SIGMA: usize = 8;
    /// `r_c`.
    pub const RC: usize = 9;
    /// `dt`.
    pub const DT: usize = 10;
    /// `dt / 2m`.
    pub const HALF_DT_OVER_M: usize = 11;
    /// `1/√dt`.
    pub const INV_SQRT_DT: usize = 12;
    /// Constant body force (3).
    pub const BODY: usize = 13;
    /// Reverse-Poiseuille force magnitude (0: none).
    pub const REVERSE: usize = 16;
    /// Half the box height (the reverse-Poiseuille split).
    pub const HALF_LZ: usize = 17;
    /// The wall's parameters (3): planes `lo, hi, –`; cylinder `radius, y_c, z_c`.
    pub const WALL: usize = 18;
    /// Speed of sliding plane walls (Couette flow).
    pub const WALL_SPEED: usize = 21;
    /// Number of values.
    pub const LEN: usize = 22;
}

// The shaders index `rpar` and compare `IPar::wall` with these numbers written out; the
// pipelines have no runtime bounds checks, so the layout is pinned here.
const _: () = assert!(
    rpar::BOX == 0
        && rpar::INV_CELL == 3
        && rpar::A == 6
        && rpar::GAMMA == 7
        && rpar::SIGMA == 8
        && rpar::RC == 9
        && rpar::DT == 10
        && rpar::HALF_DT_OVER_M == 11
        && rpar::INV_SQRT_DT == 12
        && rpar::BODY == 13
        && rpar::REVERSE == 16
        && rpar::HALF_LZ == 17
        && rpar::WALL == 18
        && rpar::WALL_SPEED == 21
        && rpar::LEN == 22
        && WALL_PLANES == 1
        && CTL_LEN == 8
);

/// The integer parameters (`ipar`, a uniform block of 12 `u32`).
pub fn ipar_struct() -> &'static str {
    r#"struct IPar {
    n: u32,
    ncells: u32,
    nx: u32,
    ny: u32,
    nz: u32,
    nblocks: u32,
    key0_lo: u32,
    key0_hi: u32,
    groups_n: u32,
    groups_c: u32,
    wall: u32,
    pad1: u32,
}"#
}

/// Number of `u32` in `IPar`.
pub const IPAR_LEN: usize = 12;

/// `IPar::wall`: no wall.
pub const WALL_NONE: u32 = 0;
/// `IPar::wall`: planes `z = lo`, `z = hi`.
pub const WALL_PLANES: u32 = 1;
/// `IPar::wall`: a cylinder along `x`.
pub const WALL_CYLINDER: u32 = 2;

/// Words of the control buffer: step (2), unstable flag, smallest unstable id, bounces (2),
/// particles left inside the wall after a bounce (2).
pub const CTL_LEN: usize = 8;

fn prelude(p: GpuPrecision) -> String {
    format!(
        "alias R = {real};\nconst WG: u32 = {WG}u;\n{ipar}\n",
        real = p.name(),
        ipar = ipar_struct()
    )
}

/// Index of this thread in a 2-D dispatch of `groups` workgroups along `x`.
const GID: &str = "fn gid(wid: vec3<u32>, li: u32, groups: u32) -> u32 { return (wid.y * groups + wid.x) * WG + li; }\n";

/// The cell of a wrapped position (coordinates `0..n` per axis).
const CELL_OF: &str = r#"fn cell_coords(x: vec3<R>) -> vec3<u32> {
    let ic = vec3<R>(rpar[3], rpar[4], rpar[5]);
    let q = x * ic;
    return vec3<u32>(
        min(u32(max(q.x, R(0.0))), ipar.nx - 1u),
        min(u32(max(q.y, R(0.0))), ipar.ny - 1u),
        min(u32(max(q.z, R(0.0))), ipar.nz - 1u));
}
fn cell_index(c: vec3<u32>) -> u32 { return (c.z * ipar.ny + c.y) * ipar.nx + c.x; }
"#;

/// 64-bit unsigned arithmetic on `vec2<u32>` (`x` the low word) and the SplitMix64 noise.
const RNG: &str = r#"fn mulhi32(a: u32, b: u32) -> u32 {
    let a0 = a & 0xffffu; let a1 = a >> 16u;
    let b0 = b & 0xffffu; let b1 = b >> 16u;
    let p00 = a0 * b0; let p01 = a0 * b1; let p10 = a1 * b0; let p11 = a1 * b1;
    let mid = (p00 >> 16u) + (p01 & 0xffffu) + (p10 & 0xffffu);
    return p11 + (p01 >> 16u) + (p10 >> 16u) + (mid >> 16u);
}
fn mul64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    return vec2<u32>(a.x * b.x, mulhi32(a.x, b.x) + a.x * b.y + a.y * b.x);
}
fn add64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let lo = a.x + b.x;
    return vec2<u32>(lo, a.y + b.y + select(0u, 1u, lo < a.x));
}
fn xorshr64(z: vec2<u32>, s: u32) -> vec2<u32> {
    return z ^ vec2<u32>((z.x >> s) | (z.y << (32u - s)), z.y >> s);
}
fn mix64(z0: vec2<u32>) -> vec2<u32> {
    var z = mul64(xorshr64(z0, 30u), vec2<u32>(0x1ce4e5b9u, 0xbf58476du));
    z = mul64(xorshr64(z, 27u), vec2<u32>(0x133111ebu, 0x94d049bbu));
    return xorshr64(z, 31u);
}
"#;

/// The wall (`crate::dpd::walls::Wall`): signed distance, bounce-back, sliding speed; and the
/// 64-bit counters of the control buffer.
const WALL_FNS: &str = r#"fn sdf(p: vec3<R>) -> R {
    if (ipar.wall == 1u) { return max(rpar[18] - p.z, p.z - rpar[19]); }
    let dy = p.y - rpar[19];
    let dz = p.z - rpar[20];
    return sqrt(dy * dy + dz * dz) - rpar[18];
}
fn path_at(x: vec3<R>, v: vec3<R>, t: R) -> vec3<R> {
    return x - ((R(1.0) - t) * rpar[10]) * v;
}
fn count_up(k: u32) {
    let old = atomicAdd(&ctl[k], 1u);
    if (old == 0xffffffffu) { atomicAdd(&ctl[k + 1u], 1u); }
}
"#;

/// The pair's unit-variance number from its 64 random bits `b`.
fn unit_variance(p: GpuPrecision) -> &'static str {
    match p {
        // (b >> 11) as f64 · 2√3/2^53 − √3, as the CPU (the 53 bits are exact in f64).
        GpuPrecision::F64 => {
            r#"fn unit_variance(b: vec2<u32>) -> R {
    let hi = R(b.y >> 11u);
    let lo = R((b.x >> 11u) | (b.y << 21u));
    let u = hi * R(4294967296.0) + lo;
    return u * (R(2.0) * R(1.7320508075688772) / R(9007199254740992.0)) - R(1.7320508075688772);
}
"#
        }
        // The top 24 bits.
        GpuPrecision::F32 => {
            r#"fn unit_variance(b: vec2<u32>) -> R {
    return R(b.y >> 8u) * (R(2.0) * R(1.7320508) / R(16777216.0)) - R(1.7320508);
}
"#
        }
    }
}

/// `w_R = w^k` for the kernel exponent `k` (`None` where this precision cannot take `k`).
fn weight_r(power: f64, p: GpuPrecision) -> Option<String> {
    if !p.takes_kernel_exponent(power) {
        return None;
    }
    let body = if power == 1.0 {
        "w".to_string()
    } else if power == 0.5 {
        "sqrt(w)".to_string()
    } else if power == 0.25 {
        "sqrt(sqrt(w))".to_string()
    } else {
        // f32 only (takes_kernel_exponent): WGSL offers no transcendental functions on f64.
        format!("pow(w, R({power:?}))")
    };
    Some(format!("fn weight_r(w: R) -> R {{ return {body}; }}\n"))
}

/// Every pass's source, by name: `(name, source)`.
pub fn sources(p: GpuPrecision, power: f64) -> Option<Vec<(&'static str, String)>> {
    let pre = prelude(p);
    let wr = weight_r(power, p)?;
    let uv = unit_variance(p);
    let rp = "@group(0) @binding(12) var<storage, read> rpar: array<R>;\n";
    let ip = "@group(0) @binding(11) var<uniform> ipar: IPar;\n";
    let drift = format!(
        r#"{pre}{GID}
@group(0) @binding(0) var<storage, read> pos: array<vec4<R>>;
@group(0) @binding(1) var<storage, read> vel: array<vec4<R>>;
@group(0) @binding(2) var<storage, read> frc: array<vec4<R>>;
@group(0) @binding(3) var<storage, read> ids: array<u32>;
@group(0) @binding(4) var<storage, read_write> pos2: array<vec4<R>>;
@group(0) @binding(5) var<storage, read_write> vel2: array<vec4<R>>;
@group(0) @binding(6) var<storage, read_write> ids2: array<u32>;
@group(0) @binding(7) var<storage, read_write> cell: array<u32>;
@group(0) @binding(8) var<storage, read_write> arrival: array<u32>;
@group(0) @binding(9) var<storage, read_write> count: array<atomic<u32>>;
@group(0) @binding(10) var<storage, read_write> ctl: array<atomic<u32>>;
{ip}{rp}{CELL_OF}{WALL_FNS}
@compute @workgroup_size({WG})
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {{
    let i = gid(wid, li, ipar.groups_n);
    if (i >= ipar.n) {{ return; }}
    // pos.w = 1 for particles that move, 0 for frozen wall particles (never kicked or drifted).
    let p = pos[i];
    let m = p.w;
    var v = vel[i].xyz + rpar[11] * frc[i].xyz * m;
    var x = p.xyz + rpar[10] * v * m;
    if (ipar.wall != 0u && m != R(0.0) && sdf(x) >= R(0.0)) {{
        // Bounce-back as Wall::bounce: the crossing by bisection, back along −v for the rest
        // of the step; off a sliding wall the velocity relative to it is reversed.
        if (sdf(path_at(x, v, R(0.0))) >= R(0.0)) {{
            x = path_at(x, v, R(0.0));
        }} else {{
            var lo = R(0.0);
            var hi = R(1.0);
            for (var it = 0u; it < 40u; it++) {{
                let mid = R(0.5) * (lo + hi);
                if (sdf(path_at(x, v, mid)) < R(0.0)) {{ lo = mid; }} else {{ hi = mid; }}
            }}
            let rest = R(1.0) - lo;
            let hit = path_at(x, v, lo);
            let back = hit - rest * rpar[10] * v;
            x = select(hit, back, sdf(back) < R(0.0));
        }}
        v = -v;
        let uw = rpar[21];
        if (ipar.wall == 1u && uw != R(0.0)) {{
            v.x += R(2.0) * select(-uw, uw, x.z > R(0.5) * (rpar[18] + rpar[19]));
        }}
        count_up(4u);
        if (sdf(x) >= R(0.0)) {{ count_up(6u); }}
    }}
    var bad = false;
    for (var k = 0u; k < 3u; k++) {{
        let l = rpar[k];
        if (x[k] < R(0.0)) {{ x[k] += l; }} else if (x[k] >= l) {{ x[k] -= l; }}
        if (!(x[k] >= R(0.0) && x[k] < l)) {{
            if (x[k] == l) {{ x[k] = R(0.0); }} else {{ bad = true; x[k] = R(0.0); }}
        }}
    }}
    if (bad) {{
        atomicMax(&ctl[2], 1u);
        atomicMin(&ctl[3], ids[i]);
    }}
    let c = cell_index(cell_coords(x));
    pos2[i] = vec4<R>(x, m);
    vel2[i] = vec4<R>(v, R(0.0));
    ids2[i] = ids[i];
    cell[i] = c;
    arrival[i] = atomicAdd(&count[c], 1u);
}}
"#
    );
    let scan_local = format!(
        r#"{pre}
const PER: u32 = {SCAN_PER_THREAD}u;
const SWG: u32 = {SCAN_WG}u;
@group(0) @binding(0) var<storage, read_write> count: array<atomic<u32>>;
@group(0) @binding(1) var<storage, read_write> start: array<u32>;
@group(0) @binding(2) var<storage, read_write> blocks: array<u32>;
{ip}
var<workgroup> sh: array<u32, SWG>;
@compute @workgroup_size({SCAN_WG})
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {{
    let b = wid.x;
    if (b >= ipar.nblocks) {{ return; }}
    let base = b * SWG * PER + li * PER;
    var v: array<u32, {SCAN_PER_THREAD}>;
    var s = 0u;
    for (var q = 0u; q < PER; q++) {{
        let c = base + q;
        v[q] = 0u;
        if (c < ipar.ncells) {{
            v[q] = atomicLoad(&count[c]);
            atomicStore(&count[c], 0u);
        }}
        s += v[q];
    }}
    sh[li] = s;
    workgroupBarrier();
    for (var off = 1u; off < SWG; off *= 2u) {{
        var t = 0u;
        if (li >= off) {{ t = sh[li - off]; }}
        workgroupBarrier();
        sh[li] += t;
        workgroupBarrier();
    }}
    var run = sh[li] - s;
    for (var q = 0u; q < PER; q++) {{
        let c = base + q;
        if (c < ipar.ncells) {{ start[c] = run; }}
        run += v[q];
    }}
    if (li == SWG - 1u) {{ blocks[b] = sh[li]; }}
}}
"#
    );
    let scan_blocks = format!(
        r#"{pre}
const SWG: u32 = {SCAN_WG}u;
@group(0) @binding(0) var<storage, read_write> blocks: array<u32>;
@group(0) @binding(1) var<storage, read_write> start: array<u32>;
@group(0) @binding(2) var<storage, read_write> ctl: array<u32>;
{ip}
var<workgroup> sh: array<u32, SWG>;
@compute @workgroup_size({SCAN_WG})
fn main(@builtin(local_invocation_index) li: u32) {{
    let per = (ipar.nblocks + SWG - 1u) / SWG;
    let base = li * per;
    var s = 0u;
    for (var q = 0u; q < per; q++) {{
        if (base + q < ipar.nblocks) {{ s += blocks[base + q]; }}
    }}
    sh[li] = s;
    workgroupBarrier();
    for (var off = 1u; off < SWG; off *= 2u) {{
        var t = 0u;
        if (li >= off) {{ t = sh[li - off]; }}
        workgroupBarrier();
        sh[li] += t;
        workgroupBarrier();
    }}
    var run = sh[li] - s;
    for (var q = 0u; q < per; q++) {{
        if (base + q < ipar.nblocks) {{
            let t = blocks[base + q];
            blocks[base + q] = run;
            run += t;
        }}
    }}
    if (li == SWG - 1u) {{ start[ipar.ncells] = sh[li]; }}
    if (li == 0u) {{
        // The step counter (64 bits): the forces of this step draw its noise.
        let lo = ctl[0] + 1u;
        ctl[0] = lo;
        if (lo == 0u) {{ ctl[1] = ctl[1] + 1u; }}
    }}
}}
"#
    );
    let scan_add = format!(
        r#"{pre}{GID}
@group(0) @binding(0) var<storage, read_write> start: array<u32>;
@group(0) @binding(1) var<storage, read> blocks: array<u32>;
{ip}
@compute @workgroup_size({WG})
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {{
    let c = gid(wid, li, ipar.groups_c);
    if (c >= ipar.ncells) {{ return; }}
    start[c] += blocks[c / {SCAN_BLOCK}u];
}}
"#
    );
    let scatter = format!(
        r#"{pre}{GID}
@group(0) @binding(0) var<storage, read> start: array<u32>;
@group(0) @binding(1) var<storage, read> cell: array<u32>;
@group(0) @binding(2) var<storage, read> arrival: array<u32>;
@group(0) @binding(3) var<storage, read_write> order: array<u32>;
{ip}
@compute @workgroup_size({WG})
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {{
    let i = gid(wid, li, ipar.groups_n);
    if (i >= ipar.n) {{ return; }}
    order[start[cell[i]] + arrival[i]] = i;
}}
"#
    );
    let sort_cells = format!(
        r#"{pre}{GID}
@group(0) @binding(0) var<storage, read> start: array<u32>;
@group(0) @binding(1) var<storage, read> ids2: array<u32>;
@group(0) @binding(2) var<storage, read_write> order: array<u32>;
{ip}
@compute @workgroup_size({WG})
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {{
    let c = gid(wid, li, ipar.groups_c);
    if (c >= ipar.ncells) {{ return; }}
    let lo = start[c];
    let hi = start[c + 1u];
    for (var k = lo + 1u; k < hi; k++) {{
        let o = order[k];
        let key = ids2[o];
        var m = k;
        while (m > lo && ids2[order[m - 1u]] > key) {{
            order[m] = order[m - 1u];
            m -= 1u;
        }}
        order[m] = o;
    }}
}}
"#
    );
    let gather = format!(
        r#"{pre}{GID}
@group(0) @binding(0) var<storage, read_write> pos: array<vec4<R>>;
@group(0) @binding(1) var<storage, read_write> vel: array<vec4<R>>;
@group(0) @binding(3) var<storage, read_write> ids: array<u32>;
@group(0) @binding(4) var<storage, read> pos2: array<vec4<R>>;
@group(0) @binding(5) var<storage, read> vel2: array<vec4<R>>;
@group(0) @binding(6) var<storage, read> ids2: array<u32>;
@group(0) @binding(7) var<storage, read> order: array<u32>;
{ip}
@compute @workgroup_size({WG})
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {{
    let s = gid(wid, li, ipar.groups_n);
    if (s >= ipar.n) {{ return; }}
    let i = order[s];
    pos[s] = pos2[i];
    vel[s] = vel2[i];
    ids[s] = ids2[i];
}}
"#
    );
    let forces = format!(
        r#"{pre}{GID}{RNG}{uv}{wr}
@group(0) @binding(0) var<storage, read> pos: array<vec4<R>>;
@group(0) @binding(1) var<storage, read> vel: array<vec4<R>>;
@group(0) @binding(2) var<storage, read_write> frc: array<vec4<R>>;
@group(0) @binding(3) var<storage, read> ids: array<u32>;
@group(0) @binding(4) var<storage, read> start: array<u32>;
@group(0) @binding(10) var<storage, read> ctl: array<u32>;
{ip}{rp}{CELL_OF}
@compute @workgroup_size({WG})
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {{
    let s = gid(wid, li, ipar.groups_n);
    if (s >= ipar.n) {{ return; }}
    // The step's key, as crate::dpd::rng::step_key (key0 = mix64(seed ^ C) from the host).
    let step = vec2<u32>(ctl[0], ctl[1]);
    let key = mix64(add64(vec2<u32>(ipar.key0_lo, ipar.key0_hi), mul64(step, vec2<u32>(0x7f4a7c15u, 0x9e3779b9u))));
    let xi = pos[s].xyz;
    let vi = vel[s].xyz;
    let idi = ids[s];
    let cc = cell_coords(xi);
    let dims = vec3<u32>(ipar.nx, ipar.ny, ipar.nz);
    let l = vec3<R>(rpar[0], rpar[1], rpar[2]);
    let a = rpar[6];
    let gamma = rpar[7];
    let sig = rpar[8] * rpar[12];
    let rc = rpar[9];
    var f = vec3<R>(R(0.0));
    var vir = R(0.0);
    let rc2 = rc * rc;
    // Nine rows of three cells (dy, dz); a row whose three cells do not wrap in x is one
    // contiguous range of particles (cells are numbered x fastest), else three ranges.
    let whole_row = cc.x >= 1u && cc.x + 1u < dims.x;
    for (var dz = 0u; dz < 3u; dz++) {{
      for (var dy = 0u; dy < 3u; dy++) {{
        var shift = vec3<R>(R(0.0));
        var nc = vec3<u32>(0u);
        let dd = vec3<u32>(0u, dy, dz);
        for (var k = 1u; k < 3u; k++) {{
            let t = cc[k] + dd[k];
            if (t == 0u) {{ nc[k] = dims[k] - 1u; shift[k] = -l[k]; }}
            else if (t == dims[k] + 1u) {{ nc[k] = 0u; shift[k] = l[k]; }}
            else {{ nc[k] = t - 1u; }}
        }}
        let row = (nc.z * ipar.ny + nc.y) * ipar.nx;
        let segments = select(3u, 1u, whole_row);
        for (var g = 0u; g < segments; g++) {{
            var lo = 0u;
            var hi = 0u;
            shift.x = R(0.0);
            if (whole_row) {{
                lo = start[row + cc.x - 1u];
                hi = start[row + cc.x + 2u];
            }} else {{
                let t = cc.x + g;
                var cx = t - 1u;
                if (t == 0u) {{ cx = dims.x - 1u; shift.x = -l.x; }}
                else if (t == dims.x + 1u) {{ cx = 0u; shift.x = l.x; }}
                lo = start[row + cx];
                hi = start[row + cx + 1u];
            }}
            for (var j = lo; j < hi; j++) {{
                let d = xi - (pos[j].xyz + shift);
                let r2 = dot(d, d);
                // j == s has r2 = 0 (and so has a coincident particle: no direction, no force).
                if (r2 < rc2 && r2 > R(0.0)) {{
                    let r = sqrt(r2);
                    if (r < rc) {{
                        let e = d / r;
                        let w = R(1.0) - r / rc;
                        let wr = weight_r(w);
                        let ve = dot(vi - vel[j].xyz, e);
                        let idj = ids[j];
                        let word = vec2<u32>(max(idi, idj), min(idi, idj));
                        let xr = unit_variance(mix64(key ^ word));
                        let fc = a * w;
                        let fs = fc - gamma * wr * wr * ve + sig * wr * xr;
                        f += fs * e;
                        vir += R(0.5) * fc * r;
                    }}
                }}
            }}
        }}
      }}
    }}
    f += vec3<R>(rpar[13], rpar[14], rpar[15]);
    let g = rpar[16];
    f.x += select(-g, g, xi.z < rpar[17]);
    frc[s] = vec4<R>(f, vir);
}}
"#
    );
    let kick = format!(
        r#"{pre}{GID}
@group(0) @binding(0) var<storage, read> pos: array<vec4<R>>;
@group(0) @binding(1) var<storage, read_write> vel: array<vec4<R>>;
@group(0) @binding(2) var<storage, read> frc: array<vec4<R>>;
{ip}{rp}
@compute @workgroup_size({WG})
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {{
    let s = gid(wid, li, ipar.groups_n);
    if (s >= ipar.n) {{ return; }}
    vel[s] = vec4<R>(vel[s].xyz + rpar[11] * frc[s].xyz * pos[s].w, R(0.0));
}}
"#
    );
    Some(vec![
        ("drift", drift),
        ("scan_local", scan_local),
        ("scan_blocks", scan_blocks),
        ("scan_add", scan_add),
        ("scatter", scatter),
        ("sort_cells", sort_cells),
        ("gather", gather),
        ("forces", forces),
        ("kick", kick),
    ])
}

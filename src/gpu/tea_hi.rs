//! The TEA-HI fused pass of Brownian dynamics on the GPU.
//!
//! For each particle `i` of a block of rows, over all `j ≠ i`, with the RPY block
//! `D̃_ij = c_i I + g r rᵀ` (`r = x_i − x_j`; both branches of the overlap, as in
//! `crate::brownian::tea_hi`): the ten row sums `Σ D̃_ij F_j` (3), `Σ D̃_ij ξ_j` (3),
//! `Σ_l D̃_ij[k][l]²` per row `k` (3) and the sum of the block's entries (1). The CPU pass
//! (`crate::brownian::tea_hi::fused_rows`) is the reference; the host adds the self term `F_i`.
//!
//! Positions, forces and noise change every step, so each call uploads them (`7 N` numbers) and
//! reads back `10` per row. Precision as in [`super::p2p`]: `f64` with `SHADER_F64`, else `f32`
//! with `hi + lo` positions and compensated accumulation per tile.

use std::ops::Range;
use std::sync::{Arc, Mutex};

use super::{Gpu, GpuError, GpuPrecision};

/// Values per row (the layout of `crate::brownian::tea_hi::ROW_VALUES`).
pub const ROW_VALUES: usize = 10;

/// Threads per workgroup of the pass (one row each).
const WG: u32 = 128;

/// Floating-point operations per pair, counted as [`super::GpuKernel::flops_per_pair`]:
/// difference 3, `r²` 5, `1/r` 4 and `r` 1, both branches' coefficients 17 with the select,
/// `g` 2, the two projections 12, the six accumulations of `D̃F` and `D̃ξ` 24, the block's
/// entries 12, their squares 18 and the entry sum 7.
pub const FLOPS_PER_PAIR: f64 = 105.0;

fn shader(p: GpuPrecision) -> String {
    let real = p.name();
    let (inv, lo_decl, xi_read, src_load, diff, fold, write) = match p {
        GpuPrecision::F64 => (
            "let inv = R(1.0) / sqrt(d2);",
            "",
            "let xh = pos[i].xyz;",
            "sp[li] = pos[j];",
            "let d = xh - sp[k].xyz;",
            "for (var c = 0u; c < 3u; c++) { tot[c] += acc[c]; acc[c] = vec4<R>(R(0.0)); }",
            "for (var c = 0u; c < 9u; c++) { out[10u * o + c] = tot[c / 3u][c % 3u]; } \
             out[10u * o + 9u] = tot[0].w;",
        ),
        GpuPrecision::F32 => (
            "let inv = inverseSqrt(d2);",
            "var<workgroup> sl: array<vec4<R>, WG>;",
            "let xh = pos[2u * i].xyz; let xl = pos[2u * i + 1u].xyz;",
            "sp[li] = pos[2u * j]; sl[li] = pos[2u * j + 1u];",
            "let d = (xh - sp[k].xyz) + (xl - sl[k].xyz);",
            "for (var c = 0u; c < 3u; c++) { let s = tot[c] + acc[c]; let bb = s - tot[c]; \
             lo[c] += (tot[c] - (s - bb)) + (acc[c] - bb); tot[c] = s; acc[c] = vec4<R>(R(0.0)); }",
            "for (var c = 0u; c < 9u; c++) { out[20u * o + c] = tot[c / 3u][c % 3u]; \
             out[20u * o + 10u + c] = lo[c / 3u][c % 3u]; } \
             out[20u * o + 9u] = tot[0].w; out[20u * o + 19u] = lo[0].w;",
        ),
    };
    format!(
        r#"alias R = {real};
const WG: u32 = {WG}u;

struct Params {{
    n: u32,
    row0: u32,
    nrows: u32,
    groups_x: u32,
}}

@group(0) @binding(0) var<storage, read> pos: array<vec4<R>>;
@group(0) @binding(1) var<storage, read> fx: array<vec4<R>>;
@group(0) @binding(2) var<storage, read_write> out: array<R>;
@group(0) @binding(3) var<storage, read> consts: array<R>;
@group(0) @binding(4) var<uniform> params: Params;

var<workgroup> sp: array<vec4<R>, WG>;
var<workgroup> sf: array<vec4<R>, WG>;
var<workgroup> se: array<vec4<R>, WG>;
{lo_decl}

@compute @workgroup_size({WG})
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) li: u32) {{
    let g0 = (wid.y * params.groups_x + wid.x) * WG;
    if (g0 >= params.nrows) {{
        return;
    }}
    let o = min(g0 + li, params.nrows - 1u);
    let i = params.row0 + o;
    let a = consts[0];
    let inv_a = R(1.0) / a;
    {xi_read}
    // acc[0] = (D̃F, entry sum), acc[1] = (D̃ξ, 0), acc[2] = (row squares, 0).
    var acc: array<vec4<R>, 3>;
    var tot: array<vec4<R>, 3>;
    var lo: array<vec4<R>, 3>;
    for (var c = 0u; c < 3u; c++) {{
        acc[c] = vec4<R>(R(0.0)); tot[c] = vec4<R>(R(0.0)); lo[c] = vec4<R>(R(0.0));
    }}
    for (var base = 0u; base < params.n; base += WG) {{
        let j = base + li;
        if (j < params.n) {{
            {src_load}
            sf[li] = fx[2u * j];
            se[li] = fx[2u * j + 1u];
        }}
        workgroupBarrier();
        let m = min(WG, params.n - base);
        for (var k = 0u; k < m; k++) {{
            if (base + k != i) {{
                {diff}
                let d2 = dot(d, d);
                {inv}
                let dist = d2 * inv;
                let s = a * inv;
                let s3 = s * s * s;
                let t = dist * inv_a;
                let far = dist >= R(2.0) * a;
                let ci = select(R(1.0) - R(0.28125) * t, R(0.75) * s + R(0.5) * s3, far);
                let crr = select(R(0.09375) * t, R(0.75) * s - R(1.5) * s3, far);
                let g = crr * inv * inv;
                let f = sf[k].xyz;
                let e = se[k].xyz;
                let rf = g * dot(d, f);
                let re = g * dot(d, e);
                let gd = g * d;
                let mdiag = vec3<R>(ci, ci, ci) + gd * d;
                let mxy = gd.x * d.y;
                let mxz = gd.x * d.z;
                let myz = gd.y * d.z;
                let sq = vec3<R>(
                    mdiag.x * mdiag.x + mxy * mxy + mxz * mxz,
                    mxy * mxy + mdiag.y * mdiag.y + myz * myz,
                    mxz * mxz + myz * myz + mdiag.z * mdiag.z);
                let entries = mdiag.x + mdiag.y + mdiag.z + R(2.0) * (mxy + mxz + myz);
                acc[0] += vec4<R>(ci * f + rf * d, entries);
                acc[1] += vec4<R>(ci * e + re * d, R(0.0));
                acc[2] += vec4<R>(sq, R(0.0));
            }}
        }}
        {fold}
        workgroupBarrier();
    }}
    if (g0 + li < params.nrows) {{
        {write}
    }}
}}
"#
    )
}

/// The fused pass with its buffers on the device, for `n` particles.
pub struct GpuTeaHi {
    gpu: Arc<Gpu>,
    precision: GpuPrecision,
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    pos: wgpu::Buffer,
    fx: wgpu::Buffer,
    out: wgpu::Buffer,
    staging: wgpu::Buffer,
    params: wgpu::Buffer,
    consts: wgpu::Buffer,
    n: usize,
    busy: Mutex<()>,
}

fn real_bytes(p: GpuPrecision) -> usize {
    match p {
        GpuPrecision::F32 => 4,
        GpuPrecision::F64 => 8,
    }
}

impl GpuTeaHi {
    /// Buffers and pipeline for `n` particles in `precision`.
    pub fn new(gpu: Arc<Gpu>, precision: GpuPrecision, n: usize) -> Result<Self, GpuError> {
        if precision == GpuPrecision::F64 && !gpu.has_f64() {
            return Err(GpuError::NoF64(gpu.describe()));
        }
        if n == 0 || n >= (u32::MAX / 32) as usize {
            return Err(GpuError::Shape(format!("TEA-HI pass of {n} particles")));
        }
        let rb = real_bytes(precision);
        let pos_bytes = n * 4 * rb * if precision == GpuPrecision::F32 { 2 } else { 1 };
        let out_bytes = n * ROW_VALUES * rb * if precision == GpuPrecision::F32 { 2 } else { 1 };
        for (what, b) in [
            ("the positions", pos_bytes),
            ("forces and noise", 8 * n * rb),
            ("the row sums", out_bytes),
        ] {
            if b as u64 > gpu.max_binding {
                return Err(GpuError::TooLarge {
                    what: what.into(),
                    bytes: b as u64,
                    limit: gpu.max_binding,
                });
            }
        }
        // SAFETY: indices are in bounds by construction: rows are clamped to `nrows`, rows and
        // sources lie in `0..n` (checked in `rows`), workgroup indices are below WG, and the
        // buffers are sized for `n` particles here.
        let pipeline = unsafe { gpu.trusted_pipeline("tea-hi", &shader(precision)) };
        let buf =
            |label: &str, size: usize, usage: wgpu::BufferUsages| gpu.buffer(label, size, usage);
        use wgpu::BufferUsages as U;
        let pos = buf("positions", pos_bytes, U::STORAGE | U::COPY_DST);
        let fx = buf("forces and noise", 8 * n * rb, U::STORAGE | U::COPY_DST);
        let out = buf("row sums", out_bytes, U::STORAGE | U::COPY_SRC);
        let staging = buf("read-back", out_bytes, U::MAP_READ | U::COPY_DST);
        let params = buf("params", 16, U::UNIFORM | U::COPY_DST);
        let consts = buf("radius", 2 * rb, U::STORAGE | U::COPY_DST);
        let bind_group = gpu.bind_group(
            "tea-hi",
            &pipeline,
            &[(0, &pos), (1, &fx), (2, &out), (3, &consts), (4, &params)],
        );
        Ok(GpuTeaHi {
            gpu,
            precision,
            pipeline,
            bind_group,
            pos,
            fx,
            out,
            staging,
            params,
            consts,
            n,
            busy: Mutex::new(()),
        })
    }

    /// The precision of the pass.
    pub fn precision(&self) -> GpuPrecision {
        self.precision
    }

    /// The device.
    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    fn upload(&self, pos: [&[f64]; 3], force: [&[f64]; 3], xi: [&[f64]; 3], a: f64) {
        let n = self.n;
        let q = &self.gpu.queue;
        match self.precision {
            GpuPrecision::F64 => {
                let p: Vec<f64> = (0..n)
                    .flat_map(|i| [pos[0][i], pos[1][i], pos[2][i], 0.0])
                    .collect();
                let f: Vec<f64> = (0..n)
                    .flat_map(|i| {
                        [
                            force[0][i],
                            force[1][i],
                            force[2][i],
                            0.0,
                            xi[0][i],
                            xi[1][i],
                            xi[2][i],
                            0.0,
                        ]
                    })
                    .collect();
                q.write_buffer(&self.pos, 0, bytemuck::cast_slice(&p));
                q.write_buffer(&self.fx, 0, bytemuck::cast_slice(&f));
                q.write_buffer(&self.consts, 0, bytemuck::cast_slice(&[a, 0.0]));
            }
            GpuPrecision::F32 => {
                let mut p: Vec<f32> = Vec::with_capacity(8 * n);
                for ((&x0, &x1), &x2) in pos[0].iter().zip(pos[1]).zip(pos[2]) {
                    let x = [x0, x1, x2];
                    let hi = x.map(|c| c as f32);
                    p.extend_from_slice(&[hi[0], hi[1], hi[2], 0.0]);
                    for (c, h) in x.iter().zip(hi) {
                        p.push((c - h as f64) as f32);
                    }
                    p.push(0.0);
                }
                let f: Vec<f32> = (0..n)
                    .flat_map(|i| {
                        [
                            force[0][i],
                            force[1][i],
                            force[2][i],
                            0.0,
                            xi[0][i],
                            xi[1][i],
                            xi[2][i],
                            0.0,
                        ]
                        .map(|v| v as f32)
                    })
                    .collect();
                q.write_buffer(&self.pos, 0, bytemuck::cast_slice(&p));
                q.write_buffer(&self.fx, 0, bytemuck::cast_slice(&f));
                q.write_buffer(&self.consts, 0, bytemuck::cast_slice(&[a as f32, 0.0]));
            }
        }
    }

    fn dispatch(&self, encoder: &mut wgpu::CommandEncoder, rows: &Range<usize>, reps: usize) {
        let groups = (rows.len() as u32).div_ceil(WG).max(1);
        let gx = groups.min(self.gpu.max_groups);
        let gy = groups.div_ceil(gx);
        let params = [self.n as u32, rows.start as u32, rows.len() as u32, gx];
        self.gpu
            .queue
            .write_buffer(&self.params, 0, bytemuck::cast_slice(&params));
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        for _ in 0..reps {
            pass.dispatch_workgroups(gx, gy, 1);
        }
    }

    fn check(
        &self,
        pos: [&[f64]; 3],
        force: [&[f64]; 3],
        xi: [&[f64]; 3],
        rows: &Range<usize>,
    ) -> Result<(), GpuError> {
        let n = self.n;
        if pos.iter().chain(&force).chain(&xi).any(|c| c.len() != n) {
            return Err(GpuError::Shape(format!(
                "TEA-HI pass built for {n} particles: every component needs {n} values"
            )));
        }
        if rows.start > rows.end || rows.end > n {
            return Err(GpuError::Shape(format!("rows {rows:?} outside 0..{n}")));
        }
        Ok(())
    }

    /// The ten row sums of the particles `rows` over all `n` particles (`j ≠ i`), in
    /// `crate::brownian::tea_hi::fused_rows`'s layout, without the self term.
    pub fn rows(
        &self,
        pos: [&[f64]; 3],
        force: [&[f64]; 3],
        xi: [&[f64]; 3],
        a: f64,
        rows: Range<usize>,
        out: &mut Vec<f64>,
    ) -> Result<(), GpuError> {
        self.check(pos, force, xi, &rows)?;
        let _guard = self
            .busy
            .lock()
            .map_err(|_| GpuError::Execution("poisoned".into()))?;
        out.clear();
        out.resize(ROW_VALUES * rows.len(), 0.0);
        if rows.is_empty() {
            return Ok(());
        }
        self.upload(pos, force, xi, a);
        let per_row = ROW_VALUES
            * if self.precision == GpuPrecision::F32 {
                2
            } else {
                1
            };
        let bytes = (rows.len() * per_row * real_bytes(self.precision)) as u64;
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        self.dispatch(&mut encoder, &rows, 1);
        encoder.copy_buffer_to_buffer(&self.out, 0, &self.staging, 0, bytes);
        self.gpu.queue.submit([encoder.finish()]);
        let slice = self.staging.slice(..bytes);
        self.gpu.map_read(&slice)?;
        {
            let view = slice
                .get_mapped_range()
                .map_err(|e| GpuError::Execution(e.to_string()))?;
            match self.precision {
                GpuPrecision::F64 => out.copy_from_slice(bytemuck::cast_slice(&view)),
                GpuPrecision::F32 => {
                    let v: &[f32] = bytemuck::cast_slice(&view);
                    for (o, r) in out.chunks_exact_mut(ROW_VALUES).zip(v.chunks_exact(20)) {
                        for c in 0..ROW_VALUES {
                            o[c] = r[c] as f64 + r[10 + c] as f64;
                        }
                    }
                }
            }
        }
        self.staging.unmap();
        Ok(())
    }

    /// Seconds of one pass over all rows on the device alone (inputs as last uploaded; `reps`
    /// launches in one submission): for pair rates.
    pub fn time_pass(&self, reps: usize) -> Result<f64, GpuError> {
        let _guard = self
            .busy
            .lock()
            .map_err(|_| GpuError::Execution("poisoned".into()))?;
        let all = 0..self.n;
        let wait = || {
            self.gpu
                .device
                .poll(wgpu::PollType::wait_indefinitely())
                .map(|_| ())
                .map_err(|e| GpuError::Execution(e.to_string()))
        };
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        self.dispatch(&mut encoder, &all, 1);
        self.gpu.queue.submit([encoder.finish()]);
        wait()?;
        let t = std::time::Instant::now();
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        self.dispatch(&mut encoder, &all, reps.max(1));
        self.gpu.queue.submit([encoder.finish()]);
        wait()?;
        Ok(t.elapsed().as_secs_f64() / reps.max(1) as f64)
    }
}

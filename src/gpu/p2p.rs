//! Batched pair sums on the GPU: geometry uploaded once, densities in and values out per call.

use std::ops::Range;
use std::sync::{Arc, Mutex};

use wgpu::util::DeviceExt;

use super::{shader, Gpu, GpuError, GpuKernel, GpuPrecision, TARGETS_PER_THREAD, WORKGROUP};

/// The rows of a pair sum, compressed-row (as `crate::fmm::near_field::NearList`): row `r`
/// sums the sources in `ranges[offsets[r]..offsets[r + 1]]` into its targets `rows[r]`.
#[derive(Clone, Copy, Debug)]
pub struct RowList<'a> {
    /// Target range of each row.
    pub rows: &'a [Range<usize>],
    /// Row `r`'s source ranges are `ranges[offsets[r]..offsets[r + 1]]` (`rows.len() + 1`
    /// entries).
    pub offsets: &'a [usize],
    /// Source ranges of all rows, concatenated.
    pub ranges: &'a [Range<usize>],
}

/// Points of a pair sum: source positions (and orientations) and target positions.
#[derive(Clone, Copy, Debug)]
pub struct PairPoints<'a> {
    /// Source positions.
    pub sources: &'a [[f64; 3]],
    /// Source orientations (double-layer kernels), one per source.
    pub normals: Option<&'a [[f64; 3]]>,
    /// Target positions.
    pub targets: &'a [[f64; 3]],
}

/// A pair sum on the GPU with its geometry resident on the device.
pub struct PairSum {
    gpu: Arc<Gpu>,
    kernel: GpuKernel,
    precision: GpuPrecision,
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    dens: wgpu::Buffer,
    out: wgpu::Buffer,
    staging: wgpu::Buffer,
    n_sources: usize,
    n_targets: usize,
    groups: (u32, u32),
    pairs: u64,
    /// One evaluation at a time (the staging buffer is mapped in turn).
    busy: Mutex<()>,
}

fn bytes<T: bytemuck::Pod>(v: &[T]) -> &[u8] {
    bytemuck::cast_slice(v)
}

/// Positions as the shader reads them: `vec4<f64>`, or `hi` and `lo` `vec4<f32>`.
fn pack_points(p: &[[f64; 3]], prec: GpuPrecision) -> Vec<u8> {
    match prec {
        GpuPrecision::F64 => {
            let v: Vec<f64> = p.iter().flat_map(|x| [x[0], x[1], x[2], 0.0]).collect();
            bytes(&v).to_vec()
        }
        GpuPrecision::F32 => {
            let mut v: Vec<f32> = Vec::with_capacity(p.len() * 8);
            for x in p {
                let hi = x.map(|c| c as f32);
                v.extend_from_slice(&[hi[0], hi[1], hi[2], 0.0]);
                for (c, h) in x.iter().zip(hi) {
                    v.push((c - h as f64) as f32);
                }
                v.push(0.0);
            }
            bytes(&v).to_vec()
        }
    }
}

/// Four density components per source (components `dim..4` zero).
fn pack_density(q: &[&[f64]], n: usize, prec: GpuPrecision) -> Vec<u8> {
    let comp = |i: usize, c: usize| q.get(c).map_or(0.0, |s| s[i]);
    match prec {
        GpuPrecision::F64 => {
            let v: Vec<f64> = (0..n)
                .flat_map(|i| [comp(i, 0), comp(i, 1), comp(i, 2), comp(i, 3)])
                .collect();
            bytes(&v).to_vec()
        }
        GpuPrecision::F32 => {
            let v: Vec<f32> = (0..n)
                .flat_map(|i| (0..4).map(move |c| comp(i, c) as f32))
                .collect();
            bytes(&v).to_vec()
        }
    }
}

/// Targets per thread: [`TARGETS_PER_THREAD`], or `MOBO_GPU_TARGETS_PER_THREAD` (1 to 8), a
/// tuning knob for other GPUs.
fn targets_per_thread() -> u32 {
    std::env::var("MOBO_GPU_TARGETS_PER_THREAD")
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|t| (1..=8).contains(t))
        .unwrap_or(TARGETS_PER_THREAD)
}

/// Threads per workgroup: [`WORKGROUP`], or `MOBO_GPU_WORKGROUP` (32, 64, 128 or 256); halved
/// where the adapter's workgroup limits ask for less.
fn workgroup_size() -> u32 {
    std::env::var("MOBO_GPU_WORKGROUP")
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|w| [32, 64, 128, 256].contains(w))
        .unwrap_or(WORKGROUP)
}

impl PairSum {
    /// Upload `points` and `list` for `kernel` in `precision` and build the pipeline.
    pub fn new(
        gpu: Arc<Gpu>,
        kernel: GpuKernel,
        precision: GpuPrecision,
        points: PairPoints,
        list: RowList,
    ) -> Result<Self, GpuError> {
        if precision == GpuPrecision::F64 && !gpu.has_f64() {
            return Err(GpuError::NoF64(gpu.describe()));
        }
        if kernel.needs_normals() && points.normals.map(|n| n.len()) != Some(points.sources.len()) {
            return Err(GpuError::Shape(format!(
                "{} needs one orientation per source",
                kernel.name()
            )));
        }
        if list.offsets.len() != list.rows.len() + 1 {
            return Err(GpuError::Shape(
                "row offsets must have one entry per row plus one".into(),
            ));
        }
        let (ns, nt) = (points.sources.len(), points.targets.len());
        let bad = |r: &Range<usize>, n: usize| r.start > r.end || r.end > n;
        if list.rows.iter().any(|r| bad(r, nt)) || list.ranges.iter().any(|r| bad(r, ns)) {
            return Err(GpuError::Shape(
                "a row or range runs past the points".into(),
            ));
        }
        if list.offsets.windows(2).any(|w| w[0] > w[1])
            || list.offsets.last().is_some_and(|&o| o > list.ranges.len())
        {
            return Err(GpuError::Shape(
                "row offsets must be non-decreasing and within the ranges".into(),
            ));
        }
        if ns.max(nt) >= (u32::MAX / 8) as usize {
            return Err(GpuError::TooLarge {
                what: format!("{} points", ns.max(nt)),
                bytes: 0,
                limit: gpu.max_binding,
            });
        }
        let too_large = |what: &str, b: usize| -> Result<(), GpuError> {
            if b as u64 > gpu.max_binding || b > u32::MAX as usize / 2 {
                Err(GpuError::TooLarge {
                    what: what.into(),
                    bytes: b as u64,
                    limit: gpu.max_binding,
                })
            } else {
                Ok(())
            }
        };
        // Work items: up to WORKGROUP targets of one row each.
        let tpt = targets_per_thread();
        // Workgroup memory per source of a tile: position (and its lo part in f32), density,
        // orientation where used.
        let per_source = (2
            + usize::from(precision == GpuPrecision::F32)
            + usize::from(shader::uses_normals(kernel)))
            * 4
            * match precision {
                GpuPrecision::F32 => 4,
                GpuPrecision::F64 => 8,
            };
        let mut wgs = workgroup_size();
        while wgs > 32
            && (wgs > gpu.max_invocations
                || wgs as usize * per_source > gpu.max_workgroup_bytes as usize)
        {
            wgs /= 2;
        }
        let wg = (wgs * tpt) as usize;
        let mut plan: Vec<u32> = Vec::new();
        let mut pairs = 0u64;
        for (r, t) in list.rows.iter().enumerate() {
            let ns_row: usize = list.ranges[list.offsets[r]..list.offsets[r + 1]]
                .iter()
                .map(|s| s.len())
                .sum();
            pairs += (ns_row * t.len()) as u64;
            let mut at = t.start;
            while at < t.end {
                let n = (t.end - at).min(wg);
                plan.extend_from_slice(&[r as u32, at as u32, n as u32]);
                at += n;
            }
        }
        let n_items = plan.len() / 3;
        let offsets_at = plan.len() as u32;
        plan.extend(list.offsets.iter().map(|&o| o as u32));
        let ranges_at = plan.len() as u32;
        for s in list.ranges {
            plan.extend_from_slice(&[s.start as u32, s.end as u32]);
        }
        let groups_x = (n_items as u32).clamp(1, gpu.max_groups);
        let groups_y = (n_items as u32).div_ceil(groups_x).max(1);
        if groups_y > gpu.max_groups {
            return Err(GpuError::TooLarge {
                what: format!("{n_items} work items"),
                bytes: 0,
                limit: gpu.max_binding,
            });
        }
        let real = match precision {
            GpuPrecision::F32 => 4,
            GpuPrecision::F64 => 8,
        };
        let out_per_target = match precision {
            GpuPrecision::F32 => 6,
            GpuPrecision::F64 => 3,
        };
        let src = pack_points(points.sources, precision);
        let tgt = pack_points(points.targets, precision);
        too_large("the sources", src.len())?;
        too_large("the targets", tgt.len())?;
        too_large("the densities", ns * 4 * real)?;
        too_large("the results", nt * out_per_target * real)?;
        too_large("the near-field list", plan.len() * 4)?;

        let dev = &gpu.device;
        let source = shader::source(kernel, precision, wgs, tpt);
        // SAFETY: every index the shader forms is in bounds by construction, checked above on
        // the host: work items, row offsets and ranges lie inside the plan, sources and targets
        // (`rows` and `ranges` validated against the point counts), and workgroup indices are
        // below the workgroup size. Without runtime checks the inner loop has no index clamps.
        let pipeline = unsafe { gpu.trusted_pipeline(kernel.name(), &source) };
        let storage = wgpu::BufferUsages::STORAGE;
        let init = |label: &str, contents: &[u8], usage| {
            // Empty bindings are not allowed: pad to one element.
            let pad = [0u8; 32];
            let contents = if contents.is_empty() {
                &pad[..]
            } else {
                contents
            };
            dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            })
        };
        let src_buf = init("sources", &src, storage);
        let tgt_buf = init("targets", &tgt, storage);
        let plan_buf = init("plan", bytes(&plan), storage);
        let nrm_buf = match points.normals {
            Some(n) if shader::uses_normals(kernel) => {
                let comps: Vec<Vec<f64>> =
                    (0..3).map(|c| n.iter().map(|x| x[c]).collect()).collect();
                let comps: Vec<&[f64]> = comps.iter().map(|c| c.as_slice()).collect();
                Some(init(
                    "normals",
                    &pack_density(&comps, ns, precision),
                    storage,
                ))
            }
            _ => None,
        };
        let consts: Vec<u8> = match (kernel, precision) {
            (GpuKernel::Rpy { radius }, GpuPrecision::F64) => bytes(&[radius, 0.0]).to_vec(),
            (GpuKernel::Rpy { radius }, GpuPrecision::F32) => {
                bytes(&[radius as f32, 0.0, 0.0, 0.0]).to_vec()
            }
            _ => Vec::new(),
        };
        let consts_buf = shader::uses_consts(kernel).then(|| init("consts", &consts, storage));
        let params = [n_items as u32, groups_x, offsets_at, ranges_at];
        let params_buf = init("params", bytes(&params), wgpu::BufferUsages::UNIFORM);
        let dens = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("densities"),
            size: (ns.max(1) * 4 * real) as u64,
            usage: storage | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let out_size = (nt.max(1) * out_per_target * real) as u64;
        let out = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("results"),
            size: out_size,
            usage: storage | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let staging = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read-back"),
            size: out_size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut entries = vec![
            (0, &src_buf),
            (1, &dens),
            (3, &tgt_buf),
            (4, &plan_buf),
            (5, &out),
            (7, &params_buf),
        ];
        if let Some(b) = &nrm_buf {
            entries.push((2, b));
        }
        if let Some(b) = &consts_buf {
            entries.push((6, b));
        }
        let bind_group = gpu.bind_group(kernel.name(), &pipeline, &entries);
        Ok(PairSum {
            gpu,
            kernel,
            precision,
            pipeline,
            bind_group,
            dens,
            out,
            staging,
            n_sources: ns,
            n_targets: nt,
            groups: (groups_x, groups_y),
            pairs,
            busy: Mutex::new(()),
        })
    }

    /// Every target against every source (one row, one range): a direct sum such as the RPY
    /// mobility product of Brownian dynamics.
    pub fn all_pairs(
        gpu: Arc<Gpu>,
        kernel: GpuKernel,
        precision: GpuPrecision,
        points: PairPoints,
    ) -> Result<Self, GpuError> {
        let rows = [Range {
            start: 0,
            end: points.targets.len(),
        }];
        let ranges = [Range {
            start: 0,
            end: points.sources.len(),
        }];
        let list = RowList {
            rows: &rows,
            offsets: &[0, 1],
            ranges: &ranges,
        };
        Self::new(gpu, kernel, precision, points, list)
    }

    /// The precision the kernels run in.
    pub fn precision(&self) -> GpuPrecision {
        self.precision
    }

    /// Target–source pairs of one evaluation.
    pub fn pairs(&self) -> u64 {
        self.pairs
    }

    /// The device.
    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    fn dispatch(&self, encoder: &mut wgpu::CommandEncoder, reps: usize) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor::default());
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        for _ in 0..reps {
            pass.dispatch_workgroups(self.groups.0, self.groups.1, 1);
        }
    }

    /// Add `scale · Σ K q` to `out` (`output_dim` values per target): `q` holds the density
    /// components, one slice per component (`density_dim` of them), in source order.
    pub fn evaluate(&self, q: &[&[f64]], out: &mut [f64]) -> Result<(), GpuError> {
        let (ds, dt) = (self.kernel.density_dim(), self.kernel.output_dim());
        if q.len() < ds || q[..ds].iter().any(|c| c.len() != self.n_sources) {
            return Err(GpuError::Shape(format!(
                "{} needs {ds} density components of {} values",
                self.kernel.name(),
                self.n_sources
            )));
        }
        if out.len() != self.n_targets * dt {
            return Err(GpuError::Shape(format!(
                "output has {} values, expected {}",
                out.len(),
                self.n_targets * dt
            )));
        }
        let _guard = self
            .busy
            .lock()
            .map_err(|_| GpuError::Execution("poisoned".into()))?;
        let (queue, dev) = (&self.gpu.queue, &self.gpu.device);
        if self.n_sources > 0 {
            queue.write_buffer(
                &self.dens,
                0,
                &pack_density(&q[..ds], self.n_sources, self.precision),
            );
        }
        let mut encoder = dev.create_command_encoder(&Default::default());
        encoder.clear_buffer(&self.out, 0, None);
        self.dispatch(&mut encoder, 1);
        encoder.copy_buffer_to_buffer(&self.out, 0, &self.staging, 0, None);
        queue.submit([encoder.finish()]);
        let slice = self.staging.slice(..);
        self.gpu.map_read(&slice)?;
        {
            let view = slice
                .get_mapped_range()
                .map_err(|e| GpuError::Execution(e.to_string()))?;
            let scale = self.kernel.scale();
            match self.precision {
                GpuPrecision::F64 => {
                    let v: &[f64] = bytemuck::cast_slice(&view);
                    for (o, t) in out.chunks_exact_mut(dt).zip(v.chunks_exact(3)) {
                        for c in 0..dt {
                            o[c] += scale * t[c];
                        }
                    }
                }
                GpuPrecision::F32 => {
                    let v: &[f32] = bytemuck::cast_slice(&view);
                    for (o, t) in out.chunks_exact_mut(dt).zip(v.chunks_exact(6)) {
                        for c in 0..dt {
                            o[c] += scale * (t[c] as f64 + t[3 + c] as f64);
                        }
                    }
                }
            }
        }
        self.staging.unmap();
        Ok(())
    }

    /// Seconds per kernel launch on the device alone (densities as last set; `reps` launches
    /// in one submission, read-back excluded): for pair rates.
    pub fn time_kernel(&self, reps: usize) -> Result<f64, GpuError> {
        let _guard = self
            .busy
            .lock()
            .map_err(|_| GpuError::Execution("poisoned".into()))?;
        // Warm up (pipeline creation is lazy on some drivers).
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        self.dispatch(&mut encoder, 1);
        self.gpu.queue.submit([encoder.finish()]);
        self.gpu.wait()?;
        let t = std::time::Instant::now();
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        self.dispatch(&mut encoder, reps.max(1));
        self.gpu.queue.submit([encoder.finish()]);
        self.gpu.wait()?;
        Ok(t.elapsed().as_secs_f64() / reps.max(1) as f64)
    }
}

impl PairSum {
    /// Density components per source of the kernel.
    pub fn density_dim(&self) -> usize {
        self.kernel.density_dim()
    }
}

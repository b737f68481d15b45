//! The velocity profile sampled on the device ([`super::super::dpd_profile`]): the pass for one
//! [`ProfileSpec`], made on first use and again when the spec changes, and one sample of its
//! per-bin sums.

use super::*;

impl DpdFluidPass {
    /// One sample of the velocity profile binned on the device (`super::dpd_profile`): per
    /// bin `Σ v_x` and the count of moving particles, with the instability word. Only the
    /// chunks' partial sums are read back (`⌈n/1024⌉ × bins` of each). The pass is made on the
    /// first call and again when `spec` changes.
    pub fn profile_sums(&mut self, spec: &ProfileSpec) -> Result<ProfileSums, GpuError> {
        dpd_profile::check(spec)?;
        if self.profile.as_ref().is_none_or(|p| p.spec != *spec) {
            self.profile = Some(self.make_profile(spec)?);
        }
        let pp = self.profile.as_ref().expect("made above");
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        {
            let mut cp = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("dpd profile"),
                timestamp_writes: None,
            });
            cp.set_pipeline(&pp.pipeline);
            cp.set_bind_group(0, &pp.bind_group, &[]);
            cp.dispatch_workgroups(pp.groups.0, pp.groups.1, 1);
        }
        self.gpu.queue.submit([encoder.finish()]);
        let (prec, bins) = (self.precision, spec.bins as usize);
        let used = pp.chunks * bins;
        let bufs = [&pp.sums, &pp.counts, &self.ctl];
        read_back(&self.gpu, &pp.staging, &bufs, |parts| {
            let sums: Vec<f64> = match prec {
                GpuPrecision::F64 => bytemuck::cast_slice::<u8, f64>(parts[0])[..used].to_vec(),
                GpuPrecision::F32 => bytemuck::cast_slice::<u8, f32>(parts[0])[..used]
                    .iter()
                    .map(|&x| x as f64)
                    .collect(),
            };
            let counts = &bytemuck::cast_slice::<u8, u32>(parts[1])[..used];
            let (sum_v, count) = dpd_profile::reduce(&sums, counts, bins);
            let ctl: &[u32] = bytemuck::cast_slice(parts[2]);
            ProfileSums {
                sum_v,
                count,
                unstable: (ctl[2] != 0).then_some(ctl[3]),
            }
        })
    }

    fn make_profile(&self, spec: &ProfileSpec) -> Result<ProfilePass, GpuError> {
        let gpu = &self.gpu;
        let prec = self.precision;
        let need = dpd_profile::workgroup_bytes(prec);
        if need > gpu.max_workgroup_bytes {
            return Err(GpuError::Unsupported(format!(
                "the profile pass needs {need} bytes of workgroup memory; {} offers {}",
                gpu.describe(),
                gpu.max_workgroup_bytes
            )));
        }
        let chunks = self.n.div_ceil(PROFILE_CHUNK as usize);
        let bins = spec.bins as usize;
        let real = match prec {
            GpuPrecision::F32 => 4usize,
            GpuPrecision::F64 => 8,
        };
        let sum_bytes = chunks
            .checked_mul(bins)
            .and_then(|c| c.checked_mul(real))
            .unwrap_or(usize::MAX);
        if sum_bytes as u64 > gpu.max_binding {
            return Err(GpuError::TooLarge {
                what: format!("the profile's partial sums ({chunks} chunks × {bins} bins)"),
                bytes: sum_bytes as u64,
                limit: gpu.max_binding,
            });
        }
        let (gx, gy) = split_groups(chunks, gpu.max_groups, || {
            format!("the profile of {} particles", self.n)
        })?;
        let dev = &gpu.device;
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC;
        let sums = gpu.buffer("dpd profile sums", sum_bytes, storage);
        let counts = gpu.buffer("dpd profile counts", chunks * bins * 4, storage);
        let ppar: [u32; dpd_profile::PPAR_LEN] = [
            self.n as u32,
            spec.bins,
            spec.radial_center.is_some() as u32,
            gx,
        ];
        let centre = spec.radial_center.unwrap_or([0.0; 2]);
        let preal = [spec.scale, centre[0], centre[1], 0.0];
        let preal_bytes = match prec {
            GpuPrecision::F64 => bytes(&preal).to_vec(),
            GpuPrecision::F32 => bytes(&preal.map(|c| c as f32)).to_vec(),
        };
        let ppar = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("dpd profile parameters"),
            contents: bytes(&ppar),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let preal = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("dpd profile reals"),
            contents: &preal_bytes,
            usage: wgpu::BufferUsages::STORAGE,
        });
        let staging = gpu.buffer(
            "dpd profile read-back",
            sums.size() as usize + counts.size() as usize + self.ctl.size() as usize,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        );
        let source = dpd_profile::source(prec);
        // SAFETY: particle indices are checked against `n` (`pos` and `vel` hold `n` entries);
        // the chunk index `g` is below `⌈n/1024⌉` (checked) and the bin below `bins`, so
        // `g · bins + b` is below the `chunks × bins` entries of `sums` and `counts`; the
        // workgroup arrays are indexed below 1024; `preal` holds 4 values, indexed up to 2.
        let pipeline = unsafe { gpu.trusted_pipeline("dpd profile", &source) };
        let bind_group = gpu.bind_group(
            "dpd profile",
            &pipeline,
            &[
                (0, &self.pos),
                (1, &self.vel),
                (2, &sums),
                (3, &counts),
                (4, &ppar),
                (5, &preal),
            ],
        );
        Ok(ProfilePass {
            spec: *spec,
            pipeline,
            bind_group,
            groups: (gx, gy),
            chunks,
            sums,
            counts,
            staging,
        })
    }
}

/// The profile pass for one [`ProfileSpec`], with its buffers.
pub(super) struct ProfilePass {
    spec: ProfileSpec,
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    groups: (u32, u32),
    chunks: usize,
    sums: wgpu::Buffer,
    counts: wgpu::Buffer,
    staging: wgpu::Buffer,
}

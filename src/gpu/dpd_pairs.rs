//! The DPD solvent's pair forces on the GPU for particles the host sorted by cell: the force
//! pass of [`super::dpd`] alone, fed every step from the host.
//!
//! [`super::dpd::DpdFluidPass`] keeps the whole fluid on the device. Cells in the fluid
//! (`crate::dpd::suspension`) need the solvent on the host at every step (bounce-back off the
//! moving membranes, the solvent–vertex pairs), so there the device computes only the solvent's
//! pair forces: the host uploads positions, velocities, ids and its cell list's starts (cells
//! numbered `x` fastest, as on the device), the pass sums each particle's pairs over its 27
//! neighbour cells with the same force and the same counter-based noise as the CPU's
//! `crate::dpd::pair_force::cell_forces`, and the forces with each particle's half of the
//! virial come back. No body force is added here: the host adds it, as after the CPU loops.
//!
//! One call moves about `2·4·R + 4` bytes per particle up and `4·R` down (`R` the bytes of a
//! real: 4 in `f32`, 8 in `f64`), plus 4 per cell.

use std::sync::Arc;

use rayon::prelude::*;
use wgpu::util::DeviceExt;

use super::dpd::{bytes, check_fluid, grid, parameters, read_back, DpdFluidSpec, FluidChecked};
use super::dpd_shader::{CTL_LEN, SCAN_BLOCK};
use super::{Gpu, GpuError, GpuPrecision};

/// The pair-force pass (see the module docs).
pub struct DpdPairPass {
    gpu: Arc<Gpu>,
    precision: GpuPrecision,
    n: usize,
    ncells: usize,
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    groups: (u32, u32),
    pos: wgpu::Buffer,
    vel: wgpu::Buffer,
    frc: wgpu::Buffer,
    ids: wgpu::Buffer,
    start: wgpu::Buffer,
    ctl: wgpu::Buffer,
    staging: wgpu::Buffer,
    /// Packing scratch (kept between calls): `vec4` in `f32` or `f64`, and the starts.
    pack32: Vec<f32>,
    pack64: Vec<f64>,
    starts32: Vec<u32>,
}

/// One call's particles, sorted by cell: positions inside the box, velocities, ids and the
/// cell list's starts (`ncells + 1` entries, the last the particle count).
pub struct SortedParticles<'a> {
    /// Positions `x`, `y`, `z`.
    pub x: [&'a [f64]; 3],
    /// Velocities.
    pub v: [&'a [f64]; 3],
    /// Permanent ids.
    pub id: &'a [u32],
    /// Cell `c` holds particles `starts[c]..starts[c + 1]`.
    pub starts: &'a [usize],
}

impl DpdPairPass {
    /// A pass for `n` particles of the fluid `spec` (its body force, wall and mass are not
    /// used).
    pub fn new(
        gpu: Arc<Gpu>,
        precision: GpuPrecision,
        spec: &DpdFluidSpec,
        n: usize,
    ) -> Result<Self, GpuError> {
        let FluidChecked {
            ncells,
            sources,
            vec4,
        } = check_fluid(&gpu, precision, spec, n)?;
        let source = sources
            .into_iter()
            .find(|(name, _)| *name == "forces")
            .map(|(_, s)| s)
            .expect("the fluid's passes include the force pass");
        let gn = grid(n, gpu.max_groups)?;
        let gc = grid(ncells, gpu.max_groups)?;
        let nblocks = ncells.div_ceil(SCAN_BLOCK as usize);
        let (ipar, rpar_bytes) = parameters(spec, precision, n, ncells, nblocks, gn, gc);
        let dev = &gpu.device;
        let storage = wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST;
        let pos = gpu.buffer("dpd pairs positions", vec4, storage);
        let vel = gpu.buffer("dpd pairs velocities", vec4, storage);
        let frc = gpu.buffer("dpd pairs forces", vec4, storage);
        let ids = gpu.buffer("dpd pairs ids", n * 4, storage);
        let start = gpu.buffer("dpd pairs cell starts", (ncells + 1) * 4, storage);
        let ctl = gpu.buffer("dpd pairs control", CTL_LEN * 4, storage);
        let ipar = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("dpd pairs integer parameters"),
            contents: bytes(&ipar),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let rpar = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("dpd pairs real parameters"),
            contents: &rpar_bytes,
            usage: wgpu::BufferUsages::STORAGE,
        });
        // SAFETY: the pass indexes particles below `n` (the grid covers at least `n` threads,
        // each checks `s < n`) and, through `start`, slots below `start[ncells] = n`; cell
        // coordinates are clamped to the grid, so `row + cx + 1 ≤ ncells`; `rpar` is read up
        // to 17 of `rpar::LEN`, `ctl` at 0 and 1 of `CTL_LEN`. [`Self::forces`] checks that
        // `start` is a non-decreasing list of `ncells + 1` offsets ending at `n` before it is
        // uploaded.
        let pipeline = unsafe { gpu.trusted_pipeline("dpd pairs", &source) };
        let bind_group = gpu.bind_group(
            "dpd pairs",
            &pipeline,
            &[
                (0, &pos),
                (1, &vel),
                (2, &frc),
                (3, &ids),
                (4, &start),
                (10, &ctl),
                (11, &ipar),
                (12, &rpar),
            ],
        );
        let staging = gpu.buffer(
            "dpd pairs read-back",
            vec4,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        );
        Ok(DpdPairPass {
            gpu,
            precision,
            n,
            ncells,
            pipeline,
            bind_group,
            groups: gn,
            pos,
            vel,
            frc,
            ids,
            start,
            ctl,
            staging,
            pack32: Vec::new(),
            pack64: Vec::new(),
            starts32: Vec::new(),
        })
    }

    /// Particles.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Whether there are none (never).
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// The precision of the pass.
    pub fn precision(&self) -> GpuPrecision {
        self.precision
    }

    /// The device.
    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// The pair forces of `p` with the noise of step `step`: `f` gets each particle's force,
    /// `virials` its half of the virial `Σ_j r_ij·F^C_ij / 2` (both in `p`'s order). Errors:
    /// arrays of the wrong length or a cell list that is not one.
    pub fn forces(
        &mut self,
        p: &SortedParticles<'_>,
        step: u64,
        f: [&mut [f64]; 3],
        virials: &mut [f64],
    ) -> Result<(), GpuError> {
        let n = self.n;
        let lens_ok = p.x.iter().chain(&p.v).all(|a| a.len() == n)
            && p.id.len() == n
            && f.iter().all(|a| a.len() == n)
            && virials.len() == n;
        if !lens_ok {
            return Err(GpuError::Shape(format!(
                "the pair pass holds {n} particles: positions, velocities, ids, forces and \
                 virials must have one entry each"
            )));
        }
        let s = p.starts;
        if s.len() != self.ncells + 1
            || s[0] != 0
            || s[self.ncells] != n
            || s.windows(2).any(|w| w[0] > w[1])
        {
            return Err(GpuError::Shape(format!(
                "a cell list of {} starts for {} cells and {n} particles: not non-decreasing \
                 from 0 to {n}",
                s.len(),
                self.ncells
            )));
        }
        let queue = &self.gpu.queue;
        for (buf, c) in [(&self.pos, p.x), (&self.vel, p.v)] {
            match self.precision {
                GpuPrecision::F32 => {
                    pack_soa(&mut self.pack32, c, |v| v as f32);
                    queue.write_buffer(buf, 0, bytes(&self.pack32));
                }
                GpuPrecision::F64 => {
                    pack_soa(&mut self.pack64, c, |v| v);
                    queue.write_buffer(buf, 0, bytes(&self.pack64));
                }
            }
        }
        queue.write_buffer(&self.ids, 0, bytes(p.id));
        self.starts32.clear();
        self.starts32.extend(s.iter().map(|&c| c as u32));
        queue.write_buffer(&self.start, 0, bytes(&self.starts32));
        let mut control = [0u32; CTL_LEN];
        control[..2].copy_from_slice(&[step as u32, (step >> 32) as u32]);
        queue.write_buffer(&self.ctl, 0, bytes(&control));
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        {
            let mut cp = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("dpd pairs"),
                timestamp_writes: None,
            });
            cp.set_pipeline(&self.pipeline);
            cp.set_bind_group(0, &self.bind_group, &[]);
            cp.dispatch_workgroups(self.groups.0, self.groups.1, 1);
        }
        queue.submit([encoder.finish()]);
        read_back(&self.gpu, &self.staging, &[&self.frc], |parts| {
            match self.precision {
                GpuPrecision::F64 => {
                    unpack_vec4::<f64>(bytemuck::cast_slice(&parts[0][..n * 32]), f, virials)
                }
                GpuPrecision::F32 => {
                    unpack_vec4::<f32>(bytemuck::cast_slice(&parts[0][..n * 16]), f, virials)
                }
            }
        })
    }
}

/// Particles per task of the packing loops.
const CHUNK: usize = 16384;

/// Interleave three coordinate arrays as `vec4` (the fourth component 0), converted by `to`.
fn pack_soa<T: Copy + Default + Send + Sync>(out: &mut Vec<T>, c: [&[f64]; 3], to: fn(f64) -> T) {
    let n = c[0].len();
    out.clear();
    out.resize(4 * n, T::default());
    out.par_chunks_mut(4 * CHUNK)
        .enumerate()
        .for_each(|(k, dst)| {
            for (m, q) in dst.chunks_exact_mut(4).enumerate() {
                let i = k * CHUNK + m;
                q[0] = to(c[0][i]);
                q[1] = to(c[1][i]);
                q[2] = to(c[2][i]);
            }
        });
}

/// Split `vec4`s into the three force components and the fourth (the virial share).
fn unpack_vec4<T: Copy + Into<f64> + Sync>(
    src: &[T],
    [fx, fy, fz]: [&mut [f64]; 3],
    virials: &mut [f64],
) {
    fx.par_chunks_mut(CHUNK)
        .zip(fy.par_chunks_mut(CHUNK))
        .zip(fz.par_chunks_mut(CHUNK))
        .zip(virials.par_chunks_mut(CHUNK))
        .zip(src.par_chunks(4 * CHUNK))
        .for_each(|((((fx, fy), fz), vir), src)| {
            for (i, q) in src.chunks_exact(4).enumerate() {
                (fx[i], fy[i], fz[i], vir[i]) =
                    (q[0].into(), q[1].into(), q[2].into(), q[3].into());
            }
        });
}

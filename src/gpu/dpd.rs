//! The DPD fluid's whole step on the GPU: particles resident on the device, cell lists rebuilt
//! there every step, many steps per submission.
//!
//! This is the GPU path of the DPD fluid of `crate::dpd::system` (periodic, or bounded by a
//! plane or cylinder wall of frozen particles, resting or sliding; cells stay on the CPU): the
//! same velocity-Verlet step, the same pair force
//! `F_ij = [a w − γ w_R² (v_ij·e) + σ w_R ξ_ij/√dt] e`, the same counter-based noise, the same
//! bounce-back off the wall. The passes
//! are listed in `dpd_shader`; between steps nothing moves to or from the host. The cell list is
//! a counting sort (atomic counts, a two-level scan, a scatter); each cell's slots are then
//! sorted by particle id, so the order of every sum is fixed and a run is reproducible bit for
//! bit on one device. Each particle sums its pairs over its 27 neighbour cells (every pair is
//! computed from both sides: no atomics; `F_ji = −F_ij` holds to rounding, since both sides see
//! the same noise and the same distance).
//!
//! **Precision.** `f64` (with `SHADER_F64`) computes what the CPU computes, in another order:
//! one force evaluation agrees with `crate::dpd::pair_force::cell_forces` to rounding. `f32` is
//! the precision of GPU DPD codes (Mirheo): positions in the box as plain `f32` (at `L = 64`, an
//! ulp of `4·10⁻⁶`), the noise from 24 random bits.

mod profile_pass;

use profile_pass::ProfilePass;

use std::sync::Arc;

use wgpu::util::DeviceExt;

use super::dpd_profile::{self, ProfileSpec, ProfileSums, PROFILE_CHUNK};
use super::dpd_shader::{
    self, rpar, CTL_LEN, IPAR_LEN, SCAN_BLOCK, WALL_CYLINDER, WALL_NONE, WALL_PLANES, WG,
};
use super::{Gpu, GpuError, GpuPrecision};

/// The fluid's parameters as the GPU pass takes them (`crate::dpd` fills them).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DpdFluidSpec {
    /// Box side lengths.
    pub box_len: [f64; 3],
    /// Cells per axis (each at least 3, sides at least `r_c`).
    pub dims: [u32; 3],
    /// Conservative amplitude `a`.
    pub a: f64,
    /// Dissipative coefficient `γ`.
    pub gamma: f64,
    /// Noise amplitude `σ = √(2γ k_BT)`.
    pub sigma: f64,
    /// Cut-off radius.
    pub rc: f64,
    /// Kernel exponent `k`.
    pub power: f64,
    /// Time step.
    pub dt: f64,
    /// Particle mass.
    pub mass: f64,
    /// `mix64(seed ^ C)`, the seed's half of `crate::dpd::rng::step_key`.
    pub key0: u64,
    /// Constant body force per particle.
    pub body: [f64; 3],
    /// Reverse-Poiseuille force magnitude along `x` (`+` below `L_z/2`, `−` above; 0: none).
    pub reverse_poiseuille: f64,
    /// The wall moving particles bounce back from (`crate::dpd::walls::Wall`).
    pub wall: Option<WallSpec>,
    /// Speed of sliding plane walls along `x` (`+` above the channel's middle; 0: resting).
    pub wall_speed: f64,
}

/// A wall as the GPU pass takes it (`crate::dpd::walls::Wall`; the fluid where the signed
/// distance is negative).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum WallSpec {
    /// Planes `z = lo` and `z = hi`.
    Planes {
        /// The lower plane.
        lo: f64,
        /// The upper plane.
        hi: f64,
    },
    /// A cylinder along `x`.
    Cylinder {
        /// Its radius.
        radius: f64,
        /// Its axis's `(y, z)`.
        center: [f64; 2],
    },
}

/// Particle state in cell order, as read back from the device.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DpdFluidState {
    /// Positions.
    pub x: Vec<[f64; 3]>,
    /// Velocities.
    pub v: Vec<[f64; 3]>,
    /// Forces of the last evaluation (pair and body).
    pub f: Vec<[f64; 3]>,
    /// Each particle's half of the virial `Σ_j r_ij·F^C_ij / 2`.
    pub virial: Vec<f64>,
    /// Permanent ids.
    pub id: Vec<u32>,
    /// 1 for moving particles, 0 for frozen wall particles.
    pub moves: Vec<f64>,
    /// Bounce-backs off the wall since the pass was made.
    pub bounces: u64,
    /// Moving particles found inside the wall after their bounce-back since the pass was made.
    pub leaked: u64,
    /// Steps done.
    pub step: u64,
    /// The smallest id of a particle that left the box by more than a box length or became
    /// non-finite since the pass was made (`None`: none did).
    pub unstable: Option<u32>,
}

struct Pass {
    name: &'static str,
    pipeline: wgpu::ComputePipeline,
    bind_group: wgpu::BindGroup,
    groups: (u32, u32),
}

/// The DPD fluid resident on the GPU.
pub struct DpdFluidPass {
    gpu: Arc<Gpu>,
    precision: GpuPrecision,
    n: usize,
    passes: Vec<Pass>,
    pos: wgpu::Buffer,
    vel: wgpu::Buffer,
    frc: wgpu::Buffer,
    ids: wgpu::Buffer,
    ctl: wgpu::Buffer,
    /// Read-back buffer for everything [`Self::read`] copies (reused by every read).
    staging: wgpu::Buffer,
    /// The profile pass of the last [`ProfileSpec`] asked for (made on first use).
    profile: Option<ProfilePass>,
}

/// The integer (`ipar`, a uniform block) and real (`rpar`, in the pass's precision) parameters
/// of the passes, for `n` particles in `ncells` cells (`nblocks` scan blocks) and the dispatch
/// grids `gn` (particles) and `gc` (cells).
pub(super) fn parameters(
    spec: &DpdFluidSpec,
    precision: GpuPrecision,
    n: usize,
    ncells: usize,
    nblocks: usize,
    gn: (u32, u32),
    gc: (u32, u32),
) -> ([u32; IPAR_LEN], Vec<u8>) {
    let mut ipar = [0u32; IPAR_LEN];
    ipar[..10].copy_from_slice(&[
        n as u32,
        ncells as u32,
        spec.dims[0],
        spec.dims[1],
        spec.dims[2],
        nblocks as u32,
        spec.key0 as u32,
        (spec.key0 >> 32) as u32,
        gn.0,
        gc.0,
    ]);
    ipar[10] = match spec.wall {
        None => WALL_NONE,
        Some(WallSpec::Planes { .. }) => WALL_PLANES,
        Some(WallSpec::Cylinder { .. }) => WALL_CYLINDER,
    };
    let mut r = [0.0f64; rpar::LEN];
    for k in 0..3 {
        // In f32 the box is the largest f32 not above L: positions the device wraps into
        // [0, L_f32) are then inside [0, L) on the host too (a resumed run continues bit for
        // bit, and the host never re-wraps them).
        r[rpar::BOX + k] = match precision {
            GpuPrecision::F64 => spec.box_len[k],
            GpuPrecision::F32 => f32_not_above(spec.box_len[k]) as f64,
        };
        r[rpar::INV_CELL + k] = spec.dims[k] as f64 / spec.box_len[k];
        r[rpar::BODY + k] = spec.body[k];
    }
    r[rpar::A] = spec.a;
    r[rpar::GAMMA] = spec.gamma;
    r[rpar::SIGMA] = spec.sigma;
    r[rpar::RC] = spec.rc;
    r[rpar::DT] = spec.dt;
    r[rpar::HALF_DT_OVER_M] = 0.5 * spec.dt / spec.mass;
    r[rpar::INV_SQRT_DT] = 1.0 / spec.dt.sqrt();
    r[rpar::REVERSE] = spec.reverse_poiseuille;
    r[rpar::HALF_LZ] = 0.5 * spec.box_len[2];
    let w = match spec.wall {
        None => [0.0; 3],
        Some(WallSpec::Planes { lo, hi }) => [lo, hi, 0.0],
        Some(WallSpec::Cylinder { radius, center }) => [radius, center[0], center[1]],
    };
    r[rpar::WALL..rpar::WALL + 3].copy_from_slice(&w);
    r[rpar::WALL_SPEED] = spec.wall_speed;
    let rpar_bytes = match precision {
        GpuPrecision::F64 => bytes(&r).to_vec(),
        GpuPrecision::F32 => bytes(&r.map(|c| c as f32)).to_vec(),
    };
    (ipar, rpar_bytes)
}

/// What [`check_fluid`] found: the cells, the passes' WGSL sources and the bytes of one
/// `vec4` array of the particles.
pub(super) struct FluidChecked {
    pub(super) ncells: usize,
    pub(super) sources: Vec<(&'static str, String)>,
    pub(super) vec4: usize,
}

/// The checks every DPD pass makes of a fluid of `n` particles on `gpu` before it builds
/// anything: `f64` shaders where asked for, the particle and cell counts within 2³¹, at least 3
/// cells per axis none narrower than `r_c`, a kernel exponent the precision's shaders take, and
/// the particles' and cells' arrays within a binding.
pub(super) fn check_fluid(
    gpu: &Gpu,
    precision: GpuPrecision,
    spec: &DpdFluidSpec,
    n: usize,
) -> Result<FluidChecked, GpuError> {
    if precision == GpuPrecision::F64 && !gpu.has_f64() {
        return Err(GpuError::NoF64(gpu.describe()));
    }
    if n == 0 || n >= (u32::MAX / 2) as usize {
        return Err(GpuError::Shape(format!("{n} particles (1 to 2³¹)")));
    }
    if spec.dims.iter().any(|&d| d < 3) {
        return Err(GpuError::Shape(format!(
            "cell grid {:?}: at least 3 cells per axis",
            spec.dims
        )));
    }
    for (k, &l) in spec.box_len.iter().enumerate() {
        if !(l.is_finite() && l / spec.dims[k] as f64 >= spec.rc) {
            return Err(GpuError::Shape(format!(
                "box length {l} on axis {k} with {} cells: the cells must be at least r_c = {} wide",
                spec.dims[k], spec.rc
            )));
        }
    }
    let ncells = spec.dims.iter().map(|&d| d as u64).product::<u64>();
    if ncells >= (u32::MAX / 2) as u64 {
        return Err(GpuError::Shape(format!("{ncells} cells (below 2³¹)")));
    }
    let ncells = ncells as usize;
    let Some(sources) = dpd_shader::sources(precision, spec.power) else {
        return Err(GpuError::Unsupported(format!(
            "kernel exponent k = {} in {}: the f64 shaders take k = 1, 1/2 and 1/4 only \
             (WGSL has no f64 pow); use f32",
            spec.power,
            precision.name()
        )));
    };
    let real = match precision {
        GpuPrecision::F32 => 4usize,
        GpuPrecision::F64 => 8,
    };
    let vec4 = n * 4 * real;
    too_large(
        format!("{n} particles' positions"),
        vec4 as u64,
        gpu.max_binding,
    )?;
    too_large(
        format!("{ncells} cells' starts"),
        (ncells as u64 + 1) * 4,
        gpu.max_binding,
    )?;
    Ok(FluidChecked {
        ncells,
        sources,
        vec4,
    })
}

/// [`GpuError::TooLarge`] for `what` of `bytes` above `limit`.
fn too_large(what: String, bytes: u64, limit: u64) -> Result<(), GpuError> {
    if bytes > limit {
        return Err(GpuError::TooLarge { what, bytes, limit });
    }
    Ok(())
}

/// Copy `bufs` into `staging` one after the other, map them and hand their bytes to `decode`.
pub(super) fn read_back<T>(
    gpu: &Gpu,
    staging: &wgpu::Buffer,
    bufs: &[&wgpu::Buffer],
    decode: impl FnOnce(&[&[u8]]) -> T,
) -> Result<T, GpuError> {
    let sizes: Vec<u64> = bufs.iter().map(|b| b.size()).collect();
    let total: u64 = sizes.iter().sum();
    let mut encoder = gpu.device.create_command_encoder(&Default::default());
    let mut at = 0;
    for (b, &s) in bufs.iter().zip(&sizes) {
        encoder.copy_buffer_to_buffer(b, 0, staging, at, s);
        at += s;
    }
    gpu.queue.submit([encoder.finish()]);
    let slice = staging.slice(..total);
    gpu.map_read(&slice)?;
    let out = {
        let view = slice
            .get_mapped_range()
            .map_err(|e| GpuError::Execution(e.to_string()))?;
        let mut parts = Vec::new();
        let mut at = 0usize;
        for &s in &sizes {
            parts.push(&view[at..at + s as usize]);
            at += s as usize;
        }
        decode(&parts)
    };
    staging.unmap();
    Ok(out)
}

/// Steps per command buffer (one submission).
pub const STEPS_PER_SUBMIT: u64 = 50;

pub(super) fn bytes<T: bytemuck::Pod>(v: &[T]) -> &[u8] {
    bytemuck::cast_slice(v)
}

fn pack4(p: &[[f64; 3]], w: Option<&[f64]>, prec: GpuPrecision) -> Vec<u8> {
    let wv = |i: usize| w.map_or(0.0, |w| w[i]);
    match prec {
        GpuPrecision::F64 => {
            let v: Vec<f64> = p
                .iter()
                .enumerate()
                .flat_map(|(i, x)| [x[0], x[1], x[2], wv(i)])
                .collect();
            bytes(&v).to_vec()
        }
        GpuPrecision::F32 => {
            let v: Vec<f32> = p
                .iter()
                .enumerate()
                .flat_map(|(i, x)| [x[0] as f32, x[1] as f32, x[2] as f32, wv(i) as f32])
                .collect();
            bytes(&v).to_vec()
        }
    }
}

fn unpack4(b: &[u8], prec: GpuPrecision) -> (Vec<[f64; 3]>, Vec<f64>) {
    let v: Vec<f64> = match prec {
        GpuPrecision::F64 => bytemuck::cast_slice::<u8, f64>(b).to_vec(),
        GpuPrecision::F32 => bytemuck::cast_slice::<u8, f32>(b)
            .iter()
            .map(|&c| c as f64)
            .collect(),
    };
    v.chunks_exact(4)
        .map(|c| ([c[0], c[1], c[2]], c[3]))
        .unzip()
}

/// The largest `f32` not above `x` (positive `x`).
fn f32_not_above(x: f64) -> f32 {
    let f = x as f32;
    if f as f64 > x {
        f.next_down()
    } else {
        f
    }
}

/// Split `items` threads of `WG` into a 2-D grid within the device's per-dimension limit.
pub(super) fn grid(items: usize, max_groups: u32) -> Result<(u32, u32), GpuError> {
    split_groups(items.div_ceil(WG as usize), max_groups, || {
        format!("{items} threads")
    })
}

/// Split `groups` workgroups (at least one) into a 2-D grid within the device's per-dimension
/// limit; `what` names the work in the error.
fn split_groups(
    groups: usize,
    max_groups: u32,
    what: impl FnOnce() -> String,
) -> Result<(u32, u32), GpuError> {
    let groups = groups.max(1);
    let gx = groups.min(max_groups as usize);
    let gy = groups.div_ceil(gx);
    if gy > max_groups as usize {
        return Err(GpuError::TooManyGroups {
            what: what(),
            limit: max_groups,
        });
    }
    Ok((gx as u32, gy as u32))
}

impl DpdFluidPass {
    /// Upload a fluid: positions inside the box, velocities, the forces of the current
    /// positions (the first half kick uses them), ids below 2³², whether each particle moves
    /// (1) or is a frozen wall particle (0), and the steps done.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        gpu: Arc<Gpu>,
        precision: GpuPrecision,
        spec: &DpdFluidSpec,
        x: &[[f64; 3]],
        v: &[[f64; 3]],
        f: &[[f64; 3]],
        id: &[u32],
        moves: &[f64],
        step: u64,
    ) -> Result<Self, GpuError> {
        let n = x.len();
        let FluidChecked {
            ncells,
            sources,
            vec4,
        } = check_fluid(&gpu, precision, spec, n)?;
        if v.len() != n || f.len() != n || id.len() != n || moves.len() != n {
            return Err(GpuError::Shape(
                "positions, velocities, forces, ids and moves must have one entry per particle"
                    .into(),
            ));
        }
        if moves.iter().any(|&m| m != 0.0 && m != 1.0) {
            return Err(GpuError::Shape("moves must be 0 or 1".into()));
        }
        if let Some(bad) = x
            .iter()
            .position(|p| (0..3).any(|k| !(p[k] >= 0.0 && p[k] < spec.box_len[k])))
        {
            return Err(GpuError::Shape(format!(
                "particle {bad} at {:?} is outside the box",
                x[bad]
            )));
        }
        // The read-back buffer holds positions, velocities, forces, ids and the control words.
        too_large(
            "the read-back buffer".into(),
            (3 * vec4 + 4 * n + 4 * CTL_LEN) as u64,
            gpu.max_buffer,
        )?;
        let nblocks = ncells.div_ceil(SCAN_BLOCK as usize);
        if nblocks > gpu.max_groups as usize {
            return Err(GpuError::TooManyGroups {
                what: format!("the scan of {ncells} cells"),
                limit: gpu.max_groups,
            });
        }
        let gn = grid(n, gpu.max_groups)?;
        let gc = grid(ncells, gpu.max_groups)?;

        let dev = &gpu.device;
        let storage = wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST;
        let init = |label: &str, contents: &[u8]| {
            dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage: storage,
            })
        };
        let zeroed = |label: &str, size: usize| gpu.buffer(label, size, storage);
        let pos = init("dpd positions", &pack4(x, Some(moves), precision));
        let vel = init("dpd velocities", &pack4(v, None, precision));
        let frc = init("dpd forces", &pack4(f, None, precision));
        let ids = init("dpd ids", bytes(id));
        let pos2 = zeroed("dpd positions (drifted)", vec4);
        let vel2 = zeroed("dpd velocities (drifted)", vec4);
        let ids2 = zeroed("dpd ids (drifted)", n * 4);
        let cell = zeroed("dpd cell of particle", n * 4);
        let arrival = zeroed("dpd arrival in cell", n * 4);
        let order = zeroed("dpd order", n * 4);
        let count = zeroed("dpd cell counts", ncells * 4);
        let start = zeroed("dpd cell starts", (ncells + 1) * 4);
        let blocks = zeroed("dpd scan blocks", nblocks * 4);
        let mut control = [0u32; CTL_LEN];
        control[..4].copy_from_slice(&[step as u32, (step >> 32) as u32, 0, u32::MAX]);
        let ctl = init("dpd control", bytes(&control));
        let (ipar, rpar_bytes) = parameters(spec, precision, n, ncells, nblocks, gn, gc);
        let ipar = dev.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("dpd integer parameters"),
            contents: bytes(&ipar),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let rparb = init("dpd real parameters", &rpar_bytes);

        // Each pass's bindings (the pipeline's layout is derived from its shader, so each bind
        // group names exactly the bindings that pass declares).
        let bindings = |name: &str| -> Vec<(u32, &wgpu::Buffer)> {
            match name {
                "drift" => vec![
                    (0, &pos),
                    (1, &vel),
                    (2, &frc),
                    (3, &ids),
                    (4, &pos2),
                    (5, &vel2),
                    (6, &ids2),
                    (7, &cell),
                    (8, &arrival),
                    (9, &count),
                    (10, &ctl),
                    (11, &ipar),
                    (12, &rparb),
                ],
                "scan_local" => vec![(0, &count), (1, &start), (2, &blocks), (11, &ipar)],
                "scan_blocks" => vec![(0, &blocks), (1, &start), (2, &ctl), (11, &ipar)],
                "scan_add" => vec![(0, &start), (1, &blocks), (11, &ipar)],
                "scatter" => vec![
                    (0, &start),
                    (1, &cell),
                    (2, &arrival),
                    (3, &order),
                    (11, &ipar),
                ],
                "sort_cells" => vec![(0, &start), (1, &ids2), (2, &order), (11, &ipar)],
                "gather" => vec![
                    (0, &pos),
                    (1, &vel),
                    (3, &ids),
                    (4, &pos2),
                    (5, &vel2),
                    (6, &ids2),
                    (7, &order),
                    (11, &ipar),
                ],
                "forces" => vec![
                    (0, &pos),
                    (1, &vel),
                    (2, &frc),
                    (3, &ids),
                    (4, &start),
                    (10, &ctl),
                    (11, &ipar),
                    (12, &rparb),
                ],
                "kick" => vec![(0, &pos), (1, &vel), (2, &frc), (11, &ipar), (12, &rparb)],
                _ => unreachable!("a pass without bindings"),
            }
        };
        let mut passes = Vec::new();
        for (name, source) in &sources {
            // SAFETY: every index the passes form is in bounds: particle and cell indices are
            // checked against `n` and `ncells` (the dispatch grids cover at least that many
            // threads); cell coordinates are clamped to the grid; `start` has `ncells + 1`
            // entries, its values are prefix sums of the counts (at most `n`), and
            // `start[c] + arrival` is below `start[c + 1]` because the arrivals of cell `c`
            // are `0..count[c]`; `blocks` has one entry per 1024 cells (`c / 1024 < nblocks`);
            // the fixed indices are below the buffers' lengths: `rpar` up to 21 of `rpar::LEN`
            // = 22, `ctl` up to 7 of `CTL_LEN` = 8 (pinned by a const assert in `dpd_shader`).
            let pipeline = unsafe { gpu.trusted_pipeline(&format!("dpd {name}"), source) };
            let bind_group = gpu.bind_group(name, &pipeline, &bindings(name));
            let groups = match *name {
                "scan_local" => (nblocks as u32, 1),
                "scan_blocks" => (1, 1),
                "scan_add" | "sort_cells" => gc,
                _ => gn,
            };
            passes.push(Pass {
                name,
                pipeline,
                bind_group,
                groups,
            });
        }
        let staging = dev.create_buffer(&wgpu::BufferDescriptor {
            label: Some("dpd read-back"),
            size: [&pos, &vel, &frc, &ids, &ctl]
                .iter()
                .map(|b| b.size())
                .sum(),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(DpdFluidPass {
            staging,
            gpu,
            precision,
            n,
            passes,
            pos,
            vel,
            frc,
            ids,
            ctl,
            profile: None,
        })
    }

    /// Particles.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Whether there are none (never: a pass holds at least one particle).
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// The precision of the passes.
    pub fn precision(&self) -> GpuPrecision {
        self.precision
    }

    /// The device.
    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// Queue and run `steps` velocity-Verlet steps, and wait for them. Steps go in batches of
    /// [`STEPS_PER_SUBMIT`], at most two batches in flight: the next is encoded while the
    /// device runs the last.
    pub fn advance(&mut self, steps: u64) -> Result<(), GpuError> {
        self.run(steps, |_| true)
    }

    /// The force pass alone, `reps` times over the current state, for timing the pass against
    /// the whole step. Positions and velocities stay; the forces are overwritten with those of
    /// the current (end-of-step) velocities, so a pass timed this way is not stepped further.
    pub fn forces_only(&mut self, reps: u64) -> Result<(), GpuError> {
        self.run(reps, |name| name == "forces")
    }

    fn run(&self, steps: u64, take: impl Fn(&str) -> bool) -> Result<(), GpuError> {
        let (dev, queue) = (&self.gpu.device, &self.gpu.queue);
        let mut left = steps;
        let mut previous = None;
        while left > 0 {
            let batch = left.min(STEPS_PER_SUBMIT);
            let mut encoder = dev.create_command_encoder(&Default::default());
            {
                let mut cp = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("dpd steps"),
                    timestamp_writes: None,
                });
                for _ in 0..batch {
                    for p in self.passes.iter().filter(|p| take(p.name)) {
                        cp.set_pipeline(&p.pipeline);
                        cp.set_bind_group(0, &p.bind_group, &[]);
                        cp.dispatch_workgroups(p.groups.0, p.groups.1, 1);
                    }
                }
            }
            let index = queue.submit([encoder.finish()]);
            left -= batch;
            if let Some(prev) = previous.replace(index) {
                dev.poll(wgpu::PollType::Wait {
                    submission_index: Some(prev),
                    timeout: None,
                })
                .map_err(|e| GpuError::Execution(e.to_string()))?;
            }
        }
        self.gpu.wait()
    }

    /// Read the state back (positions, velocities, forces, ids in the device's cell order).
    pub fn read(&self) -> Result<DpdFluidState, GpuError> {
        let (prec, n) = (self.precision, self.n);
        let bufs = [&self.pos, &self.vel, &self.frc, &self.ids, &self.ctl];
        read_back(&self.gpu, &self.staging, &bufs, |parts| {
            let (x, moves) = unpack4(parts[0], prec);
            let (v, _) = unpack4(parts[1], prec);
            let (f, virial) = unpack4(parts[2], prec);
            let id: Vec<u32> = bytemuck::cast_slice::<u8, u32>(parts[3])[..n].to_vec();
            let ctl: &[u32] = bytemuck::cast_slice(parts[4]);
            DpdFluidState {
                x,
                v,
                f,
                virial,
                id,
                moves,
                bounces: ctl[4] as u64 | ((ctl[5] as u64) << 32),
                leaked: ctl[6] as u64 | ((ctl[7] as u64) << 32),
                step: ctl[0] as u64 | ((ctl[1] as u64) << 32),
                unstable: (ctl[2] != 0).then_some(ctl[3]),
            }
        })
    }
}

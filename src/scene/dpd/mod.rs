//! The `[dpd]` scene section of `mobo dpd`.
//!
//! ```toml
//! [dpd]
//! box = [10.0, 10.0, 20.0]   # periodic box (a number: a cube)
//! density = 3.0              # number density n
//! a = 25.0                   # conservative amplitude
//! gamma = 4.5                # dissipative coefficient γ
//! kbt = 1.0                  # thermal energy (σ² = 2γk_BT)
//! rc = 1.0                   # cut-off radius (default 1)
//! power = 1.0                # kernel exponent k: w_D = w^(2k) (default 1)
//! dt = 0.01
//! steps = 10000              # or t_end = 100.0
//! seed = 1
//! mass = 1.0                 # particle mass (default 1)
//! flow = "periodic_poiseuille"   # "none" (default) | "periodic_poiseuille"
//! force = 0.1                # body force per particle: +x for z < L_z/2, −x above
//! equilibrate = 1000         # steps before the profile is averaged (default: a fifth)
//! sample_every = 10          # steps between profile samples (default 10)
//! blocks = 10                # blocks for the standard error (default 10)
//! bins = 20                  # profile bins along z (default 20, rounded up to even)
//! save_every = 1000          # steps between observables rows and checkpoints (default 1000)
//! gpu = "auto"               # the fluid's step on a GPU: "auto" | true | false (feature gpu)
//! gpu_precision = "f32"      # "f32" (default, as GPU DPD codes) | "f64" (k = 1, 1/2, 1/4 only)
//! ```
//!
//! The GPU steps the fluid, walls included (`crate::dpd::gpu_fluid`), and warms up the walls'
//! fluid before they freeze. With cells in the fluid it computes the solvent's pair forces
//! only (`crate::dpd::gpu_pairs`); the membranes, the bounce-back off them and the
//! solvent–vertex pairs stay on the CPU. `auto` takes a hardware GPU for at least
//! `AUTO_MIN_PARTICLES` (in `run::dpd`) particles, `true` any adapter, and fails where
//! there is none.
//!
//! Walls (frozen particles and bounce-back, [`crate::dpd::walls`]):
//!
//! ```toml
//! walls = { kind = "planes", gap = 10.0 }    # a channel along x, y; box z ≥ gap + 2 rc
//! walls = { kind = "cylinder", radius = 5.0 }  # a pipe along x; box y, z ≥ 2 (radius + rc)
//! wall_warmup = 300          # steps the periodic fluid is equilibrated before freezing walls
//! flow = "poiseuille"        # with walls: the body force `force` along x everywhere
//! flow = "couette"           # with planes: the walls slide along x at ±wall_speed
//! wall_speed = 0.5           # (shear rate ≈ 2 wall_speed / gap; the fluid starts linear)
//! ```
//!
//! Cells in the fluid ([`crate::dpd::suspension`]): membranes on the icosphere of a
//! spherical-harmonic shape, with the Fedosov (2010) parameters from physical moduli, coupled
//! to the solvent by dissipative pairs and bounce-back:
//!
//! ```toml
//! [[dpd.cells]]
//! shape = "rbc"              # "sphere" | "rbc" (biconcave, axis z) | "prolate" | "oblate"
//! radius = 3.0               # volume-equivalent radius (3V/4π)^(1/3)
//! reduced_volume = 0.9       # prolate/oblate only
//! center = [8.0, 8.0, 8.0]
//! subdivisions = 3           # icosphere level: 10·4^s + 2 vertices (s = 3: 642)
//! shear_modulus = 100.0      # μ0 (k_BT/r_c² units of the scene)
//! bending_rigidity = 20.0    # κ
//! bending = "juelicher"      # or "kantor_nelson"; spontaneous c0 (default 0) or theta0
//! ka = 4900.0                # global area (default 4900), kd local area (100), kv volume (5000)
//! gamma_t = 20.0             # membrane viscosity (γ_C = γ_T/3 unless gamma_c is given)
//! force = [5.0, 0.0, 0.0]    # external pull on the cell, balanced on the outer solvent
//!
//! [dpd.coupling]             # all optional
//! gamma_out = 15.0           # solvent–vertex dissipation outside
//! gamma_in = 15.0            # and inside the cell
//! power = 0.25               # their kernel exponent
//! inner_gamma = 0.0          # extra dissipation among inner solvent (a more viscous cytoplasm)
//! contact_a = 25.0           # repulsion between vertices of different cells
//! vertex_mass = 1.0
//! check_every = 100          # steps between leak counts
//! ```
//!
//! **One scene, both solvers.** The same file may hold a cell scene (`[[cells]]`, `[fluid]`,
//! `[flow]`, `[numerics]`, `[output]`: the input of `mobo run`, [`super::cells`]) beside
//! `[dpd]`: `mobo run` ignores `[dpd]`, and `mobo dpd` reads the `[[cells]]` entries, placed
//! and checked as `mobo run` does (count, lattice or random placement, orientation, every
//! shape), and puts them into the fluid by the map of `[dpd.from_cells]` ([`CellMapping`]):
//!
//! ```toml
//! [dpd.from_cells]
//! length = 3.0               # r_c per length unit of the cell scene (R = 1 → 3 r_c)
//! energy = 500.0             # k_BT per energy unit: μ0 = G_s·energy/length², κ = κ_b·energy
//! origin = [12.0, 8.0, 10.0] # where the cell scene's origin sits (default: the box's centre)
//! rotate = [1, 0, 0, 90]     # turn the cell scene's frame (axis, degrees): its shear plane
//!                            # x–y (u = γ̇y) onto the fluid's x–z (Couette walls along z)
//! subdivisions = 3           # and ka, kd, kv, gamma_t, gamma_c as in [[dpd.cells]]
//! ```
//!
//! Vesicles and RBCs (locally inextensible there) keep Fedosov's area penalties; a capsule's
//! area modulus (`G_s (1 + 2C)` for Skalak, `3 G_s` neo-Hookean) becomes the network's
//! `2μ0 + k_a + k_d`. The cell scene's flow and numerics are not mapped: the fluid's flow is
//! `[dpd]`'s own, so matching the capillary number `Ca = η γ̇ R / μ0` is the user's choice of
//! `energy`, the walls' speed and the fluid's viscosity (`docs/dpd_vs_bie.md`). Without
//! `[dpd.from_cells]`, `mobo dpd` refuses a file with `[[cells]]` rather than leave them out.

use std::path::Path;

use serde::de::IgnoredAny;
use serde::Deserialize;

use super::cells::{CellSpec as SceneCell, Shape};
use super::{parse_toml, read_scene_file, GpuFlag, SceneError};
use crate::dpd::membrane::{BendingModel, MembraneParams, Moduli};
use crate::dpd::pair_force::PairParams;
use crate::dpd::suspension::{CellSpec, CouplingParams};
use crate::dpd::system::{BodyForce, DpdParams};
use crate::dpd::walls::Wall;
use crate::gpu::{GpuChoice, GpuPrecision};
use crate::vesicle::skalak::ElasticLaw;
use crate::vesicle::{shapes, CellMesh, Surface};

mod membranes;

use membranes::{cell, coupling_params, mapped_cells};

/// The most profile bins a scene may ask for (`[dpd] bins`): the sampler keeps four arrays of
/// this length (32 MB at the bound), far finer than any box resolves.
pub const MAX_BINS: usize = 1_000_000;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    dpd: DpdSection,
    /// The cell scene's sections (`mobo run`'s): `[[cells]]` enters the DPD run through
    /// `[dpd.from_cells]`; the others are `mobo run`'s alone.
    cells: Option<IgnoredAny>,
    #[serde(rename = "fluid")]
    _fluid: Option<IgnoredAny>,
    #[serde(rename = "flow")]
    _flow: Option<IgnoredAny>,
    #[serde(rename = "numerics")]
    _numerics: Option<IgnoredAny>,
    #[serde(rename = "output")]
    _output: Option<IgnoredAny>,
}

/// A number (a cube) or three side lengths.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum BoxLen {
    Cube(f64),
    Sides([f64; 3]),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct DpdSection {
    #[serde(rename = "box")]
    box_len: BoxLen,
    density: f64,
    a: f64,
    gamma: f64,
    kbt: f64,
    #[serde(default = "one")]
    rc: f64,
    #[serde(default = "one")]
    power: f64,
    dt: f64,
    steps: Option<u64>,
    t_end: Option<f64>,
    #[serde(default)]
    seed: u64,
    #[serde(default = "one")]
    mass: f64,
    #[serde(default = "default_flow")]
    flow: String,
    force: Option<f64>,
    equilibrate: Option<u64>,
    #[serde(default = "ten")]
    sample_every: u64,
    #[serde(default = "ten")]
    blocks: u64,
    #[serde(default = "twenty")]
    bins: usize,
    #[serde(default = "thousand")]
    save_every: u64,
    walls: Option<WallsSection>,
    #[serde(default = "three_hundred")]
    wall_warmup: u64,
    wall_speed: Option<f64>,
    #[serde(default)]
    cells: Vec<CellSection>,
    coupling: Option<CouplingSection>,
    from_cells: Option<FromCellsSection>,
    gpu: Option<GpuFlag>,
    gpu_precision: Option<String>,
}

/// `[dpd.from_cells]`: the scene's `[[cells]]` (the cell scene of `mobo run`) in the fluid.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FromCellsSection {
    length: f64,
    energy: f64,
    origin: Option<[f64; 3]>,
    rotate: Option<[f64; 4]>,
    #[serde(default = "three_u32")]
    subdivisions: u32,
    ka: Option<f64>,
    kd: Option<f64>,
    kv: Option<f64>,
    gamma_t: Option<f64>,
    gamma_c: Option<f64>,
}

/// One `[[dpd.cells]]` entry.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CellSection {
    shape: String,
    radius: f64,
    reduced_volume: Option<f64>,
    center: [f64; 3],
    #[serde(default = "three_u32")]
    subdivisions: u32,
    shear_modulus: f64,
    bending_rigidity: f64,
    #[serde(default = "juelicher")]
    bending: String,
    c0: Option<f64>,
    theta0: Option<f64>,
    ka: Option<f64>,
    kd: Option<f64>,
    kv: Option<f64>,
    gamma_t: Option<f64>,
    gamma_c: Option<f64>,
    force: Option<[f64; 3]>,
}

/// `[dpd.coupling]`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CouplingSection {
    gamma_out: Option<f64>,
    gamma_in: Option<f64>,
    power: Option<f64>,
    inner_gamma: Option<f64>,
    contact_a: Option<f64>,
    vertex_mass: Option<f64>,
    check_every: Option<u64>,
}

fn three_u32() -> u32 {
    3
}
fn juelicher() -> String {
    "juelicher".into()
}

/// A cell of a DPD scene: its mesh and membrane, and the external force on it.
#[derive(Clone, Debug)]
pub struct DpdCell {
    /// Shape name as given.
    pub shape: String,
    /// Volume-equivalent radius `(3V/4π)^{1/3}`.
    pub radius: f64,
    /// The mesh and membrane parameters.
    pub spec: CellSpec,
    /// External force on the cell.
    pub force: [f64; 3],
}

/// The map from the cell scene's units to the fluid's (`[dpd.from_cells]`): a point `x` of
/// the cell scene goes to `origin + length · R x` (`R` the rotation `rotate`, the identity by
/// default), a shear modulus `G_s` to
/// `μ0 = G_s · energy / length²`, a bending modulus `κ_b` to `κ = κ_b · energy`, a force `F` to
/// `F · energy / length`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct CellMapping {
    /// Fluid lengths (r_c) per length unit of the cell scene.
    pub length: f64,
    /// Fluid energies (k_BT) per energy unit of the cell scene.
    pub energy: f64,
    /// Where the cell scene's origin sits in the box.
    pub origin: [f64; 3],
    /// The rotation `R` of the cell scene's frame (rows).
    pub rotation: [[f64; 3]; 3],
    /// Cells mapped.
    pub cells: usize,
}

/// `walls = { kind = "planes", gap = 10.0 }` or `{ kind = "cylinder", radius = 5.0 }`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct WallsSection {
    kind: String,
    gap: Option<f64>,
    radius: Option<f64>,
}

fn three_hundred() -> u64 {
    300
}

fn one() -> f64 {
    1.0
}
fn ten() -> u64 {
    10
}
fn twenty() -> usize {
    20
}
fn thousand() -> u64 {
    1000
}
fn default_flow() -> String {
    "none".into()
}

/// A validated DPD scene.
#[derive(Clone, Debug)]
pub struct DpdScene {
    /// Fluid parameters.
    pub params: DpdParams,
    /// Number density.
    pub density: f64,
    /// Body force.
    pub body: BodyForce,
    /// Steps to run.
    pub steps: u64,
    /// Steps discarded before profile averaging.
    pub equilibrate: u64,
    /// Steps between profile samples.
    pub sample_every: u64,
    /// Blocks of the block average.
    pub blocks: u64,
    /// Profile bins along `z`.
    pub bins: usize,
    /// Steps between observables rows and checkpoints.
    pub save_every: u64,
    /// Walls, if any.
    pub wall: Option<Wall>,
    /// Steps the periodic fluid is equilibrated before the wall particles are frozen.
    pub wall_warmup: u64,
    /// Speed of the sliding plane walls (`flow = "couette"`; 0 otherwise).
    pub wall_speed: f64,
    /// Cells in the fluid (`[[dpd.cells]]`, then the scene's `[[cells]]` mapped by
    /// `[dpd.from_cells]`).
    pub cells: Vec<DpdCell>,
    /// How the scene's `[[cells]]` were mapped (`None`: no `[dpd.from_cells]`).
    pub from_cells: Option<CellMapping>,
    /// Their coupling to the solvent (`[dpd.coupling]`).
    pub coupling: CouplingParams,
    /// The fluid's step on a GPU (`gpu`, default `"auto"`).
    pub gpu: GpuChoice,
    /// The GPU's precision (`gpu_precision`, default `f32`).
    pub gpu_precision: GpuPrecision,
}

impl DpdScene {
    /// Samples per block of the viscosity average (0: too short a run to average).
    pub fn block_samples(&self) -> u64 {
        let samples = self.steps.saturating_sub(self.equilibrate) / self.sample_every;
        samples / self.blocks
    }
}

/// Read and validate a DPD scene file.
pub fn load(file: &Path) -> Result<DpdScene, SceneError> {
    let text = read_scene_file(file)?;
    parse(file, &text)
}

/// Validate scene text (`file` is used in messages).
pub fn parse(file: &Path, text: &str) -> Result<DpdScene, SceneError> {
    let f: File = parse_toml(file, text)?;
    let d = f.dpd;
    let bad = |key: &str, why: String| SceneError::new(file, format!("[dpd] {key}: {why}"));
    let place = |key: &str| key_place(text, key);
    let located = |key: &str, why: String| {
        let mut e = bad(key, why);
        e.place = place(key);
        e
    };
    let box_len = match d.box_len {
        BoxLen::Cube(l) => [l; 3],
        BoxLen::Sides(s) => s,
    };
    check_positive(
        &located,
        &[
            ("density", d.density),
            ("dt", d.dt),
            ("rc", d.rc),
            ("mass", d.mass),
            ("power", d.power),
        ],
    )?;
    check_nonnegative(
        &located,
        &[
            ("a", Some(d.a)),
            ("gamma", Some(d.gamma)),
            ("kbt", Some(d.kbt)),
        ],
    )?;
    for (k, l) in box_len.iter().enumerate() {
        if !(l.is_finite() && *l >= 3.0 * d.rc) {
            return Err(located(
                "box",
                format!(
                    "side {} is {l}: each side must be at least 3 rc = {} (the cell list needs 3 cells per axis)",
                    ["x", "y", "z"][k],
                    3.0 * d.rc
                ),
            ));
        }
    }
    let wall = match &d.walls {
        None => None,
        Some(w) => {
            let need = |v: Option<f64>, key: &str| {
                v.ok_or_else(|| located("walls", format!("kind = \"{}\" needs {key}", w.kind)))
            };
            let built = match w.kind.as_str() {
                "planes" => {
                    if w.radius.is_some() {
                        return Err(located("walls", "planes take gap, not radius".into()));
                    }
                    Wall::channel(need(w.gap, "gap")?, box_len[2], d.rc)
                }
                "cylinder" => {
                    if w.gap.is_some() {
                        return Err(located("walls", "a cylinder takes radius, not gap".into()));
                    }
                    Wall::pipe(need(w.radius, "radius")?, box_len[1], box_len[2], d.rc)
                }
                other => {
                    return Err(located(
                        "walls",
                        format!("unknown kind \"{other}\" (expected \"planes\" or \"cylinder\")"),
                    ))
                }
            };
            Some(built.map_err(|e| located("walls", e.to_string()))?)
        }
    };
    let n = d.density * box_len.iter().product::<f64>();
    if !(2.0..4.0e9).contains(&n) {
        return Err(located(
            "density",
            format!("density × box volume = {n:.3e} particles; need between 2 and 4·10⁹"),
        ));
    }
    let steps = match (d.steps, d.t_end) {
        (Some(_), Some(_)) => {
            return Err(located(
                "t_end",
                "give either steps or t_end, not both".into(),
            ))
        }
        (Some(s), None) => s,
        (None, Some(t)) if t.is_finite() && t > 0.0 => (t / d.dt).round() as u64,
        (None, Some(t)) => return Err(located("t_end", format!("must be positive, got {t}"))),
        (None, None) => return Err(bad("steps", "give steps or t_end".into())),
    };
    if steps == 0 {
        return Err(located("steps", "must be at least 1".into()));
    }
    for (key, v) in [
        ("sample_every", d.sample_every),
        ("blocks", d.blocks),
        ("save_every", d.save_every),
    ] {
        if v == 0 {
            return Err(located(key, "must be at least 1".into()));
        }
    }
    if !(2..=MAX_BINS).contains(&d.bins) {
        return Err(located(
            "bins",
            format!("must be between 2 and {MAX_BINS}, got {}", d.bins),
        ));
    }
    let body = match d.flow.as_str() {
        "none" => {
            if d.force.is_some() {
                return Err(located(
                    "force",
                    "given but flow = \"none\" (set flow = \"periodic_poiseuille\")".into(),
                ));
            }
            BodyForce::None
        }
        "periodic_poiseuille" if wall.is_some() => {
            return Err(located(
                "flow",
                "periodic_poiseuille needs a periodic box; with walls use flow = \"poiseuille\"".into(),
            ))
        }
        "poiseuille" if wall.is_none() => {
            return Err(located(
                "flow",
                "poiseuille is driven between walls; give walls, or use \"periodic_poiseuille\"".into(),
            ))
        }
        "periodic_poiseuille" | "poiseuille" if d.bins < 12 => {
            return Err(located(
                "bins",
                format!(
                    "{} bins are too few for the viscosity fit (it uses the middle 70 % of each half-channel); give at least 12",
                    d.bins
                ),
            ))
        }
        "periodic_poiseuille" => match d.force {
            Some(g) if g.is_finite() && g != 0.0 => BodyForce::ReversePoiseuille { force: g },
            Some(g) => {
                return Err(located(
                    "force",
                    format!("must be a non-zero number, got {g}"),
                ))
            }
            None => {
                return Err(bad(
                    "force",
                    "required for flow = \"periodic_poiseuille\"".into(),
                ))
            }
        },
        "poiseuille" => match d.force {
            Some(g) if g.is_finite() && g != 0.0 => BodyForce::Constant([g, 0.0, 0.0]),
            Some(g) => return Err(located("force", format!("must be a non-zero number, got {g}"))),
            None => return Err(bad("force", "required for flow = \"poiseuille\"".into())),
        },
        "couette" => {
            if !matches!(wall, Some(Wall::Planes { .. })) {
                return Err(located(
                    "flow",
                    "couette flow is driven by sliding plane walls: give walls = { kind = \"planes\", … }".into(),
                ));
            }
            if d.force.is_some() {
                return Err(located(
                    "force",
                    "couette flow is driven by wall_speed, not a body force".into(),
                ));
            }
            BodyForce::None
        }
        other => {
            return Err(located(
                "flow",
                format!(
                    "unknown flow \"{other}\" (expected \"none\", \"periodic_poiseuille\", \"poiseuille\" or \"couette\")"
                ),
            ))
        }
    };
    let wall_speed = match (d.flow.as_str(), d.wall_speed) {
        ("couette", Some(u)) if u.is_finite() && u != 0.0 => u,
        ("couette", Some(u)) => {
            return Err(located(
                "wall_speed",
                format!("must be a non-zero number, got {u}"),
            ))
        }
        ("couette", None) => {
            return Err(bad("wall_speed", "required for flow = \"couette\"".into()))
        }
        (_, Some(_)) => {
            return Err(located(
                "wall_speed",
                "only flow = \"couette\" slides the walls".into(),
            ))
        }
        (_, None) => 0.0,
    };
    let equilibrate = d.equilibrate.unwrap_or(steps / 5);
    if equilibrate >= steps {
        return Err(located(
            "equilibrate",
            format!("{equilibrate} steps leave none of the {steps} to average"),
        ));
    }
    let params = DpdParams {
        box_len,
        pair: PairParams {
            a: d.a,
            gamma: d.gamma,
            kbt: d.kbt,
            rc: d.rc,
            power: d.power,
        },
        dt: d.dt,
        mass: d.mass,
        seed: d.seed,
    };
    params
        .validate()
        .map_err(|e| SceneError::new(file, format!("[dpd]: {e}")))?;
    let coupling = coupling_params(file, text, d.coupling.as_ref())?;
    let gpu = match &d.gpu {
        None => GpuChoice::Auto,
        Some(flag) => flag.choice().map_err(|why| located("gpu", why))?,
    };
    let gpu_precision = match d.gpu_precision.as_deref() {
        None | Some("f32") => GpuPrecision::F32,
        Some("f64") => {
            if !GpuPrecision::F64.takes_kernel_exponent(d.power) {
                return Err(located(
                    "gpu_precision",
                    format!(
                        "f64 on the GPU takes power = 1, 0.5 or 0.25 (WGSL has no f64 pow), got {}",
                        d.power
                    ),
                ));
            }
            GpuPrecision::F64
        }
        Some(other) => {
            return Err(located(
                "gpu_precision",
                format!("must be \"f32\" or \"f64\", got \"{other}\""),
            ))
        }
    };
    let mut cells: Vec<DpdCell> = Vec::with_capacity(d.cells.len());
    for (k, c) in d.cells.iter().enumerate() {
        let built = cell(file, text, k, c, &params, wall.as_ref())?;
        if let Some(j) = cells
            .iter()
            .position(|other| other.spec.overlaps(&built.spec, box_len))
        {
            let mut e = SceneError::new(
                file,
                format!(
                    "[[dpd.cells]] entry {}: center: the cell overlaps entry {} (a vertex of \
                     one is inside the other)",
                    k + 1,
                    j + 1
                ),
            );
            e.place = cell_key_place(text, k, "center")
                .or_else(|| section_place(text, "[[dpd.cells]]", k));
            return Err(e);
        }
        cells.push(built);
    }
    let from_cells = match &d.from_cells {
        Some(fc) => {
            let n_own = cells.len();
            let (mapping, mapped) =
                mapped_cells(file, text, fc, &params, wall.as_ref(), d.coupling.as_ref())?;
            for (line, built) in mapped {
                if let Some(j) = cells
                    .iter()
                    .position(|other| other.spec.overlaps(&built.spec, box_len))
                {
                    let other = if j < n_own {
                        format!("[[dpd.cells]] entry {}", j + 1)
                    } else {
                        "another mapped cell".into()
                    };
                    return Err(SceneError {
                        file: file.to_path_buf(),
                        place: Some((line, 1)),
                        message: format!(
                            "[[cells]] entry at line {line}, mapped by [dpd.from_cells]: the cell \
                             overlaps {other} (a vertex of one is inside the other)"
                        ),
                    });
                }
                cells.push(built);
            }
            Some(mapping)
        }
        None => {
            if f.cells.is_some() {
                return Err(SceneError {
                    file: file.to_path_buf(),
                    place: section_place(text, "[[cells]]", 0),
                    message: "[[cells]]: the scene's cells (mobo run's) are not in the DPD run \
                              unless [dpd.from_cells] maps them: give it length (r_c per scene \
                              length unit) and energy (k_BT per scene energy unit)"
                        .into(),
                });
            }
            None
        }
    };
    Ok(DpdScene {
        params,
        density: d.density,
        body,
        steps,
        equilibrate,
        sample_every: d.sample_every,
        blocks: d.blocks,
        bins: d.bins,
        save_every: d.save_every,
        wall,
        wall_warmup: d.wall_warmup,
        wall_speed,
        cells,
        from_cells,
        coupling,
        gpu,
        gpu_precision,
    })
}

/// The error `located(key, why)` of the first value that is not a positive finite number.
fn check_positive(
    located: &dyn Fn(&str, String) -> SceneError,
    values: &[(&str, f64)],
) -> Result<(), SceneError> {
    match values.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
        Some(&(key, v)) => Err(located(key, format!("must be a positive number, got {v}"))),
        None => Ok(()),
    }
}

/// The error `located(key, why)` of the first given value that is not a finite number ≥ 0
/// (`None`: not given).
fn check_nonnegative(
    located: &dyn Fn(&str, String) -> SceneError,
    values: &[(&str, Option<f64>)],
) -> Result<(), SceneError> {
    let bad = values.iter().find_map(|&(key, v)| {
        let v = v?;
        (!(v.is_finite() && v >= 0.0)).then_some((key, v))
    });
    match bad {
        Some((key, v)) => Err(located(key, format!("must be a number ≥ 0, got {v}"))),
        None => Ok(()),
    }
}

/// Icosphere subdivisions of a cell's mesh: 1 to 6.
fn check_subdivisions(
    located: &dyn Fn(&str, String) -> SceneError,
    subdivisions: u32,
) -> Result<(), SceneError> {
    if (1..=6).contains(&subdivisions) {
        Ok(())
    } else {
        Err(located(
            "subdivisions",
            format!("must be 1 to 6 (10·4^s + 2 vertices), got {subdivisions}"),
        ))
    }
}

/// Line and column of the `k`-th header `header` (e.g. `[[dpd.cells]]`).
fn section_place(text: &str, header: &str, k: usize) -> Option<(usize, usize)> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| l.trim_start().starts_with(header))
        .nth(k)
        .map(|(i, l)| (i + 1, l.len() - l.trim_start().len() + 1))
}

/// Line and column of `key = …` inside the `k`-th `[[dpd.cells]]` entry.
fn cell_key_place(text: &str, k: usize, key: &str) -> Option<(usize, usize)> {
    section_key_place(text, "[[dpd.cells]]", k, key)
}

/// Line and column of `key = …` inside the section `header` (its first occurrence).
fn key_place_in(text: &str, header: &str, key: &str) -> Option<(usize, usize)> {
    section_key_place(text, header, 0, key)
}

/// Line and column of `key = …` inside the `k`-th section `header`.
fn section_key_place(text: &str, header: &str, k: usize, key: &str) -> Option<(usize, usize)> {
    let (start, _) = section_place(text, header, k)?;
    let body: Vec<&str> = text
        .lines()
        .skip(start)
        .take_while(|l| !l.trim_start().starts_with('['))
        .collect();
    key_place(&body.join("\n"), key).map(|(line, col)| (line + start, col))
}

/// Line and column of `key = …` in the text (the first line that assigns it).
fn key_place(text: &str, key: &str) -> Option<(usize, usize)> {
    text.lines().enumerate().find_map(|(i, line)| {
        let t = line.trim_start();
        let rest = t.strip_prefix(key)?;
        rest.trim_start()
            .starts_with('=')
            .then(|| (i + 1, line.len() - t.len() + 1))
    })
}

//! Cell scenes (the input of `mobo run`): schema, validation with errors that
//! name the file, the line and the key, placement of many cells, and the assembly decisions
//! that say which physics a scene needs (and why).
//!
//! ```toml
//! [fluid]
//! viscosity = 1.0                 # μ of the suspending fluid
//!
//! [flow]
//! kind = "shear"                  # "none" | "shear" | "extensional" | "poiseuille"
//! rate = 1.0                      # shear: u = (γ̇ y, 0, 0); extensional: u = ε̇ (x, −y, 0)
//! # speed = 1.0, radius = 5.0     # poiseuille along x: u = U (1 − (y² + z²)/R²), free space
//! # frame = "cells"               # extensional: stagnation point at the cells' centre ("cells",
//! #                               # the default: a uniform translation) or at 0 ("lab")
//!
//! [[cells]]
//! shape = "rbc"                   # "sphere" | "ellipsoid" | "rbc" | "prolate" | "oblate"
//! radius = 1.0                    # equivalent radius (sphere of equal volume)
//! center = [0.0, 0.0, 0.0]
//! # axes = [1.0, 0.8, 0.6]        # ellipsoid (scaled to the equivalent radius)
//! # reduced_volume = 0.9          # prolate, oblate
//! # orientation = [0, 0, 1, 30]   # rotation axis and angle in degrees (the rbc, prolate and
//! #                               # oblate shapes have their axis of symmetry along z, which a
//! #                               # turn about z leaves there: to lay it in the x-y shear plane
//! #                               # at angle t from x, turn by 90 about (-sin t, cos t, 0))
//! membrane = "vesicle"            # "vesicle" (locally inextensible: vesicles, RBCs) |
//! #                               # "capsule" (elastic membrane whose area changes; needs
//! #                               # shear_modulus > 0; follows material points, no
//! #                               # reparametrisation; only the volume is restored)
//! bending_modulus = 0.05          # default 0.05 (vesicle), 0 (capsule)
//! shear_modulus = 0.0             # G_s of the elastic law (0: none)
//! elastic_law = "skalak"          # "skalak" | "neo_hookean"
//! skalak_c = 10.0                 # Skalak area-dilation parameter C
//! viscosity_ratio = 1.0           # λ = μ_in / μ_out
//! force = [0.0, 0.0, 0.0]         # body force per cell
//! # count = 27, placement = "lattice" | "random", spacing = 3.0, region = [[..], [..]], seed = 1
//! # random placement keeps every cell's bounding sphere 5 % clear of the others', those of
//! # earlier [[cells]] entries included (groups may share a region); a region that cannot hold
//! # the count is an error giving how many were placed and the volume fraction asked.
//!
//! [numerics]
//! order = 12                      # SH order p
//! upsample = 2                    # quadrature order q = upsample · p
//! fmm_digits = 6
//! gmres_tol = 1e-8
//! dt = 0.01
//! t_end = 1.0
//! scheme = "euler"                # "euler" | "bdf2"
//! elasticity = "auto"             # elastic force: "explicit" | "implicit" (linearised, a
//! #                               # Jacobian per GMRES iteration) | "auto" (implicit for capsules)
//! adaptive_dt = false             # true: dt from the area/volume error (dt is the first step)
//! far_side_split = true           # split off the own far side in the singular quadrature
//! operator_storage = "auto"       # self-interaction: "auto" | "grid" | "coefficients" | "matrix_free"
//! preconditioner = "cell"         # GMRES: "cell" (each cell's own step operator inverted, turned
//! #                               # with its grid, rebuilt when stale) | "sphere" (the inverse for
//! #                               # the sphere of the cell's area, turned with the grid)
//! # preconditioner_rebuild_after = 8  # "cell": a step of more iterations rebuilds it
//! # dt_tolerance = 1e-3           # adaptive: relative area/volume error allowed over the run
//! # dt_min = 1e-5, dt_max = 0.1   # adaptive: bounds of dt (defaults dt/1000, max(dt, t_end/10))
//! repulsion_range = 0.05          # contact repulsion within 0.05 R of another cell (0: off)
//! # repulsion_strength = 1.0      # its traction scale (default 10·max(κ/R³, μγ̇, |F|/4πR²))
//! rebalance_every = 10            # under mpirun: steps between checks of the split of the cells
//! max_imbalance = 0.1             # under mpirun: cost imbalance that moves cells (see run::partition)
//! gpu = "auto"                    # FMM near field on a GPU: "auto" | true | false (feature gpu)
//!
//! [output]
//! every = 10                      # steps between saved frames
//! npy = true                      # DIR/frames/*.npy
//! vtk = true                      # DIR/vtk/frame_NNNNN.vtp + frames.pvd (ParaView)
//! mesh_subdivisions = 3           # icosphere subdivisions of the VTK meshes
//! hdf5 = false                    # DIR/frames.h5 (needs the hdf5 feature)
//! checkpoint_every = 10           # steps between checkpoints (default: every)
//! ```

use std::path::Path;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use serde::Deserialize;
use toml::Spanned;

use super::{line_col, parse_toml, read_scene_file, GpuFlag, SceneError};
use crate::gpu::GpuChoice;
use crate::timestep::semi_implicit::{ElasticStepping, OperatorStorage, Preconditioning};
use crate::vesicle::shapes::{self, Spheroid, Surface};
use crate::vesicle::skalak::ElasticLaw;

/// The lowest SH order that holds the red blood cell's shape ([`shapes::rbc`]: its height is
/// `sin⁴θ cosθ` at most, a polynomial of degree 5).
pub const RBC_MIN_ORDER: usize = 5;

/// Steps between checks of the split of the cells over ranks (`[numerics] rebalance_every`'s
/// default; [`crate::run::partition`]).
pub const REBALANCE_EVERY: usize = 10;
/// Cost imbalance above which cells are moved between ranks (`[numerics] max_imbalance`'s
/// default; [`crate::run::partition`]).
pub const MAX_IMBALANCE: f64 = 0.10;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    fluid: Option<FluidSection>,
    flow: Option<FlowSection>,
    cells: Option<Vec<CellSection>>,
    numerics: Option<NumericsSection>,
    output: Option<OutputSection>,
    /// `mobo dpd`'s section: the same file runs both ways (its `[dpd.from_cells]` maps these
    /// cells into the DPD fluid); `mobo run` does not read it.
    #[serde(rename = "dpd")]
    _dpd: Option<serde::de::IgnoredAny>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FluidSection {
    viscosity: Spanned<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FlowSection {
    kind: Spanned<String>,
    rate: Option<Spanned<f64>>,
    speed: Option<Spanned<f64>>,
    radius: Option<Spanned<f64>>,
    frame: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CellSection {
    shape: Spanned<String>,
    radius: Option<Spanned<f64>>,
    center: Option<Spanned<[f64; 3]>>,
    axes: Option<Spanned<[f64; 3]>>,
    reduced_volume: Option<Spanned<f64>>,
    orientation: Option<Spanned<[f64; 4]>>,
    bending_modulus: Option<Spanned<f64>>,
    shear_modulus: Option<Spanned<f64>>,
    skalak_c: Option<Spanned<f64>>,
    membrane: Option<Spanned<String>>,
    elastic_law: Option<Spanned<String>>,
    viscosity_ratio: Option<Spanned<f64>>,
    force: Option<Spanned<[f64; 3]>>,
    count: Option<Spanned<usize>>,
    placement: Option<Spanned<String>>,
    spacing: Option<Spanned<f64>>,
    region: Option<Spanned<[[f64; 3]; 2]>>,
    seed: Option<u64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct NumericsSection {
    order: Option<Spanned<usize>>,
    upsample: Option<Spanned<usize>>,
    fmm_digits: Option<Spanned<u32>>,
    gmres_tol: Option<Spanned<f64>>,
    dt: Option<Spanned<f64>>,
    t_end: Option<Spanned<f64>>,
    scheme: Option<Spanned<String>>,
    elasticity: Option<Spanned<String>>,
    adaptive_dt: Option<bool>,
    far_side_split: Option<bool>,
    operator_storage: Option<Spanned<String>>,
    preconditioner: Option<Spanned<String>>,
    preconditioner_rebuild_after: Option<Spanned<u64>>,
    dt_tolerance: Option<Spanned<f64>>,
    dt_min: Option<Spanned<f64>>,
    dt_max: Option<Spanned<f64>>,
    repulsion_range: Option<Spanned<f64>>,
    repulsion_strength: Option<Spanned<f64>>,
    rebalance_every: Option<Spanned<u64>>,
    max_imbalance: Option<Spanned<f64>>,
    gpu: Option<Spanned<GpuFlag>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct OutputSection {
    every: Option<Spanned<u64>>,
    npy: Option<bool>,
    vtk: Option<bool>,
    hdf5: Option<bool>,
    mesh_subdivisions: Option<Spanned<u32>>,
    checkpoint_every: Option<Spanned<u64>>,
}

/// `[output]`: what is written besides `summary.json`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OutputSettings {
    /// Frames as `.npy` arrays in `DIR/frames/` (default on).
    pub npy: bool,
    /// Frames as ParaView meshes in `DIR/vtk/` with this many icosphere subdivisions (default
    /// on, 3 subdivisions: 642 vertices per cell).
    pub vtk: Option<u32>,
    /// Frames in `DIR/frames.h5` (needs the `hdf5` feature; default off).
    pub hdf5: bool,
    /// Steps between checkpoints (default: `every`).
    pub checkpoint_every: u64,
}

/// Background flow.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Flow {
    /// Quiescent fluid.
    None,
    /// `u = (γ̇ y, 0, 0)`.
    Shear {
        /// Shear rate `γ̇` (`[flow] rate`; its sign sets the direction).
        rate: f64,
    },
    /// `u = ε̇ (x − o_x, −(y − o_y), 0)` about the origin `o` of the frame.
    Extensional {
        /// Strain rate `ε̇` (`[flow] rate`).
        rate: f64,
        /// Whether the stagnation point follows the cells (`[flow] frame = "cells"`, the
        /// default): `o` is, at the start of every step, the midpoint of the bounding box of
        /// the cells' centres; otherwise (`frame = "lab"`) `o = 0`. Following the cells is a
        /// uniform translation of the whole suspension (in free space it changes no shape and
        /// no relative position), as the feedback of cross-slot experiments keeps a cell at the
        /// stagnation point; in the lab frame the stagnation point is a saddle that a cell
        /// leaves exponentially, at the strain rate, from the round-off of its position.
        follow_cells: bool,
    },
    /// `u = (U (1 − (y² + z²)/R²), 0, 0)`.
    Poiseuille {
        /// Centreline speed `U` (`[flow] speed`).
        speed: f64,
        /// Radius `R` of the profile (`[flow] radius`, positive); the flow is unbounded (no
        /// wall at `R`), so `u` turns negative beyond it.
        radius: f64,
    },
}

impl Flow {
    /// The background velocity at `x` in a frame whose origin is `origin`: for an extensional
    /// flow that follows the cells, `u(x − origin)`; every other flow is the lab frame's
    /// [`Flow::velocity`] (`origin` unused).
    pub fn velocity_about(&self, x: [f64; 3], origin: [f64; 3]) -> [f64; 3] {
        if self.follows_cells() {
            self.velocity([x[0] - origin[0], x[1] - origin[1], x[2] - origin[2]])
        } else {
            self.velocity(x)
        }
    }

    /// Whether the flow's origin follows the cells (an extensional flow with `frame = "cells"`).
    pub fn follows_cells(&self) -> bool {
        matches!(
            self,
            Flow::Extensional {
                follow_cells: true,
                ..
            }
        )
    }

    /// The background velocity at `x` (lab frame).
    pub fn velocity(&self, x: [f64; 3]) -> [f64; 3] {
        match *self {
            Flow::None => [0.0; 3],
            Flow::Shear { rate } => [rate * x[1], 0.0, 0.0],
            Flow::Extensional { rate, .. } => [rate * x[0], -rate * x[1], 0.0],
            Flow::Poiseuille { speed, radius } => [
                speed * (1.0 - (x[1] * x[1] + x[2] * x[2]) / (radius * radius)),
                0.0,
                0.0,
            ],
        }
    }
}

/// Cell shape before scaling and placement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    /// `shape = "sphere"`.
    Sphere,
    /// `shape = "ellipsoid"`.
    Ellipsoid {
        /// Semi-axes along x, y, z (`axes`, positive); only their ratios matter, the size is
        /// set by the equivalent radius.
        axes: [f64; 3],
    },
    /// `shape = "rbc"`: the biconcave red blood cell disc of [`crate::vesicle::shapes::rbc`]
    /// (axis of symmetry along z).
    Rbc,
    /// `shape = "prolate"` or `"oblate"`: the spheroid (axis of symmetry along z) of a given
    /// reduced volume.
    Spheroid {
        /// Prolate or oblate.
        kind: Spheroid,
        /// Reduced volume `v = 6√π V / A^{3/2}` (volume over that of the sphere of equal
        /// area) in `(0, 1)` (`reduced_volume`; 1 would be a sphere).
        reduced_volume: f64,
    },
}

/// One cell of a scene.
#[derive(Clone, Debug, PartialEq)]
pub struct CellSpec {
    /// Shape before scaling, rotation and placement.
    pub shape: Shape,
    /// Equivalent radius (sphere of equal volume).
    pub radius: f64,
    /// Centroid.
    pub center: [f64; 3],
    /// Rotation matrix applied about the centroid.
    pub rotation: [[f64; 3]; 3],
    /// Bending modulus `κ_b` (default 0.05).
    pub bending_modulus: f64,
    /// Shear modulus `G_s` of the elastic law (default 0: no shear elasticity); the membrane
    /// is stress-free at its initial shape.
    pub shear_modulus: f64,
    /// Skalak area-dilation parameter `C` (large `C`: nearly area-preserving; default 10).
    pub skalak_c: f64,
    /// The strain-energy function of the shear elasticity (default Skalak).
    pub elastic_law: ElasticLaw,
    /// `false` for a capsule (`membrane = "capsule"`): no inextensibility constraint.
    pub inextensible: bool,
    /// Viscosity ratio `λ = μ_in / μ_out` (default 1: no double layer).
    pub viscosity_ratio: f64,
    /// Body force on the cell, the total `F` (spread as a uniform traction `F / A`; default
    /// zero).
    pub force: [f64; 3],
    /// Radius of a sphere about the centroid that contains the cell.
    pub bounding_radius: f64,
    /// Line in the scene file of the `[[cells]]` entry this cell comes from.
    pub line: usize,
}

impl CellSpec {
    /// The cell's surface at SH order `p`.
    pub fn surface(&self, p: usize) -> Result<Surface, crate::vesicle::VesicleError> {
        let mut s = unit_shape(&self.shape, p)?;
        s.scale_to_equivalent_radius(self.radius)?;
        s.place_centroid([0.0; 3])?;
        s.rotate(self.rotation)?;
        s.translate(self.center);
        Ok(s)
    }
}

/// Time-integration scheme.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scheme {
    /// First-order semi-implicit (Veerapaneni et al. 2011).
    Euler,
    /// Second order, BDF2 with extrapolated operators.
    Bdf2,
}

/// `[numerics]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Numerics {
    /// Spherical-harmonic order `p` of the cell surfaces (2 to 64; default 12).
    pub order: usize,
    /// Upsampling factor: the quadrature order is `q = upsample · p` (1 to 4; default 2).
    pub upsample: usize,
    /// Digits of accuracy asked of the FMM between cells (3 to 10; default 6).
    pub fmm_digits: u32,
    /// Relative residual at which GMRES stops (in `(0, 1)`; default `1e-8`).
    pub gmres_tol: f64,
    /// Time step (default 0.01); with `adaptive_dt`, the first step.
    pub dt: f64,
    /// End time of the run (default 1); a fixed `dt` takes `round(t_end / dt)` steps.
    pub t_end: f64,
    /// Time-integration scheme (default [`Scheme::Euler`]).
    pub scheme: Scheme,
    /// How the elastic force enters the step (`None`, `"auto"`: linearly implicit for
    /// capsules, explicit for inextensible cells).
    pub elasticity: Option<ElasticStepping>,
    /// Choose `dt` from the area/volume error estimate ([`crate::timestep::adaptive`];
    /// default off).
    pub adaptive_dt: bool,
    /// Split a cell's own far side off its singular integrals where it comes close
    /// ([`crate::vesicle::far_side`]; default on).
    pub far_side_split: bool,
    /// How each cell keeps its self-interaction operators
    /// ([`crate::timestep::semi_implicit::OperatorStorage`]); `None` ("auto", the default): the
    /// fastest whose operators for all cells and threads fit in 60 % of the memory available at
    /// the start (the grid, unless a thread cannot hold its operators).
    pub operator_storage: Option<OperatorStorage>,
    /// GMRES preconditioner of every inextensible cell (default: each cell's own,
    /// [`Preconditioning::CELL`]; see [`crate::timestep::semi_implicit::Preconditioning`]).
    pub preconditioning: Preconditioning,
    /// Adaptive `dt`: relative area/volume error allowed over the run (default `1e-3`).
    pub dt_tolerance: f64,
    /// Adaptive `dt`: smallest step (default `dt/1000`).
    pub dt_min: f64,
    /// Adaptive `dt`: largest step (default `max(dt, t_end/10)`).
    pub dt_max: f64,
    /// Contact repulsion range as a fraction of the equivalent radius (0: off).
    pub repulsion_range: f64,
    /// Contact repulsion strength (traction); `None`: `10 · max(κ_b/R³, μ γ̇, |F|/4πR²)`
    /// over the cells, `γ̇` the flow's rate scale.
    pub repulsion_strength: Option<f64>,
    /// Under MPI: steps between checks of the split of the cells between ranks (default 10).
    pub rebalance_every: usize,
    /// Under MPI: the cost imbalance (largest rank over mean, minus 1) above which cells are
    /// moved at a check (default 0.1; see [`crate::run::partition`]).
    pub max_imbalance: f64,
    /// The FMM's near field on a GPU: `"auto"` (default), `true` or `false`
    /// ([`crate::fmm::gpu_near::choose`]).
    pub gpu: GpuChoice,
}

/// One assembly decision: whether a piece of physics is built, and why.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Effect {
    /// What is built: `"fmm"`, `"double_layer"`, `"inter_cell_double_layer"`, `"skalak"`,
    /// `"background_flow"`, `"body_force"`, `"adaptive_dt"`, or (in a run's summary, where
    /// memory left them out) `"cell_preconditioner"`.
    pub name: &'static str,
    /// Whether it is built.
    pub enabled: bool,
    /// Why, in words (e.g. `"viscosity_ratio ≠ 1 for cells 0, 2"`).
    pub reason: String,
}

/// A validated cell scene.
#[derive(Clone, Debug, PartialEq)]
pub struct CellScene {
    /// Viscosity `μ` of the suspending fluid (`[fluid] viscosity`; default 1).
    pub viscosity: f64,
    /// Background flow (`[flow]`; default none).
    pub flow: Flow,
    /// Every cell, groups expanded, in the order of the file.
    pub cells: Vec<CellSpec>,
    /// Discretisation, time stepping and parallel settings.
    pub numerics: Numerics,
    /// Steps between saved frames (`[output] every`; default 10).
    pub output_every: u64,
    /// Formats and checkpoints.
    pub output: OutputSettings,
    /// What the scene needs, decided from its contents (see [`effects`]).
    pub effects: Vec<Effect>,
}

/// Read and validate a cell scene file.
pub fn load(file: &Path) -> Result<CellScene, SceneError> {
    let text = read_scene_file(file)?;
    parse(file, &text)
}

fn unit_shape(shape: &Shape, p: usize) -> Result<Surface, crate::vesicle::VesicleError> {
    match *shape {
        Shape::Sphere => shapes::sphere(p, 1.0),
        Shape::Ellipsoid { axes } => shapes::ellipsoid(p, axes),
        Shape::Rbc => shapes::rbc(p),
        Shape::Spheroid {
            kind,
            reduced_volume,
        } => shapes::reduced_volume_spheroid(p, reduced_volume, kind, 1.0),
    }
}

/// Rotation matrix about `axis` by `deg` degrees (Rodrigues).
pub(crate) fn rotation(axis: [f64; 3], deg: f64) -> Option<[[f64; 3]; 3]> {
    let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
    if !(n > 0.0 && n.is_finite() && deg.is_finite()) {
        return None;
    }
    let (x, y, z) = (axis[0] / n, axis[1] / n, axis[2] / n);
    let (s, c) = deg.to_radians().sin_cos();
    let t = 1.0 - c;
    Some([
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ])
}

/// Where a scene's text comes from: what its messages cite.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Origin {
    /// A file the user wrote: `[[cells]]` entries by number (from 1) and line.
    File,
    /// The text of a [`super::spec::SceneSpec`]: its `cells[k]` (from 0), no lines (the user
    /// never saw the text).
    Spec,
}

/// Validate scene text (`file` names the scene in messages).
pub fn parse(file: &Path, text: &str) -> Result<CellScene, SceneError> {
    parse_from(file, text, Origin::File)
}

/// [`parse`], with messages that cite the scene as `origin` does.
pub(crate) fn parse_from(file: &Path, text: &str, origin: Origin) -> Result<CellScene, SceneError> {
    let f: File = parse_toml(file, text)?;
    let at = |span: std::ops::Range<usize>, msg: String| SceneError {
        file: file.to_path_buf(),
        place: Some(line_col(text, span.start)),
        message: msg,
    };
    let positive = |v: &Spanned<f64>, key: &str| -> Result<f64, SceneError> {
        let x = *v.get_ref();
        if x.is_finite() && x > 0.0 {
            Ok(x)
        } else {
            Err(at(
                v.span(),
                format!("{key} must be a positive number, got {x}"),
            ))
        }
    };
    let finite = |v: &Spanned<f64>, key: &str| -> Result<f64, SceneError> {
        let x = *v.get_ref();
        if x.is_finite() {
            Ok(x)
        } else {
            Err(at(v.span(), format!("{key} must be finite, got {x}")))
        }
    };
    let viscosity = match &f.fluid {
        Some(fl) => positive(&fl.viscosity, "[fluid] viscosity")?,
        None => 1.0,
    };
    let flow = match &f.flow {
        None => Flow::None,
        Some(fl) => {
            let need = |v: &Option<Spanned<f64>>, key: &str| -> Result<f64, SceneError> {
                match v {
                    Some(v) => finite(v, &format!("[flow] {key}")),
                    None => Err(at(
                        fl.kind.span(),
                        format!("[flow] kind = \"{}\" needs {key}", fl.kind.get_ref()),
                    )),
                }
            };
            match fl.kind.get_ref().as_str() {
                "none" => Flow::None,
                "shear" => Flow::Shear {
                    rate: need(&fl.rate, "rate")?,
                },
                "extensional" => Flow::Extensional {
                    rate: need(&fl.rate, "rate")?,
                    follow_cells: match &fl.frame {
                        None => true,
                        Some(f) => match f.get_ref().as_str() {
                            "cells" => true,
                            "lab" => false,
                            other => {
                                return Err(at(
                                    f.span(),
                                    format!(
                                        "[flow] frame: unknown frame \"{other}\" (cells, lab)"
                                    ),
                                ))
                            }
                        },
                    },
                },
                "poiseuille" => {
                    let speed = need(&fl.speed, "speed")?;
                    let radius = need(&fl.radius, "radius")?;
                    if radius <= 0.0 {
                        let sp = fl.radius.as_ref().map_or(fl.kind.span(), |r| r.span());
                        return Err(at(sp, format!("[flow] radius must be positive, got {radius}")));
                    }
                    Flow::Poiseuille { speed, radius }
                }
                other => {
                    return Err(at(
                        fl.kind.span(),
                        format!(
                            "[flow] kind: unknown flow \"{other}\" (none, shear, extensional, poiseuille)"
                        ),
                    ))
                }
            }
        }
    };
    let n = f.numerics.as_ref();
    let order = n.and_then(|n| n.order.as_ref());
    let numerics = Numerics {
        order: match order {
            Some(o) if !(2..=64).contains(o.get_ref()) => {
                return Err(at(
                    o.span(),
                    format!(
                        "[numerics] order must be between 2 and 64, got {}",
                        o.get_ref()
                    ),
                ))
            }
            Some(o) => *o.get_ref(),
            None => 12,
        },
        upsample: match n.and_then(|n| n.upsample.as_ref()) {
            Some(u) if !(1..=4).contains(u.get_ref()) => {
                return Err(at(
                    u.span(),
                    format!("[numerics] upsample must be 1 to 4, got {}", u.get_ref()),
                ))
            }
            Some(u) => *u.get_ref(),
            None => 2,
        },
        fmm_digits: match n.and_then(|n| n.fmm_digits.as_ref()) {
            Some(d) if !(3..=10).contains(d.get_ref()) => {
                return Err(at(
                    d.span(),
                    format!("[numerics] fmm_digits must be 3 to 10, got {}", d.get_ref()),
                ))
            }
            Some(d) => *d.get_ref(),
            None => 6,
        },
        gmres_tol: match n.and_then(|n| n.gmres_tol.as_ref()) {
            Some(t) => {
                let v = positive(t, "[numerics] gmres_tol")?;
                if v >= 1.0 {
                    return Err(at(
                        t.span(),
                        format!("[numerics] gmres_tol must be below 1, got {v}"),
                    ));
                }
                v
            }
            None => 1e-8,
        },
        dt: match n.and_then(|n| n.dt.as_ref()) {
            Some(v) => positive(v, "[numerics] dt")?,
            None => 0.01,
        },
        t_end: match n.and_then(|n| n.t_end.as_ref()) {
            Some(v) => positive(v, "[numerics] t_end")?,
            None => 1.0,
        },
        scheme: match n.and_then(|n| n.scheme.as_ref()) {
            None => Scheme::Euler,
            Some(s) => match s.get_ref().as_str() {
                "euler" => Scheme::Euler,
                "bdf2" => Scheme::Bdf2,
                other => {
                    return Err(at(
                        s.span(),
                        format!("[numerics] scheme: unknown scheme \"{other}\" (euler, bdf2)"),
                    ))
                }
            },
        },
        elasticity: match n.and_then(|n| n.elasticity.as_ref()) {
            None => None,
            Some(s) => match s.get_ref().as_str() {
                "auto" => None,
                "explicit" => Some(ElasticStepping::Explicit),
                "implicit" => Some(ElasticStepping::LinearlyImplicit),
                other => {
                    return Err(at(
                        s.span(),
                        format!(
                            "[numerics] elasticity: unknown choice \"{other}\" (auto, explicit, \
                             implicit)"
                        ),
                    ))
                }
            },
        },
        adaptive_dt: n.and_then(|n| n.adaptive_dt).unwrap_or(false),
        far_side_split: n.and_then(|n| n.far_side_split).unwrap_or(true),
        operator_storage: match n.and_then(|n| n.operator_storage.as_ref()) {
            None => None,
            Some(s) => match s.get_ref().as_str() {
                "auto" => None,
                "coefficients" => Some(OperatorStorage::Coefficients),
                "grid" => Some(OperatorStorage::Grid),
                "matrix_free" => Some(OperatorStorage::MatrixFree),
                other => {
                    return Err(at(
                        s.span(),
                        format!(
                            "[numerics] operator_storage: unknown storage \"{other}\" \
                             (auto, grid, coefficients, matrix_free)"
                        ),
                    ))
                }
            },
        },
        preconditioning: preconditioning(n, &at)?,
        dt_tolerance: match n.and_then(|n| n.dt_tolerance.as_ref()) {
            Some(t) => {
                let v = positive(t, "[numerics] dt_tolerance")?;
                if v >= 1.0 {
                    return Err(at(
                        t.span(),
                        format!("[numerics] dt_tolerance must be below 1, got {v}"),
                    ));
                }
                v
            }
            None => 1e-3,
        },
        dt_min: match n.and_then(|n| n.dt_min.as_ref()) {
            Some(v) => positive(v, "[numerics] dt_min")?,
            None => f64::NAN,
        },
        dt_max: match n.and_then(|n| n.dt_max.as_ref()) {
            Some(v) => positive(v, "[numerics] dt_max")?,
            None => f64::NAN,
        },
        repulsion_range: match n.and_then(|n| n.repulsion_range.as_ref()) {
            Some(v) if !(v.get_ref().is_finite() && *v.get_ref() >= 0.0 && *v.get_ref() <= 1.0) => {
                return Err(at(
                    v.span(),
                    format!(
                        "[numerics] repulsion_range must be between 0 and 1 (a fraction of the cell radius), got {}",
                        v.get_ref()
                    ),
                ))
            }
            Some(v) => *v.get_ref(),
            None => 0.05,
        },
        repulsion_strength: match n.and_then(|n| n.repulsion_strength.as_ref()) {
            Some(v) if !(v.get_ref().is_finite() && *v.get_ref() >= 0.0) => {
                return Err(at(
                    v.span(),
                    format!(
                        "[numerics] repulsion_strength must be a non-negative number, got {}",
                        v.get_ref()
                    ),
                ))
            }
            Some(v) => Some(*v.get_ref()),
            None => None,
        },
        rebalance_every: match n.and_then(|n| n.rebalance_every.as_ref()) {
            Some(v) if *v.get_ref() == 0 => {
                return Err(at(
                    v.span(),
                    "[numerics] rebalance_every must be at least 1".to_string(),
                ))
            }
            Some(v) => *v.get_ref() as usize,
            None => REBALANCE_EVERY,
        },
        max_imbalance: match n.and_then(|n| n.max_imbalance.as_ref()) {
            Some(v) if !(v.get_ref().is_finite() && *v.get_ref() >= 0.0) => {
                return Err(at(
                    v.span(),
                    format!(
                        "[numerics] max_imbalance must be a non-negative number, got {}",
                        v.get_ref()
                    ),
                ))
            }
            Some(v) => *v.get_ref(),
            None => MAX_IMBALANCE,
        },
        gpu: match n.and_then(|n| n.gpu.as_ref()) {
            None => GpuChoice::Auto,
            Some(g) => g
                .get_ref()
                .choice()
                .map_err(|why| at(g.span(), format!("[numerics] gpu {why}")))?,
        },
    };
    let mut numerics = numerics;
    if numerics.dt_min.is_nan() {
        numerics.dt_min = numerics.dt / 1000.0;
    }
    if numerics.dt_max.is_nan() {
        numerics.dt_max = numerics.dt.max(numerics.t_end / 10.0);
    }
    if numerics.dt_min > numerics.dt || numerics.dt > numerics.dt_max {
        let span = n
            .and_then(|n| n.dt.as_ref().or(n.dt_min.as_ref()).or(n.dt_max.as_ref()))
            .map(|v| v.span());
        let msg = format!(
            "[numerics] dt = {} must lie between dt_min = {} and dt_max = {}",
            numerics.dt, numerics.dt_min, numerics.dt_max
        );
        return Err(match span {
            Some(sp) => at(sp, msg),
            None => SceneError::new(file, msg),
        });
    }
    let output_every = match f.output.as_ref().and_then(|o| o.every.as_ref()) {
        Some(e) if *e.get_ref() == 0 => {
            return Err(at(e.span(), "[output] every must be at least 1".into()))
        }
        Some(e) => *e.get_ref(),
        None => 10,
    };
    let o = f.output.as_ref();
    let mesh_subdivisions = match o.and_then(|o| o.mesh_subdivisions.as_ref()) {
        Some(m) if *m.get_ref() > 6 => {
            return Err(at(
                m.span(),
                "[output] mesh_subdivisions must be at most 6 (20·4⁶ triangles per cell)".into(),
            ))
        }
        Some(m) => *m.get_ref(),
        None => 3,
    };
    let checkpoint_every = match o.and_then(|o| o.checkpoint_every.as_ref()) {
        Some(e) if *e.get_ref() == 0 => {
            return Err(at(
                e.span(),
                "[output] checkpoint_every must be at least 1".into(),
            ))
        }
        Some(e) => *e.get_ref(),
        None => output_every,
    };
    let output = OutputSettings {
        npy: o.and_then(|o| o.npy).unwrap_or(true),
        vtk: o
            .and_then(|o| o.vtk)
            .unwrap_or(true)
            .then_some(mesh_subdivisions),
        hdf5: o.and_then(|o| o.hdf5).unwrap_or(false),
        checkpoint_every,
    };
    let sections = f.cells.unwrap_or_default();
    if sections.is_empty() {
        return Err(SceneError::new(file, "the scene has no [[cells]]"));
    }
    // The `[[cells]]` entry a cell comes from, as the messages cite it.
    let entry_lines: Vec<usize> = sections
        .iter()
        .map(|c| line_col(text, c.shape.span().start).0)
        .collect();
    let entry = |line: usize| {
        let k = entry_lines.iter().position(|&l| l == line).unwrap_or(0);
        match origin {
            Origin::File => format!("the [[cells]] entry #{} (line {line})", k + 1),
            Origin::Spec => format!("cells[{k}] of the spec"),
        }
    };
    let mut cells = Vec::new();
    for (k, c) in sections.iter().enumerate() {
        let group = cell_specs(c, k, origin, &cells, &at, &positive, &finite, text)?;
        cells.extend(group);
    }
    check_overlaps(&cells, file, &entry)?;
    if let Some(c) = cells
        .iter()
        .find(|c| matches!(c.shape, Shape::Rbc) && numerics.order < RBC_MIN_ORDER)
    {
        let message = format!(
            "[numerics] order = {} cannot hold the red blood cell of {}: its shape has \
             spherical-harmonic degree {RBC_MIN_ORDER}; give order >= {RBC_MIN_ORDER}",
            numerics.order,
            entry(c.line)
        );
        return Err(match order {
            Some(o) => at(o.span(), message),
            None => SceneError::new(file, message),
        });
    }
    if let (true, Some(c)) = (numerics.adaptive_dt, cells.iter().find(|c| !c.inextensible)) {
        return Err(SceneError::new(
            file,
            format!(
                "[numerics] adaptive_dt = true cannot step capsules ({}): the adaptive step size \
                 is controlled by the area/volume change of a step, which does not show a \
                 capsule's elastic error; use a fixed dt",
                entry(c.line)
            ),
        ));
    }
    let mut effects = effects(&cells, &flow);
    effects.push(Effect {
        name: "adaptive_dt",
        enabled: numerics.adaptive_dt,
        reason: if numerics.adaptive_dt {
            format!(
                "[numerics] adaptive_dt = true: dt from the area/volume error, tolerance {} over \
                 the run, dt in [{}, {}]",
                numerics.dt_tolerance, numerics.dt_min, numerics.dt_max
            )
        } else {
            format!("fixed dt = {} (adaptive_dt = false)", numerics.dt)
        },
    });
    Ok(CellScene {
        viscosity,
        flow,
        cells,
        numerics,
        output_every,
        output,
        effects,
    })
}

type At<'a> = dyn Fn(std::ops::Range<usize>, String) -> SceneError + 'a;
type Check<'a> = dyn Fn(&Spanned<f64>, &str) -> Result<f64, SceneError> + 'a;

/// `[numerics] preconditioner` and `preconditioner_rebuild_after`.
fn preconditioning(
    n: Option<&NumericsSection>,
    at: &dyn Fn(std::ops::Range<usize>, String) -> SceneError,
) -> Result<Preconditioning, SceneError> {
    let rebuild = n.and_then(|n| n.preconditioner_rebuild_after.as_ref());
    let kind = n.and_then(|n| n.preconditioner.as_ref());
    let rebuild_after = match rebuild {
        Some(r) => {
            let v = *r.get_ref();
            if !(1..=1_000_000).contains(&v) {
                return Err(at(
                    r.span(),
                    format!(
                        "[numerics] preconditioner_rebuild_after must be from 1 to 1000000 \
                         (iterations), got {v}"
                    ),
                ));
            }
            v as usize
        }
        None => Preconditioning::DEFAULT_REBUILD_AFTER,
    };
    match kind.map(|k| (k, k.get_ref().as_str())) {
        Some((_, "sphere")) => {
            if let Some(r) = rebuild {
                return Err(at(
                    r.span(),
                    "[numerics] preconditioner_rebuild_after applies to preconditioner = \"cell\" \
                     only"
                        .into(),
                ));
            }
            Ok(Preconditioning::Sphere)
        }
        None | Some((_, "cell")) => Ok(Preconditioning::Cell { rebuild_after }),
        Some((k, other)) => Err(at(
            k.span(),
            format!("[numerics] preconditioner: unknown preconditioner \"{other}\" (sphere, cell)"),
        )),
    }
}

/// The cells of `[[cells]]` entry `k`; random placement keeps clear of the `earlier` entries' cells.
#[allow(clippy::too_many_arguments)]
fn cell_specs(
    c: &CellSection,
    k: usize,
    origin: Origin,
    earlier: &[CellSpec],
    at: &At,
    positive: &Check,
    finite: &Check,
    text: &str,
) -> Result<Vec<CellSpec>, SceneError> {
    let key = |name: &str| match origin {
        Origin::File => format!("[[cells]] #{} {name}", k + 1),
        Origin::Spec => format!("cells[{k}].{name}"),
    };
    let shape = match c.shape.get_ref().as_str() {
        "sphere" => Shape::Sphere,
        "rbc" => Shape::Rbc,
        "ellipsoid" => {
            let a = c.axes.as_ref().ok_or_else(|| {
                at(
                    c.shape.span(),
                    format!("{} = \"ellipsoid\" needs axes", key("shape")),
                )
            })?;
            if !a.get_ref().iter().all(|v| v.is_finite() && *v > 0.0) {
                return Err(at(
                    a.span(),
                    format!("{} must be three positive numbers", key("axes")),
                ));
            }
            Shape::Ellipsoid { axes: *a.get_ref() }
        }
        s @ ("prolate" | "oblate") => {
            let v = c.reduced_volume.as_ref().ok_or_else(|| {
                at(
                    c.shape.span(),
                    format!("{} = \"{s}\" needs reduced_volume", key("shape")),
                )
            })?;
            let x = *v.get_ref();
            if !(x > 0.0 && x < 1.0) {
                return Err(at(
                    v.span(),
                    format!("{} must be in (0, 1), got {x}", key("reduced_volume")),
                ));
            }
            Shape::Spheroid {
                kind: if s == "prolate" {
                    Spheroid::Prolate
                } else {
                    Spheroid::Oblate
                },
                reduced_volume: x,
            }
        }
        other => {
            return Err(at(
                c.shape.span(),
                format!(
                    "{}: unknown shape \"{other}\" (sphere, ellipsoid, rbc, prolate, oblate)",
                    key("shape")
                ),
            ))
        }
    };
    // Keys of other shapes are refused, not ignored.
    if let (Some(v), false) = (&c.reduced_volume, matches!(shape, Shape::Spheroid { .. })) {
        return Err(at(
            v.span(),
            format!(
                "{} applies to shape = \"prolate\" or \"oblate\" only, not \"{}\"",
                key("reduced_volume"),
                c.shape.get_ref()
            ),
        ));
    }
    if let (Some(a), false) = (&c.axes, matches!(shape, Shape::Ellipsoid { .. })) {
        return Err(at(
            a.span(),
            format!(
                "{} applies to shape = \"ellipsoid\" only, not \"{}\"",
                key("axes"),
                c.shape.get_ref()
            ),
        ));
    }
    let get = |v: &Option<Spanned<f64>>, name: &str, default: f64, pos: bool| match v {
        Some(v) if pos => positive(v, &key(name)),
        Some(v) => finite(v, &key(name)),
        None => Ok(default),
    };
    let radius = get(&c.radius, "radius", 1.0, true)?;
    let inextensible = match &c.membrane {
        None => true,
        Some(m) => match m.get_ref().as_str() {
            "vesicle" => true,
            "capsule" => false,
            other => {
                return Err(at(
                    m.span(),
                    format!(
                        "{}: unknown membrane \"{other}\" (vesicle, capsule)",
                        key("membrane")
                    ),
                ))
            }
        },
    };
    let elastic_law = match &c.elastic_law {
        None => ElasticLaw::Skalak,
        Some(m) => match m.get_ref().as_str() {
            "skalak" => ElasticLaw::Skalak,
            "neo_hookean" => ElasticLaw::NeoHookean,
            other => {
                return Err(at(
                    m.span(),
                    format!(
                        "{}: unknown elastic law \"{other}\" (skalak, neo_hookean)",
                        key("elastic_law")
                    ),
                ))
            }
        },
    };
    // A capsule may have no bending stiffness (the benchmarks have none).
    let bending = get(
        &c.bending_modulus,
        "bending_modulus",
        if inextensible { 0.05 } else { 0.0 },
        inextensible,
    )?;
    if bending < 0.0 {
        let sp = c.bending_modulus.as_ref().expect("set").span();
        return Err(at(
            sp,
            format!("{} must not be negative", key("bending_modulus")),
        ));
    }
    let shear = get(&c.shear_modulus, "shear_modulus", 0.0, false)?;
    if shear < 0.0 {
        let sp = c.shear_modulus.as_ref().expect("set").span();
        return Err(at(
            sp,
            format!("{} must not be negative", key("shear_modulus")),
        ));
    }
    if !inextensible && shear == 0.0 {
        let sp = c
            .shear_modulus
            .as_ref()
            .map_or(c.membrane.as_ref().expect("capsule").span(), |s| s.span());
        return Err(at(
            sp,
            format!(
                "{} = \"capsule\" needs {} > 0: a capsule resists deformation through its \
                 elastic law alone",
                key("membrane"),
                key("shear_modulus")
            ),
        ));
    }
    let skalak_c = get(&c.skalak_c, "skalak_c", 10.0, true)?;
    // Keys that would be silently ignored are refused.
    if let (Some(l), true) = (&c.elastic_law, shear == 0.0) {
        return Err(at(
            l.span(),
            format!(
                "{} needs {} > 0 (without it the membrane has no shear elasticity)",
                key("elastic_law"),
                key("shear_modulus")
            ),
        ));
    }
    if let (Some(k), ElasticLaw::NeoHookean) = (&c.skalak_c, elastic_law) {
        return Err(at(
            k.span(),
            format!(
                "{} applies to the Skalak law only, not to elastic_law = \"neo_hookean\"",
                key("skalak_c")
            ),
        ));
    }
    let lambda = get(&c.viscosity_ratio, "viscosity_ratio", 1.0, true)?;
    let vec3 = |v: &Option<Spanned<[f64; 3]>>, name: &str| -> Result<[f64; 3], SceneError> {
        match v {
            Some(v) if v.get_ref().iter().all(|x| x.is_finite()) => Ok(*v.get_ref()),
            Some(v) => Err(at(v.span(), format!("{} must be finite", key(name)))),
            None => Ok([0.0; 3]),
        }
    };
    let center = vec3(&c.center, "center")?;
    let force = vec3(&c.force, "force")?;
    let rot = match &c.orientation {
        Some(o) => {
            let v = o.get_ref();
            rotation([v[0], v[1], v[2]], v[3]).ok_or_else(|| {
                at(
                    o.span(),
                    format!(
                        "{} must be [axis_x, axis_y, axis_z, degrees] with a non-zero axis",
                        key("orientation")
                    ),
                )
            })?
        }
        None => [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    };
    // Bounding radius from the shape itself (order 12 is plenty for the extent).
    let unit =
        unit_shape(&shape, 12).map_err(|e| at(c.shape.span(), format!("{}: {e}", key("shape"))))?;
    let bounding = bounding_radius(&unit)
        .map_err(|e| at(c.shape.span(), format!("{}: {e}", key("shape"))))?
        * radius;
    let line = line_col(text, c.shape.span().start).0;
    let base = CellSpec {
        shape,
        radius,
        center,
        rotation: rot,
        bending_modulus: bending,
        shear_modulus: shear,
        skalak_c,
        elastic_law,
        inextensible,
        viscosity_ratio: lambda,
        force,
        bounding_radius: bounding,
        line,
    };
    let count = match &c.count {
        Some(n) if *n.get_ref() == 0 => {
            return Err(at(n.span(), format!("{} must be at least 1", key("count"))))
        }
        Some(n) => *n.get_ref(),
        None => 1,
    };
    let placement = c.placement.as_ref().map(|p| p.get_ref().as_str());
    if let (Some(r), false) = (&c.region, placement == Some("random")) {
        return Err(at(
            r.span(),
            format!(
                "{} applies to placement = \"random\" only (a lattice, and a single cell, are \
                 centred on center)",
                key("region")
            ),
        ));
    }
    if count == 1 && placement.is_none() {
        return Ok(vec![base]);
    }
    let spacing = match &c.spacing {
        Some(s) => positive(s, &key("spacing"))?,
        None => 2.2 * bounding,
    };
    let centers: Vec<[f64; 3]> = match placement.unwrap_or("lattice") {
        "lattice" => {
            let side = (count as f64).cbrt().ceil() as usize;
            let off = (side as f64 - 1.0) / 2.0;
            (0..count)
                .map(|i| {
                    let (a, b, cc) = (i % side, (i / side) % side, i / (side * side));
                    [
                        center[0] + spacing * (a as f64 - off),
                        center[1] + spacing * (b as f64 - off),
                        center[2] + spacing * (cc as f64 - off),
                    ]
                })
                .collect()
        }
        "random" => {
            let r = c.region.as_ref().ok_or_else(|| {
                at(
                    c.placement.as_ref().expect("set").span(),
                    format!(
                        "{} = \"random\" needs region = [[x0, y0, z0], [x1, y1, z1]]",
                        key("placement")
                    ),
                )
            })?;
            let [lo, hi] = *r.get_ref();
            if !(0..3).all(|d| hi[d] - lo[d] > 2.0 * bounding) {
                return Err(at(
                    r.span(),
                    format!("{} is too small for one cell", key("region")),
                ));
            }
            let mut rng = StdRng::seed_from_u64(c.seed.unwrap_or(1));
            let mut out: Vec<[f64; 3]> = Vec::with_capacity(count);
            // Bounding spheres 5 % apart, from this entry's cells and from earlier entries'.
            let gap = 2.0 * bounding * 1.05;
            let clear_of_earlier = |x: [f64; 3]| {
                earlier
                    .iter()
                    .all(|e| dist(x, e.center) >= 1.05 * (bounding + e.bounding_radius))
            };
            let mut tries = 0usize;
            while out.len() < count {
                tries += 1;
                if tries > 1000 * count {
                    let volume: f64 = (0..3).map(|d| hi[d] - lo[d]).product();
                    let ball = |r: f64| 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
                    let cell = ball(radius);
                    let inside = |e: &&CellSpec| {
                        (0..3).all(|d| e.center[d] >= lo[d] && e.center[d] <= hi[d])
                    };
                    let taken: f64 = earlier.iter().filter(inside).map(|e| ball(e.radius)).sum();
                    return Err(at(
                        r.span(),
                        format!(
                            "{}: could only place {} of {count} cells without overlap: they ask for a \
                             volume fraction of {:.1} % of the region{}; enlarge the region or lower \
                             the count",
                            key("region"),
                            out.len(),
                            100.0 * count as f64 * cell / volume,
                            if taken > 0.0 {
                                format!(
                                    ", where earlier [[cells]] entries already take {:.1} %",
                                    100.0 * taken / volume
                                )
                            } else {
                                String::new()
                            }
                        ),
                    ));
                }
                let x: [f64; 3] =
                    std::array::from_fn(|d| rng.random_range(lo[d] + bounding..hi[d] - bounding));
                if out.iter().all(|y| dist(x, *y) >= gap) && clear_of_earlier(x) {
                    out.push(x);
                }
            }
            out
        }
        other => {
            return Err(at(
                c.placement.as_ref().expect("set").span(),
                format!(
                    "{}: unknown placement \"{other}\" (lattice, random)",
                    key("placement")
                ),
            ))
        }
    };
    Ok(centers
        .into_iter()
        .map(|x| CellSpec {
            center: x,
            ..base.clone()
        })
        .collect())
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Largest distance of a grid point of the unit-size shape from its centroid.
fn bounding_radius(s: &Surface) -> Result<f64, crate::vesicle::VesicleError> {
    let mut s = s.clone();
    s.scale_to_equivalent_radius(1.0)?;
    s.place_centroid([0.0; 3])?;
    let sht = crate::sph_harmonics::ShTransform::new(s.order())
        .map_err(crate::vesicle::VesicleError::Sph)?;
    let g = s.grid_positions(&sht)?;
    let n = g.len() / 3;
    Ok((0..n)
        .map(|j| (g[j].powi(2) + g[n + j].powi(2) + g[2 * n + j].powi(2)).sqrt())
        .fold(0.0, f64::max))
}

/// Cells whose bounding spheres intersect are an error naming both.
fn check_overlaps(
    cells: &[CellSpec],
    file: &Path,
    entry: &dyn Fn(usize) -> String,
) -> Result<(), SceneError> {
    for i in 0..cells.len() {
        for j in 0..i {
            let d = dist(cells[i].center, cells[j].center);
            if d < cells[i].bounding_radius + cells[j].bounding_radius {
                return Err(SceneError {
                    file: file.to_path_buf(),
                    place: Some((cells[i].line, 1)),
                    message: format!(
                        "cells {} (of {}) and {} (of {}) overlap: centres {:.4} apart, bounding radii {:.4} and {:.4}",
                        j,
                        entry(cells[j].line),
                        i,
                        entry(cells[i].line),
                        d,
                        cells[j].bounding_radius,
                        cells[i].bounding_radius
                    ),
                });
            }
        }
    }
    Ok(())
}

/// Which physics the scene needs, each with its reason: simulate only what the scene calls for.
pub fn effects(cells: &[CellSpec], flow: &Flow) -> Vec<Effect> {
    let n = cells.len();
    let contrast: Vec<usize> = (0..n)
        .filter(|&i| (cells[i].viscosity_ratio - 1.0).abs() > 0.0)
        .collect();
    let shear: Vec<usize> = (0..n).filter(|&i| cells[i].shear_modulus > 0.0).collect();
    let capsules: Vec<usize> = (0..n).filter(|&i| !cells[i].inextensible).collect();
    let neo_hookean: Vec<usize> = shear
        .iter()
        .copied()
        .filter(|&i| cells[i].elastic_law == ElasticLaw::NeoHookean)
        .collect();
    let forced: Vec<usize> = (0..n).filter(|&i| cells[i].force != [0.0; 3]).collect();
    let list = |v: &[usize]| {
        let s: Vec<String> = v.iter().take(5).map(|i| i.to_string()).collect();
        format!("{}{}", s.join(", "), if v.len() > 5 { ", …" } else { "" })
    };
    vec![
        Effect {
            name: "fmm",
            enabled: n > 1,
            reason: if n > 1 {
                format!("{n} cells interact")
            } else {
                "one cell: no other cell to couple to".into()
            },
        },
        Effect {
            name: "double_layer",
            enabled: !contrast.is_empty(),
            reason: if contrast.is_empty() {
                "every viscosity_ratio is 1".into()
            } else {
                format!("viscosity_ratio ≠ 1 for cells {}", list(&contrast))
            },
        },
        Effect {
            name: "inter_cell_double_layer",
            enabled: n > 1 && !contrast.is_empty(),
            reason: if n < 2 {
                "one cell: its double layer is part of its own step".into()
            } else if contrast.is_empty() {
                "every viscosity_ratio is 1: cells feel only each other's single layer".into()
            } else {
                format!(
                    "viscosity_ratio ≠ 1 for cells {} and {n} cells interact: their double \
                     layer reaches the others (a stresslet FMM per step, membrane velocity of \
                     the previous step)",
                    list(&contrast)
                )
            },
        },
        Effect {
            name: "skalak",
            enabled: !shear.is_empty(),
            reason: if shear.is_empty() {
                "every shear_modulus is 0".into()
            } else if neo_hookean.is_empty() {
                format!("shear_modulus > 0 for cells {} (Skalak law)", list(&shear))
            } else {
                format!(
                    "shear_modulus > 0 for cells {} (neo-Hookean law for cells {})",
                    list(&shear),
                    list(&neo_hookean)
                )
            },
        },
        Effect {
            name: "capsule",
            enabled: !capsules.is_empty(),
            reason: if capsules.is_empty() {
                "every membrane is a locally inextensible vesicle".into()
            } else {
                format!(
                    "membrane = \"capsule\" for cells {}: no inextensibility constraint, the \
                     elastic force linearly implicit (unless [numerics] elasticity = \
                     \"explicit\"), material points followed (no reparametrisation), only the \
                     volume restored",
                    list(&capsules)
                )
            },
        },
        Effect {
            name: "background_flow",
            enabled: *flow != Flow::None,
            reason: match flow {
                Flow::None => "[flow] kind = \"none\" or absent".into(),
                f if f.follows_cells() => format!(
                    "{f:?}: stagnation point at the midpoint of the bounding box of the cells' \
                     centres, moved every step (frame = \"cells\"; positions and velocities in \
                     the summary are then those of this moving frame; \"lab\" keeps it at 0)"
                ),
                f => format!("{f:?}"),
            },
        },
        Effect {
            name: "body_force",
            enabled: !forced.is_empty(),
            reason: if forced.is_empty() {
                "no cell has a force".into()
            } else {
                format!("force set for cells {}", list(&forced))
            },
        },
    ]
}

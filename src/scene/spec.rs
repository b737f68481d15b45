//! Cell scenes written in code: [`SceneSpec`] is the scene file's schema as Rust types (every
//! section and key of [`super::cells`], each optional with the file's default), so that a
//! program and a file describe the same thing.
//!
//! * [`SceneSpec::build`] validates it into a [`CellScene`] with the file's own validation,
//!   so the errors are the same (they name the section and key; there is no line to name);
//! * [`SceneSpec::to_toml`] writes it as a scene file, [`SceneSpec::from_toml`] reads one
//!   back: `from_toml(to_toml(s)) == s`, and `parse(to_toml(s))` is `s.build()`.
//!
//! ```
//! use mobo::scene::spec::{CellGroupSpec, FlowKind, FlowSpec, NumericsSpec, SceneSpec, ShapeKind};
//!
//! let spec = SceneSpec {
//!     flow: Some(FlowSpec { kind: FlowKind::Shear, rate: Some(1.0), ..Default::default() }),
//!     cells: vec![
//!         CellGroupSpec { shear_modulus: Some(0.2), ..CellGroupSpec::new(ShapeKind::Rbc) },
//!         CellGroupSpec { center: Some([4.0, 0.0, 0.0]), ..CellGroupSpec::new(ShapeKind::Sphere) },
//!     ],
//!     numerics: Some(NumericsSpec { order: Some(8), dt: Some(0.01), ..Default::default() }),
//!     ..Default::default()
//! };
//! let scene = spec.build()?;
//! assert_eq!(scene.cells.len(), 2);
//! assert_eq!(SceneSpec::from_toml(&spec.to_toml()?)?, spec);
//! // The same validation as a file: a cell too close to another is refused.
//! let mut bad = spec.clone();
//! bad.cells[1].center = Some([0.5, 0.0, 0.0]);
//! assert!(bad.build().unwrap_err().to_string().contains("overlap"));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::cells::{parse_from, CellScene, Origin};
use super::SceneError;

/// The name a built scene's errors carry in place of a file.
const SOURCE: &str = "<scene spec>";

/// A whole cell scene: the sections of the file.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSpec {
    /// `[fluid]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fluid: Option<FluidSpec>,
    /// `[flow]` (absent: quiescent fluid).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flow: Option<FlowSpec>,
    /// `[[cells]]`, one entry per group of cells (at least one).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub cells: Vec<CellGroupSpec>,
    /// `[numerics]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub numerics: Option<NumericsSpec>,
    /// `[output]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub output: Option<OutputSpec>,
    /// `[[walls]]`, rigid walls (none: free space).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub walls: Vec<WallEntrySpec>,
    /// `[units]` (absent: the numbers are the solver's own; see [`super::units`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub units: Option<UnitsSpec>,
}

/// `[units]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UnitsSpec {
    /// `system`.
    pub system: UnitSystem,
}

/// `[units] system`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum UnitSystem {
    /// The file's numbers are SI values, made dimensionless by the first cells' radius and
    /// modulus and the fluid's viscosity.
    #[serde(rename = "SI")]
    Si,
    /// The numbers are the solver's own (the default).
    #[serde(rename = "dimensionless")]
    Dimensionless,
}

/// `[[walls]] kind`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WallKindSpec {
    /// The fluid inside.
    Container,
    /// A fixed obstacle, the fluid outside.
    Body,
}

/// `[[walls]] shape`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WallShapeKind {
    /// Needs `radius`.
    Sphere,
    /// Needs `axes`.
    Ellipsoid,
    /// Needs `radius` and `length` (axis along x).
    Tube,
    /// Needs `length` (along x), `width` (along y) and `height` (along z, plate to plate).
    Channel,
    /// Needs `positions`: a `.npy` file of the surface's points on the spherical grid.
    Grid,
    /// Needs `normal` (into the fluid); `center` is a point of it. `kind` is `body`.
    Plane,
}

/// One `[[walls]]` entry ([`super::walls`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WallEntrySpec {
    /// `kind`.
    pub kind: WallKindSpec,
    /// `shape`.
    pub shape: WallShapeKind,
    /// `radius` of a sphere.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// `axes` of an ellipsoid.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub axes: Option<[f64; 3]>,
    /// `length` of a tube or a channel (end to end).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub length: Option<f64>,
    /// `width` of a channel (side to side).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub width: Option<f64>,
    /// `height` of a channel (plate to plate).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub height: Option<f64>,
    /// `center` (default the origin).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub center: Option<[f64; 3]>,
    /// `order` (default 16, a tube or a channel 32).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub order: Option<usize>,
    /// `angular_velocity`: the wall turns about its centre (about an axis of symmetry).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub angular_velocity: Option<[f64; 3]>,
    /// `positions` of a grid wall: the `.npy` file of its points on the spherical grid (a
    /// relative name starts from the working directory: a spec has no scene file).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub positions: Option<String>,
    /// `velocity` of a grid wall: the `.npy` file of its velocity at the same points (named
    /// as `positions`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub velocity: Option<String>,
    /// `normal` of a plane, pointing into the fluid.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub normal: Option<[f64; 3]>,
}

/// `[fluid]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FluidSpec {
    /// `viscosity`: μ of the suspending fluid.
    pub viscosity: f64,
}

/// `[flow] kind`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FlowKind {
    /// Quiescent fluid.
    #[default]
    None,
    /// `u = (γ̇ y, 0, 0)`; needs `rate`.
    Shear,
    /// `u = ε̇ (x, −y, 0)`; needs `rate`; `frame` says where the stagnation point is.
    Extensional,
    /// `u = (U (1 − (y² + z²)/R²), 0, 0)`; needs `speed` and `radius`.
    Poiseuille,
    /// Poiseuille's flow through the scene's tube wall; needs one of `flow_rate`,
    /// `mean_speed`, `speed`, `pressure_gradient`.
    Tube,
    /// Plane Poiseuille flow between the plates of the scene's channel wall; needs one of
    /// `mean_speed`, `speed`, `pressure_gradient`.
    Channel,
}

/// `[flow] frame` of an extensional flow.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FrameKind {
    /// The stagnation point follows the cells (the default).
    Cells,
    /// The stagnation point stays at the origin.
    Lab,
}

/// `[flow]`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlowSpec {
    /// `kind`.
    pub kind: FlowKind,
    /// `rate`: shear rate or strain rate.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rate: Option<f64>,
    /// `speed`: Poiseuille centreline speed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub speed: Option<f64>,
    /// `radius`: Poiseuille radius.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// `flow_rate` through a tube.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flow_rate: Option<f64>,
    /// `mean_speed` through a tube or a channel.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mean_speed: Option<f64>,
    /// `pressure_gradient` `−dp/dx` along a tube or a channel.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pressure_gradient: Option<f64>,
    /// `recycle`: cells leaving a tube's straight section re-enter it upstream.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub recycle: Option<bool>,
    /// `frame` of an extensional flow.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frame: Option<FrameKind>,
}

/// `[[cells]] shape`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ShapeKind {
    /// A sphere.
    Sphere,
    /// An ellipsoid; needs `axes`.
    Ellipsoid,
    /// The biconcave red blood cell.
    Rbc,
    /// A prolate spheroid; needs `reduced_volume`.
    Prolate,
    /// An oblate spheroid; needs `reduced_volume`.
    Oblate,
}

/// `[[cells]] placement`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PlacementKind {
    /// On a cubic lattice of `spacing` about `center`.
    Lattice,
    /// At random in `region`, clear of each other and of earlier groups.
    Random,
    /// Packed at `volume_fraction` in a cube about `center`, surfaces `min_gap` apart; in a
    /// scene with a container wall, in the fluid it bounds, the count then fixed by the volume
    /// fraction (leave `count` out) ([`crate::scene::packing`]).
    Packed,
}

/// One `[[cells]]` entry: a cell, or `count` cells placed alike.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CellGroupSpec {
    /// `shape`.
    pub shape: ShapeKind,
    /// `radius`: equivalent radius (default 1).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// `center`: centroid (default the origin).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub center: Option<[f64; 3]>,
    /// `axes` of an ellipsoid.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub axes: Option<[f64; 3]>,
    /// `reduced_volume` of a spheroid, in (0, 1).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reduced_volume: Option<f64>,
    /// `orientation`: rotation axis and angle in degrees.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub orientation: Option<[f64; 4]>,
    /// `bending_modulus` (default 0.05).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bending_modulus: Option<f64>,
    /// `shear_modulus`: Skalak `G_s` (default 0: none).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shear_modulus: Option<f64>,
    /// `skalak_c`: Skalak area-dilation parameter (default 10).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub skalak_c: Option<f64>,
    /// `prestress`: inflation ratio `α` in [0, 1) of a membrane with shear elasticity, whose
    /// stress-free reference is the shape scaled by `1/(1 + α)` (default 0).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prestress: Option<f64>,
    /// `membrane`: an inextensible vesicle/RBC (default) or an elastic capsule.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub membrane: Option<MembraneKind>,
    /// `elastic_law` of the shear elasticity (default Skalak).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub elastic_law: Option<ElasticLawKind>,
    /// `viscosity_ratio`: `λ = μ_in/μ_out` (default 1).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub viscosity_ratio: Option<f64>,
    /// `force`: body force per cell.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub force: Option<[f64; 3]>,
    /// `count` of cells in the group (default 1; none for a group packed in a container).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub count: Option<usize>,
    /// `placement` of a group.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub placement: Option<PlacementKind>,
    /// `spacing` of a lattice (default 2.2 bounding radii).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub spacing: Option<f64>,
    /// `region` of random placement: lower and upper corners.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub region: Option<[[f64; 3]; 2]>,
    /// `seed` of random and packed placement (default 1).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// `volume_fraction` of packed placement, in (0, 0.6].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub volume_fraction: Option<f64>,
    /// `min_gap` of packed placement: the smallest surface gap (default 0.05 radius).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_gap: Option<f64>,
}

impl CellGroupSpec {
    /// One cell of `shape` with every other key at its default.
    pub fn new(shape: ShapeKind) -> Self {
        CellGroupSpec {
            shape,
            radius: None,
            center: None,
            axes: None,
            reduced_volume: None,
            orientation: None,
            bending_modulus: None,
            shear_modulus: None,
            skalak_c: None,
            prestress: None,
            membrane: None,
            elastic_law: None,
            viscosity_ratio: None,
            force: None,
            count: None,
            placement: None,
            spacing: None,
            region: None,
            seed: None,
            volume_fraction: None,
            min_gap: None,
        }
    }
}

/// `[[cells]] membrane`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MembraneKind {
    /// Locally inextensible (vesicles, RBCs): the tension is an unknown of the step.
    Vesicle,
    /// Elastic, area free (capsules): resists through its `elastic_law` alone.
    Capsule,
}

/// `[[cells]] elastic_law`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ElasticLawKind {
    /// Skalak, with `skalak_c`.
    Skalak,
    /// Neo-Hookean.
    NeoHookean,
}

/// `[numerics] elasticity`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ElasticityKind {
    /// Linearly implicit for capsules, explicit for inextensible cells.
    Auto,
    /// At the operators' geometry.
    Explicit,
    /// Linearised (a Jacobian-vector product per GMRES iteration).
    Implicit,
}

/// `[numerics] grid`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GridKind {
    /// Material points on cells with shear elasticity, relaxed on vesicles without.
    Auto,
    /// Every inextensible cell's grid relaxed after every step.
    Relaxed,
    /// Every grid point follows the material.
    Material,
}

/// `[numerics] scheme`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SchemeKind {
    /// First-order semi-implicit.
    Euler,
    /// Second-order BDF2.
    Bdf2,
}

/// `[numerics] operator_storage`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StorageKind {
    /// The fastest that fits in memory.
    Auto,
    /// Dense operators on the grid.
    Grid,
    /// Dense operators in coefficient space.
    Coefficients,
    /// Not stored.
    MatrixFree,
}

/// `[numerics] preconditioner`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PreconditionerKind {
    /// The inverse step operator of the cell's area-equivalent sphere.
    Sphere,
    /// The inverse of the cell's own step operator, rebuilt when stale (the default).
    Cell,
}

/// `[numerics] coupling`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CouplingKind {
    /// Near-implicit with two or more cells, else explicit (the default;
    /// [`crate::scene::dense_defaults`]).
    Auto,
    /// Every other cell through last step's densities.
    Explicit,
    /// Cells in each other's near zone solved as one system.
    NearImplicit,
}

/// `[numerics]`; every key optional (defaults as in the file's schema).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NumericsSpec {
    /// `order`: SH order `p`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub order: Option<usize>,
    /// `upsample`: quadrature order `q = upsample · p`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub upsample: Option<usize>,
    /// `fmm_digits`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fmm_digits: Option<u32>,
    /// `gmres_tol`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gmres_tol: Option<f64>,
    /// `dt`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dt: Option<f64>,
    /// `t_end`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub t_end: Option<f64>,
    /// `scheme`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scheme: Option<SchemeKind>,
    /// `elasticity`: how the elastic force enters the step.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub elasticity: Option<ElasticityKind>,
    /// `grid`: how the cells' grid points move.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub grid: Option<GridKind>,
    /// `adaptive_dt`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adaptive_dt: Option<bool>,
    /// `far_side_split`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub far_side_split: Option<bool>,
    /// `operator_storage`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub operator_storage: Option<StorageKind>,
    /// `preconditioner`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preconditioner: Option<PreconditionerKind>,
    /// `preconditioner_rebuild_after` (with `preconditioner = "cell"`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub preconditioner_rebuild_after: Option<u64>,
    /// `dt_tolerance` of the adaptive step.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dt_tolerance: Option<f64>,
    /// `dt_min` of the adaptive step.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dt_min: Option<f64>,
    /// `dt_max` of the adaptive step.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dt_max: Option<f64>,
    /// `repulsion_range` of the contact repulsion.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub repulsion_range: Option<f64>,
    /// `repulsion_strength` of the contact repulsion.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub repulsion_strength: Option<f64>,
    /// `rebalance_every` (MPI runs).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rebalance_every: Option<u64>,
    /// `max_imbalance` (MPI runs).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_imbalance: Option<f64>,
    /// `coupling`: how the cells' coupling enters a step.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub coupling: Option<CouplingKind>,
    /// `contact_distance`: the smallest surface gap `d_min` the contact projection keeps at
    /// the end of every step (absent: `0.4 · R_min / p` with two cells or a cell and a wall,
    /// [`crate::scene::dense_defaults`]; 0: no projection).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub contact_distance: Option<f64>,
    /// `implicit_zone`: the width of the near-implicit coupling's zone in units of `R/√p`
    /// (absent: 8, or `8 √(p/8)` above `p = 8`; at least 2).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub implicit_zone: Option<f64>,
    /// `start_up_passes`: the most first steps solved and thrown away to start coupled cells
    /// from a consistent tension and membrane velocity (absent: 8; 0: none).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub start_up_passes: Option<u64>,
    /// `start_up_anderson_depth`: the passes whose densities Anderson's method mixes into the
    /// next pass's (absent: 3; 0: plain passes).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub start_up_anderson_depth: Option<u64>,
    /// `gpu`: `"auto"`, `true` or `false`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gpu: Option<GpuSpec>,
    /// `wall_solve`: how the walls' system is held over MPI ranks.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wall_solve: Option<WallSolveKind>,
}

/// `[numerics] wall_solve` ([`crate::scene::cells::WallSolve`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WallSolveKind {
    /// Split with two or more ranks.
    Auto,
    /// Every rank the whole system.
    Replicated,
    /// Each rank its band's rows.
    Split,
}

/// `[numerics] gpu`: written `"auto"`, `true` or `false` in the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GpuSpec {
    /// `"auto"`: the GPU near field where it pays.
    Auto,
    /// `true`: the GPU near field.
    On,
    /// `false`: the CPU near field.
    Off,
}

/// How `gpu` is written: a flag or a word.
#[derive(Serialize, Deserialize)]
#[serde(untagged)]
enum GpuWritten {
    Flag(bool),
    Word(String),
}

impl Serialize for GpuSpec {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            GpuSpec::Auto => GpuWritten::Word("auto".into()),
            GpuSpec::On => GpuWritten::Flag(true),
            GpuSpec::Off => GpuWritten::Flag(false),
        }
        .serialize(s)
    }
}

impl<'de> Deserialize<'de> for GpuSpec {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        match GpuWritten::deserialize(d)? {
            GpuWritten::Flag(true) => Ok(GpuSpec::On),
            GpuWritten::Flag(false) => Ok(GpuSpec::Off),
            GpuWritten::Word(w) if w == "auto" => Ok(GpuSpec::Auto),
            GpuWritten::Word(w) => Err(serde::de::Error::custom(format!(
                "gpu must be \"auto\", true or false, got \"{w}\""
            ))),
        }
    }
}

/// `[output]`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputSpec {
    /// `every`: steps between frames.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub every: Option<u64>,
    /// `npy` frames.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub npy: Option<bool>,
    /// `vtk` frames.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vtk: Option<bool>,
    /// `hdf5` frames.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hdf5: Option<bool>,
    /// `mesh_subdivisions` of the VTK meshes.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mesh_subdivisions: Option<u32>,
    /// `checkpoint_every` steps.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub checkpoint_every: Option<u64>,
    /// `velocity_plane`: the velocity sampled on a plane grid at every frame.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub velocity_plane: Option<PlaneSpec>,
}

/// `[output] velocity_plane` ([`crate::scene::velocity_plane`]).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneSpec {
    /// The corner of the parallelogram.
    pub origin: [f64; 3],
    /// The edge along which the first index runs.
    pub u: [f64; 3],
    /// The edge along which the second index runs.
    pub v: [f64; 3],
    /// `[n_u, n_v]` points along the edges.
    pub points: [usize; 2],
}

impl SceneSpec {
    /// The scene as a scene file.
    pub fn to_toml(&self) -> Result<String, SceneError> {
        toml::to_string(self).map_err(|e| SceneError {
            file: SOURCE.into(),
            place: None,
            message: format!("cannot write the scene as TOML: {e}"),
        })
    }

    /// A scene file's text as a spec (the schema only: [`SceneSpec::build`] validates; a
    /// `[dpd]` section, `mobo dpd`'s part of the file, is left out).
    pub fn from_toml(text: &str) -> Result<Self, SceneError> {
        let err = |e: toml::de::Error| SceneError {
            file: SOURCE.into(),
            place: None,
            message: e.message().to_string(),
        };
        let mut table: toml::Table = toml::from_str(text).map_err(err)?;
        // `[dpd]` is `mobo dpd`'s part of a file that runs both ways (`crate::scene::dpd`).
        table.remove("dpd");
        table.try_into().map_err(err)
    }

    /// Validate into a [`CellScene`], with the scene file's validation: the same checks and
    /// messages (section and key named; no line, which a spec does not have).
    pub fn build(&self) -> Result<CellScene, SceneError> {
        let text = self.to_toml()?;
        parse_from(Path::new(SOURCE), &text, Origin::Spec)
            .map_err(|e| SceneError { place: None, ..e })
    }
}

//! A validated cell scene ([`CellScene`]): the fluid, the flow, every cell ([`CellSpec`]),
//! the numerics and the output, as [`super::cells::parse`] and
//! [`super::spec::SceneSpec::build`] produce it.

use super::units::{Groups, UnitScales};
use crate::gpu::GpuChoice;
use crate::timestep::near_implicit::CouplingMode;
use crate::timestep::semi_implicit::{ElasticStepping, OperatorStorage, Preconditioning};
use crate::vesicle::shapes::{self, Spheroid, Surface};
use crate::vesicle::skalak::ElasticLaw;
use crate::wall::{channel_surface, tube_surface, WallError, WallKind};

/// The lowest SH order that holds the red blood cell's shape ([`shapes::rbc`]: its height is
/// `sin⁴θ cosθ` at most, a polynomial of degree 5).
pub const RBC_MIN_ORDER: usize = 5;

/// Steps between checks of the split of the cells over ranks (`[numerics] rebalance_every`'s
/// default; [`crate::run::partition`]).
pub const REBALANCE_EVERY: usize = 10;

/// Cost imbalance above which cells are moved between ranks (`[numerics] max_imbalance`'s
/// default; [`crate::run::partition`]).
pub const MAX_IMBALANCE: f64 = 0.10;

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
    /// The flow's velocity sampled on a plane at every frame (`[output] velocity_plane`;
    /// default none).
    pub velocity_plane: Option<super::velocity_plane::VelocityPlane>,
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
    /// Poiseuille's flow through the scene's tube wall (`[flow] kind = "tube"`):
    /// `u = (U (1 − (y² + z²)/R²), 0, 0)` with `R` the tube's radius; the tube's wall takes
    /// this velocity (zero on its side, the inflow and outflow across its ends).
    Tube {
        /// Centreline speed `U` (from `flow_rate` `Q = πR²U/2`, `mean_speed` `U/2`, `speed`,
        /// or `pressure_gradient` `G = 4μU/R²`).
        speed: f64,
        /// The tube's radius `R`.
        radius: f64,
    },
    /// Plane Poiseuille flow through the scene's channel wall (`[flow] kind = "channel"`):
    /// `u = (U (1 − z²/H²), 0, 0)` with `2H` the channel's height (plate to plate, the plates
    /// at `z = ±H`); the channel's wall takes this velocity (zero on the plates, the undisturbed
    /// flow across its sides and ends).
    Channel {
        /// Centreline speed `U` (from `mean_speed` `2U/3`, `speed`, or `pressure_gradient`
        /// `G = 2μU/H²`).
        speed: f64,
        /// Half the channel's height, `H`.
        half_height: f64,
    },
}

/// The straight middle section of a tube, through which cells are recycled (`[flow] recycle =
/// true`; [`crate::timestep::suspension::Recycling`]): a cell whose centre passes `outlet` is
/// moved back by `outlet − inlet`. It is where the tube's radius is within
/// [`TUBE_WINDOW_TOLERANCE`] of its value ([`crate::wall::straight_length`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TubeWindow {
    /// Where cells re-enter (`x`).
    pub inlet: f64,
    /// Where cells leave (`x`).
    pub outlet: f64,
    /// The tube's centre, on its axis (parallel to `x`): recycled cells may land turned about
    /// the axis.
    pub axis: [f64; 3],
}

/// The relative departure of a tube's radius from `R` that bounds its recycling window.
pub const TUBE_WINDOW_TOLERANCE: f64 = 1e-3;

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

    /// The flow's rate scale `γ̇`: the shear or strain rate, `|U|/R` of a Poiseuille or tube
    /// flow, `|U|/H` of a channel flow, 0 without a flow.
    pub fn rate_scale(&self) -> f64 {
        match *self {
            Flow::None => 0.0,
            Flow::Shear { rate } | Flow::Extensional { rate, .. } => rate.abs(),
            Flow::Poiseuille { speed, radius } | Flow::Tube { speed, radius } => {
                (speed / radius).abs()
            }
            Flow::Channel { speed, half_height } => (speed / half_height).abs(),
        }
    }

    /// The background flow's stress `σ₀ = −p₀ I + μ (∇u₀ + ∇u₀ᵀ)` at `x` (lab frame) in a
    /// fluid of viscosity `mu`, up to a constant pressure: the pressure gradient
    /// `∇p₀ = −(4μU/R²) e_x` of a Poiseuille or tube flow and `−(2μU/H²) e_x` of a channel
    /// flow (taken zero at `x = 0`), and the rate of
    /// strain of every flow (an extensional flow's is the same about any origin).
    pub fn stress(&self, x: [f64; 3], mu: f64) -> [[f64; 3]; 3] {
        match *self {
            Flow::None => [[0.0; 3]; 3],
            Flow::Shear { rate } => [
                [0.0, mu * rate, 0.0],
                [mu * rate, 0.0, 0.0],
                [0.0, 0.0, 0.0],
            ],
            Flow::Extensional { rate, .. } => [
                [2.0 * mu * rate, 0.0, 0.0],
                [0.0, -2.0 * mu * rate, 0.0],
                [0.0, 0.0, 0.0],
            ],
            Flow::Poiseuille { speed, radius } | Flow::Tube { speed, radius } => {
                let r2 = radius * radius;
                let minus_p = 4.0 * mu * speed / r2 * x[0];
                let (sy, sz) = (-2.0 * mu * speed * x[1] / r2, -2.0 * mu * speed * x[2] / r2);
                [[minus_p, sy, sz], [sy, minus_p, 0.0], [sz, 0.0, minus_p]]
            }
            Flow::Channel { speed, half_height } => {
                let h2 = half_height * half_height;
                let minus_p = 2.0 * mu * speed / h2 * x[0];
                let sz = -2.0 * mu * speed * x[2] / h2;
                [[minus_p, 0.0, sz], [0.0, minus_p, 0.0], [sz, 0.0, minus_p]]
            }
        }
    }

    /// The background velocity at `x` (lab frame).
    pub fn velocity(&self, x: [f64; 3]) -> [f64; 3] {
        match *self {
            Flow::None => [0.0; 3],
            Flow::Shear { rate } => [rate * x[1], 0.0, 0.0],
            Flow::Extensional { rate, .. } => [rate * x[0], -rate * x[1], 0.0],
            Flow::Poiseuille { speed, radius } | Flow::Tube { speed, radius } => [
                speed * (1.0 - (x[1] * x[1] + x[2] * x[2]) / (radius * radius)),
                0.0,
                0.0,
            ],
            Flow::Channel { speed, half_height } => [
                speed * (1.0 - x[2] * x[2] / (half_height * half_height)),
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
    /// is stress-free at its initial shape unless [`Self::prestress`] says otherwise.
    pub shear_modulus: f64,
    /// Skalak area-dilation parameter `C` (large `C`: nearly area-preserving; default 10).
    pub skalak_c: f64,
    /// Prestress (inflation ratio) `α ≥ 0` of a membrane with shear elasticity: its
    /// stress-free reference is the initial shape scaled by `1/(1 + α)` about the centroid, so
    /// the cell starts inflated, every line element stretched by `1 + α` (Lac, Morel &
    /// Barthès-Biesel, J. Fluid Mech. 573, 2007, take `α = 0.05` so that a capsule's membrane
    /// is never compressed). Default 0: stress-free at the initial shape.
    pub prestress: f64,
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

    /// The stress-free reference of the cell's shear elasticity at order `p`: its initial
    /// [`Self::surface`] scaled about the centroid by `1/(1 + α)`, `α` the
    /// [`Self::prestress`] (the surface itself when `α = 0`).
    pub fn reference_surface(&self, p: usize) -> Result<Surface, crate::vesicle::VesicleError> {
        let mut s = self.surface(p)?;
        if self.prestress != 0.0 {
            s.scale_to_equivalent_radius(self.radius / (1.0 + self.prestress))?;
        }
        Ok(s)
    }
}

/// How the grid points of a cell move (`[numerics] grid`).
///
/// A locally inextensible membrane without shear elasticity (a vesicle) has no material
/// memory: tank-treading carries its grid points along the membrane and bunches them, so its
/// grid is relaxed after every step ([`crate::vesicle::reparam`]). A membrane with shear
/// elasticity (an RBC, a capsule) remembers its reference: its grid points follow the material,
/// and the elastic strain itself bounds how far they bunch. Relaxing such a grid relabels the
/// elastic reference by a re-fit at order `p` every step, and at low order that re-fit's strain
/// feeds back into the explicit elastic force: a lone RBC (Skalak, `G_s = 1`, `λ = 5`, p = 8)
/// taken from a dense suspension blows up within 15 steps with its grid relaxed and runs on
/// with it following the material (docs/hard_cases.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum GridMotion {
    /// The grid of a cell with shear elasticity follows its material points; that of a
    /// locally inextensible cell without shear elasticity is relaxed after every step (the
    /// default).
    #[default]
    Auto,
    /// The grid of every locally inextensible cell is relaxed after every step, shear
    /// elasticity or not (a capsule's always follows its material points).
    Relaxed,
    /// Every grid point follows the material.
    Material,
}

impl GridMotion {
    /// Whether the grid of `cell` is relaxed after every step.
    pub fn relaxes(self, cell: &CellSpec) -> bool {
        match self {
            GridMotion::Auto => cell.inextensible && cell.shear_modulus <= 0.0,
            GridMotion::Relaxed => cell.inextensible,
            GridMotion::Material => false,
        }
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
    /// How the cells' grid points move (`[numerics] grid`; default [`GridMotion::Auto`]).
    pub grid: GridMotion,
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
    /// How the cells' coupling enters a step (`[numerics] coupling`; default `"auto"`,
    /// resolved by [`crate::scene::dense_defaults::auto_coupling`]; see
    /// [`crate::timestep::near_implicit`]).
    pub coupling: CouplingMode,
    /// The smallest surface gap `d_min` kept at the end of every step by the contact
    /// projection (`[numerics] contact_distance`, a length; `None`: off; absent from the file,
    /// [`crate::scene::dense_defaults::auto_contact_distance`]; [`crate::timestep::contact`]).
    pub contact_distance: Option<f64>,
    /// The width of the zone in which near cells are coupled inside the solve, in units of
    /// `R/√p` (`[numerics] implicit_zone`, default
    /// [`crate::timestep::near_implicit::default_implicit_zone`]; at least 2, the coupling's
    /// near-singular zone; see [`crate::timestep::near_implicit`]).
    pub implicit_zone: f64,
    /// The most start-up passes before the first step of a coupled scene (`[numerics]
    /// start_up_passes`, default [`crate::timestep::suspension::START_UP_PASSES`]; 0: none;
    /// see [`crate::timestep::suspension`]'s start-up).
    pub start_up_passes: usize,
    /// The depth of Anderson's mixing of the start-up passes (`[numerics]
    /// start_up_anderson_depth`, default
    /// [`crate::timestep::suspension::START_UP_ANDERSON_DEPTH`]; 0: plain passes).
    pub start_up_anderson_depth: usize,
    /// The FMM's near field on a GPU: `"auto"` (default), `true` or `false`
    /// ([`crate::fmm::gpu_near::choose`]).
    pub gpu: GpuChoice,
    /// How the walls' dense system is held under `mpirun` (`[numerics] wall_solve`).
    pub wall_solve: WallSolve,
}

/// How the walls' dense system is held over MPI ranks (`[numerics] wall_solve`).
///
/// Measured on the order-40 tube of `examples/scenes/rbc_in_a_tube.toml` (9840 unknowns, a
/// 0.78 GB operator), 2 ranks on 2 cores (docs/walls.md): split, a rank's process peaks at
/// 1.5 GB instead of 2.4 GB and the setup takes 8 s instead of 21 s, but each solve takes 12
/// GMRES iterations that stream the rank's rows, 3.7 times the replicated direct solve. The
/// rows shrink as `1/P` and the iterations grow slowly with the ranks `P`, so the split pays in
/// time too from about a dozen ranks, and in memory from two.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum WallSolve {
    /// Split with two or more ranks when the whole operator would take more than
    /// [`WALL_SPLIT_BYTES`] on every rank, or when every rank's copy (twice the operator while
    /// it is factored) would take more than 60 % of the memory available, the ranks taken to
    /// share one machine (on several machines the split comes sooner than it must);
    /// replicated otherwise (the default).
    #[default]
    Auto,
    /// Every rank holds the whole system and its LU factors, and solves it alone: the same
    /// bits on every rank count, `8 (3N)²` bytes a rank.
    Replicated,
    /// Each rank holds the rows of its band of the walls' grid and the factors of their
    /// diagonal block; the system is solved by GMRES over the ranks
    /// ([`crate::wall::WallRows`]), to a relative residual of 1e-13.
    Split,
}

/// The size of the walls' whole operator above which [`WallSolve::Auto`] splits it over the
/// ranks (1 GiB; its factorisation holds twice that at its peak).
pub const WALL_SPLIT_BYTES: u64 = 1 << 30;

impl WallSolve {
    /// Whether walls whose whole operator takes `whole_bytes` are split over `ranks` ranks, on
    /// a machine with `available` bytes of memory free (`None`: unknown).
    pub fn splits(self, ranks: usize, whole_bytes: u64, available: Option<u64>) -> bool {
        match self {
            WallSolve::Replicated => false,
            WallSolve::Split => ranks > 1,
            WallSolve::Auto => {
                let crowded = available
                    .is_some_and(|a| 2 * whole_bytes as u128 * ranks as u128 > a as u128 / 10 * 6);
                ranks > 1 && (whole_bytes > WALL_SPLIT_BYTES || crowded)
            }
        }
    }
}

/// One assembly decision: whether a piece of physics is built, and why.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Effect {
    /// What is built: `"fmm"`, `"double_layer"`, `"inter_cell_double_layer"`, `"skalak"`,
    /// `"background_flow"`, `"body_force"`, `"material_grid"` (grid points that follow the
    /// material instead of being relaxed), `"adaptive_dt"`, `"walls"`, `"units"` (a scene in
    /// SI units, with its scales), or (in a run's summary, where memory left them out)
    /// `"cell_preconditioner"`.
    pub name: &'static str,
    /// Whether it is built.
    pub enabled: bool,
    /// Why, in words (e.g. `"viscosity_ratio ≠ 1 for cells 0, 2"`).
    pub reason: String,
}

/// A validated cell scene.
#[derive(Clone, Debug, PartialEq)]
pub struct CellScene {
    /// The window of a tube through which cells are recycled (`[flow] recycle = true`;
    /// `None`: off).
    pub recycle: Option<TubeWindow>,
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
    /// What the scene needs, decided from its contents (see [`super::cells::effects`]).
    pub effects: Vec<Effect>,
    /// Rigid walls (`[[walls]]`; none: free space).
    pub walls: Vec<WallSpec>,
    /// A plane wall (`[[walls]] shape = "plane"`; then no other wall).
    pub plane: Option<PlaneSpec>,
    /// The physical scales of a scene written in SI units (`[units] system = "SI"`; `None`:
    /// the file's numbers are the solver's own). Every value above is dimensionless.
    pub units: Option<UnitScales>,
    /// What each packed placement achieved (`placement = "packed"`; in `summary.json`).
    pub packings: Vec<super::packing_report::PackingReport>,
}

impl CellScene {
    /// The dimensionless groups of the first cells (`None` without cells; in `summary.json`).
    pub fn groups(&self) -> Option<Groups> {
        let c = self.cells.first()?;
        Some(Groups::of(
            self.viscosity,
            self.flow.rate_scale(),
            c.radius,
            c.shear_modulus,
            c.bending_modulus,
            c.viscosity_ratio,
        ))
    }
}

/// The shape of a wall.
#[derive(Clone, Debug, PartialEq)]
pub enum WallShape {
    /// A sphere of the given radius.
    Sphere {
        /// Its radius.
        radius: f64,
    },
    /// An ellipsoid with semi-axes along x, y, z.
    Ellipsoid {
        /// The semi-axes.
        axes: [f64; 3],
    },
    /// A tube along x with rounded ends ([`crate::wall::tube_surface`]).
    Tube {
        /// Its radius.
        radius: f64,
        /// Its length end to end.
        length: f64,
    },
    /// A planar channel along x, its plates normal to z, closed into a rounded box
    /// ([`crate::wall::channel_surface`]).
    Channel {
        /// Its length end to end (along x).
        length: f64,
        /// Its width side to side (along y).
        width: f64,
        /// Its height plate to plate (along z).
        height: f64,
    },
    /// A surface given by the user as points on the spherical grid (`shape = "grid"`,
    /// [`super::walls`]): its order-`p` coefficients, and those of the velocity given at
    /// the same points (none: at rest).
    Grid {
        /// The order of the given grid.
        p: usize,
        /// The surface's coefficients (x, y, z) at order `p`, in the scene's units, before
        /// the wall's `center` is added.
        coefs: std::sync::Arc<Vec<f64>>,
        /// The boundary velocity's coefficients (x, y, z) at order `p`.
        velocity: Option<std::sync::Arc<Vec<f64>>>,
    },
}

/// A file a wall was read from: which key, the file, and where its name is in the scene's
/// text (so that a run can copy the file beside its scene copy).
#[derive(Clone, Debug, PartialEq)]
pub struct WallFile {
    /// `positions` or `velocity`.
    pub key: &'static str,
    /// The file as resolved (relative names from the scene file's folder).
    pub path: std::path::PathBuf,
    /// The span of the quoted name in the scene's text.
    pub span: std::ops::Range<usize>,
}

/// One validated `[[walls]]` entry.
#[derive(Clone, Debug, PartialEq)]
pub struct WallSpec {
    /// Container or body.
    pub kind: WallKind,
    /// Its shape.
    pub shape: WallShape,
    /// Its centre.
    pub center: [f64; 3],
    /// Its spherical-harmonic order.
    pub order: usize,
    /// Its angular velocity about its centre (zero: at rest). The wall keeps its shape and
    /// place: the turn is about an axis of symmetry (any axis of a sphere, the axis of a
    /// spheroid, the axis of a tube), and its surface velocity `Ω × (x − c)` is tangential.
    pub angular_velocity: [f64; 3],
    /// The line of its entry (1-based; 0 for a spec).
    pub line: usize,
    /// The files a grid wall was read from.
    pub files: Vec<WallFile>,
}

/// A plane wall at rest (`[[walls]] shape = "plane"`, [`crate::wall::PlaneWall`]): the fluid
/// on the side its normal points into.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneSpec {
    /// A point of the plane (`center`, default the origin).
    pub point: [f64; 3],
    /// The unit normal into the fluid (`normal`).
    pub normal: [f64; 3],
    /// The line of its entry (1-based; 0 for a spec).
    pub line: usize,
}

/// Default order of a wall.
pub const DEFAULT_WALL_ORDER: usize = 16;

/// Default order of a channel wall (plane Poiseuille flow to 2·10⁻⁵ in the middle of a
/// channel 5 heights long and wide: `docs/walls.md`).
pub const DEFAULT_CHANNEL_ORDER: usize = 32;

/// Default order of a tube wall (Poiseuille's flow to 2·10⁻⁵ through a tube 6 radii long;
/// longer tubes need more: `docs/walls.md`).
pub const DEFAULT_TUBE_ORDER: usize = 32;

impl WallSpec {
    /// The wall's surface.
    pub fn surface(&self) -> Result<Surface, WallError> {
        let mut s = match self.shape {
            WallShape::Sphere { radius } => shapes::sphere(self.order, radius)?,
            WallShape::Ellipsoid { axes } => shapes::ellipsoid(self.order, axes)?,
            WallShape::Tube { radius, length } => tube_surface(self.order, radius, length)?,
            WallShape::Channel {
                length,
                width,
                height,
            } => channel_surface(self.order, length, width, height)?,
            WallShape::Grid { p, ref coefs, .. } => {
                Surface::from_coefs(p, coefs.to_vec())?.resampled(self.order)?
            }
        };
        s.translate(self.center);
        Ok(s)
    }

    /// The velocity a grid wall was given, at the points of its order-`order` grid
    /// (component-major); `None` for every other wall and a grid wall at rest.
    pub fn grid_velocity(&self) -> Result<Option<Vec<f64>>, WallError> {
        let WallShape::Grid {
            p,
            velocity: Some(ref v),
            ..
        } = self.shape
        else {
            return Ok(None);
        };
        let field = Surface::from_coefs(p, v.to_vec())?.resampled(self.order)?;
        let sht = crate::sph_harmonics::ShTransform::new(self.order)
            .map_err(crate::vesicle::VesicleError::Sph)?;
        Ok(Some(field.grid_positions(&sht)?))
    }
}

pub(super) fn unit_shape(shape: &Shape, p: usize) -> Result<Surface, crate::vesicle::VesicleError> {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Every flow's stress is in Stokes equilibrium (`∇·σ₀ = 0`, central differences) and its
    /// deviatoric part is `μ (∇u₀ + ∇u₀ᵀ)` of the flow's velocity (central differences).
    #[test]
    #[allow(clippy::needless_range_loop)]
    fn background_stress_is_the_velocitys_and_in_equilibrium() {
        let mu = 1.7;
        let flows = [
            Flow::None,
            Flow::Shear { rate: -0.8 },
            Flow::Extensional {
                rate: 0.6,
                follow_cells: false,
            },
            Flow::Poiseuille {
                speed: 1.3,
                radius: 2.0,
            },
            Flow::Tube {
                speed: 2.0,
                radius: 1.8,
            },
            Flow::Channel {
                speed: -1.2,
                half_height: 1.5,
            },
        ];
        let h = 1e-4;
        for flow in flows {
            for x in [[0.3, -0.7, 0.4], [-1.1, 0.2, 0.9]] {
                let shifted = |d: usize, s: f64| {
                    let mut y = x;
                    y[d] += s;
                    y
                };
                let s = flow.stress(x, mu);
                let trace = (s[0][0] + s[1][1] + s[2][2]) / 3.0;
                for i in 0..3 {
                    let div: f64 = (0..3)
                        .map(|j| {
                            (flow.stress(shifted(j, h), mu)[i][j]
                                - flow.stress(shifted(j, -h), mu)[i][j])
                                / (2.0 * h)
                        })
                        .sum();
                    assert!(div.abs() < 1e-8, "{flow:?}: div {div}");
                    for j in 0..3 {
                        let du = |a: usize, b: usize| {
                            (flow.velocity(shifted(b, h))[a] - flow.velocity(shifted(b, -h))[a])
                                / (2.0 * h)
                        };
                        let strain = mu * (du(i, j) + du(j, i));
                        let dev = s[i][j] - if i == j { trace } else { 0.0 };
                        assert!(
                            (dev - strain).abs() < 1e-8,
                            "{flow:?} {i}{j}: {dev} {strain}"
                        );
                    }
                }
            }
        }
    }
}

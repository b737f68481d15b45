//! Cell scenes (the input of `mobo run`): schema, validation with errors that
//! name the file, the line and the key, placement of many cells, and the assembly decisions
//! that say which physics a scene needs (and why).
//!
//! ```toml
//! [fluid]
//! viscosity = 1.0                 # μ of the suspending fluid
//!
//! [units]                         # optional: system = "SI" reads every number below in SI
//! system = "dimensionless"        # units (see `super::units`); the default is the solver's own
//!
//! [flow]
//! kind = "shear"                  # "none" | "shear" | "extensional" | "poiseuille" | "tube"
//!                                 # | "channel"
//! rate = 1.0                      # shear: u = (γ̇ y, 0, 0); extensional: u = ε̇ (x, −y, 0)
//! # speed = 1.0, radius = 5.0     # poiseuille along x: u = U (1 − (y² + z²)/R²), free space
//! # flow_rate = 2.0               # tube: Poiseuille's flow through the tube wall, driven by
//! #                               # one of flow_rate, mean_speed, speed, pressure_gradient
//! #                               # (see `super::tube_flow`)
//! # recycle = true                # tube: a cell leaving the straight section re-enters it
//! #                               # upstream (timestep::suspension::Recycling)
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
//! prestress = 0.0                 # inflation ratio α: the elastic reference is the shape
//! #                               # scaled by 1/(1 + α) (needs shear_modulus > 0)
//! viscosity_ratio = 1.0           # λ = μ_in / μ_out
//! force = [0.0, 0.0, 0.0]         # body force per cell
//! # count = 27, placement = "lattice" | "random", spacing = 3.0, region = [[..], [..]], seed = 1
//! # random placement keeps every cell's bounding sphere 5 % clear of the others', those of
//! # earlier [[cells]] entries included (groups may share a region); a region that cannot hold
//! # the count is an error giving how many were placed and the volume fraction asked.
//! # placement = "packed", volume_fraction = 0.4, min_gap = 0.05: grown to full size with
//! # contacts on (scene::packing) in a cube of count cells; in a scene with a container wall
//! # (a tube, ...) in the fluid it bounds, where volume_fraction fixes the count (leave it out)
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
//! grid = "auto"                   # grid points: "auto" (follow the material on cells with shear
//! #                               # elasticity, relaxed after every step on vesicles without) |
//! #                               # "relaxed" (every inextensible cell's) | "material" (none)
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
//! coupling = "auto"              # cells' coupling: "auto" (near_implicit with two or more
//! #                               # cells; see scene::dense_defaults) | "explicit" (last
//! #                               # step's densities) |
//! #                               # "near_implicit" (cells in each other's near zone solved as
//! #                               # one system, over MPI ranks too; see
//! #                               # timestep::near_implicit)
//! # contact_distance = 0.02       # keep every surface gap >= 0.02 at the end of each step
//! #                               # (a length; default 0.4·R_min/p with two cells or a cell
//! #                               # and a wall, 0: off; see scene::dense_defaults)
//! implicit_zone = 8.0             # near_implicit: neighbours within 8 R/√p coupled inside
//! #                               # the solve (>= 2; narrower is cheaper; default 8, or
//! #                               # 8·√(p/8) above p = 8: a width of 2√2 R at least, see
//! #                               # timestep::near_implicit::default_implicit_zone)
//! start_up_passes = 8             # first steps solved and thrown away to start the coupled
//! #                               # cells from a consistent tension and membrane velocity
//! #                               # (0: off; see timestep::suspension)
//! start_up_anderson_depth = 3     # passes mixed into the next by Anderson's method (0: plain)
//! gpu = "auto"                    # FMM near field on a GPU: "auto" | true | false (feature gpu)
//! wall_solve = "auto"             # under mpirun, the walls' dense system: "split" (each rank
//! #                               # holds the rows of its band of the walls, solved by GMRES
//! #                               # over the ranks) | "replicated" (every rank the whole
//! #                               # system, factored) | "auto" (split when the whole would
//! #                               # take over 1 GiB a rank, or the ranks' copies would not
//! #                               # fit in the free memory; see WallSolve)
//!
//! [[walls]]                       # rigid walls (optional; see scene::walls, docs/walls.md)
//! kind = "container"              # "container" (fluid inside) | "body" (fixed obstacle)
//! shape = "sphere"                # "sphere" (radius) | "ellipsoid" (axes)
//! radius = 6.0
//! # center = [0.0, 0.0, 0.0], order = 16
//! # angular_velocity = [0, 0, 1]  # turns in place about an axis of symmetry (default at rest)
//!
//! [output]
//! every = 10                      # steps between saved frames
//! npy = true                      # DIR/frames/*.npy
//! vtk = true                      # DIR/vtk/frame_NNNNN.vtp + frames.pvd (ParaView)
//! mesh_subdivisions = 3           # icosphere subdivisions of the VTK meshes
//! hdf5 = false                    # DIR/frames.h5 (needs the hdf5 feature)
//! checkpoint_every = 10           # steps between checkpoints (default: every)
//! # velocity_plane = { origin = [-4, -2, 0], u = [8, 0, 0], v = [0, 4, 0], points = [81, 41] }
//! #                               # the velocity on a plane grid at every frame
//! #                               # (frames/frame_NNNNN_plane_velocity.npy, vtk/plane.pvd;
//! #                               # see scene::velocity_plane and io::plane_frames)
//! ```

use std::path::Path;

use toml::Spanned;

use super::cell_groups::{cell_specs, check_overlaps};
pub(crate) use super::cell_scene::rotation;
pub use super::cell_scene::{
    CellScene, CellSpec, Effect, Flow, GridMotion, Numerics, OutputSettings, PlaneSpec, Scheme,
    Shape, TubeWindow, WallSolve, MAX_IMBALANCE, RBC_MIN_ORDER, REBALANCE_EVERY,
    TUBE_WINDOW_TOLERANCE, WALL_SPLIT_BYTES,
};
pub(crate) use super::cells_schema::Origin;
use super::cells_schema::{File, NumericsSection};
use super::{line_col, parse_toml, read_scene_file, SceneError};
use crate::gpu::GpuChoice;
use crate::timestep::near_implicit::CouplingMode;
use crate::timestep::semi_implicit::{ElasticStepping, OperatorStorage, Preconditioning};
use crate::vesicle::skalak::ElasticLaw;

/// Read and validate a cell scene file.
pub fn load(file: &Path) -> Result<CellScene, SceneError> {
    let text = read_scene_file(file)?;
    parse(file, &text)
}

/// Validate scene text (`file` names the scene in messages).
pub fn parse(file: &Path, text: &str) -> Result<CellScene, SceneError> {
    parse_from(file, text, Origin::File)
}

/// [`parse`], with messages that cite the scene as `origin` does.
pub(crate) fn parse_from(file: &Path, text: &str, origin: Origin) -> Result<CellScene, SceneError> {
    let mut f: File = parse_toml(file, text)?;
    let at = |span: std::ops::Range<usize>, msg: String| SceneError {
        file: file.to_path_buf(),
        place: Some(line_col(text, span.start)),
        message: msg,
    };
    let units = super::units::to_dimensionless(&mut f, &at)?;
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
    let at_most = |v: Option<&Spanned<u64>>, max: u64, key: &str| match v {
        Some(v) if *v.get_ref() > max => Err(at(
            v.span(),
            format!("{key} must be at most {max}, got {}", v.get_ref()),
        )),
        Some(v) => Ok(Some(*v.get_ref() as usize)),
        None => Ok(None),
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
    let tube_drive = match &f.flow {
        Some(fl) => super::tube_flow::tube_drive(fl, &at)?,
        None => None,
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
                // Set once the walls are read (the tube's radius or the channel's height
                // drives it).
                "tube" | "channel" => Flow::None,
                other => {
                    return Err(at(
                        fl.kind.span(),
                        format!(
                            "[flow] kind: unknown flow \"{other}\" (none, shear, extensional, poiseuille, \
                             tube, channel)"
                        ),
                    ))
                }
            }
        }
    };
    let n = f.numerics.as_ref();
    let order = n.and_then(|n| n.order.as_ref());
    // `None`: "auto" or absent.
    let coupling_given = match n.and_then(|n| n.coupling.as_ref()) {
        None => None,
        Some(c) => match c.get_ref().as_str() {
            "auto" => None,
            "explicit" => Some(CouplingMode::Explicit),
            "near_implicit" => Some(CouplingMode::NearImplicit),
            other => {
                return Err(at(
                    c.span(),
                    format!(
                        "[numerics] coupling: unknown coupling \"{other}\" (auto, explicit, \
                         near_implicit)"
                    ),
                ))
            }
        },
    };
    let order_value = match order {
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
    };
    let numerics = Numerics {
        order: order_value,
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
        grid: match n.and_then(|n| n.grid.as_ref()) {
            None => GridMotion::Auto,
            Some(s) => match s.get_ref().as_str() {
                "auto" => GridMotion::Auto,
                "relaxed" => GridMotion::Relaxed,
                "material" => GridMotion::Material,
                other => {
                    return Err(at(
                        s.span(),
                        format!(
                            "[numerics] grid: unknown choice \"{other}\" (auto, relaxed, material)"
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
        // "auto" (the default) and an absent contact distance are resolved once the cells and
        // walls are read (scene::dense_defaults).
        coupling: coupling_given.unwrap_or_default(),
        contact_distance: match n.and_then(|n| n.contact_distance.as_ref()) {
            Some(v) if *v.get_ref() == 0.0 => None,
            Some(v) => Some(positive(v, "[numerics] contact_distance")?),
            None => None,
        },
        implicit_zone: match n.and_then(|n| n.implicit_zone.as_ref()) {
            Some(v) if !(v.get_ref().is_finite() && *v.get_ref() >= 2.0) => {
                return Err(at(
                    v.span(),
                    format!(
                        "[numerics] implicit_zone must be a number of at least 2 (the \
                         coupling's near-singular zone, in R/√p), got {}",
                        v.get_ref()
                    ),
                ))
            }
            Some(v) => *v.get_ref(),
            None => crate::timestep::near_implicit::default_implicit_zone(order_value),
        },
        start_up_passes: at_most(
            n.and_then(|n| n.start_up_passes.as_ref()),
            100,
            "[numerics] start_up_passes",
        )?
        .unwrap_or(crate::timestep::suspension::START_UP_PASSES),
        start_up_anderson_depth: at_most(
            n.and_then(|n| n.start_up_anderson_depth.as_ref()),
            10,
            "[numerics] start_up_anderson_depth",
        )?
        .unwrap_or(crate::timestep::suspension::START_UP_ANDERSON_DEPTH),
        gpu: match n.and_then(|n| n.gpu.as_ref()) {
            None => GpuChoice::Auto,
            Some(g) => g
                .get_ref()
                .choice()
                .map_err(|why| at(g.span(), format!("[numerics] gpu {why}")))?,
        },
        wall_solve: match n.and_then(|n| n.wall_solve.as_ref()) {
            None => WallSolve::Auto,
            Some(s) => match s.get_ref().as_str() {
                "auto" => WallSolve::Auto,
                "replicated" => WallSolve::Replicated,
                "split" => WallSolve::Split,
                other => {
                    return Err(at(
                        s.span(),
                        format!(
                            "[numerics] wall_solve: unknown choice \"{other}\" (auto, \
                             replicated, split)"
                        ),
                    ))
                }
            },
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
        velocity_plane: o
            .and_then(|o| o.velocity_plane.as_ref())
            .map(|p| super::velocity_plane::validate(p, &at))
            .transpose()?,
    };
    if let (Some(p), None, false) = (
        o.and_then(|o| o.velocity_plane.as_ref()),
        output.vtk,
        output.npy,
    ) {
        return Err(at(
            p.origin.span(),
            "[output] velocity_plane is written as .npy or .vtp: it needs npy = true or vtk = \
             true"
                .into(),
        ));
    }
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
    // The walls before the cells: a packed placement fills their fluid.
    let (walls, plane) = super::walls::walls(
        f.walls.as_deref().unwrap_or(&[]),
        origin,
        text,
        &at,
        file,
        units.as_ref(),
    )?;
    // The recycling window before the cells: a packed placement fills it periodically.
    let recycle = super::tube_flow::recycle_window(f.flow.as_ref(), &walls, &at)?;
    let (mut cells, mut packings) = (Vec::new(), Vec::new());
    for (k, c) in sections.iter().enumerate() {
        let group = cell_specs(
            c,
            k,
            origin,
            &cells,
            &at,
            &positive,
            &finite,
            text,
            numerics.order.max(RBC_MIN_ORDER),
            &walls,
            recycle.as_ref(),
            &mut packings,
        )?;
        cells.extend(group);
    }
    check_overlaps(&cells, file, &entry, numerics.order.max(RBC_MIN_ORDER))?;
    let flow = match tube_drive {
        Some(d) => super::tube_flow::tube_flow(&d, &walls, viscosity, &at)?,
        None => flow,
    };
    super::walls::check_cells_in_fluid(
        &cells,
        &walls,
        file,
        &entry,
        numerics.order.max(RBC_MIN_ORDER),
    )?;
    if let Some(plane) = &plane {
        super::walls::check_plane(
            &cells,
            plane,
            &flow,
            file,
            &entry,
            numerics.order.max(RBC_MIN_ORDER),
        )?;
    }
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
    numerics.coupling = coupling_given
        .unwrap_or_else(|| super::dense_defaults::auto_coupling(&cells, plane.is_some()));
    let contact_given = n.and_then(|n| n.contact_distance.as_ref()).is_some();
    if !contact_given {
        numerics.contact_distance = super::dense_defaults::auto_contact_distance(
            &cells,
            &walls,
            plane.is_some(),
            numerics.order,
        );
    }
    let mut effects = effects(&cells, &flow);
    effects.push(grid_effect(&cells, numerics.grid));
    effects.extend(super::dense_defaults::effects(
        numerics.coupling,
        coupling_given.is_some(),
        numerics.contact_distance,
        contact_given,
        cells.len(),
        plane.is_some(),
    ));
    if let Some(u) = &units {
        effects.push(Effect {
            name: "units",
            enabled: true,
            reason: format!(
                "[units] system = \"SI\": the run is dimensionless with length {:.4e} m, time \
                 {:.4e} s, viscosity {:.4e} Pa·s, tension {:.4e} N/m (velocity {:.4e} m/s, force \
                 {:.4e} N)",
                u.length_m,
                u.time_s,
                u.viscosity_pa_s,
                u.tension_n_per_m,
                u.velocity_m_per_s(),
                u.force_n()
            ),
        });
    }
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
    if !walls.is_empty() {
        let containers = walls
            .iter()
            .filter(|w| w.kind == crate::wall::WallKind::Container)
            .count();
        effects.push(Effect {
            name: "walls",
            enabled: true,
            reason: format!(
                "{} rigid wall(s) ({containers} container, {} bodies), order {}: the completed \
                 double layer, factored once, solved every step",
                walls.len(),
                walls.len() - containers,
                walls.iter().map(|w| w.order).max().unwrap_or(0)
            ),
        });
    }
    if let Some(w) = &plane {
        effects.push(Effect {
            name: "plane_wall",
            enabled: true,
            reason: format!(
                "a plane wall through {:?} with normal {:?}: Blake's images of every cell's \
                 layers, added every step",
                w.point, w.normal
            ),
        });
    }
    Ok(CellScene {
        plane,
        recycle,
        viscosity,
        flow,
        cells,
        numerics,
        output_every,
        output,
        effects,
        walls,
        units,
        packings,
    })
}

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

/// Cell indices for an effect's reason: the first five, then "…".
fn cell_list(v: &[usize]) -> String {
    let s: Vec<String> = v.iter().take(5).map(|i| i.to_string()).collect();
    format!("{}{}", s.join(", "), if v.len() > 5 { ", …" } else { "" })
}

/// Which cells' grid points follow the material (`[numerics] grid`; the others' grids are
/// relaxed after every step), and why.
fn grid_effect(cells: &[CellSpec], grid: GridMotion) -> Effect {
    let followed: Vec<usize> = (0..cells.len())
        .filter(|&i| !grid.relaxes(&cells[i]))
        .collect();
    let why = match grid {
        GridMotion::Auto => {
            "[numerics] grid = \"auto\": cells with shear elasticity (and capsules) follow their \
             material points, vesicles without are relaxed"
        }
        GridMotion::Relaxed => {
            "[numerics] grid = \"relaxed\": every inextensible cell is relaxed, capsules follow \
             their material points"
        }
        GridMotion::Material => "[numerics] grid = \"material\"",
    };
    Effect {
        name: "material_grid",
        enabled: !followed.is_empty(),
        reason: if followed.is_empty() {
            format!("every cell's grid is relaxed after every step ({why})")
        } else {
            format!(
                "grid points follow the material on cells {} ({why})",
                cell_list(&followed)
            )
        },
    }
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
                format!("viscosity_ratio ≠ 1 for cells {}", cell_list(&contrast))
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
                    cell_list(&contrast)
                )
            },
        },
        Effect {
            name: "skalak",
            enabled: !shear.is_empty(),
            reason: if shear.is_empty() {
                "every shear_modulus is 0".into()
            } else if neo_hookean.is_empty() {
                format!(
                    "shear_modulus > 0 for cells {} (Skalak law)",
                    cell_list(&shear)
                )
            } else {
                format!(
                    "shear_modulus > 0 for cells {} (neo-Hookean law for cells {})",
                    cell_list(&shear),
                    cell_list(&neo_hookean)
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
                    cell_list(&capsules)
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
                format!("force set for cells {}", cell_list(&forced))
            },
        },
    ]
}

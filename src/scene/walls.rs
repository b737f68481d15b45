//! A cell scene's rigid walls (`[[walls]]`): validated with located errors, and the check that
//! every cell lies in the fluid they bound.
//!
//! ```toml
//! [[walls]]
//! kind = "container"       # "container" (the fluid inside: a cavity, a closed vessel) |
//! #                        # "body" (a fixed obstacle, the fluid outside)
//! shape = "sphere"         # "sphere" | "ellipsoid" | "tube" | "channel" | "grid" | "plane"
//! radius = 4.0             # sphere, tube
//! # axes = [6.0, 4.0, 3.0] # ellipsoid semi-axes
//! # length = 24.0          # tube: end to end along x (at least 2 radii), rounded ends;
//! #                        # channel: end to end along x
//! # width = 16.0           # channel: side to side along y (at least the height)
//! # height = 4.0           # channel: plate to plate along z
//! # positions = "vessel.npy"          # grid: the surface's points (below)
//! # velocity = "vessel_velocity.npy"  # grid: the wall's velocity at the same points
//! # normal = [0.0, 1.0, 0.0]          # plane: its normal, into the fluid
//! center = [0.0, 0.0, 0.0]
//! order = 16               # spherical-harmonic order of the wall (4 to 64; default 16, a
//!                          # tube or a channel 32, a grid wall its file's order)
//! # angular_velocity = [0.0, 0.0, 1.0]  # turn in place about the center (default at rest)
//! ```
//!
//! **A wall of the user's own shape** (`shape = "grid"`): any closed surface that the sphere's
//! angles parametrise smoothly (genus 0), given by its points on the spherical grid of order
//! `p`: a `float64` `.npy` array of shape `(p + 1, 2p, 3)`, the point `X(θ_i, φ_k)` at latitude
//! `θ_i = arccos x_i` (`x_i` the `p + 1` Gauss–Legendre nodes, decreasing) and longitude
//! `φ_k = kπ/p`, its normals `X_θ × X_φ` pointing out of the enclosed volume. A relative file
//! name starts from the scene file's folder; the values are in the scene's length unit (metres
//! with `[units] system = "SI"`). The surface is its order-`p` spherical-harmonic fit, resampled
//! to `order` if given, and moved by `center`. `velocity` gives the wall's velocity at the same
//! points (speed units), for a wall that moves in its own shape or lets fluid in and out (a
//! container's net flux must vanish); without it the wall is at rest. `scripts/grid_wall.py`
//! writes a stenosed vessel and the velocity that drives Poiseuille's flow through it. A run
//! copies the files into `DIR/walls/` and names them there in its scene copy, so `--resume`
//! reads the same wall.
//!
//! **A channel** (`shape = "channel"`, a container): two plates `z = ±height/2` about the
//! `center`, closed at their edges into one rounded box ([`crate::wall::channel_surface`]),
//! with `[flow] kind = "channel"` carrying plane Poiseuille flow between them and across
//! the sides and the ends ([`super::tube_flow`]).
//!
//! **A plane wall** (`shape = "plane"`, `kind = "body"`): the infinite plane through `center`
//! (default the origin) with `normal` pointing into the fluid, at rest, by Blake's images
//! ([`crate::wall::PlaneWall`]; [`crate::timestep::plane_coupling`]). It stands alone (no other
//! wall, one plane), with every cell above it, in a background flow that vanishes on it (a
//! shear flow `u = (γ̇y, 0, 0)` beside the plane `y = 0`, or none); each is checked with its
//! place. Cells with a viscosity contrast get the image of their double layer too.
//!
//! Walls are at rest unless they turn; `[flow]` is the flow the walls disturb (a container at
//! rest in a shear flow holds its fluid still at the wall). A tube container with
//! `[flow] kind = "tube"` carries Poiseuille's flow, in at one end and out at the other
//! ([`super::tube_flow`]). A wall with an `angular_velocity` `Ω` turns in place with the
//! surface velocity `Ω × (x − c)`: only about an axis of symmetry through its centre (any
//! axis of a sphere, the x axis of a tube, the axis of an ellipsoid with two equal semi-axes),
//! so that its shape and the factored wall system stay as they are (a spherical Couette cell,
//! a rotating rod). See [`crate::wall`] for the method.

use std::path::Path;

use toml::Spanned;

use super::cell_scene::CellSpec;
pub use super::cell_scene::{
    PlaneSpec, WallFile, WallShape, WallSpec, DEFAULT_CHANNEL_ORDER, DEFAULT_TUBE_ORDER,
    DEFAULT_WALL_ORDER,
};
use super::cells_schema::{Origin, WallSection};
use super::line_col;
use super::units::UnitScales;
use super::SceneError;
use crate::sph_harmonics::ShTransform;
use crate::timestep::contact::FixedSurface;
use crate::vesicle::geometry::SurfaceCalculus;
use crate::vesicle::shapes::Surface;
use crate::vesicle::surface_distance::{DistanceScratch, SurfaceDistance};
use crate::vesicle::VesicleError;
use crate::wall::WallKind;

/// Validate the `[[walls]]` entries of the scene `file` (its folder: where a grid wall's
/// relative file names start; `units`: the SI scales its files' values are divided by).
pub(super) fn walls(
    sections: &[WallSection],
    origin: Origin,
    text: &str,
    at: &dyn Fn(std::ops::Range<usize>, String) -> SceneError,
    file: &Path,
    units: Option<&UnitScales>,
) -> Result<(Vec<WallSpec>, Option<PlaneSpec>), SceneError> {
    let mut out: Vec<WallSpec> = vec![];
    let mut plane: Option<(PlaneSpec, String, std::ops::Range<usize>)> = None;
    for (k, w) in sections.iter().enumerate() {
        let line = match origin {
            Origin::File => line_col(text, w.kind.span().start).0,
            Origin::Spec => 0,
        };
        let name = match origin {
            Origin::File => format!("[[walls]] entry #{} (line {line})", k + 1),
            Origin::Spec => format!("walls[{k}] of the spec"),
        };
        let kind = match w.kind.get_ref().as_str() {
            "container" => WallKind::Container,
            "body" => WallKind::Body,
            other => {
                return Err(at(
                    w.kind.span(),
                    format!("{name}: kind must be \"container\" or \"body\", got \"{other}\""),
                ))
            }
        };
        if kind == WallKind::Container {
            if let Some(first) = out.iter().position(|o| o.kind == WallKind::Container) {
                return Err(at(
                    w.kind.span(),
                    format!(
                        "{name}: a second container (wall {first} is one); the fluid has at \
                         most one"
                    ),
                ));
            }
        }
        if w.shape.get_ref() == "plane" {
            let p = plane_entry(w, &name, line, at)?;
            if let Some((_, first, _)) = &plane {
                return Err(at(
                    w.shape.span(),
                    format!("{name}: a second plane ({first} is one); a scene has at most one"),
                ));
            }
            plane = Some((p, name, w.shape.span()));
            continue;
        }
        if let Some(n) = &w.normal {
            return Err(at(n.span(), format!("{name}: normal is for a plane")));
        }
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let channel = w.shape.get_ref() == "channel";
        if let (Some(l), false) = (&w.length, w.shape.get_ref() == "tube" || channel) {
            return Err(at(
                l.span(),
                format!("{name}: length is for a tube or a channel"),
            ));
        }
        for (key, given) in [("width", &w.width), ("height", &w.height)] {
            if let (Some(v), false) = (given, channel) {
                return Err(at(
                    v.span(),
                    format!("{name}: {key} is for a channel (shape = \"channel\")"),
                ));
            }
        }
        let grid = w.shape.get_ref() == "grid";
        for (key, given) in [("positions", &w.positions), ("velocity", &w.velocity)] {
            if let (Some(v), false) = (given, grid) {
                return Err(at(
                    v.span(),
                    format!("{name}: {key} is for a grid wall (shape = \"grid\")"),
                ));
            }
        }
        let mut files = Vec::new();
        let shape = match w.shape.get_ref().as_str() {
            "tube" => {
                if let Some(a) = &w.axes {
                    return Err(at(a.span(), format!("{name}: axes is for an ellipsoid")));
                }
                let (Some(r), Some(l)) = (&w.radius, &w.length) else {
                    return Err(at(
                        w.shape.span(),
                        format!("{name}: a tube needs radius and length"),
                    ));
                };
                let (radius, length) = (*r.get_ref(), *l.get_ref());
                if !positive(radius) {
                    return Err(at(
                        r.span(),
                        format!("{name}: radius must be positive, got {radius}"),
                    ));
                }
                if !(length.is_finite() && length >= 2.0 * radius) {
                    return Err(at(
                        l.span(),
                        format!(
                            "{name}: length (end to end) must be at least twice the radius \
                             {radius}, got {length}"
                        ),
                    ));
                }
                WallShape::Tube { radius, length }
            }
            "channel" => {
                for (key, span) in [
                    ("radius", w.radius.as_ref().map(|v| v.span())),
                    ("axes", w.axes.as_ref().map(|v| v.span())),
                ] {
                    if let Some(span) = span {
                        return Err(at(
                            span,
                            format!(
                                "{name}: {key} is not for a channel (its extents are length, \
                                 width and height)"
                            ),
                        ));
                    }
                }
                let (Some(l), Some(wd), Some(h)) = (&w.length, &w.width, &w.height) else {
                    return Err(at(
                        w.shape.span(),
                        format!(
                            "{name}: a channel needs length (along x), width (along y) and \
                             height (along z, plate to plate)"
                        ),
                    ));
                };
                let height = *h.get_ref();
                if !positive(height) {
                    return Err(at(
                        h.span(),
                        format!("{name}: height must be positive, got {height}"),
                    ));
                }
                for (key, v) in [("length", l), ("width", wd)] {
                    let x = *v.get_ref();
                    if !(x.is_finite() && x >= height) {
                        return Err(at(
                            v.span(),
                            format!(
                                "{name}: {key} must be at least the height {height} (plate to \
                                 plate), got {x}"
                            ),
                        ));
                    }
                }
                WallShape::Channel {
                    length: *l.get_ref(),
                    width: *wd.get_ref(),
                    height,
                }
            }
            "sphere" => {
                if let Some(a) = &w.axes {
                    return Err(at(a.span(), format!("{name}: axes is for an ellipsoid")));
                }
                let Some(r) = &w.radius else {
                    return Err(at(w.shape.span(), format!("{name}: a sphere needs radius")));
                };
                if !positive(*r.get_ref()) {
                    return Err(at(
                        r.span(),
                        format!("{name}: radius must be positive, got {}", r.get_ref()),
                    ));
                }
                WallShape::Sphere {
                    radius: *r.get_ref(),
                }
            }
            "ellipsoid" => {
                if let Some(r) = &w.radius {
                    return Err(at(r.span(), format!("{name}: radius is for a sphere")));
                }
                let Some(a) = &w.axes else {
                    return Err(at(
                        w.shape.span(),
                        format!("{name}: an ellipsoid needs axes"),
                    ));
                };
                if !a.get_ref().iter().all(|&v| positive(v)) {
                    return Err(at(
                        a.span(),
                        format!(
                            "{name}: axes must be three positive semi-axes, got {:?}",
                            a.get_ref()
                        ),
                    ));
                }
                WallShape::Ellipsoid { axes: *a.get_ref() }
            }
            "grid" => {
                for (key, span) in [
                    ("radius", w.radius.as_ref().map(|v| v.span())),
                    ("axes", w.axes.as_ref().map(|v| v.span())),
                    (
                        "angular_velocity",
                        w.angular_velocity.as_ref().map(|v| v.span()),
                    ),
                ] {
                    if let Some(span) = span {
                        return Err(at(
                            span,
                            format!(
                                "{name}: {key} is not for a grid wall (its shape is the \
                                 positions file; a moving grid wall has a velocity file)"
                            ),
                        ));
                    }
                }
                let Some(pos) = &w.positions else {
                    return Err(at(
                        w.shape.span(),
                        format!("{name}: a grid wall needs positions (a .npy file)"),
                    ));
                };
                let length = units.map_or(1.0, |u| u.length_m);
                let speed = units.map_or(1.0, |u| u.length_m / u.time_s);
                let base = file.parent().unwrap_or(Path::new(""));
                let read = |v: &Spanned<String>, key: &'static str, scale: f64| {
                    let path = base.join(v.get_ref());
                    let fail = |m: String| at(v.span(), format!("{name}: {key}: {m}"));
                    grid_values(&path, scale).map_err(fail).map(|(p, c)| {
                        (
                            p,
                            c,
                            WallFile {
                                key,
                                path: path.clone(),
                                span: v.span(),
                            },
                        )
                    })
                };
                let (p, coefs, f) = read(pos, "positions", length)?;
                files.push(f);
                // The geometry refuses a surface whose normals X_θ × X_φ point into the enclosed
                // volume (or one that is not a surface).
                SurfaceCalculus::new(p)
                    .and_then(|mut c| c.geometry(&coefs))
                    .map_err(|e| {
                        at(
                            pos.span(),
                            format!(
                                "{name}: positions: {e} (the normals X_θ × X_φ must point out \
                                 of the enclosed volume: reverse the order of the longitudes \
                                 if they point in)"
                            ),
                        )
                    })?;
                let velocity = match &w.velocity {
                    None => None,
                    Some(v) => {
                        let (q, c, f) = read(v, "velocity", speed)?;
                        if q != p {
                            return Err(at(
                                v.span(),
                                format!(
                                    "{name}: velocity is on the grid of order {q}, positions \
                                     on that of order {p}: give both on the same grid"
                                ),
                            ));
                        }
                        files.push(f);
                        Some(std::sync::Arc::new(c))
                    }
                };
                WallShape::Grid {
                    p,
                    coefs: std::sync::Arc::new(coefs),
                    velocity,
                }
            }
            other => {
                return Err(at(
                    w.shape.span(),
                    format!(
                        "{name}: shape must be \"sphere\", \"ellipsoid\", \"tube\", \
                         \"channel\", \"grid\" or \"plane\", got \"{other}\""
                    ),
                ))
            }
        };
        let center = match &w.center {
            Some(c) if !c.get_ref().iter().all(|v| v.is_finite()) => {
                return Err(at(c.span(), format!("{name}: center must be finite")))
            }
            Some(c) => *c.get_ref(),
            None => [0.0; 3],
        };
        let order = match &w.order {
            Some(o) if !(4..=64).contains(o.get_ref()) => {
                return Err(at(
                    o.span(),
                    format!("{name}: order must be from 4 to 64, got {}", o.get_ref()),
                ))
            }
            Some(o) => *o.get_ref(),
            None if matches!(shape, WallShape::Tube { .. }) => DEFAULT_TUBE_ORDER,
            None if matches!(shape, WallShape::Channel { .. }) => DEFAULT_CHANNEL_ORDER,
            None => match shape {
                WallShape::Grid { p, .. } if (4..=64).contains(&p) => p,
                WallShape::Grid { p, .. } => {
                    return Err(at(
                        w.shape.span(),
                        format!(
                            "{name}: the positions are on the grid of order {p}; give an order \
                             from 4 to 64 for the wall"
                        ),
                    ))
                }
                _ => DEFAULT_WALL_ORDER,
            },
        };
        let angular_velocity = match &w.angular_velocity {
            None => [0.0; 3],
            Some(o) => {
                let om = *o.get_ref();
                if !om.iter().all(|v| v.is_finite()) {
                    return Err(at(
                        o.span(),
                        format!("{name}: angular_velocity must be finite"),
                    ));
                }
                let same = |a: f64, b: f64| (a - b).abs() <= 1e-12 * a.abs().max(b.abs());
                // Rotation about coordinate axis k keeps the shape when the other two
                // semi-axes are equal.
                let keeps = match &shape {
                    WallShape::Sphere { .. } => true,
                    &WallShape::Ellipsoid { axes: [a, b, c] } => {
                        (om[0] == 0.0 || same(b, c))
                            && (om[1] == 0.0 || same(a, c))
                            && (om[2] == 0.0 || same(a, b))
                    }
                    WallShape::Tube { .. } => om[1] == 0.0 && om[2] == 0.0,
                    WallShape::Channel { .. } => false,
                    WallShape::Grid { .. } => false,
                };
                if !keeps {
                    return Err(at(
                        o.span(),
                        format!(
                            "{name}: angular_velocity {om:?} would turn the wall out of its own \
                             shape: a wall turns in place only about an axis of symmetry \
                             through its center (any axis of a sphere, the x axis of a tube, \
                             the axis of an ellipsoid with two equal semi-axes)"
                        ),
                    ));
                }
                om
            }
        };
        out.push(WallSpec {
            kind,
            shape,
            center,
            order,
            angular_velocity,
            line,
            files,
        });
    }
    match plane {
        Some((_, name, span)) if !out.is_empty() => Err(at(
            span,
            format!(
                "{name}: a plane's images hold for a plane alone; it cannot be combined with \
                 other walls"
            ),
        )),
        plane => Ok((out, plane.map(|(p, _, _)| p))),
    }
}

/// A `[[walls]] shape = "plane"` entry: `kind = "body"`, a `normal` into the fluid, `center` a
/// point of the plane (default the origin), and none of the other shapes' keys.
fn plane_entry(
    w: &WallSection,
    name: &str,
    line: usize,
    at: &dyn Fn(std::ops::Range<usize>, String) -> SceneError,
) -> Result<PlaneSpec, SceneError> {
    if w.kind.get_ref() != "body" {
        return Err(at(
            w.kind.span(),
            format!(
                "{name}: a plane is kind = \"body\" (a fixed wall; the fluid is on the side its \
                 normal points into), got \"{}\"",
                w.kind.get_ref()
            ),
        ));
    }
    for (key, span) in [
        ("radius", w.radius.as_ref().map(|v| v.span())),
        ("axes", w.axes.as_ref().map(|v| v.span())),
        ("length", w.length.as_ref().map(|v| v.span())),
        ("width", w.width.as_ref().map(|v| v.span())),
        ("height", w.height.as_ref().map(|v| v.span())),
        ("order", w.order.as_ref().map(|v| v.span())),
        (
            "angular_velocity",
            w.angular_velocity.as_ref().map(|v| v.span()),
        ),
        ("positions", w.positions.as_ref().map(|v| v.span())),
        ("velocity", w.velocity.as_ref().map(|v| v.span())),
    ] {
        if let Some(span) = span {
            return Err(at(
                span,
                format!(
                    "{name}: {key} is not for a plane (a plane at rest has a normal and a point, \
                     center)"
                ),
            ));
        }
    }
    let Some(n) = &w.normal else {
        return Err(at(
            w.shape.span(),
            format!("{name}: a plane needs normal (pointing into the fluid)"),
        ));
    };
    let v = *n.get_ref();
    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if !(len.is_finite() && len > 0.0) {
        return Err(at(
            n.span(),
            format!("{name}: normal must be a finite vector that is not zero, got {v:?}"),
        ));
    }
    let point = match &w.center {
        Some(c) if !c.get_ref().iter().all(|v| v.is_finite()) => {
            return Err(at(c.span(), format!("{name}: center must be finite")))
        }
        Some(c) => *c.get_ref(),
        None => [0.0; 3],
    };
    Ok(PlaneSpec {
        point,
        normal: v.map(|x| x / len),
        line,
    })
}

/// A plane wall's scene: every cell above it (each of its order-`2p` samples), and a
/// background flow that vanishes on the plane (the wall is at rest: a shear flow along it, or
/// none).
pub(super) fn check_plane(
    cells: &[CellSpec],
    plane: &PlaneSpec,
    flow: &super::cell_scene::Flow,
    file: &Path,
    entry: &dyn Fn(usize) -> String,
    p: usize,
) -> Result<(), SceneError> {
    let fail = |line: usize, message: String| SceneError {
        file: file.to_path_buf(),
        place: (line > 0).then_some((line, 1)),
        message,
    };
    let wall = crate::wall::PlaneWall::new(plane.point, plane.normal)
        .map_err(|e| fail(plane.line, e.to_string()))?;
    let sht = ShTransform::new(2 * p).map_err(|e| fail(0, e.to_string()))?;
    for (i, c) in cells.iter().enumerate() {
        let e = |e: VesicleError| fail(c.line, format!("cell {i} of {}: {e}", entry(c.line)));
        let s = c.surface(p).map_err(e)?;
        let samples = SurfaceDistance::new(p, s.coefs(), &sht).map_err(e)?;
        let low = samples
            .samples()
            .iter()
            .map(|&x| wall.height(x))
            .fold(f64::INFINITY, f64::min);
        if low <= 0.0 {
            return Err(fail(
                c.line,
                format!(
                    "cell {i} of {} reaches {:.4} below the plane wall (line {}): every cell \
                     must lie on the side its normal points into",
                    entry(c.line),
                    -low,
                    plane.line
                ),
            ));
        }
    }
    // The background flow at points of the plane out to 100 length units.
    let scale = flow.rate_scale().abs() * 100.0;
    for s in [-100.0, -1.0, 0.0, 1.0, 100.0] {
        for r in [-100.0, -1.0, 0.0, 1.0, 100.0] {
            let x: [f64; 3] = std::array::from_fn(|a| {
                let t = wall.vector_to_global([s, r, 0.0]);
                plane.point[a] + t[a]
            });
            let u = flow.velocity(x);
            let speed = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
            if speed > 1e-12 * scale {
                return Err(fail(
                    plane.line,
                    format!(
                        "the background flow is {u:?} at {x:?} on the plane wall, which is at \
                         rest: the flow must vanish on it (a shear flow u = (γ̇y, 0, 0) beside \
                         the plane y = 0, or no flow)"
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Every cell must lie in the fluid: inside the container, outside every body (the signed
/// distance of each of its order-`2p` samples to the wall, by Newton's closest point).
pub(super) fn check_cells_in_fluid(
    cells: &[CellSpec],
    walls: &[WallSpec],
    file: &Path,
    entry: &dyn Fn(usize) -> String,
    p: usize,
) -> Result<(), SceneError> {
    if walls.is_empty() {
        return Ok(());
    }
    let fail = |line: usize, message: String| SceneError {
        file: file.to_path_buf(),
        place: (line > 0).then_some((line, 1)),
        message,
    };
    // The walls as the contact projection sees them: their clearance is the signed distance,
    // positive in the fluid.
    let fixed = walls
        .iter()
        .enumerate()
        .map(|(k, w)| {
            let s = w
                .surface()
                .map_err(|e| fail(w.line, format!("wall {k}: {e}")))?;
            FixedSurface::new(w.order, s.coefs(), w.kind == WallKind::Container)
                .map_err(|e| fail(w.line, format!("wall {k}: {e}")))
        })
        .collect::<Result<Vec<_>, SceneError>>()?;
    let sht = ShTransform::new(2 * p).map_err(|e| fail(0, e.to_string()))?;
    for (i, c) in cells.iter().enumerate() {
        let e = |e: VesicleError| fail(c.line, format!("cell {i} of {}: {e}", entry(c.line)));
        let s = c.surface(p).map_err(e)?;
        let samples = SurfaceDistance::new(p, s.coefs(), &sht).map_err(e)?;
        for (k, (w, f)) in walls.iter().zip(&fixed).enumerate() {
            let mut scratch = DistanceScratch::new(f.order());
            let margin = samples
                .samples()
                .iter()
                .map(|&x| f.clearance(&mut scratch, x))
                .fold(f64::INFINITY, f64::min);
            if margin <= 0.0 {
                let (side, what) = match w.kind {
                    WallKind::Container => ("outside", "container"),
                    WallKind::Body => ("inside", "body"),
                };
                return Err(fail(
                    c.line,
                    format!(
                        "cell {i} of {} reaches {:.4} {side} wall {k} (a {what}): every cell \
                         must lie in the fluid",
                        entry(c.line),
                        -margin
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// The values of a grid wall's file: a `float64` array of shape `(p + 1, 2p, 3)`, the vector
/// at latitude `i` (`θ_i`, increasing) and longitude `k` (`φ_k = kπ/p`) of the spherical grid
/// of order `p`, divided by `scale`; its order-`p` coefficients.
fn grid_values(path: &Path, scale: f64) -> Result<(usize, Vec<f64>), String> {
    let (shape, data) = crate::io::npy::read_f64(path).map_err(|e| e.to_string())?;
    let p = match shape[..] {
        [lat, lon, 3] if lat >= 2 && lon == 2 * (lat - 1) => lat - 1,
        _ => {
            return Err(format!(
                "{}: shape {shape:?}: expected (p + 1, 2p, 3), the points of the spherical grid of \
                 order p (latitudes θ_i = arccos of the p + 1 Gauss–Legendre nodes, decreasing \
                 in cos θ; longitudes φ_k = kπ/p) with x, y, z",
                path.display()
            ))
        }
    };
    if let Some(j) = data.iter().position(|v| !v.is_finite()) {
        let (i, k, c) = (j / (6 * p), (j / 3) % (2 * p), j % 3);
        return Err(format!(
            "{}: value [{i}, {k}, {c}] is {}",
            path.display(),
            data[j]
        ));
    }
    let n = 2 * p * (p + 1);
    let mut grid = vec![0.0; 3 * n];
    for j in 0..n {
        for c in 0..3 {
            grid[c * n + j] = data[3 * j + c] / scale;
        }
    }
    let sht = ShTransform::new(p).map_err(|e| e.to_string())?;
    let s = Surface::from_grid(&sht, &grid).map_err(|e| e.to_string())?;
    Ok((p, s.coefs().to_vec()))
}

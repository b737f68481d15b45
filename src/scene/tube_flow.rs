//! `[flow] kind = "tube"`: Poiseuille's flow through the scene's tube wall, driven by a flow
//! rate, a mean or centreline speed, or a pressure gradient; `[flow] kind = "channel"`: plane
//! Poiseuille flow between the plates of the scene's channel wall, driven by a mean or
//! centreline speed or a pressure gradient.
//!
//! ```toml
//! [[walls]]
//! kind = "container"
//! shape = "tube"            # axis along x, through y = z = 0
//! radius = 5.0
//! length = 30.0
//!
//! [flow]
//! kind = "tube"
//! flow_rate = 39.27         # Q through a cross-section; or one of
//! # mean_speed = 0.5        # Q / (πR²)
//! # speed = 1.0             # the centreline speed U
//! # pressure_gradient = 0.16  # G = −dp/dx
//! recycle = true            # optional: cells leaving the straight section re-enter upstream
//! ```
//!
//! The profile is `u = (U (1 − (y² + z²)/R²), 0, 0)` with `R` the tube's radius and
//! `U = 2Q/(πR²) = 2ū = G R²/(4μ)` (Hagen–Poiseuille; `μ` the `[fluid]` viscosity). The tube's
//! wall takes this velocity: zero along its straight side, the inflow and outflow profile across
//! its rounded ends ([`crate::wall::tube_surface`]). Without cells the flow inside is exactly
//! Poiseuille's; cells disturb it, and the wall keeps the disturbance from leaving the tube.
//!
//! With `recycle = true` the tube's straight middle section (its radius within
//! [`TUBE_WINDOW_TOLERANCE`] of `R`, [`crate::wall::straight_length`]) is a window: a cell whose
//! centre passes its downstream end is moved back by the window's length, where it lands clear
//! of the other cells and the wall ([`crate::timestep::suspension::Recycling`]). The cells see
//! a tube of unbounded length; the flow itself stays that of the finite tube (the fluid enters
//! and leaves through the rounded ends).
//!
//! ```toml
//! [[walls]]
//! kind = "container"
//! shape = "channel"         # plates at z = ±height/2, flow along x
//! length = 20.0
//! width = 20.0
//! height = 4.0
//!
//! [flow]
//! kind = "channel"
//! mean_speed = 1.0          # 2U/3; or one of
//! # speed = 1.5             # the centreline speed U
//! # pressure_gradient = 0.75  # G = −dp/dx
//! ```
//!
//! The profile is `u = (U (1 − z²/H²), 0, 0)` with `2H` the channel's height and
//! `U = 3ū/2 = G H²/(2μ)`. The channel's wall takes it: zero on the plates, the undisturbed flow
//! across the sides and the ends ([`crate::wall::channel_surface`]). A flow rate is refused:
//! through a box of finite width it would depend on how the sides close.

use std::ops::Range;

use super::cell_scene::{Flow, TubeWindow, WallShape, WallSpec, TUBE_WINDOW_TOLERANCE};
use super::cells_schema::FlowSection;
use super::SceneError;
use crate::wall::WallKind;

/// What drives the flow through the tube.
#[derive(Clone, Copy, Debug)]
enum Drive {
    FlowRate,
    MeanSpeed,
    Speed,
    PressureGradient,
}

/// The container a driven flow goes through.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Vessel {
    /// `kind = "tube"` through a tube wall.
    Tube,
    /// `kind = "channel"` between a channel wall's plates.
    Channel,
}

/// A tube or channel flow's drive as the file gives it, before the wall's size is known.
#[derive(Clone, Debug)]
pub(super) struct TubeDrive {
    vessel: Vessel,
    drive: Drive,
    value: f64,
    span: Range<usize>,
}

type At<'a> = &'a dyn Fn(Range<usize>, String) -> SceneError;

/// The drive of a `kind = "tube"` or `"channel"` flow (`None` for every other kind, which
/// must not carry their keys).
pub(super) fn tube_drive(fl: &FlowSection, at: At) -> Result<Option<TubeDrive>, SceneError> {
    let keys = [
        ("flow_rate", &fl.flow_rate, Drive::FlowRate),
        ("mean_speed", &fl.mean_speed, Drive::MeanSpeed),
        (
            "pressure_gradient",
            &fl.pressure_gradient,
            Drive::PressureGradient,
        ),
    ];
    let vessel = match fl.kind.get_ref().as_str() {
        "tube" => Vessel::Tube,
        "channel" => Vessel::Channel,
        _ => {
            for (key, v, _) in &keys {
                if let Some(v) = v {
                    return Err(at(
                        v.span(),
                        format!("[flow] {key} applies to kind = \"tube\" or \"channel\" only"),
                    ));
                }
            }
            return Ok(None);
        }
    };
    if let Some(r) = &fl.radius {
        let m = match vessel {
            Vessel::Tube => {
                "[flow] radius: a tube flow takes the radius of the tube wall ([[walls]] shape \
                 = \"tube\")"
            }
            Vessel::Channel => {
                "[flow] radius: a channel flow takes the height of the channel wall ([[walls]] \
                 shape = \"channel\")"
            }
        };
        return Err(at(r.span(), m.into()));
    }
    if let (Vessel::Channel, Some(q)) = (vessel, &fl.flow_rate) {
        return Err(at(
            q.span(),
            "[flow] flow_rate: a channel's flow rate depends on its width and on how its sides \
             close; give mean_speed, speed or pressure_gradient"
                .into(),
        ));
    }
    if let Some(r) = &fl.rate {
        return Err(at(
            r.span(),
            "[flow] rate is for shear and extensional flows".into(),
        ));
    }
    if let Some(f) = &fl.frame {
        return Err(at(
            f.span(),
            "[flow] frame is for an extensional flow".into(),
        ));
    }
    let given: Vec<_> = keys
        .iter()
        .map(|(k, v, d)| (*k, *v, *d))
        .chain(std::iter::once(("speed", &fl.speed, Drive::Speed)))
        .filter_map(|(k, v, d)| v.as_ref().map(|v| (k, v, d)))
        .collect();
    match given.as_slice() {
        [] => Err(at(
            fl.kind.span(),
            match vessel {
                Vessel::Tube => {
                    "[flow] kind = \"tube\" needs one of flow_rate, mean_speed, speed, \
                     pressure_gradient"
                }
                Vessel::Channel => {
                    "[flow] kind = \"channel\" needs one of mean_speed, speed, \
                     pressure_gradient"
                }
            }
            .into(),
        )),
        [(key, v, drive)] => {
            let value = *v.get_ref();
            if !value.is_finite() {
                return Err(at(
                    v.span(),
                    format!("[flow] {key} must be finite, got {value}"),
                ));
            }
            Ok(Some(TubeDrive {
                vessel,
                drive: *drive,
                value,
                span: v.span(),
            }))
        }
        [(first, ..), (second, v, _), ..] => Err(at(
            v.span(),
            format!(
                "[flow] {second}: a {} flow takes one drive, and {first} is given",
                fl.kind.get_ref()
            ),
        )),
    }
}

/// The tube flow through the scene's tube container, or the channel flow through its channel
/// container, with the centreline speed from the drive.
pub(super) fn tube_flow(
    drive: &TubeDrive,
    walls: &[WallSpec],
    viscosity: f64,
    at: At,
) -> Result<Flow, SceneError> {
    if drive.vessel == Vessel::Channel {
        return channel_flow(drive, walls, viscosity, at);
    }
    let tube = walls.iter().find_map(|w| match (w.kind, &w.shape) {
        (WallKind::Container, &WallShape::Tube { radius, .. }) => Some((w, radius)),
        _ => None,
    });
    let Some((wall, radius)) = tube else {
        return Err(at(
            drive.span.clone(),
            "[flow] kind = \"tube\" needs a [[walls]] entry with kind = \"container\" and \
             shape = \"tube\""
                .into(),
        ));
    };
    let [_, y, z] = wall.center;
    if y != 0.0 || z != 0.0 {
        return Err(at(
            drive.span.clone(),
            format!(
                "[flow] kind = \"tube\": the tube wall (line {}) must have its axis on the x \
                 axis, center = [x, 0, 0]; got center = {:?}",
                wall.line, wall.center
            ),
        ));
    }
    let speed = match drive.drive {
        Drive::Speed => drive.value,
        Drive::MeanSpeed => 2.0 * drive.value,
        Drive::FlowRate => 2.0 * drive.value / (std::f64::consts::PI * radius * radius),
        Drive::PressureGradient => drive.value * radius * radius / (4.0 * viscosity),
    };
    Ok(Flow::Tube { speed, radius })
}

/// The channel flow between the plates of the scene's channel container.
fn channel_flow(
    drive: &TubeDrive,
    walls: &[WallSpec],
    viscosity: f64,
    at: At,
) -> Result<Flow, SceneError> {
    let channel = walls.iter().find_map(|w| match (w.kind, &w.shape) {
        (WallKind::Container, &WallShape::Channel { height, .. }) => Some((w, height)),
        _ => None,
    });
    let Some((wall, height)) = channel else {
        return Err(at(
            drive.span.clone(),
            "[flow] kind = \"channel\" needs a [[walls]] entry with kind = \"container\" and \
             shape = \"channel\""
                .into(),
        ));
    };
    if wall.center[2] != 0.0 {
        return Err(at(
            drive.span.clone(),
            format!(
                "[flow] kind = \"channel\": the channel wall (line {}) must have its midplane at \
                 z = 0, center = [x, y, 0]; got center = {:?}",
                wall.line, wall.center
            ),
        ));
    }
    let half_height = 0.5 * height;
    let speed = match drive.drive {
        Drive::Speed => drive.value,
        Drive::MeanSpeed => 1.5 * drive.value,
        Drive::PressureGradient => drive.value * half_height * half_height / (2.0 * viscosity),
        Drive::FlowRate => {
            return Err(at(
                drive.span.clone(),
                "[flow] flow_rate: a channel flow takes mean_speed, speed or pressure_gradient"
                    .into(),
            ))
        }
    };
    Ok(Flow::Channel { speed, half_height })
}

/// `[flow] recycle = true`: the tube's straight middle section, through which cells are
/// recycled (`None` when absent or false). Only a tube flow recycles; [`tube_flow`] has
/// checked its tube.
pub(super) fn recycle_window(
    fl: Option<&FlowSection>,
    walls: &[WallSpec],
    at: At,
) -> Result<Option<TubeWindow>, SceneError> {
    let Some(flag) = fl.and_then(|fl| fl.recycle.as_ref()) else {
        return Ok(None);
    };
    if !*flag.get_ref() {
        return Ok(None);
    }
    if fl.is_some_and(|fl| fl.kind.get_ref() != "tube") {
        return Err(at(
            flag.span(),
            "[flow] recycle applies to kind = \"tube\" only".into(),
        ));
    }
    let tube = walls.iter().find_map(|w| match (w.kind, &w.shape) {
        (WallKind::Container, &WallShape::Tube { length, .. }) => Some((w.center, length)),
        _ => None,
    });
    let Some((axis, length)) = tube else {
        return Err(at(
            flag.span(),
            "[flow] recycle needs a tube container".into(),
        ));
    };
    let half = 0.5 * crate::wall::straight_length(length, TUBE_WINDOW_TOLERANCE);
    Ok(Some(TubeWindow {
        inlet: axis[0] - half,
        outlet: axis[0] + half,
        axis,
    }))
}

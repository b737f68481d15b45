//! Cell scenes in physical units (`[units] system = "SI"`): the file's numbers are SI values,
//! and the scene is made dimensionless before it is validated and run.
//!
//! ```toml
//! [units]
//! system = "SI"             # "SI" | "dimensionless" (the default: the numbers are the
//! #                         # solver's own)
//! ```
//!
//! The scales come from the file:
//!
//! ```text
//! length     L = the first [[cells]] entry's radius (m; it must be given)
//! viscosity  μ = [fluid] viscosity (Pa·s; it must be given)
//! tension    G = that entry's shear_modulus (N/m), or κ/L² from its bending_modulus (J)
//! time       T = μ L / G,   velocity L/T = G/μ,   force G L,   energy G L²,   stress G/L
//! ```
//!
//! Every dimensional key is divided by its scale:
//!
//! | key | unit | scale |
//! |---|---|---|
//! | `[[cells]]` `radius`, `center`, `spacing`, `region`, `min_gap` | m | `L` |
//! | `[[walls]]` `radius`, `length`, `axes`, `center` | m | `L` |
//! | `[[walls]]` the values of a grid wall's `positions` file | m | `L` |
//! | `[[walls]]` the values of a grid wall's `velocity` file | m/s | `L/T` |
//! | `[output]` `velocity_plane` `origin`, `u`, `v` | m | `L` |
//! | `[numerics]` `contact_distance` | m | `L` |
//! | `[numerics]` `dt`, `t_end`, `dt_min`, `dt_max` | s | `T` |
//! | `[fluid]` `viscosity` | Pa·s | `μ` |
//! | `[flow]` `rate` | 1/s | `1/T` |
//! | `[flow]` `speed`, `mean_speed` | m/s | `L/T` |
//! | `[flow]` `radius` | m | `L` |
//! | `[flow]` `flow_rate` | m³/s | `L³/T` |
//! | `[flow]` `pressure_gradient` | Pa/m | `G/L²` |
//! | `[[cells]]` `shear_modulus` | N/m | `G` |
//! | `[[cells]]` `bending_modulus` | J | `G L²` |
//! | `[[cells]]` `force` | N | `G L` |
//! | `[numerics]` `repulsion_strength` | Pa | `G/L` |
//!
//! The rest are ratios (`axes` of a cell, `repulsion_range` (a fraction of the radius),
//! `reduced_volume`, `skalak_c`, `prestress`, `viscosity_ratio`, `volume_fraction`,
//! `gmres_tol`, `dt_tolerance`) or counts, and stay as written. The first
//! cells then have radius 1, shear modulus 1 (or bending modulus 1) in a fluid of viscosity 1.
//! Frames, observables and the summary are in these units; `summary.json`'s `units` gives the
//! scales to turn them back, and its `dimensionless` the groups of the first cells.
//!
//! Example: a red cell of equivalent radius 2.8 µm, `G = 6 µN/m`, `κ = 2·10⁻¹⁹ J`, in plasma of
//! 1.2 mPa·s: `T = 0.56 ms`, the reduced bending modulus `κ/(G L²) = 4.25·10⁻³`, and a shear
//! rate of 100/s is the capillary number `Ca = μ γ̇ L/G = 0.056`.

use std::ops::Range;

use serde::Serialize;
use toml::Spanned;

use super::cells_schema::{File, UnitsSection};
use super::SceneError;

/// The physical scales of a scene written in SI units: one unit of the solver's length, time
/// and viscosity in SI.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct UnitScales {
    /// `L` in metres.
    pub length_m: f64,
    /// `T = μL/G` in seconds.
    pub time_s: f64,
    /// `μ` in Pa·s.
    pub viscosity_pa_s: f64,
    /// `G` in N/m.
    pub tension_n_per_m: f64,
}

impl UnitScales {
    /// `L/T` in m/s.
    pub fn velocity_m_per_s(&self) -> f64 {
        self.length_m / self.time_s
    }

    /// `G L` in newtons.
    pub fn force_n(&self) -> f64 {
        self.tension_n_per_m * self.length_m
    }

    /// `G L²` in joules.
    pub fn energy_j(&self) -> f64 {
        self.tension_n_per_m * self.length_m * self.length_m
    }
}

type At<'a> = &'a dyn Fn(Range<usize>, String) -> SceneError;

fn scale(v: &mut Option<Spanned<f64>>, s: f64) {
    if let Some(v) = v {
        *v.get_mut() /= s;
    }
}

fn scale3(v: &mut Option<Spanned<[f64; 3]>>, s: f64) {
    if let Some(v) = v {
        for x in v.get_mut() {
            *x /= s;
        }
    }
}

/// Make the scene `f` dimensionless when its `[units]` asks for SI, and return the scales
/// (`None`: the numbers are the solver's own).
pub(super) fn to_dimensionless(f: &mut File, at: At) -> Result<Option<UnitScales>, SceneError> {
    let Some(UnitsSection { system }) = &f.units else {
        return Ok(None);
    };
    match system.get_ref().as_str() {
        "dimensionless" => return Ok(None),
        "SI" => {}
        other => {
            return Err(at(
                system.span(),
                format!("[units] system must be \"SI\" or \"dimensionless\", got \"{other}\""),
            ))
        }
    }
    let span = system.span();
    let positive = |v: &Option<Spanned<f64>>| {
        v.as_ref()
            .map(|v| *v.get_ref())
            .filter(|x| x.is_finite() && *x > 0.0)
    };
    let Some(first) = f.cells.as_ref().and_then(|c| c.first()) else {
        return Err(at(
            span,
            "[units] system = \"SI\" needs a [[cells]] entry (its radius sets the length scale)"
                .into(),
        ));
    };
    let Some(length) = positive(&first.radius) else {
        return Err(at(
            first.shape.span(),
            "[units] system = \"SI\": the first [[cells]] entry needs a positive radius in \
             metres (it sets the length scale)"
                .into(),
        ));
    };
    let Some(viscosity) = f
        .fluid
        .as_ref()
        .map(|fl| *fl.viscosity.get_ref())
        .filter(|x| x.is_finite() && *x > 0.0)
    else {
        return Err(at(
            span,
            "[units] system = \"SI\" needs [fluid] viscosity in Pa·s (it sets the viscosity scale)"
                .into(),
        ));
    };
    let tension = match (
        positive(&first.shear_modulus),
        positive(&first.bending_modulus),
    ) {
        (Some(g), _) => g,
        (None, Some(k)) => k / (length * length),
        (None, None) => {
            return Err(at(
                first.shape.span(),
                "[units] system = \"SI\": the first [[cells]] entry needs a positive \
                 shear_modulus (N/m) or bending_modulus (J); it sets the time scale μL/G"
                    .into(),
            ))
        }
    };
    let s = UnitScales {
        length_m: length,
        time_s: viscosity * length / tension,
        viscosity_pa_s: viscosity,
        tension_n_per_m: tension,
    };
    let (l, t, g) = (length, s.time_s, tension);
    if let Some(fl) = &mut f.fluid {
        *fl.viscosity.get_mut() /= viscosity;
    }
    if let Some(fl) = &mut f.flow {
        scale(&mut fl.rate, 1.0 / t);
        scale(&mut fl.speed, l / t);
        scale(&mut fl.mean_speed, l / t);
        scale(&mut fl.radius, l);
        scale(&mut fl.flow_rate, l * l * l / t);
        scale(&mut fl.pressure_gradient, g / (l * l));
    }
    for c in f.cells.iter_mut().flatten() {
        scale(&mut c.radius, l);
        scale3(&mut c.center, l);
        scale(&mut c.spacing, l);
        scale(&mut c.min_gap, l);
        if let Some(r) = &mut c.region {
            for x in r.get_mut().iter_mut().flatten() {
                *x /= l;
            }
        }
        scale(&mut c.shear_modulus, g);
        scale(&mut c.bending_modulus, g * l * l);
        scale3(&mut c.force, g * l);
    }
    for w in f.walls.iter_mut().flatten() {
        scale(&mut w.radius, l);
        scale(&mut w.length, l);
        scale(&mut w.width, l);
        scale(&mut w.height, l);
        scale3(&mut w.axes, l);
        scale3(&mut w.center, l);
        scale3(&mut w.angular_velocity, 1.0 / t);
    }
    if let Some(p) = f.output.as_mut().and_then(|o| o.velocity_plane.as_mut()) {
        for v in [&mut p.origin, &mut p.u, &mut p.v] {
            v.get_mut().iter_mut().for_each(|x| *x /= l);
        }
    }
    if let Some(n) = &mut f.numerics {
        scale(&mut n.contact_distance, l);
        scale(&mut n.dt, t);
        scale(&mut n.t_end, t);
        scale(&mut n.dt_min, t);
        scale(&mut n.dt_max, t);
        scale(&mut n.repulsion_strength, g / l);
    }
    Ok(Some(s))
}

/// The dimensionless groups of a scene's first cells (in `summary.json`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Groups {
    /// The flow's rate scale `γ̇` ([`super::cells::Flow::rate_scale`]).
    pub rate: f64,
    /// `Ca = μ γ̇ a / G_s` (`None` without a shear modulus).
    pub capillary_number: Option<f64>,
    /// `κ / (G_s a²)` (`None` without a shear modulus).
    pub reduced_bending: Option<f64>,
    /// `μ γ̇ a³ / κ`, the capillary number of a vesicle (`None` without bending).
    pub bending_capillary_number: Option<f64>,
    /// `λ = μ_in / μ`.
    pub viscosity_ratio: f64,
}

impl Groups {
    /// The groups of cells of radius `a`, shear modulus `g` and bending modulus `k` (each ≤ 0 when
    /// absent) and viscosity ratio `lambda`, in a fluid of viscosity `mu` at rate scale `rate`.
    pub fn of(mu: f64, rate: f64, a: f64, g: f64, k: f64, lambda: f64) -> Groups {
        let gs = (g > 0.0).then_some(g);
        let ks = (k > 0.0).then_some(k);
        Groups {
            rate,
            capillary_number: gs.map(|g| mu * rate * a / g),
            reduced_bending: gs.map(|g| k / (g * a * a)),
            bending_capillary_number: ks.map(|k| mu * rate * a.powi(3) / k),
            viscosity_ratio: lambda,
        }
    }
}

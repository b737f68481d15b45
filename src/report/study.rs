//! What an accuracy study is made of: the knobs it turns ([`Knob`]), the settings of one run
//! ([`Settings`]) and its rows and result ([`RunRow`], [`Study`]), shared by the study itself
//! ([`super::accuracy`]), its tables ([`super::tables`]) and its plot ([`super::plot`]).

use crate::scene::cells::{CellScene, Scheme};
use crate::timestep::near_implicit::CouplingMode;

/// A numerical knob of the study.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Knob {
    /// SH order `p`.
    Order,
    /// Quadrature upsampling factor (`q = upsample · p`).
    Upsample,
    /// FMM digits of the inter-cell velocity.
    FmmDigits,
    /// GMRES relative residual tolerance.
    GmresTol,
    /// Time step with the first-order scheme.
    DtEuler,
    /// Time step with BDF2.
    DtBdf2,
    /// How the cells' coupling enters a step: 0 explicit, 1 near-implicit.
    Coupling,
    /// The contact projection's smallest gap `d_min`.
    ContactDistance,
}

impl Knob {
    /// Name in the CSV, table and plot legend.
    pub fn name(self) -> &'static str {
        match self {
            Knob::Order => "order p",
            Knob::Upsample => "upsample",
            Knob::FmmDigits => "fmm digits",
            Knob::GmresTol => "gmres tol",
            Knob::DtEuler => "dt (euler)",
            Knob::DtBdf2 => "dt (bdf2)",
            Knob::Coupling => "coupling (0 explicit, 1 near-implicit)",
            Knob::ContactDistance => "contact distance",
        }
    }
}

/// The numerical settings of one run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// SH order `p`.
    pub order: usize,
    /// Quadrature upsampling factor.
    pub upsample: usize,
    /// FMM digits.
    pub fmm_digits: u32,
    /// GMRES relative residual tolerance.
    pub gmres_tol: f64,
    /// Time step.
    pub dt: f64,
    /// Time-stepping scheme.
    pub scheme: Scheme,
    /// How the cells' coupling enters a step.
    pub coupling: CouplingMode,
    /// The contact projection's `d_min` (`None`: no projection).
    pub contact_distance: Option<f64>,
}

impl Settings {
    pub(super) fn apply(&self, scene: &mut CellScene, t_end: f64) {
        let n = &mut scene.numerics;
        n.order = self.order;
        n.upsample = self.upsample;
        n.fmm_digits = self.fmm_digits;
        n.gmres_tol = self.gmres_tol;
        n.dt = self.dt;
        n.scheme = self.scheme;
        n.coupling = self.coupling;
        n.contact_distance = self.contact_distance;
        n.t_end = t_end;
        n.adaptive_dt = false;
    }

    pub(super) fn describe(&self) -> String {
        format!(
            "p = {}, upsample = {}, fmm_digits = {}, gmres_tol = {:.0e}, dt = {}, scheme = {}, \
             coupling = {}, contact_distance = {}",
            self.order,
            self.upsample,
            self.fmm_digits,
            self.gmres_tol,
            self.dt,
            scheme_name(self.scheme),
            self.coupling.name(),
            self.contact_distance
                .map_or("off".to_string(), |d| format!("{d}"))
        )
    }
}

pub(super) fn scheme_name(s: Scheme) -> &'static str {
    match s {
        Scheme::Euler => "euler",
        Scheme::Bdf2 => "bdf2",
    }
}

/// One row of the study.
#[derive(Clone, Debug)]
pub struct RunRow {
    /// `None` for the reference.
    pub knob: Option<Knob>,
    /// The knob's value (as a number, for the CSV and plot).
    pub value: f64,
    /// All numerical settings of the run.
    pub settings: Settings,
    /// Steps taken to `T` (0 for a failed run).
    pub steps: usize,
    /// Mean wall time of a step (s).
    pub step_s: f64,
    /// Mean GMRES iterations per step and cell.
    pub gmres_mean: f64,
    /// Largest distance between corresponding grid points of the final surfaces over the
    /// cell's equivalent radius.
    pub shape_error: f64,
    /// Hausdorff distance between the final surfaces over the cell radius (parametrisation-free).
    pub surface_error: f64,
    /// Centroid velocity over the last step, `|v − v_ref| / |v_ref|`, largest over the cells.
    pub velocity_error: f64,
    /// `max |σ − σ_ref| / max |σ_ref|` of the final tension.
    pub tension_error: f64,
    /// `max |u − u_ref| / max |u_ref|` of the inter-cell velocity in the first step (only
    /// with the reference's `p` and more than one cell).
    pub coupling_error: Option<f64>,
    /// Whether the run is on the Pareto front of (time per step, shape error).
    pub pareto: bool,
    /// Why the run failed, if it did (its errors are then NaN).
    pub failure: Option<String>,
}

/// The result of the study.
#[derive(Clone, Debug)]
pub struct Study {
    /// Which scene was used (a name or a path).
    pub scene_name: String,
    /// Number of cells in the scene.
    pub cells: usize,
    /// Final time `T` at which the runs are compared.
    pub t_end: f64,
    /// The reference run (its errors are 0).
    pub reference: RunRow,
    /// The knob runs, ordered by knob, then by time per step.
    pub rows: Vec<RunRow>,
    /// Knob values left out, with the reason.
    pub skipped: Vec<(Knob, f64, String)>,
    /// Remarks (reference level chosen, scheme availability, ...).
    pub notes: Vec<String>,
    /// Wall-time budget (s).
    pub budget_s: f64,
    /// Wall time of the whole study (s).
    pub wall_s: f64,
    /// Rayon threads the runs used.
    pub threads: usize,
}

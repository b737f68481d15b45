//! Reports: what accuracy costs in time (`mobo report accuracy`).
//!
//! [`accuracy`] runs the accuracy-versus-time study: every numerical knob of a cell scene
//! (SH order `p`, quadrature upsampling, FMM digits, GMRES tolerance, `dt`, scheme) is varied
//! on its own while the others stay at a high-accuracy reference, and the error of quantities
//! of interest against the reference run is set against the wall time per step. [`plot`] draws
//! the log–log plot of error against time per step (PNG).

pub mod accuracy;
pub mod plot;
pub mod study;
pub mod tables;

use std::path::PathBuf;

use crate::io::IoError;
use crate::run::CellRunError;
use crate::scene::SceneError;

/// Errors of a report.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// The scene could not be read or is invalid.
    #[error("{0}")]
    Scene(#[from] SceneError),
    /// A study run failed to build or to step; names the run (knob and value).
    #[error("study run {run}: {source}")]
    Run {
        /// The run's label.
        run: String,
        /// Its error.
        source: Box<CellRunError>,
    },
    /// A study run produced non-finite values.
    #[error("study run {run}: step {step}, cell {cell}: non-finite {quantity}")]
    NonFinite {
        /// The run's label.
        run: String,
        /// Step at which it happened.
        step: usize,
        /// Index of the cell (from 0, in scene order).
        cell: usize,
        /// Which quantity.
        quantity: &'static str,
    },
    /// A scene the study cannot use (e.g. no cells), or a bad option.
    #[error("{0}")]
    Invalid(String),
    /// A file could not be written.
    #[error("{0}")]
    Io(#[from] IoError),
    /// No TrueType font for the plot's text.
    #[error(
        "no TrueType font for the plot text: tried {tried}; install one (e.g. `apt-get install \
         fonts-dejavu-core`) or set MOBO_FONT to a .ttf file"
    )]
    Font {
        /// The font files tried.
        tried: String,
    },
    /// The plot could not be drawn.
    #[error("plot {path}: {message}")]
    Plot {
        /// The PNG file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

/// The default scene of the accuracy study: two red blood cells in simple shear, a little
/// apart (gap about 0.8 radii in x at the start, offset ±0.6 in the shear direction y), their
/// discs in the x–z plane. Two cells so that the FMM digits act on the inter-cell velocity.
/// The study overrides `[numerics]` with its reference settings and its own final time.
pub const STUDY_SCENE: &str = r#"
[fluid]
viscosity = 1.0

[flow]
kind = "shear"
rate = 1.0

[[cells]]
shape = "rbc"
radius = 1.0
bending_modulus = 0.1
center = [-2.0, 0.6, 0.0]
orientation = [1, 0, 0, 90]

[[cells]]
shape = "rbc"
radius = 1.0
bending_modulus = 0.1
center = [2.0, -0.6, 0.0]
orientation = [1, 0, 0, 90]

[numerics]
order = 12
dt = 0.05
t_end = 1.0
gmres_tol = 1e-12
fmm_digits = 10
"#;

//! Runs: what turns a scene ([`crate::scene`]) into steps, files and a summary.
//!
//! * [`cells`]: `mobo run`, a cell scene to its end on one process or over MPI ranks: frames,
//!   checkpoints, `summary.json`; [`assembly`] assembles the scene's cells into a
//!   [`crate::timestep::suspension::Suspension`] with the settings `mobo run` uses.
//! * [`simulation`]: the same scene stepped by a research code ([`Simulation`]), which reads
//!   the cells between steps and adds its own forces.
//! * [`partition`]: how the cells are split over MPI ranks and moved when the split goes stale.
//! * [`dpd`]: `mobo dpd`, dissipative particle dynamics; [`brownian`]: `mobo brownian`.
//!
//! Lower layers never import this one: the scene schema, the time steppers, the FMM and the
//! output formats know nothing of runs.

pub mod assembly;
pub mod brownian;
mod cell_step;
pub mod cells;
mod checkpoint;
pub mod dpd;
pub mod error;
pub mod observables;
mod output;
pub mod partition;
mod plane;
pub mod scene_copy;
pub mod simulation;
pub mod summary;

pub use error::CellRunError;
pub use simulation::Simulation;

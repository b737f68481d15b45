//! The errors of a cell run ([`super::cells::run_on`], [`super::simulation::Simulation`]).

use crate::comm::{CommError, Communicator};
use crate::io::IoError;
use crate::timestep::cell_state::CellStateError;
use crate::timestep::TimestepError;
use crate::vesicle::VesicleError;

/// Errors of a cell run.
#[derive(Debug, thiserror::Error)]
pub enum CellRunError {
    /// The step failed (solver, geometry), with the step number and the cell (numbered from 0
    /// in scene order, as [`crate::run::Simulation::cell`] and `summary.json`'s `per_cell`).
    #[error("step {step} (t = {time}){}: {source}", .cell.map(|c| format!(", cell {c}")).unwrap_or_default())]
    Step {
        /// The step that failed (numbered from 1; 0: building the cells).
        step: usize,
        /// The time the step was to reach.
        time: f64,
        /// The cell that failed, numbered from 0 in scene order (`None`: not one cell's).
        cell: Option<usize>,
        /// What failed.
        source: Box<TimestepError>,
    },
    /// Building a cell failed.
    #[error("{0}")]
    Cell(#[from] VesicleError),
    /// Output could not be written.
    #[error("{0}")]
    Io(#[from] IoError),
    /// A checkpoint does not fit the scene.
    #[error("cannot resume: {0}")]
    Resume(String),
    /// Communication between ranks failed, or another rank failed (its message).
    #[error("{0}")]
    Comm(CommError),
    /// A cell index beyond the scene's cells.
    #[error("no cell {index}: the scene has {cells} cells (indices from 0)")]
    NoSuchCell {
        /// The index asked for.
        index: usize,
        /// Cells in the scene.
        cells: usize,
    },
    /// A cell state gathered from the ranks does not decode.
    #[error("{0}")]
    State(#[from] CellStateError),
}

/// [`crate::comm::agreed`] with communication failures as [`CellRunError::Comm`].
pub(super) fn agreed<T>(
    comm: &dyn Communicator,
    local: Result<T, CellRunError>,
) -> Result<T, CellRunError> {
    crate::comm::agreed(comm, local, CellRunError::Comm)
}

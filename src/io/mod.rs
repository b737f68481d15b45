//! Output files: atomic writes, `.npy` arrays, JSON summaries, frames, VTK, checkpoints, HDF5.
//!
//! Every file is written to a temporary name in the same directory and renamed into place, so a
//! crashed run never leaves a half-written file under the final name. The one exception is the
//! HDF5 frame file, which grows frame by frame under a `.partial` name (see [`hdf5`]).
//!
//! * [`npy`]: `.npy` arrays.
//! * [`frames`]: the per-frame output of a run ([`frames::FrameWriter`]); [`plane_frames`]: the
//!   velocity on a plane at every frame ([`plane_frames::PlaneWriter`]).
//! * [`vtk`]: VTK XML PolyData (`.vtp`) meshes and ParaView collections (`.pvd`).
//! * [`checkpoint`]: the binary checkpoint container that restarts runs bit-for-bit.
//! * [`hdf5`]: `frames.h5` (cargo feature `hdf5`).

pub mod checkpoint;
pub mod frame_arrays;
pub mod frames;
pub mod hdf5;
pub mod npy;
pub mod plane_frames;
pub mod surface_mesh;
pub mod vtk;

pub use checkpoint::CheckpointFault;

use std::path::{Path, PathBuf};

/// Errors of the output layer.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// A file could not be written or renamed.
    #[error("{path}: {source}")]
    File {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// A malformed `.npy` file.
    #[error("{path}: {message}")]
    Npy {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A checkpoint that cannot be written or read back.
    #[error("checkpoint {path}: {fault}")]
    Checkpoint {
        /// The checkpoint file.
        path: PathBuf,
        /// What is wrong with it.
        fault: CheckpointFault,
    },
    /// A mesh or collection that cannot be written as VTK.
    #[error("{path}: {message}")]
    Vtk {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Frame data that does not fit the frame layout (wrong lengths, mixed orders, ...).
    #[error("frames in {dir}: {message}")]
    Frame {
        /// The output directory.
        dir: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An error of the HDF5 library.
    #[error("{path}: HDF5: {message}")]
    Hdf5 {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// HDF5 output was asked for but this build has no HDF5 support.
    #[error(
        "{path}: mobo was built without the hdf5 feature (rebuild with `cargo build --features hdf5`; \
         needs apt `libhdf5-dev pkg-config`)"
    )]
    Hdf5Unavailable {
        /// The HDF5 file asked for.
        path: PathBuf,
    },
}

/// Write `bytes` to `path` atomically (temporary file in the same directory, then rename;
/// [`crate::durable::write_atomic`]).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    crate::durable::write_atomic(path, bytes).map_err(|source| IoError::File {
        path: path.to_path_buf(),
        source,
    })
}

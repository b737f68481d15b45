//! Output files: atomic writes, `.npy` arrays, JSON summaries, frames, VTK, checkpoints, HDF5.
//!
//! Every file is written to a temporary name in the same directory and renamed into place, so a
//! crashed run never leaves a half-written file under the final name. The one exception is the
//! HDF5 frame file, which grows frame by frame under a `.partial` name (see [`hdf5`]).
//!
//! * [`npy`]: `.npy` arrays.
//! * [`frames`]: the per-frame output of a run ([`frames::FrameWriter`]).
//! * [`vtk`]: VTK XML PolyData (`.vtp`) meshes and ParaView collections (`.pvd`).
//! * [`checkpoint`]: the binary checkpoint container that restarts runs bit-for-bit.
//! * [`hdf5`]: `frames.h5` (cargo feature `hdf5`).

pub mod checkpoint;
pub mod frames;
pub mod hdf5;
pub mod npy;
pub mod vtk;

pub use checkpoint::CheckpointFault;

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Errors of the output layer.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// A file could not be written or renamed.
    #[error("{path}: {source}")]
    File {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A malformed `.npy` file.
    #[error("{path}: {message}")]
    Npy { path: PathBuf, message: String },
    /// A checkpoint that cannot be written or read back.
    #[error("checkpoint {path}: {fault}")]
    Checkpoint {
        path: PathBuf,
        fault: CheckpointFault,
    },
    /// A mesh or collection that cannot be written as VTK.
    #[error("{path}: {message}")]
    Vtk { path: PathBuf, message: String },
    /// Frame data that does not fit the frame layout (wrong lengths, mixed orders, ...).
    #[error("frames in {dir}: {message}")]
    Frame { dir: PathBuf, message: String },
    /// An error of the HDF5 library.
    #[error("{path}: HDF5: {message}")]
    Hdf5 { path: PathBuf, message: String },
    /// HDF5 output was asked for but this build has no HDF5 support.
    #[error(
        "{path}: mobo was built without the hdf5 feature (rebuild with `cargo build --features hdf5`; \
         needs apt `libhdf5-dev pkg-config`)"
    )]
    Hdf5Unavailable { path: PathBuf },
}

/// Write `bytes` to `path` atomically (temporary file in the same directory, then rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let err = |source| IoError::File {
        path: path.to_path_buf(),
        source,
    };
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    fs::create_dir_all(dir).map_err(err)?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    let mut f = fs::File::create(&tmp).map_err(err)?;
    f.write_all(bytes).map_err(err)?;
    f.sync_all().map_err(err)?;
    drop(f);
    fs::rename(&tmp, path).map_err(err)
}

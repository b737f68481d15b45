//! Output files: atomic writes, `.npy` arrays, JSON summaries.
//!
//! Every file is written to a temporary name in the same directory and renamed into place, so a
//! crashed run never leaves a half-written file under the final name.

pub mod npy;

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

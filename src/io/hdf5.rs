//! `DIR/frames.h5`: the frames of a run in one HDF5 file (cargo feature `hdf5`).
//!
//! # Layout
//!
//! One group per frame, `frame_NNNNN` (frame index, five digits or more), holding
//!
//! * attribute `time` (`f64` scalar), attribute `order` (`u64` scalar, the SH order `p`);
//! * dataset `coefs`, `f64`, shape `(cells, 3, n_coefs)`: per cell the `x`, `y`, `z` SH
//!   coefficients, `n_coefs = (p+1)² − 1`;
//! * dataset `positions`, `f64`, shape `(cells, 3, n_points)`: grid positions, component-major,
//!   `n_points = 2p(p+1)`;
//! * dataset `tension`, `f64`, shape `(cells, n_points)`: the tension on the SH grid.
//!
//! The arrays are the same as the `.npy` files of [`super::frames`].
//!
//! # Atomicity
//!
//! HDF5 files cannot be renamed into place after every frame without copying them, so the file
//! grows under the name `DIR/frames.h5.partial`: each frame is written and flushed (`H5Fflush`)
//! before [`H5FrameWriter::write_frame`] returns, so a crashed run leaves a readable
//! `frames.h5.partial` holding every completed frame. [`H5FrameWriter::finish`] closes the file
//! and renames it to `DIR/frames.h5`; a `frames.h5` therefore always is a complete run's output.
//! [`H5FrameWriter::create`] truncates an old `frames.h5.partial` (an old `frames.h5` stays
//! until `finish` replaces it; [`super::frames::FrameWriter::new`] deletes it first);
//! [`H5FrameWriter::resume`] continues a run restarted from a checkpoint.
//!
//! Without the `hdf5` feature every function returns [`IoError::Hdf5Unavailable`].

use std::path::{Path, PathBuf};

use super::frame_arrays::FrameArrays;
use super::IoError;

/// The finished file's name in the output directory.
pub const FILE_NAME: &str = "frames.h5";
/// The name the file grows under until [`H5FrameWriter::finish`].
pub const PARTIAL_NAME: &str = "frames.h5.partial";
/// Whether this build can write HDF5.
pub const AVAILABLE: bool = cfg!(feature = "hdf5");

/// Appends frames to `DIR/frames.h5.partial`; [`finish`](Self::finish) renames it to
/// `DIR/frames.h5`.
pub struct H5FrameWriter {
    partial: PathBuf,
    target: PathBuf,
    #[cfg(feature = "hdf5")]
    file: ::hdf5::File,
}

impl std::fmt::Debug for H5FrameWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("H5FrameWriter")
            .field("partial", &self.partial)
            .field("target", &self.target)
            .finish()
    }
}

#[cfg(feature = "hdf5")]
fn h5err(path: &Path) -> impl Fn(::hdf5::Error) -> IoError + '_ {
    move |e| IoError::Hdf5 {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

impl H5FrameWriter {
    /// Start `dir/frames.h5.partial` (creating `dir` if needed, truncating an old partial file).
    pub fn create(dir: &Path) -> Result<Self, IoError> {
        let partial = dir.join(PARTIAL_NAME);
        let target = dir.join(FILE_NAME);
        #[cfg(feature = "hdf5")]
        {
            std::fs::create_dir_all(dir).map_err(|source| IoError::File {
                path: dir.to_path_buf(),
                source,
            })?;
            let file = ::hdf5::File::create(&partial).map_err(h5err(&partial))?;
            Ok(H5FrameWriter {
                partial,
                target,
                file,
            })
        }
        #[cfg(not(feature = "hdf5"))]
        {
            let _ = partial;
            Err(IoError::Hdf5Unavailable { path: target })
        }
    }

    /// Continue the file of an interrupted (or finished) run in `dir` after its first `keep`
    /// frames: reopens `frames.h5.partial`, or else renames `frames.h5` back to it, checks that
    /// groups `frame_00000 .. frame_{keep-1}` exist, and deletes the groups of later frames (those
    /// written after the checkpoint the run restarts from).
    pub fn resume(dir: &Path, keep: usize) -> Result<Self, IoError> {
        let partial = dir.join(PARTIAL_NAME);
        let target = dir.join(FILE_NAME);
        #[cfg(feature = "hdf5")]
        {
            let source = if partial.exists() {
                partial.clone()
            } else if target.exists() {
                target.clone()
            } else if keep == 0 {
                return Self::create(dir);
            } else {
                return Err(IoError::Hdf5 {
                    path: target,
                    message: format!(
                        "cannot resume after {keep} frames: neither this file nor {PARTIAL_NAME} exists"
                    ),
                });
            };
            // Check the kept frames (read-only) before changing anything.
            {
                let file = ::hdf5::File::open(&source).map_err(h5err(&source))?;
                if let Some(name) = (0..keep)
                    .map(|i| format!("frame_{i:05}"))
                    .find(|name| !file.link_exists(name))
                {
                    return Err(IoError::Hdf5 {
                        path: source.clone(),
                        message: format!(
                            "cannot resume after {keep} frames: group {name} is missing"
                        ),
                    });
                }
            }
            if source == target {
                std::fs::rename(&target, &partial).map_err(|source| IoError::File {
                    path: target.clone(),
                    source,
                })?;
            }
            let e = h5err(&partial);
            let file = ::hdf5::File::open_rw(&partial).map_err(&e)?;
            for name in file.member_names().map_err(&e)? {
                let later = name
                    .strip_prefix("frame_")
                    .and_then(|n| n.parse::<usize>().ok())
                    .is_some_and(|n| n >= keep);
                if later {
                    file.unlink(&name).map_err(&e)?;
                }
            }
            file.flush().map_err(&e)?;
            drop(e);
            Ok(H5FrameWriter {
                partial,
                target,
                file,
            })
        }
        #[cfg(not(feature = "hdf5"))]
        {
            let _ = (partial, keep);
            Err(IoError::Hdf5Unavailable { path: target })
        }
    }

    /// Where the file grows until [`finish`](Self::finish).
    pub fn partial_path(&self) -> &Path {
        &self.partial
    }

    /// Append frame `index` (group `frame_NNNNN`) and flush it to disk.
    pub fn write_frame(
        &mut self,
        index: usize,
        time: f64,
        frame: &FrameArrays,
    ) -> Result<(), IoError> {
        #[cfg(feature = "hdf5")]
        {
            let e = h5err(&self.partial);
            let g = self
                .file
                .create_group(&format!("frame_{index:05}"))
                .map_err(&e)?;
            g.new_attr::<f64>()
                .create("time")
                .and_then(|a| a.write_scalar(&time))
                .map_err(&e)?;
            g.new_attr::<u64>()
                .create("order")
                .and_then(|a| a.write_scalar(&(frame.order as u64)))
                .map_err(&e)?;
            let data: [(&str, Vec<usize>, &[f64]); 3] = [
                ("coefs", frame.coefs_shape().to_vec(), &frame.coefs),
                (
                    "positions",
                    frame.positions_shape().to_vec(),
                    &frame.positions,
                ),
                ("tension", frame.tension_shape().to_vec(), &frame.tension),
            ];
            for (name, shape, values) in data {
                g.new_dataset::<f64>()
                    .shape(shape)
                    .create(name)
                    .and_then(|d| d.write_raw(values))
                    .map_err(&e)?;
            }
            self.file.flush().map_err(&e)?;
            Ok(())
        }
        #[cfg(not(feature = "hdf5"))]
        {
            let _ = (index, time, frame);
            Err(IoError::Hdf5Unavailable {
                path: self.target.clone(),
            })
        }
    }

    /// Flush, close, and rename `frames.h5.partial` to `frames.h5`; returns the final path.
    pub fn finish(self) -> Result<PathBuf, IoError> {
        #[cfg(feature = "hdf5")]
        {
            let H5FrameWriter {
                partial,
                target,
                file,
            } = self;
            file.flush().map_err(h5err(&partial))?;
            file.close().map_err(h5err(&partial))?;
            std::fs::rename(&partial, &target).map_err(|source| IoError::File {
                path: target.clone(),
                source,
            })?;
            Ok(target)
        }
        #[cfg(not(feature = "hdf5"))]
        {
            Err(IoError::Hdf5Unavailable { path: self.target })
        }
    }
}

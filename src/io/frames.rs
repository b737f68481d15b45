//! The frames of a run: `.npy` arrays, VTK meshes and HDF5, written by [`FrameWriter`].
//!
//! Frames are numbered `0, 1, 2, …` in the order they are written; `NNNNN` below is the frame
//! index with at least five digits. All cells of a frame have the same SH order `p`, with
//! `n_coefs = (p+1)² − 1` coefficients per coordinate and `n_points = 2p(p+1)` grid points.
//!
//! # `.npy` (`FrameFormats::npy`)
//!
//! * `DIR/frames/frame_NNNNN_coefs.npy`, shape `(cells, 3, n_coefs)`: per cell the `x`, `y`,
//!   `z` SH coefficients;
//! * `DIR/frames/frame_NNNNN_positions.npy`, shape `(cells, 3, n_points)`: grid positions,
//!   component-major;
//! * `DIR/frames/frame_NNNNN_tension.npy`, shape `(cells, n_points)`: tension on the grid;
//! * `DIR/frames/times.npy`, shape `(frames,)`: the time of every frame written so far
//!   (`times[i]` is the time of frame `i`), rewritten after each frame.
//!
//! # VTK (`FrameFormats::vtp = Some(k)`)
//!
//! * `DIR/vtk/frame_NNNNN.vtp`: every cell as a `k`-times subdivided icosphere
//!   ([`CellMesh::icosphere`] topology, `10·4^k + 2` vertices and `20·4^k` triangles per cell)
//!   placed on the cell's surface by evaluating its SH expansion, all cells in one PolyData
//!   (cell `c`'s vertices are `c·nv .. (c+1)·nv`). Point data: `tension` (the grid tension's SH
//!   expansion of order `p` evaluated at the vertices) and `cell` (the cell's index, `Int32`);
//!   cell data: `cell`.
//! * `DIR/vtk/frames.pvd`: the ParaView collection of all `.vtp` frames with their times,
//!   rewritten after each frame.
//!
//! # HDF5 (`FrameFormats::hdf5`)
//!
//! `DIR/frames.h5` (see [`super::hdf5`]; needs the cargo feature `hdf5`, otherwise
//! [`FrameWriter::new`] fails with [`IoError::Hdf5Unavailable`]).
//!
//! [`FrameWriter::new`] deletes the frame output of an earlier run in `DIR` (the files named
//! above, `frames.h5` and `frames.h5.partial`, and the plane frames of
//! [`super::plane_frames`]);
//! [`FrameWriter::resume`] keeps the frames before a checkpoint and continues after them.
//!
//! Every file is written atomically. Within a frame the data files come first and the indexes
//! (`times.npy`, `frames.pvd`) last, so an index never lists a frame whose files are missing.

use std::path::{Path, PathBuf};

pub use super::frame_arrays::{CellFrame, FrameArrays};
use super::hdf5::H5FrameWriter;
use super::vtk::{self, DataArray, PolyMesh};
use super::{npy, IoError};
use crate::sph_harmonics::basis::{angles_of, eval_basis, BasisScratch};
use crate::sph_harmonics::{CoefLayout, ShTransform, ShWorkspace};
use crate::vesicle::{shapes, CellMesh};

/// Which files a [`FrameWriter`] writes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameFormats {
    /// `.npy` arrays under `DIR/frames/`.
    pub npy: bool,
    /// `DIR/frames.h5` (needs the `hdf5` feature).
    pub hdf5: bool,
    /// `.vtp` meshes under `DIR/vtk/` with this many icosphere subdivisions.
    pub vtp: Option<u32>,
}

/// The mesh template and SH plan of the `.vtp` output (built on the first frame).
struct VtpState {
    order: usize,
    /// Icosphere topology and parameter-sphere points.
    template: CellMesh,
    sht: ShTransform,
    ws: ShWorkspace,
    /// The basis at every template vertex (`nv × n_coefs`), when small enough to keep.
    basis: Option<Vec<f64>>,
}

/// Keep the basis at the mesh vertices when it takes at most this many values (32 MiB).
const BASIS_CACHE_VALUES: usize = 1 << 22;

impl VtpState {
    fn new(order: usize, subdivisions: u32) -> Result<Self, String> {
        let unit = shapes::sphere(order, 1.0).map_err(|e| e.to_string())?;
        let template = CellMesh::icosphere(&unit, subdivisions).map_err(|e| e.to_string())?;
        let sht = ShTransform::new(order).map_err(|e| e.to_string())?;
        let ws = sht.workspace();
        let lay = CoefLayout::new(order);
        let nc = lay.len();
        let nv = template.sphere_points.len();
        let basis = (nv * nc <= BASIS_CACHE_VALUES).then(|| {
            let mut scratch = BasisScratch::new(order);
            let mut b = vec![0.0; nv * nc];
            for (y, row) in template.sphere_points.iter().zip(b.chunks_mut(nc)) {
                let (th, ph) = angles_of(*y);
                eval_basis(&lay, th, ph, &mut scratch, row);
            }
            b
        });
        Ok(VtpState {
            order,
            template,
            sht,
            ws,
            basis,
        })
    }

    /// All cells' meshes in one PolyData.
    fn mesh(&mut self, frame: &FrameArrays) -> Result<PolyMesh, String> {
        let nc = frame.n_coefs;
        let mut sigma = vec![0.0; frame.n_cells * nc];
        self.sht
            .forward(&frame.tension, &mut sigma, &mut self.ws)
            .map_err(|e| format!("tension transform: {e}"))?;
        let nv = self.template.sphere_points.len();
        let nt = self.template.triangles.len();
        let n = frame.n_cells;
        let mut mesh = PolyMesh {
            points: Vec::with_capacity(n * nv),
            triangles: Vec::with_capacity(n * nt),
            point_data: Vec::new(),
            cell_data: Vec::new(),
        };
        let mut tension = Vec::with_capacity(n * nv);
        let lay = CoefLayout::new(self.order);
        let mut scratch = BasisScratch::new(self.order);
        let mut row = vec![0.0; nc];
        for c in 0..n {
            let x = &frame.coefs[3 * nc * c..3 * nc * (c + 1)];
            let s = &sigma[nc * c..nc * (c + 1)];
            for (v, y) in self.template.sphere_points.iter().enumerate() {
                let b: &[f64] = match &self.basis {
                    Some(b) => &b[v * nc..(v + 1) * nc],
                    None => {
                        let (th, ph) = angles_of(*y);
                        eval_basis(&lay, th, ph, &mut scratch, &mut row);
                        &row
                    }
                };
                let dot = |a: &[f64]| a.iter().zip(b).map(|(a, b)| a * b).sum::<f64>();
                mesh.points
                    .push([dot(&x[..nc]), dot(&x[nc..2 * nc]), dot(&x[2 * nc..])]);
                tension.push(dot(s));
            }
            let off = c * nv;
            mesh.triangles.extend(
                self.template
                    .triangles
                    .iter()
                    .map(|t| [t[0] + off, t[1] + off, t[2] + off]),
            );
        }
        let ids = |k: usize| -> Vec<i32> {
            (0..n)
                .flat_map(|c| std::iter::repeat_n(c as i32, k))
                .collect()
        };
        mesh.point_data.push(DataArray::scalars("tension", tension));
        mesh.point_data.push(DataArray::ints("cell", ids(nv)));
        mesh.cell_data.push(DataArray::ints("cell", ids(nt)));
        Ok(mesh)
    }
}

/// The frame index of a file named `frame_NNNNN_<what>.npy` or `frame_NNNNN.vtp` (or a plane
/// frame's, [`super::plane_frames`]).
fn frame_index(name: &str) -> Option<usize> {
    let rest = name.strip_prefix("frame_")?;
    let digits = rest.bytes().take_while(u8::is_ascii_digit).count();
    let tail = &rest[digits..];
    let known = [
        "_coefs.npy",
        "_positions.npy",
        "_tension.npy",
        ".vtp",
        "_plane_velocity.npy",
        "_plane.vtp",
    ];
    (digits >= 5 && known.contains(&tail))
        .then(|| rest[..digits].parse().ok())
        .flatten()
}

fn remove_if_present(path: &Path) -> Result<(), IoError> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(IoError::File {
            path: path.to_path_buf(),
            source: e,
        }),
        _ => Ok(()),
    }
}

/// Delete the frame files of frames `keep..` in `dir` (if it exists).
fn remove_frames_from(dir: &Path, keep: usize) -> Result<(), IoError> {
    let err = |source| IoError::File {
        path: dir.to_path_buf(),
        source,
    };
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(err(e)),
    };
    for entry in entries {
        let entry = entry.map_err(err)?;
        let name = entry.file_name();
        if frame_index(&name.to_string_lossy()).is_some_and(|i| i >= keep) {
            let path = entry.path();
            std::fs::remove_file(&path).map_err(|source| IoError::File { path, source })?;
        }
    }
    Ok(())
}

/// Writes the frames of a run into an output directory (see the module documentation).
pub struct FrameWriter {
    dir: PathBuf,
    formats: FrameFormats,
    times: Vec<f64>,
    vtp: Option<VtpState>,
    h5: Option<H5FrameWriter>,
}

impl std::fmt::Debug for FrameWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FrameWriter")
            .field("dir", &self.dir)
            .field("formats", &self.formats)
            .field("frames", &self.times.len())
            .finish()
    }
}

impl FrameWriter {
    /// A writer for a new run in the output directory `dir` (created if missing). The frame
    /// output of an earlier run in `dir` (the files named in the module documentation) is
    /// deleted. Fails with
    /// [`IoError::Hdf5Unavailable`] when `formats.hdf5` is asked of a build without the `hdf5`
    /// feature, and with [`IoError::Frame`] for more than
    /// [`crate::vesicle::mesh::MAX_SUBDIVISIONS`] mesh subdivisions.
    pub fn new(dir: impl AsRef<Path>, formats: FrameFormats) -> Result<Self, IoError> {
        Self::open(dir.as_ref(), formats, &[])
    }

    /// Continue the frames of a run restarted from a checkpoint: `times` are the times of the
    /// frames written before the checkpoint (frames `0 .. times.len()`, e.g. saved in the
    /// checkpoint), whose files must exist in `dir` for every enabled format; files of later
    /// frames (written after the checkpoint) are deleted, `times.npy` and `frames.pvd` are
    /// rewritten for the kept frames, and the next frame is `times.len()`. For HDF5 see
    /// [`H5FrameWriter::resume`].
    pub fn resume(
        dir: impl AsRef<Path>,
        formats: FrameFormats,
        times: &[f64],
    ) -> Result<Self, IoError> {
        Self::open(dir.as_ref(), formats, times)
    }

    fn open(dir: &Path, formats: FrameFormats, times: &[f64]) -> Result<Self, IoError> {
        let dir = dir.to_path_buf();
        let keep = times.len();
        let err = |message: String| IoError::Frame {
            dir: dir.clone(),
            message,
        };
        if formats.hdf5 && !super::hdf5::AVAILABLE {
            return Err(IoError::Hdf5Unavailable {
                path: dir.join(super::hdf5::FILE_NAME),
            });
        }
        if let Some(k) = formats.vtp {
            if k > crate::vesicle::mesh::MAX_SUBDIVISIONS {
                return Err(err(format!(
                    "{k} mesh subdivisions asked; at most {}",
                    crate::vesicle::mesh::MAX_SUBDIVISIONS
                )));
            }
        }
        // Check the kept frames before touching anything.
        for i in 0..keep {
            let mut needed = Vec::new();
            if formats.npy {
                for what in ["coefs", "positions", "tension"] {
                    needed.push(dir.join("frames").join(format!("frame_{i:05}_{what}.npy")));
                }
            }
            if formats.vtp.is_some() {
                needed.push(dir.join("vtk").join(format!("frame_{i:05}.vtp")));
            }
            if let Some(f) = needed.iter().find(|f| !f.is_file()) {
                return Err(err(format!(
                    "cannot resume after {keep} frames: {} is missing",
                    f.display()
                )));
            }
        }
        if keep == 0 {
            for f in [
                "frames/times.npy",
                "vtk/frames.pvd",
                "vtk/plane.pvd",
                "vtk/walls.vtp",
                "frames/plane_points.npy",
                super::hdf5::FILE_NAME,
                super::hdf5::PARTIAL_NAME,
            ] {
                remove_if_present(&dir.join(f))?;
            }
        }
        let h5 = match (formats.hdf5, keep) {
            (false, _) => None,
            (true, 0) => Some(H5FrameWriter::create(&dir)?),
            (true, _) => Some(H5FrameWriter::resume(&dir, keep)?),
        };
        for (on, sub) in [(formats.npy, "frames"), (formats.vtp.is_some(), "vtk")] {
            if on {
                let d = dir.join(sub);
                std::fs::create_dir_all(&d).map_err(|source| IoError::File { path: d, source })?;
            }
        }
        remove_frames_from(&dir.join("frames"), keep)?;
        remove_frames_from(&dir.join("vtk"), keep)?;
        let w = FrameWriter {
            dir,
            formats,
            times: times.to_vec(),
            vtp: None,
            h5,
        };
        if keep > 0 {
            w.write_indexes()?;
        }
        Ok(w)
    }

    /// The output directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The times of the frames written so far.
    pub fn times(&self) -> &[f64] {
        &self.times
    }

    /// Write frame `index` at `time`. Frames are numbered consecutively from 0: `index` must be
    /// the number of frames written so far. Every cell must have the same order and slices of
    /// the lengths that order needs; nothing is written for a rejected frame.
    pub fn write_frame(
        &mut self,
        index: usize,
        time: f64,
        cells: &[CellFrame<'_>],
    ) -> Result<(), IoError> {
        let err = |message: String| IoError::Frame {
            dir: self.dir.clone(),
            message,
        };
        if index != self.times.len() {
            return Err(err(format!(
                "frame {index} written after {} frames (frames are numbered 0, 1, 2, … in order)",
                self.times.len()
            )));
        }
        let frame =
            FrameArrays::from_cells(cells).map_err(|m| err(format!("frame {index}: {m}")))?;
        if let Some(v) = &self.vtp {
            if v.order != frame.order {
                return Err(err(format!(
                    "frame {index} has SH order {} but earlier frames have {}",
                    frame.order, v.order
                )));
            }
        }
        if self.formats.npy {
            let f = self.dir.join("frames");
            npy::write_f64(
                &f.join(format!("frame_{index:05}_coefs.npy")),
                &frame.coefs_shape(),
                &frame.coefs,
            )?;
            npy::write_f64(
                &f.join(format!("frame_{index:05}_positions.npy")),
                &frame.positions_shape(),
                &frame.positions,
            )?;
            npy::write_f64(
                &f.join(format!("frame_{index:05}_tension.npy")),
                &frame.tension_shape(),
                &frame.tension,
            )?;
        }
        if let Some(h5) = &mut self.h5 {
            h5.write_frame(index, time, &frame)?;
        }
        if let Some(k) = self.formats.vtp {
            if self.vtp.is_none() {
                self.vtp = Some(
                    VtpState::new(frame.order, k)
                        .map_err(|m| err(format!("mesh of order {}: {m}", frame.order)))?,
                );
            }
            let state = self.vtp.as_mut().expect("made above");
            let mesh = state
                .mesh(&frame)
                .map_err(|m| err(format!("frame {index}: {m}")))?;
            vtk::write_polydata(
                &self.dir.join("vtk").join(format!("frame_{index:05}.vtp")),
                &mesh,
            )?;
        }
        self.times.push(time);
        self.write_indexes()
    }

    /// Rewrite `times.npy` and `frames.pvd` for the frames written so far.
    fn write_indexes(&self) -> Result<(), IoError> {
        if self.formats.npy {
            npy::write_f64(
                &self.dir.join("frames").join("times.npy"),
                &[self.times.len()],
                &self.times,
            )?;
        }
        if self.formats.vtp.is_some() {
            vtk::write_pvd_series(&self.dir.join("vtk").join("frames.pvd"), &self.times, |i| {
                format!("frame_{i:05}.vtp")
            })?;
        }
        Ok(())
    }

    /// Finish the output: closes and renames the HDF5 file (the other files are complete after
    /// every frame).
    pub fn finish(self) -> Result<(), IoError> {
        if let Some(h5) = self.h5 {
            h5.finish()?;
        }
        Ok(())
    }
}

//! The flow's velocity on a plane grid at every frame, written by [`PlaneWriter`] beside the
//! cells' frames ([`super::frames`]; frame `i` of the plane is frame `i` of the run, at
//! `times[i]`).
//!
//! * `DIR/frames/plane_points.npy`, shape `(n_v, n_u, 3)`: the sample points, `i` (along the
//!   plane's first edge) fastest;
//! * `DIR/frames/frame_NNNNN_plane_velocity.npy`, shape `(n_v, n_u, 3)`: the velocity at those
//!   points (`NaN` at points outside the fluid: inside a rigid body or outside a container);
//! * `DIR/vtk/frame_NNNNN_plane.vtp`: the plane as triangles (two per grid cell) with point
//!   data `speed` (the active scalar), `velocity` (3 components) and `in_fluid` (1, or 0 where
//!   the `.npy` has NaN: VTK's ASCII reader takes no NaN, so there the velocity is 0);
//! * `DIR/vtk/plane.pvd`: the ParaView collection of those `.vtp` files, rewritten after each.
//!
//! [`super::frames::FrameWriter`] deletes these files with the frames they belong to (a new
//! run deletes them all, a resumed run those after its checkpoint). Every file is written
//! atomically, the data before the index.

use std::path::{Path, PathBuf};

use super::vtk::{self, DataArray, DataValues, PolyMesh};
use super::{npy, IoError};

/// The `.pvd` collection of the plane's `.vtp` frames.
pub const PLANE_PVD: &str = "plane.pvd";
/// The sample points' file under `DIR/frames/`.
pub const PLANE_POINTS: &str = "plane_points.npy";

/// Writes the plane's frames (see the module documentation).
#[derive(Debug)]
pub struct PlaneWriter {
    dir: PathBuf,
    npy: bool,
    vtp: bool,
    shape: [usize; 2],
    points: Vec<[f64; 3]>,
    times: Vec<f64>,
}

impl PlaneWriter {
    /// A writer for the plane of `points` (`n_u · n_v` of them, `i` fastest; `shape` is
    /// `[n_u, n_v]`) in the output directory `dir`, as `.npy` arrays and/or `.vtp` meshes.
    /// `times` are those of the frames already written (a resumed run): their plane files must
    /// exist. The sample points are written now.
    pub fn new(
        dir: impl AsRef<Path>,
        npy: bool,
        vtp: bool,
        shape: [usize; 2],
        points: Vec<[f64; 3]>,
        times: &[f64],
    ) -> Result<Self, IoError> {
        let dir = dir.as_ref().to_path_buf();
        let err = |dir: &Path, message: String| IoError::Frame {
            dir: dir.to_path_buf(),
            message,
        };
        if shape[0] < 2 || shape[1] < 2 || points.len() != shape[0] * shape[1] {
            return Err(err(
                &dir,
                format!(
                    "a plane of {} points cannot have the shape {shape:?} (at least 2 × 2)",
                    points.len()
                ),
            ));
        }
        let w = PlaneWriter {
            dir,
            npy,
            vtp,
            shape,
            points,
            times: times.to_vec(),
        };
        for i in 0..times.len() {
            if let Some(f) = w.files(i).iter().find(|f| !f.is_file()) {
                return Err(err(
                    &w.dir,
                    format!(
                        "cannot resume after {} frames: {} is missing",
                        times.len(),
                        f.display()
                    ),
                ));
            }
        }
        for (on, sub) in [(npy, "frames"), (vtp, "vtk")] {
            if on {
                let d = w.dir.join(sub);
                std::fs::create_dir_all(&d).map_err(|source| IoError::File { path: d, source })?;
            }
        }
        if npy {
            let flat: Vec<f64> = w.points.iter().flatten().copied().collect();
            npy::write_f64(
                &w.dir.join("frames").join(PLANE_POINTS),
                &[shape[1], shape[0], 3],
                &flat,
            )?;
        }
        if !times.is_empty() {
            w.write_index()?;
        }
        Ok(w)
    }

    /// The files of plane frame `i`.
    fn files(&self, i: usize) -> Vec<PathBuf> {
        let mut out = vec![];
        if self.npy {
            out.push(
                self.dir
                    .join("frames")
                    .join(format!("frame_{i:05}_plane_velocity.npy")),
            );
        }
        if self.vtp {
            out.push(self.dir.join("vtk").join(format!("frame_{i:05}_plane.vtp")));
        }
        out
    }

    /// The sample points.
    pub fn points(&self) -> &[[f64; 3]] {
        &self.points
    }

    /// Write plane frame `index` at `time` (frames numbered from 0 in order, as the run's):
    /// `velocity` at every sample point.
    pub fn write(&mut self, index: usize, time: f64, velocity: &[[f64; 3]]) -> Result<(), IoError> {
        let err = |message: String| IoError::Frame {
            dir: self.dir.clone(),
            message,
        };
        if index != self.times.len() {
            return Err(err(format!(
                "plane frame {index} written after {} frames",
                self.times.len()
            )));
        }
        if velocity.len() != self.points.len() {
            return Err(err(format!(
                "plane frame {index}: {} velocities for {} points",
                velocity.len(),
                self.points.len()
            )));
        }
        let files = self.files(index);
        let mut files = files.iter();
        let flat: Vec<f64> = velocity.iter().flatten().copied().collect();
        if self.npy {
            let [nu, nv] = self.shape;
            npy::write_f64(files.next().expect("npy file"), &[nv, nu, 3], &flat)?;
        }
        if self.vtp {
            vtk::write_polydata(files.next().expect("vtp file"), &self.mesh(flat))?;
        }
        self.times.push(time);
        self.write_index()
    }

    /// The plane as triangles with the velocity and the speed as point data.
    fn mesh(&self, velocity: Vec<f64>) -> PolyMesh {
        let [nu, nv] = self.shape;
        let mut triangles = Vec::with_capacity(2 * (nu - 1) * (nv - 1));
        for j in 0..nv - 1 {
            for i in 0..nu - 1 {
                let a = j * nu + i;
                let (b, c, d) = (a + 1, a + nu, a + nu + 1);
                triangles.push([a, b, d]);
                triangles.push([a, d, c]);
            }
        }
        // VTK's ASCII reader takes no NaN: points outside the fluid get zeros and `in_fluid` 0.
        let in_fluid: Vec<i32> = velocity
            .chunks_exact(3)
            .map(|u| i32::from(u.iter().all(|v| v.is_finite())))
            .collect();
        let velocity: Vec<f64> = velocity
            .iter()
            .map(|&v| if v.is_finite() { v } else { 0.0 })
            .collect();
        let speed = velocity
            .chunks_exact(3)
            .map(|u| (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt())
            .collect();
        PolyMesh {
            points: self.points.clone(),
            triangles,
            point_data: vec![
                DataArray::scalars("speed", speed),
                DataArray {
                    name: "velocity".into(),
                    components: 3,
                    values: DataValues::Float64(velocity),
                },
                DataArray::ints("in_fluid", in_fluid),
            ],
            cell_data: vec![],
        }
    }

    /// Rewrite `plane.pvd` for the frames written so far.
    fn write_index(&self) -> Result<(), IoError> {
        if !self.vtp {
            return Ok(());
        }
        vtk::write_pvd_series(&self.dir.join("vtk").join(PLANE_PVD), &self.times, |i| {
            format!("frame_{i:05}_plane.vtp")
        })
    }
}

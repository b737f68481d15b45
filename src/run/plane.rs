//! `[output] velocity_plane` in `mobo run`: at every frame the flow's velocity on the scene's
//! plane grid ([`crate::scene::velocity_plane`]) is evaluated by
//! [`Suspension::velocity_at`] (background flow, every cell's single and double layer with the
//! interior value `u/λ` inside a cell, the walls; `NaN` outside the fluid) and written by
//! [`PlaneWriter`] beside the frame: `frames/frame_NNNNN_plane_velocity.npy` and
//! `vtk/frame_NNNNN_plane.vtp` (collected in `vtk/plane.pvd`).
//!
//! The cells' densities are those of the frame's state: the traction of its shape and of the
//! tension of the last solve, and the membrane velocity of the last solve. Frame 0 comes before
//! any solve: its tension is zero and the cells carry no double layer, so its plane shows the
//! flow of the bending and elastic forces alone. The walls' part is their solution of the last
//! step (at frame 0, for the background flow alone).

use super::cell_step::{flow_origin, step_error};
use super::error::{agreed, CellRunError};
use crate::comm::Communicator;
use crate::io::plane_frames::PlaneWriter;
use crate::scene::cells::CellScene;
use crate::timestep::suspension::Suspension;

/// The plane of a run: its sample points on every rank, its writer at rank 0.
pub(super) struct PlaneOutput {
    points: Vec<[f64; 3]>,
    writer: Option<PlaneWriter>,
}

impl PlaneOutput {
    /// The plane of `scene` (`None` without one), its files in `out` after the frames at
    /// `times` already written (a resumed run; collective: a failure to open is every rank's).
    pub(super) fn open(
        comm: &dyn Communicator,
        scene: &CellScene,
        out: &std::path::Path,
        times: &[f64],
    ) -> Result<Option<Self>, CellRunError> {
        let Some(plane) = scene.output.velocity_plane else {
            return Ok(None);
        };
        let points = plane.sample_points();
        let writer = (comm.rank() == 0)
            .then(|| {
                PlaneWriter::new(
                    out,
                    scene.output.npy,
                    scene.output.vtk.is_some(),
                    plane.points,
                    points.clone(),
                    times,
                )
            })
            .transpose()
            .map_err(CellRunError::from);
        let writer = agreed(comm, writer)?;
        Ok(Some(PlaneOutput { points, writer }))
    }

    /// Evaluate and write plane frame `index` (the run's frame about to be written) at step
    /// `step`, time `time` (collective).
    pub(super) fn write(
        &mut self,
        comm: &dyn Communicator,
        scene: &CellScene,
        susp: &mut Suspension,
        (index, step, time): (usize, usize, f64),
    ) -> Result<(), CellRunError> {
        let flow = scene.flow;
        let origin = flow_origin(comm, susp, &flow)?;
        let velocity = susp
            .velocity_at(comm, &|x| flow.velocity_about(x, origin), &self.points)
            .map_err(|e| step_error(step, time, e))?;
        let written = match &mut self.writer {
            Some(w) => w.write(index, time, &velocity).map_err(CellRunError::from),
            None => Ok(()),
        };
        agreed(comm, written)
    }
}

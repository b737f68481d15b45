//! Frames and cell states gathered from the ranks at rank 0 (collective).

use super::error::{agreed, CellRunError};
use crate::comm::Communicator;
use crate::io::frames::{CellFrame, FrameWriter};
use crate::io::surface_mesh::surface_mesh;
use crate::io::vtk::{write_polydata, DataArray, PolyMesh};
use crate::io::IoError;
use crate::scene::cells::{CellScene, CellSpec};
use crate::sph_harmonics::{ShTransform, ShWorkspace};
use crate::timestep::cell_state::CellState;
use crate::timestep::suspension::Suspension;
use crate::vesicle::VesicleError;

/// Every cell's `width` values from `local` (`(global index, values)`), in global order, at
/// rank 0 (`None` on the others).
pub(super) fn gather_rows(
    comm: &dyn Communicator,
    local: Vec<(usize, Vec<f64>)>,
    n_global: usize,
    width: usize,
) -> Result<Option<Vec<Vec<f64>>>, CellRunError> {
    let mut buf = Vec::with_capacity(local.len() * (width + 1));
    for (id, v) in local {
        buf.push(id as f64);
        buf.extend_from_slice(&v);
    }
    let all = comm.gather_f64(&buf, 0).map_err(CellRunError::Comm)?;
    if comm.rank() != 0 {
        return Ok(None);
    }
    let mut rows = vec![Vec::new(); n_global];
    for rec in all.iter().flat_map(|b| b.chunks_exact(width + 1)) {
        rows[rec[0] as usize] = rec[1..].to_vec();
    }
    Ok(Some(rows))
}

/// Every cell's state at rank 0, global order (`None` on the others).
pub(super) fn gather_states(
    comm: &dyn Communicator,
    susp: &Suspension,
    ncoef: usize,
    n: usize,
) -> Result<Option<Vec<CellState>>, CellRunError> {
    let width = CellState::encoded_len(ncoef, n);
    let local = (0..susp.len())
        .map(|i| {
            let mut v = Vec::with_capacity(width);
            susp.cell_state(i).encode(&mut v);
            (susp.cells()[i].id, v)
        })
        .collect();
    let Some(rows) = gather_rows(comm, local, susp.n_global(), width)? else {
        return Ok(None);
    };
    rows.iter()
        .map(|r| CellState::decode(r, ncoef, n).map_err(CellRunError::from))
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}

/// Write frame `frames.times().len()` at `time` from every cell's coefficients and tension
/// (global order).
pub(super) fn write_frame(
    frames: &mut FrameWriter,
    cells: &[(Vec<f64>, Vec<f64>)],
    sht: &ShTransform,
    ws: &mut ShWorkspace,
    time: f64,
) -> Result<(), CellRunError> {
    let n = sht.n_points();
    let mut x = vec![0.0; 3 * n * cells.len()];
    for (i, (c, _)) in cells.iter().enumerate() {
        sht.inverse(c, &mut x[3 * n * i..3 * n * (i + 1)], ws)
            .map_err(VesicleError::from)?;
    }
    let frame: Vec<CellFrame<'_>> = cells
        .iter()
        .enumerate()
        .map(|(i, (c, sigma))| CellFrame {
            order: sht.order(),
            coefs: c,
            positions: &x[3 * n * i..3 * n * (i + 1)],
            tension: sigma,
        })
        .collect();
    let index = frames.times().len();
    frames.write_frame(index, time, &frame)?;
    Ok(())
}

/// Gather the coefficients and tensions and write a frame at rank 0 (collective; an output
/// failure is returned on every rank).
pub(super) fn gathered_frame(
    comm: &dyn Communicator,
    susp: &Suspension,
    frames: Option<&mut FrameWriter>,
    sht: &ShTransform,
    ws: &mut ShWorkspace,
    time: f64,
) -> Result<(), CellRunError> {
    let (ncoef, n) = (sht.n_coefs() * 3, sht.n_points());
    let local = susp
        .cells()
        .iter()
        .map(|c| {
            (
                c.id,
                c.state
                    .coefs
                    .iter()
                    .chain(&c.state.sigma)
                    .copied()
                    .collect(),
            )
        })
        .collect();
    let rows = gather_rows(comm, local, susp.n_global(), ncoef + n)?;
    let written = match (rows, frames) {
        (Some(rows), Some(frames)) => {
            let cells: Vec<(Vec<f64>, Vec<f64>)> = rows
                .into_iter()
                .map(|mut r| {
                    let sigma = r.split_off(ncoef);
                    (r, sigma)
                })
                .collect();
            write_frame(frames, &cells, sht, ws, time)
        }
        _ => Ok(()),
    };
    agreed(comm, written)
}

/// `DIR/vtk/walls.vtp`: every wall of `scene` as a triangle mesh in its own angles
/// ([`surface_mesh`], `2p` latitudes of `4p` points for a wall of order `p`), and a plane wall
/// as a square of it under the cells ([`plane_patch`]), with the point and cell data `wall`
/// (its index in the scene; the plane's is the number of other walls) and `kind` (0 a
/// container, 1 a body). Nothing without walls or without VTK output.
pub(super) fn write_walls_vtp(
    scene: &CellScene,
    out: &std::path::Path,
) -> Result<(), CellRunError> {
    if (scene.walls.is_empty() && scene.plane.is_none()) || scene.output.vtk.is_none() {
        return Ok(());
    }
    let path = out.join("vtk").join("walls.vtp");
    let mut all = PolyMesh::default();
    let (mut wall, mut kind, mut wall_t, mut kind_t) = (vec![], vec![], vec![], vec![]);
    for (k, w) in scene.walls.iter().enumerate() {
        let surface = w.surface().map_err(|e| IoError::Frame {
            dir: path.clone(),
            message: format!("wall {k}: {e}"),
        })?;
        let p = surface.order();
        let m =
            surface_mesh(p, surface.coefs(), 2 * p, 4 * p).map_err(|message| IoError::Frame {
                dir: path.clone(),
                message,
            })?;
        let off = all.points.len();
        let code = i32::from(w.kind == crate::wall::WallKind::Body);
        wall.extend(std::iter::repeat_n(k as i32, m.points.len()));
        kind.extend(std::iter::repeat_n(code, m.points.len()));
        wall_t.extend(std::iter::repeat_n(k as i32, m.triangles.len()));
        kind_t.extend(std::iter::repeat_n(code, m.triangles.len()));
        all.points.extend(m.points);
        all.triangles
            .extend(m.triangles.iter().map(|t| t.map(|v| v + off)));
    }
    if let Some(plane) = &scene.plane {
        let plane =
            crate::wall::PlaneWall::new(plane.point, plane.normal).map_err(|e| IoError::Frame {
                dir: path.clone(),
                message: format!("the plane wall: {e}"),
            })?;
        let m = plane_patch(&plane, &scene.cells);
        let (k, off) = (scene.walls.len() as i32, all.points.len());
        wall.extend(std::iter::repeat_n(k, m.points.len()));
        kind.extend(std::iter::repeat_n(1, m.points.len()));
        wall_t.extend(std::iter::repeat_n(k, m.triangles.len()));
        kind_t.extend(std::iter::repeat_n(1, m.triangles.len()));
        all.points.extend(m.points);
        all.triangles
            .extend(m.triangles.iter().map(|t| t.map(|v| v + off)));
    }
    all.point_data = vec![DataArray::ints("wall", wall), DataArray::ints("kind", kind)];
    all.cell_data = vec![
        DataArray::ints("wall", wall_t),
        DataArray::ints("kind", kind_t),
    ];
    std::fs::create_dir_all(out.join("vtk")).map_err(|source| IoError::File {
        path: out.join("vtk"),
        source,
    })?;
    write_polydata(&path, &all)?;
    Ok(())
}

/// The points on a side of [`plane_patch`]'s square.
pub const PLANE_PATCH_POINTS: usize = 21;

/// A square of the plane wall `wall` for ParaView, centred under the cells' centres (their
/// mean projected onto the plane; the plane's point without cells) and reaching 4 radii past
/// the farthest centre (at least 4 of the largest radius; 10 without cells), as a grid of
/// [`PLANE_PATCH_POINTS`]² points along the wall's tangents, its triangles turned to the
/// plane's normal (into the fluid).
pub fn plane_patch(wall: &crate::wall::PlaneWall, cells: &[CellSpec]) -> PolyMesh {
    let n = wall.normal();
    let project = |x: [f64; 3]| {
        let h = wall.height(x);
        std::array::from_fn::<f64, 3, _>(|a| x[a] - h * n[a])
    };
    let centre = if cells.is_empty() {
        wall.point()
    } else {
        let m = cells.len() as f64;
        project(std::array::from_fn(|a| {
            cells.iter().map(|c| c.center[a]).sum::<f64>() / m
        }))
    };
    let half = if cells.is_empty() {
        10.0
    } else {
        cells
            .iter()
            .map(|c| {
                let d = project(c.center);
                let r = (0..3)
                    .map(|a| (d[a] - centre[a]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                r + 4.0 * c.radius
            })
            .fold(0.0, f64::max)
    };
    // The wall's tangents ((t1, t2, n) right-handed).
    let t1 = wall.vector_to_global([1.0, 0.0, 0.0]);
    let t2 = wall.vector_to_global([0.0, 1.0, 0.0]);
    let k = PLANE_PATCH_POINTS;
    let at = |i: usize| -half + 2.0 * half * i as f64 / (k - 1) as f64;
    let mut mesh = PolyMesh::default();
    for j in 0..k {
        for i in 0..k {
            let (u, v) = (at(i), at(j));
            mesh.points
                .push(std::array::from_fn(|a| centre[a] + u * t1[a] + v * t2[a]));
        }
    }
    for j in 0..k - 1 {
        for i in 0..k - 1 {
            let (a, b, c, d) = (
                j * k + i,
                j * k + i + 1,
                (j + 1) * k + i + 1,
                (j + 1) * k + i,
            );
            mesh.triangles.push([a, b, c]);
            mesh.triangles.push([a, c, d]);
        }
    }
    mesh
}

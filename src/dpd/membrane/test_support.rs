//! Test meshes and parameters shared by the unit tests of the membrane submodules.

use super::viscous::noise;
use super::{Bending, MembraneParams};

/// Octahedron (6 vertices, counter-clockwise from outside).
pub(crate) fn octahedron() -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
    let x = vec![
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
    ];
    let t = vec![
        [0, 2, 4],
        [2, 1, 4],
        [1, 3, 4],
        [3, 0, 4],
        [2, 0, 5],
        [1, 2, 5],
        [3, 1, 5],
        [0, 3, 5],
    ];
    (x, t)
}

/// The icosphere (the icosahedron subdivided `k` times, midpoints pushed to the unit sphere):
/// the parameter-sphere points of [`crate::vesicle::CellMesh::icosphere`], used here as a
/// plain test mesh (the membrane code itself does not depend on the vesicle module).
pub(crate) fn icosphere(k: usize) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
    let surface = crate::vesicle::shapes::sphere(2, 1.0).expect("unit sphere");
    let mesh = crate::vesicle::CellMesh::icosphere(&surface, k as u32).expect("icosphere");
    (mesh.sphere_points, mesh.triangles)
}

pub(super) fn jitter(x: &[[f64; 3]], amp: f64, seed: u64) -> Vec<[f64; 3]> {
    x.iter()
        .enumerate()
        .map(|(v, p)| {
            let mut q = *p;
            for (c, qc) in q.iter_mut().enumerate() {
                *qc += amp * noise(seed, 0, v, c as u64) / 3f64.sqrt();
            }
            q
        })
        .collect()
}

pub(super) fn full_params(bending: Bending) -> MembraneParams {
    MembraneParams {
        kbt: 1.0,
        persistence_length: 0.05,
        x0: 1.0 / 2.2,
        m: 2.0,
        bending,
        kd: 30.0,
        ka: 500.0,
        kv: 800.0,
        gamma_t: 3.0,
        gamma_c: 1.0,
    }
}

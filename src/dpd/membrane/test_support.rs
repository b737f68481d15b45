//! Test meshes and parameters shared by the unit tests of the membrane submodules.

use std::collections::HashMap;

use super::geometry::{norm, scale};
use super::viscous::noise;
use super::{Bending, MembraneParams};

/// Octahedron (6 vertices, counter-clockwise from outside).
pub(super) fn octahedron() -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
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

/// The icosphere (subdivided icosahedron) projected on the unit sphere: a test mesh that
/// does not need the vesicle module.
pub(super) fn icosphere(k: usize) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
    let g = (1.0 + 5f64.sqrt()) / 2.0;
    let mut x: Vec<[f64; 3]> = vec![
        [-1.0, g, 0.0],
        [1.0, g, 0.0],
        [-1.0, -g, 0.0],
        [1.0, -g, 0.0],
        [0.0, -1.0, g],
        [0.0, 1.0, g],
        [0.0, -1.0, -g],
        [0.0, 1.0, -g],
        [g, 0.0, -1.0],
        [g, 0.0, 1.0],
        [-g, 0.0, -1.0],
        [-g, 0.0, 1.0],
    ];
    let mut t: Vec<[usize; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..k {
        let mut mid: HashMap<(usize, usize), usize> = HashMap::new();
        let mut nt = Vec::new();
        for &[a, b, c] in &t {
            let mut m = |p: usize, q: usize| {
                *mid.entry((p.min(q), p.max(q))).or_insert_with(|| {
                    x.push(scale(
                        [x[p][0] + x[q][0], x[p][1] + x[q][1], x[p][2] + x[q][2]],
                        0.5,
                    ));
                    x.len() - 1
                })
            };
            let (ab, bc, ca) = (m(a, b), m(b, c), m(c, a));
            nt.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        t = nt;
    }
    for p in &mut x {
        *p = scale(*p, 1.0 / norm(*p));
    }
    (x, t)
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

//! A triangulated mesh of a spherical-harmonic cell surface (for VTK output and the DPD module).
//!
//! The icosahedron is subdivided `k` times (each triangle into four, midpoints pushed to the unit
//! sphere): `10·4^k + 2` vertices, `30·4^k` edges, `20·4^k` triangles, twelve vertices of valence
//! 5 and the rest of valence 6. Each vertex keeps its point `y` on the parameter sphere and is
//! placed at `X(θ(y), φ(y))` by evaluating the expansion there, so the same topology follows the
//! surface as it deforms ([`CellMesh::update`]). Triangles are oriented counter-clockwise seen
//! from outside (outward normals for a positively oriented surface).

use std::collections::HashMap;

use super::shapes::Surface;
use super::{check_len, cross, dot, VesicleError};
use crate::sph_harmonics::basis::{angles_of, eval_basis, BasisScratch};
use crate::sph_harmonics::CoefLayout;

/// Triangulated mesh of a cell surface.
#[derive(Clone, Debug)]
pub struct CellMesh {
    /// Vertex positions on the cell surface.
    pub vertices: Vec<[f64; 3]>,
    /// The vertices' points on the unit (parameter) sphere.
    pub sphere_points: Vec<[f64; 3]>,
    /// Triangles (vertex indices, counter-clockwise seen from outside).
    pub triangles: Vec<[usize; 3]>,
    /// Edges `[i, j]` with `i < j`, sorted.
    pub edges: Vec<[usize; 2]>,
    /// Adjacency in compressed rows: the neighbours of vertex `v` are
    /// `adjacency[adjacency_offsets[v]..adjacency_offsets[v + 1]]`, sorted.
    pub adjacency: Vec<usize>,
    /// Row offsets of [`Self::adjacency`] (`n_vertices + 1` values).
    pub adjacency_offsets: Vec<usize>,
    order: usize,
}

/// Subdivisions above this are refused (`20·4^10 ≈ 2·10⁷` triangles).
pub const MAX_SUBDIVISIONS: u32 = 10;

fn normalize(v: [f64; 3]) -> [f64; 3] {
    let n = dot(v, v).sqrt();
    v.map(|c| c / n)
}

impl CellMesh {
    /// The `k`-times subdivided icosphere mapped onto `surface`.
    pub fn icosphere(surface: &Surface, subdivisions: u32) -> Result<Self, VesicleError> {
        if subdivisions > MAX_SUBDIVISIONS {
            return Err(VesicleError::Parameter {
                name: "mesh subdivisions",
                value: subdivisions as f64,
                reason: "at most 10",
            });
        }
        let t = (1.0 + 5f64.sqrt()) / 2.0;
        let mut pts: Vec<[f64; 3]> = [
            [-1.0, t, 0.0],
            [1.0, t, 0.0],
            [-1.0, -t, 0.0],
            [1.0, -t, 0.0],
            [0.0, -1.0, t],
            [0.0, 1.0, t],
            [0.0, -1.0, -t],
            [0.0, 1.0, -t],
            [t, 0.0, -1.0],
            [t, 0.0, 1.0],
            [-t, 0.0, -1.0],
            [-t, 0.0, 1.0],
        ]
        .iter()
        .map(|&v| normalize(v))
        .collect();
        let mut tris: Vec<[usize; 3]> = vec![
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
        for _ in 0..subdivisions {
            let mut mid: HashMap<(usize, usize), usize> = HashMap::new();
            let mut next = Vec::with_capacity(4 * tris.len());
            let mut midpoint = |a: usize, b: usize, pts: &mut Vec<[f64; 3]>| {
                let key = (a.min(b), a.max(b));
                *mid.entry(key).or_insert_with(|| {
                    let (pa, pb) = (pts[a], pts[b]);
                    pts.push(normalize(std::array::from_fn(|c| pa[c] + pb[c])));
                    pts.len() - 1
                })
            };
            for &[a, b, c] in &tris {
                let ab = midpoint(a, b, &mut pts);
                let bc = midpoint(b, c, &mut pts);
                let ca = midpoint(c, a, &mut pts);
                next.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
            }
            tris = next;
        }
        let nv = pts.len();
        let mut edges: Vec<[usize; 2]> = tris
            .iter()
            .flat_map(|&[a, b, c]| [[a, b], [b, c], [c, a]])
            .map(|[i, j]| [i.min(j), i.max(j)])
            .collect();
        edges.sort_unstable();
        edges.dedup();
        let mut degree = vec![0usize; nv];
        for &[i, j] in &edges {
            degree[i] += 1;
            degree[j] += 1;
        }
        let mut offsets = vec![0usize; nv + 1];
        for v in 0..nv {
            offsets[v + 1] = offsets[v] + degree[v];
        }
        let mut fill = offsets.clone();
        let mut adjacency = vec![0usize; offsets[nv]];
        for &[i, j] in &edges {
            adjacency[fill[i]] = j;
            fill[i] += 1;
            adjacency[fill[j]] = i;
            fill[j] += 1;
        }
        for v in 0..nv {
            adjacency[offsets[v]..offsets[v + 1]].sort_unstable();
        }
        let mut mesh = CellMesh {
            vertices: vec![[0.0; 3]; nv],
            sphere_points: pts,
            triangles: tris,
            edges,
            adjacency,
            adjacency_offsets: offsets,
            order: surface.order(),
        };
        mesh.update(surface)?;
        Ok(mesh)
    }

    /// Re-place the vertices on a (deformed) surface of the same order.
    pub fn update(&mut self, surface: &Surface) -> Result<(), VesicleError> {
        if surface.order() != self.order {
            return Err(VesicleError::Order {
                p: self.order,
                q: surface.order(),
            });
        }
        let lay = CoefLayout::new(self.order);
        let nc = lay.len();
        check_len("surface coefficients", surface.coefs().len(), 3 * nc)?;
        let mut scratch = BasisScratch::new(self.order);
        let mut basis = vec![0.0; nc];
        let c = surface.coefs();
        for (v, y) in self.vertices.iter_mut().zip(&self.sphere_points) {
            let (th, ph) = angles_of(*y);
            eval_basis(&lay, th, ph, &mut scratch, &mut basis);
            *v = std::array::from_fn(|k| {
                c[k * nc..(k + 1) * nc]
                    .iter()
                    .zip(&basis)
                    .map(|(a, b)| a * b)
                    .sum()
            });
        }
        Ok(())
    }

    /// Neighbours of vertex `v`.
    pub fn neighbours(&self, v: usize) -> &[usize] {
        &self.adjacency[self.adjacency_offsets[v]..self.adjacency_offsets[v + 1]]
    }

    /// Length of every edge (in [`Self::edges`] order).
    pub fn edge_lengths(&self) -> Vec<f64> {
        self.edges
            .iter()
            .map(|&[i, j]| {
                let d: [f64; 3] =
                    std::array::from_fn(|c| self.vertices[i][c] - self.vertices[j][c]);
                dot(d, d).sqrt()
            })
            .collect()
    }

    /// Area of every triangle.
    pub fn triangle_areas(&self) -> Vec<f64> {
        self.triangles
            .iter()
            .map(|t| {
                let n = self.triangle_normal(t);
                0.5 * dot(n, n).sqrt()
            })
            .collect()
    }

    /// `(b − a) × (c − a)` of a triangle (twice its area along its outward normal).
    fn triangle_normal(&self, &[a, b, c]: &[usize; 3]) -> [f64; 3] {
        let (pa, pb, pc) = (self.vertices[a], self.vertices[b], self.vertices[c]);
        cross(
            std::array::from_fn(|k| pb[k] - pa[k]),
            std::array::from_fn(|k| pc[k] - pa[k]),
        )
    }

    /// Total area of the mesh.
    pub fn area(&self) -> f64 {
        self.triangle_areas().iter().sum()
    }

    /// Enclosed volume `Σ a·(b × c)/6` over the triangles.
    pub fn volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|&[a, b, c]| {
                dot(self.vertices[a], cross(self.vertices[b], self.vertices[c])) / 6.0
            })
            .sum()
    }
}

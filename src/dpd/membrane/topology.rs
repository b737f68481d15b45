//! Connectivity of a closed, consistently oriented triangle mesh ([`MembraneTopology`]).

use std::collections::HashMap;

use super::super::DpdError;

/// Connectivity of a closed, consistently oriented triangle mesh.
///
/// Edges are unique pairs `[i, j]` with `i < j`, sorted. Edge `e` has the triangle
/// `edge_triangles[e][0]`, which contains the directed edge `i → j` (so its third vertex
/// `edge_opposite[e][0]` follows `j`), and `edge_triangles[e][1]`, which contains `j → i`.
/// Vertex adjacency is stored in compressed rows.
#[derive(Debug, Clone, PartialEq)]
pub struct MembraneTopology {
    pub(super) n_vertices: usize,
    pub(super) triangles: Vec<[usize; 3]>,
    pub(super) edges: Vec<[usize; 2]>,
    edge_triangles: Vec<[usize; 2]>,
    pub(super) edge_opposite: Vec<[usize; 2]>,
    vertex_triangle_offsets: Vec<usize>,
    vertex_triangles: Vec<usize>,
    vertex_edge_offsets: Vec<usize>,
    vertex_edges: Vec<usize>,
}

impl MembraneTopology {
    /// Build the topology of `triangles` (counter-clockwise seen from outside) on
    /// `n_vertices` vertices.
    ///
    /// Errors ([`DpdError::Mesh`]): a vertex index out of range, a degenerate triangle (a repeated
    /// vertex), a directed edge used by two triangles (inconsistent orientation or a non-manifold
    /// edge), an edge with one triangle only (an open mesh), or a vertex in no triangle.
    pub fn new(n_vertices: usize, triangles: &[[usize; 3]]) -> Result<Self, DpdError> {
        if n_vertices < 4 || triangles.len() < 4 {
            return Err(DpdError::Mesh(format!(
                "{n_vertices} vertices and {} triangles cannot close a surface",
                triangles.len()
            )));
        }
        // Directed edge (a, b) -> (triangle, opposite vertex).
        let mut directed: HashMap<(usize, usize), (usize, usize)> =
            HashMap::with_capacity(3 * triangles.len());
        for (t, tri) in triangles.iter().enumerate() {
            if let Some(&v) = tri.iter().find(|&&v| v >= n_vertices) {
                return Err(DpdError::Mesh(format!(
                    "triangle {t} names vertex {v}, but there are {n_vertices} vertices"
                )));
            }
            if tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] {
                return Err(DpdError::Mesh(format!(
                    "triangle {t} = {tri:?} repeats a vertex"
                )));
            }
            for c in 0..3 {
                let (a, b, o) = (tri[c], tri[(c + 1) % 3], tri[(c + 2) % 3]);
                if let Some((t2, _)) = directed.insert((a, b), (t, o)) {
                    return Err(DpdError::Mesh(format!(
                        "edge {a}→{b} is used in the same direction by triangles {t2} and {t} \
                         (inconsistent orientation or a non-manifold edge)"
                    )));
                }
            }
        }
        let mut list: Vec<([usize; 2], [usize; 2], [usize; 2])> =
            Vec::with_capacity(directed.len() / 2);
        for (&(a, b), &(t, o)) in &directed {
            let Some(&(t2, o2)) = directed.get(&(b, a)) else {
                return Err(DpdError::Mesh(format!(
                    "edge {a}–{b} belongs to triangle {t} only: the mesh is not closed"
                )));
            };
            if a < b {
                list.push(([a, b], [t, t2], [o, o2]));
            }
        }
        list.sort_unstable_by_key(|e| e.0);
        let edges: Vec<[usize; 2]> = list.iter().map(|e| e.0).collect();
        let edge_triangles = list.iter().map(|e| e.1).collect();
        let edge_opposite = list.iter().map(|e| e.2).collect();

        let csr = |items: &mut dyn Iterator<Item = (usize, usize)>| {
            let pairs: Vec<(usize, usize)> = items.collect();
            let mut offsets = vec![0usize; n_vertices + 1];
            for &(v, _) in &pairs {
                offsets[v + 1] += 1;
            }
            for v in 0..n_vertices {
                offsets[v + 1] += offsets[v];
            }
            let mut fill = offsets.clone();
            let mut data = vec![0usize; pairs.len()];
            for &(v, item) in &pairs {
                data[fill[v]] = item;
                fill[v] += 1;
            }
            (offsets, data)
        };
        let (vertex_triangle_offsets, vertex_triangles) = csr(&mut triangles
            .iter()
            .enumerate()
            .flat_map(|(t, tri)| tri.iter().map(move |&v| (v, t))));
        let (vertex_edge_offsets, vertex_edges) = csr(&mut edges
            .iter()
            .enumerate()
            .flat_map(|(e, ed)| ed.iter().map(move |&v| (v, e))));
        if let Some(v) =
            (0..n_vertices).find(|&v| vertex_triangle_offsets[v + 1] == vertex_triangle_offsets[v])
        {
            return Err(DpdError::Mesh(format!("vertex {v} belongs to no triangle")));
        }
        Ok(Self {
            n_vertices,
            triangles: triangles.to_vec(),
            edges,
            edge_triangles,
            edge_opposite,
            vertex_triangle_offsets,
            vertex_triangles,
            vertex_edge_offsets,
            vertex_edges,
        })
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.n_vertices
    }

    /// The triangles (counter-clockwise seen from outside).
    pub fn triangles(&self) -> &[[usize; 3]] {
        &self.triangles
    }

    /// The unique edges `[i, j]`, `i < j`, sorted.
    pub fn edges(&self) -> &[[usize; 2]] {
        &self.edges
    }

    /// For every edge `[i, j]`: the triangle containing `i → j` and the one containing `j → i`.
    pub fn edge_triangles(&self) -> &[[usize; 2]] {
        &self.edge_triangles
    }

    /// For every edge `[i, j]`: the third vertex of each of its two triangles (same order as
    /// [`Self::edge_triangles`]).
    pub fn edge_opposite(&self) -> &[[usize; 2]] {
        &self.edge_opposite
    }

    /// The triangles containing vertex `v`.
    pub fn vertex_triangles(&self, v: usize) -> &[usize] {
        &self.vertex_triangles[self.vertex_triangle_offsets[v]..self.vertex_triangle_offsets[v + 1]]
    }

    /// The edges containing vertex `v`.
    pub fn vertex_edges(&self, v: usize) -> &[usize] {
        &self.vertex_edges[self.vertex_edge_offsets[v]..self.vertex_edge_offsets[v + 1]]
    }

    /// Euler characteristic `V − E + F` (2 for a sphere).
    pub fn euler_characteristic(&self) -> i64 {
        self.n_vertices as i64 - self.edges.len() as i64 + self.triangles.len() as i64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dpd::membrane::test_support::octahedron;
    use crate::dpd::membrane::{Membrane, MembraneParams};

    #[test]
    fn topology_of_octahedron() {
        let (_, t) = octahedron();
        let topo = MembraneTopology::new(6, &t).unwrap();
        assert_eq!(topo.edges().len(), 12);
        assert_eq!(topo.euler_characteristic(), 2);
        for (e, &[i, j]) in topo.edges().iter().enumerate() {
            assert!(i < j);
            let [t1, t2] = topo.edge_triangles()[e];
            let [k, l] = topo.edge_opposite()[e];
            assert!(topo.triangles()[t1].contains(&k) && topo.triangles()[t2].contains(&l));
            assert!(!topo.triangles()[t1].contains(&l));
        }
        for v in 0..6 {
            assert_eq!(topo.vertex_triangles(v).len(), 4);
            assert_eq!(topo.vertex_edges(v).len(), 4);
        }
    }

    #[test]
    fn bad_meshes_are_errors() {
        let (_, t) = octahedron();
        assert!(matches!(
            MembraneTopology::new(6, &t[..7]),
            Err(DpdError::Mesh(_))
        ));
        let mut flipped = t.clone();
        flipped[0] = [0, 4, 2];
        assert!(matches!(
            MembraneTopology::new(6, &flipped),
            Err(DpdError::Mesh(_))
        ));
        let mut bad = t.clone();
        bad[0] = [0, 2, 9];
        assert!(matches!(
            MembraneTopology::new(6, &bad),
            Err(DpdError::Mesh(_))
        ));
        bad[0] = [0, 0, 4];
        assert!(matches!(
            MembraneTopology::new(6, &bad),
            Err(DpdError::Mesh(_))
        ));
        assert!(matches!(
            MembraneTopology::new(7, &t),
            Err(DpdError::Mesh(_))
        ));
        // Inside-out mesh: a negative volume.
        let (x, _) = octahedron();
        let inv: Vec<[usize; 3]> = t.iter().map(|&[a, b, c]| [a, c, b]).collect();
        let topo = MembraneTopology::new(6, &inv).unwrap();
        assert!(Membrane::new(topo, MembraneParams::new(1.0, 1.0), &x).is_err());
    }
}

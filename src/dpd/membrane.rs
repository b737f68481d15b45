//! Visco-elastic membranes on closed triangle meshes: the RBC model of Fedosov, Caswell &
//! Karniadakis (2010, *A multiscale red blood cell model with accurate mechanics, rheology, and
//! dynamics*, Biophys. J. 98:2215) as implemented in Mirheo (Alexeev et al. 2020).
//!
//! The module depends on the mesh topology only: triangles `[a, b, c]` counter-clockwise seen
//! from outside a closed, consistently oriented surface ([`MembraneTopology`]). A [`Membrane`]
//! stores the reference (stress-free) geometry taken from the initial vertex positions: the
//! length `l0_e` of every edge, the area `A0_t` of every triangle, the total area `A0` and the
//! enclosed volume `V0`.
//!
//! # Energy
//!
//! `E = E_spring + E_bend + E_local + E_global + E_volume` with
//!
//! * **springs** (worm-like chain + power-law repulsion, one per edge `e` of length `l`):
//!   ```text
//!   E_WLC(l) = (k_BT l_max / 4p) (3x² − 2x³)/(1 − x),  x = l/l_max,  l_max = l0/x0
//!   E_POW(l) = k_p / ((m − 1) l^{m−1})        (m ≠ 1; −k_p ln l for m = 1)
//!   dE/dl    = (k_BT/p) (1/(4(1 − x)²) − 1/4 + x) − k_p / l^m
//!   ```
//!   In the stress-free model every edge has its own `l0` and `l_max = l0/x0`, and `k_p` is set
//!   so that the spring force vanishes at `l0`:
//!   `k_p = l0^m (k_BT/p) (1/(4(1 − x0)²) − 1/4 + x0)`.
//! * **bending**, one of
//!   - Kantor–Nelson: `E = Σ_edges k_b (1 − cos(θ_e − θ0))`, `θ_e` the signed angle between the
//!     outward normals of the two triangles of edge `e` (positive where the surface is convex);
//!   - Jülicher (1996): `E = 2κ Σ_v (M_v − M0_v)² / A_v` with `M_v = ¼ Σ_{e∋v} l_e θ_e` (the
//!     integrated mean curvature of the vertex), `A_v = ⅓ Σ_{t∋v} A_t` and
//!     `M0_v = C0 A_v / 2`: `C0` is the spontaneous curvature of the Helfrich energy
//!     `(κ/2) ∫ (2H − C0)² dA` (`H = (c1 + c2)/2`; a sphere of radius `R` has `M_v ≈ A_v/R`),
//!     so that `C0 = 2/R` makes the sphere of radius `R` bending-free.
//! * **local area**: `E = Σ_t k_d (A_t − A0_t)² / (2 A0_t)`;
//! * **global area**: `E = k_a (A − A0)² / (2 A0)`, `A = Σ_t A_t`;
//! * **volume**: `E = k_v (V − V0)² / (2 V0)`, `V = Σ_t (1/6) x_a · (x_b × x_c)` (signed
//!   tetrahedra with the origin).
//!
//! The forces are the analytic gradients `−∇E` ([`Membrane::add_forces`]): the spring force along
//! the edge; the triangle area gradient `∇_a A_t = ½ (x_b − x_c) × n̂` (cyclic); the volume
//! gradient `∇_a V = (1/6) Σ_{t∋a} x_b × x_c`; the dihedral-angle gradient
//! (Bridson, Marino & Fedkiw 2003) for an edge `i–j` with opposite vertices `k` (triangle
//! `i→j→k`) and `l` (triangle `j→i→l`),
//!
//! ```text
//! ∇_k θ = −n̂1 / h_k,   ∇_l θ = −n̂2 / h_l,      (h the distances to the edge line)
//! ∇_j θ = −α_k ∇_k θ − α_l ∇_l θ,   ∇_i θ = −(1 − α_k) ∇_k θ − (1 − α_l) ∇_l θ,
//! α_v = (x_v − x_i)·(x_j − x_i) / |x_j − x_i|²,
//! ```
//!
//! and for Jülicher the chain rule over the edge lengths, dihedral angles and vertex areas:
//! `∂E/∂M_v = 4κ D_v/A_v`, `∂E/∂A_v = −2κ (C0 D_v/A_v + D_v²/A_v²)` with `D_v = M_v − M0_v`.
//! Every term is invariant under translations and rotations, so its forces sum to zero and
//! exert no torque.
//!
//! # Membrane viscosity
//!
//! Every edge `i–j` carries a dissipative and a random force (Fedosov 2010, eqs. 12–13),
//! [`Membrane::add_viscous_forces`]:
//!
//! ```text
//! F^D_ij = −γ_T v_ij − γ_C (v_ij · e_ij) e_ij,
//! F^R_ij = √(2 k_BT / dt) (√(2γ_T) dW^S_ij + √(3γ_C − γ_T) tr(dW_ij)/3 · 1) · e_ij,
//! ```
//!
//! `v_ij = v_i − v_j`, `e_ij = (x_i − x_j)/|x_i − x_j|`, `dW_ij` a 3×3 matrix of independent
//! numbers of zero mean and unit variance, `dW^S = ½(dW + dWᵀ) − tr(dW)/3 · 1` its symmetric
//! traceless part. The covariance of `F^R` is `2 k_BT (γ_T 1 + γ_C e eᵀ)/dt`, which is the
//! fluctuation–dissipation theorem for `F^D`. The numbers come from a counter-based hash of
//! `(seed, step, edge, component)` (uniform, scaled to unit variance), so a trajectory does not
//! depend on the order of evaluation; `F_j = −F_i` conserves momentum.
//!
//! # Parameters from moduli
//!
//! [`MembraneParams::from_moduli`] maps the shear modulus `μ0`, the bending rigidity `κ` and the
//! area/volume coefficients onto the model (Fedosov 2010, eqs. 16–18). The linear shear modulus of
//! the triangular spring network is
//!
//! ```text
//! μ0 = √3 k_BT / (4 p l_max x0) · (x0/(2(1 − x0)³) − 1/(4(1 − x0)²) + 1/4)
//!      + √3 k_p (m + 1) / (4 l0^{m+1}),
//! ```
//!
//! which in the stress-free model (`E'(l0) = 0`) equals `(√3/4) E''(l0)`; with `k_p` from the
//! stress-free condition it is solved for the persistence length:
//!
//! ```text
//! p = √3 k_BT / (4 μ0 l0) · [x0 (1/(2(1 − x0)³) + 1) + m (1/(4(1 − x0)²) − 1/4 + x0)].
//! ```
//!
//! Bending: `k_b = 2κ/√3` (Kantor–Nelson), `κ` itself (Jülicher). The area compression modulus is
//! `K = 2μ0 + k_a + k_d` and Young's modulus `Y = 4Kμ0/(K + μ0)`.

use std::collections::HashMap;
use std::f64::consts::PI;

use super::{require, DpdError};

// ---------------------------------------------------------------------------------------------
// Small vector helpers.

#[inline]
fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
fn add_to(a: &mut [f64; 3], b: [f64; 3], s: f64) {
    a[0] += s * b[0];
    a[1] += s * b[1];
    a[2] += s * b[2];
}

#[inline]
fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

#[inline]
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline]
fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

// ---------------------------------------------------------------------------------------------
// Topology.

/// Connectivity of a closed, consistently oriented triangle mesh.
///
/// Edges are unique pairs `[i, j]` with `i < j`, sorted. Edge `e` has the triangle
/// `edge_triangles[e][0]`, which contains the directed edge `i → j` (so its third vertex
/// `edge_opposite[e][0]` follows `j`), and `edge_triangles[e][1]`, which contains `j → i`.
/// Vertex adjacency is stored in compressed rows.
#[derive(Debug, Clone, PartialEq)]
pub struct MembraneTopology {
    n_vertices: usize,
    triangles: Vec<[usize; 3]>,
    edges: Vec<[usize; 2]>,
    edge_triangles: Vec<[usize; 2]>,
    edge_opposite: Vec<[usize; 2]>,
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

// ---------------------------------------------------------------------------------------------
// Parameters.

/// Bending model with its coefficients.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Bending {
    /// No bending energy.
    None,
    /// Kantor–Nelson: `E = Σ_edges kb (1 − cos(θ − θ0))`, `θ0` in radians.
    KantorNelson { kb: f64, theta0: f64 },
    /// Jülicher: `E = 2κ Σ_v (M_v − C0 A_v/2)² / A_v`.
    Juelicher { kappa: f64, c0: f64 },
}

/// Which bending model [`MembraneParams::from_moduli`] builds, with its spontaneous shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BendingModel {
    /// Kantor–Nelson with spontaneous angle `theta0` (radians), `kb = 2κ/√3`.
    KantorNelson { theta0: f64 },
    /// Jülicher with spontaneous curvature `c0` (`C0 = 2/R` for a sphere of radius `R`).
    Juelicher { c0: f64 },
}

/// Membrane parameters, all in simulation units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MembraneParams {
    /// Thermal energy `k_BT` (scales the WLC springs and the random forces).
    pub kbt: f64,
    /// WLC persistence length `p`.
    pub persistence_length: f64,
    /// `x0 = l0/l_max` (default `1/2.2`).
    pub x0: f64,
    /// POW exponent `m` (default 2).
    pub m: f64,
    /// Bending model.
    pub bending: Bending,
    /// Local (per triangle) area coefficient `k_d`.
    pub kd: f64,
    /// Global area coefficient `k_a`.
    pub ka: f64,
    /// Volume coefficient `k_v`.
    pub kv: f64,
    /// Membrane viscosity `γ_T`.
    pub gamma_t: f64,
    /// Membrane viscosity `γ_C` (needs `3γ_C ≥ γ_T`; Fedosov takes `γ_C = γ_T/3`).
    pub gamma_c: f64,
}

/// Physical moduli for [`MembraneParams::from_moduli`], in simulation units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Moduli {
    /// Linear shear modulus `μ0` (energy/length²).
    pub shear_modulus: f64,
    /// Bending rigidity `κ` (energy).
    pub bending_rigidity: f64,
    /// Bending model and its spontaneous angle/curvature.
    pub bending: BendingModel,
    /// Global area coefficient `k_a` (energy/length²).
    pub ka: f64,
    /// Local area coefficient `k_d` (energy/length²).
    pub kd: f64,
    /// Volume coefficient `k_v` (energy/length³).
    pub kv: f64,
    /// Thermal energy `k_BT`.
    pub kbt: f64,
    /// `x0 = l0/l_max`.
    pub x0: f64,
    /// POW exponent `m`.
    pub m: f64,
    /// Mean edge length `l0` of the reference mesh.
    pub mean_edge_length: f64,
    /// Membrane viscosity `γ_T`.
    pub gamma_t: f64,
    /// Membrane viscosity `γ_C`; `None` takes `γ_T/3`.
    pub gamma_c: Option<f64>,
}

/// `g(x) = 1/(4(1 − x)²) − 1/4 + x`: the WLC force in units of `k_BT/p`.
#[inline]
fn wlc_g(x: f64) -> f64 {
    0.25 / ((1.0 - x) * (1.0 - x)) - 0.25 + x
}

impl MembraneParams {
    /// Springs with thermal energy `kbt` and persistence length `persistence_length`,
    /// `x0 = 1/2.2`, `m = 2`, no bending, no area or volume terms, no viscosity.
    pub fn new(kbt: f64, persistence_length: f64) -> Self {
        Self {
            kbt,
            persistence_length,
            x0: 1.0 / 2.2,
            m: 2.0,
            bending: Bending::None,
            kd: 0.0,
            ka: 0.0,
            kv: 0.0,
            gamma_t: 0.0,
            gamma_c: 0.0,
        }
    }

    /// Parameters from physical moduli (Fedosov 2010; see the module documentation):
    /// `p` from `μ0` with `k_p` from the stress-free condition at the mean edge length,
    /// `kb = 2κ/√3` (Kantor–Nelson) or `κ` (Jülicher).
    pub fn from_moduli(m: &Moduli) -> Result<Self, DpdError> {
        let pos = |v: f64| v > 0.0 && v.is_finite();
        require(
            pos(m.shear_modulus),
            "shear modulus",
            m.shear_modulus,
            "must be positive and finite",
        )?;
        require(
            pos(m.kbt),
            "kbt",
            m.kbt,
            "must be positive and finite (the WLC scale is kBT/p)",
        )?;
        require(
            pos(m.mean_edge_length),
            "mean edge length",
            m.mean_edge_length,
            "must be positive and finite",
        )?;
        require(m.x0 > 0.0 && m.x0 < 1.0, "x0", m.x0, "must lie in (0, 1)")?;
        require(
            pos(m.m),
            "POW exponent m",
            m.m,
            "must be positive and finite",
        )?;
        require(
            m.bending_rigidity >= 0.0 && m.bending_rigidity.is_finite(),
            "bending rigidity",
            m.bending_rigidity,
            "must be non-negative and finite",
        )?;
        let (x0, l0) = (m.x0, m.mean_edge_length);
        let c = x0 * (0.5 / (1.0 - x0).powi(3) + 1.0) + m.m * wlc_g(x0);
        let p = 3f64.sqrt() * m.kbt / (4.0 * m.shear_modulus * l0) * c;
        let bending = match m.bending {
            BendingModel::KantorNelson { theta0 } => Bending::KantorNelson {
                kb: 2.0 * m.bending_rigidity / 3f64.sqrt(),
                theta0,
            },
            BendingModel::Juelicher { c0 } => Bending::Juelicher {
                kappa: m.bending_rigidity,
                c0,
            },
        };
        let params = Self {
            kbt: m.kbt,
            persistence_length: p,
            x0,
            m: m.m,
            bending,
            kd: m.kd,
            ka: m.ka,
            kv: m.kv,
            gamma_t: m.gamma_t,
            gamma_c: m.gamma_c.unwrap_or(m.gamma_t / 3.0),
        };
        params.validate()?;
        Ok(params)
    }

    /// Check every parameter's domain.
    pub fn validate(&self) -> Result<(), DpdError> {
        let nonneg = |v: f64| v >= 0.0 && v.is_finite();
        require(
            nonneg(self.kbt),
            "kbt",
            self.kbt,
            "must be non-negative and finite",
        )?;
        require(
            self.persistence_length > 0.0 && self.persistence_length.is_finite(),
            "persistence length",
            self.persistence_length,
            "must be positive and finite",
        )?;
        require(
            self.x0 > 0.0 && self.x0 < 1.0,
            "x0",
            self.x0,
            "must lie in (0, 1)",
        )?;
        require(
            self.m > 0.0 && self.m.is_finite(),
            "POW exponent m",
            self.m,
            "must be positive and finite",
        )?;
        require(
            nonneg(self.kd),
            "kd",
            self.kd,
            "must be non-negative and finite",
        )?;
        require(
            nonneg(self.ka),
            "ka",
            self.ka,
            "must be non-negative and finite",
        )?;
        require(
            nonneg(self.kv),
            "kv",
            self.kv,
            "must be non-negative and finite",
        )?;
        require(
            nonneg(self.gamma_t),
            "gamma_t",
            self.gamma_t,
            "must be non-negative and finite",
        )?;
        require(
            nonneg(self.gamma_c),
            "gamma_c",
            self.gamma_c,
            "must be non-negative and finite",
        )?;
        require(
            3.0 * self.gamma_c >= self.gamma_t,
            "gamma_c",
            self.gamma_c,
            "must be at least gamma_t/3 (the random force needs 3γ_C − γ_T ≥ 0)",
        )?;
        match self.bending {
            Bending::None => {}
            Bending::KantorNelson { kb, theta0 } => {
                require(nonneg(kb), "kb", kb, "must be non-negative and finite")?;
                require(theta0.is_finite(), "theta0", theta0, "must be finite")?;
            }
            Bending::Juelicher { kappa, c0 } => {
                require(
                    nonneg(kappa),
                    "kappa",
                    kappa,
                    "must be non-negative and finite",
                )?;
                require(c0.is_finite(), "c0", c0, "must be finite")?;
            }
        }
        Ok(())
    }

    /// POW coefficient `k_p = l0^m (k_BT/p) g(x0)` that makes a spring of rest length `l0`
    /// stress-free.
    pub fn kp(&self, l0: f64) -> f64 {
        l0.powf(self.m) * self.kbt / self.persistence_length * wlc_g(self.x0)
    }

    /// Linear shear modulus `μ0` of a network with edge length `l0` (Fedosov 2010, eq. 16,
    /// with `k_p` from [`Self::kp`]).
    pub fn shear_modulus(&self, l0: f64) -> f64 {
        let x0 = self.x0;
        let lmax = l0 / x0;
        let s3 = 3f64.sqrt();
        s3 * self.kbt / (4.0 * self.persistence_length * lmax * x0)
            * (x0 / (2.0 * (1.0 - x0).powi(3)) - 0.25 / ((1.0 - x0) * (1.0 - x0)) + 0.25)
            + s3 * self.kp(l0) * (self.m + 1.0) / (4.0 * l0.powf(self.m + 1.0))
    }

    /// Area compression modulus `K = 2μ0 + k_a + k_d`.
    pub fn area_compression_modulus(&self, l0: f64) -> f64 {
        2.0 * self.shear_modulus(l0) + self.ka + self.kd
    }

    /// Young's modulus `Y = 4Kμ0/(K + μ0)`.
    pub fn youngs_modulus(&self, l0: f64) -> f64 {
        let mu = self.shear_modulus(l0);
        let k = self.area_compression_modulus(l0);
        4.0 * k * mu / (k + mu)
    }

    /// Bending rigidity `κ` of the bending model (`√3 kb/2` for Kantor–Nelson).
    pub fn bending_rigidity(&self) -> f64 {
        match self.bending {
            Bending::None => 0.0,
            Bending::KantorNelson { kb, .. } => 3f64.sqrt() * kb / 2.0,
            Bending::Juelicher { kappa, .. } => kappa,
        }
    }

    /// Spring energy of an edge with rest length `l0` at length `l`, and its derivative
    /// `dE/dl`; `None` where `l ≥ l_max` (the WLC diverges).
    #[inline]
    fn spring(&self, l: f64, l0: f64, kp: f64, want_energy: bool) -> Option<(f64, f64)> {
        let lmax = l0 / self.x0;
        let x = l / lmax;
        if x.is_nan() || x >= 1.0 || l.is_nan() || l <= 0.0 {
            return None;
        }
        let ks = self.kbt / self.persistence_length;
        let de = ks * wlc_g(x) - kp / l.powf(self.m);
        let e = if want_energy {
            let wlc = 0.25 * ks * lmax * (3.0 * x * x - 2.0 * x * x * x) / (1.0 - x);
            let pow = if (self.m - 1.0).abs() < 1e-12 {
                -kp * l.ln()
            } else {
                kp / ((self.m - 1.0) * l.powf(self.m - 1.0))
            };
            wlc + pow
        } else {
            0.0
        };
        Some((e, de))
    }
}

/// Spontaneous Kantor–Nelson angle of a triangulated sphere with `n_vertices` vertices (Fedosov
/// 2010): `cos θ0 = (√3 (N_v − 2) − 5π) / (√3 (N_v − 2) − 3π)`.
pub fn sphere_spontaneous_angle(n_vertices: usize) -> f64 {
    let a = 3f64.sqrt() * (n_vertices as f64 - 2.0);
    ((a - 5.0 * PI) / (a - 3.0 * PI)).clamp(-1.0, 1.0).acos()
}

// ---------------------------------------------------------------------------------------------
// Geometry kernels.

/// Signed dihedral angle of edge `i–j` (opposite vertices `k` in triangle `i→j→k`, `l` in
/// triangle `j→i→l`), positive where the surface is convex, and its gradients with respect to
/// `[x_i, x_j, x_k, x_l]`.
#[inline]
fn dihedral(xi: [f64; 3], xj: [f64; 3], xk: [f64; 3], xl: [f64; 3]) -> (f64, [[f64; 3]; 4]) {
    let e = sub(xj, xi);
    let n1 = cross(e, sub(xk, xi));
    let n2 = cross(sub(xi, xj), sub(xl, xj));
    let e2 = dot(e, e);
    let el = e2.sqrt();
    let n1n = dot(n1, n1);
    let n2n = dot(n2, n2);
    let inv = 1.0 / (n1n * n2n).sqrt();
    let cos = dot(n1, n2) * inv;
    let sin = dot(cross(n1, n2), e) * inv / el;
    let theta = sin.atan2(cos);
    // ∇_k θ = −n̂1/h_k = −n1 |e| / |n1|² (|n1| = |e| h_k).
    let gk = scale(n1, -el / n1n);
    let gl = scale(n2, -el / n2n);
    let ak = dot(sub(xk, xi), e) / e2;
    let al = dot(sub(xl, xi), e) / e2;
    let mut gj = scale(gk, -ak);
    add_to(&mut gj, gl, -al);
    let mut gi = scale(gk, ak - 1.0);
    add_to(&mut gi, gl, al - 1.0);
    (theta, [gi, gj, gk, gl])
}

/// Signed dihedral angle only.
#[inline]
fn dihedral_angle(xi: [f64; 3], xj: [f64; 3], xk: [f64; 3], xl: [f64; 3]) -> f64 {
    let e = sub(xj, xi);
    let n1 = cross(e, sub(xk, xi));
    let n2 = cross(sub(xi, xj), sub(xl, xj));
    let cos = dot(n1, n2);
    let sin = dot(cross(n1, n2), e) / norm(e);
    sin.atan2(cos)
}

/// Area of triangle `(a, b, c)` and its unit normal `n̂`.
#[inline]
fn tri_area(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> (f64, [f64; 3]) {
    let n = cross(sub(b, a), sub(c, a));
    let len = norm(n);
    (0.5 * len, scale(n, 1.0 / len))
}

/// Add `−s ∇A_t` to the forces of triangle `(a, b, c)`: `∇_a A = ½ (x_b − x_c) × n̂` (cyclic).
#[inline]
fn add_area_gradient(x: &[[f64; 3]], tri: [usize; 3], nhat: [f64; 3], s: f64, f: &mut [[f64; 3]]) {
    let [a, b, c] = tri;
    let h = -0.5 * s;
    add_to(&mut f[a], cross(sub(x[b], x[c]), nhat), h);
    add_to(&mut f[b], cross(sub(x[c], x[a]), nhat), h);
    add_to(&mut f[c], cross(sub(x[a], x[b]), nhat), h);
}

// ---------------------------------------------------------------------------------------------
// Random numbers for the membrane viscosity.

#[inline]
fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Uniform number of zero mean and unit variance (on `[−√3, √3)`), a pure function of
/// `(seed, step, edge, component)`.
#[inline]
fn noise(seed: u64, step: u64, edge: usize, component: u64) -> f64 {
    let h = splitmix64(
        splitmix64(splitmix64(seed ^ 0x6D65_6D62_7261_6E65).wrapping_add(step))
            .wrapping_add(((edge as u64) << 4) | component),
    );
    let u = (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
    (2.0 * u - 1.0) * 3f64.sqrt()
}

// ---------------------------------------------------------------------------------------------
// The membrane.

/// The energy split into its terms ([`Membrane::energy`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EnergyParts {
    /// WLC + POW springs.
    pub spring: f64,
    /// Bending (Kantor–Nelson or Jülicher).
    pub bending: f64,
    /// Local area `Σ_t k_d (A_t − A0_t)²/(2A0_t)`.
    pub local_area: f64,
    /// Global area `k_a (A − A0)²/(2A0)`.
    pub global_area: f64,
    /// Volume `k_v (V − V0)²/(2V0)`.
    pub volume: f64,
    /// The sum of the terms.
    pub total: f64,
}

/// One conservative term of the membrane energy.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Term {
    /// WLC + POW springs.
    Spring,
    /// Bending (the model of [`MembraneParams::bending`]).
    Bending,
    /// Local area.
    LocalArea,
    /// Global area.
    GlobalArea,
    /// Volume.
    Volume,
}

impl Term {
    /// Every term.
    pub const ALL: [Term; 5] = [
        Term::Spring,
        Term::Bending,
        Term::LocalArea,
        Term::GlobalArea,
        Term::Volume,
    ];
}

impl EnergyParts {
    /// The value of one term.
    pub fn term(&self, term: Term) -> f64 {
        match term {
            Term::Spring => self.spring,
            Term::Bending => self.bending,
            Term::LocalArea => self.local_area,
            Term::GlobalArea => self.global_area,
            Term::Volume => self.volume,
        }
    }
}

/// A membrane: topology, parameters and the reference (stress-free) geometry.
#[derive(Debug, Clone, PartialEq)]
pub struct Membrane {
    topology: MembraneTopology,
    params: MembraneParams,
    /// Rest length `l0` of every edge.
    l0: Vec<f64>,
    /// POW coefficient `k_p` of every edge (stress-free at `l0`).
    kp: Vec<f64>,
    /// Reference area of every triangle.
    a0: Vec<f64>,
    /// Reference total area.
    area0: f64,
    /// Reference volume.
    volume0: f64,
}

impl Membrane {
    /// A membrane whose reference geometry is `reference` (one position per vertex).
    ///
    /// Errors: invalid parameters, a wrong number of positions, non-finite positions, a
    /// degenerate edge or triangle, or a non-positive volume (the triangles must be
    /// counter-clockwise seen from outside).
    pub fn new(
        topology: MembraneTopology,
        params: MembraneParams,
        reference: &[[f64; 3]],
    ) -> Result<Self, DpdError> {
        params.validate()?;
        check_len("reference positions", reference.len(), topology.n_vertices)?;
        if let Some(v) = reference
            .iter()
            .position(|p| p.iter().any(|c| !c.is_finite()))
        {
            return Err(DpdError::Mesh(format!(
                "vertex {v} has a non-finite position"
            )));
        }
        let mut l0 = Vec::with_capacity(topology.edges.len());
        for (e, &[i, j]) in topology.edges.iter().enumerate() {
            let l = norm(sub(reference[i], reference[j]));
            if l.is_nan() || l <= 0.0 {
                return Err(DpdError::Mesh(format!(
                    "edge {e} ({i}–{j}) has zero length"
                )));
            }
            l0.push(l);
        }
        let mut a0 = Vec::with_capacity(topology.triangles.len());
        for (t, &[a, b, c]) in topology.triangles.iter().enumerate() {
            let (area, _) = tri_area(reference[a], reference[b], reference[c]);
            if area.is_nan() || area <= 0.0 {
                return Err(DpdError::Mesh(format!("triangle {t} has zero area")));
            }
            a0.push(area);
        }
        let kp = l0.iter().map(|&l| params.kp(l)).collect();
        let area0 = a0.iter().sum();
        let volume0 = volume_of(&topology.triangles, reference);
        if volume0.is_nan() || volume0 <= 0.0 {
            return Err(DpdError::Mesh(format!(
                "the enclosed volume is {volume0}: the triangles must be counter-clockwise seen \
                 from outside"
            )));
        }
        Ok(Self {
            topology,
            params,
            l0,
            kp,
            a0,
            area0,
            volume0,
        })
    }

    /// The mesh topology.
    pub fn topology(&self) -> &MembraneTopology {
        &self.topology
    }

    /// The parameters.
    pub fn params(&self) -> &MembraneParams {
        &self.params
    }

    /// Replace the parameters (the reference geometry stays; `k_p` is recomputed).
    pub fn set_params(&mut self, params: MembraneParams) -> Result<(), DpdError> {
        params.validate()?;
        for (kp, &l0) in self.kp.iter_mut().zip(&self.l0) {
            *kp = params.kp(l0);
        }
        self.params = params;
        Ok(())
    }

    /// Rest length `l0` of every edge.
    pub fn rest_lengths(&self) -> &[f64] {
        &self.l0
    }

    /// Mean rest length of the edges.
    pub fn mean_rest_length(&self) -> f64 {
        self.l0.iter().sum::<f64>() / self.l0.len() as f64
    }

    /// Reference area of every triangle.
    pub fn rest_areas(&self) -> &[f64] {
        &self.a0
    }

    /// Reference total area `A0`.
    pub fn area0(&self) -> f64 {
        self.area0
    }

    /// Reference volume `V0`.
    pub fn volume0(&self) -> f64 {
        self.volume0
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.topology.n_vertices
    }

    /// Total area `A = Σ_t A_t` of the positions `x`.
    pub fn area(&self, x: &[[f64; 3]]) -> Result<f64, DpdError> {
        check_len("positions", x.len(), self.n_vertices())?;
        Ok(self
            .topology
            .triangles
            .iter()
            .map(|&[a, b, c]| tri_area(x[a], x[b], x[c]).0)
            .sum())
    }

    /// Enclosed volume `V = Σ_t (1/6) x_a·(x_b × x_c)` of the positions `x`.
    pub fn volume(&self, x: &[[f64; 3]]) -> Result<f64, DpdError> {
        check_len("positions", x.len(), self.n_vertices())?;
        Ok(volume_of(&self.topology.triangles, x))
    }

    /// Integrated mean curvature `M_v = ¼ Σ_{e∋v} l_e θ_e` and area `A_v = ⅓ Σ_{t∋v} A_t` of
    /// vertex `v`.
    fn vertex_curvature(&self, x: &[[f64; 3]], v: usize) -> (f64, f64) {
        let topo = &self.topology;
        let mut m = 0.0;
        for &e in topo.vertex_edges(v) {
            let [i, j] = topo.edges[e];
            let [k, l] = topo.edge_opposite[e];
            let theta = dihedral_angle(x[i], x[j], x[k], x[l]);
            m += 0.25 * norm(sub(x[i], x[j])) * theta;
        }
        let mut a = 0.0;
        for &t in topo.vertex_triangles(v) {
            let [p, q, r] = topo.triangles[t];
            a += tri_area(x[p], x[q], x[r]).0 / 3.0;
        }
        (m, a)
    }

    /// The energy of the positions `x`, term by term.
    pub fn energy(&self, x: &[[f64; 3]]) -> Result<EnergyParts, DpdError> {
        check_len("positions", x.len(), self.n_vertices())?;
        let p = &self.params;
        let topo = &self.topology;
        let mut out = EnergyParts::default();
        for (e, &[i, j]) in topo.edges.iter().enumerate() {
            let l = norm(sub(x[i], x[j]));
            let Some((en, _)) = p.spring(l, self.l0[e], self.kp[e], true) else {
                return Err(overstretched(l / (self.l0[e] / p.x0)));
            };
            out.spring += en;
        }
        match p.bending {
            Bending::None => {}
            Bending::KantorNelson { kb, theta0 } => {
                for (e, &[i, j]) in topo.edges.iter().enumerate() {
                    let [k, l] = topo.edge_opposite[e];
                    let theta = dihedral_angle(x[i], x[j], x[k], x[l]);
                    out.bending += kb * (1.0 - (theta - theta0).cos());
                }
            }
            Bending::Juelicher { kappa, c0 } => {
                for v in 0..topo.n_vertices {
                    let (m, a) = self.vertex_curvature(x, v);
                    let d = m - 0.5 * c0 * a;
                    out.bending += 2.0 * kappa * d * d / a;
                }
            }
        }
        let mut area = 0.0;
        for (t, &[a, b, c]) in topo.triangles.iter().enumerate() {
            let (at, _) = tri_area(x[a], x[b], x[c]);
            area += at;
            let d = at - self.a0[t];
            out.local_area += p.kd * d * d / (2.0 * self.a0[t]);
        }
        let d = area - self.area0;
        out.global_area = p.ka * d * d / (2.0 * self.area0);
        let d = volume_of(&topo.triangles, x) - self.volume0;
        out.volume = p.kv * d * d / (2.0 * self.volume0);
        out.total = out.spring + out.bending + out.local_area + out.global_area + out.volume;
        Ok(out)
    }

    /// Add the conservative forces `−∇E` of all terms to `f`.
    pub fn add_forces(&self, x: &[[f64; 3]], f: &mut [[f64; 3]]) -> Result<(), DpdError> {
        for term in Term::ALL {
            self.add_term_forces(term, x, f)?;
        }
        Ok(())
    }

    /// Add the forces `−∇E_term` of one term to `f`.
    pub fn add_term_forces(
        &self,
        term: Term,
        x: &[[f64; 3]],
        f: &mut [[f64; 3]],
    ) -> Result<(), DpdError> {
        check_len("positions", x.len(), self.n_vertices())?;
        check_len("forces", f.len(), self.n_vertices())?;
        match term {
            Term::Spring => self.spring_forces(x, f),
            Term::Bending => {
                match self.params.bending {
                    Bending::None => {}
                    Bending::KantorNelson { kb, theta0 } => {
                        self.kantor_nelson_forces(x, kb, theta0, f)
                    }
                    Bending::Juelicher { kappa, c0 } => self.juelicher_forces(x, kappa, c0, f),
                }
                Ok(())
            }
            Term::LocalArea => {
                let kd = self.params.kd;
                if kd != 0.0 {
                    for (t, &tri) in self.topology.triangles.iter().enumerate() {
                        let [a, b, c] = tri;
                        let (at, nhat) = tri_area(x[a], x[b], x[c]);
                        let s = kd * (at - self.a0[t]) / self.a0[t];
                        add_area_gradient(x, tri, nhat, s, f);
                    }
                }
                Ok(())
            }
            Term::GlobalArea => {
                let ka = self.params.ka;
                if ka != 0.0 {
                    let area = volume_or_area(self, x, false);
                    let s = ka * (area - self.area0) / self.area0;
                    for &tri in &self.topology.triangles {
                        let [a, b, c] = tri;
                        let (_, nhat) = tri_area(x[a], x[b], x[c]);
                        add_area_gradient(x, tri, nhat, s, f);
                    }
                }
                Ok(())
            }
            Term::Volume => {
                let kv = self.params.kv;
                if kv != 0.0 {
                    let vol = volume_or_area(self, x, true);
                    let s = -kv * (vol - self.volume0) / self.volume0 / 6.0;
                    for &[a, b, c] in &self.topology.triangles {
                        add_to(&mut f[a], cross(x[b], x[c]), s);
                        add_to(&mut f[b], cross(x[c], x[a]), s);
                        add_to(&mut f[c], cross(x[a], x[b]), s);
                    }
                }
                Ok(())
            }
        }
    }

    fn spring_forces(&self, x: &[[f64; 3]], f: &mut [[f64; 3]]) -> Result<(), DpdError> {
        let p = &self.params;
        for (e, &[i, j]) in self.topology.edges.iter().enumerate() {
            let d = sub(x[i], x[j]);
            let l = norm(d);
            let Some((_, de)) = p.spring(l, self.l0[e], self.kp[e], false) else {
                return Err(overstretched(l / (self.l0[e] / p.x0)));
            };
            // F_i = −dE/dl (x_i − x_j)/l, F_j = −F_i.
            let s = -de / l;
            add_to(&mut f[i], d, s);
            add_to(&mut f[j], d, -s);
        }
        Ok(())
    }

    fn kantor_nelson_forces(&self, x: &[[f64; 3]], kb: f64, theta0: f64, f: &mut [[f64; 3]]) {
        if kb == 0.0 {
            return;
        }
        let topo = &self.topology;
        for (e, &[i, j]) in topo.edges.iter().enumerate() {
            let [k, l] = topo.edge_opposite[e];
            let (theta, g) = dihedral(x[i], x[j], x[k], x[l]);
            // dE/dθ = kb sin(θ − θ0).
            let s = -kb * (theta - theta0).sin();
            for (v, gv) in [i, j, k, l].into_iter().zip(g) {
                add_to(&mut f[v], gv, s);
            }
        }
    }

    fn juelicher_forces(&self, x: &[[f64; 3]], kappa: f64, c0: f64, f: &mut [[f64; 3]]) {
        if kappa == 0.0 {
            return;
        }
        let topo = &self.topology;
        let h0 = 0.5 * c0;
        for v in 0..topo.n_vertices {
            let (m, a) = self.vertex_curvature(x, v);
            let d = m - h0 * a;
            let de_dm = 4.0 * kappa * d / a;
            let de_da = -2.0 * kappa * (2.0 * h0 * d / a + d * d / (a * a));
            // M_v = ¼ Σ l_e θ_e: ∂M_v = ¼ Σ (θ_e ∇l_e + l_e ∇θ_e).
            let wm = 0.25 * de_dm;
            for &e in topo.vertex_edges(v) {
                let [i, j] = topo.edges[e];
                let [k, l] = topo.edge_opposite[e];
                let (theta, g) = dihedral(x[i], x[j], x[k], x[l]);
                let dij = sub(x[i], x[j]);
                let len = norm(dij);
                let sl = -wm * theta / len;
                add_to(&mut f[i], dij, sl);
                add_to(&mut f[j], dij, -sl);
                for (u, gu) in [i, j, k, l].into_iter().zip(g) {
                    add_to(&mut f[u], gu, -wm * len);
                }
            }
            // A_v = ⅓ Σ A_t.
            let wa = de_da / 3.0;
            for &t in topo.vertex_triangles(v) {
                let tri = topo.triangles[t];
                let [p, q, r] = tri;
                let (_, nhat) = tri_area(x[p], x[q], x[r]);
                add_area_gradient(x, tri, nhat, wa, f);
            }
        }
    }

    /// Viscous force on vertex `i` of edge `[i, j]` (`amp = √(2k_BT/dt)`, 0 for no noise).
    #[inline]
    fn edge_viscous_force(
        &self,
        edge: usize,
        x: &[[f64; 3]],
        v: &[[f64; 3]],
        step: u64,
        seed: u64,
        amp: f64,
    ) -> [f64; 3] {
        let p = &self.params;
        let [i, j] = self.topology.edges[edge];
        let d = sub(x[i], x[j]);
        let e = scale(d, 1.0 / norm(d));
        let vij = sub(v[i], v[j]);
        let mut fi = scale(vij, -p.gamma_t);
        add_to(&mut fi, e, -p.gamma_c * dot(vij, e));
        if amp > 0.0 {
            let at = amp * (2.0 * p.gamma_t).sqrt();
            let ac = amp * (3.0 * p.gamma_c - p.gamma_t).max(0.0).sqrt();
            let mut w = [[0.0; 3]; 3];
            for (a, row) in w.iter_mut().enumerate() {
                for (b, wab) in row.iter_mut().enumerate() {
                    *wab = noise(seed, step, edge, (3 * a + b) as u64);
                }
            }
            let tr3 = (w[0][0] + w[1][1] + w[2][2]) / 3.0;
            for (a, fa) in fi.iter_mut().enumerate() {
                // (dW^S e)_a = Σ_b (½(W_ab + W_ba) − tr/3 δ_ab) e_b.
                let mut s = -tr3 * e[a];
                for b in 0..3 {
                    s += 0.5 * (w[a][b] + w[b][a]) * e[b];
                }
                *fa += at * s + ac * tr3 * e[a];
            }
        }
        fi
    }

    /// Add the membrane-viscosity forces (dissipative and random, see the module documentation)
    /// of velocities `v` at positions `x` to `f`, for time step `dt` and step number `step`.
    ///
    /// The random part (present when `k_BT > 0`) is a pure function of `(seed, step, edge)`;
    /// every pair force enters `f_i` and `−f_j`.
    pub fn add_viscous_forces(
        &self,
        x: &[[f64; 3]],
        v: &[[f64; 3]],
        step: u64,
        seed: u64,
        dt: f64,
        f: &mut [[f64; 3]],
    ) -> Result<(), DpdError> {
        let n = self.n_vertices();
        check_len("positions", x.len(), n)?;
        check_len("velocities", v.len(), n)?;
        check_len("forces", f.len(), n)?;
        let p = &self.params;
        let random = p.kbt > 0.0 && (p.gamma_t > 0.0 || p.gamma_c > 0.0);
        if random {
            require(
                dt > 0.0 && dt.is_finite(),
                "dt",
                dt,
                "must be positive and finite",
            )?;
        }
        let amp = if random {
            (2.0 * p.kbt / dt).sqrt()
        } else {
            0.0
        };
        for (edge, &[i, j]) in self.topology.edges.iter().enumerate() {
            let fi = self.edge_viscous_force(edge, x, v, step, seed, amp);
            add_to(&mut f[i], fi, 1.0);
            add_to(&mut f[j], fi, -1.0);
        }
        Ok(())
    }
}

fn check_len(what: &'static str, len: usize, expected: usize) -> Result<(), DpdError> {
    if len == expected {
        Ok(())
    } else {
        Err(DpdError::Length {
            what,
            len,
            expected,
        })
    }
}

fn overstretched(x: f64) -> DpdError {
    DpdError::Parameter {
        name: "spring extension l/l_max",
        value: x,
        reason: "a membrane spring reached its maximum length (or zero length)",
    }
}

fn volume_of(triangles: &[[usize; 3]], x: &[[f64; 3]]) -> f64 {
    triangles
        .iter()
        .map(|&[a, b, c]| dot(x[a], cross(x[b], x[c])))
        .sum::<f64>()
        / 6.0
}

fn volume_or_area(m: &Membrane, x: &[[f64; 3]], volume: bool) -> f64 {
    if volume {
        volume_of(&m.topology.triangles, x)
    } else {
        m.topology
            .triangles
            .iter()
            .map(|&[a, b, c]| tri_area(x[a], x[b], x[c]).0)
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Octahedron (6 vertices, counter-clockwise from outside).
    fn octahedron() -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
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
    fn icosphere(k: usize) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
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

    fn jitter(x: &[[f64; 3]], amp: f64, seed: u64) -> Vec<[f64; 3]> {
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

    fn full_params(bending: Bending) -> MembraneParams {
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

    #[test]
    fn sphere_geometry_and_stress_free_reference() {
        let (x, t) = icosphere(3);
        let topo = MembraneTopology::new(x.len(), &t).unwrap();
        assert_eq!(topo.euler_characteristic(), 2);
        let m = Membrane::new(topo, full_params(Bending::None), &x).unwrap();
        assert!((m.area(&x).unwrap() - 4.0 * PI).abs() < 0.05 * 4.0 * PI);
        assert!((m.volume(&x).unwrap() - 4.0 * PI / 3.0).abs() < 0.05 * 4.0);
        let e = m.energy(&x).unwrap();
        assert!(
            e.local_area.abs() < 1e-20 && e.global_area.abs() < 1e-20 && e.volume.abs() < 1e-20
        );
        let mut f = vec![[0.0; 3]; x.len()];
        m.add_term_forces(Term::Spring, &x, &mut f).unwrap();
        let fmax = f.iter().map(|v| norm(*v)).fold(0.0, f64::max);
        assert!(fmax < 1e-9, "stress-free springs: {fmax}");
    }

    #[test]
    fn dihedral_sign_and_value() {
        // Convex hinge: θ > 0, equal to the angle between the normals.
        let h: f64 = 0.3;
        let xi = [0.0, 0.0, 0.0];
        let xj = [1.0, 0.0, 0.0];
        let xk = [0.5, 1.0, 0.0];
        let xl = [0.5, -1.0, -h];
        let (theta, _) = dihedral(xi, xj, xk, xl);
        assert!((theta - h.atan()).abs() < 1e-14, "{theta}");
        assert!((dihedral_angle(xi, xj, xk, xl) - theta).abs() < 1e-14);
    }

    /// Central differences of every term on a jittered icosphere.
    #[test]
    fn forces_match_finite_differences() {
        let (x, t) = icosphere(2);
        let topo = MembraneTopology::new(x.len(), &t).unwrap();
        for bending in [
            Bending::KantorNelson {
                kb: 2.0,
                theta0: 0.1,
            },
            Bending::Juelicher {
                kappa: 1.5,
                c0: 1.3,
            },
        ] {
            let m = Membrane::new(topo.clone(), full_params(bending), &x).unwrap();
            let y = jitter(&x, 0.03, 7);
            for term in Term::ALL {
                let mut f = vec![[0.0; 3]; y.len()];
                m.add_term_forces(term, &y, &mut f).unwrap();
                let fmax = f.iter().map(|v| norm(*v)).fold(0.0, f64::max);
                let h = 1e-6;
                let mut worst: f64 = 0.0;
                for v in (0..y.len()).step_by(7) {
                    for c in 0..3 {
                        let mut yp = y.clone();
                        yp[v][c] += h;
                        let mut ym = y.clone();
                        ym[v][c] -= h;
                        let fd = -(m.energy(&yp).unwrap().term(term)
                            - m.energy(&ym).unwrap().term(term))
                            / (2.0 * h);
                        worst = worst.max((fd - f[v][c]).abs() / fmax);
                    }
                }
                assert!(fmax > 0.0, "{term:?}");
                assert!(worst < 1e-6, "{bending:?} {term:?}: {worst:e}");
            }
        }
    }

    #[test]
    fn from_moduli_inverts_shear_modulus() {
        for x0 in [1.0 / 2.2, 0.3, 0.6] {
            let mo = Moduli {
                shear_modulus: 6.3,
                bending_rigidity: 0.24,
                bending: BendingModel::KantorNelson { theta0: 0.0 },
                ka: 300.0,
                kd: 6.3,
                kv: 300.0,
                kbt: 0.0041,
                x0,
                m: 2.0,
                mean_edge_length: 0.35,
                gamma_t: 0.0,
                gamma_c: None,
            };
            let p = MembraneParams::from_moduli(&mo).unwrap();
            assert!((p.shear_modulus(0.35) - 6.3).abs() < 1e-12 * 6.3);
            assert!((p.bending_rigidity() - 0.24).abs() < 1e-15);
            // Numerical shear modulus of the infinite triangular lattice of these springs:
            // W(ε) per unit area under the area-preserving shear diag(1 + ε, 1/(1 + ε)),
            // W ≈ 2μ ε².
            let l0: f64 = 0.35;
            let kp = p.kp(l0);
            let w = |eps: f64| {
                let mut s = 0.0;
                for d in 0..3 {
                    let phi = d as f64 * PI / 3.0;
                    let l = l0
                        * (((1.0 + eps) * phi.cos()).powi(2) + (phi.sin() / (1.0 + eps)).powi(2))
                            .sqrt();
                    s += p.spring(l, l0, kp, true).unwrap().0;
                }
                s / (3f64.sqrt() / 2.0 * l0 * l0)
            };
            let eps = 1e-4;
            let mu = (w(eps) - 2.0 * w(0.0) + w(-eps)) / (eps * eps) / 4.0;
            assert!((mu - 6.3).abs() < 1e-3 * 6.3, "x0 {x0}: lattice μ = {mu}");
        }
        let bad = Moduli {
            shear_modulus: -1.0,
            bending_rigidity: 0.0,
            bending: BendingModel::Juelicher { c0: 0.0 },
            ka: 0.0,
            kd: 0.0,
            kv: 0.0,
            kbt: 1.0,
            x0: 0.5,
            m: 2.0,
            mean_edge_length: 1.0,
            gamma_t: 0.0,
            gamma_c: None,
        };
        assert!(matches!(
            MembraneParams::from_moduli(&bad),
            Err(DpdError::Parameter { .. })
        ));
    }

    #[test]
    fn viscous_noise_has_the_fdt_covariance() {
        let (x, t) = icosphere(0);
        let topo = MembraneTopology::new(x.len(), &t).unwrap();
        let mut params = full_params(Bending::None);
        params.kbt = 0.7;
        params.gamma_t = 2.0;
        params.gamma_c = 5.0;
        let m = Membrane::new(topo, params, &x).unwrap();
        let v = vec![[0.0; 3]; x.len()];
        let dt = 0.01;
        let [i, j] = m.topology().edges()[0];
        let d = sub(x[i], x[j]);
        let e = scale(d, 1.0 / norm(d));
        let n = 40_000;
        let mut cov = [[0.0; 3]; 3];
        let mut f = vec![[0.0; 3]; x.len()];
        let amp = (2.0 * params.kbt / dt).sqrt();
        for step in 0..n {
            f.iter_mut().for_each(|q| *q = [0.0; 3]);
            m.add_viscous_forces(&x, &v, step, 11, dt, &mut f).unwrap();
            let sum = f
                .iter()
                .fold([0.0; 3], |s, q| [s[0] + q[0], s[1] + q[1], s[2] + q[2]]);
            assert!(norm(sum) < 1e-10 * amp);
            let fi = m.edge_viscous_force(0, &x, &v, step, 11, amp);
            for a in 0..3 {
                for b in 0..3 {
                    cov[a][b] += fi[a] * fi[b] / n as f64;
                }
            }
        }
        let scale_ = 2.0 * params.kbt / dt;
        for a in 0..3 {
            for b in 0..3 {
                let delta = if a == b { 1.0 } else { 0.0 };
                let want = scale_ * (params.gamma_t * delta + params.gamma_c * e[a] * e[b]);
                assert!(
                    (cov[a][b] - want).abs() < 0.04 * scale_ * (params.gamma_t + params.gamma_c),
                    "cov[{a}][{b}] = {} want {want}",
                    cov[a][b]
                );
            }
        }
    }

    #[test]
    fn noise_is_uniform_with_unit_variance() {
        let n = 100_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for k in 0..n {
            let r = noise(3, k as u64, 17, 2);
            assert!(r.abs() <= 3f64.sqrt());
            s += r;
            s2 += r * r;
        }
        assert!((s / n as f64).abs() < 0.01);
        assert!((s2 / n as f64 - 1.0).abs() < 0.01);
        assert_ne!(noise(3, 0, 17, 2), noise(3, 0, 17, 3));
        assert_ne!(noise(3, 0, 17, 2), noise(4, 0, 17, 2));
    }
}

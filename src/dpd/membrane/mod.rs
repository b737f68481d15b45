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

mod energy;
mod geometry;
mod params;
mod relax;
mod topology;
mod viscous;

#[cfg(test)]
pub(crate) mod test_support;

pub use energy::{EnergyParts, Membrane, Term};
pub use params::{sphere_spontaneous_angle, Bending, BendingModel, MembraneParams, Moduli};
pub use relax::{mesh_quality, relax_on_surface, MeshQuality, RelaxReport};
pub use topology::MembraneTopology;

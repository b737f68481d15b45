//! The membrane ([`Membrane`]): reference geometry, the conservative energy term by term
//! ([`EnergyParts`], [`Term`]) and its analytic forces `−∇E`.

use super::super::DpdError;
use super::geometry::{
    add_area_gradient, add_to, cross, dihedral, dihedral_angle, norm, sub, tri_area, volume_of,
};
use super::params::{Bending, MembraneParams};
use super::topology::MembraneTopology;

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
        // Each edge's dihedral angle, its gradient and its length, and each triangle's area
        // and normal, once (a vertex's curvature and its forces read each edge twice, and
        // every edge has two vertices).
        let edges: Vec<(f64, [[f64; 3]; 4], f64)> = topo
            .edges
            .iter()
            .zip(&topo.edge_opposite)
            .map(|(&[i, j], &[k, l])| {
                let (theta, g) = dihedral(x[i], x[j], x[k], x[l]);
                (theta, g, norm(sub(x[i], x[j])))
            })
            .collect();
        let tris: Vec<(f64, [f64; 3])> = topo
            .triangles
            .iter()
            .map(|&[p, q, r]| tri_area(x[p], x[q], x[r]))
            .collect();
        for v in 0..topo.n_vertices {
            // M_v = ¼ Σ l_e θ_e, A_v = ⅓ Σ A_t.
            let m: f64 = topo
                .vertex_edges(v)
                .iter()
                .map(|&e| 0.25 * edges[e].2 * edges[e].0)
                .sum();
            let a: f64 = topo
                .vertex_triangles(v)
                .iter()
                .map(|&t| tris[t].0 / 3.0)
                .sum();
            let d = m - h0 * a;
            let de_dm = 4.0 * kappa * d / a;
            let de_da = -2.0 * kappa * (2.0 * h0 * d / a + d * d / (a * a));
            // ∂M_v = ¼ Σ (θ_e ∇l_e + l_e ∇θ_e).
            let wm = 0.25 * de_dm;
            for &e in topo.vertex_edges(v) {
                let [i, j] = topo.edges[e];
                let [k, l] = topo.edge_opposite[e];
                let (theta, g, len) = edges[e];
                let dij = sub(x[i], x[j]);
                let sl = -wm * theta / len;
                add_to(&mut f[i], dij, sl);
                add_to(&mut f[j], dij, -sl);
                for (u, gu) in [i, j, k, l].into_iter().zip(g) {
                    add_to(&mut f[u], gu, -wm * len);
                }
            }
            let wa = de_da / 3.0;
            for &t in topo.vertex_triangles(v) {
                add_area_gradient(x, topo.triangles[t], tris[t].1, wa, f);
            }
        }
    }
}

pub(super) fn check_len(what: &'static str, len: usize, expected: usize) -> Result<(), DpdError> {
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
    use crate::dpd::membrane::test_support::{full_params, icosphere, jitter};
    use std::f64::consts::PI;

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
}

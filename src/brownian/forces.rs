//! Forces on the beads: harmonic bonds, soft overlap repulsion, the sub-cellular-element
//! potential and a constant external force. Energies in units of `k_BT`, lengths in units of the
//! scene (the bead radius `a` is the natural one).
//!
//! * bond `(i, j)`: `U = a_h (r − L)²`;
//! * overlap repulsion, every pair with `r < 2a`: `U = a_r (r − 2a)²`;
//! * sub-cellular element (Sandersius & Newman 2008), every pair with `r < r_cut`:
//!   `U = U0 e^{2ρ(1 − r²/r_eq²)} − 2U0 e^{ρ(1 − r²/r_eq²)}` (minimum `−U0` at `r_eq`);
//! * external: `F_i = F_ext` for every bead.
//!
//! Pair terms are summed directly (`O(N²)`, like the mobility pass they go with).

use serde::{Deserialize, Serialize};

use super::rpy::sub;

/// Parameters of the sub-cellular-element potential.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SubcellularElement {
    /// Well depth `U0` (k_BT).
    pub u0: f64,
    /// Stiffness `ρ`.
    pub rho: f64,
    /// Equilibrium distance `r_eq`.
    pub r_eq: f64,
    /// Cut-off distance.
    pub cutoff: f64,
}

/// The force field of a bead system.
#[derive(Clone, Debug, Default)]
pub struct ForceField {
    /// Bonded pairs.
    pub bonds: Vec<(usize, usize)>,
    /// Bond stiffness `a_h` (k_BT per length²).
    pub bond_stiffness: f64,
    /// Bond rest length `L`.
    pub bond_length: f64,
    /// Overlap repulsion stiffness `a_r` (0: none).
    pub repulsion: f64,
    /// Bead radius `a` (for the overlap distance `2a`).
    pub radius: f64,
    /// Optional sub-cellular-element potential.
    pub sce: Option<SubcellularElement>,
    /// External force on every bead.
    pub external: [f64; 3],
}

impl ForceField {
    /// Total energy.
    pub fn energy(&self, pos: &[[f64; 3]]) -> f64 {
        let mut e = 0.0;
        for &(i, j) in &self.bonds {
            let r = norm(sub(pos[i], pos[j]));
            e += self.bond_stiffness * (r - self.bond_length).powi(2);
        }
        for i in 0..pos.len() {
            for j in i + 1..pos.len() {
                let r = norm(sub(pos[i], pos[j]));
                e += self.pair_energy(r);
            }
            e -= self.external[0] * pos[i][0]
                + self.external[1] * pos[i][1]
                + self.external[2] * pos[i][2];
        }
        e
    }

    fn pair_energy(&self, r: f64) -> f64 {
        let mut e = 0.0;
        let d = 2.0 * self.radius;
        if self.repulsion > 0.0 && r < d {
            e += self.repulsion * (r - d).powi(2);
        }
        if let Some(s) = self.sce {
            if r < s.cutoff {
                let x = s.rho * (1.0 - r * r / (s.r_eq * s.r_eq));
                e += s.u0 * ((2.0 * x).exp() - 2.0 * x.exp());
            }
        }
        e
    }

    /// `−dU/dr` of the pair terms.
    fn pair_force(&self, r: f64) -> f64 {
        let mut f = 0.0;
        let d = 2.0 * self.radius;
        if self.repulsion > 0.0 && r < d {
            f -= 2.0 * self.repulsion * (r - d);
        }
        if let Some(s) = self.sce {
            if r < s.cutoff {
                let x = s.rho * (1.0 - r * r / (s.r_eq * s.r_eq));
                // dU/dr = −(4ρ r U0 / r_eq²)(e^{2x} − e^{x})
                f += 4.0 * s.rho * r * s.u0 / (s.r_eq * s.r_eq) * ((2.0 * x).exp() - x.exp());
            }
        }
        f
    }

    /// Forces `F = −∇U` on every bead (overwrites `out`): [`Self::pair_forces`] over all
    /// beads, then [`Self::add_bonded_and_external`].
    pub fn forces(&self, pos: &[[f64; 3]], out: &mut [[f64; 3]]) {
        self.pair_forces(pos, 0..pos.len(), out);
        self.add_bonded_and_external(pos, out);
    }

    /// Whether any pair potential (overlap repulsion, sub-cellular element) acts.
    pub fn has_pair_forces(&self) -> bool {
        self.repulsion > 0.0 || self.sce.is_some()
    }

    /// The pair forces on the beads `rows` (overwrites `out`, one entry a row): for each, the
    /// sum over every other bead in ascending order, so the result does not depend on how the
    /// rows are split (between MPI ranks). `O(|rows| · N)`.
    pub fn pair_forces(
        &self,
        pos: &[[f64; 3]],
        rows: std::ops::Range<usize>,
        out: &mut [[f64; 3]],
    ) {
        out.fill([0.0; 3]);
        if !self.has_pair_forces() {
            return;
        }
        let row = |i: usize, o: &mut [f64; 3]| {
            for (j, &pj) in pos.iter().enumerate() {
                if j == i {
                    continue;
                }
                let r = sub(pos[i], pj);
                let d = norm(r);
                let f = self.pair_force(d);
                if f != 0.0 {
                    for k in 0..3 {
                        o[k] += f * r[k] / d;
                    }
                }
            }
        };
        // Rows are independent (the same numbers on any thread count).
        if pos.len() < super::tea_hi::PARALLEL_THRESHOLD {
            for (i, o) in rows.zip(out.iter_mut()) {
                row(i, o);
            }
        } else {
            use rayon::prelude::*;
            out.par_iter_mut()
                .enumerate()
                .for_each(|(k, o)| row(rows.start + k, o));
        }
    }

    /// Add the bond and external forces to `out` (all beads), in bond order.
    pub fn add_bonded_and_external(&self, pos: &[[f64; 3]], out: &mut [[f64; 3]]) {
        for o in out.iter_mut() {
            for (v, e) in o.iter_mut().zip(self.external) {
                *v += e;
            }
        }
        for &(i, j) in &self.bonds {
            let r = sub(pos[i], pos[j]);
            let d = norm(r);
            let f = -2.0 * self.bond_stiffness * (d - self.bond_length) / d;
            for k in 0..3 {
                out[i][k] += f * r[k];
                out[j][k] -= f * r[k];
            }
        }
    }
}

fn norm(r: [f64; 3]) -> f64 {
    (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt()
}

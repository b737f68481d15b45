//! Membrane parameters ([`MembraneParams`], [`Bending`]) and their mapping from physical moduli
//! ([`Moduli`], [`MembraneParams::from_moduli`]): the Fedosov (2010) relations, the WLC + POW
//! spring law, and the spontaneous Kantor–Nelson angle of a sphere.

use std::f64::consts::PI;

use super::super::{require, DpdError};

/// Bending model with its coefficients.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Bending {
    /// No bending energy.
    None,
    /// Kantor–Nelson: `E = Σ_edges kb (1 − cos(θ − θ0))`, `θ0` in radians.
    KantorNelson {
        /// Bending constant `kb` (energy).
        kb: f64,
        /// Spontaneous signed dihedral angle `θ0` of an edge (radians, positive where convex).
        theta0: f64,
    },
    /// Jülicher: `E = 2κ Σ_v (M_v − C0 A_v/2)² / A_v`.
    Juelicher {
        /// Bending modulus `κ` (energy).
        kappa: f64,
        /// Spontaneous curvature `C0` (inverse length).
        c0: f64,
    },
}

/// Which bending model [`MembraneParams::from_moduli`] builds, with its spontaneous shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BendingModel {
    /// Kantor–Nelson with spontaneous angle `theta0` (radians), `kb = 2κ/√3`.
    KantorNelson {
        /// Spontaneous angle `θ0` (radians).
        theta0: f64,
    },
    /// Jülicher with spontaneous curvature `c0` (`C0 = 2/R` for a sphere of radius `R`).
    Juelicher {
        /// Spontaneous curvature `C0` (inverse length).
        c0: f64,
    },
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

impl Moduli {
    /// Shear modulus `μ0`, bending rigidity `κ` and model, and the mesh's mean edge length, in
    /// units of `k_BT = 1`, with Fedosov's (2010) remaining values: `k_a = 4900`,
    /// `k_d = 100`, `k_v = 5000`, `x0 = 1/2.2`, `m = 2`, membrane viscosity `γ_T = 20` and
    /// `γ_C = γ_T/3`. Change any of them with struct update syntax.
    pub fn new(
        shear_modulus: f64,
        bending_rigidity: f64,
        bending: BendingModel,
        mean_edge_length: f64,
    ) -> Self {
        Self {
            shear_modulus,
            bending_rigidity,
            bending,
            ka: 4900.0,
            kd: 100.0,
            kv: 5000.0,
            kbt: 1.0,
            x0: 1.0 / 2.2,
            m: 2.0,
            mean_edge_length,
            gamma_t: 20.0,
            gamma_c: None,
        }
    }
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

    /// Parameters from physical moduli (Fedosov 2010; see the [module documentation](super)):
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
    pub(super) fn spring(&self, l: f64, l0: f64, kp: f64, want_energy: bool) -> Option<(f64, f64)> {
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

#[cfg(test)]
mod tests {
    use super::*;

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
}

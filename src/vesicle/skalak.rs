//! Hyperelastic membranes (Skalak and neo-Hookean laws) relative to a stress-free reference
//! surface.
//!
//! With the reference metric `A_ij` and the current metric `a_ij` of the same parametrisation:
//! `I₁ = A^{ij} a_ij − 2`, `J² = det a / det A`, `I₂ = J² − 1`, and per unit reference area
//!
//! * **Skalak** (Skalak et al., Biophys. J. 13, 1973): `W_s = (G_s/4)(I₁² + 2I₁ − 2I₂ + C I₂²)`,
//!   area-dilation modulus `K_s = G_s(1 + 2C)`, surface Poisson ratio `ν_s = C/(1 + C)`;
//! * **neo-Hookean** (a thin sheet of incompressible neo-Hookean material; Barthès-Biesel,
//!   Diaz & Dhenin, J. Fluid Mech. 460, 2002): `W_s = (G_s/2)(I₁ + 1/(I₂ + 1) − 1)`, which
//!   softens under area dilation; `ν_s = 1/2` and surface Young modulus `E_s = 3G_s` at small
//!   strain, the same as Skalak with `C = 1` to first order.
//!
//! `E_s = ∫ W_s dA_ref`. Varying `a_ij` gives the contravariant Cauchy tension
//! `T^{ij} = (2/J) ∂W_s/∂a_ij`: for Skalak
//! `T^{ij} = (G_s/J)[(I₁ + 1) A^{ij} + J²(C I₂ − 1) a^{ij}]` (in principal stretches Skalak's
//! `τ₁ = G_s/(λ₁λ₂) [λ₁²(λ₁² − 1) + C(λ₁λ₂)²((λ₁λ₂)² − 1)]`), for neo-Hookean
//! `T^{ij} = (G_s/J)(A^{ij} − a^{ij}/J²)` (`τ₁ = G_s/(λ₁λ₂) [λ₁² − 1/(λ₁λ₂)²]`). The tension
//! tensor `τ = T^{ij} X_i ⊗ X_j` is a smooth Cartesian field; its six components are transformed
//! on the order-`q` grid and the force is the surface divergence `f_k = ∇_s·(τ e_k)`, so that
//! `∫ f·δX dA = −δE_s` (integration by parts on the closed surface; `τ` is tangential).

use super::geometry::div_at;
use super::membrane::Membrane;
use super::skalak_reference::Reference;
use super::{check_len, VesicleError};
use crate::sph_harmonics::{resample_coefs, Deriv};

/// The strain-energy function of a hyperelastic membrane (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ElasticLaw {
    /// Skalak: strain-hardening, area dilation resisted with `K_s = G_s(1 + 2C)`.
    #[default]
    Skalak,
    /// Neo-Hookean: strain-softening under area dilation; `C` is not used.
    NeoHookean,
}

/// Membrane elasticity: the law, the shear modulus `G_s` and (Skalak) the area-dilation ratio
/// `C`. The name is historical: the struct carries either law.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SkalakParams {
    /// `G_s`.
    pub shear_modulus: f64,
    /// `C` (area-dilation modulus over shear modulus; large for RBCs). Skalak only.
    pub dilation_ratio: f64,
    /// Skalak or neo-Hookean.
    pub law: ElasticLaw,
}

impl SkalakParams {
    /// The Skalak law with `G_s` and `C`.
    pub fn skalak(shear_modulus: f64, dilation_ratio: f64) -> Self {
        SkalakParams {
            shear_modulus,
            dilation_ratio,
            law: ElasticLaw::Skalak,
        }
    }

    /// The neo-Hookean law with `G_s` (surface Young modulus `E_s = 3G_s` at small strain).
    pub fn neo_hookean(shear_modulus: f64) -> Self {
        SkalakParams {
            shear_modulus,
            dilation_ratio: 0.0,
            law: ElasticLaw::NeoHookean,
        }
    }
}

impl SkalakParams {
    fn check(&self) -> Result<(), VesicleError> {
        for (name, v) in [
            ("shear modulus", self.shear_modulus),
            ("dilation ratio", self.dilation_ratio),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(VesicleError::Parameter {
                    name,
                    value: v,
                    reason: "must be finite and non-negative",
                });
            }
        }
        Ok(())
    }
}

/// Index of the symmetric component `(a, b)` in the six stored components.
const SYM: [[usize; 3]; 3] = [[0, 1, 2], [1, 3, 4], [2, 4, 5]];

/// Invariants and contravariant tension at one point: `(W_s, [T^θθ, T^θφ, T^φφ])`.
#[inline]
fn skalak_point(par: &SkalakParams, refm: [f64; 3], cur: [f64; 3]) -> (f64, [f64; 3]) {
    let det_a_ref = refm[0] * refm[2] - refm[1] * refm[1];
    let det_a = cur[0] * cur[2] - cur[1] * cur[1];
    let ai = [
        refm[2] / det_a_ref,
        -refm[1] / det_a_ref,
        refm[0] / det_a_ref,
    ];
    let ci = [cur[2] / det_a, -cur[1] / det_a, cur[0] / det_a];
    let i1 = ai[0] * cur[0] + 2.0 * ai[1] * cur[1] + ai[2] * cur[2] - 2.0;
    let j2 = det_a / det_a_ref;
    let i2 = j2 - 1.0;
    let (gs, c) = (par.shear_modulus, par.dilation_ratio);
    let j = j2.sqrt();
    match par.law {
        ElasticLaw::Skalak => {
            let w = 0.25 * gs * (i1 * i1 + 2.0 * i1 - 2.0 * i2 + c * i2 * i2);
            let t: [f64; 3] = std::array::from_fn(|k| {
                gs / j * ((i1 + 1.0) * ai[k] + j2 * (c * i2 - 1.0) * ci[k])
            });
            (w, t)
        }
        ElasticLaw::NeoHookean => {
            let w = 0.5 * gs * (i1 + 1.0 / j2 - 1.0);
            let t: [f64; 3] = std::array::from_fn(|k| gs / j * (ai[k] - ci[k] / j2));
            (w, t)
        }
    }
}

impl Membrane {
    /// Set the stress-free reference surface (order-`p` coefficients, the same parametrisation
    /// as the surfaces whose forces are computed). Allocates the Skalak scratch once.
    pub fn set_reference(&mut self, coefs: &[f64]) -> Result<(), VesicleError> {
        check_len("reference coefficients", coefs.len(), self.cp.len())?;
        if self.reference.as_ref().is_some_and(|r| r.coefs == coefs) {
            return Ok(());
        }
        let q = self.upsampled_order();
        let nq = self.n_points_upsampled();
        let ncq = self.calc.transform().n_coefs();
        let mut cq = vec![0.0; 3 * ncq];
        resample_coefs(
            self.sht_p.layout(),
            self.calc.transform().layout(),
            coefs,
            &mut cq,
        )?;
        let mut g = super::Geometry::zeros(q);
        self.calc.update_geometry(&cq, &mut g)?;
        self.reference = Some(Reference {
            coefs: coefs.to_vec(),
            metric: (0..nq).map(|j| [g.e[j], g.f[j], g.g[j]]).collect(),
            w: g.w,
            tau: vec![0.0; 6 * nq],
            ctau: vec![0.0; 6 * ncq],
            dt: vec![0.0; 6 * nq],
            dp: vec![0.0; 6 * nq],
        });
        Ok(())
    }

    fn reference(&self) -> Result<&Reference, VesicleError> {
        self.reference.as_ref().ok_or(VesicleError::Missing(
            "the reference surface (Membrane::set_reference)",
        ))
    }

    /// Skalak energy `∫ W_s dA_ref` of the frozen geometry (quadrature at order `q`).
    pub fn skalak_energy(&self, par: &SkalakParams) -> Result<f64, VesicleError> {
        par.check()?;
        let g = self.geometry()?;
        let r = self.reference()?;
        let mut e = 0.0;
        for j in 0..g.n_points() {
            let (w, _) = skalak_point(par, r.metric[j], [g.e[j], g.f[j], g.g[j]]);
            e += w * g.da[j] * r.w[j] / g.w[j];
        }
        Ok(e)
    }

    /// Skalak force density on the order-`p` grid (computed at `q`, filtered).
    pub fn skalak_force(
        &mut self,
        par: &SkalakParams,
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        self.skalak_fine(par)?;
        self.emit_vector(out, true)
    }

    /// Skalak force density on the order-`q` grid, unfiltered.
    pub fn skalak_force_upsampled(
        &mut self,
        par: &SkalakParams,
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        self.skalak_fine(par)?;
        self.emit_vector(out, false)
    }

    #[allow(clippy::needless_range_loop)] // symmetric-tensor component indices
    fn skalak_fine(&mut self, par: &SkalakParams) -> Result<(), VesicleError> {
        par.check()?;
        self.require_geometry()?;
        self.reference()?;
        let nq = self.n_points_upsampled();
        let mut r = self.reference.take().expect("checked above");
        let g = &self.geom;
        for j in 0..nq {
            let (_, t) = skalak_point(par, r.metric[j], [g.e[j], g.f[j], g.g[j]]);
            let (xt, xp) = (g.xt[j], g.xp[j]);
            for a in 0..3 {
                for b in a..3 {
                    r.tau[SYM[a][b] * nq + j] = t[0] * xt[a] * xt[b]
                        + t[1] * (xt[a] * xp[b] + xp[a] * xt[b])
                        + t[2] * xp[a] * xp[b];
                }
            }
        }
        let res = self.calc.forward(&r.tau, &mut r.ctau).and_then(|_| {
            self.calc.synthesize(
                &r.ctau,
                &[Deriv::Theta, Deriv::Phi],
                &mut [&mut r.dt, &mut r.dp],
            )
        });
        if res.is_ok() {
            let g = &self.geom;
            for j in 0..nq {
                for k in 0..3 {
                    let col_t: [f64; 3] = std::array::from_fn(|a| r.dt[SYM[a][k] * nq + j]);
                    let col_p: [f64; 3] = std::array::from_fn(|a| r.dp[SYM[a][k] * nq + j]);
                    self.a[k * nq + j] = div_at(g, j, col_t, col_p);
                }
            }
        }
        self.reference = Some(r);
        res
    }
}

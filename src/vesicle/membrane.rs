//! The membrane-force engine: geometry frozen on the upsampled grid, forces filtered back.
//!
//! A [`Membrane`] of orders `(p, q)` holds the geometry of one surface on the grid of order `q`
//! (set by [`Membrane::set_geometry`] from the order-`p` coefficients, exactly, since the surface
//! is band-limited at `p`), and the scratch for the force routines of [`super::bending`],
//! [`super::tension`] and [`super::skalak`]. Inputs on the order-`p` grid are upsampled to `q`
//! (forward at `p`, zero-padding, inverse at `q`); forces computed at `q` are filtered back
//! (forward at `q`, truncation to degree `p`, inverse at `p`). The quantity filtered is the
//! density per unit *solid angle* of the parameter sphere, `f J` with `J = W / sin θ`:
//! `f_p = P_p(f J) / J_p`, where `P_p` is the projection on degrees `≤ p` and `J_p` the exact area
//! element of the band-limited surface on the order-`p` grid. Then `∫ f_p·δX dA = ∫ f·δX dA` for
//! every `δX` of degree `≤ p` (the virtual work of the filtered force is that of the fine one),
//! which a plain filter of `f` would not give, because `J` is not band-limited. Nothing
//! allocates after construction except [`Membrane::set_reference`] (once per reference shape).
//!
//! The routines that take a field (`σ`, `u`, `Y`) are linear in it and use the frozen geometry:
//! they are the linear operators the semi-implicit time step needs.

use super::geometry::{Geometry, SurfaceCalculus};
use super::skalak_reference::Reference;
use super::{check_len, cross, dot, get3, VesicleError};
use crate::sph_harmonics::{resample_coefs, Deriv, ShTransform, ShWorkspace};

/// Geometry of one cell on the upsampled grid and scratch for its membrane forces.
pub struct Membrane {
    pub(super) sht_p: ShTransform,
    pub(super) ws_p: ShWorkspace,
    /// Calculus at order `q`.
    pub(super) calc: SurfaceCalculus,
    pub(super) geom: Geometry,
    pub(super) geom_set: bool,
    pub(super) cp: Vec<f64>,
    pub(super) cq: Vec<f64>,
    /// Vector scratch at order `q` (3 components each).
    pub(super) a: Vec<f64>,
    pub(super) b: Vec<f64>,
    /// Scalar scratch at order `q`.
    pub(super) s1: Vec<f64>,
    pub(super) s2: Vec<f64>,
    pub(super) reference: Option<Reference>,
    /// `J = W / sin θ` on the order-`q` and order-`p` grids.
    pub(super) jac_q: Vec<f64>,
    pub(super) jac_p: Vec<f64>,
    /// `X_θ, X_φ` on the order-`p` grid (scratch for `jac_p`).
    dxp: Vec<f64>,
}

impl Membrane {
    /// Engine for surfaces of order `p ≥ 1`, forces computed at order `q ≥ p`.
    pub fn new(p: usize, q: usize) -> Result<Self, VesicleError> {
        if q < p {
            return Err(VesicleError::Order { p, q });
        }
        let sht_p = ShTransform::new(p)?;
        let ws_p = sht_p.workspace();
        let calc = SurfaceCalculus::new(q)?;
        let nq = calc.n_points();
        let np = sht_p.n_points();
        let ncq = calc.transform().n_coefs();
        Ok(Membrane {
            cp: vec![0.0; 3 * sht_p.n_coefs()],
            cq: vec![0.0; 3 * ncq],
            sht_p,
            ws_p,
            geom: Geometry::zeros(q),
            geom_set: false,
            calc,
            a: vec![0.0; 3 * nq],
            b: vec![0.0; 3 * nq],
            s1: vec![0.0; nq],
            s2: vec![0.0; nq],
            reference: None,
            jac_q: vec![0.0; nq],
            jac_p: vec![0.0; np],
            dxp: vec![0.0; 6 * np],
        })
    }

    /// Engine with the default upsampling `q = 2p`.
    pub fn with_default_upsampling(p: usize) -> Result<Self, VesicleError> {
        Self::new(p, 2 * p)
    }

    /// The surface order `p`.
    pub fn order(&self) -> usize {
        self.sht_p.order()
    }
    /// The force (upsampled) order `q`.
    pub fn upsampled_order(&self) -> usize {
        self.calc.order()
    }
    /// Grid points at order `p`.
    pub fn n_points(&self) -> usize {
        self.sht_p.n_points()
    }
    /// Grid points at order `q`.
    pub fn n_points_upsampled(&self) -> usize {
        self.calc.n_points()
    }

    /// Freeze the geometry of the surface with order-`p` coefficients `coefs` (`x, y, z`).
    pub fn set_geometry(&mut self, coefs: &[f64]) -> Result<(), VesicleError> {
        check_len("surface coefficients", coefs.len(), self.cp.len())?;
        self.geom_set = false;
        resample_coefs(
            self.sht_p.layout(),
            self.calc.transform().layout(),
            coefs,
            &mut self.cq,
        )?;
        self.calc.update_geometry(&self.cq, &mut self.geom)?;
        let nlon_q = 2 * self.upsampled_order();
        let grid_q = self.calc.transform().grid();
        for (j, jq) in self.jac_q.iter_mut().enumerate() {
            *jq = self.geom.w[j] / grid_q.sin_theta[j / nlon_q];
        }
        let np = self.n_points();
        let nlon_p = 2 * self.order();
        let (xt, xp) = self.dxp.split_at_mut(3 * np);
        self.sht_p.synthesize(
            coefs,
            &[Deriv::Theta, Deriv::Phi],
            &mut [xt, xp],
            &mut self.ws_p,
        )?;
        let grid_p = self.sht_p.grid();
        for (j, jp) in self.jac_p.iter_mut().enumerate() {
            let w = cross(get3(xt, np, j), get3(xp, np, j));
            *jp = dot(w, w).sqrt() / grid_p.sin_theta[j / nlon_p];
        }
        self.geom_set = true;
        Ok(())
    }

    /// The frozen geometry on the order-`q` grid.
    pub fn geometry(&self) -> Result<&Geometry, VesicleError> {
        if self.geom_set {
            Ok(&self.geom)
        } else {
            Err(VesicleError::Missing(
                "the geometry (Membrane::set_geometry)",
            ))
        }
    }

    pub(super) fn require_geometry(&self) -> Result<(), VesicleError> {
        self.geometry().map(|_| ())
    }

    /// Upsample `k ≤ 3` functions from the order-`p` grid to the order-`q` grid.
    pub fn upsample(&mut self, src: &[f64], dst: &mut [f64]) -> Result<(), VesicleError> {
        let np = self.n_points();
        let k = src.len() / np;
        if k == 0 || k > 3 || src.len() != k * np {
            return Err(VesicleError::Length {
                what: "order-p grid data (1 to 3 functions)",
                len: src.len(),
                expected: np,
            });
        }
        check_len("upsampled output", dst.len(), k * self.n_points_upsampled())?;
        let (ncp, ncq) = (self.sht_p.n_coefs(), self.calc.transform().n_coefs());
        self.sht_p
            .forward(src, &mut self.cp[..k * ncp], &mut self.ws_p)?;
        resample_coefs(
            self.sht_p.layout(),
            self.calc.transform().layout(),
            &self.cp[..k * ncp],
            &mut self.cq[..k * ncq],
        )?;
        self.calc.inverse(&self.cq[..k * ncq], dst)
    }

    /// Filter `k ≤ 3` functions from the order-`q` grid back to the order-`p` grid (degrees
    /// above `p` removed).
    pub fn filter_down(&mut self, src: &[f64], dst: &mut [f64]) -> Result<(), VesicleError> {
        let nq = self.n_points_upsampled();
        let k = src.len() / nq;
        if k == 0 || k > 3 || src.len() != k * nq {
            return Err(VesicleError::Length {
                what: "order-q grid data (1 to 3 functions)",
                len: src.len(),
                expected: nq,
            });
        }
        check_len("filtered output", dst.len(), k * self.n_points())?;
        let (ncp, ncq) = (self.sht_p.n_coefs(), self.calc.transform().n_coefs());
        self.calc.forward(src, &mut self.cq[..k * ncq])?;
        resample_coefs(
            self.calc.transform().layout(),
            self.sht_p.layout(),
            &self.cq[..k * ncq],
            &mut self.cp[..k * ncp],
        )?;
        Ok(self
            .sht_p
            .inverse(&self.cp[..k * ncp], dst, &mut self.ws_p)?)
    }

    /// Filter `k ≤ 3` densities from the order-`q` grid to the order-`p` grid preserving their
    /// virtual work against fields of degree `≤ p`: `dst = P_p(src J_q) / J_p` (see the module
    /// docs). `src` is overwritten with `src J_q`. Needs the frozen geometry.
    pub fn filter_density(&mut self, src: &mut [f64], dst: &mut [f64]) -> Result<(), VesicleError> {
        self.require_geometry()?;
        let nq = self.n_points_upsampled();
        let np = self.n_points();
        for c in src.chunks_exact_mut(nq) {
            c.iter_mut().zip(&self.jac_q).for_each(|(v, j)| *v *= j);
        }
        self.filter_down(src, dst)?;
        for c in dst.chunks_exact_mut(np) {
            c.iter_mut().zip(&self.jac_p).for_each(|(v, j)| *v /= j);
        }
        Ok(())
    }

    /// Write the vector scratch `a` (order `q`) to `out`: filtered to order `p` by
    /// [`Self::filter_density`] if `filtered`, else copied (order-`q` length).
    pub(super) fn emit_vector(
        &mut self,
        out: &mut [f64],
        filtered: bool,
    ) -> Result<(), VesicleError> {
        if !filtered {
            check_len("upsampled force output", out.len(), self.a.len())?;
            out.copy_from_slice(&self.a);
            return Ok(());
        }
        check_len("force output", out.len(), 3 * self.n_points())?;
        let mut a = std::mem::take(&mut self.a);
        let r = self.filter_density(&mut a, out);
        self.a = a;
        r
    }
}

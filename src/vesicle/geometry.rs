//! Differential geometry of a spherical-harmonic surface on its grid.
//!
//! [`SurfaceCalculus`] (a transform plan of order `p` with its scratch) turns the coefficients of
//! a surface into a [`Geometry`] (tangents, metric, normal, curvatures, quadrature weights) and
//! applies the surface gradient, divergence and Laplace–Beltrami operator to grid fields. The
//! formulas and the curvature sign convention (`H = −1/R` on a sphere) are in the
//! [module docs](super).

use std::f64::consts::PI;

use super::{check_len, cross, dot, get3, set3, VesicleError};
use crate::sph_harmonics::{Deriv, ShTransform, ShWorkspace};

/// Geometric quantities of a surface at every point of the grid of order `p` (latitude-major).
#[derive(Clone, Debug)]
pub struct Geometry {
    p: usize,
    /// Positions `X`.
    pub x: Vec<[f64; 3]>,
    /// `X_θ`.
    pub xt: Vec<[f64; 3]>,
    /// `X_φ`.
    pub xp: Vec<[f64; 3]>,
    /// `X_θθ`.
    pub xtt: Vec<[f64; 3]>,
    /// `X_θφ`.
    pub xtp: Vec<[f64; 3]>,
    /// `X_φφ`.
    pub xpp: Vec<[f64; 3]>,
    /// First fundamental form `E, F, G`.
    pub e: Vec<f64>,
    /// `F = X_θ·X_φ`.
    pub f: Vec<f64>,
    /// `G = X_φ·X_φ`.
    pub g: Vec<f64>,
    /// Area element `W = |X_θ × X_φ|` (per unit `dθ dφ`).
    pub w: Vec<f64>,
    /// Inverse metric `[g^{θθ}, g^{θφ}, g^{φφ}] = [G, −F, E] / W²`.
    pub ginv: Vec<[f64; 3]>,
    /// Outward unit normal.
    pub normal: Vec<[f64; 3]>,
    /// Second fundamental form `L = X_θθ·n`.
    pub l: Vec<f64>,
    /// `M = X_θφ·n`.
    pub m: Vec<f64>,
    /// `N = X_φφ·n`.
    pub n: Vec<f64>,
    /// Mean curvature `H = (EN − 2FM + GL)/(2W²)` (`−1/R` on a sphere).
    pub h: Vec<f64>,
    /// Gaussian curvature `K = (LN − M²)/W²`.
    pub k: Vec<f64>,
    /// `g^{ij} X_ij` (its normal part is `2H n`; the tangential part carries the Christoffel
    /// symbols of the Laplace–Beltrami operator).
    pub lap_coord: Vec<[f64; 3]>,
    /// Quadrature weight of each point for `∫ f dA`: `w_i (π/p) W / sin θ_i`.
    pub da: Vec<f64>,
}

impl Geometry {
    /// Zero-filled storage for order `p`.
    pub fn zeros(p: usize) -> Self {
        let np = 2 * p * (p + 1);
        let v = vec![[0.0; 3]; np];
        let s = vec![0.0; np];
        Geometry {
            p,
            x: v.clone(),
            xt: v.clone(),
            xp: v.clone(),
            xtt: v.clone(),
            xtp: v.clone(),
            xpp: v.clone(),
            e: s.clone(),
            f: s.clone(),
            g: s.clone(),
            w: s.clone(),
            ginv: v.clone(),
            normal: v.clone(),
            l: s.clone(),
            m: s.clone(),
            n: s.clone(),
            h: s.clone(),
            k: s.clone(),
            lap_coord: v,
            da: s,
        }
    }

    /// The grid order `p`.
    pub fn order(&self) -> usize {
        self.p
    }
    /// Number of grid points.
    pub fn n_points(&self) -> usize {
        self.da.len()
    }

    /// `∫ f dA` of grid values `f`.
    pub fn integrate(&self, f: &[f64]) -> f64 {
        f.iter().zip(&self.da).map(|(f, w)| f * w).sum()
    }
    /// Surface area.
    pub fn area(&self) -> f64 {
        self.da.iter().sum()
    }
    /// `(∫ u·n dA, ∫ |u| dA)` of a vector field `u` on the grid (component-major, `3n`): its
    /// net flux through the surface and its size.
    pub fn normal_flux(&self, u: &[f64]) -> (f64, f64) {
        let n = self.n_points();
        assert_eq!(u.len(), 3 * n, "a vector field on the grid has 3n values");
        let (mut flux, mut size) = (0.0, 0.0);
        for j in 0..n {
            let v = [u[j], u[n + j], u[2 * n + j]];
            let nm = self.normal[j];
            flux += (v[0] * nm[0] + v[1] * nm[1] + v[2] * nm[2]) * self.da[j];
            size += (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() * self.da[j];
        }
        (flux, size)
    }
    /// Enclosed volume `⅓ ∫ X·n dA`.
    pub fn volume(&self) -> f64 {
        (0..self.n_points())
            .map(|j| dot(self.x[j], self.normal[j]) * self.da[j])
            .sum::<f64>()
            / 3.0
    }
    /// Centroid of the enclosed solid, `(1/4V) ∫ X (X·n) dA`.
    pub fn centroid(&self) -> [f64; 3] {
        let mut c = [0.0; 3];
        for j in 0..self.n_points() {
            let s = dot(self.x[j], self.normal[j]) * self.da[j];
            for (ci, xi) in c.iter_mut().zip(self.x[j]) {
                *ci += xi * s;
            }
        }
        let v4 = 4.0 * self.volume();
        c.map(|ci| ci / v4)
    }
    /// Inertia tensor of the enclosed solid of unit density about its centroid,
    /// `I = ∫_V (|r|² 𝟙 − r ⊗ r) dV` with `∫_V r_i r_j dV = ⅕ ∫ r_i r_j (r·n) dA`.
    pub fn inertia_tensor(&self) -> [[f64; 3]; 3] {
        let c = self.centroid();
        let mut s = [[0.0; 3]; 3];
        for j in 0..self.n_points() {
            let r = [
                self.x[j][0] - c[0],
                self.x[j][1] - c[1],
                self.x[j][2] - c[2],
            ];
            let wgt = dot(r, self.normal[j]) * self.da[j] / 5.0;
            for a in 0..3 {
                for b in 0..3 {
                    s[a][b] += r[a] * r[b] * wgt;
                }
            }
        }
        let tr = s[0][0] + s[1][1] + s[2][2];
        let mut out = [[0.0; 3]; 3];
        for a in 0..3 {
            for b in 0..3 {
                out[a][b] = if a == b { tr } else { 0.0 } - s[a][b];
            }
        }
        out
    }
    /// Principal moments (ascending) and axes (`axes[i]` is the unit axis of moment `i`) of the
    /// inertia tensor.
    pub fn principal_axes(&self) -> ([f64; 3], [[f64; 3]; 3]) {
        symmetric_eigen3(self.inertia_tensor())
    }
    /// The ellipsoid with the same inertia tensor per unit volume (the same principal axes and
    /// second moments; its volume equals `V` only when the surface is an ellipsoid): its
    /// semi-axes and their unit directions (`axes[i]` belongs to `semi_axes[i]`), from the
    /// principal moments `I_a = V(b² + c²)/5`: `a² = (5/2V)(I_b + I_c − I_a)`.
    pub fn equivalent_ellipsoid(&self) -> ([f64; 3], [[f64; 3]; 3]) {
        let (m, axes) = self.principal_axes();
        let s = 2.5 / self.volume();
        let semi = std::array::from_fn(|i| {
            let (b, c) = (m[(i + 1) % 3], m[(i + 2) % 3]);
            (s * (b + c - m[i])).max(0.0).sqrt()
        });
        (semi, axes)
    }

    /// Taylor deformation `D = (L − B)/(L + B)` in the plane normal to `vorticity`: `L` and `B`
    /// are the semi-axes of the [equivalent ellipsoid](Self::equivalent_ellipsoid) other than
    /// the one closest to the vorticity direction (the shear plane of a cell in simple shear).
    pub fn taylor_deformation(&self, vorticity: [f64; 3]) -> f64 {
        let (semi, axes) = self.equivalent_ellipsoid();
        let (l, b, _) = crate::linalg3::shear_plane_semi_axes(semi, axes, vorticity);
        (l - b) / (l + b)
    }
    /// The membrane phase rate about `axis` ([`crate::vesicle::tank_treading::phase_rate`], weights
    /// `da`) of the grid velocity `velocity` (`3n`, component-major, as
    /// [`crate::timestep::cell_state::CellState::membrane_velocity`]): for a steadily
    /// tank-treading cell, `2π` over the period of its material points, counter-clockwise
    /// about `axis` (pass `[0, 0, −1]` for the sense of the shear `u = (γ̇y, 0, 0)`).
    ///
    /// # Errors
    /// [`VesicleError::Length`] when `velocity` is not `3n` long.
    pub fn tank_treading_rate(
        &self,
        velocity: &[f64],
        axis: [f64; 3],
    ) -> Result<f64, VesicleError> {
        let n = self.n_points();
        check_len("membrane velocity", velocity.len(), 3 * n)?;
        let u: Vec<[f64; 3]> = (0..n)
            .map(|j| [velocity[j], velocity[n + j], velocity[2 * n + j]])
            .collect();
        Ok(crate::vesicle::tank_treading::phase_rate(
            &self.x, &u, &self.da, axis,
        ))
    }
    /// Reduced volume `6√π V / A^{3/2}`.
    pub fn reduced_volume(&self) -> f64 {
        6.0 * PI.sqrt() * self.volume() / self.area().powf(1.5)
    }
    /// Equivalent radius `(3V/4π)^{1/3}` (sphere of equal volume).
    pub fn equivalent_radius(&self) -> f64 {
        (3.0 * self.volume() / (4.0 * PI)).cbrt()
    }
    /// Skewness of the enclosed solid along the direction `e` through its centroid `c`:
    /// `γ = μ₃ / μ₂^{3/2}`, with the central moments `μ_k = (1/V) ∫_V ((r − c)·e)^k dV`, each
    /// from the divergence theorem as `∫_V s^k dV = ∫ s^{k+1}/(k+1) (e·n) dA`, `s = (r − c)·e`.
    ///
    /// Zero for a solid symmetric about its centroid's plane normal to `e`; the asymmetric
    /// "dumbbell" mode of a vesicle in extensional flow (Narsimhan, Spann & Shaqfeh, *J. Fluid
    /// Mech.* 750, 2014) makes it grow along the extension axis.
    /// `e` need not be of unit length (it is normalised).
    pub fn axial_skewness(&self, e: [f64; 3]) -> f64 {
        let len = dot(e, e).sqrt();
        let e = e.map(|v| v / len);
        let c = self.centroid();
        let (mut m2, mut m3) = (0.0, 0.0);
        for j in 0..self.n_points() {
            let r = [
                self.x[j][0] - c[0],
                self.x[j][1] - c[1],
                self.x[j][2] - c[2],
            ];
            let s = dot(r, e);
            let flux = dot(e, self.normal[j]) * self.da[j];
            let s3 = s * s * s;
            m2 += s3 / 3.0 * flux;
            m3 += s3 * s / 4.0 * flux;
        }
        let v = self.volume();
        (m3 / v) / (m2 / v).powf(1.5)
    }
}

pub use crate::linalg3::symmetric_eigen3;

/// A transform plan of order `p` and scratch for geometry and surface differential operators.
pub struct SurfaceCalculus {
    sht: ShTransform,
    ws: ShWorkspace,
    /// Six derivative fields (value, θ, φ, θθ, θφ, φφ) of up to three components.
    d: Vec<f64>,
    c: Vec<f64>,
}

impl SurfaceCalculus {
    /// Plan for order `p ≥ 1`.
    pub fn new(p: usize) -> Result<Self, VesicleError> {
        let sht = ShTransform::new(p)?;
        let ws = sht.workspace();
        let np = sht.n_points();
        let nc = sht.n_coefs();
        Ok(SurfaceCalculus {
            sht,
            ws,
            d: vec![0.0; 18 * np],
            c: vec![0.0; 3 * nc],
        })
    }
    /// The order `p`.
    pub fn order(&self) -> usize {
        self.sht.order()
    }
    /// The transform plan.
    pub fn transform(&self) -> &ShTransform {
        &self.sht
    }
    /// Grid points per function.
    pub fn n_points(&self) -> usize {
        self.sht.n_points()
    }

    /// Forward transform of a batch of grid functions with this plan's scratch.
    pub fn forward(&mut self, grid: &[f64], coefs: &mut [f64]) -> Result<(), VesicleError> {
        Ok(self.sht.forward(grid, coefs, &mut self.ws)?)
    }
    /// Inverse transform of a batch of coefficient vectors with this plan's scratch.
    pub fn inverse(&mut self, coefs: &[f64], grid: &mut [f64]) -> Result<(), VesicleError> {
        Ok(self.sht.inverse(coefs, grid, &mut self.ws)?)
    }

    /// Grid values of derivatives of a batch of expansions (see [`ShTransform::synthesize`]).
    pub fn synthesize(
        &mut self,
        coefs: &[f64],
        derivs: &[Deriv],
        outs: &mut [&mut [f64]],
    ) -> Result<(), VesicleError> {
        Ok(self.sht.synthesize(coefs, derivs, outs, &mut self.ws)?)
    }

    /// The geometry of the surface with coefficients `coefs` (`x, y, z`, order `p`).
    pub fn geometry(&mut self, coefs: &[f64]) -> Result<Geometry, VesicleError> {
        let mut g = Geometry::zeros(self.order());
        self.update_geometry(coefs, &mut g)?;
        Ok(g)
    }

    /// Recompute `geom` in place (no allocation). Errors on a degenerate area element or an
    /// inward-oriented (non-positive volume) parametrisation.
    pub fn update_geometry(
        &mut self,
        coefs: &[f64],
        geom: &mut Geometry,
    ) -> Result<(), VesicleError> {
        let np = self.n_points();
        let p = self.order();
        check_len("surface coefficients", coefs.len(), 3 * self.sht.n_coefs())?;
        if geom.p != p {
            return Err(VesicleError::Order { p, q: geom.p });
        }
        let mut it = self.d.chunks_exact_mut(3 * np);
        let mut outs: [&mut [f64]; 6] = std::array::from_fn(|_| it.next().expect("six fields"));
        self.sht
            .synthesize(coefs, &Deriv::ALL, &mut outs, &mut self.ws)?;
        let grid = self.sht.grid();
        let dphi = PI / p as f64;
        let nlon = 2 * p;
        let mut wmax: f64 = 0.0;
        for j in 0..np {
            let i = j / nlon;
            let x = get3(outs[0], np, j);
            let xt = get3(outs[1], np, j);
            let xp = get3(outs[2], np, j);
            let xtt = get3(outs[3], np, j);
            let xtp = get3(outs[4], np, j);
            let xpp = get3(outs[5], np, j);
            let (e, f, g) = (dot(xt, xt), dot(xt, xp), dot(xp, xp));
            let nv = cross(xt, xp);
            let w = dot(nv, nv).sqrt();
            let w2 = w * w;
            let n = nv.map(|c| c / w);
            let (l, m, nn) = (dot(xtt, n), dot(xtp, n), dot(xpp, n));
            let gi = [g / w2, -f / w2, e / w2];
            geom.x[j] = x;
            geom.xt[j] = xt;
            geom.xp[j] = xp;
            geom.xtt[j] = xtt;
            geom.xtp[j] = xtp;
            geom.xpp[j] = xpp;
            geom.e[j] = e;
            geom.f[j] = f;
            geom.g[j] = g;
            geom.w[j] = w;
            geom.ginv[j] = gi;
            geom.normal[j] = n;
            geom.l[j] = l;
            geom.m[j] = m;
            geom.n[j] = nn;
            geom.h[j] = (e * nn - 2.0 * f * m + g * l) / (2.0 * w2);
            geom.k[j] = (l * nn - m * m) / w2;
            geom.lap_coord[j] =
                std::array::from_fn(|c| gi[0] * xtt[c] + 2.0 * gi[1] * xtp[c] + gi[2] * xpp[c]);
            let jac = w / grid.sin_theta[i];
            geom.da[j] = grid.gl_weights[i] * dphi * jac;
            wmax = wmax.max(jac);
        }
        let wmin = (0..np)
            .map(|j| geom.w[j] / grid.sin_theta[j / nlon])
            .fold(f64::INFINITY, f64::min);
        if wmin.is_nan() || wmin <= 1e-12 * wmax || !wmax.is_finite() {
            return Err(VesicleError::Degenerate(format!(
                "area element per solid angle ranges over [{wmin:.3e}, {wmax:.3e}]"
            )));
        }
        let v = geom.volume();
        if v.is_nan() || v <= 0.0 {
            return Err(VesicleError::Degenerate(format!(
                "enclosed volume {v:.3e} ≤ 0: inward-oriented parametrisation"
            )));
        }
        Ok(())
    }

    /// Transform `k ≤ 3` grid functions and synthesize their value, `θ`, `φ` (and, if `second`,
    /// `θθ, θφ, φφ`) derivatives into `self.d` (field `t` of component `c` at
    /// `(t·3 + c)·np`… laid out as six blocks of `k·np`).
    fn derivatives(&mut self, f: &[f64], k: usize, second: bool) -> Result<(), VesicleError> {
        let np = self.n_points();
        let nc = self.sht.n_coefs();
        let c = &mut self.c[..k * nc];
        self.sht.forward(f, c, &mut self.ws)?;
        let nd = if second { 6 } else { 3 };
        let mut it = self.d.chunks_exact_mut(k * np);
        let mut outs: [&mut [f64]; 6] = std::array::from_fn(|_| it.next().expect("six fields"));
        self.sht
            .synthesize(c, &Deriv::ALL[..nd], &mut outs[..nd], &mut self.ws)?;
        Ok(())
    }

    fn check_geom(&self, geom: &Geometry) -> Result<(), VesicleError> {
        if geom.p != self.order() {
            return Err(VesicleError::Order {
                p: self.order(),
                q: geom.p,
            });
        }
        Ok(())
    }

    /// Surface gradient `∇_s f = g^{ij} f_i X_j` of a grid function; `out` is component-major.
    pub fn gradient(
        &mut self,
        geom: &Geometry,
        f: &[f64],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        let np = self.n_points();
        self.check_geom(geom)?;
        check_len("scalar field", f.len(), np)?;
        check_len("gradient output", out.len(), 3 * np)?;
        self.derivatives(f, 1, false)?;
        let (ft, fp) = (&self.d[np..2 * np], &self.d[2 * np..3 * np]);
        for j in 0..np {
            set3(out, np, j, grad_at(geom, j, ft[j], fp[j]));
        }
        Ok(())
    }

    /// Surface divergence `∇_s·v = g^{ij} X_i·v_j` of a vector field (component-major).
    pub fn divergence(
        &mut self,
        geom: &Geometry,
        v: &[f64],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        let np = self.n_points();
        self.check_geom(geom)?;
        check_len("vector field", v.len(), 3 * np)?;
        check_len("divergence output", out.len(), np)?;
        self.derivatives(v, 3, false)?;
        let (vt, vp) = (&self.d[3 * np..6 * np], &self.d[6 * np..9 * np]);
        for (j, o) in out.iter_mut().enumerate() {
            *o = div_at(geom, j, get3(vt, np, j), get3(vp, np, j));
        }
        Ok(())
    }

    /// Laplace–Beltrami `Δ_s f = g^{ij} f_ij − (g^{ij} X_ij)·∇_s f` of a grid function.
    pub fn laplace_beltrami(
        &mut self,
        geom: &Geometry,
        f: &[f64],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        let np = self.n_points();
        self.check_geom(geom)?;
        check_len("scalar field", f.len(), np)?;
        check_len("Laplace–Beltrami output", out.len(), np)?;
        self.derivatives(f, 1, true)?;
        let d = &self.d;
        for (j, o) in out.iter_mut().enumerate() {
            let fd = [
                d[np + j],
                d[2 * np + j],
                d[3 * np + j],
                d[4 * np + j],
                d[5 * np + j],
            ];
            *o = lap_at(geom, j, fd);
        }
        Ok(())
    }

    /// Laplace–Beltrami of each component of a vector field (component-major in and out).
    pub fn laplace_beltrami_vec(
        &mut self,
        geom: &Geometry,
        v: &[f64],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        let np = self.n_points();
        self.check_geom(geom)?;
        check_len("vector field", v.len(), 3 * np)?;
        check_len("Laplace–Beltrami output", out.len(), 3 * np)?;
        self.derivatives(v, 3, true)?;
        let d = &self.d;
        let b = 3 * np;
        for c in 0..3 {
            for j in 0..np {
                let o = c * np + j;
                let fd = [
                    d[b + o],
                    d[2 * b + o],
                    d[3 * b + o],
                    d[4 * b + o],
                    d[5 * b + o],
                ];
                out[o] = lap_at(geom, j, fd);
            }
        }
        Ok(())
    }
}

/// `∇_s f` at point `j` from `f_θ, f_φ`.
#[inline(always)]
pub(crate) fn grad_at(geom: &Geometry, j: usize, ft: f64, fp: f64) -> [f64; 3] {
    let gi = geom.ginv[j];
    let a = gi[0] * ft + gi[1] * fp;
    let b = gi[1] * ft + gi[2] * fp;
    let (xt, xp) = (geom.xt[j], geom.xp[j]);
    std::array::from_fn(|c| a * xt[c] + b * xp[c])
}

/// `∇_s·v` at point `j` from `v_θ, v_φ`.
#[inline(always)]
pub(crate) fn div_at(geom: &Geometry, j: usize, vt: [f64; 3], vp: [f64; 3]) -> f64 {
    let gi = geom.ginv[j];
    let (xt, xp) = (geom.xt[j], geom.xp[j]);
    gi[0] * dot(xt, vt) + gi[1] * (dot(xt, vp) + dot(xp, vt)) + gi[2] * dot(xp, vp)
}

/// `Δ_s f` at point `j` from `[f_θ, f_φ, f_θθ, f_θφ, f_φφ]`.
#[inline(always)]
pub(crate) fn lap_at(geom: &Geometry, j: usize, fd: [f64; 5]) -> f64 {
    let gi = geom.ginv[j];
    let second = gi[0] * fd[2] + 2.0 * gi[1] * fd[3] + gi[2] * fd[4];
    second - dot(geom.lap_coord[j], grad_at(geom, j, fd[0], fd[1]))
}

//! A plane wall at rest, by Blake's image system: the fluid fills the half-space on one side
//! of an infinite no-slip plane, and no unknown lives on the wall.
//!
//! A point force `F` at `y` (height `h > 0` above the plane) in a fluid of viscosity `μ`
//! bounded by a plane at rest drives the velocity `u(x) = G^B(x, y) F / (8πμ)` with Blake's
//! tensor (J. R. Blake, *A note on the image system for a stokeslet in a no-slip boundary*,
//! Proc. Camb. Phil. Soc. 70, 1971; in the form of Pozrikidis, *Boundary Integral and
//! Singularity Methods*, 1992, §3.3). In the wall's frame (the plane `x₃ = 0`, the fluid at
//! `x₃ > 0`), with `r = x − y`, the image point `y* = (y₁, y₂, −h)`, `X = x − y*`, `ρ = |X|`
//! and `D = diag(1, 1, −1)`:
//!
//! ```text
//! G^B_ij(x, y) = S_ij(r) − S_ij(X) + 2h D_jl ∂/∂X_l [ h X_i/ρ³ − S_i3(X) ],
//! S_ij(r) = δ_ij/|r| + r_i r_j/|r|³.
//! ```
//!
//! The first term is the free-space Stokeslet; the rest, the **image** ([`PlaneWall::image`]),
//! is a Stokeslet, a Stokes doublet and a potential dipole at `y*`: smooth wherever `x` and
//! `y` are in the fluid, of size `1/(h_x + h_y)`. For cells beside the wall the free part is
//! what a suspension already computes (the FMM and each cell's own step); the image is added
//! from every cell's traction by the smooth quadrature of its surface
//! ([`crate::timestep::plane_coupling`]).
//!
//! Checked (unit tests): the whole tensor vanishes on the plane (no slip) to round-off, its
//! image is divergence-free (finite differences), and it is symmetric, `G^B_ij(x, y) =
//! G^B_ji(y, x)` (Lorentz's reciprocity, which a wrong sign breaks). Against Brenner's exact
//! drag of a sphere approaching the plane and Faxén's for one moving beside it:
//! `tests/plane_wall.rs`.

use super::WallError;

/// An infinite plane at rest: the points `x` with `(x − point)·normal = 0`, the fluid on the
/// side `normal` points into.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneWall {
    point: [f64; 3],
    /// The unit normal into the fluid, and two unit tangents (a right-handed frame
    /// `(t₁, t₂, n)`).
    normal: [f64; 3],
    t1: [f64; 3],
    t2: [f64; 3],
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

impl PlaneWall {
    /// The plane through `point` with `normal` (any length, not zero) pointing into the fluid.
    pub fn new(point: [f64; 3], normal: [f64; 3]) -> Result<Self, WallError> {
        let len = dot(normal, normal).sqrt();
        if !(len.is_finite() && len > 0.0) || point.iter().any(|v| !v.is_finite()) {
            return Err(WallError::Parameter {
                name: "plane normal",
                value: len,
                reason: "must be finite and not zero, through a finite point",
            });
        }
        let n = normal.map(|v| v / len);
        // The tangent from the axis least aligned with the normal.
        let a = (0..3)
            .min_by(|&i, &j| n[i].abs().total_cmp(&n[j].abs()))
            .unwrap_or(0);
        let mut e = [0.0; 3];
        e[a] = 1.0;
        let t1 = cross(e, n);
        let l1 = dot(t1, t1).sqrt();
        let t1 = t1.map(|v| v / l1);
        let t2 = cross(n, t1);
        Ok(PlaneWall {
            point,
            normal: n,
            t1,
            t2,
        })
    }

    /// The unit normal into the fluid.
    pub fn normal(&self) -> [f64; 3] {
        self.normal
    }

    /// The point the plane was given by.
    pub fn point(&self) -> [f64; 3] {
        self.point
    }

    /// `normal · point`: the plane is `normal · x = offset`.
    pub fn offset(&self) -> f64 {
        dot(self.normal, self.point)
    }

    /// The signed height of `x` above the plane (positive in the fluid).
    pub fn height(&self, x: [f64; 3]) -> f64 {
        dot(self.normal, x) - self.offset()
    }

    /// `x` in the wall's frame: `((x − point)·t₁, (x − point)·t₂, height)`.
    pub fn to_local(&self, x: [f64; 3]) -> [f64; 3] {
        let d = [
            x[0] - self.point[0],
            x[1] - self.point[1],
            x[2] - self.point[2],
        ];
        [dot(d, self.t1), dot(d, self.t2), dot(d, self.normal)]
    }

    /// A vector's components in the wall's frame.
    pub fn vector_to_local(&self, v: [f64; 3]) -> [f64; 3] {
        [dot(v, self.t1), dot(v, self.t2), dot(v, self.normal)]
    }

    /// A vector given in the wall's frame, in the global one.
    pub fn vector_to_global(&self, v: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|a| v[0] * self.t1[a] + v[1] * self.t2[a] + v[2] * self.normal[a])
    }

    /// The image part of Blake's tensor applied to `f`, `Σ_j (G^B_ij − S_ij(x − y)) f_j`, in
    /// the wall's frame: `x` and `y` (height `y₃ > 0`) and `f` in local components, the result
    /// too (without the `1/(8πμ)`).
    #[inline]
    pub fn image_local(x: [f64; 3], y: [f64; 3], f: [f64; 3]) -> [f64; 3] {
        image_generic(x, y, f)
    }

    /// The image part of the double layer's kernel in the wall's frame, without the
    /// `−1/(8π)`: `T^B_ijk g_j n_k − T_ijk g_j n_k` for a source at `y` with density `g` and
    /// normal `n` (module docs), all in local components.
    pub fn image_double_layer_local(
        x: [f64; 3],
        y: [f64; 3],
        g: [f64; 3],
        n: [f64; 3],
    ) -> [f64; 3] {
        // The force dipoles: −∂/∂y_k of the Stokeslet's image contracted with `n_k` (on `g`)
        // and with `g_k` (on `n`): two directional derivatives, by forward differentiation.
        let mut u = [0.0; 3];
        let xd = x.map(Dual::constant);
        for (f, along) in [(g, n), (n, g)] {
            let yd: [Dual; 3] = std::array::from_fn(|k| Dual {
                v: y[k],
                d: along[k],
            });
            let a = image_generic(xd, yd, f.map(Dual::constant));
            for i in 0..3 {
                u[i] -= a[i].d;
            }
        }
        // The source −2 (g·n) s(x − y), and its image.
        let h = y[2];
        let xx = [x[0] - y[0], x[1] - y[1], x[2] + h];
        let r2 = dot(xx, xx);
        let inv3 = 1.0 / (r2 * r2.sqrt());
        let inv5 = inv3 / r2;
        let gn = dot(g, n);
        for i in 0..3 {
            let d3 = if i == 2 { 2.0 * h * inv3 } else { 0.0 };
            let image = -xx[i] * inv3 + 6.0 * xx[i] * xx[2] * xx[2] * inv5 + d3
                - 6.0 * h * xx[i] * xx[2] * inv5;
            u[i] -= 2.0 * gn * image;
        }
        u
    }
}

/// The arithmetic [`image_generic`] needs: `f64`, or a number carrying one derivative.
trait Scalar:
    Copy
    + std::ops::Add<Output = Self>
    + std::ops::Sub<Output = Self>
    + std::ops::Mul<Output = Self>
    + std::ops::Div<Output = Self>
    + std::ops::Neg<Output = Self>
{
    fn constant(v: f64) -> Self;
    fn sqrt(self) -> Self;
}

impl Scalar for f64 {
    fn constant(v: f64) -> Self {
        v
    }
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
}

/// A value and its derivative along one direction (forward differentiation).
#[derive(Clone, Copy, Debug)]
struct Dual {
    v: f64,
    d: f64,
}

impl Dual {
    fn constant(v: f64) -> Self {
        Dual { v, d: 0.0 }
    }
}

impl std::ops::Add for Dual {
    type Output = Dual;
    fn add(self, o: Dual) -> Dual {
        Dual {
            v: self.v + o.v,
            d: self.d + o.d,
        }
    }
}

impl std::ops::Sub for Dual {
    type Output = Dual;
    fn sub(self, o: Dual) -> Dual {
        Dual {
            v: self.v - o.v,
            d: self.d - o.d,
        }
    }
}

impl std::ops::Mul for Dual {
    type Output = Dual;
    fn mul(self, o: Dual) -> Dual {
        Dual {
            v: self.v * o.v,
            d: self.d * o.v + self.v * o.d,
        }
    }
}

impl std::ops::Div for Dual {
    type Output = Dual;
    fn div(self, o: Dual) -> Dual {
        Dual {
            v: self.v / o.v,
            d: (self.d * o.v - self.v * o.d) / (o.v * o.v),
        }
    }
}

impl std::ops::Neg for Dual {
    type Output = Dual;
    fn neg(self) -> Dual {
        Dual {
            v: -self.v,
            d: -self.d,
        }
    }
}

impl Scalar for Dual {
    fn constant(v: f64) -> Self {
        Dual::constant(v)
    }
    fn sqrt(self) -> Self {
        let r = self.v.sqrt();
        Dual {
            v: r,
            d: self.d / (2.0 * r),
        }
    }
}

/// [`PlaneWall::image_local`] in any [`Scalar`] arithmetic.
#[inline]
fn image_generic<T: Scalar>(x: [T; 3], y: [T; 3], f: [T; 3]) -> [T; 3] {
    let c = T::constant;
    let dot = |a: [T; 3], b: [T; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    {
        let h = y[2];
        let xx = [x[0] - y[0], x[1] - y[1], x[2] + h];
        let r2 = dot(xx, xx);
        let r1 = r2.sqrt();
        let inv = c(1.0) / r1;
        let inv3 = inv / r2;
        let inv5 = inv3 / r2;
        // −S(X) f
        let xf = dot(xx, f);
        // g = D f
        let g = [f[0], f[1], -f[2]];
        let xg = dot(xx, g);
        let x3 = xx[2];
        let mut u = [c(0.0); 3];
        for i in 0..3 {
            let stokeslet = -(f[i] * inv + xx[i] * xf * inv3);
            // Σ_l g_l ∂Φ_i/∂X_l with Φ_i = h X_i/ρ³ − S_i3(X).
            let d_i3 = if i == 2 { xg * inv3 } else { c(0.0) };
            let dphi = h * (g[i] * inv3 - c(3.0) * xx[i] * xg * inv5) + d_i3
                - (g[i] * x3 + xx[i] * g[2]) * inv3
                + c(3.0) * xx[i] * x3 * xg * inv5;
            u[i] = stokeslet + c(2.0) * h * dphi;
        }
        u
    }
}

impl PlaneWall {
    /// The image velocity at `x` of a point force `f` at `y` (global frame), without the
    /// `1/(8πμ)`: [`Self::image_local`] in the wall's frame.
    pub fn image(&self, x: [f64; 3], y: [f64; 3], f: [f64; 3]) -> [f64; 3] {
        let u = Self::image_local(self.to_local(x), self.to_local(y), self.vector_to_local(f));
        self.vector_to_global(u)
    }

    /// Add `Σ_s image(x_t, y_s, F_s) / (8πμ)` at every target to `out` (component-major,
    /// `3 · targets.len()`), the point forces `sources` given as `(y_s, F_s)` in the wall's
    /// frame (weights included), summed in their order.
    pub fn add_images(
        &self,
        viscosity: f64,
        sources: &[crate::vesicle::smooth_layer::PointForce],
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<(), WallError> {
        let c = 1.0 / (8.0 * std::f64::consts::PI * viscosity);
        self.add_at(targets, out, c, |xl| {
            let mut u = [0.0; 3];
            for &(y, f) in sources {
                let v = Self::image_local(xl, y, f);
                u[0] += v[0];
                u[1] += v[1];
                u[2] += v[2];
            }
            u
        })
    }

    /// Add `c · field(x_t)` (the field in the wall's frame, of the local target) at every target
    /// to `out` (component-major).
    fn add_at(
        &self,
        targets: &[[f64; 3]],
        out: &mut [f64],
        c: f64,
        field: impl Fn([f64; 3]) -> [f64; 3],
    ) -> Result<(), WallError> {
        let nt = targets.len();
        super::check_len("image velocity", out.len(), 3 * nt)?;
        for (t, &x) in targets.iter().enumerate() {
            let u = self.vector_to_global(field(self.to_local(x)));
            for a in 0..3 {
                out[a * nt + t] += c * u[a];
            }
        }
        Ok(())
    }
}

impl PlaneWall {
    /// Add the images of double layers `D[g](x) = (3/4π) ∫ r (r·g)(r·n)/r⁵ dA` at every target
    /// to `out` (component-major, `3 · targets.len()`), the sources given as `(y_s, g_s dA_s,
    /// n_s)` in the wall's frame, summed in their order. With
    /// `T_ijk g_j n_k = ∂_k S_ij (g_j n_k + n_j g_k) − 2 (g·n) r_i/r³` (a force dipole and a
    /// point source; `D = −T g n/(8π)`), the image is that of each part: `−∂/∂y_k` of the
    /// Stokeslet's image for the dipoles (forward differentiation of [`Self::image_local`]),
    /// and for the source `s(X) − 2 ∂_{X₃} S_i3(X) + 2h ∂_{X₃} s(X)` at the mirror point
    /// (checked: the whole kernel vanishes on the plane).
    pub fn add_double_layer_images(
        &self,
        sources: &[[[f64; 3]; 3]],
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<(), WallError> {
        let c = -1.0 / (8.0 * std::f64::consts::PI);
        self.add_at(targets, out, c, |xl| {
            let mut u = [0.0; 3];
            for &[y, g, n] in sources {
                let v = Self::image_double_layer_local(xl, y, g, n);
                u[0] += v[0];
                u[1] += v[1];
                u[2] += v[2];
            }
            u
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stokeslet(r: [f64; 3], f: [f64; 3]) -> [f64; 3] {
        let d = dot(r, r).sqrt();
        let rf = dot(r, f);
        std::array::from_fn(|i| f[i] / d + r[i] * rf / (d * d * d))
    }

    fn blake(w: &PlaneWall, x: [f64; 3], y: [f64; 3], f: [f64; 3]) -> [f64; 3] {
        let s = stokeslet([x[0] - y[0], x[1] - y[1], x[2] - y[2]], f);
        let i = w.image(x, y, f);
        std::array::from_fn(|a| s[a] + i[a])
    }

    fn tilted() -> PlaneWall {
        PlaneWall::new([0.3, -0.2, 0.5], [0.4, -1.0, 2.0]).unwrap()
    }

    /// The force dipoles' image is minus the derivative of the Stokeslet's image along the
    /// source point (by central differences here, against the forward differentiation of
    /// [`PlaneWall::image_double_layer_local`]): with `g ⟂ n` the source part vanishes and
    /// `u = −(∂_n image(g) + ∂_g image(n))`.
    #[test]
    fn the_dipoles_image_is_the_derivative_of_the_stokeslets_image() {
        let eps = 1e-5;
        for (x, y, g) in [
            ([0.3, -0.4, 0.8], [0.1, 0.2, 0.15], [1.0, 0.5, 0.0]),
            ([-1.0, 2.0, 3.0], [0.5, -0.5, 1.2], [0.2, -1.0, 0.7]),
        ] {
            let n = {
                // A unit normal orthogonal to g.
                let t = cross(g, [0.3, 0.9, -0.2]);
                let l = dot(t, t).sqrt();
                t.map(|v| v / l)
            };
            let d = |f: [f64; 3], along: [f64; 3]| -> [f64; 3] {
                let yp = std::array::from_fn(|k| y[k] + eps * along[k]);
                let ym = std::array::from_fn(|k| y[k] - eps * along[k]);
                let (a, b) = (
                    PlaneWall::image_local(x, yp, f),
                    PlaneWall::image_local(x, ym, f),
                );
                std::array::from_fn(|i| (a[i] - b[i]) / (2.0 * eps))
            };
            let (a, b) = (d(g, n), d(n, g));
            let want: [f64; 3] = std::array::from_fn(|i| -(a[i] + b[i]));
            let got = PlaneWall::image_double_layer_local(x, y, g, n);
            let size = dot(want, want).sqrt();
            for i in 0..3 {
                assert!(
                    (got[i] - want[i]).abs() < 1e-8 * size,
                    "{x:?} {y:?}: {got:?} against {want:?}"
                );
            }
        }
    }

    /// A point above the tilted plane: local coordinates turned to global ones.
    fn above(w: &PlaneWall, local: [f64; 3]) -> [f64; 3] {
        let v = w.vector_to_global(local);
        std::array::from_fn(|a| w.point()[a] + v[a])
    }

    /// The whole tensor vanishes on the plane, for sources at several heights and forces in
    /// every direction (relative to the free Stokeslet's size there).
    #[test]
    fn blakes_tensor_vanishes_on_the_plane() {
        let w = tilted();
        for (k, &y) in [[0.1, 0.2, 0.05], [1.0, -0.5, 1.3], [-2.0, 3.0, 7.0]]
            .iter()
            .enumerate()
        {
            let y = above(&w, y);
            for f in [
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
                [0.3, -0.7, 0.2],
            ] {
                for x in [[0.0, 0.0, 0.0], [0.4, -0.9, 0.0], [5.0, 2.0, 0.0]] {
                    let x = above(&w, x);
                    assert!(w.height(x).abs() < 1e-14);
                    let u = blake(&w, x, y, f);
                    let s = stokeslet([x[0] - y[0], x[1] - y[1], x[2] - y[2]], f);
                    let (size, scale) = (dot(u, u).sqrt(), dot(s, s).sqrt());
                    assert!(
                        size < 1e-14 * scale,
                        "source {k}, {x:?}: {u:?} against {scale}"
                    );
                }
            }
        }
    }

    /// `G^B_ij(x, y) = G^B_ji(y, x)`: reciprocity of the wall-bounded Stokeslet.
    #[test]
    fn blakes_tensor_is_symmetric_in_its_points() {
        let w = tilted();
        let e = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        for (x, y) in [
            ([0.2, 0.1, 0.3], [1.0, -0.4, 1.7]),
            ([-1.0, 2.0, 0.05], [0.3, 0.2, 0.4]),
        ] {
            let (x, y) = (above(&w, x), above(&w, y));
            for i in 0..3 {
                for j in 0..3 {
                    let gij = dot(e[i], w.image(x, y, e[j]));
                    let gji = dot(e[j], w.image(y, x, e[i]));
                    assert!(
                        (gij - gji).abs() < 1e-13 * gij.abs().max(1.0),
                        "{i}{j}: {gij} {gji}"
                    );
                }
            }
        }
    }

    /// The image is divergence-free in `x` (centred differences, step 1e-4: error ~1e-8).
    #[test]
    fn the_image_is_divergence_free() {
        let w = tilted();
        let y = above(&w, [0.2, -0.3, 0.8]);
        let f = [0.3, -1.0, 0.6];
        for x in [[0.1, 0.4, 0.5], [1.5, -0.2, 0.1], [-0.7, 0.9, 2.0]] {
            let x = above(&w, x);
            let h = 1e-4;
            let mut div = 0.0;
            let mut size: f64 = 0.0;
            for a in 0..3 {
                let (mut xp, mut xm) = (x, x);
                xp[a] += h;
                xm[a] -= h;
                let (up, um) = (w.image(xp, y, f), w.image(xm, y, f));
                div += (up[a] - um[a]) / (2.0 * h);
                size = size.max(((up[a] - um[a]) / (2.0 * h)).abs());
            }
            assert!(size > 1e-2, "a test that sees the field ({size})");
            assert!(div.abs() < 1e-7 * size.max(1.0), "∇·u = {div} at {x:?}");
        }
    }

    /// The free double layer's kernel, `(3/4π) r (r·g)(r·n)/r⁵`, as `−T g n/(8π)`.
    fn free_double_layer(r: [f64; 3], g: [f64; 3], n: [f64; 3]) -> [f64; 3] {
        let d2 = dot(r, r);
        let c = 3.0 / (4.0 * std::f64::consts::PI) * dot(r, g) * dot(r, n) / (d2 * d2 * d2.sqrt());
        r.map(|v| c * v)
    }

    /// The double layer's kernel with its image vanishes on the plane (the wall's frame), for
    /// densities along and across the normal; and the image alone is divergence-free.
    #[test]
    fn the_double_layers_image_vanishes_on_the_plane_with_it() {
        let c = -1.0 / (8.0 * std::f64::consts::PI);
        for (y, g, n) in [
            ([0.1, 0.2, 0.3], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
            ([0.3, -0.2, 1.1], [0.2, -0.5, 0.7], [0.6, 0.0, -0.8]),
            ([-1.0, 0.4, 0.05], [0.0, 0.0, 1.0], [0.0, 0.8, 0.6]),
        ] {
            for x in [[0.0, 0.0, 0.0], [0.7, -1.2, 0.0], [4.0, 3.0, 0.0]] {
                let free = free_double_layer([x[0] - y[0], x[1] - y[1], x[2] - y[2]], g, n);
                let image = PlaneWall::image_double_layer_local(x, y, g, n).map(|v| c * v);
                let total: [f64; 3] = std::array::from_fn(|a| free[a] + image[a]);
                let size = dot(free, free).sqrt();
                assert!(size > 1e-6, "a test that sees the field ({size})");
                assert!(
                    dot(total, total).sqrt() < 1e-13 * size,
                    "{x:?}: {total:?} of {size}"
                );
            }
            let x = [0.4, 0.9, 0.6];
            let step = 1e-4;
            let mut div = 0.0;
            for a in 0..3 {
                let (mut xp, mut xm) = (x, x);
                xp[a] += step;
                xm[a] -= step;
                let up = PlaneWall::image_double_layer_local(xp, y, g, n);
                let um = PlaneWall::image_double_layer_local(xm, y, g, n);
                div += (up[a] - um[a]) / (2.0 * step);
            }
            let size = dot(PlaneWall::image_double_layer_local(x, y, g, n), [1.0; 3]).abs();
            assert!(div.abs() < 1e-6 * size.max(1.0), "∇·u = {div}");
        }
    }

    #[test]
    fn a_plane_needs_a_normal() {
        assert!(PlaneWall::new([0.0; 3], [0.0; 3]).is_err());
        assert!(PlaneWall::new([f64::NAN, 0.0, 0.0], [0.0, 0.0, 1.0]).is_err());
        let w = PlaneWall::new([0.0, 0.0, 1.0], [0.0, 0.0, 3.0]).unwrap();
        assert_eq!(w.normal(), [0.0, 0.0, 1.0]);
        assert!((w.height([5.0, -2.0, 3.0]) - 2.0).abs() < 1e-15);
    }
}

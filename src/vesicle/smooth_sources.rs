//! A smooth quadrature rule's nodes as a block of point sources, summed at many targets at once.
//!
//! Away from a surface its layer potentials are the smooth quadrature
//!
//! ```text
//!     S[f](x) = (1/8πμ) Σ_j (I/r + r rᵀ/r³) f_j dA_j,
//!     D[f](x) = (3/4π)  Σ_j (r·n_j)(r·f_j) r/r⁵ dA_j,      r = x − y_j,
//! ```
//!
//! over the nodes `y_j` of an upsampled grid (normals `n_j`, area weights `dA_j`). A rule of
//! order 6p over a wall of order 44 has 140 000 nodes, about 11 MB of positions, normals and
//! densities: a loop over them per target streams them from memory for every target. Here the
//! nodes are kept as a structure of arrays and summed in blocks of [`SOURCE_BLOCK`] (which stay
//! in cache) for a chunk of [`TARGET_CHUNK`] targets at a time, with the FMM's vectorised
//! point-to-point loops ([`crate::fmm::p2p`]); the chunks run on rayon's threads. Each target's
//! sum is taken by one thread in a fixed order, so the result does not depend on the number of
//! threads.
//!
//! ```
//! use mobo::vesicle::smooth_sources::SmoothSources;
//! use mobo::vesicle::{shapes, Geometry, LayerKernel, SurfaceCalculus};
//!
//! // The unit sphere at order 24 and a unit density along x.
//! let q = 24;
//! let mut g = Geometry::zeros(q);
//! SurfaceCalculus::new(q)?.update_geometry(shapes::sphere(q, 1.0)?.coefs(), &mut g)?;
//! let n = g.n_points();
//! let mut f = vec![0.0; 3 * n];
//! f[..n].fill(1.0);
//! let mut src = SmoothSources::new();
//! src.set_geometry(&g);
//! src.set_density(&f)?;
//! // Far away the single layer is a Stokeslet of the total force 4π e_x (μ = 1).
//! let x = [0.0, 0.0, 30.0];
//! let mut u = [0.0; 3];
//! src.add_to(LayerKernel::SingleLayer { viscosity: 1.0 }, &[x], &mut u)?;
//! let stokeslet = 4.0 * std::f64::consts::PI / (8.0 * std::f64::consts::PI * 30.0);
//! assert!((u[0] / stokeslet - 1.0).abs() < 1e-3);
//! // Outside a closed surface the solid angle is zero, inside one.
//! assert!(src.solid_angle(x).abs() < 1e-10);
//! assert!((src.solid_angle([0.1, 0.2, 0.0]) - 1.0).abs() < 1e-10);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use rayon::prelude::*;

use super::geometry::Geometry;
use super::layer::LayerKernel;
use super::{check_len, VesicleError};
use crate::fmm::blocks::SourceView;
use crate::fmm::p2p;

/// Sources summed together for a chunk of targets (positions, normals and densities of 2048
/// nodes: 160 kB).
pub const SOURCE_BLOCK: usize = 2048;
/// Targets one thread takes at a time.
pub const TARGET_CHUNK: usize = 32;

/// The nodes of a smooth rule with their normals and a density times the area weights.
#[derive(Clone, Debug, Default)]
pub struct SmoothSources {
    x: [Vec<f64>; 3],
    n: [Vec<f64>; 3],
    da: Vec<f64>,
    /// `f_j dA_j`, by component.
    f: [Vec<f64>; 3],
    has_density: bool,
}

impl SmoothSources {
    /// An empty block (no nodes).
    pub fn new() -> Self {
        Self::default()
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.da.len()
    }

    /// Whether there are no nodes.
    pub fn is_empty(&self) -> bool {
        self.da.is_empty()
    }

    /// Take the nodes, normals and weights of `g` (the density must be set again).
    pub fn set_geometry(&mut self, g: &Geometry) {
        let n = g.n_points();
        for c in 0..3 {
            self.x[c].clear();
            self.x[c].extend(g.x.iter().map(|x| x[c]));
            self.n[c].clear();
            self.n[c].extend(g.normal.iter().map(|x| x[c]));
            self.f[c].clear();
            self.f[c].resize(n, 0.0);
        }
        self.da.clear();
        self.da.extend_from_slice(&g.da);
        self.has_density = false;
    }

    /// Set the density at the nodes (component-major, `3 · len()`).
    pub fn set_density(&mut self, density: &[f64]) -> Result<(), VesicleError> {
        let n = self.len();
        check_len("density at the smooth rule's nodes", density.len(), 3 * n)?;
        for c in 0..3 {
            for ((f, &d), &w) in self.f[c]
                .iter_mut()
                .zip(&density[c * n..(c + 1) * n])
                .zip(&self.da)
            {
                *f = d * w;
            }
        }
        self.has_density = true;
        Ok(())
    }

    /// Add the layer potential of the density set at `targets` to `out`, three values per
    /// target in turn (`out[3t + c]`).
    pub fn add_to(
        &self,
        kernel: LayerKernel,
        targets: &[[f64; 3]],
        out: &mut [f64],
    ) -> Result<(), VesicleError> {
        kernel.check()?;
        check_len("smooth sum output", out.len(), 3 * targets.len())?;
        if !self.has_density {
            return Err(VesicleError::Missing(
                "the density at the smooth rule's nodes (SmoothSources::set_density)",
            ));
        }
        let scale = match kernel {
            LayerKernel::SingleLayer { viscosity } => 1.0 / viscosity,
            LayerKernel::DoubleLayer => 1.0,
        };
        out.par_chunks_mut(3 * TARGET_CHUNK)
            .zip(targets.par_chunks(TARGET_CHUNK))
            .for_each(|(o, t)| {
                let mut acc = [0.0; 3 * TARGET_CHUNK];
                let acc = &mut acc[..o.len()];
                self.sum_chunk(kernel, t, acc);
                for (a, b) in o.iter_mut().zip(acc.iter()) {
                    *a += scale * b;
                }
            });
        Ok(())
    }

    /// The node nearest `x`: its squared distance and index (the first of equals). A
    /// vectorised pass finds the smallest squared distance, a second the first node at it.
    pub fn nearest(&self, x: [f64; 3]) -> (f64, usize) {
        const L: usize = 8;
        let n = self.len();
        let (sx, sy, sz) = (&self.x[0][..n], &self.x[1][..n], &self.x[2][..n]);
        let d2 =
            |k: usize| (sx[k] - x[0]).powi(2) + (sy[k] - x[1]).powi(2) + (sz[k] - x[2]).powi(2);
        let mut lanes = [f64::INFINITY; L];
        let nb = n - n % L;
        let mut j = 0;
        while j < nb {
            for (l, b) in lanes.iter_mut().enumerate() {
                let v = d2(j + l);
                *b = if v < *b { v } else { *b };
            }
            j += L;
        }
        let mut best = (nb..n)
            .map(d2)
            .fold(f64::INFINITY, |b, v| if v < b { v } else { b });
        for b in lanes {
            best = if b < best { b } else { best };
        }
        let at = (0..n).position(|k| d2(k) == best).unwrap_or(0);
        (best, at)
    }

    /// The solid angle the surface subtends at `x` over 4π, `(1/4π) Σ_j (y_j − x)·n_j dA_j /
    /// |y_j − x|³` (Gauss: 1 inside a closed surface, 0 outside, up to the rule's error).
    pub fn solid_angle(&self, x: [f64; 3]) -> f64 {
        let n = self.len();
        let mut sum = 0.0;
        let mut start = 0;
        while start < n {
            let end = (start + SOURCE_BLOCK).min(n);
            let view = self.block(start..end, [&self.da[start..end], &[], &[], &[]]);
            let mut out = [0.0];
            p2p::laplace_dl(&[x], &view, &mut out);
            sum += out[0];
            start = end;
        }
        // The Laplace double layer takes r = x − y.
        -sum
    }

    /// The nodes `range` with their normals, carrying the densities `q`.
    fn block<'a>(&'a self, range: std::ops::Range<usize>, q: [&'a [f64]; 4]) -> SourceView<'a> {
        SourceView {
            x: &self.x[0][range.clone()],
            y: &self.x[1][range.clone()],
            z: &self.x[2][range.clone()],
            q,
            n: [
                &self.n[0][range.clone()],
                &self.n[1][range.clone()],
                &self.n[2][range],
            ],
        }
    }

    /// `Σ_j K(t − y_j) f_j dA_j` into `acc` (zeroed), over the nodes in blocks.
    fn sum_chunk(&self, kernel: LayerKernel, t: &[[f64; 3]], acc: &mut [f64]) {
        let n = self.len();
        let mut start = 0;
        while start < n {
            let end = (start + SOURCE_BLOCK).min(n);
            let f = &self.f;
            let view = self.block(
                start..end,
                [&f[0][start..end], &f[1][start..end], &f[2][start..end], &[]],
            );
            match kernel {
                LayerKernel::SingleLayer { .. } => p2p::stokeslet(t, &view, acc),
                LayerKernel::DoubleLayer => p2p::stresslet(t, &view, acc),
            }
            start = end;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sph_harmonics::ShTransform;
    use crate::vesicle::geometry::SurfaceCalculus;
    use crate::vesicle::shapes;

    /// The direct loop the block sums replace.
    fn naive(g: &Geometry, dens: &[f64], kernel: LayerKernel, x: [f64; 3]) -> [f64; 3] {
        let nq = g.n_points();
        let mut u = [0.0; 3];
        for j in 0..nq {
            let r: [f64; 3] = std::array::from_fn(|c| x[c] - g.x[j][c]);
            let r2: f64 = r.iter().map(|v| v * v).sum();
            let f: [f64; 3] = std::array::from_fn(|c| dens[c * nq + j]);
            let rf: f64 = (0..3).map(|c| r[c] * f[c]).sum();
            let ri = 1.0 / r2.sqrt();
            match kernel {
                LayerKernel::SingleLayer { viscosity } => {
                    for c in 0..3 {
                        u[c] += (f[c] + rf * r[c] * ri * ri) * ri * g.da[j]
                            / (8.0 * std::f64::consts::PI * viscosity);
                    }
                }
                LayerKernel::DoubleLayer => {
                    let rn: f64 = (0..3).map(|c| r[c] * g.normal[j][c]).sum();
                    for c in 0..3 {
                        u[c] += 3.0 / (4.0 * std::f64::consts::PI)
                            * rn
                            * rf
                            * r[c]
                            * ri.powi(5)
                            * g.da[j];
                    }
                }
            }
        }
        u
    }

    #[test]
    fn block_sums_agree_with_the_direct_loop() {
        // An ellipsoid at order 40 (3321 nodes: two source blocks), 70 targets (three chunks).
        let q = 40;
        let sht = ShTransform::new(q).unwrap();
        let surface = shapes::ellipsoid(q, [1.3, 0.9, 0.7]).unwrap();
        let mut g = Geometry::zeros(q);
        SurfaceCalculus::new(q)
            .unwrap()
            .update_geometry(surface.coefs(), &mut g)
            .unwrap();
        let n = sht.n_points();
        let dens: Vec<f64> = (0..3 * n)
            .map(|i| ((i as f64) * 0.37).sin() + 0.2)
            .collect();
        let targets: Vec<[f64; 3]> = (0..70)
            .map(|i| {
                let t = i as f64 * 0.41;
                let r = if i % 2 == 0 { 1.6 } else { 0.3 };
                [r * t.cos(), r * t.sin(), 0.5 * (t * 0.7).sin()]
            })
            .collect();
        let mut src = SmoothSources::new();
        src.set_geometry(&g);
        src.set_density(&dens).unwrap();
        for kernel in [
            LayerKernel::SingleLayer { viscosity: 1.7 },
            LayerKernel::DoubleLayer,
        ] {
            let mut out = vec![0.0; 3 * targets.len()];
            src.add_to(kernel, &targets, &mut out).unwrap();
            for (t, &x) in targets.iter().enumerate() {
                let u = naive(&g, &dens, kernel, x);
                let size = u.iter().map(|v| v.abs()).fold(1e-3, f64::max);
                for c in 0..3 {
                    let e = (out[3 * t + c] - u[c]).abs() / size;
                    assert!(e < 1e-12, "{kernel:?}: target {t} component {c}: {e:e}");
                }
            }
        }
        // The nearest node and the solid angle against direct loops.
        for &x in &targets {
            let d2: Vec<f64> =
                g.x.iter()
                    .map(|y| (0..3).map(|c| (y[c] - x[c]).powi(2)).sum())
                    .collect();
            let (b, j) = src.nearest(x);
            let first = d2.iter().position(|v| *v == b).unwrap();
            assert_eq!((b, j), (d2[j], first));
            assert!(d2.iter().all(|v| *v >= b));
            let solid: f64 = (0..g.n_points())
                .map(|k| {
                    let r: [f64; 3] = std::array::from_fn(|c| g.x[k][c] - x[c]);
                    let rr: f64 = r.iter().map(|v| v * v).sum();
                    (0..3).map(|c| r[c] * g.normal[k][c]).sum::<f64>() * g.da[k] / (rr * rr.sqrt())
                })
                .sum::<f64>()
                / (4.0 * std::f64::consts::PI);
            assert!((src.solid_angle(x) - solid).abs() < 1e-12, "{x:?}");
            // Gauss: the points at radius 0.3 are inside the ellipsoid, those at 1.6 outside.
            let inside = x[0].hypot(x[1]) < 1.0;
            assert!(
                (solid - if inside { 1.0 } else { 0.0 }).abs() < 1e-6,
                "{x:?}: {solid}"
            );
        }
        // Without a density: an error, not a sum of zeros.
        let mut bare = SmoothSources::new();
        bare.set_geometry(&g);
        let mut out = vec![0.0; 3];
        assert!(bare
            .add_to(LayerKernel::DoubleLayer, &targets[..1], &mut out)
            .is_err());
    }
}

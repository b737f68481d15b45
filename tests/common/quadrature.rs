//! A direct smooth quadrature of the single (or double) layer of several cells at each other's
//! grid points:
//! the independent reference of the inter-cell coupling (fine enough, it is accurate at small
//! gaps too: the error of the smooth rule falls like `exp(−2π d/h)` at distance `d`, spacing `h`).

use std::f64::consts::PI;

use mobo::sph_harmonics::ShTransform;
use mobo::vesicle::membrane::Membrane;

/// The kernel of [`reference_layer`], written out here independently of the library's.
#[derive(Clone, Copy)]
pub enum Kernel {
    /// Single layer `(1/8πμ) (I/r + r⊗r/r³) f`.
    Stokeslet { viscosity: f64 },
    /// Double layer `(3/4π) (r·n)(r⊗r)/r⁵ u`.
    Stresslet,
}

/// `Σ_{j≠i} S_j[f_j]` at cell `i`'s grid points by the smooth quadrature of order `big_q`.
pub fn reference(
    p: usize,
    big_q: usize,
    coefs: &[Vec<f64>],
    f: &[Vec<f64>],
    mu: f64,
) -> Vec<Vec<f64>> {
    reference_layer(p, big_q, coefs, f, Kernel::Stokeslet { viscosity: mu })
}

/// `Σ_{j≠i} K_j[f_j]` at cell `i`'s grid points by the smooth quadrature of order `big_q`, for
/// the single or the double layer.
pub fn reference_layer(
    p: usize,
    big_q: usize,
    coefs: &[Vec<f64>],
    f: &[Vec<f64>],
    kernel: Kernel,
) -> Vec<Vec<f64>> {
    let sht = ShTransform::new(p).unwrap();
    let n = sht.n_points();
    let mut mem = Membrane::new(p, big_q).unwrap();
    let nq = mem.n_points_upsampled();
    // Per cell: quadrature points, outward normals and weighted densities.
    type Quadrature = (Vec<[f64; 3]>, Vec<[f64; 3]>, Vec<[f64; 3]>);
    let mut src: Vec<Quadrature> = Vec::new();
    for (c, fc) in coefs.iter().zip(f) {
        mem.set_geometry(c).unwrap();
        let mut fq = vec![0.0; 3 * nq];
        mem.upsample(fc, &mut fq).unwrap();
        let g = mem.geometry().unwrap();
        let w: Vec<[f64; 3]> = (0..nq)
            .map(|k| std::array::from_fn(|d| fq[d * nq + k] * g.da[k]))
            .collect();
        src.push((g.x.clone(), g.normal.clone(), w));
    }
    coefs
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let mut x = vec![0.0; 3 * n];
            sht.inverse(c, &mut x, &mut sht.workspace()).unwrap();
            let mut u = vec![0.0; 3 * n];
            for t in 0..n {
                let xt = [x[t], x[n + t], x[2 * n + t]];
                let mut acc = [0.0; 3];
                for (j, (ys, ns, ws)) in src.iter().enumerate() {
                    if j == i {
                        continue;
                    }
                    for ((y, nv), w) in ys.iter().zip(ns).zip(ws) {
                        let r = [xt[0] - y[0], xt[1] - y[1], xt[2] - y[2]];
                        let r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
                        let ri = 1.0 / r2.sqrt();
                        let rw = r[0] * w[0] + r[1] * w[1] + r[2] * w[2];
                        match kernel {
                            Kernel::Stokeslet { .. } => {
                                let rw3 = rw * ri * ri * ri;
                                for d in 0..3 {
                                    acc[d] += w[d] * ri + rw3 * r[d];
                                }
                            }
                            Kernel::Stresslet => {
                                let rn = r[0] * nv[0] + r[1] * nv[1] + r[2] * nv[2];
                                let s = rn * rw * ri.powi(5);
                                for d in 0..3 {
                                    acc[d] += s * r[d];
                                }
                            }
                        }
                    }
                }
                let scale = match kernel {
                    Kernel::Stokeslet { viscosity } => 1.0 / (8.0 * PI * viscosity),
                    Kernel::Stresslet => 3.0 / (4.0 * PI),
                };
                for d in 0..3 {
                    u[d * n + t] = acc[d] * scale;
                }
            }
            u
        })
        .collect()
}

/// Largest difference relative to the largest value of `b`.
pub fn max_rel(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    let scale = b.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    a.iter()
        .flatten()
        .zip(b.iter().flatten())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
        / scale
}

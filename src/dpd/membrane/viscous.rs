//! Membrane viscosity: the dissipative and random edge forces of Fedosov (2010, eqs. 12–13),
//! [`Membrane::add_viscous_forces`], with their counter-based random numbers (the fluid's
//! [`crate::dpd::rng`] finaliser and unit-variance map, keyed on the edge).

use super::super::rng::{mix64, unit_variance};
use super::super::{require, DpdError};
use super::energy::{check_len, Membrane};
use super::geometry::{add_to, dot, norm, scale, sub};

// ---------------------------------------------------------------------------------------------
// Random numbers for the membrane viscosity.

/// SplitMix64 (Steele, Lea & Flood 2014): the golden-ratio increment, then the finaliser
/// shared with the fluid's pair noise ([`crate::dpd::rng::mix64`]).
#[inline]
fn splitmix64(z: u64) -> u64 {
    mix64(z.wrapping_add(0x9E37_79B9_7F4A_7C15))
}

/// Uniform number of zero mean and unit variance (on `[−√3, √3)`), a pure function of
/// `(seed, step, edge, component)`.
#[inline]
pub(super) fn noise(seed: u64, step: u64, edge: usize, component: u64) -> f64 {
    unit_variance(splitmix64(
        splitmix64(splitmix64(seed ^ 0x6D65_6D62_7261_6E65).wrapping_add(step))
            .wrapping_add(((edge as u64) << 4) | component),
    ))
}

impl Membrane {
    /// Viscous force on vertex `i` of edge `[i, j]` (`amp = √(2k_BT/dt)`, 0 for no noise).
    #[inline]
    fn edge_viscous_force(
        &self,
        edge: usize,
        x: &[[f64; 3]],
        v: &[[f64; 3]],
        step: u64,
        seed: u64,
        amp: f64,
    ) -> [f64; 3] {
        let p = self.params();
        let [i, j] = self.topology().edges[edge];
        let d = sub(x[i], x[j]);
        let e = scale(d, 1.0 / norm(d));
        let vij = sub(v[i], v[j]);
        let mut fi = scale(vij, -p.gamma_t);
        add_to(&mut fi, e, -p.gamma_c * dot(vij, e));
        if amp > 0.0 {
            let at = amp * (2.0 * p.gamma_t).sqrt();
            let ac = amp * (3.0 * p.gamma_c - p.gamma_t).max(0.0).sqrt();
            let mut w = [[0.0; 3]; 3];
            for (a, row) in w.iter_mut().enumerate() {
                for (b, wab) in row.iter_mut().enumerate() {
                    *wab = noise(seed, step, edge, (3 * a + b) as u64);
                }
            }
            let tr3 = (w[0][0] + w[1][1] + w[2][2]) / 3.0;
            for (a, fa) in fi.iter_mut().enumerate() {
                // (dW^S e)_a = Σ_b (½(W_ab + W_ba) − tr/3 δ_ab) e_b.
                let mut s = -tr3 * e[a];
                for b in 0..3 {
                    s += 0.5 * (w[a][b] + w[b][a]) * e[b];
                }
                *fa += at * s + ac * tr3 * e[a];
            }
        }
        fi
    }

    /// Add the membrane-viscosity forces (dissipative and random, see the
    /// [module documentation](super)) of velocities `v` at positions `x` to `f`, for time step
    /// `dt` and step number `step`.
    ///
    /// The random part (present when `k_BT > 0`) is a pure function of `(seed, step, edge)`;
    /// every pair force enters `f_i` and `−f_j`.
    pub fn add_viscous_forces(
        &self,
        x: &[[f64; 3]],
        v: &[[f64; 3]],
        step: u64,
        seed: u64,
        dt: f64,
        f: &mut [[f64; 3]],
    ) -> Result<(), DpdError> {
        let n = self.n_vertices();
        check_len("positions", x.len(), n)?;
        check_len("velocities", v.len(), n)?;
        check_len("forces", f.len(), n)?;
        let p = self.params();
        let random = p.kbt > 0.0 && (p.gamma_t > 0.0 || p.gamma_c > 0.0);
        if random {
            require(
                dt > 0.0 && dt.is_finite(),
                "dt",
                dt,
                "must be positive and finite",
            )?;
        }
        let amp = if random {
            (2.0 * p.kbt / dt).sqrt()
        } else {
            0.0
        };
        for (edge, &[i, j]) in self.topology().edges.iter().enumerate() {
            let fi = self.edge_viscous_force(edge, x, v, step, seed, amp);
            add_to(&mut f[i], fi, 1.0);
            add_to(&mut f[j], fi, -1.0);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dpd::membrane::test_support::{full_params, icosphere};
    use crate::dpd::membrane::{Bending, MembraneTopology};

    #[test]
    fn viscous_noise_has_the_fdt_covariance() {
        let (x, t) = icosphere(0);
        let topo = MembraneTopology::new(x.len(), &t).unwrap();
        let mut params = full_params(Bending::None);
        params.kbt = 0.7;
        params.gamma_t = 2.0;
        params.gamma_c = 5.0;
        let m = Membrane::new(topo, params, &x).unwrap();
        let v = vec![[0.0; 3]; x.len()];
        let dt = 0.01;
        let [i, j] = m.topology().edges()[0];
        let d = sub(x[i], x[j]);
        let e = scale(d, 1.0 / norm(d));
        let n = 40_000;
        let mut cov = [[0.0; 3]; 3];
        let mut f = vec![[0.0; 3]; x.len()];
        let amp = (2.0 * params.kbt / dt).sqrt();
        for step in 0..n {
            f.iter_mut().for_each(|q| *q = [0.0; 3]);
            m.add_viscous_forces(&x, &v, step, 11, dt, &mut f).unwrap();
            let sum = f
                .iter()
                .fold([0.0; 3], |s, q| [s[0] + q[0], s[1] + q[1], s[2] + q[2]]);
            assert!(norm(sum) < 1e-10 * amp);
            let fi = m.edge_viscous_force(0, &x, &v, step, 11, amp);
            for a in 0..3 {
                for b in 0..3 {
                    cov[a][b] += fi[a] * fi[b] / n as f64;
                }
            }
        }
        let scale_ = 2.0 * params.kbt / dt;
        for a in 0..3 {
            for b in 0..3 {
                let delta = if a == b { 1.0 } else { 0.0 };
                let want = scale_ * (params.gamma_t * delta + params.gamma_c * e[a] * e[b]);
                assert!(
                    (cov[a][b] - want).abs() < 0.04 * scale_ * (params.gamma_t + params.gamma_c),
                    "cov[{a}][{b}] = {} want {want}",
                    cov[a][b]
                );
            }
        }
    }

    #[test]
    fn noise_is_uniform_with_unit_variance() {
        let n = 100_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for k in 0..n {
            let r = noise(3, k as u64, 17, 2);
            assert!(r.abs() <= 3f64.sqrt());
            s += r;
            s2 += r * r;
        }
        assert!((s / n as f64).abs() < 0.01);
        assert!((s2 / n as f64 - 1.0).abs() < 0.01);
        assert_ne!(noise(3, 0, 17, 2), noise(3, 0, 17, 3));
        assert_ne!(noise(3, 0, 17, 2), noise(4, 0, 17, 2));
    }
}

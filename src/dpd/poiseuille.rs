//! Viscosity from the periodic (reverse) Poiseuille flow, and the kinetic-theory estimate it
//! is compared with.
//!
//! # Measurement (Backer, Lowe, Hoefsloot & Iedema 2005)
//! The body force `+g x̂` on particles with `z < L_z/2` and `−g x̂` on the others drives two
//! counter-flowing Poiseuille flows whose planes of symmetry `z = 0, L_z/2` are planes of zero
//! velocity. With `n` the number density and `η` the dynamic viscosity, the steady profile is
//!
//! ```text
//! u_x(z) = (n g / 2η) φ(z),   φ(z) = z (L_z/2 − z) for z < L_z/2,  −(z − L_z/2)(L_z − z) else.
//! ```
//!
//! The profile (binned in `z`, averaged per block of samples, the upper half folded onto the
//! lower) is fitted by least squares with `u = A + C ζ²`, `ζ = z − L_z/4`, on the middle
//! [`FIT_WINDOW`] of each half (see [`ProfileSampler::viscosity`]), `η = −n g / 2C`; the
//! standard error comes from the spread of `C` over the blocks (block averaging).
//!
//! # Kinetic theory (Marsh 1998; Groot & Warren 1997)
//! For `w_D = w^{2k}`, `w = 1 − r/r_c`:
//!
//! ```text
//! η_K = m n D / 2,  D = 3 k_BT / (γ n ∫ w_D d³r),  ∫ w_D d³r = 8π r_c³ / ((2k+1)(2k+2)(2k+3)),
//! η_D = (2π γ n² / 15) ∫₀^{r_c} r⁴ w_D dr = (2π γ n² r_c⁵ / 15) · 24 / Π_{m=1..5}(2k+m).
//! ```
//!
//! (`k = 1`: `D = 45 k_BT / 2πγn r_c³`, `η_D = 2πγn² r_c⁵/1575`, Groot & Warren's eq. 32.)
//! The estimate ignores the conservative force and correlations: measured viscosities differ
//! from it by 10–30 % at the usual parameters (Marsh, Backer et al.); `docs/dpd_validation.md`
//! states the deviation measured here.

use serde::Serialize;

use super::system::DpdSystem;

/// The kinetic-theory viscosity and its two parts.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct KineticViscosity {
    /// Kinetic (momentum carried by particles) part `η_K`.
    pub kinetic: f64,
    /// Dissipative (momentum passed by the dissipative force) part `η_D`.
    pub dissipative: f64,
    /// `η_K + η_D`.
    pub total: f64,
}

/// The kinetic-theory estimate of the dynamic viscosity (see the module docs).
pub fn kinetic_theory_viscosity(
    density: f64,
    gamma: f64,
    kbt: f64,
    rc: f64,
    power: f64,
    mass: f64,
) -> KineticViscosity {
    let k2 = 2.0 * power;
    let int_wd = 8.0 * std::f64::consts::PI * rc.powi(3) / ((k2 + 1.0) * (k2 + 2.0) * (k2 + 3.0));
    let d = 3.0 * kbt / (gamma * density * int_wd);
    let kinetic = mass * density * d / 2.0;
    let prod: f64 = (1..=5).map(|m| k2 + m as f64).product();
    let dissipative =
        2.0 * std::f64::consts::PI * gamma * density * density * rc.powi(5) / 15.0 * 24.0 / prod;
    KineticViscosity {
        kinetic,
        dissipative,
        total: kinetic + dissipative,
    }
}

/// Velocity and density profiles along `z`, sampled every few steps and averaged per block.
#[derive(Clone, Debug)]
pub struct ProfileSampler {
    /// Number of bins (even, so no bin straddles `L_z/2`).
    pub bins: usize,
    /// The flow's geometry (what is binned, what is fitted).
    pub geometry: FlowGeometry,
    /// The binned range: `[0, L_z)` along `z`, or `[0, R]` in radius for a pipe.
    lz: f64,
    box_len: [f64; 3],
    /// Per bin, current block: `Σ v_x`, particle count.
    sum_v: Vec<f64>,
    count: Vec<u64>,
    samples_in_block: usize,
    /// Samples per block.
    pub block_samples: usize,
    /// Completed blocks: mean `v_x` per bin.
    pub blocks: Vec<Vec<f64>>,
    /// Over all samples: `Σ v_x` and counts per bin.
    total_v: Vec<f64>,
    total_count: Vec<u64>,
    /// Samples taken.
    pub samples: usize,
}

/// The fitted viscosity with its standard error.
#[derive(Clone, Debug, Serialize)]
pub struct ViscosityFit {
    /// `η = −n g / 2C` (`−n g / 4C` in a pipe).
    pub value: f64,
    /// Standard error from the block spread of `C`.
    pub stderr: f64,
    /// The fitted `A` of `u = ±(A + C ζ²)` (`ζ` the distance from the middle of a
    /// half-channel, the channel's mid-plane, or the pipe's axis; mean over the blocks).
    pub offset: f64,
    /// The fitted `C` of `u = ±(A + C ζ²)` (mean over the blocks).
    pub curvature: f64,
    /// The fraction of each half's width fitted (centred; the rest, next to the planes where
    /// the force changes sign, is left out).
    pub window: f64,
    /// Blocks averaged over.
    pub blocks: usize,
    /// Samples (one every `sample_every` steps) in all blocks.
    pub samples: usize,
}

/// The geometry of a pressure-driven flow whose profile gives the viscosity.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum FlowGeometry {
    /// Periodic (reverse) Poiseuille: `±g` in the two halves of the box in `z`.
    Periodic,
    /// Plane Poiseuille between walls at `z = lo, hi`: `u = (n g/2η)(z − lo)(hi − z)` with
    /// no slip; binned in `z`.
    Channel {
        /// The lower wall's `z`.
        lo: f64,
        /// The upper wall's `z`.
        hi: f64,
    },
    /// Pipe of radius `R` along `x` around `(y, z) = center`: `u = (n g/4η)(R² − r²)`;
    /// binned in `r`.
    Pipe {
        /// The axis's `(y, z)`.
        center: [f64; 2],
        /// The radius `R`.
        radius: f64,
    },
}

impl ProfileSampler {
    /// A sampler of the periodic Poiseuille profile in a box of height `lz`, with `bins` bins
    /// (rounded up to even) and `block_samples` samples per block.
    pub fn new(lz: f64, bins: usize, block_samples: usize) -> Self {
        Self::with_geometry(FlowGeometry::Periodic, [1.0, 1.0, lz], bins, block_samples)
    }

    /// A sampler of the profile of `geometry` in a box of side `box_len`.
    pub fn with_geometry(
        geometry: FlowGeometry,
        box_len: [f64; 3],
        bins: usize,
        block_samples: usize,
    ) -> Self {
        let bins = bins.max(2).div_ceil(2) * 2;
        let lz = match geometry {
            FlowGeometry::Pipe { radius, .. } => radius,
            _ => box_len[2],
        };
        ProfileSampler {
            bins,
            geometry,
            lz,
            box_len,
            sum_v: vec![0.0; bins],
            count: vec![0; bins],
            samples_in_block: 0,
            block_samples: block_samples.max(1),
            blocks: Vec::new(),
            total_v: vec![0.0; bins],
            total_count: vec![0; bins],
            samples: 0,
        }
    }

    /// Add the current state.
    pub fn sample(&mut self, sys: &DpdSystem) {
        let p = &sys.particles;
        let moving = (0..p.len()).filter(|&i| p.moves[i] != 0.0);
        let geometry = self.geometry;
        self.add_sample(moving.map(|i| (coordinate(geometry, p.y[i], p.z[i]), p.vx[i])));
    }

    /// Add a sample binned elsewhere (the GPU's, `crate::gpu::dpd_profile`): per bin `Σ v_x`
    /// and the count of moving particles, binned as [`Self::sample`] bins, with
    /// [`Self::bin_scale`] bins per unit of the coordinate. `None` (nothing added) if the
    /// lengths are not [`Self::bins`].
    pub fn add_binned(&mut self, sum_v: &[f64], count: &[u64]) -> Option<()> {
        if sum_v.len() != self.bins || count.len() != self.bins {
            return None;
        }
        for b in 0..self.bins {
            self.sum_v[b] += sum_v[b];
            self.count[b] += count[b];
        }
        self.end_sample();
        Some(())
    }

    /// Bins per unit of the binned coordinate (`z`, or the radius in a pipe): a particle at
    /// `c` falls in bin `min(⌊c · bin_scale⌋, bins − 1)`.
    pub fn bin_scale(&self) -> f64 {
        self.bins as f64 / self.lz
    }

    /// Add one sample: the binned coordinate and `v_x` of each particle.
    fn add_sample(&mut self, points: impl Iterator<Item = (f64, f64)>) {
        let scale = self.bin_scale();
        for (coord, vx) in points {
            let b = ((coord * scale) as usize).min(self.bins - 1);
            self.sum_v[b] += vx;
            self.count[b] += 1;
        }
        self.end_sample();
    }

    /// Count a sample, and close the block when it is full.
    fn end_sample(&mut self) {
        self.samples += 1;
        self.samples_in_block += 1;
        if self.samples_in_block == self.block_samples {
            let mean: Vec<f64> = self
                .sum_v
                .iter()
                .zip(&self.count)
                .map(|(s, &c)| if c > 0 { s / c as f64 } else { 0.0 })
                .collect();
            self.blocks.push(mean);
            for b in 0..self.bins {
                self.total_v[b] += self.sum_v[b];
                self.total_count[b] += self.count[b];
            }
            self.sum_v.iter_mut().for_each(|s| *s = 0.0);
            self.count.iter_mut().for_each(|c| *c = 0);
            self.samples_in_block = 0;
        }
    }

    /// The sampler's whole state as numbers (for checkpoints) and its shape:
    /// `[bins, block_samples, samples_in_block, samples, blocks]`, then per bin the current
    /// block's `Σ v_x` and counts, the totals' `Σ v_x` and counts, then the blocks' profiles.
    pub fn state(&self) -> (Vec<f64>, Vec<usize>) {
        let mut v = vec![
            self.bins as f64,
            self.block_samples as f64,
            self.samples_in_block as f64,
            self.samples as f64,
            self.blocks.len() as f64,
        ];
        v.extend(&self.sum_v);
        v.extend(self.count.iter().map(|&c| c as f64));
        v.extend(&self.total_v);
        v.extend(self.total_count.iter().map(|&c| c as f64));
        for b in &self.blocks {
            v.extend(b);
        }
        let len = v.len();
        (v, vec![len])
    }

    /// The sampler back from [`Self::state`] (`None` if the numbers do not form a state).
    pub fn from_state(
        geometry: FlowGeometry,
        box_len: [f64; 3],
        v: &[f64],
        shape: &[usize],
    ) -> Option<Self> {
        if shape != [v.len()]
            || v.len() < 5
            || v[..5].iter().any(|x| !(*x >= 0.0 && x.fract() == 0.0))
        {
            return None;
        }
        let [bins, block_samples, in_block, samples, nblocks] =
            [v[0], v[1], v[2], v[3], v[4]].map(|x| x as usize);
        if bins < 2 || v.len() != 5 + 4 * bins + nblocks.checked_mul(bins)? {
            return None;
        }
        let part = |k: usize| &v[5 + k * bins..5 + (k + 1) * bins];
        let counts = |k: usize| part(k).iter().map(|&c| c as u64).collect::<Vec<u64>>();
        let empty = Self::with_geometry(geometry, box_len, bins, block_samples);
        if empty.bins != bins {
            return None;
        }
        Some(ProfileSampler {
            bins,
            geometry,
            lz: empty.lz,
            box_len,
            sum_v: part(0).to_vec(),
            count: counts(1),
            samples_in_block: in_block,
            block_samples: block_samples.max(1),
            blocks: v[5 + 4 * bins..]
                .chunks_exact(bins)
                .map(|b| b.to_vec())
                .collect(),
            total_v: part(2).to_vec(),
            total_count: counts(3),
            samples,
        })
    }

    /// Bin edges `(z0, z1)`.
    pub fn bin(&self, b: usize) -> (f64, f64) {
        let h = self.lz / self.bins as f64;
        (b as f64 * h, (b + 1) as f64 * h)
    }

    /// The profile over the completed blocks: per bin `(centre, mean v_x, number density)`
    /// (`z` bins, or radial shells for a pipe).
    pub fn profile(&self) -> Vec<(f64, f64, f64)> {
        let nblocks = self.blocks.len().max(1) as f64;
        let l = self.box_len;
        (0..self.bins)
            .map(|b| {
                let (z0, z1) = self.bin(b);
                let v = if self.total_count[b] > 0 {
                    self.total_v[b] / self.total_count[b] as f64
                } else {
                    0.0
                };
                let samples = nblocks * self.block_samples as f64;
                let volume = match self.geometry {
                    FlowGeometry::Pipe { .. } => l[0] * std::f64::consts::PI * (z1 * z1 - z0 * z0),
                    _ => l[0] * l[1] * (z1 - z0),
                };
                (
                    0.5 * (z0 + z1),
                    v,
                    self.total_count[b] as f64 / (samples * volume),
                )
            })
            .collect()
    }

    /// The kinetic temperature of the mean flow, `m ⟨u_x²⟩ / 3` over the sampled particles
    /// (`u_x` the bin means): what a driven flow adds to the kinetic temperature of all
    /// velocities. `None` before any block is complete.
    pub fn flow_temperature(&self, mass: f64) -> Option<f64> {
        let n: u64 = self.total_count.iter().sum();
        if n == 0 {
            return None;
        }
        let s: f64 = self
            .total_v
            .iter()
            .zip(&self.total_count)
            .filter(|(_, &c)| c > 0)
            .map(|(v, &c)| v * v / c as f64)
            .sum();
        Some(mass * s / (3.0 * n as f64))
    }

    /// The viscosity fitted to the blocks (`None` with fewer than two blocks).
    ///
    /// Between walls (channel, pipe) the parabola `u = A + C ζ²` is fitted to the middle
    /// [`FIT_WINDOW`] of the channel (the layers next to the walls, with their density
    /// oscillations and slip, are left out): `η = −n g / 2C`, or `−n g / 4C` in a pipe. For the
    /// periodic flow:
    ///
    /// The upper half is folded onto the lower (`u → −u`), `ζ = z − L_z/4` is the distance
    /// from the middle of a half, and `u = A + C ζ²` is fitted by least squares to the bins
    /// whose centre lies within [`FIT_WINDOW`] of each half's width around its middle, with
    /// the bin averages of `ζ²`; `η = −n g / 2C`. The planes where the force changes sign are
    /// left out: there the profile is not a parabola (momentum diffuses across them over a
    /// few mean free paths, rounding the cusp), and fitting through them biases `η` upwards
    /// (measured for an ideal DPD gas at `ρ = 3, γ = 4.5`: 1.41 times the kinetic-theory
    /// estimate fitting the whole profile, 1.35 with the window; the rest of that gap is the
    /// estimate's, docs/dpd_validation.md).
    pub fn viscosity(&self, density: f64, force: f64) -> Option<ViscosityFit> {
        let nb = self.blocks.len();
        if nb < 2 {
            return None;
        }
        let quarter = 0.25 * self.lz;
        let bins: Vec<(usize, f64, f64)> = (0..self.bins)
            .filter_map(|b| {
                let (sign, in_window, x) = self.abscissa(b);
                in_window.then_some((b, sign, x))
            })
            .collect();
        let factor = match self.geometry {
            FlowGeometry::Pipe { .. } => 4.0,
            _ => 2.0,
        };
        // At least two distinct bin averages of ζ² per fit (else the curvature is undefined).
        let z2 = bins.first()?.2;
        if !bins
            .iter()
            .any(|b| (b.2 - z2).abs() > 1e-9 * quarter * quarter)
        {
            return None;
        }
        let fits: Vec<(f64, f64)> = self
            .blocks
            .iter()
            .map(|u| {
                // Each bin weighted by the particles it held (radial shells of a pipe differ
                // in volume, so their means differ in noise).
                let pts: Vec<(f64, f64, f64)> = bins
                    .iter()
                    .map(|&(b, s, z2)| (z2, s * u[b], self.total_count[b] as f64))
                    .collect();
                fit_line(&pts)
            })
            .collect();
        let mean_a = fits.iter().map(|f| f.0).sum::<f64>() / nb as f64;
        let mean = fits.iter().map(|f| f.1).sum::<f64>() / nb as f64;
        let var = fits.iter().map(|f| (f.1 - mean).powi(2)).sum::<f64>() / (nb - 1) as f64;
        let se_c = (var / nb as f64).sqrt();
        let value = -density * force / (factor * mean);
        Some(ViscosityFit {
            value,
            stderr: value.abs() * se_c / mean.abs(),
            offset: mean_a,
            curvature: mean,
            window: FIT_WINDOW,
            blocks: nb,
            samples: nb * self.block_samples,
        })
    }

    /// The fitted profile `±(A + C ζ²)` averaged over bin `b` (for plotting).
    pub fn fitted(&self, fit: &ViscosityFit, b: usize) -> f64 {
        let (sign, _, x) = self.abscissa(b);
        sign * (fit.offset + fit.curvature * x)
    }

    /// What bin `b` contributes to the fit `u = ±(A + C x)`: the sign of the flow there (the
    /// upper half of the periodic flow is folded onto the lower), whether the bin centre is in
    /// the fitted window ([`FIT_WINDOW`]), and `x`, the bin average of `ζ²` (`ζ = z − L_z/4`
    /// after folding, or `z` − the channel's mid-plane) or, in a pipe, of `r²` over the shell.
    fn abscissa(&self, b: usize) -> (f64, bool, f64) {
        let (z0, z1) = self.bin(b);
        // Average of ζ² over [a, c], and the window test on the centre.
        let square = |a: f64, c: f64, half_width: f64| {
            (
                (0.5 * (a + c)).abs() <= FIT_WINDOW * half_width,
                (c * c * c - a * a * a) / (3.0 * (c - a)),
            )
        };
        match self.geometry {
            FlowGeometry::Periodic => {
                let (quarter, half) = (0.25 * self.lz, 0.5 * self.lz);
                let (sign, off) = if z1 <= half + 1e-12 * self.lz {
                    (1.0, 0.0)
                } else {
                    (-1.0, half)
                };
                let (inside, x) = square(z0 - off - quarter, z1 - off - quarter, quarter);
                (sign, inside, x)
            }
            FlowGeometry::Channel { lo, hi } => {
                let mid = 0.5 * (lo + hi);
                let (inside, x) = square(z0 - mid, z1 - mid, 0.5 * (hi - lo));
                (1.0, inside, x)
            }
            FlowGeometry::Pipe { radius, .. } => (
                1.0,
                0.5 * (z0 + z1) <= FIT_WINDOW * radius,
                (z1.powi(4) - z0.powi(4)) / (2.0 * (z1 * z1 - z0 * z0)),
            ),
        }
    }
}

/// The fraction of each half of the periodic Poiseuille profile used in the fit (centred).
pub const FIT_WINDOW: f64 = 0.7;

/// Weighted least-squares line `y = a + c x` through the points `(x, y, weight)`; returns
/// `(a, c)`.
pub fn fit_line(pts: &[(f64, f64, f64)]) -> (f64, f64) {
    let w: f64 = pts.iter().map(|p| p.2).sum();
    let mx = pts.iter().map(|p| p.2 * p.0).sum::<f64>() / w;
    let my = pts.iter().map(|p| p.2 * p.1).sum::<f64>() / w;
    let sxx: f64 = pts.iter().map(|p| p.2 * (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| p.2 * (p.0 - mx) * (p.1 - my)).sum();
    let c = sxy / sxx;
    (my - c * mx, c)
}

/// The coordinate a profile is binned along: `z`, or the distance from a pipe's axis.
#[inline]
fn coordinate(geometry: FlowGeometry, y: f64, z: f64) -> f64 {
    match geometry {
        FlowGeometry::Pipe { center, .. } => {
            let (dy, dz) = (y - center[0], z - center[1]);
            (dy * dy + dz * dz).sqrt()
        }
        _ => z,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kinetic_estimate_matches_groot_warren_for_k1() {
        // Groot & Warren eq. 32 with n = 3, γ = 4.5, k_BT = 1, r_c = 1.
        let v = kinetic_theory_viscosity(3.0, 4.5, 1.0, 1.0, 1.0, 1.0);
        let d = 45.0 / (2.0 * std::f64::consts::PI * 4.5 * 3.0);
        let want_k = 3.0 * d / 2.0;
        let want_d = 2.0 * std::f64::consts::PI * 4.5 * 9.0 / 1575.0;
        assert!((v.kinetic - want_k).abs() < 1e-12 * want_k);
        assert!((v.dissipative - want_d).abs() < 1e-12 * want_d);
    }

    #[test]
    fn kinetic_estimate_integrals_match_quadrature_for_any_k() {
        // ∫ w_D d³r and ∫ r⁴ w_D dr by the midpoint rule against the closed forms.
        for k in [0.25, 0.5, 1.0, 2.0] {
            let m = 200_000;
            let h = 1.0 / m as f64;
            let (mut i2, mut i4) = (0.0, 0.0);
            for q in 0..m {
                let r = (q as f64 + 0.5) * h;
                let wd = (1.0 - r).powf(2.0 * k);
                i2 += 4.0 * std::f64::consts::PI * r * r * wd * h;
                i4 += r.powi(4) * wd * h;
            }
            let (n, g) = (3.0, 4.5);
            let v = kinetic_theory_viscosity(n, g, 1.0, 1.0, k, 1.0);
            let want_k = n * (3.0 / (g * n * i2)) / 2.0;
            let want_d = 2.0 * std::f64::consts::PI * g * n * n / 15.0 * i4;
            assert!((v.kinetic / want_k - 1.0).abs() < 1e-6, "k = {k}");
            assert!((v.dissipative / want_d - 1.0).abs() < 1e-6, "k = {k}");
        }
    }

    #[test]
    fn fit_recovers_an_exact_profile() {
        let lz = 10.0;
        let bins = 20;
        let h = lz / bins as f64;
        // Bin averages of the exact profile by fine quadrature.
        let c = 0.37;
        let u: Vec<f64> = (0..bins)
            .map(|b| {
                let m = 1000;
                (0..m)
                    .map(|q| {
                        let z = b as f64 * h + (q as f64 + 0.5) * h / m as f64;
                        let f = if z < lz / 2.0 {
                            z * (lz / 2.0 - z)
                        } else {
                            -(z - lz / 2.0) * (lz - z)
                        };
                        c * f / m as f64
                    })
                    .sum()
            })
            .collect();
        // The windowed parabola fit of the sampler: η = n g / 2c for this profile.
        let mut sampler = ProfileSampler::new(lz, bins, 1);
        sampler.blocks = vec![u.clone(), u.iter().map(|v| v * 1.0000001).collect()];
        sampler.total_count = vec![100; bins];
        let (n, g) = (3.0, 0.2);
        let fit = sampler.viscosity(n, g).unwrap();
        let want = n * g / (2.0 * c);
        assert!(
            (fit.value / want - 1.0).abs() < 1e-6,
            "{} vs {want}",
            fit.value
        );
        for (b, ub) in u.iter().enumerate() {
            assert!((sampler.fitted(&fit, b) - ub).abs() < 1e-6 * c, "bin {b}");
        }
    }

    /// The exact no-slip profiles between walls (bin averages by quadrature; radial shells
    /// weighted by r) give back η: channel `u = (n g/2η)(z − lo)(hi − z)`, pipe
    /// `u = (n g/4η)(R² − r²)`.
    #[test]
    fn fit_recovers_exact_channel_and_pipe_profiles() {
        let (n, g, eta) = (3.0, 0.05, 0.9);
        let cases = [
            (
                FlowGeometry::Channel { lo: 1.0, hi: 9.0 },
                [4.0, 4.0, 10.0],
                Box::new(|z: f64| n * g / (2.0 * eta) * ((z - 1.0) * (9.0 - z)).max(0.0))
                    as Box<dyn Fn(f64) -> f64>,
                false,
            ),
            (
                FlowGeometry::Pipe {
                    center: [5.0, 5.0],
                    radius: 4.0,
                },
                [4.0, 10.0, 10.0],
                Box::new(|r: f64| n * g / (4.0 * eta) * (16.0 - r * r)),
                true,
            ),
        ];
        for (geometry, box_len, exact, radial) in cases {
            let mut sampler = ProfileSampler::with_geometry(geometry, box_len, 20, 1);
            let u: Vec<f64> = (0..sampler.bins)
                .map(|b| {
                    let (z0, z1) = sampler.bin(b);
                    let m = 2000;
                    let (mut s, mut w) = (0.0, 0.0);
                    for q in 0..m {
                        let z = z0 + (q as f64 + 0.5) * (z1 - z0) / m as f64;
                        let weight = if radial { z } else { 1.0 };
                        s += weight * exact(z);
                        w += weight;
                    }
                    s / w
                })
                .collect();
            sampler.blocks = vec![u.clone(), u.iter().map(|v| v * 1.0000001).collect()];
            sampler.total_count = vec![100; sampler.bins];
            let fit = sampler.viscosity(n, g).unwrap();
            assert!(
                (fit.value / eta - 1.0).abs() < 1e-6,
                "{geometry:?}: {}",
                fit.value
            );
            let (b, _) = (0..sampler.bins)
                .map(|b| (b, sampler.bin(b)))
                .find(|(_, (z0, _))| *z0 >= if radial { 0.0 } else { 3.0 })
                .unwrap();
            assert!((sampler.fitted(&fit, b) - u[b]).abs() < 1e-6 * u[b].abs().max(1e-3));
        }
    }
}

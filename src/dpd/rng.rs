//! Counter-based random numbers for the DPD pair noise.
//!
//! A pair's random number is a pure function of `(seed, step, min(id), max(id))`: the
//! SplitMix64 finaliser (Steele, Lea & Flood 2014) applied to a per-step key mixed with the
//! pair's word. The same pair in the same step gets the same number whichever particle
//! computes it, whichever thread or rank, in whatever order: the noise is symmetric
//! (`ξ_ij = ξ_ji`, so momentum is conserved) and runs are reproducible bit for bit across
//! thread and rank counts. The number is uniform on `[−√3, √3)`: zero mean and unit
//! variance, the usual choice in DPD (Groot & Warren 1997), where only the first two moments
//! matter at the time steps used.

/// The SplitMix64 finaliser: a bijection of `u64` with good avalanche.
#[inline(always)]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The constant the seed is mixed with in [`step_key`].
pub const SEED_MIX: u64 = 0x6a09_e667_f3bc_c909;

/// The key of one step: computed once per step, then combined with each pair's word.
#[inline]
pub fn step_key(seed: u64, step: u64) -> u64 {
    mix64(mix64(seed ^ SEED_MIX).wrapping_add(step.wrapping_mul(0x9e37_79b9_7f4a_7c15)))
}

/// The word of the unordered pair `{i, j}` (ids below 2³²).
#[inline(always)]
pub fn pair_word(i: u32, j: u32) -> u64 {
    let (lo, hi) = if i < j { (i, j) } else { (j, i) };
    ((lo as u64) << 32) | hi as u64
}

/// A uniform number of zero mean and unit variance on `[−√3, √3)` from 64 random bits.
#[inline(always)]
pub fn unit_variance(bits: u64) -> f64 {
    // 53 bits to [0, 1), then to [−√3, √3).
    const SCALE: f64 = 2.0 * 1.732_050_807_568_877_2 / (1u64 << 53) as f64;
    (bits >> 11) as f64 * SCALE - 1.732_050_807_568_877_2
}

/// The pair noise `ξ_ij` of a step (`key` from [`step_key`]).
#[inline(always)]
pub fn pair_noise(key: u64, i: u32, j: u32) -> f64 {
    unit_variance(mix64(key ^ pair_word(i, j)))
}

/// A standard normal number from two 64-bit words (Box–Muller), for initial velocities and
/// other per-particle draws that must not depend on the order of the particles.
pub fn normal(a: u64, b: u64) -> f64 {
    let u1 = ((a >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
    let u2 = (b >> 11) as f64 / (1u64 << 53) as f64;
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// A uniform number on `[0, 1)` from 64 bits.
#[inline]
pub fn unit_interval(bits: u64) -> f64 {
    (bits >> 11) as f64 / (1u64 << 53) as f64
}

/// The `n`-th 64-bit word of the stream `(seed, tag)`, for per-particle draws.
#[inline]
pub fn stream(seed: u64, tag: u64, n: u64) -> u64 {
    mix64(step_key(seed, tag) ^ mix64(n.wrapping_add(0x3c6e_f372_fe94_f82b)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_symmetric_and_depends_on_every_input() {
        let k = step_key(7, 3);
        assert_eq!(pair_noise(k, 5, 9), pair_noise(k, 9, 5));
        assert_ne!(pair_noise(k, 5, 9), pair_noise(k, 5, 10));
        assert_ne!(pair_noise(k, 5, 9), pair_noise(step_key(7, 4), 5, 9));
        assert_ne!(pair_noise(k, 5, 9), pair_noise(step_key(8, 3), 5, 9));
    }

    #[test]
    fn noise_has_unit_variance_and_no_correlation_between_neighbouring_pairs() {
        // Moments over 10^6 pairs: mean 0 ± 5σ/√n, variance 1 ± 5·(0.8/√n) (uniform: Var ξ² = 4/5).
        let n = 1_000_000u32;
        let k = step_key(1, 0);
        let (mut s1, mut s2, mut c) = (0.0, 0.0, 0.0);
        let mut prev = pair_noise(k, 0, 1);
        for m in 1..n {
            let x = pair_noise(k, m, m + 1);
            s1 += x;
            s2 += x * x;
            c += x * prev;
            prev = x;
        }
        let nf = (n - 1) as f64;
        let (mean, var, corr) = (s1 / nf, s2 / nf, c / nf);
        assert!(mean.abs() < 5.0 / nf.sqrt(), "mean {mean}");
        assert!((var - 1.0).abs() < 5.0 * 0.9 / nf.sqrt(), "variance {var}");
        assert!(corr.abs() < 5.0 / nf.sqrt(), "lag-1 correlation {corr}");
        // Range of the uniform.
        let lim = 3f64.sqrt();
        assert!((0..1000).all(|m| pair_noise(k, m, 2000).abs() <= lim));
    }

    #[test]
    fn normal_draws_have_unit_variance() {
        let n = 200_000u64;
        let (mut s1, mut s2) = (0.0, 0.0);
        for m in 0..n {
            let x = normal(stream(3, 1, 2 * m), stream(3, 1, 2 * m + 1));
            s1 += x;
            s2 += x * x;
        }
        let nf = n as f64;
        assert!((s1 / nf).abs() < 5.0 / nf.sqrt());
        assert!((s2 / nf - 1.0).abs() < 5.0 * 2f64.sqrt() / nf.sqrt());
    }
}

//! Layout of the real spherical-harmonic coefficients of one function.
//!
//! Basis (orthonormal on the unit sphere, no Condon–Shortley phase), with `P̄_n^m` the associated
//! Legendre functions normalised so that `∫_{-1}^{1} (P̄_n^m)² dx = 1`:
//!
//! * `Y_n^0 = P̄_n^0(cos θ) / √(2π)`,
//! * `Y_n^m = P̄_n^m(cos θ) cos(mφ) / √π` for `m > 0`,
//! * `Y_n^{-m} = P̄_n^m(cos θ) sin(mφ) / √π` for `m > 0`.
//!
//! On the grid of order `p` (`2p` longitudes) `sin(pφ)` vanishes at every node, so `Y_p^{-p}` is
//! not representable and is left out: a function of order `p` has `(p+1)² − 1` coefficients.
//!
//! Coefficients are stored order-major (the layout that makes the Legendre step one GEMM per
//! order `m`): the `m = 0` block (`n = 0..=p`), then for `m = 1..p−1` a cosine block and a sine
//! block (`n = m..=p` each), then the single `m = p` cosine coefficient.

/// Index map for the coefficients of order `p`.
#[derive(Clone, Debug)]
pub struct CoefLayout {
    p: usize,
    cos_offset: Vec<usize>,
    sin_offset: Vec<usize>,
    len: usize,
}

impl CoefLayout {
    /// Layout for order `p ≥ 1`.
    pub fn new(p: usize) -> Self {
        let mut cos_offset = vec![0; p + 1];
        let mut sin_offset = vec![usize::MAX; p + 1];
        let mut off = 0;
        for m in 0..=p {
            cos_offset[m] = off;
            off += p + 1 - m;
            if m > 0 && m < p {
                sin_offset[m] = off;
                off += p + 1 - m;
            }
        }
        debug_assert_eq!(off, (p + 1) * (p + 1) - 1);
        CoefLayout {
            p,
            cos_offset,
            sin_offset,
            len: off,
        }
    }
    /// The order `p`.
    pub fn order(&self) -> usize {
        self.p
    }
    /// Number of coefficients, `(p+1)² − 1`.
    pub fn len(&self) -> usize {
        self.len
    }
    /// Always false (order ≥ 1).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// Start of the cosine block of order `m` (`n = m..=p`).
    pub fn cos_block(&self, m: usize) -> usize {
        self.cos_offset[m]
    }
    /// Start of the sine block of order `m`, if it exists (`1 ≤ m < p`).
    pub fn sin_block(&self, m: usize) -> Option<usize> {
        (m > 0 && m < self.p).then(|| self.sin_offset[m])
    }
    /// Index of `Y_n^m` (`m < 0` for the sine functions); `None` if it is not in the layout.
    pub fn index(&self, n: usize, m: isize) -> Option<usize> {
        let am = m.unsigned_abs();
        if n > self.p || am > n {
            return None;
        }
        if m >= 0 {
            Some(self.cos_offset[am] + n - am)
        } else {
            self.sin_block(am).map(|o| o + n - am)
        }
    }
    /// Every `(n, m)` in storage order.
    pub fn modes(&self) -> Vec<(usize, isize)> {
        let mut out = vec![(0, 0); self.len];
        for n in 0..=self.p {
            for m in -(n as isize)..=n as isize {
                if let Some(i) = self.index(n, m) {
                    out[i] = (n, m);
                }
            }
        }
        out
    }
    /// Degree `n` of every coefficient in storage order.
    pub fn degrees(&self) -> Vec<usize> {
        self.modes().into_iter().map(|(n, _)| n).collect()
    }
}

//! Resampling between orders and spectral filtering.
//!
//! Resampling copies the coefficients of every degree `n ≤ min(p, q)` from the layout of order
//! `p` to that of order `q` (zero for the new degrees); with grids, it is forward at `p`, copy,
//! inverse at `q`. Upsampling (`q > p`) is exact for band-limited functions and is used for
//! quadrature and anti-aliasing of products; down-sampling is a sharp truncation.
//! Filters multiply each degree `n` by a factor `σ_n`: sharp (`σ_n = 1` for `n ≤ n_c`, else 0) or
//! smooth, the exponential filter `σ_n = exp(−α (n/p)^{2s})` (α = 36 gives σ_p = ε_machine).

use super::layout::CoefLayout;
use super::transform::{ShTransform, ShWorkspace};
use super::SphError;

/// Copy coefficients of a batch between orders (`src` in `from`'s layout, `dst` in `to`'s).
pub fn resample_coefs(
    from: &CoefLayout,
    to: &CoefLayout,
    src: &[f64],
    dst: &mut [f64],
) -> Result<(), SphError> {
    let nf = src.len() / from.len();
    if src.len() != nf * from.len() {
        return Err(SphError::CoefLength {
            len: src.len(),
            expected: (nf + 1) * from.len(),
        });
    }
    if dst.len() != nf * to.len() {
        return Err(SphError::CoefLength {
            len: dst.len(),
            expected: nf * to.len(),
        });
    }
    let nmax = from.order().min(to.order());
    for (s, d) in src
        .chunks_exact(from.len())
        .zip(dst.chunks_exact_mut(to.len()))
    {
        d.fill(0.0);
        for m in 0..=nmax {
            let cnt = nmax + 1 - m;
            let (a, b) = (from.cos_block(m), to.cos_block(m));
            d[b..b + cnt].copy_from_slice(&s[a..a + cnt]);
            if let (Some(a), Some(b)) = (from.sin_block(m), to.sin_block(m)) {
                d[b..b + cnt].copy_from_slice(&s[a..a + cnt]);
            }
        }
    }
    Ok(())
}

/// Grid-to-grid resampling of batches from order `p` to order `q`.
pub struct Resampler {
    from: ShTransform,
    to: ShTransform,
    ws_from: ShWorkspace,
    ws_to: ShWorkspace,
    c_from: Vec<f64>,
    c_to: Vec<f64>,
}

impl Resampler {
    /// Resampler from order `p` to order `q`.
    pub fn new(p: usize, q: usize) -> Result<Self, SphError> {
        let from = ShTransform::new(p)?;
        let to = ShTransform::new(q)?;
        let ws_from = from.workspace();
        let ws_to = to.workspace();
        Ok(Resampler {
            from,
            to,
            ws_from,
            ws_to,
            c_from: Vec::new(),
            c_to: Vec::new(),
        })
    }
    /// Resample `nf` functions: `src` on the order-`p` grid, `dst` on the order-`q` grid.
    pub fn apply(&mut self, src: &[f64], dst: &mut [f64]) -> Result<(), SphError> {
        let nf = src.len() / self.from.n_points();
        self.c_from.resize(nf * self.from.n_coefs(), 0.0);
        self.c_to.resize(nf * self.to.n_coefs(), 0.0);
        self.from
            .forward(src, &mut self.c_from, &mut self.ws_from)?;
        resample_coefs(
            self.from.layout(),
            self.to.layout(),
            &self.c_from,
            &mut self.c_to,
        )?;
        self.to.inverse(&self.c_to, dst, &mut self.ws_to)
    }
}

/// A spectral filter: a factor per degree.
#[derive(Clone, Debug)]
pub enum Filter {
    /// Keep degrees `n ≤ n_max`, zero the rest.
    Sharp {
        /// Highest degree kept.
        n_max: usize,
    },
    /// `σ_n = exp(−alpha (n/p)^{2·order})`.
    Exponential {
        /// Strength `alpha` (the factor at `n = p` is `exp(−alpha)`).
        alpha: f64,
        /// Filter order: the exponent is `2·order`.
        order: u32,
    },
}

impl Filter {
    /// Factor for degree `n` at order `p`.
    pub fn factor(&self, n: usize, p: usize) -> f64 {
        match *self {
            Filter::Sharp { n_max } => {
                if n <= n_max {
                    1.0
                } else {
                    0.0
                }
            }
            Filter::Exponential { alpha, order } => {
                (-alpha * (n as f64 / p as f64).powi(2 * order as i32)).exp()
            }
        }
    }
    /// Apply in place to a batch of coefficient vectors.
    pub fn apply(&self, layout: &CoefLayout, coefs: &mut [f64]) {
        let p = layout.order();
        let factors: Vec<f64> = layout
            .degrees()
            .iter()
            .map(|&n| self.factor(n, p))
            .collect();
        for c in coefs.chunks_exact_mut(layout.len()) {
            for (a, f) in c.iter_mut().zip(&factors) {
                *a *= f;
            }
        }
    }
}

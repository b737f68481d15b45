//! Accuracy asked for in digits, mapped to the FMM order (surface points per edge).
//!
//! The table holds, for `digits = 3 … 10`, the smallest order whose relative L2 error against
//! direct sums stayed below `10^-digits` (with some margin) on three clouds (uniform cube,
//! Gaussian blobs, points on small spheres) with the default leaf sizes, measured with
//! `examples/fmm_probe.rs` on 10⁴–2·10⁴ points (2026-11-21). `tests/fmm_accuracy.rs` re-measures
//! the entries for 3, 6 and 9 digits on every kernel and cloud; the ignored test
//! `fmm_convergence_table` prints the whole error-against-order table.
//!
//! Measured errors (worst cloud) that set the table:
//!
//! | order | 4 | 5 | 6 | 7 | 8 | 9 | 10 | 11 | 12 | 14 |
//! |---|---|---|---|---|---|---|---|---|---|---|
//! | Laplace | 2.5e-4 | 1.9e-5 | 3.4e-6 | 3.5e-7 | 6.5e-8 | 8.5e-9 | 1.7e-9 | 1.4e-10 | 7e-11 | |
//! | Stokeslet | 4.6e-3 | 1.6e-3 | 2.3e-4 | 3.2e-5 | 3.7e-6 | 6.2e-7 | 1.6e-7 | 1.4e-8 | 6e-9 | 6e-10 |
//!
//! The strongly clustered cloud ([`super::clouds::Cloud::Clustered`]: 90 % of the points in a
//! Gaussian of width 10⁻⁴, trees 15–16 levels deep) is harder for Laplace: with 2400 points
//! and leaves of `10·order` points (2026-11-25) order 7 gave 9.6e-7 and 1.0e-6 with leaves of
//! 40, order 8 1.2e-7, order 9 1.8e-8, so 6, 7 and 8 digits take orders 8, 9 and 10 (they
//! were 7, 8, 9). Every other entry held there with at least 1.5× margin:
//!
//! | order | 4 | 5 | 6 | 7 | 8 | 9 | 10 | 11 | 12 | 13 | 14 |
//! |---|---|---|---|---|---|---|---|---|---|---|---|
//! | Laplace | 4.4e-4 | 5.4e-5 | 5.5e-6 | 9.6e-7 | 1.2e-7 | 1.8e-8 | 3.6e-9 | 5.9e-10 | 1.1e-10 | 2.9e-11 | 3.6e-12 |
//! | Laplace DL | 5.8e-4 | 7.1e-5 | 1.2e-5 | 1.7e-6 | 3.4e-7 | 6.7e-8 | 8.8e-9 | 3.3e-9 | 3.1e-10 | 3.0e-10 | 2.2e-11 |
//! | Stokeslet | | | 2.6e-4 | 4.3e-5 | 3.5e-6 | | 1.8e-7 | 1.8e-8 | | 1.9e-9 | |

use super::kernels::FmmKernel;
use super::FmmError;

/// Orders for 3, 4, …, 10 digits.
const LAPLACE: [usize; 8] = [4, 5, 6, 8, 9, 10, 11, 13];
const LAPLACE_DL: [usize; 8] = [4, 5, 7, 8, 9, 10, 12, 14];
const STOKES: [usize; 8] = [6, 7, 8, 10, 11, 13, 15, 16];

/// Smallest accuracy offered, in digits.
pub const MIN_DIGITS: u32 = 3;
/// Largest accuracy offered, in digits.
pub const MAX_DIGITS: u32 = 10;

/// The order that reaches `digits` correct digits (relative L2) for `kernel`.
pub fn order_for_digits(kernel: FmmKernel, digits: u32) -> Result<usize, FmmError> {
    if !(MIN_DIGITS..=MAX_DIGITS).contains(&digits) {
        return Err(FmmError::Digits {
            got: digits,
            min: MIN_DIGITS,
            max: MAX_DIGITS,
        });
    }
    let table = match kernel {
        FmmKernel::Laplace => &LAPLACE,
        FmmKernel::LaplaceDoubleLayer => &LAPLACE_DL,
        _ => &STOKES,
    };
    Ok(table[(digits - MIN_DIGITS) as usize])
}

/// The digits `order` is calibrated to reach for `kernel`: the most digits whose table order
/// is at most `order` (`MIN_DIGITS − 1` below the table, [`MAX_DIGITS`] above it).
pub fn digits_for_order(kernel: FmmKernel, order: usize) -> u32 {
    (MIN_DIGITS..=MAX_DIGITS)
        .rev()
        .find(|&d| order_for_digits(kernel, d).is_ok_and(|o| o <= order))
        .unwrap_or(MIN_DIGITS - 1)
}

/// The relative error per pair the near field may add at `order`: a tenth of the accuracy the
/// order is calibrated to (`0.1 · 10^-digits`), none at or above [`MAX_DIGITS`] digits' order.
pub fn near_tolerance(kernel: FmmKernel, order: usize) -> f64 {
    let d = digits_for_order(kernel, order);
    if d >= MAX_DIGITS {
        0.0
    } else {
        0.1 * 10f64.powi(-(d as i32))
    }
}

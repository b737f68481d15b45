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

use super::evaluator::FmmKernel;
use super::FmmError;

/// Orders for 3, 4, …, 10 digits.
const LAPLACE: [usize; 8] = [4, 5, 6, 7, 8, 9, 11, 13];
const LAPLACE_DL: [usize; 8] = [4, 5, 7, 8, 9, 10, 12, 14];
const STOKES: [usize; 8] = [6, 7, 8, 10, 11, 13, 15, 16];

/// Smallest accuracy offered, in digits.
pub const MIN_DIGITS: u32 = 3;
/// Largest accuracy offered, in digits.
pub const MAX_DIGITS: u32 = 10;

/// The order that reaches `digits` correct digits (relative L2) for `kernel`.
pub fn order_for_digits(kernel: FmmKernel, digits: u32) -> Result<usize, FmmError> {
    if !(MIN_DIGITS..=MAX_DIGITS).contains(&digits) {
        return Err(FmmError::Shape(format!(
            "digits must be between {MIN_DIGITS} and {MAX_DIGITS}, got {digits}"
        )));
    }
    let table = match kernel {
        FmmKernel::Laplace => &LAPLACE,
        FmmKernel::LaplaceDoubleLayer => &LAPLACE_DL,
        _ => &STOKES,
    };
    Ok(table[(digits - MIN_DIGITS) as usize])
}

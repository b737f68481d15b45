//! N-body sums of Stokes and Laplace kernels.
//!
//! So far: the kernels of the `mobo fmm` contract ([`kernels`]) and their direct sums
//! ([`direct`]), the exact reference. The kernel-independent FMM (Ying, Biros & Zorin, J. Comput.
//! Phys. 196, 2004) with its adaptive octree is the next step (issue 3).

pub mod blocks;
pub mod calibration;
pub mod clouds;
pub mod direct;
pub mod evaluator;
pub mod kernels;
pub mod kifmm;
pub mod m2l_fft;
pub mod octree;
pub mod operators;
pub mod p2p;
pub mod surface;

pub use calibration::order_for_digits;
pub use direct::{direct_sum, SumInput};
pub use evaluator::{Fmm, FmmKernel, FmmTimings};
pub use kernels::{Kernel, Laplace, LaplaceDoubleLayer, Rpy, RpyFar, Stokeslet, Stresslet};

/// Errors of the N-body sums.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum FmmError {
    /// Inputs whose sizes do not fit the kernel or each other.
    #[error("{0}")]
    Shape(String),
}

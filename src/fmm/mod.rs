//! N-body sums of Stokes and Laplace kernels: direct and by a kernel-independent FMM.
//!
//! * [`kernels`]: the kernels of the `mobo fmm` contract and their normalisations;
//!   [`direct`]: exact sums, the reference.
//! * [`octree`]: adaptive Morton octree with U, V, W, X lists (the reference of the lists);
//!   [`dist_tree`]: the same tree split over ranks by keys ([`box_key`]) at the cuts of
//!   [`splitters`], with the locally essential tree each rank needs, which the evaluator runs
//!   on (one rank: the whole tree).
//! * [`evaluator::Fmm`]: the KIFMM of Ying, Biros & Zorin (J. Comput. Phys. 196, 2004) with
//!   level-independent operators ([`operators`]), M2L by FFT ([`m2l_fft`], the scheme of PVFMM,
//!   Malhotra & Biros 2015) and batched P2P ([`p2p`]) over the near field's one list
//!   ([`near_field`]), on the CPU or the GPU ([`gpu_near`]); accuracy in digits via
//!   [`calibration`]. [`kifmm`] is the first, dense reference version kept for comparison.
//!
//! ```
//! use mobo::fmm::{clouds::Cloud, direct_sum, order_for_digits, Fmm, FmmKernel, SumInput};
//! let pts = Cloud::Spheres.points(3000, 1);
//! let f = Cloud::densities(3 * pts.len(), 2);
//! let order = order_for_digits(FmmKernel::Stokeslet, 3).unwrap();
//! let mut fmm = Fmm::new(FmmKernel::Stokeslet, &pts, None, &pts, order, 200).unwrap();
//! let mut u = vec![0.0; f.len()];
//! fmm.evaluate(&f, &mut u).unwrap(); // again with other densities on the same tree
//! let mut exact = vec![0.0; f.len()];
//! let input = SumInput { sources: &pts, density: &f, normals: None, targets: &pts };
//! direct_sum(&mobo::fmm::Stokeslet, &input, &mut exact).unwrap();
//! let err = (u.iter().zip(&exact).map(|(a, b)| (a - b).powi(2)).sum::<f64>()
//!     / exact.iter().map(|b| b * b).sum::<f64>()).sqrt();
//! assert!(err < 1e-3);
//! ```

pub mod blocks;
pub mod box_key;
pub mod calibration;
pub mod clouds;
pub mod direct;
pub mod dist_tree;
pub mod evaluator;
pub mod fit_cache;
pub mod gpu_near;
pub mod kernels;
pub mod kifmm;
pub mod m2l_fft;
pub mod m2l_plan;
pub mod near_field;
pub mod near_list;
pub mod near_pairs;
pub mod octree;
pub mod operators;
pub mod p2p;
pub mod pinv;
pub mod splitters;
pub mod surface;

pub use calibration::order_for_digits;
pub use direct::{direct_sum, SumInput};
pub use evaluator::{clear_operator_cache, Fmm, FmmComm, FmmTimings};
pub use kernels::{
    FmmKernel, Kernel, Laplace, LaplaceDoubleLayer, Rpy, RpyFar, Stokeslet, Stresslet,
};

/// Errors of the N-body sums.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum FmmError {
    /// Inputs whose sizes do not fit the kernel or each other.
    #[error("{0}")]
    Shape(String),
    /// Communication between ranks failed, or another rank failed.
    #[error(transparent)]
    Comm(#[from] crate::comm::CommError),
    /// An accuracy outside the calibrated range.
    #[error("digits must be between {min} and {max}, got {got}")]
    Digits {
        /// Digits asked for.
        got: u32,
        /// Fewest digits calibrated.
        min: u32,
        /// Most digits calibrated.
        max: u32,
    },
    /// A singular value decomposition did not converge.
    #[error("the SVD of the {0} did not converge")]
    Svd(&'static str),
    /// The on-disk operator cache (`MOBO_OPERATOR_CACHE`) could not be written.
    #[error(transparent)]
    Cache(#[from] fit_cache::FitCacheError),
    /// The GPU near field failed or was asked for where there is none.
    #[error(transparent)]
    Gpu(#[from] crate::gpu::GpuError),
}

#![warn(missing_docs)]
//! # mobo
//!
//! Deformable cells (red blood cells, vesicles) in Stokes flow, and the particle methods
//! around them. Each cell membrane is a closed surface expanded in spherical harmonics of
//! order `p`; its bending, tension and (optionally) Skalak shear forces are spectral, its
//! self-interaction is a boundary integral with singular quadrature, and it is advanced by the
//! semi-implicit scheme of Veerapaneni, Rahimian, Biros & Zorin (*A fast algorithm for
//! simulating vesicle flows in three dimensions*, J. Comput. Phys. 230, 2011). Many cells are
//! coupled through the velocity their tractions induce on each other, summed by a
//! kernel-independent fast multipole method (Ying, Biros & Zorin, *A kernel-independent
//! adaptive fast multipole algorithm in two and three dimensions*, J. Comput. Phys. 196, 2004),
//! one evaluation per step, as in MOBO (Rahimian et al., *Petascale direct numerical
//! simulation of blood flow on 200K cores and heterogeneous architectures*, SC'10, 2010).
//! Beside the cells: Brownian dynamics of beads with hydrodynamic interactions (Ermak &
//! McCammon 1978, Rotne–Prager–Yamakawa mobility, TEA-HI noise), and dissipative particle
//! dynamics with an explicit solvent (Groot & Warren, J. Chem. Phys. 107, 1997) and
//! visco-elastic triangulated membranes (Fedosov, Caswell & Karniadakis, Biophys. J. 98, 2010).
//!
//! ## Modules, in data-flow order
//!
//! * [`durable`]: atomic file replacement and the FNV-1a checksum, below every other layer.
//! * [`check`]: relative max-norm errors of a fast routine against its reference (tests).
//! * [`linalg3`]: the eigen-decomposition of symmetric 3 × 3 matrices.
//! * [`comm`]: the communicator the distributed algorithms are written against (one rank, or
//!   MPI ranks with the `mpi` feature).
//! * [`gpu`]: one wgpu device per process, batched pair sums on it, and the DPD fluid's whole
//!   step (`gpu` feature).
//! * [`sph_harmonics`]: the Gauss–Legendre × uniform grid, batched transforms and
//!   derivatives, resampling, rotations and singular quadrature weights.
//! * [`fmm`]: N-body sums of Laplace, Stokes and RPY kernels, direct and by the KIFMM, on one
//!   or many ranks, with the near field on the CPU or the GPU.
//! * [`vesicle`]: cells as spherical-harmonic surfaces: shapes, geometry, membrane forces,
//!   layer potentials with singular and near-singular quadrature.
//! * [`wall`]: rigid containers and bodies with a prescribed surface velocity, by the completed
//!   double layer (Power & Miranda), assembled and factored once.
//! * [`timestep`]: GMRES and preconditioners, the semi-implicit step of one cell, many cells
//!   coupled through the FMM, adaptive `dt`.
//! * [`brownian`]: Brownian dynamics with hydrodynamic interactions.
//! * [`dpd`]: dissipative particle dynamics: fluid, walls, membranes, viscosity from
//!   Poiseuille flow.
//! * [`io`]: output files: `.npy` arrays, frames, VTK, HDF5, binary checkpoints.
//! * [`scene`]: TOML scene files and their typed spec ([`SceneSpec`]): the schema, validated
//!   with errors that name the file, line and key.
//! * [`run`]: the runs scenes describe: `mobo run` (one process or MPI ranks, checkpoints,
//!   frames, summary), [`Simulation`] for research codes, `mobo dpd` and `mobo brownian`.
//! * [`report`]: the accuracy-versus-time study of the cell solver.
//!
//! ## Command line (`mobo`)
//!
//! * `mobo run [SCENE]`: a cell scene (or the built-in red blood cell in shear): frames,
//!   summary and checkpoints; `--resume DIR` continues bit for bit.
//! * `mobo fmm`: one N-body sum on user `.npy` data by the FMM (or `--direct`), one JSON line of
//!   settings and timings.
//! * `mobo brownian SCENE`: Brownian dynamics from a scene's `[brownian]` section.
//! * `mobo dpd SCENE`: DPD from a scene's `[dpd]` section; `--resume DIR` continues.
//! * `mobo report accuracy`: error against time per step for each numerical knob.
//!
//! ## Where to start
//!
//! The types a research code starts from are re-exported here:
//!
//! * [`SceneSpec`]: a cell scene typed in code (the scene file's schema as Rust types),
//!   validated by [`SceneSpec::build`] into a [`CellScene`];
//! * [`Simulation`]: that scene stepped by the caller, who reads the cells between steps and
//!   adds forces of their own;
//! * [`Fmm`]: an N-body sum by the KIFMM, built once over sources and targets and evaluated for
//!   many densities ([`Kernel`] is what it sums);
//! * [`sph_harmonics::ShTransform`]: forward and inverse transforms and grid derivatives.
//!
//! `mobo run`'s own driver is [`run::cells`]; `docs/architecture.md` (in the repository)
//! walks one step through the layers.

pub mod brownian;
pub mod check;
pub mod comm;
pub mod dpd;
pub mod durable;
pub mod fmm;
pub mod gpu;
pub mod io;
pub mod linalg3;
pub mod lu_pivots;
pub mod report;
pub mod run;
pub mod scene;
pub mod sph_harmonics;
pub mod timestep;
pub mod vesicle;
pub mod wall;

pub use fmm::{Fmm, Kernel};

/// The README's Rust snippets, compiled and run by `cargo test --doc`.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
pub use run::Simulation;
pub use scene::cells::CellScene;
pub use scene::spec::SceneSpec;

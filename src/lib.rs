//! # mobo
//!
//! Deformable cells (red blood cells, vesicles) in Stokes flow: a boundary-integral method on
//! spherical-harmonic surfaces, coupled by a kernel-independent fast multipole method.
//!
//! The library is built bottom-up following the data flow of the design (`shared/design.md`):
//! [`sph_harmonics`] (grids, transforms, derivatives, resampling, rotations, singular
//! quadrature weights) is the foundation; the FMM, cell mechanics, time stepping, scenes and
//! output build on it.

pub mod brownian;
pub mod check;
pub mod comm;
pub mod dpd;
pub mod durable;
pub mod fmm;
pub mod gpu;
pub mod io;
pub mod report;
pub mod scene;
pub mod sph_harmonics;
pub mod timestep;
pub mod vesicle;

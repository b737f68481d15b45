//! Cells in the DPD fluid with the solvent's pair forces on the GPU (feature `gpu`).
//!
//! The whole fluid can live on the device ([`super::gpu_fluid::GpuFluid`]), but cells cannot
//! yet: the bounce-back of the solvent off the moving membrane triangles, the solvent–vertex
//! pairs, the membranes' forces and the contacts between cells run on the CPU
//! ([`super::suspension`]). What the GPU takes for them is the part that costs most, the
//! solvent's own pair forces (two thirds of a CPU step of one RBC in 17 000 solvent
//! particles): [`GpuPairForces`] implements [`PairForces`] by uploading the host's sorted
//! particles and cell list at every step and reading the forces back
//! ([`crate::gpu::dpd_pairs`]). The rest of the step is [`DpdSuspension::step`]'s, so the
//! model, its bounce-back and its leak count are the CPU's; in `f64` a step agrees with the
//! CPU's to rounding (the pair sums run in another order).
//!
//! [`DpdSuspension::step`]: super::suspension::DpdSuspension::step
//!
//! # Example
//! ```no_run
//! use mobo::dpd::gpu_pairs::GpuPairForces;
//! use mobo::gpu::{Gpu, GpuPrecision};
//! use mobo::{run, scene::dpd};
//!
//! let scene = dpd::load(std::path::Path::new("examples/scenes/rbc_shear_bie_and_dpd.toml"))?;
//! let mut sim = run::dpd::build_suspension(&scene)?;
//! let mut pairs = GpuPairForces::new(Gpu::shared()?, &sim.fluid, GpuPrecision::F32)?;
//! for _ in 0..100 {
//!     sim.step_with(Some(&mut pairs))?;
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::sync::Arc;

use super::cell_list::CellList;
use super::gpu_fluid::fluid_spec;
use super::pair_force::{PairParams, Particles};
use super::system::{DpdSystem, PairForces};
use super::DpdError;
use crate::gpu::dpd::DpdFluidSpec;
use crate::gpu::dpd_pairs::{DpdPairPass, SortedParticles};
use crate::gpu::{Gpu, GpuError, GpuPrecision};

/// The solvent's pair forces computed on the GPU (see the module docs).
pub struct GpuPairForces {
    pass: DpdPairPass,
    pair: PairParams,
    virials: Vec<f64>,
}

impl GpuPairForces {
    /// A pass for the particles of `fluid` (their number stays; the parameters are its
    /// pair force, time step, seed and box).
    pub fn new(
        gpu: Arc<Gpu>,
        fluid: &DpdSystem,
        precision: GpuPrecision,
    ) -> Result<Self, DpdError> {
        // The host adds the body force after the pairs, as after the CPU loops.
        let spec = DpdFluidSpec {
            body: [0.0; 3],
            reverse_poiseuille: 0.0,
            ..fluid_spec(fluid)?
        };
        let pass = DpdPairPass::new(gpu, precision, &spec, fluid.len())?;
        Ok(GpuPairForces {
            pass,
            pair: fluid.params.pair,
            virials: Vec::new(),
        })
    }

    /// The precision the device computes in.
    pub fn precision(&self) -> GpuPrecision {
        self.pass.precision()
    }

    /// `"NVIDIA H100 … (Vulkan)"`.
    pub fn adapter(&self) -> String {
        self.pass.gpu().describe()
    }
}

impl PairForces for GpuPairForces {
    fn pair_forces(
        &mut self,
        pair: &PairParams,
        p: &Particles,
        cells: &CellList,
        step: u64,
        f: [&mut [f64]; 3],
    ) -> Result<f64, DpdError> {
        if *pair != self.pair {
            return Err(DpdError::Gpu(GpuError::Shape(
                "the pair pass was made for another pair force".into(),
            )));
        }
        self.virials.resize(p.len(), 0.0);
        let sorted = SortedParticles {
            x: [&p.x, &p.y, &p.z],
            v: [&p.vx, &p.vy, &p.vz],
            id: &p.id,
            starts: &cells.starts,
        };
        self.pass.forces(&sorted, step, f, &mut self.virials)?;
        // Each particle holds half of its pairs' virial: the sum is Σ_{i<j}.
        Ok(self.virials.iter().sum())
    }
}

//! The working state of a vesicle step, shared by the cells of one order: transforms, the
//! membrane-force engine, the layer potentials, the GMRES basis and the scratch of the dense
//! operators, pooled per `(p, q, restart)` and lent to a cell for the duration of a call.
//!
//! A cell's own state (its surface history, tension, velocity, dense self-interaction operators,
//! preconditioners) stays in its [`super::semi_implicit::VesicleStepper`]; everything here is
//! either a plan that depends only on `(p, q)` or scratch that a call fills before it reads it.
//! A suspension therefore holds as many engines as cells step at once (the threads), not one
//! per cell: at `p = 12` an engine is several MB (plans and workspaces at `q = 24`, the grid
//! operators of the step as rows over coefficients, `3n × 3n_c`, 3.8 MB each), which per cell
//! would rule out 10⁴ cells in 24 GiB.
//!
//! Results do not depend on which engine a cell gets: every call sets the geometry it uses
//! (and the cell's far-side settings and Skalak reference) before reading anything.

use std::sync::{Arc, Mutex, Weak};

use super::gmres::GmresWorkspace;
use super::TimestepError;
use crate::sph_harmonics::{ShTransform, ShWorkspace};
use crate::vesicle::coefficient_operator::CoefficientOperator;
use crate::vesicle::geometry::SurfaceCalculus;
use crate::vesicle::layer::{RotationAlgorithm, SelfInteraction};
use crate::vesicle::membrane::Membrane;
use crate::vesicle::reparam::Reparametrizer;

/// What one application of the step operator needs, reused across GMRES iterations (locked
/// while applied: the operator closure is shared).
pub(crate) struct OperatorWork {
    pub membrane: Membrane,
    /// Bending and tension forces (`3n` each).
    pub fb: Vec<f64>,
    pub ft: Vec<f64>,
    /// The self-interaction products.
    pub products: ProductWork,
    /// A capsule's elastic Jacobian (made at its first use).
    pub elastic: Option<ElasticWork>,
}

/// The scratch of a capsule's elastic Jacobian-vector products: a second membrane engine for
/// the perturbed surface, so that the operators' frozen geometry stays set.
pub(crate) struct ElasticWork {
    pub membrane: Membrane,
    /// The direction and the perturbed surface (coefficients, `3n_c`) and its elastic force
    /// (`3n`).
    pub dir: Vec<f64>,
    pub dc: Vec<f64>,
    pub fp: Vec<f64>,
}

impl ElasticWork {
    /// For orders `(p, q)`, `n_c` coefficients per component.
    pub fn new(p: usize, q: usize, nc: usize) -> Result<Self, TimestepError> {
        let membrane = Membrane::new(p, q)?;
        let n = membrane.n_points();
        Ok(ElasticWork {
            membrane,
            dir: vec![0.0; 3 * nc],
            dc: vec![0.0; 3 * nc],
            fp: vec![0.0; 3 * n],
        })
    }
}

/// The layer potentials and the scratch of the self-interaction products of a step.
pub(crate) struct ProductWork {
    /// The layer potentials (assembly, and the matrix-free products).
    pub layer: SelfInteraction,
    /// Transform workspace and the coefficient vectors (`3n_c` each) of the coefficient-space
    /// products: an input and the sum.
    pub ws: ShWorkspace,
    pub xc: Vec<f64>,
    pub yc: Vec<f64>,
    /// Grid scratch (`3n`): a product or the sum.
    pub yg: Vec<f64>,
}

/// One engine: everything a step of a cell of order `p` needs besides the cell's own state.
pub(crate) struct StepEngine {
    pub work: Mutex<OperatorWork>,
    pub sht: ShTransform,
    pub ws: ShWorkspace,
    pub gmres_ws: GmresWorkspace,
    pub calc: SurfaceCalculus,
    pub reparametrizer: Option<Reparametrizer>,
    pub compressor: CoefficientOperator,
    /// A grid operator's rows over coefficients, `3n × 3n_c` (`3n × 3n` without upsampling),
    /// assembled here, then compressed into the cell's storage.
    pub grid_op: Vec<f64>,
    /// The grid operators (rows over coefficients, `3n × 3n_c`; `3n × 3n` without
    /// upsampling) of the step that holds this engine, with
    /// [`super::semi_implicit::OperatorStorage::Grid`]: the single layer, and the double layer
    /// with a viscosity contrast. A cell's operators are assembled at its step and read only
    /// within it, so they are lent with the engine: one pair per thread, not per cell.
    pub grid_single: Vec<f64>,
    /// See [`Self::grid_single`].
    pub grid_double: Vec<f64>,
}

impl StepEngine {
    fn new(p: usize, q: usize, restart: usize) -> Result<Self, TimestepError> {
        let sht = ShTransform::new(p).map_err(crate::vesicle::VesicleError::from)?;
        let (n, nc) = (sht.n_points(), sht.n_coefs());
        Ok(StepEngine {
            work: Mutex::new(OperatorWork {
                membrane: Membrane::new(p, q)?,
                fb: vec![0.0; 3 * n],
                ft: vec![0.0; 3 * n],
                products: ProductWork {
                    layer: SelfInteraction::new(p, q, RotationAlgorithm::Direct)?,
                    ws: sht.workspace(),
                    xc: vec![0.0; 3 * nc],
                    yc: vec![0.0; 3 * nc],
                    yg: vec![0.0; 3 * n],
                },
                elastic: None,
            }),
            ws: sht.workspace(),
            gmres_ws: GmresWorkspace::new(4 * n, restart),
            calc: SurfaceCalculus::new(p)?,
            reparametrizer: None,
            compressor: CoefficientOperator::new(&sht)?,
            grid_op: Vec::new(),
            grid_single: Vec::new(),
            grid_double: Vec::new(),
            sht,
        })
    }
}

type PoolKey = (usize, usize, usize);

/// The free engines of one `(p, q, restart)`.
pub(crate) struct EnginePool {
    key: PoolKey,
    free: Mutex<Vec<Box<StepEngine>>>,
}

impl EnginePool {
    /// The pool of `(p, q, restart)` shared by every stepper of the process alive with the same
    /// key (made if there is none).
    pub fn shared(p: usize, q: usize, restart: usize) -> Arc<EnginePool> {
        static POOLS: Mutex<Vec<(PoolKey, Weak<EnginePool>)>> = Mutex::new(Vec::new());
        let key = (p, q, restart);
        let mut pools = POOLS.lock().unwrap_or_else(|e| e.into_inner());
        pools.retain(|(_, w)| w.strong_count() > 0);
        if let Some(pool) = pools
            .iter()
            .find(|(k, _)| *k == key)
            .and_then(|(_, w)| w.upgrade())
        {
            return pool;
        }
        let pool = Arc::new(EnginePool {
            key,
            free: Mutex::new(Vec::new()),
        });
        pools.push((key, Arc::downgrade(&pool)));
        pool
    }

    /// An engine for the caller's exclusive use, returned to the pool when the lease drops.
    pub fn lease(self: &Arc<Self>) -> Result<EngineLease, TimestepError> {
        let free = self.free.lock().unwrap_or_else(|e| e.into_inner()).pop();
        let engine = match free {
            Some(e) => e,
            None => {
                let (p, q, restart) = self.key;
                Box::new(StepEngine::new(p, q, restart)?)
            }
        };
        Ok(EngineLease {
            pool: Arc::clone(self),
            engine: Some(engine),
        })
    }

    /// Engines currently idle in the pool.
    #[cfg(test)]
    pub fn idle(&self) -> usize {
        self.free.lock().unwrap_or_else(|e| e.into_inner()).len()
    }
}

/// An engine lent by an [`EnginePool`].
pub(crate) struct EngineLease {
    pool: Arc<EnginePool>,
    engine: Option<Box<StepEngine>>,
}

impl std::ops::Deref for EngineLease {
    type Target = StepEngine;
    fn deref(&self) -> &StepEngine {
        self.engine.as_ref().expect("held until drop")
    }
}

impl std::ops::DerefMut for EngineLease {
    fn deref_mut(&mut self) -> &mut StepEngine {
        self.engine.as_mut().expect("held until drop")
    }
}

impl Drop for EngineLease {
    fn drop(&mut self) {
        if let Some(e) = self.engine.take() {
            // An engine whose operator lock was poisoned by a panic is dropped, not reused.
            if !e.work.is_poisoned() {
                self.pool
                    .free
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .push(e);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn leases_are_returned_and_reused_and_pools_are_shared_per_key() {
        let a = EnginePool::shared(3, 7, 13);
        let b = EnginePool::shared(3, 7, 13);
        assert!(Arc::ptr_eq(&a, &b));
        let c = EnginePool::shared(3, 7, 14);
        assert!(!Arc::ptr_eq(&a, &c));
        {
            let _l1 = a.lease().unwrap();
            let _l2 = b.lease().unwrap();
            assert_eq!(a.idle(), 0);
        }
        assert_eq!(a.idle(), 2);
        let _l3 = a.lease().unwrap();
        assert_eq!(a.idle(), 1);
    }
}

//! The state one cell of a [`super::suspension::Suspension`] carries from step to step, apart
//! from its fixed setup ([`super::suspension::CellSetup`]): what a checkpoint saves and what
//! moves with a cell when it changes rank.
//!
//! A step of a cell is a function of this state, its setup and the explicit inter-cell terms
//! only: a stepper rebuilt from the setup and given this state
//! ([`super::suspension::Suspension::insert_cell`]) continues bit for bit as the one it came
//! from. (The sphere preconditioner is rebuilt, at the radius of the drift-correction target
//! area, which the state carries; without drift correction its radius would be the current
//! one, and a moved cell's GMRES iterates would differ from a kept cell's at the solver
//! tolerance. The cell's own preconditioner is rebuilt from its [`PreconditionerRecord`]: the
//! surface, `τ` and Skalak reference of the operator it inverts.)
//!
//! ## Flat codec
//!
//! [`CellState::encode`] appends the state to a `f64` buffer in a fixed layout for cells of
//! `n_c` coefficients (`3 (p+1)²`) and `n` grid points (`2p(p+1)`): a presence word (bit `b`
//! set when optional field `b` is present, an exact integer in an `f64`), then every field at
//! its full length (absent ones as zeros), so that every cell of an order takes the same
//! [`CellState::encoded_len`] values and a buffer of many cells is sliced without a header.
//! Values travel as their bits: the decoded state is bit-identical.

use crate::vesicle::material_labels::MaterialLabels;

/// What a cell's own preconditioner
/// ([`super::semi_implicit::Preconditioning::Cell`]) was built from: a stepper given it
/// rebuilds the very same preconditioner (bit for bit), so it travels with the state instead of
/// the `(4n_c)²` inverse.
#[derive(Clone, Debug, PartialEq)]
pub struct PreconditionerRecord {
    /// The surface (order-`p` coefficients) at which the inverted step operator was frozen
    /// (the build step's `X*`).
    pub surface: Vec<f64>,
    /// That operator's `τ`.
    pub tau: f64,
    /// The Skalak reference of the elastic Jacobian in that operator (`None`: no Jacobian).
    pub jacobian_reference: Option<Vec<f64>>,
    /// GMRES iterations of the last step that used it (its staleness).
    pub last_iterations: usize,
}

/// What a cell carries between steps.
#[derive(Clone, Debug, PartialEq)]
pub struct CellState {
    /// Order-`p` SH coefficients `Xⁿ` (x, y, z).
    pub coefs: Vec<f64>,
    /// Tension of the last step on the order-`p` grid.
    pub sigma: Vec<f64>,
    /// Area and volume the drift correction restores (set by the first step).
    pub drift_targets: Option<(f64, f64)>,
    /// `Xⁿ⁻¹` for BDF2.
    pub previous_coefs: Option<Vec<f64>>,
    /// The step that led from `Xⁿ⁻¹` to `Xⁿ`.
    pub previous_dt: Option<f64>,
    /// Membrane velocity of the last solve (`3n`): the explicit double-layer density.
    pub membrane_velocity: Option<Vec<f64>>,
    /// Skalak reference surface in the current parametrisation (composed from the material
    /// labels after the reparametrisations so far).
    pub skalak_reference: Option<Vec<f64>>,
    /// The Skalak reference's first surface and the grid's material labels it is composed
    /// from ([`crate::vesicle::material_labels`]).
    pub material_labels: Option<MaterialLabels>,
    /// Inter-cell velocity of the last step (`3n`).
    pub velocity: Option<Vec<f64>>,
    /// Inter-cell velocity of the step before (BDF2 extrapolation).
    pub previous_velocity: Option<Vec<f64>>,
    /// GMRES iterations of the cell's last solve (0 before the first): the measured cost that
    /// weighs the cell when cells are split between ranks.
    pub iterations: usize,
    /// The cell's own preconditioner, if it has one.
    pub preconditioner: Option<PreconditionerRecord>,
    /// The densities this cell passed to the coupling at the step before (`6n`: the traction,
    /// then the double-layer density `(1 − λ) u`, zero without one), kept by the
    /// near-implicit coupling to extrapolate them as the explicit velocities are
    /// ([`super::near_implicit`]); `None` with the explicit coupling.
    pub previous_density: Option<Vec<f64>>,
}

/// A buffer that does not hold a cell state of the expected size.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("cell state buffer: {0}")]
pub struct CellStateError(pub String);

/// Bits of the presence word.
const TARGETS: u64 = 1;
const PREVIOUS: u64 = 2;
const PREVIOUS_DT: u64 = 4;
const MEMBRANE_VELOCITY: u64 = 8;
const SKALAK: u64 = 16;
const VELOCITY: u64 = 32;
const PREVIOUS_VELOCITY: u64 = 64;
const PRECONDITIONER: u64 = 128;
const PRECONDITIONER_JACOBIAN: u64 = 256;
const LABELS: u64 = 512;
const PREVIOUS_DENSITY: u64 = 1024;

impl CellState {
    /// Bytes of the state's vectors (what a cell keeps between steps besides its stepper).
    pub fn memory_bytes(&self) -> usize {
        let opt = |v: &Option<Vec<f64>>| v.as_ref().map_or(0, |v| v.capacity());
        8 * (self.coefs.capacity()
            + self.sigma.capacity()
            + opt(&self.previous_coefs)
            + opt(&self.membrane_velocity)
            + opt(&self.skalak_reference)
            + self
                .material_labels
                .as_ref()
                .map_or(0, |l| l.original.capacity() + l.map.capacity())
            + opt(&self.velocity)
            + opt(&self.previous_velocity)
            + self
                .preconditioner
                .as_ref()
                .map_or(0, |r| r.surface.capacity() + opt(&r.jacobian_reference))
            + opt(&self.previous_density))
            + std::mem::size_of::<Self>()
    }

    /// Values one state takes in the flat codec for `ncoef` coefficients and `n` grid points.
    pub fn encoded_len(ncoef: usize, n: usize) -> usize {
        // presence, iterations, coefs, sigma, targets (2), previous, previous dt,
        // membrane velocity, Skalak reference, velocity, previous velocity, preconditioner
        // (surface, τ, last iterations, Jacobian reference), material labels (first
        // reference, label map), previous coupling densities.
        2 + ncoef
            + n
            + 2
            + ncoef
            + 1
            + 3 * n
            + ncoef
            + 3 * n
            + 3 * n
            + ncoef
            + 2
            + ncoef
            + 2 * ncoef
            + 6 * n
    }

    /// Append the state (see the module docs); `ncoef` and `n` are taken from `coefs` and
    /// `sigma`.
    pub fn encode(&self, out: &mut Vec<f64>) {
        let (ncoef, n) = (self.coefs.len(), self.sigma.len());
        let mut flags = 0u64;
        for (present, bit) in [
            (self.drift_targets.is_some(), TARGETS),
            (self.previous_coefs.is_some(), PREVIOUS),
            (self.previous_dt.is_some(), PREVIOUS_DT),
            (self.membrane_velocity.is_some(), MEMBRANE_VELOCITY),
            (self.skalak_reference.is_some(), SKALAK),
            (self.velocity.is_some(), VELOCITY),
            (self.previous_velocity.is_some(), PREVIOUS_VELOCITY),
            (self.preconditioner.is_some(), PRECONDITIONER),
            (
                self.preconditioner
                    .as_ref()
                    .is_some_and(|r| r.jacobian_reference.is_some()),
                PRECONDITIONER_JACOBIAN,
            ),
            (self.material_labels.is_some(), LABELS),
            (self.previous_density.is_some(), PREVIOUS_DENSITY),
        ] {
            if present {
                flags |= bit;
            }
        }
        out.push(flags as f64);
        out.push(self.iterations as f64);
        out.extend_from_slice(&self.coefs);
        out.extend_from_slice(&self.sigma);
        let (a, v) = self.drift_targets.unwrap_or((0.0, 0.0));
        out.extend_from_slice(&[a, v]);
        let field = |out: &mut Vec<f64>, v: &Option<Vec<f64>>, len: usize| match v {
            Some(v) => out.extend_from_slice(v),
            None => out.extend(std::iter::repeat_n(0.0, len)),
        };
        field(out, &self.previous_coefs, ncoef);
        out.push(self.previous_dt.unwrap_or(0.0));
        field(out, &self.membrane_velocity, 3 * n);
        field(out, &self.skalak_reference, ncoef);
        field(out, &self.velocity, 3 * n);
        field(out, &self.previous_velocity, 3 * n);
        let rec = self.preconditioner.as_ref();
        field(out, &rec.map(|r| r.surface.clone()), ncoef);
        out.push(rec.map_or(0.0, |r| r.tau));
        out.push(rec.map_or(0.0, |r| r.last_iterations as f64));
        field(out, &rec.and_then(|r| r.jacobian_reference.clone()), ncoef);
        let labels = self.material_labels.as_ref();
        field(out, &labels.map(|l| l.original.clone()), ncoef);
        field(out, &labels.map(|l| l.map.clone()), ncoef);
        field(out, &self.previous_density, 6 * n);
    }

    /// Read one state of a cell with `ncoef` coefficients and `n` grid points from the start
    /// of `buf` (exactly [`CellState::encoded_len`] values are read).
    pub fn decode(buf: &[f64], ncoef: usize, n: usize) -> Result<Self, CellStateError> {
        let len = Self::encoded_len(ncoef, n);
        if buf.len() < len {
            return Err(CellStateError(format!(
                "{} values, a cell of {ncoef} coefficients and {n} points needs {len}",
                buf.len()
            )));
        }
        let word = |v: f64, what: &str| -> Result<u64, CellStateError> {
            if v >= 0.0 && v.fract() == 0.0 && v < 2f64.powi(53) {
                Ok(v as u64)
            } else {
                Err(CellStateError(format!("{what} {v} is not a count")))
            }
        };
        let flags = word(buf[0], "presence word")?;
        if flags >= 2048 {
            return Err(CellStateError(format!(
                "presence word {flags} has unknown bits"
            )));
        }
        let iterations = word(buf[1], "iteration count")? as usize;
        let mut at = 2;
        let mut take = |len: usize| {
            let s = &buf[at..at + len];
            at += len;
            s
        };
        let coefs = take(ncoef).to_vec();
        let sigma = take(n).to_vec();
        let t = take(2);
        let has = |bit: u64| flags & bit != 0;
        let drift_targets = has(TARGETS).then_some((t[0], t[1]));
        let previous_coefs = Some(take(ncoef).to_vec()).filter(|_| has(PREVIOUS));
        let pdt = take(1)[0];
        let previous_dt = has(PREVIOUS_DT).then_some(pdt);
        let membrane_velocity = Some(take(3 * n).to_vec()).filter(|_| has(MEMBRANE_VELOCITY));
        let skalak_reference = Some(take(ncoef).to_vec()).filter(|_| has(SKALAK));
        let velocity = Some(take(3 * n).to_vec()).filter(|_| has(VELOCITY));
        let previous_velocity = Some(take(3 * n).to_vec()).filter(|_| has(PREVIOUS_VELOCITY));
        let surface = take(ncoef).to_vec();
        let tau = take(1)[0];
        let last = take(1)[0];
        let jacobian_reference =
            Some(take(ncoef).to_vec()).filter(|_| has(PRECONDITIONER_JACOBIAN));
        let original = take(ncoef).to_vec();
        let map = take(ncoef).to_vec();
        let material_labels = has(LABELS).then_some(MaterialLabels { original, map });
        let previous_density = Some(take(6 * n).to_vec()).filter(|_| has(PREVIOUS_DENSITY));
        let preconditioner = if has(PRECONDITIONER) {
            Some(PreconditionerRecord {
                surface,
                tau,
                jacobian_reference,
                last_iterations: word(last, "preconditioner iteration count")? as usize,
            })
        } else {
            None
        };
        Ok(CellState {
            coefs,
            sigma,
            drift_targets,
            previous_coefs,
            previous_dt,
            membrane_velocity,
            skalak_reference,
            material_labels,
            velocity,
            previous_velocity,
            iterations,
            preconditioner,
            previous_density,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(seed: u64, full: bool) -> CellState {
        let mut s = seed;
        let mut next = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            f64::from_bits((s >> 12) | 0x3ff0_0000_0000_0000) - 1.5
        };
        let (ncoef, n) = (48, 24);
        let mut v = |len: usize| (0..len).map(|_| next()).collect::<Vec<f64>>();
        CellState {
            coefs: v(ncoef),
            sigma: v(n),
            drift_targets: full.then_some((12.5, -0.0)),
            previous_coefs: full.then(|| v(ncoef)),
            previous_dt: full.then_some(0.05),
            membrane_velocity: full.then(|| v(3 * n)),
            skalak_reference: full.then(|| v(ncoef)),
            material_labels: full.then(|| MaterialLabels {
                original: v(ncoef),
                map: v(ncoef),
            }),
            velocity: Some(v(3 * n)),
            previous_velocity: full.then(|| v(3 * n)),
            iterations: 17,
            preconditioner: full.then(|| PreconditionerRecord {
                surface: v(ncoef),
                tau: 0.0125,
                jacobian_reference: seed.is_multiple_of(2).then(|| v(ncoef)),
                last_iterations: 5,
            }),
            previous_density: full.then(|| v(6 * n)),
        }
    }

    #[test]
    fn states_round_trip_bit_for_bit_back_to_back() {
        // Full without and with the Jacobian's reference in the preconditioner record, and bare.
        let states = [state(1, true), state(2, false), state(4, true)];
        assert!(states[2]
            .preconditioner
            .as_ref()
            .unwrap()
            .jacobian_reference
            .is_some());
        let mut buf = Vec::new();
        for s in &states {
            s.encode(&mut buf);
        }
        let len = CellState::encoded_len(48, 24);
        assert_eq!(buf.len(), 3 * len);
        for (k, s) in states.iter().enumerate() {
            let back = CellState::decode(&buf[k * len..(k + 1) * len], 48, 24).unwrap();
            assert_eq!(&back, s);
        }
        let a2 = CellState::decode(&buf[..len], 48, 24).unwrap();
        assert!(a2.drift_targets.unwrap().1.is_sign_negative(), "-0.0 kept");
    }

    #[test]
    fn short_or_corrupt_buffers_are_errors() {
        let mut buf = Vec::new();
        state(3, true).encode(&mut buf);
        assert!(CellState::decode(&buf[..buf.len() - 1], 48, 24).is_err());
        buf[0] = 0.5;
        assert!(CellState::decode(&buf, 48, 24).is_err());
        buf[0] = 2048.0;
        assert!(CellState::decode(&buf, 48, 24).is_err());
        buf[0] = 4096.0;
        assert!(CellState::decode(&buf, 48, 24).is_err());
    }
}

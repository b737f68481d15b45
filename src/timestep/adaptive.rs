//! Adaptive time step from the area and volume error (Quaife & Biros, J. Comput. Phys. 306
//! (2016), "Adaptive time stepping for vesicle suspensions").
//!
//! A cell's membrane is inextensible and its interior incompressible: the exact flow keeps
//! every cell's area `A` and volume `V`. The change a step makes to them,
//!
//! `e = max_cells max(|Aⁿ⁺¹ − Aⁿ| / Aⁿ, |Vⁿ⁺¹ − Vⁿ| / Vⁿ)`
//!
//! (measured after the solve, before the drift correction restores them) is therefore an error
//! of the step that costs nothing extra. Asking that the error committed over the run stays
//! below a tolerance `ε` over the time `T` means that a step of size `Δt` may commit
//! `e ≤ ε Δt / T`. A step that commits more is **rejected** and repeated with a smaller `Δt`;
//! after an accepted step the next `Δt` is chosen so that, with the local error
//! `e ∝ Δt^{k+1}` of a scheme of order `k`, it would commit a fraction `β` of what it may:
//!
//! `Δt_new = Δt · min(α_max, max(α_min, (β ε Δt / (T e))^{1/k}))`.
//!
//! To keep the per-cell preconditioners (built for one `Δt`) and the BDF2 step ratio
//! `ω = Δtⁿ/Δtⁿ⁻¹` few and bounded, `Δt` moves on the ladder `Δt₀ · 2^{j/4}` (`Δt₀` the
//! scene's `dt`): the proposal is rounded down to a rung, clamped to `[Δt_min, Δt_max]`, and
//! the step grows by at most two rungs (`ω ≤ √2`, well inside BDF2's zero-stability bound
//! `1 + √2`).

use super::TimestepError;

/// Rungs of the `Δt` ladder per factor of two.
const RUNGS_PER_OCTAVE: f64 = 4.0;
/// Safety factor `β` of the proposal.
const SAFETY: f64 = 0.9;
/// Largest growth of one step (two rungs).
const MAX_GROWTH: f64 = std::f64::consts::SQRT_2;
/// Smallest factor after a rejection.
const MIN_FACTOR: f64 = 0.2;

/// Settings of the controller.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdaptiveDt {
    /// Relative area/volume error `ε` allowed over the run.
    pub tolerance: f64,
    /// Length of the run `T`.
    pub t_end: f64,
    /// Order `k` of the scheme (1: Euler, 2: BDF2).
    pub order: usize,
    /// The ladder's base `Δt₀` (the first step).
    pub dt0: f64,
    /// Lower bound of `Δt` (below it a step is accepted, and counted as above tolerance).
    pub dt_min: f64,
    /// Upper bound of `Δt`.
    pub dt_max: f64,
}

/// What to do after a step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Decision {
    /// Keep the step.
    pub accept: bool,
    /// The size of the next try (the repeat, if rejected).
    pub dt: f64,
}

fn invalid(name: &'static str, value: f64, reason: &'static str) -> TimestepError {
    TimestepError::InvalidParameter {
        name,
        value: format!("{value}"),
        reason,
    }
}

impl AdaptiveDt {
    /// Checks the settings.
    pub fn new(
        tolerance: f64,
        t_end: f64,
        order: usize,
        dt0: f64,
        dt_min: f64,
        dt_max: f64,
    ) -> Result<Self, TimestepError> {
        for (name, v) in [
            ("dt_tolerance", tolerance),
            ("t_end", t_end),
            ("dt", dt0),
            ("dt_min", dt_min),
            ("dt_max", dt_max),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(invalid(name, v, "must be positive and finite"));
            }
        }
        if !(1..=2).contains(&order) {
            return Err(invalid("order", order as f64, "must be 1 or 2"));
        }
        if dt_min > dt0 || dt0 > dt_max {
            return Err(invalid("dt", dt0, "must lie between dt_min and dt_max"));
        }
        Ok(Self {
            tolerance,
            t_end,
            order,
            dt0,
            dt_min,
            dt_max,
        })
    }

    /// The error a step of size `dt` may commit, `ε Δt / T`.
    pub fn allowed(&self, dt: f64) -> f64 {
        self.tolerance * dt / self.t_end
    }

    /// The highest rung of the ladder not above `dt`.
    fn rung_below(&self, dt: f64) -> f64 {
        let j = (RUNGS_PER_OCTAVE * (dt / self.dt0).log2() + 1e-9).floor();
        self.dt0 * (j / RUNGS_PER_OCTAVE).exp2()
    }

    /// The size to retry with after a step of size `dt` whose solve failed (GMRES stagnated or
    /// ran out of iterations): one shrink factor down the ladder, or `None` at `dt_min` (the
    /// run then gives up with the solver's error).
    pub fn after_failure(&self, dt: f64) -> Option<f64> {
        (dt > self.dt_min).then(|| self.rung_below(dt * MIN_FACTOR).max(self.dt_min))
    }

    /// Decide on a step of size `dt` that committed the error `error`. A step at `dt_min` is
    /// accepted whatever its error (the caller reports it); a non-finite error rejects.
    pub fn decide(&self, dt: f64, error: f64) -> Decision {
        let allowed = self.allowed(dt);
        if !error.is_finite() {
            return Decision {
                accept: dt <= self.dt_min,
                dt: (dt * MIN_FACTOR).max(self.dt_min),
            };
        }
        let accept = error <= allowed || dt <= self.dt_min;
        let factor = if error > 0.0 {
            (SAFETY * allowed / error).powf(1.0 / self.order as f64)
        } else {
            MAX_GROWTH
        };
        let factor = if accept {
            factor.clamp(MIN_FACTOR, MAX_GROWTH)
        } else {
            factor.clamp(MIN_FACTOR, SAFETY)
        };
        let next = self.rung_below(dt * factor).clamp(self.dt_min, self.dt_max);
        Decision { accept, dt: next }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ctl(order: usize) -> AdaptiveDt {
        AdaptiveDt::new(1e-3, 10.0, order, 0.1, 1e-4, 1.0).unwrap()
    }

    #[test]
    fn small_error_grows_on_the_ladder() {
        let c = ctl(1);
        let d = c.decide(0.1, 1e-9);
        assert!(d.accept);
        assert!((d.dt / 0.1 - MAX_GROWTH).abs() < 1e-12, "{}", d.dt);
    }

    #[test]
    fn large_error_rejects_and_shrinks() {
        let c = ctl(1);
        // allowed = 1e-5; error 4e-5 → factor 0.9/4 = 0.225 → rung 2^{-9/4} ≈ 0.21.
        let d = c.decide(0.1, 4e-5);
        assert!(!d.accept);
        assert!(d.dt < 0.1 * 0.225 && d.dt > 0.1 * 0.2, "{}", d.dt);
    }

    #[test]
    fn error_just_below_allowed_keeps_or_lowers_one_rung() {
        let c = ctl(2);
        let d = c.decide(0.1, 0.95e-5);
        assert!(d.accept);
        // factor (0.9/0.95)^{1/2} ≈ 0.973 → one rung below: 2^{-1/4}.
        assert!((d.dt / 0.1 - (-0.25f64).exp2()).abs() < 1e-12, "{}", d.dt);
    }

    #[test]
    fn bounds_hold() {
        let c = ctl(1);
        assert_eq!(c.decide(1.0, 0.0).dt, 1.0);
        let d = c.decide(1e-4, 1.0);
        assert!(d.accept && d.dt == 1e-4);
        assert!(!c.decide(0.1, f64::NAN).accept);
        assert!(AdaptiveDt::new(1e-3, 10.0, 1, 2.0, 1e-4, 1.0).is_err());
        assert!(AdaptiveDt::new(-1.0, 10.0, 1, 0.1, 1e-4, 1.0).is_err());
    }

    #[test]
    fn rungs_are_exact_multiples() {
        let c = ctl(1);
        assert_eq!(c.rung_below(0.1), 0.1);
        assert!((c.rung_below(0.2) - 0.2).abs() < 1e-15);
    }
}

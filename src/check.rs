//! One shared checker for comparing a fast routine against its reference.
//!
//! Errors are relative to the largest magnitude of the reference (max-norm),
//! `max_j |a_j − b_j| / max_j |b_j|`; where the reference itself can vanish (a derivative that is
//! zero on the grid), pass a scale floor, e.g. the magnitude of the function being
//! differentiated, with [`rel_max_error_floor`].

/// Relative max-norm error of `got` against `want`.
pub fn rel_max_error(got: &[f64], want: &[f64]) -> f64 {
    rel_max_error_floor(got, want, 0.0)
}

/// Max-norm error of `got` against `want`, relative to `max(max_j |want_j|, floor)`.
pub fn rel_max_error_floor(got: &[f64], want: &[f64], floor: f64) -> f64 {
    assert_eq!(got.len(), want.len(), "compared arrays differ in length");
    let scale = want.iter().fold(floor, |m, v| m.max(v.abs()));
    let err = got
        .iter()
        .zip(want)
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    if scale > 0.0 {
        err / scale
    } else {
        err
    }
}

/// Panic with a descriptive message unless `rel_max_error(got, want) <= tol`. Returns the error.
#[track_caller]
pub fn assert_close(what: &str, got: &[f64], want: &[f64], tol: f64) -> f64 {
    assert_close_floor(what, got, want, tol, 0.0)
}

/// [`assert_close`] with a scale floor (see [`rel_max_error_floor`]).
#[track_caller]
pub fn assert_close_floor(what: &str, got: &[f64], want: &[f64], tol: f64, floor: f64) -> f64 {
    let e = rel_max_error_floor(got, want, floor);
    assert!(
        e <= tol && e.is_finite(),
        "{what}: relative error {e:.3e} exceeds {tol:.1e}"
    );
    e
}

//! Observables of bead systems and their time correlations.

/// Centre of mass.
pub fn center_of_mass(pos: &[[f64; 3]]) -> [f64; 3] {
    let n = pos.len() as f64;
    let mut c = [0.0; 3];
    for p in pos {
        for k in 0..3 {
            c[k] += p[k] / n;
        }
    }
    c
}

/// Squared radius of gyration `R_g² = (1/N) Σ |x_i − x_cm|²`.
pub fn radius_of_gyration_sq(pos: &[[f64; 3]]) -> f64 {
    let c = center_of_mass(pos);
    pos.iter()
        .map(|p| (0..3).map(|k| (p[k] - c[k]).powi(2)).sum::<f64>())
        .sum::<f64>()
        / pos.len() as f64
}

/// End-to-end vector `x_{N−1} − x_0`.
pub fn end_to_end(pos: &[[f64; 3]]) -> [f64; 3] {
    let (a, b) = (pos[0], pos[pos.len() - 1]);
    [b[0] - a[0], b[1] - a[1], b[2] - a[2]]
}

/// Unit vector along [`end_to_end`].
pub fn orientation(pos: &[[f64; 3]]) -> [f64; 3] {
    let e = end_to_end(pos);
    let n = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
    [e[0] / n, e[1] / n, e[2] / n]
}

/// Average of `f(x(t), x(t+lag))` over all time origins `t` of a vector series (NaN if the series
/// is not longer than `lag`).
fn lag_average(series: &[[f64; 3]], lag: usize, f: impl Fn(&[f64; 3], &[f64; 3]) -> f64) -> f64 {
    if lag >= series.len() {
        return f64::NAN;
    }
    let n = series.len() - lag;
    (0..n).map(|t| f(&series[t], &series[t + lag])).sum::<f64>() / n as f64
}

/// Mean squared displacement `⟨|x(t+lag) − x(t)|²⟩` of a vector time series at lag `lag`
/// (samples), averaged over all time origins.
pub fn mean_square_displacement(series: &[[f64; 3]], lag: usize) -> f64 {
    lag_average(series, lag, |a, b| {
        (0..3).map(|k| (b[k] - a[k]).powi(2)).sum()
    })
}

/// Autocorrelation `⟨u(t+lag)·u(t)⟩` of a vector time series, averaged over time origins.
pub fn autocorrelation(series: &[[f64; 3]], lag: usize) -> f64 {
    lag_average(series, lag, |a, b| (0..3).map(|k| a[k] * b[k]).sum())
}

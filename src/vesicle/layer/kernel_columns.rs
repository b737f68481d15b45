//! The kernel rows of one target: the entries of the single- or double-layer kernel between a
//! target `x_t` and every point of a rotated surface on the order-`q` grid, with the
//! Graham–Sloan weight and the area element `|y_θ × y_φ| / sin θ` folded in (see the parent
//! module for the rule).

use super::*;

/// Kernel rows `K_ab(j)` (quadrature weights `gs` per latitude included) of target point `xt`
/// from the rotated surface `y, y_θ, y_φ` (component-major on the order-`q` grid), into `kern`
/// (`9 × n_q`).
#[allow(clippy::too_many_arguments)]
pub(super) fn kernel_rows(
    kernel: LayerKernel,
    xt: [f64; 3],
    y: &[f64],
    yt: &[f64],
    yp: &[f64],
    gs: &[f64],
    sin_q: &[f64],
    kern: &mut [f64],
) {
    for_each_kernel_column(kernel, xt, y, yt, yp, gs, sin_q, |j, col| {
        kern[9 * j..9 * j + 9].copy_from_slice(&col)
    });
}

/// The same rows stored by symmetric entry: `kern[e · n_q + j] = K_ab(j)` for
/// `(a, b) = SYM[e]` (both kernels are symmetric, `K_ab = K_ba`; `6` functions on the order-`q`
/// grid, the layout of a transform batch).
#[allow(clippy::too_many_arguments)]
pub(super) fn kernel_rows_by_entry(
    kernel: LayerKernel,
    xt: [f64; 3],
    y: &[f64],
    yt: &[f64],
    yp: &[f64],
    gs: &[f64],
    sin_q: &[f64],
    kern: &mut [f64],
) {
    let nq = y.len() / 3;
    for_each_kernel_column(kernel, xt, y, yt, yp, gs, sin_q, |j, col| {
        for (e, &(a, b)) in SYM.iter().enumerate() {
            kern[e * nq + j] = col[3 * a + b];
        }
    });
}

/// `put(j, K(j))` for every point `j` of the order-`q` grid, `K(j)` the nine kernel entries
/// (row-major) at `r = x_t − y_j` with the weight `gs[lat] |y_θ × y_φ| / sin θ`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn for_each_kernel_column(
    kernel: LayerKernel,
    xt: [f64; 3],
    y: &[f64],
    yt: &[f64],
    yp: &[f64],
    gs: &[f64],
    sin_q: &[f64],
    mut put: impl FnMut(usize, [f64; 9]),
) {
    let nq = y.len() / 3;
    let nlon = nq / gs.len();
    for j in 0..nq {
        let lat = j / nlon;
        let yj = get3(y, nq, j);
        let nv = cross(get3(yt, nq, j), get3(yp, nq, j));
        let w = dot(nv, nv).sqrt();
        let wt = gs[lat] * w / sin_q[lat];
        let r = [xt[0] - yj[0], xt[1] - yj[1], xt[2] - yj[2]];
        let n = [nv[0] / w, nv[1] / w, nv[2] / w];
        put(j, kernel_entries(kernel, r, n, wt));
    }
}

//! 3 × 3 linear algebra shared by the geometry of spherical-harmonic cells
//! ([`crate::vesicle::geometry`]) and of DPD membranes ([`crate::dpd::suspension`]), and the
//! 3-vector products they and [`crate::vesicle::tank_treading`] use.

/// `a · b`.
#[inline]
pub fn dot3(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a − b`.
#[inline]
pub fn sub3(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `|a − b|²`.
#[inline]
pub fn dist3_squared(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = sub3(a, b);
    dot3(d, d)
}

/// `|a − b|`.
#[inline]
pub fn dist3(a: [f64; 3], b: [f64; 3]) -> f64 {
    dist3_squared(a, b).sqrt()
}

/// `a × b`.
#[inline]
pub fn cross3(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// The rotation by the angle `|w|` about the axis `w / |w|` (Rodrigues' formula,
/// `R = I + sin θ K + (1 − cos θ) K²` with `K` the cross-product matrix of the unit axis); the
/// identity for `w = 0`.
pub fn rotation_from_vector(w: [f64; 3]) -> [[f64; 3]; 3] {
    let theta = dot3(w, w).sqrt();
    if theta == 0.0 {
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    }
    let k = w.map(|v| v / theta);
    let (s, c) = theta.sin_cos();
    let kk = [[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]];
    let mut r = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let k2 = k[i] * k[j] - if i == j { 1.0 } else { 0.0 };
            r[i][j] = if i == j { 1.0 } else { 0.0 } + s * kk[i][j] + (1.0 - c) * k2;
        }
    }
    r
}

/// `a b` of two 3 × 3 matrices.
pub fn matmul3(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

/// Of an ellipsoid's semi-axes `semi` with unit directions `axes` (`axes[i]` belongs to
/// `semi[i]`), the two in the plane most nearly normal to `vorticity`: the one whose axis is
/// closest to `vorticity` (largest `|axes[i] · vorticity|`) is left out. Returns `(L, B, a_L)`,
/// `L ≥ B` and the direction of `L` (on a tie, the lower index's). The Taylor deformation in
/// that plane (the shear plane of a cell in simple shear) is `(L − B)/(L + B)`.
pub fn shear_plane_semi_axes(
    semi: [f64; 3],
    axes: [[f64; 3]; 3],
    vorticity: [f64; 3],
) -> (f64, f64, [f64; 3]) {
    let along = |a: [f64; 3]| dot3(a, vorticity).abs();
    let k = (0..3)
        .max_by(|&i, &j| along(axes[i]).total_cmp(&along(axes[j])))
        .unwrap_or(2);
    let (i, j) = match k {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    };
    if semi[i] >= semi[j] {
        (semi[i], semi[j], axes[i])
    } else {
        (semi[j], semi[i], axes[j])
    }
}

/// The angle in degrees of the axis (a line: `axis` and `−axis` are the same) from the
/// coordinate direction `from` towards `towards`, `atan2(axis[towards], axis[from])` folded into
/// `[−90, 90]`: the inclination of a cell's long axis in a shear plane.
pub fn axis_inclination_deg(axis: [f64; 3], from: usize, towards: usize) -> f64 {
    let deg = axis[towards].atan2(axis[from]).to_degrees();
    if deg > 90.0 {
        deg - 180.0
    } else if deg < -90.0 {
        deg + 180.0
    } else {
        deg
    }
}

/// Eigen-decomposition of a symmetric 3 × 3 matrix by cyclic Jacobi rotations: eigenvalues in
/// ascending order and unit eigenvectors (`vecs[i]` belongs to `vals[i]`).
#[allow(clippy::needless_range_loop)] // index-heavy 3 × 3 linear algebra
pub fn symmetric_eigen3(a: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut a = a;
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]; // columns = eigenvectors
    for _ in 0..64 {
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        let scale = a[0][0].abs() + a[1][1].abs() + a[2][2].abs();
        if off <= 1e-17 * scale || off == 0.0 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q] == 0.0 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            // A ← Jᵀ A J with J the rotation in the (p, q) plane.
            for k in 0..3 {
                let (akp, akq) = (a[k][p], a[k][q]);
                a[k][p] = c * akp - s * akq;
                a[k][q] = s * akp + c * akq;
            }
            for k in 0..3 {
                let (apk, aqk) = (a[p][k], a[q][k]);
                a[p][k] = c * apk - s * aqk;
                a[q][k] = s * apk + c * aqk;
            }
            for row in v.iter_mut() {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    let mut idx = [0, 1, 2];
    idx.sort_by(|&i, &j| a[i][i].total_cmp(&a[j][j]));
    let vals = idx.map(|i| a[i][i]);
    let vecs = idx.map(|i| [v[0][i], v[1][i], v[2][i]]);
    (vals, vecs)
}

//! Geometry kernels shared by the membrane terms: small vector operations, the signed dihedral
//! angle of an edge and its gradients, triangle areas and their gradients, and the enclosed
//! volume.

// ---------------------------------------------------------------------------------------------
// Small vector helpers.

#[inline]
pub(super) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline]
pub(super) fn add_to(a: &mut [f64; 3], b: [f64; 3], s: f64) {
    a[0] += s * b[0];
    a[1] += s * b[1];
    a[2] += s * b[2];
}

#[inline]
pub(super) fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

#[inline]
pub(super) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
pub(super) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline]
pub(super) fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

// ---------------------------------------------------------------------------------------------
// Geometry kernels.

/// Signed dihedral angle of edge `i–j` (opposite vertices `k` in triangle `i→j→k`, `l` in
/// triangle `j→i→l`), positive where the surface is convex, and its gradients with respect to
/// `[x_i, x_j, x_k, x_l]`.
#[inline]
pub(super) fn dihedral(
    xi: [f64; 3],
    xj: [f64; 3],
    xk: [f64; 3],
    xl: [f64; 3],
) -> (f64, [[f64; 3]; 4]) {
    let e = sub(xj, xi);
    let n1 = cross(e, sub(xk, xi));
    let n2 = cross(sub(xi, xj), sub(xl, xj));
    let e2 = dot(e, e);
    let el = e2.sqrt();
    let n1n = dot(n1, n1);
    let n2n = dot(n2, n2);
    let inv = 1.0 / (n1n * n2n).sqrt();
    let cos = dot(n1, n2) * inv;
    let sin = dot(cross(n1, n2), e) * inv / el;
    let theta = sin.atan2(cos);
    // ∇_k θ = −n̂1/h_k = −n1 |e| / |n1|² (|n1| = |e| h_k).
    let gk = scale(n1, -el / n1n);
    let gl = scale(n2, -el / n2n);
    let ak = dot(sub(xk, xi), e) / e2;
    let al = dot(sub(xl, xi), e) / e2;
    let mut gj = scale(gk, -ak);
    add_to(&mut gj, gl, -al);
    let mut gi = scale(gk, ak - 1.0);
    add_to(&mut gi, gl, al - 1.0);
    (theta, [gi, gj, gk, gl])
}

/// Signed dihedral angle only.
#[inline]
pub(super) fn dihedral_angle(xi: [f64; 3], xj: [f64; 3], xk: [f64; 3], xl: [f64; 3]) -> f64 {
    let e = sub(xj, xi);
    let n1 = cross(e, sub(xk, xi));
    let n2 = cross(sub(xi, xj), sub(xl, xj));
    let cos = dot(n1, n2);
    let sin = dot(cross(n1, n2), e) / norm(e);
    sin.atan2(cos)
}

/// Area of triangle `(a, b, c)` and its unit normal `n̂`.
#[inline]
pub(super) fn tri_area(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> (f64, [f64; 3]) {
    let n = cross(sub(b, a), sub(c, a));
    let len = norm(n);
    (0.5 * len, scale(n, 1.0 / len))
}

/// Add `−s ∇A_t` to the forces of triangle `(a, b, c)`: `∇_a A = ½ (x_b − x_c) × n̂` (cyclic).
#[inline]
pub(super) fn add_area_gradient(
    x: &[[f64; 3]],
    tri: [usize; 3],
    nhat: [f64; 3],
    s: f64,
    f: &mut [[f64; 3]],
) {
    let [a, b, c] = tri;
    let h = -0.5 * s;
    add_to(&mut f[a], cross(sub(x[b], x[c]), nhat), h);
    add_to(&mut f[b], cross(sub(x[c], x[a]), nhat), h);
    add_to(&mut f[c], cross(sub(x[a], x[b]), nhat), h);
}

pub(super) fn volume_of(triangles: &[[usize; 3]], x: &[[f64; 3]]) -> f64 {
    triangles
        .iter()
        .map(|&[a, b, c]| dot(x[a], cross(x[b], x[c])))
        .sum::<f64>()
        / 6.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dihedral_sign_and_value() {
        // Convex hinge: θ > 0, equal to the angle between the normals.
        let h: f64 = 0.3;
        let xi = [0.0, 0.0, 0.0];
        let xj = [1.0, 0.0, 0.0];
        let xk = [0.5, 1.0, 0.0];
        let xl = [0.5, -1.0, -h];
        let (theta, _) = dihedral(xi, xj, xk, xl);
        assert!((theta - h.atan()).abs() < 1e-14, "{theta}");
        assert!((dihedral_angle(xi, xj, xk, xl) - theta).abs() < 1e-14);
    }
}

//! A closed spherical-harmonic surface as a triangle mesh in its own angles: `rows` circles of
//! latitude `θ_i = π i/(rows + 1)` (`i = 1..rows`) with `cols` points each at
//! `φ_j = 2π j/cols`, and the two poles, the surface's expansion evaluated at each vertex. It
//! follows the parametrisation, so a long tube parametrised along its axis gets rings along
//! that axis (the walls in ParaView, `vtk/walls.vtp`).

use super::vtk::PolyMesh;
use crate::sph_harmonics::basis::{eval_basis, BasisScratch};
use crate::sph_harmonics::CoefLayout;

/// The surface of order `p` with coefficients `coefs` (`x`, `y`, `z`, `(p+1)² − 1` each) on
/// `rows ≥ 1` latitudes of `cols ≥ 3` points and the poles: `rows · cols + 2` vertices,
/// `2 rows · cols` triangles, no point or cell data.
pub fn surface_mesh(p: usize, coefs: &[f64], rows: usize, cols: usize) -> Result<PolyMesh, String> {
    let lay = CoefLayout::new(p);
    let nc = lay.len();
    if coefs.len() != 3 * nc || rows == 0 || cols < 3 {
        return Err(format!(
            "a surface mesh of order {p} needs 3·{nc} coefficients (got {}), rows ≥ 1 and \
             cols ≥ 3 (got {rows}, {cols})",
            coefs.len()
        ));
    }
    let mut scratch = BasisScratch::new(p);
    let mut row = vec![0.0; nc];
    let mut point = |theta: f64, phi: f64| -> [f64; 3] {
        eval_basis(&lay, theta, phi, &mut scratch, &mut row);
        std::array::from_fn(|a| {
            coefs[a * nc..(a + 1) * nc]
                .iter()
                .zip(&row)
                .map(|(c, b)| c * b)
                .sum()
        })
    };
    let pi = std::f64::consts::PI;
    let mut points = Vec::with_capacity(rows * cols + 2);
    points.push(point(0.0, 0.0));
    for i in 1..=rows {
        let theta = pi * i as f64 / (rows + 1) as f64;
        for j in 0..cols {
            points.push(point(theta, 2.0 * pi * j as f64 / cols as f64));
        }
    }
    points.push(point(pi, 0.0));
    let south = rows * cols + 1;
    let at = |i: usize, j: usize| 1 + i * cols + j % cols;
    let mut triangles = Vec::with_capacity(2 * rows * cols);
    for j in 0..cols {
        triangles.push([0, at(0, j), at(0, j + 1)]);
        triangles.push([south, at(rows - 1, j + 1), at(rows - 1, j)]);
    }
    for i in 0..rows - 1 {
        for j in 0..cols {
            triangles.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            triangles.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    Ok(PolyMesh {
        points,
        triangles,
        point_data: vec![],
        cell_data: vec![],
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vesicle::shapes;

    /// The unit sphere's mesh lies on the sphere, and its triangles face outward (the
    /// divergence theorem gives the enclosed volume, below 4π/3 by the chords).
    #[test]
    fn the_unit_sphere_is_meshed_outward_on_its_surface() {
        let s = shapes::sphere(6, 1.0).unwrap();
        let m = surface_mesh(6, s.coefs(), 20, 40).unwrap();
        assert_eq!(m.points.len(), 20 * 40 + 2);
        assert_eq!(m.triangles.len(), 2 * 20 * 40);
        for x in &m.points {
            let r = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
            assert!((r - 1.0).abs() < 1e-12, "{r}");
        }
        let volume: f64 = m
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|k| m.points[k]);
                (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                    + a[2] * (b[0] * c[1] - b[1] * c[0]))
                    / 6.0
            })
            .sum();
        let exact = 4.0 * std::f64::consts::PI / 3.0;
        assert!(volume > 0.98 * exact && volume < exact, "{volume}");
        assert!(surface_mesh(6, s.coefs(), 0, 40).is_err());
    }
}

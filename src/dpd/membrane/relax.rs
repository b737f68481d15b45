//! Relaxation of a triangulation on a given surface towards nearly equilateral triangles
//! ([`relax_on_surface`]) and the mesh statistics it reports ([`MeshQuality`]).
//!
//! Fedosov et al. (2010) build their RBC from a relaxed, nearly equilateral triangulation, so
//! that the stress-free springs (one rest length per edge) carry a nearly uniform network. A
//! mesh mapped from a parameter domain (the icosphere on a biconcave surface, say) is uneven;
//! this moves its vertices along the surface until the edges have nearly the same length.
//!
//! Each iteration moves every vertex `i` by
//!
//! ```text
//! Δx_i = h P_i Σ_{j∼i} (l_ij − L)/l_ij (x_j − x_i),     P_i = 1 − n̂_i n̂_iᵀ,
//! ```
//!
//! a spring force towards the target length `L` (the current mean edge length) restricted to
//! the tangent plane (`n̂_i` the area-weighted vertex normal of the mesh), and then puts it back
//! on the surface with the caller's projection. The connectivity is not changed; an iteration
//! that would flip a triangle (its normal turned by more than 90°) is undone and retried with
//! half the step.
//!
//! The connectivity limits what relaxation can reach: a patch of valence-6 vertices with equal
//! edges is flat, so with a fixed triangulation the surface's Gaussian curvature must be taken
//! up by unequal edges wherever it is not where the valence-5 (or -7) vertices sit. The
//! icosphere puts its twelve valence-5 vertices where the sphere would; on an ellipsoid or a
//! biconcave disc the edge-length spread shrinks by about half, not to zero (making it vanish
//! would need edge flips, which change the topology and are not done here).

use super::super::{require, DpdError};
use super::energy::check_len;
use super::geometry::{add_to, cross, dot, norm, scale, sub};
use super::topology::MembraneTopology;

/// Edge-length and triangle-shape statistics of a mesh ([`mesh_quality`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshQuality {
    /// Shortest edge.
    pub min_edge: f64,
    /// Longest edge.
    pub max_edge: f64,
    /// Mean edge length.
    pub mean_edge: f64,
    /// Standard deviation of the edge lengths relative to their mean.
    pub edge_cv: f64,
    /// Smallest triangle quality `q = 4√3 A/(l1² + l2² + l3²)` (1 for an equilateral
    /// triangle, 0 for a degenerate one).
    pub min_quality: f64,
    /// Mean triangle quality.
    pub mean_quality: f64,
}

impl MeshQuality {
    /// `min_edge / max_edge` (1 for a uniform mesh).
    pub fn edge_ratio(&self) -> f64 {
        self.min_edge / self.max_edge
    }
}

/// What [`relax_on_surface`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelaxReport {
    /// The mesh before relaxation.
    pub before: MeshQuality,
    /// The mesh after relaxation.
    pub after: MeshQuality,
    /// Iterations carried out (undone ones not counted).
    pub iterations: usize,
    /// Iterations undone because a triangle would have flipped (the step was halved each time).
    pub rejected: usize,
    /// The step at the end (the initial one unless halved).
    pub final_step: f64,
    /// Largest vertex displacement in the last iteration, relative to the mean edge length.
    pub last_max_move: f64,
}

/// Edge-length and triangle-quality statistics of the positions `x` on `topology`.
///
/// Errors: a wrong number of positions.
pub fn mesh_quality(x: &[[f64; 3]], topology: &MembraneTopology) -> Result<MeshQuality, DpdError> {
    check_len("positions", x.len(), topology.n_vertices)?;
    let (mut min_edge, mut max_edge, mut sum, mut sum2) = (f64::INFINITY, 0.0f64, 0.0, 0.0);
    for &[i, j] in &topology.edges {
        let l = norm(sub(x[i], x[j]));
        min_edge = min_edge.min(l);
        max_edge = max_edge.max(l);
        sum += l;
        sum2 += l * l;
    }
    let ne = topology.edges.len() as f64;
    let mean_edge = sum / ne;
    let var = (sum2 / ne - mean_edge * mean_edge).max(0.0);
    let (mut min_quality, mut qsum) = (f64::INFINITY, 0.0);
    for &[a, b, c] in &topology.triangles {
        let q = triangle_quality(x[a], x[b], x[c]);
        min_quality = min_quality.min(q);
        qsum += q;
    }
    Ok(MeshQuality {
        min_edge,
        max_edge,
        mean_edge,
        edge_cv: var.sqrt() / mean_edge,
        min_quality,
        mean_quality: qsum / topology.triangles.len() as f64,
    })
}

/// `4√3 A/(l1² + l2² + l3²)`: 1 for an equilateral triangle.
fn triangle_quality(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
    let n = cross(sub(b, a), sub(c, a));
    let s = dot(sub(b, a), sub(b, a)) + dot(sub(c, b), sub(c, b)) + dot(sub(a, c), sub(a, c));
    2.0 * 3f64.sqrt() * norm(n) / s
}

/// Relax the positions `x` of a closed triangulation (`topology`) on a surface towards equal
/// edge lengths, keeping every vertex on the surface: `iterations` tangential spring steps
/// of size `step` (a fraction of the spring force, `0 < step ≤ 0.5`; 0.2 is a good value),
/// each followed by `project`, which must map a point near the surface to the surface (its
/// closest point, ideally). The vertices are projected once before the first iteration, so
/// they lie on the surface even for `iterations = 0`. Relaxation stops early when no vertex
/// moves by more than `1e-12` mean edge lengths.
///
/// The result is meant as a reference (stress-free) state: build the [`super::Membrane`] from
/// the relaxed positions.
///
/// Errors: a wrong number of positions, a step outside `(0, 0.5]`, or a projection that
/// returns a non-finite point.
pub fn relax_on_surface<P>(
    x: &mut [[f64; 3]],
    topology: &MembraneTopology,
    project: P,
    iterations: usize,
    step: f64,
) -> Result<RelaxReport, DpdError>
where
    P: Fn([f64; 3]) -> [f64; 3],
{
    check_len("positions", x.len(), topology.n_vertices)?;
    require(
        step > 0.0 && step <= 0.5,
        "relaxation step",
        step,
        "must lie in (0, 0.5]",
    )?;
    let project_checked = |v: usize, p: [f64; 3]| -> Result<[f64; 3], DpdError> {
        let q = project(p);
        if q.iter().all(|c| c.is_finite()) {
            Ok(q)
        } else {
            Err(DpdError::Mesh(format!(
                "the projection of vertex {v} at {p:?} is not finite: {q:?}"
            )))
        }
    };
    for (v, p) in x.iter_mut().enumerate() {
        *p = project_checked(v, *p)?;
    }
    let before = mesh_quality(x, topology)?;
    let n = x.len();
    let mut normals = vec![[0.0; 3]; n];
    let mut moves = vec![[0.0; 3]; n];
    let mut trial = x.to_vec();
    let mut tri_normals: Vec<[f64; 3]> = Vec::with_capacity(topology.triangles.len());
    let (mut h, mut done, mut rejected, mut last_max_move) = (step, 0usize, 0usize, 0.0);
    while done < iterations {
        // Vertex normals (area-weighted) and triangle normals of the current mesh.
        normals.iter_mut().for_each(|m| *m = [0.0; 3]);
        tri_normals.clear();
        for &[a, b, c] in &topology.triangles {
            let nt = cross(sub(x[b], x[a]), sub(x[c], x[a]));
            tri_normals.push(nt);
            for v in [a, b, c] {
                add_to(&mut normals[v], nt, 1.0);
            }
        }
        let target = topology
            .edges
            .iter()
            .map(|&[i, j]| norm(sub(x[i], x[j])))
            .sum::<f64>()
            / topology.edges.len() as f64;
        // Spring forces towards the target length.
        moves.iter_mut().for_each(|m| *m = [0.0; 3]);
        for &[i, j] in &topology.edges {
            let d = sub(x[j], x[i]);
            let l = norm(d);
            let s = (l - target) / l;
            add_to(&mut moves[i], d, s);
            add_to(&mut moves[j], d, -s);
        }
        // Tangential step, limited to a quarter of the target length, then projection.
        let mut max_move = 0.0f64;
        for v in 0..n {
            let nv = scale(normals[v], 1.0 / norm(normals[v]));
            let mut m = moves[v];
            let mn = dot(m, nv);
            add_to(&mut m, nv, -mn);
            let mut d = scale(m, h);
            let len = norm(d);
            if len > 0.25 * target {
                d = scale(d, 0.25 * target / len);
            }
            let mut p = x[v];
            add_to(&mut p, d, 1.0);
            trial[v] = project_checked(v, p)?;
            max_move = max_move.max(norm(sub(trial[v], x[v])));
        }
        let flipped = topology
            .triangles
            .iter()
            .zip(&tri_normals)
            .any(|(&[a, b, c], &n0)| {
                dot(cross(sub(trial[b], trial[a]), sub(trial[c], trial[a])), n0) <= 0.0
            });
        if flipped {
            h *= 0.5;
            rejected += 1;
            if h < 1e-12 * step {
                return Err(DpdError::Mesh(
                    "mesh relaxation: every step flips a triangle".into(),
                ));
            }
            continue;
        }
        x.copy_from_slice(&trial);
        done += 1;
        last_max_move = max_move / target;
        if last_max_move < 1e-12 {
            break;
        }
    }
    let after = mesh_quality(x, topology)?;
    Ok(RelaxReport {
        before,
        after,
        iterations: done,
        rejected,
        final_step: h,
        last_max_move,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dpd::membrane::geometry::volume_of;
    use crate::dpd::membrane::test_support::icosphere;

    /// Closest point of the ellipsoid `Σ (x_c/a_c)² = 1` to a point `p` near it: `x_c =
    /// a_c² p_c/(a_c² + t)` with `t > −a_min²` the root of `g(t) = Σ (a_c p_c/(a_c² + t))² − 1`
    /// (decreasing and convex), by Newton's method safeguarded with bisection in the bracket
    /// `(−a_min², a_max |p|]`.
    fn ellipsoid_closest(axes: [f64; 3], p: [f64; 3]) -> [f64; 3] {
        let g = |t: f64| {
            let (mut g, mut dg) = (-1.0, 0.0);
            for c in 0..3 {
                let r = axes[c] * p[c] / (axes[c] * axes[c] + t);
                g += r * r;
                dg -= 2.0 * r * r / (axes[c] * axes[c] + t);
            }
            (g, dg)
        };
        let amin = axes.iter().cloned().fold(f64::INFINITY, f64::min);
        let amax = axes.iter().cloned().fold(0.0, f64::max);
        let (mut lo, mut hi) = (-amin * amin, amax * norm(p));
        let mut t = 0.0f64.clamp(lo, hi);
        for _ in 0..200 {
            let (gt, dg) = g(t);
            if gt > 0.0 {
                lo = t;
            } else {
                hi = t;
            }
            if gt == 0.0 || hi - lo <= 1e-16 * (1.0 + t.abs()) {
                break;
            }
            let next = t - gt / dg;
            let next = if next > lo && next < hi {
                next
            } else {
                0.5 * (lo + hi)
            };
            if (next - t).abs() <= 1e-16 * (1.0 + t.abs()) {
                t = next;
                break;
            }
            t = next;
        }
        std::array::from_fn(|c| axes[c] * axes[c] * p[c] / (axes[c] * axes[c] + t))
    }

    fn ellipsoid_residual(axes: [f64; 3], p: [f64; 3]) -> f64 {
        (0..3).map(|c| (p[c] / axes[c]).powi(2)).sum::<f64>() - 1.0
    }

    #[test]
    fn closest_point_on_ellipsoid() {
        let axes = [1.5, 1.0, 0.6];
        for p in [
            [2.0, 0.3, -0.1],
            [0.5, 0.6, 0.3],
            [0.0, 0.0, 2.0],
            [1.4, 0.0, 0.0],
        ] {
            let q = ellipsoid_closest(axes, p);
            assert!(ellipsoid_residual(axes, q).abs() < 1e-12, "{p:?} {q:?}");
            // p − q is along the normal ∇(Σ x²/a²) at q.
            let g: [f64; 3] = std::array::from_fn(|c| q[c] / (axes[c] * axes[c]));
            let d = sub(p, q);
            assert!(norm(cross(d, g)) <= 1e-12 * norm(g).max(1.0), "{p:?}");
        }
    }

    /// An icosphere stretched onto an ellipsoid (axes 1.5, 1, 0.6): the edge lengths become
    /// more uniform, the triangles better, the vertices stay on the ellipsoid to 1e-9, and no
    /// triangle turns over.
    #[test]
    fn relax_icosphere_on_ellipsoid() {
        let axes = [1.5, 1.0, 0.6];
        let (sphere, t) = icosphere(3);
        let topo = MembraneTopology::new(sphere.len(), &t).unwrap();
        let mut x: Vec<[f64; 3]> = sphere
            .iter()
            .map(|p| std::array::from_fn(|c| axes[c] * p[c]))
            .collect();
        let project = |p: [f64; 3]| ellipsoid_closest(axes, p);
        let r = relax_on_surface(&mut x, &topo, project, 500, 0.2).unwrap();
        println!("{r:#?}");
        assert_eq!(topo.triangles(), &t[..]);
        assert!(r.after.edge_cv < 0.6 * r.before.edge_cv, "{r:?}");
        assert!(r.after.edge_ratio() > r.before.edge_ratio() + 0.2, "{r:?}");
        assert!(r.after.min_quality > r.before.min_quality, "{r:?}");
        assert!(r.after.mean_quality > r.before.mean_quality, "{r:?}");
        for p in &x {
            assert!(ellipsoid_residual(axes, *p).abs() < 1e-9, "{p:?}");
        }
        // Every triangle still faces outwards (its normal along the ellipsoid's at its centre),
        // and the enclosed volume is close to the ellipsoid's.
        for &[a, b, c] in &t {
            let n = cross(sub(x[b], x[a]), sub(x[c], x[a]));
            let m: [f64; 3] = std::array::from_fn(|k| (x[a][k] + x[b][k] + x[c][k]) / 3.0);
            let g: [f64; 3] = std::array::from_fn(|k| m[k] / (axes[k] * axes[k]));
            assert!(dot(n, g) > 0.0);
        }
        let v = volume_of(&t, &x);
        let v_exact = 4.0 / 3.0 * std::f64::consts::PI * axes[0] * axes[1] * axes[2];
        assert!((v / v_exact - 1.0).abs() < 0.02, "{v} {v_exact}");
    }

    /// On the unit sphere the icosphere is nearly uniform already: relaxation keeps it valid.
    #[test]
    fn relax_errors_and_trivial_cases() {
        let (x0, t) = icosphere(2);
        let topo = MembraneTopology::new(x0.len(), &t).unwrap();
        let unit = |p: [f64; 3]| scale(p, 1.0 / norm(p));
        let mut x = x0.clone();
        let r = relax_on_surface(&mut x, &topo, unit, 0, 0.2).unwrap();
        assert_eq!(r.iterations, 0);
        assert_eq!(r.before, r.after);
        let r = relax_on_surface(&mut x, &topo, unit, 200, 0.2).unwrap();
        assert!(r.after.edge_cv <= r.before.edge_cv, "{r:?}");
        assert!(x.iter().all(|p| (norm(*p) - 1.0).abs() < 1e-12));
        assert!(matches!(
            relax_on_surface(&mut x[..10], &topo, unit, 1, 0.2),
            Err(DpdError::Length { .. })
        ));
        for bad in [0.0, -0.1, 0.6, f64::NAN] {
            assert!(matches!(
                relax_on_surface(&mut x, &topo, unit, 1, bad),
                Err(DpdError::Parameter { .. })
            ));
        }
        assert!(matches!(
            relax_on_surface(&mut x, &topo, |_| [f64::NAN; 3], 1, 0.2),
            Err(DpdError::Mesh(_))
        ));
    }
}

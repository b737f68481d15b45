//! `[output] velocity_plane`: the flow's velocity sampled on a grid of points on a plane (a
//! parallelogram) at every frame, e.g. an axial section of a tube with the cells in it.
//!
//! ```toml
//! [output]
//! velocity_plane = { origin = [-8.0, -2.0, 0.0], u = [16.0, 0.0, 0.0], v = [0.0, 4.0, 0.0], points = [161, 41] }
//! ```
//!
//! The points are `origin + u·i/(n_u − 1) + v·j/(n_v − 1)` for `i < n_u`, `j < n_v`
//! (`points = [n_u, n_v]`), stored with `i` fastest. What is sampled:
//! [`crate::timestep::suspension::Suspension::velocity_at`]; where it is written:
//! [`crate::io::plane_frames`].

use super::SceneError;
use crate::linalg3::{cross3, dot3};

/// The largest number of points of a plane (`n_u · n_v`).
pub const MAX_PLANE_POINTS: usize = 1_000_000;

/// A plane grid of sample points: `origin + u·i/(n_u − 1) + v·j/(n_v − 1)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VelocityPlane {
    /// The corner of the parallelogram (`i = j = 0`).
    pub origin: [f64; 3],
    /// The edge from the origin to the corner `i = n_u − 1`.
    pub u: [f64; 3],
    /// The edge from the origin to the corner `j = n_v − 1`.
    pub v: [f64; 3],
    /// `[n_u, n_v]`: points along `u` and along `v` (at least 2 each).
    pub points: [usize; 2],
}

impl VelocityPlane {
    /// The sample points, `i` (along `u`) fastest.
    pub fn sample_points(&self) -> Vec<[f64; 3]> {
        let [nu, nv] = self.points;
        let mut out = Vec::with_capacity(nu * nv);
        for j in 0..nv {
            let b = j as f64 / (nv - 1) as f64;
            for i in 0..nu {
                let a = i as f64 / (nu - 1) as f64;
                out.push(std::array::from_fn(|k| {
                    self.origin[k] + a * self.u[k] + b * self.v[k]
                }));
            }
        }
        out
    }
}

/// `[output] velocity_plane` as written.
#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct PlaneSection {
    pub(super) origin: toml::Spanned<[f64; 3]>,
    pub(super) u: toml::Spanned<[f64; 3]>,
    pub(super) v: toml::Spanned<[f64; 3]>,
    pub(super) points: toml::Spanned<[usize; 2]>,
}

/// Check a plane as written: finite vectors, edges neither zero nor parallel, at least two
/// points a side and at most [`MAX_PLANE_POINTS`] in all.
pub(super) fn validate(
    s: &PlaneSection,
    at: &dyn Fn(std::ops::Range<usize>, String) -> SceneError,
) -> Result<VelocityPlane, SceneError> {
    let key = |k: &str| format!("[output] velocity_plane {k}");
    for (name, v) in [("origin", &s.origin), ("u", &s.u), ("v", &s.v)] {
        if !v.get_ref().iter().all(|x| x.is_finite()) {
            return Err(at(v.span(), format!("{} must be finite", key(name))));
        }
    }
    let (u, v) = (*s.u.get_ref(), *s.v.get_ref());
    let norm = |a: [f64; 3]| dot3(a, a).sqrt();
    for (name, e) in [("u", &s.u), ("v", &s.v)] {
        if norm(*e.get_ref()) == 0.0 {
            return Err(at(e.span(), format!("{} must not be zero", key(name))));
        }
    }
    if norm(cross3(u, v)) <= 1e-9 * norm(u) * norm(v) {
        return Err(at(
            s.v.span(),
            format!(
                "{} is parallel to u: the two edges must span a plane",
                key("v")
            ),
        ));
    }
    let [nu, nv] = *s.points.get_ref();
    if nu < 2 || nv < 2 {
        return Err(at(
            s.points.span(),
            format!(
                "{} must be at least 2 along each edge, got [{nu}, {nv}]",
                key("points")
            ),
        ));
    }
    if nu.saturating_mul(nv) > MAX_PLANE_POINTS {
        return Err(at(
            s.points.span(),
            format!(
                "{} = [{nu}, {nv}] asks for more than {MAX_PLANE_POINTS} points",
                key("points")
            ),
        ));
    }
    Ok(VelocityPlane {
        origin: *s.origin.get_ref(),
        u,
        v,
        points: [nu, nv],
    })
}

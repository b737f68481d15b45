//! Walls from signed distance functions: frozen wall particles and bounce-back.
//!
//! A wall is the region where its signed distance function `d(x)` is positive (the fluid is
//! where `d < 0`). As in Mirheo (Alexeev et al. 2020), the wall is made of frozen particles
//! of the fluid's own density, taken from an equilibrated fluid in a layer of thickness `r_c`
//! behind the surface (`0 ≤ d < r_c`), so a fluid particle near the wall sees the same
//! density of neighbours as in the bulk; frozen particles never move, and their zero velocity
//! in the dissipative force gives the no-slip condition. A fluid particle whose drift ends
//! inside the wall is bounced back: it is moved to where its path met the surface
//! (`d = 0`, found by bisection), then back along the reversed path for the rest of the step,
//! and its velocity is reversed (`v → −v`).
//!
//! Geometries: two parallel planes normal to `z` (a channel of width `gap`, centred in the
//! box), and a cylinder along `x` (a pipe of radius `R` centred in `y, z`).

use serde::Serialize;

use super::{require, DpdError};

/// A wall geometry; the fluid is where [`Wall::sdf`] is negative.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Wall {
    /// Planes `z = lo` and `z = hi`, fluid in between.
    Planes {
        /// The lower plane's `z`.
        lo: f64,
        /// The upper plane's `z`.
        hi: f64,
    },
    /// A cylinder along `x` of radius `radius` around the line `(y, z) = center`.
    Cylinder {
        /// The radius.
        radius: f64,
        /// The axis's `(y, z)`.
        center: [f64; 2],
    },
}

impl Wall {
    /// A channel of width `gap` centred in a box of height `lz`: the wall layers (`r_c` each)
    /// must fit.
    pub fn channel(gap: f64, lz: f64, rc: f64) -> Result<Self, DpdError> {
        require(
            gap.is_finite() && gap > 0.0,
            "wall gap",
            gap,
            "must be positive",
        )?;
        require(
            lz >= gap + 2.0 * rc,
            "box height",
            lz,
            "must be at least the wall gap + 2 rc (room for the frozen wall layers)",
        )?;
        let lo = 0.5 * (lz - gap);
        Ok(Wall::Planes { lo, hi: lo + gap })
    }

    /// A pipe of radius `radius` along `x`, centred in a box of cross-section `ly × lz`.
    pub fn pipe(radius: f64, ly: f64, lz: f64, rc: f64) -> Result<Self, DpdError> {
        require(
            radius.is_finite() && radius > 0.0,
            "wall radius",
            radius,
            "must be positive",
        )?;
        require(
            2.0 * (radius + rc) <= ly.min(lz),
            "box cross-section",
            ly.min(lz),
            "must be at least 2 (radius + rc) (room for the frozen wall layer)",
        )?;
        Ok(Wall::Cylinder {
            radius,
            center: [0.5 * ly, 0.5 * lz],
        })
    }

    /// Signed distance: negative in the fluid, positive in the wall.
    #[inline]
    pub fn sdf(&self, p: [f64; 3]) -> f64 {
        match *self {
            Wall::Planes { lo, hi } => (lo - p[2]).max(p[2] - hi),
            Wall::Cylinder { radius, center } => {
                let (dy, dz) = (p[1] - center[0], p[2] - center[1]);
                (dy * dy + dz * dz).sqrt() - radius
            }
        }
    }

    /// The fluid volume in a box of side `box_len`.
    pub fn fluid_volume(&self, box_len: [f64; 3]) -> f64 {
        match *self {
            Wall::Planes { lo, hi } => box_len[0] * box_len[1] * (hi - lo),
            Wall::Cylinder { radius, .. } => box_len[0] * std::f64::consts::PI * radius * radius,
        }
    }

    /// Bounce a particle back whose drift `x_old → x` (velocity `v` over `dt`) ended in the
    /// wall: returns the new position and velocity. `x_old` must be in the fluid.
    pub fn bounce(&self, x: [f64; 3], v: [f64; 3], dt: f64) -> ([f64; 3], [f64; 3]) {
        let at = |t: f64| [0, 1, 2].map(|k| x[k] - (1.0 - t) * dt * v[k]);
        // Bisection for the crossing time t* in [0, 1] (d(at(0)) < 0 ≤ d(at(1))).
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        if self.sdf(at(0.0)) >= 0.0 {
            // Started in the wall (should not happen): stay put, reversed.
            return (at(0.0), v.map(|c| -c));
        }
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if self.sdf(at(mid)) < 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        // Back from the crossing along −v for the rest of the step.
        let rest = 1.0 - lo;
        let hit = at(lo);
        let back = [0, 1, 2].map(|k| hit[k] - rest * dt * v[k]);
        let out = if self.sdf(back) < 0.0 { back } else { hit };
        (out, v.map(|c| -c))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sdf_signs_and_bounce_back() {
        let w = Wall::channel(6.0, 8.0, 1.0).unwrap();
        assert_eq!(w, Wall::Planes { lo: 1.0, hi: 7.0 });
        assert!(w.sdf([0.0, 0.0, 4.0]) < 0.0 && w.sdf([0.0, 0.0, 0.5]) > 0.0);
        assert!((w.sdf([0.0, 0.0, 7.5]) - 0.5).abs() < 1e-15);
        // A particle moving up by 0.4 from z = 6.8 crosses z = 7 at t = 0.5: it ends at 6.8.
        let (x, v) = w.bounce([0.0, 0.0, 7.2], [0.1, 0.0, 4.0], 0.1);
        // (It retraces its whole path: x goes back to where it started, −0.01.)
        assert!(
            (x[2] - 6.8).abs() < 1e-9 && (x[0] + 0.01).abs() < 1e-9,
            "{x:?}"
        );
        assert_eq!(v, [-0.1, 0.0, -4.0]);
        let c = Wall::pipe(3.0, 10.0, 10.0, 1.0).unwrap();
        assert!((c.sdf([0.0, 5.0, 9.0]) - 1.0).abs() < 1e-15);
        let (x, _) = c.bounce([0.0, 5.0, 8.1], [0.0, 0.0, 2.0], 0.1);
        assert!(c.sdf(x) < 0.0);
        assert!(Wall::channel(7.0, 8.0, 1.0).is_err());
        assert!(Wall::pipe(4.5, 10.0, 10.0, 1.0).is_err());
    }
}

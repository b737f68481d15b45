//! The DPD pair force and its two evaluations: the naive all-pairs reference and the
//! cell-list pass the time step uses.
//!
//! For `r = |x_i − x_j| < r_c`, `e = (x_i − x_j)/r`, `w = 1 − r/r_c`, `v_ij = v_i − v_j`:
//!
//! ```text
//! F_ij = [ a w − γ w_R² (v_ij·e) + σ w_R ξ_ij / √dt ] e,   w_R = w^k,   σ² = 2γ k_BT,
//! ```
//!
//! the conservative, dissipative and random forces of Groot & Warren (1997) with the kernel
//! exponent `k` of Fan et al. (2006) (`k = 1` the standard kernel; `k = 1/4` gives a higher
//! Schmidt number). `ξ_ij = ξ_ji` comes from [`super::rng::pair_noise`], so `F_ji = −F_ij`
//! exactly in exact arithmetic. The fluctuation–dissipation relation `w_D = w_R²`,
//! `σ² = 2γk_BT` (Español & Warren 1995) fixes the temperature.

use super::cell_list::CellList;
use super::rng::pair_noise;
use super::{require, DpdError};

/// Parameters of the pair force.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PairParams {
    /// Conservative (repulsion) amplitude `a`.
    pub a: f64,
    /// Dissipative coefficient `γ`.
    pub gamma: f64,
    /// Thermal energy `k_BT`.
    pub kbt: f64,
    /// Cut-off radius `r_c`.
    pub rc: f64,
    /// Kernel exponent `k` (`w_R = w^k`, `w_D = w^{2k}`).
    pub power: f64,
}

impl PairParams {
    /// Check the parameters.
    pub fn validate(&self) -> Result<(), DpdError> {
        require(
            self.a.is_finite() && self.a >= 0.0,
            "a",
            self.a,
            "must be ≥ 0",
        )?;
        require(
            self.gamma.is_finite() && self.gamma >= 0.0,
            "gamma",
            self.gamma,
            "must be ≥ 0",
        )?;
        require(
            self.kbt.is_finite() && self.kbt >= 0.0,
            "kbt",
            self.kbt,
            "must be ≥ 0",
        )?;
        require(
            self.rc.is_finite() && self.rc > 0.0,
            "rc",
            self.rc,
            "must be positive",
        )?;
        require(
            self.power.is_finite() && self.power > 0.0 && self.power <= 4.0,
            "power",
            self.power,
            "the kernel exponent k must be in (0, 4]",
        )
    }

    /// `σ = √(2γ k_BT)`.
    pub fn sigma(&self) -> f64 {
        (2.0 * self.gamma * self.kbt).sqrt()
    }

    /// The random weight `w_R = w^k` (the dissipative weight is its square).
    #[inline]
    pub fn weight_r(&self, w: f64) -> f64 {
        weight_r(self.power, w)
    }
}

#[inline(always)]
pub(crate) fn weight_r(power: f64, w: f64) -> f64 {
    if power == 1.0 {
        w
    } else if power == 0.5 {
        w.sqrt()
    } else if power == 0.25 {
        w.sqrt().sqrt()
    } else {
        w.powf(power)
    }
}

/// The force on `i` from `j` (one pair, the definition): `d = x_i − x_j` (minimum image),
/// `dv = v_i − v_j`, `xi` the pair's noise, `inv_sqrt_dt = 1/√dt`. Returns the total force and
/// its conservative part.
pub fn pair_force(
    p: &PairParams,
    d: [f64; 3],
    dv: [f64; 3],
    xi: f64,
    inv_sqrt_dt: f64,
) -> ([f64; 3], [f64; 3]) {
    let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    if r >= p.rc || r == 0.0 {
        return ([0.0; 3], [0.0; 3]);
    }
    let e = d.map(|c| c / r);
    let w = 1.0 - r / p.rc;
    let wr = p.weight_r(w);
    let ve = dv[0] * e[0] + dv[1] * e[1] + dv[2] * e[2];
    let fc = p.a * w;
    let f = fc - p.gamma * wr * wr * ve + p.sigma() * wr * xi * inv_sqrt_dt;
    (e.map(|c| f * c), e.map(|c| fc * c))
}

/// Minimum-image difference `a − b` in a periodic box.
#[inline]
pub fn minimum_image(a: [f64; 3], b: [f64; 3], box_len: [f64; 3]) -> [f64; 3] {
    let mut d = [0.0; 3];
    for k in 0..3 {
        let l = box_len[k];
        d[k] = a[k] - b[k];
        d[k] -= l * (d[k] / l).round();
    }
    d
}

/// Reference: the forces by a sum over all pairs with the minimum image (`O(N²)`; the box
/// must be at least `2 r_c` per axis). Returns per-particle forces.
pub fn all_pairs_forces(
    p: &PairParams,
    box_len: [f64; 3],
    x: &[[f64; 3]],
    v: &[[f64; 3]],
    ids: &[u32],
    key: u64,
    dt: f64,
) -> Vec<[f64; 3]> {
    let n = x.len();
    let mut f = vec![[0.0; 3]; n];
    for i in 0..n {
        for j in 0..n {
            if i == j {
                continue;
            }
            let d = minimum_image(x[i], x[j], box_len);
            let dv = [v[i][0] - v[j][0], v[i][1] - v[j][1], v[i][2] - v[j][2]];
            let (fij, _) = pair_force(p, d, dv, pair_noise(key, ids[i], ids[j]), 1.0 / dt.sqrt());
            for k in 0..3 {
                f[i][k] += fij[k];
            }
        }
    }
    f
}

/// Particle state as structure of arrays, sorted by cell.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Particles {
    /// Positions, `x` component.
    pub x: Vec<f64>,
    /// Positions, `y` component.
    pub y: Vec<f64>,
    /// Positions, `z` component.
    pub z: Vec<f64>,
    /// Velocities, `x` component.
    pub vx: Vec<f64>,
    /// Velocities, `y` component.
    pub vy: Vec<f64>,
    /// Velocities, `z` component.
    pub vz: Vec<f64>,
    /// Permanent particle ids (the noise key and the output order).
    pub id: Vec<u32>,
    /// 1 for particles that move, 0 for frozen (wall) particles: the kicks are scaled by it.
    pub moves: Vec<f64>,
}

impl Particles {
    /// Number of particles.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
}

/// Raw force arrays shared by the slab tasks of [`cell_forces`], which write disjoint
/// particle ranges at any one time.
#[derive(Clone, Copy)]
struct ForceOut {
    fx: *mut f64,
    fy: *mut f64,
    fz: *mut f64,
}

// SAFETY: the pointers are only written through in `slab_forces`, and the slabs of one phase
// of `cell_forces` touch disjoint particle ranges (see there).
unsafe impl Send for ForceOut {}
unsafe impl Sync for ForceOut {}

/// The pair forces of all particles from the cell list (`cells` sorted for `pts`), written
/// into `fx, fy, fz` (overwritten). Returns the virial `Σ_{i<j} r_ij · F^C_ij` of the
/// conservative force (for the pressure).
///
/// Each pair is computed once (Newton's third law: `F_ji = −F_ij`, the noise being
/// symmetric), from the half stencil of its lower cell. The work is split into slabs of
/// cells (one `z` layer each); a slab's pairs write its own particles and those of the slab
/// above, so the even slabs run in parallel, then the odd ones (and, with an odd number of
/// layers, the last one alone, as it wraps onto layer 0). Within a slab the order is fixed,
/// so the forces, bit for bit, do not depend on the number of threads.
#[allow(clippy::too_many_arguments)]
pub fn cell_forces(
    p: &PairParams,
    pts: &Particles,
    cells: &CellList,
    key: u64,
    dt: f64,
    fx: &mut [f64],
    fy: &mut [f64],
    fz: &mut [f64],
    virials: &mut Vec<f64>,
) -> f64 {
    use rayon::prelude::*;
    let n = pts.len();
    assert!(
        fx.len() == n && fy.len() == n && fz.len() == n,
        "force arrays of length N"
    );
    fx.fill(0.0);
    fy.fill(0.0);
    fz.fill(0.0);
    let nz = cells.grid.dims[2];
    virials.clear();
    virials.resize(nz, 0.0);
    let out = ForceOut {
        fx: fx.as_mut_ptr(),
        fy: fy.as_mut_ptr(),
        fz: fz.as_mut_ptr(),
    };
    let last_alone = nz % 2 == 1;
    let phase_end = if last_alone { nz - 1 } else { nz };
    for parity in 0..2 {
        let slabs: Vec<usize> = (parity..phase_end).step_by(2).collect();
        let v: Vec<f64> = slabs
            .par_iter()
            // SAFETY: slabs of one parity are two layers apart, so the layers each writes
            // (its own and the next, wrapping only for the last layer, which with an odd count
            // runs alone below) are disjoint.
            .map(|&layer| unsafe { slab_forces(p, pts, cells, key, dt, layer, out) })
            .collect();
        for (&layer, v) in slabs.iter().zip(v) {
            virials[layer] = v;
        }
    }
    if last_alone {
        // SAFETY: no other task runs.
        virials[nz - 1] = unsafe { slab_forces(p, pts, cells, key, dt, nz - 1, out) };
    }
    virials.iter().sum()
}

/// The pairs whose lower cell is in `z` layer `layer`, accumulated into `out` (serial
/// kernel). Returns their conservative virial.
///
/// Cells are numbered with `x` fastest and particles are sorted by cell, so the three cells
/// of a half-stencil row (`dx = −1, 0, 1`) hold one contiguous range of particles, as do a
/// cell and its `+x` neighbour: a cell's candidates are about five ranges, each with one
/// periodic shift. For each particle and range, a branch-free pass computes squared
/// distances and compacts the candidates within `r_c`; the forces of those pairs follow.
///
/// # Safety
/// No other thread may access the particles of layers `layer` and `layer + 1 (mod n_z)` of
/// `out` during the call; `out` points at arrays of `pts.len()` values.
#[allow(clippy::too_many_arguments)]
unsafe fn slab_forces(
    p: &PairParams,
    pts: &Particles,
    cells: &CellList,
    key: u64,
    dt: f64,
    layer: usize,
    out: ForceOut,
) -> f64 {
    let (inv_rc, rc2) = (1.0 / p.rc, p.rc * p.rc);
    let (a, gamma, power) = (p.a, p.gamma, p.power);
    let sigma_dt = p.sigma() / dt.sqrt();
    let (x, y, z, vx, vy, vz, id) = (&pts.x, &pts.y, &pts.z, &pts.vx, &pts.vy, &pts.vz, &pts.id);
    let per_layer = cells.grid.dims[0] * cells.grid.dims[1];
    let mut virial = 0.0;
    // Candidate ranges of a cell (start, end, shift): at most 14.
    let mut segs = [(0usize, 0usize, [0.0f64; 3]); 14];
    let mut hits = [0u32; 256];
    for c in layer * per_layer..(layer + 1) * per_layer {
        let (c0, c1) = (cells.starts[c], cells.starts[c + 1]);
        if c0 == c1 {
            continue;
        }
        // Segment 0: the cell itself (its particles after i), merged with following ranges.
        let mut ns = 1;
        segs[0] = (c0, c1, [0.0; 3]);
        let half = cells.grid.half_neighbours(c);
        // The +x neighbour first (it may extend segment 0), then the rows.
        for &(nc, s) in half[12..].iter().chain(half[..12].iter()) {
            let (b0, b1) = (cells.starts[nc], cells.starts[nc + 1]);
            if b0 == b1 {
                continue;
            }
            let last = &mut segs[ns - 1];
            if last.1 == b0 && last.2 == s && (ns > 1 || nc == c + 1) {
                last.1 = b1;
            } else {
                segs[ns] = (b0, b1, s);
                ns += 1;
            }
        }
        for i in c0..c1 {
            let (xi, yi, zi) = (x[i], y[i], z[i]);
            let (vxi, vyi, vzi, idi) = (vx[i], vy[i], vz[i], id[i]);
            let (mut sx, mut sy, mut sz, mut vir) = (0.0, 0.0, 0.0, 0.0);
            for (q, &(b0, b1, s)) in segs[..ns].iter().enumerate() {
                let b0 = if q == 0 { i + 1 } else { b0 };
                let (xs, ys, zs) = (xi - s[0], yi - s[1], zi - s[2]);
                let mut k = b0;
                while k < b1 {
                    // Branch-free distance pass over a block of candidates.
                    let end = b1.min(k + hits.len());
                    let mut nh = 0usize;
                    let (bx, by, bz) = (&x[k..end], &y[k..end], &z[k..end]);
                    for (m, ((xj, yj), zj)) in bx.iter().zip(by).zip(bz).enumerate() {
                        let dx = xs - xj;
                        let dy = ys - yj;
                        let dz = zs - zj;
                        let r2 = dx * dx + dy * dy + dz * dz;
                        // SAFETY: nh ≤ m < end − k ≤ hits.len().
                        unsafe { *hits.get_unchecked_mut(nh) = (k + m) as u32 };
                        nh += (r2 < rc2) as usize;
                    }
                    k = end;
                    for &j in &hits[..nh] {
                        let j = j as usize;
                        // SAFETY: j < n: it came from a cell's particle range.
                        let (xj, yj, zj, vxj, vyj, vzj, idj) = unsafe {
                            (
                                *x.get_unchecked(j),
                                *y.get_unchecked(j),
                                *z.get_unchecked(j),
                                *vx.get_unchecked(j),
                                *vy.get_unchecked(j),
                                *vz.get_unchecked(j),
                                *id.get_unchecked(j),
                            )
                        };
                        let dx = xs - xj;
                        let dy = ys - yj;
                        let dz = zs - zj;
                        let r2 = dx * dx + dy * dy + dz * dz;
                        if r2 == 0.0 {
                            continue;
                        }
                        let r = r2.sqrt();
                        let inv_r = 1.0 / r;
                        let w = 1.0 - r * inv_rc;
                        let wr = weight_r(power, w);
                        let ve = ((vxi - vxj) * dx + (vyi - vyj) * dy + (vzi - vzj) * dz) * inv_r;
                        let fc = a * w;
                        let f = (fc - gamma * wr * wr * ve
                            + sigma_dt * wr * pair_noise(key, idi, idj))
                            * inv_r;
                        sx += f * dx;
                        sy += f * dy;
                        sz += f * dz;
                        // SAFETY: j is in this layer or the next (the caller's contract).
                        unsafe {
                            *out.fx.add(j) -= f * dx;
                            *out.fy.add(j) -= f * dy;
                            *out.fz.add(j) -= f * dz;
                        }
                        vir += fc * r;
                    }
                }
            }
            // SAFETY: i is in this layer.
            unsafe {
                *out.fx.add(i) += sx;
                *out.fy.add(i) += sy;
                *out.fz.add(i) += sz;
            }
            virial += vir;
        }
    }
    virial
}

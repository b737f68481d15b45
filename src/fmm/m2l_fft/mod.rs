//! M2L by FFT (the scheme of PVFMM: Malhotra & Biros, Commun. Comput. Phys. 2015).
//!
//! The upward equivalent surface of a source box and the downward check surface of a target
//! box of the same level have the same radius (`INNER · h`), so their points lie on one lattice
//! of spacing `δ = 2·INNER·h/(p−1)`, and for boxes at offset `Δ` (in box widths) the check
//! potential is a discrete convolution,
//!
//! `C[j] = Σ_s G_Δ[j − s] φ[s]`,   `G_Δ[m] = K(2hΔ + δ m)`,  `m ∈ [−(p−1), p−1]³`,
//!
//! which on a `(2p)³` grid has no wrap-around for `j ∈ [0, p)³`. Densities are normalised
//! (`φ̃ = h^d φ` per component of degree `d`, see [`super::operators`]), so the kernel
//! spectra `Ĝ_Δ` are needed, at `h = 1`, for the 316 offsets with `2 ≤ |Δ|∞ ≤ 3`.
//! Real data: spectra keep the `p + 1` non-negative frequencies of the last axis.
//!
//! Where the kernel has reflection signs (`K(Rx) = S_out K(x) S_in` for `R = diag(±1)`), only
//! the 56 offsets with no negative component are computed and kept; the others follow as
//! `Ĝ_{RΔ}(k) = S_out Ĝ_Δ(Rk) S_in`. The frequencies are stored in an order that keeps each
//! orbit `{(±k_x, ±k_y, k_z)}` inside one chunk, so a reflected spectrum on a chunk is a
//! permutation of its base spectrum on the same chunk, expanded in cache just before the
//! chunk's products ([`FftM2l::expand_chunk`]). This keeps 56/316 of the table in memory
//! (116 MB instead of 655 MB for the Stokeslet at order 15), which is most of the setup time
//! of a fresh process: the pages of a table written once cost more than its arithmetic.
//!
//! The products run per chunk of [`CHUNK`] frequencies, pair by pair
//! ([`FftM2l::accumulate_chunk`]) or for all children of two neighbouring parents at once
//! ([`FftM2l::accumulate_siblings`]: their child offsets `2Δp + c_i − c_j` take 27 values,
//! so a block of up to 63 products, those whose children do not touch, reads 27 kernel spectra
//! and 8 source chunks from cache).

use std::sync::Arc;

use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};

use super::kernels::Kernel;
use super::operators::{reflection_of, reflection_signs, INNER};
use super::surface::CubeSurface;
use rayon::prelude::*;

mod products;
#[cfg(test)]
mod tests;

pub use products::SiblingPath;
use products::{hadamard, siblings};

/// Frequencies per chunk of the blocked Hadamard products.
pub const CHUNK: usize = 32;

/// Index of the offset `Δ ∈ [−3, 3]³` among the 343 slots.
pub fn offset_index(d: [i32; 3]) -> usize {
    ((d[0] + 3) * 49 + (d[1] + 3) * 7 + (d[2] + 3)) as usize
}

/// Index of the parent offset `Δp ∈ [−1, 1]³` among 27 slots.
pub fn parent_offset_index(d: [i32; 3]) -> usize {
    ((d[0] + 1) * 9 + (d[1] + 1) * 3 + (d[2] + 1)) as usize
}

/// The parent offset `Δp ∈ [−1, 1]³` of slot `slot < 27` (the inverse of
/// [`parent_offset_index`]).
pub fn parent_offset(slot: usize) -> [i32; 3] {
    let s = slot as i32;
    [s / 9 - 1, (s / 3) % 3 - 1, s % 3 - 1]
}

/// Position of octant `o` in its parent (x bit 2, y bit 1, z bit 0, as
/// [`super::box_key::BoxKey::octant`]).
#[cfg(test)]
fn octant_position(o: usize) -> [i32; 3] {
    [(o >> 2) as i32 & 1, (o >> 1) as i32 & 1, o as i32 & 1]
}

/// Index of the difference `e = c_i − c_j ∈ [−1, 1]³` of two octants' positions among 27.
const fn difference_index(i: usize, j: usize) -> usize {
    const fn e(i: usize, j: usize, bit: usize) -> usize {
        ((i >> bit) & 1) + 1 - ((j >> bit) & 1)
    }
    e(i, j, 2) * 9 + e(i, j, 1) * 3 + e(i, j, 0)
}

/// The child offsets of two sibling groups for the 27 parent offsets: target child `i` of a
/// parent at `Δp` from the source's parent and source child `j` are `2Δp + e` apart, `e = c_i −
/// c_j` ([`difference_index`]); per parent offset, the compact offset of each `e`
/// (`u16::MAX` where such children touch).
fn sibling_tables(compact: &[u16]) -> Vec<[u16; 27]> {
    (0..27usize)
        .map(|slot| {
            let dp = parent_offset(slot);
            std::array::from_fn(|e| {
                let ev = parent_offset(e);
                let d = [0, 1, 2].map(|k| 2 * dp[k] + ev[k]);
                if d.iter().any(|c| c.abs() >= 2) {
                    let o = compact[offset_index(d)];
                    debug_assert!(o != u16::MAX, "offset {d:?} without a spectrum");
                    o
                } else {
                    u16::MAX
                }
            })
        })
        .collect()
}

/// Scratch buffers of one thread.
pub struct FftScratch {
    grid: Vec<Complex64>,
    line: Vec<Complex64>,
    fft: Vec<Complex64>,
}

/// Precomputed kernel spectra and FFT plans for one kernel and order.
///
/// Spectra are stored in *position* order, not in the natural order of the frequencies
/// `(i, j, k)`: the positions group each orbit `{(±i, ±j, k)}` of the reflections inside one
/// chunk of [`CHUNK`] positions, so that a reflected offset's spectrum on a chunk is a
/// permutation of its base offset's spectrum on the same chunk
/// ([`FftM2l::expand_chunk`]). Only the base offsets are kept (56 of 316 for the kernels
/// with reflection signs: 116 MB instead of 655 MB for the Stokeslet at order 15).
pub struct FftM2l {
    p: usize,
    n: usize,
    /// Frequencies kept per component: `n · n · (p + 1)`.
    pub nf: usize,
    /// Positions per component: [`FftM2l::n_chunks`] `· CHUNK` (the last chunk padded with
    /// zeros after the `nf` frequencies).
    np: usize,
    dt: usize,
    de: usize,
    /// Position of each natural frequency `(i n + j)(p + 1) + k`.
    pos: Vec<u32>,
    /// The spectra of the base offsets by frequency chunk:
    /// `[base offset][chunk][a][b][re; CHUNK][im; CHUNK]`.
    base_chunks: Vec<f64>,
    /// Per compact offset (0..316): its base offset and reflection pattern (0..8).
    derived: Vec<(u16, u8)>,
    /// Per compact offset: the sign of each `a·de + b` block (`S_out[a] S_in[b]`).
    block_signs: Vec<f64>,
    /// Per chunk and reflection pattern: the position within the chunk that each position
    /// of the reflected spectrum reads, `[chunk][pattern][CHUNK]`.
    within: Vec<u8>,
    /// Per reflection pattern: the sign of the imaginary part (−1 where z is reflected).
    conj: [f64; 8],
    /// Compact index (0..316) of each of the 343 offset slots.
    compact: Vec<u16>,
    /// Per parent offset `Δp ∈ [−1, 1]³` (27 slots, [`parent_offset_index`]): the compact
    /// child offset `2Δp + e` of each octant difference `e` ([`difference_index`]),
    /// `u16::MAX` where such children touch (no M2L between them).
    siblings: Vec<[u16; 27]>,
    /// Number of frequency chunks.
    pub n_chunks: usize,
    lattice: Vec<[usize; 3]>,
    fwd: Arc<dyn Fft<f64>>,
    inv: Arc<dyn Fft<f64>>,
}

/// The positions of the frequencies `(i, j, k)` (natural index `(i n + j) nh + k`): the
/// orbits `{(±i, ±j, k)}` (mod `n`) of 4, then of 2, then of 1 element, each orbit at
/// consecutive positions, so that no orbit straddles a multiple of [`CHUNK`].
fn frequency_positions(n: usize, nh: usize) -> Vec<u32> {
    let neg = |k: usize| (n - k) % n;
    let mut seen = vec![false; n * n];
    // Orbits of (i, j) by size: 4, 2, 1.
    let mut classes: [Vec<Vec<usize>>; 3] = [Vec::new(), Vec::new(), Vec::new()];
    for i in 0..n {
        for j in 0..n {
            if seen[i * n + j] {
                continue;
            }
            let mut orbit: Vec<usize> = Vec::with_capacity(4);
            for (a, b) in [(i, j), (neg(i), j), (i, neg(j)), (neg(i), neg(j))] {
                let ij = a * n + b;
                if !orbit.contains(&ij) {
                    orbit.push(ij);
                    seen[ij] = true;
                }
            }
            let class = match orbit.len() {
                4 => 0,
                2 => 1,
                _ => 2,
            };
            classes[class].push(orbit);
        }
    }
    let mut pos = vec![u32::MAX; n * n * nh];
    let mut next = 0u32;
    for class in &classes {
        for k in 0..nh {
            for orbit in class {
                for &ij in orbit {
                    pos[ij * nh + k] = next;
                    next += 1;
                }
            }
        }
    }
    pos
}

impl FftM2l {
    /// Spectra of `ke` for every well-separated offset at unit half-width (56 computed, the
    /// others by reflection where the kernel allows it).
    pub fn new(ke: &dyn Kernel, surf: &CubeSurface) -> Self {
        Self::build(ke, surf, true)
    }

    /// [`FftM2l::new`], with (`reflect`) or without the reflections.
    fn build(ke: &dyn Kernel, surf: &CubeSurface, reflect: bool) -> Self {
        let p = surf.p;
        let n = 2 * p;
        let nh = p + 1;
        let nf = n * n * nh;
        let n_chunks = nf.div_ceil(CHUNK);
        let (dt, de) = (ke.output_dim(), ke.density_dim());
        let nblk = dt * de;
        let mut planner = FftPlanner::new();
        let fwd = planner.plan_fft_forward(n);
        let inv = planner.plan_fft_inverse(n);
        let mut m2l = FftM2l {
            p,
            n,
            nf,
            np: n_chunks * CHUNK,
            dt,
            de,
            pos: frequency_positions(n, nh),
            base_chunks: Vec::new(),
            derived: Vec::new(),
            block_signs: Vec::new(),
            within: Vec::new(),
            conj: [1.0; 8],
            compact: vec![u16::MAX; 343],
            siblings: Vec::new(),
            n_chunks,
            lattice: surf.lattice.clone(),
            fwd,
            inv,
        };
        let offsets: Vec<[i32; 3]> = (-3i32..=3)
            .flat_map(|dx| (-3i32..=3).flat_map(move |dy| (-3i32..=3).map(move |dz| [dx, dy, dz])))
            .filter(|d| d[0].abs().max(d[1].abs()).max(d[2].abs()) >= 2)
            .collect();
        // The offsets with no negative component (56 of 316) directly; the others are their
        // reflections: with R = sign(d), K(Rx) = S_out K(x) S_in gives the grid samples
        // g_d(m) = S_out g_|d|(Rm) S_in and the spectra ĝ_d(k) = S_out ĝ_|d|(Rk) S_in.
        let signs: Vec<Option<(Vec<f64>, Vec<f64>)>> = (0..8)
            .map(|o| reflection_signs(ke, reflection_of(o)))
            .collect();
        let reflect = reflect && signs.iter().all(Option::is_some);
        let computed: Vec<[i32; 3]> = offsets
            .iter()
            .copied()
            .filter(|d| !reflect || d.iter().all(|&c| c >= 0))
            .collect();
        m2l.base_chunks = m2l.spectra(ke, &computed);
        let mut base = vec![u16::MAX; 343];
        for (b, d) in computed.iter().enumerate() {
            base[offset_index(*d)] = b as u16;
        }
        for (k, d) in offsets.iter().enumerate() {
            m2l.compact[offset_index(*d)] = k as u16;
            let o = if reflect {
                (usize::from(d[0] < 0) << 2) | (usize::from(d[1] < 0) << 1) | usize::from(d[2] < 0)
            } else {
                0
            };
            let b = base[offset_index(d.map(|c| if reflect { c.abs() } else { c }))];
            assert!(b != u16::MAX, "every source offset computed");
            m2l.derived.push((b, o as u8));
            match &signs[o] {
                Some((so, si)) if reflect => m2l
                    .block_signs
                    .extend((0..nblk).map(|blk| so[blk / de] * si[blk % de])),
                _ => m2l.block_signs.extend(std::iter::repeat_n(1.0, nblk)),
            }
        }
        m2l.siblings = sibling_tables(&m2l.compact);
        // Per reflection pattern and chunk: where each position reads (within its chunk).
        let mut order = vec![usize::MAX; m2l.np];
        for (f, &q) in m2l.pos.iter().enumerate() {
            order[q as usize] = f;
        }
        m2l.within = vec![0; n_chunks * 8 * CHUNK];
        for o in 0..8 {
            let (map, conj) = m2l.reflected_frequencies(reflection_of(o));
            m2l.conj[o] = conj;
            for (q, &f) in order.iter().enumerate() {
                let (c, i) = (q / CHUNK, q % CHUNK);
                let from = if f == usize::MAX {
                    i
                } else {
                    let g = m2l.pos[map[f] as usize] as usize;
                    assert_eq!(g / CHUNK, c, "a reflection leaves its chunk");
                    g % CHUNK
                };
                m2l.within[(c * 8 + o) * CHUNK + i] = from as u8;
            }
        }
        m2l
    }

    /// Number of well-separated offsets (316), the compact offsets' range.
    pub fn n_offsets(&self) -> usize {
        self.derived.len()
    }

    /// Length of the buffer [`FftM2l::expand_chunk`] fills: every offset's kernel blocks on
    /// one chunk.
    pub fn kernel_chunk_len(&self) -> usize {
        self.derived.len() * self.dt * self.de * 2 * CHUNK
    }

    /// Mark in `used` (one flag per compact offset) the offsets of the sibling blocks of
    /// parent offset slot `dp`.
    pub fn mark_siblings(&self, dp: usize, used: &mut [bool]) {
        for &o in &self.siblings[dp] {
            if o != u16::MAX {
                used[o as usize] = true;
            }
        }
    }

    /// The kernel blocks of frequency chunk `c` of the compact offsets marked in `used`
    /// (`[offset][a][b][re; CHUNK][im; CHUNK]`; the others are left as they are), each read
    /// from its base offset's chunk: `ĝ_d(q) = s_ab ĝ_|d|(w(q))`, the imaginary part negated
    /// where the reflection flips z.
    pub fn expand_chunk(&self, c: usize, used: &[bool], out: &mut [f64]) {
        let nblk = self.dt * self.de;
        let len = nblk * 2 * CHUNK;
        for (k, &(b, o)) in self.derived.iter().enumerate() {
            if !used[k] {
                continue;
            }
            let src = &self.base_chunks[(b as usize * self.n_chunks + c) * len..][..len];
            let dst = &mut out[k * len..(k + 1) * len];
            let signs = &self.block_signs[k * nblk..(k + 1) * nblk];
            let o = o as usize;
            // Pattern 0 (no reflection) reads each position itself, with conj = 1.
            let w: &[u8; CHUNK] = self.within[(c * 8 + o) * CHUNK..][..CHUNK]
                .try_into()
                .expect("a chunk");
            let conj = self.conj[o];
            for ((d, s), &sg) in dst
                .chunks_exact_mut(2 * CHUNK)
                .zip(src.chunks_exact(2 * CHUNK))
                .zip(signs)
            {
                let (dre, dim) = d.split_at_mut(CHUNK);
                let (sre, sim) = s.split_at(CHUNK);
                let si = sg * conj;
                for i in 0..CHUNK {
                    let from = w[i] as usize;
                    dre[i] = sg * sre[from];
                    dim[i] = si * sim[from];
                }
            }
        }
    }

    /// Spectra of the kernel sampled on the doubled grid for each offset in `offsets`, in
    /// parallel (the direct computation), in the chunked layout of
    /// [`FftM2l::base_chunks`](FftM2l): `[offset][chunk][a][b][re; CHUNK][im; CHUNK]`.
    fn spectra(&self, ke: &dyn Kernel, offsets: &[[i32; 3]]) -> Vec<f64> {
        let (p, n, np, dt, de) = (self.p, self.n, self.np, self.dt, self.de);
        let delta = 2.0 * INNER / (p - 1) as f64;
        let scale = 1.0 / (n * n * n) as f64;
        let wrap = |m: i64| -> usize { m.rem_euclid(n as i64) as usize };
        let lim = p as i64 - 1;
        let nblk = dt * de;
        let mut out = vec![0.0; offsets.len() * nblk * 2 * np];
        out.par_chunks_mut(nblk * 2 * np)
            .zip(offsets)
            .for_each_init(
                || {
                    (
                        self.scratch(),
                        vec![vec![0.0; n * n * n]; dt],
                        vec![0.0; 2 * np],
                    )
                },
                |(scratch, grids, hat), (dst, &[dx, dy, dz])| {
                    let mut unit = vec![0.0; de];
                    let mut val = vec![0.0; dt];
                    for b in 0..de {
                        unit.fill(0.0);
                        unit[b] = 1.0;
                        for mx in -lim..=lim {
                            for my in -lim..=lim {
                                for mz in -lim..=lim {
                                    let r = [
                                        2.0 * dx as f64 + delta * mx as f64,
                                        2.0 * dy as f64 + delta * my as f64,
                                        2.0 * dz as f64 + delta * mz as f64,
                                    ];
                                    val.fill(0.0);
                                    ke.accumulate(r, &unit, [0.0; 3], &mut val);
                                    let idx = (wrap(mx) * n + wrap(my)) * n + wrap(mz);
                                    for a in 0..dt {
                                        grids[a][idx] = val[a] * scale;
                                    }
                                }
                            }
                        }
                        for (a, g) in grids.iter().enumerate() {
                            self.forward_full(g, hat, scratch);
                            // Into the chunked layout: chunk × block × [re; CHUNK][im; CHUNK].
                            let blk = a * de + b;
                            for c in 0..self.n_chunks {
                                let at = (c * nblk + blk) * 2 * CHUNK;
                                let d = &mut dst[at..at + 2 * CHUNK];
                                d[..CHUNK].copy_from_slice(&hat[c * CHUNK..(c + 1) * CHUNK]);
                                d[CHUNK..]
                                    .copy_from_slice(&hat[np + c * CHUNK..np + (c + 1) * CHUNK]);
                            }
                        }
                    }
                },
            );
        out
    }

    /// For the reflection `R`: the stored frequency `g(f)` whose value gives frequency `f`
    /// of the reflected spectrum, `ĝ_R(k) = ĝ(Rk)` (then times the component signs), and the
    /// sign of the imaginary part: the half spectrum (frequency `(i, j, k)` at
    /// `(i n + j)(p+1) + k`, `k ≤ p`) has no `−k_z`, so where `R` negates z it reads
    /// `ĝ(k_x, k_y, −k_z) = conj ĝ(−k_x, −k_y, k_z)` (real samples).
    fn reflected_frequencies(&self, r: [f64; 3]) -> (Vec<u32>, f64) {
        let (n, nh) = (self.n, self.p + 1);
        let neg = |k: usize| (n - k) % n;
        let flip_z = r[2] < 0.0;
        let (fx, fy) = if flip_z {
            (r[0] > 0.0, r[1] > 0.0)
        } else {
            (r[0] < 0.0, r[1] < 0.0)
        };
        let mut map = Vec::with_capacity(self.nf);
        for i in 0..n {
            let si = if fx { neg(i) } else { i };
            for j in 0..n {
                let sj = if fy { neg(j) } else { j };
                for k in 0..nh {
                    map.push(((si * n + sj) * nh + k) as u32);
                }
            }
        }
        (map, if flip_z { -1.0 } else { 1.0 })
    }

    /// Compact offset index (0..316) of a well-separated offset slot.
    pub fn compact_offset(&self, slot: usize) -> usize {
        self.compact[slot] as usize
    }

    /// Length of one box's `comps` components in one frequency chunk.
    pub fn chunk_len(comps: usize) -> usize {
        comps * 2 * CHUNK
    }

    /// Scatter per-box spectra (`boxes × comps × [re; np][im; np]`, position order) into
    /// slots `slots[k]` of chunked storage of `nslots` slots (`chunk × slot × comps × [re;
    /// CHUNK][im; CHUNK]`; other slots are left as they are), chunks in parallel.
    pub fn to_chunks(
        &self,
        per_box: &[f64],
        slots: &[u32],
        comps: usize,
        nslots: usize,
        out: &mut [f64],
    ) {
        let np = self.np;
        let per_chunk = nslots * comps * 2 * CHUNK;
        out.par_chunks_mut(per_chunk)
            .enumerate()
            .for_each(|(c, dst)| {
                let f0 = c * CHUNK;
                for (bx, &slot) in slots.iter().enumerate() {
                    for k in 0..comps {
                        let src = &per_box[(bx * comps + k) * 2 * np..][..2 * np];
                        let at = (slot as usize * comps + k) * 2 * CHUNK;
                        let d = &mut dst[at..at + 2 * CHUNK];
                        d[..CHUNK].copy_from_slice(&src[f0..f0 + CHUNK]);
                        d[CHUNK..].copy_from_slice(&src[np + f0..np + f0 + CHUNK]);
                    }
                }
            });
    }

    /// Gather box `bx`'s spectrum (`comps × [re; np][im; np]`) from chunked storage of `nbox`
    /// boxes.
    pub fn from_chunks(
        &self,
        chunks: &[f64],
        nbox: usize,
        bx: usize,
        comps: usize,
        out: &mut [f64],
    ) {
        let np = self.np;
        let per_chunk = nbox * comps * 2 * CHUNK;
        for c in 0..self.n_chunks {
            let f0 = c * CHUNK;
            for k in 0..comps {
                let s = &chunks[c * per_chunk + (bx * comps + k) * 2 * CHUNK..];
                out[k * 2 * np + f0..][..CHUNK].copy_from_slice(&s[..CHUNK]);
                out[k * 2 * np + np + f0..][..CHUNK].copy_from_slice(&s[CHUNK..2 * CHUNK]);
            }
        }
    }

    /// Within one frequency chunk: `target += Ĝ_o · source` for compact offset `o`, with
    /// `kernels` that chunk's blocks from [`FftM2l::expand_chunk`].
    pub fn accumulate_chunk(&self, kernels: &[f64], o: usize, source: &[f64], target: &mut [f64]) {
        let len = self.dt * self.de * 2 * CHUNK;
        hadamard(
            &kernels[o * len..(o + 1) * len],
            source,
            target,
            self.dt,
            self.de,
        );
    }

    /// The kernel blocks (from `kernels`, one chunk's blocks from [`FftM2l::expand_chunk`])
    /// between the 8 children of a target box and the 8 children of a source box at parent
    /// offset slot `dp` ([`parent_offset_index`]), by the difference `e = c_i − c_j` of target
    /// octant `i` and source octant `j` (the offset is `2Δp + e`): empty where such children
    /// touch (the products skip them).
    pub fn sibling_blocks<'a>(&'a self, kernels: &'a [f64], dp: usize) -> [&'a [f64]; 27] {
        let len = self.dt * self.de * 2 * CHUNK;
        self.siblings[dp].map(|o| {
            if o == u16::MAX {
                &[][..]
            } else {
                &kernels[o as usize * len..(o as usize + 1) * len]
            }
        })
    }

    /// Within one frequency chunk, the M2L between all children of two boxes:
    /// `target[i] += Σ_j Ĝ_{ij} · source[j]` for the 8 target octants `i` and 8 source octants
    /// `j` (`g` from [`FftM2l::sibling_blocks`]; `source`: `8 × de` chunk slices, zeros for
    /// absent children; `target`: `8 × dt`). The same sums as [`FftM2l::accumulate_chunk`] over
    /// the pairs that do not touch (the products of Malhotra & Biros 2015 blocked by siblings),
    /// on the widest [`SiblingPath`] of the CPU: with AVX-512 ordered by octant difference, each
    /// kernel block loaded once for all its pairs; otherwise by target octant, each target's
    /// chunk kept in registers over its partners.
    pub fn accumulate_siblings(&self, g: &[&[f64]; 27], source: &[f64], target: &mut [f64]) {
        siblings(SiblingPath::best(), g, source, target, self.dt, self.de);
    }

    /// [`FftM2l::accumulate_siblings`] on a given instruction set (for tests and benchmarks).
    /// On x86-64, panics where the CPU does not support it; elsewhere, and for kernel shapes
    /// other than 1 × 1, 3 × 3 and 3 × 4, every path runs the portable sums.
    pub fn accumulate_siblings_on(
        &self,
        path: SiblingPath,
        g: &[&[f64]; 27],
        source: &[f64],
        target: &mut [f64],
    ) {
        siblings(path, g, source, target, self.dt, self.de);
    }

    /// Fresh scratch buffers.
    pub fn scratch(&self) -> FftScratch {
        let len = self.n * self.n * (self.p + 1);
        FftScratch {
            grid: vec![Complex64::new(0.0, 0.0); len.max(self.n * self.n * self.n)],
            line: vec![Complex64::new(0.0, 0.0); self.n * self.n * self.n],
            fft: vec![
                Complex64::new(0.0, 0.0);
                self.fwd
                    .get_inplace_scratch_len()
                    .max(self.inv.get_inplace_scratch_len())
            ],
        }
    }

    /// Length of one spectrum of `comps` components.
    pub fn spectrum_len(&self, comps: usize) -> usize {
        comps * 2 * self.np
    }

    /// Half spectrum (`[re; np] [im; np]`, position order) of a full real `n³` grid.
    fn forward_full(&self, real: &[f64], out: &mut [f64], s: &mut FftScratch) {
        let n = self.n;
        for (c, &r) in s.line.iter_mut().zip(real) {
            *c = Complex64::new(r, 0.0);
        }
        self.fwd
            .process_with_scratch(&mut s.line[..n * n * n], &mut s.fft);
        let nh = self.p + 1;
        for i in 0..n {
            for j in 0..n {
                for k in 0..nh {
                    s.grid[(i * n + j) * nh + k] = s.line[(i * n + j) * n + k];
                }
            }
        }
        self.transform_ij(s, false, n);
        self.store(s, out);
    }

    /// `s.grid`'s spectrum into `out` (`[re; np] [im; np]`) at the frequencies' positions,
    /// zeros in the padding.
    fn store(&self, s: &FftScratch, out: &mut [f64]) {
        let (nf, np) = (self.nf, self.np);
        let (re, im) = out[..2 * np].split_at_mut(np);
        for (c, &q) in s.grid[..nf].iter().zip(&self.pos) {
            re[q as usize] = c.re;
            im[q as usize] = c.im;
        }
        re[nf..].fill(0.0);
        im[nf..].fill(0.0);
    }

    /// FFTs of `s.grid` (`n × n × (p+1)`) along one of its first two axes (`axis` 0: along
    /// `i`, 1: along `j`), for the indices `< limit` of the other of the two.
    fn fft_axis(&self, s: &mut FftScratch, axis: usize, limit: usize, inverse: bool) {
        let (n, nh) = (self.n, self.p + 1);
        let plan = if inverse { &self.inv } else { &self.fwd };
        let at = |other: usize, along: usize, k: usize| -> usize {
            let (i, j) = if axis == 0 {
                (along, other)
            } else {
                (other, along)
            };
            (i * n + j) * nh + k
        };
        let mut cnt = 0;
        for other in 0..limit {
            for k in 0..nh {
                for along in 0..n {
                    s.line[cnt * n + along] = s.grid[at(other, along, k)];
                }
                cnt += 1;
            }
        }
        plan.process_with_scratch(&mut s.line[..cnt * n], &mut s.fft);
        cnt = 0;
        for other in 0..limit {
            for k in 0..nh {
                for along in 0..n {
                    s.grid[at(other, along, k)] = s.line[cnt * n + along];
                }
                cnt += 1;
            }
        }
    }

    /// FFTs of `s.grid` (last axis already transformed) along `j` for `i < rows`, then along
    /// `i` for all `j`.
    fn transform_ij(&self, s: &mut FftScratch, inverse: bool, rows: usize) {
        self.fft_axis(s, 1, rows.min(self.n), inverse);
        self.fft_axis(s, 0, self.n, inverse);
    }

    /// Spectrum of an equivalent density on the surface (`de` values per surface point,
    /// interleaved) into `out` (`de` blocks of `[re; np] [im; np]`, position order).
    pub fn spectrum(&self, density: &[f64], out: &mut [f64], s: &mut FftScratch) {
        let (p, n, nh, nf) = (self.p, self.n, self.p + 1, self.nf);
        for b in 0..self.de {
            // Rows along k for i, j < p: real data, FFT of length n, keep p + 1 entries.
            s.line[..p * p * n].fill(Complex64::new(0.0, 0.0));
            for (pt, l) in self.lattice.iter().enumerate() {
                s.line[(l[0] * p + l[1]) * n + l[2]] =
                    Complex64::new(density[pt * self.de + b], 0.0);
            }
            self.fwd
                .process_with_scratch(&mut s.line[..p * p * n], &mut s.fft);
            s.grid[..nf].fill(Complex64::new(0.0, 0.0));
            for i in 0..p {
                for j in 0..p {
                    for k in 0..nh {
                        s.grid[(i * n + j) * nh + k] = s.line[(i * p + j) * n + k];
                    }
                }
            }
            self.transform_ij(s, false, p);
            self.store(s, &mut out[b * 2 * self.np..(b + 1) * 2 * self.np]);
        }
    }

    /// Add the check values (`dt` per surface point, interleaved) of a target spectrum.
    pub fn check_values(&self, spec: &[f64], out: &mut [f64], s: &mut FftScratch) {
        let (p, n, nh, nf) = (self.p, self.n, self.p + 1, self.nf);
        for a in 0..self.dt {
            let (re, im) = spec[a * 2 * self.np..(a + 1) * 2 * self.np].split_at(self.np);
            for (g, &q) in s.grid[..nf].iter_mut().zip(&self.pos) {
                *g = Complex64::new(re[q as usize], im[q as usize]);
            }
            // Inverse along i (all j, k), then along j for i < p.
            self.fft_axis(s, 0, n, true);
            self.fft_axis(s, 1, p, true);
            // Along k: rebuild the full Hermitian row, inverse FFT, real part.
            for i in 0..p {
                for j in 0..p {
                    let row = &mut s.line[(i * p + j) * n..(i * p + j + 1) * n];
                    let src = &s.grid[(i * n + j) * nh..(i * n + j + 1) * nh];
                    row[..nh].copy_from_slice(src);
                    for k in nh..n {
                        row[k] = src[n - k].conj();
                    }
                }
            }
            self.inv
                .process_with_scratch(&mut s.line[..p * p * n], &mut s.fft);
            for (pt, l) in self.lattice.iter().enumerate() {
                out[pt * self.dt + a] += s.line[(l[0] * p + l[1]) * n + l[2]].re;
            }
        }
    }
}

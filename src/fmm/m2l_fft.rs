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

/// `t[a] += Σ_b g[a][b] · s[b]` over `CHUNK` complex frequencies (`[re; CHUNK][im; CHUNK]`
/// blocks), with the target of each frequency kept in registers across `b`.
#[inline(always)]
fn hadamard_body<const DT: usize, const DE: usize>(g: &[f64], src: &[f64], tgt: &mut [f64]) {
    const F: usize = CHUNK;
    let g = &g[..DT * DE * 2 * F];
    let src = &src[..DE * 2 * F];
    let tgt = &mut tgt[..DT * 2 * F];
    for a in 0..DT {
        let (tre, tim) = tgt[a * 2 * F..(a + 1) * 2 * F].split_at_mut(F);
        for f in 0..F {
            let (mut re, mut im) = (tre[f], tim[f]);
            for b in 0..DE {
                let o = (a * DE + b) * 2 * F;
                let (gr, gi) = (g[o + f], g[o + F + f]);
                let (sr, si) = (src[b * 2 * F + f], src[b * 2 * F + F + f]);
                re += gr * sr - gi * si;
                im += gr * si + gi * sr;
            }
            tre[f] = re;
            tim[f] = im;
        }
    }
}

fn hadamard_generic<const DT: usize, const DE: usize>(g: &[f64], src: &[f64], tgt: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2,fma")]
        unsafe fn avx2<const DT: usize, const DE: usize>(g: &[f64], s: &[f64], t: &mut [f64]) {
            hadamard_body::<DT, DE>(g, s, t)
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX2 and FMA (checked just above).
            unsafe { avx2::<DT, DE>(g, src, tgt) };
            return;
        }
    }
    hadamard_body::<DT, DE>(g, src, tgt)
}

/// `c + a·b`, fused where the caller is compiled for FMA.
#[inline(always)]
fn madd<const FMA: bool>(a: f64, b: f64, c: f64) -> f64 {
    if FMA {
        a.mul_add(b, c)
    } else {
        a * b + c
    }
}

/// The `CHUNK` values of `s` from `at`.
#[inline(always)]
fn lane(s: &[f64], at: usize) -> &[f64; CHUNK] {
    s[at..at + CHUNK].try_into().expect("a chunk")
}

/// `t[i][a] += Σ_j Σ_b g[e(i, j)][a][b] · s[j][b]` over `CHUNK` complex frequencies
/// (`e` = [`difference_index`]; touching children skipped), for the 8
/// target and 8 source octants of two sibling groups; each target component is summed in
/// local arrays (registers) over its 8 · `DE` partners, then added once.
#[inline(always)]
fn siblings_body<const DT: usize, const DE: usize, const FMA: bool>(
    g: &[&[f64]; 27],
    src: &[f64],
    tgt: &mut [f64],
) {
    const F: usize = CHUNK;
    let src = &src[..8 * DE * 2 * F];
    let tgt = &mut tgt[..8 * DT * 2 * F];
    for (i, ti) in tgt.chunks_exact_mut(DT * 2 * F).enumerate() {
        for a in 0..DT {
            let (mut re, mut im) = ([0.0; F], [0.0; F]);
            for j in 0..8 {
                let gij = g[difference_index(i, j)];
                if gij.is_empty() {
                    // Touching children: no M2L between them.
                    continue;
                }
                for b in 0..DE {
                    let o = (a * DE + b) * 2 * F;
                    let (gr, gi) = (lane(gij, o), lane(gij, o + F));
                    let so = (j * DE + b) * 2 * F;
                    let (sr, si) = (lane(src, so), lane(src, so + F));
                    for f in 0..F {
                        re[f] = madd::<FMA>(gr[f], sr[f], re[f]);
                        re[f] = madd::<FMA>(-gi[f], si[f], re[f]);
                        im[f] = madd::<FMA>(gr[f], si[f], im[f]);
                        im[f] = madd::<FMA>(gi[f], sr[f], im[f]);
                    }
                }
            }
            let (tre, tim) = ti[a * 2 * F..(a + 1) * 2 * F].split_at_mut(F);
            for f in 0..F {
                tre[f] += re[f];
                tim[f] += im[f];
            }
        }
    }
}

/// The instruction sets the sibling products ([`FftM2l::accumulate_siblings`]) can run on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SiblingPath {
    /// The loop by target octant (each target's sums kept over its partners) without FMA:
    /// the reference.
    Portable,
    /// The loop by target octant compiled for AVX2 and FMA.
    Avx2,
    /// AVX-512 registers, the products ordered by octant difference (x86-64 only).
    Avx512,
}

impl SiblingPath {
    /// The widest path this CPU runs (the one [`FftM2l::accumulate_siblings`] takes).
    pub fn best() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f") {
                return SiblingPath::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                return SiblingPath::Avx2;
            }
        }
        SiblingPath::Portable
    }

    /// The paths this CPU runs, the reference first.
    pub fn available() -> Vec<Self> {
        let mut paths = vec![SiblingPath::Portable];
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                paths.push(SiblingPath::Avx2);
            }
            if std::arch::is_x86_feature_detected!("avx512f") {
                paths.push(SiblingPath::Avx512);
            }
        }
        paths
    }
}

fn siblings_generic<const DT: usize, const DE: usize>(
    path: SiblingPath,
    g: &[&[f64]; 27],
    src: &[f64],
    tgt: &mut [f64],
) {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2,fma")]
        unsafe fn avx2<const DT: usize, const DE: usize>(
            g: &[&[f64]; 27],
            s: &[f64],
            t: &mut [f64],
        ) {
            siblings_body::<DT, DE, true>(g, s, t)
        }
        match path {
            SiblingPath::Avx512 => {
                assert!(std::arch::is_x86_feature_detected!("avx512f"));
                // SAFETY: the CPU supports AVX-512F (asserted just above).
                unsafe { by_difference::siblings::<DT, DE>(g, src, tgt) };
                return;
            }
            SiblingPath::Avx2 => {
                assert!(
                    std::arch::is_x86_feature_detected!("avx2")
                        && std::arch::is_x86_feature_detected!("fma")
                );
                // SAFETY: the CPU supports AVX2 and FMA (asserted just above).
                unsafe { avx2::<DT, DE>(g, src, tgt) };
                return;
            }
            SiblingPath::Portable => {}
        }
    }
    let _ = path;
    siblings_body::<DT, DE, false>(g, src, tgt)
}

/// The sibling products on AVX-512, ordered by octant difference.
///
/// For one vector of 8 frequencies, one target component `a` and one half of the target
/// octants (those with the same `x` bit), the sums of the 4 target octants stay in 8 registers
/// and the 8 source octants of one source component `b` are loaded into 16. Each of the 27
/// kernel blocks `Ĝ_e` is then loaded once and applied to every pair `(i, j)` of the half with
/// `c_i − c_j = e`. The pairs of each `e` are compile-time constants, so the sums and sources
/// are indexed by constants and never leave the registers. Per complex multiply-add (4 FMAs)
/// this loads about half a vector (the sources once per half, each kernel value once or twice
/// per block), against two in [`siblings_body`], whose every product loads its kernel and its
/// source value. That loop's `one load per FMA` held the Stokeslet's blocks at 45–50 % of
/// GEMM on an AVX-512 core (`examples/m2l_roofline.rs`; 50–62 % with this one).
#[cfg(target_arch = "x86_64")]
mod by_difference {
    use super::{difference_index, CHUNK};
    use std::arch::x86_64::{
        __m512d, _mm512_add_pd, _mm512_fmadd_pd, _mm512_fnmadd_pd, _mm512_loadu_pd,
        _mm512_setzero_pd, _mm512_storeu_pd,
    };

    /// Frequencies per AVX-512 vector.
    const W: usize = 8;
    const _: () = assert!(CHUNK.is_multiple_of(W), "a chunk is whole AVX-512 vectors");

    /// The source octant `j` with `c_i − c_j = e` for target octant `i`, or 8 where there is
    /// none.
    const fn partner(e: usize, i: usize) -> usize {
        let mut j = 0;
        while j < 8 {
            if difference_index(i, j) == e {
                return j;
            }
            j += 1;
        }
        8
    }

    /// The sums of the 4 target octants of one half (`x` bit `H`), real and imaginary parts.
    type Sums = [[__m512d; 2]; 4];

    /// One source component of the 8 source octants, real and imaginary parts.
    type Sources = [[__m512d; 2]; 8];

    /// Whether some target octant of half `H` has a partner at difference `E`.
    const fn has_pairs(e: usize, h: usize) -> bool {
        let mut k = 0;
        while k < 4 {
            if partner(e, 4 * h + k) < 8 {
                return true;
            }
            k += 1;
        }
        false
    }

    /// `acc[K] += ĝ · s[j]` for target octant `4H + K` and `j` = [`partner`]`(E, 4H + K)`,
    /// if any.
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn pair<const E: usize, const H: usize, const K: usize>(
        gr: __m512d,
        gi: __m512d,
        s: &Sources,
        acc: &mut Sums,
    ) {
        let j = const { partner(E, 4 * H + K) };
        if j < 8 {
            let [sr, si] = s[j];
            let [re, im] = &mut acc[K];
            *re = _mm512_fmadd_pd(gr, sr, *re);
            *re = _mm512_fnmadd_pd(gi, si, *re);
            *im = _mm512_fmadd_pd(gr, si, *im);
            *im = _mm512_fmadd_pd(gi, sr, *im);
        }
    }

    /// The pairs at difference `E` of half `H`, with the kernel value at offset `o` of
    /// block `g[E]` (null where those children touch).
    ///
    /// # Safety
    /// A non-null `g[E]` holds at least `o + CHUNK + W` values.
    #[inline]
    #[target_feature(enable = "avx512f")]
    unsafe fn difference<const E: usize, const H: usize>(
        g: &[*const f64; 27],
        o: usize,
        s: &Sources,
        acc: &mut Sums,
    ) {
        if !const { has_pairs(E, H) } || g[E].is_null() {
            return;
        }
        // SAFETY: the caller's bound.
        let (gr, gi) = unsafe {
            (
                _mm512_loadu_pd(g[E].add(o)),
                _mm512_loadu_pd(g[E].add(o + CHUNK)),
            )
        };
        pair::<E, H, 0>(gr, gi, s, acc);
        pair::<E, H, 1>(gr, gi, s, acc);
        pair::<E, H, 2>(gr, gi, s, acc);
        pair::<E, H, 3>(gr, gi, s, acc);
    }

    /// Half `H` of the target octants (those with `x` bit `H`) for target component `a` and
    /// frequency vector `v`: the 8 source octants of each source component are loaded into
    /// registers once, then every kernel value once for all its pairs in the half.
    ///
    /// # Safety
    /// Every non-null `g[e]` holds `DT · DE · 2 · CHUNK` values.
    #[inline]
    #[target_feature(enable = "avx512f")]
    unsafe fn half<const H: usize, const DT: usize, const DE: usize>(
        g: &[*const f64; 27],
        src: &[f64],
        tgt: &mut [f64],
        a: usize,
        v: usize,
    ) {
        let src = &src[..8 * DE * 2 * CHUNK];
        let mut acc: Sums = [[_mm512_setzero_pd(); 2]; 4];
        for b in 0..DE {
            let s: Sources = std::array::from_fn(|j| {
                let at = &src[(j * DE + b) * 2 * CHUNK + v * W..][..CHUNK + W];
                // SAFETY: `at` holds `CHUNK + W` values.
                unsafe {
                    [
                        _mm512_loadu_pd(at.as_ptr()),
                        _mm512_loadu_pd(at.as_ptr().add(CHUNK)),
                    ]
                }
            });
            let o = (a * DE + b) * 2 * CHUNK + v * W;
            macro_rules! differences {
                ($($e:literal)*) => {
                    // SAFETY: `o + CHUNK + W ≤ DT · DE · 2 · CHUNK` (a < DT, b < DE, v < CHUNK / W).
                    $(unsafe { difference::<$e, H>(g, o, &s, &mut acc) };)*
                };
            }
            differences!(0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20 21 22 23 24 25 26);
        }
        for (k, [re, im]) in acc.iter().enumerate() {
            let t = &mut tgt[((4 * H + k) * DT + a) * 2 * CHUNK + v * W..][..CHUNK + W];
            let p = t.as_mut_ptr();
            // SAFETY: `t` holds `CHUNK + W` values: the real part's `W` at 0, the imaginary
            // part's at `CHUNK`.
            unsafe {
                _mm512_storeu_pd(p, _mm512_add_pd(_mm512_loadu_pd(p), *re));
                let q = p.add(CHUNK);
                _mm512_storeu_pd(q, _mm512_add_pd(_mm512_loadu_pd(q), *im));
            }
        }
    }

    /// [`super::siblings_body`]'s sums (`t[i][a] += Σ_j Σ_b g[e(i, j)][a][b] · s[j][b]`),
    /// ordered by difference.
    ///
    /// # Safety
    /// The CPU must support AVX-512F.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn siblings<const DT: usize, const DE: usize>(
        g: &[&[f64]; 27],
        src: &[f64],
        tgt: &mut [f64],
    ) {
        let src = &src[..8 * DE * 2 * CHUNK];
        let tgt = &mut tgt[..8 * DT * 2 * CHUNK];
        let g: [*const f64; 27] = g.map(|ge| {
            if ge.is_empty() {
                std::ptr::null()
            } else {
                assert!(ge.len() >= DT * DE * 2 * CHUNK, "a short kernel block");
                ge.as_ptr()
            }
        });
        for v in 0..CHUNK / W {
            for a in 0..DT {
                // SAFETY: the non-null blocks were checked just above.
                unsafe {
                    half::<0, DT, DE>(&g, src, tgt, a, v);
                    half::<1, DT, DE>(&g, src, tgt, a, v);
                }
            }
        }
    }
}

/// The sibling products on `path` for the kernels' shapes ([`siblings_body`] or
/// `by_difference::siblings`), any other shape through the pair-by-pair sum.
fn siblings(
    path: SiblingPath,
    g: &[&[f64]; 27],
    src: &[f64],
    tgt: &mut [f64],
    dt: usize,
    de: usize,
) {
    match (dt, de) {
        (1, 1) => siblings_generic::<1, 1>(path, g, src, tgt),
        (3, 3) => siblings_generic::<3, 3>(path, g, src, tgt),
        (3, 4) => siblings_generic::<3, 4>(path, g, src, tgt),
        _ => {
            let (sl, tl) = (de * 2 * CHUNK, dt * 2 * CHUNK);
            for i in 0..8 {
                for j in (0..8).filter(|&j| !g[difference_index(i, j)].is_empty()) {
                    hadamard(
                        g[difference_index(i, j)],
                        &src[j * sl..(j + 1) * sl],
                        &mut tgt[i * tl..(i + 1) * tl],
                        dt,
                        de,
                    );
                }
            }
        }
    }
}

/// `target[a] += Σ_b Ĝ[a][b] · source[b]` on one frequency chunk.
fn hadamard(g: &[f64], src: &[f64], tgt: &mut [f64], dt: usize, de: usize) {
    match (dt, de) {
        (1, 1) => hadamard_generic::<1, 1>(g, src, tgt),
        (3, 3) => hadamard_generic::<3, 3>(g, src, tgt),
        (3, 4) => hadamard_generic::<3, 4>(g, src, tgt),
        _ => {
            // Any other shape: the same sum without compile-time sizes.
            let f = CHUNK;
            for a in 0..dt {
                for b in 0..de {
                    let o = (a * de + b) * 2 * f;
                    for k in 0..f {
                        let (gr, gi) = (g[o + k], g[o + f + k]);
                        let (sr, si) = (src[b * 2 * f + k], src[b * 2 * f + f + k]);
                        tgt[a * 2 * f + k] += gr * sr - gi * si;
                        tgt[a * 2 * f + f + k] += gr * si + gi * sr;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fmm::kernels::{Laplace, Stokeslet, StokesletSource};

    /// The spectra obtained by reflecting the 56 offsets with no negative component equal
    /// the ones computed directly for all 316 offsets, on every chunk.
    #[test]
    fn reflected_spectra_equal_the_direct_ones() {
        let kernels: [&dyn Kernel; 3] = [&Laplace, &Stokeslet, &StokesletSource];
        for ke in kernels {
            let surf = CubeSurface::new(4);
            let (a, b) = (
                FftM2l::build(ke, &surf, true),
                FftM2l::build(ke, &surf, false),
            );
            assert_eq!(a.base_chunks.len() * 316, b.base_chunks.len() * 56);
            let used = vec![true; a.n_offsets()];
            let (mut ka, mut kb) = (
                vec![0.0; a.kernel_chunk_len()],
                vec![0.0; b.kernel_chunk_len()],
            );
            let scale = b.base_chunks.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for c in 0..a.n_chunks {
                a.expand_chunk(c, &used, &mut ka);
                b.expand_chunk(c, &used, &mut kb);
                let err = ka
                    .iter()
                    .zip(&kb)
                    .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
                assert!(
                    err <= 1e-13 * scale,
                    "{} chunk {c}: {err:e} of {scale:e}",
                    ke.name()
                );
            }
        }
    }

    /// The positions put each frequency once, group every reflection orbit inside one chunk,
    /// and leave only the last chunk's tail as padding, for even and odd orders.
    #[test]
    fn frequency_positions_keep_reflection_orbits_in_one_chunk() {
        for p in [3usize, 4, 6, 10, 15] {
            let (n, nh) = (2 * p, p + 1);
            let pos = frequency_positions(n, nh);
            let nf = n * n * nh;
            let mut seen = vec![false; nf];
            for &q in &pos {
                assert!(
                    (q as usize) < nf && !seen[q as usize],
                    "p = {p}: position {q}"
                );
                seen[q as usize] = true;
            }
            let neg = |k: usize| (n - k) % n;
            for i in 0..n {
                for j in 0..n {
                    for k in 0..nh {
                        let c = pos[(i * n + j) * nh + k] as usize / CHUNK;
                        for (a, b) in [(neg(i), j), (i, neg(j)), (neg(i), neg(j))] {
                            assert_eq!(pos[(a * n + b) * nh + k] as usize / CHUNK, c);
                        }
                    }
                }
            }
        }
    }

    /// `octant_position` is where `BoxKey` puts a child: its anchor is twice its parent's plus
    /// the position (in child widths), for every octant.
    #[test]
    fn octant_positions_follow_the_box_keys() {
        use crate::fmm::box_key::BoxKey;
        let parent = BoxKey::from_anchor(3, [3 << 18, 5 << 18, 6 << 18]).expect("in the cube");
        let pa = parent.anchor();
        for o in 0..8 {
            let c = octant_position(o);
            let w = parent.width() / 2;
            let anchor = [0, 1, 2].map(|k| (pa[k] + c[k] as u64 * w) as i64);
            let child = BoxKey::from_anchor(4, anchor).expect("in the cube");
            assert_eq!(child.octant(), o, "octant {o} at {c:?}");
            assert_eq!(child.parent(), Some(parent));
        }
    }

    /// The 8 × 8 sibling products equal the pair-by-pair products over the children that do
    /// not touch, for every parent offset, every kernel shape and every instruction set this
    /// CPU runs.
    #[test]
    fn sibling_blocks_equal_the_pairwise_products() {
        let kernels: [&dyn Kernel; 3] = [&Laplace, &Stokeslet, &StokesletSource];
        for ke in kernels {
            let m2l = FftM2l::new(ke, &CubeSurface::new(4));
            let (de, dt) = (ke.density_dim(), ke.output_dim());
            let (sl, tl) = (FftM2l::chunk_len(de), FftM2l::chunk_len(dt));
            let mut seed = 1u64;
            let mut next = || {
                seed = seed
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            };
            let src: Vec<f64> = (0..8 * sl).map(|_| next()).collect();
            let start: Vec<f64> = (0..8 * tl).map(|_| next()).collect();
            let used = vec![true; m2l.n_offsets()];
            let mut kernels = vec![0.0; m2l.kernel_chunk_len()];
            for dp in (0..27).filter(|&d| d != 13) {
                for c in [0, m2l.n_chunks - 1] {
                    m2l.expand_chunk(c, &used, &mut kernels);
                    let mut pairs = start.clone();
                    let dpv = parent_offset(dp);
                    assert_eq!(parent_offset_index(dpv), dp);
                    let mut n = 0;
                    for i in 0..8 {
                        for j in 0..8 {
                            let (ci, cj) = (octant_position(i), octant_position(j));
                            let d = [0, 1, 2].map(|k| 2 * dpv[k] + ci[k] - cj[k]);
                            if d.iter().all(|x| x.abs() <= 1) {
                                continue;
                            }
                            n += 1;
                            let o = m2l.compact_offset(offset_index(d));
                            m2l.accumulate_chunk(
                                &kernels,
                                o,
                                &src[j * sl..(j + 1) * sl],
                                &mut pairs[i * tl..(i + 1) * tl],
                            );
                        }
                    }
                    assert!((48..=63).contains(&n), "parent offset {dpv:?}: {n} pairs");
                    let scale = pairs.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                    for path in SiblingPath::available() {
                        let mut blocked = start.clone();
                        m2l.accumulate_siblings_on(
                            path,
                            &m2l.sibling_blocks(&kernels, dp),
                            &src,
                            &mut blocked,
                        );
                        let err = blocked
                            .iter()
                            .zip(&pairs)
                            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
                        assert!(
                            err <= 64.0 * f64::EPSILON * scale,
                            "{} {path:?} dp {dpv:?} chunk {c}: {err:e} of {scale:e}",
                            ke.name()
                        );
                    }
                }
            }
        }
    }
}

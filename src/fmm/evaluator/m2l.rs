//! The M2L of one level of the downward pass, by FFT, in parts that bound the spectra's memory.

use super::*;

/// The default most bytes of the M2L's chunked spectra at once (2 GiB). A level whose V-list
/// sources and targets need more (at 6 digits, Stokeslet: about 0.4 MB per box, so a level of
/// more than about 5000 boxes) runs in parts of consecutive target boxes, split between
/// sibling groups, each part with the spectra of its own sources: the sources near a split
/// are transformed once per part that needs them. Before it a 10⁴-cell suspension at p = 12
/// (1.2·10⁷ upsampled sources) peaked at 22.6 GiB on a 24 GiB machine (`benches/RESULTS.md`).
pub const M2L_BUFFER_BYTES: usize = 2 << 30;

/// The M2L's source and target spectra by frequency chunk, for one downward pass.
#[derive(Default)]
pub(super) struct M2lBuffers {
    src: Vec<f64>,
    tgt: Vec<f64>,
}

/// The first `n` values of `v`, zeroed in parallel (`v` grown to `n` if shorter, and kept at
/// its largest length, so a later level that fits reuses it).
fn zeroed(v: &mut Vec<f64>, n: usize) -> &mut [f64] {
    if v.len() < n {
        // Free the old buffer first; the new one comes as untouched zero pages.
        *v = Vec::new();
        *v = vec![0.0; n];
    }
    let head = &mut v[..n];
    head.par_chunks_mut(1 << 16).for_each(|c| c.fill(0.0));
    head
}

impl Fmm {
    /// M2L into the check potentials of the target boxes `sel` (one level), in parts whose
    /// chunked spectra fit [`Fmm::set_m2l_buffer_bytes`] ([`Fmm::m2l_parts`]).
    pub(super) fn m2l_level(
        &self,
        sel: &[usize],
        up: &[f64],
        check: &mut [f64],
        buffers: &mut M2lBuffers,
        clock: &PhaseClock,
    ) {
        let nc = self.ops.n_check();
        let t = Instant::now();
        let parts = self.m2l_parts(sel);
        clock.add(2, t);
        for (range, plan) in parts {
            let rows = &mut check[range.start * nc..range.end * nc];
            self.m2l_part(&plan, up, rows, buffers, clock);
        }
    }

    /// Bytes of the chunked spectra a plan needs (its source and target slots).
    fn m2l_bytes(&self, plan: &M2lPlan) -> usize {
        let de = self.ops.degrees.len();
        let dt = self.near.output_dim();
        let slots = plan.n_source_slots * FftM2l::chunk_len(de)
            + plan.n_target_slots * FftM2l::chunk_len(dt);
        slots * self.m2l.n_chunks * std::mem::size_of::<f64>()
    }

    /// `sel` split into consecutive parts, each with its plan, whose chunked spectra fit the
    /// budget: halves, split at the nearest change of parent after the middle (so a sibling
    /// group stays in one part and its blocks are those of the whole level), until each part
    /// fits or holds one sibling group.
    fn m2l_parts(&self, sel: &[usize]) -> Vec<(std::ops::Range<usize>, M2lPlan)> {
        let parent = |i: usize| self.tree.boxes[sel[i]].parent;
        let mut parts = Vec::new();
        let mut todo = Vec::new();
        todo.push(0..sel.len());
        while let Some(r) = todo.pop() {
            let plan = M2lPlan::new(&self.tree, &self.m2l, &sel[r.clone()], self.m2l_dense_pairs);
            let mut mid = r.start + r.len() / 2;
            while mid < r.end && mid > r.start && parent(mid) == parent(mid - 1) {
                mid += 1;
            }
            // One sibling group (or one box) is not split further.
            if self.m2l_bytes(&plan) <= self.m2l_buffer_bytes || mid == r.end || mid == r.start {
                parts.push((r, plan));
                continue;
            }
            // The first half is taken next, so the parts come in order.
            todo.push(mid..r.end);
            todo.push(r.start..mid);
        }
        parts
    }

    /// The M2L of one part of a level (`check`: its target boxes' rows): spectra of the V-list
    /// sources, blocked Hadamard products per frequency chunk (8 × 8 sibling blocks in uniform
    /// regions, pairs elsewhere: [`M2lPlan`]), one inverse FFT per target box.
    fn m2l_part(
        &self,
        plan: &M2lPlan,
        up: &[f64],
        check: &mut [f64],
        buffers: &mut M2lBuffers,
        clock: &PhaseClock,
    ) {
        let ne = self.ops.n_equiv();
        let de = self.ops.degrees.len();
        let dt = self.near.output_dim();
        let nc = self.ops.n_check();
        let nf2 = self.m2l.spectrum_len(1);
        let mut t = Instant::now();
        if plan.blocks.is_empty() && plan.pairs.is_empty() {
            return;
        }
        self.m2l_peak_bytes
            .fetch_max(self.m2l_bytes(plan), std::sync::atomic::Ordering::Relaxed);
        let (nss, nts) = (plan.n_source_slots, plan.n_target_slots);
        let (sl, tl) = (FftM2l::chunk_len(de), FftM2l::chunk_len(dt));
        let nch = self.m2l.n_chunks;
        // The chunked spectra of sources and targets (zeros where a slot has no box).
        let src = zeroed(&mut buffers.src, nch * nss * sl);
        let tgt = zeroed(&mut buffers.tgt, nch * nts * tl);
        // Spectra of the sources, a batch at a time, scattered into their slots.
        const BATCH: usize = 256;
        let mut batch = vec![0.0; BATCH.min(plan.sources.len()) * de * nf2];
        for part in plan.sources.chunks(BATCH) {
            batch[..part.len() * de * nf2]
                .par_chunks_mut(de * nf2)
                .zip(part)
                .for_each_init(
                    || self.m2l.scratch(),
                    |s, (dst, &(_, bx))| self.m2l.spectrum(&up[bx * ne..(bx + 1) * ne], dst, s),
                );
            let slots: Vec<u32> = part.iter().map(|&(slot, _)| slot).collect();
            self.m2l.to_chunks(&batch, &slots, de, nss, src);
        }
        t = clock.add(2, t);
        // The kernel offsets this level uses, expanded per chunk from their base offsets.
        let mut used = vec![false; self.m2l.n_offsets()];
        let mut dps = [false; 27];
        for b in &plan.blocks {
            dps[b.dp as usize] = true;
        }
        for (dp, _) in dps.iter().enumerate().filter(|(_, &u)| u) {
            self.m2l.mark_siblings(dp, &mut used);
        }
        for &(_, _, o) in &plan.pairs {
            used[o as usize] = true;
        }
        tgt.par_chunks_mut(nts * tl)
            .zip(src.par_chunks(nss * sl))
            .enumerate()
            .for_each_init(
                || vec![0.0; self.m2l.kernel_chunk_len()],
                |kernels, (c, (tc, sc))| {
                    self.m2l.expand_chunk(c, &used, kernels);
                    let kernels = &kernels[..];
                    let tables: Vec<[&[f64]; 27]> = (0..27)
                        .map(|dp| {
                            if dps[dp] {
                                self.m2l.sibling_blocks(kernels, dp)
                            } else {
                                [&[][..]; 27]
                            }
                        })
                        .collect();
                    for b in &plan.blocks {
                        let (t0, s0) = (b.target as usize, b.source as usize);
                        self.m2l.accumulate_siblings(
                            &tables[b.dp as usize],
                            &sc[s0 * sl..(s0 + 8) * sl],
                            &mut tc[t0 * tl..(t0 + 8) * tl],
                        );
                    }
                    for &(ti, si, o) in &plan.pairs {
                        let (ti, si) = (ti as usize, si as usize);
                        self.m2l.accumulate_chunk(
                            kernels,
                            o as usize,
                            &sc[si * sl..(si + 1) * sl],
                            &mut tc[ti * tl..(ti + 1) * tl],
                        );
                    }
                },
            );
        t = clock.add(3, t);
        check.par_chunks_mut(nc).enumerate().for_each_init(
            || (self.m2l.scratch(), vec![0.0; self.m2l.spectrum_len(dt)]),
            |(s, sp), (i, col)| {
                if let Some(slot) = plan.target_slot[i] {
                    self.m2l.from_chunks(tgt, nts, slot as usize, dt, sp);
                    self.m2l.check_values(sp, col, s);
                }
            },
        );
        clock.add(2, t);
    }
}

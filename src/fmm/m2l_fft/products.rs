//! The M2L's Hadamard products on one chunk of frequencies: pair by pair, and for the
//! children of two neighbouring parents at once (portable, AVX2 and AVX-512 paths).

use super::*;

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
pub(super) fn siblings(
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
pub(super) fn hadamard(g: &[f64], src: &[f64], tgt: &mut [f64], dt: usize, de: usize) {
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

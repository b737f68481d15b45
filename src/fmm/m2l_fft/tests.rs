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

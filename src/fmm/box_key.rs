//! Keys of octree boxes: a level and the Morton key of the box's first finest cell.
//!
//! The root cube is divided into `2²¹` cells per edge; a point's key interleaves the 21 bits
//! of its three cell indices (x highest, [`super::octree::morton_key`]). A box at level `l`
//! covers the keys `[morton, morton + 8^(21-l))`, a contiguous interval, so a partition of
//! the key line into intervals is a partition of space, and "does rank `r` hold part of box
//! `B`" is an interval overlap. Adjacency is decided on integer cell coordinates, never on
//! floating-point centres.

use super::octree::spread;

/// Bits per coordinate of the finest cells (the serial octree's deepest level).
pub const FINE: u32 = super::octree::MAX_DEPTH;

/// One past the largest key: keys are `0..KEY_END`.
pub const KEY_END: u64 = 1 << (3 * FINE);

/// A box of the octree over the root cube.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct BoxKey {
    /// Depth (root: 0). Ordering by `(level, morton)` lists boxes level by level.
    pub level: u32,
    /// Key of the first finest cell in the box (the low `3·(21 − level)` bits are zero).
    pub morton: u64,
}

/// Inverse of the Morton spreading: the bits 0, 3, 6, … of `v`, packed.
fn compact(v: u64) -> u64 {
    let mut x = v & 0x1249249249249249;
    x = (x | (x >> 2)) & 0x10c30c30c30c30c3;
    x = (x | (x >> 4)) & 0x100f00f00f00f00f;
    x = (x | (x >> 8)) & 0x1f0000ff0000ff;
    x = (x | (x >> 16)) & 0x1f00000000ffff;
    x = (x | (x >> 32)) & 0x1f_ffff;
    x
}

impl BoxKey {
    /// The root cube.
    pub const ROOT: BoxKey = BoxKey {
        level: 0,
        morton: 0,
    };

    fn shift(level: u32) -> u32 {
        3 * (FINE - level)
    }

    /// The box at `level` that contains the finest cell `key`.
    pub fn containing(key: u64, level: u32) -> Self {
        let s = Self::shift(level);
        BoxKey {
            level,
            morton: if s >= 64 { 0 } else { (key >> s) << s },
        }
    }

    /// One past the last finest key in the box.
    pub fn end(&self) -> u64 {
        self.morton + (1u64 << Self::shift(self.level))
    }

    /// Whether the key interval of the box overlaps `[lo, hi)` (an empty interval overlaps
    /// nothing).
    pub fn overlaps(&self, lo: u64, hi: u64) -> bool {
        lo < hi && self.morton < hi && lo < self.end()
    }

    /// The parent box (`None` for the root).
    pub fn parent(&self) -> Option<Self> {
        (self.level > 0).then(|| Self::containing(self.morton, self.level - 1))
    }

    /// The 8 children, in octant order (`None` at the finest level).
    pub fn children(&self) -> Option<[BoxKey; 8]> {
        (self.level < FINE).then(|| {
            let s = Self::shift(self.level + 1);
            std::array::from_fn(|o| BoxKey {
                level: self.level + 1,
                morton: self.morton | ((o as u64) << s),
            })
        })
    }

    /// Which child of its parent the box is (x bit 2, y bit 1, z bit 0).
    pub fn octant(&self) -> usize {
        ((self.morton >> Self::shift(self.level)) & 7) as usize
    }

    /// Edge length in finest cells.
    pub fn width(&self) -> u64 {
        1 << (FINE - self.level)
    }

    /// Integer coordinates of the box's lowest corner, in finest cells.
    pub fn anchor(&self) -> [u64; 3] {
        let m = self.morton;
        [compact(m >> 2), compact(m >> 1), compact(m)]
    }

    /// The box at `level` with lowest corner `anchor` (in finest cells, a multiple of the
    /// width); `None` outside the root cube.
    pub fn from_anchor(level: u32, anchor: [i64; 3]) -> Option<Self> {
        let lim = 1i64 << FINE;
        if anchor.iter().any(|&a| a < 0 || a >= lim) {
            return None;
        }
        let a = anchor.map(|v| v as u64);
        Some(Self::containing(
            (spread(a[0]) << 2) | (spread(a[1]) << 1) | spread(a[2]),
            level,
        ))
    }

    /// Whether the closed boxes touch or overlap (exact, on cell coordinates).
    pub fn adjacent(&self, other: &BoxKey) -> bool {
        let (a, b) = (self.anchor(), other.anchor());
        let (wa, wb) = (self.width(), other.width());
        (0..3).all(|k| a[k] <= b[k] + wb && b[k] <= a[k] + wa)
    }

    /// The boxes of the same level that touch this one, and itself (up to 27, inside the
    /// root cube).
    pub fn neighbourhood(&self) -> Vec<BoxKey> {
        let a = self.anchor().map(|v| v as i64);
        let w = self.width() as i64;
        let mut out = Vec::with_capacity(27);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let c = [a[0] + dx * w, a[1] + dy * w, a[2] + dz * w];
                    if let Some(k) = Self::from_anchor(self.level, c) {
                        out.push(k);
                    }
                }
            }
        }
        out
    }

    /// Offset from `other` to this box in units of the (common) box width, for M2L.
    pub fn offset_from(&self, other: &BoxKey) -> [i32; 3] {
        let (a, b) = (self.anchor(), other.anchor());
        let w = self.width() as i64;
        [0, 1, 2].map(|k| ((a[k] as i64 - b[k] as i64) / w) as i32)
    }
}

/// The root cube agreed by all ranks: lowest corner and edge.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Domain {
    /// Lowest corner.
    pub lo: [f64; 3],
    /// Edge length.
    pub side: f64,
}

impl Domain {
    /// The cube of the serial octree over points with bounding box `[lo, hi]`: edge the
    /// largest extent times `1 + 1e-10`, lowest corner `lo`.
    pub fn from_bounds(lo: [f64; 3], hi: [f64; 3]) -> Self {
        if lo.iter().zip(&hi).any(|(l, h)| l > h) {
            return Domain {
                lo: [0.0; 3],
                side: 1.0,
            };
        }
        let side = (0..3).map(|k| hi[k] - lo[k]).fold(0.0f64, f64::max);
        let side = if side > 0.0 {
            side * (1.0 + 1e-10)
        } else {
            1.0
        };
        Domain { lo, side }
    }

    /// Key of the finest cell holding `p`.
    pub fn key(&self, p: [f64; 3]) -> u64 {
        super::octree::morton_key(p, self.lo, self.side)
    }

    /// Centre and half edge of a box.
    pub fn geometry(&self, b: &BoxKey) -> ([f64; 3], f64) {
        let cell = self.side / (1u64 << FINE) as f64;
        let a = b.anchor();
        let w = b.width();
        let c = [0, 1, 2].map(|k| self.lo[k] + (2 * a[k] + w) as f64 * 0.5 * cell);
        (c, w as f64 * 0.5 * cell)
    }

    /// Half edge of the boxes at `level`.
    pub fn half(&self, level: u32) -> f64 {
        self.side / (1u64 << (level + 1)) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A box's children are its octants in order, each with the box as parent, tiling its key
    /// interval; the finest boxes have none.
    #[test]
    fn children_tile_the_parent() {
        let b = BoxKey::containing(0x1234_5678_9abc, 5);
        let ch = b.children().unwrap();
        for (o, c) in ch.iter().enumerate() {
            assert_eq!(c.parent(), Some(b));
            assert_eq!(c.octant(), o);
        }
        assert_eq!(ch[0].morton, b.morton);
        for w in ch.windows(2) {
            assert_eq!(w[0].end(), w[1].morton);
        }
        assert_eq!(ch[7].end(), b.end());
        assert!(BoxKey::containing(77, FINE).children().is_none());
    }

    /// An empty key interval (a rank that holds no keys) overlaps no box, not even the root.
    #[test]
    fn an_empty_interval_overlaps_nothing() {
        let b = BoxKey::containing(1 << 40, 3);
        assert!(b.overlaps(b.morton, b.morton + 1));
        assert!(!b.overlaps(b.morton + 1, b.morton + 1));
        assert!(!BoxKey::ROOT.overlaps(5, 5));
        assert!(!b.overlaps(b.end(), b.end() + 10));
    }
}

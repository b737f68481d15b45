//! [`PackingReport`]: what a `placement = "packed"` entry achieved, kept in
//! [`crate::scene::cells::CellScene`]'s `packings` and written to `summary.json`.

/// What a packed placement achieved (`summary.json`'s `packings`, printed by `mobo run`).
/// Two reports are equal when they place the same: the seconds are left out.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PackingReport {
    /// The `[[cells]]` entry (from 0).
    pub entry: usize,
    /// Cells placed.
    pub cells: usize,
    /// Their volume fraction of the region.
    pub volume_fraction: f64,
    /// `"cube"` or `"walls"` (the fluid of the scene's container).
    pub region: &'static str,
    /// The smallest surface gap at full size, between cells or to a wall or face, as the
    /// projection measured it (`None`: none within its range, a few `min_gap`).
    pub smallest_gap: Option<f64>,
    /// Seconds the placement took.
    pub seconds: f64,
}

impl PartialEq for PackingReport {
    fn eq(&self, other: &Self) -> bool {
        (self.entry, self.cells, self.region) == (other.entry, other.cells, other.region)
            && self.volume_fraction == other.volume_fraction
            && self.smallest_gap == other.smallest_gap
    }
}

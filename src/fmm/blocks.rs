//! Point data in the layout the summation loops want: structure of arrays (one slice per
//! coordinate and per density component), so that the loop over sources vectorises.

/// A borrowed block of sources: positions, density components and (for double-layer kernels)
/// orientations, all of the same length.
#[derive(Clone, Copy, Debug)]
pub struct SourceView<'a> {
    /// Coordinates, `x`.
    pub x: &'a [f64],
    /// Coordinates, `y`.
    pub y: &'a [f64],
    /// Coordinates, `z`.
    pub z: &'a [f64],
    /// Density components (`density_dim` of them are used).
    pub q: [&'a [f64]; 4],
    /// Orientation components (empty slices when the kernel has none).
    pub n: [&'a [f64]; 3],
}

impl SourceView<'_> {
    /// Number of sources.
    pub fn len(&self) -> usize {
        self.x.len()
    }
    /// Whether the block is empty.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
}

/// An owned structure-of-arrays copy of sources with densities and orientations.
#[derive(Clone, Debug, Default)]
pub struct SourceBlock {
    /// Coordinates, `x`.
    pub x: Vec<f64>,
    /// Coordinates, `y`.
    pub y: Vec<f64>,
    /// Coordinates, `z`.
    pub z: Vec<f64>,
    /// Density components (`density_dim` of them are filled, the rest empty).
    pub q: [Vec<f64>; 4],
    /// Orientation components (empty when the kernel has none).
    pub n: [Vec<f64>; 3],
}

impl SourceBlock {
    /// Copy points (and orientations) in the given order; densities are set by
    /// [`SourceBlock::set_density`].
    pub fn new(points: &[[f64; 3]], normals: Option<&[[f64; 3]]>, order: &[usize]) -> Self {
        let pick = |k: usize| order.iter().map(|&i| points[i][k]).collect::<Vec<f64>>();
        let mut b = SourceBlock {
            x: pick(0),
            y: pick(1),
            z: pick(2),
            ..Default::default()
        };
        if let Some(nm) = normals {
            for (k, comp) in b.n.iter_mut().enumerate() {
                *comp = order.iter().map(|&i| nm[i][k]).collect();
            }
        }
        b
    }

    /// Number of sources.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// Whether there are no sources.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Scatter an interleaved density (`dim` values per source, input order) into the
    /// component arrays, in the block's order.
    pub fn set_density(&mut self, density: &[f64], dim: usize, order: &[usize]) {
        for c in 0..4 {
            if c < dim {
                self.q[c].resize(order.len(), 0.0);
                for (v, &i) in self.q[c].iter_mut().zip(order) {
                    *v = density[i * dim + c];
                }
            } else {
                self.q[c].clear();
            }
        }
    }

    /// Set the sources to the points `p` (AoS) with interleaved densities `dens` (`dim` per
    /// point), reusing the allocations.
    pub fn set_points(&mut self, p: &[[f64; 3]], dens: &[f64], dim: usize) {
        self.x.clear();
        self.y.clear();
        self.z.clear();
        self.x.extend(p.iter().map(|v| v[0]));
        self.y.extend(p.iter().map(|v| v[1]));
        self.z.extend(p.iter().map(|v| v[2]));
        for c in 0..4 {
            self.q[c].clear();
            if c < dim {
                self.q[c].extend(dens.chunks_exact(dim).map(|d| d[c]));
            }
        }
    }

    /// The sources `range` as a view.
    pub fn view(&self, range: std::ops::Range<usize>) -> SourceView<'_> {
        fn sl(v: &[f64], r: std::ops::Range<usize>) -> &[f64] {
            if v.is_empty() {
                &[]
            } else {
                &v[r]
            }
        }
        let r = || range.clone();
        SourceView {
            x: &self.x[r()],
            y: &self.y[r()],
            z: &self.z[r()],
            q: [
                sl(&self.q[0], r()),
                sl(&self.q[1], r()),
                sl(&self.q[2], r()),
                sl(&self.q[3], r()),
            ],
            n: [
                sl(&self.n[0], r()),
                sl(&self.n[1], r()),
                sl(&self.n[2], r()),
            ],
        }
    }

    /// All sources as a view.
    pub fn all(&self) -> SourceView<'_> {
        self.view(0..self.len())
    }
}

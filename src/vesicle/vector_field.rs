//! A vector field on a cell's grid: one 3-vector per grid point, typed so that its layout is
//! not a convention a caller has to remember.
//!
//! The step's operators keep a field component-major (all `x`, then all `y`, then all `z`:
//! `3n` numbers, the layout of [`crate::vesicle::layer`], the transforms and the solves), while
//! points ([`super::geometry::Geometry::x`], `normal`) and the FMM's densities go per point. A
//! [`VectorField`] is read and written per point ([`VectorField::point`], [`VectorField::add`])
//! whatever its storage, and hands the component-major numbers to the routines that take them
//! ([`VectorField::as_component_major`], e.g. for
//! [`super::geometry::Geometry::tank_treading_rate`]).
//!
//! ```
//! use mobo::vesicle::vector_field::VectorField;
//!
//! let mut t = VectorField::zeros(2);
//! t.add(1, [1.0, 2.0, 3.0]);
//! assert_eq!(t.point(1), [1.0, 2.0, 3.0]);
//! assert_eq!(t.as_component_major(), &[0.0, 1.0, 0.0, 2.0, 0.0, 3.0]);
//! assert_eq!(VectorField::from_points(&t.points()), t);
//! ```

/// `n` 3-vectors, one per grid point (stored component-major; see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct VectorField {
    n: usize,
    data: Vec<f64>,
}

impl VectorField {
    /// `n` zero vectors.
    pub fn zeros(n: usize) -> Self {
        VectorField {
            n,
            data: vec![0.0; 3 * n],
        }
    }

    /// The field of `3n` component-major numbers (all `x`, then all `y`, then all `z`); `None`
    /// when the length is not a multiple of 3.
    pub fn from_component_major(data: Vec<f64>) -> Option<Self> {
        if !data.len().is_multiple_of(3) {
            return None;
        }
        Some(VectorField {
            n: data.len() / 3,
            data,
        })
    }

    /// The field of one vector per point.
    pub fn from_points(points: &[[f64; 3]]) -> Self {
        let n = points.len();
        let mut data = vec![0.0; 3 * n];
        for (k, v) in points.iter().enumerate() {
            for (c, vc) in v.iter().enumerate() {
                data[c * n + k] = *vc;
            }
        }
        VectorField { n, data }
    }

    /// The number of points `n`.
    pub fn n_points(&self) -> usize {
        self.n
    }

    /// The vector at point `k` (panics if `k ≥ n`, as slice indexing does).
    pub fn point(&self, k: usize) -> [f64; 3] {
        let n = self.n;
        [self.data[k], self.data[n + k], self.data[2 * n + k]]
    }

    /// Set the vector at point `k`.
    pub fn set(&mut self, k: usize, v: [f64; 3]) {
        let n = self.n;
        for (c, vc) in v.into_iter().enumerate() {
            self.data[c * n + k] = vc;
        }
    }

    /// Add `v` to the vector at point `k`.
    pub fn add(&mut self, k: usize, v: [f64; 3]) {
        let n = self.n;
        for (c, vc) in v.into_iter().enumerate() {
            self.data[c * n + k] += vc;
        }
    }

    /// Every point's vector set to `v`.
    pub fn fill(&mut self, v: [f64; 3]) {
        for (c, vc) in v.into_iter().enumerate() {
            self.data[c * self.n..(c + 1) * self.n].fill(vc);
        }
    }

    /// One vector per point.
    pub fn points(&self) -> Vec<[f64; 3]> {
        (0..self.n).map(|k| self.point(k)).collect()
    }

    /// The `3n` component-major numbers.
    pub fn as_component_major(&self) -> &[f64] {
        &self.data
    }

    /// The `3n` component-major numbers, to write.
    pub fn as_component_major_mut(&mut self) -> &mut [f64] {
        &mut self.data
    }

    /// The `3n` component-major numbers, taken.
    pub fn into_component_major(self) -> Vec<f64> {
        self.data
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_and_component_major_agree() {
        let pts = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]];
        let f = VectorField::from_points(&pts);
        assert_eq!(f.n_points(), 3);
        assert_eq!(
            f.as_component_major(),
            &[1.0, 4.0, 7.0, 2.0, 5.0, 8.0, 3.0, 6.0, 9.0]
        );
        assert_eq!(f.points(), pts.to_vec());
        let mut g = VectorField::from_component_major(f.clone().into_component_major()).unwrap();
        assert_eq!(g, f);
        g.add(2, [1.0, 1.0, 1.0]);
        g.set(0, [0.0, 0.0, -1.0]);
        assert_eq!(g.point(2), [8.0, 9.0, 10.0]);
        assert_eq!(g.point(0), [0.0, 0.0, -1.0]);
        g.fill([f64::NAN, 0.0, 0.0]);
        assert!(g.points().iter().all(|v| v[0].is_nan() && v[1] == 0.0));
        assert!(VectorField::from_component_major(vec![0.0; 4]).is_none());
    }
}

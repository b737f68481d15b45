//! Equivalent and check surfaces of the KIFMM: the points of a `p × p × p` lattice on the
//! boundary of the cube `[-1, 1]³` (`6(p−1)² + 2` points). Boxes scale and shift them; because
//! the points lie on a lattice, the M2L between two surfaces of the same size is a discrete
//! convolution (see [`super::m2l_fft`]).

/// The surface lattice of order `p` (points per edge, `p ≥ 2`).
#[derive(Clone, Debug)]
pub struct CubeSurface {
    /// Points per edge.
    pub p: usize,
    /// Unit-cube coordinates of the points.
    pub points: Vec<[f64; 3]>,
    /// Lattice indices `(i, j, k) ∈ [0, p)³` of the points.
    pub lattice: Vec<[usize; 3]>,
}

impl CubeSurface {
    /// The lattice points on the cube's boundary, in lexicographic order of `(i, j, k)`.
    pub fn new(p: usize) -> Self {
        assert!(p >= 2, "a cube surface needs at least 2 points per edge");
        let c = |t: usize| -1.0 + 2.0 * t as f64 / (p - 1) as f64;
        let edge = |t: usize| t == 0 || t == p - 1;
        let mut points = Vec::new();
        let mut lattice = Vec::new();
        for i in 0..p {
            for j in 0..p {
                for k in 0..p {
                    if edge(i) || edge(j) || edge(k) {
                        points.push([c(i), c(j), c(k)]);
                        lattice.push([i, j, k]);
                    }
                }
            }
        }
        CubeSurface { p, points, lattice }
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether the surface has no points (never: `p ≥ 2`).
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The points scaled by `radius · half` around `center`.
    pub fn place(&self, center: [f64; 3], half: f64, radius: f64, out: &mut Vec<[f64; 3]>) {
        let s = radius * half;
        out.clear();
        out.extend(self.points.iter().map(|u| {
            [
                center[0] + s * u[0],
                center[1] + s * u[1],
                center[2] + s * u[2],
            ]
        }));
    }
}

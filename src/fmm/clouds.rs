//! Point clouds for tests and benchmarks of the N-body sums: uniform in the unit cube,
//! strongly clustered Gaussian blobs, points on a few hundred small spheres (cell-like), and
//! one tight cluster with a sparse background.
//! The same generators drive the tests, `benches/fmm.rs` and `mobo fmm-cloud`, so that every
//! measurement names its cloud by kind, size and seed.

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};

/// Kinds of clouds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cloud {
    /// Uniform in `[0, 1]³`.
    Uniform,
    /// Four Gaussian blobs with standard deviations 0.1 and 0.01 (half the points each).
    Blobs,
    /// Points uniformly on spheres of radius 0.03 at random centres in `[0, 1]³`, about 300
    /// spheres (at least 20 points each).
    Spheres,
    /// Strongly clustered: 90 % of the points in a Gaussian of standard deviation 10⁻⁴ near a
    /// corner, the rest uniform in `[0, 1]³` (a tree ten levels deep in one place, shallow
    /// elsewhere; its partition over ranks cuts the deep branch).
    Clustered,
    /// A dense core: half the points uniform in `[0, 1]³`, half in a Gaussian of standard
    /// deviation 0.01 about the centre (neighbours 25× closer in the core than outside; RPY
    /// beads sized by the core overlap).
    DenseCore,
    /// Two scales: half the points uniform in `[0, 1]³`, half uniform in a cube of side 0.01
    /// at `(0.3, 0.3, 0.3)` (spacing 100× finer there).
    TwoScale,
}

impl Cloud {
    /// Parse `uniform`, `blobs`, `spheres`, `clustered`, `dense-core` or `two-scale`.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "uniform" => Some(Cloud::Uniform),
            "blobs" => Some(Cloud::Blobs),
            "spheres" => Some(Cloud::Spheres),
            "clustered" => Some(Cloud::Clustered),
            "dense-core" => Some(Cloud::DenseCore),
            "two-scale" => Some(Cloud::TwoScale),
            _ => None,
        }
    }

    /// The name.
    pub fn name(&self) -> &'static str {
        match self {
            Cloud::Uniform => "uniform",
            Cloud::Blobs => "blobs",
            Cloud::Spheres => "spheres",
            Cloud::Clustered => "clustered",
            Cloud::DenseCore => "dense-core",
            Cloud::TwoScale => "two-scale",
        }
    }

    /// `n` points, reproducible from `seed`.
    pub fn points(&self, n: usize, seed: u64) -> Vec<[f64; 3]> {
        let mut rng = StdRng::seed_from_u64(seed);
        let g = |r: &mut StdRng| -> f64 { StandardNormal.sample(r) };
        match self {
            Cloud::Uniform => (0..n)
                .map(|_| [rng.random(), rng.random(), rng.random()])
                .collect(),
            Cloud::Blobs => {
                let c: Vec<[f64; 3]> = (0..4)
                    .map(|_| [rng.random(), rng.random(), rng.random()])
                    .collect();
                (0..n)
                    .map(|i| {
                        let s = 10f64.powi(-(1 + (i % 2) as i32));
                        let k = c[i % 4];
                        [
                            k[0] + s * g(&mut rng),
                            k[1] + s * g(&mut rng),
                            k[2] + s * g(&mut rng),
                        ]
                    })
                    .collect()
            }
            Cloud::Spheres => {
                let per = (n / 300).max(20);
                let radius = 0.03;
                let mut out = Vec::with_capacity(n);
                while out.len() < n {
                    let c = [
                        rng.random::<f64>(),
                        rng.random::<f64>(),
                        rng.random::<f64>(),
                    ];
                    for _ in 0..per.min(n - out.len()) {
                        let v = [g(&mut rng), g(&mut rng), g(&mut rng)];
                        let r = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() / radius;
                        out.push([c[0] + v[0] / r, c[1] + v[1] / r, c[2] + v[2] / r]);
                    }
                }
                out
            }
            Cloud::Clustered => (0..n)
                .map(|i| {
                    if i % 10 == 9 {
                        [rng.random(), rng.random(), rng.random()]
                    } else {
                        let mut c = || 0.1 + 1e-4 * g(&mut rng);
                        [c(), c(), c()]
                    }
                })
                .collect(),
            Cloud::DenseCore => (0..n)
                .map(|i| {
                    if i % 2 == 0 {
                        [rng.random(), rng.random(), rng.random()]
                    } else {
                        let mut c = || 0.5 + 0.01 * g(&mut rng);
                        [c(), c(), c()]
                    }
                })
                .collect(),
            Cloud::TwoScale => (0..n)
                .map(|i| {
                    let (o, s) = if i % 2 == 0 { (0.0, 1.0) } else { (0.3, 0.01) };
                    [
                        o + s * rng.random::<f64>(),
                        o + s * rng.random::<f64>(),
                        o + s * rng.random::<f64>(),
                    ]
                })
                .collect(),
        }
    }

    /// Half the median distance from a point to its nearest neighbour over the points of
    /// `sample` (indices into `points`), by brute force: the bead radius at which those points'
    /// neighbours overlap (RPY pairs closer than `2a`).
    pub fn half_median_spacing(points: &[[f64; 3]], sample: &[usize]) -> f64 {
        let mut d: Vec<f64> = sample
            .iter()
            .map(|&i| {
                let x = points[i];
                points
                    .iter()
                    .enumerate()
                    .filter(|&(j, _)| j != i)
                    .map(|(_, y)| {
                        (x[0] - y[0]).powi(2) + (x[1] - y[1]).powi(2) + (x[2] - y[2]).powi(2)
                    })
                    .fold(f64::INFINITY, f64::min)
                    .sqrt()
            })
            .collect();
        d.sort_by(f64::total_cmp);
        0.5 * d.get(d.len() / 2).copied().unwrap_or(0.0)
    }

    /// `n` random unit vectors (orientations for double layers), reproducible from `seed`.
    pub fn unit_vectors(n: usize, seed: u64) -> Vec<[f64; 3]> {
        let mut rng = StdRng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                let v: [f64; 3] = [
                    StandardNormal.sample(&mut rng),
                    StandardNormal.sample(&mut rng),
                    StandardNormal.sample(&mut rng),
                ];
                let r = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                [v[0] / r, v[1] / r, v[2] / r]
            })
            .collect()
    }

    /// `n` values uniform in `[−1, 1]`, reproducible from `seed`.
    pub fn densities(n: usize, seed: u64) -> Vec<f64> {
        let mut rng = StdRng::seed_from_u64(seed);
        (0..n).map(|_| rng.random_range(-1.0..1.0)).collect()
    }
}

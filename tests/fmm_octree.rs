//! The adaptive octree and its interaction lists: every source is counted exactly once for every
//! target leaf, on uniform, clustered and cell-surface clouds, with and without separate targets.

use mobo::fmm::octree::{morton_key, Octree};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};

fn uniform(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n)
        .map(|_| [rng.random(), rng.random(), rng.random()])
        .collect()
}

fn blobs(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = StdRng::seed_from_u64(seed);
    let centers: Vec<[f64; 3]> = (0..5)
        .map(|_| [rng.random(), rng.random(), rng.random()])
        .collect();
    (0..n)
        .map(|i| {
            let c = centers[i % 5];
            let s = 10f64.powi(-(1 + (i % 3) as i32));
            let g = |r: &mut StdRng| -> f64 { StandardNormal.sample(r) };
            [
                c[0] + s * g(&mut rng),
                c[1] + s * g(&mut rng),
                c[2] + s * g(&mut rng),
            ]
        })
        .collect()
}

fn spheres(cells: usize, per: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut out = Vec::new();
    for _ in 0..cells {
        let c = [
            rng.random::<f64>() * 10.0,
            rng.random::<f64>() * 10.0,
            rng.random::<f64>() * 10.0,
        ];
        for _ in 0..per {
            let v: [f64; 3] = [
                StandardNormal.sample(&mut rng),
                StandardNormal.sample(&mut rng),
                StandardNormal.sample(&mut rng),
            ];
            let r = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() / 0.3;
            out.push([c[0] + v[0] / r, c[1] + v[1] / r, c[2] + v[2] / r]);
        }
    }
    out
}

fn check_coverage(src: &[[f64; 3]], tgt: &[[f64; 3]], leaf: usize) -> (usize, u32) {
    let tree = Octree::new(src, tgt, leaf);
    let lists = tree.lists();
    // Sorted arrays are permutations of the inputs.
    for (i, &p) in tree.source_perm.iter().enumerate() {
        assert_eq!(tree.sources_sorted[i], src[p]);
    }
    let mut seen = vec![0u32; src.len()];
    for (b, node) in tree.nodes.iter().enumerate() {
        // Children partition their parent's points.
        if !node.is_leaf() {
            let s: usize = node
                .children
                .iter()
                .map(|&c| tree.nodes[c].sources.len())
                .sum();
            let t: usize = node
                .children
                .iter()
                .map(|&c| tree.nodes[c].targets.len())
                .sum();
            assert_eq!((s, t), (node.sources.len(), node.targets.len()));
            for &c in &node.children {
                let ch = &tree.nodes[c];
                assert!((ch.half * 2.0 - node.half).abs() < 1e-12 * node.half);
                for p in &tree.sources_sorted[ch.sources.clone()] {
                    assert!(
                        (0..3).all(|k| (p[k] - ch.center[k]).abs() <= ch.half * (1.0 + 1e-9)),
                        "point outside its box"
                    );
                }
            }
            continue;
        }
        assert!(
            node.sources.len() + node.targets.len() <= leaf
                || node.level == mobo::fmm::octree::MAX_DEPTH
        );
        if node.targets.is_empty() {
            continue;
        }
        seen.iter_mut().for_each(|s| *s = 0);
        let mut mark = |bx: usize| {
            for i in tree.nodes[bx].sources.clone() {
                seen[i] += 1;
            }
        };
        lists.u[b].iter().for_each(|&a| mark(a));
        lists.w[b].iter().for_each(|&a| mark(a));
        let mut c = Some(b);
        while let Some(cb) = c {
            lists.v[cb].iter().for_each(|&a| mark(a));
            lists.x[cb].iter().for_each(|&a| mark(a));
            c = tree.nodes[cb].parent;
        }
        if let Some(i) = seen.iter().position(|&s| s != 1) {
            panic!("leaf {b}: sorted source {i} counted {} times", seen[i]);
        }
        // Same-level V boxes are well separated; W boxes are smaller than b and not adjacent.
        for &v in &lists.v[b] {
            assert!(!tree.adjacent(v, b) && tree.nodes[v].level == node.level);
        }
        for &w in &lists.w[b] {
            assert!(!tree.adjacent(w, b) && tree.nodes[w].level > node.level);
        }
    }
    (tree.nodes.len(), tree.depth())
}

#[test]
fn lists_cover_every_source_exactly_once() {
    let u = uniform(3000, 1);
    let b = blobs(3000, 2);
    let s = spheres(40, 80, 3);
    for (name, pts) in [("uniform", &u), ("blobs", &b), ("spheres", &s)] {
        for leaf in [8, 40] {
            let (nodes, depth) = check_coverage(pts, pts, leaf);
            println!("{name}: leaf {leaf}: {nodes} boxes, depth {depth}");
        }
    }
    // Separate targets from another distribution.
    check_coverage(&b, &u[..500], 20);
    check_coverage(&s, &b[..700], 20);
}

#[test]
fn clustered_clouds_get_deep_adaptive_trees() {
    let b = blobs(4000, 5);
    let tree = Octree::new(&b, &b, 20);
    // A uniform tree with the same leaf size would need depth ~3; the blobs (widths down to
    // 1e-3 of the domain) need many more levels, but only where the points are.
    assert!(tree.depth() >= 8, "depth {}", tree.depth());
    let full_uniform_boxes: usize = (0..tree.depth()).map(|l| 8usize.pow(l)).sum();
    assert!(tree.nodes.len() < full_uniform_boxes / 1000);
}

#[test]
fn morton_keys_interleave_bits() {
    let lo = [0.0; 3];
    // Highest-level octant bit order: x, y, z.
    assert_eq!(morton_key([0.75, 0.25, 0.25], lo, 1.0) >> 60, 0b100);
    assert_eq!(morton_key([0.25, 0.75, 0.25], lo, 1.0) >> 60, 0b010);
    assert_eq!(morton_key([0.25, 0.25, 0.75], lo, 1.0) >> 60, 0b001);
    assert!(morton_key([0.1, 0.1, 0.1], lo, 1.0) < morton_key([0.9, 0.9, 0.9], lo, 1.0));
}

//! The near field of a point set on itself, each pair of leaves once
//! (`mobo::fmm::near_pairs`): the split covers every interaction of the row-by-row list
//! exactly once, no round writes a row twice, the mutual loops equal two one-way loops on
//! every instruction set, and whole FMM evaluations agree with the one-way near field.

use std::collections::HashMap;

use mobo::check::assert_close;
use mobo::fmm::blocks::SourceBlock;
use mobo::fmm::clouds::Cloud;
use mobo::fmm::near_field::CpuNearField;
use mobo::fmm::near_pairs::MutualPairs;
use mobo::fmm::p2p::{self, Newton, Simd};
use mobo::fmm::{Fmm, FmmKernel};

/// Every (row, range) of the list is summed exactly once by the split: one way in its row, or
/// as one direction of a mutual pair; every pair's mirror is in the list; rounds share no row.
fn check_split(pts: &[[f64; 3]], leaf: usize) -> (usize, usize) {
    let fmm = Fmm::new(FmmKernel::Laplace, pts, None, pts, 6, leaf).unwrap();
    let list = fmm.near_list();
    let split = MutualPairs::build(list);
    assert!(split.fits(list));
    let mut want: HashMap<(usize, usize, usize), usize> = HashMap::new();
    for r in 0..list.rows.len() {
        for s in list.row_ranges(r) {
            *want.entry((r, s.start, s.end)).or_default() += 1;
        }
    }
    let mut got: HashMap<(usize, usize, usize), usize> = HashMap::new();
    for r in 0..split.one_way().rows.len() {
        for s in split.one_way().row_ranges(r) {
            *got.entry((r, s.start, s.end)).or_default() += 1;
        }
    }
    for round in split.rounds() {
        let mut seen = vec![false; list.rows.len()];
        for &[a, b] in round {
            assert!(a < b, "pair [{a}, {b}] not ordered");
            for r in [a, b] {
                assert!(!seen[r], "row {r} twice in one round");
                seen[r] = true;
            }
            let (ra, rb) = (&list.rows[a], &list.rows[b]);
            *got.entry((a, rb.start, rb.end)).or_default() += 1;
            *got.entry((b, ra.start, ra.end)).or_default() += 1;
        }
    }
    assert_eq!(got, want, "the split does not cover the list once");
    // The points of each pair's rows are the same as the sources they stand for.
    let points = fmm.near_points();
    assert_eq!(points.sources, points.targets);
    (split.mutual_pairs(), split.rounds().len())
}

#[test]
fn the_split_covers_every_near_interaction_once() {
    for (cloud, n, leaf) in [
        (Cloud::Uniform, 20_000, 200),
        (Cloud::Clustered, 20_000, 60),
        (Cloud::Spheres, 20_000, 100),
        (Cloud::TwoScale, 10_000, 40),
    ] {
        let pts = cloud.points(n, 3);
        let (pairs, rounds) = check_split(&pts, leaf);
        println!("{}: {pairs} mutual pairs in {rounds} rounds", cloud.name());
        assert!(pairs > 0, "{}: no mutual pair", cloud.name());
        assert!(rounds > 0, "{}: no round", cloud.name());
    }
}

/// The mutual loops against two one-way calls (the exact portable loop, and the same
/// instruction set with the same Newton steps), every instruction set this CPU has, block sizes
/// 0–19 against 0–19 (all remainders of the four- and eight-wide steps); then blocks of
/// coincident points (nothing).
#[test]
fn mutual_loops_equal_two_one_way_loops() {
    let pts = Cloud::Blobs.points(40, 4);
    let q = Cloud::densities(40, 5);
    let order: Vec<usize> = (0..40).collect();
    let mut blk = SourceBlock::new(&pts, None, &order);
    blk.set_density(&q, 1, &order);
    for na in [0, 1, 3, 7, 8, 9, 16, 19] {
        for nb in 0..20 {
            let (ra, rb) = (0..na, 20..20 + nb);
            let (va, vb) = (blk.view(ra.clone()), blk.view(rb.clone()));
            let mut want_a = vec![0.0; na];
            let mut want_b = vec![0.0; nb];
            p2p::laplace_portable(&pts[ra.clone()], &vb, &mut want_a);
            p2p::laplace_portable(&pts[rb.clone()], &va, &mut want_b);
            for simd in [Simd::Portable, Simd::Avx2, Simd::Avx512] {
                for newton in [Newton::Two, Newton::One] {
                    let (mut oa, mut ob) = (vec![0.0; na], vec![0.0; nb]);
                    let ran = p2p::laplace_mutual_with(simd, newton, &va, &mut oa, &vb, &mut ob);
                    assert_eq!(ran, simd.available());
                    if !ran {
                        continue;
                    }
                    let what = format!("{simd:?} {newton:?} {na}×{nb}");
                    // Against the one-way loop of the same instruction set and step count: a
                    // pair's value must not depend on how the blocks are cut (the one-rank
                    // mutual pass and the K-rank one-way pass agree to round-off).
                    let (mut one_a, mut one_b) = (vec![0.0; na], vec![0.0; nb]);
                    p2p::laplace_with(simd, newton, &pts[ra.clone()], &vb, &mut one_a);
                    p2p::laplace_with(simd, newton, &pts[rb.clone()], &va, &mut one_b);
                    assert_close(&format!("{what} a, one way"), &oa, &one_a, 1e-13);
                    assert_close(&format!("{what} b, one way"), &ob, &one_b, 1e-13);
                    if newton == Newton::Two {
                        assert_close(&format!("{what} a"), &oa, &want_a, 1e-13);
                        assert_close(&format!("{what} b"), &ob, &want_b, 1e-13);
                    }
                }
            }
        }
    }
    // Coincident points between the blocks give nothing (as the one-way loops).
    let same = [[0.3, 0.2, 0.1]; 9];
    let o: Vec<usize> = (0..9).collect();
    let mut b2 = SourceBlock::new(&same, None, &o);
    b2.set_density(&[1.0; 9], 1, &o);
    for simd in [Simd::Portable, Simd::Avx2, Simd::Avx512] {
        let (mut oa, mut ob) = (vec![0.0; 9], vec![0.0; 9]);
        if p2p::laplace_mutual_with(
            simd,
            Newton::Two,
            &b2.view(0..9),
            &mut oa,
            &b2.view(0..9),
            &mut ob,
        ) {
            assert!(
                oa.iter().chain(&ob).all(|v| *v == 0.0),
                "{simd:?}: {oa:?} {ob:?}"
            );
        }
    }
}

/// Whole evaluations: the default near field (mutual pairs where targets are sources) against
/// the one-way CPU near field, exact (tolerance 0) and at the default tolerance, on a uniform
/// and a clustered (adaptive, W and X lists) cloud.
#[test]
fn mutual_near_field_matches_the_one_way_near_field() {
    for (cloud, n, leaf) in [
        (Cloud::Uniform, 30_000, 400),
        (Cloud::Clustered, 20_000, 60),
    ] {
        let pts = cloud.points(n, 8);
        let dens = Cloud::densities(n, 9);
        let mut fmm = Fmm::new(FmmKernel::Laplace, &pts, None, &pts, 8, leaf).unwrap();
        let run = |fmm: &mut Fmm| {
            let mut u = vec![0.0; n];
            fmm.evaluate(&dens, &mut u).unwrap();
            u
        };
        fmm.set_cpu_near_tolerance(0.0);
        let mutual = run(&mut fmm);
        fmm.set_near_field(Box::new(CpuNearField::new(FmmKernel::Laplace.near())));
        let one_way = run(&mut fmm);
        assert_close(&format!("{} exact", cloud.name()), &mutual, &one_way, 1e-13);
        assert_ne!(
            mutual,
            one_way,
            "{}: the mutual pass did not run",
            cloud.name()
        );
        // The default: mutual and one Newton step (Laplace at order 8 is calibrated to 6
        // digits: 1e-7 per pair allowed).
        let tol = mobo::fmm::calibration::near_tolerance(FmmKernel::Laplace, 8);
        fmm.set_cpu_near_tolerance(tol);
        let fast = run(&mut fmm);
        assert_close(
            &format!("{} default", cloud.name()),
            &fast,
            &one_way,
            10.0 * tol,
        );
    }
}

/// Targets other than the sources: no mutual split (the one-way pass), same values as the
/// direct sum within the FMM's digits.
#[test]
fn separate_targets_keep_the_one_way_pass() {
    let pts = Cloud::Uniform.points(8000, 10);
    let tgt = Cloud::Uniform.points(3000, 11);
    let dens = Cloud::densities(8000, 12);
    let mut fmm = Fmm::new(FmmKernel::Laplace, &pts, None, &tgt, 8, 200).unwrap();
    let mut u = vec![0.0; 3000];
    fmm.evaluate(&dens, &mut u).unwrap();
    let mut exact = vec![0.0; 3000];
    let blk = {
        let order: Vec<usize> = (0..8000).collect();
        let mut b = SourceBlock::new(&pts, None, &order);
        b.set_density(&dens, 1, &order);
        b
    };
    p2p::laplace_portable(&tgt, &blk.all(), &mut exact);
    assert_close("separate targets", &u, &exact, 1e-6);
}

/// Leaves √2 larger only where the near field can run mutual pairs (Laplace, targets that are
/// the sources).
#[test]
fn mutual_near_fields_take_larger_default_leaves() {
    for order in [4, 8, 13] {
        let base = FmmKernel::Laplace.default_leaf_size(order);
        let mutual = FmmKernel::Laplace.default_leaf_size_for(order, true);
        assert_eq!(
            mutual,
            (base as f64 * std::f64::consts::SQRT_2).round() as usize
        );
        assert_eq!(FmmKernel::Laplace.default_leaf_size_for(order, false), base);
        for k in [FmmKernel::Stokeslet, FmmKernel::Stresslet] {
            assert_eq!(
                k.default_leaf_size_for(order, true),
                k.default_leaf_size(order)
            );
        }
    }
}

/// A hand-made list: a star row with 130 partners (more than the colouring's 128 rounds can
/// hold for one row), a row that sums itself, a one-sided entry (no mirror) and rows without
/// ranges. Every interaction is covered once; rows past the cap stay one way in both rows.
#[test]
fn a_hand_made_list_splits_exactly() {
    use mobo::fmm::near_field::NearList;
    let rows: Vec<std::ops::Range<usize>> = (0..140).map(|r| 2 * r..2 * r + 2).collect();
    let mut list = NearList {
        rows: rows.clone(),
        offsets: vec![0],
        ranges: Vec::new(),
    };
    for r in 0..140 {
        match r {
            // The star: row 0 with rows 1..=130, and itself.
            0 => list.ranges.extend((0..=130).map(|b| rows[b].clone())),
            1..=130 => list.ranges.push(rows[0].clone()),
            // One-sided: row 131 sums row 132, which does not sum it back.
            131 => list.ranges.push(rows[132].clone()),
            _ => {}
        }
        list.offsets.push(list.ranges.len());
    }
    let split = MutualPairs::build(&list);
    assert!(split.fits(&list));
    let pairs = split.mutual_pairs();
    assert_eq!(pairs, 128, "the star's pairs up to the cap");
    assert_eq!(split.rounds().len(), 128);
    // Row 0 keeps itself and the two pairs past the cap one way; rows 129 and 130 keep row 0.
    let one = split.one_way();
    assert_eq!(one.row_ranges(0).len(), 3);
    assert!(one.row_ranges(0).contains(&rows[0]));
    assert_eq!(one.row_ranges(129), &[rows[0].clone()]);
    assert_eq!(one.row_ranges(131), &[rows[132].clone()]);
    assert!(one.row_ranges(1).is_empty());
    // Overlapping rows: not a tree's list, everything one way.
    let mut bad = list.clone();
    bad.rows[1] = 1..3;
    let split = MutualPairs::build(&bad);
    assert_eq!(split.mutual_pairs(), 0);
    assert_eq!(split.one_way(), &bad);
    assert!(!split.fits(&list));
}

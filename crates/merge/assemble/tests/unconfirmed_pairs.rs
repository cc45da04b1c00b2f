//! A pair that no triangle of pairs confirms needs more loop edges of its own
//! (`AssembleParams::unconfirmed_min_loops`) than one a triangle confirms. The pairs'
//! associations are given (`Assembler::add_segment_reusing`), so only the group checks run.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;

use mapmerge_assemble::{AssembleParams, Assembler, PairAssociation, Segment, SegmentLoop};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::LaserScan;
use nalgebra::Matrix3;

/// 40 scans 0.5 m apart along x, each seeing a wall 4 m ahead (what they see does not
/// matter here: every pair's association is given).
fn segment(name: &str) -> Segment {
    let poses: Vec<Se2> = (0..40)
        .map(|k| Se2::new(0.5 * k as f64, 0.0, 0.0))
        .collect();
    let scans = (0..40)
        .map(|_| LaserScan::new(-1.0, 1.0, 30.0, vec![4.0; 61]))
        .collect();
    Segment {
        name: name.to_owned(),
        stamps_secs: (0..40).map(f64::from).collect(),
        poses,
        scans,
    }
}

/// The association of `a < b` with `edges` loop edges between their submaps that all agree
/// with `a_from_b` (the group graphs join submap centres).
fn pair(a: &Segment, b: &Segment, a_from_b: Se2, edges: usize) -> PairAssociation {
    let preparer = Assembler::new(AssembleParams::default()).unwrap();
    let (pa, pb) = (preparer.prepare(a).unwrap(), preparer.prepare(b).unwrap());
    assert!(pa.submaps.len() >= edges && pb.submaps.len() >= edges);
    let loops: Vec<SegmentLoop> = (0..edges)
        .map(|k| {
            let (sa, sb) = (&pa.submaps[k], &pb.submaps[k]);
            SegmentLoop {
                from_segment: a.name.clone(),
                from_submap: sa.index,
                from_scan: sa.centre_scan,
                to_segment: b.name.clone(),
                to_submap: sb.index,
                to_scan: sb.centre_scan,
                from_from_to: sa
                    .segment_from_centre
                    .inverse()
                    .compose(&a_from_b)
                    .compose(&sb.segment_from_centre),
                score: 0.99,
                information: Matrix3::from_diagonal(&nalgebra::Vector3::new(100.0, 100.0, 1000.0)),
            }
        })
        .collect();
    PairAssociation {
        a: a.name.clone(),
        b: b.name.clone(),
        sequence_matches: edges,
        single_frame_matches: 0,
        zone_inliers: edges,
        verifications: edges,
        verified: edges,
        loops,
        a_from_b: Some(a_from_b),
        overlap_length_m: 3.0 * edges as f64,
        feature_distance_sq: 0.01,
        weight: 0.9,
        predicted_overlap: 0,
        predicted_agreement: 0,
    }
}

fn assemble(
    params: AssembleParams,
    segments: &[Segment],
    pairs: Vec<PairAssociation>,
) -> Assembler {
    let known: BTreeMap<(String, String), PairAssociation> = pairs
        .into_iter()
        .map(|p| ((p.a.clone(), p.b.clone()), p))
        .collect();
    let mut assembler = Assembler::new(params).unwrap();
    for s in segments {
        assembler.add_segment_reusing(s.clone(), &known).unwrap();
    }
    assembler
}

#[test]
fn a_segments_only_link_needs_more_edges_than_a_pair_in_a_triangle() {
    let (a, b) = (segment("a"), segment("b"));
    let a_from_b = Se2::new(1.0, 0.2, 0.1);
    let key = ("a".to_owned(), "b".to_owned());

    // Two agreeing edges and no triangle: refused (default 3).
    let mut two = assemble(
        AssembleParams::default(),
        &[a.clone(), b.clone()],
        vec![pair(&a, &b, a_from_b, 2)],
    );
    assert!(two.rejected_pairs().contains(&key));
    assert_eq!(two.groups().unwrap().len(), 2);
    assert_eq!(two.loops().count(), 0);

    // Three edges: kept.
    let mut three = assemble(
        AssembleParams::default(),
        &[a.clone(), b.clone()],
        vec![pair(&a, &b, a_from_b, 3)],
    );
    assert!(three.rejected_pairs().is_empty());
    assert_eq!(
        three.groups().unwrap(),
        vec![vec!["a".to_owned(), "b".to_owned()]]
    );

    // With the rule set to the pair's own minimum, two edges are enough again.
    let lenient = AssembleParams {
        unconfirmed_min_loops: 2,
        ..AssembleParams::default()
    };
    let mut kept = assemble(
        lenient,
        &[a.clone(), b.clone()],
        vec![pair(&a, &b, a_from_b, 2)],
    );
    assert!(kept.rejected_pairs().is_empty());
    assert_eq!(kept.groups().unwrap().len(), 1);
}

#[test]
fn pairs_a_consistent_triangle_confirms_keep_two_edges_and_a_contradicted_one_does_not_count() {
    let (a, b, c) = (segment("a"), segment("b"), segment("c"));
    let a_from_b = Se2::new(1.0, 0.2, 0.1);
    let b_from_c = Se2::new(-0.5, 0.8, -0.2);
    let a_from_c = a_from_b.compose(&b_from_c);
    let mut triangle = assemble(
        AssembleParams::default(),
        &[a.clone(), b.clone(), c.clone()],
        vec![
            pair(&a, &b, a_from_b, 2),
            pair(&b, &c, b_from_c, 2),
            pair(&a, &c, a_from_c, 2),
        ],
    );
    assert!(
        triangle.rejected_pairs().is_empty(),
        "{:?}",
        triangle.rejected_pairs()
    );
    assert_eq!(triangle.groups().unwrap().len(), 1);
    assert_eq!(triangle.loops().count(), 6);

    // The same triangle with a×c slid 6 m (a corridor slide): no triangle confirms any
    // pair, and with two edges each none of them stands alone.
    let slid = Se2::new(6.0, 0.0, 0.0).compose(&a_from_c);
    let mut contradicted = assemble(
        AssembleParams::default(),
        &[a.clone(), b.clone(), c.clone()],
        vec![
            pair(&a, &b, a_from_b, 2),
            pair(&b, &c, b_from_c, 2),
            pair(&a, &c, slid, 2),
        ],
    );
    assert_eq!(contradicted.groups().unwrap().len(), 3);
    assert_eq!(contradicted.loops().count(), 0);
}

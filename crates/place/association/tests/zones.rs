//! Zones + RANSAC with the edge-length test (AutoMerge Sec. V-A, Eq. 7): true overlaps survive,
//! aliased zones and pure outliers do not.

use mapmerge_association::{
    verify_zones, SubmapMatch, ZoneClustering, ZoneError, ZoneOutcome, ZoneParams,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Submap `i` of a 1 m-spaced trajectory that turns every 25 m (an office-like tour).
fn tour(i: usize) -> [f64; 3] {
    let leg = i / 25;
    let s = (i % 25) as f64;
    let corners = [
        [0.0, 0.0],
        [25.0, 0.0],
        [25.0, 25.0],
        [50.0, 25.0],
        [50.0, 50.0],
    ];
    let start = corners[leg % corners.len()];
    let heading = if leg % 2 == 0 { [1.0, 0.0] } else { [0.0, 1.0] };
    [start[0] + s * heading[0], start[1] + s * heading[1], 0.0]
}

/// `p` in B's odometry frame when B's frame is A's turned by 2 rad and shifted.
fn b_from_a(p: [f64; 3]) -> [f64; 3] {
    let (sin, cos) = 2.0f64.sin_cos();
    [
        cos * p[0] - sin * p[1] + 40.0,
        sin * p[0] + cos * p[1] - 13.0,
        0.0,
    ]
}

/// A with 100 submaps; B with 100 submaps, of which 40..60 revisit A's 10..30 (with 0.3 m of
/// noise) and the rest wander elsewhere.
fn segments(rng: &mut ChaCha8Rng) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let positions_a: Vec<[f64; 3]> = (0..100).map(tour).collect();
    let mut positions_b: Vec<[f64; 3]> = (0..100)
        .map(|j| {
            [
                300.0 + 2.0 * j as f64,
                -200.0 + (j as f64 * 0.3).sin() * 30.0,
                0.0,
            ]
        })
        .collect();
    for j in 40..60 {
        let p = b_from_a(positions_a[j - 30]);
        positions_b[j] = [
            p[0] + rng.random_range(-0.3..0.3),
            p[1] + rng.random_range(-0.3..0.3),
            0.0,
        ];
    }
    (positions_a, positions_b)
}

fn true_matches() -> Vec<SubmapMatch> {
    (10..30)
        .map(|i| SubmapMatch {
            query: i,
            reference: i + 30,
            distance: 0.1 + 0.001 * i as f32,
        })
        .collect()
}

fn is_true(m: &SubmapMatch) -> bool {
    m.reference == m.query + 30 && (10..30).contains(&m.query)
}

#[test]
fn scattered_aliased_zone_is_rejected_and_true_zone_kept() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let (positions_a, positions_b) = segments(&mut rng);
    let mut matches = true_matches();
    // A look-alike stretch of A (60..75) matched to places all over B: no consistent layout.
    for i in 60..75 {
        let reference = loop {
            let j = rng.random_range(0..100);
            if !(40..60).contains(&j) {
                break j;
            }
        };
        matches.push(SubmapMatch {
            query: i,
            reference,
            distance: 0.25,
        });
    }
    for clustering in [ZoneClustering::QueryIndex, ZoneClustering::FeatureDistance] {
        let params = ZoneParams {
            clustering,
            ..ZoneParams::default()
        };
        let result = verify_zones(&matches, &positions_a, &positions_b, &params).unwrap();
        assert!(
            result.inliers.iter().all(is_true),
            "{clustering:?}: aliased match kept: {:?}",
            result.inliers
        );
        assert!(
            result.inliers.len() >= 18,
            "{clustering:?}: only {} of 20 true matches kept",
            result.inliers.len()
        );
        assert_eq!(
            result.inlier_indices.len(),
            result.inliers.len(),
            "{clustering:?}"
        );
    }
}

#[test]
fn rigid_look_alike_zone_is_rejected_by_the_cross_check() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let (positions_a, mut positions_b) = segments(&mut rng);
    // B's 70..82 is a rigid copy of A's 60..72 under a different transform: a look-alike
    // corridor. On its own the zone is perfectly consistent; against the true zone it is not.
    for j in 70..82 {
        let p = positions_a[j - 10];
        positions_b[j] = [-p[1] + 200.0, p[0] + 150.0, 0.0];
    }
    let mut matches = true_matches();
    matches.extend((60..72).map(|i| SubmapMatch {
        query: i,
        reference: i + 10,
        distance: 0.3,
    }));
    let params = ZoneParams {
        zones: 2,
        ..ZoneParams::default()
    };
    let result = verify_zones(&matches, &positions_a, &positions_b, &params).unwrap();
    assert_eq!(result.inliers.len(), 20, "{:?}", result.zones);
    assert!(result.inliers.iter().all(is_true));
    let outcomes: Vec<ZoneOutcome> = result.zones.iter().map(|z| z.outcome).collect();
    assert_eq!(
        outcomes,
        vec![
            ZoneOutcome::Accepted,
            ZoneOutcome::Aliased { better_zone: 0 }
        ]
    );
    // The aliased zone was internally consistent: RANSAC found all of it.
    assert_eq!(result.zones[1].inliers.len(), 12);

    // Without the true zone the look-alike has nothing to disagree with and is kept: the
    // rejection above came from the cross-check, not from RANSAC.
    let alone: Vec<SubmapMatch> = matches[20..].to_vec();
    let result = verify_zones(&alone, &positions_a, &positions_b, &params).unwrap();
    assert_eq!(result.inliers.len(), 12);
}

#[test]
fn two_true_zones_of_one_placement_are_both_kept() {
    // B revisits two separate stretches of A under the same transform.
    let positions_a: Vec<[f64; 3]> = (0..100).map(tour).collect();
    let positions_b: Vec<[f64; 3]> = positions_a.iter().map(|&p| b_from_a(p)).collect();
    let matches: Vec<SubmapMatch> = (5..20)
        .chain(70..85)
        .map(|i| SubmapMatch {
            query: i,
            reference: i,
            distance: 0.1,
        })
        .collect();
    let result =
        verify_zones(&matches, &positions_a, &positions_b, &ZoneParams::default()).unwrap();
    assert_eq!(result.inliers, matches);
}

#[test]
fn all_outliers_give_nothing() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let positions_a: Vec<[f64; 3]> = (0..200)
        .map(|_| {
            [
                rng.random_range(0.0..500.0),
                rng.random_range(0.0..500.0),
                0.0,
            ]
        })
        .collect();
    let positions_b: Vec<[f64; 3]> = (0..200)
        .map(|_| {
            [
                rng.random_range(0.0..500.0),
                rng.random_range(0.0..500.0),
                0.0,
            ]
        })
        .collect();
    let matches: Vec<SubmapMatch> = (0..60)
        .map(|_| SubmapMatch {
            query: rng.random_range(0..200),
            reference: rng.random_range(0..200),
            distance: rng.random_range(0.1..0.5),
        })
        .collect();
    for clustering in [ZoneClustering::QueryIndex, ZoneClustering::FeatureDistance] {
        let params = ZoneParams {
            clustering,
            ..ZoneParams::default()
        };
        let result = verify_zones(&matches, &positions_a, &positions_b, &params).unwrap();
        assert!(
            result.inliers.is_empty(),
            "{clustering:?}: {:?}",
            result.zones
        );
        assert!(result
            .zones
            .iter()
            .all(|z| z.outcome == ZoneOutcome::TooFewInliers));
    }
}

#[test]
fn same_seed_same_result_and_every_match_in_one_zone() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let (positions_a, positions_b) = segments(&mut rng);
    let mut matches = true_matches();
    matches.extend((0..30).map(|_| SubmapMatch {
        query: rng.random_range(0..100),
        reference: rng.random_range(0..100),
        distance: 0.2,
    }));
    let params = ZoneParams {
        seed: 9,
        iterations: 20,
        ..ZoneParams::default()
    };
    let first = verify_zones(&matches, &positions_a, &positions_b, &params).unwrap();
    let second = verify_zones(&matches, &positions_a, &positions_b, &params).unwrap();
    assert_eq!(first, second);
    let mut seen: Vec<usize> = first
        .zones
        .iter()
        .flat_map(|z| z.candidates.iter().copied())
        .collect();
    seen.sort_unstable();
    assert_eq!(seen, (0..matches.len()).collect::<Vec<_>>());
}

#[test]
fn bad_input_is_refused() {
    let positions = vec![[0.0, 0.0, 0.0]; 3];
    let far = [SubmapMatch {
        query: 0,
        reference: 7,
        distance: 0.1,
    }];
    assert!(matches!(
        verify_zones(&far, &positions, &positions, &ZoneParams::default()),
        Err(ZoneError::SubmapOutOfRange { submap: 7, .. })
    ));
    let nan = [SubmapMatch {
        query: 0,
        reference: 1,
        distance: f32::NAN,
    }];
    assert!(matches!(
        verify_zones(&nan, &positions, &positions, &ZoneParams::default()),
        Err(ZoneError::NonFinite { .. })
    ));
    let mut bad_positions = positions.clone();
    bad_positions[1][2] = f64::INFINITY;
    let ok = [SubmapMatch {
        query: 0,
        reference: 1,
        distance: 0.1,
    }];
    assert!(matches!(
        verify_zones(&ok, &positions, &bad_positions, &ZoneParams::default()),
        Err(ZoneError::NonFinite { .. })
    ));
    for params in [
        ZoneParams {
            beta: 1.5,
            ..ZoneParams::default()
        },
        ZoneParams {
            sample_size: 1,
            ..ZoneParams::default()
        },
        ZoneParams {
            min_inliers: 2,
            ..ZoneParams::default()
        },
        ZoneParams {
            zones: 0,
            ..ZoneParams::default()
        },
    ] {
        assert!(matches!(
            verify_zones(&ok, &positions, &positions, &params),
            Err(ZoneError::InvalidParams(_))
        ));
    }
    let empty = verify_zones(&[], &positions, &positions, &ZoneParams::default()).unwrap();
    assert!(empty.inliers.is_empty() && empty.zones.is_empty());
}

//! Spectral grouping (AutoMerge Algorithm 1) and Eq. 9 confidences.

use mapmerge_association::{
    confidence, spectral_groups, GroupingError, GroupingParams, IncrementalGrouping,
};
use proptest::prelude::*;

fn matrix(n: usize, edges: &[(usize, usize, f64)]) -> Vec<f64> {
    let mut w = vec![0.0; n * n];
    for &(i, j, value) in edges {
        w[i * n + j] = value;
        w[j * n + i] = value;
    }
    w
}

#[test]
fn block_diagonal_weights_give_the_blocks() {
    // Blocks {0, 3, 5}, {1, 4, 6, 8}, {2, 7} (interleaved numbering), strong inside, with
    // small cross terms above the connection floor so the spectral cut, not the floor, decides.
    let blocks: [&[usize]; 3] = [&[0, 3, 5], &[1, 4, 6, 8], &[2, 7]];
    let mut edges = Vec::new();
    for block in blocks {
        for (a, &i) in block.iter().enumerate() {
            for &j in &block[a + 1..] {
                edges.push((i, j, 0.6 + 0.05 * ((i + j) % 5) as f64));
            }
        }
    }
    edges.extend([(0, 1, 0.004), (5, 6, 0.003), (4, 7, 0.002), (3, 2, 0.002)]);
    let groups = spectral_groups(&matrix(9, &edges), GroupingParams::default()).unwrap();
    assert_eq!(groups, vec![vec![0, 3, 5], vec![1, 4, 6, 8], vec![2, 7]]);

    // A cross term as strong as the blocks joins them.
    edges.push((5, 6, 0.9));
    let groups = spectral_groups(&matrix(9, &edges), GroupingParams::default()).unwrap();
    assert_eq!(groups, vec![vec![0, 1, 3, 4, 5, 6, 8], vec![2, 7]]);
}

#[test]
fn isolated_vertices_are_their_own_groups() {
    // 1 and 4 have no weight at all, 3 only one below the floor.
    let w = matrix(6, &[(0, 2, 0.8), (2, 5, 0.7), (0, 5, 0.9), (3, 5, 1e-5)]);
    let groups = spectral_groups(&w, GroupingParams::default()).unwrap();
    assert_eq!(groups, vec![vec![0, 2, 5], vec![1], vec![3], vec![4]]);
    assert_eq!(
        spectral_groups(&[], GroupingParams::default()).unwrap(),
        Vec::<Vec<usize>>::new()
    );
    assert_eq!(
        spectral_groups(&[0.0], GroupingParams::default()).unwrap(),
        vec![vec![0]]
    );
}

#[test]
fn every_group_is_connected() {
    // Two tight pairs {0, 1} and {3, 4}, each hanging weakly on a big hub clique {5..9}, and 2
    // bridging nothing but the hub: three groups, each connected.
    let mut edges = vec![
        (0, 1, 1.0),
        (3, 4, 1.0),
        (1, 5, 0.002),
        (3, 6, 0.002),
        (2, 7, 0.9),
    ];
    for i in 5..10 {
        for j in i + 1..10 {
            edges.push((i, j, 1.0));
        }
    }
    let w = matrix(10, &edges);
    let groups = spectral_groups(&w, GroupingParams::default()).unwrap();
    for group in &groups {
        assert!(is_connected(&w, 10, group, 1e-3), "{groups:?}");
    }
    assert_eq!(groups, vec![vec![0, 1], vec![2, 5, 6, 7, 8, 9], vec![3, 4]]);
}

fn is_connected(w: &[f64], n: usize, group: &[usize], floor: f64) -> bool {
    let mut reached = vec![group[0]];
    let mut frontier = vec![group[0]];
    while let Some(v) = frontier.pop() {
        for &u in group {
            if !reached.contains(&u) && w[v * n + u] >= floor {
                reached.push(u);
                frontier.push(u);
            }
        }
    }
    reached.len() == group.len()
}

#[test]
fn bad_weights_are_refused() {
    let params = GroupingParams::default();
    assert_eq!(
        spectral_groups(&[0.0; 5], params),
        Err(GroupingError::NotSquare { len: 5 })
    );
    let mut w = matrix(3, &[(0, 1, 0.5)]);
    w[2 * 3 + 1] = 0.3;
    assert_eq!(
        spectral_groups(&w, params),
        Err(GroupingError::Asymmetric { row: 1, col: 2 })
    );
    let w = matrix(2, &[(0, 1, -0.5)]);
    assert!(matches!(
        spectral_groups(&w, params),
        Err(GroupingError::InvalidWeight { .. })
    ));
    let w = matrix(2, &[(0, 1, f64::NAN)]);
    assert!(matches!(
        spectral_groups(&w, params),
        Err(GroupingError::InvalidWeight { .. })
    ));
    let bad_theta = GroupingParams {
        theta: f64::NAN,
        ..params
    };
    assert!(matches!(
        spectral_groups(&[0.0], bad_theta),
        Err(GroupingError::InvalidParams(_))
    ));
}

/// Blocks of sizes `sizes` (≥ 2 each) with strong random internal weights and sparse tiny
/// cross weights; returns the weights and the blocks as canonical groups.
fn planted(sizes: &[usize], internal: &[f64], cross: &[f64]) -> (Vec<f64>, Vec<Vec<usize>>) {
    let n: usize = sizes.iter().sum();
    let mut block_of = Vec::with_capacity(n);
    for (b, &size) in sizes.iter().enumerate() {
        block_of.extend(std::iter::repeat_n(b, size));
    }
    let mut w = vec![0.0; n * n];
    let mut pair = 0;
    for i in 0..n {
        for j in i + 1..n {
            let value = if block_of[i] == block_of[j] {
                internal[pair % internal.len()]
            } else {
                cross[pair % cross.len()]
            };
            w[i * n + j] = value;
            w[j * n + i] = value;
            pair += 1;
        }
    }
    let mut blocks = vec![Vec::new(); sizes.len()];
    for (i, &b) in block_of.iter().enumerate() {
        blocks[b].push(i);
    }
    (w, blocks)
}

fn permuted(w: &[f64], n: usize, new_of_old: &[usize]) -> Vec<f64> {
    let mut out = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..n {
            out[new_of_old[i] * n + new_of_old[j]] = w[i * n + j];
        }
    }
    out
}

fn canonical(mut groups: Vec<Vec<usize>>) -> Vec<Vec<usize>> {
    for group in &mut groups {
        group.sort_unstable();
    }
    groups.sort();
    groups
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn permuting_segments_permutes_the_groups(
        sizes in prop::collection::vec(2usize..6, 1..5),
        internal in prop::collection::vec(0.5f64..1.0, 1..40),
        cross in prop::collection::vec(
            prop_oneof![Just(0.0), 0.0f64..0.0004], 1..40),
        shuffle_seed in any::<u64>(),
    ) {
        let (w, blocks) = planted(&sizes, &internal, &cross);
        let n = blocks.iter().map(Vec::len).sum::<usize>();
        // Fisher–Yates from a small LCG so the permutation is a function of the seed.
        let mut new_of_old: Vec<usize> = (0..n).collect();
        let mut state = shuffle_seed | 1;
        for i in (1..n).rev() {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            new_of_old.swap(i, (state >> 33) as usize % (i + 1));
        }
        let params = GroupingParams { connection_floor: 1e-6, ..GroupingParams::default() };
        let groups = spectral_groups(&w, params).unwrap();
        prop_assert_eq!(&groups, &canonical(blocks));
        let groups_permuted = spectral_groups(&permuted(&w, n, &new_of_old), params).unwrap();
        let mut old_of_new = vec![0; n];
        for (old, &new) in new_of_old.iter().enumerate() {
            old_of_new[new] = old;
        }
        let mapped_back: Vec<Vec<usize>> = groups_permuted
            .iter()
            .map(|g| g.iter().map(|&v| old_of_new[v]).collect())
            .collect();
        prop_assert_eq!(canonical(mapped_back), groups);
    }
}

/// Fig. 13's recovery: a wrong early connection between two true groups is cut once the
/// groups' own overlaps arrive.
#[test]
fn weak_early_connection_is_dropped_when_strong_evidence_arrives() {
    let truth = [
        vec!["a1", "a2", "a3", "a4"],
        vec!["b1", "b2", "b3", "b4"],
        vec!["c1", "c2", "c3"],
    ];
    // Arrival in a scrambled order.
    let arrival = [
        "b3", "a2", "c1", "a4", "b1", "c3", "a1", "b4", "c2", "a3", "b2",
    ];
    let mut grouping = IncrementalGrouping::new(GroupingParams::default());
    let add = |grouping: &mut IncrementalGrouping<&str>, key: &'static str| {
        assert!(grouping.add_segment(key));
        assert!(!grouping.add_segment(key));
    };
    // Early: short partial overlaps only, so every weight is weak, and a spurious match a2–b3
    // (perceptual aliasing) as strong as the true ones.
    for key in &arrival[..6] {
        add(&mut grouping, key);
    }
    grouping.set_weight(&"a2", &"a4", 0.05).unwrap();
    grouping.set_weight(&"b3", &"b1", 0.05).unwrap();
    grouping.set_weight(&"a2", &"b3", 0.05).unwrap();
    grouping.set_weight(&"c1", &"c3", 0.05).unwrap();
    let early = grouping.groups().unwrap().to_vec();
    assert!(
        early.iter().any(|g| g.contains(&"a2") && g.contains(&"b3")),
        "the spurious connection should join the groups early on: {early:?}"
    );

    // Later: the rest arrives and the true overlaps grow long (strong ω).
    for key in &arrival[6..] {
        add(&mut grouping, key);
    }
    for group in &truth {
        for (i, a) in group.iter().enumerate() {
            for b in &group[i + 1..] {
                grouping.set_weight(a, b, 0.9).unwrap();
            }
        }
    }
    let late = grouping.groups().unwrap().to_vec();
    let mut expected: Vec<Vec<&str>> = truth
        .iter()
        .map(|g| {
            let mut g = g.clone();
            g.sort_unstable();
            g
        })
        .collect();
    expected.sort();
    assert_eq!(late, expected);
    assert_eq!(
        grouping.weight(&"b3", &"a2"),
        0.05,
        "the spurious weight is still there"
    );
}

#[test]
fn incremental_groups_do_not_depend_on_arrival_order() {
    let edges = [
        (3usize, 7usize, 0.8),
        (7, 1, 0.7),
        (1, 3, 0.6),
        (2, 5, 0.9),
        (5, 0, 0.5),
        (3, 2, 0.004),
        (4, 6, 0.0005),
    ];
    let run = |order: &[usize]| {
        let mut grouping = IncrementalGrouping::default();
        for &key in order {
            grouping.add_segment(key);
            for &(a, b, w) in &edges {
                if (a == key || b == key)
                    && grouping.segments().any(|&s| s == a)
                    && grouping.segments().any(|&s| s == b)
                {
                    grouping.set_weight(&a, &b, w).unwrap();
                }
            }
            grouping.groups().unwrap();
        }
        grouping.groups().unwrap().to_vec()
    };
    let forward = run(&[0, 1, 2, 3, 4, 5, 6, 7]);
    assert_eq!(
        forward,
        vec![vec![0, 2, 5], vec![1, 3, 7], vec![4], vec![6]]
    );
    assert_eq!(run(&[7, 6, 5, 4, 3, 2, 1, 0]), forward);
    assert_eq!(run(&[4, 1, 6, 0, 3, 7, 5, 2]), forward);
}

#[test]
fn incremental_refuses_unknown_and_self_weights_and_tracks_changes() {
    let mut grouping: IncrementalGrouping<String> = IncrementalGrouping::default();
    grouping.add_segment("x".to_string());
    grouping.add_segment("y".to_string());
    assert!(matches!(
        grouping.set_weight(&"x".into(), &"z".into(), 0.5),
        Err(GroupingError::UnknownSegment(_))
    ));
    assert!(matches!(
        grouping.set_weight(&"x".into(), &"x".into(), 0.5),
        Err(GroupingError::SelfWeight(_))
    ));
    assert!(matches!(
        grouping.set_weight(&"x".into(), &"y".into(), -1.0),
        Err(GroupingError::InvalidWeight { .. })
    ));
    assert_eq!(grouping.groups().unwrap().len(), 2);
    grouping.set_weight(&"y".into(), &"x".into(), 0.5).unwrap();
    assert_eq!(
        grouping.groups().unwrap(),
        &[vec!["x".to_string(), "y".to_string()]]
    );
    // Lowering the evidence to nothing separates them again.
    grouping.set_weight(&"x".into(), &"y".into(), 0.0).unwrap();
    assert_eq!(grouping.groups().unwrap().len(), 2);
    assert_eq!(grouping.len(), 2);
}

#[test]
fn eq9_confidence() {
    // exp(−(‖F‖² + C_ω) / (2 L² + ε)) at ‖F‖² = 1, L = 2 m, C_ω = 3.
    let expected = (-(1.0f64 + 3.0) / (8.0 + 1e-4)).exp();
    assert!((confidence(1.0, 2.0, 3.0) - expected).abs() < 1e-15);
    // No overlap, bad input: no confidence.
    assert_eq!(confidence(0.1, 0.0, 3.0), 0.0);
    assert_eq!(confidence(0.1, -4.0, 3.0), 0.0);
    assert_eq!(confidence(f64::NAN, 4.0, 3.0), 0.0);
    assert_eq!(confidence(0.1, f64::INFINITY, 3.0), 0.0);
    // Monotone: longer overlaps raise ω, larger feature distances lower it.
    let mut previous = 0.0;
    for length_m in [0.5, 1.0, 2.0, 5.0, 10.0, 50.0, 500.0] {
        let omega = confidence(0.2, length_m, 25.0);
        assert!(omega > previous && omega <= 1.0, "L = {length_m}: {omega}");
        previous = omega;
    }
    let mut previous = 1.0;
    for distance_sq in [0.0, 0.1, 0.5, 1.0, 4.0] {
        let omega = confidence(distance_sq, 10.0, 25.0);
        assert!(
            omega < previous && omega > 0.0,
            "‖F‖² = {distance_sq}: {omega}"
        );
        previous = omega;
    }
    // ‖F‖² ≪ C_ω: ω ≈ exp(−C_ω / 2L²).
    assert!((confidence(1e-9, 10.0, 50.0) - (-0.25f64).exp()).abs() < 1e-6);
}

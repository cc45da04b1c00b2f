//! The robot never passes through a wall, a piece of furniture or a closed door: every move
//! between consecutive scans (kidnap jumps excepted) is checked against every segment of
//! that session's world, brute force.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use mapmerge_sim::{simulate, ChangeParams, SimParams, WorldChange, WorldPreset};

#[test]
fn the_robot_never_crosses_an_obstacle_in_any_preset_or_session() {
    let mut closed_doors_seen = 0;
    for (k, preset) in WorldPreset::ALL.into_iter().enumerate() {
        let params = SimParams {
            changes: ChangeParams {
                doors_closed: 3,
                ..ChangeParams::default()
            },
            ..SimParams::default()
                .with_preset(preset)
                .with_sessions(3)
                .with_duration_secs(240.0)
        };
        let dataset = simulate(&params, 100 + k as u64).unwrap();
        for session in &dataset.sessions {
            closed_doors_seen += session
                .world_changes
                .iter()
                .filter(|c| matches!(c, WorldChange::DoorClosed { .. }))
                .count();
            let segments = session.world.segments();
            let jumps: Vec<usize> = session.kidnaps.iter().map(|k| k.scan_index).collect();
            for (i, pair) in session.truth.windows(2).enumerate() {
                if jumps.contains(&(i + 1)) {
                    continue;
                }
                let (a, b) = (pair[0].1.translation(), pair[1].1.translation());
                for s in &segments {
                    assert!(
                        !common::crosses(&a, &b, &s.start_m, &s.end_m),
                        "{preset} session {}: move {i} from {a:?} to {b:?} crosses {s:?}",
                        session.index
                    );
                }
            }
            for (i, (_, pose)) in session.truth.iter().enumerate() {
                let p = pose.translation();
                assert!(
                    !session.world.is_inside_obstacle(&p),
                    "{preset}: pose {i} inside an obstacle"
                );
                assert!(session.world.is_inside_building(&p));
                // The safety stop keeps 10 cm (the planner 30 cm).
                assert!(
                    common::clearance(&session.world, &p) > 0.099,
                    "{preset}: pose {i} touches an obstacle"
                );
            }
            assert!(
                session.motion.distance_m > 50.0,
                "{preset}: the robot hardly moved"
            );
            assert!(
                session.motion.visited_rooms.len() >= 3,
                "{preset}: {:?}",
                session.motion.visited_rooms
            );
        }
    }
    assert!(
        closed_doors_seen >= 8,
        "only {closed_doors_seen} closed doors"
    );
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(12))]

    /// Any seed, any preset: no move between two scans crosses an obstacle.
    #[test]
    fn no_seed_makes_the_robot_cross_a_wall(seed in proptest::prelude::any::<u64>(), preset in 0usize..WorldPreset::ALL.len()) {
        let params = SimParams::default()
            .with_preset(WorldPreset::ALL[preset])
            .with_sessions(2)
            .with_duration_secs(60.0);
        let dataset = simulate(&params, seed).unwrap();
        for session in &dataset.sessions {
            let segments = session.world.segments();
            for (i, pair) in session.truth.windows(2).enumerate() {
                if session.kidnaps.iter().any(|k| k.scan_index == i + 1) {
                    continue;
                }
                let (a, b) = (pair[0].1.translation(), pair[1].1.translation());
                proptest::prop_assert!(segments.iter().all(|s| !common::crosses(&a, &b, &s.start_m, &s.end_m)));
            }
            proptest::prop_assert_eq!(session.motion.safety_stops, 0);
        }
    }
}

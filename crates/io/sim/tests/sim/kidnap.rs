//! Kidnaps: the truth jumps, the odometry does not.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_sim::{simulate, KidnapParams, KidnapTarget, SimParams, WorldPreset};

#[test]
fn truth_jumps_while_odometry_goes_on() {
    let params = SimParams {
        kidnap: KidnapParams {
            max_per_session: 2,
            probability: 1.0,
            target: KidnapTarget::Random,
            ..KidnapParams::default()
        },
        ..SimParams::default()
            .with_sessions(3)
            .with_duration_secs(120.0)
    };
    let dataset = simulate(&params, 9).unwrap();
    for session in &dataset.sessions {
        assert_eq!(session.kidnaps.len(), 2, "session {}", session.index);
        let odometry: Vec<Se2> = common::scan_odometry(session);
        for kidnap in &session.kidnaps {
            let i = kidnap.scan_index;
            assert!(i > 0 && i < session.truth.len());
            assert!(
                session.truth[i].0 >= kidnap.stamp_secs - 1e-6
                    && session.truth[i - 1].0 < kidnap.stamp_secs - 1e-6
            );
            // The truth jumps by at least the minimum distance...
            let jump =
                (session.truth[i].1.translation() - session.truth[i - 1].1.translation()).norm();
            assert!(jump >= params.kidnap.min_distance_m - 0.2, "jump {jump}");
            assert!(
                (kidnap.from.translation() - kidnap.to.translation()).norm()
                    >= params.kidnap.min_distance_m
            );
            // ...while the odometry moves no more than the robot can in 0.1 s.
            let step = odometry[i - 1].between(&odometry[i]).translation().norm();
            assert!(step < 0.1, "odometry moved {step} m across the kidnap");
        }
        // Elsewhere the truth moves smoothly.
        for (i, pair) in session.truth.windows(2).enumerate() {
            if session.kidnaps.iter().all(|k| k.scan_index != i + 1) {
                let d = (pair[1].1.translation() - pair[0].1.translation()).norm();
                assert!(d < 0.1, "truth moved {d} m between scans {i} and {}", i + 1);
            }
        }
    }
}

#[test]
fn no_kidnaps_when_disabled() {
    let params = SimParams {
        kidnap: KidnapParams::none(),
        ..SimParams::default()
            .with_sessions(2)
            .with_duration_secs(60.0)
    };
    assert!(simulate(&params, 1)
        .unwrap()
        .sessions
        .iter()
        .all(|s| s.kidnaps.is_empty()));
}

#[test]
fn look_alike_kidnaps_land_on_the_same_spot_of_a_copy() {
    // Start every session in one of the three identical rooms and kidnap early, while the
    // robot is most likely still in it (or in a repeated-section room).
    let world = WorldPreset::OfficeAliased.params();
    let generated = mapmerge_sim::generate_world(&world, 1).unwrap();
    let aliased: Vec<String> = generated
        .rooms
        .iter()
        .filter(|r| r.alias_group.is_some() && generated.look_alikes(r.id).len() >= 2)
        .map(|r| r.name.clone())
        .collect();
    assert!(aliased.len() >= 3, "{aliased:?}");
    let mut landed_in_copies = 0;
    for seed in 0..6u64 {
        let params = SimParams {
            world_seed: Some(1),
            start_rooms: vec![aliased[seed as usize % aliased.len()].clone()],
            kidnap: KidnapParams {
                max_per_session: 1,
                probability: 1.0,
                min_gap_secs: 1.0,
                target: KidnapTarget::LookAlike,
                ..KidnapParams::default()
            },
            robot: mapmerge_sim::RobotParams {
                dwell_max_secs: 6.0,
                ..Default::default()
            },
            ..SimParams::default()
                .with_preset(WorldPreset::OfficeAliased)
                .with_sessions(1)
                .with_duration_secs(3.0)
        };
        let dataset = simulate(&params, seed).unwrap();
        let session = &dataset.sessions[0];
        let kidnap = session.kidnaps[0];
        let from_room = session.world.room_at(&kidnap.from.translation()).unwrap();
        let to_room = session.world.room_at(&kidnap.to.translation()).unwrap();
        if from_room.alias_group.is_some() {
            assert_eq!(from_room.alias_group, to_room.alias_group);
            assert_ne!(from_room.id, to_room.id);
            let in_from = from_room.world_from_room.inverse().compose(&kidnap.from);
            let in_to = to_room.world_from_room.inverse().compose(&kidnap.to);
            assert!((in_from.translation() - in_to.translation()).norm() < 1e-9);
            landed_in_copies += 1;
        }
    }
    assert!(landed_in_copies >= 3, "{landed_in_copies}");
}

//! The shape of a dataset: sessions, start places, time stamps, the log's records.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_sim::{simulate, SimError, SimParams, WorldPreset, SCAN_SOURCE_TAG};

#[test]
fn sessions_have_logs_truth_and_stamps_as_configured() {
    let params = SimParams {
        odometry_rate_hz: 25.0,
        scan_rate_hz: 8.0,
        first_stamp_secs: 1000.0,
        session_spacing_secs: 500.0,
        ..SimParams::default()
            .with_sessions(3)
            .with_duration_secs(30.0)
    };
    let dataset = simulate(&params, 2).unwrap();
    assert_eq!(dataset.world_name, "office");
    assert_eq!(dataset.seed, 2);
    assert_eq!(dataset.params, params);
    for (index, session) in dataset.sessions.iter().enumerate() {
        assert_eq!(session.index, index);
        let start = 1000.0 + 500.0 * index as f64;
        let log = &session.log;
        assert_eq!(log.odometry.len(), 751);
        assert_eq!(log.scans.len(), 241);
        assert_eq!(session.truth.len(), log.scans.len());
        assert_eq!(log.odometry[0].stamp_secs, start);
        assert!((log.odometry[1].stamp_secs - start - 0.04).abs() < 1e-9);
        assert!((log.scans[1].stamp_secs - start - 0.125).abs() < 1e-9);
        for (record, (stamp, _)) in log.scans.iter().zip(&session.truth) {
            assert_eq!(record.stamp_secs, *stamp);
            assert_eq!(record.source_tag, SCAN_SOURCE_TAG);
            assert!(record.odom_from_robot.is_some());
            assert_eq!(record.scan.range_max_m, 30.0);
            assert_eq!(record.scan.ranges_m.len(), 360);
        }
        assert!(log
            .scans
            .windows(2)
            .all(|w| w[0].stamp_secs < w[1].stamp_secs));
        assert_eq!(
            log.params.get("mapmerge_sim_session"),
            Some(&index.to_string())
        );
        // The start is in the start room.
        let start_room = session.world.room(session.start_room).unwrap();
        assert!(start_room.rect.contains(&session.truth[0].1.translation()));
        assert_eq!(session.motion.visited_rooms[0], session.start_room);
    }
    let starts: Vec<_> = dataset.sessions.iter().map(|s| s.start_room).collect();
    assert!(
        starts[0] != starts[1] && starts[1] != starts[2] && starts[0] != starts[2],
        "{starts:?}"
    );
}

#[test]
fn named_start_rooms_are_used_and_unknown_ones_refused() {
    let params = SimParams {
        start_rooms: vec!["room-03".to_owned(), "room-07".to_owned()],
        ..SimParams::default()
            .with_preset(WorldPreset::CorridorLoop)
            .with_sessions(3)
            .with_duration_secs(10.0)
    };
    let dataset = simulate(&params, 5).unwrap();
    let name = |i: usize| {
        dataset.sessions[i]
            .world
            .room(dataset.sessions[i].start_room)
            .unwrap()
            .name
            .clone()
    };
    assert_eq!((name(0).as_str(), name(1).as_str()), ("room-03", "room-07"));
    let bad = SimParams {
        start_rooms: vec!["kitchen".to_owned()],
        ..params
    };
    assert!(matches!(
        simulate(&bad, 5),
        Err(SimError::UnknownStartRoom { session: 0, .. })
    ));
}

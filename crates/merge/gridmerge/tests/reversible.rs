//! Reversibility (Andersone, Sec. 3.1 and 3.2): undo in 2M gives back exactly the map that
//! never merged; undo in 1M keeps exactly the locally updated cells.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use core::f64::consts::PI;

use mapmerge_geometry::Se2;
use mapmerge_grid::{GridGeometry, OccupancyGrid, Point2};
use mapmerge_gridmerge::{
    CheckInput, GridMergeEvent, GridMergeEventKind, KeepMerge, MapperState, MergeError, Metric,
    ReversibleMapper, ReversibleMode, ReversibleParams, UndoReason, Verdict,
};
use mapmerge_scan::LaserScan;
use proptest::prelude::*;

/// A scan pose (x, y, yaw) and its ranges.
type PosedScan = (Se2, LaserScan);

fn scan_strategy(reach_m: f64) -> impl Strategy<Value = PosedScan> {
    (
        -reach_m..reach_m,
        -reach_m..reach_m,
        -PI..PI,
        prop::collection::vec(0.2f32..5.0, 5..40),
    )
        .prop_map(|(x, y, yaw, ranges)| {
            // Some beams without a return (≥ range_max): free space only, or skipped.
            let ranges = ranges
                .into_iter()
                .enumerate()
                .map(|(i, r)| if i % 7 == 3 { 6.0 } else { r })
                .collect();
            (Se2::new(x, y, yaw), LaserScan::new(-2.0, 2.0, 6.0, ranges))
        })
}

/// Map B: random log-odds (a third unknown) on a random grid near the origin.
fn other_map() -> impl Strategy<Value = OccupancyGrid> {
    (
        prop::sample::select(vec![0.05, 0.07, 0.1, 0.14]),
        -3.0f64..0.0,
        -3.0f64..0.0,
        3usize..30,
        3usize..30,
    )
        .prop_flat_map(|(resolution_m, x, y, width, height)| {
            let geometry = GridGeometry {
                resolution_m,
                origin_m: Point2::new(x, y),
                width,
                height,
            };
            prop::collection::vec(
                prop_oneof![Just(0.0f32), -2.0f32..-0.1, 0.1f32..3.0],
                width * height,
            )
            .prop_map(move |values| OccupancyGrid::from_log_odds(geometry, values).unwrap())
        })
}

fn transform() -> impl Strategy<Value = Se2> {
    (-1.0f64..1.0, -1.0f64..1.0, -PI..PI).prop_map(|(x, y, yaw)| Se2::new(x, y, yaw))
}

fn insert_all(grid: &mut OccupancyGrid, scans: &[PosedScan], params: &ReversibleParams) {
    for (pose, scan) in scans {
        grid.insert_scan(pose, scan, &params.insert).unwrap();
    }
}

fn bits(grid: &OccupancyGrid) -> Vec<u32> {
    grid.log_odds().iter().map(|l| l.to_bits()).collect()
}

/// A check that fails at `fail_at` scans since the merge.
fn fail_at(fail_at: usize) -> impl Fn(&CheckInput<'_>) -> Verdict {
    move |input: &CheckInput<'_>| {
        let metrics = vec![Metric {
            name: "scans".into(),
            value: input.scans_since_merge as f64,
        }];
        if input.scans_since_merge >= fail_at {
            Verdict::Inconsistent {
                reason: format!("failed at {}", input.scans_since_merge),
                metrics,
            }
        } else {
            Verdict::Consistent { metrics }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// 2M (Sec. 3.1): after undo — by request or by a failing check — the own map is bit for
    /// bit the map of a copy that never merged and got the same scans; it also is at every
    /// scan in between.
    #[test]
    fn undo_in_2m_restores_the_never_merged_map(
        before in prop::collection::vec(scan_strategy(3.0), 1..4),
        after in prop::collection::vec(scan_strategy(6.0), 0..12),
        resolution_m in prop::sample::select(vec![0.05, 0.1]),
        b in other_map(),
        a_from_b in transform(),
        check_every in 0usize..4,
        fail in 1usize..12,
    ) {
        let params = ReversibleParams {
            mode: ReversibleMode::MultiMap,
            check_every_scans: check_every,
            ..ReversibleParams::default()
        };
        let mut reference = OccupancyGrid::new(resolution_m).unwrap();
        let mut mapper = ReversibleMapper::new(reference.clone(), params).unwrap();
        for (pose, scan) in &before {
            mapper.insert_scan(pose, scan, &KeepMerge).unwrap();
        }
        insert_all(&mut reference, &before, &params);
        prop_assert_eq!(mapper.current(), &reference);
        mapper.merge(&b, &a_from_b, "test").unwrap();
        let check = fail_at(fail);
        for (i, (pose, scan)) in after.iter().enumerate() {
            let update = mapper.insert_scan(pose, scan, &check).unwrap();
            insert_all(&mut reference, &after[i..=i], &params);
            prop_assert_eq!(mapper.own().unwrap(), &reference);
            prop_assert_eq!(update.undone, mapper.state() == MapperState::Own
                && update.verdict.is_some());
        }
        if mapper.state() == MapperState::MultiMap {
            mapper.undo("end of test").unwrap();
        }
        prop_assert_eq!(mapper.state(), MapperState::Own);
        prop_assert_eq!(mapper.current().geometry(), reference.geometry());
        prop_assert_eq!(bits(mapper.current()), bits(&reference));
        // One merge, one undo, with verifications in between.
        let events = mapper.events();
        let merged_first = matches!(events.first().map(|e| &e.kind), Some(GridMergeEventKind::Merged { .. }));
        let undone_last = matches!(events.last().map(|e| &e.kind), Some(GridMergeEventKind::Undone { .. }));
        prop_assert!(merged_first && undone_last);
        prop_assert_eq!(mapper.update_times().len(), before.len() + after.len());
    }

    /// 1M (Sec. 3.2): after undo every locally updated cell (observed by the robot before the
    /// merge or touched by a scan after it) keeps the merged map's value and every other cell
    /// is unknown.
    #[test]
    fn undo_in_1m_keeps_exactly_the_local_cells(
        before in prop::collection::vec(scan_strategy(3.0), 1..4),
        after in prop::collection::vec(scan_strategy(6.0), 0..10),
        b in other_map(),
        a_from_b in transform(),
    ) {
        let params = ReversibleParams {
            mode: ReversibleMode::SingleMap,
            check_every_scans: 0,
            ..ReversibleParams::default()
        };
        // A big enough grid that neither scans nor B make it grow: the merged map then has
        // A's geometry and a copy of A that never merged is the oracle of "touched".
        let geometry = GridGeometry {
            resolution_m: 0.1,
            origin_m: Point2::new(-20.0, -20.0),
            width: 400,
            height: 400,
        };
        let mut reference = OccupancyGrid::with_geometry(geometry).unwrap();
        insert_all(&mut reference, &before, &params);
        let mut mapper = ReversibleMapper::new(reference.clone(), params).unwrap();
        mapper.merge(&b, &a_from_b, "test").unwrap();
        prop_assert_eq!(mapper.state(), MapperState::SingleMap);
        prop_assert!(mapper.own().is_none());
        for (pose, scan) in &after {
            mapper.insert_scan(pose, scan, &KeepMerge).unwrap();
        }
        insert_all(&mut reference, &after, &params);
        let merged = mapper.merged().unwrap().clone();
        let local = mapper.local_updates().unwrap().clone();
        prop_assert_eq!(merged.geometry(), &geometry);
        prop_assert_eq!(local.geometry(), &geometry);
        mapper.undo("end of test").unwrap();
        let undone = mapper.current();
        prop_assert_eq!(undone.geometry(), &geometry);
        let mut reset = 0;
        for (i, ((&u, &m), &r)) in undone
            .log_odds()
            .iter()
            .zip(merged.log_odds())
            .zip(reference.log_odds())
            .enumerate()
        {
            let flagged = local.flags().nth(i).unwrap();
            prop_assert_eq!(flagged, r != 0.0, "local-update map at cell {}", i);
            if r != 0.0 {
                prop_assert_eq!(u.to_bits(), m.to_bits(), "local cell {} changed", i);
            } else {
                prop_assert_eq!(u, 0.0, "cell {} not updated locally is not unknown", i);
                reset += usize::from(m != 0.0);
            }
        }
        match &mapper.events().last().unwrap().kind {
            GridMergeEventKind::Undone { cells_reset, mode, .. } => {
                prop_assert_eq!(*cells_reset, reset);
                prop_assert_eq!(*mode, ReversibleMode::SingleMap);
            }
            other => prop_assert!(false, "last event {:?}", other),
        }
    }
}

fn room_scan() -> LaserScan {
    LaserScan::new(-PI / 2.0, PI / 2.0, 8.0, vec![2.0; 91])
}

#[test]
fn a_failing_check_undoes_the_merge_and_is_logged() {
    let params = ReversibleParams {
        check_every_scans: 3,
        ..ReversibleParams::default()
    };
    let mut mapper = ReversibleMapper::new(OccupancyGrid::new(0.05).unwrap(), params).unwrap();
    let scan = room_scan();
    mapper
        .insert_scan(&Se2::new(0.0, 0.0, 0.0), &scan, &KeepMerge)
        .unwrap();
    let b = mapper.current().clone();
    let merge = mapper
        .merge(&b, &Se2::new(5.0, 0.0, 0.0), "record grids-known-pose")
        .unwrap();
    assert!(matches!(merge.kind, GridMergeEventKind::Merged { .. }));
    assert!(matches!(
        mapper.merge(&b, &Se2::new(0.0, 0.0, 0.0), "again"),
        Err(MergeError::AlreadyMerged(_))
    ));
    let check = fail_at(6);
    let mut verdicts = Vec::new();
    for i in 0..8 {
        let update = mapper
            .insert_scan(&Se2::new(0.1 * f64::from(i), 0.0, 0.0), &scan, &check)
            .unwrap();
        verdicts.push((update.verdict.map(|v| v.is_consistent()), update.undone));
    }
    assert_eq!(
        verdicts,
        vec![
            (None, false),
            (None, false),
            (Some(true), false),
            (None, false),
            (None, false),
            (Some(false), true),
            (None, false),
            (None, false),
        ]
    );
    assert_eq!(mapper.state(), MapperState::Own);
    assert!(matches!(mapper.undo("again"), Err(MergeError::NotMerged)));
    let kinds: Vec<&str> = mapper
        .events()
        .iter()
        .map(|e| match e.kind {
            GridMergeEventKind::Merged { .. } => "merged",
            GridMergeEventKind::Verified { .. } => "verified",
            GridMergeEventKind::Undone { .. } => "undone",
        })
        .collect();
    assert_eq!(kinds, ["merged", "verified", "verified", "undone"]);
    let undone = mapper.events().last().unwrap();
    assert_eq!(undone.after_scans, 7);
    assert!(matches!(
        &undone.kind,
        GridMergeEventKind::Undone { reason: UndoReason::CheckFailed { reason, .. }, scans_since_merge: 6, .. }
            if reason == "failed at 6"
    ));
    // The event list is data: it survives JSON.
    let json = serde_json::to_string(mapper.events()).unwrap();
    let back: Vec<GridMergeEvent> = serde_json::from_str(&json).unwrap();
    assert_eq!(back, mapper.events());
    // Update times: one per scan, by state.
    let states: Vec<MapperState> = mapper.update_times().iter().map(|t| t.state).collect();
    assert_eq!(states.len(), 9);
    assert_eq!(states[0], MapperState::Own);
    assert!(states[1..7].iter().all(|&s| s == MapperState::MultiMap));
    assert!(states[7..].iter().all(|&s| s == MapperState::Own));
    for t in mapper.update_times() {
        assert!(t.update_seconds >= t.own_seconds && t.update_seconds >= t.merged_seconds);
        assert_eq!(t.local_seconds, 0.0);
        assert_eq!(t.merged_seconds > 0.0, t.state == MapperState::MultiMap);
    }
    // A merge can follow an undo.
    let again = mapper.merge(&b, &Se2::new(0.0, 0.0, 0.0), "retry").unwrap();
    assert_eq!(again.merge.0, 1);
}

#[test]
fn single_map_mode_times_the_local_map_and_checks_see_it() {
    let params = ReversibleParams {
        mode: ReversibleMode::SingleMap,
        check_every_scans: 1,
        ..ReversibleParams::default()
    };
    let mut mapper = ReversibleMapper::new(OccupancyGrid::new(0.1).unwrap(), params).unwrap();
    let scan = room_scan();
    mapper
        .insert_scan(&Se2::new(0.0, 0.0, 0.0), &scan, &KeepMerge)
        .unwrap();
    let b = mapper.current().clone();
    mapper.merge(&b, &Se2::new(0.0, 3.0, 0.0), "test").unwrap();
    let seen = std::cell::Cell::new(false);
    let check = |input: &CheckInput<'_>| {
        seen.set(
            input.mode == ReversibleMode::SingleMap
                && input.own.is_none()
                && input.local_updates.is_some()
                && input.scans_since_merge == 1,
        );
        Verdict::Consistent {
            metrics: Vec::new(),
        }
    };
    let update = mapper
        .insert_scan(&Se2::new(0.0, 6.0, 0.0), &scan, &check)
        .unwrap();
    assert!(seen.get());
    assert_eq!(update.timing.state, MapperState::SingleMap);
    assert!(update.timing.local_seconds > 0.0 && update.timing.own_seconds == 0.0);
    assert!(update.verdict.is_some());
    let local = mapper.local_updates().unwrap();
    assert!(local.count() > 0);
    // The scan at y = 6 grew the merged map; the local-update map grew alike.
    assert_eq!(local.geometry(), mapper.merged().unwrap().geometry());
    assert_eq!(local.to_mask().count(), local.count());
    // Undo keeps what the robot saw, drops what only B saw.
    let merged = mapper.merged().unwrap().clone();
    // B's free space 3.2 m from both scan poses; the robot's own free space.
    let far_b_only = Point2::new(1.0, 3.0);
    let robot_seen = Point2::new(1.0, 1.5);
    assert_ne!(merged.log_odds_at(&far_b_only), 0.0);
    mapper.undo("test").unwrap();
    assert_eq!(mapper.current().log_odds_at(&far_b_only), 0.0);
    assert_eq!(
        mapper.current().log_odds_at(&robot_seen),
        merged.log_odds_at(&robot_seen)
    );
}

#[test]
fn bad_parameters_and_poses_are_errors() {
    let mut params = ReversibleParams::default();
    params.fusion.repeat_thresholds = [0.3, 0.1, 0.2];
    assert!(matches!(
        ReversibleMapper::new(OccupancyGrid::new(0.1).unwrap(), params),
        Err(MergeError::BadParams { .. })
    ));
    let mut mapper = ReversibleMapper::new(
        OccupancyGrid::new(0.1).unwrap(),
        ReversibleParams::default(),
    )
    .unwrap();
    let nan = Se2 {
        x_m: f64::NAN,
        y_m: 0.0,
        theta_rad: 0.0,
    };
    assert!(mapper.insert_scan(&nan, &room_scan(), &KeepMerge).is_err());
    let b = OccupancyGrid::new(0.1).unwrap();
    assert!(mapper.merge(&b, &nan, "nan").is_err());
    assert_eq!(mapper.state(), MapperState::Own);
    assert!(mapper.events().is_empty());
}

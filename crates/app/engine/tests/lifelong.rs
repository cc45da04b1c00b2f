//! The lifelong engine on the simulator: kidnaps start epochs, merges are decided on
//! accumulated evidence (conditional in G' first, then full), wrong ones are rejected or
//! undone with a reason, and an undo restores the merged map exactly while keeping
//! everything mapped since.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::{BTreeMap, BTreeSet};

use mapmerge_atlas::{AtlasEvent, EpochEndReason, EpochId, MapId};
use mapmerge_engine::{
    Decision, Engine, EngineParams, EpochEnd, EventKind, MergeRecord, MergeState,
};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_hypothesis::{FilterEvent, RejectReason};
use mapmerge_posegraph::{NodeId, PoseGraph2};
use mapmerge_sim::{simulate, SimParams};
use mapmerge_verify::LearnedModel;

/// Runs a simulated data set through the engine; checks the invariants after every scan and
/// returns the engine and every keyframe's true pose.
fn run(preset: &str, seed: u64, sessions: usize, duration: f64) -> (Engine, BTreeMap<NodeId, Se2>) {
    run_with(EngineParams::default(), preset, seed, sessions, duration)
}

/// [`run`] with the engine's parameters.
fn run_with(
    engine_params: EngineParams,
    preset: &str,
    seed: u64,
    sessions: usize,
    duration: f64,
) -> (Engine, BTreeMap<NodeId, Se2>) {
    let mut params = SimParams::default().with_preset_name(preset).unwrap();
    params.sessions = sessions;
    params.duration_secs = duration;
    let dataset = simulate(&params, seed).unwrap();
    let mut engine = Engine::new(engine_params).unwrap();
    let mut truth_of = BTreeMap::new();
    let mut undos = 0;
    // Each merged graph as it was just before its merge.
    let mut before_merge: BTreeMap<MapId, PoseGraph2> = BTreeMap::new();
    for (s, session) in dataset.sessions.iter().enumerate() {
        if s > 0 {
            engine.end_epoch(EpochEndReason::Restart).unwrap();
        }
        let kidnaps: BTreeSet<usize> = session.kidnaps.iter().map(|k| k.scan_index).collect();
        let mut odometry = Se2::identity();
        for (k, record) in session.log.scans.iter().enumerate() {
            if kidnaps.contains(&k) {
                let events = engine.end_epoch(EpochEndReason::Kidnap).unwrap();
                assert!(events.iter().any(|e| matches!(
                    e.atlas(),
                    Some(AtlasEvent::EpochEnded {
                        reason: EpochEndReason::Kidnap,
                        ..
                    })
                )));
                assert_eq!(engine.atlas().active().num_vertices(), 0);
            }
            odometry = record.odom_from_robot.unwrap_or(odometry);
            // What an undo must restore: the inactive graphs as they were before the scan.
            let inactive_before: BTreeMap<MapId, PoseGraph2> = engine
                .atlas()
                .inactive_maps()
                .map(|(id, g)| (id, g.clone()))
                .collect();
            let current_before: BTreeSet<NodeId> = current_vertices(&engine);
            let report = engine
                .add_scan(&odometry, &record.scan, Some(record.stamp_secs))
                .unwrap();
            if let Some(node) = report.keyframe {
                truth_of.insert(node, session.truth[k].1);
            }
            let events: Vec<EventKind> = report.events.iter().map(|e| e.event.clone()).collect();
            for event in events {
                match event {
                    EventKind::Atlas(AtlasEvent::Merged(merge)) => {
                        let graph = inactive_before.get(&merge.map).cloned().unwrap();
                        before_merge.insert(merge.map, graph);
                    }
                    EventKind::Atlas(AtlasEvent::Unmerged(undo)) => {
                        undos += 1;
                        // Every merged graph comes back exactly; the current epoch keeps every
                        // vertex, and the active graph holds nothing else.
                        for map in &undo.restored_maps {
                            let restored = engine.atlas().inactive(*map).unwrap();
                            assert_eq!(Some(restored), before_merge.get(map), "{map}");
                        }
                        let current_after = current_vertices(&engine);
                        assert!(current_before.is_subset(&current_after));
                        assert_eq!(current_after.len(), engine.atlas().active().num_vertices());
                    }
                    _ => {}
                }
            }
        }
    }
    engine.finish().unwrap();
    eprintln!(
        "{preset} seed {seed}: {undos} undos, {:?}",
        mapmerge_engine::hypothesis_summary(engine.events())
    );
    (engine, truth_of)
}

/// The current epoch's vertices in the active graph.
fn current_vertices(engine: &Engine) -> BTreeSet<NodeId> {
    let epoch = engine.atlas().current_epoch();
    engine
        .atlas()
        .active()
        .vertices()
        .filter(|(_, v)| EpochId::of(&v.meta) == epoch)
        .map(|(id, _)| id)
        .collect()
}

/// For each of `edges` whose vertices have a truth: whether it lies within 0.5 m and 10°
/// of it.
fn edge_verdicts(truth_of: &BTreeMap<NodeId, Se2>, edges: &[(NodeId, NodeId, Se2)]) -> Vec<bool> {
    edges
        .iter()
        .filter_map(|(from, to, z)| {
            let error = truth_of.get(from)?.between(truth_of.get(to)?).between(z);
            Some(error.translation().norm() <= 0.5 && error.theta_rad.abs() <= 10f64.to_radians())
        })
        .collect()
}

/// True when most of `edges` lie within 0.5 m and 10° of the truth.
fn correct(truth_of: &BTreeMap<NodeId, Se2>, edges: &[(NodeId, NodeId, Se2)]) -> Option<bool> {
    let verdicts = edge_verdicts(truth_of, edges);
    (!verdicts.is_empty()).then(|| 2 * verdicts.iter().filter(|v| **v).count() > verdicts.len())
}

#[test]
fn evidence_decides_merges_and_wrong_ones_do_not_stay() {
    let (engine, truth_of) = run("symmetric-hall", 103, 3, 120.0);
    let log = engine.merge_log();
    assert!(!log.is_empty());
    // Conditional merges came first (G' only), then became full or were dropped.
    assert!(log.iter().any(|r| r.conditional_at_scan.is_some()));
    let mut kept_correct = 0;
    for record in log {
        let verdict = correct(&truth_of, &record.edges);
        match record.state {
            MergeState::Rejected | MergeState::Undone => {
                assert!(record.reason.is_some(), "{record:?}");
                assert!(record.ended_after_m().is_some());
            }
            MergeState::Full => {
                assert_eq!(verdict, Some(true), "a wrong merge was kept: {record:?}");
                kept_correct += 1;
            }
            MergeState::Conditional => {}
        }
        if verdict == Some(false) {
            // A wrong merge is rejected or undone within 10 m of travel.
            assert!(
                record.ended_after_m().is_some_and(|d| d <= 10.0),
                "{record:?}"
            );
        }
    }
    assert!(kept_correct >= 1);
    // Every merge decision is in the event log.
    let conditional_events = engine
        .events()
        .iter()
        .filter(|e| {
            matches!(
                &e.event,
                EventKind::Decision(mapmerge_engine::Decision::ConditionalMerge { .. })
            )
        })
        .count();
    assert_eq!(
        conditional_events,
        log.iter()
            .filter(|r| r.conditional_at_scan.is_some())
            .count()
    );
    let summary = mapmerge_engine::hypothesis_summary(engine.events());
    assert!(summary.merge > 0 && summary.conditional >= 1);
    // Each epoch's outcome agrees with the merge log: an epoch with a full merge ended
    // merged, its hypotheses got that far, and the first epoch had nothing to merge into.
    let outcomes = mapmerge_engine::epoch_outcomes(engine.events(), engine.travel_m());
    assert_eq!(
        outcomes.first().map(|o| o.end),
        Some(EpochEnd::NoHypothesis)
    );
    let merged_epochs: BTreeSet<u32> = log
        .iter()
        .filter(|r| r.state == MergeState::Full)
        .map(|r| r.epoch)
        .collect();
    assert!(!merged_epochs.is_empty());
    for outcome in &outcomes {
        if merged_epochs.contains(&outcome.epoch.0) {
            assert_eq!(outcome.end, EpochEnd::Merged, "{outcome:?}");
            assert!(
                outcome.hypotheses >= 1 && outcome.merges >= 1,
                "{outcome:?}"
            );
            assert!(outcome.most_observations >= 2, "{outcome:?}");
        }
        assert!(outcome.travel_m >= 0.0);
    }
    let total_m: f64 = outcomes.iter().map(|o| o.travel_m).sum();
    assert!((total_m - engine.travel_m()).abs() < 1e-6, "{total_m}");
}

#[test]
fn a_conditional_merge_lives_in_g_prime_only() {
    let mut params = SimParams::default()
        .with_preset_name("office-aliased")
        .unwrap();
    params.sessions = 2;
    params.duration_secs = 120.0;
    let dataset = simulate(&params, 3).unwrap();
    let mut engine = Engine::new(EngineParams::default()).unwrap();
    let mut seen_conditional = false;
    for (s, session) in dataset.sessions.iter().enumerate() {
        if s > 0 {
            engine.end_epoch(EpochEndReason::Restart).unwrap();
        }
        let mut odometry = Se2::identity();
        for record in &session.log.scans {
            odometry = record.odom_from_robot.unwrap_or(odometry);
            engine.add_scan(&odometry, &record.scan, None).unwrap();
            let conditional = engine
                .merge_log()
                .iter()
                .any(|r| r.state == MergeState::Conditional)
                && !engine.conditional_edges().is_empty();
            if conditional {
                seen_conditional = true;
                // Reads see the merged map; the atlas's graphs stay apart until it is full.
                let map = engine
                    .merge_log()
                    .iter()
                    .rev()
                    .find(|r| r.state == MergeState::Conditional)
                    .unwrap()
                    .map;
                assert!(engine.atlas().inactive(MapId(map)).is_some());
                assert!(engine.map_graph().num_vertices() > engine.atlas().active().num_vertices());
                let robot = engine.robot_node().unwrap();
                assert!(engine.robot_pose().is_some());
                assert!(engine.atlas().active().contains_vertex(robot));
            }
        }
    }
    assert!(seen_conditional, "no conditional merge on this seed");
}

/// Feeds `scans` to the engine, each with its odometry (the previous one where it has none).
fn feed(engine: &mut Engine, scans: &[mapmerge_scan::ScanRecord]) {
    let mut odometry = Se2::identity();
    for record in scans {
        odometry = record.odom_from_robot.unwrap_or(odometry);
        engine.add_scan(&odometry, &record.scan, None).unwrap();
    }
}

/// Two kidnap-free sessions of `duration_secs` each in the office world, seed 5.
fn two_office_sessions(duration_secs: f64) -> mapmerge_sim::Dataset {
    let mut params = SimParams::default().with_preset_name("office").unwrap();
    params.sessions = 2;
    params.duration_secs = duration_secs;
    params.kidnap.max_per_session = 0;
    simulate(&params, 5).unwrap()
}

#[test]
fn a_wrong_merge_is_undone_with_its_reason_and_nothing_mapped_since_is_lost() {
    let dataset = two_office_sessions(60.0);
    let mut engine = Engine::new(EngineParams::default()).unwrap();
    feed(&mut engine, &dataset.sessions[0].log.scans);
    engine.end_epoch(EpochEndReason::Restart).unwrap();
    let second = &dataset.sessions[1].log.scans;
    feed(&mut engine, &second[..100]);
    let before: PoseGraph2 = engine.atlas().inactive(MapId(0)).unwrap().clone();
    let active_before = current_vertices(&engine);
    // Each epoch's frame is its first scan's pose: the right merge from the truth, then
    // 2.5 m and 30° off, which overlaps the map and contradicts what the robot sees.
    let truth = |s: usize| dataset.sessions[s].truth[0].1;
    let right = truth(1).inverse().compose(&truth(0));
    let wrong = right.compose(&Se2::new(2.5, 1.0, 0.5));
    engine
        .force_merge(MapId(0), wrong, "wrong on purpose")
        .unwrap();
    assert!(engine.atlas().is_undoable());
    let mut odometry = second[99].odom_from_robot.unwrap();
    let mut undone = None;
    for record in &second[100..] {
        odometry = record.odom_from_robot.unwrap_or(odometry);
        let report = engine.add_scan(&odometry, &record.scan, None).unwrap();
        if let Some(undo) = report.events.iter().find_map(|e| match e.atlas() {
            Some(AtlasEvent::Unmerged(u)) => Some(u.clone()),
            _ => None,
        }) {
            undone = Some(undo);
            break;
        }
    }
    let undo = undone.expect("the wrong merge is undone");
    assert!(matches!(
        undo.reason,
        mapmerge_atlas::UnmergeReason::InvalidMerge { .. }
    ));
    assert_eq!(engine.atlas().inactive(MapId(0)), Some(&before));
    let after = current_vertices(&engine);
    assert!(active_before.is_subset(&after) && after.len() > active_before.len());
    assert_eq!(after.len(), engine.atlas().active().num_vertices());
    let record = engine.merge_log().last().unwrap();
    assert_eq!(record.state, MergeState::Undone);
    assert!(record
        .reason
        .as_deref()
        .unwrap_or("")
        .contains("invalidity"));
    // What the detector read while judging it: its own ratio first, above the threshold
    // that undid it, on every vertex it judged.
    let reading = &record.readings[0];
    assert_eq!(reading.method, EngineParams::default().detector);
    assert!(reading.peak_ratio > EngineParams::default().unmerge_threshold);
    assert!(reading.vertices >= 1 && reading.supported_vertices <= reading.vertices);
}

#[test]
fn a_learned_model_in_the_parameters_is_the_engines_decision_and_its_components_are_recorded() {
    let dataset = two_office_sessions(40.0);
    // A model that never calls a merge invalid, whatever its components read.
    let never = LearnedModel {
        methods: vec!["change_detection".into(), "gridmap".into()],
        ratio_weights: vec![0.0, 0.0],
        unsupported_weights: vec![0.0, 0.0],
        intercept: -50.0,
        ratio_transform: Default::default(),
        forest: None,
        or_better_hypothesis: false,
        threshold: 0.5,
        fitted_on: "test".into(),
    };
    // A model for another detector is a mistake, not something to ignore.
    let misplaced = Engine::new(EngineParams {
        detector: "combined".into(),
        learned_model: Some(never.clone()),
        ..EngineParams::default()
    });
    assert!(matches!(
        misplaced,
        Err(mapmerge_engine::EngineError::Params(ref e)) if e.field == "learned_model"
            && e.value.contains("combined")
    ));
    let mut engine = Engine::new(EngineParams {
        detector: "learned".into(),
        learned_model: Some(never),
        ..EngineParams::default()
    })
    .unwrap();
    let mut odometry = Se2::identity();
    for record in &dataset.sessions[0].log.scans {
        odometry = record.odom_from_robot.unwrap_or(odometry);
        engine.add_scan(&odometry, &record.scan, None).unwrap();
    }
    engine.end_epoch(EpochEndReason::Restart).unwrap();
    let second = &dataset.sessions[1].log.scans;
    let truth = |s: usize| dataset.sessions[s].truth[0].1;
    let wrong = truth(1)
        .inverse()
        .compose(&truth(0))
        .compose(&Se2::new(2.5, 1.0, 0.5));
    let mut odometry = Se2::identity();
    for (k, record) in second.iter().enumerate() {
        if k == 50 {
            engine
                .force_merge(MapId(0), wrong, "wrong on purpose")
                .unwrap();
        }
        odometry = record.odom_from_robot.unwrap_or(odometry);
        engine.add_scan(&odometry, &record.scan, None).unwrap();
    }
    let record = engine.merge_log().last().unwrap();
    assert_eq!(record.state, MergeState::Full, "the model never undoes");
    let methods: Vec<&str> = record.readings.iter().map(|r| r.method.as_str()).collect();
    assert_eq!(methods, ["learned", "change_detection", "gridmap"]);
    assert!(record.readings[0].peak_ratio < 1e-6);
    // The components saw the wrong merge for what it is.
    assert!(record.readings[1].peak_ratio > 0.3, "{:?}", record.readings);
    assert!(record
        .readings
        .iter()
        .all(|r| r.vertices == record.readings[0].vertices));
}

#[test]
fn the_symmetric_hall_makes_a_view_ambiguous() {
    // The world built for Sec. 5.3: a hall block point-symmetric about (18, 10) m, where a
    // view matches its turned twin; on this seed the tracker marks one (found with
    // `mapmerge atlas --sim symmetric-hall --seed S`, not tuned on: seed 6 of the fitting
    // seeds 1–20 did until the overlap search took partners at any heading; since then none
    // of 1–20 and two of 21–40 do, 29 in the east wing, 31 in a room of the symmetric block;
    // held-out seed 107 marked one until the flip was measured by whole-map agreement).
    // The tracker alone: views whose own map fits itself elsewhere are marked by another
    // rule (the next test).
    let (seed, sessions, duration) = (31, 3, 120.0);
    let mut engine_params = EngineParams::default();
    engine_params.decisions.self_similarity = None;
    let (engine, truth_of) = run_with(engine_params, "symmetric-hall", seed, sessions, duration);
    let views = mapmerge_engine::ambiguous_views(engine.events());
    assert!(!views.is_empty(), "no ambiguous view");
    // Where it is ambiguous: in a room of the symmetric block (the hall's halves, or a room
    // and its turned copy: rooms with an alias group).
    let mut params = SimParams::default()
        .with_preset_name("symmetric-hall")
        .unwrap();
    params.sessions = sessions;
    params.duration_secs = duration;
    let world = simulate(&params, seed).unwrap().world;
    for view in &views {
        let p = truth_of[view].translation();
        let room = world.room_at(&p);
        eprintln!(
            "ambiguous view {view} at ({:.1}, {:.1}) in {:?}",
            p.x,
            p.y,
            room.map(|r| &r.name)
        );
        assert!(
            room.is_some_and(|r| r.alias_group.is_some()),
            "{view} at {p:?} is outside the symmetric block"
        );
    }
}

#[test]
fn a_view_whose_own_map_fits_itself_elsewhere_is_ambiguous_from_its_first_observation() {
    // The warehouse's rack rows repeat every aisle and every bay: views in the racking fit
    // themselves a bay or an aisle over (seed 7 of the fitting seeds 1–20, where three
    // wrong merges one aisle over were made on such views before this rule).
    let (engine, _) = run("warehouse", 7, 3, 120.0);
    let params = engine.params().decisions.clone();
    let scores = mapmerge_engine::view_self_similarity(engine.events());
    assert!(
        !scores.is_empty(),
        "no view of an inactive graph was observed"
    );
    let ambiguous = mapmerge_engine::ambiguous_views(engine.events());
    let mut marked = 0;
    for (view, score) in &scores {
        assert!((0.0..=1.0).contains(score), "{view}: {score}");
        if *score >= params.self_similar_from_score {
            marked += 1;
            assert!(
                ambiguous.contains(view),
                "{view} scored {score} but is not ambiguous"
            );
        }
    }
    assert!(marked > 0, "no self-similar view: {scores:?}");
    // Hypotheses on several such views: their views joined are searched once per set, and
    // only self-similar views are joined (`decisions.joint_views`).
    let joints = engine.joint_self_similarity();
    assert!(!joints.is_empty(), "no joint set searched");
    for (views, score) in joints {
        assert!((2..=8).contains(&views.len()), "{views:?}");
        assert!(
            views.windows(2).all(|w| w[0] < w[1]),
            "{views:?} not sorted"
        );
        assert!((0.0..=1.0).contains(score), "{views:?}: {score}");
        for view in views {
            let alone = scores.get(&NodeId(*view)).copied().unwrap_or(0.0);
            assert!(
                alone >= params.self_similar_from_score,
                "{view} joined but scored {alone} alone"
            );
        }
    }
    // Without the rule nothing is searched, though views of inactive graphs were observed.
    let mut engine_params = EngineParams::default();
    engine_params.decisions.self_similarity = None;
    let (engine, _) = run_with(engine_params, "warehouse", 7, 3, 120.0);
    assert!(mapmerge_engine::hypothesis_summary(engine.events()).merge > 0);
    assert!(mapmerge_engine::view_self_similarity(engine.events()).is_empty());
    assert!(engine.joint_self_similarity().is_empty());
}

#[test]
fn a_conditional_merge_not_made_full_in_time_is_rejected() {
    // Office fitting seed 9 with a bound below the ~1.5 m a correct merge takes to become
    // full (`decisions.conditional_max_m`): every conditional merge is made full within it
    // or rejected, in the filter too, at the last keyframe before the robot would pass it.
    let max_m = 1.0;
    let mut engine_params = EngineParams::default();
    engine_params.decisions.conditional_max_m = Some(max_m);
    let (engine, _) = run_with(engine_params, "office", 9, 3, 120.0);
    let log = engine.merge_log();
    let is_timeout = |note: &str| note == format!("not made full within {max_m} m");
    let timed_out: Vec<_> = log
        .iter()
        .filter(|r| r.reason.as_deref().is_some_and(is_timeout))
        .collect();
    assert!(
        !timed_out.is_empty(),
        "no conditional merge timed out: {log:?}"
    );
    for record in log.iter().filter(|r| r.conditional_travel_m.is_some()) {
        let started_m = record.conditional_travel_m.unwrap();
        let decided_m = match record.state {
            MergeState::Full => record.full_travel_m,
            MergeState::Rejected => record.ended_travel_m,
            _ => continue,
        };
        assert!(decided_m.unwrap() - started_m < max_m + 1.0, "{record:?}");
    }
    for record in &timed_out {
        // The simulator's keyframe steps (at most ~0.5 m) are regular enough that looking
        // one step ahead keeps every rejection within the bound, and none comes more than a
        // step early.
        let lived_m = record.ended_travel_m.unwrap() - record.conditional_travel_m.unwrap();
        assert!(
            (max_m - 0.6..=max_m).contains(&lived_m),
            "{lived_m} m: {record:?}"
        );
        let rejected_in_filter = engine.events().iter().any(|e| {
            matches!(
                &e.event,
                EventKind::Hypothesis(FilterEvent::Rejected {
                    id,
                    reason: RejectReason::Caller { note },
                    ..
                }) if Some(id.0) == record.hypothesis && is_timeout(note)
            )
        });
        assert!(rejected_in_filter, "{record:?}");
    }
}

#[test]
fn a_conditional_bound_that_is_no_distance_is_refused() {
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let mut engine_params = EngineParams::default();
        engine_params.decisions.conditional_max_m = Some(bad);
        assert!(
            matches!(
                Engine::new(engine_params),
                Err(mapmerge_engine::EngineError::Params(e)) if e.field == "decisions.conditional_max_m"
            ),
            "{bad}"
        );
    }
    let mut engine_params = EngineParams::default();
    engine_params.decisions.conditional_max_m = None;
    assert!(Engine::new(engine_params).is_ok());
}

#[test]
fn a_disagreement_bound_of_no_edge_is_refused() {
    let mut engine_params = EngineParams::default();
    engine_params.decisions.undo_disagreeing_edges = Some(0);
    assert!(matches!(
        Engine::new(engine_params),
        Err(mapmerge_engine::EngineError::Params(e)) if e.field == "decisions.undo_disagreeing_edges"
    ));
    for fine in [None, Some(1), Some(3)] {
        let mut engine_params = EngineParams::default();
        engine_params.decisions.undo_disagreeing_edges = fine;
        assert!(Engine::new(engine_params).is_ok(), "{fine:?}");
    }
}

/// A tracking-failure bound out of range is refused with its field's name, and a run with
/// the detector off (`tracker.lost: null`) is allowed.
#[test]
fn a_tracking_failure_bound_out_of_range_is_refused() {
    let mut engine_params = EngineParams::default();
    if let Some(lost) = engine_params.tracker.lost.as_mut() {
        lost.off_to_lose = 0;
    }
    let message = Engine::new(engine_params).err().map(|e| e.to_string());
    assert_eq!(
        message.as_deref(),
        Some("invalid parameter `tracker.lost.off_to_lose` = 0: must be in [1, 100000]")
    );
    let mut engine_params = EngineParams::default();
    engine_params.tracker.lost = None;
    assert!(Engine::new(engine_params).is_ok());
}

#[test]
fn a_match_verified_where_a_hypothesis_says_is_searched_for_a_rival_nearby() {
    // The warehouse's aisles repeat: a match verified where a tracked hypothesis puts the
    // robot can fit one aisle over as well (`decisions.track_unique`), seed 7 of the fitting
    // seeds (the self-similarity test's).
    let mut engine_params = EngineParams::default();
    engine_params.decisions.track_every_keyframes = Some(2);
    engine_params.decisions.track_unique = true;
    let (engine, _) = run_with(engine_params.clone(), "warehouse", 7, 3, 120.0);
    let threshold = engine.params().decisions.self_similar_from_score;
    let rivals: Vec<f64> = engine
        .events()
        .iter()
        .filter_map(|e| match &e.event {
            EventKind::Decision(Decision::TrackedRival { score, .. }) => Some(*score),
            _ => None,
        })
        .collect();
    assert!(!rivals.is_empty(), "no predicted match searched");
    assert!(rivals.iter().all(|s| (0.0..=1.0).contains(s)), "{rivals:?}");
    assert!(
        rivals.iter().any(|s| *s >= threshold),
        "no rival: {rivals:?}"
    );
    assert!(
        rivals.iter().any(|s| *s < threshold),
        "all rivals: {rivals:?}"
    );
    // Off (and off for the sessions' start matches too), nothing is searched.
    engine_params.decisions.track_unique = false;
    engine_params.decisions.start_unique = false;
    let (engine, _) = run_with(engine_params, "warehouse", 7, 3, 120.0);
    assert!(!engine
        .events()
        .iter()
        .any(|e| matches!(&e.event, EventKind::Decision(Decision::TrackedRival { .. }))));
}

/// Issue 64, part 4: when an epoch's merges are about to become final, the engine asks
/// whether the optimised graph satisfies every edge between the epoch and the merged ones
/// (an `epoch_agreement` decision). A forced merge 0.45 m off (inside the overlap gate) is
/// pulled onto the true place by the loops found in the merged data after it (to 0.12 m,
/// against 0.09 m after the right merge), so at the run's end the epochs agree as they do
/// after the right merge, and both merges stand.
#[test]
fn loops_into_merged_data_bring_a_slightly_wrong_merge_into_agreement() {
    let dataset = two_office_sessions(60.0);
    let truth = |s: usize| dataset.sessions[s].truth[0].1;
    let right = truth(1).inverse().compose(&truth(0));
    let run = |active_from_inactive: Se2| {
        let params = EngineParams {
            detector: "none".into(),
            ..EngineParams::default()
        };
        let mut engine = Engine::new(params).unwrap();
        feed(&mut engine, &dataset.sessions[0].log.scans);
        engine.end_epoch(EpochEndReason::Restart).unwrap();
        let old = engine.atlas().inactive(MapId(0)).unwrap().clone();
        // The second session runs along the first from scan 375 to 460.
        let (before, after) = dataset.sessions[1].log.scans.split_at(390);
        feed(&mut engine, before);
        engine
            .force_merge(MapId(0), active_from_inactive, "test")
            .unwrap();
        let robot_at_merge = engine.robot_node();
        feed(&mut engine, after);
        engine.finish().unwrap();
        let agreement = engine
            .events()
            .iter()
            .find_map(|e| match &e.event {
                EventKind::Decision(Decision::EpochAgreement {
                    agreeing_edges,
                    disagreeing_edges,
                    undone,
                    ..
                }) => Some((*agreeing_edges, *disagreeing_edges, *undone)),
                _ => None,
            })
            .expect("the epoch's agreement is judged");
        // Where the old map ends up beside the robot's vertex at the merge, against where
        // the right transform puts it.
        let graph = engine.atlas().active();
        let robot = graph.vertex(robot_at_merge.unwrap()).unwrap().pose;
        let (near, _) = old
            .vertices()
            .map(|(id, v)| {
                (
                    id,
                    (right.compose(&v.pose).translation() - robot.translation()).norm(),
                )
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        let placed = graph.vertex(near).unwrap().pose;
        let expected = right.compose(&old.vertex(near).unwrap().pose);
        let off_m = (placed.translation() - expected.translation()).norm();
        (engine, agreement, off_m)
    };
    let (engine, (agreeing, disagreeing, undone), right_off_m) = run(right);
    assert!(
        agreeing > 1 && disagreeing == 0 && !undone,
        "{agreeing} {disagreeing}"
    );
    assert!(engine.atlas().is_undoable());
    let (engine, (agreeing, disagreeing, undone), off_m) =
        run(right.compose(&Se2::new(0.35, 0.28, 0.0)));
    assert!(
        agreeing > 1 && disagreeing == 0 && !undone,
        "{agreeing} {disagreeing}"
    );
    assert!(engine.atlas().is_undoable());
    assert!(
        off_m < 0.2 && off_m < right_off_m + 0.1,
        "{off_m} vs {right_off_m}"
    );
}

/// Issue 64, part 4, on the simulator's tuning seed 12 of the symmetric hall: the fourth
/// epoch's merge is right where it was made, but its later edges include matches in the
/// hall's turned twin, and an accepted recovery hypothesis adds edges the graph cannot
/// satisfy with them. When the epoch ends, the merged epochs disagree: the merge is undone
/// with its reason instead of becoming final, and the next session merges every epoch with
/// edges the truth confirms.
#[test]
fn epochs_that_disagree_are_undone_before_their_merges_become_final() {
    let (engine, truth_of) = run("symmetric-hall", 12, 3, 120.0);
    // Each merge's edges that the truth confirms, of those judged.
    let right_of = |edges: &[(NodeId, NodeId, Se2)]| {
        let verdicts = edge_verdicts(&truth_of, edges);
        (verdicts.iter().filter(|v| **v).count(), verdicts.len())
    };
    let disagreeing = |r: &&MergeRecord| {
        r.state == MergeState::Undone
            && r.reason
                .as_deref()
                .is_some_and(|why| why.starts_with("epochs disagree"))
    };
    let undone: Vec<&MergeRecord> = engine.merge_log().iter().filter(disagreeing).collect();
    assert_eq!(undone.len(), 1, "{:?}", engine.merge_log());
    let (right, judged) = right_of(&undone[0].edges);
    assert!(
        judged > 0 && right < judged,
        "{right} of {judged} edges right"
    );
    for record in engine
        .merge_log()
        .iter()
        .filter(|r| r.state == MergeState::Full)
    {
        let (right, judged) = right_of(&record.edges);
        assert!(
            judged > 0 && right == judged,
            "{right} of {judged}: {record:?}"
        );
    }
    assert!(engine.events().iter().any(|e| matches!(
        &e.event,
        EventKind::Decision(Decision::EpochAgreement {
            disagreeing_edges,
            undone: true,
            ..
        }) if *disagreeing_edges >= 3
    )));
}

/// Issue 65: a robot carried elsewhere while its odometry goes on, and nobody tells the
/// engine. Its tracker must lose track within 10 scans of each kidnap; the scans it held in
/// doubt start the new epoch (none of them made a keyframe in the old one), and every scan
/// fed keeps exactly one anchor.
#[test]
fn withheld_kidnaps_are_found_by_the_tracker_and_the_scans_in_doubt_start_the_new_epoch() {
    let mut params = SimParams::default().with_preset_name("office").unwrap();
    params.sessions = 1;
    params.duration_secs = 150.0;
    params.kidnap.max_per_session = 3;
    params.kidnap.probability = 1.0;
    params.kidnap.target = mapmerge_sim::KidnapTarget::Random;
    let dataset = simulate(&params, 7).unwrap();
    let session = &dataset.sessions[0];
    let kidnaps: Vec<usize> = session.kidnaps.iter().map(|k| k.scan_index).collect();
    assert!(kidnaps.len() >= 2, "{kidnaps:?}");
    let mut engine = Engine::new(EngineParams::default()).unwrap();
    let mut odometry = Se2::identity();
    for record in &session.log.scans {
        odometry = record.odom_from_robot.unwrap_or(odometry);
        engine
            .add_scan(&odometry, &record.scan, Some(record.stamp_secs))
            .unwrap();
    }
    engine.finish().unwrap();
    assert_eq!(engine.scans(), session.log.scans.len());
    // Each break: the first scan in doubt and the scan that decided.
    let breaks: Vec<(usize, usize)> = engine
        .events()
        .iter()
        .filter_map(|e| match &e.event {
            EventKind::Decision(Decision::TrackingLost { in_doubt, .. }) => {
                Some((e.scan, e.scan + in_doubt.len() - 1))
            }
            _ => None,
        })
        .collect();
    for &k in &kidnaps {
        assert!(
            breaks
                .iter()
                .any(|&(first, decided)| first + 2 >= k && decided <= k + 10),
            "kidnap at scan {k} not found: breaks {breaks:?}"
        );
    }
    assert_eq!(breaks.len(), kidnaps.len(), "no other break: {breaks:?}");
    // Every break ended its epoch as `tracking_lost`, and the next epoch says so.
    let outcomes = mapmerge_engine::epoch_outcomes(engine.events(), engine.travel_m());
    assert_eq!(outcomes.len(), kidnaps.len() + 1);
    assert_eq!(outcomes[0].started_by, None);
    for o in &outcomes[1..] {
        assert_eq!(o.started_by, Some(EpochEndReason::TrackingLost));
    }
    // Every scan fed hangs on exactly one keyframe, and the scans in doubt hang on the new
    // epoch's (they were fed to it again), the scan before them on the old one's.
    let mut epoch_of_scan = BTreeMap::new();
    for trajectory in engine.map_trajectories() {
        for scan in trajectory.scans {
            assert!(epoch_of_scan.insert(scan.scan, scan.epoch).is_none());
        }
    }
    assert_eq!(epoch_of_scan.len(), session.log.scans.len());
    for &(first, decided) in &breaks {
        let new = epoch_of_scan[&first];
        assert!((first..=decided).all(|k| epoch_of_scan[&k] == new));
        assert_eq!(epoch_of_scan[&(first - 1)] + 1, new);
    }
}

/// The same office without kidnaps: the tracker never loses track.
#[test]
fn a_robot_never_carried_never_loses_track() {
    let (engine, _) = run("office", 3, 2, 120.0);
    let lost = engine
        .events()
        .iter()
        .filter(|e| matches!(e.event, EventKind::Decision(Decision::TrackingLost { .. })))
        .count();
    let kidnaps = engine
        .events()
        .iter()
        .filter(|e| {
            matches!(
                e.atlas(),
                Some(AtlasEvent::EpochEnded {
                    reason: EpochEndReason::Kidnap,
                    ..
                })
            )
        })
        .count();
    // The run announces its own kidnaps; between them nothing is lost.
    assert_eq!(lost, 0, "{kidnaps} announced kidnaps");
}

//! Retrieval and loop candidates on simulated office floors with known true poses.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{between, scan_points, BruteForceVerifier};
use mapmerge_geometry::{wrap_angle_rad, Se2};
use mapmerge_place::{
    find_loop_candidates_with_poses, Keyframe, KeyframeId, PlaceIndex, PlaceParams, ScanContext,
};
use mapmerge_sim::{simulate, Dataset, SimParams, WorldPreset};

fn dataset(preset: WorldPreset, duration_secs: f64) -> Dataset {
    let params = SimParams::default()
        .with_preset(preset)
        .with_sessions(2)
        .with_duration_secs(duration_secs);
    simulate(&params, 11).unwrap()
}

/// Keyframes of `session` every `every` scans, with their true poses.
fn keyframes(data: &Dataset, session: usize, every: usize, id_base: u64) -> Vec<(Keyframe, Se2)> {
    let s = &data.sessions[session];
    s.log
        .scans
        .iter()
        .zip(&s.truth)
        .enumerate()
        .step_by(every)
        .map(|(i, (record, (_, pose)))| {
            (
                Keyframe::new(id_base + i as u64, scan_points(&record.scan)),
                *pose,
            )
        })
        .collect()
}

#[test]
fn office_scans_near_a_keyframe_retrieve_it() {
    let data = dataset(WorldPreset::Office, 180.0);
    let params = common::descriptor_params();
    let indexed = keyframes(&data, 0, 5, 0);
    let mut index: PlaceIndex = PlaceIndex::new(common::index_params());
    for (k, _) in &indexed {
        index.insert(k.id, ScanContext::new(&k.points_in_keyframe, &params));
    }
    let pose_of = |id: KeyframeId| indexed.iter().find(|(k, _)| k.id == id).map(|(_, p)| *p);
    let queries = keyframes(&data, 1, 7, 1_000_000);
    let (mut total, mut hits1, mut hits5) = (0usize, 0usize, 0usize);
    let mut yaw_ok = 0usize;
    for (query, pose) in &queries {
        let near = |p: &Se2| (p.translation() - pose.translation()).norm() < 0.5;
        if !indexed.iter().any(|(_, p)| near(p)) {
            continue;
        }
        total += 1;
        let found = index.query(&ScanContext::new(&query.points_in_keyframe, &params), 5);
        let hit = |c: &mapmerge_place::Candidate| pose_of(c.keyframe).is_some_and(|p| near(&p));
        if found.first().is_some_and(hit) {
            hits1 += 1;
            let truth = between(&pose_of(found[0].keyframe).unwrap(), pose);
            if wrap_angle_rad(found[0].yaw_rad - truth.theta_rad).abs() < 6f64.to_radians() {
                yaw_ok += 1;
            }
        }
        if found.iter().any(hit) {
            hits5 += 1;
        }
    }
    let (r1, r5) = (hits1 as f64 / total as f64, hits5 as f64 / total as f64);
    println!(
        "office: {} keyframes, {total} queries within 0.5 m; recall@1 {r1:.3}, recall@5 {r5:.3}, yaw within 6° for {yaw_ok}/{hits1} top-1 hits",
        indexed.len()
    );
    assert!(total > 50, "too few queries: {total}");
    assert!(r5 >= 0.8, "recall@5 {r5}");
    assert!(yaw_ok as f64 >= 0.9 * hits1 as f64);
}

#[test]
fn look_alike_places_lower_the_confidence() {
    let data = dataset(WorldPreset::OfficeAliased, 150.0);
    let b = keyframes(&data, 0, 5, 0);
    let a = keyframes(&data, 1, 15, 1_000_000);
    let keyframes_b: Vec<Keyframe> = b.iter().map(|(k, _)| k.clone()).collect();
    let keyframes_a: Vec<Keyframe> = a.iter().map(|(k, _)| k.clone()).collect();
    // B's poses in its own map: the truth stands in for B's optimised pose graph.
    let map_from_b: Vec<Se2> = b.iter().map(|(_, p)| *p).collect();
    let params = PlaceParams {
        candidates_per_query: 8,
        ..PlaceParams::default()
    };
    let loops = find_loop_candidates_with_poses(
        &keyframes_a,
        &keyframes_b,
        &map_from_b,
        &BruteForceVerifier::default(),
        &params,
    );
    let world = &data.world;
    let aliased_room = |pose: &Se2| {
        world
            .room_at(&pose.translation())
            .is_some_and(|room| !world.look_alikes(room.id).is_empty())
    };
    let (mut conf_right, mut conf_wrong, mut conf_alias_room) =
        (Vec::new(), Vec::new(), Vec::new());
    for l in &loops {
        let pose_a = a.iter().find(|(k, _)| k.id == l.a).unwrap().1;
        let pose_b = b.iter().find(|(k, _)| k.id == l.b).unwrap().1;
        let truth = between(&pose_b, &pose_a);
        let right = (truth.translation() - l.b_from_a.translation()).norm() < 0.5
            && wrap_angle_rad(truth.theta_rad - l.b_from_a.theta_rad).abs() < 0.1;
        if std::env::var("PLACE_DEBUG").is_ok() {
            let room = |p: &Se2| {
                world
                    .room_at(&p.translation())
                    .map(|r| (r.name.clone(), r.alias_group))
            };
            println!(
                "{:?} {:?} score {:.2} conf {:.2} right {right} rooms {:?} {:?}",
                l.a,
                l.b,
                l.score,
                l.confidence,
                room(&pose_a),
                room(&pose_b)
            );
        }
        if right {
            conf_right.push(l.confidence)
        } else {
            conf_wrong.push(l.confidence)
        }
        if aliased_room(&pose_a) {
            conf_alias_room.push(l.confidence);
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let confident = |v: &[f64]| v.iter().filter(|c| **c >= 0.3).count();
    println!(
        "office-aliased: {} queries, {} loops: {} right (mean confidence {:.3}, {} with ≥ 0.3), {} wrong (look-alike places; mean confidence {:.3}, {} with ≥ 0.3); {} loops in look-alike rooms (mean confidence {:.3})",
        a.len(),
        loops.len(),
        conf_right.len(),
        mean(&conf_right),
        confident(&conf_right),
        conf_wrong.len(),
        mean(&conf_wrong),
        confident(&conf_wrong),
        conf_alias_room.len(),
        mean(&conf_alias_room),
    );
    assert!(!conf_right.is_empty() && !conf_wrong.is_empty());
    assert!(mean(&conf_wrong) < 0.5 * mean(&conf_right));
}

/// Identical rooms (an alias group of `office-aliased`) give near-identical descriptors; a
/// query in one of them matches but with a low confidence, while a query in a unique room
/// matches confidently.
#[test]
fn look_alike_rooms_match_with_low_confidence() {
    use mapmerge_geometry::LieGroup;
    use mapmerge_sim::{generate_world, Lidar, LidarParams, Point2, Room};
    let world = generate_world(&WorldPreset::OfficeAliased.params(), 11).unwrap();
    let lidar = Lidar::new(&world, LidarParams::default()).unwrap();
    let free_pose_in = |room: &Room| {
        let centre = (room.rect.min_m + room.rect.max_m) * 0.5;
        (0..25)
            .map(|i| centre + Point2::new(f64::from(i % 5) - 2.0, f64::from(i / 5) - 2.0) * 0.4)
            .find(|p| room.rect.contains(p) && !world.is_inside_obstacle(p))
            .map(|p| Se2::new(p.x, p.y, 0.3))
    };
    let group: Vec<&Room> = world
        .rooms
        .iter()
        .find(|r| !world.look_alikes(r.id).is_empty())
        .map(|r| {
            let mut g = vec![r];
            g.extend(world.look_alikes(r.id));
            g
        })
        .unwrap();
    // B: one keyframe per room (look-alikes at corresponding poses), in world order.
    let first = group[0];
    let pose_in_first = free_pose_in(first).unwrap();
    let mut b_poses: Vec<Se2> = Vec::new();
    for room in &world.rooms {
        let pose = if group.iter().any(|g| g.id == room.id) {
            Some(
                room.world_from_room
                    .compose(&first.world_from_room.inverse())
                    .compose(&pose_in_first),
            )
        } else {
            free_pose_in(room)
        };
        if let Some(pose) = pose {
            b_poses.push(pose);
        }
    }
    let keyframes_b: Vec<Keyframe> = b_poses
        .iter()
        .enumerate()
        .map(|(i, pose)| Keyframe::new(i as u64, scan_points(&lidar.scan(pose, i as u64))))
        .collect();
    // A: a query 0.2 m and 0.5 rad away in the first look-alike room, and one in a unique room.
    let unique_room = world
        .rooms
        .iter()
        .filter(|r| r.alias_group.is_none() && r.rect.width_m().min(r.rect.height_m()) > 2.5)
        .find_map(free_pose_in)
        .unwrap();
    let offset = Se2::new(0.2, -0.1, 0.5);
    let a_poses = [pose_in_first.compose(&offset), unique_room.compose(&offset)];
    let keyframes_a: Vec<Keyframe> = a_poses
        .iter()
        .enumerate()
        .map(|(i, pose)| {
            Keyframe::new(
                1000 + i as u64,
                scan_points(&lidar.scan(pose, 77 + i as u64)),
            )
        })
        .collect();
    let loops = find_loop_candidates_with_poses(
        &keyframes_a,
        &keyframes_b,
        &b_poses,
        &BruteForceVerifier::default(),
        &PlaceParams::default(),
    );
    println!(
        "look-alike rooms {:?}: {loops:#?}",
        group.iter().map(|r| &r.name).collect::<Vec<_>>()
    );
    let aliased = loops.iter().find(|l| l.a.0 == 1000).unwrap();
    let unique = loops.iter().find(|l| l.a.0 == 1001).unwrap();
    assert!(aliased.score > 0.8 && unique.score > 0.8);
    assert!(aliased.confidence < 0.2, "{aliased:?}");
    assert!(unique.confidence > 0.3, "{unique:?}");
}

#[test]
fn the_scan_matcher_verifies_loops_between_sessions_correctly() {
    // Session 1 (queries) against session 0 (indexed) in the `office` world, verified by the
    // production verifier: every accepted loop must carry the true relative pose.
    let data = dataset(WorldPreset::Office, 90.0);
    let b = keyframes(&data, 0, 10, 0);
    let a = keyframes(&data, 1, 10, 100_000);
    let (b_keyframes, b_poses): (Vec<Keyframe>, Vec<Se2>) = b.iter().cloned().unzip();
    let a_keyframes: Vec<Keyframe> = a.iter().map(|(k, _)| k.clone()).collect();
    let truth_of = |id: KeyframeId| {
        a.iter()
            .chain(&b)
            .find(|(k, _)| k.id == id)
            .map(|(_, pose)| *pose)
            .unwrap()
    };
    let verifier = mapmerge_place::ScanMatchVerifier::default();
    // Wrong loops here are 180° flips in symmetric corridors, scoring 0.61–0.66 (confidence
    // ≤ 0.19); right ones score ≥ 0.73.
    let params = PlaceParams {
        min_score: 0.7,
        ..PlaceParams::default()
    };
    let loops =
        find_loop_candidates_with_poses(&a_keyframes, &b_keyframes, &b_poses, &verifier, &params);
    let correct = loops
        .iter()
        .filter(|l| {
            let truth = between(&truth_of(l.b), &truth_of(l.a));
            let error = between(&truth, &l.b_from_a);
            error.translation().norm() < 0.1
                && wrap_angle_rad(error.theta_rad).abs() < 2f64.to_radians()
        })
        .count();
    eprintln!(
        "{} loops accepted, {correct} within 10 cm / 2° of the truth",
        loops.len()
    );
    assert!(loops.len() >= 20, "{} loops", loops.len());
    assert_eq!(correct, loops.len());
}

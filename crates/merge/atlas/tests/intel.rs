//! The atlas on real data: the Intel Research Lab log cut into two sessions (a kidnap between
//! them), each mapped by the local tracker with the atlas as the graph's owner; the second recognises the first, merges onto
//! the right transform, keeps mapping, and an unmerge restores the first session's graph
//! exactly while keeping every vertex of the second.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::{BTreeMap, BTreeSet};

use mapmerge_atlas::{
    default_verifier, Atlas, AtlasParams, EpochEndReason, EpochId, MapId, UnmergeReason,
};
use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_posegraph::{EdgeKind, NodeId};
use mapmerge_scan::LaserLog;
use mapmerge_slam::{LocalTracker, TrackerParams};

/// Feeds `scans` through a fresh tracker into the atlas's current epoch, searching
/// constraints after every keyframe (loops in the epoch, matches in the inactive graphs) and
/// optimising when due, as the engine does; stops after the first keyframe whose search
/// matched an inactive graph when `stop_at_match`. Returns each keyframe's scan index and the
/// first match.
fn map_scans(
    atlas: &mut Atlas,
    log: &LaserLog,
    scans: std::ops::Range<usize>,
    stop_at_match: bool,
) -> (
    BTreeMap<NodeId, usize>,
    Option<mapmerge_atlas::MergeProposal>,
    usize,
) {
    let verifier = default_verifier().unwrap();
    let mut tracker = LocalTracker::new(TrackerParams::default()).unwrap();
    let mut odometry = Se2::identity();
    let mut scan_of = BTreeMap::new();
    for index in scans.clone() {
        let record = &log.scans[index];
        odometry = record.odom_from_robot.unwrap_or(odometry);
        let tracked = tracker
            .add_scan(&odometry, &record.scan, None, atlas.next_node_id())
            .unwrap();
        let Some(insertion) = tracked.keyframe else {
            continue;
        };
        let node = atlas.insert_keyframe(insertion, None).unwrap();
        scan_of.insert(node, index);
        let found = atlas.search_constraints(node, &verifier).unwrap();
        atlas.optimize_if_due(false).unwrap();
        if stop_at_match {
            if let Some(best) = found.merge_candidates.into_iter().next() {
                return (scan_of, Some(best), index + 1);
            }
        }
    }
    atlas.optimize_if_due(true).unwrap();
    (scan_of, None, scans.end)
}

/// The corrected Intel log from the shared data (`None` without it, and the test skips).
fn intel_log() -> Option<LaserLog> {
    let path = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz")?;
    Some(mapmerge_io::read_carmen(&path).unwrap())
}

#[test]
fn intel_two_sessions_merge_by_recognition_and_unmerge_exactly() {
    let Some(log) = intel_log() else {
        return;
    };
    let corrected: Vec<Se2> = log
        .scans
        .iter()
        .map(|s| s.odom_from_robot.unwrap())
        .collect();
    let (first, second) = (0..500, 500..log.scans.len());
    let mut atlas = Atlas::new(AtlasParams::default()).unwrap();
    let started = std::time::Instant::now();
    let (scans_a, _, _) = map_scans(&mut atlas, &log, first.clone(), false);
    atlas.end_epoch(EpochEndReason::Kidnap);
    let inactive_before = atlas.inactive(MapId(0)).unwrap().clone();
    // The second session keyframe by keyframe until it recognises the first.
    let (mut scans_b, proposal, resume_at) = map_scans(&mut atlas, &log, second.clone(), true);
    let proposal = proposal.expect("the second session recognises the first");
    let robot = atlas.robot_node().unwrap();
    let robot_pose = atlas.active().vertex(robot).unwrap().pose;
    let verifier = default_verifier().unwrap();
    let event = atlas
        .merge(proposal.into_request(), Some(&verifier))
        .unwrap();
    eprintln!(
        "two sessions mapped and merged after scan {resume_at} in {:.1} s: {event:?}",
        started.elapsed().as_secs_f64()
    );
    assert_eq!(atlas.active().vertex(robot).unwrap().pose, robot_pose);

    // The transform is the truth: session frames are the poses of their first scans.
    let truth = corrected[second.start].between(&corrected[first.start]);
    let t = event.active_from_inactive;
    let error = truth.between(&Se2::new(t[0], t[1], t[2]));
    assert!(
        error.translation().norm() < 0.5
            && wrap_angle_rad(error.theta_rad).abs() < 5f64.to_radians(),
        "merge {t:?} vs truth {truth:?}"
    );
    // Every merge edge agrees with the corrected poses.
    let scan_of = |node: &NodeId| scans_a.get(node).or(scans_b.get(node)).copied();
    let merge_edges = atlas
        .active()
        .edges()
        .filter(|(_, e)| e.kind == EdgeKind::Merge)
        .count();
    assert!(merge_edges > 0);
    for (_, e) in atlas
        .active()
        .edges()
        .filter(|(_, e)| e.kind == EdgeKind::Merge)
    {
        let (from, to) = (scan_of(&e.from).unwrap(), scan_of(&e.to).unwrap());
        let z = corrected[from].between(&corrected[to]);
        let d = z.between(&e.measurement);
        assert!(
            d.translation().norm() < 0.5 && wrap_angle_rad(d.theta_rad).abs() < 0.1,
            "{e:?}: {d:?}"
        );
    }

    // The robot maps on after the merge: the rest of the second session (a fresh tracker
    // stands in for the one that would continue; the new keyframes join the same epoch).
    let current = atlas.current_epoch();
    let (rest, _, _) = map_scans(&mut atlas, &log, resume_at..second.end, false);
    scans_b.extend(rest);
    let current_vertices: BTreeSet<NodeId> = scans_b.keys().copied().collect();
    let current_edges = atlas
        .active()
        .edges()
        .filter(|(_, e)| current_vertices.contains(&e.from) && current_vertices.contains(&e.to))
        .filter(|(_, e)| e.kind != EdgeKind::Merge)
        .count();

    // An invalid-merge detector fires: everything merged goes, the second session stays.
    let undo = atlas
        .unmerge_all(UnmergeReason::InvalidMerge {
            detector: "test".into(),
            invalidity: 1.0,
        })
        .unwrap()
        .unwrap();
    assert_eq!(undo.restored_maps, vec![MapId(0)]);
    assert_eq!(atlas.inactive(MapId(0)), Some(&inactive_before));
    let kept: BTreeSet<NodeId> = atlas.active().vertices().map(|(id, _)| id).collect();
    assert_eq!(kept, current_vertices);
    assert!(atlas
        .active()
        .vertices()
        .all(|(_, v)| EpochId::of(&v.meta) == current));
    assert_eq!(atlas.active().num_edges(), current_edges);
}

/// Intel's first 600 scans mapped in one epoch with the default parameters as `edit` leaves
/// them: keyframes made, the active graph's poses, the loops and the constraint builder's
/// counters.
fn map_intel_600(
    log: &LaserLog,
    edit: impl FnOnce(&mut AtlasParams),
) -> (
    usize,
    Vec<(NodeId, Se2)>,
    Vec<mapmerge_atlas::LoopRecord>,
    mapmerge_atlas::ConstraintInfo,
) {
    let mut params = AtlasParams::default();
    edit(&mut params);
    let mut atlas = Atlas::new(params).unwrap();
    let (scan_of, _, _) = map_scans(&mut atlas, log, 0..600, false);
    let poses = atlas
        .active()
        .vertices()
        .map(|(n, v)| (n, v.pose))
        .collect();
    (
        scan_of.len(),
        poses,
        atlas.loops().to_vec(),
        atlas.constraint_info(),
    )
}

/// Finished submaps that release their match targets (`loops.submap_targets_mb`) and rebuild
/// them from their scans when searched again close the same loops: the graph is the same to
/// the bit, while the targets held at once stay a fraction of keeping them all.
#[test]
fn released_submap_targets_are_rebuilt_to_the_same_loops_and_graph() {
    let Some(log) = intel_log() else {
        return;
    };
    let run = |budget_mb: f64| map_intel_600(&log, |p| p.loops.submap_targets_mb = budget_mb);
    let (_, kept_poses, kept_loops, kept) = run(1e6);
    let (_, poses, loops, released) = run(0.0);
    eprintln!(
        "all kept: {} loops, peak {:.1} MB; released: {} rebuilds, peak {:.1} MB",
        kept_loops.len(),
        kept.peak_submap_target_bytes as f64 / 1e6,
        released.submap_target_rebuilds,
        released.peak_submap_target_bytes as f64 / 1e6
    );
    assert!(kept.local_loops >= 10, "{kept:?}");
    assert_eq!(kept.submap_target_rebuilds, 0);
    assert!(released.submap_target_rebuilds > 0);
    assert!(released.peak_submap_target_bytes * 4 < kept.peak_submap_target_bytes);
    assert_eq!(loops, kept_loops);
    assert_eq!(poses, kept_poses);
}

/// Revisits of mapped places stay out of the place index (`loops.revisit_spacing_m`): on the
/// first 600 scans of intel, which pass the same corridors more than once, a fifth or more of
/// the keyframes are left out, and the loops and poses are those of indexing every keyframe.
#[test]
fn revisits_stay_out_of_the_place_index_and_the_loops_are_the_same() {
    let Some(log) = intel_log() else {
        return;
    };
    let run = |spacing_m: f64| map_intel_600(&log, |p| p.loops.revisit_spacing_m = spacing_m);
    let (keyframes, all_poses, all_loops, all) = run(0.0);
    let (_, poses, loops, culled) = run(1.0);
    eprintln!(
        "{keyframes} keyframes, {} left out, {} loops",
        culled.revisits_not_indexed,
        loops.len()
    );
    assert_eq!(all.revisits_not_indexed, 0);
    assert!(5 * culled.revisits_not_indexed >= keyframes, "{culled:?}");
    assert!(all.local_loops >= 10, "{all:?}");
    assert_eq!(loops, all_loops);
    assert_eq!(poses, all_poses);
}

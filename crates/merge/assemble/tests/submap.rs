//! Submaps along segments: spacing, windows, frames (a synthetic corridor in 2D, a wall in 3D),
//! and descriptors of real submaps on a public log (revisits found by the descriptor).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use mapmerge_assemble::{
    build_submaps, cosine_distance, describe_submaps, Point3, RingSpectrumDescriptor, Segment,
    Segment3, SegmentPoints, SubmapParams,
};
use mapmerge_geometry::{LieGroup, Se2, Se3};
use mapmerge_scan::{LaserScan, Point2};
use nalgebra::{UnitQuaternion, Vector3};

/// Corridor walls 1.5 m either side of its axis, which runs from `origin` at `axis_rad`.
const HALF_WIDTH_M: f64 = 1.5;

/// A robot driving down a straight corridor: 100 scans 0.2 m apart with a heading that wobbles
/// by ±0.1 rad, a 181-beam front laser mounted 0.1 m ahead of the robot, and the true poses.
fn corridor() -> (Vec<Se2>, Vec<LaserScan>) {
    let (origin, axis_rad) = (Point2::new(5.0, -3.0), 0.7f64);
    let axis = Point2::new(axis_rad.cos(), axis_rad.sin());
    let mut poses = Vec::new();
    let mut scans = Vec::new();
    for k in 0..100 {
        let wobble = if k % 2 == 0 { 0.1 } else { -0.1 };
        let position = origin + axis * (0.2 * k as f64);
        let robot = Se2::new(position.x, position.y, axis_rad + wobble);
        let mut scan = LaserScan::new(
            -std::f64::consts::FRAC_PI_2,
            std::f64::consts::FRAC_PI_2,
            30.0,
            vec![0.0; 181],
        );
        scan.robot_from_sensor = Se2::new(0.1, 0.0, 0.0);
        let sensor = robot.compose(&scan.robot_from_sensor);
        let ranges: Vec<f32> = (0..181)
            .map(|i| {
                // Lateral direction of the beam relative to the corridor axis.
                let beam_rad = sensor.theta_rad - axis_rad + scan.beam_angle_rad(i);
                let lateral_m = axis.perp(&(sensor.translation() - origin));
                let sin = beam_rad.sin();
                let range_m = if sin > 1e-3 {
                    (HALF_WIDTH_M - lateral_m) / sin
                } else if sin < -1e-3 {
                    (-HALF_WIDTH_M - lateral_m) / sin
                } else {
                    f64::INFINITY
                };
                range_m.min(30.0) as f32
            })
            .collect();
        scan.ranges_m = ranges;
        poses.push(robot);
        scans.push(scan);
    }
    (poses, scans)
}

#[test]
fn corridor_submaps_have_the_spacing_window_and_frame() {
    let (world_from_robot, scans) = corridor();
    let stamps = (0..scans.len()).map(|k| k as f64).collect();
    let segment = Segment::new("corridor", stamps, world_from_robot.clone(), scans).unwrap();
    assert_eq!(segment.poses[0], Se2::identity());
    // A window that falls between scans (0.2 m apart), so rounding cannot move its edge.
    let params = SubmapParams {
        window_m: 3.9,
        ..SubmapParams::default()
    };
    let submaps = build_submaps(&segment, &params).unwrap();
    let travel = segment.travel_m();
    // 19.8 m of travel, a submap every metre (within one 0.2 m step).
    assert!((19..=20).contains(&submaps.len()), "{}", submaps.len());
    for pair in submaps.windows(2) {
        let gap_m = pair[1].travel_m - pair[0].travel_m;
        assert!(
            (params.spacing_m - 1e-9..=params.spacing_m + 0.2 + 1e-9).contains(&gap_m),
            "{gap_m}"
        );
    }
    let world_from_segment = world_from_robot[0];
    for (index, submap) in submaps.iter().enumerate() {
        assert_eq!(submap.index, index);
        // The centre's pose is the re-based true pose of its scan.
        let truth = world_from_segment
            .inverse()
            .compose(&world_from_robot[submap.centre_scan]);
        assert!(truth.local(&submap.segment_from_centre).norm() < 1e-9);
        assert!((submap.travel_m - travel[submap.centre_scan]).abs() < 1e-12);
        // Every scan within the window, none outside.
        let (first, last) = submap.scan_range;
        for (k, &t) in travel.iter().enumerate() {
            let inside = (t - submap.travel_m).abs() <= params.window_m;
            assert_eq!(
                inside,
                (first..=last).contains(&k),
                "scan {k} of submap {index}"
            );
        }
        // Points in the centre's robot frame: back in the world they lie on the walls.
        assert!(submap.points_in_centre.len() > 50);
        let world_from_centre = world_from_robot[submap.centre_scan];
        let axis = Point2::new(0.7f64.cos(), 0.7f64.sin());
        for p in &submap.points_in_centre {
            assert!(p.norm() < params.radius_m);
            let in_world = world_from_centre.transform_point(p);
            let lateral_m = (in_world - Point2::new(5.0, -3.0)).perp(&axis);
            assert!((lateral_m.abs() - HALF_WIDTH_M).abs() < 1e-6, "{lateral_m}");
        }
        // Voxel-downsampled: at most one point per 0.1 m cell.
        let mut cells: Vec<(i64, i64)> = submap
            .points_in_centre
            .iter()
            .map(|p| ((p.x / 0.1).floor() as i64, (p.y / 0.1).floor() as i64))
            .collect();
        let count = cells.len();
        cells.sort_unstable();
        cells.dedup();
        assert_eq!(cells.len(), count);
    }
    // Bad parameters are refused, not panicked on.
    let bad = SubmapParams {
        radius_m: -1.0,
        ..SubmapParams::default()
    };
    assert!(build_submaps(&segment, &bad).is_err());
}

#[test]
fn three_d_submaps_use_the_same_stage() {
    // A wall 4 m to the left of a robot driving along x at 0.5 m per cloud, 1 m up and turned
    // by 0.3 rad in the world; each cloud sees the wall beside it.
    let world_from_start = Se3::new(
        UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3),
        Vector3::new(2.0, 1.0, 1.0),
    );
    let mut poses = Vec::new();
    let mut clouds = Vec::new();
    for k in 0..40 {
        let start_from_robot = Se3::new(
            UnitQuaternion::identity(),
            Vector3::new(0.5 * k as f64, 0.0, 0.0),
        );
        poses.push(world_from_start.compose(&start_from_robot));
        let cloud: Vec<Point3> = (-10..=10)
            .flat_map(|i| (0..5).map(move |z| Point3::new(0.25 * i as f64, 4.0, z as f64 - 1.0)))
            .collect();
        clouds.push(cloud);
    }
    let segment = Segment3::new("wall", poses, clouds).unwrap();
    let params = SubmapParams {
        spacing_m: 5.0,
        radius_m: 20.0,
        window_m: 5.0,
        voxel_m: 0.5,
        ..SubmapParams::default()
    };
    let submaps = build_submaps(&segment, &params).unwrap();
    assert_eq!(segment.scan_count(), 40);
    // 19.5 m of travel: centres 5 m apart (5.5 m when rounding leaves 5 m just short).
    let travel: Vec<f64> = submaps.iter().map(|s| s.travel_m).collect();
    assert!((3..=4).contains(&travel.len()), "{travel:?}");
    for pair in travel.windows(2) {
        assert!(
            (5.0 - 1e-9..5.5 + 1e-9).contains(&(pair[1] - pair[0])),
            "{travel:?}"
        );
    }
    for submap in &submaps {
        assert!(submap.segment_from_centre.translation_m.y.abs() < 1e-9);
        for p in &submap.points_in_centre {
            // The wall in the centre frame: y = 4, heights −1..3.
            assert!(
                (p.y - 4.0).abs() < 1e-9 && (-1.0..=3.0).contains(&p.z),
                "{p:?}"
            );
            assert!(p.x.hypot(p.y) < params.radius_m);
        }
    }
}

#[test]
fn descriptors_of_real_submaps_find_revisits() {
    let Some(path) = mapmerge_testkit::shared_data("carmen/intel-corrected.log.xz") else {
        return;
    };
    let log = mapmerge_io::read_carmen(&path).unwrap();
    // The corrected poses: submaps are drift-free, so only the descriptor is under test.
    let segment = Segment::from_log_odometry("intel", &log).unwrap();
    let submaps = build_submaps(&segment, &SubmapParams::default()).unwrap();
    let descriptor = RingSpectrumDescriptor::default();
    let rows = describe_submaps(&descriptor, &submaps);
    assert_eq!(rows.len(), submaps.len());
    // Queries: submaps with an earlier submap within 1 m, at least 20 m of travel before. The
    // descriptor's nearest earlier submap (20 m of travel back or more) should be within 2 m.
    let (mut queries, mut hits) = (0, 0);
    for (i, query) in submaps.iter().enumerate() {
        let earlier: Vec<usize> = (0..i)
            .filter(|&j| query.travel_m - submaps[j].travel_m >= 20.0)
            .collect();
        let distance_m = |j: usize| {
            (query.segment_from_centre.translation() - submaps[j].segment_from_centre.translation())
                .norm()
        };
        if !earlier.iter().any(|&j| distance_m(j) < 1.0) {
            continue;
        }
        queries += 1;
        let best = earlier
            .iter()
            .copied()
            .min_by(|&a, &b| {
                let da = cosine_distance(rows.row(i).unwrap(), rows.row(a).unwrap());
                let db = cosine_distance(rows.row(i).unwrap(), rows.row(b).unwrap());
                da.total_cmp(&db)
            })
            .unwrap();
        hits += usize::from(distance_m(best) < 2.0);
    }
    eprintln!(
        "intel: {} submaps, revisit queries {queries}, nearest descriptor within 2 m: {hits}",
        submaps.len()
    );
    assert!(queries > 50, "{queries}");
    assert!(hits * 10 >= queries * 6, "{hits}/{queries}");
}

/// With `free_space_m`, a 2D submap keeps the cells its beams crossed: the corridor's axis
/// around the centre is free, the space behind its walls is not; without it a submap keeps
/// none, and a bad cell size is refused.
#[test]
fn planar_submaps_keep_the_free_space_their_beams_crossed() {
    let (world_from_robot, scans) = corridor();
    let stamps = (0..scans.len()).map(|k| k as f64).collect();
    let segment = Segment::new("corridor", stamps, world_from_robot, scans).unwrap();
    let with = SubmapParams {
        free_space_m: 0.1,
        ..SubmapParams::default()
    };
    let submaps = build_submaps(&segment, &with).unwrap();
    let middle = &submaps[submaps.len() / 2];
    let free = middle.free_space.as_ref().expect("free space kept");
    // Centre frame: the robot looks down the corridor (heading wobble ±0.1 rad).
    assert!(free.is_free(&Point2::new(2.0, 0.0)));
    assert!(free.is_free(&Point2::new(1.0, 0.8)));
    assert!(!free.is_free(&Point2::new(2.0, 3.0)), "behind a wall");
    let without = SubmapParams {
        free_space_m: 0.0,
        ..SubmapParams::default()
    };
    assert!(build_submaps(&segment, &without)
        .unwrap()
        .iter()
        .all(|s| s.free_space.is_none()));
    let bad = SubmapParams {
        free_space_m: f64::NAN,
        ..SubmapParams::default()
    };
    assert!(build_submaps(&segment, &bad).is_err());
}

//! Why door passings were missed: for each true passing no detection matched (tuning seeds
//! only, by default 1–20), what the detector had to go on — passway sightings of that door in
//! front before the crossing and behind after it (placed by the true pose), criterion 3 around
//! the crossing, the nearest detection in time, and how close the passing was to the
//! session's end.
//!
//!     cargo run --release -p mapmerge-lab --example door_misses -- [WORLDS] [FIRST] [LAST]
#![allow(clippy::unwrap_used, clippy::expect_used)]
use mapmerge_areas::{passways, DoorDetector, DoorParams};
use mapmerge_geometry::LieGroup;
use mapmerge_lab::area_truth::{score_session, DoorScoring};
use mapmerge_sim::{simulate, SimParams};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let worlds = args
        .get(1)
        .cloned()
        .unwrap_or("office,office-aliased,corridor-loop,warehouse,symmetric-hall".into());
    let first: u64 = args.get(2).map(|s| s.parse().unwrap()).unwrap_or(1);
    let last: u64 = args.get(3).map(|s| s.parse().unwrap()).unwrap_or(20);
    let params = DoorParams::default();
    let half = params.sector_half_angle_rad;
    println!("world seed session scan door to_end front_sightings back_sightings min_range_m nearest_detection");
    for world in worlds.split(',') {
        for seed in first..=last {
            let sim = SimParams::default()
                .with_preset_name(world)
                .unwrap()
                .with_sessions(2)
                .with_duration_secs(120.0);
            let data = simulate(&sim, seed).unwrap();
            for session in &data.sessions {
                let (_, _, missed) =
                    score_session(session, &params, &DoorScoring::default()).unwrap();
                if missed.is_empty() {
                    continue;
                }
                let mut detector = DoorDetector::new(params.clone()).unwrap();
                let mut detections = Vec::new();
                for record in &session.log.scans {
                    if let Some(d) = detector.push(&record.odom_from_robot.unwrap(), &record.scan) {
                        detections.push(d);
                    }
                }
                let n = session.log.scans.len();
                for (_, scan, door) in missed {
                    let centre = session
                        .world
                        .doors
                        .iter()
                        .find(|d| d.id.0 == door)
                        .unwrap()
                        .center_m;
                    let mut min_range = f64::INFINITY;
                    for k in scan.saturating_sub(60)..(scan + 30).min(n) {
                        let (_, truth) = session.truth[k];
                        min_range = min_range.min(truth.inverse().transform_point(&centre).norm());
                    }
                    // Sightings of this door before (front) and after (back) the crossing, by
                    // the default parameters and by each relaxed in turn.
                    let count = |p: &DoorParams, half: f64| {
                        let (mut front, mut back) = (0, 0);
                        for k in scan.saturating_sub(60)..(scan + 30).min(n) {
                            let (_, truth) = session.truth[k];
                            for s in passways(&session.log.scans[k].scan, p) {
                                let c = truth.transform_point(&s.center_m());
                                if (c - centre).norm() > 0.6 {
                                    continue;
                                }
                                let local = s.center_m();
                                let bearing = local.y.atan2(local.x).abs();
                                if k <= scan && bearing <= half {
                                    front += 1;
                                }
                                if k >= scan && bearing >= std::f64::consts::PI - half {
                                    back += 1;
                                }
                            }
                        }
                        format!("{front}/{back}")
                    };
                    let relaxed = [
                        ("default", params.clone(), half),
                        ("any-bearing", params.clone(), std::f64::consts::FRAC_PI_2),
                        (
                            "no-wall",
                            DoorParams {
                                min_wall_m: 0.0,
                                ..params.clone()
                            },
                            half,
                        ),
                        (
                            "jump-0.3",
                            DoorParams {
                                jump_m: 0.3,
                                ..params.clone()
                            },
                            half,
                        ),
                        (
                            "width-0.4-2.2",
                            DoorParams {
                                min_width_m: 0.4,
                                max_width_m: 2.2,
                                ..params.clone()
                            },
                            half,
                        ),
                        (
                            "range-6",
                            DoorParams {
                                max_post_range_m: 6.0,
                                ..params.clone()
                            },
                            half,
                        ),
                    ];
                    let counts: Vec<String> = relaxed
                        .iter()
                        .map(|(name, p, h)| format!("{name}={}", count(p, *h)))
                        .collect();
                    let width = session
                        .world
                        .doors
                        .iter()
                        .find(|d| d.id.0 == door)
                        .map(|d| d.width_m)
                        .unwrap_or(0.0);
                    let nearest = detections
                        .iter()
                        .min_by_key(|d| d.crossing_scan.abs_diff(scan))
                        .map(|d| {
                            let (_, truth) = session.truth[d.scan];
                            let p = truth.transform_point(&d.center_in_robot_m);
                            format!(
                                "crossing {} ({:+}) at {:.2} m from the door, criteria {:?}",
                                d.crossing_scan,
                                d.crossing_scan as i64 - scan as i64,
                                (p - centre).norm(),
                                d.criteria
                            )
                        })
                        .unwrap_or_default();
                    println!(
                        "{world} {seed} {} {scan} {door} w={width:.2} end={} {} min_range={min_range:.2} | {nearest}",
                        session.index,
                        n - scan,
                        counts.join(" ")
                    );
                }
            }
        }
    }
}

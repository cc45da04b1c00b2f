//! Do a corrected log's poses of two passes agree with the scans? Each scan of the second
//! range is matched (correlative search and ICP, ±0.5 m, ±5°) against the points of the
//! first range placed by the log's poses, starting where the log's pose puts it; the offset
//! printed is the match in the scan's frame (`robot_from_matched`), so 0 means the poses
//! agree with the scans (a check that forced merges valid by the corrected poses are true).
//!
//! `cargo run --release -p mapmerge-lab --example pose_consistency -- LOG A B C D`
//! (first range A..=B, second C..=D, scan indices). One line per scan: `SCAN dx DX dy DY dth
//! DEG deg score S`, or `SCAN none` where nothing within the window scores.
use std::error::Error;
use std::path::Path;

use mapmerge_geometry::LieGroup;
use mapmerge_scan::{transform_points, BeamFilter};
use mapmerge_scanmatch::{ScanMatcher, SearchWindow};

fn main() -> Result<(), Box<dyn Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 6 {
        return Err("usage: pose_consistency LOG FIRST_FROM FIRST_TO SECOND_FROM SECOND_TO".into());
    }
    let log = mapmerge_io::read_carmen(Path::new(&args[1]))?;
    let mut range = [0usize; 4];
    for (slot, text) in range.iter_mut().zip(&args[2..6]) {
        *slot = text
            .parse()
            .map_err(|e| format!("scan index {text:?}: {e}"))?;
    }
    let scan = |k: usize| {
        log.scans
            .get(k)
            .and_then(|record| Some((record, record.odom_from_robot?)))
            .ok_or_else(|| format!("scan {k}: missing, or without a pose"))
    };
    let filter = BeamFilter::default();
    let matcher = ScanMatcher::default();
    let mut points_in_world = Vec::new();
    for k in range[0]..=range[1] {
        let (record, world_from_robot) = scan(k)?;
        let points = record.scan.points_in_robot(&filter);
        points_in_world.extend(transform_points(&world_from_robot, &points));
    }
    let target = matcher.target(&points_in_world)?;
    let window = SearchWindow {
        linear_m: 0.5,
        angular_rad: 5f64.to_radians(),
    };
    for k in range[2]..=range[3] {
        let (record, world_from_robot) = scan(k)?;
        let points = record.scan.points_in_robot(&filter);
        match matcher.match_scan(&target, &points, &world_from_robot, &window) {
            Some(found) => {
                let robot_from_matched =
                    world_from_robot.inverse().compose(&found.target_from_query);
                let t = robot_from_matched.translation();
                println!(
                    "{k} dx {:+.3} dy {:+.3} dth {:+.2} deg score {:.3}",
                    t.x,
                    t.y,
                    robot_from_matched.theta_rad.to_degrees(),
                    found.score
                );
            }
            None => println!("{k} none"),
        }
    }
    Ok(())
}

//! The front-end on every public corrected log with seeded odometry noise, scored against the
//! corrected poses (ATE after rigid alignment):
//! `cargo run --release -p mapmerge-slam --example front_end_logs -- [DATA_DIR] [PROFILE] [SEED]`
//! (defaults: ../shared/data, default, 0). Prints a Markdown table.

use std::path::PathBuf;
use std::time::Instant;

use mapmerge_eval::{absolute_trajectory_error, add_odometry_noise, OdometryNoiseProfile};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_slam::{FrontEnd, FrontEndParams};

const LOGS: [&str; 13] = [
    "acapulco",
    "aces",
    "belgioioso",
    "csail",
    "edmonton",
    "fhw",
    "freiburg-079",
    "freiburg-101",
    "freiburg-campus",
    "infinite-corridor",
    "intel",
    "orebro",
    "seattle",
];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let data = PathBuf::from(args.get(1).map_or("../shared/data", String::as_str));
    let profile = OdometryNoiseProfile::from_name(args.get(2).map_or("default", String::as_str))?;
    let seed: u64 = args.get(3).map_or(Ok(0), |s| s.parse())?;
    println!("| log | scans | odometry ATE m | front-end ATE m | keyframes | matched | ms/scan |");
    println!("|---|---|---|---|---|---|---|");
    for name in LOGS {
        let log = mapmerge_io::read_carmen(&data.join(format!("carmen/{name}-corrected.log.xz")))?;
        let corrected: Vec<Se2> = log.scans.iter().filter_map(|s| s.odom_from_robot).collect();
        let noisy = add_odometry_noise(&log, &profile, seed)?;
        let odometry: Vec<Se2> = noisy
            .log
            .scans
            .iter()
            .filter_map(|s| s.odom_from_robot)
            .collect();
        let mut front_end = FrontEnd::new(FrontEndParams::default())?;
        let started = Instant::now();
        for (record, odom) in noisy.log.scans.iter().zip(&odometry) {
            front_end.add_scan(odom, &record.scan)?;
        }
        let ms = started.elapsed().as_secs_f64() * 1e3 / odometry.len().max(1) as f64;
        let estimate: Vec<Se2> = front_end
            .anchors()
            .trajectory(front_end.graph())
            .into_iter()
            .map(|p| p.unwrap_or_else(Se2::identity))
            .collect();
        let ate = absolute_trajectory_error(&corrected, &estimate, true)?;
        let ate_odometry = absolute_trajectory_error(&corrected, &odometry, true)?;
        let info = front_end.info();
        println!(
            "| {name} | {} | {:.3} | {:.3} | {} | {} | {:.1} |",
            corrected.len(),
            ate_odometry.rms_m,
            ate.rms_m,
            info.keyframes,
            info.matched,
            ms
        );
    }
    Ok(())
}

//! Times the simulator: 30 minutes of robot time (one session, 360 beams at 10 Hz: 18,001
//! scans, 6.5 M beams) in the `office` world, and the lidar alone on the same poses.
//!
//! `cargo run --release -p mapmerge-lab --example sim_speed [preset] [minutes]`

use std::time::Instant;

use mapmerge_sim::{simulate, Lidar, SimError, SimParams};

fn main() -> Result<(), SimError> {
    let mut args = std::env::args().skip(1);
    let preset = args.next().unwrap_or_else(|| "office".to_owned());
    let minutes: f64 = args.next().and_then(|m| m.parse().ok()).unwrap_or(30.0);
    let params = SimParams::default()
        .with_preset_name(&preset)?
        .with_sessions(1)
        .with_duration_secs(minutes * 60.0);
    let started = Instant::now();
    let dataset = simulate(&params, 1)?;
    let total_secs = started.elapsed().as_secs_f64();
    let session = &dataset.sessions[0];
    let scans = session.log.scans.len();
    let beams: usize = session
        .log
        .scans
        .iter()
        .map(|r| r.scan.ranges_m.len())
        .sum();
    println!(
        "simulate: {preset}, {minutes} min of robot time, {scans} scans, {beams} beams, {} odometry readings, \
         {:.1} m driven: {total_secs:.2} s wall time on {} threads",
        session.log.odometry.len(),
        session.motion.distance_m,
        rayon::current_num_threads()
    );
    println!(
        "motion: {} rooms visited, {} safety stops, {} replans, {} kidnaps, {} slips",
        session.motion.visited_rooms.len(),
        session.motion.safety_stops,
        session.motion.replans,
        session.kidnaps.len(),
        session.slips.len()
    );
    let lidar = Lidar::new(&session.world, params.lidar.clone())?;
    let poses: Vec<_> = session.truth.iter().map(|(_, pose)| *pose).collect();
    let started = Instant::now();
    let again = lidar.scans(&poses, 2);
    let lidar_secs = started.elapsed().as_secs_f64();
    println!(
        "lidar alone: {} scans in {lidar_secs:.2} s ({:.0} ns per beam per thread)",
        again.len(),
        lidar_secs * 1e9 * rayon::current_num_threads() as f64 / beams.max(1) as f64
    );
    Ok(())
}

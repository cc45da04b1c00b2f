//! The front-end on one CARMEN log, its scans' `odom_from_robot` as wheel odometry:
//! `cargo run --release -p mapmerge-slam --example front_end_log -- NOISY.log OUT.tum`
//! writes one pose per scan (line k = scan k) and prints one JSON line. scripts/bench_slam.sh
//! runs it beside MRPT icp-slam on the same noisy logs.

use mapmerge_slam::{run_front_end, FrontEndParams};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(log_path), Some(out)) = (args.get(1), args.get(2)) else {
        return Err("usage: front_end_log NOISY.log OUT.tum".into());
    };
    let log = mapmerge_io::read_carmen(std::path::Path::new(log_path))?;
    let run = run_front_end(&log, FrontEndParams::default())?;
    let stamped: Vec<(f64, mapmerge_geometry::Se2)> = run
        .trajectory
        .iter()
        .enumerate()
        .map(|(k, pose)| (k as f64, *pose))
        .collect();
    mapmerge_io::write_tum_planar(std::path::Path::new(out), &stamped)?;
    println!(
        "{{\"scans\":{},\"seconds\":{},\"keyframes\":{},\"matched\":{}}}",
        run.trajectory.len(),
        run.seconds,
        run.info.keyframes,
        run.info.matched
    );
    Ok(())
}

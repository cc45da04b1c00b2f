//! The front-end on one CARMEN log, its scans' `odom_from_robot` as wheel odometry:
//! `cargo run --release -p mapmerge-slam --example front_end_log -- NOISY.log OUT.tum`
//! writes one pose per scan (line k = scan k) and prints one JSON line. scripts/bench_slam.sh
//! runs it beside MRPT icp-slam on the same noisy logs.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::NodeId;
use mapmerge_slam::{run_front_end, FrontEndParams};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(log_path), Some(out)) = (args.get(1), args.get(2)) else {
        return Err("usage: front_end_log NOISY.log OUT.tum".into());
    };
    let log = mapmerge_io::read_carmen(std::path::Path::new(log_path))?;
    // FRONT_END_PARAMS: a JSON object overriding defaults (diagnostics only).
    let params: FrontEndParams = match std::env::var("FRONT_END_PARAMS") {
        Ok(json) => serde_json::from_str(&json)?,
        Err(_) => FrontEndParams::default(),
    };
    let run = run_front_end(&log, params)?;
    let stamped: Vec<(f64, Se2)> = run
        .trajectory
        .iter()
        .enumerate()
        .map(|(k, pose)| (k as f64, *pose))
        .collect();
    mapmerge_io::write_tum_planar(std::path::Path::new(out), &stamped)?;
    let info = serde_json::to_value(run.info)?;
    let mut line = serde_json::json!({"scans": run.trajectory.len(), "seconds": run.seconds});
    if let (Some(line), Some(info)) = (line.as_object_mut(), info.as_object()) {
        for (key, value) in info {
            line.entry(key.clone()).or_insert(value.clone());
        }
    }
    // With the corrected log as a third argument: how many loop edges are wrong.
    if let (Some(reference), Some(line)) = (args.get(3), line.as_object_mut()) {
        let truth = mapmerge_io::read_carmen(std::path::Path::new(reference))?;
        let truth: Vec<Option<Se2>> = truth.scans.iter().map(|s| s.odom_from_robot).collect();
        let (mut loops, mut wrong, mut worst) = (0, [0usize; 2], 0.0f64);
        for record in &run.loops {
            let scan = |node: NodeId| {
                run.keyframe_scans
                    .get(node.0 as usize)
                    .and_then(|&i| truth.get(i).copied().flatten())
            };
            let (Some(a), Some(b)) = (scan(record.from), scan(record.to)) else {
                continue;
            };
            let error = a.between(&b).between(&record.measurement);
            loops += 1;
            let t = error.translation().norm();
            worst = worst.max(t);
            if std::env::var("EDGE_ERRORS").is_ok() {
                let eigen = record
                    .covariance
                    .fixed_view::<2, 2>(0, 0)
                    .into_owned()
                    .symmetric_eigen();
                eprintln!(
                    "{} {} {:?} {:.3} {:.2} dist {:.2} score {:.3} sigma {:.3} {:.3} rot {:.2}",
                    record.from.0,
                    record.to.0,
                    record.source,
                    t,
                    error.theta_rad.to_degrees(),
                    record.measurement.translation().norm(),
                    record.score,
                    eigen.eigenvalues.max().sqrt(),
                    eigen.eigenvalues.min().sqrt(),
                    record.covariance[(2, 2)].sqrt().to_degrees()
                );
            }
            if t > 0.5 || error.theta_rad.abs() > 10f64.to_radians() {
                wrong[usize::from(record.source == mapmerge_slam::LoopSource::Place)] += 1;
            }
        }
        line.insert("loop_edges".into(), loops.into());
        line.insert("wrong_local_loops".into(), wrong[0].into());
        line.insert("wrong_place_loops".into(), wrong[1].into());
        line.insert("worst_loop_error_m".into(), worst.into());
    }
    println!("{line}");
    Ok(())
}

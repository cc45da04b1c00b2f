//! ROS 2 bags wherever a LOG goes: `sim --bag`, `convert`, and `slam`, `grid`, `split`,
//! `atlas`, `assemble` on bags give what they give on the CARMEN logs.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;

use crate::common::{ok_json, p, run, scratch};

/// `mapmerge assemble A B … -o OUT --no-pictures --json` with `extra` arguments; its report.
fn assemble(a: &Path, b: &Path, out: &Path, extra: &[&str]) -> serde_json::Value {
    let mut args = vec!["assemble", p(a), p(b)];
    args.extend_from_slice(extra);
    args.extend(["--no-pictures", "-o", p(out), "--json"]);
    ok_json(&args)
}

/// `(x, y)` of every pose of a TUM file.
fn tum_xy(path: &Path) -> Vec<(f64, f64)> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            (v[1], v[2])
        })
        .collect()
}

fn largest_gap_m(a: &[(f64, f64)], b: &[(f64, f64)]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(p, q)| (p.0 - q.0).hypot(p.1 - q.1))
        .fold(0.0, f64::max)
}

#[test]
fn every_log_command_reads_bags_as_it_reads_the_logs() {
    let dir = scratch("bags");
    let sim = dir.join("sim");
    ok_json(&[
        "sim",
        "--world",
        "office",
        "--sessions",
        "2",
        "--duration",
        "60",
        "--seed",
        "3",
        "--bag",
        "mcap",
        "--no-pictures",
        "-o",
        p(&sim),
        "--json",
    ]);
    let (log0, log1) = (sim.join("session_0.log"), sim.join("session_1.log"));
    let bag0 = sim.join("session_0.mcap");
    let bag1 = dir.join("session_1.db3");
    let converted = ok_json(&["convert", p(&log1), "-o", p(&bag1), "--json"]);
    assert_eq!(converted["scans"], 601);
    assert!(converted["stamps_rewritten"].is_null(), "{converted}");

    // slam: the same trajectory, up to the float32 beam angles of a LaserScan.
    let from_log = ok_json(&["slam", p(&log0), "-o", p(&dir.join("slam-log")), "--json"]);
    let from_bag = ok_json(&["slam", p(&bag0), "-o", p(&dir.join("slam-bag")), "--json"]);
    assert_eq!(from_log["scans"], from_bag["scans"]);
    let gap = largest_gap_m(
        &tum_xy(&dir.join("slam-log/trajectory.tum")),
        &tum_xy(&dir.join("slam-bag/trajectory.tum")),
    );
    assert!(gap < 0.05, "slam trajectories {gap} m apart");

    // grid: the same map from the same poses.
    let grid = |source: &Path, out: &str| {
        ok_json(&[
            "grid",
            "--log",
            p(source),
            "-o",
            p(&dir.join(out)),
            "--json",
        ])
    };
    let (grid_log, grid_bag) = (grid(&log1, "g-log.yaml"), grid(&bag1, "g-bag.yaml"));
    assert_eq!(grid_log["scans"], grid_bag["scans"]);
    assert_eq!(grid_log["width"], grid_bag["width"]);

    // split: the bag's poses are the truth, to the nanometre.
    for (source, out) in [(&log0, "split-log"), (&bag0, "split-bag")] {
        ok_json(&[
            "split",
            p(source),
            "--segments",
            "2",
            "-o",
            p(&dir.join(out)),
            "--json",
        ]);
    }
    for k in ["00", "01"] {
        let truth = |out: &str| tum_xy(&dir.join(format!("{out}/truth/session_0_{k}.tum")));
        assert!(largest_gap_m(&truth("split-log"), &truth("split-bag")) < 1e-6);
    }

    // atlas and assemble: a bag per session, the two storages mixed.
    let atlas = |a: &Path, b: &Path, out: &str| {
        ok_json(&["atlas", p(a), p(b), "-o", p(&dir.join(out)), "--json"])
    };
    let (atlas_log, atlas_bag) = (
        atlas(&log0, &log1, "atlas-log"),
        atlas(&bag0, &bag1, "atlas-bag"),
    );
    assert_eq!(atlas_log["scans"], atlas_bag["scans"]);
    assert_eq!(atlas_log["epochs"], atlas_bag["epochs"]);
    let odometry = ["--trajectory", "odometry"];
    let (assembled_log, assembled_bag) = (
        assemble(&log0, &log1, &dir.join("asm-log"), &odometry),
        assemble(&bag0, &bag1, &dir.join("asm-bag"), &odometry),
    );
    assert_eq!(
        assembled_log["groups"].as_array().map(Vec::len),
        assembled_bag["groups"].as_array().map(Vec::len)
    );
    assert_eq!(assembled_bag["arrivals"][0]["segment"], "session_0");

    // And back: a bag converts to a CARMEN log with the same scans.
    let back = dir.join("back.log");
    let round = ok_json(&["convert", p(&bag1), "-o", p(&back), "--json"]);
    assert_eq!(round["scans"], 601);
}

#[test]
fn bad_bags_exit_with_code_2_and_name_the_file_and_reason() {
    let dir = scratch("bad-bags");
    let sim = dir.join("sim");
    ok_json(&[
        "sim",
        "--sessions",
        "1",
        "--duration",
        "20",
        "--bag",
        "mcap",
        "--no-pictures",
        "-o",
        p(&sim),
        "--json",
    ]);
    let bag = sim.join("session_0.mcap");
    let expect_bad = |args: &[&str], needles: &[&str]| {
        let out = run(args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
        for needle in needles {
            assert!(stderr.contains(needle), "{args:?}: {stderr}");
        }
    };
    let out_dir = dir.join("out");
    let out = p(&out_dir);
    expect_bad(
        &["slam", p(&bag), "--scan-topic", "/front_scan", "-o", out],
        &["session_0.mcap", "no topic '/front_scan'"],
    );
    expect_bad(
        &["slam", p(&bag), "--odom-topic", "/scan", "-o", out],
        &["topic '/scan' carries sensor_msgs/msg/LaserScan"],
    );
    let bytes = std::fs::read(&bag).unwrap();
    let truncated = dir.join("truncated.mcap");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    expect_bad(
        &["slam", p(&truncated), "-o", out],
        &["truncated.mcap", "MCAP"],
    );
    let garbage = dir.join("garbage.db3");
    std::fs::write(&garbage, b"not a database").unwrap();
    expect_bad(
        &["grid", "--log", p(&garbage), "-o", p(&dir.join("m.yaml"))],
        &["garbage.db3", "SQLite"],
    );
    let bag_dir = dir.join("bag_dir");
    std::fs::create_dir_all(&bag_dir).unwrap();
    std::fs::write(bag_dir.join("metadata.yaml"), "rosbag2_bagfile_information:\n  storage_identifier: mcap\n  relative_file_paths: [gone.mcap]\n").unwrap();
    expect_bad(&["atlas", p(&bag_dir), "-o", out], &["gone.mcap"]);
    expect_bad(
        &["convert", p(&bag), "-o", p(&dir.join("x.bag"))],
        &["x.bag", ".mcap, .db3"],
    );
}

/// A KITTI-style folder of a drive along a street from `x0_m` to `x1_m`: building faces at
/// y = ±8 m with gaps, poles, one cloud every 2 m.
fn kitti_drive(dir: &Path, x0_m: i32, x1_m: i32) {
    let mut world = Vec::new();
    for x in -20i32..140 {
        for z in [0.5f32, 1.5, 2.5, 3.5] {
            let xf = x as f32 + 0.5;
            if (x.div_euclid(7)) % 3 != 0 {
                world.push([xf, 8.0 + 0.3 * (x as f32).sin(), z]);
            }
            if (x.div_euclid(5)) % 4 != 1 {
                world.push([xf, -8.0 - 0.3 * (x as f32).cos(), z]);
            }
        }
    }
    std::fs::create_dir_all(dir.join("velodyne")).unwrap();
    let mut poses = String::new();
    for (k, x) in (x0_m..x1_m).step_by(2).enumerate() {
        let mut bytes = Vec::new();
        for p in world.iter().filter(|p| (p[0] - x as f32).abs() < 30.0) {
            for v in [p[0] - x as f32, p[1], p[2] - 1.7, 0.5] {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
        std::fs::write(dir.join(format!("velodyne/{k:06}.bin")), bytes).unwrap();
        poses.push_str(&format!("1 0 0 {x} 0 1 0 0 0 0 1 1.7\n"));
    }
    std::fs::write(dir.join("poses.txt"), poses).unwrap();
}

#[test]
fn point_cloud_bags_assemble_as_the_kitti_folders_they_came_from() {
    let dir = scratch("cloud-bags");
    let (a, b) = (dir.join("drive_a"), dir.join("drive_b"));
    kitti_drive(&a, 0, 80);
    kitti_drive(&b, 40, 120);
    let (bag_a, bag_b) = (dir.join("drive_a.mcap"), dir.join("drive_b.db3"));
    let converted = ok_json(&["convert", p(&a), "-o", p(&bag_a), "--json"]);
    assert_eq!(converted["scans"], 40);
    ok_json(&["convert", p(&b), "-o", p(&bag_b), "--json"]);
    let (folders, bags) = (
        assemble(&a, &b, &dir.join("folders"), &[]),
        assemble(&bag_a, &bag_b, &dir.join("bags"), &[]),
    );
    for k in 0..2 {
        assert_eq!(
            folders["arrivals"][k]["submaps"],
            bags["arrivals"][k]["submaps"]
        );
        assert_eq!(
            folders["arrivals"][k]["segment"],
            bags["arrivals"][k]["segment"]
        );
    }
    assert_eq!(folders["groups"], bags["groups"]);
    // A 3D bag among laser logs is refused.
    let sim = dir.join("sim");
    ok_json(&[
        "sim",
        "--sessions",
        "1",
        "--duration",
        "20",
        "--no-pictures",
        "-o",
        p(&sim),
        "--json",
    ]);
    let out = run(&[
        "assemble",
        p(&sim.join("session_0.log")),
        p(&bag_a),
        "-o",
        p(&dir.join("mixed")),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("a 3D segment among 2D ones"));
}

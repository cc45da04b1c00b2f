//! Issue 67, part 6: every config type, one field at a time set to a hostile value (negative,
//! zero, tiny, huge, the integer limits), fed to the command that reads it. The command
//! refuses the config (exit code 2, naming the file) or runs; it never panics, aborts or
//! hangs, within a time limit and a 4 GB address space. `MAPMERGE_MUTATION_CASES` sets the
//! cases per command (default 24; proptest's fixed seed).
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use proptest::strategy::{Strategy, ValueTree};
use proptest::test_runner::TestRunner;
use serde_json::Value;

use crate::common::{p, scratch, BIN};

/// Values out of most fields' ranges, and a few inside that stress sizes.
const HOSTILE: &[&str] = &[
    "-1",
    "0",
    "-1e9",
    "1e308",
    "-1e308",
    "1e-300",
    "18446744073709551615",
    "4294967295",
    "1e9",
    "0.5",
    "3.5",
    "null",
    "\"x\"",
];

/// The path of every number in `value` (array elements by index).
fn numeric_leaves(value: &Value, path: &mut Vec<Value>, out: &mut Vec<Vec<Value>>) {
    match value {
        Value::Number(_) => out.push(path.clone()),
        Value::Object(map) => {
            for (key, child) in map {
                path.push(Value::String(key.clone()));
                numeric_leaves(child, path, out);
                path.pop();
            }
        }
        Value::Array(items) => {
            for (k, child) in items.iter().enumerate() {
                path.push(Value::from(k));
                numeric_leaves(child, path, out);
                path.pop();
            }
        }
        _ => {}
    }
}

/// `defaults` with the leaf at `path` replaced by `value`.
fn mutated(defaults: &Value, path: &[Value], value: Value) -> Value {
    let mut config = defaults.clone();
    let mut slot = &mut config;
    for step in path {
        slot = match step {
            Value::String(key) => &mut slot[key.as_str()],
            Value::Number(k) => &mut slot[k.as_u64().unwrap_or(0) as usize],
            _ => unreachable!("paths hold keys and indices"),
        };
    }
    *slot = value;
    config
}

/// Runs `args` in a 4 GB address space; `None` when it outlived `limit` (then killed).
fn run_bounded(args: &[String], limit: Duration) -> Option<std::process::Output> {
    let mut command = Command::new("sh");
    command
        .arg("-c")
        .arg("ulimit -v 4194304; exec \"$@\"")
        .arg("sh")
        .arg(BIN)
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    let mut child = command.spawn().unwrap();
    let started = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            return Some(child.wait_with_output().unwrap());
        }
        if started.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            return None;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Mutates `defaults` `cases` times and runs `command(config_path, output_dir)` on each.
fn mutate_and_run(name: &str, defaults: &Value, command: &dyn Fn(&Path, &Path) -> Vec<String>) {
    let cases: usize = std::env::var("MAPMERGE_MUTATION_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(24);
    let mut leaves = Vec::new();
    numeric_leaves(defaults, &mut Vec::new(), &mut leaves);
    assert!(leaves.len() > 5, "{name}: {} numeric fields", leaves.len());
    let dir = scratch(&format!("mutation-{name}"));
    let mut runner = TestRunner::deterministic();
    let pick = (0..leaves.len(), 0..HOSTILE.len());
    let (mut refused, mut ran) = (0, 0);
    for case in 0..cases {
        let (leaf, hostile) = pick.new_tree(&mut runner).unwrap().current();
        let value: Value = serde_json::from_str(HOSTILE[hostile]).unwrap();
        let config = mutated(defaults, &leaves[leaf], value);
        let config_path = dir.join(format!("config-{case}.json"));
        std::fs::write(&config_path, config.to_string()).unwrap();
        let output = dir.join(format!("out-{case}"));
        let what = format!("{name}: {:?} = {}", leaves[leaf], HOSTILE[hostile]);
        let out = run_bounded(&command(&config_path, &output), Duration::from_secs(120))
            .unwrap_or_else(|| panic!("{what}: still running after 120 s"));
        let stderr = String::from_utf8_lossy(&out.stderr);
        match out.status.code() {
            Some(2) => {
                assert!(
                    stderr.contains(&format!("config-{case}.json")),
                    "{what}: {stderr}"
                );
                refused += 1;
            }
            Some(0 | 1 | 3) => ran += 1,
            code => panic!("{what}: exit {code:?} (a panic or a signal): {stderr}"),
        }
    }
    eprintln!("{name}: {refused} refused, {ran} ran of {cases}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A 15 s simulated session: a log, its map.
fn inputs(dir: &Path) -> (PathBuf, PathBuf) {
    let sim = dir.join("sim");
    let out = crate::common::run(&[
        "sim",
        "--sessions",
        "1",
        "--duration",
        "15",
        "--no-pictures",
        "-o",
        p(&sim),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    (sim.join("session_0.log"), sim.join("world.yaml"))
}

fn strings(args: &[&str]) -> Vec<String> {
    args.iter().map(|s| (*s).to_owned()).collect()
}

#[test]
fn mutated_engine_configs_never_panic_abort_or_hang() {
    let dir = scratch("mutation-engine-inputs");
    let (log, _) = inputs(&dir);
    let defaults = serde_json::to_value(mapmerge_engine::EngineParams::default()).unwrap();
    mutate_and_run("slam", &defaults, &|config, out| {
        strings(&["slam", p(&log), "-o", p(out), "--config", p(config)])
    });
    mutate_and_run("atlas", &defaults, &|config, out| {
        strings(&[
            "atlas",
            p(&log),
            "-o",
            p(out),
            "--no-pictures",
            "--config",
            p(config),
        ])
    });
}

#[test]
fn mutated_map_configs_never_panic_abort_or_hang() {
    let dir = scratch("mutation-map-inputs");
    let (log, map) = inputs(&dir);
    let grid = serde_json::to_value(mapmerge_gridmatch::GridMatchParams::default()).unwrap();
    mutate_and_run("grid-merge", &grid, &|config, out| {
        let merged = out.with_extension("yaml");
        strings(&[
            "grid-merge",
            p(&map),
            p(&map),
            "-o",
            p(&merged),
            "--config",
            p(config),
        ])
    });
    let areas = serde_json::to_value(mapmerge_areas::ManagerParams::default()).unwrap();
    mutate_and_run("areas", &areas, &|config, out| {
        strings(&["areas", p(&log), "-o", p(out), "--config", p(config)])
    });
    let segments = dir.join("segments");
    let out = crate::common::run(&["split", p(&log), "--segments", "2", "-o", p(&segments)]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (first, second) = (
        segments.join("session_0_00.log"),
        segments.join("session_0_01.log"),
    );
    let assemble = serde_json::to_value(mapmerge_assemble::AssembleParams::default()).unwrap();
    mutate_and_run("assemble", &assemble, &|config, out| {
        strings(&[
            "assemble",
            p(&first),
            p(&second),
            "-o",
            p(out),
            "--no-pictures",
            "--config",
            p(config),
        ])
    });
}

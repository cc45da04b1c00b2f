//! Success rate, false accepts and time of `match_grids` on crops of real building maps: the
//! ROS maps in `../shared/data/gridmaps` ("real maps") and grids built at 0.05 m from the
//! public CARMEN logs in `../shared/data/carmen` with their corrected scan poses ("log-built
//! maps"). Each pair is two overlapping windows of one map, the second turned by a random
//! heading, shifted and (either one) coarsened by up to 2:1, overlap 30–70 %. Prints a
//! markdown table, then the time of the 1000 × 1000-cell pair (median of 15 runs, wall and
//! CPU).
//!
//! ```text
//! cargo run --release -p mapmerge-lab --example match_benchmark -- [--pairs 30] [--seed 1] [--map NAME] [--verbose]
//! ```

use std::time::Instant;

use mapmerge_grid::{InsertParams, OccupancyGrid};
use mapmerge_gridmatch::{match_grids, GridMatchParams};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

#[path = "../../../merge/gridmatch/tests/common/crops.rs"]
mod crops;

/// Map folder, file, crop side (m).
const MAPS: &[(&str, &str, f64)] = &[
    ("intel-bwi", "intel.yaml", 30.0),
    ("willow-2010-02-18", "willow-2010-02-18-0.10.yaml", 30.0),
    ("willow-full", "willow-full.yaml", 30.0),
    ("utexas-gdc-1", "1.yaml", 40.0),
    ("utexas-gdc-2", "2.yaml", 40.0),
    ("utexas-gdc-3", "3.yaml", 40.0),
    ("utexas-gdc-4", "4.yaml", 40.0),
];

/// Log (below `carmen/`), crop side (m): indoor buildings.
const LOGS: &[(&str, f64)] = &[
    ("intel-corrected.log.xz", 20.0),
    ("aces-corrected.log.xz", 30.0),
    ("csail-corrected.log.xz", 30.0),
    ("fhw-corrected.log.xz", 30.0),
];

/// Resolution of the log-built grids (m).
const LOG_RESOLUTION_M: f64 = 0.05;

const MAX_ERROR_CELLS: f64 = 2.0;
const MAX_ERROR_DEG: f64 = 1.0;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let value = |name: &str, default: u64| {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
            .and_then(|v| v.parse().ok())
            .unwrap_or(default)
    };
    let pairs = value("--pairs", 30) as usize;
    let seed = value("--seed", 1);
    let verbose = args.iter().any(|a| a == "--verbose");
    let Some(data) = mapmerge_testkit::shared_data_dir() else {
        return;
    };
    let mut params = GridMatchParams::default();
    if let Ok(json) = std::env::var("GRIDMATCH_PARAMS") {
        match serde_json::from_str(&json) {
            Ok(p) => params = p,
            Err(e) => eprintln!("GRIDMATCH_PARAMS ignored: {e}"),
        }
    }
    let only: Option<String> = args
        .iter()
        .position(|a| a == "--map")
        .and_then(|i| args.get(i + 1))
        .cloned();
    println!("| map | pairs | found (≤ {MAX_ERROR_CELLS} cells, ≤ {MAX_ERROR_DEG}°) | accepted | accepted & right | false accepts | right but rejected | median ms | max ms |");
    println!("|---|---|---|---|---|---|---|---|---|");
    // Real maps, log-built maps: counts (pairs, found, accepted, accepted & right, false
    // accepts) and times.
    let mut totals = [([0usize; 5], Vec::new()), ([0usize; 5], Vec::new())];
    let sources = MAPS
        .iter()
        .map(|&(folder, file, side_m)| {
            let path = data.join("gridmaps").join(folder).join(file);
            (folder.to_string(), Source::Ros(path), side_m)
        })
        .chain(LOGS.iter().map(|&(file, side_m)| {
            let name = format!("log: {}", file.trim_end_matches("-corrected.log.xz"));
            (name, Source::Log(data.join("carmen").join(file)), side_m)
        }));
    for (index, (folder, source, side_m)) in sources.enumerate() {
        let folder = folder.as_str();
        if only.as_deref().is_some_and(|m| !folder.contains(m)) {
            continue;
        }
        let Some(map) = source.load() else {
            continue;
        };
        let mut rng = ChaCha8Rng::seed_from_u64(seed * 1000 + index as u64);
        let mut counts = [0usize; 5];
        let mut ms = Vec::new();
        for k in 0..pairs {
            let Some(pair) = crops::crop_pair(&map, &mut rng, side_m, 0.3, 0.7, 2.0) else {
                continue;
            };
            if verbose {
                eprintln!(
                    "{folder} #{k}: truth {:.3} {:.3} {:.2}°",
                    pair.a_from_b.x_m,
                    pair.a_from_b.y_m,
                    pair.a_from_b.theta_rad.to_degrees()
                );
            }
            let start = Instant::now();
            let result = match match_grids(&pair.a, &pair.b, &params) {
                Ok(r) => r,
                Err(e) => {
                    eprintln!("{folder} #{k}: {e}");
                    counts[0] += 1;
                    continue;
                }
            };
            ms.push(start.elapsed().as_secs_f64() * 1e3);
            counts[0] += 1;
            let resolution = result.resolution_m;
            let right = result.hypotheses.first().is_some_and(|h| {
                let (cells, rad) = crops::error(&pair.b, &pair.a_from_b, &h.a_from_b, resolution);
                cells <= MAX_ERROR_CELLS && rad.to_degrees() <= MAX_ERROR_DEG
            });
            counts[1] += usize::from(right);
            counts[2] += usize::from(result.accepted);
            counts[3] += usize::from(result.accepted && right);
            counts[4] += usize::from(result.accepted && !right);
            if verbose {
                let h = result.hypotheses.first();
                let (cells, rad) = h.map_or((f64::NAN, f64::NAN), |h| {
                    crops::error(&pair.b, &pair.a_from_b, &h.a_from_b, resolution)
                });
                let truth = pair.a_from_b.theta_rad;
                let nearest_rotation = result
                    .rotations_rad
                    .iter()
                    .map(|r| {
                        mapmerge_geometry::wrap_angle_rad(r - truth)
                            .abs()
                            .to_degrees()
                    })
                    .fold(f64::MAX, f64::min);
                let right_rank = result.hypotheses.iter().position(|h| {
                    let (cells, rad) =
                        crops::error(&pair.b, &pair.a_from_b, &h.a_from_b, resolution);
                    cells <= MAX_ERROR_CELLS && rad.to_degrees() <= MAX_ERROR_DEG
                });
                eprintln!(
                    "{folder} #{k}: right at {right_rank:?} of {} rot-err {nearest_rotation:.2}° overlap {:.2} res {:.3}/{:.3} err {:.1} cells {:.2}° acc {:?} ω {:.3} dm {:.2} margin {:.3} right {right} {:?} runner ω {:?}",
                    result.hypotheses.len(),
                    pair.overlap,
                    pair.a.resolution_m(),
                    pair.b.resolution_m(),
                    cells,
                    rad.to_degrees(),
                    result.accepted,
                    h.map_or(0.0, |h| h.acceptance),
                    h.map_or(0.0, |h| h.metrics.dm_cells),
                    result.margin,
                    result.rejection,
                    result.hypotheses.get(1).map(|h| (h.acceptance, h.metrics.dm_cells)),
                );
            }
        }
        row(folder, &counts, &mut ms);
        let group = usize::from(index >= MAPS.len());
        for (t, c) in totals[group].0.iter_mut().zip(counts) {
            *t += c;
        }
        totals[group].1.extend(ms);
    }
    let mut all = ([0usize; 5], Vec::new());
    for ((counts, ms), name) in totals
        .iter_mut()
        .zip(["**real maps**", "**log-built maps**"])
    {
        row(name, counts, ms);
        for (t, c) in all.0.iter_mut().zip(*counts) {
            *t += c;
        }
        all.1.extend_from_slice(ms);
    }
    row("**all**", &all.0, &mut all.1);
    timing_1000(&data, &params);
}

/// One table row: counts (pairs, found, accepted, accepted & right, false accepts), times.
fn row(name: &str, counts: &[usize; 5], ms: &mut [f64]) {
    println!(
        "| {name} | {} | {} ({:.1} %) | {} | {} | {} | {} | {:.0} | {:.0} |",
        counts[0],
        counts[1],
        100.0 * counts[1] as f64 / counts[0].max(1) as f64,
        counts[2],
        counts[3],
        counts[4],
        counts[1] - counts[3],
        median(ms),
        ms.iter().copied().fold(0.0, f64::max),
    );
}

/// Where a benchmark map comes from.
enum Source {
    /// A ROS map_server map.
    Ros(std::path::PathBuf),
    /// A CARMEN log whose scans carry (corrected) poses, built into a grid.
    Log(std::path::PathBuf),
}

impl Source {
    fn load(&self) -> Option<OccupancyGrid> {
        match self {
            Source::Ros(path) => {
                let map = crops::read_map(path);
                if map.is_none() {
                    eprintln!("cannot read {}", path.display());
                }
                map
            }
            Source::Log(path) => {
                let log = match mapmerge_io::read_carmen(path) {
                    Ok(log) => log,
                    Err(e) => {
                        eprintln!("cannot read {}: {e}", path.display());
                        return None;
                    }
                };
                let scans = log
                    .scans
                    .iter()
                    .filter_map(|r| Some((r.odom_from_robot?, &r.scan)));
                match OccupancyGrid::from_scans(LOG_RESOLUTION_M, scans, &InsertParams::default()) {
                    Ok((grid, _)) => Some(grid),
                    Err(e) => {
                        eprintln!("cannot build a grid from {}: {e}", path.display());
                        None
                    }
                }
            }
        }
    }
}

/// Two 1000 × 1000-cell crops (50 m at 0.05 m) of UT Austin GDC floor 1, B turned by 37°.
fn timing_1000(data: &std::path::Path, params: &GridMatchParams) {
    let path = data.join("gridmaps/utexas-gdc-1/1.yaml");
    let Some(map) = crops::read_map(&path) else {
        return;
    };
    let (a, b, truth) = crops::pair_1000(&map);
    let mut ms = Vec::new();
    let mut cpu_ms = Vec::new();
    let mut right = false;
    for _ in 0..15 {
        let (start, cpu_start) = (Instant::now(), process_cpu_ms());
        let Ok(result) = match_grids(&a, &b, params) else {
            return;
        };
        ms.push(start.elapsed().as_secs_f64() * 1e3);
        cpu_ms.push(process_cpu_ms() - cpu_start);
        right = result.hypotheses.first().is_some_and(|h| {
            let (cells, rad) = crops::error(&b, &truth, &h.a_from_b, result.resolution_m);
            cells <= MAX_ERROR_CELLS && rad.to_degrees() <= MAX_ERROR_DEG && result.accepted
        });
    }
    println!();
    println!("| 1000 × 1000 cells (utexas-gdc-1, 0.05 m) | runs | median ms | min ms | max ms | median CPU ms | found & accepted |");
    println!("|---|---|---|---|---|---|---|");
    let min = ms.iter().copied().fold(f64::MAX, f64::min);
    let max = ms.iter().copied().fold(0.0, f64::max);
    println!(
        "| {} threads | {} | {:.1} | {:.1} | {:.1} | {:.1} | {right} |",
        rayon::current_num_threads(),
        ms.len(),
        median(&mut ms),
        min,
        max,
        median(&mut cpu_ms),
    );
}

/// CPU time of this process's threads so far (ms; Linux `/proc/self/task/*/schedstat`, NaN
/// elsewhere): the cost of a match independent of what else the machine runs.
fn process_cpu_ms() -> f64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return f64::NAN;
    };
    tasks
        .filter_map(Result::ok)
        .filter_map(|task| std::fs::read_to_string(task.path().join("schedstat")).ok())
        .filter_map(|stat| stat.split_whitespace().next()?.parse::<f64>().ok())
        .sum::<f64>()
        * 1e-6
}

fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

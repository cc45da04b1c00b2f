//! Success rate, false accepts and time of `match_grids` on crops of the real building maps
//! in `../shared/data/gridmaps`: two overlapping windows of one map, the second turned by a
//! random heading, shifted and (either one) coarsened by up to 2:1, overlap 30–70 %.
//! Prints a markdown table.
//!
//! ```text
//! cargo run --release -p mapmerge-gridmatch --example match_benchmark -- [--pairs 30] [--seed 1]
//! ```

use std::time::Instant;

use mapmerge_gridmatch::{match_grids, GridMatchParams};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

#[path = "../tests/common/crops.rs"]
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
    let mut total = [0usize; 5];
    let mut all_ms = Vec::new();
    for (index, &(folder, file, side_m)) in MAPS.iter().enumerate() {
        if only.as_deref().is_some_and(|m| m != folder) {
            continue;
        }
        let path = data.join("gridmaps").join(folder).join(file);
        let Some(map) = crops::read_map(&path) else {
            eprintln!("cannot read {}", path.display());
            continue;
        };
        let mut rng = ChaCha8Rng::seed_from_u64(seed * 1000 + index as u64);
        let mut counts = [0usize; 5];
        let mut ms = Vec::new();
        for k in 0..pairs {
            let Some(pair) = crops::crop_pair(&map, &mut rng, side_m, 0.3, 0.7, 2.0) else {
                continue;
            };
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
        let right_rejected = counts[1] - counts[3];
        println!(
            "| {folder} | {} | {} ({:.0} %) | {} | {} | {} | {} | {:.0} | {:.0} |",
            counts[0],
            counts[1],
            100.0 * counts[1] as f64 / counts[0].max(1) as f64,
            counts[2],
            counts[3],
            counts[4],
            right_rejected,
            median(&mut ms),
            ms.iter().copied().fold(0.0, f64::max),
        );
        for (t, c) in total.iter_mut().zip(counts) {
            *t += c;
        }
        all_ms.extend(ms);
    }
    println!(
        "| **all** | {} | {} ({:.1} %) | {} | {} | {} | {} | {:.0} | {:.0} |",
        total[0],
        total[1],
        100.0 * total[1] as f64 / total[0].max(1) as f64,
        total[2],
        total[3],
        total[4],
        total[1] - total[3],
        median(&mut all_ms),
        all_ms.iter().copied().fold(0.0, f64::max),
    );
    timing_1000(&data, &params);
}

/// Two 1000 × 1000-cell crops (50 m at 0.05 m) of UT Austin GDC floor 1, B turned by 37°.
fn timing_1000(data: &std::path::Path, params: &GridMatchParams) {
    let path = data.join("gridmaps/utexas-gdc-1/1.yaml");
    let Some(map) = crops::read_map(&path) else {
        return;
    };
    let (a, b, truth) = crops::pair_1000(&map);
    let mut ms = Vec::new();
    let mut right = false;
    for _ in 0..15 {
        let start = Instant::now();
        let Ok(result) = match_grids(&a, &b, params) else {
            return;
        };
        ms.push(start.elapsed().as_secs_f64() * 1e3);
        right = result.hypotheses.first().is_some_and(|h| {
            let (cells, rad) = crops::error(&b, &truth, &h.a_from_b, result.resolution_m);
            cells <= MAX_ERROR_CELLS && rad.to_degrees() <= MAX_ERROR_DEG && result.accepted
        });
    }
    println!();
    println!("| 1000 × 1000 cells (utexas-gdc-1, 0.05 m) | runs | median ms | min ms | max ms | found & accepted |");
    println!("|---|---|---|---|---|---|");
    let min = ms.iter().copied().fold(f64::MAX, f64::min);
    let max = ms.iter().copied().fold(0.0, f64::max);
    println!(
        "| {} threads | {} | {:.1} | {:.1} | {:.1} | {right} |",
        rayon::current_num_threads(),
        ms.len(),
        median(&mut ms),
        min,
        max
    );
}

fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

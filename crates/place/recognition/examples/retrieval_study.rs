//! Retrieval alone (issue 16, part 2): how often a true revisit comes back among the top k of
//! Scan Context, of the ring spectrum (`RingSpectrumDescriptor`, translation-invariant), and of
//! both lists fused, on the same keyframes as `place_benchmark` (its `support/place_eval.rs`
//! defines keyframes, local maps and revisits). No verification: this measures the ceiling
//! retrieval puts on recall.
//!
//! ```sh
//! cargo run --release -p mapmerge-place --example retrieval_study -- LOG-corrected.log.xz \
//!     [--config JSON] [--spectrum JSON]
//! ```
//!
//! Without options, keyframes are described as the benchmark's default configuration does
//! (the scan; the spectrum of `place.appearance`); `--config` changes the keyframes (e.g.
//! `{"describe_local_map": true, "local_map_m": 6}`), `--spectrum` the ring spectrum.
//!
//! Prints one JSON line: per k in {1, 5, 10, 20}, the revisits retrieved by each list, where
//! *retrieved* means a keyframe within `revisit_m` and the view overlap of the query is in the
//! list and a yaw estimate for it is within 20° of the truth (Scan Context's column shift for
//! Scan Context's list; for the spectrum's, Scan Context's shift or the spectrum's own polar
//! correlation, whichever is the production's guess: both are reported).

#[path = "support/place_eval.rs"]
mod place_eval;

use std::path::PathBuf;
use std::time::Instant;

use mapmerge_geometry::{wrap_angle_rad, LieGroup};
use mapmerge_place::{
    cosine_distance, PlaceDescriptor, PlaceIndex, RingSpectrumDescriptor, RingSpectrumParams,
    ScanContext, SubmapDescriptor,
};
use place_eval::BenchConfig;
use rayon::prelude::*;
use serde::Serialize;

const KS: [usize; 6] = [1, 5, 10, 20, 50, 100];

#[derive(Serialize, Default)]
struct Study {
    name: String,
    keyframes: usize,
    revisits: usize,
    /// Per k: revisits with a true candidate in Scan Context's top k.
    scan_context: Vec<usize>,
    /// … in the spectrum's top k, yaw from Scan Context's column shift.
    spectrum_yaw_by_scan_context: Vec<usize>,
    /// … in the spectrum's top k, yaw from the spectrum's polar correlation.
    spectrum_yaw_by_polar: Vec<usize>,
    /// … in the union of both top-k lists (≤ 2k candidates), each with its own list's yaw.
    fused: Vec<usize>,
    /// … in the top k of one list ranked by reciprocal-rank fusion of both (Cormack et al.
    /// 2009, constant 60), the spectrum's candidates with Scan Context's yaw.
    fused_by_rank: Vec<usize>,
    /// Per k: the union's top k holds a keyframe within the verifier's reach of the query
    /// (within `window_linear_m` and the view overlap, yaw guess within `window_angular_rad`):
    /// a candidate from which verification can find the true pose.
    fused_within_reach: Vec<usize>,
    /// Mean ms per query: describing with the spectrum, and its brute-force top-k.
    spectrum_describe_ms: f64,
    spectrum_query_ms: f64,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let usage = "usage: retrieval_study LOG [--config JSON] [--spectrum JSON]";
    let mut log: Option<PathBuf> = None;
    let mut config = BenchConfig::default();
    let mut spectrum_params: Option<RingSpectrumParams> = None;
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--config" => config = serde_json::from_str(&args.next().ok_or(usage)?)?,
            "--spectrum" => {
                spectrum_params = Some(serde_json::from_str(&args.next().ok_or(usage)?)?)
            }
            _ if log.is_none() && !arg.starts_with("--") => log = Some(arg.into()),
            _ => return Err(usage.into()),
        }
    }
    let path = log.ok_or(usage)?;
    let (keyframes, fov_rad) = place_eval::carmen_keyframes(&path, &config)?;
    let name = path.file_name().map_or_else(String::new, |n| {
        n.to_string_lossy().replace("-corrected.log.xz", "")
    });
    let revisit_rad = (1.0 - config.revisit_min_overlap) * fov_rad;
    // The spectrum of the benchmark's configuration unless `--spectrum` says otherwise.
    let spectrum = RingSpectrumDescriptor::new(
        &spectrum_params
            .or_else(|| config.place.appearance.clone())
            .unwrap_or_default(),
    );
    // What describes a keyframe: its local map or its scan, as the benchmark does.
    let described = |k: &place_eval::BenchKeyframe| -> Vec<mapmerge_scan::Point2> {
        if config.describe_local_map {
            k.keyframe.points_in_keyframe.to_vec()
        } else {
            k.scan_points.clone()
        }
    };
    let contexts: Vec<ScanContext> = keyframes
        .par_iter()
        .map(|k| ScanContext::new(&described(k), &config.place.descriptor))
        .collect();
    let started = Instant::now();
    let rows: Vec<Vec<f32>> = keyframes
        .par_iter()
        .map(|k| spectrum.describe(&described(k)))
        .collect();
    let describe_ms = 1e3 * started.elapsed().as_secs_f64() * rayon::current_num_threads() as f64
        / keyframes.len().max(1) as f64;
    let kmax = *KS.last().unwrap_or(&20);
    let yaw_ok = |truth_rad: f64, yaw_rad: f64| {
        wrap_angle_rad(yaw_rad - truth_rad).abs() <= 20f64.to_radians()
    };
    let mut study = Study {
        name,
        keyframes: keyframes.len(),
        scan_context: vec![0; KS.len()],
        spectrum_yaw_by_scan_context: vec![0; KS.len()],
        spectrum_yaw_by_polar: vec![0; KS.len()],
        fused: vec![0; KS.len()],
        fused_by_rank: vec![0; KS.len()],
        fused_within_reach: vec![0; KS.len()],
        spectrum_describe_ms: describe_ms,
        ..Study::default()
    };
    let mut index: PlaceIndex = PlaceIndex::new(config.place.index.clone());
    let mut query_secs = 0.0;
    for (q, query) in keyframes.iter().enumerate() {
        let visible =
            keyframes.partition_point(|k| k.path_m <= query.path_m - config.min_path_gap_m);
        while index.len() < visible {
            let next = index.len();
            index.insert(keyframes[next].keyframe.id, contexts[next].clone());
        }
        if visible == 0 {
            continue;
        }
        let world_from_query = query.world_from_keyframe;
        let truth_of = |ordinal: usize| {
            keyframes[ordinal]
                .world_from_keyframe
                .between(&world_from_query)
        };
        let is_revisit = |ordinal: usize| {
            let t = truth_of(ordinal);
            t.translation().norm() <= config.revisit_m && t.theta_rad.abs() <= revisit_rad
        };
        if !(0..visible).any(is_revisit) {
            continue;
        }
        study.revisits += 1;
        // Scan Context's list: rank of the first true candidate.
        let sc_list = index.query(&contexts[q], kmax);
        let sc_rank = sc_list.iter().position(|c| {
            let ordinal = c.keyframe.0 as usize;
            is_revisit(ordinal) && yaw_ok(truth_of(ordinal).theta_rad, c.yaw_rad)
        });
        // The spectrum's list, brute force.
        let t = Instant::now();
        let mut ranked: Vec<(f32, usize)> = (0..visible)
            .map(|o| (cosine_distance(&rows[q], &rows[o]), o))
            .collect();
        let top = kmax.min(ranked.len());
        ranked.select_nth_unstable_by(top - 1, |a, b| a.0.total_cmp(&b.0));
        ranked.truncate(top);
        ranked.sort_by(|a, b| a.0.total_cmp(&b.0));
        query_secs += t.elapsed().as_secs_f64();
        let rank_by = |yaw: &dyn Fn(usize) -> Option<f64>| {
            ranked.iter().position(|&(_, o)| {
                is_revisit(o) && yaw(o).is_some_and(|y| yaw_ok(truth_of(o).theta_rad, y))
            })
        };
        let by_context = rank_by(&|o| Some(contexts[q].compare(&contexts[o]).yaw_rad));
        let reachable = |o: usize, yaw_rad: f64| {
            let t = truth_of(o);
            t.translation().norm() <= config.window_linear_m
                && t.theta_rad.abs() <= revisit_rad
                && wrap_angle_rad(yaw_rad - t.theta_rad).abs() <= config.window_angular_rad
        };
        let reach_sc = sc_list
            .iter()
            .position(|c| reachable(c.keyframe.0 as usize, c.yaw_rad));
        let reach_spectrum = ranked
            .iter()
            .position(|&(_, o)| reachable(o, contexts[q].compare(&contexts[o]).yaw_rad));
        let by_polar = rank_by(&|o| {
            spectrum
                .relative_yaw(&described(query), &described(&keyframes[o]))
                .map(|y| y.yaw_rad)
        });
        // Reciprocal-rank fusion: score Σ 1 / (60 + rank) over the lists holding a keyframe.
        let mut fusion: std::collections::BTreeMap<usize, f64> = Default::default();
        for (rank, c) in sc_list.iter().enumerate() {
            *fusion.entry(c.keyframe.0 as usize).or_default() += 1.0 / (60.0 + rank as f64);
        }
        for (rank, &(_, o)) in ranked.iter().enumerate() {
            *fusion.entry(o).or_default() += 1.0 / (60.0 + rank as f64);
        }
        let mut fused: Vec<(f64, usize)> = fusion.into_iter().map(|(o, s)| (s, o)).collect();
        fused.sort_by(|a, b| b.0.total_cmp(&a.0));
        let fused_rank = fused.iter().position(|&(_, o)| {
            is_revisit(o)
                && yaw_ok(
                    truth_of(o).theta_rad,
                    contexts[q].compare(&contexts[o]).yaw_rad,
                )
        });
        for (i, &k) in KS.iter().enumerate() {
            study.fused_by_rank[i] += usize::from(fused_rank.is_some_and(|r| r < k));
            let within = |r: Option<usize>| r.is_some_and(|r| r < k);
            study.scan_context[i] += usize::from(within(sc_rank));
            study.spectrum_yaw_by_scan_context[i] += usize::from(within(by_context));
            study.spectrum_yaw_by_polar[i] += usize::from(within(by_polar));
            study.fused[i] += usize::from(within(sc_rank) || within(by_context));
            study.fused_within_reach[i] += usize::from(within(reach_sc) || within(reach_spectrum));
        }
    }
    study.spectrum_query_ms = 1e3 * query_secs / study.revisits.max(1) as f64;
    println!("{}", serde_json::to_string(&study)?);
    Ok(())
}

//! Retrieval alone: how often a true revisit comes back among the top k of Scan Context, of the
//! ring spectrum (`RingSpectrumDescriptor`, translation-invariant), and of both lists fused, on
//! the same keyframes as `place_benchmark` (its `support/place_eval.rs` defines keyframes,
//! local maps and revisits). No verification: this measures the ceiling retrieval puts on
//! recall.
//!
//! ```sh
//! cargo run --release -p mapmerge-lab --example retrieval_study -- LOG-corrected.log.xz \
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
    DescriptorExtractor, PlaceIndex, PlaceParams, PlaceSignature, RingSpectrumDescriptor,
    RingSpectrumParams, SignatureExtractor, SubmapDescriptor,
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
    /// Mean ms per keyframe: describing it (Scan Context and spectrum), and retrieving both
    /// lists from the index (the spectrum's by brute force).
    describe_ms: f64,
    query_ms: f64,
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
    // The benchmark's place parameters, with `--spectrum` in place of its appearance.
    let place = PlaceParams {
        appearance: Some(
            spectrum_params
                .or_else(|| config.place.appearance.clone())
                .unwrap_or_default(),
        ),
        ..config.place.clone()
    };
    let spectrum =
        RingSpectrumDescriptor::new(place.appearance.as_ref().unwrap_or(&Default::default()));
    let extractor = SignatureExtractor::new(&place);
    // What describes a keyframe: its local map or its scan, as the benchmark does.
    let described = |k: &place_eval::BenchKeyframe| -> Vec<mapmerge_scan::Point2> {
        if config.describe_local_map {
            k.keyframe.points_in_keyframe.to_vec()
        } else {
            k.scan_points.clone()
        }
    };
    let started = Instant::now();
    let signatures: Vec<PlaceSignature> = keyframes
        .par_iter()
        .map(|k| extractor.describe(&described(k)))
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
        describe_ms,
        ..Study::default()
    };
    let mut index: PlaceIndex<PlaceSignature> = PlaceIndex::new(place.index.clone());
    let mut query_secs = 0.0;
    for (q, query) in keyframes.iter().enumerate() {
        let visible =
            keyframes.partition_point(|k| k.path_m <= query.path_m - config.min_path_gap_m);
        while index.len() < visible {
            let next = index.len();
            index.insert(keyframes[next].keyframe.id, signatures[next].clone());
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
        // Both lists of the production index (ids are ordinals here), each with Scan
        // Context's yaw.
        let t = Instant::now();
        let (sc_list, spectrum_list) =
            index.query_lists_filtered(&signatures[q], kmax, |_, _| true);
        query_secs += t.elapsed().as_secs_f64();
        let ordinal = |c: &mapmerge_place::Candidate| c.keyframe.0 as usize;
        let rank_in =
            |list: &[mapmerge_place::Candidate],
             yaw: &dyn Fn(&mapmerge_place::Candidate) -> Option<f64>| {
                list.iter().position(|c| {
                    is_revisit(ordinal(c))
                        && yaw(c).is_some_and(|y| yaw_ok(truth_of(ordinal(c)).theta_rad, y))
                })
            };
        let sc_rank = rank_in(&sc_list, &|c| Some(c.yaw_rad));
        let by_context = rank_in(&spectrum_list, &|c| Some(c.yaw_rad));
        let by_polar = rank_in(&spectrum_list, &|c| {
            spectrum
                .relative_yaw(&described(query), &described(&keyframes[ordinal(c)]))
                .map(|y| y.yaw_rad)
        });
        let reachable = |c: &mapmerge_place::Candidate| {
            let t = truth_of(ordinal(c));
            t.translation().norm() <= config.window_linear_m
                && t.theta_rad.abs() <= revisit_rad
                && wrap_angle_rad(c.yaw_rad - t.theta_rad).abs() <= config.window_angular_rad
        };
        let reach_sc = sc_list.iter().position(reachable);
        let reach_spectrum = spectrum_list.iter().position(reachable);
        // Reciprocal-rank fusion: score Σ 1 / (60 + rank) over the lists holding a keyframe.
        let mut fusion: std::collections::BTreeMap<usize, (f64, f64)> = Default::default();
        for list in [&sc_list, &spectrum_list] {
            for (rank, c) in list.iter().enumerate() {
                fusion.entry(ordinal(c)).or_insert((0.0, c.yaw_rad)).0 +=
                    1.0 / (60.0 + rank as f64);
            }
        }
        let mut fused: Vec<(f64, usize, f64)> = fusion
            .into_iter()
            .map(|(o, (s, yaw))| (s, o, yaw))
            .collect();
        fused.sort_by(|a, b| b.0.total_cmp(&a.0));
        let fused_rank = fused
            .iter()
            .position(|&(_, o, yaw)| is_revisit(o) && yaw_ok(truth_of(o).theta_rad, yaw));
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
    study.query_ms = 1e3 * query_secs / study.revisits.max(1) as f64;
    println!("{}", serde_json::to_string(&study)?);
    Ok(())
}

//! `mapmerge eval assemble --split DIR`: scores the assembly of segments made by `mapmerge
//! split` against the ground truth it kept apart (`DIR/truth/STEM.tum`: every scan's true pose
//! in the original log's frame). The assembly never sees the truth.
//!
//! - **Loop edges**: an edge is true when `truth(from)⁻¹ · truth(to)` is within 0.5 m and 10°
//!   of its transform; precision = true / all.
//! - **Overlapping pairs** (the truth's): two segments overlap when at least `--min-overlap`
//!   metres of one's path (sampled every 0.5 m) pass within 1 m of the other's, or when a true
//!   edge joins them. Pair recall = overlapping pairs with at least one true edge /
//!   overlapping pairs; edge coverage = the fraction of the path-overlap samples within 2 m of
//!   travel of a true edge's scan; false pairs = pairs with at least one false edge.
//! - **Groups**: the truth's groups are the connected components of the overlapping pairs;
//!   the assembly is correct when its groups are exactly those.
//! - **Trajectory error**: per assembled group, every scan's pose against the truth after one
//!   rigid alignment (ATE RMS).
//! - **Order invariance**: the segments arrive again in `--orders` random orders (seeds 1…N);
//!   each pair's association is reused from the first run (it depends on the two segments
//!   only), the incremental grouping is redone arrival by arrival; an order passes when its
//!   final groups equal the given order's.
//! - **Pools** (`--split` given more than once): the segments of every folder go into one
//!   assembly. The folders are cut from different logs, so any edge between segments of two
//!   folders is false by construction, and so is any group that mixes folders; the truth's
//!   overlapping pairs and groups are those of each folder. `--arrival-seed` shuffles the
//!   measured run's arrivals (the replays of the invariance test shuffle anyway).

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use mapmerge_assemble::{solve_group, Assembler, Segment, SegmentLoop};
use mapmerge_eval::absolute_trajectory_error;
use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use serde::Serialize;

use crate::{bad_file, bad_input, print_json, progress_bar};
use mapmerge_jobs::cli::{
    load_assemble_params as load_params, load_segments_with_progress as load_segments,
};
use mapmerge_jobs::{arrival_order, segment_name, LoadedSegment, Order, TrajectorySource};

/// A loop edge is true within this (m, deg) of the truth.
const TRUE_EDGE: (f64, f64) = (0.5, 10.0);
/// Overlap: path samples every this (m) …
const OVERLAP_SAMPLE_M: f64 = 0.5;
/// … within this (m) of the other path.
const OVERLAP_RADIUS_M: f64 = 1.0;
/// A true edge covers overlap samples within this travel (m) of its scan.
const COVERAGE_TRAVEL_M: f64 = 2.0;

#[derive(Args, Debug)]
pub struct AssembleEvalArgs {
    /// A folder written by `mapmerge split` (segment logs + `truth/`). Give it once per log
    /// to pool the segments of several logs in one assembly.
    #[arg(long, required = true)]
    pub split: Vec<PathBuf>,
    /// The measured run takes the segments in a random order with this seed (default: the
    /// folders in the order given, each folder's segments by name).
    #[arg(long)]
    pub arrival_seed: Option<u64>,
    /// Random arrival orders for the invariance test.
    #[arg(long, default_value_t = 20)]
    pub orders: u64,
    /// Two segments overlap from this much shared path (m).
    #[arg(long, default_value_t = 3.0)]
    pub min_overlap: f64,
    /// Trajectory of each segment.
    #[arg(long, value_enum, default_value = "slam")]
    pub trajectory: TrajectorySource,
    /// Parameters (JSON, `mapmerge_assemble::AssembleParams`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Write the assembly's loop edges with their verdicts here (JSON lines).
    #[arg(long)]
    pub edges: Option<PathBuf>,
    /// Write every pair's association counts here (JSON lines, `PairAssociation` without
    /// its edges).
    #[arg(long)]
    pub pairs: Option<PathBuf>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct EdgeVerdict<'a> {
    #[serde(flatten)]
    edge: &'a SegmentLoop,
    /// Between segments of two different pooled folders: false by construction.
    cross_log: bool,
    /// `null` for a cross-log edge.
    translation_error_m: f64,
    rotation_error_deg: f64,
    correct: bool,
}

/// The scores of one assembly of the segments of one or more split folders.
#[derive(Clone, Debug, Serialize)]
pub struct AssembleScore {
    pub splits: Vec<PathBuf>,
    pub segments: usize,
    pub scans: usize,
    pub loop_edges: usize,
    pub true_edges: usize,
    pub precision: Option<f64>,
    pub overlapping_pairs: usize,
    pub pairs_found: usize,
    pub pair_recall: Option<f64>,
    pub edge_coverage: Option<f64>,
    pub false_pairs: usize,
    /// Loop edges between segments of two different folders (false by construction).
    pub cross_log_edges: usize,
    /// Assembled groups holding segments of more than one folder.
    pub mixed_groups: usize,
    /// Per folder: its edges (between two of its own segments) and its overlapping pairs.
    pub per_split: Vec<SplitScore>,
    pub truth_groups: Vec<Vec<String>>,
    pub groups: Vec<Vec<String>>,
    pub groups_correct: bool,
    /// ATE RMS (m) per assembled group of two or more segments.
    pub group_ate_m: Vec<f64>,
    pub orders_tested: u64,
    pub orders_same: u64,
    pub trajectory_secs: f64,
    pub association_secs: f64,
    pub optimisation_secs: f64,
    /// The replays of the order-invariance test (pairs reused; grouping and consistency
    /// checks redone arrival by arrival).
    pub order_invariance_secs: f64,
}

/// One folder's share of a pooled assembly.
#[derive(Clone, Debug, Serialize)]
pub struct SplitScore {
    pub split: PathBuf,
    pub segments: usize,
    pub loop_edges: usize,
    pub true_edges: usize,
    pub overlapping_pairs: usize,
    pub pairs_found: usize,
    /// Edges from this folder's segments to another folder's (an edge between two folders
    /// counts in both).
    pub cross_log_edges: usize,
}

/// Path samples every `OVERLAP_SAMPLE_M` of travel: (scan, travel m, position).
fn path_samples(truth: &[Se2]) -> Vec<(usize, f64, nalgebra::Vector2<f64>)> {
    let mut samples = Vec::new();
    let mut last_sample = f64::NEG_INFINITY;
    for (k, travel) in travel_of(truth).into_iter().enumerate() {
        if travel - last_sample >= OVERLAP_SAMPLE_M {
            samples.push((k, travel, truth[k].translation()));
            last_sample = travel;
        }
    }
    samples
}

fn travel_of(truth: &[Se2]) -> Vec<f64> {
    let mut travel = Vec::with_capacity(truth.len());
    let mut total = 0.0;
    for (k, pose) in truth.iter().enumerate() {
        if k > 0 {
            total += (pose.translation() - truth[k - 1].translation()).norm();
        }
        travel.push(total);
    }
    travel
}

/// Connected components of `names` under `edges`, canonical (sorted, by first name).
fn components(names: &[String], edges: &BTreeSet<(String, String)>) -> Vec<Vec<String>> {
    let mut parent: BTreeMap<&str, &str> = names.iter().map(|n| (n.as_str(), n.as_str())).collect();
    fn root<'a>(parent: &BTreeMap<&'a str, &'a str>, mut x: &'a str) -> &'a str {
        while let Some(&p) = parent.get(x) {
            if p == x {
                break;
            }
            x = p;
        }
        x
    }
    for (a, b) in edges {
        let (ra, rb) = (root(&parent, a), root(&parent, b));
        if ra != rb {
            let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
            parent.insert(hi, lo);
        }
    }
    let mut groups: BTreeMap<&str, Vec<String>> = BTreeMap::new();
    for n in names {
        groups.entry(root(&parent, n)).or_default().push(n.clone());
    }
    let mut out: Vec<Vec<String>> = groups.into_values().collect();
    for g in &mut out {
        g.sort();
    }
    out.sort();
    out
}

pub fn run(args: &AssembleEvalArgs) -> anyhow::Result<()> {
    let score = evaluate(args)?;
    if args.json {
        print_json(&score)
    } else {
        println!(
            "{}: {} segments, {} loop edges ({} true, precision {}), pair recall {} ({} of {} overlapping pairs), coverage {}, {} false pairs, {} edges between logs, {} groups mixing logs; groups {} (truth {:?}, assembled {:?}); ATE per group {:?} m; order invariance {}/{}",
            args.split
                .iter()
                .map(|s| s.display().to_string())
                .collect::<Vec<_>>()
                .join(" + "),
            score.segments,
            score.loop_edges,
            score.true_edges,
            fmt_ratio(score.precision),
            fmt_ratio(score.pair_recall),
            score.pairs_found,
            score.overlapping_pairs,
            fmt_ratio(score.edge_coverage),
            score.false_pairs,
            score.cross_log_edges,
            score.mixed_groups,
            if score.groups_correct { "correct" } else { "WRONG" },
            score.truth_groups,
            score.groups,
            score.group_ate_m,
            score.orders_same,
            score.orders_tested
        );
        Ok(())
    }
}

fn fmt_ratio(r: Option<f64>) -> String {
    r.map_or_else(|| "–".into(), |r| format!("{:.1} %", 100.0 * r))
}

/// The segment logs of one split folder, sorted.
fn split_segment_paths(split: &std::path::Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(split)
        .with_context(|| format!("reading {}", split.display()))
        .map_err(|e| bad_input(format!("{e:#}")))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_file()
                && p.file_name().is_some_and(|n| {
                    n.to_string_lossy().ends_with(".log")
                        || n.to_string_lossy().ends_with(".log.xz")
                })
        })
        .collect();
    paths.sort();
    if paths.is_empty() {
        return Err(bad_input(format!(
            "{}: no segment logs (write them with `mapmerge split`)",
            split.display()
        )));
    }
    Ok(paths)
}

/// Runs the assembly on the segments of `args.split` (one folder, or a pool of several) and
/// scores it.
pub fn evaluate(args: &AssembleEvalArgs) -> anyhow::Result<AssembleScore> {
    // Every segment, the folder it came from, and its truth, kept apart from the assembly.
    let mut paths: Vec<PathBuf> = Vec::new();
    let mut split_of: BTreeMap<String, usize> = BTreeMap::new();
    let mut truth: BTreeMap<String, Vec<Se2>> = BTreeMap::new();
    for (index, split) in args.split.iter().enumerate() {
        for path in split_segment_paths(split)? {
            let name = segment_name(&path);
            if split_of.insert(name.clone(), index).is_some() {
                return Err(bad_input(format!(
                    "{}: a segment named `{name}` is in two of the pooled folders (split \
                     different logs)",
                    path.display()
                )));
            }
            let file = split.join("truth").join(format!("{name}.tum"));
            let poses: Vec<Se2> = mapmerge_io::read_tum_planar(&file)
                .map_err(bad_file)?
                .into_iter()
                .map(|(_, p)| p)
                .collect();
            truth.insert(name, poses);
            paths.push(path);
        }
    }
    let same_split = |a: &str, b: &str| split_of.get(a).is_some_and(|i| split_of.get(b) == Some(i));
    let params = load_params(args.config.as_deref(), false)?;
    let started = Instant::now();
    let loaded = load_segments(
        &paths,
        &crate::BagTopics::default(),
        args.trajectory,
        !args.json,
    )?;
    let trajectory_secs = started.elapsed().as_secs_f64();
    for segment in loaded.iter().filter_map(|s| match s {
        LoadedSegment::Planar(segment) => Some(segment),
        LoadedSegment::Spatial(_) => None,
    }) {
        let t = truth.get(&segment.name).map_or(0, Vec::len);
        if t != segment.poses.len() {
            return Err(bad_input(format!(
                "{}: truth has {t} poses for {} scans",
                segment.name,
                segment.poses.len()
            )));
        }
    }
    let segments: Vec<Segment> = loaded
        .into_iter()
        .filter_map(|s| match s {
            LoadedSegment::Planar(segment) => Some(segment),
            LoadedSegment::Spatial(_) => None,
        })
        .collect();
    let names: Vec<String> = segments.iter().map(|s| s.name.clone()).collect();
    // The assembly in the given (sorted) order.
    let started = Instant::now();
    let mut assembler = Assembler::new(params.clone()).map_err(|e| bad_input(e.to_string()))?;
    let measured_order = match args.arrival_seed {
        Some(seed) => arrival_order(segments.len(), Order::Random, seed),
        None => arrival_order(segments.len(), Order::Given, 0),
    };
    let bar = progress_bar(segments.len(), "segments", "association", !args.json);
    for &i in &measured_order {
        let arrival = assembler.add_segment(segments[i].clone())?;
        bar.inc(1);
        if !args.json {
            bar.println(format!(
                "  {}: connected to [{}] ({:.1} s)",
                arrival.segment,
                arrival.connected.join(", "),
                arrival.association_secs
            ));
        }
    }
    bar.finish_and_clear();
    let association_secs = started.elapsed().as_secs_f64();
    let groups = assembler.groups()?;
    // Loop edges against the truth.
    let mut verdicts = Vec::new();
    let mut true_pairs: BTreeSet<(String, String)> = BTreeSet::new();
    let mut found_pairs: BTreeSet<(String, String)> = BTreeSet::new();
    let mut true_edge_scans: BTreeMap<(String, String), Vec<usize>> = BTreeMap::new();
    for l in assembler.loops() {
        let (Some(tf), Some(tt)) = (
            truth.get(&l.from_segment).and_then(|t| t.get(l.from_scan)),
            truth.get(&l.to_segment).and_then(|t| t.get(l.to_scan)),
        ) else {
            continue;
        };
        // Two folders' truths are in unrelated frames: an edge between them has no error,
        // only the verdict false.
        let cross_log = !same_split(&l.from_segment, &l.to_segment);
        let (dt, dr) = if cross_log {
            (f64::NAN, f64::NAN)
        } else {
            let error = tf.between(tt).between(&l.from_from_to);
            (
                error.translation().norm(),
                wrap_angle_rad(error.theta_rad).abs().to_degrees(),
            )
        };
        let correct = !cross_log && dt <= TRUE_EDGE.0 && dr <= TRUE_EDGE.1;
        let pair = (l.from_segment.clone(), l.to_segment.clone());
        found_pairs.insert(pair.clone());
        if correct {
            true_pairs.insert(pair.clone());
            true_edge_scans
                .entry(pair.clone())
                .or_default()
                .push(l.from_scan);
            true_edge_scans
                .entry((pair.1, pair.0))
                .or_default()
                .push(l.to_scan);
        }
        verdicts.push(EdgeVerdict {
            edge: l,
            cross_log,
            translation_error_m: dt,
            rotation_error_deg: dr,
            correct,
        });
    }
    if let Some(path) = &args.edges {
        let mut text = String::new();
        for v in &verdicts {
            text.push_str(&serde_json::to_string(v)?);
            text.push('\n');
        }
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &args.pairs {
        let mut text = String::new();
        for (key, pair) in assembler.pairs() {
            let mut value = serde_json::to_value(pair)?;
            if let Some(object) = value.as_object_mut() {
                object.remove("loops");
                object.insert(
                    "rejected".into(),
                    assembler.rejected_pairs().contains(key).into(),
                );
            }
            text.push_str(&serde_json::to_string(&value)?);
            text.push('\n');
        }
        std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    // The truth's overlapping pairs, and how much of each overlap the true edges cover.
    let samples: BTreeMap<&String, _> = truth.iter().map(|(n, t)| (n, path_samples(t))).collect();
    let travel: BTreeMap<&String, Vec<f64>> =
        truth.iter().map(|(n, t)| (n, travel_of(t))).collect();
    let mut overlapping: BTreeSet<(String, String)> = BTreeSet::new();
    let (mut covered, mut overlap_samples) = (0usize, 0usize);
    for (i, a) in names.iter().enumerate() {
        for b in names.iter().skip(i + 1).filter(|b| same_split(a, b)) {
            let (sa, sb) = (&samples[a], &samples[b]);
            let near = |s: &(usize, f64, nalgebra::Vector2<f64>),
                        others: &[(usize, f64, nalgebra::Vector2<f64>)]| {
                others
                    .iter()
                    .any(|o| (o.2 - s.2).norm() <= OVERLAP_RADIUS_M)
            };
            let in_a: Vec<_> = sa.iter().filter(|s| near(s, sb)).collect();
            // Shared path: travel between consecutive samples that are both near the other.
            let shared_m: f64 = sa
                .windows(2)
                .filter(|w| near(&w[0], sb) && near(&w[1], sb))
                .map(|w| w[1].1 - w[0].1)
                .sum();
            if shared_m < args.min_overlap {
                continue;
            }
            overlapping.insert((a.clone(), b.clone()));
            let in_b: Vec<_> = sb.iter().filter(|s| near(s, sa)).collect();
            for (side, other, these) in [(a, b, &in_a), (b, a, &in_b)] {
                let edge_travel: Vec<f64> = true_edge_scans
                    .get(&(side.clone(), other.clone()))
                    .map(|scans| {
                        scans
                            .iter()
                            .filter_map(|&k| travel[side].get(k).copied())
                            .collect()
                    })
                    .unwrap_or_default();
                overlap_samples += these.len();
                covered += these
                    .iter()
                    .filter(|s| {
                        edge_travel
                            .iter()
                            .any(|t| (t - s.1).abs() <= COVERAGE_TRAVEL_M)
                    })
                    .count();
            }
        }
    }
    // A pair joined by a true edge overlaps, whatever the path rule says (a short overlap
    // seen from afar).
    overlapping.extend(true_pairs.iter().cloned());
    let pairs_found = overlapping
        .iter()
        .filter(|p| true_pairs.contains(*p))
        .count();
    let false_pairs = verdicts
        .iter()
        .filter(|v| !v.correct)
        .map(|v| (&v.edge.from_segment, &v.edge.to_segment))
        .collect::<BTreeSet<_>>()
        .len();
    let truth_groups = components(&names, &overlapping);
    let split_count = |group: &[String]| {
        group
            .iter()
            .filter_map(|n| split_of.get(n))
            .collect::<BTreeSet<_>>()
            .len()
    };
    let mixed_groups = groups.iter().filter(|g| split_count(g) > 1).count();
    let per_split: Vec<SplitScore> = args
        .split
        .iter()
        .enumerate()
        .map(|(index, split)| {
            let of_split = |name: &String| split_of.get(name) == Some(&index);
            let own: Vec<&EdgeVerdict> = verdicts
                .iter()
                .filter(|v| of_split(&v.edge.from_segment) && of_split(&v.edge.to_segment))
                .collect();
            let pairs: Vec<&(String, String)> =
                overlapping.iter().filter(|(a, _)| of_split(a)).collect();
            SplitScore {
                split: split.clone(),
                segments: names.iter().filter(|n| of_split(n)).count(),
                loop_edges: own.len(),
                true_edges: own.iter().filter(|v| v.correct).count(),
                overlapping_pairs: pairs.len(),
                pairs_found: pairs.iter().filter(|p| true_pairs.contains(**p)).count(),
                cross_log_edges: verdicts
                    .iter()
                    .filter(|v| {
                        v.cross_log
                            && (of_split(&v.edge.from_segment) || of_split(&v.edge.to_segment))
                    })
                    .count(),
            }
        })
        .collect();
    // One graph per group; its error after alignment.
    let started = Instant::now();
    let mut group_ate_m = Vec::new();
    for group in groups.iter().filter(|g| g.len() > 1) {
        let solution = solve_group(&assembler, group, &assembler.params().graph)?;
        let (mut reference, mut estimate) = (Vec::new(), Vec::new());
        for (name, poses) in &solution.scan_poses {
            if let Some(t) = truth.get(name) {
                reference.extend_from_slice(t);
                estimate.extend_from_slice(poses);
            }
        }
        let ate = absolute_trajectory_error(&reference, &estimate, true)
            .map_err(|e| anyhow::anyhow!("trajectory error: {e}"))?;
        group_ate_m.push(ate.rms_m);
    }
    let optimisation_secs = started.elapsed().as_secs_f64();
    // Order invariance: replay arrivals, pairs reused.
    let started = Instant::now();
    let known = assembler.pairs().clone();
    let mut orders_same = 0;
    let bar = progress_bar(
        usize::try_from(args.orders).unwrap_or(usize::MAX),
        "orders",
        "order invariance",
        !args.json,
    );
    for seed in 1..=args.orders {
        let mut replay = Assembler::new(params.clone()).map_err(|e| bad_input(e.to_string()))?;
        for i in arrival_order(segments.len(), Order::Random, seed) {
            replay.add_segment_reusing(segments[i].clone(), &known)?;
        }
        if replay.groups()? == groups {
            orders_same += 1;
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let order_invariance_secs = started.elapsed().as_secs_f64();
    let ratio = |n: usize, d: usize| (d > 0).then(|| n as f64 / d as f64);
    Ok(AssembleScore {
        splits: args.split.clone(),
        segments: names.len(),
        scans: segments.iter().map(|s| s.poses.len()).sum(),
        loop_edges: verdicts.len(),
        true_edges: verdicts.iter().filter(|v| v.correct).count(),
        precision: ratio(
            verdicts.iter().filter(|v| v.correct).count(),
            verdicts.len(),
        ),
        overlapping_pairs: overlapping.len(),
        pairs_found,
        pair_recall: ratio(pairs_found, overlapping.len()),
        edge_coverage: ratio(covered, overlap_samples),
        false_pairs,
        cross_log_edges: verdicts.iter().filter(|v| v.cross_log).count(),
        mixed_groups,
        per_split,
        groups_correct: truth_groups == groups,
        truth_groups,
        groups,
        group_ate_m,
        orders_tested: args.orders,
        orders_same,
        trajectory_secs,
        association_secs,
        optimisation_secs,
        order_invariance_secs,
    })
}

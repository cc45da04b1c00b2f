//! `mapmerge eval protrusions`: the erroneous-protrusion detector (iRobot Sec. 5.4) on
//! simulated sessions, trained on tuning seeds and scored on held-out seeds.
//!
//! Per world and seed, a robot lives a few sessions (`simulate_session_alone` 0, 1, …) through
//! the engine, each ended by maintenance. For each session that joined the previous one's
//! map, the parent map is the atlas before it and the child the atlas after it. Then
//! undetected wheel slips are injected: everything the session mapped after a random local
//! map is moved by a random rigid error about that map's anchor (0.2–1.0 m, 5–25°), as when
//! the tracker follows a slipped odometry. A cell of new space is wrong where the world has
//! no free space (outside the building or inside an obstacle) or, in a slipped child, where
//! the child without the slip is not free; a region is a protrusion when most of its cells
//! are wrong, new space otherwise.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use mapmerge_atlas::{
    new_regions, AtlasSnapshot, FeatureSet, LabelledRegion, ProtrusionClassifier, ProtrusionParams,
    RegionFeatures, DEFAULT_DEPTH, DEFAULT_MIN_LEAF,
};
use mapmerge_engine::{Engine, EngineParams};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::NodeId;
use mapmerge_sim::{simulate_session_alone, SimParams};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::{bad_input, print_json};

/// Arguments of `mapmerge eval protrusions`.
#[derive(Args, Debug)]
pub struct ProtrusionEvalArgs {
    /// World presets.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "office,warehouse,corridor-loop"
    )]
    pub worlds: Vec<String>,
    /// Tuning seeds the classifier is trained on (`A-B` or a comma list).
    #[arg(long, default_value = "1-8")]
    pub train_seeds: String,
    /// Held-out seeds it is scored on.
    #[arg(long, default_value = "101-110")]
    pub test_seeds: String,
    /// Slips injected per world and seed.
    #[arg(long, default_value_t = 4)]
    pub slips: usize,
    /// Robot time per session (s).
    #[arg(long, default_value_t = 90.0)]
    pub duration: f64,
    /// Sessions lived per world and seed (each consecutive pair whose later session joined
    /// the earlier's map is a parent and a child).
    #[arg(long, default_value_t = 4)]
    pub sessions: usize,
    /// Writes the training regions here (the default classifier's data:
    /// crates/merge/atlas/src/protrusion_training.json).
    #[arg(long)]
    pub write_training: Option<PathBuf>,
    /// Writes every region, tuning and held out, with its label and its source, one JSON
    /// object a line.
    #[arg(long)]
    pub write_regions: Option<PathBuf>,
    /// Keeps the lived sessions of each world and seed here (postcard), and reads them back
    /// on the next run with the same world, seed, duration and sessions. The files are not
    /// keyed by the engine's code: empty the directory after changing the engine or the
    /// simulator (the detector and the labels are computed afresh on every run).
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Precision and recall of the protrusion class.
#[derive(Clone, Copy, Debug, Default, Serialize)]
struct Score {
    regions: usize,
    protrusions: usize,
    true_positives: usize,
    false_positives: usize,
    false_negatives: usize,
    precision: f64,
    recall: f64,
}

impl Score {
    fn of(labels: &[bool], predicted: &[bool]) -> Self {
        let mut s = Self {
            regions: labels.len(),
            protrusions: labels.iter().filter(|l| **l).count(),
            ..Self::default()
        };
        for (label, guess) in labels.iter().zip(predicted) {
            match (label, guess) {
                (true, true) => s.true_positives += 1,
                (false, true) => s.false_positives += 1,
                (true, false) => s.false_negatives += 1,
                (false, false) => {}
            }
        }
        let ratio = |a: usize, b: usize| {
            if b == 0 {
                f64::NAN
            } else {
                a as f64 / b as f64
            }
        };
        s.precision = ratio(s.true_positives, s.true_positives + s.false_positives);
        s.recall = ratio(s.true_positives, s.true_positives + s.false_negatives);
        s
    }
}

/// One region of `--write-regions`.
#[derive(Serialize)]
struct RegionLine {
    held_out: bool,
    /// Fraction of its cells that are wrong (over half: a protrusion).
    wrong_fraction: f64,
    #[serde(flatten)]
    region: LabelledRegion,
}

#[derive(Serialize)]
struct Report {
    worlds: Vec<String>,
    train_seeds: Vec<u64>,
    test_seeds: Vec<u64>,
    /// Seeds skipped because no session joined the previous one's map.
    skipped: Vec<String>,
    train: Score,
    test: Score,
    /// The same tree on the paper's three features alone.
    train_paper_features: Score,
    test_paper_features: Score,
    /// Held-out score per world.
    test_by_world: Vec<(String, Score)>,
    seconds: f64,
}

/// `A-B` or `a,b,c`.
pub(crate) fn seeds(text: &str) -> anyhow::Result<Vec<u64>> {
    let parse = |s: &str| {
        s.trim()
            .parse::<u64>()
            .map_err(|e| bad_input(format!("seed {s:?}: {e}")))
    };
    if let Some((a, b)) = text.split_once('-') {
        Ok((parse(a)?..=parse(b)?).collect())
    } else {
        text.split(',').map(parse).collect()
    }
}

/// One session lived: the atlas after it, its first vertex, the world as it was, and the true
/// pose of every keyframe so far.
struct Lived {
    atlas: AtlasSnapshot,
    first: NodeId,
    world: mapmerge_sim::World,
    truth: BTreeMap<NodeId, Se2>,
}

/// The atlas after each of `sessions` sessions of `world` (seed), each ended by
/// maintenance.
fn lived_sessions(
    world: &str,
    seed: u64,
    duration: f64,
    sessions: usize,
) -> anyhow::Result<Vec<Lived>> {
    let mut params = SimParams::default()
        .with_preset_name(world)
        .map_err(bad_input)?;
    params.duration_secs = duration;
    let mut engine = Engine::new(EngineParams::default()).map_err(bad_input)?;
    let mut lived = Vec::new();
    let mut truth = BTreeMap::new();
    for index in 0..sessions {
        let session = simulate_session_alone(&params, seed, index).map_err(bad_input)?;
        let first = engine.atlas().next_node_id();
        let mut previous = None;
        for (k, record) in session.log.scans.iter().enumerate() {
            let odometry = record
                .odom_from_robot
                .or(previous)
                .unwrap_or_else(Se2::identity);
            previous = Some(odometry);
            let report = engine.add_scan(&odometry, &record.scan, Some(record.stamp_secs))?;
            if let (Some(node), Some((_, pose))) = (report.keyframe, session.truth.get(k)) {
                truth.insert(node, *pose);
            }
        }
        engine.finish()?;
        engine.end_session(first)?;
        lived.push(Lived {
            atlas: engine.atlas().snapshot()?,
            first,
            world: session.world,
            truth: truth.clone(),
        });
    }
    Ok(lived)
}

/// [`lived_sessions`], read from and written to `args.cache` when it is set.
fn cached_lived_sessions(
    world: &str,
    seed: u64,
    args: &ProtrusionEvalArgs,
) -> anyhow::Result<Vec<Lived>> {
    let Some(dir) = &args.cache else {
        return lived_sessions(world, seed, args.duration, args.sessions);
    };
    let path = dir.join(format!(
        "{world}-{seed}-{}s-{}.postcard",
        args.duration, args.sessions
    ));
    // What the detector reads of a version: its graphs and local maps (no keyframes).
    #[derive(Serialize, Deserialize)]
    struct Cached {
        counters: mapmerge_atlas::AtlasCounters,
        active: mapmerge_posegraph::PoseGraph2,
        inactive: BTreeMap<mapmerge_atlas::MapId, mapmerge_posegraph::PoseGraph2>,
        local_maps: BTreeMap<NodeId, mapmerge_atlas::LocalMapGrid>,
        first: NodeId,
        world: mapmerge_sim::World,
        truth: BTreeMap<NodeId, Se2>,
    }
    if let Ok(bytes) = std::fs::read(&path) {
        if let Ok(cached) = postcard::from_bytes::<Vec<Cached>>(&bytes) {
            return Ok(cached
                .into_iter()
                .map(|c| Lived {
                    atlas: AtlasSnapshot {
                        counters: c.counters,
                        active: c.active,
                        inactive: c.inactive,
                        keyframes: BTreeMap::new(),
                        backups: BTreeMap::new(),
                        local_maps: c.local_maps,
                    },
                    first: c.first,
                    world: c.world,
                    truth: c.truth,
                })
                .collect());
        }
    }
    let lived = lived_sessions(world, seed, args.duration, args.sessions)?;
    let cached: Vec<Cached> = lived
        .iter()
        .map(|l| Cached {
            counters: l.atlas.counters.clone(),
            active: l.atlas.active.clone(),
            inactive: l.atlas.inactive.clone(),
            local_maps: l.atlas.local_maps.clone(),
            first: l.first,
            world: l.world.clone(),
            truth: l.truth.clone(),
        })
        .collect();
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    std::fs::write(&path, postcard::to_stdvec(&cached)?)
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(lived)
}

/// `world_from_map` of a version's site graph: the rigid transform that best aligns its
/// vertices with their true poses.
fn world_from_map(atlas: &AtlasSnapshot, truth: &BTreeMap<NodeId, Se2>) -> Option<Se2> {
    let site = atlas.graphs().max_by_key(|g| g.num_vertices())?;
    let mut world = mapmerge_posegraph::PoseGraph2::new();
    for (node, _) in site.vertices() {
        if let Some(pose) = truth.get(&node) {
            world
                .add_vertex(node, mapmerge_posegraph::Vertex::new(*pose))
                .ok()?;
        }
    }
    mapmerge_atlas::align_graphs(site, &world)
}

/// Whether the session from `first` on joined the parent's site map: the child's largest
/// graph holds vertices of both.
fn joined(parent: &AtlasSnapshot, child: &AtlasSnapshot, first: NodeId) -> bool {
    let Some(site) = child.graphs().max_by_key(|g| g.num_vertices()) else {
        return false;
    };
    let Some(parent_site) = parent.graphs().max_by_key(|g| g.num_vertices()) else {
        return false;
    };
    let shared = parent_site
        .vertices()
        .filter(|(n, _)| site.contains_vertex(*n))
        .count();
    shared >= 2 && site.vertices().any(|(n, _)| n >= first)
}

/// `child` with an undetected slip: the session's local maps from the `k`-th on moved by
/// `error` about the `k`-th's anchor. `None` when the session has fewer than two local maps
/// in the site graph.
fn slipped(
    child: &AtlasSnapshot,
    first: NodeId,
    rng: &mut rand_chacha::ChaCha8Rng,
) -> Option<AtlasSnapshot> {
    let mut slipped = child.clone();
    let site = slipped
        .inactive
        .values_mut()
        .max_by_key(|g| g.num_vertices())?;
    let anchors: Vec<NodeId> = child
        .local_maps
        .keys()
        .filter(|a| **a >= first && site.contains_vertex(**a))
        .copied()
        .collect();
    if anchors.len() < 2 {
        return None;
    }
    let k = rng.random_range(0..anchors.len() - 1);
    let pivot = site.vertex(anchors[k])?.pose;
    let distance = rng.random_range(0.2..1.0);
    let direction = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
    let angle =
        rng.random_range(5f64..25.0).to_radians() * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let error = Se2::new(
        distance * direction.cos(),
        distance * direction.sin(),
        angle,
    );
    let about = pivot.compose(&error).compose(&pivot.inverse());
    for anchor in &anchors[k..] {
        if let Some(v) = site.vertex_mut(*anchor) {
            v.pose = about.compose(&v.pose);
        }
    }
    Some(slipped)
}

/// A labelled region and the fraction of its cells that are wrong.
type Labelled = (LabelledRegion, f64);

/// The labelled regions of one world and seed: every consecutive pair of sessions where
/// the later joined the earlier's map; `None` when no session did.
fn regions_of(
    world: &str,
    seed: u64,
    args: &ProtrusionEvalArgs,
) -> anyhow::Result<Option<Vec<Labelled>>> {
    let params = ProtrusionParams::default();
    let lived = cached_lived_sessions(world, seed, args)?;
    let mut labelled = Vec::new();
    let mut pairs = 0;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x05ee_d0f5_11b5);
    for (k, pair) in lived.windows(2).enumerate() {
        let (parent, child) = (&pair[0], &pair[1]);
        if !joined(&parent.atlas, &child.atlas, child.first) {
            continue;
        }
        let Some(world_from_child) = world_from_map(&child.atlas, &child.truth) else {
            continue;
        };
        // The truth: a cell of new space is wrong where the world has no free space (outside
        // the building or inside an obstacle) or, after a slip, where the child without the
        // slip has no free space; a region is a protrusion when most of it is wrong.
        let Some(site) = child.atlas.site_graph() else {
            continue;
        };
        let Some(correct) =
            mapmerge_atlas::RenderedMap::render(site, &child.atlas.local_maps, params.resolution_m)
        else {
            continue;
        };
        let thresholds = mapmerge_grid::ClassThresholds::default();
        let correct_free = |p: &mapmerge_scan::Point2| {
            let g = &correct.geometry;
            g.index_of(g.cell_of(p))
                .and_then(|i| correct.sums.get(i))
                .is_some_and(|l| thresholds.classify(*l) == mapmerge_grid::CellClass::Free)
        };
        let label =
            |map: &mapmerge_atlas::RenderedMap, region: &mapmerge_atlas::Region, slipped: bool| {
                let g = &map.geometry;
                let stride = (region.cells.len() / 400).max(1);
                let (mut sampled, mut wrong) = (0usize, 0usize);
                for &i in region.cells.iter().step_by(stride) {
                    let child_p = g.center_of(g.cell_at(i as usize));
                    let p = world_from_child.transform_point(&child_p);
                    sampled += 1;
                    wrong += usize::from(
                        !child.world.is_inside_building(&p)
                            || child.world.is_inside_obstacle(&p)
                            || (slipped && !correct_free(&child_p)),
                    );
                }
                wrong as f64 / sampled.max(1) as f64
            };
        // The child as mapped (no slip), then its slipped copies (`Some(slip)`).
        let cases = std::iter::once((None, Some(child.atlas.clone()))).chain(
            (0..args.slips)
                .map(|slip| (Some(slip), slipped(&child.atlas, child.first, &mut rng)))
                .collect::<Vec<_>>(),
        );
        let mut any = false;
        for (slip, atlas) in cases {
            let Some(atlas) = atlas else { continue };
            let Some((map, regions)) = new_regions(&parent.atlas, &atlas, &params) else {
                continue;
            };
            any = true;
            let case = slip.map_or_else(|| "correct".to_owned(), |slip| format!("slip{slip}"));
            for region in &regions {
                let wrong_fraction = label(&map, region, slip.is_some());
                labelled.push((
                    LabelledRegion {
                        source: format!("{world}/{seed}/{}/{case}", k + 1),
                        features: region.features,
                        protrusion: wrong_fraction > 0.5,
                    },
                    wrong_fraction,
                ));
            }
        }
        pairs += usize::from(any);
    }
    Ok((pairs > 0).then_some(labelled))
}

/// Runs `mapmerge eval protrusions`.
pub fn run(args: &ProtrusionEvalArgs) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let (train_seeds, test_seeds) = (seeds(&args.train_seeds)?, seeds(&args.test_seeds)?);
    let mut skipped = Vec::new();
    let mut train: Vec<LabelledRegion> = Vec::new();
    let mut test: Vec<(String, LabelledRegion)> = Vec::new();
    let bar = crate::progress_bar(
        args.worlds.len() * (train_seeds.len() + test_seeds.len()),
        "seeds",
        "",
        !args.json && std::io::IsTerminal::is_terminal(&std::io::stderr()),
    );
    let jobs: Vec<(&String, u64, bool)> = args
        .worlds
        .iter()
        .flat_map(|world| {
            train_seeds
                .iter()
                .map(move |s| (world, *s, false))
                .chain(test_seeds.iter().map(move |s| (world, *s, true)))
        })
        .collect();
    let per_job: Vec<anyhow::Result<Option<Vec<Labelled>>>> = jobs
        .par_iter()
        .map(|(world, seed, _)| {
            let regions = regions_of(world, *seed, args);
            bar.inc(1);
            regions
        })
        .collect();
    let mut dump: Vec<RegionLine> = Vec::new();
    for ((world, seed, is_test), regions) in jobs.iter().zip(per_job) {
        match regions? {
            None => skipped.push(format!("{world}/{seed}")),
            Some(regions) => {
                for (region, wrong_fraction) in regions {
                    if args.write_regions.is_some() {
                        dump.push(RegionLine {
                            held_out: *is_test,
                            wrong_fraction,
                            region: region.clone(),
                        });
                    }
                    if *is_test {
                        test.push(((*world).clone(), region));
                    } else {
                        train.push(region);
                    }
                }
            }
        }
    }
    bar.finish_and_clear();
    if let Some(path) = &args.write_regions {
        let lines: Vec<String> = dump
            .iter()
            .map(serde_json::to_string)
            .collect::<Result<_, _>>()?;
        std::fs::write(path, lines.join("\n") + "\n")
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &args.write_training {
        let lines: Vec<String> = train
            .iter()
            .map(serde_json::to_string)
            .collect::<Result<_, _>>()?;
        std::fs::write(path, format!("[\n{}\n]\n", lines.join(",\n")))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let fit = |features| {
        ProtrusionClassifier::fit(&train, features, DEFAULT_DEPTH, DEFAULT_MIN_LEAF)
            .map_err(bad_input)
    };
    let (classifier, paper_only) = (fit(FeatureSet::PaperAndMap)?, fit(FeatureSet::Paper)?);
    let score_with =
        |classifier: &ProtrusionClassifier, regions: &[&LabelledRegion]| -> anyhow::Result<Score> {
            let features: Vec<RegionFeatures> = regions.iter().map(|r| r.features).collect();
            let predicted = classifier.predict(&features).map_err(anyhow::Error::msg)?;
            let labels: Vec<bool> = regions.iter().map(|r| r.protrusion).collect();
            Ok(Score::of(&labels, &predicted))
        };
    let score = |regions: &[&LabelledRegion]| score_with(&classifier, regions);
    let train_score = score(&train.iter().collect::<Vec<_>>())?;
    let test_regions: Vec<&LabelledRegion> = test.iter().map(|(_, r)| r).collect();
    let test_score = score(&test_regions)?;
    let test_paper_only = score_with(&paper_only, &test_regions)?;
    let train_paper_only = score_with(&paper_only, &train.iter().collect::<Vec<_>>())?;
    let mut test_by_world = Vec::new();
    for world in &args.worlds {
        let regions: Vec<&LabelledRegion> = test
            .iter()
            .filter(|(w, _)| w == world)
            .map(|(_, r)| r)
            .collect();
        test_by_world.push((world.clone(), score(&regions)?));
    }
    let report = Report {
        worlds: args.worlds.clone(),
        train_seeds,
        test_seeds,
        skipped,
        train: train_score,
        test: test_score,
        train_paper_features: train_paper_only,
        test_paper_features: test_paper_only,
        test_by_world,
        seconds: started.elapsed().as_secs_f64(),
    };
    if args.json {
        print_json(&report)?;
    } else {
        let line = |name: &str, s: &Score| {
            println!(
                "{name}: {} regions ({} protrusions): precision {:.3}, recall {:.3} (TP {}, FP {}, FN {})",
                s.regions, s.protrusions, s.precision, s.recall, s.true_positives, s.false_positives, s.false_negatives
            )
        };
        line("tuning seeds (in-sample)", &report.train);
        line("held-out seeds", &report.test);
        line(
            "tuning seeds, paper's features only",
            &report.train_paper_features,
        );
        line(
            "held-out seeds, paper's features only",
            &report.test_paper_features,
        );
        for (world, s) in &report.test_by_world {
            line(&format!("  held-out {world}"), s);
        }
        if !report.skipped.is_empty() {
            println!(
                "skipped (no session joined the previous one's map): {:?}",
                report.skipped
            );
        }
    }
    Ok(())
}

//! `mapmerge grid-merge A.yaml B.yaml -o MERGED.yaml`: merge two ROS map_server maps of any
//! resolution without an initial guess (Andersone's framework: decision table, Carpin's
//! matching, quality-weighted Bayes fusion into A's frame and resolution).
//!
//! Exit codes: 0 merged, 3 no acceptable hypothesis (or the decision table refused; the reason
//! is printed), 2 bad input.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{ClassThresholds, OccupancyGrid};
use mapmerge_gridmatch::{match_grids, GridMatchParams, MatchHypothesis};
use mapmerge_gridmerge::{
    fuse, Decision, DecisionTable, FusionParams, MapKind, MapMetadata, MergeRequest, SensorKind,
};
use mapmerge_io::{MapMode, RosMap};
use mapmerge_render::{PairStyle, Picture};
use serde::Serialize;

use crate::{bad_file, bad_input, print_json};

/// Exit code when no hypothesis is acceptable.
const NOT_MERGED: u8 = 3;

/// Arguments of `mapmerge grid-merge`.
#[derive(Args, Debug)]
pub struct GridMergeArgs {
    /// The receiving map (ROS map_server YAML); the merged map has its frame and resolution.
    pub a: PathBuf,
    /// The map to merge in (ROS map_server YAML), any resolution.
    pub b: PathBuf,
    /// The merged map (YAML; the PGM is written next to it, the picture as `.png`).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Matching parameters (JSON file, `mapmerge_gridmatch::GridMatchParams`; absent fields
    /// keep their defaults).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Runner-up hypotheses reported.
    #[arg(long, default_value_t = 4)]
    pub hypotheses: usize,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// A transform in the output: B's map frame in A's map frame (m, rad).
#[derive(Clone, Copy, Debug, Serialize)]
struct Transform {
    x: f64,
    y: f64,
    yaw: f64,
}

/// One hypothesis in the output.
#[derive(Clone, Copy, Debug, Serialize)]
struct Hypothesis {
    transform: Transform,
    acceptance: f64,
    sm: f64,
    /// DM in cells of the coarser resolution.
    dm: f64,
    dm_m: f64,
    overlap_cells: usize,
    score: f64,
}

#[derive(Serialize)]
struct Report<'a> {
    accepted: bool,
    reason: Option<String>,
    transform: Option<Transform>,
    acceptance: Option<f64>,
    sm: Option<f64>,
    dm: Option<f64>,
    seconds: f64,
    match_seconds: f64,
    hypotheses: Vec<Hypothesis>,
    procedure: Option<String>,
    resolution_a_m: f64,
    resolution_b_m: f64,
    merged: Option<&'a Path>,
    png: Option<PathBuf>,
}

/// A map's frame from its grid's: `map_server` places the grid's lower-left corner at the
/// YAML origin turned by its yaw; the grid itself is read axis-aligned at that origin.
fn map_from_grid(map: &RosMap) -> Se2 {
    let origin = Se2::new(map.origin_x_m, map.origin_y_m, 0.0);
    origin
        .compose(&Se2::new(0.0, 0.0, map.origin_yaw_rad))
        .compose(&origin.inverse())
}

fn load(path: &Path) -> anyhow::Result<(RosMap, OccupancyGrid)> {
    let map = mapmerge_io::read_ros_map(path).map_err(bad_file)?;
    let grid = map.to_grid().map_err(bad_file)?;
    Ok((map, grid))
}

/// What a map_server map says about itself: a grid of some resolution, in a frame of its
/// own (the YAML names none, so the relative pose is unknown).
fn metadata(map: &RosMap) -> MapMetadata {
    MapMetadata {
        kind: MapKind::OccupancyGrid,
        resolution_m: Some(map.resolution_m),
        frame_id: String::new(),
        quality: None,
        sensor: SensorKind::Unknown,
    }
}

/// Runs `mapmerge grid-merge`.
pub fn run(args: &GridMergeArgs) -> anyhow::Result<ExitCode> {
    let started = Instant::now();
    let params: GridMatchParams = crate::read_config(args.config.as_deref())?;
    params
        .validate()
        .map_err(|e| bad_input(format!("matching parameters: {e}")))?;
    let (map_a, grid_a) = load(&args.a)?;
    let (map_b, grid_b) = load(&args.b)?;
    let mut report = Report {
        accepted: false,
        reason: None,
        transform: None,
        acceptance: None,
        sm: None,
        dm: None,
        seconds: 0.0,
        match_seconds: 0.0,
        hypotheses: Vec::new(),
        procedure: None,
        resolution_a_m: map_a.resolution_m,
        resolution_b_m: map_b.resolution_m,
        merged: None,
        png: None,
    };
    // 1. Whether and how (Andersone Sec. 2.1).
    let request = MergeRequest {
        a: metadata(&map_a),
        b: metadata(&map_b),
        a_from_b: None,
    };
    let fusion = match DecisionTable::default().decide(&request) {
        Decision::Merge(choice) => {
            report.procedure = Some(format!("{:?} + {:?}", choice.matching, choice.fusion));
            FusionParams::default()
        }
        Decision::Reject(rejection) => {
            report.reason = Some(format!("decision table: {}", rejection.message));
            return finish(args, report, started);
        }
    };
    // 2. Matching without a guess, on the grids as read (axis-aligned at their origins).
    let match_started = Instant::now();
    let matched = match match_grids(&grid_a, &grid_b, &params) {
        Ok(m) => m,
        Err(e) => {
            report.reason = Some(format!("matching failed: {e}"));
            report.match_seconds = match_started.elapsed().as_secs_f64();
            return finish(args, report, started);
        }
    };
    report.match_seconds = match_started.elapsed().as_secs_f64();
    let (a_map_from_grid, b_map_from_grid) = (map_from_grid(&map_a), map_from_grid(&map_b));
    let in_map_frames = |h: &MatchHypothesis| {
        let t = a_map_from_grid
            .compose(&h.a_from_b)
            .compose(&b_map_from_grid.inverse());
        Hypothesis {
            transform: Transform {
                x: t.x_m,
                y: t.y_m,
                yaw: t.theta_rad,
            },
            acceptance: h.acceptance,
            sm: h.metrics.sm,
            dm: h.metrics.dm_cells,
            dm_m: h.metrics.dm_m(),
            overlap_cells: h.metrics.overlap_cells,
            score: h.score,
        }
    };
    report.hypotheses = matched
        .hypotheses
        .iter()
        .skip(1)
        .take(args.hypotheses)
        .map(in_map_frames)
        .collect();
    let Some(best) = matched.hypotheses.first() else {
        report.reason =
            Some("no hypothesis: the maps share no rotation or translation peak".into());
        return finish(args, report, started);
    };
    let shown = in_map_frames(best);
    report.transform = Some(shown.transform);
    report.acceptance = Some(shown.acceptance);
    report.sm = Some(shown.sm);
    report.dm = Some(shown.dm);
    // The picture shows the best placement, accepted or not.
    let png = args.output.with_extension("png");
    let thresholds = ClassThresholds::default();
    Picture::of_grid_pair(
        &grid_a,
        &grid_b,
        &best.a_from_b,
        &thresholds,
        &PairStyle::default(),
    )
    .save_png(&png)
    .with_context(|| format!("writing {}", png.display()))?;
    report.png = Some(png);
    if !matched.accepted {
        report.reason = Some(match matched.rejection {
            Some(r) => format!("not accepted: {r}"),
            None => "not accepted".into(),
        });
        return finish(args, report, started);
    }
    // 3. Fusion in A's grid frame and resolution (Andersone Sec. 4.1).
    let fused = fuse(&grid_a, &grid_b, &best.a_from_b, &fusion).context("fusing the maps")?;
    let mut merged = RosMap::from_grid(&fused.merged, MapMode::Trinary, &thresholds);
    merged.origin_yaw_rad = map_a.origin_yaw_rad;
    mapmerge_io::write_ros_map(&args.output, &merged).context("writing the merged map")?;
    report.accepted = true;
    report.merged = Some(&args.output);
    finish(args, report, started)
}

fn finish(
    args: &GridMergeArgs,
    mut report: Report<'_>,
    started: Instant,
) -> anyhow::Result<ExitCode> {
    report.seconds = started.elapsed().as_secs_f64();
    if args.json {
        print_json(&report)?;
    } else if report.accepted {
        if let Some(t) = report.transform {
            println!(
                "merged: B in A at x {:.3} m, y {:.3} m, yaw {:.2}° (acceptance {:.3}, DM {:.2} cells) in {:.3} s; wrote {}{}",
                t.x,
                t.y,
                t.yaw.to_degrees(),
                report.acceptance.unwrap_or(0.0),
                report.dm.unwrap_or(0.0),
                report.seconds,
                args.output.display(),
                report
                    .png
                    .as_ref()
                    .map(|p| format!(" and {}", p.display()))
                    .unwrap_or_default()
            );
        }
    } else {
        eprintln!(
            "mapmerge: not merged: {}",
            report
                .reason
                .as_deref()
                .unwrap_or("no acceptable hypothesis")
        );
    }
    Ok(if report.accepted {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(NOT_MERGED)
    })
}

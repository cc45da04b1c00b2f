//! Merging two ROS map_server maps of any resolution without an initial guess
//! (`mapmerge grid-merge`; Andersone's framework: decision table, Carpin's matching,
//! quality-weighted Bayes fusion into A's frame and resolution).

use std::path::{Path, PathBuf};
use std::time::Instant;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_grid::{ClassThresholds, OccupancyGrid};
use mapmerge_gridmatch::{match_grids, GridMatchParams, MatchHypothesis};
use mapmerge_gridmerge::{
    fuse, DecisionTable, FusionParams, GridMergeDecision, GridMergeRequest, MapKind, MapMetadata,
    SensorKind,
};
use mapmerge_io::{MapMode, RosMap};
use mapmerge_render::{PairStyle, Picture};
use serde::Serialize;

use crate::JobError;

/// Runner-up hypotheses reported by default.
pub const DEFAULT_HYPOTHESES: usize = 4;

/// A transform in the report: B's map frame in A's map frame (m, rad).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct TransformReport {
    /// Translation (m).
    pub x: f64,
    /// See `x`.
    pub y: f64,
    /// Rotation (rad).
    pub yaw: f64,
}

/// One hypothesis in the report.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct HypothesisReport {
    /// B in A.
    pub transform: TransformReport,
    /// Birk & Carpin's acceptance index ω.
    pub acceptance: f64,
    /// Andersone's SM.
    pub sm: f64,
    /// DM in cells of the coarser resolution.
    pub dm: f64,
    /// DM in metres.
    pub dm_m: f64,
    /// Cells both maps know.
    pub overlap_cells: usize,
    /// The matcher's ranking score.
    pub score: f64,
}

/// What a grid merge did: the `--json` object of `mapmerge grid-merge`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GridMergeReport {
    /// Whether the maps were merged.
    pub accepted: bool,
    /// Why not.
    pub reason: Option<String>,
    /// The best hypothesis (accepted or not): B in A, ω, SM, DM (cells).
    pub transform: Option<TransformReport>,
    /// See `transform`.
    pub acceptance: Option<f64>,
    /// See `transform`.
    pub sm: Option<f64>,
    /// See `transform`.
    pub dm: Option<f64>,
    /// Wall time of the job and of the matching (s).
    pub seconds: f64,
    /// See `seconds`.
    pub match_seconds: f64,
    /// The runners-up.
    pub hypotheses: Vec<HypothesisReport>,
    /// The decision table's matching and fusion procedure.
    pub procedure: Option<String>,
    /// The maps' cell sides (m).
    pub resolution_a_m: f64,
    /// See `resolution_a_m`.
    pub resolution_b_m: f64,
    /// The merged map written (YAML), when merged and written.
    pub merged: Option<PathBuf>,
    /// The picture of the best placement, when written.
    pub png: Option<PathBuf>,
}

/// The report and, when merged, the merged grid (in A's frame and resolution).
#[derive(Clone, Debug)]
pub struct GridMerged {
    /// What happened.
    pub report: GridMergeReport,
    /// The fused grid.
    pub merged: Option<OccupancyGrid>,
    /// The best hypothesis (accepted or not) between the grids as read: B's grid in A's
    /// (the report's transform is between the maps' frames).
    pub a_grid_from_b_grid: Option<Se2>,
}

/// A map's frame from its grid's: `map_server` places the grid's lower-left corner at the
/// YAML origin turned by its yaw; the grid itself is read axis-aligned at that origin.
pub fn map_from_grid(map: &RosMap) -> Se2 {
    let origin = Se2::new(map.origin_x_m, map.origin_y_m, 0.0);
    origin
        .compose(&Se2::new(0.0, 0.0, map.origin_yaw_rad))
        .compose(&origin.inverse())
}

/// Reads a map_server map and its grid; any failure is bad input.
pub fn load_map(path: &Path) -> Result<(RosMap, OccupancyGrid), JobError> {
    let map = mapmerge_io::read_ros_map(path).map_err(|e| JobError::bad_file(&e))?;
    let grid = map.to_grid().map_err(|e| JobError::bad_file(&e))?;
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

/// Merges map `b` into map `a` (map_server YAML files) with `params`, reporting `hypotheses`
/// runners-up. With `output` (a YAML path) it writes the picture of the best placement
/// (`output` with `.png`, accepted or not) and, when merged, the merged map, as the CLI does.
/// Not merging is not an error: the report says why.
pub fn grid_merge(
    a: &Path,
    b: &Path,
    params: &GridMatchParams,
    hypotheses: usize,
    output: Option<&Path>,
) -> Result<GridMerged, JobError> {
    params
        .validate()
        .map_err(|e| JobError::bad_input(format!("matching parameters: {e}")))?;
    let (map_a, grid_a) = load_map(a)?;
    let (map_b, grid_b) = load_map(b)?;
    merge_loaded(
        (&map_a, &grid_a),
        (&map_b, &grid_b),
        params,
        hypotheses,
        output,
    )
}

/// [`grid_merge`] on maps already read (each with its grid, [`RosMap::to_grid`]): a live
/// node's received maps, or files.
pub fn merge_loaded(
    (map_a, grid_a): (&RosMap, &OccupancyGrid),
    (map_b, grid_b): (&RosMap, &OccupancyGrid),
    params: &GridMatchParams,
    hypotheses: usize,
    output: Option<&Path>,
) -> Result<GridMerged, JobError> {
    let started = Instant::now();
    params
        .validate()
        .map_err(|e| JobError::bad_input(format!("matching parameters: {e}")))?;
    let mut report = GridMergeReport {
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
    let finish = |mut report: GridMergeReport,
                  merged: Option<OccupancyGrid>,
                  a_grid_from_b_grid: Option<Se2>| {
        report.seconds = started.elapsed().as_secs_f64();
        Ok(GridMerged {
            report,
            merged,
            a_grid_from_b_grid,
        })
    };
    // 1. Whether and how (Andersone Sec. 2.1).
    let request = GridMergeRequest {
        a: metadata(map_a),
        b: metadata(map_b),
        a_from_b: None,
    };
    let fusion = match DecisionTable::default().decide(&request) {
        GridMergeDecision::Merge(choice) => {
            report.procedure = Some(format!("{:?} + {:?}", choice.matching, choice.fusion));
            FusionParams::default()
        }
        GridMergeDecision::Reject(rejection) => {
            report.reason = Some(format!("decision table: {}", rejection.message));
            return finish(report, None, None);
        }
    };
    // 2. Matching without a guess, on the grids as read (axis-aligned at their origins).
    let match_started = Instant::now();
    let matched = match match_grids(grid_a, grid_b, params) {
        Ok(m) => m,
        Err(e) => {
            report.reason = Some(format!("matching failed: {e}"));
            report.match_seconds = match_started.elapsed().as_secs_f64();
            return finish(report, None, None);
        }
    };
    report.match_seconds = match_started.elapsed().as_secs_f64();
    let (a_map_from_grid, b_map_from_grid) = (map_from_grid(map_a), map_from_grid(map_b));
    let in_map_frames = |h: &MatchHypothesis| {
        let t = a_map_from_grid
            .compose(&h.a_from_b)
            .compose(&b_map_from_grid.inverse());
        HypothesisReport {
            transform: TransformReport {
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
        .take(hypotheses)
        .map(in_map_frames)
        .collect();
    let Some(best) = matched.hypotheses.first() else {
        report.reason =
            Some("no hypothesis: the maps share no rotation or translation peak".into());
        return finish(report, None, None);
    };
    let shown = in_map_frames(best);
    report.transform = Some(shown.transform);
    report.acceptance = Some(shown.acceptance);
    report.sm = Some(shown.sm);
    report.dm = Some(shown.dm);
    // The picture shows the best placement, accepted or not.
    let thresholds = ClassThresholds::default();
    if let Some(output) = output {
        let png = output.with_extension("png");
        Picture::of_grid_pair(
            grid_a,
            grid_b,
            &best.a_from_b,
            &thresholds,
            &PairStyle::default(),
        )
        .save_png(&png)
        .map_err(|e| JobError::writing(&png, &e))?;
        report.png = Some(png);
    }
    if !matched.accepted {
        report.reason = Some(match matched.rejection {
            Some(r) => format!("not accepted: {r}"),
            None => "not accepted".into(),
        });
        return finish(report, None, Some(best.a_from_b));
    }
    // 3. Fusion in A's grid frame and resolution (Andersone Sec. 4.1).
    let fused = fuse(grid_a, grid_b, &best.a_from_b, &fusion)
        .map_err(|e| JobError::context("fusing the maps", &e))?;
    if let Some(output) = output {
        let mut merged = RosMap::from_grid(&fused.merged, MapMode::Trinary, &thresholds);
        merged.origin_yaw_rad = map_a.origin_yaw_rad;
        mapmerge_io::write_ros_map(output, &merged).map_err(|e| JobError::writing(output, &e))?;
        report.merged = Some(output.to_path_buf());
    }
    report.accepted = true;
    finish(report, Some(fused.merged), Some(best.a_from_b))
}

//! `mapmerge eval make-merge-cases` and `mapmerge eval invalid-merge`: Holoch et al.'s
//! evaluation scheme (Sec. V-A, Table III) on the public corrected laser logs.
//!
//! # Cases
//! One JSON object per line:
//! `{"id", "log", "first": [i_start, i_end], "second": [i_start, i_end], "merge_at": i,
//! "merge_transform": [x, y, yaw], "odometry_noise": PROFILE|null, "seed": S,
//! "label": "valid"|"invalid"|null, "kind": K, "merge_place": {"first_scan": j, "relative":
//! [x, y, yaw]}}`; `kind` (how the case was made: `valid`, `rotation`, `shift`, `careless`,
//! `place`, `lookalike`; results are also reported per kind) and `merge_place` are optional.
//! Indices count the log's laser scans from 0 (file order, end inclusive). A relative `log`
//! is read from the working directory, else next to the cases file. Unknown fields are
//! ignored.
//!
//! # Frames
//! Each segment's frame is the robot pose at its first scan. `merge_transform` is
//! `first_from_second`: the second segment's frame in the first segment's frame. With the
//! corrected poses `world_from_robot[k]` the truth is
//! `first_from_second = world_from_robot[first.0]⁻¹ ∘ world_from_robot[second.0]`.
//! The merged map lives in the *second* (current, active) segment's frame, so the robot's pose
//! does not jump at the merge: a first-segment keyframe at `first_from_robot` is handed to
//! the detectors at `second_from_robot = merge_transform⁻¹ ∘ first_from_robot`.
//!
//! Two definitions of a valid merge (`make-merge-cases --valid-at`):
//! - `start-frames` (the default, Holoch's): `merge_transform` is the truth between the
//!   segments' start frames. Each segment's own map drifts away from the corrected poses by
//!   the time it reaches the overlap, so the "valid" merge is off where the robot is.
//! - `merge-place`: the case carries `merge_place`, the true pose of the second segment's
//!   scan `merge_at` in the frame of the first segment's scan `first_scan` (the one nearest
//!   to it). The evaluator forces `first_from_second = first_from_scan ∘ relative ∘
//!   second_from_merge_scan⁻¹` with its own estimates of both scans' poses (the first
//!   segment's optimised graph, the engine's live pose of the merge scan), so a valid merge
//!   is exact at the merge place whatever either map drifted elsewhere; `merge_transform`
//!   then records what the merge is under the corrected poses.
//!
//! # make-merge-cases (needs the corrected poses; only it reads them)
//! 1. Segments: consecutive pieces of about `--segment-secs` (100 s) of robot time, cut by the
//!    scans' stamps. Stamps are *broken* when a stamp is not finite, more than 1 % of the
//!    steps between consecutive scans do not go forward, or a step exceeds 300 s (csail,
//!    belgioioso: a handful of distinct values; freiburg-campus, orebro: all 0;
//!    infinite-corridor: bogus values); then segments have `--segment-scans` scans (default
//!    35, about the median number of scans per 100 s of the logs with sound stamps). A
//!    remainder shorter than half a segment joins the last segment.
//! 2. Each segment's map: an occupancy grid at 0.1 m from the corrected poses in the world
//!    frame, returns trusted up to 10 m (beyond, the beam only clears free space up to 10 m).
//!    Two segments overlap by the area of the cells known (free or occupied) in both.
//! 3. Ordered pairs (first, second) of distinct segments whose maps overlap by at least
//!    `--min-overlap` m² (1.5, as the paper) and where the second segment's robot comes
//!    within `--overlap-radius` m (2) of the first segment's path, at least 2 scans after its
//!    start and 8 before its end. `merge_at` is the first such scan.
//! 4. Per pair, in a seeded random order, at most `--max-pairs`: one *valid* case (the truth)
//!    and up to `--invalid-per-pair` *invalid* ones, each putting the robot at the merge scan
//!    at least 1 m or 10° away from where the truth puts it:
//!    - `place`: careless place recognition (Scan Context over the first segment's scans,
//!      5 candidates per query, verified by the scan matcher with no confidence test, score
//!      ≥ 0.3) queried with second-segment scans in the overlap; the best-scoring wrong
//!      alignment, merged at its query scan.
//!    - `lookalike`: a turn by a multiple of 90° (± 3°) about the robot at `merge_at` and a
//!      shift of up to 3 m per axis (corridor aliasing) that still looks right to a map
//!      matcher: Andersone's SM ≥ 0.9 between the first segment's grid and the second
//!      segment's grid so far (counted on the second grid's cells), overlapping at least half
//!      as much as the truth; the one with the most agreeing occupied cells of 200 seeded
//!      tries.
//!
//!
//!    With `--valid-at merge-place`, per pair instead: the valid case (the true relative pose
//!    at the merge place) and one invalid case of each kind, each as a relative pose at the
//!    merge place (seeded per pair): `rotation`, the truth turned by 90°, 180° or 270° about
//!    the robot; `shift`, the robot moved 2–8 m in a random direction; `careless`, the
//!    best-scoring wrong pose (≥ 1 m or 10° off) of the last 3 m of second-segment scans
//!    against the whole first segment within ±4 m of the truth at any heading (the tracker's
//!    correlative matcher, exact in each of 18 × 16 sub-windows of 20° × 2 m × 2 m; a wrong
//!    optimum in the truth's own sub-window is not seen).
//!    `--segment-length-m` cuts segments by travel along the corrected poses instead of time;
//!    with `--split-at-jumps-m` a segment also ends where the corrected poses jump (kidnaps,
//!    session changes in `mapmerge sim --corrected-log`). `--place-kind` adds a `place` case
//!    per pair, made as with `start-frames` (no `merge_place`: its transform is the case).
//!
//!    Every case's merged maps overlap by at least `--min-overlap` m² (whole segments).
//!
//! # invalid-merge
//! Per case: both segments' graphs from the project's SLAM (the lifelong engine with one
//! epoch, default parameters) on their scans and the log's odometry, with the case's noise profile
//! and seed (`mapmerge_eval::add_odometry_noise` on the whole log, so segments of one log and
//! seed share one noisy odometry); `null` runs on the log's own odometry. The first segment
//! runs to its end (its optimised graph) and becomes an inactive graph of the lifelong
//! engine's atlas (`mapmerge_engine::Engine`, no detector of its own, no merges by
//! recognition); the second segment's scans run through the engine; after scan `merge_at` the
//! merge is forced with `merge_transform` (overlap loops, re-optimisation) and each detector
//! gets `on_merge`; then after every keyframe the engine adds (it keeps closing loops into
//! the merged data and re-optimising, as it does live) each detector gets the merged map
//! (current: the second segment's keyframes, other: the first segment's, at their poses in
//! the merged graph) and its invalidity ratio is recorded. Nothing is undone. Keyframe points
//! are the tracker's (range-limited as it matches them), as the atlas stores them.
//! `ms_per_vertex` is the mean wall time of `on_vertex` (not of `on_merge`).
//! A log is read once and each first-segment run (log, segment, noise, seed) is shared by the
//! cases that name it.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::fmt::Write as _;
use std::io::{BufRead, IsTerminal, Write as _};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use mapmerge_engine::{Engine, EngineParams, NO_DETECTOR};
use mapmerge_eval::{add_odometry_noise, roc_auc, scan_poses, OdometryNoiseProfile};
use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_grid::{CellClass, ClassThresholds, InsertParams, OccupancyGrid};
use mapmerge_place::{GeometricVerifier, Keyframe, PlaceIndex, ScanContext, ScanMatchVerifier};
use mapmerge_posegraph::{NodeId, PoseGraph2};
use mapmerge_scan::{BeamFilter, LaserLog, Point2};
use mapmerge_slam::ScanAnchors;
use mapmerge_verify::{
    DetectorParams, InvalidMergeDetector, MergedMap, RatioSupport, DETECTOR_NAMES,
};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::{bad_file, bad_input, print_json};

/// Scans per segment when the stamps are broken (about the median scans per 100 s of the logs
/// with sound stamps: intel 34, aces 33, fr101 32, edmonton 48, fhw 24, seattle 21).
const BROKEN_STAMPS_SEGMENT_SCANS: usize = 35;
/// Cell side of the segment maps used for overlap and look-alike scoring (m).
const PAIR_GRID_M: f64 = 0.1;
/// Returns beyond this (m) only clear free space in those maps.
const PAIR_GRID_RANGE_M: f32 = 10.0;
/// `merge_at` leaves at least this many scans of the second segment before it …
const MIN_SCANS_BEFORE_MERGE: usize = 2;
/// … and this many after it.
const MIN_SCANS_AFTER_MERGE: usize = 8;
/// An invalid merge is at least this far from the truth (m, rad).
const WRONG_BEYOND: (f64, f64) = (1.0, 0.175);
/// Look-alikes must pass Andersone's acceptance (SM ≥ 0.9).
const LOOKALIKE_MIN_SM: f64 = 0.9;
/// Random look-alike transforms tried per pair, shifted by up to this (m) per axis.
const LOOKALIKE_TRIALS: usize = 200;
const LOOKALIKE_SHIFT_M: f64 = 3.0;
/// Place-recognition queries per pair, candidates per query, minimal verification score.
const PLACE_QUERIES: usize = 4;
const PLACE_CANDIDATES: usize = 5;
const PLACE_MIN_SCORE: f64 = 0.3;

// ------------------------------------------------------------------ arguments

/// Arguments of `mapmerge eval make-merge-cases`.
#[derive(Args, Debug)]
pub struct MakeMergeCasesArgs {
    /// The log the evaluator runs on (written to the cases as given; a corrected log is fine
    /// with `--odometry-noise`).
    #[arg(long)]
    pub log: PathBuf,
    /// Corrected CARMEN log of the same scans: its poses give the overlaps and the labels.
    #[arg(long)]
    pub corrected: PathBuf,
    /// Output cases (JSON lines).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Seed of the pair order, the look-alikes and the odometry noise (ChaCha8).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Noise profile written to every case (`default`, `harsh`, `none`), or `null` for the
    /// log's own odometry.
    #[arg(long, default_value = "default")]
    pub odometry_noise: String,
    /// Segment length in robot time (s), from the scans' stamps.
    #[arg(long, default_value_t = 100.0)]
    pub segment_secs: f64,
    /// Segment length in scans (overrides `--segment-secs`; used when stamps are broken,
    /// default 35 then).
    #[arg(long)]
    pub segment_scans: Option<usize>,
    /// Minimal map overlap of a pair (m²).
    #[arg(long, default_value_t = 1.5)]
    pub min_overlap: f64,
    /// At `merge_at` the second segment's robot is within this distance (m) of the first
    /// segment's path.
    #[arg(long, default_value_t = 2.0)]
    pub overlap_radius: f64,
    /// At most this many pairs (seeded random choice); default all.
    #[arg(long)]
    pub max_pairs: Option<usize>,
    /// Invalid cases per pair with `--valid-at start-frames` (0–2: place recognition first,
    /// then a look-alike).
    #[arg(long, default_value_t = 2)]
    pub invalid_per_pair: usize,
    /// Where the valid merge is the truth: between the segments' start frames (as it
    /// always was), or at the merge place (each case then carries `merge_place` and one
    /// invalid case per pair of each kind: `rotation`, `shift`, `careless`).
    #[arg(long, value_enum, default_value_t = ValidAt::StartFrames)]
    pub valid_at: ValidAt,
    /// Segment length in travel (m) from the corrected poses (overrides `--segment-secs`
    /// and `--segment-scans`).
    #[arg(long)]
    pub segment_length_m: Option<f64>,
    /// With `--valid-at merge-place`: also one `place` case per pair, careless place
    /// recognition over the whole first segment as with `start-frames` (the wrong place may
    /// lie far from the truth, e.g. in a look-alike room: the lifelong engine's own wrong
    /// merges).
    #[arg(long)]
    pub place_kind: bool,
    /// With `--segment-length-m`: consecutive corrected poses further apart than this (m)
    /// are a jump (a kidnap, or the next session in `mapmerge sim --corrected-log`), where a
    /// segment ends. Off by default: some public logs keep one scan per 1–3 m (orebro).
    #[arg(long)]
    pub split_at_jumps_m: Option<f64>,
    /// Print one JSON summary instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Where a valid merge of `make-merge-cases` is the truth.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ValidAt {
    /// `merge_transform` is the true pose of the second segment's first scan in the first's.
    StartFrames,
    /// The true relative pose of the scans at the merge place (`merge_place`).
    MergePlace,
}

/// Arguments of `mapmerge eval invalid-merge`.
#[derive(Args, Debug)]
pub struct InvalidMergeArgs {
    /// Cases (JSON lines, see `make-merge-cases`).
    #[arg(long)]
    pub cases: PathBuf,
    /// Output results (JSON lines: one per case and method).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Detectors to run (comma-separated; default all).
    #[arg(long, value_delimiter = ',')]
    pub methods: Vec<String>,
    /// Only the first N cases.
    #[arg(long)]
    pub max_cases: Option<usize>,
    /// Print the per-log summary (ROC AUC, ms per new vertex; Holoch Table III).
    #[arg(long)]
    pub summary: bool,
    /// Write the summary as Markdown to this file.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Print one JSON summary instead of text (no progress bar).
    #[arg(long)]
    pub json: bool,
    /// Detector parameters other than the defaults (JSON: `{"change_detection": {…},
    /// "gridmap": {…}, "entropy": {…}, "histogram": {…}, "sm": {…}, "dm": {…},
    /// "better_hypothesis": {…}, "combined": {…}}`, each optional and each partial, fields as
    /// in `mapmerge_verify::DetectorParams`; `combined` carries its parts' own), e.g. to vary
    /// the window.
    #[arg(long)]
    pub detector_params: Option<PathBuf>,
    /// Also write every detector's invalidity after every new vertex to this file (JSON
    /// lines `{"id", "method", "vertex", "scan", "invalidity", "support", "evidence",
    /// "cross_edges", "local_error"}`; `vertex` counts from 0 after the merge, `scan` is the
    /// log's scan index, `support` how many compared points or cells the ratio rests on,
    /// `null` for detectors without such a count).
    #[arg(long)]
    pub trace: Option<PathBuf>,
    /// Also draw, per case, the merged map at the first new vertex after the merge
    /// (`DIR/ID-first.png`) and where the first method's invalidity peaked
    /// (`DIR/ID-peak.png`; `/` in ids becomes `_`): the newest scans in change detection's
    /// colours (red change, green agree, grey no information), other scans by epoch.
    #[arg(long)]
    pub pictures: Option<PathBuf>,
    /// Engine parameters for the run of each second segment (JSON,
    /// `mapmerge_engine::EngineParams`; absent fields keep their defaults, and the evaluation
    /// still turns the engine's own detector and merge search off), e.g.
    /// `{"atlas": {"merge": {"overlap": {"local_loops": false}}}}`.
    #[arg(long)]
    pub engine_config: Option<PathBuf>,
}

/// `--detector-params`: parameters per detector name, the rest default.
fn read_detector_params(path: &Path) -> anyhow::Result<DetectorParams> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text)
        .map_err(|e| bad_input(format!("{}: bad detector parameters: {e}", path.display())))
}

// ------------------------------------------------------------------ formats

/// The label of a case.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Label {
    /// The transform is the truth.
    Valid,
    /// The transform is wrong.
    Invalid,
}

/// One forced merge (a line of a cases file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MergeCase {
    /// Unique name.
    pub id: String,
    /// The CARMEN log.
    pub log: String,
    /// First segment's scans (inclusive).
    pub first: [usize; 2],
    /// Second segment's scans (inclusive).
    pub second: [usize; 2],
    /// The merge happens right after this scan of the second segment.
    pub merge_at: usize,
    /// `first_from_second` (m, m, rad).
    pub merge_transform: [f64; 3],
    /// Noise profile of the odometry, `None` for the log's own.
    pub odometry_noise: Option<String>,
    /// Seed of the noise.
    pub seed: u64,
    /// Ground truth, when known.
    pub label: Option<Label>,
    /// How the case was made (`valid`, `rotation`, `shift`, `careless`, `place`,
    /// `lookalike`), for results per kind; absent in older files (then the id's last part).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kind: Option<String>,
    /// The merge defined at the merge place (see the module docs); absent: `merge_transform`
    /// between the start frames is forced as it is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub merge_place: Option<MergePlace>,
}

/// A merge defined where it happens: the first segment's scan `first_scan` and the pose of
/// the second segment's scan `merge_at` in its frame. The evaluator turns it into
/// `first_from_second` with its own estimates of both scans' poses, so the merge is exactly
/// this relative pose at the merge place, whatever either segment's map drifted elsewhere.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MergePlace {
    /// A scan of the first segment (log index).
    pub first_scan: usize,
    /// `first_scan_from_merge_scan` (m, m, rad).
    pub relative: [f64; 3],
}

impl MergeResult {
    /// True when the detector never had enough to compare after the merge (and saw new
    /// vertices); unknown (older files) counts as supported.
    pub fn unsupported(&self) -> bool {
        self.vertices > 0 && self.supported_vertices == Some(0)
    }
}

impl MergeCase {
    /// The case's kind: `kind`, else the last part of its id.
    fn kind(&self) -> String {
        self.kind.clone().unwrap_or_else(|| {
            self.id
                .rsplit('/')
                .next()
                .unwrap_or(self.id.as_str())
                .to_owned()
        })
    }
}

/// One line of a results file.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MergeResult {
    /// The case.
    pub id: String,
    /// The detector.
    pub method: String,
    /// Its highest invalidity ratio after the merge (0 without new vertices).
    pub max_invalidity: f64,
    /// Mean wall time per new vertex (ms); `null` without new vertices.
    pub ms_per_vertex: Option<f64>,
    /// New vertices after the merge.
    pub vertices: usize,
    /// The case's label.
    pub label: Option<Label>,
    /// The case's kind (see [`MergeCase::kind`]).
    #[serde(default)]
    pub kind: String,
    /// The case's log.
    pub log: String,
    /// New vertices at which the detector had enough to compare ([`RatioSupport::Supported`]);
    /// 0 of `vertices`: the merge was *unsupported* (nothing it claims could be checked).
    /// Absent in older files.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub supported_vertices: Option<usize>,
}

/// Parses a cases file's text; errors are `source:line: reason`. Checks what needs no log.
fn parse_cases(text: &str, source: &str) -> Result<Vec<(usize, MergeCase)>, String> {
    let mut cases = Vec::new();
    let mut ids = HashSet::new();
    for (number, raw) in text.lines().enumerate() {
        let number = number + 1;
        let line = raw.trim();
        if line.is_empty() {
            continue;
        }
        let fail = |reason: String| format!("{source}:{number}: {reason}");
        let case: MergeCase =
            serde_json::from_str(line).map_err(|e| fail(format!("not a merge case: {e}")))?;
        check_case(&case).map_err(fail)?;
        if !ids.insert(case.id.clone()) {
            return Err(fail(format!("duplicate id `{}`", case.id)));
        }
        cases.push((number, case));
    }
    Ok(cases)
}

/// What can be checked about a case without its log.
fn check_case(case: &MergeCase) -> Result<(), String> {
    if case.id.is_empty() {
        return Err("empty id".into());
    }
    for (name, [start, end]) in [("first", case.first), ("second", case.second)] {
        if start > end {
            return Err(format!("{name} [{start}, {end}] ends before it starts"));
        }
    }
    let scan_of = |field: &str, scan: usize, (name, [start, end]): (&str, [usize; 2])| {
        if scan < start || scan > end {
            return Err(format!(
                "{field} {scan} is not a scan of {name} [{start}, {end}]"
            ));
        }
        Ok(())
    };
    let finite = |field: &str, pose: &[f64; 3]| {
        if pose.iter().any(|v| !v.is_finite()) {
            return Err(format!("{field} {pose:?} is not finite"));
        }
        Ok(())
    };
    scan_of("merge_at", case.merge_at, ("second", case.second))?;
    finite("merge_transform", &case.merge_transform)?;
    if let Some(name) = &case.odometry_noise {
        OdometryNoiseProfile::from_name(name).map_err(|e| format!("odometry_noise: {e}"))?;
    }
    if let Some(place) = &case.merge_place {
        scan_of(
            "merge_place.first_scan",
            place.first_scan,
            ("first", case.first),
        )?;
        finite("merge_place.relative", &place.relative)?;
    }
    Ok(())
}

/// Checks a case's indices against its log's scan count.
fn check_in_log(case: &MergeCase, scans: usize, log: &Path) -> Result<(), String> {
    for (name, [start, end]) in [("first", case.first), ("second", case.second)] {
        if end >= scans {
            return Err(format!(
                "{name} [{start}, {end}] is beyond the {scans} scans of {}",
                log.display()
            ));
        }
    }
    Ok(())
}

fn se2_of(v: [f64; 3]) -> Se2 {
    Se2::new(v[0], v[1], v[2])
}

fn array_of(p: &Se2) -> [f64; 3] {
    [p.x_m, p.y_m, wrap_angle_rad(p.theta_rad)]
}

/// True when the merges `a` and `b` (`first_from_second`) put the robot, at
/// `second_from_robot`, at least `m` metres or `rad` apart: the error where the robot is, not
/// at the segment's origin (a small turn about a far-away robot is no wrong merge).
fn far_from(a: &Se2, b: &Se2, second_from_robot: &Se2, (m, rad): (f64, f64)) -> bool {
    let d = a
        .compose(second_from_robot)
        .between(&b.compose(second_from_robot));
    d.translation().norm() >= m || wrap_angle_rad(d.theta_rad).abs() >= rad
}

/// A log's short name: `intel` for `…/intel-corrected.log.xz`.
pub(crate) fn log_name(log: &str) -> String {
    crate::log_short_name(Path::new(log))
}

// ------------------------------------------------------------------ segments

/// True when the stamps can be trusted as robot time (see the module docs).
fn stamps_usable(stamps: &[f64]) -> bool {
    if stamps.len() < 2 || stamps.iter().any(|s| !s.is_finite()) {
        return false;
    }
    let steps: Vec<f64> = stamps.windows(2).map(|w| w[1] - w[0]).collect();
    let backward = steps.iter().filter(|d| **d <= 0.0).count();
    backward * 100 <= steps.len() && steps.iter().all(|d| d.abs() <= 300.0)
}

/// Consecutive segments `[start, end]` covering `scans` scans.
fn cut_segments(
    stamps: &[f64],
    segment_secs: f64,
    segment_scans: Option<usize>,
) -> Vec<[usize; 2]> {
    let n = stamps.len();
    let mut starts = vec![0usize];
    match segment_scans {
        Some(count) => {
            let count = count.max(1);
            starts.extend((count..n).step_by(count));
        }
        None => {
            // Robot time, kept monotone across the rare step back.
            let mut time = Vec::with_capacity(n);
            let mut latest = f64::NEG_INFINITY;
            for s in stamps {
                latest = latest.max(*s);
                time.push(latest);
            }
            let mut start_time = time.first().copied().unwrap_or(0.0);
            for (k, t) in time.iter().enumerate().skip(1) {
                if t - start_time >= segment_secs {
                    starts.push(k);
                    start_time = *t;
                }
            }
        }
    }
    segments_from_starts(&starts, n)
}

/// Consecutive segments of about `length_m` of travel each (corrected poses). With `jump_m`,
/// consecutive poses further apart than that are a jump, not travel, and a segment ends
/// there (each stretch between jumps is cut as a whole log is; one shorter than a segment is
/// one segment).
fn segments_by_travel(poses: &[Se2], length_m: f64, jump_m: Option<f64>) -> Vec<[usize; 2]> {
    let mut segments = Vec::new();
    let mut piece_start = 0;
    let jump_m = jump_m.unwrap_or(f64::INFINITY);
    for (k, pair) in poses.windows(2).enumerate() {
        if (pair[1].translation() - pair[0].translation()).norm() > jump_m {
            segments.extend(travel_pieces(
                poses.get(piece_start..=k).unwrap_or_default(),
                length_m,
                piece_start,
            ));
            piece_start = k + 1;
        }
    }
    segments.extend(travel_pieces(
        poses.get(piece_start..).unwrap_or_default(),
        length_m,
        piece_start,
    ));
    segments
}

/// [`segments_by_travel`] within a stretch without jumps starting at scan `offset`.
fn travel_pieces(poses: &[Se2], length_m: f64, offset: usize) -> Vec<[usize; 2]> {
    let mut starts = vec![0usize];
    let mut travel_m = 0.0;
    for (k, pair) in poses.windows(2).enumerate() {
        travel_m += (pair[1].translation() - pair[0].translation()).norm();
        if travel_m >= length_m {
            starts.push(k + 1);
            travel_m = 0.0;
        }
    }
    segments_from_starts(&starts, poses.len())
        .into_iter()
        .map(|[s, e]| [s + offset, e + offset])
        .collect()
}

/// `[start, end]` of the segments beginning at `starts` (ascending, the first 0) over `n`
/// scans; a remainder shorter than half the first segment joins the last full one.
fn segments_from_starts(starts: &[usize], n: usize) -> Vec<[usize; 2]> {
    let mut segments: Vec<[usize; 2]> = starts
        .iter()
        .enumerate()
        .map(|(i, &s)| [s, starts.get(i + 1).map_or(n, |&e| e) - 1])
        .filter(|[s, e]| s <= e && *e < n)
        .collect();
    // A short remainder joins the last full segment.
    if segments.len() >= 2 {
        let typical = segments[0][1] - segments[0][0] + 1;
        if let Some(last) = segments.last().copied() {
            if (last[1] - last[0] + 1) * 2 < typical {
                segments.pop();
                if let Some(previous) = segments.last_mut() {
                    previous[1] = last[1];
                }
            }
        }
    }
    segments
}

/// `pose` as a point map with its sine and cosine computed once.
fn point_map(pose: &Se2) -> impl Fn(&Point2) -> Point2 {
    let (sin, cos) = pose.theta_rad.sin_cos();
    let (x, y) = (pose.x_m, pose.y_m);
    move |p: &Point2| Point2::new(cos * p.x - sin * p.y + x, sin * p.x + cos * p.y + y)
}

/// Cells known in `a` (world frame) whose centre, mapped by `world_from_b⁻¹`, is known in `b`
/// (its own world frame), as an area (m²).
fn overlap_m2(a: &OccupancyGrid, b: &OccupancyGrid, world_from_b: &Se2) -> f64 {
    let thresholds = ClassThresholds::default();
    let b_from_world = point_map(&world_from_b.inverse());
    let geometry = a.geometry();
    let known = |l: f32| thresholds.classify(l) != CellClass::Unknown;
    let count = a
        .log_odds()
        .iter()
        .enumerate()
        .filter(|(_, l)| known(**l))
        .filter(|(index, _)| {
            let p = geometry.center_of(geometry.cell_at(*index));
            known(b.log_odds_at(&b_from_world(&p)))
        })
        .count();
    count as f64 * geometry.resolution_m * geometry.resolution_m
}

fn bounds_intersect(a: &OccupancyGrid, b: &OccupancyGrid) -> bool {
    let (a_low, a_high) = a.geometry().bounds_m();
    let (b_low, b_high) = b.geometry().bounds_m();
    a_low.x <= b_high.x && b_low.x <= a_high.x && a_low.y <= b_high.y && b_low.y <= a_high.y
}

fn pair_grid<'a>(
    posed: impl IntoIterator<Item = (Se2, &'a mapmerge_scan::LaserScan)>,
) -> anyhow::Result<OccupancyGrid> {
    let params = InsertParams {
        max_hit_range_m: PAIR_GRID_RANGE_M,
        ..InsertParams::default()
    };
    Ok(OccupancyGrid::from_scans(PAIR_GRID_M, posed, &params)?.0)
}

// ------------------------------------------------------------------ make-merge-cases

#[derive(Serialize)]
struct MakeCasesReport<'a> {
    log: &'a Path,
    output: &'a Path,
    scans: usize,
    stamps_usable: bool,
    segments: usize,
    segment_scans_mean: f64,
    pairs_overlapping: usize,
    pairs_used: usize,
    cases: usize,
    valid: usize,
    invalid_place: usize,
    invalid_lookalike: usize,
    invalid_rotation: usize,
    invalid_shift: usize,
    invalid_careless: usize,
    seconds: f64,
}

/// Runs `mapmerge eval make-merge-cases`.
pub fn make_merge_cases(args: &MakeMergeCasesArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    let noise = match args.odometry_noise.as_str() {
        "null" => None,
        name => {
            OdometryNoiseProfile::from_name(name).map_err(bad_input)?;
            Some(name.to_owned())
        }
    };
    if !(args.segment_secs.is_finite() && args.segment_secs > 0.0)
        || args.segment_scans == Some(0)
        || args
            .segment_length_m
            .is_some_and(|m| !(m.is_finite() && m > 0.0))
        || !(args.min_overlap.is_finite() && args.min_overlap >= 0.0)
        || !(args.overlap_radius.is_finite() && args.overlap_radius > 0.0)
        || args
            .split_at_jumps_m
            .is_some_and(|m| !(m.is_finite() && m > 0.0))
    {
        return Err(bad_input(
            "--segment-secs, --segment-scans, --segment-length-m, --overlap-radius and \
             --split-at-jumps-m must be positive, --min-overlap not negative",
        ));
    }
    let raw = mapmerge_io::read_carmen(&args.log).map_err(bad_file)?;
    let corrected_log = mapmerge_io::read_carmen(&args.corrected).map_err(bad_file)?;
    let poses = scan_poses(&corrected_log)
        .map_err(|e| bad_input(format!("{}: {e}", args.corrected.display())))?;
    if poses.len() != raw.scans.len() {
        return Err(bad_input(format!(
            "{} has {} scans but {} has {} (scans pair by order)",
            args.corrected.display(),
            poses.len(),
            args.log.display(),
            raw.scans.len()
        )));
    }
    let stamps: Vec<f64> = raw.scans.iter().map(|r| r.stamp_secs).collect();
    let usable = stamps_usable(&stamps);
    let segment_scans = args
        .segment_scans
        .or((!usable).then_some(BROKEN_STAMPS_SEGMENT_SCANS));
    let segments = match args.segment_length_m {
        Some(length_m) => segments_by_travel(&poses, length_m, args.split_at_jumps_m),
        None => cut_segments(&stamps, args.segment_secs, segment_scans),
    };
    let progress = !args.json && std::io::stderr().is_terminal();
    if !args.json {
        eprintln!(
            "{}: {} scans, stamps {}, {} segments",
            args.log.display(),
            raw.scans.len(),
            if usable {
                "usable"
            } else {
                "broken (cut by scan count)"
            },
            segments.len()
        );
    }
    // Each segment's map in the world frame, from the corrected poses.
    let scans = &corrected_log.scans;
    let grids: Vec<OccupancyGrid> = segments
        .iter()
        .map(|[s, e]| pair_grid((*s..=*e).map(|k| (poses[k], &scans[k].scan))))
        .collect::<anyhow::Result<_>>()?;
    // 1. Candidate pairs: overlapping maps and a merge scan in the overlap.
    let mut pairs: Vec<(usize, usize, usize)> = Vec::new();
    for (i, first) in segments.iter().enumerate() {
        for (j, second) in segments.iter().enumerate() {
            if i == j || !bounds_intersect(&grids[i], &grids[j]) {
                continue;
            }
            let Some(merge_at) = merge_scan(&poses, *first, *second, args.overlap_radius) else {
                continue;
            };
            if overlap_m2(&grids[i], &grids[j], &Se2::identity()) < args.min_overlap {
                continue;
            }
            pairs.push((i, j, merge_at));
        }
    }
    let pairs_overlapping = pairs.len();
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    pairs.shuffle(&mut rng);
    if let Some(max) = args.max_pairs {
        pairs.truncate(max);
    }
    // Keep the file in segment order, whatever was drawn.
    pairs.sort_unstable();
    let bar = crate::progress_bar(pairs.len(), "pairs", "merge cases", progress);
    let engine_params = EngineParams::default();
    let mut window = engine_params.atlas.loops.place_window;
    window.linear_m = window.linear_m.max(2.0);
    let verifier = ScanMatchVerifier::new(engine_params.tracker.matcher, window)
        .map_err(|e| anyhow::anyhow!("scan matcher: {e}"))?;
    let filter = BeamFilter {
        max_range_m: engine_params.tracker.max_match_range_m,
        ..BeamFilter::default()
    };
    let log_text = args.log.to_string_lossy().into_owned();
    let name = log_name(&log_text);
    let matcher = mapmerge_scanmatch::ScanMatcher::new(engine_params.tracker.matcher)
        .map_err(|e| anyhow::anyhow!("scan matcher: {e}"))?;
    let mut cases = Vec::new();
    let (mut valid, mut place, mut lookalike) = (0, 0, 0);
    let mut per_kind: BTreeMap<&'static str, usize> = BTreeMap::new();
    for &(i, j, merge_at) in &pairs {
        bar.inc(1);
        let (first, second) = (segments[i], segments[j]);
        let world_from_first = poses[first[0]];
        let world_from_second = poses[second[0]];
        let truth = world_from_first.between(&world_from_second);
        let pair_seed = args.seed ^ ((i as u64) << 40) ^ ((j as u64) << 20);
        let make = |suffix: &str, merge_at: usize, transform: &Se2, label: Label| MergeCase {
            id: format!("{name}/s{i:03}-s{j:03}/{suffix}"),
            log: log_text.clone(),
            first,
            second,
            merge_at,
            merge_transform: array_of(transform),
            odometry_noise: noise.clone(),
            seed: args.seed,
            label: Some(label),
            kind: Some(suffix.to_owned()),
            merge_place: None,
        };
        // A wrong merge must still overlap the first map, or there is nothing to detect.
        let overlaps = |first_from_second: &Se2| {
            let world_from_world2 = world_from_first
                .compose(first_from_second)
                .compose(&world_from_second.inverse());
            overlap_m2(&grids[i], &grids[j], &world_from_world2) >= args.min_overlap
        };
        // Careless place recognition over the whole first segment: (query scan, transform).
        let wrong_place = || {
            careless_place_recognition(
                &poses,
                scans,
                first,
                second,
                &truth,
                args.overlap_radius,
                &filter,
                &verifier,
                &SearchWindowM {
                    linear_m: window.linear_m,
                    angular_rad: window.angular_rad,
                },
                &engine_params.atlas.loops.place,
            )
            .filter(|(_, t)| overlaps(t))
        };
        if args.valid_at == ValidAt::MergePlace {
            let mut pair_rng = ChaCha8Rng::seed_from_u64(pair_seed);
            let place =
                MergePlaceCases::new(&poses, scans, [first, second], merge_at, &filter, &matcher);
            for (kind, relative) in place.cases(&mut pair_rng) {
                let transform = place.start_frames(&relative);
                let label = if kind == "valid" {
                    Label::Valid
                } else {
                    Label::Invalid
                };
                if label == Label::Invalid && !overlaps(&transform) {
                    continue;
                }
                let mut case = make(kind, merge_at, &transform, label);
                case.merge_place = Some(MergePlace {
                    first_scan: place.first_scan,
                    relative: array_of(&relative),
                });
                cases.push(case);
                *per_kind.entry(kind).or_default() += 1;
            }
            if args.place_kind {
                if let Some((at, transform)) = wrong_place() {
                    cases.push(make("place", at, &transform, Label::Invalid));
                    *per_kind.entry("place").or_default() += 1;
                }
            }
            continue;
        }
        cases.push(make("valid", merge_at, &truth, Label::Valid));
        valid += 1;
        let mut invalid = 0;
        if invalid < args.invalid_per_pair {
            if let Some((at, transform)) = wrong_place() {
                cases.push(make("place", at, &transform, Label::Invalid));
                place += 1;
                invalid += 1;
            }
        }
        if invalid < args.invalid_per_pair {
            let own = &grids[i];
            let other = pair_grid((second[0]..=merge_at).map(|k| (poses[k], &scans[k].scan)))?;
            let mut pair_rng = ChaCha8Rng::seed_from_u64(pair_seed);
            if let Some(transform) = lookalike_transform(
                own,
                &other,
                &world_from_first,
                &world_from_second,
                &poses[merge_at],
                &mut pair_rng,
            )
            .filter(|t| overlaps(t))
            {
                cases.push(make("lookalike", merge_at, &transform, Label::Invalid));
                lookalike += 1;
            }
        }
    }
    bar.finish_and_clear();
    let mut text = String::new();
    for case in &cases {
        text.push_str(&serde_json::to_string(case)?);
        text.push('\n');
    }
    if let Some(dir) = args.output.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    std::fs::write(&args.output, text)
        .with_context(|| format!("writing {}", args.output.display()))?;
    valid += per_kind.get("valid").copied().unwrap_or(0);
    let report = MakeCasesReport {
        log: &args.log,
        output: &args.output,
        scans: raw.scans.len(),
        stamps_usable: usable,
        segments: segments.len(),
        segment_scans_mean: raw.scans.len() as f64 / segments.len().max(1) as f64,
        pairs_overlapping,
        pairs_used: pairs.len(),
        cases: cases.len(),
        valid,
        invalid_place: place + per_kind.get("place").copied().unwrap_or(0),
        invalid_lookalike: lookalike,
        invalid_rotation: per_kind.get("rotation").copied().unwrap_or(0),
        invalid_shift: per_kind.get("shift").copied().unwrap_or(0),
        invalid_careless: per_kind.get("careless").copied().unwrap_or(0),
        seconds: started.elapsed().as_secs_f64(),
    };
    if args.json {
        print_json(&report)
    } else {
        println!(
            "{}: {} segments ({:.0} scans each), {} overlapping pairs, {} used: {} cases \
             ({} valid, {} invalid by place recognition, {} look-alikes, {} turned, {} \
             shifted, {} careless) in {:.1} s -> {}",
            args.log.display(),
            report.segments,
            report.segment_scans_mean,
            report.pairs_overlapping,
            report.pairs_used,
            report.cases,
            valid,
            report.invalid_place,
            lookalike,
            report.invalid_rotation,
            report.invalid_shift,
            report.invalid_careless,
            report.seconds,
            args.output.display()
        );
        Ok(())
    }
}

/// Scans of `second` where the robot is within `radius_m` of `first`'s path (and far enough
/// from the segment's ends).
fn overlap_scans(
    poses: &[Se2],
    first: [usize; 2],
    second: [usize; 2],
    radius_m: f64,
) -> Vec<usize> {
    let lo = second[0] + MIN_SCANS_BEFORE_MERGE;
    let Some(hi) = second[1].checked_sub(MIN_SCANS_AFTER_MERGE) else {
        return Vec::new();
    };
    (lo..=hi)
        .filter(|&k| {
            let p = poses[k].translation();
            (first[0]..=first[1]).any(|m| (poses[m].translation() - p).norm() <= radius_m)
        })
        .collect()
}

fn merge_scan(
    poses: &[Se2],
    first: [usize; 2],
    second: [usize; 2],
    radius_m: f64,
) -> Option<usize> {
    overlap_scans(poses, first, second, radius_m)
        .first()
        .copied()
}

/// Half-width of the careless search around the true merge place (m): "the best-scoring
/// wrong pose within ±4 m at any heading".
const CARELESS_REACH_M: f64 = 4.0;
/// Travel (m) of second-segment scans up to `merge_at` that the careless search matches.
const CARELESS_QUERY_TRAVEL_M: f64 = 3.0;
/// Shifts of the `shift` kind (m).
const SHIFT_RANGE_M: (f64, f64) = (2.0, 8.0);

/// The merge-place cases of one pair (`--valid-at merge-place`): every merge is a pose of
/// the second segment's scan `merge_at` in the frame of the first segment's scan nearest to
/// it (the relative pose the evaluator applies at the merge place).
struct MergePlaceCases<'a> {
    poses: &'a [Se2],
    scans: &'a [mapmerge_scan::ScanRecord],
    first: [usize; 2],
    second: [usize; 2],
    merge_at: usize,
    /// The first segment's scan nearest to the robot at `merge_at`.
    first_scan: usize,
    filter: &'a BeamFilter,
    matcher: &'a mapmerge_scanmatch::ScanMatcher,
}

impl<'a> MergePlaceCases<'a> {
    /// The cases of the pair `first`, `second` merged at scan `merge_at` (corrected poses).
    fn new(
        poses: &'a [Se2],
        scans: &'a [mapmerge_scan::ScanRecord],
        [first, second]: [[usize; 2]; 2],
        merge_at: usize,
        filter: &'a BeamFilter,
        matcher: &'a mapmerge_scanmatch::ScanMatcher,
    ) -> Self {
        let at = poses[merge_at].translation();
        let first_scan = (first[0]..=first[1])
            .min_by(|&a, &b| {
                let da = (poses[a].translation() - at).norm();
                let db = (poses[b].translation() - at).norm();
                da.total_cmp(&db).then(a.cmp(&b))
            })
            .unwrap_or(first[0]);
        Self {
            poses,
            scans,
            first,
            second,
            merge_at,
            first_scan,
            filter,
            matcher,
        }
    }

    /// The truth: `first_scan_from_merge_scan`.
    fn truth(&self) -> Se2 {
        self.poses[self.first_scan].between(&self.poses[self.merge_at])
    }

    /// `first_from_second` that a merge-place pose is under the corrected poses (what
    /// `merge_transform` records; the truth for the valid case).
    fn start_frames(&self, relative: &Se2) -> Se2 {
        self.poses[self.first[0]]
            .inverse()
            .compose(&self.poses[self.first_scan])
            .compose(relative)
            .compose(&self.poses[self.merge_at].inverse())
            .compose(&self.poses[self.second[0]])
    }

    /// `(kind, first_scan_from_merge_scan)`: the truth, a turn by 90°, 180° or 270° about
    /// the robot, a shift of 2–8 m in a random direction, and careless place recognition.
    fn cases(&self, rng: &mut ChaCha8Rng) -> Vec<(&'static str, Se2)> {
        let truth = self.truth();
        let quarter_turns = f64::from(rng.random_range(1i32..=3));
        let turned = truth.compose(&Se2::new(
            0.0,
            0.0,
            quarter_turns * std::f64::consts::FRAC_PI_2,
        ));
        let distance_m = rng.random_range(SHIFT_RANGE_M.0..=SHIFT_RANGE_M.1);
        let direction = rng.random_range(0.0..std::f64::consts::TAU);
        let shifted = truth.compose(&Se2::new(
            distance_m * direction.cos(),
            distance_m * direction.sin(),
            0.0,
        ));
        let mut cases = vec![("valid", truth), ("rotation", turned), ("shift", shifted)];
        if let Some(careless) = self.careless(&truth) {
            cases.push(("careless", careless));
        }
        cases
    }

    /// The best-scoring wrong pose of the merge scan within ±4 m of the truth at any
    /// heading: the last `CARELESS_QUERY_TRAVEL_M` of second-segment scans (corrected poses,
    /// merge scan frame) matched against every first-segment scan (first-scan frame) in 18
    /// heading sectors × 16 boxes of 2 m, each searched exactly; optima within 1 m and 10°
    /// of the truth are right, the best of the others is the careless merge. (A wrong
    /// optimum hidden by the truth in the truth's own box is not seen.)
    fn careless(&self, truth: &Se2) -> Option<Se2> {
        let first_scan = self.first_scan;
        let posed_points = |range: std::ops::RangeInclusive<usize>, frame: usize| {
            let frame_from_world = self.poses[frame].inverse();
            range
                .flat_map(|k| {
                    let frame_from_robot = frame_from_world.compose(&self.poses[k]);
                    let map = point_map(&frame_from_robot);
                    self.scans[k]
                        .scan
                        .points_in_robot(self.filter)
                        .into_iter()
                        .map(move |p| map(&p))
                })
                .collect::<Vec<Point2>>()
        };
        let target = self
            .matcher
            .target(&posed_points(self.first[0]..=self.first[1], first_scan))
            .ok()?;
        let mut query_start = self.merge_at;
        let mut travel_m = 0.0;
        while query_start > self.second[0] && travel_m < CARELESS_QUERY_TRAVEL_M {
            travel_m += (self.poses[query_start].translation()
                - self.poses[query_start - 1].translation())
            .norm();
            query_start -= 1;
        }
        let query = posed_points(query_start..=self.merge_at, self.merge_at);
        let sectors = 18;
        let sector_rad = std::f64::consts::TAU / f64::from(sectors);
        let window = mapmerge_scanmatch::SearchWindow::new(1.0, sector_rad / 2.0);
        let mut best: Option<(f64, Se2)> = None;
        // Boxes of ±1 m side by side over ±CARELESS_REACH_M.
        let boxes = CARELESS_REACH_M.round() as usize;
        let centres: Vec<f64> = (0..boxes)
            .map(|b| -CARELESS_REACH_M + 1.0 + 2.0 * b as f64)
            .collect();
        for sector in 0..sectors {
            for &bx in &centres {
                for &by in &centres {
                    let guess = Se2::new(
                        truth.x_m + bx,
                        truth.y_m + by,
                        truth.theta_rad + f64::from(sector) * sector_rad,
                    );
                    let Some(found) = mapmerge_scanmatch::match_scan(
                        target.correlative(),
                        &query,
                        &guess,
                        &window,
                    ) else {
                        continue;
                    };
                    let pose = found.target_from_query;
                    if !far_from(truth, &pose, &Se2::identity(), WRONG_BEYOND) {
                        continue;
                    }
                    if best.as_ref().is_none_or(|(score, _)| found.score > *score) {
                        best = Some((found.score, pose));
                    }
                }
            }
        }
        best.map(|(_, pose)| pose)
    }
}

/// The verifier's search window (m, rad).
struct SearchWindowM {
    linear_m: f64,
    angular_rad: f64,
}

/// Careless place recognition: queries second-segment scans in the overlap against every
/// first-segment scan, verifies the top candidates without any confidence test, and returns
/// the best-scoring alignment that is wrong (`(query scan, first_from_second)`).
#[allow(clippy::too_many_arguments)]
fn careless_place_recognition(
    poses: &[Se2],
    scans: &[mapmerge_scan::ScanRecord],
    first: [usize; 2],
    second: [usize; 2],
    truth: &Se2,
    radius_m: f64,
    filter: &BeamFilter,
    verifier: &ScanMatchVerifier,
    window: &SearchWindowM,
    place: &mapmerge_place::PlaceParams,
) -> Option<(usize, Se2)> {
    let descriptor = &place.descriptor;
    let mut index: PlaceIndex<ScanContext> = PlaceIndex::new(place.index.clone());
    let mut keyframes = HashMap::new();
    for (k, record) in scans.iter().enumerate().take(first[1] + 1).skip(first[0]) {
        let points = record.scan.points_in_robot(filter);
        index.insert(
            mapmerge_place::KeyframeId(k as u64),
            ScanContext::new(&points, descriptor),
        );
        keyframes.insert(k as u64, Keyframe::new(k as u64, points));
    }
    let candidates = overlap_scans(poses, first, second, radius_m);
    let step = candidates.len().div_ceil(PLACE_QUERIES).max(1);
    let world_from_first = poses[first[0]];
    let world_from_second = poses[second[0]];
    // 1. Retrieval: (query, candidate, yaw guess), leaving out candidates whose true relative
    //    pose lies inside the verifier's window (the verifier would find the right place).
    let mut jobs: Vec<(usize, Arc<Keyframe>, Se2)> = Vec::new();
    for &a in candidates.iter().step_by(step) {
        let points = scans[a].scan.points_in_robot(filter);
        let query = Arc::new(Keyframe::new(a as u64, points));
        let descriptor = ScanContext::new(&query.points_in_keyframe, descriptor);
        for candidate in index.query(&descriptor, PLACE_CANDIDATES) {
            let b = candidate.keyframe.0 as usize;
            let guess = Se2::new(0.0, 0.0, candidate.yaw_rad);
            let true_b_from_a = poses[b].between(&poses[a]);
            if true_b_from_a.translation().norm() <= window.linear_m
                && wrap_angle_rad(true_b_from_a.theta_rad - guess.theta_rad).abs()
                    <= window.angular_rad
            {
                continue;
            }
            if keyframes.contains_key(&candidate.keyframe.0) {
                jobs.push((b, query.clone(), guess));
            }
        }
    }
    // 2. Verification on every core (each job builds a match target: the costly part).
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let chunk = jobs.len().div_ceil(threads).max(1);
    let verified: Vec<(usize, usize, mapmerge_place::Verification)> = std::thread::scope(|scope| {
        let handles: Vec<_> = jobs
            .chunks(chunk)
            .map(|part| {
                let keyframes = &keyframes;
                scope.spawn(move || {
                    part.iter()
                        .filter_map(|(b, query, guess)| {
                            let keyframe = keyframes.get(&(*b as u64))?;
                            let v = verifier.verify(query, keyframe, guess)?;
                            Some((query.id.0 as usize, *b, v))
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap_or_default())
            .collect()
    });
    // 3. The best-scoring wrong alignment, whatever its confidence.
    let mut best: Option<(f64, usize, Se2)> = None;
    for (a, b, v) in verified {
        if !(v.score.is_finite() && v.score >= PLACE_MIN_SCORE) {
            continue;
        }
        // first_from_second = first_from_b ∘ b_from_a ∘ (second_from_a)⁻¹.
        let first_from_b = world_from_first.between(&poses[b]);
        let second_from_a = world_from_second.between(&poses[a]);
        let transform = first_from_b
            .compose(&v.candidate_from_query)
            .compose(&second_from_a.inverse());
        if far_from(&transform, truth, &second_from_a, WRONG_BEYOND)
            && best
                .as_ref()
                .is_none_or(|(s, a_best, _)| v.score > *s || (v.score == *s && a < *a_best))
        {
            best = Some((v.score, a, transform));
        }
    }
    best.map(|(_, a, t)| (a, t))
}

/// Andersone's SM (Eq. 1: agreeing / (agreeing + disagreeing) cells) of `other` moved by
/// `world_from_other` over `own`, with the cells known in both and those occupied in both;
/// counted on `other`'s lattice (`cells`: its known cells' centres and whether occupied).
fn agreement(
    own: &OccupancyGrid,
    cells: &[(Point2, bool)],
    world_from_other: &Se2,
) -> (f64, usize, usize) {
    let thresholds = ClassThresholds::default();
    let world_from_other = point_map(world_from_other);
    let (mut agree, mut disagree, mut overlap, mut occupied) = (0usize, 0usize, 0usize, 0usize);
    for (p, other_occupied) in cells {
        let own_class = thresholds.classify(own.log_odds_at(&world_from_other(p)));
        let own_occupied = match own_class {
            CellClass::Unknown => continue,
            CellClass::Occupied => true,
            CellClass::Free => false,
        };
        overlap += 1;
        if own_occupied == *other_occupied {
            agree += 1;
            occupied += usize::from(own_occupied);
        } else {
            disagree += 1;
        }
    }
    let sm = if agree == 0 {
        0.0
    } else {
        agree as f64 / (agree + disagree) as f64
    };
    (sm, overlap, occupied)
}

/// A wrong `first_from_second` that a map matcher would accept (see the module docs).
fn lookalike_transform(
    own: &OccupancyGrid,
    other: &OccupancyGrid,
    world_from_first: &Se2,
    world_from_second: &Se2,
    world_from_robot: &Se2,
    rng: &mut ChaCha8Rng,
) -> Option<Se2> {
    let thresholds = ClassThresholds::default();
    // In world terms: the second segment's map is moved by `world_from_world2` (identity at
    // the truth) and first_from_second = world_from_first⁻¹ ∘ world_from_world2 ∘ world_from_second.
    let to_case = |w: &Se2| {
        world_from_first
            .inverse()
            .compose(w)
            .compose(world_from_second)
    };
    let truth = to_case(&Se2::identity());
    let g = other.geometry();
    let cells: Vec<(Point2, bool)> = other
        .log_odds()
        .iter()
        .enumerate()
        .filter_map(|(index, l)| {
            let occupied = match thresholds.classify(*l) {
                CellClass::Unknown => return None,
                CellClass::Occupied => true,
                CellClass::Free => false,
            };
            Some((g.center_of(g.cell_at(index)), occupied))
        })
        .collect();
    let (_, truth_overlap, _) = agreement(own, &cells, &Se2::identity());
    let about = Se2::new(world_from_robot.x_m, world_from_robot.y_m, 0.0);
    let second_from_robot = world_from_second.between(world_from_robot);
    let mut best: Option<(usize, Se2)> = None;
    for _ in 0..LOOKALIKE_TRIALS {
        let turn = f64::from(rng.random_range(-1i32..=2)) * std::f64::consts::FRAC_PI_2
            + rng.random_range(-0.05..0.05);
        let shift = Se2::new(
            rng.random_range(-LOOKALIKE_SHIFT_M..LOOKALIKE_SHIFT_M),
            rng.random_range(-LOOKALIKE_SHIFT_M..LOOKALIKE_SHIFT_M),
            0.0,
        );
        let world_from_world2 = shift
            .compose(&about)
            .compose(&Se2::new(0.0, 0.0, turn))
            .compose(&about.inverse());
        let candidate = to_case(&world_from_world2);
        if !far_from(&candidate, &truth, &second_from_robot, WRONG_BEYOND) {
            continue;
        }
        let (sm, overlap, agree_occupied) = agreement(own, &cells, &world_from_world2);
        if sm >= LOOKALIKE_MIN_SM
            && overlap * 2 >= truth_overlap
            && best.is_none_or(|(s, _)| agree_occupied > s)
        {
            best = Some((agree_occupied, candidate));
        }
    }
    best.map(|(_, t)| t)
}

// ------------------------------------------------------------------ invalid-merge

/// The first segment of a case, run to its end by the front-end: its optimised graph (the
/// first keyframe, i.e. the segment's first scan, at the origin) and every keyframe's points.
struct FirstSegment {
    graph: PoseGraph2,
    points: BTreeMap<NodeId, Arc<[Point2]>>,
    /// Every scan's pose in the optimised graph (index: scan − the segment's first scan;
    /// `None` for a scan whose anchor left the graph).
    scan_poses: Vec<Option<Se2>>,
    /// The log scan of each keyframe, by the address of its points (the merged map's
    /// detector scans share them), for `--trace`'s local error.
    keyframe_scans: HashMap<usize, usize>,
}

/// The key of a keyframe's points in [`FirstSegment::keyframe_scans`].
fn points_key(points: &Arc<[Point2]>) -> usize {
    Arc::as_ptr(points) as *const Point2 as usize
}

fn run_first_segment(log: &LaserLog, [start, end]: [usize; 2]) -> anyhow::Result<FirstSegment> {
    let mut engine = Engine::new(EngineParams {
        detector: NO_DETECTOR.into(),
        ..EngineParams::default()
    })?;
    let mut odometry = Se2::identity();
    let mut anchors = ScanAnchors::new();
    let mut scan_of_node = HashMap::new();
    for (k, record) in log.scans.iter().enumerate().take(end + 1).skip(start) {
        odometry = record.odom_from_robot.unwrap_or(odometry);
        let report = engine
            .add_scan(&odometry, &record.scan, None)
            .with_context(|| format!("SLAM at scan {k}"))?;
        anchors.push(report.anchor.0, report.anchor.1);
        scan_of_node.entry(report.anchor.0).or_insert(k);
    }
    engine.finish()?;
    let atlas = engine.atlas();
    let graph = atlas.active().clone();
    let points: BTreeMap<NodeId, Arc<[Point2]>> = graph
        .vertices()
        .filter_map(|(node, _)| Some((node, Arc::clone(atlas.keyframes().get(node)?))))
        .collect();
    let scan_poses = anchors.trajectory(&graph);
    let keyframe_scans = points
        .iter()
        .filter_map(|(node, p)| Some((points_key(p), *scan_of_node.get(node)?)))
        .collect();
    Ok(FirstSegment {
        graph,
        points,
        scan_poses,
        keyframe_scans,
    })
}

/// A log with an odometry: its path, noise profile and seed (0 without noise).
type OdometryKey = (PathBuf, Option<String>, u64);

/// The logs, noisy odometries and first-segment runs the cases share.
#[derive(Default)]
struct Cache {
    logs: HashMap<PathBuf, Arc<LaserLog>>,
    odometry: HashMap<OdometryKey, Arc<LaserLog>>,
    segments: HashMap<(OdometryKey, [usize; 2]), Arc<FirstSegment>>,
}

impl Cache {
    fn log(&mut self, path: &Path) -> anyhow::Result<Arc<LaserLog>> {
        if let Some(log) = self.logs.get(path) {
            return Ok(log.clone());
        }
        let log = Arc::new(mapmerge_io::read_carmen(path).map_err(bad_file)?);
        self.logs.insert(path.to_owned(), log.clone());
        Ok(log)
    }

    fn odometry(
        &mut self,
        path: &Path,
        noise: &Option<String>,
        seed: u64,
    ) -> anyhow::Result<Arc<LaserLog>> {
        let seed = if noise.is_some() { seed } else { 0 };
        let key = (path.to_owned(), noise.clone(), seed);
        if let Some(log) = self.odometry.get(&key) {
            return Ok(log.clone());
        }
        let raw = self.log(path)?;
        let log = match noise {
            None => raw,
            Some(name) => {
                let profile = OdometryNoiseProfile::from_name(name).map_err(bad_input)?;
                let noisy = add_odometry_noise(&raw, &profile, seed)
                    .map_err(|e| bad_input(format!("{}: {e}", path.display())))?;
                Arc::new(noisy.log)
            }
        };
        self.odometry.insert(key, log.clone());
        Ok(log)
    }

    fn first_segment(
        &mut self,
        path: &Path,
        noise: &Option<String>,
        seed: u64,
        range: [usize; 2],
    ) -> anyhow::Result<Arc<FirstSegment>> {
        let seed = if noise.is_some() { seed } else { 0 };
        let key = ((path.to_owned(), noise.clone(), seed), range);
        if let Some(run) = self.segments.get(&key) {
            return Ok(run.clone());
        }
        let log = self.odometry(path, noise, seed)?;
        let run = Arc::new(run_first_segment(&log, range)?);
        self.segments.insert(key, run.clone());
        Ok(run)
    }
}

/// The per-vertex outcome of one detector on one case.
#[derive(Clone, Debug, Default)]
struct Outcome {
    max_invalidity: f64,
    seconds: f64,
    vertices: usize,
    supported_vertices: usize,
    /// What every new vertex saw.
    trace: Vec<TraceEntry>,
}

/// One new vertex of [`Outcome::trace`].
#[derive(Clone, Copy, Debug)]
struct TraceEntry {
    scan: usize,
    invalidity: f64,
    support: Option<u64>,
    evidence: RatioSupport,
    /// What the trace adds (only when tracing).
    diagnostics: Option<Diagnostics>,
}

/// Per vertex, for `--trace` only: the misalignment where the robot is and the edges joining
/// the epochs.
#[derive(Clone, Copy, Debug)]
struct Diagnostics {
    local_error: Option<LocalError>,
    /// Edges between the current epoch and the merged data (the merge's and loops since).
    cross_edges: usize,
}

/// Edges of `graph` between vertices of different epochs (sessions).
fn cross_epoch_edges(graph: &PoseGraph2) -> usize {
    let session = |n: NodeId| graph.vertex(n).map(|v| v.meta.session);
    graph
        .edges()
        .filter(|(_, e)| session(e.from) != session(e.to))
        .count()
}

/// How far the newest keyframe's pose relative to its nearest first-segment keyframe is from
/// the log's corrected relative pose: the misalignment the detectors see there.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
struct LocalError {
    /// The first-segment scan it is compared with.
    first_scan: usize,
    /// Translation error (m).
    m: f64,
    /// Rotation error (degrees).
    deg: f64,
}

/// [`LocalError`] of the newest current scan (log scan `scan`) in `map`, from the corrected
/// poses `truth`; `None` without a pose or a first-segment keyframe.
fn local_error(
    first: &FirstSegment,
    map: &MergedMap<'_>,
    scan: usize,
    truth: &[Option<Se2>],
) -> Option<LocalError> {
    let newest = map.current.last()?;
    let here = newest.map_from_robot.translation();
    let nearest = map
        .other
        .iter()
        .filter_map(|o| {
            Some((
                o,
                *first.keyframe_scans.get(&points_key(&o.points_in_robot))?,
            ))
        })
        .min_by(|(a, _), (b, _)| {
            let da = (a.map_from_robot.translation() - here).norm();
            let db = (b.map_from_robot.translation() - here).norm();
            da.total_cmp(&db)
        })?;
    let (other, first_scan) = nearest;
    let estimated = other
        .map_from_robot
        .inverse()
        .compose(&newest.map_from_robot);
    let (true_other, true_newest) = (truth.get(first_scan)?.as_ref()?, truth.get(scan)?.as_ref()?);
    let error = true_other
        .inverse()
        .compose(true_newest)
        .inverse()
        .compose(&estimated);
    Some(LocalError {
        first_scan,
        m: error.translation().norm(),
        deg: error.theta_rad.abs().to_degrees(),
    })
}

/// A line of `--trace`.
#[derive(Serialize)]
struct TraceLine<'a> {
    id: &'a str,
    method: &'a str,
    vertex: usize,
    scan: usize,
    invalidity: f64,
    /// What the ratio rests on (`InvalidMergeDetector::support`), `null` if not counted.
    support: Option<u64>,
    /// Whether that was enough (`supported`) or not (`unsupported`).
    evidence: RatioSupport,
    /// The newest keyframe's misalignment against the corrected poses (valid cases).
    #[serde(skip_serializing_if = "Option::is_none")]
    local_error: Option<LocalError>,
    /// Edges between the current epoch and the merged data.
    cross_edges: Option<usize>,
}

/// The lifelong loop as the evaluation runs it: no verification of its own (the detectors
/// under test look at its merged map), no merges by recognition (the case forces one).
fn evaluation_engine(params: &EngineParams) -> anyhow::Result<Engine> {
    let mut params = EngineParams {
        detector: NO_DETECTOR.into(),
        ..params.clone()
    };
    params.atlas.recognition.min_epoch_keyframes = usize::MAX;
    params.atlas.recognition.session_start_search_m = 0.0;
    Ok(Engine::new(params)?)
}

/// Forces the merge of `case` and feeds every new vertex to each detector (never undoing).
///
/// The first segment is an inactive graph of the engine's atlas; the second segment's scans
/// (`log` holds the case's odometry) run through the engine; after scan `merge_at` the merge
/// is forced with `merge_transform`, and from then on the engine keeps closing loops into the
/// merged data and re-optimising, as it does live (Holoch et al. evaluate on the merged
/// graph of their SLAM system). After every new keyframe each detector sees the merged map.
/// `truth` (the log's corrected poses) turns on the trace's [`Diagnostics`].
fn evaluate_case(
    first: &FirstSegment,
    log: &LaserLog,
    truth: Option<&[Option<Se2>]>,
    case: &MergeCase,
    detectors: &mut [Box<dyn InvalidMergeDetector>],
    pictures: Option<&Path>,
    engine_params: &EngineParams,
) -> anyhow::Result<Vec<Outcome>> {
    let picture = |engine: &Engine, which: &str| -> anyhow::Result<()> {
        let Some(dir) = pictures else {
            return Ok(());
        };
        let name = format!("{}-{which}.png", case.id.replace('/', "_"));
        mapmerge_jobs::draw_graph(engine.map_graph(), engine, &[], &dir.join(name))
            .map_err(crate::job_error)
    };
    let mut engine = evaluation_engine(engine_params)?;
    let map = engine.import_inactive(&first.graph, |node| first.points.get(&node).cloned())?;
    let mut outcomes = vec![Outcome::default(); detectors.len()];
    let mut odometry = Se2::identity();
    let mut merged = false;
    let mut robot = None;
    let mut merge_scan_anchor: Option<(NodeId, Se2)> = None;
    let [start, end] = case.second;
    for (k, record) in log.scans.iter().enumerate().take(end + 1).skip(start) {
        odometry = record.odom_from_robot.unwrap_or(odometry);
        let anchor = engine
            .add_scan(&odometry, &record.scan, Some(record.stamp_secs))
            .with_context(|| format!("engine at scan {k}"))?
            .anchor;
        if k == case.merge_at {
            merge_scan_anchor = Some(anchor);
        }
        let keyframe = engine.robot_node() != robot;
        robot = engine.robot_node();
        if !merged {
            if k >= case.merge_at && robot.is_some() {
                // The merge scan's pose now: its anchor keyframe's pose and the offset.
                let second_from_merge_scan = merge_scan_anchor.and_then(|(node, offset)| {
                    Some(engine.map_graph().vertex(node)?.pose.compose(&offset))
                });
                let first_from_second = merge_transform(first, case, second_from_merge_scan)?;
                // Holoch et al., Sec. V-A: the merged map is in the current (second)
                // segment's frame.
                let second_from_first = first_from_second.inverse();
                engine.force_merge(map, second_from_first, format!("case {}", case.id))?;
                merged = true;
                let (current, other) = engine.merged_map_scans();
                let map = MergedMap {
                    current: &current,
                    other: &other,
                };
                for detector in detectors.iter_mut() {
                    detector.on_merge(&map);
                }
            }
            continue;
        }
        if !keyframe {
            continue;
        }
        let (current, other) = engine.merged_map_scans();
        let map = MergedMap {
            current: &current,
            other: &other,
        };
        let peak_before = outcomes.first().map(|o| o.max_invalidity);
        let diagnostics = truth.map(|truth| Diagnostics {
            local_error: local_error(first, &map, k, truth),
            cross_edges: cross_epoch_edges(engine.map_graph()),
        });
        for (detector, outcome) in detectors.iter_mut().zip(outcomes.iter_mut()) {
            let started = Instant::now();
            let ratio = detector.on_vertex(&map);
            outcome.seconds += started.elapsed().as_secs_f64();
            outcome.vertices += 1;
            let evidence = detector.evidence();
            if evidence == RatioSupport::Supported {
                outcome.supported_vertices += 1;
            }
            outcome.trace.push(TraceEntry {
                scan: k,
                invalidity: ratio,
                support: detector.support(),
                evidence,
                diagnostics,
            });
            if ratio.is_finite() {
                outcome.max_invalidity = outcome.max_invalidity.max(ratio);
            }
        }
        if let Some(outcome) = outcomes.first() {
            if outcome.vertices == 1 {
                picture(&engine, "first")?;
            }
            if outcome.vertices == 1 || Some(outcome.max_invalidity) > peak_before {
                picture(&engine, "peak")?;
            }
        }
    }
    Ok(outcomes)
}

/// The merge `first_from_second` the evaluator forces: `merge_transform`, or with a merge
/// place `first_from_scan · relative · second_from_merge_scan⁻¹` from the first segment's
/// optimised pose of its scan and the engine's live pose of the merge scan.
fn merge_transform(
    first: &FirstSegment,
    case: &MergeCase,
    second_from_merge_scan: Option<Se2>,
) -> anyhow::Result<Se2> {
    let Some(place) = &case.merge_place else {
        return Ok(se2_of(case.merge_transform));
    };
    let first_from_scan = place
        .first_scan
        .checked_sub(case.first[0])
        .and_then(|i| first.scan_poses.get(i).copied().flatten())
        .ok_or_else(|| anyhow::anyhow!("no pose of first-segment scan {}", place.first_scan))?;
    let second_from_merge_scan = second_from_merge_scan
        .ok_or_else(|| anyhow::anyhow!("no pose of merge scan {}", case.merge_at))?;
    Ok(first_from_scan
        .compose(&se2_of(place.relative))
        .compose(&second_from_merge_scan.inverse()))
}

/// Where a case's log is: as written, else relative to the cases file's folder.
fn resolve_log(log: &str, cases_file: &Path) -> PathBuf {
    let path = PathBuf::from(log);
    if path.is_absolute() || path.exists() {
        return path;
    }
    match cases_file.parent() {
        Some(dir) if dir.join(&path).exists() => dir.join(path),
        _ => path,
    }
}

/// Reads and checks a cases file (errors name the file and line: exit code 2).
fn read_cases(path: &Path) -> anyhow::Result<Vec<(usize, MergeCase)>> {
    let file = std::fs::File::open(path)
        .map_err(|e| bad_input(format!("{}: cannot read: {e}", path.display())))?;
    let mut text = String::new();
    for (number, line) in std::io::BufReader::new(file).lines().enumerate() {
        let line = line.map_err(|e| {
            bad_input(format!(
                "{}:{}: cannot read: {e}",
                path.display(),
                number + 1
            ))
        })?;
        text.push_str(&line);
        text.push('\n');
    }
    let cases = parse_cases(&text, &path.display().to_string()).map_err(bad_input)?;
    if cases.is_empty() {
        return Err(bad_input(format!("{}: no cases", path.display())));
    }
    Ok(cases)
}

/// Runs `mapmerge eval invalid-merge`.
pub fn invalid_merge(args: &InvalidMergeArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    let methods: Vec<String> = if args.methods.is_empty() {
        DETECTOR_NAMES.iter().map(|s| (*s).to_owned()).collect()
    } else {
        args.methods.iter().map(|m| m.trim().to_owned()).collect()
    };
    for method in &methods {
        if mapmerge_verify::detector(method).is_none() {
            return Err(bad_input(format!(
                "unknown method `{method}`; known: {}",
                DETECTOR_NAMES.join(", ")
            )));
        }
    }
    let detector_params = match &args.detector_params {
        Some(path) => read_detector_params(path)?,
        None => DetectorParams::default(),
    };
    let engine_params: EngineParams = crate::read_config(args.engine_config.as_deref())?;
    let mut cases = read_cases(&args.cases)?;
    if let Some(max) = args.max_cases {
        cases.truncate(max);
    }
    // Validate every case against its log before the long run.
    let mut cache = Cache::default();
    let mut resolved = Vec::with_capacity(cases.len());
    for (line, case) in &cases {
        let path = resolve_log(&case.log, &args.cases);
        let log = cache.log(&path).map_err(|e| {
            bad_input(format!(
                "{}:{line}: log {}: {e:#}",
                args.cases.display(),
                case.log
            ))
        })?;
        check_in_log(case, log.scans.len(), &path)
            .map_err(|reason| bad_input(format!("{}:{line}: {reason}", args.cases.display())))?;
        if case.odometry_noise.is_some() {
            if let Err(e) = scan_poses(&log) {
                return Err(bad_input(format!(
                    "{}:{line}: odometry noise needs a pose on every scan of {}: {e}",
                    args.cases.display(),
                    path.display()
                )));
            }
        }
        resolved.push(path);
    }
    let progress = !args.json && std::io::stderr().is_terminal();
    let bar = crate::progress_bar(cases.len(), "cases", "", progress);
    if let Some(dir) = args.output.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let file = std::fs::File::create(&args.output)
        .with_context(|| format!("writing {}", args.output.display()))?;
    let mut out = std::io::BufWriter::new(file);
    if let Some(dir) = &args.pictures {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let mut trace = match &args.trace {
        Some(path) => Some(std::io::BufWriter::new(
            std::fs::File::create(path).with_context(|| format!("writing {}", path.display()))?,
        )),
        None => None,
    };
    let mut results = Vec::with_capacity(cases.len() * methods.len());
    for ((line, case), path) in cases.iter().zip(&resolved) {
        bar.set_message(case.id.clone());
        let context = |e: anyhow::Error| {
            anyhow::anyhow!("{}:{line}: case {}: {e:#}", args.cases.display(), case.id)
        };
        let first = cache
            .first_segment(path, &case.odometry_noise, case.seed, case.first)
            .map_err(context)?;
        let log = cache
            .odometry(path, &case.odometry_noise, case.seed)
            .map_err(context)?;
        let mut detectors: Vec<Box<dyn InvalidMergeDetector>> = methods
            .iter()
            .filter_map(|m| detector_params.detector(m))
            .collect();
        // The corrected poses, for the trace's misalignment (only when tracing).
        let truth: Option<Vec<Option<Se2>>> = if args.trace.is_some() {
            let raw = cache.log(path).map_err(context)?;
            Some(
                raw.scans
                    .iter()
                    .map(|record| record.odom_from_robot)
                    .collect(),
            )
        } else {
            None
        };
        let outcomes = evaluate_case(
            &first,
            &log,
            truth.as_deref(),
            case,
            &mut detectors,
            args.pictures.as_deref(),
            &engine_params,
        )
        .map_err(context)?;
        for (method, outcome) in methods.iter().zip(outcomes) {
            if let Some(trace) = trace.as_mut() {
                for (vertex, entry) in outcome.trace.iter().enumerate() {
                    let line = TraceLine {
                        id: &case.id,
                        method,
                        vertex,
                        scan: entry.scan,
                        invalidity: entry.invalidity,
                        support: entry.support,
                        evidence: entry.evidence,
                        local_error: entry
                            .diagnostics
                            .and_then(|d| d.local_error)
                            .filter(|_| case.label == Some(Label::Valid)),
                        cross_edges: entry.diagnostics.map(|d| d.cross_edges),
                    };
                    serde_json::to_writer(&mut *trace, &line)?;
                    writeln!(trace)?;
                }
                trace.flush()?;
            }
            let result = MergeResult {
                id: case.id.clone(),
                method: method.clone(),
                max_invalidity: outcome.max_invalidity,
                ms_per_vertex: (outcome.vertices > 0)
                    .then(|| 1e3 * outcome.seconds / outcome.vertices as f64),
                vertices: outcome.vertices,
                label: case.label,
                kind: case.kind(),
                log: case.log.clone(),
                supported_vertices: Some(outcome.supported_vertices),
            };
            serde_json::to_writer(&mut out, &result)?;
            writeln!(out)?;
            results.push(result);
        }
        out.flush()?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    let summary = summarise(&results, &methods);
    let markdown = summary_markdown(&summary, started.elapsed().as_secs_f64());
    if let Some(report) = &args.report {
        if let Some(dir) = report.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        std::fs::write(report, &markdown)
            .with_context(|| format!("writing {}", report.display()))?;
    }
    if args.json {
        print_json(&InvalidMergeReport {
            cases: cases.len(),
            methods: &methods,
            output: &args.output,
            seconds: started.elapsed().as_secs_f64(),
            summary: &summary,
        })
    } else {
        if args.summary {
            print!("{markdown}");
        } else {
            println!(
                "{} cases × {} methods in {:.1} s -> {}",
                cases.len(),
                methods.len(),
                started.elapsed().as_secs_f64(),
                args.output.display()
            );
        }
        Ok(())
    }
}

// ------------------------------------------------------------------ summary

#[derive(Serialize)]
struct InvalidMergeReport<'a> {
    cases: usize,
    methods: &'a [String],
    output: &'a Path,
    seconds: f64,
    summary: &'a [SummaryRow],
}

/// One row of Table III: a log (or `all`) and a method.
#[derive(Clone, Debug, Serialize)]
struct SummaryRow {
    log: String,
    method: String,
    valid: usize,
    invalid: usize,
    unlabelled: usize,
    /// ROC AUC, invalid merges positive; `None` without both labels.
    auc: Option<f64>,
    /// Mean wall time per new vertex (ms) over every vertex of every case.
    ms_per_vertex: Option<f64>,
    vertices: usize,
    /// Mean highest invalidity of the valid and of the invalid cases.
    mean_valid: Option<f64>,
    mean_invalid: Option<f64>,
    /// ROC AUC of the valid cases against the invalid cases of each kind.
    auc_by_kind: BTreeMap<String, Option<f64>>,
    /// Valid and invalid cases that were never supported after the merge.
    unsupported: [usize; 2],
}

fn summary_row(log: &str, method: &str, results: &[&MergeResult]) -> SummaryRow {
    let of = |label| -> Vec<f64> {
        results
            .iter()
            .filter(|r| r.label == Some(label))
            .map(|r| r.max_invalidity)
            .collect()
    };
    let (valid, invalid) = (of(Label::Valid), of(Label::Invalid));
    let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
    let vertices: usize = results.iter().map(|r| r.vertices).sum();
    let ms: f64 = results
        .iter()
        .map(|r| r.ms_per_vertex.unwrap_or(0.0) * r.vertices as f64)
        .sum();
    let mut auc_by_kind = BTreeMap::new();
    for r in results.iter().filter(|r| r.label == Some(Label::Invalid)) {
        auc_by_kind.entry(r.kind.clone()).or_insert_with(|| {
            let of_kind: Vec<f64> = results
                .iter()
                .filter(|o| o.label == Some(Label::Invalid) && o.kind == r.kind)
                .map(|o| o.max_invalidity)
                .collect();
            roc_auc(&of_kind, &valid)
        });
    }
    SummaryRow {
        log: log.to_owned(),
        method: method.to_owned(),
        valid: valid.len(),
        invalid: invalid.len(),
        unlabelled: results.iter().filter(|r| r.label.is_none()).count(),
        auc: roc_auc(&invalid, &valid),
        ms_per_vertex: (vertices > 0).then(|| ms / vertices as f64),
        vertices,
        mean_valid: mean(&valid),
        mean_invalid: mean(&invalid),
        auc_by_kind,
        unsupported: [Label::Valid, Label::Invalid].map(|label| {
            results
                .iter()
                .filter(|r| r.label == Some(label) && r.unsupported())
                .count()
        }),
    }
}

/// Rows per log and method, then `all` (every case pooled) per method.
fn summarise(results: &[MergeResult], methods: &[String]) -> Vec<SummaryRow> {
    let mut by_log: BTreeMap<String, Vec<&MergeResult>> = BTreeMap::new();
    for r in results {
        by_log.entry(log_name(&r.log)).or_default().push(r);
    }
    let mut rows = Vec::new();
    for (log, results) in &by_log {
        for method in methods {
            let mine: Vec<&MergeResult> = results
                .iter()
                .copied()
                .filter(|r| &r.method == method)
                .collect();
            rows.push(summary_row(log, method, &mine));
        }
    }
    if by_log.len() > 1 {
        for method in methods {
            let mine: Vec<&MergeResult> = results.iter().filter(|r| &r.method == method).collect();
            rows.push(summary_row("all", method, &mine));
        }
    }
    rows
}

/// Holoch et al., Table III: (method, MIT Stata AUC, ms, Flats and Offices AUC, ms).
const PAPER_TABLE_III: [(&str, f64, f64, f64, f64); 4] = [
    ("change_detection", 0.987, 11.87, 0.974, 8.10),
    ("gridmap", 0.994, 42.38, 0.971, 6.75),
    ("entropy", 0.701, 998.40, 0.725, 2376.48),
    ("histogram", 0.671, 0.518, 0.808, 0.700),
];

fn summary_markdown(rows: &[SummaryRow], seconds: f64) -> String {
    let mut md = String::new();
    let _ = writeln!(
        md,
        "| log | method | valid / invalid | AUC | AUC by kind | mean ms per new vertex | vertices | mean max. invalidity valid / invalid | paper AUC (MIT Stata / Flats and Offices) | paper ms (MIT Stata / Flats and Offices) |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|---|---|---|---|");
    let f3 = |v: Option<f64>| v.map_or("–".to_owned(), |v| format!("{v:.3}"));
    for row in rows {
        let paper = PAPER_TABLE_III.iter().find(|p| p.0 == row.method);
        let (paper_auc, paper_ms) = paper.map_or(("–".to_owned(), "–".to_owned()), |p| {
            (
                format!("{:.3} / {:.3}", p.1, p.3),
                format!("{} / {}", p.2, p.4),
            )
        });
        let by_kind = row
            .auc_by_kind
            .iter()
            .map(|(kind, auc)| format!("{kind} {}", f3(*auc)))
            .collect::<Vec<_>>()
            .join(", ");
        let _ = writeln!(
            md,
            "| {} | {} | {} / {}{}{} | {} | {by_kind} | {} | {} | {} / {} | {paper_auc} | {paper_ms} |",
            row.log,
            row.method,
            row.valid,
            row.invalid,
            if row.unlabelled > 0 {
                format!(" (+{} unlabelled)", row.unlabelled)
            } else {
                String::new()
            },
            if row.unsupported != [0, 0] {
                format!(
                    " (unsupported {} / {})",
                    row.unsupported[0], row.unsupported[1]
                )
            } else {
                String::new()
            },
            f3(row.auc),
            row.ms_per_vertex
                .map_or("–".to_owned(), |v| format!("{v:.3}")),
            row.vertices,
            f3(row.mean_valid),
            f3(row.mean_invalid),
        );
    }
    let _ = writeln!(
        md,
        "\nAUC: ROC area with invalid merges as positives, scored by each method's highest \
         invalidity ratio after the merge (Holoch et al., Sec. V-A); time: mean wall time of \
         one detector call per new vertex, one core. {seconds:.1} s in all."
    );
    md
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;

    /// [`evaluate_case`] with the default engine, no truth and no pictures.
    fn evaluate_with_defaults(
        first: &FirstSegment,
        log: &LaserLog,
        case: &MergeCase,
        detectors: &mut [Box<dyn InvalidMergeDetector>],
    ) -> Vec<Outcome> {
        evaluate_case(
            first,
            log,
            None,
            case,
            detectors,
            None,
            &EngineParams::default(),
        )
        .unwrap()
    }

    fn case() -> MergeCase {
        MergeCase {
            id: "x/s000-s001/valid".into(),
            log: "intel.log".into(),
            first: [0, 9],
            second: [10, 29],
            merge_at: 12,
            merge_transform: [1.0, -2.0, 0.5],
            odometry_noise: Some("default".into()),
            seed: 3,
            label: Some(Label::Valid),
            kind: None,
            merge_place: None,
        }
    }

    #[test]
    fn a_case_round_trips_with_exactly_the_format_fields() {
        let c = case();
        let text = serde_json::to_string(&c).unwrap();
        assert_eq!(
            text,
            r#"{"id":"x/s000-s001/valid","log":"intel.log","first":[0,9],"second":[10,29],"merge_at":12,"merge_transform":[1.0,-2.0,0.5],"odometry_noise":"default","seed":3,"label":"valid"}"#
        );
        let parsed = parse_cases(&format!("{text}\n\n"), "c").unwrap();
        assert_eq!(parsed, vec![(1, c)]);
        let null = r#"{"id":"a","log":"l","first":[0,1],"second":[2,3],"merge_at":2,"merge_transform":[0,0,0],"odometry_noise":null,"seed":0,"label":null}"#;
        let parsed = parse_cases(null, "c").unwrap();
        assert_eq!(parsed[0].1.odometry_noise, None);
        assert_eq!(parsed[0].1.label, None);
        assert_eq!(parsed[0].1.kind(), "a");
        // A merge-place case.
        let mut c = case();
        c.kind = Some("rotation".into());
        c.merge_place = Some(MergePlace {
            first_scan: 4,
            relative: [0.5, 0.0, 3.0],
        });
        let text = serde_json::to_string(&c).unwrap();
        assert!(
            text.ends_with(r#""label":"valid","kind":"rotation","merge_place":{"first_scan":4,"relative":[0.5,0.0,3.0]}}"#),
            "{text}"
        );
        assert_eq!(parse_cases(&text, "c").unwrap(), vec![(1, c)]);
    }

    #[test]
    fn bad_cases_name_the_line_and_reason() {
        let good = serde_json::to_string(&case()).unwrap();
        let with = |f: &dyn Fn(&mut MergeCase)| {
            let mut c = case();
            f(&mut c);
            serde_json::to_string(&c).unwrap()
        };
        let cases = [
            (format!("{good}\n{{\"id\": 1"), "c:2: not a merge case"),
            (
                with(&|c| c.merge_at = 30),
                "c:1: merge_at 30 is not a scan of second",
            ),
            (with(&|c| c.first = [5, 4]), "c:1: first [5, 4] ends before"),
            (
                with(&|c| c.odometry_noise = Some("loud".into())),
                "c:1: odometry_noise",
            ),
            (format!("{good}\n{good}"), "c:2: duplicate id"),
            (
                with(&|c| {
                    c.merge_place = Some(MergePlace {
                        first_scan: 10,
                        relative: [0.0; 3],
                    })
                }),
                "c:1: merge_place.first_scan 10 is not a scan of first",
            ),
            (
                with(&|c| {
                    c.merge_place = Some(MergePlace {
                        first_scan: 3,
                        relative: [f64::NAN, 0.0, 0.0],
                    })
                }),
                // JSON has no NaN: it is written as null, which is no number.
                "c:1: not a merge case",
            ),
        ];
        for (text, expected) in cases {
            let err = parse_cases(&text, "c").unwrap_err();
            assert!(err.starts_with(expected), "{err} vs {expected}");
        }
        let err = check_in_log(&case(), 20, Path::new("l")).unwrap_err();
        assert!(
            err.starts_with("second [10, 29] is beyond the 20 scans"),
            "{err}"
        );
    }

    #[test]
    fn segments_follow_time_or_count() {
        let stamps: Vec<f64> = (0..100).map(|k| f64::from(k) * 3.0).collect();
        assert!(stamps_usable(&stamps));
        let segments = cut_segments(&stamps, 100.0, None);
        assert_eq!(segments[0], [0, 33]);
        assert_eq!(segments.last().unwrap()[1], 99);
        // 100 scans in 34s: 2 full segments and a remainder of 32 (kept, ≥ half).
        assert_eq!(segments.len(), 3);
        assert!(!stamps_usable(&[0.0; 10]));
        assert!(!stamps_usable(&[0.0, 1.0, 4.29e9, 3.0]));
        let segments = cut_segments(&[0.0; 45], 100.0, Some(20));
        assert_eq!(segments, vec![[0, 19], [20, 44]]);
        // By travel: 0.5 m per scan, 10 m segments are 20 scans; a 15-scan rest stays.
        let poses: Vec<Se2> = (0..75)
            .map(|k| Se2::new(0.5 * f64::from(k), 0.0, 0.0))
            .collect();
        assert_eq!(
            segments_by_travel(&poses, 10.0, None),
            vec![[0, 19], [20, 39], [40, 59], [60, 74]]
        );
        // A rest shorter than half a segment joins the last.
        assert_eq!(
            segments_by_travel(&poses[..65], 10.0, None),
            vec![[0, 19], [20, 39], [40, 64]]
        );
        // A jump (a kidnap, the next session) ends a segment and is no travel; a short rest
        // before it joins its stretch's last segment, nothing joins across it.
        let mut jumped = poses[..25].to_vec();
        jumped.extend((0..30).map(|k| Se2::new(100.0 + 0.5 * f64::from(k), 5.0, 0.0)));
        assert_eq!(
            segments_by_travel(&jumped, 10.0, Some(2.0)),
            vec![[0, 24], [25, 44], [45, 54]]
        );
    }

    /// A detector that reports, at the first vertex after the merge only, how far the newest
    /// current scan is from the nearest other-epoch scan (÷ 10 m, at most 1).
    #[derive(Default)]
    struct FirstDistance {
        seen: bool,
    }

    impl InvalidMergeDetector for FirstDistance {
        fn name(&self) -> &'static str {
            "first-distance"
        }
        fn on_merge(&mut self, _: &MergedMap<'_>) {
            self.seen = false;
        }
        fn on_vertex(&mut self, map: &MergedMap<'_>) -> f64 {
            if std::mem::replace(&mut self.seen, true) {
                return 0.0;
            }
            let Some(newest) = map.current.iter().max_by_key(|s| s.node) else {
                return 0.0;
            };
            let nearest = map
                .other
                .iter()
                .map(|o| {
                    (o.map_from_robot.translation() - newest.map_from_robot.translation()).norm()
                })
                .fold(f64::INFINITY, f64::min);
            (nearest / 10.0).min(1.0)
        }
    }

    #[test]
    fn the_first_segment_is_placed_by_the_inverse_transform() {
        // One simulated session without kidnaps; the segments overlap in the middle.
        let params = mapmerge_sim::SimParams {
            sessions: 1,
            duration_secs: 60.0,
            kidnap: mapmerge_sim::KidnapParams {
                max_per_session: 0,
                ..Default::default()
            },
            ..Default::default()
        };
        let dataset = mapmerge_sim::simulate(&params, 5).unwrap();
        let session = &dataset.sessions[0];
        let n = session.log.scans.len();
        let (first, second) = ([0, 3 * n / 4], [n / 4, n - 1]);
        let truth = |k: usize| session.truth[k].1;
        let first_from_second = truth(first[0]).between(&truth(second[0]));
        let first_run = run_first_segment(&session.log, first).unwrap();
        let mut c = case();
        c.first = first;
        c.second = second;
        c.merge_at = n / 4 + 30;
        c.merge_transform = array_of(&first_from_second);
        let mut detectors: Vec<Box<dyn InvalidMergeDetector>> =
            vec![Box::new(FirstDistance::default())];
        let right = evaluate_with_defaults(&first_run, &session.log, &c, &mut detectors);
        assert!(right[0].vertices > 10, "{right:?}");
        assert!(right[0].max_invalidity < 0.05, "{right:?}");
        c.merge_transform = array_of(&first_from_second.compose(&Se2::new(-30.0, 0.0, 0.0)));
        let wrong = evaluate_with_defaults(&first_run, &session.log, &c, &mut detectors);
        assert!(wrong[0].max_invalidity > 0.9, "{wrong:?}");

        // At the merge place: the relative pose decides, whatever `merge_transform` says.
        let poses: Vec<Se2> = (0..n).map(truth).collect();
        let (filter, matcher) = (
            BeamFilter::default(),
            mapmerge_scanmatch::ScanMatcher::default(),
        );
        let place = MergePlaceCases::new(
            &poses,
            &session.log.scans,
            [first, second],
            c.merge_at,
            &filter,
            &matcher,
        );
        let true_relative = place.truth();
        let start_frames = place.start_frames(&true_relative);
        let error = start_frames.between(&first_from_second);
        assert!(error.translation().norm() < 1e-9 && error.theta_rad.abs() < 1e-9);
        c.merge_place = Some(MergePlace {
            first_scan: place.first_scan,
            relative: array_of(&true_relative),
        });
        let right = evaluate_with_defaults(&first_run, &session.log, &c, &mut detectors);
        assert!(right[0].max_invalidity < 0.05, "{right:?}");
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let kinds = place.cases(&mut rng);
        let names: Vec<&str> = kinds.iter().map(|(k, _)| *k).collect();
        assert_eq!(&names[..3], ["valid", "rotation", "shift"]);
        for (kind, relative) in &kinds[1..] {
            assert!(
                far_from(&true_relative, relative, &Se2::identity(), WRONG_BEYOND),
                "{kind} {relative:?} is right"
            );
        }
        let turn = wrap_angle_rad(kinds[1].1.theta_rad - true_relative.theta_rad);
        assert!(((turn / std::f64::consts::FRAC_PI_2).round().abs() - 1.0).abs() <= 1.0);
        assert!(
            (turn / std::f64::consts::FRAC_PI_2 - (turn / std::f64::consts::FRAC_PI_2).round())
                .abs()
                < 1e-9
        );
        let shift = true_relative.between(&kinds[2].1);
        assert!(
            (2.0..=8.0).contains(&shift.translation().norm()),
            "{shift:?}"
        );
        c.merge_place = Some(MergePlace {
            first_scan: place.first_scan,
            relative: array_of(&true_relative.compose(&Se2::new(-30.0, 0.0, 0.0))),
        });
        c.merge_transform = array_of(&first_from_second);
        let wrong = evaluate_with_defaults(&first_run, &session.log, &c, &mut detectors);
        assert!(wrong[0].max_invalidity > 0.9, "{wrong:?}");
    }
}

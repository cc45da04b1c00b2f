//! `mapmerge eval …`: inputs and scores for evaluating a SLAM front-end on the public corrected
//! laser logs.
//!
//! - `add-noise LOG -o NOISY.log`: the log with seeded, drifting odometry instead of the
//!   corrected poses (`mapmerge_eval::add_odometry_noise`), plus the noisy odometry's own error.
//! - `make-relations LOG -o RELATIONS`: Kümmerle et al. (2009) relations from a corrected log's
//!   scan poses (`mapmerge_eval::make_relations`).
//! - `relations --trajectory T --relations R`: the relations error of a trajectory.
//! - `ate --trajectory T --reference REF`: ATE (after rigid alignment) and RPE.
//!
//! Trajectories are keyed by scan index: a TUM file's line `k` is scan `k` (its stamps are
//! ignored), a CARMEN log gives its scans' poses.
//!
//! Relation files (one relation per line, `#` comments and blank lines skipped):
//! - Freiburg form (Kümmerle et al.'s published `*.relations`): `stamp1 stamp2 x y z roll pitch
//!   yaw`, the pose of the scan at `stamp2` in the frame of the scan at `stamp1`; planar, so
//!   `z`, `roll`, `pitch` are 0 (`z` is ignored; roll or pitch beyond 1e-6 rad is an error). A
//!   stamp names the scan of the log whose stamp is within 1 ms of it, so reading and writing
//!   this form needs a log whose scan stamps are finite and pairwise more than 2 ms apart
//!   (they need not increase: intel has one step back).
//! - Index-keyed form: the first line is [`INDEX_HEADER`], then `i j x y 0 0 0 yaw` with scan
//!   indices `i`, `j` (from 0, file order of the log's scans). Logs with broken stamps
//!   (constant, duplicate or bogus) must use this form.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Args, Subcommand};
use mapmerge_eval::{
    add_odometry_noise, attach_stamps, make_relations, make_relations_with_info, relations_error,
    scan_poses, trajectory_report, OdometryNoiseProfile, Relation, RelationsError, RelationsInfo,
    RelationsParams, RpeDelta, TrajectoryReport, DEFAULT_RPE_DELTAS,
};
use mapmerge_geometry::Se2;
use serde::Serialize;

use crate::{bad_file, bad_input, print_json};

/// The first line of an index-keyed relations file.
pub const INDEX_HEADER: &str = "# mapmerge relations keyed by scan index";

/// Stamps within this many seconds of a scan's stamp name that scan.
const STAMP_TOLERANCE_SECS: f64 = 1e-3;

/// Roll and pitch beyond this (rad) make a relation non-planar.
const PLANAR_TOLERANCE_RAD: f64 = 1e-6;

/// Arguments of `mapmerge eval`.
#[derive(Args, Debug)]
pub struct EvalArgs {
    #[command(subcommand)]
    command: EvalCommand,
}

#[derive(Subcommand, Debug)]
enum EvalCommand {
    /// Replace a corrected log's odometry by seeded, drifting wheel odometry (for SLAM tests).
    AddNoise(AddNoiseArgs),
    /// Write Kümmerle et al. (2009) relations from a corrected log's scan poses.
    MakeRelations(MakeRelationsArgs),
    /// Score a trajectory (one pose per scan) with a relations file (Kümmerle et al. 2009).
    Relations(RelationsArgs),
    /// Absolute trajectory error (after rigid alignment) and relative pose error.
    Ate(AteArgs),
    /// Andersone's grid-merge experiment (Tables 1–4) and ROC/AUC of SM and DM on a log.
    GridMerge(crate::grid_merge_eval::GridMergeEvalArgs),
    /// Holoch et al.'s invalid-merge cases from a corrected log: segment pairs, valid and wrong merges.
    MakeMergeCases(crate::invalid_merge_eval::MakeMergeCasesArgs),
    /// Run the invalid-merge detectors on forced merges (Holoch et al. Table III: AUC, ms/vertex).
    InvalidMerge(crate::invalid_merge_eval::InvalidMergeArgs),
    /// Leave-one-log-out calibration of the invalid-merge decision on `invalid-merge` results:
    /// per held-out log the single detectors and the learned combination; writes the model.
    Calibrate(crate::calibrate_eval::CalibrateArgs),
    /// Score the assembly of `mapmerge split` segments against their kept-apart truth (loop
    /// edge precision/recall, groups, ATE per group, order invariance).
    Assemble(crate::assemble_eval::AssembleEvalArgs),
    /// The erroneous-protrusion detector (iRobot Sec. 5.4) on simulated slips and new space:
    /// trained on tuning seeds, scored on held-out seeds.
    Protrusions(crate::protrusion_eval::ProtrusionEvalArgs),
    /// Door-passing detection (Ehlers et al. Sec. II-B) against the simulator's doors:
    /// precision and recall within 1 m of the true door, time per scan.
    Doors(crate::door_eval::DoorEvalArgs),
    /// The map manager's global tracking and topological loop closure on long simulated
    /// tours: door revisits found, closures true, link-point ATE.
    Areas(crate::areas_eval::AreasEvalArgs),
    /// The lifelong engine under real conditions: corrected logs as kidnapped robots with
    /// noisy odometry recorded them (seeded), and simulated worlds, judged from each run's
    /// per-map trajectories (merged and placed, misplaced, where lost, relocalization).
    Lifelong(crate::lifelong_eval::LifelongEvalArgs),
    /// How two maps of one resolution agree, cell by cell by place (a live node's `/map`
    /// against `slam`'s map of the same data): cells known in either, and of the same class.
    MapAgreement(crate::live_judge::MapAgreementArgs),
}

/// Arguments of `mapmerge eval add-noise`.
#[derive(Args, Debug)]
struct AddNoiseArgs {
    /// Corrected CARMEN log (`.xz` accepted); every scan must carry a pose.
    log: PathBuf,
    /// Output CARMEN log (`ODOM` + `ROBOTLASER1`; `.xz` compresses).
    #[arg(short, long)]
    output: PathBuf,
    /// Noise profile: default, harsh or none.
    #[arg(long, default_value = "default")]
    profile: String,
    /// Seed of the noise (ChaCha8).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// Arguments of `mapmerge eval make-relations`.
#[derive(Args, Debug)]
struct MakeRelationsArgs {
    /// Corrected CARMEN log whose scan poses are the reference.
    log: PathBuf,
    /// Output relations file.
    #[arg(short, long)]
    output: PathBuf,
    /// Write scan indices instead of stamps (required for logs with broken stamps).
    #[arg(long)]
    index_keyed: bool,
    /// Pairs at most this far apart (m).
    #[arg(long, default_value_t = RelationsParams::default().max_distance_m)]
    max_distance: f64,
    /// Pairs at least this far apart along the path (m) are loop relations.
    #[arg(long, default_value_t = RelationsParams::default().loop_min_path_m)]
    loop_min_path: f64,
    /// At most this many local relations.
    #[arg(long, default_value_t = RelationsParams::default().max_local)]
    max_local: usize,
    /// At most this many loop relations.
    #[arg(long, default_value_t = RelationsParams::default().max_loop)]
    max_loop: usize,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// Arguments of `mapmerge eval relations`.
#[derive(Args, Debug)]
struct RelationsArgs {
    /// Trajectory to score: TUM (line k = scan k) or a CARMEN log (its scan poses).
    #[arg(long)]
    trajectory: Option<PathBuf>,
    /// CARMEN log: scored itself when no --trajectory is given; its scan stamps map a
    /// stamp-keyed relations file to scan indices.
    #[arg(long)]
    log: Option<PathBuf>,
    /// Relations file (Freiburg stamp form or index-keyed).
    #[arg(long)]
    relations: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// Arguments of `mapmerge eval ate`.
#[derive(Args, Debug)]
struct AteArgs {
    /// Estimated trajectory: TUM (line k = scan k) or a CARMEN log (its scan poses).
    #[arg(long)]
    trajectory: PathBuf,
    /// Reference: TUM or a corrected CARMEN log, one pose per scan.
    #[arg(long)]
    reference: PathBuf,
    /// RPE between scan i and scan i + N.
    #[arg(long, default_value_t = 1)]
    rpe_delta: usize,
    /// RPE over this much path (m).
    #[arg(long, default_value_t = 5.0)]
    rpe_distance: f64,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// Runs `mapmerge eval …`.
pub fn run(args: &EvalArgs) -> anyhow::Result<ExitCode> {
    match &args.command {
        EvalCommand::AddNoise(a) => add_noise(a),
        EvalCommand::MakeRelations(a) => make(a),
        EvalCommand::Relations(a) => score_relations(a),
        EvalCommand::Ate(a) => ate(a),
        EvalCommand::GridMerge(a) => crate::grid_merge_eval::run(a),
        EvalCommand::MakeMergeCases(a) => crate::invalid_merge_eval::make_merge_cases(a),
        EvalCommand::InvalidMerge(a) => crate::invalid_merge_eval::invalid_merge(a),
        EvalCommand::Calibrate(a) => crate::calibrate_eval::calibrate(a),
        EvalCommand::Assemble(a) => crate::assemble_eval::run(a),
        EvalCommand::Protrusions(a) => crate::protrusion_eval::run(a),
        EvalCommand::Doors(a) => crate::door_eval::run(a),
        EvalCommand::Areas(a) => crate::areas_eval::run(a),
        EvalCommand::Lifelong(a) => crate::lifelong_eval::run(a),
        EvalCommand::MapAgreement(a) => crate::live_judge::map_agreement(a),
    }
    .map(|()| ExitCode::SUCCESS)
}

/// Poses keyed by scan index, and the scans' stamps when they came from a log.
struct Trajectory {
    poses: Vec<Se2>,
    stamps: Option<Vec<f64>>,
}

fn is_tum(path: &Path) -> bool {
    let name = path.to_string_lossy();
    let name = name.strip_suffix(".xz").unwrap_or(&name);
    name.ends_with(".tum") || name.ends_with(".txt")
}

/// A CARMEN log and its scan poses (bad input when a scan has none).
fn read_log(path: &Path) -> anyhow::Result<(mapmerge_scan::LaserLog, Vec<Se2>)> {
    let log = crate::read_log(path, &crate::BagTopics::default())?;
    let poses = scan_poses(&log).map_err(|e| bad_input(format!("{}: {e}", path.display())))?;
    Ok((log, poses))
}

/// A trajectory from a TUM file (`.tum`/`.txt`) or a CARMEN log.
fn load_trajectory(path: &Path) -> anyhow::Result<Trajectory> {
    if is_tum(path) {
        let poses = mapmerge_io::read_tum_planar(path)
            .map_err(bad_file)?
            .into_iter()
            .map(|(_, pose)| pose)
            .collect();
        Ok(Trajectory {
            poses,
            stamps: None,
        })
    } else {
        let (log, poses) = read_log(path)?;
        Ok(Trajectory {
            poses,
            stamps: Some(log.scans.iter().map(|r| r.stamp_secs).collect()),
        })
    }
}

/// The scans' `(stamp, index)` sorted by stamp, or `Err(reason)` naming two scans whose
/// stamps cannot be told apart (within 2 ms, or not finite).
fn stamp_index(stamps: &[f64]) -> Result<Vec<(f64, usize)>, String> {
    if let Some(k) = stamps.iter().position(|s| !s.is_finite()) {
        return Err(format!(
            "scan {k} has stamp {}; use the index-keyed relations form \
             (make-relations --index-keyed)",
            stamps[k]
        ));
    }
    let mut sorted: Vec<(f64, usize)> = stamps.iter().copied().zip(0..).collect();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    for pair in sorted.windows(2) {
        if pair[1].0 - pair[0].0 <= 2.0 * STAMP_TOLERANCE_SECS {
            return Err(format!(
                "scans {} and {} have stamps {} and {}, which cannot be told apart; use the \
                 index-keyed relations form (make-relations --index-keyed)",
                pair[0].1, pair[1].1, pair[0].0, pair[1].0
            ));
        }
    }
    Ok(sorted)
}

// ------------------------------------------------------------------ relations files

/// The text of a relations file, index-keyed or in the Freiburg stamp form (stamps must be set).
fn format_relations(relations: &[Relation], index_keyed: bool) -> Result<String, String> {
    let mut out = String::with_capacity(relations.len() * 64 + 64);
    if index_keyed {
        out.push_str(INDEX_HEADER);
        out.push('\n');
    }
    for (n, r) in relations.iter().enumerate() {
        let t = &r.from_to;
        if index_keyed {
            let _ = write!(out, "{} {}", r.from, r.to);
        } else {
            match (r.from_stamp_secs, r.to_stamp_secs) {
                (Some(a), Some(b)) => {
                    let _ = write!(out, "{a} {b}");
                }
                _ => return Err(format!("relation {n} has no stamps")),
            }
        }
        let _ = writeln!(out, " {} {} 0 0 0 {}", t.x_m, t.y_m, t.theta_rad);
    }
    Ok(out)
}

/// One line of a relations file before its keys are mapped to scan indices.
struct RelationLine {
    line: usize,
    keys: [f64; 2],
    from_to: Se2,
}

/// Parses a relations file: `(index_keyed, lines)`; errors are `source:line: reason`.
fn parse_relations(text: &str, source: &str) -> Result<(bool, Vec<RelationLine>), String> {
    let mut index_keyed = false;
    let mut lines = Vec::new();
    for (number, raw) in text.lines().enumerate() {
        let number = number + 1;
        let line = raw.trim();
        if line.is_empty() {
            continue;
        }
        if line.starts_with('#') {
            if line == INDEX_HEADER {
                if !lines.is_empty() {
                    return Err(format!(
                        "{source}:{number}: the index-keyed header must come before any relation"
                    ));
                }
                index_keyed = true;
            }
            continue;
        }
        let fields: Vec<&str> = line.split_ascii_whitespace().collect();
        let fail = |reason: String| format!("{source}:{number}: {reason}");
        if fields.len() != 8 {
            let what = if index_keyed { "i j" } else { "stamp1 stamp2" };
            return Err(fail(format!(
                "expected 8 fields ({what} x y z roll pitch yaw), found {}",
                fields.len()
            )));
        }
        let mut keys = [0.0; 2];
        for (slot, (k, field)) in keys.iter_mut().zip(fields.iter().enumerate()) {
            *slot = if index_keyed {
                field
                    .parse::<u32>()
                    .map(f64::from)
                    .map_err(|_| fail(format!("field {} `{field}` is not a scan index", k + 1)))?
            } else {
                match field.parse::<f64>() {
                    Ok(v) if v.is_finite() => v,
                    _ => {
                        return Err(fail(format!(
                            "field {} `{field}` is not a finite stamp",
                            k + 1
                        )))
                    }
                }
            };
        }
        let mut pose = [0.0; 6];
        for (k, slot) in pose.iter_mut().enumerate() {
            let field = fields[k + 2];
            *slot = match field.parse::<f64>() {
                Ok(v) if v.is_finite() => v,
                _ => {
                    return Err(fail(format!(
                        "field {} `{field}` is not a finite number",
                        k + 3
                    )))
                }
            };
        }
        let [x, y, _z, roll, pitch, yaw] = pose;
        if roll.abs() > PLANAR_TOLERANCE_RAD || pitch.abs() > PLANAR_TOLERANCE_RAD {
            return Err(fail(format!(
                "roll {roll} / pitch {pitch} are not 0: not a planar relation"
            )));
        }
        lines.push(RelationLine {
            line: number,
            keys,
            from_to: Se2::new(x, y, yaw),
        });
    }
    Ok((index_keyed, lines))
}

/// The index of the scan whose stamp is within [`STAMP_TOLERANCE_SECS`] of `stamp`
/// (`sorted` from [`stamp_index`]).
fn scan_at(sorted: &[(f64, usize)], stamp: f64) -> Option<usize> {
    let k = sorted.partition_point(|&(s, _)| s < stamp);
    [k.checked_sub(1), Some(k)]
        .into_iter()
        .flatten()
        .filter_map(|i| sorted.get(i))
        .find(|(s, _)| (s - stamp).abs() <= STAMP_TOLERANCE_SECS)
        .map(|&(_, index)| index)
}

/// Reads a relations file; stamp-keyed files need `stamps` (the log's scan stamps) to map
/// stamps to scan indices.
fn read_relations(path: &Path, stamps: Option<&[f64]>) -> anyhow::Result<Vec<Relation>> {
    let source = path.display().to_string();
    let text = std::fs::read(path)
        .map_err(|e| bad_input(format!("{source}: cannot read: {e}")))
        .and_then(|bytes| {
            if bytes.starts_with(&[0xFD, b'7', b'z', b'X', b'Z']) {
                Err(bad_input(format!(
                    "{source}: xz-compressed relations files are not supported; decompress it"
                )))
            } else {
                String::from_utf8(bytes).map_err(|_| bad_input(format!("{source}: not UTF-8 text")))
            }
        })?;
    let (index_keyed, lines) = parse_relations(&text, &source).map_err(bad_input)?;
    if lines.is_empty() {
        return Err(bad_input(format!("{source}: no relations")));
    }
    let mut relations = Vec::with_capacity(lines.len());
    if index_keyed {
        for l in lines {
            relations.push(Relation {
                from: l.keys[0] as usize,
                to: l.keys[1] as usize,
                from_stamp_secs: None,
                to_stamp_secs: None,
                from_to: l.from_to,
            });
        }
        if let Some(stamps) = stamps {
            attach_stamps(&mut relations, stamps);
        }
        return Ok(relations);
    }
    let Some(stamps) = stamps else {
        return Err(bad_input(format!(
            "{source} is keyed by stamps: give --log LOG (the log whose scans the trajectory \
             follows) to map stamps to scan indices, or use an index-keyed relations file"
        )));
    };
    let sorted = stamp_index(stamps).map_err(|reason| {
        bad_input(format!(
            "{source} is keyed by stamps, but the log cannot map them: {reason}"
        ))
    })?;
    for l in lines {
        let mut index = [0usize; 2];
        for (slot, stamp) in index.iter_mut().zip(l.keys) {
            *slot = scan_at(&sorted, stamp).ok_or_else(|| {
                bad_input(format!(
                    "{source}:{}: no scan of the log has stamp {stamp} (±{STAMP_TOLERANCE_SECS} s)",
                    l.line
                ))
            })?;
        }
        relations.push(Relation {
            from: index[0],
            to: index[1],
            from_stamp_secs: Some(l.keys[0]),
            to_stamp_secs: Some(l.keys[1]),
            from_to: l.from_to,
        });
    }
    Ok(relations)
}

// ------------------------------------------------------------------ commands

#[derive(Serialize)]
struct AddNoiseReport<'a> {
    log: &'a Path,
    output: &'a Path,
    scans: usize,
    profile: &'a str,
    seed: u64,
    slips: usize,
    translation_scale: f64,
    rotation_scale: f64,
    /// The noisy odometry against the corrected poses (relations from `make_relations`
    /// with default parameters).
    odometry: TrajectoryReport,
}

fn add_noise(args: &AddNoiseArgs) -> anyhow::Result<()> {
    let profile = OdometryNoiseProfile::from_name(&args.profile).map_err(bad_input)?;
    let (log, corrected) = read_log(&args.log)?;
    if corrected.len() < 2 {
        return Err(bad_input(format!(
            "{}: {} scans; odometry noise needs at least 2",
            args.log.display(),
            corrected.len()
        )));
    }
    let noisy = add_odometry_noise(&log, &profile, args.seed)
        .map_err(|e| bad_input(format!("{}: {e}", args.log.display())))?;
    mapmerge_io::write_carmen(&args.output, &noisy.log)?;
    let relations = make_relations(&corrected, &RelationsParams::default())?;
    let odometry = trajectory_report(
        &corrected,
        &noisy.odometry_poses(),
        &relations,
        &DEFAULT_RPE_DELTAS,
    )?;
    let report = AddNoiseReport {
        log: &args.log,
        output: &args.output,
        scans: corrected.len(),
        profile: &args.profile,
        seed: args.seed,
        slips: noisy.slips.len(),
        translation_scale: noisy.translation_scale,
        rotation_scale: noisy.rotation_scale,
        odometry,
    };
    if args.json {
        print_json(&report)?;
    } else {
        println!(
            "{}: {} scans, profile {} seed {}, {} slips -> {}",
            args.log.display(),
            report.scans,
            args.profile,
            args.seed,
            report.slips,
            args.output.display()
        );
        print_report("noisy odometry", &report.odometry);
    }
    Ok(())
}

fn print_report(what: &str, report: &TrajectoryReport) {
    println!(
        "{what}: ATE rmse {:.4} m (mean {:.4}, max {:.4}) over {} poses",
        report.ate.rms_m, report.ate.mean_m, report.ate.max_m, report.ate.matched
    );
    for rpe in &report.rpe {
        let delta = match rpe.delta {
            RpeDelta::Scans(n) => format!("{n} scans"),
            RpeDelta::DistanceM(d) => format!("{d} m"),
        };
        println!(
            "  RPE over {delta}: {:.4} m, {:.3} deg rmse ({} pairs)",
            rpe.translation_rmse_m, rpe.rotation_rmse_deg, rpe.count
        );
    }
    if let Some(r) = &report.relations {
        print_relations(r);
    }
}

fn print_relations(r: &RelationsError) {
    println!(
        "  relations (Kümmerle et al. 2009, {} relations): {:.4} ± {:.4} m, {:.3} ± {:.3} deg \
         (squared: {:.5} m², {:.4} deg²)",
        r.count,
        r.translation_mean_m,
        r.translation_std_m,
        r.rotation_mean_deg,
        r.rotation_std_deg,
        r.translation_squared_mean_m2,
        r.rotation_squared_mean_deg2
    );
}

#[derive(Serialize)]
struct MakeRelationsReport<'a> {
    log: &'a Path,
    output: &'a Path,
    scans: usize,
    index_keyed: bool,
    relations: usize,
    info: RelationsInfo,
}

fn make(args: &MakeRelationsArgs) -> anyhow::Result<()> {
    let params = RelationsParams {
        max_distance_m: args.max_distance,
        loop_min_path_m: args.loop_min_path,
        max_local: args.max_local,
        max_loop: args.max_loop,
        ..RelationsParams::default()
    };
    let (log, corrected) = read_log(&args.log)?;
    let (mut relations, info) = make_relations_with_info(&corrected, &params).map_err(bad_input)?;
    if !args.index_keyed {
        let stamps: Vec<f64> = log.scans.iter().map(|r| r.stamp_secs).collect();
        stamp_index(&stamps).map_err(|reason| {
            bad_input(format!(
                "{}: cannot write stamp-keyed relations: {reason}",
                args.log.display()
            ))
        })?;
        attach_stamps(&mut relations, &stamps);
    }
    let text = format_relations(&relations, args.index_keyed).map_err(bad_input)?;
    std::fs::write(&args.output, text)
        .map_err(|e| anyhow::anyhow!("{}: cannot write: {e}", args.output.display()))?;
    let report = MakeRelationsReport {
        log: &args.log,
        output: &args.output,
        scans: corrected.len(),
        index_keyed: args.index_keyed,
        relations: relations.len(),
        info,
    };
    if args.json {
        print_json(&report)?;
    } else {
        println!(
            "{}: {} relations ({} local of {} candidates, {} loop of {}) -> {}",
            args.log.display(),
            report.relations,
            info.local,
            info.local_candidates,
            info.loops,
            info.loop_candidates,
            args.output.display()
        );
    }
    Ok(())
}

#[derive(Serialize)]
struct RelationsReport<'a> {
    trajectory: &'a Path,
    relations_file: &'a Path,
    poses: usize,
    #[serde(flatten)]
    error: RelationsError,
}

fn score_relations(args: &RelationsArgs) -> anyhow::Result<()> {
    let (trajectory, path) = match (&args.trajectory, &args.log) {
        (Some(path), _) | (None, Some(path)) => (load_trajectory(path)?, path.as_path()),
        (None, None) => return Err(bad_input("give --trajectory T or --log LOG to score")),
    };
    let log = match (&args.trajectory, &args.log) {
        (Some(_), Some(log_path)) => Some(load_trajectory(log_path)?),
        _ => None,
    };
    // Stamps: from --log when a separate trajectory is scored, else from the scored log.
    let stamps = match &log {
        Some(log) => {
            if log.poses.len() != trajectory.poses.len() {
                return Err(bad_input(format!(
                    "{} has {} poses but {} has {} scans (poses pair with scans by order)",
                    path.display(),
                    trajectory.poses.len(),
                    args.log.as_deref().unwrap_or(path).display(),
                    log.poses.len()
                )));
            }
            log.stamps.as_deref()
        }
        None => trajectory.stamps.as_deref(),
    };
    let relations = read_relations(&args.relations, stamps)?;
    let error = relations_error(&trajectory.poses, &relations).map_err(|e| {
        bad_input(format!(
            "{} on {}: {e}",
            args.relations.display(),
            path.display()
        ))
    })?;
    let report = RelationsReport {
        trajectory: path,
        relations_file: &args.relations,
        poses: trajectory.poses.len(),
        error,
    };
    if args.json {
        print_json(&report)?;
    } else {
        println!("{} ({} poses):", path.display(), report.poses);
        print_relations(&report.error);
    }
    Ok(())
}

#[derive(Serialize)]
struct AteReport<'a> {
    trajectory: &'a Path,
    reference: &'a Path,
    poses: usize,
    #[serde(flatten)]
    report: TrajectoryReport,
}

fn ate(args: &AteArgs) -> anyhow::Result<()> {
    if !(args.rpe_distance.is_finite() && args.rpe_distance > 0.0) || args.rpe_delta == 0 {
        return Err(bad_input(
            "--rpe-delta must be at least 1 and --rpe-distance a positive number of metres",
        ));
    }
    let estimate = load_trajectory(&args.trajectory)?;
    let reference = load_trajectory(&args.reference)?;
    if estimate.poses.len() != reference.poses.len() {
        return Err(bad_input(format!(
            "{} has {} poses, {} has {} (poses pair by scan index)",
            args.trajectory.display(),
            estimate.poses.len(),
            args.reference.display(),
            reference.poses.len()
        )));
    }
    let deltas = [
        RpeDelta::Scans(args.rpe_delta),
        RpeDelta::DistanceM(args.rpe_distance),
    ];
    let report = trajectory_report(&reference.poses, &estimate.poses, &[], &deltas)
        .map_err(|e| bad_input(format!("{}: {e}", args.trajectory.display())))?;
    let report = AteReport {
        trajectory: &args.trajectory,
        reference: &args.reference,
        poses: estimate.poses.len(),
        report,
    };
    if args.json {
        print_json(&report)?;
    } else {
        print_report(&args.trajectory.display().to_string(), &report.report);
    }
    Ok(())
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;

    fn relation(from: usize, to: usize, stamps: Option<(f64, f64)>) -> Relation {
        Relation {
            from,
            to,
            from_stamp_secs: stamps.map(|s| s.0),
            to_stamp_secs: stamps.map(|s| s.1),
            from_to: Se2::new(0.5, -0.25, 0.125),
        }
    }

    #[test]
    fn both_forms_round_trip() {
        let relations = vec![
            relation(0, 3, Some((1.5, 2.25))),
            relation(2, 7, Some((2.0, 4.5))),
        ];
        let text = format_relations(&relations, true).unwrap();
        assert!(text.starts_with(INDEX_HEADER));
        let (keyed, lines) = parse_relations(&text, "r").unwrap();
        assert!(keyed);
        assert_eq!(lines[1].keys, [2.0, 7.0]);
        assert_eq!(lines[1].from_to, relations[1].from_to);
        let text = format_relations(&relations, false).unwrap();
        let (keyed, lines) = parse_relations(&text, "r").unwrap();
        assert!(!keyed);
        assert_eq!(lines[0].keys, [1.5, 2.25]);
        let stamps = stamp_index(&[1.5, 1.75, 2.0, 2.25, 2.5, 3.0, 4.5, 4.0]).unwrap();
        assert_eq!(scan_at(&stamps, 2.2505), Some(3));
        assert_eq!(scan_at(&stamps, 4.5), Some(6));
        assert_eq!(scan_at(&stamps, 3.9995), Some(7));
        assert_eq!(scan_at(&stamps, 3.3), None);
        assert!(format_relations(&[relation(0, 1, None)], false).is_err());
    }

    #[test]
    fn parse_errors_name_file_and_line() {
        let cases = [
            ("1 2 0 0 0 0 0\n", "r:1: expected 8 fields"),
            (
                "# c\n\n1 2 0 0 0 0 0 x\n",
                "r:3: field 8 `x` is not a finite number",
            ),
            ("1 2 0 0 0 0.1 0 0\n", "r:1: roll 0.1"),
            (
                "# mapmerge relations keyed by scan index\n1.5 2 0 0 0 0 0 0\n",
                "r:2: field 1 `1.5` is not a scan index",
            ),
            (
                "nan 2 0 0 0 0 0 0\n",
                "r:1: field 1 `nan` is not a finite stamp",
            ),
            (
                "1 2 0 0 0 0 0 0\n# mapmerge relations keyed by scan index\n",
                "r:2: the index-keyed header",
            ),
        ];
        for (text, expected) in cases {
            let err = parse_relations(text, "r").err().unwrap();
            assert!(err.starts_with(expected), "{err} vs {expected}");
        }
        assert!(stamp_index(&[0.0, 1.0, 0.0]).is_err());
        assert!(stamp_index(&[0.0, f64::NAN]).is_err());
        assert!(stamp_index(&[1.0, 0.0]).is_ok());
    }
}

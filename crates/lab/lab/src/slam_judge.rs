//! `mapmerge slam --odometry-noise`: SLAM on a *corrected* public log judged against the log's
//! own poses. The log's odometry is replaced by seeded noisy wheel odometry first
//! ([`noisy_session`]); the run is then scored by ATE, RPE and Kümmerle et al.'s relations,
//! beside the noisy odometry's own score, and its loop edges are judged against the poses
//! ([`judge_slam`]).

use mapmerge_atlas::LoopSource;
use mapmerge_engine::SlamRun;
pub use mapmerge_eval::TrajectoryReport;
use mapmerge_eval::{
    add_odometry_noise, make_relations, scan_poses, trajectory_report, OdometryNoiseProfile,
    RelationsParams, DEFAULT_RPE_DELTAS,
};
use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::LaserLog;
use serde::Serialize;

/// A corrected session with noisy odometry: the log to run, and the poses to judge by.
pub struct NoisySession {
    /// The log with the noisy odometry in place of its poses.
    pub log: LaserLog,
    /// The log's own (corrected) pose of every scan: the reference.
    pub corrected: Vec<Se2>,
    /// The noisy odometry pose of every scan.
    pub odometry: Vec<Se2>,
}

/// `log` with its odometry replaced by the named noise profile (`default`, `harsh`, `none`)
/// drawn with `seed`; an error (bad input) names `name` or the first scan without a pose.
pub fn noisy_session(log: &LaserLog, name: &str, seed: u64) -> anyhow::Result<NoisySession> {
    let profile = OdometryNoiseProfile::from_name(name).map_err(crate::bad_input)?;
    let corrected = scan_poses(log).map_err(crate::bad_input)?;
    let noisy = add_odometry_noise(log, &profile, seed).map_err(crate::bad_input)?;
    Ok(NoisySession {
        odometry: noisy.odometry_poses(),
        corrected,
        log: noisy.log,
    })
}

/// A SLAM run judged against the corrected poses.
#[derive(Clone, Debug, Serialize)]
pub struct SlamScores {
    /// The SLAM trajectory's ATE, RPE and relations error.
    pub score: TrajectoryReport,
    /// The noisy odometry's, for comparison.
    pub odometry_score: TrajectoryReport,
    /// The accepted loop edges judged against the poses.
    pub loops: LoopPrecision,
}

/// Scores `run` (and the noisy odometry) against `session`'s corrected poses.
pub fn judge_slam(run: &SlamRun, session: &NoisySession) -> anyhow::Result<SlamScores> {
    let relations = make_relations(&session.corrected, &RelationsParams::default())?;
    Ok(SlamScores {
        score: trajectory_report(
            &session.corrected,
            &run.trajectory,
            &relations,
            &DEFAULT_RPE_DELTAS,
        )?,
        odometry_score: trajectory_report(
            &session.corrected,
            &session.odometry,
            &relations,
            &DEFAULT_RPE_DELTAS,
        )?,
        loops: loop_precision(run, &session.corrected),
    })
}

/// Accepted loop edges judged against reference poses: true when within 0.5 m and 10° of
/// the reference relative pose (the rule for a verified candidate).
#[derive(Clone, Debug, Serialize)]
pub struct LoopPrecision {
    pub accepted: usize,
    pub accepted_local: usize,
    pub accepted_place: usize,
    pub true_local: usize,
    pub true_place: usize,
    pub precision: Option<f64>,
    pub worst_translation_error_m: f64,
    pub worst_rotation_error_deg: f64,
    /// The loop edges that are not true, with their errors.
    pub false_loops: Vec<FalseLoop>,
}

/// A loop edge beyond 0.5 m or 10° of the reference.
#[derive(Clone, Debug, Serialize)]
pub struct FalseLoop {
    pub from: u64,
    pub to: u64,
    pub from_scan: usize,
    pub to_scan: usize,
    pub source: LoopSource,
    pub score: f64,
    pub translation_error_m: f64,
    pub rotation_error_deg: f64,
}

/// Judges every loop of `run` against `reference` (one pose per scan).
pub fn loop_precision(run: &SlamRun, reference: &[Se2]) -> LoopPrecision {
    let mut precision = LoopPrecision {
        accepted: run.loops.len(),
        accepted_local: 0,
        accepted_place: 0,
        true_local: 0,
        true_place: 0,
        precision: None,
        worst_translation_error_m: 0.0,
        worst_rotation_error_deg: 0.0,
        false_loops: Vec::new(),
    };
    let scan_of = |node: mapmerge_posegraph::NodeId| {
        run.keyframe_scans
            .get(usize::try_from(node.0).ok()?)
            .copied()
    };
    let pose_of = |node| reference.get(scan_of(node)?).copied();
    for record in &run.loops {
        let is_place = record.source == LoopSource::Place;
        if is_place {
            precision.accepted_place += 1;
        } else {
            precision.accepted_local += 1;
        }
        let (Some(from), Some(to)) = (pose_of(record.from), pose_of(record.to)) else {
            continue;
        };
        let error = from.between(&to).between(&record.measurement);
        let (translation_m, rotation_deg) = (
            error.translation().norm(),
            error.theta_rad.abs().to_degrees(),
        );
        precision.worst_translation_error_m =
            precision.worst_translation_error_m.max(translation_m);
        precision.worst_rotation_error_deg = precision.worst_rotation_error_deg.max(rotation_deg);
        if translation_m <= 0.5 && rotation_deg <= 10.0 {
            if is_place {
                precision.true_place += 1;
            } else {
                precision.true_local += 1;
            }
        } else {
            precision.false_loops.push(FalseLoop {
                from: record.from.0,
                to: record.to.0,
                from_scan: scan_of(record.from).unwrap_or_default(),
                to_scan: scan_of(record.to).unwrap_or_default(),
                source: record.source,
                score: record.score,
                translation_error_m: translation_m,
                rotation_error_deg: rotation_deg,
            });
        }
    }
    if precision.accepted > 0 {
        precision.precision =
            Some((precision.true_local + precision.true_place) as f64 / precision.accepted as f64);
    }
    precision
}

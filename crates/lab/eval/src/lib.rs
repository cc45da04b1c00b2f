//! Evaluation tools for mapmerge's back-end: corrupt a graph with false loop closures, score
//! which edges a robust optimiser rejected, measure trajectory error, and simulate a Manhattan
//! world with known ground truth.
//!
//! Entry points:
//! - [`add_false_loop_closures`]: vertigo's random outliers (Sünderhauf & Protzel, IROS 2012).
//!   `fraction` is the share of **all** loop closures that is false afterwards:
//!   `n_false = round(fraction / (1 − fraction) · n_true)` ([`false_loop_count`]), so 0.5 adds as
//!   many false loop closures as there are true ones. They are appended after every existing
//!   edge, so in a written file they are the edge lines with index ≥ the original edge count.
//! - [`precision_recall`]: rejected edges against the known false ones ([`RejectionScore`]).
//! - [`trajectory_error`]: RMS/mean/max position error over common vertex ids, optionally after
//!   the best rigid alignment ([`align_rigid`], Horn/Umeyama without scale).
//! - [`add_odometry_noise`]: seeded wheel-odometry noise (random, calibration, wheel slips) for
//!   a *corrected* laser log, so a SLAM front-end can be scored against the corrected poses
//!   ([`OdometryNoiseProfile`]: `default`, `harsh`, `none`). Re-exported from `mapmerge-sim`,
//!   which owns the one odometry model (the simulator's wheel odometry).
//! - [`make_relations`] / [`relations_error`]: the relations metric of Kümmerle et al. 2009
//!   ("On measuring the accuracy of SLAM algorithms"), with [`absolute_trajectory_error`] and
//!   [`relative_pose_error`] on scan-indexed planar trajectories ([`trajectory_report`]).
//! - [`roc_curve`] / [`roc_auc`]: ROC curves and their area (Mann–Whitney) for detectors that
//!   score cases, e.g. wrong merges against correct ones.
//! - [`simulate_manhattan_2d`]: a grid-world random walk with noisy odometry and loop closures
//!   ([`ManhattanParams`]).
//!
//! ```
//! use mapmerge_eval::{
//!     add_false_loop_closures, count_loop_closures, precision_recall, simulate_manhattan_2d,
//!     trajectory_error, ManhattanParams,
//! };
//! let params = ManhattanParams { num_poses: 200, ..Default::default() };
//! let (mut noisy, truth) = simulate_manhattan_2d(&params, 7).unwrap();
//! let true_loops = count_loop_closures(&noisy);
//! let false_edges = add_false_loop_closures(&mut noisy, 0.5, 42).unwrap();
//! assert_eq!(false_edges.len(), true_loops);
//!
//! // A detector that rejected exactly the false edges:
//! let score = precision_recall(&false_edges, &false_edges, true_loops);
//! assert_eq!((score.precision, score.recall, score.true_loops_kept), (1.0, 1.0, 1.0));
//!
//! // The odometry guess drifts away from the ground truth.
//! let ate = trajectory_error(&truth, &noisy, true).unwrap();
//! assert_eq!(ate.matched, 200);
//! assert!(ate.rms_m > 0.0);
//! ```
//!
//! Scoring a trajectory keyed by scan index (here: a circle and a copy of it with drift):
//!
//! ```
//! use mapmerge_eval::{absolute_trajectory_error, make_relations, relations_error, RelationsParams};
//! use mapmerge_geometry::Se2;
//! let truth: Vec<Se2> = (0..200)
//!     .map(|k| {
//!         let t = k as f64 * 0.063;
//!         Se2::new(5.0 * t.cos(), 5.0 * t.sin(), t + std::f64::consts::FRAC_PI_2)
//!     })
//!     .collect();
//! let drifted: Vec<Se2> = truth
//!     .iter()
//!     .enumerate()
//!     .map(|(k, p)| Se2::new(p.x_m * (1.0 + 1e-4 * k as f64), p.y_m, p.theta_rad))
//!     .collect();
//! let relations = make_relations(&truth, &RelationsParams::default()).unwrap();
//! assert!(relations_error(&truth, &relations).unwrap().translation_mean_m < 1e-12);
//! assert!(relations_error(&drifted, &relations).unwrap().translation_mean_m > 0.0);
//! assert!(absolute_trajectory_error(&truth, &drifted, true).unwrap().rms_m > 0.0);
//! ```

mod error;
mod outliers;
mod pose;
mod relations;
mod revisit;
mod roc;
mod score;
mod simulate;
mod trajectory;

pub use error::EvalError;
pub use mapmerge_sim::{
    add_odometry_noise, scan_poses, NoisyLog, OdometryNoiseParams, OdometryNoiseProfile, SlipEvent,
    SlipKind, SlipSchedule, SlipSpan, NOISE_PROFILE_NAMES,
};
pub use outliers::{
    add_false_loop_closures, add_false_loop_closures_with, count_loop_closures, false_loop_count,
    is_loop_closure, FalseLoopMeasurement, FalseLoopParams,
};
pub use pose::EvalPose;
pub use relations::{
    absolute_trajectory_error, attach_stamps, make_relations, make_relations_with_info,
    relations_error, relative_pose_error, rpe_relations, trajectory_report, Relation,
    RelationsError, RelationsInfo, RelationsParams, RelativePoseError, RpeDelta, TrajectoryReport,
    DEFAULT_RPE_DELTAS,
};
pub use revisit::revisit_travel_m;
pub use roc::{roc_auc, roc_curve, RocPoint};
pub use score::{precision_recall, RejectionScore};
pub use simulate::{simulate_manhattan_2d, ManhattanParams};
pub use trajectory::{align_rigid, trajectory_error, RigidTransform, TrajectoryError};

//! A laser log in memory: what a CARMEN file holds, format-independent.

use std::collections::BTreeMap;

use mapmerge_geometry::Se2;
use serde::{Deserialize, Serialize};

use crate::LaserScan;

/// One odometry message: the robot's pose in the odometry frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OdometryReading {
    /// Timestamp (s) as written in the log (see `LaserLog` for logs whose stamps are broken).
    pub stamp_secs: f64,
    /// Pose of the robot in the odometry frame.
    pub odom_from_robot: Se2,
    /// Translational velocity (m/s), 0 when the format has none.
    pub velocity_m_per_s: f64,
    /// Rotational velocity (rad/s), 0 when the format has none.
    pub turn_rate_rad_per_s: f64,
}

/// One scan with the robot pose the log attached to it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScanRecord {
    /// Timestamp (s) as written in the log.
    pub stamp_secs: f64,
    /// The scan (the sensor offset is in `scan.robot_from_sensor`).
    pub scan: LaserScan,
    /// Robot pose in the odometry frame when the scan was taken, if the message carries one
    /// (CARMEN `FLASER`/`ROBOTLASER1` do, `RAWLASER*` does not). In *corrected* logs this is
    /// the corrected pose.
    pub odom_from_robot: Option<Se2>,
    /// The message tag it came from (`FLASER`, `ROBOTLASER1`, ...).
    pub source_tag: String,
}

/// Everything read from a laser log, in file order.
///
/// Stamps are kept as written; some public logs have constant or bogus stamps, so code that
/// pairs scans with other data should key scans by their index in `scans`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LaserLog {
    /// Odometry messages in file order.
    pub odometry: Vec<OdometryReading>,
    /// Scans in file order.
    pub scans: Vec<ScanRecord>,
    /// `PARAM name value` lines (the last value wins).
    pub params: BTreeMap<String, String>,
    /// How many lines of each unknown message type were skipped.
    pub skipped_messages: BTreeMap<String, usize>,
}

impl LaserLog {
    /// Stamps (s) for the scans that strictly increase, as TUM files and bags need: the log's
    /// own when they do, else a clock of `period_secs` per scan from the first stamp (0 when
    /// that is not finite and non-negative), with the reason the log's own were replaced.
    pub fn increasing_scan_stamps(&self, period_secs: f64) -> (Vec<f64>, Option<String>) {
        let stamps: Vec<f64> = self.scans.iter().map(|record| record.stamp_secs).collect();
        let why = match stamps.iter().position(|t| !t.is_finite()) {
            Some(i) => Some(format!("scan {} is stamped {} s", i + 1, stamps[i])),
            None => stamps.windows(2).position(|w| w[1] <= w[0]).map(|i| {
                format!(
                    "the stamps do not increase at scan {} ({} s after {} s)",
                    i + 2,
                    stamps[i + 1],
                    stamps[i]
                )
            }),
        };
        match why {
            None => (stamps, None),
            Some(why) => {
                let start = stamps
                    .first()
                    .copied()
                    .filter(|t| t.is_finite() && *t >= 0.0)
                    .unwrap_or(0.0);
                let clock = (0..stamps.len())
                    .map(|k| start + k as f64 * period_secs)
                    .collect();
                (clock, Some(why))
            }
        }
    }

    /// Poses attached to the scans (`None` for scans without one), in scan order.
    pub fn scan_poses(&self) -> Vec<Option<Se2>> {
        self.scans
            .iter()
            .map(|record| record.odom_from_robot)
            .collect()
    }
}

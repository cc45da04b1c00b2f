//! Segments: one agent's or one session's trajectory with its observations (Yin et al.,
//! AutoMerge, Sec. III-A: the trajectory list `V_N`, each with odometry and 3-D observations).
//!
//! A segment lives in its own frame: the first scan's robot pose is the origin, because
//! segments arrive without any initial guess of where they are relative to each other. The 2D
//! path ([`Segment`]: laser scans + SE(2) poses) and the 3D path ([`Segment3`]: point clouds +
//! SE(3) poses) share every later stage through [`SegmentPoints`], which is all the submap
//! builder needs: how many scans, where each was taken, and its points in another scan's frame.

use mapmerge_geometry::{LieGroup, Se2, Se3};
use mapmerge_scan::{LaserLog, LaserScan, Point2};
use nalgebra::Vector3;

use crate::error::AssembleError;
use crate::submap::SubmapPoint;

pub use mapmerge_geometry::Point3;

/// What the submap builder reads from a segment, 2D or 3D.
pub trait SegmentPoints: Sync {
    /// The point type of the observations ([`Point2`] or [`Point3`]).
    type Point: SubmapPoint;
    /// The pose type (`Se2` or `Se3`).
    type Pose: Copy + Send + Sync + std::fmt::Debug;

    /// The segment's name (a file stem).
    fn name(&self) -> &str;

    /// Number of scans (or clouds).
    fn scan_count(&self) -> usize;

    /// `segment_from_robot` of scan `scan`, `None` out of range.
    fn pose(&self, scan: usize) -> Option<Self::Pose>;

    /// Position of the robot at scan `scan` in the segment frame (m; `z = 0` in 2D), `None`
    /// out of range. Travel along the trajectory is measured between these.
    fn position_m(&self, scan: usize) -> Option<Vector3<f64>>;

    /// Appends the obstacle points of scan `scan`, expressed in the robot frame of scan
    /// `centre`, whose horizontal range from that frame's origin is below `radius_m`. Out of
    /// range indices append nothing; non-finite points are dropped.
    fn push_points_in_centre(
        &self,
        centre: usize,
        scan: usize,
        radius_m: f64,
        out: &mut Vec<Self::Point>,
    );

    /// Position of scan `scan`'s sensor in the robot frame of scan `centre`, in the ground
    /// plane (m): where its beams start. `None` (the default) when the segment does not say,
    /// out of range, or for 3D clouds.
    fn sensor_in_centre(&self, centre: usize, scan: usize) -> Option<Point2> {
        let _ = (centre, scan);
        None
    }

    /// Cumulative translation along the trajectory at every scan (m, starting at 0).
    fn travel_m(&self) -> Vec<f64> {
        let mut travel = Vec::with_capacity(self.scan_count());
        let mut total_m = 0.0;
        let mut previous: Option<Vector3<f64>> = None;
        for scan in 0..self.scan_count() {
            let position = self.position_m(scan);
            if let (Some(a), Some(b)) = (previous, position) {
                let step_m = (b - a).norm();
                if step_m.is_finite() {
                    total_m += step_m;
                }
            }
            previous = position.or(previous);
            travel.push(total_m);
        }
        travel
    }
}

/// A 2D segment: laser scans with one robot pose each, in the segment frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Segment {
    /// Name (the file stem of the log it came from).
    pub name: String,
    /// Timestamp of every scan (s), as the log wrote it.
    pub stamps_secs: Vec<f64>,
    /// `segment_from_robot` of every scan; `poses[0]` is the identity.
    pub poses: Vec<Se2>,
    /// The scans (sensor frame, with their mounting pose).
    pub scans: Vec<LaserScan>,
}

impl Segment {
    /// A segment from a log's scans and one pose per scan in any frame (`odom_from_robot`:
    /// odometry, or a SLAM front-end's trajectory); the poses are re-based so the first scan
    /// is the origin. Fails when the counts differ, the log has no scans, or a pose is not
    /// finite.
    pub fn from_log(
        name: impl Into<String>,
        log: &LaserLog,
        odom_from_robot: &[Se2],
    ) -> Result<Self, AssembleError> {
        let name = name.into();
        if log.scans.len() != odom_from_robot.len() {
            return Err(AssembleError::InvalidSegment {
                segment: name,
                reason: format!(
                    "{} scans but {} poses",
                    log.scans.len(),
                    odom_from_robot.len()
                ),
            });
        }
        let stamps_secs = log.scans.iter().map(|record| record.stamp_secs).collect();
        let scans = log.scans.iter().map(|record| record.scan.clone()).collect();
        Self::new(name, stamps_secs, odom_from_robot.to_vec(), scans)
    }

    /// A segment from a log's own scan poses (its odometry). Fails on the first scan
    /// without a pose.
    pub fn from_log_odometry(
        name: impl Into<String>,
        log: &LaserLog,
    ) -> Result<Self, AssembleError> {
        let name = name.into();
        let mut poses = Vec::with_capacity(log.scans.len());
        for (scan, record) in log.scans.iter().enumerate() {
            match record.odom_from_robot {
                Some(pose) => poses.push(pose),
                None => {
                    return Err(AssembleError::InvalidSegment {
                        segment: name,
                        reason: format!("scan {scan} carries no odometry pose"),
                    })
                }
            }
        }
        Self::from_log(name, log, &poses)
    }

    /// A segment from its parts; `odom_from_robot` is re-based so its first pose becomes the
    /// identity. Fails when the lengths differ, there is no scan, or a pose is not finite.
    pub fn new(
        name: impl Into<String>,
        stamps_secs: Vec<f64>,
        odom_from_robot: Vec<Se2>,
        scans: Vec<LaserScan>,
    ) -> Result<Self, AssembleError> {
        let name = name.into();
        let bad = |reason: String| AssembleError::InvalidSegment {
            segment: name.clone(),
            reason,
        };
        if scans.len() != odom_from_robot.len() || scans.len() != stamps_secs.len() {
            return Err(bad(format!(
                "{} scans, {} poses and {} stamps",
                scans.len(),
                odom_from_robot.len(),
                stamps_secs.len()
            )));
        }
        if let Some(k) = odom_from_robot.iter().position(|pose| !pose.is_finite()) {
            return Err(bad(format!("pose of scan {k} is not finite")));
        }
        let Some(first) = odom_from_robot.first().copied() else {
            return Err(bad("no scans".to_owned()));
        };
        let segment_from_odom = first.inverse();
        let mut poses: Vec<Se2> = odom_from_robot
            .iter()
            .map(|pose| segment_from_odom.compose(pose))
            .collect();
        // Exactly the origin, not x⁻¹·x up to rounding.
        if let Some(origin) = poses.first_mut() {
            *origin = Se2::identity();
        }
        Ok(Self {
            name,
            stamps_secs,
            poses,
            scans,
        })
    }

    /// Number of scans.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when the segment has no scan (never, for one built by [`Segment::new`]).
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }
}

impl SegmentPoints for Segment {
    type Point = Point2;
    type Pose = Se2;

    fn name(&self) -> &str {
        &self.name
    }

    fn scan_count(&self) -> usize {
        self.poses.len().min(self.scans.len())
    }

    fn pose(&self, scan: usize) -> Option<Se2> {
        self.poses.get(scan).copied()
    }

    fn position_m(&self, scan: usize) -> Option<Vector3<f64>> {
        self.poses
            .get(scan)
            .map(|pose| Vector3::new(pose.x_m, pose.y_m, 0.0))
    }

    fn sensor_in_centre(&self, centre: usize, scan: usize) -> Option<Point2> {
        let centre_from_sensor = self
            .poses
            .get(centre)?
            .inverse()
            .compose(self.poses.get(scan)?)
            .compose(&self.scans.get(scan)?.robot_from_sensor);
        Some(centre_from_sensor.translation())
    }

    fn push_points_in_centre(
        &self,
        centre: usize,
        scan: usize,
        radius_m: f64,
        out: &mut Vec<Point2>,
    ) {
        let (Some(segment_from_centre), Some(segment_from_robot), Some(laser)) = (
            self.poses.get(centre),
            self.poses.get(scan),
            self.scans.get(scan),
        ) else {
            return;
        };
        // centre_from_sensor = centre⁻¹ · robot · robot_from_sensor, applied to each beam.
        let centre_from_sensor = segment_from_centre
            .inverse()
            .compose(segment_from_robot)
            .compose(&laser.robot_from_sensor);
        let rotation = centre_from_sensor.rotation_matrix();
        let translation = centre_from_sensor.translation();
        let radius_sq = radius_m * radius_m;
        for (angle_rad, range_m) in laser.beams() {
            if !laser.is_return(range_m) {
                continue;
            }
            let (sin, cos) = angle_rad.sin_cos();
            let range_m = f64::from(range_m);
            let p_in_centre = rotation * Point2::new(range_m * cos, range_m * sin) + translation;
            let range_sq = p_in_centre.norm_squared();
            if range_sq < radius_sq && range_sq.is_finite() {
                out.push(p_in_centre);
            }
        }
    }
}

/// A 3D segment: point clouds (robot frame) with one SE(3) pose each, in the segment frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Segment3 {
    /// Name (the folder or file stem it came from).
    pub name: String,
    /// `segment_from_robot` of every cloud; `poses[0]` is the identity.
    pub poses: Vec<Se3>,
    /// The clouds, each in its robot (sensor) frame, `z` up.
    pub clouds: Vec<Vec<Point3>>,
}

impl Segment3 {
    /// A segment from clouds and one pose per cloud in any frame; the poses are re-based so
    /// the first cloud is the origin. Fails when the counts differ, there is no cloud, or a
    /// pose is not finite.
    pub fn new(
        name: impl Into<String>,
        world_from_robot: Vec<Se3>,
        clouds: Vec<Vec<Point3>>,
    ) -> Result<Self, AssembleError> {
        let name = name.into();
        let bad = |reason: String| AssembleError::InvalidSegment {
            segment: name.clone(),
            reason,
        };
        if clouds.len() != world_from_robot.len() {
            return Err(bad(format!(
                "{} clouds but {} poses",
                clouds.len(),
                world_from_robot.len()
            )));
        }
        if let Some(k) = world_from_robot.iter().position(|pose| !pose.is_finite()) {
            return Err(bad(format!("pose of cloud {k} is not finite")));
        }
        let Some(first) = world_from_robot.first().copied() else {
            return Err(bad("no clouds".to_owned()));
        };
        let segment_from_world = first.inverse();
        let mut poses: Vec<Se3> = world_from_robot
            .iter()
            .map(|pose| segment_from_world.compose(pose))
            .collect();
        if let Some(origin) = poses.first_mut() {
            *origin = Se3::identity();
        }
        Ok(Self {
            name,
            poses,
            clouds,
        })
    }

    /// Number of clouds.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when the segment has no cloud.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }
}

impl SegmentPoints for Segment3 {
    type Point = Point3;
    type Pose = Se3;

    fn name(&self) -> &str {
        &self.name
    }

    fn scan_count(&self) -> usize {
        self.poses.len().min(self.clouds.len())
    }

    fn pose(&self, scan: usize) -> Option<Se3> {
        self.poses.get(scan).copied()
    }

    fn position_m(&self, scan: usize) -> Option<Vector3<f64>> {
        self.poses.get(scan).map(|pose| pose.translation_m)
    }

    fn push_points_in_centre(
        &self,
        centre: usize,
        scan: usize,
        radius_m: f64,
        out: &mut Vec<Point3>,
    ) {
        let (Some(segment_from_centre), Some(segment_from_robot), Some(cloud)) = (
            self.poses.get(centre),
            self.poses.get(scan),
            self.clouds.get(scan),
        ) else {
            return;
        };
        let centre_from_robot = segment_from_centre.inverse().compose(segment_from_robot);
        let rotation = centre_from_robot.rotation_matrix();
        let translation = centre_from_robot.translation_m;
        let radius_sq = radius_m * radius_m;
        for p_in_robot in cloud {
            let p_in_centre = rotation * p_in_robot + translation;
            let range_sq = p_in_centre.x * p_in_centre.x + p_in_centre.y * p_in_centre.y;
            if range_sq < radius_sq && p_in_centre.z.is_finite() && range_sq.is_finite() {
                out.push(p_in_centre);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapmerge_scan::ScanRecord;
    use nalgebra::UnitQuaternion;

    fn record(x_m: f64) -> ScanRecord {
        ScanRecord {
            stamp_secs: x_m,
            scan: LaserScan::new(0.0, 0.0, 30.0, vec![2.0]),
            odom_from_robot: Some(Se2::new(x_m, 5.0, 0.5)),
            source_tag: "FLASER".to_owned(),
        }
    }

    #[test]
    fn rebases_to_the_first_pose_and_measures_travel() {
        let log = LaserLog {
            scans: vec![record(1.0), record(2.0), record(4.0)],
            ..LaserLog::default()
        };
        let segment = Segment::from_log_odometry("s", &log).unwrap();
        assert_eq!(segment.poses[0], Se2::identity());
        let (s, c) = 0.5f64.sin_cos();
        let second = segment.poses[1];
        assert!((second.x_m - c).abs() < 1e-12 && (second.y_m + s).abs() < 1e-12);
        let travel = segment.travel_m();
        assert!((travel[2] - 3.0).abs() < 1e-12, "{travel:?}");
        // The beam at 0 rad, 2 m ahead of scan 1 (same heading), seen from scan 0.
        let mut points = Vec::new();
        segment.push_points_in_centre(0, 1, 10.0, &mut points);
        assert!((points[0] - Point2::new(2.0 + c, -s)).norm() < 1e-12);
        segment.push_points_in_centre(0, 2, 4.0, &mut points);
        assert_eq!(points.len(), 1, "the point 5 m away is beyond the radius");
    }

    #[test]
    fn refuses_mismatched_or_missing_poses() {
        let mut log = LaserLog {
            scans: vec![record(1.0), record(2.0)],
            ..LaserLog::default()
        };
        assert!(Segment::from_log("s", &log, &[Se2::identity()]).is_err());
        log.scans[1].odom_from_robot = None;
        let err = Segment::from_log_odometry("s", &log).unwrap_err();
        assert!(err.to_string().contains("scan 1"), "{err}");
        assert!(Segment::from_log_odometry("empty", &LaserLog::default()).is_err());
        let nan = [Se2::identity(), Se2::new(f64::NAN, 0.0, 0.0)];
        log.scans[1].odom_from_robot = Some(Se2::identity());
        assert!(Segment::from_log("s", &log, &nan).is_err());
    }

    #[test]
    fn segment3_rebases_and_transforms_clouds() {
        let yaw = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3);
        let poses = vec![
            Se3::new(yaw, Vector3::new(10.0, 0.0, 1.0)),
            Se3::new(
                yaw,
                Vector3::new(10.0, 0.0, 1.0) + yaw * Vector3::new(2.0, 0.0, 0.0),
            ),
        ];
        let clouds = vec![vec![], vec![Point3::new(1.0, 0.0, 0.5)]];
        let segment = Segment3::new("k", poses, clouds).unwrap();
        assert!(segment.poses[0].translation_m.norm() < 1e-12);
        let mut points = Vec::new();
        segment.push_points_in_centre(0, 1, 50.0, &mut points);
        assert!((points[0] - Point3::new(3.0, 0.0, 0.5)).norm() < 1e-12);
        assert!((segment.travel_m()[1] - 2.0).abs() < 1e-12);
    }
}

//! A laser session assembled as its messages arrive (a live robot's topics): each scan paired
//! with the odometry pose at its stamp and the laser's mount from tf, by the rules a bag is
//! read with ([`crate::read_bag`]), so a session heard live and the same session read from a
//! bag give the same scan records.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_scan::ScanRecord;

use crate::messages::{LaserScanMessage, OdometryMessage, TfMessage};
use crate::session::{odom_pose, planar_mount, pose_at, Angles, MountSource, Tf};

/// A scan waits at most this long after it was heard for tf to link the laser to the robot,
/// and for odometry before any was heard (wall time: messages of different topics travel
/// separately, and a busy network or host delays one topic more than another).
pub const LIVE_WAIT: Duration = Duration::from_millis(500);

/// Once odometry has been heard, a scan waits this long for the odometry after its stamp: a
/// loaded host delays the pose rather than leaving the scan out.
pub const LIVE_ODOMETRY_WAIT: Duration = Duration::from_secs(5);

/// Scans waiting at most (a robot without odometry or tf would otherwise grow the queue).
pub const LIVE_QUEUE_MAX: usize = 256;

/// Odometry poses kept at most (newest); those older than every waiting scan are dropped.
const ODOMETRY_KEPT_MAX: usize = 4096;

/// What the assembler left out, by reason.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct LiveDrops {
    /// No odometry within [`crate::ODOMETRY_HOLD_S`] of the scan's stamp.
    pub without_odometry: usize,
    /// Stamped before a scan already given out.
    pub out_of_order: usize,
    /// tf does not link the laser to the robot.
    pub without_mount: usize,
    /// The queue was full ([`LIVE_QUEUE_MAX`]).
    pub queue_full: usize,
    /// Odometry messages with a non-finite pose or going back in time.
    pub bad_odometry: usize,
    /// Scans not left out but taken with the last odometry held (none came after their stamp
    /// within the wait).
    pub odometry_held: usize,
}

/// The laser's mount once known.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct LiveMount {
    /// The robot's frame (odometry's `child_frame_id`, else `base_link`).
    pub base_frame: String,
    /// The laser's frame.
    pub laser_frame: String,
    /// `robot_from_sensor` on the plane.
    pub robot_from_sensor: Se2,
    /// The laser is upside down (its beams are mirrored).
    pub upside_down: bool,
    /// Where it came from.
    pub source: MountSource,
}

/// Scans, odometry and tf in, scan records out, in stamp order.
#[derive(Default)]
pub struct ScanAssembler {
    tf: Tf,
    odom_stamps_s: VecDeque<f64>,
    odom_poses: VecDeque<Se2>,
    base_frame: Option<String>,
    /// Scans waiting, with when each was heard.
    waiting: VecDeque<(LaserScanMessage, Instant)>,
    last_out_s: Option<f64>,
    mount: Option<LiveMount>,
    angles: Angles,
    drops: LiveDrops,
    /// Why scans were last left out for want of a mount.
    mount_problem: Option<String>,
    /// Whether any odometry was taken.
    odometry_heard: bool,
}

impl ScanAssembler {
    /// An assembler with nothing heard.
    pub fn new() -> Self {
        Self::default()
    }

    /// Takes a tf message (`/tf_static` when `is_static`). A transform that is not finite is
    /// refused, naming its frames.
    pub fn tf(&mut self, tf: &TfMessage, is_static: bool) -> Result<(), String> {
        self.tf.insert(tf, is_static)
    }

    /// Takes an odometry message. One with a non-finite pose or stamped before the last is
    /// refused (and counted).
    pub fn odometry(&mut self, odometry: &OdometryMessage) -> Result<(), String> {
        let stamp_s = odometry.header.stamp.seconds();
        let pose = odom_pose(odometry);
        if !pose.is_finite() {
            self.drops.bad_odometry += 1;
            return Err(format!(
                "odometry at {stamp_s} s: the pose is not finite or its quaternion is zero"
            ));
        }
        if self
            .odom_stamps_s
            .back()
            .is_some_and(|&last| stamp_s < last)
        {
            self.drops.bad_odometry += 1;
            return Err(format!(
                "odometry at {stamp_s} s goes back in time (last {} s)",
                self.odom_stamps_s.back().copied().unwrap_or(0.0)
            ));
        }
        if self.base_frame.is_none() {
            let child = odometry.child_frame_id.trim_start_matches('/');
            if !child.is_empty() {
                self.base_frame = Some(child.to_owned());
            }
        }
        self.odometry_heard = true;
        self.odom_stamps_s.push_back(stamp_s);
        self.odom_poses.push_back(pose);
        if self.odom_stamps_s.len() > ODOMETRY_KEPT_MAX {
            self.odom_stamps_s.pop_front();
            self.odom_poses.pop_front();
        }
        Ok(())
    }

    /// Takes a scan heard at `heard`; it waits for its odometry and mount
    /// ([`ScanAssembler::next_record`]).
    pub fn scan(&mut self, scan: LaserScanMessage, heard: Instant) {
        let stamp_s = scan.header.stamp.seconds();
        if self.last_out_s.is_some_and(|last| stamp_s < last)
            || self
                .waiting
                .back()
                .is_some_and(|(w, _)| stamp_s < w.header.stamp.seconds())
        {
            self.drops.out_of_order += 1;
            return;
        }
        if self.waiting.len() >= LIVE_QUEUE_MAX {
            self.waiting.pop_front();
            self.drops.queue_full += 1;
        }
        self.waiting.push_back((scan, heard));
    }

    /// The next scan whose odometry and mount are known at `now`, in stamp order, with when
    /// it was heard; scans that waited [`LIVE_WAIT`] for the mount, or for odometry
    /// ([`LIVE_ODOMETRY_WAIT`] once some was heard), are taken with what is known
    /// (the odometry held for [`crate::ODOMETRY_HOLD_S`] past its last message) or left out
    /// (counted in [`ScanAssembler::drops`]).
    pub fn next_record(&mut self, now: Instant) -> Option<(ScanRecord, Instant)> {
        while let Some((front, heard)) = self.waiting.front() {
            let stamp_s = front.header.stamp.seconds();
            let waited = now.saturating_duration_since(*heard);
            let timed_out = waited > LIVE_WAIT;
            let laser_frame = front.header.frame_id.clone();
            if self.mount.is_none() && !self.find_mount(&laser_frame, timed_out) {
                if !timed_out {
                    return None;
                }
                self.waiting.pop_front();
                self.drops.without_mount += 1;
                continue;
            }
            let covered = self
                .odom_stamps_s
                .back()
                .is_some_and(|&last| last >= stamp_s);
            let odometry_wait = if self.odometry_heard {
                LIVE_ODOMETRY_WAIT
            } else {
                LIVE_WAIT
            };
            if !covered && waited <= odometry_wait {
                return None;
            }
            let (scan, heard) = self.waiting.pop_front()?;
            let (stamps, poses) = (
                self.odom_stamps_s.make_contiguous(),
                self.odom_poses.make_contiguous(),
            );
            let Some(odom_from_robot) = pose_at(stamps, poses, stamp_s) else {
                self.drops.without_odometry += 1;
                continue;
            };
            if !covered {
                self.drops.odometry_held += 1;
            }
            // Odometry older than the one before this scan is no longer needed.
            let keep_from = stamps.partition_point(|&t| t <= stamp_s).saturating_sub(1);
            self.odom_stamps_s.drain(..keep_from);
            self.odom_poses.drain(..keep_from);
            self.last_out_s = Some(stamp_s);
            let mount = self.mount.as_ref()?;
            let record = self.angles.record(
                scan,
                stamp_s,
                Some(odom_from_robot),
                mount.robot_from_sensor,
                mount.upside_down,
            );
            return Some((record, heard));
        }
        None
    }

    /// Looks the laser's mount up; `give_up` takes what the bag reader would (identity when
    /// no tf was heard at all).
    fn find_mount(&mut self, laser_frame: &str, give_up: bool) -> bool {
        let laser = laser_frame.trim_start_matches('/');
        let base = self
            .base_frame
            .clone()
            .unwrap_or_else(|| "base_link".into());
        let found = match self.tf.mount(&base, laser) {
            // Without any tf yet, wait for it before taking the laser at the origin.
            Ok((_, MountSource::NoTf)) if !give_up => return false,
            Ok(found) => found,
            Err(reason) => {
                self.mount_problem = Some(reason);
                return false;
            }
        };
        match planar_mount(&found.0) {
            Ok((robot_from_sensor, upside_down)) => {
                self.mount = Some(LiveMount {
                    base_frame: base,
                    laser_frame: laser.to_owned(),
                    robot_from_sensor,
                    upside_down,
                    source: found.1,
                });
                self.mount_problem = None;
                true
            }
            Err(reason) => {
                self.mount_problem = Some(reason);
                false
            }
        }
    }

    /// The laser's mount, once known.
    pub fn mount(&self) -> Option<&LiveMount> {
        self.mount.as_ref()
    }

    /// Why the mount is not known yet, if tf was heard but does not give it.
    pub fn mount_problem(&self) -> Option<&str> {
        self.mount_problem.as_deref()
    }

    /// What was left out so far.
    pub fn drops(&self) -> LiveDrops {
        self.drops
    }

    /// Scans waiting.
    pub fn waiting(&self) -> usize {
        self.waiting.len()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use crate::messages::{Header, Quaternion, Time, Transform, TransformStamped, Vector3};

    fn stamp(seconds: f64) -> Time {
        Time::from_nanoseconds((seconds * 1e9).round() as i64).unwrap()
    }

    fn scan_at(seconds: f64) -> LaserScanMessage {
        LaserScanMessage {
            header: Header {
                stamp: stamp(seconds),
                frame_id: "laser".into(),
            },
            angle_min: -1.5,
            angle_max: 1.5,
            angle_increment: 1.0,
            range_min: 0.1,
            range_max: 30.0,
            ranges: vec![1.0, 2.0, 3.0, 4.0],
            ..Default::default()
        }
    }

    fn odom_at(seconds: f64, x: f64) -> OdometryMessage {
        let mut o = OdometryMessage {
            header: Header {
                stamp: stamp(seconds),
                frame_id: "odom".into(),
            },
            child_frame_id: "base_link".into(),
            ..Default::default()
        };
        o.pose.pose.position.x = x;
        o.pose.pose.orientation = Quaternion::from_yaw(0.0);
        o
    }

    fn mount_tf(x: f64) -> TfMessage {
        TfMessage {
            transforms: vec![TransformStamped {
                header: Header {
                    frame_id: "base_link".into(),
                    ..Default::default()
                },
                child_frame_id: "laser".into(),
                transform: Transform {
                    translation: Vector3 { x, y: 0.0, z: 0.2 },
                    rotation: Quaternion::from_yaw(0.0),
                },
            }],
        }
    }

    fn after(t0: Instant, ms: u64) -> Instant {
        t0 + Duration::from_millis(ms)
    }

    #[test]
    fn a_scan_waits_for_the_odometry_after_it_and_is_interpolated() {
        let t0 = Instant::now();
        let mut live = ScanAssembler::new();
        live.tf(&mount_tf(0.3), true).unwrap();
        live.odometry(&odom_at(1.0, 0.0)).unwrap();
        live.scan(scan_at(1.5), t0);
        assert!(
            live.next_record(after(t0, 400)).is_none(),
            "no odometry after 1.5 s yet"
        );
        live.odometry(&odom_at(2.0, 1.0)).unwrap();
        let (record, heard) = live.next_record(after(t0, 450)).unwrap();
        assert_eq!(heard, t0);
        assert!((record.odom_from_robot.unwrap().x_m - 0.5).abs() < 1e-9);
        assert!((record.scan.robot_from_sensor.x_m - 0.3).abs() < 1e-12);
        assert_eq!(live.mount().unwrap().source, MountSource::TfStatic);
        assert!(live.next_record(after(t0, 450)).is_none());
        assert_eq!(live.drops(), LiveDrops::default());
    }

    #[test]
    fn scans_late_or_without_odometry_are_left_out_or_held_and_counted() {
        let t0 = Instant::now();
        let mut live = ScanAssembler::new();
        live.tf(&mount_tf(0.0), true).unwrap();
        live.odometry(&odom_at(1.0, 0.0)).unwrap();
        live.scan(scan_at(2.0), t0); // 1 s past the last odometry
        live.scan(scan_at(1.9), t0); // goes back
        assert_eq!(live.drops().out_of_order, 1);
        live.scan(scan_at(1.02), t0); // goes back too
        live.scan(scan_at(2.6), after(t0, 300));
        // Odometry was heard: a scan waits 5 s for the odometry after it, not 0.5 s.
        assert!(
            live.next_record(after(t0, 600)).is_none(),
            "within the wait"
        );
        assert_eq!(live.drops().without_odometry, 0);
        assert!(live.next_record(after(t0, 5100)).is_none());
        assert_eq!(
            live.drops().without_odometry,
            1,
            "2.0 s: nothing within the hold"
        );
        assert_eq!(live.waiting(), 1);
        // The 2.6 s scan, 0.03 s after odometry at 2.57 s, takes it held once its wait is over.
        live.odometry(&odom_at(2.57, 2.0)).unwrap();
        let (held, _) = live.next_record(after(t0, 5400)).unwrap();
        assert_eq!(held.odom_from_robot.unwrap().x_m, 2.0);
        assert_eq!(live.drops().odometry_held, 1);
        let mut bad = odom_at(3.0, 0.0);
        bad.pose.pose.orientation = Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 0.0,
        };
        assert!(live.odometry(&bad).unwrap_err().contains("not finite"));
        assert!(live.odometry(&odom_at(0.5, 0.0)).is_err());
        assert_eq!(live.drops().bad_odometry, 2);
    }

    #[test]
    fn without_any_tf_the_laser_is_taken_at_the_origin_once_the_wait_is_over() {
        let t0 = Instant::now();
        let mut live = ScanAssembler::new();
        live.odometry(&odom_at(0.0, 0.0)).unwrap();
        live.odometry(&odom_at(5.0, 5.0)).unwrap();
        live.scan(scan_at(1.0), t0);
        assert!(
            live.next_record(after(t0, 100)).is_none(),
            "tf may still come"
        );
        live.scan(scan_at(1.6), after(t0, 100));
        let (first, _) = live.next_record(after(t0, 501)).unwrap();
        assert_eq!(first.stamp_secs, 1.0);
        assert_eq!(live.mount().unwrap().source, MountSource::NoTf);
        assert_eq!(live.next_record(after(t0, 501)).unwrap().0.stamp_secs, 1.6);
    }

    #[test]
    fn a_tree_without_the_laser_leaves_scans_out_and_says_why() {
        let t0 = Instant::now();
        let mut live = ScanAssembler::new();
        let mut other = mount_tf(0.0);
        other.transforms[0].child_frame_id = "camera".into();
        live.tf(&other, true).unwrap();
        live.odometry(&odom_at(0.0, 0.0)).unwrap();
        live.odometry(&odom_at(5.0, 0.0)).unwrap();
        live.scan(scan_at(1.0), t0);
        live.scan(scan_at(2.0), after(t0, 400));
        assert!(live.next_record(after(t0, 600)).is_none());
        assert_eq!(live.drops().without_mount, 1);
        assert!(live.mount_problem().unwrap().contains("'laser'"));
        live.tf(&mount_tf(0.1), false).unwrap();
        assert_eq!(live.next_record(after(t0, 600)).unwrap().0.stamp_secs, 2.0);
        assert_eq!(live.mount().unwrap().source, MountSource::Tf);
    }
}

//! The 3D path (point-cloud submaps from KITTI-style folders or any `Segment3`): described in
//! 3D, verified and optimised in the ground plane.
//!
//! As AutoMerge's cars (and its final ICP refinement), a ground vehicle moves in the plane
//! up to small roll and pitch, so a 3D segment shares every stage after the descriptor with
//! the 2D path: [`prepare_3d`] builds the [`Submap3`]s, describes them with the 3D descriptor
//! (that is what association compares) and converts each into a [`Submap2`] for the scan
//! matcher and the group graph:
//! - the pose is `segment_from_centre` projected to SE(2): `(x, y)` of the translation and
//!   the yaw of the rotation (heading of the robot's x axis in the segment's xy plane);
//! - the points are those within a height band ([`GroundSlice`]) above or below the sensor,
//!   measured along the segment's `z` after removing each scan's roll and pitch, projected to
//!   `(x, y)` of the centre's levelled frame and voxel-downsampled in 2D.
//!
//! **Assumptions**: the segment frame (the first cloud's robot frame) has `z` up, i.e. the
//! first pose is level, and roll and pitch stay small (a few degrees), so that the ground
//! plane of the segment frame is the plane the vehicle moves in. The band is measured from
//! every scan's own sensor, so gentle slopes along a submap's window do not shift it.
//!
//! Per-scan poses come from a 2D [`Segment`] with the projected poses and one virtual 360°
//! laser scan per cloud (nearest band point per beam), which the group graph and the
//! renderers use as for a 2D segment.

use std::path::{Path, PathBuf};

use mapmerge_association::DescriptorMatrix;
use mapmerge_geometry::{LieGroup, Se2, Se3};
use mapmerge_params::{Checker, Real, Validate};
use mapmerge_scan::{LaserScan, Point2};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::associate::PreparedSegment;
use crate::descriptor::{describe_submaps, RingSpectrumDescriptor3};
use crate::error::AssembleError;
use crate::segment::{Point3, Segment, Segment3, SegmentPoints};
use crate::submap::{build_submaps, voxel_downsample, SegmentSubmap, Submap2, SubmapParams};

/// Beams of the virtual 360° scan of each cloud (0.5° apart).
const VIRTUAL_BEAMS: usize = 720;
/// Accumulated 2D points are voxel-downsampled whenever this many are waiting (bounds memory
/// for dense clouds and long windows).
const DOWNSAMPLE_BATCH: usize = 1 << 20;

/// The height band of a 3D cloud that becomes the planar observation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GroundSlice {
    /// Lowest kept height relative to the sensor, along the segment's `z` (m) (default:
    /// −1.2: 0.53 m above the ground for KITTI's Velodyne 1.73 m up, clear of the road even
    /// with a degree of residual pitch at 30 m range, low enough for parked cars and curbside
    /// walls).
    pub min_height_m: f64,
    /// Highest kept height relative to the sensor (m) (default: 1.5: 3.2 m above the ground;
    /// a 64-beam Velodyne sees at most 2° up, so higher parts of facades are seen only close
    /// by and would make the slice depend on the distance).
    pub max_height_m: f64,
    /// Voxel (cell) side of the planar points (m) (default: 0.1; the pair verifier's
    /// correlative grid has 5 cm cells, and sparser points leave gaps in its likelihood).
    pub voxel_m: f64,
}

impl Default for GroundSlice {
    fn default() -> Self {
        Self {
            min_height_m: -1.2,
            max_height_m: 1.5,
            voxel_m: 0.1,
        }
    }
}

impl GroundSlice {
    /// Checks the band (within ±100 m, `min < max`) and the voxel (0 to 10 m).
    pub fn validate(&self) -> Result<(), AssembleError> {
        Ok(Validate::validate(self)?)
    }

    /// True when a height relative to the sensor (m) lies in the band.
    fn contains(&self, height_m: f64) -> bool {
        height_m >= self.min_height_m && height_m <= self.max_height_m
    }
}

impl Validate for GroundSlice {
    fn check(&self, check: &mut Checker) {
        let height = Real::within(-100.0, 100.0);
        check
            .real("min_height_m", self.min_height_m, height)
            .real("max_height_m", self.max_height_m, height)
            .rule(
                "max_height_m",
                self.max_height_m,
                self.min_height_m < self.max_height_m,
                "must be > min_height_m",
            )
            .real("voxel_m", self.voxel_m, Real::within(0.0, 10.0));
    }
}

/// The yaw of a 3D rotation: heading of its x axis in the xy plane (rad). For a pure
/// rotation about `z` this is its angle; small roll and pitch change it only to second order.
pub fn yaw_of(rotation: &UnitQuaternion<f64>) -> f64 {
    let x_axis = rotation * Vector3::x();
    x_axis.y.atan2(x_axis.x)
}

/// `segment_from_robot` projected to the ground plane: `(x, y, yaw)` (module doc).
pub fn project_pose(segment_from_robot: &Se3) -> Se2 {
    let t = segment_from_robot.translation_m;
    Se2::new(t.x, t.y, yaw_of(&segment_from_robot.rotation))
}

/// The rotation of `segment_from_robot` with its yaw removed (`levelled_from_robot`): it maps
/// robot-frame points to a frame with the robot's origin and heading whose `z` is the
/// segment's.
fn levelled_from_robot(segment_from_robot: &Se3) -> Matrix3<f64> {
    let unyaw = UnitQuaternion::from_euler_angles(0.0, 0.0, -yaw_of(&segment_from_robot.rotation));
    (unyaw * segment_from_robot.rotation)
        .to_rotation_matrix()
        .into_inner()
}

/// Prepares a 3D segment for the assembly: its submaps described in 3D by `descriptor3` and
/// converted to planar submaps (module doc), and the planar [`Segment`] that carries the
/// per-scan poses (projected; stamps are the cloud indices in seconds, as a [`Segment3`]
/// carries no time) and one virtual laser scan per cloud of `submap_params.radius_m` range.
pub fn prepare_3d(
    segment: &Segment3,
    submap_params: &SubmapParams,
    descriptor3: &RingSpectrumDescriptor3,
    slice: &GroundSlice,
) -> Result<(PreparedSegment, Segment), AssembleError> {
    slice.validate()?;
    let submaps3 = build_submaps(segment, submap_params)?;
    let rows = describe_submaps(descriptor3, &submaps3);
    let descriptors =
        DescriptorMatrix::new(rows.dim, rows.values).map_err(|e| AssembleError::Association {
            pair: segment.name.clone(),
            reason: e.to_string(),
        })?;
    let count = segment.scan_count();
    let planar_poses: Vec<Se2> = segment.poses[..count].iter().map(project_pose).collect();
    let levelling: Vec<Matrix3<f64>> = segment.poses[..count]
        .iter()
        .map(levelled_from_robot)
        .collect();
    let submaps: Vec<Submap2> = submaps3
        .par_iter()
        .map(|submap| {
            let points = slice_points(
                segment,
                &levelling,
                submap.centre_scan,
                submap.scan_range,
                submap_params.radius_m,
                slice,
            );
            SegmentSubmap {
                index: submap.index,
                centre_scan: submap.centre_scan,
                scan_range: submap.scan_range,
                segment_from_centre: project_pose(&submap.segment_from_centre),
                travel_m: submap.travel_m,
                points_in_centre: points,
                free_space: None,
            }
        })
        .collect();
    let range_max_m = submap_params.radius_m as f32;
    let scans: Vec<LaserScan> = (0..count)
        .into_par_iter()
        .map(|scan| {
            virtual_scan(
                segment.clouds.get(scan).map_or(&[][..], Vec::as_slice),
                &levelling[scan],
                range_max_m,
                slice,
            )
        })
        .collect();
    let stamps_secs = (0..count).map(|k| k as f64).collect();
    let planar = Segment::new(segment.name.clone(), stamps_secs, planar_poses, scans)?;
    Ok((
        PreparedSegment {
            name: segment.name.clone(),
            submaps,
            descriptors,
        },
        planar,
    ))
}

/// The band points of scans `first..=last`, in the levelled frame of scan `centre`, within
/// `radius_m` of its origin (horizontal), projected to the plane and voxel-downsampled.
fn slice_points(
    segment: &Segment3,
    levelling: &[Matrix3<f64>],
    centre: usize,
    (first, last): (usize, usize),
    radius_m: f64,
    slice: &GroundSlice,
) -> Vec<Point2> {
    let Some(segment_from_centre) = segment.poses.get(centre) else {
        return Vec::new();
    };
    // centre_level_from_segment: translate to the centre, turn by −yaw (z untouched).
    let unyaw = UnitQuaternion::from_euler_angles(0.0, 0.0, -yaw_of(&segment_from_centre.rotation));
    let radius_sq = radius_m * radius_m;
    let mut points: Vec<Point2> = Vec::new();
    for scan in first..=last {
        let (Some(segment_from_robot), Some(cloud), Some(level_from_robot)) = (
            segment.poses.get(scan),
            segment.clouds.get(scan),
            levelling.get(scan),
        ) else {
            continue;
        };
        // Robot origin in the centre's levelled frame; the rotation from the robot frame.
        let offset = unyaw * (segment_from_robot.translation_m - segment_from_centre.translation_m);
        let rotation = unyaw.to_rotation_matrix().into_inner()
            * segment_from_robot
                .rotation
                .to_rotation_matrix()
                .into_inner();
        for p_in_robot in cloud {
            // Height above or below this scan's own sensor, levelled.
            let height_m = (level_from_robot * p_in_robot).z;
            if !slice.contains(height_m) {
                continue;
            }
            let p = rotation * p_in_robot + offset;
            let range_sq = p.x * p.x + p.y * p.y;
            if range_sq < radius_sq && range_sq.is_finite() {
                points.push(Point2::new(p.x, p.y));
            }
        }
        if points.len() >= DOWNSAMPLE_BATCH && slice.voxel_m > 0.0 {
            points = voxel_downsample(&points, slice.voxel_m);
        }
    }
    voxel_downsample(&points, slice.voxel_m)
}

/// A 360° virtual laser scan of one cloud: per beam the nearest band point (levelled robot
/// frame), `range_max_m` where there is none.
fn virtual_scan(
    cloud: &[Point3],
    level_from_robot: &Matrix3<f64>,
    range_max_m: f32,
    slice: &GroundSlice,
) -> LaserScan {
    let step_rad = std::f64::consts::TAU / VIRTUAL_BEAMS as f64;
    let mut ranges_m = vec![range_max_m; VIRTUAL_BEAMS];
    for p_in_robot in cloud {
        let p = level_from_robot * p_in_robot;
        if !slice.contains(p.z) {
            continue;
        }
        let range_m = p.x.hypot(p.y);
        if !(range_m.is_finite() && range_m > 0.0) {
            continue;
        }
        // Beam k covers [−π + (k − ½)·step, −π + (k + ½)·step).
        let beam =
            ((p.y.atan2(p.x) + std::f64::consts::PI) / step_rad).round() as usize % VIRTUAL_BEAMS;
        if let Some(slot) = ranges_m.get_mut(beam) {
            *slot = slot.min(range_m as f32);
        }
    }
    let last_rad = -std::f64::consts::PI + step_rad * (VIRTUAL_BEAMS - 1) as f64;
    LaserScan::new(-std::f64::consts::PI, last_rad, range_max_m, ranges_m)
}

/// How [`load_kitti_folder`] thins the clouds (a full KITTI cloud holds ~120 000 points, and a
/// [`Segment3`] keeps every cloud in memory).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KittiFolderOptions {
    /// Each cloud is voxel-downsampled with this cell (m) (default: 0.2; 0 keeps every
    /// point: ~3 MB a cloud).
    pub voxel_m: f64,
    /// Points farther than this from the sensor (horizontal, m) are dropped (default: 80,
    /// beyond any submap radius).
    pub max_range_m: f64,
    /// Only every `stride`-th cloud (and its pose) is kept, from the first (default: 1;
    /// 0 counts as 1).
    pub stride: usize,
}

impl Default for KittiFolderOptions {
    fn default() -> Self {
        Self {
            voxel_m: 0.2,
            max_range_m: 80.0,
            stride: 1,
        }
    }
}

impl Validate for KittiFolderOptions {
    fn check(&self, check: &mut Checker) {
        // No upper limit on the range: a huge one keeps every point.
        check
            .real("voxel_m", self.voxel_m, Real::within(0.0, 10.0))
            .real("max_range_m", self.max_range_m, Real::positive())
            .size("stride", self.stride, 0, 1_000_000);
    }
}

/// Loads a KITTI-style folder as a [`Segment3`] named after the folder:
/// - `velodyne/*.bin` (or `*.bin.xz`), sorted by file name: one cloud each, Velodyne frame
///   (x forward, y left, z up);
/// - `poses.txt`: one KITTI pose line (row-major 3×4 `[R | t]`) per cloud, in the same order;
/// - optional `calib.txt`: when it has a `Tr:` line (`camera_from_velodyne`, as KITTI's
///   odometry calibration), the poses are camera poses (KITTI's ground truth,
///   `world_from_camera`) and become `world_from_camera · Tr`; without it the poses are taken
///   as the Velodyne's own.
///
/// Fails, naming the file, on an unreadable or malformed file, and when the number of clouds
/// and poses differ.
pub fn load_kitti_folder(
    dir: &Path,
    options: &KittiFolderOptions,
) -> Result<Segment3, AssembleError> {
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| dir.display().to_string());
    let bad = |reason: String| AssembleError::InvalidSegment {
        segment: name.clone(),
        reason,
    };
    options.validate()?;
    let velodyne = dir.join("velodyne");
    let entries =
        std::fs::read_dir(&velodyne).map_err(|e| bad(format!("{}: {e}", velodyne.display())))?;
    let mut files: Vec<PathBuf> = Vec::new();
    for entry in entries {
        let path = entry
            .map_err(|e| bad(format!("{}: {e}", velodyne.display())))?
            .path();
        let file_name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if path.is_file() && (file_name.ends_with(".bin") || file_name.ends_with(".bin.xz")) {
            files.push(path);
        }
    }
    files.sort();
    let poses_path = dir.join("poses.txt");
    let mut world_from_sensor =
        mapmerge_io::read_kitti_poses(&poses_path).map_err(|e| bad(e.to_string()))?;
    if files.len() != world_from_sensor.len() {
        return Err(bad(format!(
            "{} holds {} clouds but {} has {} poses",
            velodyne.display(),
            files.len(),
            poses_path.display(),
            world_from_sensor.len()
        )));
    }
    let calib_path = dir.join("calib.txt");
    if calib_path.is_file() {
        if let Some(camera_from_velodyne) = read_velodyne_calibration(&calib_path)
            .map_err(|reason| bad(format!("{}: {reason}", calib_path.display())))?
        {
            for pose in &mut world_from_sensor {
                *pose = pose.compose(&camera_from_velodyne);
            }
        }
    }
    kept_clouds(name.clone(), &world_from_sensor, options, |k| {
        mapmerge_io::read_kitti_cloud(&files[k]).map_err(|e| bad(e.to_string()))
    })
}

impl KittiFolderOptions {
    /// Checks every field's range.
    fn validate(&self) -> Result<(), AssembleError> {
        Ok(Validate::validate(self)?)
    }
}

/// A [`Segment3`] of every `options.stride`-th cloud of `world_from_sensor.len()`, each read by
/// `cloud(k)` (in parallel), cut to `options.max_range_m` and voxel-downsampled.
fn kept_clouds(
    name: String,
    world_from_sensor: &[Se3],
    options: &KittiFolderOptions,
    cloud: impl Fn(usize) -> Result<Vec<Point3>, AssembleError> + Sync,
) -> Result<Segment3, AssembleError> {
    let kept: Vec<usize> = (0..world_from_sensor.len())
        .step_by(options.stride.max(1))
        .collect();
    let radius_sq = options.max_range_m * options.max_range_m;
    let clouds: Vec<Result<Vec<Point3>, AssembleError>> = kept
        .par_iter()
        .map(|&k| {
            let near: Vec<Point3> = cloud(k)?
                .into_iter()
                .filter(|p| p.x * p.x + p.y * p.y < radius_sq)
                .collect();
            Ok(voxel_downsample(&near, options.voxel_m))
        })
        .collect();
    let clouds = clouds.into_iter().collect::<Result<Vec<_>, _>>()?;
    let poses = kept.iter().map(|&k| world_from_sensor[k]).collect();
    Segment3::new(name, poses, clouds)
}

/// A [`Segment3`] from clouds in memory (e.g. a ROS 2 bag's PointCloud2 messages) and the
/// sensor's pose of each (`world_from_sensor`), kept, cut and downsampled as
/// [`load_kitti_folder`] does with a folder's.
pub fn segment3_from_clouds(
    name: String,
    world_from_sensor: &[Se3],
    clouds: &[Vec<Point3>],
    options: &KittiFolderOptions,
) -> Result<Segment3, AssembleError> {
    options.validate()?;
    if clouds.len() != world_from_sensor.len() {
        return Err(AssembleError::InvalidSegment {
            segment: name,
            reason: format!(
                "{} clouds but {} poses",
                clouds.len(),
                world_from_sensor.len()
            ),
        });
    }
    kept_clouds(name, world_from_sensor, options, |k| Ok(clouds[k].clone()))
}

/// `camera_from_velodyne` from a KITTI `calib.txt` (`Tr: ` + 12 numbers), `None` when the file
/// has no `Tr:` line; `Err` with the reason when the line is malformed or unreadable.
fn read_velodyne_calibration(path: &Path) -> Result<Option<Se3>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| e.to_string())?;
    for line in text.lines() {
        if let Some(rest) = line.trim_start().strip_prefix("Tr:") {
            let poses = mapmerge_io::parse_kitti_poses(rest, &path.display().to_string())
                .map_err(|e| format!("Tr: {e}"))?;
            return match poses.as_slice() {
                [pose] => Ok(Some(*pose)),
                _ => Err("Tr: expected one 3x4 matrix".to_owned()),
            };
        }
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projection_keeps_yaw_under_small_tilt() {
        let rotation = UnitQuaternion::from_euler_angles(0.03, -0.02, 1.2);
        let pose = Se3::new(rotation, Vector3::new(3.0, -4.0, 0.7));
        let planar = project_pose(&pose);
        assert!((planar.theta_rad - 1.2).abs() < 1e-3, "{planar:?}");
        assert_eq!((planar.x_m, planar.y_m), (3.0, -4.0));
        // Levelling removes the tilt: the robot's up axis becomes the segment's z again.
        let level = levelled_from_robot(&pose);
        let up = level * (rotation.inverse() * Vector3::z());
        assert!((up - Vector3::z()).norm() < 1e-12, "{up:?}");
    }

    #[test]
    fn slices_are_checked() {
        assert!(GroundSlice::default().validate().is_ok());
        let empty = GroundSlice {
            min_height_m: 1.0,
            max_height_m: 1.0,
            ..GroundSlice::default()
        };
        assert!(empty.validate().is_err());
        let nan = GroundSlice {
            voxel_m: f64::NAN,
            ..GroundSlice::default()
        };
        assert!(nan.validate().is_err());
    }

    #[test]
    fn virtual_scan_keeps_the_nearest_band_point() {
        let cloud = vec![
            Point3::new(5.0, 0.0, 0.0),
            Point3::new(3.0, 0.0, 0.5),
            Point3::new(2.0, 0.0, -1.6), // road: below the band
            Point3::new(0.0, 4.0, 0.0),
            Point3::new(f64::NAN, 1.0, 0.0),
        ];
        let scan = virtual_scan(&cloud, &Matrix3::identity(), 30.0, &GroundSlice::default());
        let returns: Vec<(f64, f32)> = scan.beams().filter(|(_, r)| scan.is_return(*r)).collect();
        assert_eq!(returns.len(), 2, "{returns:?}");
        assert!(returns[0].0.abs() < 1e-9 && returns[0].1 == 3.0);
        assert!((returns[1].0 - std::f64::consts::FRAC_PI_2).abs() < 1e-9 && returns[1].1 == 4.0);
    }
}

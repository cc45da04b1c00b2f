//! Planar laser scans and the logs that carry them.
//!
//! Entry points: [`LaserScan`] (one sweep of evenly spaced beams in the sensor frame, with the
//! sensor's mounting pose on the robot), [`LaserLog`] (timestamped odometry and scans in file
//! order, as read from a CARMEN log), and the point operations [`voxel_downsample`],
//! [`estimate_normals`] and [`transform_points`].
//!
//! ```
//! use mapmerge_geometry::Se2;
//! use mapmerge_scan::{BeamFilter, LaserScan};
//! // Three beams at -90°, 0°, +90°; the middle one returned nothing (max range).
//! let scan = LaserScan::new(-std::f64::consts::FRAC_PI_2, std::f64::consts::FRAC_PI_2, 30.0, vec![2.0, 30.0, 1.0]);
//! let points = scan.points_in_robot(&BeamFilter::default());
//! assert_eq!(points.len(), 2);
//! assert!((points[0].y + 2.0).abs() < 1e-6 && (points[1].y - 1.0).abs() < 1e-6);
//! ```

mod cloud;
mod log;
mod scan;

pub use cloud::{estimate_normals, scan_normals, transform_points, voxel_downsample, PointNormal};
pub use log::{LaserLog, OdometryReading, ScanRecord};
pub use mapmerge_geometry::Point2;
pub use scan::{BeamFilter, LaserScan};

//! `nav_msgs/msg/OccupancyGrid` and the grids mapmerge keeps: a map published as map_server
//! and slam_toolbox publish it (trinary: 100 occupied, 0 free, −1 unknown), and a received
//! map read as a map_server map (its values as percent, [`MapMode::Raw`]).

use mapmerge_grid::{CellClass, ClassThresholds, OccupancyGrid};
use mapmerge_io::{MapMode, RosMap};

use crate::messages::{Header, MapMetaData, OccupancyGridMessage, Pose, Quaternion, Vector3};

/// The occupancy values a published map holds.
const OCCUPIED: u8 = 100;
const FREE: u8 = 0;
/// −1 as its byte.
const UNKNOWN: u8 = 0xFF;

/// Cells a received map may have at most (a 20,000 × 20,000 map).
pub const MAP_CELLS_MAX: u64 = 400_000_000;

/// `grid` as an OccupancyGrid message in `header`'s frame: each cell classified by
/// `thresholds`, rows bottom first (the grid's own order), the origin the grid's lower-left
/// corner with zero yaw.
pub fn occupancy_grid_message(
    grid: &OccupancyGrid,
    thresholds: &ClassThresholds,
    header: Header,
) -> OccupancyGridMessage {
    let geometry = grid.geometry();
    let mut classify = thresholds.classifier();
    let data: Vec<u8> = grid
        .log_odds()
        .iter()
        .map(|&l| match classify(l) {
            CellClass::Occupied => OCCUPIED,
            CellClass::Free => FREE,
            CellClass::Unknown => UNKNOWN,
        })
        .collect();
    OccupancyGridMessage {
        info: MapMetaData {
            map_load_time: header.stamp,
            resolution: geometry.resolution_m as f32,
            width: u32::try_from(geometry.width).unwrap_or(u32::MAX),
            height: u32::try_from(geometry.height).unwrap_or(u32::MAX),
            origin: Pose {
                position: Vector3 {
                    x: geometry.origin_m.x,
                    y: geometry.origin_m.y,
                    z: 0.0,
                },
                orientation: Quaternion::from_yaw(0.0),
            },
        },
        header,
        data: serde_bytes::ByteBuf::from(data),
    }
}

/// A received map as a map_server map in memory ([`MapMode::Raw`]: 0–100 percent, anything
/// else unknown; the image's top row first), for [`RosMap::to_grid`]. The reason names what
/// is wrong: sizes that do not match the data, more than [`MAP_CELLS_MAX`] cells, a
/// resolution or origin that is not a finite positive number.
pub fn ros_map_of_message(message: &OccupancyGridMessage) -> Result<RosMap, String> {
    let info = &message.info;
    let cells = u64::from(info.width) * u64::from(info.height);
    if cells > MAP_CELLS_MAX {
        return Err(format!(
            "{} x {} cells: more than {MAP_CELLS_MAX}",
            info.width, info.height
        ));
    }
    if cells != message.data.len() as u64 {
        return Err(format!(
            "{} cells of data for a {} x {} map",
            message.data.len(),
            info.width,
            info.height
        ));
    }
    if !(info.resolution.is_finite() && info.resolution > 0.0) {
        return Err(format!(
            "resolution {} is not a positive number",
            info.resolution
        ));
    }
    let origin = &info.origin;
    let yaw = origin.orientation.yaw();
    if ![origin.position.x, origin.position.y, yaw]
        .iter()
        .all(|v| v.is_finite())
    {
        return Err("the origin is not finite".into());
    }
    let width = info.width as usize;
    let mut pixels = Vec::with_capacity(message.data.len());
    for row in message.data.chunks_exact(width.max(1)).rev() {
        pixels.extend_from_slice(row);
    }
    Ok(RosMap {
        image: Default::default(),
        resolution_m: f64::from(info.resolution),
        origin_x_m: origin.position.x,
        origin_y_m: origin.position.y,
        origin_yaw_rad: yaw,
        negate: false,
        occupied_thresh: 0.65,
        free_thresh: 0.196,
        mode: MapMode::Raw,
        width,
        height: info.height as usize,
        pixels,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use mapmerge_grid::{log_odds_of, GridGeometry, Point2};

    #[test]
    fn a_published_map_reads_back_as_the_same_classes_and_place() {
        let geometry = GridGeometry {
            resolution_m: 0.05,
            origin_m: Point2::new(-3.0, 2.5),
            width: 3,
            height: 2,
        };
        // Bottom row: occupied, free, unknown; top row: free, unknown, occupied.
        let (occupied, free) = (log_odds_of(0.97), log_odds_of(0.12));
        let grid =
            OccupancyGrid::from_log_odds(geometry, vec![occupied, free, 0.0, free, 0.0, occupied])
                .unwrap();
        let thresholds = ClassThresholds::default();
        let message = occupancy_grid_message(&grid, &thresholds, Header::default());
        assert_eq!(message.data.as_slice(), &[100, 0, 0xFF, 0, 0xFF, 100]);
        assert_eq!(message.cell(2, 1), Some(100));
        assert_eq!(message.cell(2, 0), Some(-1));
        let back = ros_map_of_message(&message).unwrap().to_grid().unwrap();
        assert_eq!(back.geometry().width, 3);
        assert!((back.geometry().origin_m - geometry.origin_m).norm() < 1e-12);
        assert!((back.resolution_m() - 0.05).abs() < 1e-7);
        assert_eq!(back.classes(&thresholds), grid.classes(&thresholds));
    }

    #[test]
    fn maps_whose_sizes_lie_are_refused() {
        let mut message = OccupancyGridMessage::default();
        message.info.width = 4;
        message.info.height = 2;
        message.info.resolution = 0.05;
        message.data = serde_bytes::ByteBuf::from(vec![0; 7]);
        assert!(ros_map_of_message(&message)
            .unwrap_err()
            .contains("7 cells"));
        message.data = serde_bytes::ByteBuf::from(vec![0; 8]);
        message.info.resolution = f32::NAN;
        assert!(ros_map_of_message(&message)
            .unwrap_err()
            .contains("resolution"));
        message.info.resolution = 0.05;
        message.info.width = u32::MAX;
        message.info.height = u32::MAX;
        assert!(ros_map_of_message(&message)
            .unwrap_err()
            .contains("more than"));
    }
}

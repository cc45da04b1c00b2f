//! Readers and writers for pose graphs (g2o, TORO/HOG-Man), trajectories (TUM), laser logs
//! (CARMEN) and occupancy maps (ROS `map_server` YAML + PGM).
//!
//! Entry points:
//! - pose graphs: [`read_graph`] / [`parse_graph`] (format detected from the first data line;
//!   `*_with` variants take [`ReadParams`]), [`write_graph`] / [`format_graph`];
//! - trajectories: [`write_tum`] (a graph's vertices), [`read_tum_planar`] /
//!   [`write_tum_planar`] (planar `(stamp, pose)` lists);
//! - laser logs: [`read_carmen`] / [`parse_carmen`] → [`mapmerge_scan::LaserLog`],
//!   [`write_carmen`] / [`format_carmen`];
//! - maps: [`read_ros_map`] / [`write_ros_map`] → [`RosMap`], with [`RosMap::to_grid`] /
//!   [`RosMap::from_grid`] for [`mapmerge_grid::OccupancyGrid`]; [`parse_pgm`] /
//!   [`format_pgm`] for the images.
//!
//! Files are read plain or xz-compressed (recognised by their magic bytes) and written
//! xz-compressed when the name ends in `.xz`. Nothing here panics on input: every problem is an
//! [`IoError`] naming file and line. See `docs/formats.md` for the exact layouts, the
//! information-matrix ordering, the CARMEN max-range rule and the map_server semantics.
//!
//! ```
//! use mapmerge_io::{format_graph, parse_graph, AnyGraph, GraphFormat};
//! let text = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n";
//! let loaded = parse_graph(text, "example.g2o").unwrap();
//! assert_eq!(loaded.format, GraphFormat::G2o);
//! let AnyGraph::Planar(graph) = &loaded.graph else { unreachable!() };
//! assert_eq!((graph.num_vertices(), graph.num_edges()), (2, 1));
//! let again = format_graph(&loaded.graph, GraphFormat::Toro).unwrap();
//! assert_eq!(parse_graph(&again, "again.graph").unwrap().graph, loaded.graph);
//!
//! let err = parse_graph("VERTEX_SE2 0 0 0\n", "bad.g2o").unwrap_err();
//! assert_eq!(err.to_string(), "bad.g2o:1: truncated VERTEX_SE2 line: expected 4 fields after the tag, found 3");
//!
//! // A CARMEN log: one odometry reading and one 3-beam scan, written back as ROBOTLASER1.
//! let log = mapmerge_io::parse_carmen(
//!     "ODOM 1 2 0.5 0 0 0 10.0 host 10.0\nFLASER 3 1.5 81.91 2 1 2 0.5 1 2 0.5 10.1 host 10.1\n",
//!     "example.log",
//! ).unwrap();
//! assert_eq!((log.odometry.len(), log.scans.len()), (1, 1));
//! assert_eq!(log.scans[0].scan.angle_increment_rad, std::f64::consts::FRAC_PI_2);
//! let text = mapmerge_io::format_carmen(&log).unwrap();
//! assert!(text.lines().nth(1).unwrap().starts_with("ROBOTLASER1"));
//! ```

mod carmen;
mod document;
mod error;
mod g2o;
mod graph_file;
mod input;
mod kitti;
mod pgm;
mod reader;
mod rosmap;
mod toro;
mod tum;
mod writer;

pub use carmen::{
    format_carmen, old_laser_increment_rad, old_laser_max_range_m, parse_carmen, read_carmen,
    write_carmen, FRONT_LASER_MAX_PARAM, REAR_LASER_MAX_PARAM,
};
pub use document::{check_document, read_document, MAX_DOCUMENT_BYTES, MAX_DOCUMENT_DEPTH};
pub use error::IoError;
pub use graph_file::{
    format_graph, parse_graph, parse_graph_with, read_graph, read_graph_with, write_graph,
    AnyGraph, BadInformation, GraphFormat, LoadedGraph, ReadParams,
};
pub use kitti::{parse_kitti_cloud, parse_kitti_poses, read_kitti_cloud, read_kitti_poses};
pub use pgm::{format_pgm, parse_pgm, PgmImage};
pub use rosmap::{
    format_ros_map_yaml, parse_ros_map_yaml, read_ros_map, write_ros_map, write_ros_map_with,
    MapMode, RosMap, FREE_PROBABILITY, OCCUPIED_PROBABILITY,
};
pub use tum::{
    format_tum, format_tum_planar, parse_tum_planar, read_tum_planar, write_tum, write_tum_planar,
};

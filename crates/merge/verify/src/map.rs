//! What a detector sees, and the trait every detector implements.

use std::sync::Arc;

use mapmerge_geometry::Se2;
use mapmerge_posegraph::NodeId;
use mapmerge_scan::Point2;
use serde::{Deserialize, Serialize};

/// One keyframe scan of the merged map.
#[derive(Clone, Debug, PartialEq)]
pub struct DetectorScan {
    /// Its vertex.
    pub node: NodeId,
    /// Its epoch (the vertex's session id).
    pub epoch: u32,
    /// Its pose in the active map frame (the current estimate; it may change between calls,
    /// e.g. after loop closures).
    pub map_from_robot: Se2,
    /// The scan's endpoints in the robot frame, in beam order; the sensor is at the robot
    /// frame's origin (ranges and bearings are measured from there).
    pub points_in_robot: Arc<[Point2]>,
}

/// The merged map as the detectors see it after a new vertex.
#[derive(Clone, Copy, Debug)]
pub struct MergedMap<'a> {
    /// Scans of the current epoch, oldest first: the newest vertex is the last.
    pub current: &'a [DetectorScan],
    /// Scans of every other epoch merged into the active graph.
    pub other: &'a [DetectorScan],
}

/// Whether a detector's last ratio rests on anything. A merge claims that the maps overlap,
/// so a detector that finds nothing to compare has no evidence of validity: its ratio (0)
/// must not count as "valid".
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RatioSupport {
    /// Enough was compared for the ratio to be evidence either way.
    #[default]
    Supported,
    /// Too little was compared (the current scans fall where the merged epochs have no
    /// structure, or nothing overlaps): the ratio is 0 and says nothing.
    Unsupported,
}

/// An invalid-merge detector (Holoch et al., Sec. IV).
pub trait InvalidMergeDetector: Send {
    /// Short name, e.g. `change_detection`; used in result files.
    fn name(&self) -> &'static str;

    /// A merge happened (or was undone and another one made): precompute what depends only on
    /// the other epochs' data (e.g. the visibility grid of change detection, Sec. IV-A) and
    /// forget the evidence gathered for the last merge. What a detector cached may be kept
    /// where it still holds for the epochs now merged (the same epochs, not moved beyond its
    /// cache's tolerance: a conditional merge made full), as a new vertex would keep it.
    fn on_merge(&mut self, map: &MergedMap<'_>);

    /// A new current-epoch vertex was added (the last of `map.current`): the invalidity ratio
    /// in [0, 1] now. Poses in `map` may have moved since the last call.
    fn on_vertex(&mut self, map: &MergedMap<'_>) -> f64;

    /// How many compared elements the last ratio rests on (change detection: points
    /// classified *change* or *agree*; gridmap: cells known in both grids), `None` for a
    /// detector without such a count. A ratio of few elements is weak evidence either way.
    fn support(&self) -> Option<u64> {
        None
    }

    /// Whether the last ratio rests on enough compared data (see [`RatioSupport`]); detectors
    /// without a minimum of their own are always [`RatioSupport::Supported`].
    fn evidence(&self) -> RatioSupport {
        RatioSupport::Supported
    }

    /// For a detector made of other detectors: each component's name, last ratio and
    /// evidence (after the last [`InvalidMergeDetector::on_vertex`]); empty for a single
    /// detector. Lets a caller record what a combination's decision rested on.
    fn component_readings(&self) -> Vec<(&'static str, f64, RatioSupport)> {
        Vec::new()
    }
}

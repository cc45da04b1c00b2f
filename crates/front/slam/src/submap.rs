//! Submaps: consecutive keyframes' scans gathered in the frame of the first one (Hess et al.,
//! "Real-Time Loop Closure in 2D LIDAR SLAM", ICRA 2016, Sec. IV), so a scan is matched
//! against a map that is built incrementally instead of rebuilt per keyframe, and a finished
//! submap is a loop-closure target with deep branch-and-bound levels.

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::NodeId;
use mapmerge_scan::Point2;
use mapmerge_scanmatch::{ScanMatchError, ScanMatchTarget, ScanMatcher};

/// One submap: its anchor keyframe (whose frame is the submap's), the scans inserted so far
/// and the match target built from them.
pub struct Submap {
    /// The keyframe node whose frame the submap is expressed in.
    pub anchor: NodeId,
    /// Pose of the submap (= of its anchor keyframe) in the front-end's local frame, when it
    /// was created.
    pub local_from_submap: Se2,
    /// Keyframes inserted, in order, with their pose in the submap frame.
    pub keyframes: Vec<(NodeId, Se2)>,
    /// True once no more scans go in (it is then a loop-closure target).
    pub finished: bool,
    target: ScanMatchTarget,
}

impl std::fmt::Debug for Submap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Submap")
            .field("anchor", &self.anchor)
            .field("keyframes", &self.keyframes.len())
            .field("finished", &self.finished)
            .finish_non_exhaustive()
    }
}

impl Submap {
    /// An empty submap anchored at `anchor`, whose local pose is `local_from_submap`.
    pub fn new(
        matcher: &ScanMatcher,
        anchor: NodeId,
        local_from_submap: Se2,
    ) -> Result<Self, ScanMatchError> {
        Ok(Self {
            anchor,
            local_from_submap,
            keyframes: Vec::new(),
            finished: false,
            target: matcher.empty_target()?,
        })
    }

    /// Inserts keyframe `node`'s points (robot frame, beam order), seen at `local_from_robot`.
    pub fn insert(
        &mut self,
        node: NodeId,
        local_from_robot: &Se2,
        points_in_robot: &[Point2],
    ) -> Result<(), ScanMatchError> {
        let submap_from_robot = self.local_from_submap.between(local_from_robot);
        self.target
            .insert_scan(&submap_from_robot, points_in_robot)?;
        self.keyframes.push((node, submap_from_robot));
        Ok(())
    }

    /// Ends insertion and deepens the branch-and-bound levels to `depth` for loop search.
    pub fn finish(&mut self, depth: usize) -> Result<(), ScanMatchError> {
        self.finished = true;
        self.target
            .correlative_mut()
            .set_branch_and_bound_depth(depth)?;
        self.target.prepare();
        Ok(())
    }

    /// Brings the match target up to date with the scans inserted so far.
    pub fn prepare(&mut self) {
        self.target.prepare();
    }

    /// The match target (submap frame).
    pub fn target(&self) -> &ScanMatchTarget {
        &self.target
    }

    /// Pose of keyframe `node` in the submap frame, when it was inserted.
    pub fn submap_from_keyframe(&self, node: NodeId) -> Option<Se2> {
        self.keyframes
            .iter()
            .find(|(id, _)| *id == node)
            .map(|(_, pose)| *pose)
    }

    /// The member keyframe nearest to `submap_from_robot` (by position) and `keyframe_from_robot`:
    /// a constraint to it bakes in only the submap's shape between the two, not all the drift
    /// since the anchor.
    pub fn relative_to_nearest(&self, submap_from_robot: &Se2) -> Option<(NodeId, Se2)> {
        self.keyframes
            .iter()
            .min_by(|(_, a), (_, b)| {
                let da = (a.translation() - submap_from_robot.translation()).norm_squared();
                let db = (b.translation() - submap_from_robot.translation()).norm_squared();
                da.total_cmp(&db)
            })
            .map(|(node, submap_from_keyframe)| {
                (*node, submap_from_keyframe.between(submap_from_robot))
            })
    }

    /// True when the submap has no scan.
    pub fn is_empty(&self) -> bool {
        self.keyframes.is_empty()
    }
}

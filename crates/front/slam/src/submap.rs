//! Submaps: consecutive keyframes' scans gathered in the frame of the first one (Hess et al.,
//! "Real-Time Loop Closure in 2D LIDAR SLAM", ICRA 2016, Sec. IV), so a scan is matched
//! against a map that is built incrementally instead of rebuilt per keyframe, and a finished
//! submap is a loop-closure target with deep branch-and-bound levels. A finished submap may
//! release its target (tens of MB outdoors: the grid and its levels) and rebuild it from the
//! scans it keeps, so whoever holds many of them bounds the memory by the ones in use.

use std::sync::Arc;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::NodeId;
use mapmerge_scan::Point2;
use mapmerge_scanmatch::{ScanMatchError, ScanMatchTarget, ScanMatcher};

/// One submap: its anchor keyframe (whose frame is the submap's), the scans inserted so far
/// and the match target built from them (absent while released).
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
    /// Each keyframe's points (robot frame, beam order) as inserted, in `keyframes`' order:
    /// what the target is rebuilt from (shared with the keyframe's owner).
    scans: Vec<Arc<[Point2]>>,
    /// Branch-and-bound depth given by [`Submap::finish`] (`None` while it grows).
    finished_depth: Option<usize>,
    target: Option<ScanMatchTarget>,
}

impl std::fmt::Debug for Submap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Submap")
            .field("anchor", &self.anchor)
            .field("keyframes", &self.keyframes.len())
            .field("finished", &self.finished)
            .field("target_bytes", &self.target_bytes())
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
            scans: Vec::new(),
            finished_depth: None,
            target: Some(matcher.empty_target()?),
        })
    }

    /// Inserts keyframe `node`'s points (robot frame, beam order), seen at `local_from_robot`.
    pub fn insert(
        &mut self,
        node: NodeId,
        local_from_robot: &Se2,
        points_in_robot: &Arc<[Point2]>,
    ) -> Result<(), ScanMatchError> {
        let submap_from_robot = self.local_from_submap.between(local_from_robot);
        if let Some(target) = self.target.as_mut() {
            target.insert_scan(&submap_from_robot, points_in_robot)?;
        }
        self.keyframes.push((node, submap_from_robot));
        self.scans.push(Arc::clone(points_in_robot));
        Ok(())
    }

    /// Ends insertion and deepens the branch-and-bound levels to `depth` for loop search.
    pub fn finish(&mut self, depth: usize) -> Result<(), ScanMatchError> {
        self.finished = true;
        self.finished_depth = Some(depth);
        if let Some(target) = self.target.as_mut() {
            Self::deepen(target, depth)?;
        }
        Ok(())
    }

    /// Levels to `depth` for loop search, and the scratch of their computation freed.
    fn deepen(target: &mut ScanMatchTarget, depth: usize) -> Result<(), ScanMatchError> {
        target.correlative_mut().set_branch_and_bound_depth(depth)?;
        target.prepare();
        target.correlative_mut().release_scratch();
        Ok(())
    }

    /// Brings the match target up to date with the scans inserted so far.
    pub fn prepare(&mut self) {
        if let Some(target) = self.target.as_mut() {
            target.prepare();
        }
    }

    /// The match target (submap frame); `None` while released ([`Submap::release_target`]).
    pub fn target(&self) -> Option<&ScanMatchTarget> {
        self.target.as_ref()
    }

    /// Bytes the match target holds on the heap (0 while released).
    pub fn target_bytes(&self) -> usize {
        self.target.as_ref().map_or(0, ScanMatchTarget::heap_bytes)
    }

    /// Drops the match target of a finished submap (the scans stay); returns whether it had
    /// one. A submap that still grows keeps it.
    pub fn release_target(&mut self) -> bool {
        self.finished && self.target.take().is_some()
    }

    /// Rebuilds a released target from the kept scans, exactly as it was built (the same
    /// insertions in the same order, then the same depth); returns its bytes. Does nothing
    /// when the target is there.
    pub fn restore_target(&mut self, matcher: &ScanMatcher) -> Result<usize, ScanMatchError> {
        if self.target.is_none() {
            let mut target = matcher.empty_target()?;
            for ((_, submap_from_robot), points) in self.keyframes.iter().zip(&self.scans) {
                target.insert_scan(submap_from_robot, points)?;
            }
            match self.finished_depth {
                Some(depth) => Self::deepen(&mut target, depth)?,
                None => target.prepare(),
            }
            self.target = Some(target);
        }
        Ok(self.target_bytes())
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

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use mapmerge_scanmatch::{ScanMatchParams, SearchWindow};

    /// A room's walls as a scan from `(x, 0)`, in beam order.
    fn room_scan(x_m: f64) -> Arc<[Point2]> {
        (0..360)
            .map(|k| {
                let a = f64::from(k).to_radians();
                let (s, c) = a.sin_cos();
                // Walls at x = ±6, y = ±4 (room frame).
                let t_x = if c > 0.0 {
                    (6.0 - x_m) / c
                } else if c < 0.0 {
                    (-6.0 - x_m) / c
                } else {
                    f64::INFINITY
                };
                let t_y = if s > 0.0 {
                    4.0 / s
                } else if s < 0.0 {
                    -4.0 / s
                } else {
                    f64::INFINITY
                };
                let t = t_x.min(t_y);
                Point2::new(t * c, t * s)
            })
            .collect()
    }

    #[test]
    fn a_released_target_is_rebuilt_as_it_was_and_only_a_finished_one_is_released() {
        let matcher = ScanMatcher::new(ScanMatchParams::default()).unwrap();
        let mut submap = Submap::new(&matcher, NodeId(0), Se2::identity()).unwrap();
        for (k, x_m) in [0.0, 0.5, 1.0, 1.5].into_iter().enumerate() {
            submap
                .insert(NodeId(k as u64), &Se2::new(x_m, 0.0, 0.0), &room_scan(x_m))
                .unwrap();
        }
        assert!(
            !submap.release_target(),
            "a growing submap keeps its target"
        );
        submap.finish(7).unwrap();
        let query = room_scan(0.8);
        let guess = Se2::new(0.6, 0.2, 0.05);
        let window = SearchWindow::new(1.0, 0.2);
        let before = matcher
            .match_scan(submap.target().unwrap(), &query, &guess, &window)
            .unwrap();
        let bytes = submap.target_bytes();
        assert!(bytes > 0);
        assert!(submap.release_target());
        assert!(submap.target().is_none());
        assert!(!submap.release_target(), "released once");
        assert_eq!(submap.target_bytes(), 0);
        assert_eq!(submap.restore_target(&matcher).unwrap(), bytes);
        let after = matcher
            .match_scan(submap.target().unwrap(), &query, &guess, &window)
            .unwrap();
        assert_eq!(before, after);
        assert!(
            (after.target_from_query.x_m - 0.8).abs() < 0.05,
            "{after:?}"
        );
    }
}

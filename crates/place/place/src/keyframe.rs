//! Keyframes: the points a place is recognised from, in the keyframe's own frame.

use std::sync::Arc;

use mapmerge_grid::FreeSpace;
use mapmerge_scan::Point2;
use serde::{Deserialize, Serialize};

/// Identifies a keyframe (a pose-graph node's scan or local map) across sessions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct KeyframeId(pub u64);

impl std::fmt::Display for KeyframeId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "keyframe {}", self.0)
    }
}

/// A keyframe: one scan's points, or a small local map (several scans merged), expressed in
/// the robot frame at the keyframe's node. Non-finite points are allowed and ignored.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Keyframe {
    /// Its id.
    pub id: KeyframeId,
    /// Obstacle points in the keyframe frame (m), shared: a keyframe is made from stored
    /// points without copying them.
    pub points_in_keyframe: Arc<[Point2]>,
    /// Where the sensor saw through while taking those points (keyframe frame), when the
    /// keyframe was built with its rays ([`Keyframe::with_free_space`]). Verification then
    /// compares two keyframes over their whole overlap, free against occupied
    /// ([`crate::Evidence::agreement`]); without it the free space is approximated from the
    /// keyframe's origin.
    #[serde(default)]
    pub free_space: Option<Arc<FreeSpace>>,
}

impl Keyframe {
    /// A keyframe with id `id` and the points `points_in_keyframe` (a `Vec` or a shared
    /// `Arc<[Point2]>`).
    pub fn new(id: u64, points_in_keyframe: impl Into<Arc<[Point2]>>) -> Self {
        Self {
            id: KeyframeId(id),
            points_in_keyframe: points_in_keyframe.into(),
            free_space: None,
        }
    }

    /// The same keyframe with the free space its rays crossed.
    pub fn with_free_space(mut self, free_space: FreeSpace) -> Self {
        self.free_space = Some(Arc::new(free_space));
        self
    }

    /// The same keyframe with the free space that `rays` (sensor origin, return; keyframe
    /// frame) crossed, at `resolution_m`. Unchanged when `resolution_m` is not positive or
    /// the rays make no free space (verification then approximates it from the origin).
    pub fn with_rays(
        self,
        resolution_m: f64,
        rays: impl IntoIterator<Item = (Point2, Point2)>,
    ) -> Self {
        if resolution_m.is_nan() || resolution_m <= 0.0 {
            return self;
        }
        match FreeSpace::from_rays(resolution_m, rays) {
            Ok(free) => self.with_free_space(free),
            Err(_) => self,
        }
    }
}

//! Retrieval: a k-d tree over retrieval (ring) keys, re-ranked by the full descriptor
//! distance (Kim & Kim, IROS 2018, Sec. IV: ring-key k-NN, then Eq. 6 on the candidates).

use std::num::NonZeroUsize;

use kiddo::{MutableKdTree, SquaredEuclidean};
use serde::{Deserialize, Serialize};

use crate::descriptor::PlaceDescriptor;
use crate::keyframe::KeyframeId;
use crate::scan_context::ScanContext;

/// Dimension of the k-d tree's keys; retrieval keys of another length are resampled (mean
/// over equal slices, zero padding) to this length.
const TREE_DIMS: usize = 20;

/// Parameters of the index.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct IndexParams {
    /// How many ring-key nearest neighbours are re-ranked by the full descriptor distance
    /// (default: 25). More finds places whose ring key drifted (translation, clutter) at a
    /// cost linear in this number; at least the `k` of each query is used.
    pub ring_key_neighbours: usize,
}

impl Default for IndexParams {
    fn default() -> Self {
        Self {
            ring_key_neighbours: 25,
        }
    }
}

/// One retrieved place.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// The indexed keyframe.
    pub keyframe: KeyframeId,
    /// Euclidean distance between the retrieval (ring) keys.
    pub ring_key_distance: f64,
    /// Full descriptor distance (Scan Context: Eq. 6, in `[0, 1]`); candidates are ranked by it.
    pub descriptor_distance: f64,
    /// Estimated yaw of the query in the candidate's frame (rad): the rotation guess for
    /// `candidate_from_query`.
    pub yaw_rad: f64,
}

/// An indexed keyframe.
#[derive(Clone, Debug)]
struct Entry<D> {
    id: KeyframeId,
    descriptor: D,
}

/// Place-recognition index over many keyframes: incremental insertion into a kiddo k-d tree
/// of retrieval keys; queries take the ring-key neighbours and rank them by the full
/// descriptor distance.
pub struct PlaceIndex<D: PlaceDescriptor = ScanContext> {
    params: IndexParams,
    entries: Vec<Entry<D>>,
    tree: MutableKdTree<f32, TREE_DIMS>,
    /// Ordinals the tree refused (too many identical keys to split a bucket); searched by
    /// brute force.
    overflow: Vec<u32>,
}

impl<D: PlaceDescriptor> std::fmt::Debug for PlaceIndex<D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PlaceIndex")
            .field("params", &self.params)
            .field("len", &self.entries.len())
            .field("overflow", &self.overflow.len())
            .finish()
    }
}

/// `key` resampled to the tree's dimension; non-finite values become 0.
fn tree_key(key: &[f32]) -> [f32; TREE_DIMS] {
    let mut out = [0.0f32; TREE_DIMS];
    if key.len() <= TREE_DIMS {
        for (o, k) in out.iter_mut().zip(key) {
            *o = *k;
        }
    } else {
        for (i, o) in out.iter_mut().enumerate() {
            let start = i * key.len() / TREE_DIMS;
            let end = ((i + 1) * key.len() / TREE_DIMS).max(start + 1);
            if let Some(slice) = key.get(start..end) {
                *o = slice.iter().sum::<f32>() / slice.len() as f32;
            }
        }
    }
    for o in &mut out {
        if !o.is_finite() {
            *o = 0.0;
        }
    }
    out
}

/// Squared Euclidean distance between two tree keys.
fn squared_distance(a: &[f32; TREE_DIMS], b: &[f32; TREE_DIMS]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

impl<D: PlaceDescriptor> Default for PlaceIndex<D> {
    fn default() -> Self {
        Self::new(IndexParams::default())
    }
}

impl<D: PlaceDescriptor> PlaceIndex<D> {
    /// An empty index.
    pub fn new(params: IndexParams) -> Self {
        Self {
            params,
            entries: Vec::new(),
            tree: MutableKdTree::default(),
            overflow: Vec::new(),
        }
    }

    /// Number of indexed keyframes.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// True when nothing is indexed.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The descriptor of the `ordinal`-th inserted keyframe.
    pub fn descriptor(&self, ordinal: usize) -> Option<&D> {
        self.entries.get(ordinal).map(|e| &e.descriptor)
    }

    /// Adds a keyframe; it becomes the newest (ordinal `len() − 1`). Ids need not be unique,
    /// but candidates report ids only. Beyond `u32::MAX` entries, keyframes are ignored.
    pub fn insert(&mut self, keyframe: KeyframeId, descriptor: D) {
        let Ok(ordinal) = u32::try_from(self.entries.len()) else {
            return;
        };
        let key = tree_key(descriptor.retrieval_key());
        if self.tree.add(&key, ordinal).is_err() {
            self.overflow.push(ordinal);
        }
        self.entries.push(Entry {
            id: keyframe,
            descriptor,
        });
    }

    /// The `k` best candidates for `descriptor` among all indexed keyframes, best first.
    pub fn query(&self, descriptor: &D, k: usize) -> Vec<Candidate> {
        self.query_filtered(descriptor, k, |_, _| true)
    }

    /// As [`PlaceIndex::query`], ignoring the `recent` most recently inserted keyframes:
    /// for intra-session loop closure, where the robot's last keyframes trivially look alike.
    pub fn query_excluding_recent(
        &self,
        descriptor: &D,
        k: usize,
        recent: usize,
    ) -> Vec<Candidate> {
        let newest_allowed = self.entries.len().saturating_sub(recent);
        self.query_filtered(descriptor, k, |ordinal, _| ordinal < newest_allowed)
    }

    /// As [`PlaceIndex::query`], considering only keyframes for which
    /// `keep(insertion ordinal, id)` holds.
    pub fn query_filtered(
        &self,
        descriptor: &D,
        k: usize,
        keep: impl Fn(usize, KeyframeId) -> bool,
    ) -> Vec<Candidate> {
        if k == 0 || self.entries.is_empty() {
            return Vec::new();
        }
        let wanted = self.params.ring_key_neighbours.max(k);
        let key = tree_key(descriptor.retrieval_key());
        let kept = |ordinal: usize| {
            self.entries
                .get(ordinal)
                .is_some_and(|e| keep(ordinal, e.id))
        };
        // Ring-key neighbours: ask the tree for more until enough survive the filter.
        let mut neighbours: Vec<(f32, usize)> = Vec::new();
        let mut ask = wanted;
        while let Some(n) = NonZeroUsize::new(ask.min(self.entries.len())) {
            let found = self
                .tree
                .query(&key)
                .nearest_n::<SquaredEuclidean<f32>>(n)
                .execute();
            let exhausted = found.len() < n.get() || n.get() >= self.entries.len();
            neighbours = found
                .into_iter()
                .map(|item| (item.distance, item.item as usize))
                .filter(|&(_, ordinal)| kept(ordinal))
                .collect();
            if neighbours.len() >= wanted || exhausted {
                break;
            }
            ask = ask.saturating_mul(4);
        }
        for &ordinal in &self.overflow {
            let ordinal = ordinal as usize;
            if let Some(entry) = self.entries.get(ordinal) {
                if kept(ordinal) {
                    let d = squared_distance(&key, &tree_key(entry.descriptor.retrieval_key()));
                    neighbours.push((d, ordinal));
                }
            }
        }
        neighbours.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        neighbours.dedup_by_key(|n| n.1);
        neighbours.truncate(wanted);
        // Kim & Kim, Eq. 6 on every ring-key neighbour, then rank by it.
        let mut candidates: Vec<(usize, Candidate)> = neighbours
            .into_iter()
            .filter_map(|(squared, ordinal)| {
                let entry = self.entries.get(ordinal)?;
                let m = descriptor.compare(&entry.descriptor);
                Some((
                    ordinal,
                    Candidate {
                        keyframe: entry.id,
                        ring_key_distance: f64::from(squared.max(0.0)).sqrt(),
                        descriptor_distance: m.distance,
                        yaw_rad: m.yaw_rad,
                    },
                ))
            })
            .collect();
        candidates.sort_by(|a, b| {
            a.1.descriptor_distance
                .total_cmp(&b.1.descriptor_distance)
                .then(a.0.cmp(&b.0))
        });
        candidates.truncate(k);
        candidates.into_iter().map(|(_, c)| c).collect()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;
    use crate::scan_context::ScanContextParams;
    use mapmerge_scan::Point2;

    /// A rectangular room `w × h` seen from its centre plus a box at `(bx, by)`.
    fn room(w: f64, h: f64, bx: f64, by: f64) -> Vec<Point2> {
        let mut points = Vec::new();
        for i in 0..200 {
            let t = f64::from(i) / 200.0;
            points.push(Point2::new(-w / 2.0 + w * t, -h / 2.0));
            points.push(Point2::new(-w / 2.0 + w * t, h / 2.0));
            points.push(Point2::new(-w / 2.0, -h / 2.0 + h * t));
            points.push(Point2::new(w / 2.0, -h / 2.0 + h * t));
            points.push(Point2::new(bx + 0.5 * t, by));
        }
        points
    }

    fn index_of_rooms() -> (PlaceIndex, Vec<ScanContext>) {
        let params = ScanContextParams::default();
        let mut index = PlaceIndex::default();
        let mut all = Vec::new();
        for i in 0..100 {
            let w = 3.0 + 0.1 * f64::from(i % 10);
            let h = 2.0 + 0.15 * f64::from(i / 10);
            let d = ScanContext::new(&room(w, h, 0.5, -0.3), &params);
            index.insert(KeyframeId(i as u64), d.clone());
            all.push(d);
        }
        (index, all)
    }

    #[test]
    fn finds_itself_first() {
        let (index, all) = index_of_rooms();
        for (i, d) in all.iter().enumerate() {
            let found = index.query(d, 3);
            assert_eq!(found.len(), 3);
            assert_eq!(found[0].keyframe, KeyframeId(i as u64));
            assert!(found[0].descriptor_distance < 1e-6);
            assert!(found[0].ring_key_distance < 1e-6);
            assert!(found
                .windows(2)
                .all(|w| w[0].descriptor_distance <= w[1].descriptor_distance));
        }
    }

    #[test]
    fn excludes_recent_and_filtered() {
        let (index, all) = index_of_rooms();
        let last = all.last().unwrap();
        let found = index.query_excluding_recent(last, 5, 10);
        assert_eq!(found.len(), 5);
        assert!(found.iter().all(|c| c.keyframe.0 < 90));
        let found = index.query_filtered(last, 5, |_, id| id.0 % 2 == 0);
        assert!(found.iter().all(|c| c.keyframe.0 % 2 == 0));
        assert!(index.query_excluding_recent(last, 5, 1000).is_empty());
    }

    #[test]
    fn empty_index_and_identical_keys() {
        let index: PlaceIndex = PlaceIndex::default();
        let empty = ScanContext::new(&[], &ScanContextParams::default());
        assert!(index.query(&empty, 5).is_empty());
        // Many identical (empty) keys: more than a k-d tree bucket holds.
        let mut index: PlaceIndex = PlaceIndex::default();
        for i in 0..500 {
            index.insert(KeyframeId(i), empty.clone());
        }
        let found = index.query(&empty, 4);
        assert_eq!(found.len(), 4);
        assert_eq!(index.len(), 500);
    }

    #[test]
    fn resamples_keys_of_any_length() {
        assert_eq!(tree_key(&[1.0; 40]), [1.0; TREE_DIMS]);
        let short = tree_key(&[2.0, f32::NAN]);
        assert_eq!(short[0], 2.0);
        assert_eq!(short[1], 0.0);
    }
}

//! Retrieval: a k-d tree over retrieval (ring) keys, re-ranked by the full descriptor
//! distance (Kim & Kim, IROS 2018, Sec. IV: ring-key k-NN, then Eq. 6 on the candidates).

use std::num::NonZeroUsize;

use kiddo::{MutableKdTree, SquaredEuclidean};
use mapmerge_params::{Checker, Validate};
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
    /// Full descriptor distance (Scan Context: Eq. 6, in `[0, 1]`); the first list is ranked
    /// by it.
    pub descriptor_distance: f64,
    /// Cosine distance of the appearance vectors ([`PlaceDescriptor::appearance`], in
    /// `[0, 2]`); the second list is ranked by it. Infinite when either has none.
    pub appearance_distance: f64,
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
/// descriptor distance. Descriptors with an appearance vector
/// ([`PlaceDescriptor::appearance`]) also give a second list, the nearest appearances by
/// cosine distance (brute force over contiguous rows: 20,000 keyframes × 256 values is about
/// a millisecond), fused with the first.
pub struct PlaceIndex<D: PlaceDescriptor = ScanContext> {
    params: IndexParams,
    entries: Vec<Entry<D>>,
    /// Appearance rows, `appearance_dim` values per entry in insertion order (zeros for an
    /// entry without one: never retrieved by appearance).
    appearance_rows: Vec<f32>,
    /// Length of the appearance vectors (that of the first non-empty one; 0 while none).
    appearance_dim: usize,
    /// Whether entry `i` has an appearance row of `appearance_dim` values that is not all
    /// zeros (set once at insertion, so queries skip the others without reading them).
    has_appearance: Vec<bool>,
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

/// Cosine distance `1 − a·b` of two unit vectors (the appearance rows and queries).
fn unit_cosine_distance(a: &[f32], b: &[f32]) -> f32 {
    1.0 - a.iter().zip(b).map(|(x, y)| x * y).sum::<f32>()
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
            appearance_rows: Vec::new(),
            appearance_dim: 0,
            has_appearance: Vec::new(),
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
        let appearance = descriptor.appearance();
        if self.appearance_dim == 0 && !appearance.is_empty() {
            self.appearance_dim = appearance.len();
            self.appearance_rows = vec![0.0; self.entries.len() * appearance.len()];
        }
        let usable = self.appearance_dim > 0
            && appearance.len() == self.appearance_dim
            && appearance.iter().any(|&v| v != 0.0);
        if usable {
            self.appearance_rows.extend_from_slice(appearance);
        } else if self.appearance_dim > 0 {
            let len = self.appearance_rows.len();
            self.appearance_rows.resize(len + self.appearance_dim, 0.0);
        }
        self.has_appearance.push(usable);
        self.entries.push(Entry {
            id: keyframe,
            descriptor,
        });
    }

    /// The `k` best candidates for `descriptor` among all indexed keyframes, best first; with
    /// appearance vectors, the `k` best of each list (at most `2k`), ordered by their better
    /// rank in either list (ties: Scan Context's first).
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
        let (by_descriptor, by_appearance) = self.lists(descriptor, k, keep);
        // Fuse: (better rank, list, ordinal) orders the union.
        let mut fused: Vec<((usize, usize, usize), Candidate)> = by_descriptor
            .into_iter()
            .enumerate()
            .map(|(rank, (ordinal, c))| ((rank, 0, ordinal), c))
            .collect();
        for (rank, (ordinal, c)) in by_appearance.into_iter().enumerate() {
            if let Some(existing) = fused.iter_mut().find(|(key, _)| key.2 == ordinal) {
                existing.0 = existing.0.min((rank, 1, ordinal));
            } else {
                fused.push(((rank, 1, ordinal), c));
            }
        }
        fused.sort_by_key(|(key, _)| *key);
        fused.into_iter().map(|(_, c)| c).collect()
    }

    /// The two lists [`PlaceIndex::query_filtered`] fuses, each best first: the `k` best by
    /// the full descriptor distance among the ring-key neighbours, and the `k` nearest
    /// appearances (empty without appearance vectors). For measuring each list alone.
    pub fn query_lists_filtered(
        &self,
        descriptor: &D,
        k: usize,
        keep: impl Fn(usize, KeyframeId) -> bool,
    ) -> (Vec<Candidate>, Vec<Candidate>) {
        let (a, b) = self.lists(descriptor, k, keep);
        let drop_ordinal =
            |list: Vec<(usize, Candidate)>| list.into_iter().map(|(_, c)| c).collect();
        (drop_ordinal(a), drop_ordinal(b))
    }

    /// Both lists with the insertion ordinal of each candidate.
    #[allow(clippy::type_complexity)]
    fn lists(
        &self,
        descriptor: &D,
        k: usize,
        keep: impl Fn(usize, KeyframeId) -> bool,
    ) -> (Vec<(usize, Candidate)>, Vec<(usize, Candidate)>) {
        if k == 0 || self.entries.is_empty() {
            return (Vec::new(), Vec::new());
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
        let query_appearance = descriptor.appearance();
        let candidate_of = |ordinal: usize, ring_key_distance: f64| -> Option<Candidate> {
            let entry = self.entries.get(ordinal)?;
            let m = descriptor.compare(&entry.descriptor);
            Some(Candidate {
                keyframe: entry.id,
                ring_key_distance,
                descriptor_distance: m.distance,
                appearance_distance: self.appearance_distance(query_appearance, ordinal),
                yaw_rad: m.yaw_rad,
            })
        };
        let mut candidates: Vec<(usize, Candidate)> = neighbours
            .into_iter()
            .filter_map(|(squared, ordinal)| {
                Some((
                    ordinal,
                    candidate_of(ordinal, f64::from(squared.max(0.0)).sqrt())?,
                ))
            })
            .collect();
        candidates.sort_by(|a, b| {
            a.1.descriptor_distance
                .total_cmp(&b.1.descriptor_distance)
                .then(a.0.cmp(&b.0))
        });
        candidates.truncate(k);
        // The second list: nearest appearances among the kept keyframes.
        let by_appearance = self
            .nearest_appearances(query_appearance, k, &kept)
            .into_iter()
            .filter_map(|(_, ordinal)| {
                let entry = self.entries.get(ordinal)?;
                let squared = squared_distance(&key, &tree_key(entry.descriptor.retrieval_key()));
                Some((
                    ordinal,
                    candidate_of(ordinal, f64::from(squared.max(0.0)).sqrt())?,
                ))
            })
            .collect();
        (candidates, by_appearance)
    }

    /// Cosine distance between `query` and the appearance row of `ordinal` (rows and queries
    /// are unit vectors or zeros); infinite when either is missing.
    fn appearance_distance(&self, query: &[f32], ordinal: usize) -> f64 {
        let dim = self.appearance_dim;
        match self.appearance_rows.get(ordinal * dim..(ordinal + 1) * dim) {
            Some(row) if query.len() == dim && self.has_appearance.get(ordinal) == Some(&true) => {
                f64::from(unit_cosine_distance(row, query))
            }
            _ => f64::INFINITY,
        }
    }

    /// The `k` kept ordinals whose appearance rows are nearest to `query`: `(distance,
    /// ordinal)`, nearest first; empty without appearance vectors.
    fn nearest_appearances(
        &self,
        query: &[f32],
        k: usize,
        kept: &impl Fn(usize) -> bool,
    ) -> Vec<(f32, usize)> {
        let dim = self.appearance_dim;
        if k == 0 || dim == 0 || query.len() != dim || query.iter().all(|&v| v == 0.0) {
            return Vec::new();
        }
        let mut nearest: Vec<(f32, usize)> = self
            .appearance_rows
            .chunks_exact(dim)
            .enumerate()
            .filter(|(ordinal, _)| {
                self.has_appearance.get(*ordinal) == Some(&true) && kept(*ordinal)
            })
            .map(|(ordinal, row)| (unit_cosine_distance(row, query), ordinal))
            .filter(|(d, _)| d.is_finite())
            .collect();
        if nearest.len() > k {
            nearest.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            nearest.truncate(k);
        }
        nearest.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        nearest
    }
}

impl Validate for IndexParams {
    fn check(&self, check: &mut Checker) {
        check.size("ring_key_neighbours", self.ring_key_neighbours, 1, 10_000);
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

    /// A toy descriptor: a one-number key (its distance is the "Scan Context" distance) and
    /// an explicit appearance vector.
    #[derive(Clone, Debug)]
    struct Toy {
        key: [f32; 1],
        appearance: Vec<f32>,
    }

    impl PlaceDescriptor for Toy {
        fn retrieval_key(&self) -> &[f32] {
            &self.key
        }
        fn compare(&self, candidate: &Self) -> crate::DescriptorMatch {
            crate::DescriptorMatch {
                distance: f64::from((self.key[0] - candidate.key[0]).abs()),
                yaw_rad: 0.0,
            }
        }
        fn appearance(&self) -> &[f32] {
            &self.appearance
        }
    }

    fn unit(angle: f32) -> Vec<f32> {
        vec![angle.cos(), angle.sin()]
    }

    #[test]
    fn fuses_the_appearance_list_with_the_first() {
        let mut index: PlaceIndex<Toy> = PlaceIndex::default();
        // Keys 0..50 (key i at i/100); appearances all far from the query's except keyframe 40.
        for i in 0..50u64 {
            let angle = if i == 40 { 0.05 } else { 1.0 + i as f32 * 0.01 };
            index.insert(
                KeyframeId(i),
                Toy {
                    key: [i as f32 / 100.0],
                    appearance: unit(angle),
                },
            );
        }
        let query = Toy {
            key: [0.0],
            appearance: unit(0.0),
        };
        let found = index.query(&query, 3);
        let ids: Vec<u64> = found.iter().map(|c| c.keyframe.0).collect();
        // Rank 0 of each list first (Scan Context's before the appearance's), then rank 1 …
        assert_eq!(ids[0], 0);
        assert_eq!(ids[1], 40, "{ids:?}");
        assert!(ids.len() <= 6 && ids.len() >= 4, "{ids:?}");
        let mut unique = ids.clone();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), ids.len(), "no keyframe twice: {ids:?}");
        let forty = found.iter().find(|c| c.keyframe.0 == 40).unwrap();
        assert!(forty.appearance_distance < 0.01);
        assert!((forty.descriptor_distance - 0.4).abs() < 1e-6);
        // The two lists alone: k each, and their union is the fused list.
        let (first, second) = index.query_lists_filtered(&query, 3, |_, _| true);
        assert_eq!(
            first.iter().map(|c| c.keyframe.0).collect::<Vec<_>>(),
            vec![0, 1, 2]
        );
        assert_eq!(second[0].keyframe.0, 40);
        assert_eq!(second.len(), 3);
        let mut union: Vec<u64> = first.iter().chain(&second).map(|c| c.keyframe.0).collect();
        union.sort_unstable();
        union.dedup();
        assert_eq!(union, unique);
        // The filter applies to both lists.
        let filtered = index.query_filtered(&query, 3, |_, id| id.0 != 40);
        assert!(filtered.iter().all(|c| c.keyframe.0 != 40));
        // Without an appearance in the query: the first list alone.
        let plain = Toy {
            key: [0.0],
            appearance: Vec::new(),
        };
        let found = index.query(&plain, 3);
        assert_eq!(found.len(), 3);
        assert!(found.iter().all(|c| c.appearance_distance.is_infinite()));
    }

    #[test]
    fn entries_without_appearance_are_never_retrieved_by_it() {
        let mut index: PlaceIndex<Toy> = PlaceIndex::default();
        index.insert(
            KeyframeId(0),
            Toy {
                key: [0.9],
                appearance: Vec::new(),
            },
        );
        index.insert(
            KeyframeId(1),
            Toy {
                key: [0.5],
                appearance: unit(0.0),
            },
        );
        let query = Toy {
            key: [0.0],
            appearance: unit(0.0),
        };
        let found = index.query(&query, 1);
        let ids: Vec<u64> = found.iter().map(|c| c.keyframe.0).collect();
        assert_eq!(ids, vec![1]);
        assert!(index
            .appearance_distance(&query.appearance, 0)
            .is_infinite());
    }

    #[test]
    fn resamples_keys_of_any_length() {
        assert_eq!(tree_key(&[1.0; 40]), [1.0; TREE_DIMS]);
        let short = tree_key(&[2.0, f32::NAN]);
        assert_eq!(short[0], 2.0);
        assert_eq!(short[1], 0.0);
    }
}

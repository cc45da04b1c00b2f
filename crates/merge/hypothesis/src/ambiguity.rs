//! The ambiguous-view tracker (Banerjee et al., Sec. 5.3, Fig. 10): a view is ambiguous when
//! the back-end keeps refusing observations of it from different places while the robot is
//! sure of its pose thanks to a recently accepted observation of an older ("trusted") view.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use mapmerge_params::{Checker, Real, Validate};
use serde::{Deserialize, Serialize};

use crate::HypothesisError;

/// An item stamped with the robot travel when it was added.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrackedEntry<T> {
    /// Robot travel when added (m).
    pub travel_m: f64,
    /// The item.
    pub item: T,
}

/// A distance tracker (DT): recent items, forgotten once the robot has travelled more than
/// `window_m` since they were added.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DistanceTracker<T> {
    window_m: f64,
    entries: VecDeque<TrackedEntry<T>>,
}

impl<T> DistanceTracker<T> {
    /// An empty tracker that keeps items for `window_m` of travel.
    pub fn new(window_m: f64) -> Self {
        Self {
            window_m,
            entries: VecDeque::new(),
        }
    }

    /// Its window (m).
    pub fn window_m(&self) -> f64 {
        self.window_m
    }

    /// Adds `item` at `travel_m`; a non-finite travel is ignored (returns false).
    pub fn push(&mut self, travel_m: f64, item: T) -> bool {
        if !travel_m.is_finite() {
            return false;
        }
        self.entries.push_back(TrackedEntry { travel_m, item });
        true
    }

    /// Drops the entries added more than `window_m` before `travel_m`; returns how many.
    pub fn prune(&mut self, travel_m: f64) -> usize {
        let before = self.entries.len();
        let window_m = self.window_m;
        self.entries.retain(|e| travel_m - e.travel_m <= window_m);
        before - self.entries.len()
    }

    /// The entries, oldest first.
    pub fn iter(&self) -> impl Iterator<Item = &TrackedEntry<T>> {
        self.entries.iter()
    }

    /// Number of entries.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

/// Parameters of [`AmbiguityTracker`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AmbiguityParams {
    /// A view needs this many rejected observations within the window to be a candidate
    /// (default: 2). More means fewer views marked and more bad edges offered first.
    pub min_rejected: usize,
    /// … and the robot must have travelled this far since the first of them (m) (default: 1),
    /// so that the view was seen from distinct places.
    pub min_spread_m: f64,
    /// Rejected observations are forgotten after this much travel (m) (default: 10).
    pub rejected_window_m: f64,
    /// The robot counts as certain of its pose for this much travel after an accepted
    /// observation of a trusted view (m) (default: 3); the accepted DT's window.
    pub certainty_window_m: f64,
}

impl Default for AmbiguityParams {
    fn default() -> Self {
        Self {
            min_rejected: 2,
            min_spread_m: 1.0,
            rejected_window_m: 10.0,
            certainty_window_m: 3.0,
        }
    }
}

impl AmbiguityParams {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<(), HypothesisError> {
        Ok(Validate::validate(self)?)
    }
}

impl Validate for AmbiguityParams {
    fn check(&self, check: &mut Checker) {
        check
            .size("min_rejected", self.min_rejected, 1, 100_000)
            .real("min_spread_m", self.min_spread_m, Real::non_negative())
            .real(
                "rejected_window_m",
                self.rejected_window_m,
                Real::non_negative(),
            )
            .real(
                "certainty_window_m",
                self.certainty_window_m,
                Real::non_negative(),
            );
    }
}

/// Entry of the structure `V`: a view's rejected observations within the window.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RejectedView {
    /// Rejected observations of the view.
    pub rejected: usize,
    /// Robot travel at the first of them (m).
    pub first_travel_m: f64,
}

/// An accepted observation of a view, with the view's creation order.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
struct AcceptedView {
    view: u64,
    created_order: u64,
}

/// The ambiguity tracker (Sec. 5.3, Fig. 10): a rejected-observation DT and an
/// accepted-observation DT; views once marked ambiguous stay ambiguous.
#[derive(Clone, Debug)]
pub struct AmbiguityTracker {
    params: AmbiguityParams,
    rejected: DistanceTracker<u64>,
    accepted: DistanceTracker<AcceptedView>,
    ambiguous: BTreeSet<u64>,
}

impl AmbiguityTracker {
    /// An empty tracker; refuses parameters out of range.
    pub fn new(params: AmbiguityParams) -> Result<Self, HypothesisError> {
        params.validate()?;
        Ok(Self {
            rejected: DistanceTracker::new(params.rejected_window_m),
            accepted: DistanceTracker::new(params.certainty_window_m),
            params,
            ambiguous: BTreeSet::new(),
        })
    }

    /// Its parameters.
    pub fn params(&self) -> &AmbiguityParams {
        &self.params
    }

    /// An observation of `view` the back-end refused: it contradicted the robot's confident
    /// estimate. A non-finite travel is ignored.
    pub fn on_rejected(&mut self, view: u64, travel_m: f64) {
        self.rejected.push(travel_m, view);
    }

    /// An observation of `view` the back-end accepted. `view_created_order` orders views by
    /// creation and is compared with the ids of rejected views: pass the view's node id when
    /// node ids grow with time, as they do in mapmerge. A non-finite travel is ignored.
    pub fn on_accepted(&mut self, view: u64, view_created_order: u64, travel_m: f64) {
        self.accepted.push(
            travel_m,
            AcceptedView {
                view,
                created_order: view_created_order,
            },
        );
    }

    /// The structure `V` at the last [`AmbiguityTracker::update`]: every view with rejected
    /// observations in the window.
    pub fn rejected_views(&self) -> BTreeMap<u64, RejectedView> {
        let mut views: BTreeMap<u64, RejectedView> = BTreeMap::new();
        for entry in self.rejected.iter() {
            views
                .entry(entry.item)
                .and_modify(|v| {
                    v.rejected += 1;
                    v.first_travel_m = v.first_travel_m.min(entry.travel_m);
                })
                .or_insert(RejectedView {
                    rejected: 1,
                    first_travel_m: entry.travel_m,
                });
        }
        views
    }

    /// Prunes both trackers at `travel_m` and marks the new ambiguous views: candidates
    /// (`min_rejected` rejected observations, the first at least `min_spread_m` ago) for which
    /// an older view (`view_created_order` below the candidate's id) was accepted within
    /// `certainty_window_m`. Returns the newly marked views, ascending.
    pub fn update(&mut self, travel_m: f64) -> Vec<u64> {
        if !travel_m.is_finite() {
            return Vec::new();
        }
        self.rejected.prune(travel_m);
        self.accepted.prune(travel_m);
        let certain_since = travel_m - self.params.certainty_window_m;
        let mut marked = Vec::new();
        for (view, v) in self.rejected_views() {
            let candidate = v.rejected >= self.params.min_rejected
                && travel_m - v.first_travel_m >= self.params.min_spread_m;
            if !candidate || self.ambiguous.contains(&view) {
                continue;
            }
            let trusted_recently = self.accepted.iter().any(|e| {
                e.item.created_order < view && e.item.view != view && e.travel_m >= certain_since
            });
            if trusted_recently {
                self.ambiguous.insert(view);
                marked.push(view);
            }
        }
        marked
    }

    /// Marks `view` ambiguous for a reason found outside the two trackers (e.g. its own map
    /// fits itself at another place); returns whether it was newly marked.
    pub fn mark(&mut self, view: u64) -> bool {
        self.ambiguous.insert(view)
    }

    /// True once `view` was marked ambiguous.
    pub fn is_ambiguous(&self, view: u64) -> bool {
        self.ambiguous.contains(&view)
    }

    /// Every view marked ambiguous so far.
    pub fn ambiguous_views(&self) -> &BTreeSet<u64> {
        &self.ambiguous
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_tracker_forgets_after_its_window() {
        let mut dt = DistanceTracker::new(3.0);
        dt.push(0.0, 'a');
        dt.push(1.0, 'b');
        dt.push(2.5, 'c');
        assert!(!dt.push(f64::NAN, 'x'));
        assert_eq!(dt.prune(3.0), 0, "exactly at the window stays");
        assert_eq!(dt.prune(4.5), 2);
        let left: Vec<char> = dt.iter().map(|e| e.item).collect();
        assert_eq!(left, vec!['c']);
        assert_eq!(dt.prune(10.0), 1);
        assert!(dt.is_empty());
    }

    fn tracker() -> AmbiguityTracker {
        AmbiguityTracker::new(AmbiguityParams::default()).unwrap()
    }

    #[test]
    fn repeated_rejections_with_a_recent_trusted_acceptance_mark_the_view() {
        let mut t = tracker();
        // View 50 refused at 10 m and 11.5 m; view 7 (older) accepted at 11 m.
        t.on_rejected(50, 10.0);
        assert!(t.update(10.0).is_empty());
        t.on_accepted(7, 7, 11.0);
        t.on_rejected(50, 11.5);
        assert_eq!(t.update(11.5), vec![50]);
        assert!(t.is_ambiguous(50));
        assert!(t.update(12.0).is_empty(), "reported once");
        // Stays ambiguous after everything is forgotten.
        assert!(t.update(100.0).is_empty());
        assert!(t.is_ambiguous(50));
        assert_eq!(
            t.ambiguous_views().iter().copied().collect::<Vec<_>>(),
            vec![50]
        );
        assert!(t.rejected_views().is_empty());
    }

    #[test]
    fn no_recent_trusted_acceptance_no_ambiguity() {
        // Only newer views accepted: the robot may be the one that is lost.
        let mut t = tracker();
        t.on_rejected(50, 10.0);
        t.on_accepted(60, 60, 10.5);
        t.on_accepted(50, 50, 10.8); // the view itself is not trusted for itself
        t.on_rejected(50, 11.5);
        assert!(t.update(11.5).is_empty());
        // An old view accepted too long ago (> 3 m).
        let mut t = tracker();
        t.on_accepted(7, 7, 5.0);
        t.on_rejected(50, 10.0);
        t.on_rejected(50, 11.5);
        assert!(t.update(11.5).is_empty());
        assert!(!t.is_ambiguous(50));
    }

    #[test]
    fn rejections_without_spread_or_outside_the_window_do_not_count() {
        // Two rejections, but the robot moved only 0.5 m since the first.
        let mut t = tracker();
        t.on_accepted(7, 7, 10.0);
        t.on_rejected(50, 10.0);
        t.on_rejected(50, 10.5);
        assert!(t.update(10.5).is_empty());
        // The same view later once more is enough: 3 rejections, first 1.2 m ago.
        t.on_rejected(50, 11.2);
        assert_eq!(t.update(11.2), vec![50]);

        // One rejection fell out of the 10 m window: a single one is left.
        let mut t = tracker();
        t.on_rejected(50, 0.0);
        t.on_accepted(7, 7, 11.0);
        t.on_rejected(50, 11.5);
        assert!(t.update(11.5).is_empty());
        assert_eq!(t.rejected_views()[&50].rejected, 1);
    }

    #[test]
    fn params_refuse_bad_values_and_unknown_fields() {
        let bad = AmbiguityParams {
            certainty_window_m: f64::NAN,
            ..AmbiguityParams::default()
        };
        assert!(AmbiguityTracker::new(bad).is_err());
        let parsed: AmbiguityParams = serde_json::from_str(r#"{"min_rejected": 3}"#).unwrap();
        assert_eq!(parsed.min_rejected, 3);
        assert_eq!(parsed.certainty_window_m, 3.0);
        assert!(serde_json::from_str::<AmbiguityParams>(r#"{"window": 3}"#).is_err());
    }
}

//! Fragments rejoin the site map (issue 66, "a bounded store"): an epoch that place
//! recognition never joined stays an inactive graph beside the site's map, and a lifelong
//! store would keep it until it goes stale. At each session's end, each such fragment is
//! searched for in the site map by the merge search of "Merge what real robot data offers"
//! (its views as queries, the site's views as candidates); when enough verified matches
//! agree on one transform, the fragment is moved into the site's frame and joined to it by
//! those matches as `Merge` edges (Holoch et al., Sec. III-A, between two inactive graphs).
//!
//! A rejoin happens after the epoch's merges became final, so no backup keeps the fragment:
//! it is undone by rolling the store back to the version before the session.

use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_params::{Checker, Real, Validate};
use mapmerge_place::GeometricVerifier;
use mapmerge_posegraph::NodeId;
use serde::{Deserialize, Serialize};

use crate::atlas::{epochs_of, optimize_holding, Atlas};
use crate::backup::BackupStore;
use crate::error::AtlasError;
use crate::events::{pose_array, AtlasEvent};
use crate::ids::{EpochId, MapId};
use crate::merge::{information_from_covariance, LoopEdge};

/// How fragments rejoin the site map ([`Atlas::rejoin_fragments`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RejoinParams {
    /// Views of a fragment searched for in the site map, spread over its views (default: 24;
    /// 0 turns rejoining off).
    pub queries: usize,
    /// Verified matches that must agree on the fragment's transform (default: 2, as the
    /// engine's merges need two agreeing observations).
    pub min_agreeing: usize,
    /// Matches agree when their transforms differ by at most this (m) ...
    pub agree_m: f64,
    /// ... and this (rad) (default: 0.5 m and 5°, the overlap gate of a merge).
    pub agree_rad: f64,
}

impl Default for RejoinParams {
    fn default() -> Self {
        Self {
            queries: 24,
            min_agreeing: 2,
            agree_m: 0.5,
            agree_rad: 5f64.to_radians(),
        }
    }
}

/// What one rejoin did.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RejoinEvent {
    /// The fragment, and the site map it joined (which keeps its id).
    pub map: MapId,
    pub into: MapId,
    /// The fragment's epochs and vertices.
    pub epochs: Vec<EpochId>,
    pub vertices: usize,
    /// The agreeing matches, as edges `(site view, fragment view, site_view_from_fragment_view)`.
    pub loops: Vec<(NodeId, NodeId, [f64; 3])>,
    /// The fragment's frame in the site map's, `[x_m, y_m, yaw_rad]`.
    pub site_from_fragment: [f64; 3],
    /// Best verification score among the agreeing matches.
    pub score: f64,
}

/// One verified match of a fragment view in the site map.
struct FragmentMatch {
    edge: LoopEdge,
    /// The fragment view's pose in the fragment.
    fragment_from_view: Se2,
    site_from_fragment: Se2,
    score: f64,
}

impl<B: BackupStore> Atlas<B> {
    /// Searches every inactive graph other than the site map (the largest) for in the site
    /// map, and joins each that `params.min_agreeing` verified matches agree on (see the
    /// module documentation). Returns the rejoin events. Refused while a merge into the
    /// active graph can be undone; on an error the atlas is unchanged for the fragment at hand.
    pub fn rejoin_fragments(
        &mut self,
        params: &RejoinParams,
        verifier: &dyn GeometricVerifier,
    ) -> Result<Vec<AtlasEvent>, AtlasError> {
        if self.is_undoable() {
            return Err(AtlasError::Config(
                "fragments rejoin once no merge can be undone (end the epoch first)".into(),
            ));
        }
        let mut events = Vec::new();
        if params.queries == 0 {
            return Ok(events);
        }
        let Some(site) = self.site_map() else {
            return Ok(events);
        };
        let fragments: Vec<MapId> = self
            .inactive
            .keys()
            .copied()
            .filter(|m| *m != site)
            .collect();
        for fragment in fragments {
            let matches = self.fragment_matches(site, fragment, params, verifier);
            let Some(agreeing) = agreeing_matches(matches, params) else {
                continue;
            };
            events.push(self.join_fragment(site, fragment, agreeing)?);
        }
        self.events.extend(events.iter().cloned());
        Ok(events)
    }

    /// The site map: the inactive graph with the most vertices (the lowest id among equals).
    pub fn site_map(&self) -> Option<MapId> {
        self.inactive
            .iter()
            .max_by_key(|(m, g)| (g.num_vertices(), std::cmp::Reverse(**m)))
            .map(|(m, _)| *m)
    }

    /// Up to `params.queries` of `fragment`'s views, evenly spread, each recognised in `site`.
    fn fragment_matches(
        &self,
        site: MapId,
        fragment: MapId,
        params: &RejoinParams,
        verifier: &dyn GeometricVerifier,
    ) -> Vec<FragmentMatch> {
        let (Some(site_graph), Some(graph)) =
            (self.inactive.get(&site), self.inactive.get(&fragment))
        else {
            return Vec::new();
        };
        let views: Vec<NodeId> = graph
            .vertices()
            .map(|(n, _)| n)
            .filter(|n| self.keyframes.get(*n).is_some())
            .collect();
        let step = views.len().div_ceil(params.queries).max(1);
        views
            .iter()
            .step_by(step)
            .filter_map(|node| {
                let query = self.query_in(graph, *node, true)?;
                let found = self.recognise(&query, site_graph, |_| true, verifier, None)?;
                let b = NodeId(found.b.0);
                let site_from_view = site_graph.vertex(b)?.pose;
                let site_from_fragment = site_from_view
                    .compose(&found.b_from_a)
                    .compose(&query.pose.inverse());
                Some(FragmentMatch {
                    edge: LoopEdge {
                        active: *node,
                        inactive: b,
                        inactive_from_active: found.b_from_a,
                        information: information_from_covariance(
                            &found.covariance,
                            self.params.merge.loop_min_sigma,
                        ),
                    },
                    fragment_from_view: query.pose,
                    site_from_fragment,
                    score: found.score,
                })
            })
            .collect()
    }

    /// Moves `fragment` into `site`'s frame, joins it by the matches' edges and re-optimises
    /// the site map.
    fn join_fragment(
        &mut self,
        site: MapId,
        fragment: MapId,
        agreeing: Vec<FragmentMatch>,
    ) -> Result<AtlasEvent, AtlasError> {
        let (Some(site_graph), Some(graph)) =
            (self.inactive.get(&site), self.inactive.get(&fragment))
        else {
            return Err(AtlasError::MissingMap(fragment));
        };
        let Some(best) = agreeing.iter().max_by(|a, b| a.score.total_cmp(&b.score)) else {
            return Err(AtlasError::BadMerge {
                map: fragment,
                reason: "no match to join by".into(),
            });
        };
        let site_from_fragment = best.site_from_fragment;
        let mut moved = graph.clone();
        moved.reanchor(&site_from_fragment);
        for (_, v) in moved.vertices_mut() {
            v.fixed = false;
        }
        let edges: Vec<_> = agreeing.iter().map(|m| m.edge.edge()).collect();
        let mut joined = site_graph.clone();
        joined.union(&moved, &edges)?;
        optimize_holding(&mut joined, None, &self.params.optimizer)?;
        let event = AtlasEvent::Rejoined(RejoinEvent {
            map: fragment,
            into: site,
            epochs: epochs_of(graph).into_iter().collect(),
            vertices: graph.num_vertices(),
            loops: agreeing
                .iter()
                .map(|m| {
                    (
                        m.edge.inactive,
                        m.edge.active,
                        pose_array(&m.edge.inactive_from_active),
                    )
                })
                .collect(),
            site_from_fragment: pose_array(&site_from_fragment),
            score: best.score,
        });
        self.inactive.remove(&fragment);
        self.inactive.insert(site, joined);
        Ok(event)
    }
}

/// The largest set of matches whose transforms agree with one of them where they matched
/// (each match's view placed by both), when it has at least `params.min_agreeing`.
fn agreeing_matches(
    matches: Vec<FragmentMatch>,
    params: &RejoinParams,
) -> Option<Vec<FragmentMatch>> {
    let agree = |seed: &Se2, m: &FragmentMatch| {
        let d = seed
            .compose(&m.fragment_from_view)
            .between(&m.site_from_fragment.compose(&m.fragment_from_view));
        d.translation().norm() <= params.agree_m
            && wrap_angle_rad(d.theta_rad).abs() <= params.agree_rad
    };
    let best = (0..matches.len()).max_by_key(|i| {
        let seed = &matches[*i].site_from_fragment;
        matches.iter().filter(|m| agree(seed, m)).count()
    })?;
    let seed = matches[best].site_from_fragment;
    let agreeing: Vec<FragmentMatch> = matches.into_iter().filter(|m| agree(&seed, m)).collect();
    (agreeing.len() >= params.min_agreeing.max(1)).then_some(agreeing)
}

impl Validate for RejoinParams {
    fn check(&self, check: &mut Checker) {
        check
            .size("queries", self.queries, 0, 10_000)
            .size("min_agreeing", self.min_agreeing, 1, 10_000)
            .real("agree_m", self.agree_m, Real::non_negative())
            .real(
                "agree_rad",
                self.agree_rad,
                Real::within(0.0, std::f64::consts::PI),
            );
    }
}

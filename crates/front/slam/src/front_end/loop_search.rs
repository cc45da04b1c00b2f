//! Loop search from a new keyframe: nearby finished submaps, then place recognition; large
//! corrections wait for confirmation. A child module of `front_end`, so it sees the
//! front-end's state.

use std::time::Instant;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_place::{verify_candidates, Keyframe, KeyframeId, PlaceCandidate, ScanContext};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId};
use mapmerge_scan::Point2;

use super::{edge_information, FrontEnd, LoopRecord, LoopSource};
use crate::loop_closing::SubmapVerifier;

impl FrontEnd {
    /// Searches loops from keyframe `node`; returns how many loop edges were added.
    pub(super) fn close_loops(&mut self, node: NodeId) -> usize {
        let Some(map_from_robot) = self.graph.vertex(node).map(|v| v.pose) else {
            return 0;
        };
        let Some(points) = self.keyframes.get(&node).map(|k| k.points_in_robot.clone()) else {
            return 0;
        };
        let loops_params = self.params.loops.clone();
        // Nearby finished submaps, nearest first.
        let mut nearby: Vec<(f64, usize)> = self
            .submaps
            .iter()
            .enumerate()
            .filter(|(_, submap)| submap.finished)
            .filter_map(|(s, submap)| {
                let distance = submap
                    .keyframes
                    .iter()
                    .filter_map(|(member, _)| self.graph.vertex(*member))
                    .map(|v| (v.pose.translation() - map_from_robot.translation()).norm())
                    .fold(f64::INFINITY, f64::min);
                (distance <= loops_params.max_distance_m).then_some((distance, s))
            })
            .collect();
        nearby.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut added = 0;
        let started = Instant::now();
        for &(_, s) in nearby.iter().take(loops_params.max_submaps_per_keyframe) {
            let Some(submap) = self.submaps.get(s) else {
                continue;
            };
            let Some(map_from_submap) = self.graph.vertex(submap.anchor).map(|v| v.pose) else {
                continue;
            };
            // Uncertainty: travel since the submap ended or since the last long loop.
            let distance = submap
                .keyframes
                .last()
                .map_or(0.0, |(member, _)| self.drift_since(*member));
            let Some(window) = loops_params.local_window(distance) else {
                continue;
            };
            let guess = map_from_submap.between(&map_from_robot);
            self.info.local_searches += 1;
            // Right after a long loop the estimate is good: ICP from it, trusted as the
            // odometry trusts it, spares the search.
            let refined = self
                .matcher
                .refine(submap.target(), &points, &guess)
                .filter(|m| {
                    distance <= loops_params.refine_below_drift_m
                        && self.params.refine_first.accepts(m, &guess)
                });
            let Some(found) = refined.or_else(|| {
                self.matcher
                    .match_scan(submap.target(), &points, &guess, &window)
            }) else {
                continue;
            };
            // ICP's covariance shows a corridor's ambiguity; the correlative one cannot.
            if found.score < loops_params.min_score || found.icp.is_none() {
                continue;
            }
            let Some((member, member_from_robot)) =
                submap.relative_to_nearest(&found.target_from_query)
            else {
                continue;
            };
            let record = LoopRecord {
                from: member,
                to: node,
                measurement: member_from_robot,
                source: LoopSource::Local,
                score: found.score,
                covariance: found.covariance,
            };
            added += self.propose_loop(record);
        }
        self.info.seconds.local_loops += started.elapsed().as_secs_f64();
        if added > 0 {
            return added;
        }
        // Place recognition after a long stretch without loops.
        if self.travel_m - self.travel_at_last_loop_m < loops_params.place_after_m
            || self.place_keyframes.is_empty()
        {
            return 0;
        }
        let started = Instant::now();
        let found = self.recognise_place(node, points, map_from_robot);
        self.info.seconds.place += started.elapsed().as_secs_f64();
        found
    }

    /// Place recognition for keyframe `node` (points, current estimate): a gated loop edge
    /// or nothing; returns how many loop edges were added.
    fn recognise_place(&mut self, node: NodeId, points: Vec<Point2>, map_from_robot: Se2) -> usize {
        let loops_params = self.params.loops.clone();
        self.info.place_queries += 1;
        let descriptor = ScanContext::new(&points, &loops_params.place.descriptor);
        let retrieved = self
            .place_index
            .query(&descriptor, loops_params.place.candidates_per_query);
        // Candidates the gate would refuse anyway are not verified: the query must lie within
        // the verifier's window of the candidate, and the candidate within the gate.
        let (gate_m, gate_per_m, gate_rad, gate_rad_per_m) = loops_params.place_gate;
        let candidates: Vec<PlaceCandidate> = retrieved
            .iter()
            .filter(|c| c.descriptor_distance <= loops_params.place.max_descriptor_distance)
            .filter_map(|c| {
                let ordinal = *self.place_ordinal.get(&c.keyframe)?;
                let (keyframe, _) = self.place_keyframes.get(ordinal)?;
                let map_from_keyframe = self.graph.vertex(NodeId(c.keyframe.0))?.pose;
                let distance_m =
                    (map_from_keyframe.translation() - map_from_robot.translation()).norm();
                let drift_m = self.drift_since(NodeId(c.keyframe.0));
                let reach_m = gate_m + gate_per_m * drift_m + loops_params.place_window.linear_m;
                (distance_m <= reach_m).then_some(PlaceCandidate {
                    ordinal,
                    keyframe,
                    yaw_rad: c.yaw_rad,
                    map_from_keyframe: Some(map_from_keyframe),
                })
            })
            .collect();
        if candidates.is_empty() {
            return 0;
        }
        let locate = |id: KeyframeId| {
            let ordinal = *self.place_ordinal.get(&id)?;
            let (_, s) = self.place_keyframes.get(ordinal)?;
            let pose = self.submaps.get(*s)?.submap_from_keyframe(NodeId(id.0))?;
            Some((*s, pose))
        };
        let verifier = SubmapVerifier {
            matcher: &self.matcher,
            submaps: &self.submaps,
            locate: &locate,
            window: loops_params.place_window,
        };
        let query = Keyframe::new(node.0, points);
        let Some(found) = verify_candidates(&query, &candidates, &verifier, &loops_params.place)
        else {
            return 0;
        };
        if found.confidence < loops_params.place_min_confidence {
            return 0;
        }
        let Some((s, submap_from_candidate)) = locate(found.b) else {
            return 0;
        };
        let Some(map_from_submap) = self
            .submaps
            .get(s)
            .and_then(|submap| Some(self.graph.vertex(submap.anchor)?.pose))
        else {
            return 0;
        };
        // Gate by the estimate's uncertainty: the loop may move the keyframe only as far as
        // the drift since the last loop can explain.
        let measurement = submap_from_candidate.compose(&found.b_from_a);
        let correction = map_from_robot.between(&map_from_submap.compose(&measurement));
        let drift_m = self.drift_since(NodeId(found.b.0));
        if correction.translation().norm() > gate_m + gate_per_m * drift_m
            || correction.theta_rad.abs() > gate_rad + gate_rad_per_m * drift_m
        {
            self.info.place_gated += 1;
            return 0;
        }
        let Some((member, member_from_robot)) = self
            .submaps
            .get(s)
            .and_then(|submap| submap.relative_to_nearest(&measurement))
        else {
            return 0;
        };
        let record = LoopRecord {
            from: member,
            to: node,
            measurement: member_from_robot,
            source: LoopSource::Place,
            score: found.score,
            covariance: found.covariance,
        };
        self.propose_loop(record)
    }

    /// Travel (m) up to keyframe `node`.
    fn travel_at(&self, node: NodeId) -> f64 {
        self.keyframes
            .get(&node)
            .map_or(self.travel_m, |k| k.travel_m)
    }

    /// How far the robot may have drifted from where it was at keyframe `node`: the path
    /// since then, or since the last loop that spanned a long path, whichever is shorter.
    fn drift_since(&self, node: NodeId) -> f64 {
        (self.travel_m - self.travel_at(node))
            .min(self.travel_m - self.travel_at_last_loop_m)
            .max(0.0)
    }

    /// Proposes a loop edge. One that moves the keyframe's estimate by little is added at
    /// once; a large correction must be confirmed by another loop from a different submap
    /// or a later keyframe that implies the same correction (temporal consistency, as
    /// look-alike places rarely agree twice), until then it waits. Returns the loop edges
    /// added.
    fn propose_loop(&mut self, record: LoopRecord) -> usize {
        let (Some(map_from_member), Some(map_from_robot)) = (
            self.graph.vertex(record.from).map(|v| v.pose),
            self.graph.vertex(record.to).map(|v| v.pose),
        ) else {
            return 0;
        };
        let implied = map_from_member.compose(&record.measurement);
        let params = &self.params.loops;
        let (small_m, small_rad) = params.confirm_above;
        let correction = map_from_robot.between(&implied);
        if correction.translation().norm() <= small_m && correction.theta_rad.abs() <= small_rad {
            self.add_loop(record);
            return 1;
        }
        // The map-frame correction this loop asks for, applied to the other's estimate.
        let map_correction = implied.compose(&map_from_robot.inverse());
        let oldest = record
            .to
            .0
            .saturating_sub(params.confirm_within_keyframes as u64);
        self.pending_loops
            .retain(|(pending, _)| pending.to.0 >= oldest);
        let (agree_m, agree_rad) = params.confirm_agreement;
        let submap_of = |node: NodeId| self.keyframe_submap.get(&node).copied();
        let agreeing: Vec<usize> = self
            .pending_loops
            .iter()
            .enumerate()
            .filter(|(_, (pending, pending_implied))| {
                let distinct =
                    pending.to != record.to || submap_of(pending.from) != submap_of(record.from);
                let Some(estimate) = self.graph.vertex(pending.to).map(|v| v.pose) else {
                    return false;
                };
                let difference = map_correction.compose(&estimate).between(pending_implied);
                distinct
                    && difference.translation().norm() <= agree_m
                    && difference.theta_rad.abs() <= agree_rad
            })
            .map(|(index, _)| index)
            .collect();
        if agreeing.is_empty() {
            self.pending_loops.push((record, implied));
            return 0;
        }
        let mut added = 0;
        for index in agreeing.into_iter().rev() {
            let (pending, _) = self.pending_loops.remove(index);
            self.add_loop(pending);
            added += 1;
        }
        self.add_loop(record);
        added + 1
    }

    fn add_loop(&mut self, record: LoopRecord) {
        // A loop across a long path bounds the drift from then on; short ones (to the
        // submap just finished) say little about it.
        if self.travel_m - self.travel_at(record.from) >= self.params.loops.long_loop_span_m {
            self.travel_at_last_loop_m = self.travel_m;
        }
        match record.source {
            LoopSource::Local => self.info.local_loops += 1,
            LoopSource::Place => self.info.place_loops += 1,
        }
        let information = edge_information(&record.covariance, self.params.loops.min_edge_sigma);
        let _ = self.graph.add_edge(Edge {
            from: record.from,
            to: record.to,
            measurement: record.measurement,
            information,
            kind: EdgeKind::Loop,
        });
        self.loops.push(record);
        self.loops_since_optimization += 1;
    }
}

//! Association of two prepared segments (AutoMerge Sec. V): difference matrix → sequence
//! matches + single-frame matches → zones + RANSAC (Eq. 7) → geometric verification of the
//! surviving matches by the scan matcher → one consistent placement of B in A → loop edges and
//! the pair's confidence ω (Eq. 9).
//!
//! A pair is always associated in the order of its names (`a < b`), so the result depends on
//! the two segments only, never on which arrived first: that is what makes assembly order
//! invariant.

use mapmerge_association::{
    confidence, difference_matrix, sequence_matches, single_frame_matches, verify_zones,
    DescriptorMatrix, DifferenceMatrix, SequenceParams, SingleFrameParams, SubmapMatch, ZoneParams,
};
use mapmerge_geometry::{planar_information_from_covariance, wrap_angle_rad, LieGroup, Se2};
use mapmerge_params::{Checker, ParamError, Real, Validate};
use mapmerge_place::{GeometricVerifier, Keyframe, ScanMatchVerifier};
use mapmerge_scan::Point2;
use nalgebra::Matrix3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::descriptor::SubmapDescriptor;
use crate::error::AssembleError;
use crate::submap::Submap2;

/// Parameters of the geometric verification and of the pair's acceptance.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VerificationParams {
    /// Search window of the scan matcher around the descriptor's yaw: translation (m)
    /// (default: 3; submap centres of the same place are up to a spacing plus the
    /// descriptor's translation tolerance apart).
    pub window_m: f64,
    /// … and rotation (deg) (default: 180, the whole circle: where a place was passed in
    /// opposite directions the submaps see different sides of it and the descriptor's yaw is
    /// unreliable; branch-and-bound keeps the whole circle affordable).
    pub window_deg: f64,
    /// A match is verified from this evidence score (`mapmerge_place::Evidence::score`:
    /// inliers minus free-space violations, scaled by the structure in the weakest
    /// direction) (default: 0.25). Two submaps of one place seen from different sides share
    /// about half their points, and corridors are weakly constrained, so the score is lower
    /// than a keyframe against its own submap; precision comes from the agreement of several
    /// edges and from the group graph's residuals. Applies to submaps without free space (3D
    /// segments, or `SubmapParams::free_space_m = 0`).
    pub min_score: f64,
    /// The same for two submaps that carry their free space: the score is then their
    /// whole-map agreement (`mapmerge_place::Evidence::agreement`), on its own scale, here at
    /// the lower end of its Wilson interval (`evidence.agreement_z` 3) (default: 0.94; chosen
    /// on the tuning logs, per log and pooled (the 7 logs' segments in one assembly): 0.94
    /// found 63 of 95 pairs, all true, and no edge between logs; 0.93 62 pairs; 0.92 and
    /// 0.9 joined logs in the pool (3 edges), 0.8 gave false pairs per log. With the plain
    /// agreement 0.965 was needed and found 62 pairs: pooled, freiburg-079 and
    /// infinite-corridor met at 0.955–0.960).
    pub min_whole_map_score: f64,
    /// At most this many matches are verified per pair, spread evenly over the zone inliers
    /// (default: 24; each costs a match target, ~10–30 ms).
    pub max_verifications: usize,
    /// … and this many of them first, spread evenly: when none of them verifies the pair is
    /// given up without verifying the rest; 0 verifies all at once (default: 6; chosen on
    /// the tuning logs, where 6 and 8 found the same pairs and edges as 0 and 3–4 lost
    /// some; in the pooled run of 13 logs, where most pairs share no place, association
    /// took 101 s instead of 108 s).
    pub first_round: usize,
    /// A pair is associated only with at least this many verified edges that agree on the
    /// placement of B in A (default: 2): one edge alone may be a look-alike.
    pub min_loops: usize,
    /// Verified edges agree when the placements of B in A they imply differ by at most this
    /// (m) … (default: 1: the segments' own drift between the edges, less than the slide of
    /// a corridor match)
    pub consistency_m: f64,
    /// … and this (deg) (default: 5).
    pub consistency_deg: f64,
    /// … and span at least this much travel in the first segment (m) (default: 2): edges
    /// between the same two places are one piece of evidence, and one place can be a
    /// look-alike (a symmetric room verifies turned by 180°).
    pub min_span_m: f64,
    /// The overlap the placement predicts (`predicted_overlap`): B's submaps that land within
    /// this of one of A's (m) (default: 1.5) …
    pub predicted_radius_m: f64,
    /// … look alike when their difference is among this fraction of the smallest in A's row
    /// (default: 0.25) …
    pub predicted_rank_fraction: f64,
    /// … and at least this fraction of them must (default: 0.5; places paired at random
    /// agree at about `predicted_rank_fraction`).
    pub min_predicted_agreement: f64,
    /// Standard deviations floored into every loop edge's covariance (m, deg) (default: 0.05,
    /// 1).
    pub loop_min_sigma: (f64, f64),
    /// The scan matcher's search and ICP see the query submap thinned to one point per cell
    /// of this size (m); the evidence sees every point (default: 0.4; chosen on the tuning
    /// logs, where the matcher's own 0.05, 0.2 and 0.4 found the same 62 of 95 pairs (571,
    /// 571 and 566 edges, all true) with 18.8, 11.2 and 7.5 s of association, and 0.3, 0.35
    /// and 0.5 lost one infinite-corridor pair each; a submap has several times a scan's
    /// points, so it is thinned more than the atlas's keyframes,
    /// `mapmerge_place::PlaceVerifierParams`).
    pub search_voxel_m: f64,
    /// How a verification is scored (`mapmerge_place::EvidenceParams`; default: its
    /// defaults with the whole-map agreement at the lower end of its Wilson interval over
    /// the overlap's points, `agreement_z` 3, as the place benchmark's configuration; see
    /// `min_whole_map_score`).
    pub evidence: mapmerge_place::EvidenceParams,
}

impl Default for VerificationParams {
    fn default() -> Self {
        Self {
            window_m: 3.0,
            window_deg: 180.0,
            min_score: 0.25,
            min_whole_map_score: 0.94,
            max_verifications: 24,
            first_round: 6,
            min_loops: 2,
            consistency_m: 1.0,
            consistency_deg: 5.0,
            min_span_m: 2.0,
            predicted_radius_m: 1.5,
            predicted_rank_fraction: 0.25,
            min_predicted_agreement: 0.5,
            loop_min_sigma: (0.05, 1.0),
            search_voxel_m: 0.4,
            evidence: mapmerge_place::EvidenceParams {
                agreement_z: 3.0,
                ..mapmerge_place::EvidenceParams::default()
            },
        }
    }
}

impl Validate for VerificationParams {
    fn check(&self, check: &mut Checker) {
        let degrees = Real::within(0.0, 180.0);
        check
            .real("window_m", self.window_m, Real::within(0.0, 100.0))
            .real("window_deg", self.window_deg, degrees)
            .real("min_score", self.min_score, Real::fraction())
            .real(
                "min_whole_map_score",
                self.min_whole_map_score,
                Real::fraction(),
            )
            .size("max_verifications", self.max_verifications, 1, 10_000)
            .size("first_round", self.first_round, 0, 10_000)
            .size("min_loops", self.min_loops, 1, 10_000)
            .real("consistency_m", self.consistency_m, Real::non_negative())
            .real("consistency_deg", self.consistency_deg, degrees)
            .real("min_span_m", self.min_span_m, Real::non_negative())
            .real(
                "predicted_radius_m",
                self.predicted_radius_m,
                Real::non_negative(),
            )
            .real(
                "predicted_rank_fraction",
                self.predicted_rank_fraction,
                Real::fraction(),
            )
            .real(
                "min_predicted_agreement",
                self.min_predicted_agreement,
                Real::fraction(),
            )
            .reals(
                "loop_min_sigma",
                &[
                    (self.loop_min_sigma.0, Real::within(1e-6, 1000.0)),
                    (self.loop_min_sigma.1, Real::within(1e-6, 180.0)),
                ],
            )
            // The matcher's `correlative.query_voxel_m`.
            .real(
                "search_voxel_m",
                self.search_voxel_m,
                Real::within(0.0, 10.0),
            )
            .nested("evidence", &self.evidence);
    }
}

/// Parameters of one pair's association.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AssociationParams {
    /// Sequence matching (SeqSLAM) over the difference matrix.
    pub sequence: SequenceParams,
    /// Single-frame matches for short overlaps.
    pub single_frame: SingleFrameParams,
    /// k-means zones + RANSAC with Eq. 7.
    pub zones: ZoneParams,
    /// Scan-matcher verification and acceptance.
    pub verification: VerificationParams,
    /// `C_ω` of Eq. 9 (m²) (default: 4): an overlap of L metres gives ω ≈ exp(−C_ω / 2L²) when
    /// the features agree, so a 2 m overlap weighs 0.6 and a 10 m one 0.98.
    pub c_omega: f64,
}

impl Default for AssociationParams {
    fn default() -> Self {
        Self {
            sequence: SequenceParams::default(),
            single_frame: SingleFrameParams::default(),
            zones: ZoneParams::default(),
            verification: VerificationParams::default(),
            c_omega: 4.0,
        }
    }
}

impl Validate for AssociationParams {
    fn check(&self, check: &mut Checker) {
        check
            .nested("sequence", &self.sequence)
            .nested("single_frame", &self.single_frame)
            .nested("zones", &self.zones)
            .nested("verification", &self.verification)
            .real("c_omega", self.c_omega, Real::non_negative());
    }
}

/// A segment ready for association: its submaps and their descriptors.
#[derive(Clone, Debug)]
pub struct PreparedSegment {
    /// The segment's name (the file stem).
    pub name: String,
    /// Submaps in travel order.
    pub submaps: Vec<Submap2>,
    /// One unit descriptor row per submap.
    pub descriptors: DescriptorMatrix,
}

impl PreparedSegment {
    /// Submap centre positions in the segment frame, `z = 0` (the association's input).
    pub fn centre_positions(&self) -> Vec<[f64; 3]> {
        self.submaps
            .iter()
            .map(|s| {
                let t = s.segment_from_centre.translation();
                [t.x, t.y, 0.0]
            })
            .collect()
    }
}

/// A verified inter-segment loop edge between two submap centres.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SegmentLoop {
    /// The `from` segment (the pair's first name) and its submap.
    pub from_segment: String,
    pub from_submap: usize,
    /// The `from` submap's centre scan (the segment's laser scans counted from 0).
    pub from_scan: usize,
    /// The `to` segment and its submap.
    pub to_segment: String,
    pub to_submap: usize,
    pub to_scan: usize,
    /// `from_robot_from_to_robot`: the `to` scan's robot pose in the `from` scan's robot frame.
    pub from_from_to: Se2,
    /// Verification score (evidence, `[0, 1]`).
    pub score: f64,
    /// Information of the edge in the tangent order `(vx, vy, ω)`.
    pub information: Matrix3<f64>,
}

/// What the association of one pair found, with the counts of every stage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairAssociation {
    /// The pair, `a < b`.
    pub a: String,
    pub b: String,
    /// Matches from sequence matching and from single-frame matching (after de-duplication).
    pub sequence_matches: usize,
    pub single_frame_matches: usize,
    /// Matches that survived zones + RANSAC.
    pub zone_inliers: usize,
    /// Matches given to the scan matcher, and those it verified.
    pub verifications: usize,
    pub verified: usize,
    /// The accepted loop edges (empty when the pair is not associated).
    pub loops: Vec<SegmentLoop>,
    /// `a_from_b`: B's segment frame in A's, from the accepted edges (the best one's).
    pub a_from_b: Option<Se2>,
    /// `L_ij`: travel in A spanned by the accepted edges plus one submap spacing (m).
    pub overlap_length_m: f64,
    /// `‖F_i − F_j‖²`: mean squared descriptor difference of the accepted edges' submaps.
    pub feature_distance_sq: f64,
    /// ω of Eq. 9 (0 when not associated).
    pub weight: f64,
    /// Submap pairs the placement puts side by side, and how many of them look alike.
    pub predicted_overlap: usize,
    pub predicted_agreement: usize,
}

/// The scan-matcher verifier of the pair stage.
pub fn pair_verifier(params: &VerificationParams) -> Result<ScanMatchVerifier, AssembleError> {
    let window =
        mapmerge_scanmatch::SearchWindow::new(params.window_m, params.window_deg.to_radians());
    let mut matcher = mapmerge_scanmatch::ScanMatchParams::default();
    matcher.correlative.query_voxel_m = params.search_voxel_m;
    let verifier = ScanMatchVerifier::new(matcher, window).map_err(|e| {
        AssembleError::InvalidParams(ParamError {
            field: "verification".into(),
            value: format!(
                "window {} m, {}°, search voxel {} m",
                params.window_m, params.window_deg, params.search_voxel_m
            ),
            allowed: format!("refused by the scan matcher: {e}"),
        })
    })?;
    Ok(verifier.with_evidence(params.evidence))
}

/// Associates `a` with `b` (call with `a.name < b.name` for order invariance).
pub fn associate_pair<D: SubmapDescriptor<Point = Point2>>(
    a: &PreparedSegment,
    b: &PreparedSegment,
    descriptor: &D,
    verifier: &ScanMatchVerifier,
    params: &AssociationParams,
    spacing_m: f64,
) -> Result<PairAssociation, AssembleError> {
    let association = |e: &dyn std::fmt::Display| AssembleError::Association {
        pair: format!("{} × {}", a.name, b.name),
        reason: e.to_string(),
    };
    let mut result = PairAssociation {
        a: a.name.clone(),
        b: b.name.clone(),
        sequence_matches: 0,
        single_frame_matches: 0,
        zone_inliers: 0,
        verifications: 0,
        verified: 0,
        loops: Vec::new(),
        a_from_b: None,
        overlap_length_m: 0.0,
        feature_distance_sq: 0.0,
        weight: 0.0,
        predicted_overlap: 0,
        predicted_agreement: 0,
    };
    if a.submaps.is_empty() || b.submaps.is_empty() {
        return Ok(result);
    }
    // Sec. V-A: the difference matrix, sequence matches for long overlaps and single-frame
    // matches for short ones.
    let d = difference_matrix(&a.descriptors, &b.descriptors).map_err(|e| association(&e))?;
    let mut matches = sequence_matches(&d, &params.sequence).map_err(|e| association(&e))?;
    result.sequence_matches = matches.len();
    let singles = single_frame_matches(&d, &params.single_frame).map_err(|e| association(&e))?;
    let before = matches.len();
    for m in singles {
        if !matches
            .iter()
            .any(|s| s.query == m.query && s.reference == m.reference)
        {
            matches.push(m);
        }
    }
    result.single_frame_matches = matches.len() - before;
    if matches.is_empty() {
        return Ok(result);
    }
    // k-means zones + RANSAC with the edge-length test (Eq. 7).
    let zones = verify_zones(
        &matches,
        &a.centre_positions(),
        &b.centre_positions(),
        &params.zones,
    )
    .map_err(|e| association(&e))?;
    result.zone_inliers = zones.inliers.len();
    let tried = spread(&zones.inliers, params.verification.max_verifications);
    // Geometric verification: B's submap (query) against A's (candidate) from the
    // descriptor's yaw.
    let verify = |m: &SubmapMatch| -> Option<(SubmapMatch, mapmerge_place::Verification)> {
        let sa = a.submaps.get(m.query)?;
        let sb = b.submaps.get(m.reference)?;
        let yaw = descriptor
            .relative_yaw(&sb.points_in_centre, &sa.points_in_centre)
            .map_or(0.0, |y| y.yaw_rad);
        let mut query = Keyframe::new(sb.index as u64, sb.points_in_centre.clone());
        query.free_space = sb.free_space.clone();
        let mut candidate = Keyframe::new(sa.index as u64, sa.points_in_centre.clone());
        candidate.free_space = sa.free_space.clone();
        let min_score = if query.free_space.is_some() && candidate.free_space.is_some() {
            params.verification.min_whole_map_score
        } else {
            params.verification.min_score
        };
        let found = verifier.verify(&query, &candidate, &Se2::new(0.0, 0.0, yaw))?;
        (found.score >= min_score && found.candidate_from_query.is_finite()).then_some((*m, found))
    };
    // A first round, spread over the tried matches; a pair none of whose first round
    // verifies is given up (most pairs of a large pool share no place).
    let first_round = spread_indices(tried.len(), params.verification.first_round);
    let verify_at = |&k: &usize| (k, tried.get(k).and_then(verify));
    let mut outcomes: Vec<(usize, Option<(SubmapMatch, mapmerge_place::Verification)>)> =
        first_round.par_iter().map(verify_at).collect();
    if outcomes.iter().any(|(_, v)| v.is_some()) || first_round.is_empty() {
        let rest: Vec<usize> = (0..tried.len())
            .filter(|k| !first_round.contains(k))
            .collect();
        outcomes.par_extend(rest.par_iter().map(verify_at));
    }
    result.verifications = outcomes.len();
    // In the order of `tried`, as if verified in one pass.
    outcomes.sort_by_key(|(k, _)| *k);
    let verified: Vec<(SubmapMatch, mapmerge_place::Verification)> =
        outcomes.into_iter().filter_map(|(_, v)| v).collect();
    result.verified = verified.len();
    // One placement of B in A that most verified edges agree with (a look-alike verifies
    // somewhere else).
    let placements: Vec<Se2> = verified
        .iter()
        .map(|(m, v)| {
            a.submaps[m.query]
                .segment_from_centre
                .compose(&v.candidate_from_query)
                .compose(&b.submaps[m.reference].segment_from_centre.inverse())
        })
        .collect();
    let tolerance = (
        params.verification.consistency_m,
        params.verification.consistency_deg.to_radians(),
    );
    let Some(best) = (0..placements.len()).max_by(|&i, &j| {
        let support = |k: usize| {
            let agreeing: Vec<usize> = (0..placements.len())
                .filter(|&o| agree(&placements[k], &placements[o], tolerance))
                .collect();
            let score: f64 = agreeing.iter().map(|&o| verified[o].1.score).sum();
            (agreeing.len(), score)
        };
        let (ni, si) = support(i);
        let (nj, sj) = support(j);
        ni.cmp(&nj).then(si.total_cmp(&sj)).then(j.cmp(&i))
    }) else {
        return Ok(result);
    };
    let agreeing: Vec<usize> = (0..placements.len())
        .filter(|&o| agree(&placements[best], &placements[o], tolerance))
        .collect();
    if agreeing.len() < params.verification.min_loops.max(1) {
        return Ok(result);
    }
    let (lo, hi) = agreeing.iter().fold((f64::MAX, f64::MIN), |(lo, hi), &k| {
        let t = a.submaps[verified[k].0.query].travel_m;
        (lo.min(t), hi.max(t))
    });
    if hi - lo < params.verification.min_span_m {
        return Ok(result);
    }
    let (predicted, agreeing_places) =
        predicted_overlap(a, b, &d, &placements[best], &params.verification);
    result.predicted_overlap = predicted;
    result.predicted_agreement = agreeing_places;
    if predicted > 0
        && (agreeing_places as f64) < params.verification.min_predicted_agreement * predicted as f64
    {
        return Ok(result);
    }
    let sigma = params.verification.loop_min_sigma;
    for &k in &agreeing {
        let (m, v) = &verified[k];
        let (sa, sb) = (&a.submaps[m.query], &b.submaps[m.reference]);
        result.loops.push(SegmentLoop {
            from_segment: a.name.clone(),
            from_submap: sa.index,
            from_scan: sa.centre_scan,
            to_segment: b.name.clone(),
            to_submap: sb.index,
            to_scan: sb.centre_scan,
            from_from_to: v.candidate_from_query,
            score: v.score,
            information: planar_information_from_covariance(
                &v.covariance,
                (sigma.0, sigma.1.to_radians()),
            ),
        });
    }
    result.loops.sort_by_key(|l| (l.from_submap, l.to_submap));
    result.a_from_b = Some(placements[best]);
    // Eq. 9: overlap length and feature distance of the accepted edges.
    result.overlap_length_m = (hi - lo).max(0.0) + spacing_m;
    result.feature_distance_sq = result
        .loops
        .iter()
        .map(|l| {
            let (fa, fb) = (
                a.descriptors.row(l.from_submap),
                b.descriptors.row(l.to_submap),
            );
            fa.iter()
                .zip(fb)
                .map(|(x, y)| f64::from(x - y).powi(2))
                .sum::<f64>()
        })
        .sum::<f64>()
        / result.loops.len() as f64;
    result.weight = confidence(
        result.feature_distance_sq,
        result.overlap_length_m,
        params.c_omega,
    );
    Ok(result)
}

/// The overlap the placement `a_from_b` predicts: pairs of submap centres it puts within
/// `predicted_radius_m` of each other, and how many of them look alike (their descriptor
/// difference among the smallest `predicted_rank_fraction` of A's submap row). A look-alike
/// stretch (a symmetric room, a repeated corridor section) verifies where it was matched, but
/// the placement it implies puts unrelated places side by side elsewhere.
fn predicted_overlap(
    a: &PreparedSegment,
    b: &PreparedSegment,
    d: &DifferenceMatrix,
    a_from_b: &Se2,
    params: &VerificationParams,
) -> (usize, usize) {
    let centres_a: Vec<nalgebra::Vector2<f64>> = a
        .submaps
        .iter()
        .map(|s| s.segment_from_centre.translation())
        .collect();
    let radius_sq = params.predicted_radius_m * params.predicted_radius_m;
    let rank_limit = (params.predicted_rank_fraction * d.cols() as f64).ceil() as usize;
    let (mut predicted, mut agreeing) = (0, 0);
    for (j, sb) in b.submaps.iter().enumerate() {
        let p = a_from_b.compose(&sb.segment_from_centre).translation();
        let Some((i, _)) = centres_a
            .iter()
            .enumerate()
            .map(|(i, c)| (i, (c - p).norm_squared()))
            .filter(|(_, dist_sq)| *dist_sq <= radius_sq)
            .min_by(|x, y| x.1.total_cmp(&y.1))
        else {
            continue;
        };
        predicted += 1;
        let row = d.row(i);
        let Some(&value) = row.get(j) else {
            continue;
        };
        if row.iter().filter(|&&x| x < value).count() < rank_limit {
            agreeing += 1;
        }
    }
    (predicted, agreeing)
}

/// At most `n` of `matches`, spread evenly (by position in the list, which is query order).
fn spread(matches: &[SubmapMatch], n: usize) -> Vec<SubmapMatch> {
    spread_indices(matches.len(), n)
        .into_iter()
        .filter_map(|k| matches.get(k).copied())
        .collect()
}

/// `n` indices of `0..len` spread evenly (all of them when `len ≤ n`), ascending.
fn spread_indices(len: usize, n: usize) -> Vec<usize> {
    if len <= n {
        return (0..len).collect();
    }
    (0..n).map(|k| k * len / n).collect()
}

/// Two placements agree within `(m, rad)`.
fn agree(p: &Se2, q: &Se2, (m, rad): (f64, f64)) -> bool {
    (p.translation() - q.translation()).norm() <= m
        && wrap_angle_rad(p.theta_rad - q.theta_rad).abs() <= rad
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_indices_are_even_ascending_and_all_of_a_short_list() {
        assert_eq!(spread_indices(10, 4), vec![0, 2, 5, 7]);
        assert_eq!(spread_indices(3, 5), vec![0, 1, 2]);
        assert_eq!(spread_indices(5, 0), Vec::<usize>::new());
    }
}

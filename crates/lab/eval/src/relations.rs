//! SLAM accuracy on planar trajectories keyed by scan index: the relations metric of
//! Kümmerle et al., "On measuring the accuracy of SLAM algorithms", Autonomous Robots 27(4),
//! 2009, the relative pose error (RPE, the same measure on relations between poses a fixed index
//! or distance apart; Sturm et al., IROS 2012) and the absolute trajectory error (ATE, after the
//! best rigid alignment, [`align_rigid`](crate::align_rigid)).

use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::trajectory::{position_errors, TrajectoryError};
use crate::EvalError;

/// One relation: the reference pose of scan `to` seen from scan `from` (`δ*_ij` of Kümmerle et
/// al. 2009, Sec. 3).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Relation {
    /// Index of the first scan.
    pub from: usize,
    /// Index of the second scan.
    pub to: usize,
    /// Stamp of the first scan (s), when known (relation files keyed by time carry it).
    pub from_stamp_secs: Option<f64>,
    /// Stamp of the second scan (s), when known.
    pub to_stamp_secs: Option<f64>,
    /// `from_T_to = x_from⁻¹ · x_to` in the reference.
    pub from_to: Se2,
}

/// The relations error of a trajectory (Kümmerle et al. 2009, Eq. 2 and Sec. 6): with
/// `e_ij = δ*_ij⁻¹ · δ_ij` (their `δ_ij ⊖ δ*_ij`), `trans(e) = |t(e)|` (m) and `rot(e) = |θ(e)|`
/// (reported in degrees), `ε = 1/N Σ trans(e)² + rot(e)²` is split into its two terms, and the
/// absolute errors are reported as mean ± standard deviation, as in the paper's tables.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RelationsError {
    /// Number of relations.
    pub count: usize,
    /// Mean absolute translational error (m).
    pub translation_mean_m: f64,
    /// Standard deviation of the absolute translational error (m, population).
    pub translation_std_m: f64,
    /// Mean squared translational error (m²), the translational term of ε.
    pub translation_squared_mean_m2: f64,
    /// Largest translational error (m).
    pub translation_max_m: f64,
    /// Mean absolute rotational error (deg).
    pub rotation_mean_deg: f64,
    /// Standard deviation of the absolute rotational error (deg, population).
    pub rotation_std_deg: f64,
    /// Mean squared rotational error (deg²), the rotational term of ε.
    pub rotation_squared_mean_deg2: f64,
    /// Largest rotational error (deg).
    pub rotation_max_deg: f64,
}

impl RelationsError {
    /// Root mean square translational error (m) (the RPE's translational RMSE).
    pub fn translation_rmse_m(&self) -> f64 {
        self.translation_squared_mean_m2.sqrt()
    }

    /// Root mean square rotational error (deg).
    pub fn rotation_rmse_deg(&self) -> f64 {
        self.rotation_squared_mean_deg2.sqrt()
    }
}

/// Mean, population standard deviation, mean square and maximum of non-negative values.
fn stats(values: &[f64]) -> (f64, f64, f64, f64) {
    let n = values.len().max(1) as f64;
    let mean = values.iter().sum::<f64>() / n;
    let squared_mean = values.iter().map(|v| v * v).sum::<f64>() / n;
    let variance = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    let max = values.iter().copied().fold(0.0, f64::max);
    (mean, variance.sqrt(), squared_mean, max)
}

/// The relations error of `trajectory` (one pose per scan, index = scan) against `relations`
/// (Kümmerle et al. 2009; see [`RelationsError`]). Fails if there are no relations or one names
/// a scan beyond the trajectory.
pub fn relations_error(
    trajectory: &[Se2],
    relations: &[Relation],
) -> Result<RelationsError, EvalError> {
    if relations.is_empty() {
        return Err(EvalError::Empty("no relations"));
    }
    let mut translation_m = Vec::with_capacity(relations.len());
    let mut rotation_deg = Vec::with_capacity(relations.len());
    for (index, relation) in relations.iter().enumerate() {
        let (Some(from), Some(to)) = (trajectory.get(relation.from), trajectory.get(relation.to))
        else {
            return Err(EvalError::RelationOutOfRange {
                relation: index,
                from: relation.from,
                to: relation.to,
                poses: trajectory.len(),
            });
        };
        // Kümmerle et al. 2009, Eq. 2: δ_ij ⊖ δ*_ij = δ*_ij⁻¹ ⊕ δ_ij.
        let estimated = from.between(to);
        let error = relation.from_to.between(&estimated);
        translation_m.push(error.translation().norm());
        rotation_deg.push(wrap_angle_rad(error.theta_rad).abs().to_degrees());
    }
    let (t_mean, t_std, t_sq, t_max) = stats(&translation_m);
    let (r_mean, r_std, r_sq, r_max) = stats(&rotation_deg);
    Ok(RelationsError {
        count: relations.len(),
        translation_mean_m: t_mean,
        translation_std_m: t_std,
        translation_squared_mean_m2: t_sq,
        translation_max_m: t_max,
        rotation_mean_deg: r_mean,
        rotation_std_deg: r_std,
        rotation_squared_mean_deg2: r_sq,
        rotation_max_deg: r_max,
    })
}

/// How [`make_relations`] picks pairs of scans.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RelationsParams {
    /// Pairs must be at most this far apart in the reference (m) (default: 2.5): close enough
    /// for their scans to overlap, like the scan-matched relations of the published files.
    pub max_distance_m: f64,
    /// ... and their headings at most this far apart (deg) (default: 90, half a 180° scan).
    pub max_heading_difference_deg: f64,
    /// A pair whose path along the reference trajectory is at least this long (m) is a *loop*
    /// relation (a revisit), shorter ones are *local* (default: 10).
    pub loop_min_path_m: f64,
    /// Pairs whose path is shorter than this (m) and who turned less than 5° are skipped: the
    /// robot stood still (default: 0.1).
    pub min_path_m: f64,
    /// At most this many local relations are kept (default: 1500).
    pub max_local: usize,
    /// At most this many loop relations are kept (default: 1500).
    pub max_loop: usize,
}

impl Default for RelationsParams {
    fn default() -> Self {
        Self {
            max_distance_m: 2.5,
            max_heading_difference_deg: 90.0,
            loop_min_path_m: 10.0,
            min_path_m: 0.1,
            max_local: 1500,
            max_loop: 1500,
        }
    }
}

/// What [`make_relations_with_info`] found and kept.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RelationsInfo {
    /// Local candidate pairs (path shorter than `loop_min_path_m`).
    pub local_candidates: usize,
    /// Loop candidate pairs.
    pub loop_candidates: usize,
    /// Local relations kept.
    pub local: usize,
    /// Loop relations kept.
    pub loops: usize,
}

/// `keep` indices out of `n`, evenly spread: `⌊(k + ½) · n / keep⌋` for `k < keep` (all when
/// `n ≤ keep`).
fn evenly_spaced(n: usize, keep: usize) -> Vec<usize> {
    if n <= keep {
        return (0..n).collect();
    }
    (0..keep).map(|k| ((2 * k + 1) * n) / (2 * keep)).collect()
}

/// Relations from reference poses (one per scan), like the published relation files: pairs of
/// scans that are close in space. See [`make_relations_with_info`] for the rule.
pub fn make_relations(
    corrected: &[Se2],
    params: &RelationsParams,
) -> Result<Vec<Relation>, EvalError> {
    make_relations_with_info(corrected, params).map(|(relations, _)| relations)
}

/// [`make_relations`] and how many candidates each class had.
///
/// Rule (deterministic, no randomness):
/// 1. Candidates: every pair `i < j` whose reference positions are at most `max_distance_m`
///    apart and headings at most `max_heading_difference_deg` apart, excluding pairs the robot
///    did not move between (path `< min_path_m` and turn `< 5°`).
/// 2. A candidate is a *loop* relation when the path length along the reference trajectory
///    from `i` to `j` is at least `loop_min_path_m` (the robot left and came back), else *local*.
/// 3. Each class, sorted by `(i, j)`, is thinned to at most `max_local` / `max_loop` pairs
///    evenly spread over that order (kept: positions `⌊(k + ½) · n / keep⌋`), so both
///    cover the whole run.
/// 4. The result lists the kept local and loop relations together, sorted by `(i, j)`.
pub fn make_relations_with_info(
    corrected: &[Se2],
    params: &RelationsParams,
) -> Result<(Vec<Relation>, RelationsInfo), EvalError> {
    for (field, value) in [
        ("max_distance_m", params.max_distance_m),
        (
            "max_heading_difference_deg",
            params.max_heading_difference_deg,
        ),
        ("loop_min_path_m", params.loop_min_path_m),
        ("min_path_m", params.min_path_m),
    ] {
        if !(value.is_finite() && value >= 0.0) {
            return Err(EvalError::InvalidParams {
                field,
                reason: format!("{value} must be finite and non-negative"),
            });
        }
    }
    // Path length from scan 0 to scan k along the reference, and the accumulated turn.
    let mut path_m = Vec::with_capacity(corrected.len());
    let mut turn_rad = Vec::with_capacity(corrected.len());
    let (mut s, mut a) = (0.0, 0.0);
    for (k, pose) in corrected.iter().enumerate() {
        if let Some(previous) = k.checked_sub(1).and_then(|p| corrected.get(p)) {
            let u = previous.between(pose);
            s += u.translation().norm();
            a += u.theta_rad.abs();
        }
        path_m.push(s);
        turn_rad.push(a);
    }
    let max_heading_rad = params.max_heading_difference_deg.to_radians();
    let max_d2 = params.max_distance_m * params.max_distance_m;
    let still_turn_rad = 5f64.to_radians();
    let (mut local, mut loops) = (Vec::new(), Vec::new());
    for (i, a) in corrected.iter().enumerate() {
        for (j, b) in corrected.iter().enumerate().skip(i + 1) {
            let (dx, dy) = (b.x_m - a.x_m, b.y_m - a.y_m);
            if dx * dx + dy * dy > max_d2
                || wrap_angle_rad(b.theta_rad - a.theta_rad).abs() > max_heading_rad
            {
                continue;
            }
            let path = path_m[j] - path_m[i];
            if path < params.min_path_m && turn_rad[j] - turn_rad[i] < still_turn_rad {
                continue;
            }
            if path >= params.loop_min_path_m {
                loops.push((i, j));
            } else {
                local.push((i, j));
            }
        }
    }
    let info = RelationsInfo {
        local_candidates: local.len(),
        loop_candidates: loops.len(),
        local: local.len().min(params.max_local),
        loops: loops.len().min(params.max_loop),
    };
    let mut pairs: Vec<(usize, usize)> = evenly_spaced(local.len(), params.max_local)
        .into_iter()
        .map(|k| local[k])
        .chain(
            evenly_spaced(loops.len(), params.max_loop)
                .into_iter()
                .map(|k| loops[k]),
        )
        .collect();
    pairs.sort_unstable();
    let relations = pairs
        .into_iter()
        .map(|(i, j)| Relation {
            from: i,
            to: j,
            from_stamp_secs: None,
            to_stamp_secs: None,
            from_to: corrected[i].between(&corrected[j]),
        })
        .collect();
    Ok((relations, info))
}

/// Fills in the stamps of relations from the scans' stamps (`stamps[k]` = scan `k`); relations
/// beyond `stamps` keep `None`.
pub fn attach_stamps(relations: &mut [Relation], stamps: &[f64]) {
    for relation in relations {
        relation.from_stamp_secs = stamps.get(relation.from).copied();
        relation.to_stamp_secs = stamps.get(relation.to).copied();
    }
}

/// Which pairs the relative pose error compares.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RpeDelta {
    /// Scan `i` and scan `i + n`, for every `i`.
    Scans(usize),
    /// Scan `i` and the first scan `j` whose path along the reference from `i` is at least this
    /// long (m), for every `i` that has one.
    DistanceM(f64),
}

/// The relative pose error for one delta: the relations error over the pairs it defines.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RelativePoseError {
    /// The delta.
    pub delta: RpeDelta,
    /// Number of pairs.
    pub count: usize,
    /// Translational RMSE (m).
    pub translation_rmse_m: f64,
    /// Rotational RMSE (deg).
    pub rotation_rmse_deg: f64,
    /// Mean absolute translational error (m).
    pub translation_mean_m: f64,
    /// Mean absolute rotational error (deg).
    pub rotation_mean_deg: f64,
}

/// The pairs of an RPE delta as relations of the reference.
pub fn rpe_relations(reference: &[Se2], delta: RpeDelta) -> Vec<Relation> {
    let pair = |i: usize, j: usize| Relation {
        from: i,
        to: j,
        from_stamp_secs: None,
        to_stamp_secs: None,
        from_to: reference[i].between(&reference[j]),
    };
    match delta {
        RpeDelta::Scans(n) => {
            let n = n.max(1);
            (0..reference.len().saturating_sub(n))
                .map(|i| pair(i, i + n))
                .collect()
        }
        RpeDelta::DistanceM(distance_m) => {
            let mut path_m = vec![0.0; reference.len()];
            for k in 1..reference.len() {
                path_m[k] = path_m[k - 1]
                    + (reference[k].translation() - reference[k - 1].translation()).norm();
            }
            let mut out = Vec::new();
            let mut j = 0;
            for i in 0..reference.len() {
                j = j.max(i + 1);
                while j < reference.len() && path_m[j] - path_m[i] < distance_m {
                    j += 1;
                }
                if j >= reference.len() {
                    break;
                }
                out.push(pair(i, j));
            }
            out
        }
    }
}

/// The relative pose error of `estimate` against `reference` (equal length, index = scan).
/// Fails on a length mismatch or when the delta yields no pair.
pub fn relative_pose_error(
    reference: &[Se2],
    estimate: &[Se2],
    delta: RpeDelta,
) -> Result<RelativePoseError, EvalError> {
    check_lengths("relative pose error", reference, estimate)?;
    let relations = rpe_relations(reference, delta);
    if relations.is_empty() {
        return Err(EvalError::Empty("the RPE delta yields no pair of scans"));
    }
    let error = relations_error(estimate, &relations)?;
    Ok(RelativePoseError {
        delta,
        count: error.count,
        translation_rmse_m: error.translation_rmse_m(),
        rotation_rmse_deg: error.rotation_rmse_deg(),
        translation_mean_m: error.translation_mean_m,
        rotation_mean_deg: error.rotation_mean_deg,
    })
}

fn check_lengths(what: &'static str, reference: &[Se2], estimate: &[Se2]) -> Result<(), EvalError> {
    if reference.len() == estimate.len() {
        Ok(())
    } else {
        Err(EvalError::LengthMismatch {
            what,
            reference: reference.len(),
            estimate: estimate.len(),
        })
    }
}

/// The absolute trajectory error of `estimate` against `reference` (equal length, index =
/// scan): position errors after the best rigid alignment of the estimate onto the reference
/// when `align` is set ([`align_rigid`](crate::align_rigid), planar). Fails on a length mismatch or empty input.
pub fn absolute_trajectory_error(
    reference: &[Se2],
    estimate: &[Se2],
    align: bool,
) -> Result<TrajectoryError, EvalError> {
    check_lengths("absolute trajectory error", reference, estimate)?;
    let lift = |poses: &[Se2]| -> Vec<Vector3<f64>> {
        poses
            .iter()
            .map(|p| Vector3::new(p.x_m, p.y_m, 0.0))
            .collect()
    };
    position_errors(&lift(reference), &lift(estimate), true, align)
}

/// Everything the SLAM table reports for one trajectory.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrajectoryReport {
    /// ATE after rigid alignment.
    pub ate: TrajectoryError,
    /// RPE for each requested delta.
    pub rpe: Vec<RelativePoseError>,
    /// The relations error (Kümmerle et al. 2009), when relations were given.
    pub relations: Option<RelationsError>,
}

/// The default RPE deltas: consecutive scans (the front-end's local accuracy) and 5 m of path.
pub const DEFAULT_RPE_DELTAS: [RpeDelta; 2] = [RpeDelta::Scans(1), RpeDelta::DistanceM(5.0)];

/// ATE (aligned), RPE for each of `rpe_deltas` (deltas that yield no pair are left out) and,
/// when `relations` is not empty, the relations error of `estimate` against `reference`.
pub fn trajectory_report(
    reference: &[Se2],
    estimate: &[Se2],
    relations: &[Relation],
    rpe_deltas: &[RpeDelta],
) -> Result<TrajectoryReport, EvalError> {
    let ate = absolute_trajectory_error(reference, estimate, true)?;
    let mut rpe = Vec::with_capacity(rpe_deltas.len());
    for delta in rpe_deltas {
        match relative_pose_error(reference, estimate, *delta) {
            Ok(error) => rpe.push(error),
            Err(EvalError::Empty(_)) => {}
            Err(err) => return Err(err),
        }
    }
    let relations = if relations.is_empty() {
        None
    } else {
        Some(relations_error(estimate, relations)?)
    };
    Ok(TrajectoryReport {
        ate,
        rpe,
        relations,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Two laps of a loop, one pose every ~0.25 m.
    fn two_laps(n: usize) -> Vec<Se2> {
        (0..n)
            .map(|k| {
                let t = k as f64 * std::f64::consts::TAU * 2.0 / n as f64;
                Se2::new(
                    8.0 * t.cos(),
                    5.0 * t.sin(),
                    t + std::f64::consts::FRAC_PI_2,
                )
            })
            .collect()
    }

    #[test]
    fn ground_truth_has_zero_relations_error() {
        let truth = two_laps(400);
        let (relations, info) =
            make_relations_with_info(&truth, &RelationsParams::default()).unwrap();
        assert!(info.local > 100 && info.loops > 100, "{info:?}");
        assert_eq!(relations.len(), info.local + info.loops);
        let error = relations_error(&truth, &relations).unwrap();
        assert!(error.translation_mean_m < 1e-12 && error.rotation_mean_deg < 1e-9);
        assert!(error.translation_std_m < 1e-12 && error.rotation_squared_mean_deg2 < 1e-15);
        // Deterministic, sorted, within the distance.
        assert_eq!(
            relations,
            make_relations(&truth, &RelationsParams::default()).unwrap()
        );
        assert!(relations
            .windows(2)
            .all(|w| (w[0].from, w[0].to) < (w[1].from, w[1].to)));
        assert!(relations
            .iter()
            .all(|r| r.from_to.translation().norm() <= 2.5));
    }

    #[test]
    fn relations_are_capped_and_spread() {
        let truth = two_laps(1200);
        let params = RelationsParams {
            max_local: 100,
            max_loop: 50,
            ..RelationsParams::default()
        };
        let (relations, info) = make_relations_with_info(&truth, &params).unwrap();
        assert_eq!((info.local, info.loops), (100, 50));
        assert!(info.local_candidates > 100 && info.loop_candidates > 50);
        assert_eq!(relations.len(), 150);
        assert!(relations.first().unwrap().from < 60 && relations.last().unwrap().from > 1000);
    }

    #[test]
    fn known_perturbation_gives_the_expected_error() {
        let truth = two_laps(100);
        // Move scan 10 by 0.3 m along its own x axis and turn it by 2°: relation 10 → 11 sees
        // scan 11 from a frame shifted by (0.3, 0) and turned by 2°.
        let mut estimate = truth.clone();
        estimate[10] = truth[10].compose(&Se2::new(0.3, 0.0, 2f64.to_radians()));
        let relations = rpe_relations(&truth, RpeDelta::Scans(1));
        let one = [relations[10]];
        let error = relations_error(&estimate, &one).unwrap();
        // e = δ*⁻¹ δ with δ = (x10 p)⁻¹ x11 = p⁻¹ δ*: |t(e)| = |t(δ*⁻¹ p⁻¹ δ*)|.
        let expected = relations[10]
            .from_to
            .inverse()
            .compose(&Se2::new(0.3, 0.0, 2f64.to_radians()).inverse())
            .compose(&relations[10].from_to);
        assert!((error.translation_mean_m - expected.translation().norm()).abs() < 1e-12);
        assert!((error.rotation_mean_deg - 2.0).abs() < 1e-9);
        // A pure translation of one scan by 0.3 m along x of its frame: the relation to the
        // next scan is off by exactly 0.3 m; over both neighbours' relations too.
        let mut shifted = truth.clone();
        shifted[10] = truth[10].compose(&Se2::new(0.3, 0.0, 0.0));
        let both = [relations[9], relations[10], relations[20]];
        let error = relations_error(&shifted, &both).unwrap();
        assert!((error.translation_mean_m - 0.2).abs() < 1e-12, "{error:?}");
        assert!((error.translation_squared_mean_m2 - 0.06).abs() < 1e-12);
        let std = (0.09f64 * 2.0 / 3.0 - 0.04).sqrt();
        assert!((error.translation_std_m - std).abs() < 1e-12);
        assert!(error.rotation_mean_deg < 1e-9);
    }

    #[test]
    fn errors_on_bad_input() {
        let truth = two_laps(10);
        let relation = Relation {
            from: 3,
            to: 12,
            from_stamp_secs: None,
            to_stamp_secs: None,
            from_to: Se2::identity(),
        };
        assert!(matches!(
            relations_error(&truth, &[relation]),
            Err(EvalError::RelationOutOfRange { to: 12, .. })
        ));
        assert!(matches!(
            relations_error(&truth, &[]),
            Err(EvalError::Empty(_))
        ));
        assert!(matches!(
            absolute_trajectory_error(&truth, &truth[1..], true),
            Err(EvalError::LengthMismatch { .. })
        ));
    }

    #[test]
    fn rpe_by_distance_pairs_scans_the_distance_apart() {
        let truth = two_laps(200);
        let relations = rpe_relations(&truth, RpeDelta::DistanceM(3.0));
        assert!(!relations.is_empty());
        for r in &relations {
            let path: f64 = (r.from..r.to)
                .map(|k| (truth[k + 1].translation() - truth[k].translation()).norm())
                .sum();
            assert!((3.0..3.5).contains(&path), "{path}");
        }
        let rpe = relative_pose_error(&truth, &truth, RpeDelta::DistanceM(3.0)).unwrap();
        assert!(rpe.translation_rmse_m < 1e-12);
    }

    proptest! {
        #[test]
        fn errors_are_invariant_to_a_rigid_transform(
            dx in -50.0f64..50.0, dy in -50.0f64..50.0, dth in -3.1f64..3.1,
            noise in prop::collection::vec(prop::array::uniform3(-0.3f64..0.3), 120),
        ) {
            let truth = two_laps(120);
            let estimate: Vec<Se2> = truth.iter().zip(&noise)
                .map(|(p, n)| p.compose(&Se2::new(n[0], n[1], n[2])))
                .collect();
            let moved = Se2::new(dx, dy, dth);
            let moved_estimate: Vec<Se2> = estimate.iter().map(|p| moved.compose(p)).collect();
            let a = absolute_trajectory_error(&truth, &estimate, true).unwrap();
            let b = absolute_trajectory_error(&truth, &moved_estimate, true).unwrap();
            prop_assert!((a.rms_m - b.rms_m).abs() < 1e-9, "{} vs {}", a.rms_m, b.rms_m);
            let relations = make_relations(&truth, &RelationsParams::default()).unwrap();
            let ra = relations_error(&estimate, &relations).unwrap();
            let rb = relations_error(&moved_estimate, &relations).unwrap();
            prop_assert!((ra.translation_mean_m - rb.translation_mean_m).abs() < 1e-9);
            prop_assert!((ra.rotation_mean_deg - rb.rotation_mean_deg).abs() < 1e-7);
        }
    }
}

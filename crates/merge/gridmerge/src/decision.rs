//! Deciding whether and how to merge two maps from their metadata (Andersone, Sec. 2.1):
//! a table of records, each naming the conditions under which a matching and a fusion
//! procedure apply. The first record (by priority, then table order) whose conditions all hold
//! is chosen; when none does, the attempt is rejected with a reason.

use core::fmt;

use mapmerge_geometry::Se2;
use serde::{Deserialize, Serialize};

/// What kind of map a robot keeps.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MapKind {
    /// A 2D occupancy grid (log-odds or probabilities per cell).
    OccupancyGrid,
    /// A set of points (2D or 3D), e.g. a lidar point cloud map.
    PointCloud,
    /// Landmarks or line/corner features.
    FeatureMap,
    /// Places and their connections, without metric cells.
    Topological,
}

/// The sensor a map was built with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SensorKind {
    /// Planar laser range finder.
    Lidar2d,
    /// Multi-layer or 3D lidar.
    Lidar3d,
    /// Sonar ring (wide beams, coarse maps).
    Sonar,
    /// RGB-D or time-of-flight camera.
    DepthCamera,
    /// Monocular or stereo camera.
    Camera,
    /// Not reported.
    Unknown,
}

/// What a robot says about its map when offering it for merging.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapMetadata {
    /// Map representation.
    pub kind: MapKind,
    /// Cell side (m) for grids; `None` for maps without cells (required for grids).
    #[serde(default)]
    pub resolution_m: Option<f64>,
    /// Name of the map's frame. Two maps in the same non-empty frame (e.g. a shared `utm`
    /// frame) have a known relative pose, the identity.
    #[serde(default)]
    pub frame_id: String,
    /// Quality estimate in [0, 1] (1 = best), e.g. [`crate::QualityMap::overall`]; `None`
    /// when not estimated.
    #[serde(default)]
    pub quality: Option<f64>,
    /// The sensor the map was built with.
    #[serde(default = "unknown_sensor")]
    pub sensor: SensorKind,
}

fn unknown_sensor() -> SensorKind {
    SensorKind::Unknown
}

/// The two maps of a merge attempt: `a` is the receiving (own) map, `b` the other robot's.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GridMergeRequest {
    /// The receiving robot's map.
    pub a: MapMetadata,
    /// The other robot's map.
    pub b: MapMetadata,
    /// B's map frame expressed in A's map frame, when the robots know it (rendezvous,
    /// relative observation); `None` when it has to be found by matching.
    #[serde(default)]
    pub a_from_b: Option<Se2>,
}

/// How much is known about the relative pose of the two maps.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseKnowledge {
    /// `a_from_b` was given.
    Given,
    /// Both maps are in the same named frame: `a_from_b` is the identity.
    SharedFrame,
    /// It must be found by matching.
    Unknown,
}

impl PoseKnowledge {
    fn is_known(self) -> bool {
        !matches!(self, PoseKnowledge::Unknown)
    }
}

/// A record's condition on the relative pose.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseCondition {
    /// Applies whether or not the pose is known.
    Any,
    /// Applies only when the pose is given or the frames are shared.
    Known,
    /// Applies only when the pose is unknown.
    Unknown,
}

fn any_pose() -> PoseCondition {
    PoseCondition::Any
}

/// How the transform between the maps is found.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MatchingProcedure {
    /// Use the known relative pose as it is.
    KnownPose,
    /// Refine the known relative pose by a local search around it (scan-to-map matching).
    RefineKnownPose,
    /// No initial guess: rotation from Hough spectra, translation by correlation, then
    /// refinement (Carpin 2008; crate `mapmerge-gridmatch`). Maps are resampled to the
    /// receiving map's resolution first (Andersone, Sec. 4.1).
    SpectralGrid,
}

/// How the other map is fused into the receiving one.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FusionProcedure {
    /// Binary Bayes (log-odds) fusion applied 0–3 times per region depending on the quality
    /// difference (Andersone, Sec. 4.1; [`crate::fuse`] with [`crate::FusionWeighting::Quality`]).
    QualityWeightedBayes,
    /// Binary Bayes fusion, once per cell ([`crate::FusionWeighting::Uniform`]).
    BinaryBayes,
    /// Rasterise the other map's points into hit/miss evidence, then binary Bayes fusion
    /// (point clouds into grids; not implemented in this crate).
    RasterizeThenBayes,
}

/// One row of the decision table: conditions, then the procedures they select.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DecisionRecord {
    /// A short name, reported with the choice or the rejection.
    pub name: String,
    /// Higher is tried first; equal priorities keep table order (default 0).
    #[serde(default)]
    pub priority: i32,
    /// Kind of the receiving map A.
    pub a_kind: MapKind,
    /// Kind of the other map B.
    pub b_kind: MapKind,
    /// Condition on the relative pose (default `any`).
    #[serde(default = "any_pose")]
    pub relative_pose: PoseCondition,
    /// Largest ratio of the coarser to the finer resolution when both maps have one
    /// (default `None`: unlimited). Matching gets unreliable as the ratio grows.
    #[serde(default)]
    pub max_resolution_ratio: Option<f64>,
    /// Smallest quality accepted for each map that reports one (default 0: any). A map
    /// without an estimate passes.
    #[serde(default)]
    pub min_quality: f64,
    /// Sensors accepted for map B (default empty: any).
    #[serde(default)]
    pub b_sensors: Vec<SensorKind>,
    /// The matching procedure selected.
    pub matching: MatchingProcedure,
    /// The fusion procedure selected.
    pub fusion: FusionProcedure,
}

/// The decision table (Andersone, Sec. 2.1).
///
/// The default table, highest priority first:
///
/// | name | A | B | pose | max ratio | min quality | matching | fusion |
/// |---|---|---|---|---|---|---|---|
/// | `grids-known-pose` | grid | grid | known | 4 | 0 | refine known pose | quality-weighted Bayes |
/// | `grids-no-pose` | grid | grid | unknown | 2 | 0.3 | spectral grid | quality-weighted Bayes |
/// | `cloud-into-grid-known-pose` | grid | point cloud | known | – | 0 | known pose | rasterise then Bayes |
///
/// Without a pose the resolution ratio is limited to 2:1 (the range the spectral matcher is
/// specified for) and poor maps are refused, because a wrong match is likelier without
/// structure; feature and topological maps have no procedure and are rejected. The same table
/// ships as `config/decision_table.yaml`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DecisionTable {
    /// The records; see [`DecisionTable::decide`] for the order they are tried in.
    pub records: Vec<DecisionRecord>,
}

impl Default for DecisionTable {
    fn default() -> Self {
        Self {
            records: vec![
                DecisionRecord {
                    name: "grids-known-pose".into(),
                    priority: 0,
                    a_kind: MapKind::OccupancyGrid,
                    b_kind: MapKind::OccupancyGrid,
                    relative_pose: PoseCondition::Known,
                    max_resolution_ratio: Some(4.0),
                    min_quality: 0.0,
                    b_sensors: Vec::new(),
                    matching: MatchingProcedure::RefineKnownPose,
                    fusion: FusionProcedure::QualityWeightedBayes,
                },
                DecisionRecord {
                    name: "grids-no-pose".into(),
                    priority: 0,
                    a_kind: MapKind::OccupancyGrid,
                    b_kind: MapKind::OccupancyGrid,
                    relative_pose: PoseCondition::Unknown,
                    max_resolution_ratio: Some(2.0),
                    min_quality: 0.3,
                    b_sensors: Vec::new(),
                    matching: MatchingProcedure::SpectralGrid,
                    fusion: FusionProcedure::QualityWeightedBayes,
                },
                DecisionRecord {
                    name: "cloud-into-grid-known-pose".into(),
                    priority: 0,
                    a_kind: MapKind::OccupancyGrid,
                    b_kind: MapKind::PointCloud,
                    relative_pose: PoseCondition::Known,
                    max_resolution_ratio: None,
                    min_quality: 0.0,
                    b_sensors: Vec::new(),
                    matching: MatchingProcedure::KnownPose,
                    fusion: FusionProcedure::RasterizeThenBayes,
                },
            ],
        }
    }
}

/// The procedures chosen for a merge attempt.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GridMergeChoice {
    /// Name of the record that matched.
    pub record: String,
    /// Its index in the table.
    pub record_index: usize,
    /// How to find the transform.
    pub matching: MatchingProcedure,
    /// How to fuse.
    pub fusion: FusionProcedure,
    /// What was known about the relative pose.
    pub pose: PoseKnowledge,
    /// The known `a_from_b` (the identity for a shared frame), if any.
    pub a_from_b: Option<Se2>,
    /// Resolution B must be resampled to before matching (A's), when the two differ.
    pub resample_b_to_m: Option<f64>,
}

/// Which of the two maps a reason is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WhichMap {
    /// The receiving map.
    A,
    /// The other map.
    B,
}

impl fmt::Display for WhichMap {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            WhichMap::A => "A (own)",
            WhichMap::B => "B (other)",
        })
    }
}

/// Why a merge attempt was rejected.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "reason", rename_all = "snake_case")]
#[non_exhaustive]
pub enum GridRejectReason {
    /// The metadata itself is unusable (non-finite or out-of-range values).
    InvalidMetadata {
        /// Field at fault, e.g. `b.resolution_m`.
        field: String,
        /// What is wrong.
        problem: String,
    },
    /// No record handles this pair of map kinds.
    UnsupportedMapKinds {
        /// Kind of A.
        a: MapKind,
        /// Kind of B.
        b: MapKind,
    },
    /// The best record for the kinds needs a known pose, or an unknown one.
    RelativePose {
        /// Record that was closest.
        record: String,
        /// What it requires.
        required: PoseCondition,
        /// What the request has.
        actual: PoseKnowledge,
    },
    /// The resolutions differ too much.
    ResolutionRatio {
        /// Record that was closest.
        record: String,
        /// Coarser over finer resolution.
        ratio: f64,
        /// The record's limit.
        max: f64,
    },
    /// A map's quality is below the record's minimum.
    QualityTooLow {
        /// Record that was closest.
        record: String,
        /// Which map.
        map: WhichMap,
        /// Its quality.
        quality: f64,
        /// The record's minimum.
        min: f64,
    },
    /// B's sensor is not in the record's list.
    SensorNotAccepted {
        /// Record that was closest.
        record: String,
        /// B's sensor.
        sensor: SensorKind,
    },
}

impl GridRejectReason {
    /// How far a record got before this failure (pose, ratio, quality, sensor).
    fn stage(&self) -> u8 {
        match self {
            GridRejectReason::InvalidMetadata { .. }
            | GridRejectReason::UnsupportedMapKinds { .. } => 0,
            GridRejectReason::RelativePose { .. } => 1,
            GridRejectReason::ResolutionRatio { .. } => 2,
            GridRejectReason::QualityTooLow { .. } => 3,
            GridRejectReason::SensorNotAccepted { .. } => 4,
        }
    }
}

impl fmt::Display for GridRejectReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            GridRejectReason::InvalidMetadata { field, problem } => {
                write!(f, "invalid metadata: {field} {problem}")
            }
            GridRejectReason::UnsupportedMapKinds { a, b } => {
                write!(f, "no procedure merges a {b:?} map into a {a:?} map")
            }
            GridRejectReason::RelativePose {
                record,
                required,
                actual,
            } => write!(
                f,
                "record `{record}` needs the relative pose {}, but it is {actual:?}",
                match required {
                    PoseCondition::Known => "known",
                    PoseCondition::Unknown => "unknown",
                    PoseCondition::Any => "known or unknown",
                }
            ),
            GridRejectReason::ResolutionRatio { record, ratio, max } => write!(
                f,
                "record `{record}`: resolutions differ by {ratio:.3}:1, more than {max}:1"
            ),
            GridRejectReason::QualityTooLow {
                record,
                map,
                quality,
                min,
            } => write!(
                f,
                "record `{record}`: quality of map {map} is {quality:.3}, below {min}"
            ),
            GridRejectReason::SensorNotAccepted { record, sensor } => {
                write!(f, "record `{record}` does not accept maps from {sensor:?}")
            }
        }
    }
}

/// A rejected attempt: the reason as data and as a sentence.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GridMergeRejection {
    /// Why.
    pub reason: GridRejectReason,
    /// `reason` in words.
    pub message: String,
}

impl From<GridRejectReason> for GridMergeRejection {
    fn from(reason: GridRejectReason) -> Self {
        Self {
            message: reason.to_string(),
            reason,
        }
    }
}

/// The outcome of [`DecisionTable::decide`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "decision", rename_all = "snake_case")]
pub enum GridMergeDecision {
    /// Merge with these procedures.
    Merge(GridMergeChoice),
    /// Do not attempt the merge.
    Reject(GridMergeRejection),
}

impl DecisionTable {
    /// Chooses the procedures for `request` (Andersone, Sec. 2.1).
    ///
    /// Records are tried by descending `priority`, equal priorities in table order; the first
    /// whose conditions all hold is chosen. Conditions are checked in the order pose,
    /// resolution ratio, quality, sensor; when no record holds, the reason is the failing
    /// condition of the record for the two map kinds that got furthest (the first tried among
    /// equals), or "unsupported kinds" when no record names them. Invalid metadata is
    /// rejected before any record is tried.
    pub fn decide(&self, request: &GridMergeRequest) -> GridMergeDecision {
        if let Err(reason) = validate(request) {
            return GridMergeDecision::Reject(reason.into());
        }
        let pose = pose_knowledge(request);
        let mut order: Vec<usize> = (0..self.records.len()).collect();
        // Stable: equal priorities keep table order.
        order.sort_by_key(|&i| {
            core::cmp::Reverse(self.records.get(i).map_or(i32::MIN, |r| r.priority))
        });
        let mut best_failure: Option<(u8, GridRejectReason)> = None;
        for index in order {
            let Some(record) = self.records.get(index) else {
                continue;
            };
            if record.a_kind != request.a.kind || record.b_kind != request.b.kind {
                continue;
            }
            match check_record(record, request, pose) {
                Ok(()) => {
                    let a_from_b = match pose {
                        PoseKnowledge::Given => request.a_from_b,
                        PoseKnowledge::SharedFrame => Some(Se2::new(0.0, 0.0, 0.0)),
                        PoseKnowledge::Unknown => None,
                    };
                    let resample_b_to_m = match (request.a.resolution_m, request.b.resolution_m) {
                        (Some(a), Some(b)) if a != b => Some(a),
                        _ => None,
                    };
                    return GridMergeDecision::Merge(GridMergeChoice {
                        record: record.name.clone(),
                        record_index: index,
                        matching: record.matching,
                        fusion: record.fusion,
                        pose,
                        a_from_b,
                        resample_b_to_m,
                    });
                }
                Err(reason) => {
                    // Keep the failure of the record that got furthest; ties: the first tried.
                    let stage = reason.stage();
                    if best_failure.as_ref().is_none_or(|(s, _)| stage > *s) {
                        best_failure = Some((stage, reason));
                    }
                }
            }
        }
        let reason = best_failure.map_or(
            GridRejectReason::UnsupportedMapKinds {
                a: request.a.kind,
                b: request.b.kind,
            },
            |(_, reason)| reason,
        );
        GridMergeDecision::Reject(reason.into())
    }
}

fn pose_knowledge(request: &GridMergeRequest) -> PoseKnowledge {
    if request.a_from_b.is_some() {
        PoseKnowledge::Given
    } else if !request.a.frame_id.is_empty() && request.a.frame_id == request.b.frame_id {
        PoseKnowledge::SharedFrame
    } else {
        PoseKnowledge::Unknown
    }
}

fn validate(request: &GridMergeRequest) -> Result<(), GridRejectReason> {
    let invalid = |field: &str, problem: String| GridRejectReason::InvalidMetadata {
        field: field.into(),
        problem,
    };
    for (name, map) in [("a", &request.a), ("b", &request.b)] {
        match map.resolution_m {
            Some(r) if !(r.is_finite() && r > 0.0) => {
                return Err(invalid(
                    &format!("{name}.resolution_m"),
                    format!("must be positive and finite, got {r}"),
                ))
            }
            None if map.kind == MapKind::OccupancyGrid => {
                return Err(invalid(
                    &format!("{name}.resolution_m"),
                    "is required for occupancy grids".into(),
                ))
            }
            _ => {}
        }
        if let Some(q) = map.quality {
            if !(0.0..=1.0).contains(&q) {
                return Err(invalid(
                    &format!("{name}.quality"),
                    format!("must lie in [0, 1], got {q}"),
                ));
            }
        }
    }
    if let Some(p) = &request.a_from_b {
        if !(p.x_m.is_finite() && p.y_m.is_finite() && p.theta_rad.is_finite()) {
            return Err(invalid("a_from_b", "must be finite".into()));
        }
    }
    Ok(())
}

fn check_record(
    record: &DecisionRecord,
    request: &GridMergeRequest,
    pose: PoseKnowledge,
) -> Result<(), GridRejectReason> {
    let pose_ok = match record.relative_pose {
        PoseCondition::Any => true,
        PoseCondition::Known => pose.is_known(),
        PoseCondition::Unknown => !pose.is_known(),
    };
    if !pose_ok {
        return Err(GridRejectReason::RelativePose {
            record: record.name.clone(),
            required: record.relative_pose,
            actual: pose,
        });
    }
    if let (Some(a), Some(b), Some(max)) = (
        request.a.resolution_m,
        request.b.resolution_m,
        record.max_resolution_ratio,
    ) {
        let ratio = a.max(b) / a.min(b);
        if ratio > max {
            return Err(GridRejectReason::ResolutionRatio {
                record: record.name.clone(),
                ratio,
                max,
            });
        }
    }
    for (map, meta) in [(WhichMap::A, &request.a), (WhichMap::B, &request.b)] {
        if let Some(quality) = meta.quality {
            if quality < record.min_quality {
                return Err(GridRejectReason::QualityTooLow {
                    record: record.name.clone(),
                    map,
                    quality,
                    min: record.min_quality,
                });
            }
        }
    }
    if !record.b_sensors.is_empty() && !record.b_sensors.contains(&request.b.sensor) {
        return Err(GridRejectReason::SensorNotAccepted {
            record: record.name.clone(),
            sensor: request.b.sensor,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(resolution_m: f64, quality: Option<f64>) -> MapMetadata {
        MapMetadata {
            kind: MapKind::OccupancyGrid,
            resolution_m: Some(resolution_m),
            frame_id: String::new(),
            quality,
            sensor: SensorKind::Lidar2d,
        }
    }

    fn request(a: MapMetadata, b: MapMetadata, a_from_b: Option<Se2>) -> GridMergeRequest {
        GridMergeRequest { a, b, a_from_b }
    }

    fn reject_reason(decision: GridMergeDecision) -> GridRejectReason {
        match decision {
            GridMergeDecision::Reject(r) => {
                assert_eq!(r.message, r.reason.to_string());
                r.reason
            }
            GridMergeDecision::Merge(c) => panic!("expected a rejection, got {c:?}"),
        }
    }

    fn choice(decision: GridMergeDecision) -> GridMergeChoice {
        match decision {
            GridMergeDecision::Merge(c) => c,
            GridMergeDecision::Reject(r) => panic!("expected a merge, got {}", r.message),
        }
    }

    #[test]
    fn grids_without_pose_use_spectral_matching_and_resample_b() {
        let table = DecisionTable::default();
        let c = choice(table.decide(&request(grid(0.07, Some(0.8)), grid(0.10, Some(0.7)), None)));
        assert_eq!(c.record, "grids-no-pose");
        assert_eq!(c.record_index, 1);
        assert_eq!(c.matching, MatchingProcedure::SpectralGrid);
        assert_eq!(c.fusion, FusionProcedure::QualityWeightedBayes);
        assert_eq!(c.pose, PoseKnowledge::Unknown);
        assert_eq!(c.resample_b_to_m, Some(0.07));
        assert_eq!(c.a_from_b, None);
    }

    #[test]
    fn a_known_pose_or_shared_frame_selects_refinement() {
        let table = DecisionTable::default();
        let pose = Se2::new(1.0, 2.0, 0.3);
        let c = choice(table.decide(&request(grid(0.05, None), grid(0.05, None), Some(pose))));
        assert_eq!(c.record, "grids-known-pose");
        assert_eq!(c.matching, MatchingProcedure::RefineKnownPose);
        assert_eq!(c.a_from_b, Some(pose));
        assert_eq!(c.resample_b_to_m, None);

        let (mut a, mut b) = (grid(0.05, None), grid(0.2, None));
        a.frame_id = "utm".into();
        b.frame_id = "utm".into();
        let c = choice(table.decide(&request(a, b, None)));
        assert_eq!(c.pose, PoseKnowledge::SharedFrame);
        assert_eq!(c.a_from_b, Some(Se2::new(0.0, 0.0, 0.0)));
        assert_eq!(
            c.record, "grids-known-pose",
            "ratio 4 is allowed with a pose"
        );
    }

    #[test]
    fn rejections_name_the_first_failing_condition() {
        let table = DecisionTable::default();
        assert_eq!(
            reject_reason(table.decide(&request(grid(0.05, None), grid(0.15, None), None))),
            GridRejectReason::ResolutionRatio {
                record: "grids-no-pose".into(),
                ratio: 0.15 / 0.05,
                max: 2.0
            }
        );
        assert!(matches!(
            reject_reason(table.decide(&request(grid(0.05, None), grid(0.05, Some(0.1)), None))),
            GridRejectReason::QualityTooLow { map: WhichMap::B, min, .. } if min == 0.3
        ));
        let topo = MapMetadata {
            kind: MapKind::Topological,
            resolution_m: None,
            ..grid(1.0, None)
        };
        assert_eq!(
            reject_reason(table.decide(&request(grid(0.05, None), topo, None))),
            GridRejectReason::UnsupportedMapKinds {
                a: MapKind::OccupancyGrid,
                b: MapKind::Topological
            }
        );
        let cloud = MapMetadata {
            kind: MapKind::PointCloud,
            resolution_m: None,
            ..grid(1.0, None)
        };
        let reason = reject_reason(table.decide(&request(grid(0.05, None), cloud.clone(), None)));
        assert!(matches!(
            reason,
            GridRejectReason::RelativePose {
                required: PoseCondition::Known,
                actual: PoseKnowledge::Unknown,
                ..
            }
        ));
        assert!(reason.to_string().contains("needs the relative pose known"));
        let c = choice(table.decide(&request(
            grid(0.05, None),
            cloud,
            Some(Se2::new(0.0, 0.0, 0.0)),
        )));
        assert_eq!(c.fusion, FusionProcedure::RasterizeThenBayes);
    }

    #[test]
    fn invalid_metadata_is_rejected_not_panicked_on() {
        let table = DecisionTable::default();
        for (a, b, pose, field) in [
            (grid(-1.0, None), grid(0.05, None), None, "a.resolution_m"),
            (
                grid(0.05, None),
                grid(f64::NAN, None),
                None,
                "b.resolution_m",
            ),
            (grid(0.05, Some(1.5)), grid(0.05, None), None, "a.quality"),
            (
                grid(0.05, None),
                grid(0.05, None),
                Some(Se2 {
                    x_m: f64::INFINITY,
                    y_m: 0.0,
                    theta_rad: 0.0,
                }),
                "a_from_b",
            ),
        ] {
            match reject_reason(table.decide(&request(a, b, pose))) {
                GridRejectReason::InvalidMetadata { field: f, .. } => assert_eq!(f, field),
                other => panic!("{other:?}"),
            }
        }
        let no_resolution = MapMetadata {
            resolution_m: None,
            ..grid(0.05, None)
        };
        assert!(matches!(
            reject_reason(table.decide(&request(no_resolution, grid(0.05, None), None))),
            GridRejectReason::InvalidMetadata { .. }
        ));
        // An empty table rejects everything as unsupported.
        let empty = DecisionTable { records: vec![] };
        assert!(matches!(
            reject_reason(empty.decide(&request(grid(0.05, None), grid(0.05, None), None))),
            GridRejectReason::UnsupportedMapKinds { .. }
        ));
    }

    #[test]
    fn priority_beats_table_order_and_ties_keep_order() {
        let mut table = DecisionTable::default();
        let mut sonar_only = table.records[1].clone();
        sonar_only.name = "sonar".into();
        sonar_only.b_sensors = vec![SensorKind::Sonar];
        sonar_only.fusion = FusionProcedure::BinaryBayes;
        sonar_only.priority = 5;
        table.records.push(sonar_only);
        let mut b = grid(0.05, None);
        // Lidar: the high-priority sonar record fails on the sensor, the default record wins.
        let c = choice(table.decide(&request(grid(0.05, None), b.clone(), None)));
        assert_eq!(c.record, "grids-no-pose");
        b.sensor = SensorKind::Sonar;
        let c = choice(table.decide(&request(grid(0.05, None), b.clone(), None)));
        assert_eq!((c.record.as_str(), c.record_index), ("sonar", 3));
        // Both grid records without a pose fail on quality; the higher-priority one reports.
        b.quality = Some(0.1);
        assert!(matches!(
            reject_reason(table.decide(&request(grid(0.05, None), b.clone(), None))),
            GridRejectReason::QualityTooLow { record, .. } if record == "sonar"
        ));
        // The record that got furthest reports: sonar fails on the sensor (after passing
        // pose, ratio and quality), the default record on the quality.
        b.quality = Some(0.25);
        let mut lenient = table.records[3].clone();
        lenient.min_quality = 0.2;
        table.records[3] = lenient;
        b.sensor = SensorKind::Camera;
        assert!(matches!(
            reject_reason(table.decide(&request(grid(0.05, None), b, None))),
            GridRejectReason::SensorNotAccepted { record, .. } if record == "sonar"
        ));
        // Ties: two identical records, the first in the table wins.
        let mut twin = table.records[1].clone();
        twin.name = "twin".into();
        table.records.push(twin);
        let c = choice(table.decide(&request(grid(0.05, None), grid(0.05, None), None)));
        assert_eq!(c.record, "grids-no-pose");
    }

    #[test]
    fn the_table_round_trips_and_refuses_unknown_fields() {
        let table = DecisionTable::default();
        let json = serde_json::to_string(&table).unwrap();
        let back: DecisionTable = serde_json::from_str(&json).unwrap();
        assert_eq!(back, table);
        let minimal = r#"{"records": [{"name": "r", "a_kind": "occupancy_grid",
            "b_kind": "occupancy_grid", "matching": "spectral_grid", "fusion": "binary_bayes"}]}"#;
        let t: DecisionTable = serde_json::from_str(minimal).unwrap();
        assert_eq!(t.records[0].relative_pose, PoseCondition::Any);
        assert_eq!(t.records[0].max_resolution_ratio, None);
        let typo = minimal
            .replace("\"priority\"", "x")
            .replace("\"name\"", "\"nmae\"");
        assert!(serde_json::from_str::<DecisionTable>(&typo).is_err());
    }
}

//! `mapmerge atlas`'s outputs against the truth, as evo would judge them: every map's
//! `maps/<map>/trajectory.tum`, read back with `maps.json`, aligned to the reference poses.
//! The unit is the segment, the robot's path between two kidnaps (or session starts): the
//! engine's epochs may cut a segment further, but the truth knows only where the robot was
//! carried.
//!
//! A segment *revisits* when its true path runs [`REVISIT_MIN_M`] or more within
//! [`REVISIT_RADIUS_M`] of an earlier segment's. It *ends merged correctly* when the map
//! holding its last scan also holds an earlier segment, and both are *placed* there: aligned
//! with the whole map, their error exceeds their own error (aligned alone) by no more than
//! [`PLACED_WITHIN_M`] (issue target "consistency").

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;
use mapmerge_geometry::Se2;
use mapmerge_jobs::{AtlasSession, MapReport};
use nalgebra::{Vector2, Vector3};
use serde::Serialize;

use crate::atlas_judge::{REVISIT_MIN_M, REVISIT_RADIUS_M};

/// A segment is placed in its map when its error there exceeds its own by at most this (m).
pub const PLACED_WITHIN_M: f64 = 0.5;
/// Segment parts with fewer scans in a map are too short to align and not judged.
const MIN_SCANS: usize = 3;

/// Whether the sessions' reference poses share one frame (a simulated world) or each has its
/// own (corrected logs: segments are compared within their session only).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Frames {
    Shared,
    PerSession,
}

/// A segment: where it ended up and how well it is placed.
#[derive(Clone, Debug, Serialize)]
pub struct SegmentJudgement {
    pub session: usize,
    /// Its number within the session (0 before the first kidnap).
    pub segment: usize,
    pub scans: usize,
    /// Its true path's length (m), and the part within [`REVISIT_RADIUS_M`] of an earlier
    /// segment's true path in the same frame (m).
    pub travel_m: f64,
    pub revisit_travel_m: f64,
    pub revisits: bool,
    /// Its first scan within [`REVISIT_RADIUS_M`] of an earlier segment's true path (in its
    /// session's numbering).
    pub first_revisit_scan: Option<usize>,
    /// The map holding its last scan (none when maintenance dropped it).
    pub map: Option<String>,
    /// Its scans in that map: ATE (m) aligned alone, and aligned with the whole map.
    pub own_ate_m: Option<f64>,
    pub in_map_ate_m: Option<f64>,
    /// `in_map_ate_m − own_ate_m`.
    pub placed_off_m: Option<f64>,
    /// Its map holds an earlier segment, and both are placed.
    pub merged_correctly: bool,
}

/// A map: its segments, its whole error beside theirs.
#[derive(Clone, Debug, Serialize)]
pub struct MapJudgement {
    pub map: String,
    /// `[session, segment]` of every part with enough scans to judge.
    pub segments: Vec<[usize; 2]>,
    /// ATE (m) of all its scans aligned together (one frame group), and the largest
    /// `placed_off_m` of its parts.
    pub whole_ate_m: Option<f64>,
    pub worst_placed_off_m: Option<f64>,
}

/// The run judged from its output files.
#[derive(Clone, Debug, Default, Serialize)]
pub struct MapsJudgement {
    pub segments_revisiting: usize,
    pub revisiting_merged_correctly: usize,
    /// Segment parts sharing a map with another segment and placed more than
    /// [`PLACED_WITHIN_M`] off: wrong merges left standing.
    pub misplaced: usize,
    /// Scans in no map (their graph was dropped by maintenance).
    pub scans_in_no_map: usize,
    pub maps: Vec<MapJudgement>,
    pub segments: Vec<SegmentJudgement>,
}

/// A map as read back: its name and, per line of its trajectory, `[session, scan]` and the
/// pose.
type PlacedMap = (String, Vec<([usize; 2], Se2)>);

/// Reads `output`'s `maps.json` and trajectories and judges them against `sessions`' reference
/// poses, with segments cut at their kidnaps.
pub fn judge_maps(
    output: &Path,
    sessions: &[AtlasSession],
    frames: Frames,
) -> anyhow::Result<MapsJudgement> {
    let path = output.join("maps.json");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let maps: Vec<MapReport> =
        serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    // Each map's scans: (session, scan) → estimated pose.
    let mut placed: Vec<PlacedMap> = Vec::new();
    for map in &maps {
        let Some(trajectory) = &map.trajectory else {
            continue;
        };
        let poses = mapmerge_io::read_tum_planar(trajectory)
            .with_context(|| format!("reading {}", trajectory.display()))?;
        let scans: Vec<[usize; 2]> = map
            .epochs
            .iter()
            .filter_map(|e| Some((e.session_index?, &e.scan_ranges)))
            .flat_map(|(s, ranges)| {
                ranges
                    .iter()
                    .flat_map(move |r| (r[0]..=r[1]).map(move |k| [s, k]))
            })
            .collect();
        anyhow::ensure!(
            scans.len() == poses.len(),
            "{}: {} poses, but maps.json gives {} scans",
            trajectory.display(),
            poses.len(),
            scans.len()
        );
        placed.push((
            map.map.clone(),
            scans
                .into_iter()
                .zip(poses.into_iter().map(|(_, p)| p))
                .collect(),
        ));
    }
    judge_placed(&placed, sessions, frames)
}

/// The judgement of `placed` maps (each with its `[session, scan]`s and their poses).
fn judge_placed(
    placed: &[PlacedMap],
    sessions: &[AtlasSession],
    frames: Frames,
) -> anyhow::Result<MapsJudgement> {
    let reference = |[s, k]: [usize; 2]| -> anyhow::Result<Se2> {
        sessions
            .get(s)
            .and_then(|x| x.reference.as_ref())
            .and_then(|r| r.get(k))
            .copied()
            .with_context(|| format!("session {s} scan {k} has no reference pose"))
    };
    // Segment of a scan: the kidnaps before it.
    let segment_of = |[s, k]: [usize; 2]| -> usize {
        sessions
            .get(s)
            .map_or(0, |x| x.kidnaps.iter().filter(|&&at| at <= k).count())
    };
    let frame_of = |s: usize| match frames {
        Frames::Shared => 0,
        Frames::PerSession => s,
    };
    // Every segment's true path, in run order; revisits within its frame.
    let mut segments: Vec<SegmentJudgement> = Vec::new();
    let mut paths: BTreeMap<usize, Vec<Vec<Vector2<f64>>>> = BTreeMap::new();
    for (s, session) in sessions.iter().enumerate() {
        let Some(truth) = &session.reference else {
            anyhow::bail!("session {s} ({}) has no reference poses", session.name);
        };
        let cuts: Vec<usize> = std::iter::once(0)
            .chain(session.kidnaps.iter().copied())
            .chain(std::iter::once(truth.len()))
            .collect();
        for (g, pair) in cuts.windows(2).enumerate() {
            let path: Vec<Vector2<f64>> = truth
                .get(pair[0]..pair[1])
                .unwrap_or_default()
                .iter()
                .map(Se2::translation)
                .collect();
            segments.push(SegmentJudgement {
                session: s,
                segment: g,
                scans: path.len(),
                travel_m: path.windows(2).map(|w| (w[1] - w[0]).norm()).sum(),
                revisit_travel_m: 0.0,
                revisits: false,
                first_revisit_scan: None,
                map: None,
                own_ate_m: None,
                in_map_ate_m: None,
                placed_off_m: None,
                merged_correctly: false,
            });
            paths.entry(frame_of(s)).or_default().push(path);
        }
    }
    let revisits: BTreeMap<usize, Vec<f64>> = paths
        .iter()
        .map(|(&frame, p)| (frame, mapmerge_eval::revisit_travel_m(p, REVISIT_RADIUS_M)))
        .collect();
    let mut next_in_frame = BTreeMap::<usize, usize>::new();
    for segment in &mut segments {
        let frame = frame_of(segment.session);
        let k = next_in_frame.entry(frame).or_default();
        segment.revisit_travel_m = revisits[&frame][*k];
        segment.revisits = segment.revisit_travel_m >= REVISIT_MIN_M;
        let earlier = &paths[&frame][..*k];
        let first_scan = sessions[segment.session]
            .kidnaps
            .get(segment.segment.wrapping_sub(1))
            .copied()
            .filter(|_| segment.segment > 0)
            .unwrap_or(0);
        segment.first_revisit_scan = paths[&frame][*k]
            .iter()
            .position(|p| {
                earlier
                    .iter()
                    .flatten()
                    .any(|q| (p - q).norm_squared() <= REVISIT_RADIUS_M * REVISIT_RADIUS_M)
            })
            .map(|i| first_scan + i);
        *k += 1;
    }
    let index_of: BTreeMap<[usize; 2], usize> = segments
        .iter()
        .enumerate()
        .map(|(i, s)| ([s.session, s.segment], i))
        .collect();
    let mut judgement = MapsJudgement::default();
    // Each segment's last scan's map.
    let mut last_scan: BTreeMap<usize, (usize, usize)> = BTreeMap::new();
    // Per map: parts by segment, with their placement.
    let mut placed_parts: Vec<BTreeMap<usize, f64>> = Vec::new();
    let mut seen = 0;
    for (m, (name, scans)) in placed.iter().enumerate() {
        seen += scans.len();
        // Parts: segment → (reference, estimate); groups by frame.
        let mut parts: BTreeMap<usize, (Vec<Se2>, Vec<Se2>)> = BTreeMap::new();
        for &(at, estimate) in scans {
            let i = index_of[&[at[0], segment_of(at)]];
            let part = parts.entry(i).or_default();
            part.0.push(reference(at)?);
            part.1.push(estimate);
            let last = last_scan.entry(i).or_insert((m, at[1]));
            if at[1] >= last.1 {
                *last = (m, at[1]);
            }
        }
        parts.retain(|_, (r, _)| r.len() >= MIN_SCANS);
        let mut offs = BTreeMap::new();
        let mut whole = (Vec::new(), Vec::new());
        let mut groups: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for &i in parts.keys() {
            groups
                .entry(frame_of(segments[i].session))
                .or_default()
                .push(i);
        }
        for members in groups.values() {
            let (reference, estimate): (Vec<Se2>, Vec<Se2>) = members
                .iter()
                .flat_map(|i| parts[i].0.iter().copied().zip(parts[i].1.iter().copied()))
                .unzip();
            let together = mapmerge_eval::absolute_trajectory_error(&reference, &estimate, true)?;
            for &i in members {
                let (r, e) = &parts[&i];
                let own = mapmerge_eval::absolute_trajectory_error(r, e, true)?.rms_m;
                let in_map = rms_under(&together.alignment, r, e);
                offs.insert(i, (own, in_map));
            }
            whole.0.extend(reference);
            whole.1.extend(estimate);
        }
        let whole_ate_m = (groups.len() == 1 && !whole.0.is_empty())
            .then(|| mapmerge_eval::absolute_trajectory_error(&whole.0, &whole.1, true))
            .transpose()?
            .map(|e| e.rms_m);
        let shared = parts.len() > 1;
        let mut placed_off = BTreeMap::new();
        for (&i, &(own, in_map)) in &offs {
            placed_off.insert(i, in_map - own);
            if shared && in_map - own > PLACED_WITHIN_M {
                judgement.misplaced += 1;
            }
        }
        judgement.maps.push(MapJudgement {
            map: name.clone(),
            segments: parts
                .keys()
                .map(|&i| [segments[i].session, segments[i].segment])
                .collect(),
            whole_ate_m,
            worst_placed_off_m: placed_off.values().copied().reduce(f64::max),
        });
        for (&i, &(own, in_map)) in &offs {
            if last_scan.get(&i).is_some_and(|&(lm, _)| lm == m) {
                segments[i].own_ate_m = Some(own);
                segments[i].in_map_ate_m = Some(in_map);
                segments[i].placed_off_m = Some(in_map - own);
            }
        }
        placed_parts.push(placed_off);
    }
    judgement.scans_in_no_map = segments.iter().map(|s| s.scans).sum::<usize>() - seen;
    for (&i, &(m, _)) in &last_scan {
        let segment = &segments[i];
        let parts = &placed_parts[m];
        let is_placed = |j: usize| parts.get(&j).is_some_and(|&off| off <= PLACED_WITHIN_M);
        let frame = frame_of(segment.session);
        let earlier_placed = parts
            .keys()
            .any(|&j| j < i && frame_of(segments[j].session) == frame && is_placed(j));
        let merged = is_placed(i) && earlier_placed;
        segments[i].map = Some(placed[m].0.clone());
        segments[i].merged_correctly = merged;
    }
    judgement.segments_revisiting = segments.iter().filter(|s| s.revisits).count();
    judgement.revisiting_merged_correctly = segments
        .iter()
        .filter(|s| s.revisits && s.merged_correctly)
        .count();
    judgement.segments = segments;
    Ok(judgement)
}

/// RMS position error (m) of `estimate` against `reference` under a given alignment.
fn rms_under(
    alignment: &mapmerge_eval::RigidTransform,
    reference: &[Se2],
    estimate: &[Se2],
) -> f64 {
    let sum: f64 = reference
        .iter()
        .zip(estimate)
        .map(|(r, e)| {
            let moved = alignment.apply(&Vector3::new(e.x_m, e.y_m, 0.0));
            (Vector2::new(r.x_m, r.y_m) - moved.xy()).norm_squared()
        })
        .sum();
    (sum / reference.len().max(1) as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapmerge_geometry::LieGroup;

    /// A robot driving a 10 m square twice, kidnapped at the start of the second lap.
    fn session() -> AtlasSession {
        let mut truth = Vec::new();
        for lap in 0..2 {
            for k in 0..40 {
                let (side, t) = (k / 10, (k % 10) as f64);
                let (x, y) = match side {
                    0 => (t, 0.0),
                    1 => (10.0, t),
                    2 => (10.0 - t, 10.0),
                    _ => (0.0, 10.0 - t),
                };
                truth.push(Se2::new(x + 0.01 * lap as f64, y, 0.0));
            }
        }
        AtlasSession {
            name: "square".into(),
            log: mapmerge_scan::LaserLog::default(),
            kidnaps: vec![40],
            reference: Some(truth),
        }
    }

    /// Both laps in one map, the second moved by `second_from_first` in it.
    fn one_map(session: &AtlasSession, second_from_first: Se2) -> Vec<PlacedMap> {
        let truth = session.reference.as_ref().unwrap();
        let map_from_world = Se2::new(3.0, -2.0, 0.7);
        let scans = truth
            .iter()
            .enumerate()
            .map(|(k, pose)| {
                let world = if k >= 40 {
                    second_from_first.compose(pose)
                } else {
                    *pose
                };
                ([0, k], map_from_world.compose(&world))
            })
            .collect();
        vec![("active".into(), scans)]
    }

    #[test]
    fn a_lap_placed_where_it_was_is_merged_and_one_placed_off_is_not() {
        let session = session();
        let judged = judge_placed(
            &one_map(&session, Se2::identity()),
            std::slice::from_ref(&session),
            Frames::PerSession,
        )
        .unwrap();
        assert_eq!(judged.segments_revisiting, 1);
        assert_eq!(judged.revisiting_merged_correctly, 1);
        assert_eq!(judged.misplaced, 0);
        assert_eq!(judged.segments[1].first_revisit_scan, Some(40));
        assert!(judged.maps[0].whole_ate_m.unwrap() < 1e-9);
        // The second lap 2 m off: both laps are misplaced in the map, nothing is merged.
        let judged = judge_placed(
            &one_map(&session, Se2::new(2.0, 0.0, 0.0)),
            std::slice::from_ref(&session),
            Frames::PerSession,
        )
        .unwrap();
        assert_eq!(judged.revisiting_merged_correctly, 0);
        assert_eq!(judged.misplaced, 2);
        assert!(judged.maps[0].worst_placed_off_m.unwrap() > PLACED_WITHIN_M);
        // Each lap in a map of its own: revisiting, not merged, nothing misplaced.
        let mut apart = one_map(&session, Se2::identity());
        let second = apart[0].1.split_off(40);
        apart.push(("inactive-0".into(), second));
        let judged =
            judge_placed(&apart, std::slice::from_ref(&session), Frames::PerSession).unwrap();
        assert_eq!(judged.revisiting_merged_correctly, 0);
        assert_eq!(judged.misplaced, 0);
        assert_eq!(judged.segments[1].map.as_deref(), Some("inactive-0"));
    }
}

//! A session as the map manager keeps it: the log, its split at door passings and each area
//! span's SLAM result. The lifelong store holds these, so a later run can add sessions to a
//! site's areas and rebuild its hybrid map.

use mapmerge_geometry::Se2;
use mapmerge_posegraph::PoseGraph2;
use mapmerge_scan::{LaserLog, LaserScan};
use serde::{Deserialize, Serialize};

use crate::environment::Preset;
use crate::error::AreasError;
use crate::manager::{
    manage_sessions, segment, ManagedMap, ManagerParams, Segmentation, SessionInput,
};
use mapmerge_place::GeometricVerifier;

/// Maps one span: its scans (a log of their own) with its environment's preset in, each
/// scan's `map_from_robot` and the span's pose graph out. The caller brings the SLAM
/// pipeline (the app layer's `run_slam`), so this crate stays below it.
pub type MapSpan<'a> = dyn FnMut(&LaserLog, &Preset) -> Result<(Vec<Se2>, PoseGraph2), String> + 'a;

/// Splits `log` at its door passings (its scans' odometry poses) and maps each span with
/// `map_span`: one session as the manager keeps it.
pub fn map_session(
    name: String,
    log: LaserLog,
    params: &ManagerParams,
    map_span: &mut MapSpan<'_>,
) -> Result<MappedSession, AreasError> {
    let mut poses = Vec::with_capacity(log.scans.len());
    for (k, record) in log.scans.iter().enumerate() {
        let pose = record
            .odom_from_robot
            .ok_or_else(|| AreasError::Mapping(format!("{name}: scan {k} has no odometry pose")))?;
        poses.push(pose);
    }
    let segmentation = segment(
        poses.iter().copied().zip(log.scans.iter().map(|r| &r.scan)),
        params,
    )?;
    let (mut trajectories, mut graphs) = (Vec::new(), Vec::new());
    for (k, span) in segmentation.spans.iter().enumerate() {
        let part = LaserLog {
            scans: log.scans.get(span.scans.clone()).unwrap_or(&[]).to_vec(),
            params: log.params.clone(),
            ..LaserLog::default()
        };
        let preset = span.environment.preset()?;
        let (trajectory, graph) = map_span(&part, &preset)
            .map_err(|e| AreasError::Mapping(format!("{name} span {k}: {e}")))?;
        trajectories.push(trajectory);
        graphs.push(graph);
    }
    Ok(MappedSession {
        name,
        log,
        segmentation,
        trajectories,
        graphs,
    })
}

/// One session, mapped area by area.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MappedSession {
    /// Its name (the log's path, or the simulated session).
    pub name: String,
    /// The log.
    pub log: LaserLog,
    /// The log split at its door passings.
    pub segmentation: Segmentation,
    /// Each span's trajectory (`map_from_robot` of each of its scans, in its own frame).
    pub trajectories: Vec<Vec<Se2>>,
    /// Each span's pose graph, in the same frame.
    pub graphs: Vec<PoseGraph2>,
}

impl MappedSession {
    /// The log's scans, in order.
    pub fn scans(&self) -> Vec<&LaserScan> {
        self.log.scans.iter().map(|record| &record.scan).collect()
    }

    /// `Err` with the reason when its parts do not fit each other: one trajectory and one
    /// graph per span, one pose per scan of the span, spans within the log.
    pub fn validate(&self) -> Result<(), String> {
        let spans = &self.segmentation.spans;
        if self.trajectories.len() != spans.len() || self.graphs.len() != spans.len() {
            return Err(format!(
                "session {:?}: {} spans, {} trajectories, {} graphs",
                self.name,
                spans.len(),
                self.trajectories.len(),
                self.graphs.len()
            ));
        }
        for (k, (span, trajectory)) in spans.iter().zip(&self.trajectories).enumerate() {
            if span.scans.end > self.log.scans.len() || trajectory.len() != span.scans.len() {
                return Err(format!(
                    "session {:?} span {k}: scans {:?} of {}, {} poses",
                    self.name,
                    span.scans,
                    self.log.scans.len(),
                    trajectory.len()
                ));
            }
        }
        Ok(())
    }
}

/// [`manage_sessions`] over mapped sessions.
pub fn manage_mapped(
    sessions: &[MappedSession],
    params: &ManagerParams,
    verifier: &dyn GeometricVerifier,
) -> Result<ManagedMap, AreasError> {
    let scans: Vec<Vec<&LaserScan>> = sessions.iter().map(MappedSession::scans).collect();
    let inputs: Vec<SessionInput<'_>> = sessions
        .iter()
        .zip(&scans)
        .map(|(session, scans)| SessionInput {
            segmentation: &session.segmentation,
            trajectories: &session.trajectories,
            scans,
        })
        .collect();
    manage_sessions(&inputs, params, verifier)
}

impl ManagedMap {
    /// `Err` with the reason when this map was not built from `sessions`: one placement per
    /// session, one area, session and frame per span, one crossing and link per boundary,
    /// areas and link points that exist.
    pub fn validate_against(&self, sessions: &[MappedSession]) -> Result<(), String> {
        for session in sessions {
            session.validate()?;
        }
        let spans: usize = sessions.iter().map(|s| s.segmentation.spans.len()).sum();
        let boundaries: usize = sessions
            .iter()
            .map(|s| s.segmentation.boundaries.len())
            .sum();
        let counts = [
            ("placements", self.session_placed.len(), sessions.len()),
            ("span areas", self.span_area.len(), spans),
            ("span sessions", self.span_session.len(), spans),
            ("span frames", self.first_from_span.len(), spans),
            ("crossings", self.crossings.len(), boundaries),
            ("boundary links", self.boundary_link.len(), boundaries),
        ];
        for (what, found, expected) in counts {
            if found != expected {
                return Err(format!("{found} {what} for {expected}"));
            }
        }
        let areas = self.hybrid.areas.len();
        if let Some(a) = self.span_area.iter().find(|a| **a >= areas) {
            return Err(format!("a span in area {a} of {areas}"));
        }
        if let Some(s) = self.span_session.iter().find(|s| **s >= sessions.len()) {
            return Err(format!("a span of session {s} of {}", sessions.len()));
        }
        let links = self.hybrid.link_points.len();
        if let Some(l) = self.boundary_link.iter().flatten().find(|l| **l >= links) {
            return Err(format!("a boundary at link point {l} of {links}"));
        }
        Ok(())
    }
}

//! A session as the map manager keeps it: the log, its split at door passings and each area
//! span's SLAM result. The lifelong store holds these (issue 17's store), so a later run can
//! add sessions to a site's areas and rebuild its hybrid map.

use mapmerge_geometry::Se2;
use mapmerge_posegraph::PoseGraph2;
use mapmerge_scan::{LaserLog, LaserScan};
use serde::{Deserialize, Serialize};

use crate::error::AreasError;
use crate::manager::{manage_sessions, ManagedMap, ManagerParams, Segmentation, SessionInput};
use mapmerge_place::GeometricVerifier;

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

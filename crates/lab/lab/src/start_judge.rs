//! Sessions that start localized (issue 65, part 3), judged against the truth of a run whose
//! sessions share one frame (the simulator's): a later session *starts covered* when its
//! first true pose lies within [`REVISIT_RADIUS_M`] of an earlier session's true path, and
//! *starts localized* when the epoch its restart began holds a merge decision (conditional
//! or full) within [`START_LOCALIZED_WITHIN_M`] of its start: correctly or wrongly, as the
//! merge's edges agree with the truth (`correct` of [`crate::atlas_judge::judge_atlas`]).

use mapmerge_atlas::AtlasEvent;
use mapmerge_engine::EngineEvent;
use mapmerge_jobs::{AtlasSession, MergeReport};
use serde::Serialize;

use crate::atlas_judge::REVISIT_RADIUS_M;

/// A session starts localized with a merge decision within this much travel (m) of its
/// start.
pub const START_LOCALIZED_WITHIN_M: f64 = 2.0;

/// How later sessions started, over one run or many.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct StartJudgement {
    /// Sessions after the first.
    pub sessions: usize,
    /// Of those, the ones starting where an earlier session's true path passed.
    pub covered: usize,
    /// Of the covered ones, started localized correctly, and (covered or not) wrongly.
    pub localized: usize,
    pub wrongly: usize,
    /// Travel (m) from each covered session's start to its first correct merge decision.
    pub to_localized_m: Vec<f64>,
}

impl StartJudgement {
    /// Adds another run's counts.
    pub fn add(&mut self, other: &Self) {
        self.sessions += other.sessions;
        self.covered += other.covered;
        self.localized += other.localized;
        self.wrongly += other.wrongly;
        self.to_localized_m.extend(&other.to_localized_m);
    }
}

/// Judges how each session after the first started: `events` and `merges` (their
/// `correct` set by the atlas judge) of one run over `sessions`, which share one frame.
pub fn judge_starts(
    events: &[EngineEvent],
    merges: &[MergeReport],
    sessions: &[AtlasSession],
) -> StartJudgement {
    let mut judgement = StartJudgement::default();
    let mut start = 0;
    let mut earlier: Vec<mapmerge_geometry::Point2> = Vec::new();
    for session in sessions {
        let reference = session.reference.as_deref().unwrap_or_default();
        if start > 0 {
            judgement.sessions += 1;
            let covered = reference.first().is_some_and(|first| {
                earlier
                    .iter()
                    .any(|p| (p - first.translation()).norm() <= REVISIT_RADIUS_M)
            });
            // The epoch the session's restart began, and the travel then.
            let began = events.iter().find_map(|e| match e.atlas() {
                Some(AtlasEvent::EpochStarted { epoch }) if e.scan == start => {
                    Some((epoch.0, e.travel_m))
                }
                _ => None,
            });
            if let Some((epoch, travel_m)) = began {
                let decisions: Vec<(f64, Option<bool>)> = merges
                    .iter()
                    .filter(|m| m.epoch == epoch)
                    .map(|m| (m.travel_m - travel_m, m.correct))
                    .collect();
                let early = |correct: bool| {
                    decisions
                        .iter()
                        .any(|(d, c)| *d <= START_LOCALIZED_WITHIN_M && *c == Some(correct))
                };
                judgement.wrongly += usize::from(early(false));
                if covered {
                    judgement.covered += 1;
                    judgement.localized += usize::from(early(true));
                    if let Some(d) = decisions
                        .iter()
                        .filter(|(_, c)| *c == Some(true))
                        .map(|(d, _)| *d)
                        .min_by(f64::total_cmp)
                    {
                        judgement.to_localized_m.push(d.max(0.0));
                    }
                }
            }
        }
        earlier.extend(reference.iter().map(|p| p.translation()));
        start += session.log.scans.len();
    }
    judgement
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapmerge_engine::EngineParams;
    use mapmerge_jobs::{AtlasJob, AtlasOptions};

    /// How the later sessions of simulated `world` (3 sessions of 120 s, `seed`) start with
    /// `decisions.start_unique` set as given.
    fn starts(world: &str, seed: u64, start_unique: bool) -> anyhow::Result<StartJudgement> {
        let sessions = crate::atlas_judge::simulated_sessions(world, 3, 120.0, seed, None)?;
        let mut params = EngineParams::default();
        params.decisions.start_unique = start_unique;
        let output = std::env::temp_dir().join(format!(
            "mapmerge-starts-{}-{world}-{seed}-{start_unique}",
            std::process::id()
        ));
        let job = AtlasJob::open(AtlasOptions {
            params,
            output: output.clone(),
            pictures: false,
            store: None,
            keep_versions: 1,
            announce_kidnaps: true,
        })
        .map_err(crate::job_error)?;
        let mut done = job.run(&sessions, |_| {}).map_err(crate::job_error)?;
        crate::atlas_judge::judge_atlas(&mut done, &sessions);
        let judged = judge_starts(done.engine.events(), &done.report.merges, &sessions);
        std::fs::remove_dir_all(&output)?;
        Ok(judged)
    }

    /// Tuning seed 8 of the warehouse: a session starts between rack rows an aisle apart.
    /// The start search takes them for one another unless its match must fit nowhere else.
    #[test]
    fn a_session_starting_in_a_periodic_aisle_is_not_placed_in_its_twin() -> anyhow::Result<()> {
        assert_eq!(starts("warehouse", 8, false)?.wrongly, 1);
        assert_eq!(starts("warehouse", 8, true)?.wrongly, 0);
        Ok(())
    }
}

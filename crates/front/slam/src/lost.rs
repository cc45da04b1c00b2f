//! The tracking-failure detector: Colosi et al. 2019's SLAM state machine ("Better lost in
//! transition than lost in space", IROS 2019) reduced to the local tracker's three states.
//!
//! - **Tracking**: each scan matches the submap near where the odometry predicts it.
//! - **Relocalizing**: a reading is off: the match failed or jumped far from the prediction
//!   *and* the scan contradicts the submap (its rays cross the submap's walls; a scan of new
//!   ground fails to match yet contradicts nothing), or the first scan after a gap in the
//!   stamps does not match where the odometry says (the robot may have been carried). The
//!   tracker makes no keyframe and inserts nothing into its submaps, so the scans in doubt
//!   are matched against the map as it was; a run of clean matches brings it back.
//! - **Lost**: the scans in doubt kept being off, or stayed unresolved, or one match jumped
//!   so far that no odometry explains it. The tracker reports it; the engine ends the epoch
//!   (`tracking_lost`) and feeds the scans in doubt to the new one (Holoch et al., Sec. III).
//!
//! A kidnapped robot's first scans no longer fit its map, yet once they are inserted the next
//! scans fit *them*: holding the map still while in doubt is what lets the failure persist.

use mapmerge_params::{Checker, Real, Validate};
use serde::{Deserialize, Serialize};

use crate::tracker::TrackingReading;

/// The detector's bounds (one default for every log).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LostParams {
    /// A match this many standard deviations of the odometry prior away from the prediction
    /// is off (default: 10).
    pub jump_sigma: f64,
    /// A match this far away is lost at once, whatever the scan contradicts (default: 20):
    /// no wheel odometry drifts that much between two scans.
    pub lost_jump_sigma: f64,
    /// Where the odometry window finds no match, the tracker searches this window around
    /// the prediction (m, rad; default: 2 m, 30°; null: never) …
    pub relocalize_window: Option<(f64, f64)>,
    /// … and keeps a match scoring at least this (default: 0.6, what tracking scores). Such a
    /// match is a slip within `lost_jump_sigma` of the prediction; beyond, the tracker is lost.
    pub relocalize_min_score: f64,
    /// A failed or jumped match is off only when at least this share of the submap's points
    /// near the robot lie where the scan saw through (default: 0.03): a scan of new ground
    /// fails to match yet contradicts nothing, a kidnapped robot's scan crosses the map's
    /// walls.
    pub seen_through_min: f64,
    /// A gap between two scans' stamps longer than this (s) puts the tracker in doubt
    /// (default: 10; null: stamps are not read).
    pub doubt_gap_s: Option<f64>,
    /// Off readings while relocalizing that make the tracker lost (default: 3) …
    pub off_to_lose: usize,
    /// … unless this many good ones in a row come first (default: 2): matches within this
    /// many standard deviations of the prediction (default: 3), as clean as tracking.
    pub good_to_recover: usize,
    pub recover_sigma: f64,
    /// Scans in doubt after which the tracker is lost if any of them was off, and tracking
    /// again if none was (default: 5).
    pub max_doubt_scans: usize,
    /// Matched scans after a (re)start before any reading counts (default: 5): a new map is
    /// too small to be judged against.
    pub warm_up_scans: usize,
}

impl Default for LostParams {
    fn default() -> Self {
        Self {
            jump_sigma: 10.0,
            lost_jump_sigma: 20.0,
            seen_through_min: 0.03,
            relocalize_window: Some((2.0, 30f64.to_radians())),
            relocalize_min_score: 0.6,
            doubt_gap_s: Some(10.0),
            off_to_lose: 3,
            good_to_recover: 2,
            recover_sigma: 3.0,
            max_doubt_scans: 5,
            warm_up_scans: 5,
        }
    }
}

impl Validate for LostParams {
    fn check(&self, check: &mut Checker) {
        check
            .real("jump_sigma", self.jump_sigma, Real::positive_up_to(1e6))
            .real(
                "recover_sigma",
                self.recover_sigma,
                Real::positive_up_to(self.jump_sigma),
            )
            .real(
                "lost_jump_sigma",
                self.lost_jump_sigma,
                Real::within(self.jump_sigma, 1e6),
            )
            .real("seen_through_min", self.seen_through_min, Real::fraction());
        if let Some((linear_m, angular_rad)) = self.relocalize_window {
            check.reals(
                "relocalize_window",
                &[
                    (linear_m, Real::positive_up_to(20.0)),
                    (angular_rad, Real::positive_up_to(std::f64::consts::PI)),
                ],
            );
        }
        check
            .real(
                "relocalize_min_score",
                self.relocalize_min_score,
                Real::fraction(),
            )
            .real_opt("doubt_gap_s", self.doubt_gap_s, Real::positive())
            .size("off_to_lose", self.off_to_lose, 1, 100_000)
            .size("good_to_recover", self.good_to_recover, 1, 100_000)
            .size("max_doubt_scans", self.max_doubt_scans, 1, 100_000)
            .size("warm_up_scans", self.warm_up_scans, 0, 100_000);
    }
}

/// Colosi et al.'s states, as the tracker is after a scan.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrackingState {
    /// Scans match the map near the prediction.
    #[default]
    Tracking,
    /// Readings are off: scans are held in doubt against the map as it was.
    Relocalizing,
    /// The tracker lost track; the scans in doubt belong to a new epoch.
    Lost,
}

/// What made a scan's reading off.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OffReading {
    /// The scan did not match the submap.
    NoMatch,
    /// The match jumped from the prediction beyond `jump_sigma`.
    Jump,
    /// The stamps have a gap beyond `doubt_gap_s`.
    StampGap,
}

/// One scan as the detector read it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReadScan {
    /// The tracker's reading.
    #[serde(flatten)]
    pub reading: TrackingReading,
    /// The gap to the previous scan's stamp (s), when both have one.
    pub stamp_gap_s: Option<f64>,
    /// Why it was off, if it was.
    pub off: Option<OffReading>,
}

/// Why the tracker lost track, with the readings of the scans in doubt (oldest first; the
/// last is the scan that decided).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LostReport {
    /// Which bound was crossed.
    pub cause: LostCause,
    /// The scans in doubt: they go into the new epoch.
    pub in_doubt: Vec<ReadScan>,
}

/// See [`LostReport::cause`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LostCause {
    /// One match jumped beyond `lost_jump_sigma`.
    Jump,
    /// `off_to_lose` off readings while relocalizing.
    OffReadings,
    /// `max_doubt_scans` in doubt, some off, and no run of good matches.
    Unresolved,
}

/// What the detector made of one scan.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Verdict {
    /// Why the scan was off, if it was (always `None` while warming up).
    pub off: Option<OffReading>,
    /// When the scan made the tracker lost: why, and the scans in doubt.
    pub lost: Option<LostReport>,
}

/// The state machine; one per epoch (a new tracker starts a new one).
#[derive(Clone, Debug)]
pub struct LostDetector {
    params: LostParams,
    state: TrackingState,
    matched: usize,
    previous_stamp_s: Option<f64>,
    in_doubt: Vec<ReadScan>,
    off_in_doubt: usize,
    good_in_a_row: usize,
    /// The doubt began with a gap in the stamps.
    after_gap: bool,
}

impl LostDetector {
    /// A detector in state tracking, warming up.
    pub fn new(params: LostParams) -> Self {
        Self {
            params,
            state: TrackingState::Tracking,
            matched: 0,
            previous_stamp_s: None,
            in_doubt: Vec::new(),
            off_in_doubt: 0,
            good_in_a_row: 0,
            after_gap: false,
        }
    }

    /// The state after the last scan.
    pub fn state(&self) -> TrackingState {
        self.state
    }

    /// Reads the next scan: its reading and stamp. The verdict holds the report when this
    /// scan made the tracker lost; the detector then starts over (warming up).
    pub fn observe(&mut self, reading: &TrackingReading, stamp_s: Option<f64>) -> Verdict {
        if self.state == TrackingState::Lost {
            self.state = TrackingState::Tracking;
        }
        let stamp_gap_s = match (self.previous_stamp_s, stamp_s) {
            (Some(previous), Some(now)) if now.is_finite() => Some(now - previous),
            _ => None,
        };
        if let Some(now) = stamp_s.filter(|s| s.is_finite()) {
            self.previous_stamp_s = Some(now);
        }
        let warm = self.matched >= self.params.warm_up_scans;
        self.matched += usize::from(reading.score.is_some());
        if !warm {
            return Verdict::default();
        }
        let jump = reading.correction_sigma.unwrap_or(0.0);
        let gap = stamp_gap_s
            .zip(self.params.doubt_gap_s)
            .is_some_and(|(gap, bound)| gap > bound);
        // A good match: within `recover_sigma` of the prediction, as clean as tracking; or
        // found by the wider search (a slip) within `lost_jump_sigma`.
        let good = reading.score.is_some()
            && (jump <= self.params.recover_sigma
                || (reading.relocalized && jump <= self.params.lost_jump_sigma));
        // The first scan after a gap in the stamps must find the robot where the odometry
        // says; if it does not, the robot may have been carried, and from then on new ground
        // excuses nothing.
        self.after_gap |= gap && !good;
        // A failed or jumped match counts where the scan contradicts the map, or after such
        // a gap.
        let counts = self.after_gap
            || reading
                .seen_through
                .is_some_and(|share| share >= self.params.seen_through_min);
        let off = if reading.score.is_none() && counts {
            Some(OffReading::NoMatch)
        } else if jump > self.params.jump_sigma && !reading.relocalized && counts {
            Some(OffReading::Jump)
        } else if gap && !good {
            Some(OffReading::StampGap)
        } else {
            None
        };
        let verdict = |lost| Verdict { off, lost };
        let read = ReadScan {
            reading: *reading,
            stamp_gap_s,
            off,
        };
        if jump > self.params.lost_jump_sigma {
            self.in_doubt.push(read);
            return verdict(Some(self.lose(LostCause::Jump)));
        }
        if self.state == TrackingState::Tracking && off.is_none() {
            self.after_gap = false;
            return verdict(None);
        }
        self.state = TrackingState::Relocalizing;
        self.in_doubt.push(read);
        match off {
            Some(off) => {
                // A gap alone is doubt, not evidence against the map.
                self.off_in_doubt += usize::from(off != OffReading::StampGap);
                self.good_in_a_row = 0;
            }
            // A good match counts towards recovery; a failed one that contradicts nothing
            // (new ground the held map does not cover) does not.
            None if good => self.good_in_a_row += 1,
            None => self.good_in_a_row = 0,
        }
        if self.off_in_doubt >= self.params.off_to_lose {
            return verdict(Some(self.lose(LostCause::OffReadings)));
        }
        if self.good_in_a_row >= self.params.good_to_recover {
            self.recover();
        } else if self.in_doubt.len() >= self.params.max_doubt_scans {
            if self.off_in_doubt > 0 {
                return verdict(Some(self.lose(LostCause::Unresolved)));
            }
            // Only a stamp gap, and nothing contradicted the map since.
            self.recover();
        }
        verdict(None)
    }

    fn recover(&mut self) {
        self.state = TrackingState::Tracking;
        self.after_gap = false;
        self.in_doubt.clear();
        self.off_in_doubt = 0;
        self.good_in_a_row = 0;
    }

    fn lose(&mut self, cause: LostCause) -> LostReport {
        let report = LostReport {
            cause,
            in_doubt: std::mem::take(&mut self.in_doubt),
        };
        *self = Self::new(self.params.clone());
        self.state = TrackingState::Lost;
        report
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn good() -> TrackingReading {
        TrackingReading {
            score: Some(0.8),
            inlier_fraction: Some(0.9),
            correction_sigma: Some(1.0),
            seen_through: None,
            relocalized: false,
        }
    }

    /// A failed match whose scan crosses the map's walls.
    fn failed() -> TrackingReading {
        TrackingReading {
            seen_through: Some(0.2),
            ..TrackingReading::default()
        }
    }

    /// A failed match on new ground: the scan contradicts nothing.
    fn new_ground() -> TrackingReading {
        TrackingReading {
            seen_through: Some(0.0),
            ..TrackingReading::default()
        }
    }

    fn jumped(sigma: f64) -> TrackingReading {
        TrackingReading {
            correction_sigma: Some(sigma),
            seen_through: Some(0.2),
            ..good()
        }
    }

    fn warm() -> LostDetector {
        let mut detector = LostDetector::new(LostParams::default());
        for k in 0..5 {
            assert!(detector.observe(&good(), Some(k as f64)).lost.is_none());
        }
        detector
    }

    #[test]
    fn a_glitch_is_doubt_and_good_matches_bring_tracking_back() {
        let mut detector = warm();
        let verdict = detector.observe(&failed(), Some(5.0));
        assert_eq!(verdict.off, Some(OffReading::NoMatch));
        assert!(detector.observe(&failed(), Some(6.0)).lost.is_none());
        assert_eq!(detector.state(), TrackingState::Relocalizing);
        assert!(detector.observe(&good(), Some(7.0)).lost.is_none());
        assert_eq!(detector.state(), TrackingState::Relocalizing);
        assert!(detector.observe(&good(), Some(8.0)).lost.is_none());
        assert_eq!(detector.state(), TrackingState::Tracking);
        // The count starts over: two more failures are doubt again, not lost.
        assert!(detector.observe(&failed(), Some(9.0)).lost.is_none());
        assert!(detector.observe(&failed(), Some(10.0)).lost.is_none());
        assert_eq!(detector.state(), TrackingState::Relocalizing);
    }

    #[test]
    fn new_ground_is_no_evidence_and_no_recovery() {
        let mut detector = warm();
        // Failing on new ground while tracking: nothing happens.
        let verdict = detector.observe(&new_ground(), Some(5.0));
        assert_eq!(verdict.off, None);
        assert_eq!(detector.state(), TrackingState::Tracking);
        // In doubt it neither counts against the map nor brings tracking back: after
        // `max_doubt_scans` the one off reading decides.
        assert!(detector.observe(&failed(), Some(6.0)).lost.is_none());
        for k in 0..3 {
            assert!(detector
                .observe(&new_ground(), Some(7.0 + k as f64))
                .lost
                .is_none());
        }
        let report = detector
            .observe(&new_ground(), Some(10.0))
            .lost
            .expect("lost");
        assert_eq!(report.cause, LostCause::Unresolved);
        assert_eq!(report.in_doubt.len(), 5);
    }

    #[test]
    fn failures_in_doubt_lose_track_with_every_scan_in_doubt() {
        let mut detector = warm();
        assert!(detector.observe(&failed(), Some(5.0)).lost.is_none());
        assert!(detector.observe(&good(), Some(6.0)).lost.is_none());
        assert!(detector.observe(&jumped(12.0), Some(7.0)).lost.is_none());
        let report = detector.observe(&failed(), Some(8.0)).lost.expect("lost");
        assert_eq!(report.cause, LostCause::OffReadings);
        let offs: Vec<_> = report.in_doubt.iter().map(|r| r.off).collect();
        assert_eq!(
            offs,
            [
                Some(OffReading::NoMatch),
                None,
                Some(OffReading::Jump),
                Some(OffReading::NoMatch)
            ]
        );
        assert_eq!(detector.state(), TrackingState::Lost);
        // It starts over warming up: failures of a new map's first scans do not count.
        for k in 0..5 {
            assert!(detector
                .observe(&failed(), Some(9.0 + k as f64))
                .lost
                .is_none());
        }
        assert_eq!(detector.state(), TrackingState::Tracking);
    }

    #[test]
    fn a_slip_found_by_the_wider_search_is_good_and_a_far_one_is_lost() {
        let relocalized = TrackingReading {
            correction_sigma: Some(12.0),
            relocalized: true,
            ..good()
        };
        let mut detector = warm();
        let verdict = detector.observe(&relocalized, Some(5.0));
        assert_eq!((verdict.off, verdict.lost), (None, None));
        // In doubt it counts towards recovery.
        assert!(detector.observe(&failed(), Some(6.0)).lost.is_none());
        assert!(detector.observe(&relocalized, Some(7.0)).lost.is_none());
        assert!(detector.observe(&relocalized, Some(8.0)).lost.is_none());
        assert_eq!(detector.state(), TrackingState::Tracking);
        // Beyond `lost_jump_sigma` no slip explains it.
        let far = TrackingReading {
            correction_sigma: Some(40.0),
            ..relocalized
        };
        let report = detector.observe(&far, Some(9.0)).lost.expect("lost");
        assert_eq!(report.cause, LostCause::Jump);
    }

    #[test]
    fn a_jump_no_odometry_explains_is_lost_at_once() {
        let mut detector = warm();
        let report = detector
            .observe(&jumped(25.0), Some(5.0))
            .lost
            .expect("lost");
        assert_eq!(report.cause, LostCause::Jump);
        assert_eq!(report.in_doubt.len(), 1);
        assert_eq!(report.in_doubt[0].off, Some(OffReading::Jump));
        // Even where the scan contradicts nothing …
        let mut detector = warm();
        let quiet = |sigma| TrackingReading {
            seen_through: Some(0.0),
            ..jumped(sigma)
        };
        assert!(detector.observe(&quiet(25.0), Some(5.0)).lost.is_some());
        // … while a smaller jump there is not even off.
        let mut detector = warm();
        let verdict = detector.observe(&quiet(15.0), Some(5.0));
        assert_eq!((verdict.off, verdict.lost), (None, None));
    }

    #[test]
    fn after_a_stamp_gap_the_first_scan_must_match_where_odometry_says() {
        // A good match after the gap: no doubt at all.
        let mut detector = warm();
        assert_eq!(detector.observe(&good(), Some(100.0)).off, None);
        assert_eq!(detector.state(), TrackingState::Tracking);
        // A failed one: doubt, and from then on failures count even on new ground.
        let mut detector = warm();
        let verdict = detector.observe(&new_ground(), Some(100.0));
        assert_eq!(verdict.off, Some(OffReading::NoMatch));
        assert_eq!(detector.in_doubt[0].stamp_gap_s, Some(96.0));
        assert!(detector.observe(&new_ground(), Some(101.0)).lost.is_none());
        let report = detector
            .observe(&new_ground(), Some(102.0))
            .lost
            .expect("lost");
        assert_eq!(report.cause, LostCause::OffReadings);
        // A moderate jump after a gap opens doubt without counting; good matches end it.
        let mut detector = warm();
        let verdict = detector.observe(&jumped(5.0), Some(100.0));
        assert_eq!(verdict.off, Some(OffReading::StampGap));
        assert!(detector.observe(&good(), Some(101.0)).lost.is_none());
        assert!(detector.observe(&good(), Some(102.0)).lost.is_none());
        assert_eq!(detector.state(), TrackingState::Tracking);
        // Without stamps nothing is read from them.
        let mut detector = LostDetector::new(LostParams::default());
        for _ in 0..10 {
            assert!(detector.observe(&good(), None).lost.is_none());
        }
        assert_eq!(detector.state(), TrackingState::Tracking);
    }

    #[test]
    fn bounds_out_of_range_are_named() {
        let bad = |f: fn(&mut LostParams)| {
            let mut p = LostParams::default();
            f(&mut p);
            p.validate().err().map(|e| e.field)
        };
        assert_eq!(
            bad(|p| p.jump_sigma = f64::NAN),
            Some("jump_sigma".to_owned())
        );
        assert_eq!(
            bad(|p| p.recover_sigma = 11.0),
            Some("recover_sigma".to_owned())
        );
        assert_eq!(
            bad(|p| p.lost_jump_sigma = 5.0),
            Some("lost_jump_sigma".to_owned())
        );
        assert_eq!(
            bad(|p| p.seen_through_min = 1.5),
            Some("seen_through_min".to_owned())
        );
        assert_eq!(
            bad(|p| p.relocalize_window = Some((0.0, 0.5))),
            Some("relocalize_window[0]".to_owned())
        );
        assert_eq!(
            bad(|p| p.relocalize_min_score = 2.0),
            Some("relocalize_min_score".to_owned())
        );
        assert_eq!(
            bad(|p| p.doubt_gap_s = Some(-1.0)),
            Some("doubt_gap_s".to_owned())
        );
        assert_eq!(bad(|p| p.off_to_lose = 0), Some("off_to_lose".to_owned()));
        assert_eq!(
            bad(|p| p.good_to_recover = 0),
            Some("good_to_recover".to_owned())
        );
        assert_eq!(
            bad(|p| p.max_doubt_scans = 0),
            Some("max_doubt_scans".to_owned())
        );
        assert_eq!(bad(|_| {}), None);
    }
}

//! The wall distances of criterion (3) and the choice of the next map's configuration
//! (Ehlers et al., Sec. II-B): the scan is averaged over neighbouring beams (low-pass),
//! transformed to the map frame, and its bounding box (min/max x and y) is low-pass filtered
//! over time. Quick changes of the box mark a change of room; three of its four sides farther
//! than 15 m from the robot mark a large environment.

use std::collections::VecDeque;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_params::{Checker, Real, Validate};
use mapmerge_scan::{LaserScan, Point2};
use mapmerge_slam::TrackerParams;
use serde::{Deserialize, Serialize};

use crate::error::AreasError;

/// Parameters of [`Extents`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EnvironmentParams {
    /// Beams averaged around each beam (the spatial low-pass) (default: 5).
    pub smoothing_beams: usize,
    /// Beams without a return count as this far, and no range counts as farther (m)
    /// (default: 30).
    pub far_m: f64,
    /// The box's sides are these quantiles of the points' x and y, not their extremes, so
    /// that a few beams escaping through a gap do not move it (default: 0.05, the 5th and
    /// 95th percentiles; 0 gives min and max).
    pub quantile: f64,
    /// Weight of the newest box in the temporal low-pass, per scan (default: 0.3).
    pub low_pass: f64,
    /// Criterion (3) compares the filtered box this much travel before a crossing with the
    /// box this much after it (m) (default: 0.5, chosen on the simulator's tuning seeds
    /// 1–20 over 1: recall 0.93 against 0.90 at the same precision)…
    pub change_travel_m: f64,
    /// … and holds when a side moved by at least this (m) (default: 1.5).
    pub change_m: f64,
    /// A side at least this far from the robot counts as far (m) (default: 15, the paper's).
    pub large_extent_m: f64,
    /// With at least this many far sides the environment is large (default: 3, the
    /// paper's "three of the four").
    pub large_sides: usize,
}

impl Default for EnvironmentParams {
    fn default() -> Self {
        Self {
            smoothing_beams: 5,
            far_m: 30.0,
            quantile: 0.05,
            low_pass: 0.3,
            change_travel_m: 0.5,
            change_m: 1.5,
            large_extent_m: 15.0,
            large_sides: 3,
        }
    }
}

impl Validate for EnvironmentParams {
    fn check(&self, check: &mut Checker) {
        check
            .size("smoothing_beams", self.smoothing_beams, 1, 10_000)
            .real("far_m", self.far_m, Real::positive())
            .real("quantile", self.quantile, Real::within(0.0, 0.5))
            .rule(
                "quantile",
                self.quantile,
                self.quantile < 0.5,
                "must be in [0, 0.5)",
            )
            .real("low_pass", self.low_pass, Real::positive_up_to(1.0))
            .real("change_travel_m", self.change_travel_m, Real::positive())
            .real("change_m", self.change_m, Real::positive())
            .real("large_extent_m", self.large_extent_m, Real::positive())
            .size("large_sides", self.large_sides, 1, 4);
    }
}

impl EnvironmentParams {
    /// Checks every parameter ([`Validate`]).
    pub fn validate(&self) -> Result<(), AreasError> {
        Ok(Validate::validate(self)?)
    }
}

/// The kind of environment a map is built in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Environment {
    /// Rooms and corridors: short ranges.
    Indoor,
    /// Halls and outdoors: long ranges.
    Large,
}

impl Environment {
    /// The preset's name.
    pub fn name(self) -> &'static str {
        match self {
            Environment::Indoor => "indoor",
            Environment::Large => "large",
        }
    }

    /// The front-end configuration shipped for it ([`Preset`]).
    pub fn preset(self) -> Result<Preset, AreasError> {
        let text = match self {
            Environment::Indoor => include_str!("../presets/indoor.json"),
            Environment::Large => include_str!("../presets/large.json"),
        };
        Preset::parse(self.name(), text)
    }
}

/// A SLAM configuration for one kind of environment: a parameter file of the front-end
/// (`presets/*.json`; fields left out keep the tracker's defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Preset {
    /// Its name.
    pub name: String,
    /// The tracker's parameters.
    pub tracker: TrackerParams,
}

impl Validate for Preset {
    fn check(&self, check: &mut Checker) {
        check.nested("tracker", &self.tracker);
    }
}

impl Preset {
    /// A preset from the text of its parameter file.
    pub fn parse(name: &str, text: &str) -> Result<Self, AreasError> {
        let tracker = serde_json::from_str(text).map_err(|e| AreasError::Preset {
            name: name.to_owned(),
            reason: e.to_string(),
        })?;
        Ok(Self {
            name: name.to_owned(),
            tracker,
        })
    }
}

/// The filtered bounding box of the scans along the path, and criterion (3) over it.
#[derive(Clone, Debug)]
pub struct Extents {
    params: EnvironmentParams,
    /// Travel (m) and `[x_min, x_max, y_min, y_max]` after the temporal low-pass, newest
    /// last, over the last `keep_m` of travel.
    history: VecDeque<(f64, [f64; 4])>,
    keep_m: f64,
}

impl Extents {
    /// Empty; keeps the boxes of the last `keep_m` of travel.
    pub fn new(params: EnvironmentParams, keep_m: f64) -> Self {
        Self {
            params,
            history: VecDeque::new(),
            keep_m,
        }
    }

    /// Takes the next scan at `map_from_robot` after `travel_m` of travel.
    pub fn push(&mut self, map_from_robot: &Se2, scan: &LaserScan, travel_m: f64) {
        let Some(raw) = self.scan_box(map_from_robot, scan) else {
            return;
        };
        let a = self.params.low_pass;
        let filtered = match self.history.back() {
            Some((_, previous)) => std::array::from_fn(|k| a * raw[k] + (1.0 - a) * previous[k]),
            None => raw,
        };
        self.history.push_back((travel_m, filtered));
        while self
            .history
            .front()
            .is_some_and(|(t, _)| travel_m - t > self.keep_m)
        {
            self.history.pop_front();
        }
    }

    /// Criterion (3) for a crossing after `crossed_m` of travel: a side of the box
    /// `change_travel_m` before it and of the newest box moved by `change_m`; `None` until
    /// the robot has gone `change_travel_m` beyond the crossing (or when the box before it
    /// is no longer kept).
    pub fn changed_around(&self, crossed_m: f64) -> Option<bool> {
        let d = self.params.change_travel_m;
        let (now_m, now) = self.history.back()?;
        if *now_m < crossed_m + d {
            return None;
        }
        let (first_m, _) = self.history.front()?;
        if *first_m > crossed_m - d {
            return None;
        }
        let (_, before) = self
            .history
            .iter()
            .rev()
            .find(|(t, _)| *t <= crossed_m - d)?;
        Some((0..4).any(|k| (now[k] - before[k]).abs() >= self.params.change_m))
    }

    /// The environment around the robot at `map_from_robot` by the filtered box: large when
    /// enough of its sides are far.
    pub fn environment(&self, map_from_robot: &Se2) -> Environment {
        let Some((_, b)) = self.history.back() else {
            return Environment::Indoor;
        };
        let p = map_from_robot.translation();
        let distances = [p.x - b[0], b[1] - p.x, p.y - b[2], b[3] - p.y];
        let far = distances
            .iter()
            .filter(|d| **d >= self.params.large_extent_m)
            .count();
        if far >= self.params.large_sides {
            Environment::Large
        } else {
            Environment::Indoor
        }
    }

    /// The box of one scan after the spatial low-pass (map frame); `None` without beams.
    fn scan_box(&self, map_from_robot: &Se2, scan: &LaserScan) -> Option<[f64; 4]> {
        let n = scan.len();
        if n == 0 {
            return None;
        }
        let far = self.params.far_m;
        let ranges: Vec<f64> = scan
            .ranges_m
            .iter()
            .map(|r| {
                if scan.is_return(*r) {
                    f64::from(*r).min(far)
                } else {
                    far
                }
            })
            .collect();
        let half = self.params.smoothing_beams / 2;
        let map_from_sensor = map_from_robot.compose(&scan.robot_from_sensor);
        let (mut xs, mut ys) = (Vec::with_capacity(n), Vec::with_capacity(n));
        // Running sum over the window (clipped at the scan's ends).
        let mut sum = 0.0;
        let (mut lo, mut hi) = (0usize, 0usize);
        for i in 0..n {
            let (want_lo, want_hi) = (i.saturating_sub(half), (i + half + 1).min(n));
            while hi < want_hi {
                sum += ranges[hi];
                hi += 1;
            }
            while lo < want_lo {
                sum -= ranges[lo];
                lo += 1;
            }
            let r = sum / (hi - lo) as f64;
            let angle = scan.beam_angle_rad(i);
            let p = map_from_sensor.transform_point(&Point2::new(r * angle.cos(), r * angle.sin()));
            xs.push(p.x);
            ys.push(p.y);
        }
        let q = self.params.quantile;
        let (x_lo, x_hi) = quantiles(&mut xs, q);
        let (y_lo, y_hi) = quantiles(&mut ys, q);
        Some([x_lo, x_hi, y_lo, y_hi])
    }
}

/// The `q` and `1 − q` quantiles of `values` (not empty), reordering them.
fn quantiles(values: &mut [f64], q: f64) -> (f64, f64) {
    let last = values.len().saturating_sub(1);
    let k = ((q * last as f64).round() as usize).min(last);
    let lo = *values.select_nth_unstable_by(k, f64::total_cmp).1;
    let hi = *values.select_nth_unstable_by(last - k, f64::total_cmp).1;
    (lo, hi)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    fn ring(range_m: f32) -> LaserScan {
        let n = 360;
        crate::door::tests::full_circle(vec![range_m; n])
    }

    #[test]
    fn a_change_of_room_around_a_crossing_is_criterion_three_a_steady_room_is_not() {
        let params = EnvironmentParams {
            change_travel_m: 1.0,
            ..EnvironmentParams::default()
        };
        let mut extents = Extents::new(params, 10.0);
        let at = |x: f64| Se2::new(x, 0.0, 0.0);
        // 3 m walls up to x = 2, then 8 m walls, one scan every 0.1 m.
        for i in 0..40 {
            let x = f64::from(i) * 0.1;
            extents.push(&at(x), &ring(if x < 2.0 { 3.0 } else { 8.0 }), x);
        }
        assert_eq!(extents.changed_around(2.0), Some(true));
        assert_eq!(extents.changed_around(0.5), None, "no box 1 m before");
        assert_eq!(extents.changed_around(3.5), None, "not yet 1 m beyond");
        let mut steady = Extents::new(EnvironmentParams::default(), 10.0);
        for i in 0..40 {
            let x = f64::from(i) * 0.1;
            steady.push(&at(0.0), &ring(3.0), x);
        }
        assert_eq!(steady.changed_around(2.0), Some(false));
        assert_eq!(steady.environment(&at(0.0)), Environment::Indoor);
        for i in 40..80 {
            steady.push(&at(0.0), &ring(20.0), f64::from(i) * 0.1);
        }
        assert_eq!(steady.environment(&at(0.0)), Environment::Large);
    }

    #[test]
    fn presets_parse_and_differ() {
        let indoor = Environment::Indoor.preset().unwrap();
        let large = Environment::Large.preset().unwrap();
        assert_eq!(
            indoor.tracker,
            TrackerParams::default(),
            "indoor: the defaults"
        );
        assert!(large.tracker.submap_travel_m > indoor.tracker.submap_travel_m);
        assert!(large.tracker.max_match_range_m > indoor.tracker.max_match_range_m);
        assert!(Preset::parse("bad", "{\"no_such_field\": 1}").is_err());
    }

    #[test]
    fn the_defaults_and_the_presets_pass_their_checks_and_bad_values_do_not() {
        assert!(EnvironmentParams::default().validate().is_ok());
        for environment in [Environment::Indoor, Environment::Large] {
            let preset = environment.preset().unwrap();
            assert_eq!(Validate::validate(&preset), Ok(()), "{}", preset.name);
        }
        let field = |params: EnvironmentParams| match params.validate() {
            Err(AreasError::Params(e)) => e.field,
            other => panic!("{other:?}"),
        };
        let quantile = EnvironmentParams {
            quantile: 0.5,
            ..EnvironmentParams::default()
        };
        assert_eq!(field(quantile), "quantile");
        let sides = EnvironmentParams {
            large_sides: 5,
            ..EnvironmentParams::default()
        };
        assert_eq!(field(sides), "large_sides");
        let beams = EnvironmentParams {
            smoothing_beams: usize::MAX,
            ..EnvironmentParams::default()
        };
        assert_eq!(field(beams), "smoothing_beams");
        let change = EnvironmentParams {
            change_m: -1.5,
            ..EnvironmentParams::default()
        };
        assert_eq!(field(change), "change_m");
    }
}

//! Odometry noise statistics: the random error has the configured spread per distance, the
//! drift grows with time, slips happen at the configured rate and scale the reported motion.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use mapmerge_geometry::{wrap_angle_rad, LieGroup, Se2};
use mapmerge_sim::{
    simulate, ChangeParams, KidnapParams, OdometryNoiseParams, SessionData, SimParams, SlipKind,
    SlipSchedule,
};

fn params(odometry: OdometryNoiseParams, sessions: usize, duration_secs: f64) -> SimParams {
    SimParams {
        odometry,
        kidnap: KidnapParams::none(),
        changes: ChangeParams::none(),
        ..SimParams::default()
            .with_sessions(sessions)
            .with_duration_secs(duration_secs)
    }
}

/// Per scan interval: (true distance, true |turn|, odometry distance error, odometry turn error).
fn increments(session: &SessionData) -> Vec<(f64, f64, f64, f64)> {
    let odometry: Vec<Se2> = common::scan_odometry(session);
    (1..odometry.len())
        .map(|i| {
            let truth = session.truth[i - 1].1.between(&session.truth[i].1);
            let odom = odometry[i - 1].between(&odometry[i]);
            let (d_true, d_odom) = (truth.translation().norm(), odom.translation().norm());
            let sign = if truth.x_m >= 0.0 { 1.0 } else { -1.0 };
            (
                d_true,
                truth.theta_rad.abs(),
                sign * (d_odom - d_true),
                wrap_angle_rad(odom.theta_rad - truth.theta_rad),
            )
        })
        .collect()
}

#[test]
fn translation_and_rotation_noise_have_the_configured_density() {
    let noise = OdometryNoiseParams {
        translation_sigma_per_sqrt_m: 0.05,
        rotation_sigma_per_sqrt_rad: 0.04,
        ..OdometryNoiseParams::perfect()
    };
    let dataset = simulate(&params(noise.clone(), 2, 600.0), 3).unwrap();
    let all: Vec<_> = dataset.sessions.iter().flat_map(increments).collect();
    // Σ e² ≈ σ² Σ d (variance proportional to the motion).
    let distance: f64 = all.iter().map(|i| i.0).sum();
    let turned: f64 = all.iter().map(|i| i.1).sum();
    let translation_sq: f64 = all.iter().map(|i| i.2 * i.2).sum();
    let rotation_sq: f64 = all.iter().map(|i| i.3 * i.3).sum();
    let translation_sigma = (translation_sq / distance).sqrt();
    let rotation_sigma = (rotation_sq / turned).sqrt();
    assert!(
        distance > 500.0 && turned > 100.0,
        "{distance} m, {turned} rad"
    );
    assert!(
        (translation_sigma / 0.05 - 1.0).abs() < 0.1,
        "translation σ {translation_sigma}"
    );
    assert!(
        (rotation_sigma / 0.04 - 1.0).abs() < 0.1,
        "rotation σ {rotation_sigma}"
    );
}

#[test]
fn perfect_odometry_is_the_truth_seen_from_the_start() {
    let dataset = simulate(&params(OdometryNoiseParams::perfect(), 1, 60.0), 8).unwrap();
    let session = &dataset.sessions[0];
    let start = session.truth[0].1;
    for (record, (_, truth)) in session.log.scans.iter().zip(&session.truth) {
        let expected = start.between(truth);
        let odom = record.odom_from_robot.unwrap();
        assert!((odom.translation() - expected.translation()).norm() < 1e-6);
        assert!(wrap_angle_rad(odom.theta_rad - expected.theta_rad).abs() < 1e-6);
    }
    assert_eq!(
        session.log.odometry[0].odom_from_robot,
        Se2::new(0.0, 0.0, 0.0)
    );
}

#[test]
fn drift_grows_with_time() {
    let dataset = simulate(&params(OdometryNoiseParams::default(), 4, 300.0), 21).unwrap();
    let (mut early, mut late) = (0.0, 0.0);
    for session in &dataset.sessions {
        let start = session.truth[0].1;
        let n = session.truth.len();
        let error_at = |i: usize| {
            let odom_in_world = start.compose(&session.log.scans[i].odom_from_robot.unwrap());
            (odom_in_world.translation() - session.truth[i].1.translation()).norm()
        };
        early += (n / 10..n / 5).map(error_at).sum::<f64>();
        late += (4 * n / 5..9 * n / 10).map(error_at).sum::<f64>();
    }
    assert!(late > 2.0 * early, "early {early}, late {late}");
    assert!(late > 0.0);
}

#[test]
fn slips_happen_at_the_configured_rate_and_scale_the_odometry() {
    let noise = OdometryNoiseParams {
        slip_schedule: SlipSchedule::ByTime {
            rate_per_min: 3.0,
            duration_min_secs: 2.0,
            duration_max_secs: 2.0,
        },
        ..OdometryNoiseParams::perfect()
    };
    let dataset = simulate(&params(noise, 1, 1800.0), 4).unwrap();
    let session = &dataset.sessions[0];
    // 30 minutes at 3 per minute, less the 2 s each event lasts: ≈ 86 expected.
    let count = session.slips.len();
    assert!((60..115).contains(&count), "{count} slips");
    // Inside translation slips, reported over true distance is the factor.
    let odometry: Vec<Se2> = common::scan_odometry(session);
    let mut checked = 0;
    for slip in session
        .slips
        .iter()
        .filter(|s| s.kind == SlipKind::Translation)
    {
        let inside: Vec<usize> = (0..session.truth.len())
            .filter(|&i| {
                session.truth[i].0 >= slip.span.start() + 0.2
                    && session.truth[i].0 <= slip.span.end() - 0.2
            })
            .collect();
        let (Some(&a), Some(&b)) = (inside.first(), inside.last()) else {
            continue;
        };
        let true_m: f64 = (a..b)
            .map(|i| {
                session.truth[i]
                    .1
                    .between(&session.truth[i + 1].1)
                    .translation()
                    .norm()
            })
            .sum();
        let odom_m: f64 = (a..b)
            .map(|i| odometry[i].between(&odometry[i + 1]).translation().norm())
            .sum();
        if true_m > 0.3 {
            assert!(
                (odom_m / true_m - slip.factor).abs() < 0.02,
                "ratio {} vs factor {}",
                odom_m / true_m,
                slip.factor
            );
            checked += 1;
        }
    }
    assert!(
        checked >= 5,
        "only {checked} translation slips while driving"
    );
}

#[test]
fn the_simulator_refuses_slips_over_wheel_travel() {
    let noise = mapmerge_sim::OdometryNoiseProfile::default();
    let err = simulate(&params(noise, 1, 10.0), 1).unwrap_err();
    assert!(err.to_string().contains("robot time"), "{err}");
}

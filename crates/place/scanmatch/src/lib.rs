//! 2D scan matching for the graph-SLAM front-end (scan-to-map odometry) and for geometric
//! verification of place-recognition candidates.
//!
//! Entry points:
//! - [`ScanMatcher`] with [`ScanMatchParams`]: prepare a target once
//!   ([`ScanMatcher::target`]), then [`ScanMatcher::match_scan`] a query within a
//!   [`SearchWindow`]: correlative search, then ICP; a [`Match`] with pose, score and
//!   covariance.
//! - [`match_scan`] on a [`MatchTarget`]: the real-time correlative matcher alone (Olson 2009)
//!   with multi-resolution branch-and-bound (Hess et al. 2016); it returns exactly what
//!   [`match_scan_brute_force`] returns.
//! - [`refine_icp`] on an [`IcpTarget`]: point-to-line ICP (Censi 2008).
//!
//! ```
//! use mapmerge_geometry::{LieGroup, Se2};
//! use mapmerge_scan::Point2;
//! use mapmerge_scanmatch::{ScanMatcher, SearchWindow};
//! // An L-shaped room corner with a pillar, in the target frame.
//! let mut target_points = Vec::new();
//! for k in 0..80 {
//!     let t = f64::from(k) * 0.05;
//!     target_points.push(Point2::new(t, 0.0));
//!     target_points.push(Point2::new(0.0, t));
//!     if k < 20 { target_points.push(Point2::new(2.0 + t * 0.5, 1.5)); }
//! }
//! // The same points seen from a robot at (0.2, 0.1, 5°) in the target frame.
//! let truth = Se2::new(0.2, 0.1, 5f64.to_radians());
//! let query: Vec<Point2> = target_points.iter().map(|p| truth.inverse().transform_point(p)).collect();
//! let matcher = ScanMatcher::default();
//! let target = matcher.target(&target_points).unwrap();
//! let found = matcher
//!     .match_scan(&target, &query, &Se2::identity(), &SearchWindow::new(0.5, 0.3))
//!     .unwrap();
//! let error = truth.between(&found.target_from_query);
//! assert!(error.translation().norm() < 0.02 && error.theta_rad.abs() < 0.01);
//! assert!(found.score > 0.8);
//! ```

#![warn(missing_docs)]

mod correlation_grid;
mod correlative;
mod error;
mod icp;
mod matcher;
mod params;

pub use correlation_grid::CorrelationGrid;
pub use correlative::{
    match_scan, match_scan_above, match_scan_brute_force, score_at, CorrelativeMatch, MatchTarget,
};
pub use error::ScanMatchError;
pub use icp::{refine_icp, IcpInfo, IcpTarget};
pub use matcher::{Match, ScanMatchTarget, ScanMatcher};
pub use params::{
    CorrelativeParams, IcpParams, ScanMatchParams, SearchWindow, MAX_GRID_CELLS_LIMIT,
};

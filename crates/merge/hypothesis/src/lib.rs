//! Merge and recovery hypotheses for lifelong mapping (Banerjee et al., "Lifelong Mapping in
//! the Wild: Novel Strategies for Ensuring Map Stability and Accuracy over Time Evaluated on
//! Thousands of Robots", Sec. 3.2.1, 5.2 and 5.3).
//!
//! A view observation that would join the robot's component to another map (a merge) or
//! contradict the robot's estimate (a recovery) is not added to the graph at once. It becomes
//! evidence for a hypothesis: an EKF on SE(2) over `G = robot_from_target` with its
//! covariance in the left tangent, initialised by Eq. 4, moved with the robot by Eq. 5, gated
//! by the Mahalanobis distance of the residual of Eq. 6 and refined by Eq. 7–8.
//!
//! Entry points:
//! - [`HypothesisFilter`]: `predict` per motion, `observe` per observation, `reject` when an
//!   invalid-merge detector refutes the conditional merge, `clear` when the epoch ends. A
//!   merge hypothesis meeting the permissive criteria becomes *conditional* (Sec. 5.2, one at
//!   a time); any meeting the strict criteria is accepted *fully* and handed back with its
//!   payloads, and every competitor is removed. Every change is a serialisable
//!   [`FilterEvent`].
//! - [`AmbiguityTracker`] (Sec. 5.3): views that keep being refused from different places
//!   while the robot is sure of its pose are marked ambiguous; their observations then count
//!   with [`HypothesisFilterParams::ambiguous_weight`] (default 0).
//!
//! ```
//! use mapmerge_geometry::Se2;
//! use mapmerge_hypothesis::{HypothesisFilter, HypothesisFilterParams, Observation, Target};
//! use nalgebra::Matrix3;
//!
//! let mut filter = HypothesisFilter::new(HypothesisFilterParams::default()).unwrap();
//! let observation = |view, robot_from_target, edge| Observation {
//!     target: Target::Merge { map: 3 },
//!     view,
//!     robot: 100 + view,
//!     robot_from_target,
//!     covariance: Matrix3::from_diagonal_element(1e-3),
//!     ambiguous: false,
//!     edge,
//! };
//! // View 10 of map 3 puts the map frame 5 m ahead: a new hypothesis (Eq. 4).
//! let first = filter.observe(observation(10, Se2::new(5.0, 1.0, 0.5), "e10"), 0.0, None).unwrap();
//! assert!(first.created);
//! // The robot drives 0.5 m forward (Eq. 5) …
//! let step_covariance = Matrix3::from_diagonal_element(1e-4);
//! filter.predict(&Se2::new(0.5, 0.0, 0.0), &step_covariance, 0.5, None).unwrap();
//! // … and view 11 agrees (Eq. 6–8): 2 observations of 2 views, a conditional merge.
//! let second = filter.observe(observation(11, Se2::new(4.5, 1.0, 0.5), "e11"), 0.5, None).unwrap();
//! assert_eq!(second.hypothesis, first.hypothesis);
//! assert!(second.conditional_started);
//! let edges: Vec<&str> = filter.conditional().unwrap().edges().copied().collect();
//! assert_eq!(edges, ["e10", "e11"]);
//! ```

mod ambiguity;
mod ekf;
mod error;
mod event;
mod filter;
mod hypothesis;
mod params;

pub use ambiguity::{
    AmbiguityParams, AmbiguityTracker, DistanceTracker, RejectedView, TrackedEntry,
};
pub use error::HypothesisError;
pub use event::{
    FilterEvent, FilterStats, GateCandidate, ObserveOutcome, Reconsidered, RejectReason,
};
pub use filter::HypothesisFilter;
pub use hypothesis::{
    Hypothesis, HypothesisCounts, HypothesisId, HypothesisState, Observation, ObservationRecord,
    Target,
};
pub use params::{AcceptanceCriteria, HypothesisFilterParams};

//! Geometry for mapmerge: the Lie groups SE(2) and SE(3) with exp/log, adjoints, Jacobians,
//! interpolation and covariance propagation.
//!
//! Entry points: [`Se2`], [`Se3`] and the [`LieGroup`] trait they implement; covariance
//! propagation ([`compose_covariance`], [`inverse_covariance`]) and the Jacobians of
//! compose/inverse/between ([`compose_jacobians`], ...) work for any [`LieGroup`].
//! Perturbations act on the right everywhere: `x ⊞ δ = x · Exp(δ)`.
//!
//! ```
//! use mapmerge_geometry::{compose_covariance, LieGroup, Se2};
//! use nalgebra::Matrix3;
//! let a = Se2::new(1.0, 2.0, 0.3);
//! let b = Se2::new(-0.5, 0.1, -1.0);
//! let ab = a.compose(&b);
//! let back = a.inverse().compose(&ab);
//! assert!((back.x_m - b.x_m).abs() < 1e-12);
//!
//! // Uncertainty of `ab` when `a` and `b` carry independent noise.
//! let cov = Matrix3::from_diagonal_element(1e-4);
//! let cov_ab = compose_covariance(&b, &cov, &cov);
//! assert!(cov_ab[(2, 2)] > cov[(2, 2)]);
//! ```

mod covariance;
mod lie;
mod numerical;
mod se2;
mod se3;
mod so3;
mod trig;

pub use covariance::{
    between_covariance, between_jacobians, compose_covariance, compose_covariance_correlated,
    compose_jacobians, inverse_covariance, inverse_jacobian, planar_information_from_covariance,
};
pub use lie::{skew, LieGroup};
pub use numerical::{numerical_jacobian, numerical_lie_jacobian};
pub use se2::{wrap_angle_rad, Se2};
pub use se3::Se3;
pub use so3::{
    exp_so3, left_jacobian_inverse_so3, left_jacobian_so3, log_so3, right_jacobian_inverse_so3,
    right_jacobian_so3,
};

/// A point in the plane (metres), in whatever frame its name says; every crate's `Point2`.
pub type Point2 = nalgebra::Vector2<f64>;

/// A point in space (metres), in whatever frame its name says; every crate's `Point3`.
pub type Point3 = nalgebra::Vector3<f64>;

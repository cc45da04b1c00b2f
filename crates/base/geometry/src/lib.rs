//! Geometry for mapmerge: the Lie groups SE(2) and SE(3) with exp/log, adjoints, Jacobians,
//! interpolation and covariance propagation.
//!
//! Entry points: [`Se2`], [`Se3`] and the [`LieGroup`] trait they implement.
//!
//! ```
//! use mapmerge_geometry::{LieGroup, Se2};
//! let a = Se2::new(1.0, 2.0, 0.3);
//! let b = Se2::new(-0.5, 0.1, -1.0);
//! let ab = a.compose(&b);
//! let back = a.inverse().compose(&ab);
//! assert!((back.x_m - b.x_m).abs() < 1e-12);
//! ```

mod lie;
mod se2;
mod se3;
mod so3;

pub use lie::{skew, LieGroup};
pub use se2::{wrap_angle_rad, Se2};
pub use se3::Se3;
pub use so3::{
    exp_so3, left_jacobian_inverse_so3, left_jacobian_so3, log_so3, right_jacobian_inverse_so3,
    right_jacobian_so3,
};

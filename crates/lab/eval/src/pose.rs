//! What the evaluation helpers need from a pose type beyond [`LieGroup`].

use mapmerge_geometry::{LieGroup, Se2, Se3};
use mapmerge_sim::gaussian;
use nalgebra::{UnitQuaternion, Vector3};
use rand::Rng;

/// A pose type the evaluation helpers can handle: [`Se2`] and [`Se3`].
pub trait EvalPose<const D: usize>: LieGroup<D> {
    /// True for planar poses: rigid alignment is then a rotation about z only.
    const PLANAR: bool;

    /// The position in metres, lifted to 3D (`z = 0` for planar poses).
    fn position_m(&self) -> Vector3<f64>;

    /// A random relative pose for a false loop closure, vertigo's distribution
    /// (`generateDataset.py`): every translation component ~ N(0, σ_t), every rotation angle
    /// (yaw; roll, pitch and yaw in 3D) ~ N(0, σ_r).
    fn sample_vertigo<R: Rng + ?Sized>(rng: &mut R, sigma_t_m: f64, sigma_r_rad: f64) -> Self;

    /// A random relative pose, translation uniform in `±half_extent_m` per axis, rotation
    /// uniform (yaw in `[-π, π)`; a uniformly distributed rotation in 3D).
    fn sample_uniform<R: Rng + ?Sized>(rng: &mut R, half_extent_m: f64) -> Self;
}

fn uniform_sym<R: Rng + ?Sized>(rng: &mut R, half: f64) -> f64 {
    (rng.random::<f64>() * 2.0 - 1.0) * half
}

impl EvalPose<3> for Se2 {
    const PLANAR: bool = true;

    fn position_m(&self) -> Vector3<f64> {
        Vector3::new(self.x_m, self.y_m, 0.0)
    }

    fn sample_vertigo<R: Rng + ?Sized>(rng: &mut R, sigma_t_m: f64, sigma_r_rad: f64) -> Self {
        let x = gaussian(rng) * sigma_t_m;
        let y = gaussian(rng) * sigma_t_m;
        let theta = gaussian(rng) * sigma_r_rad;
        Se2::new(x, y, theta)
    }

    fn sample_uniform<R: Rng + ?Sized>(rng: &mut R, half_extent_m: f64) -> Self {
        let x = uniform_sym(rng, half_extent_m);
        let y = uniform_sym(rng, half_extent_m);
        let theta = uniform_sym(rng, std::f64::consts::PI);
        Se2::new(x, y, theta)
    }
}

impl EvalPose<6> for Se3 {
    const PLANAR: bool = false;

    fn position_m(&self) -> Vector3<f64> {
        self.translation_m
    }

    fn sample_vertigo<R: Rng + ?Sized>(rng: &mut R, sigma_t_m: f64, sigma_r_rad: f64) -> Self {
        let t = Vector3::new(gaussian(rng), gaussian(rng), gaussian(rng)) * sigma_t_m;
        let roll = gaussian(rng) * sigma_r_rad;
        let pitch = gaussian(rng) * sigma_r_rad;
        let yaw = gaussian(rng) * sigma_r_rad;
        Se3::new(UnitQuaternion::from_euler_angles(roll, pitch, yaw), t)
    }

    fn sample_uniform<R: Rng + ?Sized>(rng: &mut R, half_extent_m: f64) -> Self {
        let t = Vector3::new(
            uniform_sym(rng, half_extent_m),
            uniform_sym(rng, half_extent_m),
            uniform_sym(rng, half_extent_m),
        );
        // Shoemake, "Uniform random rotations", Graphics Gems III (1992).
        let (u1, u2, u3): (f64, f64, f64) = (rng.random(), rng.random(), rng.random());
        let tau = std::f64::consts::TAU;
        let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
        let q = nalgebra::Quaternion::new(
            b * (tau * u3).cos(),
            a * (tau * u2).sin(),
            a * (tau * u2).cos(),
            b * (tau * u3).sin(),
        );
        Se3::new(UnitQuaternion::from_quaternion(q), t)
    }
}

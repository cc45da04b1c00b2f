//! Chordal relaxation for 3D pose graphs: Carlone, Tron, Daniilidis, Dellaert, "Initialization
//! techniques for 3D SLAM: a survey on rotation estimation and its use in pose graph
//! optimization", ICRA 2015 — rotations from a linear least-squares problem on the rotation
//! matrices' entries projected back onto SO(3), then translations given the rotations.

use std::time::Instant;

use mapmerge_geometry::{log_so3, LieGroup, Se3};
use mapmerge_posegraph::PoseGraph3;
use nalgebra::{Matrix3, Matrix6, Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::InitError;
use crate::info::InitInfo;
use crate::sparse::NormalEquations;
use crate::topology::Topology;

/// How the chordal rotation problem weights each edge.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RotationWeighting {
    /// `‖(R_j − R_i R_ij) C‖²_F` with `C Cᵀ = tr(Ω)/2 · I − Ω`, `Ω` the marginal rotation
    /// information: to first order this is `φᵀ Ω φ` for the rotation error `φ`, so anisotropic
    /// information (e.g. a planar robot's certain roll/pitch and uncertain yaw) is honoured.
    /// Negative eigenvalues of `tr(Ω)/2 · I − Ω` (strongly anisotropic `Ω`) are clamped to 0.
    Information,
    /// A scalar weight `tr(Ω)/3` per edge (`Ω` the marginal rotation information), the survey's
    /// isotropic weighting.
    Trace,
    /// Every edge weighs 1.
    Unit,
}

/// Parameters of [`initialize_chordal`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ChordalParams {
    /// Edge weights of the rotation problem. `information` follows the measurement noise in
    /// every direction; `trace` only in magnitude and is misled by anisotropic information
    /// (e.g. cubicle.g2o's odometry, with roll/pitch information 10⁶ and yaw 6.25); `unit`
    /// ignores the noise. The translation problem always uses the translation information.
    /// (default: information)
    pub rotation_weighting: RotationWeighting,
}

impl Default for ChordalParams {
    fn default() -> Self {
        Self {
            rotation_weighting: RotationWeighting::Information,
        }
    }
}

/// Initialises a 3D pose graph by chordal relaxation (Carlone et al. 2015, the
/// survey's "chordal relaxation" for rotations):
///
/// 1. **rotations** — the nine entries of every rotation matrix are unknowns; each edge
///    contributes `R_j − R_i R_ij = 0` (weighted, see [`RotationWeighting`]), the anchors'
///    rotations are held; the sparse linear least-squares problem is solved and every 3x3 block
///    projected onto SO(3) by SVD (`det = +1`);
/// 2. **translations** — with the rotations fixed, weighted linear least squares on
///    `t_j − t_i = R_i t_ij`.
///
/// Anchors (each component's lowest-id fixed vertex, else its lowest id) and all fixed vertices
/// keep their pose; every other vertex is written. Priors are ignored. On error the graph is
/// unchanged.
pub fn initialize_chordal(
    graph: &mut PoseGraph3,
    params: &ChordalParams,
) -> Result<InitInfo, InitError> {
    let start = Instant::now();
    let topology = Topology::new(graph)?;
    let (unknown, num_unknowns) = topology.unknown_indices();
    let n = topology.num_vertices();
    let current: Vec<Matrix3<f64>> = topology.poses.iter().map(|p| p.rotation_matrix()).collect();

    // Step 1: rotations. Row r of R_j − R_i R_ij is (u_j − R_ijᵀ u_i)ᵀ with u = (row r of R)ᵀ,
    // so the nine unknowns per vertex split into three 3-vector problems sharing one matrix:
    // min Σ_r (u_j^r − M u_i^r)ᵀ P (u_j^r − M u_i^r), M = R_ijᵀ (the survey's chordal
    // relaxation, with per-edge weights).
    let mut normal = NormalEquations::new(3 * num_unknowns, 3, 21 * topology.edges.len());
    for e in &topology.edges {
        let p = rotation_weight(&e.information, params.rotation_weighting).ok_or_else(|| {
            InitError::InvalidInformation {
                edge: e.id,
                from: topology.ids[e.from],
                to: topology.ids[e.to],
                reason: "negative rotation information",
            }
        })?;
        let m = e.measurement.rotation_matrix().transpose();
        match (unknown[e.from], unknown[e.to]) {
            (Some(i), Some(j)) => {
                add_diagonal_block(&mut normal, i, &(m.transpose() * p * m));
                add_diagonal_block(&mut normal, j, &p);
                add_block_full(&mut normal, j, i, &(-p * m));
            }
            (None, Some(j)) => {
                add_diagonal_block(&mut normal, j, &p);
                // Column r of Rᵀ is u^r, so all three right-hand sides at once.
                add_rhs_block(&mut normal, j, &(p * m * current[e.from].transpose()));
            }
            (Some(i), None) => {
                add_diagonal_block(&mut normal, i, &(m.transpose() * p * m));
                add_rhs_block(
                    &mut normal,
                    i,
                    &(m.transpose() * p * current[e.to].transpose()),
                );
            }
            (None, None) => {}
        }
    }
    let solution = normal.solve("chordal rotations")?;
    let dim = 3 * num_unknowns;
    let mut rotations = current;
    for k in 0..n {
        if let Some(u) = unknown[k] {
            // Rᵀ column r = solution of right-hand side r.
            let relaxed = Matrix3::from_fn(|r, c| solution[r * dim + 3 * u + c]);
            rotations[k] = project_to_so3(&relaxed).ok_or(InitError::NonFiniteEstimate {
                stage: "chordal rotation projection",
                node: topology.ids[k],
            })?;
        }
    }

    // Step 2: translations given the rotations. The residual's translation part is, to first
    // order, Qᵀ (t_j − t_i − R_i t_ij) with Q = R_i R_ij, so the world-frame weight is
    // Q Ω_vv Qᵀ; a rotation residual r_ω with cross information Ω_vω shifts the target by
    // −Q Ω_vv⁻¹ Ω_vω r_ω (the conditional mean), as in the planar case.
    let mut normal = NormalEquations::new(3 * num_unknowns, 1, 21 * topology.edges.len());
    for e in &topology.edges {
        let omega = &e.information;
        let omega_vv = omega.fixed_view::<3, 3>(3, 3).into_owned();
        let omega_v_omega = omega.fixed_view::<3, 3>(3, 0).into_owned();
        let r_i = rotations[e.from];
        let q = r_i * e.measurement.rotation_matrix();
        let mut target = r_i * e.measurement.translation_m;
        // Only for a positive-definite Ω; an indefinite one has no conditional mean.
        if omega_v_omega.iter().any(|v| *v != 0.0) && omega.cholesky().is_some() {
            if let Some(inv) = omega_vv.try_inverse() {
                let rel = q.transpose() * rotations[e.to];
                let r_omega = log_so3(&UnitQuaternion::from_rotation_matrix(
                    &Rotation3::from_matrix_unchecked(rel),
                ));
                target -= q * (inv * omega_v_omega * r_omega);
            }
        }
        let w = q * omega_vv * q.transpose();
        normal.add_difference::<3>(&unknown, e.from, e.to, &w, &target, |k| {
            topology.poses[k].translation_m
        });
    }
    let solution = normal.solve("chordal translations")?;

    let mut poses = topology.poses.clone();
    for k in 0..n {
        if let Some(u) = unknown[k] {
            let t = Vector3::new(solution[3 * u], solution[3 * u + 1], solution[3 * u + 2]);
            let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
                rotations[k],
            ));
            let pose = Se3::new(rotation, t);
            if !pose.is_finite() {
                return Err(InitError::NonFiniteEstimate {
                    stage: "chordal",
                    node: topology.ids[k],
                });
            }
            poses[k] = pose;
        }
    }
    Ok(topology.finish(graph, &poses, 0, start))
}

/// The weight `P` of `(u_j − M u_i)ᵀ P (u_j − M u_i)`; `None` if the information is negative.
///
/// With `R_j = R_i R_ij Exp(φ)`, `R_j − R_i R_ij ≈ R_i R_ij [φ]×` and
/// `‖[φ]× C‖²_F = φᵀ (tr(P) I − P) φ` for `P = C Cᵀ`; `P = tr(Ω)/2 · I − Ω` makes this `φᵀ Ω φ`,
/// the rotation part of the chi2. That `P` is singular or indefinite when one eigenvalue of `Ω`
/// reaches half its trace, and a singular `P` leaves rank-one deformations of the relaxed
/// matrices unconstrained; so, in `Ω`'s eigenbasis, `p_k = max(tr(Ω)/2 − ω_k, 0) + δ` with
/// `δ = λ_min(Ω)/4`, which approximates `Ω + 2δ I` (at most 1.5 `Ω` in the weakest direction).
fn rotation_weight(
    information: &Matrix6<f64>,
    weighting: RotationWeighting,
) -> Option<Matrix3<f64>> {
    if weighting == RotationWeighting::Unit {
        return Some(Matrix3::identity());
    }
    let omega = marginal_rotation_information(information);
    let trace = omega.trace();
    if trace.is_nan() || trace < 0.0 {
        return None;
    }
    let isotropic = Matrix3::identity() * (trace / 6.0);
    if weighting == RotationWeighting::Trace {
        // tr(Ω)/3 · I as Ω gives tr(Ω)/6 · I as P.
        return Some(isotropic);
    }
    // If the eigen-solver fails, fall back to the isotropic weight.
    let Some(eigen) = omega.try_symmetric_eigen(f64::EPSILON, 1000) else {
        return Some(isotropic);
    };
    let delta = 0.25 * eigen.eigenvalues.min().max(0.0);
    let p = eigen
        .eigenvalues
        .map(|w| (0.5 * trace - w).max(0.0) + delta);
    Some(eigen.eigenvectors * Matrix3::from_diagonal(&p) * eigen.eigenvectors.transpose())
}

/// `(Σ_ωω)⁻¹ = Ω_ωω − Ω_ωv Ω_vv⁻¹ Ω_vω` (symmetrised) when `Ω` is positive definite, else the
/// block `Ω_ωω` (some files carry indefinite matrices, e.g. cubicle.g2o's loop closures, whose
/// Schur complement would be meaningless).
fn marginal_rotation_information(information: &Matrix6<f64>) -> Matrix3<f64> {
    let omega_ww = information.fixed_view::<3, 3>(0, 0).into_owned();
    let omega_wv = information.fixed_view::<3, 3>(0, 3).into_owned();
    let mut marginal = omega_ww;
    if omega_wv.iter().any(|v| *v != 0.0) && information.cholesky().is_some() {
        let omega_vv = information.fixed_view::<3, 3>(3, 3).into_owned();
        if let Some(inv) = omega_vv.try_inverse() {
            let schur = omega_ww - omega_wv * inv * omega_wv.transpose();
            if schur.iter().all(|v| v.is_finite()) {
                marginal = schur;
            }
        }
    }
    (marginal + marginal.transpose()) * 0.5
}

/// The rotation nearest to `m` in the Frobenius norm: `U diag(1, 1, det(U Vᵀ)) Vᵀ` from the SVD
/// `m = U Σ Vᵀ` (the survey's projection onto SO(3)).
fn project_to_so3(m: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    if m.iter().any(|v| !v.is_finite()) {
        return None;
    }
    // try_svd sorts the singular values decreasingly, so the last column is the one to flip.
    let svd = m.try_svd(true, true, f64::EPSILON, 1000)?;
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = u * d * v_t;
    r.iter().all(|v| v.is_finite()).then_some(r)
}

/// Adds the 3x3 block `b` at block position `(i, i)` (lower triangle only).
fn add_diagonal_block(normal: &mut NormalEquations, i: usize, b: &Matrix3<f64>) {
    for a in 0..3 {
        for c in 0..=a {
            normal.add(3 * i + a, 3 * i + c, b[(a, c)]);
        }
    }
}

/// Adds the 3x3 block `b` at block position `(j, i)`, `i != j`, and `bᵀ` at `(i, j)`.
fn add_block_full(normal: &mut NormalEquations, j: usize, i: usize, b: &Matrix3<f64>) {
    for a in 0..3 {
        for c in 0..3 {
            normal.add(3 * j + a, 3 * i + c, b[(a, c)]);
        }
    }
}

/// Adds column `r` of `b` to right-hand side `r` at block `k`.
fn add_rhs_block(normal: &mut NormalEquations, k: usize, b: &Matrix3<f64>) {
    for r in 0..3 {
        for a in 0..3 {
            normal.add_rhs(3 * k + a, r, b[(a, r)]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn so3_error(r: &Matrix3<f64>) -> f64 {
        (r.transpose() * r - Matrix3::identity()).norm() + (r.determinant() - 1.0).abs()
    }

    #[test]
    fn projection_returns_a_rotation_and_keeps_rotations() {
        let r = Rotation3::from_euler_angles(0.3, -1.2, 2.9).into_inner();
        let p = project_to_so3(&r).unwrap_or_else(Matrix3::zeros);
        assert!((p - r).norm() < 1e-12);
        // A reflection-contaminated, scaled, noisy matrix still projects into SO(3).
        let m = r * Matrix3::from_diagonal(&Vector3::new(2.0, 0.5, -0.1))
            + Matrix3::new(0.01, 0.0, 0.02, 0.0, -0.03, 0.0, 0.01, 0.0, 0.0);
        let p = project_to_so3(&m).unwrap_or_else(Matrix3::zeros);
        assert!(so3_error(&p) < 1e-12, "{p}");
        assert_eq!(project_to_so3(&(r * f64::NAN)), None);
    }

    #[test]
    fn information_weight_reproduces_the_rotation_information() {
        // Small rotation error φ: ‖[φ]× C‖² must equal φᵀ (Ω + 2δ I) φ, δ = λ_min(Ω)/4.
        let mut info = Matrix6::zeros();
        let omega = Matrix3::new(5.0, 1.0, 0.0, 1.0, 4.0, 0.5, 0.0, 0.5, 3.0);
        info.fixed_view_mut::<3, 3>(0, 0).copy_from(&omega);
        info.fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&Matrix3::identity());
        let p =
            rotation_weight(&info, RotationWeighting::Information).unwrap_or_else(Matrix3::zeros);
        let delta = 0.25 * omega.symmetric_eigenvalues().min();
        let effective = omega + Matrix3::identity() * (2.0 * delta);
        let phi = Vector3::new(0.3, -0.2, 0.7);
        let s = mapmerge_geometry::skew(&phi);
        let chordal = (s * p * s.transpose()).trace();
        assert!((chordal - (phi.transpose() * effective * phi)[(0, 0)]).abs() < 1e-12);
        assert_eq!(rotation_weight(&(-info), RotationWeighting::Trace), None);
    }

    #[test]
    fn information_weight_stays_positive_definite_for_anisotropic_information() {
        // cubicle.g2o's odometry: roll/pitch 10⁶, yaw 6.25 — and diag(30, 20, 10), whose
        // unregularised P would be singular.
        for diag in [Vector3::new(1e6, 1e6, 6.25), Vector3::new(30.0, 20.0, 10.0)] {
            let mut info = Matrix6::identity();
            info.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&Matrix3::from_diagonal(&diag));
            let p = rotation_weight(&info, RotationWeighting::Information)
                .unwrap_or_else(Matrix3::zeros);
            assert!(p.symmetric_eigenvalues().min() > 0.0, "{p}");
            // The effective information keeps the ordering and stays within 1.5x of Ω.
            let effective = Matrix3::identity() * p.trace() - p;
            for k in 0..3 {
                assert!(
                    effective[(k, k)] >= diag[k] && effective[(k, k)] <= 1.5 * diag[k],
                    "{effective}"
                );
            }
        }
    }
}

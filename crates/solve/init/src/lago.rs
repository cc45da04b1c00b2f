//! LAGO: Carlone, Aragues, Castellanos, Bona, "A fast and accurate approximation for planar pose
//! graph optimization", IJRR 33(7), 2014 — linear estimate of the orientations, then of the
//! positions given the orientations.

use std::f64::consts::PI;
use std::time::Instant;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::PoseGraph2;
use nalgebra::{Matrix2, Matrix3};
use serde::{Deserialize, Serialize};

use crate::error::InitError;
use crate::info::InitInfo;
use crate::sparse::NormalEquations;
use crate::topology::Topology;

/// Parameters of [`initialize_lago`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LagoParams {
    /// Weight each edge's orientation constraint by the inverse of its marginal heading
    /// variance, `1 / (Ω⁻¹)_θθ` (`true`), or give every edge weight 1 (`false`).
    /// Information weighting is the paper's choice and follows how good each measurement is;
    /// unit weights only help when the information matrices are badly scaled. (default: true)
    pub weight_by_information: bool,
}

impl Default for LagoParams {
    fn default() -> Self {
        Self {
            weight_by_information: true,
        }
    }
}

/// Initialises a planar pose graph with LAGO (Carlone et al. 2014):
///
/// 1. **orientations** — unwrapped headings along the odometry-first spanning tree; each
///    measured heading change is regularised by the multiple of 2π that makes it agree with the
///    tree; then weighted linear least squares on the headings with the anchors held;
/// 2. **positions** — with the headings fixed, weighted linear least squares on
///    `p_j − p_i = R(θ_i) t_ij`.
///
/// Both systems are solved by sparse Cholesky. Anchors (each component's lowest-id fixed vertex,
/// else its lowest id) and all fixed vertices keep their pose; every other vertex is written.
/// Priors are ignored. On error the graph is unchanged.
pub fn initialize_lago(graph: &mut PoseGraph2, params: &LagoParams) -> Result<InitInfo, InitError> {
    let start = Instant::now();
    let topology = Topology::new(graph)?;
    let (unknown, num_unknowns) = topology.unknown_indices();
    let n = topology.num_vertices();

    // Phase 1a: unwrapped tree headings (Carlone et al. 2014, LAGO phase 1:
    // orientations along a spanning tree).
    let mut theta_tree: Vec<f64> = topology.poses.iter().map(|p| p.theta_rad).collect();
    for step in topology.spanning_tree() {
        let delta = topology.edges[step.edge].measurement.theta_rad;
        theta_tree[step.vertex] =
            theta_tree[step.parent] + if step.forward { delta } else { -delta };
    }

    // Phase 1b: regularised measurements δ_ij + 2π k_ij, k_ij = round((θ_j − θ_i − δ_ij) / 2π),
    // then min Σ w_ij (θ_j − θ_i − δ_ij − 2π k_ij)² with the anchors held (LAGO phase 1:
    // regularisation and linear estimate of the orientations).
    let mut regularised = Vec::with_capacity(topology.edges.len());
    let mut angle_corrections = 0;
    let mut normal = NormalEquations::new(num_unknowns, 1, 3 * topology.edges.len() + n);
    for e in &topology.edges {
        let delta = e.measurement.theta_rad;
        let k = ((theta_tree[e.to] - theta_tree[e.from] - delta) / (2.0 * PI)).round();
        if k != 0.0 {
            angle_corrections += 1;
        }
        let d = delta + 2.0 * PI * k;
        regularised.push(d);
        let w = if params.weight_by_information {
            heading_weight(&e.information).ok_or_else(|| InitError::InvalidInformation {
                edge: e.id,
                from: topology.ids[e.from],
                to: topology.ids[e.to],
                reason: "negative heading information",
            })?
        } else {
            1.0
        };
        // Residual θ_j − θ_i − d.
        match (unknown[e.from], unknown[e.to]) {
            (Some(i), Some(j)) => {
                normal.add(i, i, w);
                normal.add(j, j, w);
                normal.add(j, i, -w);
                normal.add_rhs(i, 0, -w * d);
                normal.add_rhs(j, 0, w * d);
            }
            (None, Some(j)) => {
                normal.add(j, j, w);
                normal.add_rhs(j, 0, w * (theta_tree[e.from] + d));
            }
            (Some(i), None) => {
                normal.add(i, i, w);
                normal.add_rhs(i, 0, w * (theta_tree[e.to] - d));
            }
            (None, None) => {}
        }
    }
    let solution = normal.solve("LAGO orientations")?;
    let mut theta = theta_tree;
    for (k, u) in unknown.iter().enumerate() {
        if let Some(u) = u {
            theta[k] = solution[*u];
        }
    }

    // Phase 2: positions given the headings (LAGO's linear position estimate). The g2o/GTSAM residual is
    // r_t = R(δ_ij)ᵀ (R(θ_i)ᵀ (p_j − p_i) − t_ij) = Qᵀ (p_j − p_i − R(θ_i) t_ij) with
    // Q = R(θ_i + δ_ij), so the world-frame weight is Q Ω_tt Qᵀ. With the heading residual r_θ
    // now fixed, the cross information Ω_tθ shifts the target by −Q Ω_tt⁻¹ Ω_tθ r_θ (the
    // conditional mean of r_t).
    let mut normal = NormalEquations::new(2 * num_unknowns, 1, 7 * topology.edges.len());
    for (e, d) in topology.edges.iter().zip(&regularised) {
        let omega = &e.information;
        let omega_tt = omega.fixed_view::<2, 2>(0, 0).into_owned();
        let omega_t_theta = omega.fixed_view::<2, 1>(0, 2).into_owned();
        let q = rotation(theta[e.from] + e.measurement.theta_rad);
        let mut target = rotation(theta[e.from]) * e.measurement.translation();
        // Only for a positive-definite Ω; an indefinite one has no conditional mean.
        if omega_t_theta.iter().any(|v| *v != 0.0) && omega.cholesky().is_some() {
            if let Some(inv) = omega_tt.try_inverse() {
                let r_theta = theta[e.to] - theta[e.from] - d;
                target -= q * (inv * omega_t_theta * r_theta);
            }
        }
        let w = q * omega_tt * q.transpose();
        normal.add_difference::<2>(&unknown, e.from, e.to, &w, &target, |k| {
            topology.poses[k].translation()
        });
    }
    let solution = normal.solve("LAGO positions")?;

    let mut poses = topology.poses.clone();
    for k in 0..n {
        if let Some(u) = unknown[k] {
            let pose = Se2::new(solution[2 * u], solution[2 * u + 1], theta[k]);
            if !pose.is_finite() {
                return Err(InitError::NonFiniteEstimate {
                    stage: "LAGO",
                    node: topology.ids[k],
                });
            }
            poses[k] = pose;
        }
    }
    Ok(topology.finish(graph, &poses, angle_corrections, start))
}

/// `1 / (Ω⁻¹)_θθ`, the information of the heading alone, as the Schur complement
/// `Ω_θθ − Ω_θt Ω_tt⁻¹ Ω_tθ` when `Ω` is positive definite, else `Ω_θθ`. `None` if negative.
fn heading_weight(omega: &Matrix3<f64>) -> Option<f64> {
    let omega_tt = omega.fixed_view::<2, 2>(0, 0).into_owned();
    let omega_t_theta = omega.fixed_view::<2, 1>(0, 2).into_owned();
    let mut w = omega[(2, 2)];
    if omega_t_theta.iter().any(|v| *v != 0.0) && omega.cholesky().is_some() {
        if let Some(inv) = omega_tt.try_inverse() {
            let schur = w - (omega_t_theta.transpose() * inv * omega_t_theta)[(0, 0)];
            if schur.is_finite() && schur > 0.0 {
                w = schur;
            }
        }
    }
    (w >= 0.0).then_some(w)
}

fn rotation(theta_rad: f64) -> Matrix2<f64> {
    let (s, c) = theta_rad.sin_cos();
    Matrix2::new(c, -s, s, c)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heading_weight_is_the_marginal_information() {
        let omega = Matrix3::new(2.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 3.0);
        let cov = match omega.try_inverse() {
            Some(c) => c,
            None => panic!("invertible"),
        };
        let w = heading_weight(&omega).unwrap_or(f64::NAN);
        assert!((w - 1.0 / cov[(2, 2)]).abs() < 1e-12);
        assert_eq!(
            heading_weight(&Matrix3::from_diagonal(&nalgebra::Vector3::new(
                1.0, 1.0, 5.0
            ))),
            Some(5.0)
        );
        assert_eq!(
            heading_weight(&Matrix3::from_diagonal(&nalgebra::Vector3::new(
                1.0, 1.0, -5.0
            ))),
            None
        );
    }

    #[test]
    fn rotation_matches_se2() {
        let r = rotation(0.7);
        let p = Se2::new(0.0, 0.0, 0.7).rotation_matrix();
        assert!((r - p).norm() < 1e-15);
    }
}

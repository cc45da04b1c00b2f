//! A synthetic Manhattan world: a random walk on a square grid with quarter turns, noisy
//! odometry and loop closures between poses that come close again. After Olson, Leonard &
//! Teller, "Fast iterative alignment of pose graphs with poor initial estimates", ICRA 2006
//! (the M3500 dataset was made this way).

use std::collections::HashMap;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::{Edge, EdgeKind, NodeId, PoseGraph2, Vertex};
use mapmerge_sim::{gaussian, seeded, SimRng};
use nalgebra::Matrix3;
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::EvalError;

/// Parameters of [`simulate_manhattan_2d`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ManhattanParams {
    /// Number of poses (default: 500). At least 2.
    pub num_poses: usize,
    /// Length of one step, m (default: 1). Every step moves one grid cell.
    pub step_m: f64,
    /// Side of the square world the walk stays in, m (default: 12). Smaller worlds are
    /// revisited more often and so give more loop closures. At least `2 · step_m`.
    pub world_size_m: f64,
    /// Probability of a quarter turn (left or right, equally likely) before a step
    /// (default: 0.3). At the border the walk turns whatever this says.
    pub turn_probability: f64,
    /// Standard deviation of the x and y measurement noise of every edge, m (default: 0.05).
    pub sigma_xy_m: f64,
    /// Standard deviation of the heading measurement noise of every edge, rad (default: 0.02,
    /// about 1.1°; heading noise is what makes the odometry drift).
    pub sigma_theta_rad: f64,
    /// Poses closer than this (ground truth) may get a loop closure, m (default: 0.5, i.e. only
    /// returns to the same grid cell).
    pub loop_radius_m: f64,
    /// Probability that a candidate pair actually gets a loop closure (default: 0.4).
    pub loop_probability: f64,
    /// Minimum index distance between the two poses of a loop closure (default: 10; at least 2,
    /// so a loop closure never looks like odometry).
    pub min_loop_separation: usize,
}

impl Default for ManhattanParams {
    fn default() -> Self {
        Self {
            num_poses: 500,
            step_m: 1.0,
            world_size_m: 12.0,
            turn_probability: 0.3,
            sigma_xy_m: 0.05,
            sigma_theta_rad: 0.02,
            loop_radius_m: 0.5,
            loop_probability: 0.4,
            min_loop_separation: 10,
        }
    }
}

impl ManhattanParams {
    fn validate(&self) -> Result<(), EvalError> {
        let bad = |field, reason: &str| {
            Err(EvalError::InvalidParams {
                field,
                reason: reason.into(),
            })
        };
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let probability = |v: f64| v.is_finite() && (0.0..=1.0).contains(&v);
        if self.num_poses < 2 {
            return bad("num_poses", "must be at least 2");
        }
        if !positive(self.step_m) {
            return bad("step_m", "must be finite and > 0");
        }
        if !(self.world_size_m.is_finite() && self.world_size_m >= 2.0 * self.step_m) {
            return bad("world_size_m", "must be finite and at least 2 · step_m");
        }
        if self.world_size_m / self.step_m > 1e6 {
            return bad("world_size_m", "must be at most 10⁶ steps");
        }
        if !probability(self.turn_probability) {
            return bad("turn_probability", "must be in [0, 1]");
        }
        if !positive(self.sigma_xy_m) {
            return bad("sigma_xy_m", "must be finite and > 0");
        }
        if !positive(self.sigma_theta_rad) {
            return bad("sigma_theta_rad", "must be finite and > 0");
        }
        if !(self.loop_radius_m.is_finite() && self.loop_radius_m >= 0.0) {
            return bad("loop_radius_m", "must be finite and >= 0");
        }
        if !probability(self.loop_probability) {
            return bad("loop_probability", "must be in [0, 1]");
        }
        if self.min_loop_separation < 2 {
            return bad("min_loop_separation", "must be at least 2");
        }
        Ok(())
    }
}

/// A random walk in a Manhattan world and its pose graph.
///
/// Returns `(noisy, truth)`: both graphs have vertex ids `0..num_poses` and the same edges
/// (odometry `i → i+1` first, then loop closures `i → j` with `j − i ≥ min_loop_separation`, in
/// order of `j`); every measurement is the true relative pose times `Exp`-free noise
/// `Se2(n_x, n_y, n_θ)`, `n ~ N(0, diag(σ_xy², σ_xy², σ_θ²))`, and carries the information
/// `diag(1/σ_xy², 1/σ_xy², 1/σ_θ²)`. `noisy` holds the odometry-chained initial guess (from
/// the identity at vertex 0); `truth` the exact grid poses (vertex 0 at the identity, heading
/// east). Same params and seed, same graphs (ChaCha8).
pub fn simulate_manhattan_2d(
    params: &ManhattanParams,
    seed: u64,
) -> Result<(PoseGraph2, PoseGraph2), EvalError> {
    params.validate()?;
    let mut rng = seeded(seed);
    // The walk stays in the cells [-half, half]² around the start.
    let half = ((params.world_size_m / params.step_m) / 2.0).floor() as i64;

    // 1. The walk on the grid: cell and heading (quarter turns, 0 = east).
    let mut cells: Vec<(i64, i64)> = Vec::with_capacity(params.num_poses);
    let mut headings: Vec<i64> = Vec::with_capacity(params.num_poses);
    let (mut cell, mut heading) = ((0i64, 0i64), 0i64);
    cells.push(cell);
    headings.push(heading);
    let inside = |c: (i64, i64)| c.0.abs() <= half && c.1.abs() <= half;
    let advance = |c: (i64, i64), h: i64| match h.rem_euclid(4) {
        0 => (c.0 + 1, c.1),
        1 => (c.0, c.1 + 1),
        2 => (c.0 - 1, c.1),
        _ => (c.0, c.1 - 1),
    };
    for _ in 1..params.num_poses {
        let u: f64 = rng.random();
        let wanted = if u < params.turn_probability / 2.0 {
            1
        } else if u < params.turn_probability {
            -1
        } else {
            0
        };
        let turn = if inside(advance(cell, heading + wanted)) {
            wanted
        } else {
            let options: Vec<i64> = [0, 1, -1]
                .into_iter()
                .filter(|t| inside(advance(cell, heading + t)))
                .collect();
            match options.as_slice() {
                [] => 2, // a dead end cannot happen for half ≥ 1, but a U-turn always works
                list => list[rng.random_range(0..list.len())],
            }
        };
        heading = (heading + turn).rem_euclid(4);
        cell = advance(cell, heading);
        cells.push(cell);
        headings.push(heading);
    }
    let truth_pose = |k: usize| {
        let (c, h) = (cells[k], headings[k]);
        let theta = std::f64::consts::FRAC_PI_2 * h as f64;
        Se2::new(
            c.0 as f64 * params.step_m,
            c.1 as f64 * params.step_m,
            theta,
        )
    };
    let truth_poses: Vec<Se2> = (0..params.num_poses).map(truth_pose).collect();

    let information = Matrix3::from_diagonal(&nalgebra::Vector3::new(
        1.0 / (params.sigma_xy_m * params.sigma_xy_m),
        1.0 / (params.sigma_xy_m * params.sigma_xy_m),
        1.0 / (params.sigma_theta_rad * params.sigma_theta_rad),
    ));
    let noisy_measurement = |from: &Se2, to: &Se2, rng: &mut SimRng| {
        let noise = Se2::new(
            gaussian(rng) * params.sigma_xy_m,
            gaussian(rng) * params.sigma_xy_m,
            gaussian(rng) * params.sigma_theta_rad,
        );
        from.between(to).compose(&noise)
    };

    // 2. Odometry edges.
    let mut edges: Vec<Edge<Se2, 3>> = Vec::with_capacity(params.num_poses * 2);
    for k in 1..params.num_poses {
        let measurement = noisy_measurement(&truth_poses[k - 1], &truth_poses[k], &mut rng);
        edges.push(Edge {
            from: NodeId(k as u64 - 1),
            to: NodeId(k as u64),
            measurement,
            information,
            kind: EdgeKind::Odometry,
        });
    }

    // 3. Loop closures between poses that come within `loop_radius_m` (cell hash, ground truth).
    let reach = (params.loop_radius_m / params.step_m).ceil() as i64;
    let mut by_cell: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    for j in 0..params.num_poses {
        if j >= params.min_loop_separation {
            let i_new = j - params.min_loop_separation;
            by_cell.entry(cells[i_new]).or_default().push(i_new);
        }
        let mut candidates: Vec<usize> = Vec::new();
        for dx in -reach..=reach {
            for dy in -reach..=reach {
                if let Some(list) = by_cell.get(&(cells[j].0 + dx, cells[j].1 + dy)) {
                    candidates.extend(list.iter().copied());
                }
            }
        }
        candidates.sort_unstable();
        for i in candidates {
            let (pi, pj) = (truth_poses[i].translation(), truth_poses[j].translation());
            if (pi - pj).norm() >= params.loop_radius_m {
                continue;
            }
            if rng.random::<f64>() >= params.loop_probability {
                continue;
            }
            let measurement = noisy_measurement(&truth_poses[i], &truth_poses[j], &mut rng);
            edges.push(Edge {
                from: NodeId(i as u64),
                to: NodeId(j as u64),
                measurement,
                information,
                kind: EdgeKind::Loop,
            });
        }
    }

    // 4. The graphs: ground truth, and the odometry-chained initial guess.
    let mut truth = PoseGraph2::new();
    let mut noisy = PoseGraph2::new();
    let mut guess = Se2::identity();
    for (k, pose) in truth_poses.iter().enumerate() {
        if k > 0 {
            guess = guess.compose(&edges[k - 1].measurement);
        }
        truth.add_vertex(NodeId(k as u64), Vertex::new(*pose))?;
        noisy.add_vertex(NodeId(k as u64), Vertex::new(guess))?;
    }
    for edge in edges {
        truth.add_edge(edge)?;
        noisy.add_edge(edge)?;
    }
    Ok((noisy, truth))
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;
    use crate::count_loop_closures;

    #[test]
    fn default_world_is_reproducible_and_well_formed() {
        let p = ManhattanParams::default();
        let (noisy, truth) = simulate_manhattan_2d(&p, 1).unwrap();
        let (noisy2, truth2) = simulate_manhattan_2d(&p, 1).unwrap();
        assert_eq!(noisy, noisy2);
        assert_eq!(truth, truth2);
        let (other, _) = simulate_manhattan_2d(&p, 2).unwrap();
        assert_ne!(noisy, other);

        assert_eq!(noisy.num_vertices(), 500);
        assert_eq!(truth.num_vertices(), 500);
        let loops = count_loop_closures(&noisy);
        assert!((100..2000).contains(&loops), "{loops} loop closures");
        assert_eq!(noisy.num_edges(), 499 + loops);
        // Same edges in both graphs.
        assert!(noisy.edges().zip(truth.edges()).all(|(a, b)| a == b));
        for (id, e) in noisy.edges() {
            if id.0 < 499 {
                assert_eq!((e.kind, e.to.0), (EdgeKind::Odometry, e.from.0 + 1));
            } else {
                assert_eq!(e.kind, EdgeKind::Loop);
                assert!(e.to.0 >= e.from.0 + 10);
            }
        }
        // Ground truth on the grid, inside the world, unit steps.
        let h = (p.world_size_m / 2.0).floor();
        for (_, v) in truth.vertices() {
            assert!(v.pose.x_m.abs() <= h && v.pose.y_m.abs() <= h);
            assert_eq!(v.pose.x_m, v.pose.x_m.round());
        }
        // Vertex 0 at the identity in both.
        assert_eq!(noisy.vertex(NodeId(0)).unwrap().pose, Se2::identity());
        assert_eq!(truth.vertex(NodeId(0)).unwrap().pose, Se2::identity());
    }

    #[test]
    fn chi2_at_truth_matches_the_noise_model() {
        // Σ rᵀΩr over E edges with 3-dof whitened noise is χ²(3E): mean 3E, sd √(6E).
        let (noisy, truth) = simulate_manhattan_2d(&ManhattanParams::default(), 11).unwrap();
        let e = truth.num_edges() as f64;
        let chi2 = truth.chi2();
        assert!(
            (chi2 - 3.0 * e).abs() < 5.0 * (6.0 * e).sqrt(),
            "chi2 {chi2} for {e} edges"
        );
        // The odometry guess drifts: its chi2 is dominated by the loop closures.
        assert!(noisy.chi2() > 10.0 * chi2);
    }

    #[test]
    fn odometry_guess_fits_odometry_exactly() {
        let (noisy, _) = simulate_manhattan_2d(&ManhattanParams::default(), 3).unwrap();
        for (_, e) in noisy.edges().filter(|(_, e)| e.kind == EdgeKind::Odometry) {
            assert!(noisy.edge_chi2(e).unwrap() < 1e-12);
        }
    }

    #[test]
    fn rejects_bad_params() {
        let base = ManhattanParams::default();
        let cases = [
            ManhattanParams {
                num_poses: 1,
                ..base
            },
            ManhattanParams {
                step_m: 0.0,
                ..base
            },
            ManhattanParams {
                world_size_m: 1.0,
                ..base
            },
            ManhattanParams {
                world_size_m: f64::NAN,
                ..base
            },
            ManhattanParams {
                turn_probability: 1.5,
                ..base
            },
            ManhattanParams {
                sigma_xy_m: 0.0,
                ..base
            },
            ManhattanParams {
                sigma_theta_rad: -1.0,
                ..base
            },
            ManhattanParams {
                loop_radius_m: f64::INFINITY,
                ..base
            },
            ManhattanParams {
                loop_probability: -0.1,
                ..base
            },
            ManhattanParams {
                min_loop_separation: 1,
                ..base
            },
        ];
        for p in cases {
            assert!(
                matches!(
                    simulate_manhattan_2d(&p, 0),
                    Err(EvalError::InvalidParams { .. })
                ),
                "{p:?}"
            );
        }
    }

    #[test]
    fn tiny_world_still_walks() {
        let p = ManhattanParams {
            world_size_m: 2.0,
            num_poses: 50,
            turn_probability: 0.0,
            ..Default::default()
        };
        let (_, truth) = simulate_manhattan_2d(&p, 4).unwrap();
        for (_, v) in truth.vertices() {
            assert!(v.pose.x_m.abs() <= 1.0 && v.pose.y_m.abs() <= 1.0);
        }
        for (_, e) in truth.edges().filter(|(_, e)| e.kind == EdgeKind::Odometry) {
            assert!((e.measurement.translation().norm() - 1.0).abs() < 0.5);
        }
    }
}

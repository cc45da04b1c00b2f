//! Marginal covariances of chosen vertices from the sparse Cholesky factor of `H`.

use mapmerge_geometry::LieGroup;
use mapmerge_posegraph::{NodeId, PoseGraph};
use nalgebra::SMatrix;

use crate::error::SolveError;
use crate::optimizer::Session;
use crate::problem::Problem;
use crate::robust::RobustKernel;

/// Vertices per multi-right-hand-side solve.
const VERTICES_PER_SOLVE: usize = 64;

/// The marginal covariance of each requested vertex, in its tangent space (right perturbation,
/// the convention of GTSAM's `Marginals`), at the graph's current poses.
///
/// Computed as the diagonal blocks of `H⁻¹` by solving `H X = E` for the requested columns.
/// Fixed vertices (including the gauge vertex) have zero covariance.
pub fn marginal_covariances<G: LieGroup<D>, const D: usize>(
    graph: &PoseGraph<G, D>,
    vertices: &[NodeId],
) -> Result<Vec<SMatrix<f64, D, D>>, SolveError> {
    let mut problem = Problem::compile(graph)?;
    let mut session = Session::new(&mut problem)?;
    let weights = vec![1.0; problem.edges.len()];
    session.linearize(&problem, &weights, &RobustKernel::None);
    let dim = session.normal.dim();
    let mut slots = Vec::with_capacity(vertices.len());
    for id in vertices {
        let index = problem
            .ids
            .binary_search(id)
            .map_err(|_| SolveError::BadVertex(*id, "no such vertex"))?;
        slots.push(Session::<G, D>::slot_of(&problem, index));
    }
    let mut out = vec![SMatrix::<f64, D, D>::zeros(); vertices.len()];
    let free: Vec<(usize, usize)> = slots
        .iter()
        .enumerate()
        .filter_map(|(k, s)| s.map(|s| (k, s)))
        .collect();
    for chunk in free.chunks(VERTICES_PER_SOLVE) {
        let ncols = chunk.len() * D;
        let mut rhs = vec![0.0; dim * ncols];
        for (c, &(_, slot)) in chunk.iter().enumerate() {
            for a in 0..D {
                rhs[(c * D + a) * dim + slot * D + a] = 1.0;
            }
        }
        if !session.normal.solve_undamped(&mut rhs, ncols) {
            return Err(SolveError::NotPositiveDefinite(
                "information matrix is singular; some vertex is unconstrained".into(),
            ));
        }
        for (c, &(k, slot)) in chunk.iter().enumerate() {
            for a in 0..D {
                for b in 0..D {
                    out[k][(b, a)] = rhs[(c * D + a) * dim + slot * D + b];
                }
            }
        }
    }
    Ok(out)
}

//! TUM trajectory format (Sturm et al., TUM RGB-D benchmark): one line
//! `stamp x y z qx qy qz qw` per vertex, in id order. Planar poses get `z = 0` and a rotation
//! about z. The stamp is the vertex's `meta.stamp_secs`, or its id when it has none.

use std::path::Path;

use mapmerge_geometry::LieGroup;
use mapmerge_posegraph::PoseGraph;
use nalgebra::{UnitQuaternion, Vector3};

use crate::writer::{push_fields, save, write_f64};
use crate::{AnyGraph, IoError};

/// The TUM text of `graph`; `pose_fields` gives a pose's `x y z qx qy qz qw`.
fn tum_fields<G: LieGroup<D>, const D: usize>(
    graph: &PoseGraph<G, D>,
    pose_fields: impl Fn(&G) -> [f64; 7],
) -> Result<String, IoError> {
    let mut out = String::with_capacity(graph.num_vertices() * 96);
    for (id, vertex) in graph.vertices() {
        // Ids above 2^53 lose precision as stamps; they are only a fallback ordering key.
        let stamp = vertex.meta.stamp_secs.unwrap_or(id.0 as f64);
        if !vertex.pose.is_finite() || !stamp.is_finite() {
            return Err(IoError::Unwritable {
                format: "TUM",
                reason: format!("vertex {id} has a non-finite pose or stamp"),
            });
        }
        write_f64(&mut out, stamp);
        push_fields(&mut out, pose_fields(&vertex.pose));
        out.push('\n');
    }
    Ok(out)
}

/// The TUM text of a graph's vertices (`stamp x y z qx qy qz qw` per line, id order).
pub fn format_tum(graph: &AnyGraph) -> Result<String, IoError> {
    match graph {
        AnyGraph::Planar(g) => tum_fields(g, |p| {
            let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), p.theta_rad);
            [p.x_m, p.y_m, 0.0, q.i, q.j, q.k, q.w]
        }),
        AnyGraph::Spatial(g) => tum_fields(g, |p| {
            let (t, q) = (&p.translation_m, p.rotation.quaternion());
            [t.x, t.y, t.z, q.i, q.j, q.k, q.w]
        }),
    }
}

/// Writes the TUM trajectory of a graph's vertices to `path` (xz-compressed if it ends in
/// `.xz`).
pub fn write_tum(path: &Path, graph: &AnyGraph) -> Result<(), IoError> {
    save(path, &format_tum(graph)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapmerge_geometry::Se2;
    use mapmerge_posegraph::{NodeId, PoseGraph2, Vertex};

    #[test]
    fn planar_poses_become_z_rotations_and_stamps_fall_back_to_ids() {
        let mut g = PoseGraph2::new();
        let half_pi = core::f64::consts::FRAC_PI_2;
        let _ = g.add_vertex(NodeId(7), Vertex::new(Se2::new(1.0, 2.0, half_pi)));
        let mut stamped = Vertex::new(Se2::new(0.0, 0.0, 0.0));
        stamped.meta.stamp_secs = Some(12.5);
        let _ = g.add_vertex(NodeId(8), stamped);
        let text = format_tum(&AnyGraph::Planar(g)).unwrap_or_else(|e| panic!("{e}"));
        let lines: Vec<Vec<f64>> = text
            .lines()
            .map(|l| {
                l.split(' ')
                    .map(|t| t.parse().unwrap_or(f64::NAN))
                    .collect()
            })
            .collect();
        assert_eq!(lines.len(), 2);
        assert_eq!(lines[0][..4], [7.0, 1.0, 2.0, 0.0]);
        let s = (half_pi / 2.0).sin();
        assert!((lines[0][6] - s).abs() < 1e-15 && (lines[0][7] - s).abs() < 1e-15);
        assert_eq!(lines[1], [12.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
    }

    #[test]
    fn non_finite_pose_is_an_error() {
        let mut g = PoseGraph2::new();
        let _ = g.add_vertex(
            NodeId(0),
            Vertex::new(Se2 {
                x_m: f64::NAN,
                y_m: 0.0,
                theta_rad: 0.0,
            }),
        );
        assert!(matches!(
            format_tum(&AnyGraph::Planar(g)),
            Err(IoError::Unwritable { .. })
        ));
    }
}

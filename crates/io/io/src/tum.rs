//! TUM trajectory format (Sturm et al., TUM RGB-D benchmark): one line
//! `stamp x y z qx qy qz qw` per pose. Graphs are written one vertex per line in id order,
//! the stamp being the vertex's `meta.stamp_secs`, or its id when it has none. Planar poses
//! get `z = 0` and a rotation about z; planar trajectories are read back keeping `x`, `y` and
//! the yaw of the rotation.

use std::path::Path;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::PoseGraph;
use nalgebra::{UnitQuaternion, Vector3};

use crate::input::read_text;
use crate::reader::{data_lines, parse_error, parse_f64s, unit_quaternion, LineResult};
use crate::writer::{push_fields, save, write_f64};
use crate::{AnyGraph, IoError};

/// `x y z qx qy qz qw` of a planar pose: `z = 0`, a rotation by `theta_rad` about z.
fn planar_fields(pose: &Se2) -> [f64; 7] {
    let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), pose.theta_rad);
    [pose.x_m, pose.y_m, 0.0, q.i, q.j, q.k, q.w]
}

/// Appends one TUM line: the stamp and the seven pose fields.
fn push_line(out: &mut String, stamp: f64, fields: [f64; 7]) {
    write_f64(out, stamp);
    push_fields(out, fields);
    out.push('\n');
}

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
        push_line(&mut out, stamp, pose_fields(&vertex.pose));
    }
    Ok(out)
}

/// The TUM text of a graph's vertices (`stamp x y z qx qy qz qw` per line, id order).
pub fn format_tum(graph: &AnyGraph) -> Result<String, IoError> {
    match graph {
        AnyGraph::Planar(g) => tum_fields(g, planar_fields),
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

/// Reads a planar TUM trajectory (plain or xz-compressed); see [`parse_tum_planar`].
pub fn read_tum_planar(path: &Path) -> Result<Vec<(f64, Se2)>, IoError> {
    let text = read_text(path)?;
    parse_tum_planar(&text, &path.display().to_string())
}

/// Parses a TUM trajectory as planar poses: `(stamp, pose)` per line in file order, keeping
/// `x`, `y` and the yaw of the rotation (`z`, roll and pitch are dropped without a check).
/// Blank lines and `#` comments are skipped. Lines without exactly 8 finite numbers, and
/// quaternions further than 0.01 from unit norm, are [`IoError::Parse`] errors.
pub fn parse_tum_planar(text: &str, source: &str) -> Result<Vec<(f64, Se2)>, IoError> {
    let mut poses = Vec::new();
    for line in data_lines(text) {
        let mut tokens = [""; 8];
        let mut count = 0;
        for token in core::iter::once(line.tag).chain(line.fields.rest()) {
            if let Some(slot) = tokens.get_mut(count) {
                *slot = token;
            }
            count += 1;
        }
        let parsed = if count == tokens.len() {
            planar_pose(&tokens)
        } else {
            Err(format!(
                "expected 8 fields (stamp x y z qx qy qz qw), found {count}"
            ))
        };
        poses.push(parsed.map_err(|reason| parse_error(source, line.number, reason))?);
    }
    Ok(poses)
}

/// `(stamp, pose)` from the 8 fields of a TUM line (field numbers count from 1 at the stamp).
fn planar_pose(tokens: &[&str; 8]) -> LineResult<(f64, Se2)> {
    let [stamp, x, y, _z, qx, qy, qz, qw] = parse_f64s::<8>(tokens, 0)?;
    let q = unit_quaternion(qx, qy, qz, qw)?;
    Ok((stamp, Se2::new(x, y, yaw_rad(&q))))
}

/// The yaw (rotation about z) of `q` in the z-y-x (yaw-pitch-roll) convention.
fn yaw_rad(q: &UnitQuaternion<f64>) -> f64 {
    let (w, x, y, z) = (q.w, q.i, q.j, q.k);
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

/// The TUM text of a planar trajectory: `stamp x y 0 0 0 qz qw` per pose, in the given order.
/// Non-finite stamps or poses are [`IoError::Unwritable`].
pub fn format_tum_planar(poses: &[(f64, Se2)]) -> Result<String, IoError> {
    let mut out = String::with_capacity(poses.len() * 96);
    for (k, (stamp, pose)) in poses.iter().enumerate() {
        if !pose.is_finite() || !stamp.is_finite() {
            return Err(IoError::Unwritable {
                format: "TUM",
                reason: format!("pose {k} has a non-finite pose or stamp"),
            });
        }
        push_line(&mut out, *stamp, planar_fields(pose));
    }
    Ok(out)
}

/// Writes a planar trajectory as TUM (see [`format_tum_planar`]), xz-compressed when the path
/// ends in `.xz`.
pub fn write_tum_planar(path: &Path, poses: &[(f64, Se2)]) -> Result<(), IoError> {
    save(path, &format_tum_planar(poses)?)
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

    #[test]
    fn planar_trajectories_round_trip_to_rounding() {
        let poses = vec![
            (0.5, Se2::new(1.0, -2.0, 0.25)),
            (1.0, Se2::new(0.0, 0.0, core::f64::consts::PI)),
            (1.5, Se2::new(3.0, 4.0, -3.0)),
            (2.0, Se2::new(-0.0, 1e-9, 0.0)),
        ];
        let text = format_tum_planar(&poses).unwrap_or_else(|e| panic!("{e}"));
        let back = parse_tum_planar(&text, "t.tum").unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(back.len(), poses.len());
        for ((t0, p0), (t1, p1)) in poses.iter().zip(&back) {
            assert_eq!((t0, p0.x_m, p0.y_m), (t1, p1.x_m, p1.y_m));
            assert!(p0.between(p1).theta_rad.abs() < 1e-15, "{p0:?} {p1:?}");
        }
    }
}

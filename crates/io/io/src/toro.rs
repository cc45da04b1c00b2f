//! The TORO / HOG-Man text format (Grisetti et al., TORO; HOG-Man `README-fileformat.txt`).
//!
//! 2D: `VERTEX2 id x y θ`, `EDGE2 i j dx dy dθ I11 I12 I22 I33 I13 I23` (note the order;
//! `VERTEX`/`EDGE` are accepted as synonyms, as TORO does).
//! 3D: `VERTEX3 id x y z roll pitch yaw`, `EDGE3 i j x y z roll pitch yaw` + 21
//! upper-triangular information entries over `(x, y, z, roll, pitch, yaw)`. The rotation is
//! `Rz(yaw) · Ry(pitch) · Rx(roll)` (TORO's and GTSAM's `Rot3::Ypr`); the information is
//! reordered to our `(ω, v)` tangent order, reading the small-angle roll/pitch/yaw errors as
//! rotation-vector components.
//!
//! TORO has no fixed vertices and no priors: `FIX` flags are not written, priors cannot be.

use mapmerge_geometry::{Se2, Se3};
use mapmerge_posegraph::{PoseGraph2, PoseGraph3};
use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use crate::reader::{
    build_graph, from_upper_row_major, parse_f64s, parse_id, se2, swap_translation_rotation,
    upper_row_major, Built, Dim, LineResult,
};
use crate::writer::{push_fields, push_id};
use crate::{GraphFormat, IoError, ReadParams};

/// TORO's 2D information order `I11 I12 I22 I33 I13 I23` as `(row, col)` pairs.
const PLANAR_INFO_ORDER: [(usize, usize); 6] = [(0, 0), (0, 1), (1, 1), (2, 2), (0, 2), (1, 2)];

fn planar_information(values: &[f64; 6]) -> Matrix3<f64> {
    let mut m = Matrix3::zeros();
    for ((i, j), v) in PLANAR_INFO_ORDER.iter().zip(values.iter()) {
        m[(*i % 3, *j % 3)] = *v;
        m[(*j % 3, *i % 3)] = *v;
    }
    m
}

/// Parses a 2D TORO file.
pub(crate) fn parse_planar(
    text: &str,
    file: &str,
    params: &ReadParams,
) -> Result<Built<Se2, 3>, IoError> {
    build_graph(
        text,
        file,
        params,
        GraphFormat::Toro,
        Dim::Planar,
        "VERTEX2",
        |b, tag, fields| {
            match tag {
                "VERTEX2" | "VERTEX" => {
                    let f = fields.exactly::<4>()?;
                    let id = parse_id(f[0], 1)?;
                    let [x, y, theta] = parse_f64s::<3>(&f, 1)?;
                    b.add_vertex(id, se2(x, y, theta))?;
                }
                "EDGE2" | "EDGE" => {
                    let f = fields.exactly::<11>()?;
                    let (from, to) = (parse_id(f[0], 1)?, parse_id(f[1], 2)?);
                    let [x, y, theta] = parse_f64s::<3>(&f, 2)?;
                    let info = parse_f64s::<6>(&f, 5)?;
                    b.add_edge(from, to, se2(x, y, theta), planar_information(&info))?;
                }
                _ => return Ok(false),
            }
            Ok(true)
        },
    )
}

/// `x y z roll pitch yaw` starting at `tokens[start]`.
fn parse_pose3(tokens: &[&str], start: usize) -> LineResult<Se3> {
    let [x, y, z, roll, pitch, yaw] = parse_f64s::<6>(tokens, start)?;
    let rotation = UnitQuaternion::from_euler_angles(roll, pitch, yaw);
    Ok(Se3::new(rotation, Vector3::new(x, y, z)))
}

/// Parses a 3D TORO file.
pub(crate) fn parse_spatial(
    text: &str,
    file: &str,
    params: &ReadParams,
) -> Result<Built<Se3, 6>, IoError> {
    build_graph(
        text,
        file,
        params,
        GraphFormat::Toro,
        Dim::Spatial,
        "VERTEX3",
        |b, tag, fields| {
            match tag {
                "VERTEX3" => {
                    let f = fields.exactly::<7>()?;
                    let id = parse_id(f[0], 1)?;
                    b.add_vertex(id, parse_pose3(&f, 1)?)?;
                }
                "EDGE3" => {
                    let f = fields.exactly::<29>()?;
                    let (from, to) = (parse_id(f[0], 1)?, parse_id(f[1], 2)?);
                    let measurement = parse_pose3(&f, 2)?;
                    let values = parse_f64s::<21>(&f, 8)?;
                    let info = swap_translation_rotation(&from_upper_row_major::<6>(&values));
                    b.add_edge(from, to, measurement, info)?;
                }
                _ => return Ok(false),
            }
            Ok(true)
        },
    )
}

fn unwritable_prior() -> IoError {
    IoError::Unwritable {
        format: "TORO",
        reason: "the graph has prior edges, which TORO cannot express (use g2o)".to_owned(),
    }
}

/// Writes a 2D graph: vertices, then edges, in id order. Fixed flags are not written.
pub(crate) fn write_planar(out: &mut String, graph: &PoseGraph2) -> Result<(), IoError> {
    if graph.edges().any(|(_, e)| e.is_prior()) {
        return Err(unwritable_prior());
    }
    for (id, vertex) in graph.vertices() {
        out.push_str("VERTEX2");
        push_id(out, id.0);
        let p = &vertex.pose;
        push_fields(out, [p.x_m, p.y_m, p.theta_rad]);
        out.push('\n');
    }
    for (_, edge) in graph.edges() {
        out.push_str("EDGE2");
        push_id(out, edge.from.0);
        push_id(out, edge.to.0);
        let z = &edge.measurement;
        push_fields(out, [z.x_m, z.y_m, z.theta_rad]);
        let info = &edge.information;
        push_fields(
            out,
            PLANAR_INFO_ORDER
                .iter()
                .map(|(i, j)| info[(*i % 3, *j % 3)]),
        );
        out.push('\n');
    }
    Ok(())
}

fn push_pose3(out: &mut String, pose: &Se3) {
    let (roll, pitch, yaw) = pose.rotation.euler_angles();
    let t = &pose.translation_m;
    push_fields(out, [t.x, t.y, t.z, roll, pitch, yaw]);
}

/// Writes a 3D graph: vertices, then edges, in id order. Rotations go through roll/pitch/yaw,
/// so poses read back equal only to rounding (about 1e-15); information is exact.
pub(crate) fn write_spatial(out: &mut String, graph: &PoseGraph3) -> Result<(), IoError> {
    if graph.edges().any(|(_, e)| e.is_prior()) {
        return Err(unwritable_prior());
    }
    for (id, vertex) in graph.vertices() {
        out.push_str("VERTEX3");
        push_id(out, id.0);
        push_pose3(out, &vertex.pose);
        out.push('\n');
    }
    for (_, edge) in graph.edges() {
        out.push_str("EDGE3");
        push_id(out, edge.from.0);
        push_id(out, edge.to.0);
        push_pose3(out, &edge.measurement);
        let file_order = swap_translation_rotation(&edge.information);
        push_fields(out, upper_row_major(&file_order));
        out.push('\n');
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn planar_information_uses_toro_order() {
        let text = "VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 11 12 22 33 13 23\n";
        let Built { graph: g, .. } =
            parse_planar(text, "t.graph", &ReadParams::default()).unwrap_or_else(|e| panic!("{e}"));
        let (_, e) = g.edges().next().unwrap_or_else(|| panic!("no edge"));
        let expected = Matrix3::new(11.0, 12.0, 13.0, 12.0, 22.0, 23.0, 13.0, 23.0, 33.0);
        assert_eq!(e.information, expected);
        let mut out = String::new();
        write_planar(&mut out, &g).unwrap_or_else(|e| panic!("{e}"));
        assert!(
            out.ends_with("EDGE2 0 1 1 0 0 11 12 22 33 13 23\n"),
            "{out}"
        );
    }

    #[test]
    fn spatial_rotation_is_rz_ry_rx() {
        let (roll, pitch, yaw) = (-0.256, 0.2, 0.272);
        let text = format!("VERTEX3 1 19 2.35 98.2 {roll} {pitch} {yaw}\n");
        let Built {
            graph: g,
            had_vertices,
            ..
        } = parse_spatial(&text, "t.graph", &ReadParams::default())
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(had_vertices);
        let pose = g
            .vertices()
            .next()
            .map(|(_, v)| v.pose)
            .unwrap_or_else(|| panic!("no vertex"));
        let rz = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
        let ry = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), pitch);
        let rx = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), roll);
        assert!(pose.rotation.angle_to(&(rz * ry * rx)) < 1e-12);
        // The same vertex in se-sync/sphere_bignoise_vertex3.g2o (rounded to 6 digits there).
        let q = pose.rotation.quaternion();
        assert!(
            (q.i - -0.139007).abs() < 1e-3 && (q.w - 0.976059).abs() < 1e-3,
            "{q:?}"
        );
    }
}

//! The g2o text format (Kümmerle et al., "g2o: A General Framework for Graph Optimization",
//! ICRA 2011; tags as registered in g2o's `types_slam2d` / `types_slam3d`).
//!
//! 2D: `VERTEX_SE2 id x y θ`, `EDGE_SE2 i j dx dy dθ` + upper-triangular information
//! `I11 I12 I13 I22 I23 I33`, `EDGE_PRIOR_SE2 id x y θ` + the same 6 entries.
//! 3D: `VERTEX_SE3:QUAT id x y z qx qy qz qw`, `EDGE_SE3:QUAT i j x y z qx qy qz qw` + 21
//! upper-triangular entries in `(t, r)` order, and `EDGE_SE3_PRIOR id param x y z qx qy qz qw`
//! with the same 21 entries, where `param` names an identity
//! `PARAMS_SE3OFFSET param 0 0 0 0 0 0 1`.
//! Both: `FIX id [id …]`.

use std::collections::BTreeSet;

use mapmerge_geometry::{Se2, Se3};
use mapmerge_posegraph::{PoseGraph2, PoseGraph3};
use nalgebra::{Matrix3, Matrix6, Vector3};

use crate::reader::{
    build_graph, from_upper_row_major, handle_fix, parse_f64s, parse_id, se2,
    swap_translation_rotation, unit_quaternion, upper_row_major, Built, Dim, LineResult,
};
use crate::writer::{push_fields, push_id};
use crate::{GraphFormat, IoError, ReadParams};

/// Parses a 2D g2o file.
pub(crate) fn parse_planar(
    text: &str,
    file: &str,
    params: &ReadParams,
) -> Result<Built<Se2, 3>, IoError> {
    build_graph(
        text,
        file,
        params,
        GraphFormat::G2o,
        Dim::Planar,
        "VERTEX_SE2",
        |b, tag, fields| {
            match tag {
                "VERTEX_SE2" => {
                    let f = fields.exactly::<4>()?;
                    let id = parse_id(f[0], 1)?;
                    let [x, y, theta] = parse_f64s::<3>(&f, 1)?;
                    b.add_vertex(id, se2(x, y, theta))?;
                }
                "EDGE_SE2" => {
                    let f = fields.exactly::<11>()?;
                    let (from, to) = (parse_id(f[0], 1)?, parse_id(f[1], 2)?);
                    let [x, y, theta] = parse_f64s::<3>(&f, 2)?;
                    let info = parse_f64s::<6>(&f, 5)?;
                    b.add_edge(from, to, se2(x, y, theta), from_upper_row_major::<3>(&info))?;
                }
                "EDGE_PRIOR_SE2" => {
                    let f = fields.exactly::<10>()?;
                    let id = parse_id(f[0], 1)?;
                    let [x, y, theta] = parse_f64s::<3>(&f, 1)?;
                    let info = parse_f64s::<6>(&f, 4)?;
                    b.add_prior(id, se2(x, y, theta), from_upper_row_major::<3>(&info))?;
                }
                "FIX" => handle_fix(b, fields)?,
                _ => return Ok(false),
            }
            Ok(true)
        },
    )
}

/// `x y z qx qy qz qw` starting at `tokens[start]`.
fn parse_se3(tokens: &[&str], start: usize) -> LineResult<Se3> {
    let [x, y, z, qx, qy, qz, qw] = parse_f64s::<7>(tokens, start)?;
    Ok(Se3::new(
        unit_quaternion(qx, qy, qz, qw)?,
        Vector3::new(x, y, z),
    ))
}

/// 21 upper-triangular entries in g2o's `(t, r)` order, as an information matrix in our
/// `(ω, v)` order.
fn parse_information6(tokens: &[&str], start: usize) -> LineResult<Matrix6<f64>> {
    let values = parse_f64s::<21>(tokens, start)?;
    Ok(swap_translation_rotation(&from_upper_row_major::<6>(
        &values,
    )))
}

/// Parses a 3D g2o file.
pub(crate) fn parse_spatial(
    text: &str,
    file: &str,
    params: &ReadParams,
) -> Result<Built<Se3, 6>, IoError> {
    // PARAMS_SE3OFFSET ids seen so far; only identity offsets are accepted.
    let mut offsets: BTreeSet<u64> = BTreeSet::new();
    build_graph(
        text,
        file,
        params,
        GraphFormat::G2o,
        Dim::Spatial,
        "VERTEX_SE3:QUAT",
        |b, tag, fields| {
            match tag {
                "VERTEX_SE3:QUAT" => {
                    let f = fields.exactly::<8>()?;
                    let id = parse_id(f[0], 1)?;
                    b.add_vertex(id, parse_se3(&f, 1)?)?;
                }
                "EDGE_SE3:QUAT" => {
                    let f = fields.exactly::<30>()?;
                    let (from, to) = (parse_id(f[0], 1)?, parse_id(f[1], 2)?);
                    let measurement = parse_se3(&f, 2)?;
                    b.add_edge(from, to, measurement, parse_information6(&f, 9)?)?;
                }
                "EDGE_SE3_PRIOR" => {
                    let f = fields.exactly::<30>()?;
                    let id = parse_id(f[0], 1)?;
                    let param = parse_id(f[1], 2)?;
                    if !offsets.contains(&param) {
                        return Err(format!(
                            "EDGE_SE3_PRIOR uses parameter {param}, which no earlier \
                         PARAMS_SE3OFFSET line defines"
                        ));
                    }
                    let measurement = parse_se3(&f, 2)?;
                    b.add_prior(id, measurement, parse_information6(&f, 9)?)?;
                }
                "PARAMS_SE3OFFSET" => {
                    let f = fields.exactly::<8>()?;
                    let param = parse_id(f[0], 1)?;
                    let [x, y, z, qx, qy, qz, qw] = parse_f64s::<7>(&f, 1)?;
                    if [x, y, z, qx, qy, qz] != [0.0; 6] || qw <= 0.0 {
                        return Err(
                            "only identity PARAMS_SE3OFFSET (0 0 0 0 0 0 1) is supported"
                                .to_owned(),
                        );
                    }
                    if !offsets.insert(param) {
                        return Err(format!("duplicate PARAMS_SE3OFFSET id {param}"));
                    }
                }
                "FIX" => handle_fix(b, fields)?,
                _ => return Ok(false),
            }
            Ok(true)
        },
    )
}

fn push_information3(out: &mut String, info: &Matrix3<f64>) {
    push_fields(out, upper_row_major(info));
}

fn push_information6(out: &mut String, info: &Matrix6<f64>) {
    let file_order = swap_translation_rotation(info);
    push_fields(out, upper_row_major(&file_order));
}

fn push_se2(out: &mut String, pose: &Se2) {
    push_fields(out, [pose.x_m, pose.y_m, pose.theta_rad]);
}

fn push_se3(out: &mut String, pose: &Se3) {
    let q = pose.rotation.quaternion();
    let t = &pose.translation_m;
    push_fields(out, [t.x, t.y, t.z, q.i, q.j, q.k, q.w]);
}

/// Appends the `FIX` lines of `fixed` ids.
fn push_fixes(out: &mut String, fixed: impl Iterator<Item = u64>) {
    for id in fixed {
        out.push_str("FIX");
        push_id(out, id);
        out.push('\n');
    }
}

/// Writes a 2D graph: vertices, `FIX` lines, then edges, each in id order.
pub(crate) fn write_planar(out: &mut String, graph: &PoseGraph2) {
    for (id, vertex) in graph.vertices() {
        out.push_str("VERTEX_SE2");
        push_id(out, id.0);
        push_se2(out, &vertex.pose);
        out.push('\n');
    }
    push_fixes(
        out,
        graph
            .vertices()
            .filter(|(_, v)| v.fixed)
            .map(|(id, _)| id.0),
    );
    for (_, edge) in graph.edges() {
        if edge.is_prior() {
            out.push_str("EDGE_PRIOR_SE2");
            push_id(out, edge.to.0);
        } else {
            out.push_str("EDGE_SE2");
            push_id(out, edge.from.0);
            push_id(out, edge.to.0);
        }
        push_se2(out, &edge.measurement);
        push_information3(out, &edge.information);
        out.push('\n');
    }
}

/// Writes a 3D graph: vertices, `FIX` lines, an identity `PARAMS_SE3OFFSET 0` if there are
/// priors, then edges, each in id order.
pub(crate) fn write_spatial(out: &mut String, graph: &PoseGraph3) {
    for (id, vertex) in graph.vertices() {
        out.push_str("VERTEX_SE3:QUAT");
        push_id(out, id.0);
        push_se3(out, &vertex.pose);
        out.push('\n');
    }
    push_fixes(
        out,
        graph
            .vertices()
            .filter(|(_, v)| v.fixed)
            .map(|(id, _)| id.0),
    );
    if graph.edges().any(|(_, e)| e.is_prior()) {
        out.push_str("PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1\n");
    }
    for (_, edge) in graph.edges() {
        if edge.is_prior() {
            out.push_str("EDGE_SE3_PRIOR");
            push_id(out, edge.to.0);
            push_id(out, 0);
        } else {
            out.push_str("EDGE_SE3:QUAT");
            push_id(out, edge.from.0);
            push_id(out, edge.to.0);
        }
        push_se3(out, &edge.measurement);
        push_information6(out, &edge.information);
        out.push('\n');
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mapmerge_posegraph::{EdgeKind, NodeId};

    #[test]
    fn reads_a_small_planar_graph() {
        let text = "# comment\nVERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0.5\n\nFIX 0\n\
                    EDGE_SE2 0 1 1 0 0.5 10 1 2 20 3 30\n";
        let Built {
            graph: g,
            had_vertices,
            ..
        } = parse_planar(text, "t.g2o", &ReadParams::default()).unwrap_or_else(|e| panic!("{e}"));
        assert!(had_vertices);
        assert_eq!(g.num_vertices(), 2);
        assert!(g.vertex(NodeId(0)).is_some_and(|v| v.fixed));
        let (_, e) = g.edges().next().unwrap_or_else(|| panic!("no edge"));
        assert_eq!(e.kind, EdgeKind::Odometry);
        assert_eq!(
            e.information,
            Matrix3::new(10.0, 1.0, 2.0, 1.0, 20.0, 3.0, 2.0, 3.0, 30.0)
        );
    }

    #[test]
    fn information_reordered_on_read_and_back_on_write() {
        // Translation block 1, 2, 3 on the diagonal, rotation 4, 5, 6, and a t–r coupling
        // g2o[0][4] = 0.5 (x with ω_y).
        let mut info = [0.0; 21];
        let diag_positions = [0, 6, 11, 15, 18, 20];
        for (k, p) in diag_positions.iter().enumerate() {
            info[*p] = (k + 1) as f64 * 10.0;
        }
        info[4] = 0.5;
        let info_text: Vec<String> = info.iter().map(|v| v.to_string()).collect();
        let text = format!(
            "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\n\
             EDGE_SE3:QUAT 0 1 1 2 3 0 0 0 1 {}\n",
            info_text.join(" ")
        );
        let Built { graph: g, .. } =
            parse_spatial(&text, "t.g2o", &ReadParams::default()).unwrap_or_else(|e| panic!("{e}"));
        let (_, e) = g.edges().next().unwrap_or_else(|| panic!("no edge"));
        // Our order (ω, v): rotation entries first.
        assert_eq!(e.information[(0, 0)], 40.0);
        assert_eq!(e.information[(3, 3)], 10.0);
        // g2o (x, ω_y) = (0, 4) → ours (v_x, ω_y) = (3, 1).
        assert_eq!(e.information[(3, 1)], 0.5);
        assert_eq!(e.information[(1, 3)], 0.5);
        let mut out = String::new();
        write_spatial(&mut out, &g);
        assert!(
            out.contains(&format!("3 0 0 0 1 {}", info_text.join(" "))),
            "{out}"
        );
    }
}

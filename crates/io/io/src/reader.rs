//! The shared reader: line splitting, field parsing, validation (information matrices,
//! quaternions) and graph assembly, used by `g2o.rs` and `toro.rs`.
//!
//! Handlers return `Result<_, String>` (the reason only); the driver adds file and line.

use core::str::SplitAsciiWhitespace;

use mapmerge_geometry::{LieGroup, Se2};
use mapmerge_posegraph::{Edge, EdgeId, EdgeKind, GraphError, NodeId, PoseGraph, Vertex};
use nalgebra::{Matrix6, Quaternion, SMatrix, UnitQuaternion};

use crate::{BadInformation, GraphFormat, IoError, ReadParams};

/// The reason a line is rejected; the driver turns it into [`IoError::Parse`].
pub(crate) type LineResult<T> = Result<T, String>;

/// A quaternion whose norm differs from 1 by more than this is rejected rather than normalised.
const QUATERNION_NORM_TOLERANCE: f64 = 1e-2;

/// Quaternions whose squared norm is this close to 1 count as unit already (a normalised
/// quaternion is within a few ulps; the rotation error of this slack is below 1e-14).
const UNIT_NORM_SQUARED_SLACK: f64 = 1e-14;

/// Longest token (in chars) quoted verbatim in an error message.
const MAX_QUOTED_CHARS: usize = 40;

/// Dimension of the poses a tag belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Dim {
    /// SE(2).
    Planar,
    /// SE(3).
    Spatial,
}

impl Dim {
    fn name(self) -> &'static str {
        match self {
            Dim::Planar => "2D",
            Dim::Spatial => "3D",
        }
    }
}

/// The family of every tag this crate knows: format and (for all but `FIX`) dimension.
pub(crate) fn tag_family(tag: &str) -> Option<(GraphFormat, Option<Dim>)> {
    use GraphFormat::{G2o, Toro};
    match tag {
        "VERTEX_SE2" | "EDGE_SE2" | "EDGE_PRIOR_SE2" => Some((G2o, Some(Dim::Planar))),
        "VERTEX_SE3:QUAT" | "EDGE_SE3:QUAT" | "EDGE_SE3_PRIOR" | "PARAMS_SE3OFFSET" => {
            Some((G2o, Some(Dim::Spatial)))
        }
        "FIX" => Some((G2o, None)),
        // TORO accepts `VERTEX`/`EDGE` as synonyms of the 2D tags.
        "VERTEX2" | "EDGE2" | "VERTEX" | "EDGE" => Some((Toro, Some(Dim::Planar))),
        "VERTEX3" | "EDGE3" => Some((Toro, Some(Dim::Spatial))),
        _ => None,
    }
}

/// Why `tag` is not accepted in a `format` file of dimension `dim`.
fn foreign_tag_reason(tag: &str, format: GraphFormat, dim: Dim) -> String {
    let shown = quoted(tag);
    match tag_family(tag) {
        Some((_, Some(other))) if other != dim => format!(
            "tag {shown} is {} but the file is {} (mixing 2D and 3D is not allowed)",
            other.name(),
            dim.name()
        ),
        Some((other, _)) if other != format => format!(
            "tag {shown} is {other} but the file is {format} (mixing formats is not allowed)"
        ),
        _ => format!("unknown tag {shown}"),
    }
}

/// A token for an error message: back-quoted, cut after [`MAX_QUOTED_CHARS`] chars.
pub(crate) fn quoted(token: &str) -> String {
    match token.char_indices().nth(MAX_QUOTED_CHARS) {
        Some((cut, _)) => format!("`{}…`", token.get(..cut).unwrap_or_default()),
        None => format!("`{token}`"),
    }
}

/// The fields of one data line after its tag.
pub(crate) struct Fields<'a> {
    tag: &'a str,
    rest: SplitAsciiWhitespace<'a>,
}

impl<'a> Fields<'a> {
    /// Exactly `N` fields, or an error saying how many there were.
    pub(crate) fn exactly<const N: usize>(mut self) -> LineResult<[&'a str; N]> {
        let mut out = [""; N];
        for (found, slot) in out.iter_mut().enumerate() {
            match self.rest.next() {
                Some(token) => *slot = token,
                None => {
                    return Err(format!(
                        "truncated {} line: expected {N} fields after the tag, found {found}",
                        self.tag
                    ))
                }
            }
        }
        let extra = self.rest.count();
        if extra > 0 {
            return Err(format!(
                "too many fields on {} line: expected {N} after the tag, found {}",
                self.tag,
                N + extra
            ));
        }
        Ok(out)
    }

    /// The remaining fields, for lines of variable length (`FIX`).
    pub(crate) fn rest(self) -> SplitAsciiWhitespace<'a> {
        self.rest
    }
}

/// One non-blank, non-comment line.
pub(crate) struct DataLine<'a> {
    /// 1-based line number.
    pub(crate) number: usize,
    /// The first token.
    pub(crate) tag: &'a str,
    /// The tokens after the tag.
    pub(crate) fields: Fields<'a>,
}

/// The data lines of `text`: blank lines and lines whose first token starts with `#` are
/// skipped. Lines end at `\n`; a trailing `\r` is whitespace.
pub(crate) fn data_lines(text: &str) -> impl Iterator<Item = DataLine<'_>> {
    text.split('\n').enumerate().filter_map(|(index, line)| {
        let mut rest = line.split_ascii_whitespace();
        let tag = rest.next()?;
        if tag.starts_with('#') {
            return None;
        }
        Some(DataLine {
            number: index + 1,
            tag,
            fields: Fields { tag, rest },
        })
    })
}

/// A finite `f64`; `field` is the 1-based field number after the tag, for the message.
pub(crate) fn parse_f64(token: &str, field: usize) -> LineResult<f64> {
    // fast-float2: the same round-to-nearest results as `str::parse`, about twice as fast.
    match fast_float2::parse::<f64, _>(token) {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(format!(
            "field {field} {} is not a finite number",
            quoted(token)
        )),
        Err(_) => Err(format!("field {field} {} is not a number", quoted(token))),
    }
}

/// A finite `f32`, rounded once from the decimal text (not through `f64`), so a value written
/// with the shortest `f32` digits reads back bit for bit.
pub(crate) fn parse_f32(token: &str, field: usize) -> LineResult<f32> {
    match fast_float2::parse::<f32, _>(token) {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(format!(
            "field {field} {} is not a finite number",
            quoted(token)
        )),
        Err(_) => Err(format!("field {field} {} is not a number", quoted(token))),
    }
}

/// A count of items (`what`, e.g. "beam count"): a non-negative integer that fits in `usize`.
pub(crate) fn parse_count(token: &str, field: usize, what: &str) -> LineResult<usize> {
    token.parse::<usize>().map_err(|_| {
        let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
        match token.strip_prefix('-') {
            Some(rest) if digits(rest) => {
                format!("field {field}: negative {what} {}", quoted(token))
            }
            _ if digits(token.strip_prefix('+').unwrap_or(token)) => {
                format!("field {field}: {what} {} is too large", quoted(token))
            }
            _ => format!(
                "field {field} {} is not a {what} (non-negative integer)",
                quoted(token)
            ),
        }
    })
}

/// `N` finite numbers from `tokens[start..start + N]` (`start` is 0-based after the tag).
pub(crate) fn parse_f64s<const N: usize>(tokens: &[&str], start: usize) -> LineResult<[f64; N]> {
    let mut out = [0.0; N];
    for (k, slot) in out.iter_mut().enumerate() {
        let index = start + k;
        let token = tokens
            .get(index)
            .ok_or_else(|| format!("missing field {}", index + 1))?;
        *slot = parse_f64(token, index + 1)?;
    }
    Ok(out)
}

/// A vertex id: a non-negative integer that fits in `u64`.
pub(crate) fn parse_id(token: &str, field: usize) -> LineResult<u64> {
    token.parse::<u64>().map_err(|_| {
        let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
        match token.strip_prefix('-') {
            Some(rest) if digits(rest) => {
                format!("field {field}: negative vertex id {}", quoted(token))
            }
            _ if digits(token.strip_prefix('+').unwrap_or(token)) => {
                format!(
                    "field {field}: vertex id {} does not fit in 64 bits",
                    quoted(token)
                )
            }
            _ => format!(
                "field {field} {} is not a vertex id (non-negative integer)",
                quoted(token)
            ),
        }
    })
}

/// A symmetric matrix from its upper triangle given row by row (g2o order). `values` must hold
/// `D (D + 1) / 2` entries; missing ones stay zero (callers always pass the full count).
pub(crate) fn from_upper_row_major<const D: usize>(values: &[f64]) -> SMatrix<f64, D, D> {
    let mut m = SMatrix::<f64, D, D>::zeros();
    let positions = (0..D).flat_map(|i| (i..D).map(move |j| (i, j)));
    for ((i, j), v) in positions.zip(values.iter().copied()) {
        m[(i, j)] = v;
        m[(j, i)] = v;
    }
    m
}

/// The upper triangle of `m`, row by row (g2o order).
pub(crate) fn upper_row_major<const D: usize>(
    m: &SMatrix<f64, D, D>,
) -> impl Iterator<Item = f64> + '_ {
    (0..D).flat_map(move |i| (i..D).map(move |j| m[(i, j)]))
}

/// Swaps the translation and rotation blocks of a 6x6 information matrix: g2o/TORO order
/// `(t, r)` ↔ our SE(3) tangent order `(ω, v)`. The permutation is its own inverse.
///
/// This is GTSAM's `readG2o` conversion: `gtsam[0..3,0..3] = g2o[3..6,3..6]`,
/// `gtsam[3..6,3..6] = g2o[0..3,0..3]`, `gtsam[3..6,0..3] = g2o[0..3,3..6]`,
/// `gtsam[0..3,3..6] = g2o[3..6,0..3]`.
pub(crate) fn swap_translation_rotation(m: &Matrix6<f64>) -> Matrix6<f64> {
    const PERM: [usize; 6] = [3, 4, 5, 0, 1, 2];
    Matrix6::from_fn(|i, j| m[(PERM[i % 6], PERM[j % 6])])
}

/// A planar pose with the heading wrapped into (-π, π]; in-range headings are kept bit for
/// bit, so reading a written file gives the same pose.
pub(crate) fn se2(x_m: f64, y_m: f64, theta_rad: f64) -> Se2 {
    Se2::new(x_m, y_m, theta_rad)
}

/// Accepts `m` if it is symmetric and positive definite (its Cholesky factorisation exists).
pub(crate) fn check_information<const D: usize>(m: &SMatrix<f64, D, D>) -> LineResult<()> {
    for i in 0..D {
        for j in (i + 1)..D {
            if m[(i, j)] != m[(j, i)] {
                return Err("information matrix is not symmetric".to_owned());
            }
        }
    }
    // Cholesky–Banachiewicz, column by column; fails on a non-positive or non-finite pivot.
    let mut l = SMatrix::<f64, D, D>::zeros();
    for j in 0..D {
        let mut pivot = m[(j, j)];
        for k in 0..j {
            pivot -= l[(j, k)] * l[(j, k)];
        }
        if !(pivot > 0.0 && pivot.is_finite()) {
            return Err(format!(
                "information matrix is not positive definite (Cholesky fails at row {})",
                j + 1
            ));
        }
        let d = pivot.sqrt();
        l[(j, j)] = d;
        for i in (j + 1)..D {
            let mut s = m[(i, j)];
            for k in 0..j {
                s -= l[(i, k)] * l[(j, k)];
            }
            l[(i, j)] = s / d;
        }
    }
    Ok(())
}

/// A unit quaternion from file coordinates. If `|‖q‖² − 1| ≤` [`UNIT_NORM_SQUARED_SLACK`]
/// the coordinates are kept bit for bit: normalising is not idempotent in floating point, and
/// this way a written file reads back identically. Others within
/// [`QUATERNION_NORM_TOLERANCE`] are normalised; the rest (including zero) are rejected.
pub(crate) fn unit_quaternion(
    qx: f64,
    qy: f64,
    qz: f64,
    qw: f64,
) -> LineResult<UnitQuaternion<f64>> {
    let q = Quaternion::new(qw, qx, qy, qz);
    let norm_squared = q.norm_squared();
    let norm = norm_squared.sqrt();
    if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE || !norm.is_finite() {
        return Err(format!(
            "quaternion ({qx}, {qy}, {qz}, {qw}) has norm {norm}, too far from 1 to normalise"
        ));
    }
    if (norm_squared - 1.0).abs() <= UNIT_NORM_SQUARED_SLACK {
        Ok(UnitQuaternion::new_unchecked(q))
    } else {
        Ok(UnitQuaternion::new_normalize(q))
    }
}

/// Collects vertices, edges and fixes; [`GraphBuilder::finish`] checks references and builds
/// the graph. Edge ids follow the order of the edge lines.
pub(crate) struct GraphBuilder<G, const D: usize> {
    graph: PoseGraph<G, D>,
    /// Edges with their line numbers, in file order.
    edges: Vec<(usize, Edge<G, D>)>,
    /// `FIX` ids with their line numbers.
    fixes: Vec<(usize, NodeId)>,
    /// The line being handled.
    line: usize,
    /// The vertex tag of the format, for messages.
    vertex_tag: &'static str,
    /// What to do with information matrices that are not positive definite.
    bad_information: BadInformation,
    /// Edges (by id) whose information matrix was replaced by its diagonal.
    repaired_edges: Vec<EdgeId>,
}

/// What [`build_graph`] produces.
pub(crate) struct Built<G, const D: usize> {
    /// The graph.
    pub(crate) graph: PoseGraph<G, D>,
    /// Whether the text had vertex lines.
    pub(crate) had_vertices: bool,
    /// Edges whose information matrix was replaced by its diagonal.
    pub(crate) repaired_edges: Vec<EdgeId>,
}

impl<G: LieGroup<D>, const D: usize> GraphBuilder<G, D> {
    fn new(vertex_tag: &'static str, params: &ReadParams) -> Self {
        Self {
            graph: PoseGraph::new(),
            edges: Vec::new(),
            fixes: Vec::new(),
            line: 0,
            vertex_tag,
            bad_information: params.bad_information,
            repaired_edges: Vec::new(),
        }
    }

    /// `information` if it is positive definite; otherwise its diagonal when the policy allows
    /// and the diagonal is positive (the edge about to be pushed is recorded as repaired).
    fn accept_information(
        &mut self,
        information: SMatrix<f64, D, D>,
    ) -> LineResult<SMatrix<f64, D, D>> {
        let Err(reason) = check_information(&information) else {
            return Ok(information);
        };
        match self.bad_information {
            BadInformation::Reject => Err(reason),
            BadInformation::KeepDiagonal => {
                let diagonal = SMatrix::<f64, D, D>::from_diagonal(&information.diagonal());
                check_information(&diagonal)
                    .map_err(|_| format!("{reason}, and its diagonal is not positive either"))?;
                self.repaired_edges.push(EdgeId(self.edges.len() as u64));
                Ok(diagonal)
            }
        }
    }

    /// A vertex line.
    pub(crate) fn add_vertex(&mut self, id: u64, pose: G) -> LineResult<()> {
        self.graph
            .add_vertex(NodeId(id), Vertex::new(pose))
            .map_err(|err| match err {
                GraphError::DuplicateVertex(_) => format!("duplicate vertex id {id}"),
                other => other.to_string(),
            })
    }

    /// A binary edge line. Kind: odometry when `to == from + 1`, loop otherwise.
    pub(crate) fn add_edge(
        &mut self,
        from: u64,
        to: u64,
        measurement: G,
        information: SMatrix<f64, D, D>,
    ) -> LineResult<()> {
        if from == to {
            return Err(format!("self-loop edge {from} -> {to}"));
        }
        let information = self.accept_information(information)?;
        let kind = if from.checked_add(1) == Some(to) {
            EdgeKind::Odometry
        } else {
            EdgeKind::Loop
        };
        let edge = Edge {
            from: NodeId(from),
            to: NodeId(to),
            measurement,
            information,
            kind,
        };
        self.edges.push((self.line, edge));
        Ok(())
    }

    /// A prior (unary) edge line; `measurement` is `world_from_node`.
    pub(crate) fn add_prior(
        &mut self,
        id: u64,
        measurement: G,
        information: SMatrix<f64, D, D>,
    ) -> LineResult<()> {
        let information = self.accept_information(information)?;
        let node = NodeId(id);
        let edge = Edge {
            from: node,
            to: node,
            measurement,
            information,
            kind: EdgeKind::Prior,
        };
        self.edges.push((self.line, edge));
        Ok(())
    }

    /// A `FIX` id; checked in [`GraphBuilder::finish`].
    pub(crate) fn fix(&mut self, id: u64) {
        self.fixes.push((self.line, NodeId(id)));
    }

    /// The graph and whether the file had vertex lines. Without vertex lines every edge
    /// endpoint becomes a vertex at the identity.
    fn finish(mut self, file: &str) -> Result<Built<G, D>, IoError> {
        let had_vertices = self.graph.num_vertices() > 0;
        if !had_vertices && self.edges.is_empty() {
            // Only parameter lines (e.g. `PARAMS_SE3OFFSET`): nothing to build.
            return Err(IoError::Empty {
                file: file.to_owned(),
            });
        }
        if !had_vertices {
            for (_, edge) in &self.edges {
                for end in [edge.from, edge.to] {
                    if !self.graph.contains_vertex(end) {
                        // Cannot fail: the id is new.
                        let _ = self.graph.add_vertex(end, Vertex::new(G::identity()));
                    }
                }
            }
        }
        for (line, edge) in self.edges {
            let (from, to) = (edge.from, edge.to);
            self.graph.add_edge(edge).map_err(|err| {
                let reason = match err {
                    GraphError::MissingVertex(id) => format!(
                        "edge {from} -> {to} refers to vertex {id}, which no {} line defines",
                        self.vertex_tag
                    ),
                    other => other.to_string(),
                };
                parse_error(file, line, reason)
            })?;
        }
        for (line, id) in self.fixes {
            match self.graph.vertex_mut(id) {
                Some(vertex) => vertex.fixed = true,
                None => {
                    let reason = format!("FIX refers to vertex {id}, which does not exist");
                    return Err(parse_error(file, line, reason));
                }
            }
        }
        Ok(Built {
            graph: self.graph,
            had_vertices,
            repaired_edges: self.repaired_edges,
        })
    }
}

/// An [`IoError::Parse`].
pub(crate) fn parse_error(file: &str, line: usize, reason: String) -> IoError {
    IoError::Parse {
        file: file.to_owned(),
        line,
        reason,
    }
}

/// Runs `handle` on every data line and builds the graph. `handle` returns `Ok(false)` for a
/// tag it does not know; the driver then reports it as unknown or as mixing formats/dimensions.
pub(crate) fn build_graph<G, const D: usize>(
    text: &str,
    file: &str,
    params: &ReadParams,
    format: GraphFormat,
    dim: Dim,
    vertex_tag: &'static str,
    mut handle: impl for<'x> FnMut(&mut GraphBuilder<G, D>, &'x str, Fields<'x>) -> LineResult<bool>,
) -> Result<Built<G, D>, IoError>
where
    G: LieGroup<D>,
{
    let mut builder = GraphBuilder::new(vertex_tag, params);
    for line in data_lines(text) {
        builder.line = line.number;
        let handled = handle(&mut builder, line.tag, line.fields)
            .map_err(|reason| parse_error(file, line.number, reason))?;
        if !handled {
            let reason = foreign_tag_reason(line.tag, format, dim);
            return Err(parse_error(file, line.number, reason));
        }
    }
    builder.finish(file)
}

/// Handles a `FIX id [id …]` line (g2o).
pub(crate) fn handle_fix<G: LieGroup<D>, const D: usize>(
    builder: &mut GraphBuilder<G, D>,
    fields: Fields<'_>,
) -> LineResult<()> {
    let mut count = 0;
    for (k, token) in fields.rest().enumerate() {
        builder.fix(parse_id(token, k + 1)?);
        count += 1;
    }
    if count == 0 {
        return Err("truncated FIX line: expected at least one vertex id".to_owned());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    #[test]
    fn cholesky_accepts_spd_and_rejects_the_rest() {
        let spd = Matrix3::new(4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0);
        assert!(check_information(&spd).is_ok());
        let singular = Matrix3::new(1.0, 1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        assert!(check_information(&singular).is_err());
        let indefinite = Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0);
        assert!(check_information(&indefinite).is_err());
        let asymmetric = Matrix3::new(1.0, 0.1, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        assert!(check_information(&asymmetric).is_err());
        let huge = Matrix3::from_diagonal_element(f64::MAX) + Matrix3::from_element(f64::MAX);
        assert!(check_information(&huge).is_err());
    }

    #[test]
    fn swap_is_an_involution_and_moves_blocks() {
        let m = Matrix6::from_fn(|i, j| (10 * i + j) as f64);
        let s = swap_translation_rotation(&m);
        assert_eq!(s[(0, 0)], m[(3, 3)]);
        assert_eq!(s[(3, 3)], m[(0, 0)]);
        assert_eq!(s[(4, 1)], m[(1, 4)]);
        assert_eq!(s[(1, 4)], m[(4, 1)]);
        assert_eq!(swap_translation_rotation(&s), m);
    }

    #[test]
    fn upper_triangle_round_trips() {
        let values: Vec<f64> = (1..=21).map(f64::from).collect();
        let m = from_upper_row_major::<6>(&values);
        assert_eq!(m[(0, 5)], 6.0);
        assert_eq!(m[(5, 0)], 6.0);
        assert_eq!(m[(1, 1)], 7.0);
        assert_eq!(upper_row_major(&m).collect::<Vec<_>>(), values);
    }

    #[test]
    fn ids_and_numbers() {
        assert_eq!(parse_id("42", 1), Ok(42));
        assert!(parse_id("-1", 1).is_err_and(|r| r.contains("negative")));
        assert!(parse_id("99999999999999999999", 1).is_err_and(|r| r.contains("64 bits")));
        assert!(parse_id("1.5", 1).is_err_and(|r| r.contains("not a vertex id")));
        assert_eq!(parse_f64("-2.5e-3", 1), Ok(-2.5e-3));
        for bad in ["nan", "inf", "-infinity", "1e400"] {
            assert!(
                parse_f64(bad, 3).is_err_and(|r| r.contains("not a finite")),
                "{bad}"
            );
        }
        assert!(parse_f64("1,5", 3).is_err_and(|r| r.contains("field 3")));
    }

    #[test]
    fn quaternions_are_checked_and_normalised() {
        assert!(unit_quaternion(0.0, 0.0, 0.0, 0.0).is_err());
        assert!(unit_quaternion(0.0, 0.0, 0.0, 2.0).is_err());
        let q = unit_quaternion(0.0, 0.0, 0.0, 1.001).unwrap_or_else(|e| panic!("{e}"));
        assert!((q.quaternion().norm() - 1.0).abs() < 1e-15);
        let exact = unit_quaternion(0.6, 0.0, 0.0, 0.8).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(exact.quaternion().coords.as_slice(), &[0.6, 0.0, 0.0, 0.8]);
    }

    #[test]
    fn headings_wrap_exactly() {
        use core::f64::consts::PI;
        for theta in [0.0, 1.0, -1.0, PI, -PI + 1e-15, 3.0, -3.0] {
            assert_eq!(se2(0.0, 0.0, theta).theta_rad, theta, "{theta}");
        }
        assert_eq!(se2(0.0, 0.0, -PI).theta_rad, PI);
        for theta in [1e20, -1e20, 1e300, 7.0, -7.0, 2.0 * PI, -2.0 * PI, 3.0 * PI] {
            let wrapped = se2(0.0, 0.0, theta).theta_rad;
            assert!(wrapped > -PI && wrapped <= PI, "{theta} -> {wrapped}");
            assert_eq!(se2(0.0, 0.0, wrapped).theta_rad, wrapped);
        }
    }

    #[test]
    fn long_tokens_are_cut_in_messages() {
        let long = "é".repeat(100);
        let shown = quoted(&long);
        assert!(shown.chars().count() < 50, "{shown}");
    }
}

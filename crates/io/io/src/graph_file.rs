//! Pose-graph files: format detection, reading (plain or xz) and writing.

use std::path::Path;

use mapmerge_geometry::{LieGroup, Se2, Se3};
use mapmerge_posegraph::{EdgeId, PoseGraph, PoseGraph2, PoseGraph3};

use crate::input::read_text;
use crate::reader::{data_lines, parse_error, quoted, tag_family, Built, Dim};
use crate::writer::save;
use crate::{g2o, toro, IoError};

/// A planar or a spatial pose graph, as a file can hold either.
#[derive(Clone, Debug, PartialEq)]
pub enum AnyGraph {
    /// SE(2) poses (`VERTEX_SE2`, `VERTEX2`).
    Planar(PoseGraph2),
    /// SE(3) poses (`VERTEX_SE3:QUAT`, `VERTEX3`).
    Spatial(PoseGraph3),
}

impl AnyGraph {
    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        match self {
            AnyGraph::Planar(g) => g.num_vertices(),
            AnyGraph::Spatial(g) => g.num_vertices(),
        }
    }

    /// Number of edges (priors included).
    pub fn num_edges(&self) -> usize {
        match self {
            AnyGraph::Planar(g) => g.num_edges(),
            AnyGraph::Spatial(g) => g.num_edges(),
        }
    }
}

/// A pose-graph text format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum GraphFormat {
    /// g2o: `VERTEX_SE2`/`EDGE_SE2`, `VERTEX_SE3:QUAT`/`EDGE_SE3:QUAT`, `FIX`.
    G2o,
    /// TORO / HOG-Man: `VERTEX2`/`EDGE2`, `VERTEX3`/`EDGE3`.
    Toro,
}

impl GraphFormat {
    /// `"g2o"` or `"TORO"`.
    pub fn name(self) -> &'static str {
        match self {
            GraphFormat::G2o => "g2o",
            GraphFormat::Toro => "TORO",
        }
    }
}

impl core::fmt::Display for GraphFormat {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name())
    }
}

/// What to do with an edge whose information matrix is not symmetric positive definite.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum BadInformation {
    /// Fail with [`IoError::Parse`] at that line (default).
    #[default]
    Reject,
    /// Keep only the diagonal if that is positive (dropping all correlations), record the edge
    /// in [`LoadedGraph::repaired_edges`]; otherwise fail as with `Reject`. Needed for e.g.
    /// SE-Sync's `cubicle.g2o`, where 5021 of 16869 edges carry indefinite matrices.
    KeepDiagonal,
}

/// How [`read_graph_with`] / [`parse_graph_with`] treat questionable input.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ReadParams {
    /// Edges whose information matrix is not positive definite (default: `Reject`). Rejecting
    /// is safe; `KeepDiagonal` loads broken datasets at the cost of their correlations.
    pub bad_information: BadInformation,
}

/// A graph read from a file.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadedGraph {
    /// The graph; edge ids are the order of the edge lines (0, 1, 2, …).
    pub graph: AnyGraph,
    /// The format the file was in.
    pub format: GraphFormat,
    /// False when the file had no vertex lines: every vertex was created at the identity and
    /// must be initialised (e.g. by chaining odometry) before optimising.
    pub had_vertices: bool,
    /// Edges whose information matrix was replaced by its diagonal
    /// ([`BadInformation::KeepDiagonal`]); always empty with the default [`ReadParams`].
    pub repaired_edges: Vec<EdgeId>,
}

/// Reads a g2o or TORO graph file; xz-compressed files are recognised by their magic bytes.
/// The format is detected from the first data line's tag. Uses the default [`ReadParams`].
pub fn read_graph(path: &Path) -> Result<LoadedGraph, IoError> {
    read_graph_with(path, &ReadParams::default())
}

/// [`read_graph`] with explicit [`ReadParams`].
pub fn read_graph_with(path: &Path, params: &ReadParams) -> Result<LoadedGraph, IoError> {
    let text = read_text(path)?;
    parse_graph_with(&text, &path.display().to_string(), params)
}

/// Parses the text of a g2o or TORO graph; `source` names it in errors. Uses the default
/// [`ReadParams`].
pub fn parse_graph(text: &str, source: &str) -> Result<LoadedGraph, IoError> {
    parse_graph_with(text, source, &ReadParams::default())
}

/// [`parse_graph`] with explicit [`ReadParams`].
pub fn parse_graph_with(
    text: &str,
    source: &str,
    params: &ReadParams,
) -> Result<LoadedGraph, IoError> {
    // `FIX` carries no dimension; the first other tag decides.
    let first = data_lines(text).find(|line| line.tag != "FIX");
    let Some(first) = first else {
        return Err(IoError::Empty {
            file: source.to_owned(),
        });
    };
    let (format, dim) = match tag_family(first.tag) {
        Some((format, Some(dim))) => (format, dim),
        _ => {
            let reason = format!("unknown tag {}", quoted(first.tag));
            return Err(parse_error(source, first.number, reason));
        }
    };
    let loaded = match (format, dim) {
        (GraphFormat::G2o, Dim::Planar) => planar(g2o::parse_planar(text, source, params)?),
        (GraphFormat::G2o, Dim::Spatial) => spatial(g2o::parse_spatial(text, source, params)?),
        (GraphFormat::Toro, Dim::Planar) => planar(toro::parse_planar(text, source, params)?),
        (GraphFormat::Toro, Dim::Spatial) => spatial(toro::parse_spatial(text, source, params)?),
    };
    Ok(LoadedGraph { format, ..loaded })
}

fn planar(built: Built<Se2, 3>) -> LoadedGraph {
    LoadedGraph {
        graph: AnyGraph::Planar(built.graph),
        format: GraphFormat::G2o,
        had_vertices: built.had_vertices,
        repaired_edges: built.repaired_edges,
    }
}

fn spatial(built: Built<Se3, 6>) -> LoadedGraph {
    LoadedGraph {
        graph: AnyGraph::Spatial(built.graph),
        format: GraphFormat::G2o,
        had_vertices: built.had_vertices,
        repaired_edges: built.repaired_edges,
    }
}

/// Rejects non-finite poses, measurements and information (they would not read back).
fn check_finite<G: LieGroup<D>, const D: usize>(
    graph: &PoseGraph<G, D>,
    format: GraphFormat,
) -> Result<(), IoError> {
    let unwritable = |reason| IoError::Unwritable {
        format: format.name(),
        reason,
    };
    if let Some((id, _)) = graph.vertices().find(|(_, v)| !v.pose.is_finite()) {
        return Err(unwritable(format!("vertex {id} has a non-finite pose")));
    }
    let bad_edge = |e: &mapmerge_posegraph::Edge<G, D>| {
        !e.measurement.is_finite() || e.information.iter().any(|v| !v.is_finite())
    };
    if let Some((id, _)) = graph.edges().find(|(_, e)| bad_edge(e)) {
        return Err(unwritable(format!(
            "edge {id} has a non-finite measurement or information"
        )));
    }
    Ok(())
}

/// The text of `graph` in `format`: vertices in id order (then g2o `FIX` lines), then edges in
/// id order, numbers with full `f64` precision. Fails for what the format cannot express
/// (priors in TORO) and for non-finite numbers.
pub fn format_graph(graph: &AnyGraph, format: GraphFormat) -> Result<String, IoError> {
    // About 100 bytes per 2D line and 300 per 3D edge line.
    let mut out = String::with_capacity((graph.num_vertices() + graph.num_edges()) * 128);
    match graph {
        AnyGraph::Planar(g) => {
            check_finite(g, format)?;
            match format {
                GraphFormat::G2o => g2o::write_planar(&mut out, g),
                GraphFormat::Toro => toro::write_planar(&mut out, g)?,
            }
        }
        AnyGraph::Spatial(g) => {
            check_finite(g, format)?;
            match format {
                GraphFormat::G2o => g2o::write_spatial(&mut out, g),
                GraphFormat::Toro => toro::write_spatial(&mut out, g)?,
            }
        }
    }
    Ok(out)
}

/// Writes `graph` to `path` in `format` (see [`format_graph`]), xz-compressed when the path
/// ends in `.xz`.
pub fn write_graph(path: &Path, graph: &AnyGraph, format: GraphFormat) -> Result<(), IoError> {
    save(path, &format_graph(graph, format)?)
}

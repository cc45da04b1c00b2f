//! Readers and writers for pose-graph files (g2o, TORO/HOG-Man) and TUM trajectories.
//!
//! Entry points: [`read_graph`] / [`parse_graph`] (format detected from the first data line,
//! `.xz` decompressed transparently; `*_with` variants take [`ReadParams`]), [`write_graph`] /
//! [`format_graph`], and [`write_tum`].
//! Nothing here panics on input: every problem is an [`IoError`] naming file and line.
//! See `docs/formats.md` for the exact line layouts and the information-matrix ordering.
//!
//! ```
//! use mapmerge_io::{format_graph, parse_graph, AnyGraph, GraphFormat};
//! let text = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n";
//! let loaded = parse_graph(text, "example.g2o").unwrap();
//! assert_eq!(loaded.format, GraphFormat::G2o);
//! let AnyGraph::Planar(graph) = &loaded.graph else { unreachable!() };
//! assert_eq!((graph.num_vertices(), graph.num_edges()), (2, 1));
//! let again = format_graph(&loaded.graph, GraphFormat::Toro).unwrap();
//! assert_eq!(parse_graph(&again, "again.graph").unwrap().graph, loaded.graph);
//!
//! let err = parse_graph("VERTEX_SE2 0 0 0\n", "bad.g2o").unwrap_err();
//! assert_eq!(err.to_string(), "bad.g2o:1: truncated VERTEX_SE2 line: expected 4 fields after the tag, found 3");
//! ```

mod error;
mod g2o;
mod graph_file;
mod reader;
mod toro;
mod tum;
mod writer;

pub use error::IoError;
pub use graph_file::{
    format_graph, parse_graph, parse_graph_with, read_graph, read_graph_with, write_graph,
    AnyGraph, BadInformation, GraphFormat, LoadedGraph, ReadParams,
};
pub use tum::{format_tum, write_tum};

//! `mapmerge corrupt`: add vertigo-style false loop closures to a graph (robustness tests).
//!
//! The false edges are appended after every edge of the input, so in OUT they are exactly the
//! edge lines with index ≥ the input's edge count (0-based, in file order — the numbering
//! `mapmerge optimize --json` uses for `rejected_edges`). `--json` lists them, and
//! `--false-edges FILE` writes them one per line.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Args, ValueEnum};
use mapmerge_eval::{
    add_false_loop_closures_with, count_loop_closures, EvalError, EvalPose, FalseLoopMeasurement,
    FalseLoopParams,
};
use mapmerge_io::{read_graph, write_graph, AnyGraph, GraphFormat, LoadedGraph};
use mapmerge_posegraph::{EdgeId, PoseGraph};
use serde::Serialize;

use crate::BadInput;

/// How false relative poses are drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MeasurementChoice {
    /// vertigo's generateDataset.py: translation N(0, 0.3 m) per axis, angles N(0, 10°).
    Vertigo,
    /// Translation uniform in ±--box-m per axis, rotation uniform.
    Uniform,
}

/// An output format on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum FormatChoice {
    /// g2o (`VERTEX_SE2`/`EDGE_SE2`, `VERTEX_SE3:QUAT`/`EDGE_SE3:QUAT`).
    G2o,
    /// TORO / HOG-Man (`VERTEX2`/`EDGE2`, `VERTEX3`/`EDGE3`).
    Toro,
}

/// Arguments of `mapmerge corrupt`.
#[derive(Args, Debug)]
pub struct CorruptArgs {
    /// Input graph (g2o or TORO, 2D or 3D; `.xz` accepted).
    pub input: PathBuf,
    /// Output graph: the input's vertices and edges, then the false loop closures. A file
    /// without vertex lines gets odometry-chained vertices (what `optimize --init auto` uses).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Share of ALL loop closures (non-odometry edges) that is false afterwards, in [0, 1):
    /// n_false = round(F / (1 − F) · n_true); 0.5 adds as many false as true loop closures.
    /// 0 only rewrites the graph (with --format: a format conversion).
    #[arg(long, value_name = "F")]
    pub outlier_fraction: f64,
    /// Seed of the random generator (ChaCha8): same input, fraction and seed, same output.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Distribution of the false relative poses.
    #[arg(long, value_enum, default_value_t = MeasurementChoice::Vertigo)]
    pub measurement: MeasurementChoice,
    /// Half side of the translation box of `--measurement uniform`, m.
    #[arg(long, default_value_t = 10.0)]
    pub box_m: f64,
    /// Output format (default: the input's).
    #[arg(long, value_enum)]
    pub format: Option<FormatChoice>,
    /// Also write the false edges' indices (edge-line index in OUT), one per line, to this file.
    #[arg(long, value_name = "FILE")]
    pub false_edges: Option<PathBuf>,
    /// Print one JSON object on stdout instead of the human summary.
    #[arg(long)]
    pub json: bool,
}

/// The `--json` report.
#[derive(Serialize, Debug)]
struct Report {
    input: String,
    output: String,
    format: String,
    dimension: usize,
    vertices: usize,
    /// Edges in the input; every false edge index is ≥ this.
    original_edges: usize,
    /// Edges in the output.
    edges: usize,
    /// Loop closures (non-odometry, non-prior edges) of the input.
    true_loops: usize,
    false_loops: usize,
    outlier_fraction: f64,
    seed: u64,
    measurement: MeasurementChoice,
    /// Indices (0-based edge-line order in OUT) of the false loop closures.
    false_edges: Vec<u64>,
}

/// Reads a graph; every failure is bad input (exit code 2).
pub(crate) fn load(path: &Path) -> anyhow::Result<LoadedGraph> {
    read_graph(path).map_err(|err| anyhow::Error::new(BadInput(err.to_string())))
}

fn eval_error(err: EvalError) -> anyhow::Error {
    match err {
        EvalError::Graph(_) => anyhow::Error::new(err),
        other => anyhow::Error::new(BadInput(other.to_string())),
    }
}

fn corrupt_graph<G: EvalPose<D>, const D: usize>(
    graph: &mut PoseGraph<G, D>,
    had_vertices: bool,
    args: &CorruptArgs,
    params: &FalseLoopParams,
) -> anyhow::Result<(usize, Vec<EdgeId>)> {
    if !had_vertices {
        mapmerge_init::initialize_odometry(graph)
            .map_err(|err| BadInput(format!("odometry initialisation: {err}")))?;
        if !args.json {
            eprintln!(
                "{}: no vertex lines; wrote odometry-chained vertices",
                args.input.display()
            );
        }
    }
    let true_loops = count_loop_closures(graph);
    let added = add_false_loop_closures_with(graph, args.outlier_fraction, params, args.seed)
        .map_err(eval_error)?;
    Ok((true_loops, added))
}

/// Runs `mapmerge corrupt`.
pub fn run(args: &CorruptArgs) -> anyhow::Result<ExitCode> {
    let measurement = match args.measurement {
        MeasurementChoice::Vertigo => FalseLoopMeasurement::default(),
        MeasurementChoice::Uniform => FalseLoopMeasurement::Uniform {
            half_extent_m: args.box_m,
        },
    };
    let params = FalseLoopParams { measurement };
    // Check the fraction before reading a possibly large file.
    mapmerge_eval::false_loop_count(args.outlier_fraction, 0).map_err(eval_error)?;

    let loaded = load(&args.input)?;
    let format = match args.format {
        None => loaded.format,
        Some(FormatChoice::G2o) => GraphFormat::G2o,
        Some(FormatChoice::Toro) => GraphFormat::Toro,
    };
    let mut graph = loaded.graph;
    let original_edges = graph.num_edges();
    let (dimension, (true_loops, added)) = match &mut graph {
        AnyGraph::Planar(g) => (2, corrupt_graph(g, loaded.had_vertices, args, &params)?),
        AnyGraph::Spatial(g) => (3, corrupt_graph(g, loaded.had_vertices, args, &params)?),
    };
    write_graph(&args.output, &graph, format)?;
    let false_edges: Vec<u64> = added.iter().map(|id| id.0).collect();
    if let Some(path) = &args.false_edges {
        let text: String = false_edges.iter().map(|i| format!("{i}\n")).collect();
        std::fs::write(path, text)
            .map_err(|err| anyhow::anyhow!("cannot write {}: {err}", path.display()))?;
    }
    let report = Report {
        input: args.input.display().to_string(),
        output: args.output.display().to_string(),
        format: format.name().to_lowercase(),
        dimension,
        vertices: graph.num_vertices(),
        original_edges,
        edges: graph.num_edges(),
        true_loops,
        false_loops: false_edges.len(),
        outlier_fraction: args.outlier_fraction,
        seed: args.seed,
        measurement: args.measurement,
        false_edges,
    };
    if args.json {
        crate::print_json(&report)?;
    } else {
        println!(
            "{}: {} true loop closures, added {} false ones (edge indices {}..{}); wrote {}",
            report.input,
            report.true_loops,
            report.false_loops,
            report.original_edges,
            report.edges,
            report.output
        );
    }
    Ok(ExitCode::SUCCESS)
}

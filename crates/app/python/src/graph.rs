//! Pose graphs: `Graph`, `read_graph`, `write_graph`, `optimize`.

use std::path::PathBuf;
use std::time::Instant;

use mapmerge_geometry::{Se2, Se3};
use mapmerge_io::{AnyGraph, GraphFormat, LoadedGraph};
use mapmerge_jobs::{
    load_graph, numerical_failure_message, optimize_loaded, AlgorithmChoice, BadInformationChoice,
    Choice, InitChoice, OptimizeOptions, RobustChoice,
};
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::PyRuntimeWarning;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert::{planar_poses, rows, to_dict, vector};
use crate::{bad_input, job_error};

/// A pose graph as read from a g2o or TORO file (2D or 3D), with the file's ids and format.
/// Immutable: `optimize` and `with_poses` return new graphs.
#[pyclass(module = "mapmerge", frozen)]
pub struct Graph {
    pub(crate) loaded: LoadedGraph,
    /// The file it came from (the report's `input`).
    pub(crate) source: String,
    /// Reading time (s).
    pub(crate) load_seconds: f64,
}

impl Graph {
    /// A graph made in memory (SLAM), written as g2o.
    pub(crate) fn made(graph: AnyGraph, source: String) -> Self {
        Self {
            loaded: LoadedGraph {
                graph,
                format: GraphFormat::G2o,
                had_vertices: true,
                repaired_edges: Vec::new(),
            },
            source,
            load_seconds: 0.0,
        }
    }
}

#[pymethods]
impl Graph {
    /// 2 (SE(2) poses) or 3 (SE(3) poses).
    #[getter]
    fn dimension(&self) -> usize {
        match self.loaded.graph {
            AnyGraph::Planar(_) => 2,
            AnyGraph::Spatial(_) => 3,
        }
    }

    /// `"g2o"` or `"toro"`: the format it was read in (and is written in by default).
    #[getter]
    fn format(&self) -> &'static str {
        format_name(self.loaded.format)
    }

    /// The file it was read from.
    #[getter]
    fn source(&self) -> &str {
        &self.source
    }

    /// Vertex ids, ascending (the rows of `poses`).
    #[getter]
    fn ids<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u64>> {
        let ids = match &self.loaded.graph {
            AnyGraph::Planar(g) => g.vertices().map(|(id, _)| id.0).collect(),
            AnyGraph::Spatial(g) => g.vertices().map(|(id, _)| id.0).collect(),
        };
        vector(py, ids)
    }

    /// Vertex poses, one row per id: `(N, 3)` `[x, y, yaw]` in 2D, `(N, 7)`
    /// `[x, y, z, qx, qy, qz, qw]` in 3D (m, rad).
    #[getter]
    fn poses<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        match &self.loaded.graph {
            AnyGraph::Planar(g) => {
                let poses: Vec<Se2> = g.vertices().map(|(_, v)| v.pose).collect();
                planar_poses(py, &poses)
            }
            AnyGraph::Spatial(g) => rows(
                py,
                g.vertices().map(|(_, v)| {
                    let (t, q) = (&v.pose.translation_m, v.pose.rotation.coords);
                    [t.x, t.y, t.z, q.x, q.y, q.z, q.w]
                }),
            ),
        }
    }

    /// Edges in file order: `(E, 2)` `[from, to]` vertex ids (a prior has `from == to`).
    #[getter]
    fn edges<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<u64>> {
        let ends: Vec<u64> = match &self.loaded.graph {
            AnyGraph::Planar(g) => g.edges().flat_map(|(_, e)| [e.from.0, e.to.0]).collect(),
            AnyGraph::Spatial(g) => g.edges().flat_map(|(_, e)| [e.from.0, e.to.0]).collect(),
        };
        let n = ends.len() / 2;
        Array2::from_shape_vec((n, 2), ends)
            .unwrap_or_else(|_| Array2::zeros((0, 2)))
            .into_pyarray(py)
    }

    /// Number of vertices.
    #[getter]
    fn num_vertices(&self) -> usize {
        self.loaded.graph.num_vertices()
    }

    /// Number of edges (priors included).
    #[getter]
    fn num_edges(&self) -> usize {
        self.loaded.graph.num_edges()
    }

    /// The same graph with other poses (same shape as `poses`, rows in `ids` order).
    fn with_poses(&self, py: Python<'_>, poses: PyReadonlyArray2<'_, f64>) -> PyResult<Graph> {
        let shape = poses.shape();
        let columns = if self.dimension() == 2 { 3 } else { 7 };
        if shape != [self.loaded.graph.num_vertices(), columns] {
            return Err(bad_input(
                py,
                format!(
                    "poses must have shape ({}, {columns}), got {:?}",
                    self.loaded.graph.num_vertices(),
                    shape
                ),
            ));
        }
        let array = poses.as_array();
        if array.iter().any(|v| !v.is_finite()) {
            return Err(bad_input(py, "poses must be finite"));
        }
        let mut loaded = self.loaded.clone();
        // Given poses are an initial guess: `init="auto"` keeps them.
        loaded.had_vertices = true;
        match &mut loaded.graph {
            AnyGraph::Planar(g) => {
                for ((_, vertex), row) in g.vertices_mut().zip(array.rows()) {
                    vertex.pose = Se2::new(row[0], row[1], row[2]);
                }
            }
            AnyGraph::Spatial(g) => {
                for ((_, vertex), row) in g.vertices_mut().zip(array.rows()) {
                    let q = Quaternion::new(row[6], row[3], row[4], row[5]);
                    if q.norm() < 1e-9 {
                        return Err(bad_input(py, "a quaternion of poses is zero"));
                    }
                    vertex.pose = Se3::new(
                        UnitQuaternion::from_quaternion(q),
                        Vector3::new(row[0], row[1], row[2]),
                    );
                }
            }
        }
        Ok(Graph {
            loaded,
            source: self.source.clone(),
            load_seconds: self.load_seconds,
        })
    }

    fn __len__(&self) -> usize {
        self.loaded.graph.num_vertices()
    }

    fn __repr__(&self) -> String {
        format!(
            "Graph({}D, {} vertices, {} edges, {} from {:?})",
            self.dimension(),
            self.loaded.graph.num_vertices(),
            self.loaded.graph.num_edges(),
            self.format(),
            self.source
        )
    }
}

fn format_name(format: GraphFormat) -> &'static str {
    match format {
        GraphFormat::G2o => "g2o",
        GraphFormat::Toro => "toro",
    }
}

/// Reads a g2o or TORO graph file (2D or 3D; `.xz` is decompressed).
#[pyfunction]
#[pyo3(signature = (path, *, bad_information = "reject"))]
pub fn read_graph(py: Python<'_>, path: PathBuf, bad_information: &str) -> PyResult<Graph> {
    let bad_information =
        BadInformationChoice::from_name(bad_information).map_err(|e| job_error(py, e))?;
    let started = Instant::now();
    let loaded = py
        .detach(|| load_graph(&path, bad_information))
        .map_err(|e| job_error(py, e))?;
    Ok(Graph {
        loaded,
        source: path.display().to_string(),
        load_seconds: started.elapsed().as_secs_f64(),
    })
}

/// Writes `graph` to `path` in `format` (`"g2o"` or `"toro"`; default: the graph's own),
/// with its ids; `.xz` compresses.
#[pyfunction]
#[pyo3(signature = (path, graph, format = None))]
pub fn write_graph(
    py: Python<'_>,
    path: PathBuf,
    graph: &Graph,
    format: Option<&str>,
) -> PyResult<()> {
    let format = match format {
        None => graph.loaded.format,
        Some("g2o") => GraphFormat::G2o,
        Some("toro") => GraphFormat::Toro,
        Some(other) => {
            return Err(bad_input(
                py,
                format!("invalid value '{other}' for format: possible values are g2o, toro"),
            ))
        }
    };
    let any = &graph.loaded.graph;
    // The output path is the user's: bad input, as the CLI has it (issue 67).
    py.detach(|| mapmerge_io::write_graph(&path, any, format))
        .map_err(|e| job_error(py, mapmerge_jobs::JobError::bad_file(&e)))
}

/// Initialises and optimises a graph (a `Graph`, or a file path read as by `read_graph`);
/// returns the optimised graph and the report `mapmerge optimize --json` prints. With
/// `output`, the result is also written there, as the CLI does.
#[pyfunction]
#[pyo3(signature = (
    graph, robust = "none", init = "auto", *, algorithm = "lm", max_iterations = None,
    relative_tolerance = None, kernel_width = None, bad_information = "reject", output = None
))]
#[allow(clippy::too_many_arguments)]
pub fn optimize<'py>(
    py: Python<'py>,
    graph: &Bound<'py, PyAny>,
    robust: &str,
    init: &str,
    algorithm: &str,
    max_iterations: Option<usize>,
    relative_tolerance: Option<f64>,
    kernel_width: Option<f64>,
    bad_information: &str,
    output: Option<PathBuf>,
) -> PyResult<(Graph, Bound<'py, PyDict>)> {
    let choice_error = |e| job_error(py, e);
    let defaults = OptimizeOptions::default();
    let options = OptimizeOptions {
        robust: RobustChoice::from_name(robust).map_err(choice_error)?,
        kernel_width,
        init: InitChoice::from_name(init).map_err(choice_error)?,
        algorithm: AlgorithmChoice::from_name(algorithm).map_err(choice_error)?,
        max_iterations: max_iterations.unwrap_or(defaults.max_iterations),
        relative_tolerance: relative_tolerance.unwrap_or(defaults.relative_tolerance),
        bad_information: BadInformationChoice::from_name(bad_information).map_err(choice_error)?,
    };
    let given = match graph.cast::<Graph>() {
        Ok(given) => given.clone(),
        Err(_) => {
            let path: PathBuf = graph.extract().map_err(|_| {
                pyo3::exceptions::PyTypeError::new_err(
                    "graph must be a mapmerge.Graph or a path (str or os.PathLike)",
                )
            })?;
            Bound::new(py, read_graph(py, path, bad_information)?)?
        }
    };
    let given = given.get();
    let loaded = given.loaded.clone();
    let (source, load_seconds) = (given.source.clone(), given.load_seconds);
    let optimized = py
        .detach(|| {
            optimize_loaded(
                loaded,
                &source,
                load_seconds,
                output.as_deref(),
                &options,
                |_| {},
            )
        })
        .map_err(|e| job_error(py, e))?;
    if let Some(reason) = optimized.numerical_failure() {
        PyErr::warn(
            py,
            &py.get_type::<PyRuntimeWarning>(),
            &std::ffi::CString::new(numerical_failure_message(reason)).unwrap_or_default(),
            1,
        )?;
    }
    let report = to_dict(py, &optimized.report)?;
    let graph = Graph {
        loaded: LoadedGraph {
            graph: optimized.graph,
            format: optimized.format,
            had_vertices: true,
            repaired_edges: given.loaded.repaired_edges.clone(),
        },
        source,
        load_seconds,
    };
    Ok((graph, report))
}

//! The Python module `mapmerge`: thin bindings over `mapmerge-jobs` (the jobs the CLI runs,
//! one implementation for both) and `mapmerge-engine` (the lifelong loop), with poses,
//! scans and grids as numpy arrays and reports as the dicts `--json` prints.
//!
//! - [`graph`]: `Graph`, `read_graph`, `write_graph`, `optimize`;
//! - [`maps`]: `grid_merge`, `read_log`, `slam`, `assemble`;
//! - [`atlas`]: the `Atlas` class (the lifelong engine, scan by scan) and `run_atlas` (a
//!   whole `mapmerge atlas` run).
//!
//! Errors: every failure the CLI reports as `mapmerge: error: MESSAGE` raises
//! `mapmerge.MapmergeError(MESSAGE)`; those the CLI exits with code 2 for (unreadable or
//! malformed input, bad arguments) raise its subclass `mapmerge.BadInputError`, which is
//! also a `ValueError`. The long jobs release the GIL.

mod atlas;
mod convert;
mod graph;
mod maps;

use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyTuple, PyType};

pyo3::create_exception!(
    mapmerge,
    MapmergeError,
    pyo3::exceptions::PyException,
    "A failure the CLI reports as `mapmerge: error: MESSAGE` (exit code 1; its subclass \
     BadInputError: exit code 2); the message is the CLI's."
);

/// `BadInputError(MapmergeError, ValueError)`, made when the module is imported.
static BAD_INPUT_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();

/// The class `BadInputError`: a subclass of both `MapmergeError` and `ValueError`, so that
/// `except ValueError` catches bad input as Python code expects.
fn bad_input_error(py: Python<'_>) -> PyResult<&Bound<'_, PyType>> {
    BAD_INPUT_ERROR
        .get_or_try_init(py, || {
            let bases = PyTuple::new(
                py,
                [
                    py.get_type::<MapmergeError>(),
                    py.get_type::<pyo3::exceptions::PyValueError>(),
                ],
            )?;
            let namespace = PyDict::new(py);
            namespace.set_item("__module__", "mapmerge")?;
            namespace.set_item(
                "__doc__",
                "Unreadable or malformed input, bad arguments: what the CLI exits with code 2 \
                 for; the message is the CLI's.",
            )?;
            let class = py
                .get_type::<PyType>()
                .call1(("BadInputError", bases, namespace))?
                .cast_into::<PyType>()?;
            Ok(class.unbind())
        })
        .map(|class| class.bind(py))
}

/// A job's error as a Python exception with the CLI's message.
pub(crate) fn job_error(py: Python<'_>, err: mapmerge_jobs::JobError) -> PyErr {
    match err {
        mapmerge_jobs::JobError::BadInput(message) => match bad_input_error(py) {
            Ok(class) => PyErr::from_type(class.clone(), message),
            Err(e) => e,
        },
        other => MapmergeError::new_err(other.to_string()),
    }
}

/// Bad input (`BadInputError`) with `message`.
pub(crate) fn bad_input(py: Python<'_>, message: impl std::fmt::Display) -> PyErr {
    job_error(py, mapmerge_jobs::JobError::bad_input(message))
}

/// Merges robot maps: pose graphs, occupancy grids, laser sessions, the lifelong atlas.
#[pymodule]
fn mapmerge(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("MapmergeError", py.get_type::<MapmergeError>())?;
    m.add("BadInputError", bad_input_error(py)?)?;
    m.add_class::<graph::Graph>()?;
    m.add_function(wrap_pyfunction!(graph::read_graph, m)?)?;
    m.add_function(wrap_pyfunction!(graph::write_graph, m)?)?;
    m.add_function(wrap_pyfunction!(graph::optimize, m)?)?;
    m.add_function(wrap_pyfunction!(maps::grid_merge, m)?)?;
    m.add_function(wrap_pyfunction!(maps::read_log, m)?)?;
    m.add_function(wrap_pyfunction!(maps::slam, m)?)?;
    m.add_function(wrap_pyfunction!(maps::assemble, m)?)?;
    m.add_class::<atlas::PyAtlas>()?;
    m.add_function(wrap_pyfunction!(atlas::run_atlas, m)?)?;
    Ok(())
}

//! Rust values to Python ones: reports as the JSON the CLI prints, poses and grids as numpy
//! arrays.

use mapmerge_geometry::Se2;
use mapmerge_grid::{probability_of, OccupancyGrid};
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::MapmergeError;

/// `value` as the Python object `json.loads` makes of the JSON the CLI prints for it (same
/// serializer, so the same fields, names and numbers).
pub(crate) fn to_python<'py>(
    py: Python<'py>,
    value: &impl serde::Serialize,
) -> PyResult<Bound<'py, PyAny>> {
    let text =
        serde_json::to_string(value).map_err(|e| MapmergeError::new_err(format!("report: {e}")))?;
    py.import("json")?.call_method1("loads", (text,))
}

/// [`to_python`] of a value that serialises as an object.
pub(crate) fn to_dict<'py>(
    py: Python<'py>,
    value: &impl serde::Serialize,
) -> PyResult<Bound<'py, PyDict>> {
    Ok(to_python(py, value)?.cast_into::<PyDict>()?)
}

/// Planar poses as an `(N, 3)` array of `[x, y, yaw]` (m, rad).
pub(crate) fn planar_poses<'py>(py: Python<'py>, poses: &[Se2]) -> Bound<'py, PyArray2<f64>> {
    rows(py, poses.iter().map(|p| [p.x_m, p.y_m, p.theta_rad]))
}

/// `K`-column rows as an `(N, K)` array.
pub(crate) fn rows<'py, const K: usize>(
    py: Python<'py>,
    rows: impl Iterator<Item = [f64; K]>,
) -> Bound<'py, PyArray2<f64>> {
    let flat: Vec<f64> = rows.flatten().collect();
    let n = flat.len() / K;
    Array2::from_shape_vec((n, K), flat)
        .unwrap_or_else(|_| Array2::zeros((0, K)))
        .into_pyarray(py)
}

/// A one-dimensional array.
pub(crate) fn vector<'py, T: numpy::Element>(
    py: Python<'py>,
    values: Vec<T>,
) -> Bound<'py, PyArray1<T>> {
    values.into_pyarray(py)
}

/// A grid as Python sees it: `grid` is the `(height, width)` float32 array of occupancy
/// probabilities (0.5 where unknown), row 0 at the bottom (`imshow(..., origin="lower")`),
/// cell `[row, col]`'s lower-left corner at `grid_origin_m + resolution · (col, row)`.
pub(crate) fn add_grid(
    py: Python<'_>,
    dict: &Bound<'_, PyDict>,
    grid: Option<&OccupancyGrid>,
) -> PyResult<()> {
    let Some(grid) = grid else {
        dict.set_item("grid", py.None())?;
        dict.set_item("grid_origin_m", py.None())?;
        dict.set_item("grid_resolution_m", py.None())?;
        return Ok(());
    };
    let geometry = grid.geometry();
    let probabilities: Vec<f32> = grid
        .log_odds()
        .iter()
        .map(|&l| probability_of(l) as f32)
        .collect();
    let array = Array2::from_shape_vec((geometry.height, geometry.width), probabilities)
        .map_err(|e| MapmergeError::new_err(format!("grid: {e}")))?;
    dict.set_item("grid", array.into_pyarray(py))?;
    dict.set_item("grid_origin_m", (geometry.origin_m.x, geometry.origin_m.y))?;
    dict.set_item("grid_resolution_m", geometry.resolution_m)?;
    Ok(())
}

//! Python values in, owned Rust values out (and back): arrays of points and 4×4 matrices.
//! Everything is copied while the GIL is held, so the heavy work can run without it.

use nalgebra::{Isometry3, Matrix4, Matrix6, Point3};
use numpy::ndarray::Array2;
use numpy::{
    IntoPyArray, PyArray2, PyArrayDescrMethods, PyArrayMethods, PyUntypedArray,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use sdfreg_core::geometry::se3::isometry_from_matrix;

use crate::error;

/// `obj` as a C-contiguous float64 ndarray of the given number of columns, named `name` in
/// errors. Arrays must hold floats (float32, float64, …, any byte order or memory layout); other
/// sequences (lists, Open3D vectors) are converted by `numpy.asarray`.
fn float_array<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    rows: Option<usize>,
    cols: usize,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let py = obj.py();
    let expected = match rows {
        Some(r) => format!("a ({r}, {cols}) array"),
        None => format!("an (N, {cols}) array"),
    };
    if let Ok(a) = obj.cast::<PyUntypedArray>() {
        let dtype = a.dtype();
        if dtype.kind() != b'f' {
            return Err(error::argument(
                name,
                format!("expected {expected} of float32 or float64, got dtype {dtype}"),
            ));
        }
    }
    let numpy = py.import("numpy")?;
    // C order, native-endian float64, aligned: views, big-endian data and buffers at odd
    // offsets (np.frombuffer, arrays unpickled by Dask) are copied into one.
    let converted = numpy
        .call_method1("require", (obj, "float64", "CA"))
        .map_err(|e| error::argument(name, format!("expected {expected} of numbers ({e})")))?;
    let untyped = converted.cast::<PyUntypedArray>()?;
    let shape = untyped.shape();
    if shape.len() != 2 || shape[1] != cols || rows.is_some_and(|r| shape[0] != r) {
        // Python's tuple notation: (5,) for one dimension.
        let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
        let comma = if dims.len() == 1 { "," } else { "" };
        return Err(error::argument(
            name,
            format!(
                "expected {expected}, got shape ({}{comma})",
                dims.join(", ")
            ),
        ));
    }
    Ok(converted.cast_into::<PyArray2<f64>>()?)
}

/// An (N, 3) array-like as points (copied); an object with a `.points` attribute (an Open3D
/// `PointCloud`) gives that. Finiteness and the minimum count are the core's checks, which name
/// the cloud and the point.
pub fn points(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<Point3<f64>>> {
    let cloud;
    let obj = if !obj.is_instance_of::<PyUntypedArray>() && obj.hasattr("points")? {
        cloud = obj.getattr("points")?;
        &cloud
    } else {
        obj
    };
    let array = float_array(obj, name, None, 3)?;
    let ro = array.readonly();
    let data = ro.as_slice()?;
    Ok(data
        .chunks_exact(3)
        .map(|p| Point3::new(p[0], p[1], p[2]))
        .collect())
}

/// Points that must all be finite (for writing files), named `name` in errors.
pub fn finite_points(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<Point3<f64>>> {
    let pts = points(obj, name)?;
    if let Some(row) = pts
        .iter()
        .position(|p| !p.coords.iter().all(|v| v.is_finite()))
    {
        let p = pts[row];
        return Err(error::argument(
            name,
            format!(
                "row {row} has a non-finite coordinate [{}, {}, {}]",
                p.x, p.y, p.z
            ),
        ));
    }
    Ok(pts)
}

/// `f` of `model` and `points` (an (N, 3) array of finite points, copied), with the GIL
/// released: the queries of `SdfModel` and `MeshModel`.
pub fn query<M: Send + Sync, T: Send>(
    model: &std::sync::Arc<M>,
    points: &Bound<'_, PyAny>,
    f: impl FnOnce(&M, &[Point3<f64>]) -> T + Send,
) -> PyResult<T> {
    let pts = finite_points(points, "points")?;
    let model = model.clone();
    Ok(points.py().detach(move || f(&model, &pts)))
}

/// A 4×4 rigid transform (array-like).
pub fn isometry(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Isometry3<f64>> {
    let array = float_array(obj, name, Some(4), 4)?;
    let ro = array.readonly();
    let m = Matrix4::from_row_slice(ro.as_slice()?);
    isometry_from_matrix(&m).ok_or_else(|| {
        error::argument(
            name,
            "not a rigid transform (the 3×3 block must be a rotation, the last row 0 0 0 1)",
        )
    })
}

/// A 4×4 similarity `[s R | t]` (array-like): its rigid part and `s`.
pub fn similarity(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<(Isometry3<f64>, f64)> {
    let array = float_array(obj, name, Some(4), 4)?;
    let ro = array.readonly();
    let m = Matrix4::from_row_slice(ro.as_slice()?);
    sdfreg_core::geometry::se3::similarity_from_matrix(&m).ok_or_else(|| {
        error::argument(
            name,
            "not a similarity (the 3×3 block must be a positive scale times a rotation, the last row 0 0 0 1)",
        )
    })
}

/// Points as a new (N, 3) float64 array.
pub fn points_to_array<'py>(py: Python<'py>, pts: &[Point3<f64>]) -> Bound<'py, PyArray2<f64>> {
    let flat: Vec<f64> = pts.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
    Array2::from_shape_vec((pts.len(), 3), flat)
        .expect("3 values per point")
        .into_pyarray(py)
}

/// Vertex index triples as a new (F, 3) int64 array.
pub fn faces_to_array<'py>(py: Python<'py>, faces: &[[usize; 3]]) -> Bound<'py, PyArray2<i64>> {
    let flat: Vec<i64> = faces.iter().flatten().map(|&i| i as i64).collect();
    Array2::from_shape_vec((faces.len(), 3), flat)
        .expect("3 indices per face")
        .into_pyarray(py)
}

/// A 4×4 matrix as a new float64 array.
pub fn matrix4<'py>(py: Python<'py>, m: &Matrix4<f64>) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((4, 4), |(r, c)| m[(r, c)]).into_pyarray(py)
}

/// A 6×6 matrix as a new float64 array.
pub fn matrix6<'py>(py: Python<'py>, m: &Matrix6<f64>) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((6, 6), |(r, c)| m[(r, c)]).into_pyarray(py)
}

/// What a result's `__reduce__` returns: `sdfreg._sdfreg.<restore>` and `value`'s JSON, which
/// `restore` reads back (a `Registration`, an `Evaluation`).
pub fn reduce_as_json<'py, T: serde::Serialize>(
    py: Python<'py>,
    restore: &str,
    value: &T,
) -> PyResult<Bound<'py, pyo3::types::PyTuple>> {
    let json = serde_json::to_string(value)
        .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))?;
    let restore = py.import("sdfreg._sdfreg")?.getattr(restore)?;
    let args = pyo3::types::PyTuple::new(py, [json])?;
    pyo3::types::PyTuple::new(py, [restore.into_any(), args.into_any()])
}

//! `sdfreg.MeshModel`: a target mesh as its own exact distance field (the core's `MeshModel`),
//! `sdfreg.mesh_model` and `sdfreg.read_mesh`. Registering against it needs no fitting.

use std::path::PathBuf;
use std::sync::Arc;

use nalgebra::Point3;
use numpy::{PyArray1, PyArray2, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple};
use sdfreg_core::{MeshModel, RegisterSettings};

use crate::convert;
use crate::error;
use crate::model::MeshArrays;
use crate::settings::IntoSetting;

/// A target mesh as its exact distance field (see :func:`mesh_model`).
#[pyclass(module = "sdfreg", name = "MeshModel", frozen)]
pub struct PyMeshModel {
    pub model: Arc<MeshModel>,
    vertices: Vec<Point3<f64>>,
    faces: Vec<[usize; 3]>,
    seed: u64,
    max_target_points: usize,
}

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// A target mesh as its own exact distance field: registering against it needs no fitting
/// (scans onto CAD models or reconstructions).
///
/// Φ(x) is the distance to the nearest triangle (signed, negative inside, when the mesh is
/// closed and consistently wound; see :attr:`MeshModel.is_signed`); far from the surface
/// (beyond four edge lengths from the nearest vertex) the nearest vertex's distance stands in.
///
/// Args:
///     vertices: (V, 3) points, any units.
///     faces: (F, 3) integer vertex indices.
///     seed: Seed of the target points sampled on the faces for the polish.
///     max_target_points: How many target points are sampled (default: as ``register``).
///
/// Raises:
///     ValueError: ``vertices`` is not an (N, 3) finite float array, ``faces`` not an (F, 3)
///         integer array, an index is out of range, there are no faces or they have no area.
#[pyfunction]
#[pyo3(signature = (vertices, faces, *, seed = 0, max_target_points = None))]
pub fn mesh_model(
    py: Python<'_>,
    vertices: &Bound<'_, PyAny>,
    faces: &Bound<'_, PyAny>,
    seed: i64,
    max_target_points: Option<i64>,
) -> PyResult<PyMeshModel> {
    let vertices = convert::finite_points(vertices, "vertices")?;
    let faces = face_indices(faces)?;
    let mut s = RegisterSettings {
        seed: seed.into_setting("seed")?,
        ..Default::default()
    };
    if let Some(n) = max_target_points {
        s.max_target_points = n.into_setting("max_target_points")?;
    }
    let model = py
        .detach(|| MeshModel::new(&vertices, &faces, &s))
        .map_err(error::registration)?;
    Ok(PyMeshModel {
        model: Arc::new(model),
        vertices,
        faces,
        seed: s.seed,
        max_target_points: s.max_target_points,
    })
}

/// `faces` as vertex index triples: an (F, 3) array of integers ≥ 0.
fn face_indices(faces: &Bound<'_, PyAny>) -> PyResult<Vec<[usize; 3]>> {
    let np = faces.py().import("numpy")?;
    let array = np.call_method1("asarray", (faces,))?;
    let kind: String = array.getattr("dtype")?.getattr("kind")?.extract()?;
    let shape: Vec<usize> = array.getattr("shape")?.extract()?;
    if !matches!(kind.as_str(), "i" | "u") || shape.len() != 2 || shape[1] != 3 {
        return Err(error::argument(
            "faces",
            format!("expected an (F, 3) integer array, got shape {shape:?} of kind {kind:?}"),
        ));
    }
    let array = np.call_method1("ascontiguousarray", (array, "int64"))?;
    let array: PyReadonlyArray2<'_, i64> = array.extract()?;
    array
        .as_slice()?
        .chunks_exact(3)
        .enumerate()
        .map(|(k, f)| {
            let index = |i: i64| {
                usize::try_from(i).map_err(|_| {
                    error::argument("faces", format!("face {k} has a negative index {i}"))
                })
            };
            Ok([index(f[0])?, index(f[1])?, index(f[2])?])
        })
        .collect()
}

/// A MeshModel from its parts (unpickling).
#[pyfunction]
pub fn _mesh_model_from_parts(
    py: Python<'_>,
    vertices: &Bound<'_, PyAny>,
    faces: &Bound<'_, PyAny>,
    seed: i64,
    max_target_points: i64,
) -> PyResult<PyMeshModel> {
    mesh_model(py, vertices, faces, seed, Some(max_target_points))
}

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// Reads a PLY mesh: ``(vertices (V, 3) float64, faces (F, 3) int64)``; a cloud without faces
/// gives an empty ``faces``.
///
/// Raises:
///     OSError: the file cannot be read, is not a PLY or is malformed (naming the file).
#[pyfunction]
pub fn read_mesh(py: Python<'_>, path: PathBuf) -> PyResult<MeshArrays<'_>> {
    let (vertices, faces) = py
        .detach(|| sdfreg_core::io::read_mesh(&path))
        .map_err(error::io)?;
    Ok((
        convert::points_to_array(py, &vertices),
        convert::faces_to_array(py, &faces),
    ))
}

#[pymethods]
impl PyMeshModel {
    /// Registers ``source`` onto the mesh: ``sdfreg.register(source, mesh, **kwargs)``.
    #[pyo3(signature = (source, **kwargs))]
    fn register<'py>(
        slf: &Bound<'py, Self>,
        source: &Bound<'py, PyAny>,
        kwargs: Option<&Bound<'py, PyDict>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let register = slf.py().import("sdfreg._sdfreg")?.getattr("register")?;
        register.call((source, slf), kwargs)
    }

    /// The distance at ``points`` ((N, 3), the mesh's units and frame), negative inside when
    /// :attr:`is_signed`, as an (N,) float64 array.
    fn distance<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let d = convert::query(&self.model, points, |m, p| m.distance(p))?;
        Ok(PyArray1::from_vec(py, d))
    }

    /// The closest surface point of each of ``points``, as (N, 3).
    fn closest_points<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let c = convert::query(&self.model, points, |m, p| m.closest_points(p))?;
        Ok(convert::points_to_array(py, &c))
    }

    /// Whether the distance is signed: the mesh is closed and consistently wound.
    #[getter]
    fn is_signed(&self) -> bool {
        self.model.is_signed()
    }

    /// The points sampled on the faces for the polish, (M, 3).
    #[getter]
    fn target_points<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        convert::points_to_array(py, &self.model.target_points())
    }

    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let restore = py
            .import("sdfreg._sdfreg")?
            .getattr("_mesh_model_from_parts")?;
        let args = (
            convert::points_to_array(py, &self.vertices),
            convert::faces_to_array(py, &self.faces),
            self.seed,
            self.max_target_points,
        )
            .into_pyobject(py)?;
        PyTuple::new(py, [restore.into_any(), args.into_any()])
    }

    fn __repr__(&self) -> String {
        format!(
            "MeshModel({} vertices, {} faces, {}, seed {})",
            self.vertices.len(),
            self.faces.len(),
            if self.model.is_signed() {
                "signed"
            } else {
                "unsigned"
            },
            self.seed
        )
    }
}

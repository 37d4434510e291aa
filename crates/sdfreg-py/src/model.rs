//! `sdfreg.SdfModel`: the fitted target (the core's `SdfModel`), `sdfreg.fit` and
//! `sdfreg.load_model`. A model is immutable and shared (`Arc`): registering against it from
//! several Python threads at once is safe, and every call that computes releases the GIL.
//! Pickling goes through the `.sdfm` bytes, so a model travels to multiprocessing, Dask and Ray
//! workers and comes back bit-identical.

use std::path::PathBuf;
use std::sync::Arc;

use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyTuple};
use sdfreg_core::geometry::cloud::LeftOut;
use sdfreg_core::SdfModel;

use crate::convert;
use crate::error;
use crate::settings::{Caller, IntoSetting, SettingsArgs};

/// A mesh as numpy arrays: vertices (V, 3) and faces (F, 3).
pub(crate) type MeshArrays<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<i64>>);

/// A target fitted once (see :func:`fit`).
#[pyclass(module = "sdfreg", name = "SdfModel", frozen)]
pub struct PySdfModel(pub Arc<SdfModel>);

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// Fits the SDF model of ``target`` once, to register many sources against it.
///
/// Runs the first stages of :func:`register` on the target alone: the normalisation and the
/// pre-fit of Φ. ``register(source, model)`` (or ``model.register(source)``) then skips them.
///
/// Args:
///     target: (M, 3) points (array, Open3D ``PointCloud``, …), any units.
///     seed: Seed of every random choice; equal seeds give identical models.
///     threads: Worker threads; 0 = one per core. The model does not depend on it.
///     max_target_points: Target points used at most (larger clouds are subsampled, seeded).
///     mlp: The network (:class:`MlpSettings`).
///     fit: The fit (:class:`FitSettings`).
///     model: Kind of Φ: ``"global"`` (one MLP: objects), ``"local"`` (the MLP plus a sparse
///         voxel grid of corrections near the target's points: rooms, streets), or ``"auto"``
///         (local when the target's largest side is at least 400 point spacings). None keeps
///         ``fit``'s (auto by default).
///
/// Returns:
///     The :class:`SdfModel`.
///
/// Raises:
///     ValueError: ``target`` is not an (N, 3) float array, has a NaN or infinite coordinate,
///         fewer than 10 points or no extent; a setting is out of range.
///
/// Warns:
///     UserWarning: points were left out of ``target``: missing returns at (0, 0, 0) or stray
///         points, one warning per kind with how many.
#[pyfunction]
#[pyo3(signature = (target, **settings))]
pub fn fit<'py>(
    py: Python<'py>,
    target: &Bound<'py, PyAny>,
    settings: Option<&Bound<'py, PyDict>>,
) -> PyResult<PySdfModel> {
    let target = convert::points(target, "target")?;
    let s = SettingsArgs::from_kwargs(Caller::Fit, settings)?.build("default")?;
    let (model, left_out) = py
        .detach(|| {
            let model = SdfModel::fit(&target, &s)?;
            Ok((model, LeftOut::of(&target)))
        })
        .map_err(error::registration)?;
    error::warn_left_out(py, "target", target.len(), &left_out)?;
    Ok(PySdfModel(Arc::new(model)))
}

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// Reads a model written by :meth:`SdfModel.save` (``.sdfm``).
///
/// Raises:
///     OSError: the file cannot be read, or it is not an sdfreg model: truncated, corrupted
///         (checksum), of another program, or of a newer format version; the message names
///         the file and what is wrong.
#[pyfunction]
pub fn load_model(py: Python<'_>, path: PathBuf) -> PyResult<PySdfModel> {
    let model = py.detach(|| SdfModel::load(&path)).map_err(error::io)?;
    Ok(PySdfModel(Arc::new(model)))
}

/// A model from `.sdfm` bytes (unpickling).
#[pyfunction]
pub fn _model_from_bytes(py: Python<'_>, data: &[u8]) -> PyResult<PySdfModel> {
    let bytes = data.to_vec();
    let model = py
        .detach(|| SdfModel::from_bytes(&bytes, std::path::Path::new("<pickle>")))
        .map_err(error::io)?;
    Ok(PySdfModel(Arc::new(model)))
}

#[pymethods]
impl PySdfModel {
    /// Registers ``source`` onto this model: ``sdfreg.register(source, model, **kwargs)``
    /// (Φ frozen unless ``refine=True``).
    #[pyo3(signature = (source, **kwargs))]
    fn register<'py>(
        slf: &Bound<'py, Self>,
        source: &Bound<'py, PyAny>,
        kwargs: Option<&Bound<'py, PyDict>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let py = slf.py();
        let register = py.import("sdfreg._sdfreg")?.getattr("register")?;
        register.call((source, slf), kwargs)
    }

    /// Signed distance Φ at ``points`` ((N, 3), the target's units and frame), positive
    /// outside, as an (N,) float64 array.
    fn distance<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let d = convert::query(&self.0, points, |m, p| m.distance(p))?;
        Ok(PyArray1::from_vec(py, d))
    }

    /// ∇Φ at ``points`` as an (N, 3) float64 array (about unit length near the surface).
    fn gradient<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let g = convert::query(&self.0, points, |m, p| m.gradient(p))?;
        let as_points: Vec<nalgebra::Point3<f64>> =
            g.into_iter().map(nalgebra::Point3::from).collect();
        Ok(convert::points_to_array(py, &as_points))
    }

    /// The closest surface point of each of ``points``, ``p − Φ ∇Φ/‖∇Φ‖``, as (N, 3).
    fn closest_points<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let q = convert::query(&self.0, points, |m, p| m.closest_points(p))?;
        Ok(convert::points_to_array(py, &q))
    }

    /// Φ's zero level set as a triangle mesh: ``(vertices (V, 3) float64, faces (F, 3)
    /// int64)``, the target's units and frame, outward normals by the right-hand rule.
    /// ``resolution``: grid cells along the target's largest side (4 to 1024).
    #[pyo3(signature = (resolution = 128))]
    fn mesh<'py>(&self, py: Python<'py>, resolution: i64) -> PyResult<MeshArrays<'py>> {
        let resolution: usize = resolution.into_setting("resolution")?;
        let model = self.0.clone();
        let (vertices, triangles) = py
            .detach(move || model.mesh(resolution))
            .map_err(error::registration)?;
        let faces: Vec<i64> = triangles.iter().flatten().map(|&i| i as i64).collect();
        let faces = numpy::ndarray::Array2::from_shape_vec((triangles.len(), 3), faces)
            .expect("3 indices per face");
        Ok((
            convert::points_to_array(py, &vertices),
            numpy::IntoPyArray::into_pyarray(faces, py),
        ))
    }

    /// Registers a sequence of ``frames`` ((N, 3) each) against the model, the first from
    /// ``init`` (4×4, frame into target; identity when None), each next one from the previous
    /// frame's pose, with the ``"tracking"`` preset (no multi-start, a few LM steps, a short
    /// polish) and these overrides. Returns one :class:`Registration` per frame, or the
    /// ``ValueError`` of a frame that could not be registered, in its place. Points left out
    /// of a frame are counted in its result's ``points_left_out``, without a warning.
    #[pyo3(signature = (frames, *, init = None, **settings))]
    fn track<'py>(
        &self,
        py: Python<'py>,
        frames: &Bound<'py, PyAny>,
        init: Option<&Bound<'py, PyAny>>,
        settings: Option<&Bound<'py, PyDict>>,
    ) -> PyResult<Vec<Bound<'py, PyAny>>> {
        let s = SettingsArgs::from_kwargs(Caller::Track, settings)?.build("tracking")?;
        let clouds: Vec<Vec<nalgebra::Point3<f64>>> = frames
            .try_iter()?
            .enumerate()
            .map(|(i, f)| convert::points(&f?, &format!("frames[{i}]")))
            .collect::<PyResult<_>>()?;
        let init = init
            .map(|m| convert::isometry(m, "init"))
            .transpose()?
            .unwrap_or_else(nalgebra::Isometry3::identity);
        let model = self.0.clone();
        let results = py
            .detach(move || {
                let refs: Vec<&[nalgebra::Point3<f64>]> =
                    clouds.iter().map(Vec::as_slice).collect();
                model.track(refs, &init, &s)
            })
            .map_err(error::registration)?;
        results
            .into_iter()
            .enumerate()
            .map(|(i, r)| match r {
                Ok(r) => Ok(Bound::new(py, crate::registration::PyRegistration(r))?.into_any()),
                Err(e) => Ok(error::argument(&format!("frames[{i}]"), e)
                    .into_value(py)
                    .into_bound(py)
                    .into_any()),
            })
            .collect()
    }

    /// The target points Φ was fitted to (subsampled), (M, 3), the target's units and frame.
    #[getter]
    fn target_points<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        convert::points_to_array(py, &self.0.target_points())
    }

    /// The seed the model was fitted with.
    #[getter]
    fn seed(&self) -> u64 {
        self.0.seed()
    }

    /// ``"global"`` (Φ is one MLP) or ``"local"`` (the MLP plus a sparse voxel grid of
    /// corrections near the target's points), as ``model=`` decided it.
    #[getter]
    fn kind(&self) -> &'static str {
        self.0.kind().name()
    }

    /// A local model's voxel side, in the target's units; None for a global model.
    #[getter]
    fn voxel(&self) -> Option<f64> {
        self.0.voxel()
    }

    /// The local grid's corrections (one per voxel corner near the target); 0 for a global
    /// model.
    #[getter]
    fn local_parameters(&self) -> usize {
        self.0.local_parameters()
    }

    /// Writes the model to ``path`` (``.sdfm``: a safetensors file, readable without sdfreg);
    /// an existing file is replaced.
    ///
    /// Raises:
    ///     OSError: the file cannot be written.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let model = self.0.clone();
        py.detach(move || model.save(&path)).map_err(error::io)
    }

    /// The ``.sdfm`` file's bytes.
    fn to_bytes<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        let model = self.0.clone();
        let bytes = py.detach(move || model.to_bytes());
        PyBytes::new(py, &bytes)
    }

    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let restore = py.import("sdfreg._sdfreg")?.getattr("_model_from_bytes")?;
        let args = PyTuple::new(py, [self.to_bytes(py)])?;
        PyTuple::new(py, [restore.into_any(), args.into_any()])
    }

    fn __repr__(&self) -> String {
        let (mlp, _) = self.0.settings();
        let n = self.0.normalization();
        format!(
            "SdfModel({} target points, extent {:.6}, centre [{:.6}, {:.6}, {:.6}], MLP {}×{}{}, seed {})",
            self.0.target_points().len(),
            n.scale,
            n.centre.x,
            n.centre.y,
            n.centre.z,
            mlp.width,
            mlp.depth,
            match self.0.voxel() {
                Some(v) => format!(
                    ", local grid of {} corrections at voxel {v:.6}",
                    self.0.local_parameters()
                ),
                None => String::new(),
            },
            self.0.seed()
        )
    }
}

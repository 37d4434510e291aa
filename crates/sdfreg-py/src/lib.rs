//! Python bindings of sdfreg: `sdfreg.register`, `sdfreg.read_point_cloud`,
//! `sdfreg.write_point_cloud`, the `sdfreg.Registration` result and the settings groups
//! (`sdfreg.LmSettings`, …, in `settings.rs`). They only convert and
//! forward to `sdfreg-core`: arguments are copied into owned Rust values, then the work runs with
//! the GIL released (`Python::detach`), so Python threads can register in parallel.
//!
//! Fork safety: the core runs every call in its own rayon pool, created for that call, and
//! never touches rayon's global pool, so a forked child (multiprocessing) starts no work on
//! threads that only its parent had.
//!
//! Stubs and docstrings for Python users: `python/sdfreg/_sdfreg.pyi`.

mod align;
mod batch;
mod convert;
mod error;
mod evaluate;
mod mesh_model;
mod model;
mod registration;
mod settings;

use std::path::PathBuf;

use numpy::PyArray2;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use mesh_model::PyMeshModel;
use model::PySdfModel;
use registration::{PyFreeMotion, PyRegistration};
use settings::{
    Caller, PyCoarseToFineSettings, PyFitSettings, PyLmSettings, PyMlpSettings,
    PyMultistartSettings, PyPolishSettings, PyRobustSettings, PyShiftSearchSettings, SettingsArgs,
};

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// Registers ``source`` onto ``target``: finds the rigid transform that moves the source
/// cloud onto the target's surface, without point correspondences.
///
/// The target is represented by a small neural signed distance function Φ, fitted to it; the
/// source is moved by Levenberg–Marquardt so that ``Σ Φ(R p + t)²`` is minimal, alternating
/// with refinements of Φ near the moving source. Without ``init``, the centroids are aligned
/// and the 24 rotations of the cube group (and small shifts) are tried, so any initial
/// rotation works.
///
/// Args:
///     source: (N, 3) points to move: a float32 or float64 array in any memory layout, an
///         Open3D ``PointCloud`` (anything with a ``.points`` that numpy reads), or anything
///         ``numpy.asarray`` turns into one.
///     target: (M, 3) points that stay fixed, same units as ``source``; or an
///         :class:`SdfModel` of them (:func:`fit`), registered against without fitting; or a
///         :class:`MeshModel` (:func:`mesh_model`), a mesh's exact distance field.
///         Points at exactly (0, 0, 0) (two or more: a scanner's missing returns) and stray
///         points (under 1 % of a cloud, more than 30 times as far from its middle as 99 % of
///         it) are left out of either cloud.
///     init: Optional 4×4 rigid initial guess mapping source into target; replaces the
///         multi-start.
///     refine: With an :class:`SdfModel` target: refine a private copy of Φ with the moved
///         source among its queries, as registering against the cloud does (slower; the same
///         numbers as the cloud). None: False for a model (Φ frozen); a cloud is always
///         refined.
///     preset: ``"default"``, ``"scans"`` for scans known to overlap only in part (the
///         robust kernel from the start, multi-start tie 0.05), ``"views"`` (``"scans"`` with an
///         object's polish pass ending when its steps stop shrinking, against planes at the target's points; a scene's polish on 16384 source points), or ``"learned"`` (an object's pre-fit of 150 steps from an initialisation learned on procedural objects: about 0.7 of the time). The arguments below override it; None keeps the
///         preset's value.
///     robust: ``"auto"`` (least squares, redone with the robust kernel when it fits poorly),
///         ``"on"``, ``"off"``, or a :class:`RobustSettings`.
///     seed: Seed of every random choice; equal seeds give identical results.
///     threads: Worker threads; 0 = one per core. The result does not depend on it.
///     max_source_points: Source points used at most (larger clouds are subsampled, seeded).
///     max_target_points: Target points used at most.
///     inlier_distance: A source point within this distance of a target point is an inlier
///         (``fitness``, ``inlier_rmse``); a fraction of the target's largest side.
///     free_motion_ratio: Constraint eigenvalues below this (relative) are reported as
///         ``free_motions``.
///     mlp: The SDF network (:class:`MlpSettings`).
///     fit: Fitting Φ (:class:`FitSettings`).
///     multistart: The initial hypotheses (:class:`MultistartSettings`).
///     coarse_to_fine: The alternation schedule (:class:`CoarseToFineSettings`).
///     lm: The Levenberg–Marquardt solver (:class:`LmSettings`).
///     polish: The final point-to-plane steps (:class:`PolishSettings`).
///     shift_search: The translation search (:class:`ShiftSearchSettings`).
///     scale: Estimate a scale with the pose (similarity registration: millimetres against
///         metres, an SfM reconstruction against a LiDAR map). ``transformation`` is then
///         ``[s R | t]`` and :attr:`Registration.scale` holds ``s``; with ``init``, the scale
///         of its 3×3 block is the start. Default False (rigid).
///     scale_range: ``(min, max)``: the scale (target units per source unit) stays within
///         them; needs ``scale=True``. Default 0.1 to 10 times the unit factor (1, 1000 or
///         0.001) the clouds' extents point to.
///     swap_ratio: A cloud target with at least this many times fewer points than the source
///         (and at least half its size) is registered the other way round, the denser cloud as
///         Φ's, and the result inverted (``stages["swapped"]``); 0 never. Default 4.
///     model: Kind of Φ fitted to a cloud target: ``"global"`` (one MLP: objects),
///         ``"local"`` (the MLP plus a sparse voxel grid of corrections near the target's
///         points: rooms, streets), or ``"auto"`` (local when the target's largest side is at
///         least 400 point spacings). None keeps ``fit``'s (auto by default).
///
/// A settings object replaces the preset's whole group.
///
/// Returns:
///     The :class:`Registration`.
///
/// Raises:
///     ValueError: a cloud is not an (N, 3) float array, has a NaN or infinite coordinate,
///         fewer than 10 points or no extent; ``init`` is not a rigid 4×4 transform (with
///         ``scale=True``: not a positive scale times a rotation); a setting is out of range
///         (``scale_range`` with min ≥ max or a bound ≤ 0).
///
/// Warns:
///     UserWarning: the target is a local (scene) :class:`SdfModel` and the result fits less
///         than ``LocalSettings.global_rerun_below_fitness`` of the source (a full call would
///         run again with a global Φ): scans that overlap only in part register more reliably
///         against a model fitted with ``model="global"``.
///     UserWarning: points were left out of ``source`` or a cloud ``target``: missing returns
///         at (0, 0, 0) or stray points, one warning per kind and cloud with how many
///         (:attr:`Registration.points_left_out` holds the counts).
#[pyfunction]
#[pyo3(signature = (source, target, *, init = None, refine = None, **settings))]
fn register<'py>(
    py: Python<'py>,
    source: &Bound<'py, PyAny>,
    target: &Bound<'py, PyAny>,
    init: Option<&Bound<'py, PyAny>>,
    refine: Option<bool>,
    settings: Option<&Bound<'py, PyDict>>,
) -> PyResult<PyRegistration> {
    let source = convert::points(source, "source")?;
    let target = Target::from_python(target)?;
    let refine = match (&target, refine) {
        (Target::Mesh(_), Some(true)) => {
            return Err(error::argument(
                "refine",
                "True needs an SdfModel target (a mesh's exact field is not refined)",
            ));
        }
        (Target::Cloud(_), Some(false)) => {
            return Err(error::argument(
                "refine",
                "False needs an SdfModel target (a cloud is fitted and refined)",
            ));
        }
        (_, refine) => refine.unwrap_or(false),
    };
    let mut s = SettingsArgs::from_kwargs(Caller::Register, settings)?.build("default")?;
    let init = match init {
        Some(m) if s.scale.enabled => {
            let (pose, scale) = convert::similarity(m, "init")?;
            s.scale.initial = Some(scale);
            Some(pose)
        }
        m => m.map(|m| convert::isometry(m, "init")).transpose()?,
    };
    let result = py
        .detach(|| match &target {
            Target::Cloud(points) => sdfreg_core::register(&source, points, init.as_ref(), &s),
            Target::Model(model) if refine => model.register_refined(&source, init.as_ref(), &s),
            Target::Model(model) => model.register(&source, init.as_ref(), &s),
            Target::Mesh(mesh) => mesh.register(&source, init.as_ref(), &s),
        })
        .map_err(error::registration)?;
    if let Target::Model(model) = &target {
        if model.fits_poorly(&result, &s) {
            let message = format!(
                "the source fits {:.3} of a local (scene) model; scans that overlap only in part register more reliably against a global one (sdfreg.fit(target, model=\"global\"))",
                result.fitness
            );
            error::warn(py, message)?;
        }
    }
    error::warn_left_out(py, "source", source.len(), &result.source_left_out)?;
    if let Target::Cloud(points) = &target {
        error::warn_left_out(py, "target", points.len(), &result.target_left_out)?;
    }
    Ok(PyRegistration(result))
}

/// What a source is registered against (`register`'s and each pair's `target`): the target's
/// points, a fitted model, or a mesh's exact field.
pub(crate) enum Target {
    Cloud(Vec<nalgebra::Point3<f64>>),
    Model(std::sync::Arc<sdfreg_core::SdfModel>),
    Mesh(std::sync::Arc<sdfreg_core::MeshModel>),
}

impl Target {
    /// An `SdfModel`, a `MeshModel`, or else an (N, 3) cloud (`ValueError` naming `target`).
    pub(crate) fn from_python(obj: &Bound<'_, PyAny>) -> PyResult<Self> {
        if let Ok(model) = obj.cast::<PySdfModel>() {
            Ok(Target::Model(model.get().0.clone()))
        } else if let Ok(mesh) = obj.cast::<PyMeshModel>() {
            Ok(Target::Mesh(mesh.get().model.clone()))
        } else {
            Ok(Target::Cloud(convert::points(obj, "target")?))
        }
    }
}

/// The core's defaults of every settings group, as nested dicts (for tests).
#[pyfunction]
fn _core_defaults(py: Python<'_>) -> PyResult<Bound<'_, PyAny>> {
    settings::core_defaults(py)
}

/// Each settings keyword of the binding and the functions that take it (for the test that
/// holds the stubs' keyword declarations equal to [`settings::KEYWORDS`]).
#[pyfunction]
fn _settings_keywords() -> std::collections::BTreeMap<&'static str, Vec<&'static str>> {
    settings::KEYWORDS
        .iter()
        .map(|k| (k.name, k.callers.iter().map(|c| c.name()).collect()))
        .collect()
}

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// Reads a point cloud as an (N, 3) float64 array.
///
/// Formats by extension: ``.ply`` (ascii or binary, any numeric type; the ``vertex``
/// element's x, y, z), ``.pcd`` (ascii, binary or binary_compressed; the x, y, z fields),
/// ``.las`` and ``.laz`` (any version and point format, LASzip-compressed or not; x, y, z
/// with the file's scale and offset), ``.e57`` (every scan placed by its pose in the file's
/// frame; spherical scans converted; points without coordinates skipped), ``.xyz``, ``.txt``,
/// ``.csv``, ``.pts`` (first three columns; a ``.pts`` block's point-count line is
/// checked against its rows).
///
/// Args:
///     path: The file.
///     drop_non_finite: Drop points with a NaN or infinite coordinate (organised PCL clouds
///         and range scanners mark missing returns that way) and warn how many, instead of
///         raising.
///
/// Raises:
///     OSError: the file cannot be read (``FileNotFoundError``, ``PermissionError``, …), its
///         format is unknown, or its contents are malformed; the message names the file and,
///         for text and ascii PLY, the line.
#[pyfunction]
#[pyo3(signature = (path, *, drop_non_finite = false))]
fn read_point_cloud(
    py: Python<'_>,
    path: PathBuf,
    drop_non_finite: bool,
) -> PyResult<Bound<'_, PyArray2<f64>>> {
    let (points, dropped) = py
        .detach(|| {
            if drop_non_finite {
                sdfreg_core::io::read_point_cloud_dropping_non_finite(&path)
            } else {
                sdfreg_core::io::read_point_cloud(&path).map(|p| (p, 0))
            }
        })
        .map_err(error::io)?;
    warn_dropped(py, &path, dropped, points.len() + dropped)?;
    Ok(convert::points_to_array(py, &points))
}

/// A `UserWarning` saying how many of `path`'s `total` points were dropped as non-finite, if
/// any.
fn warn_dropped(
    py: Python<'_>,
    path: &std::path::Path,
    dropped: usize,
    total: usize,
) -> PyResult<()> {
    if dropped == 0 {
        return Ok(());
    }
    let message = format!(
        "{}: dropped {dropped} of {total} points with a NaN or infinite coordinate",
        path.display()
    );
    error::warn(py, message)
}

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// Reads each scan of an E57 file apart: a list of ``(name, pose, points)``, in the file's
/// order. ``name`` is the scan's name in the file (``None`` if it has none), ``pose`` the
/// (4, 4) float64 that maps the scan's coordinates into the file's frame, ``points`` its
/// (N, 3) float64 points in its own frame (points the file marks as having no coordinates are
/// not points; a scan may have none). :func:`read_point_cloud` gives all of them in the file's
/// frame instead; ``sdfreg.align([points for _, _, points in scans])`` aligns them anew.
///
/// Args:
///     path: The ``.e57`` file.
///     drop_non_finite: Drop points with a NaN or infinite coordinate and warn how many,
///         instead of raising.
///
/// Raises:
///     OSError: the file cannot be read, is not an E57 file, fails a page's checksum, has no
///         point in any scan, or a NaN coordinate (naming the file and the scan).
#[pyfunction]
#[pyo3(signature = (path, *, drop_non_finite = false))]
fn read_e57_scans(
    py: Python<'_>,
    path: PathBuf,
    drop_non_finite: bool,
) -> PyResult<Vec<E57ScanArrays<'_>>> {
    let (scans, dropped) = py
        .detach(|| sdfreg_core::io::read_e57_scans(&path, drop_non_finite))
        .map_err(error::io)?;
    let kept: usize = scans.iter().map(|s| s.points.len()).sum();
    warn_dropped(py, &path, dropped, kept + dropped)?;
    Ok(scans
        .into_iter()
        .map(|s| {
            (
                s.name,
                convert::matrix4(py, &s.pose.to_homogeneous()),
                convert::points_to_array(py, &s.points),
            )
        })
        .collect())
}

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// Writes scans as the scans of one E57 file, each with its name, its pose and its points in
/// its own frame as float64: what :func:`read_e57_scans` reads back, to the bit. An existing file
/// is replaced. With :func:`align`, a campaign registered anew::
///
///     scans = sdfreg.read_e57_scans("campaign.e57")
///     aligned = sdfreg.align([points for _, _, points in scans])
///     sdfreg.write_e57_scans("registered.e57", [
///         (name, pose, points)
///         for (name, _, points), pose in zip(scans, aligned.poses) if pose is not None
///     ])
///
/// Args:
///     path: The ``.e57`` file to write.
///     scans: ``(name, pose, points)`` per scan: ``name`` a str or ``None``, ``pose`` a (4, 4)
///         rigid transform from the scan's frame into the file's, ``points`` (N, 3) finite.
///
/// Raises:
///     ValueError: a scan is not such a triple, its pose is not rigid or a point is not finite
///         (naming the scan).
///     OSError: the file cannot be written.
#[pyfunction]
fn write_e57_scans(py: Python<'_>, path: PathBuf, scans: &Bound<'_, PyAny>) -> PyResult<()> {
    let mut owned = Vec::new();
    let not_triples =
        || error::argument("scans", "not an iterable of (name, pose, points) triples");
    for (k, scan) in scans.try_iter().map_err(|_| not_triples())?.enumerate() {
        let scan = scan?;
        let name = format!("scans[{k}]");
        let triple = || error::argument(&name, "not a (name, pose, points) triple");
        let (label, pose, points): (Bound<'_, PyAny>, Bound<'_, PyAny>, Bound<'_, PyAny>) =
            scan.extract().map_err(|_| triple())?;
        let label: Option<String> = label.extract().map_err(|_| triple())?;
        let pose = convert::isometry(&pose, &format!("{name} pose"))?;
        let points = convert::finite_points(&points, &format!("{name} points"))?;
        owned.push((label, pose, points));
    }
    py.detach(|| {
        let scans: Vec<sdfreg_core::io::E57ScanRef<'_>> = owned
            .iter()
            .map(|(name, pose, points)| sdfreg_core::io::E57ScanRef {
                name: name.as_deref(),
                pose: *pose,
                points,
            })
            .collect();
        sdfreg_core::io::write_e57_scans(&path, &scans)
    })
    .map_err(error::io)
}

/// One scan of an E57 file for Python: name, pose, points.
type E57ScanArrays<'py> = (
    Option<String>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<f64>>,
);

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// Writes (N, 3) finite points; the format follows the extension (``.ply``: binary
/// float64; ``.pcd``: binary float64; ``.las``: LAS 1.2 point format 0, integers at a
/// scale of 10⁻⁹–10⁻⁸ of the cloud's extent, LASzip-compressed in ``.laz``; ``.e57``: one scan of float64; text formats: one ``x y z`` line per point, full
/// precision, after a point-count line in ``.pts``). An existing file is replaced.
///
/// Raises:
///     ValueError: ``points`` is not an (N, 3) float array or has a non-finite coordinate.
///     OSError: the file cannot be written or the extension is unknown.
#[pyfunction]
fn write_point_cloud(py: Python<'_>, path: PathBuf, points: &Bound<'_, PyAny>) -> PyResult<()> {
    let points = convert::finite_points(points, "points")?;
    py.detach(|| sdfreg_core::io::write_point_cloud(&path, &points))
        .map_err(error::io)
}

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// Writes the cloud file ``input`` moved by ``transformation`` (a 4×4 ``[s R | t]`` mapping
/// its coordinates into the output's, such as a registration's, source into target) to
/// ``output``. When ``output`` has ``input``'s format, every point keeps its other fields
/// (intensity, colour, classification, GPS time, extra columns), its normals turned, and the
/// file its other elements and header records: PLY and PCD (ascii or binary), LAS and LAZ, and
/// text. Otherwise, or for a PCD ``binary_compressed`` body, integer or list coordinates in a
/// PLY, or E57, the moved coordinates alone are written, as ``write_point_cloud`` does.
/// Missing returns at (0, 0, 0) and non-finite points stay as they are. An existing file is
/// replaced.
///
/// Returns:
///     A dict: ``points`` (written, in the input's order), ``left_in_place`` (missing returns
///     and non-finite points), ``fields_kept`` (bool) and ``reason`` (why only the coordinates
///     were written, else ``None``).
///
/// Raises:
///     ValueError: ``transformation`` is not a 4×4 similarity.
///     OSError: ``input`` cannot be read or is not a valid cloud, or ``output`` cannot be
///         written, or an extension is unknown.
#[pyfunction]
fn write_moved_point_cloud<'py>(
    py: Python<'py>,
    input: PathBuf,
    output: PathBuf,
    transformation: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyDict>> {
    let (pose, scale) = convert::similarity(transformation, "transformation")?;
    let motion = nalgebra::Similarity3::from_isometry(pose, scale);
    let moved = py
        .detach(|| sdfreg_core::io::write_moved_point_cloud(&input, &output, &motion))
        .map_err(error::io)?;
    let d = PyDict::new(py);
    d.set_item("points", moved.points)?;
    d.set_item("left_in_place", moved.left_in_place)?;
    let reason = match moved.fields {
        sdfreg_core::io::Fields::Kept => None,
        sdfreg_core::io::Fields::CoordinatesOnly(why) => Some(why),
    };
    d.set_item("fields_kept", reason.is_none())?;
    d.set_item("reason", reason)?;
    Ok(d)
}

/// The native part of the `sdfreg` package.
#[pymodule]
fn _sdfreg(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(register, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate::evaluate_registration, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate::_evaluation_from_json, m)?)?;
    m.add_class::<evaluate::PyEvaluation>()?;
    m.add_function(wrap_pyfunction!(align::align, m)?)?;
    m.add_class::<align::PyAlignment>()?;
    m.add_function(wrap_pyfunction!(align::read_poses, m)?)?;
    m.add_function(wrap_pyfunction!(batch::register_many, m)?)?;
    m.add_function(wrap_pyfunction!(read_point_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(read_e57_scans, m)?)?;
    m.add_function(wrap_pyfunction!(write_e57_scans, m)?)?;
    m.add_function(wrap_pyfunction!(write_point_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(write_moved_point_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(_core_defaults, m)?)?;
    m.add_function(wrap_pyfunction!(_settings_keywords, m)?)?;
    m.add_function(wrap_pyfunction!(model::fit, m)?)?;
    m.add_function(wrap_pyfunction!(model::load_model, m)?)?;
    m.add_function(wrap_pyfunction!(model::_model_from_bytes, m)?)?;
    m.add_function(wrap_pyfunction!(registration::_registration_from_json, m)?)?;
    m.add_function(wrap_pyfunction!(settings::_settings_from_json, m)?)?;
    m.add_class::<PySdfModel>()?;
    m.add_class::<PyMeshModel>()?;
    m.add_function(wrap_pyfunction!(mesh_model::mesh_model, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_model::_mesh_model_from_parts, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_model::read_mesh, m)?)?;
    m.add_class::<PyRegistration>()?;
    m.add_class::<PyFreeMotion>()?;
    m.add_class::<PyMlpSettings>()?;
    m.add_class::<PyFitSettings>()?;
    m.add_class::<settings::PyLocalSettings>()?;
    m.add_class::<PyMultistartSettings>()?;
    m.add_class::<PyCoarseToFineSettings>()?;
    m.add_class::<PyLmSettings>()?;
    m.add_class::<PyRobustSettings>()?;
    m.add_class::<PyPolishSettings>()?;
    m.add_class::<PyShiftSearchSettings>()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}

//! Python bindings of sdfreg: `sdfreg.register`, `sdfreg.read_point_cloud`,
//! `sdfreg.write_point_cloud` and the `sdfreg.Registration` result. They only convert and
//! forward to `sdfreg-core`: arguments are copied into owned Rust values, then the work runs with
//! the GIL released (`Python::detach`), so Python threads can register in parallel.
//!
//! Fork safety: the core runs every call in its own rayon pool, created for that call, and
//! never touches rayon's global pool, so a forked child (multiprocessing) starts no work on
//! threads that only its parent had.
//!
//! Stubs and docstrings for Python users: `python/sdfreg/_sdfreg.pyi`.

mod convert;
mod error;
mod registration;

use std::path::PathBuf;

use numpy::PyArray2;
use pyo3::prelude::*;
use sdfreg_core::RegisterSettings;

use registration::{PyFreeMotion, PyRegistration};

/// A Python keyword argument converted to the core's type of that setting.
trait IntoSetting<T> {
    fn into_setting(self, name: &str) -> PyResult<T>;
}

impl IntoSetting<usize> for i64 {
    fn into_setting(self, name: &str) -> PyResult<usize> {
        usize::try_from(self)
            .map_err(|_| error::argument(name, format!("must be a count ≥ 0, got {self}")))
    }
}

impl IntoSetting<u64> for i64 {
    fn into_setting(self, name: &str) -> PyResult<u64> {
        u64::try_from(self)
            .map_err(|_| error::argument(name, format!("must be an integer ≥ 0, got {self}")))
    }
}

impl IntoSetting<f32> for f64 {
    fn into_setting(self, _: &str) -> PyResult<f32> {
        Ok(self as f32)
    }
}

impl<T> IntoSetting<T> for T {
    fn into_setting(self, _: &str) -> PyResult<T> {
        Ok(self)
    }
}

/// Defines `register` with one keyword argument per core setting: `name: python type = default
/// => field path in RegisterSettings`. The defaults are those of `RegisterSettings::default()`
/// (the Python tests check that they agree).
macro_rules! register_function {
    ($($name:ident: $ty:ty = $default:tt => $($path:ident).+),* $(,)?) => {
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
        ///     source: (N, 3) points to move; float32 or float64 array in any memory layout, or
        ///         anything ``numpy.asarray`` turns into one (e.g. ``np.asarray(pcd.points)``).
        ///     target: (M, 3) points that stay fixed, same units as ``source``.
        ///     init: Optional 4×4 rigid initial guess mapping source into target; replaces the
        ///         multi-start.
        ///     seed: Seed of every random choice; equal seeds give identical results.
        ///     threads: Worker threads; 0 = one per core. The result does not depend on it.
        ///
        /// The other keyword arguments are the engine's settings, with its defaults; lengths are
        /// fractions of the target's largest bounding-box side. ``alternations``,
        /// ``lm_steps_per_alternation``, ``final_lm_steps``: the coarse-to-fine schedule.
        /// ``multistart*``, ``hypotheses``: the initialisation. ``max_source_points``,
        /// ``max_target_points``: larger clouds are subsampled (seeded). ``free_motion_ratio``:
        /// constraint eigenvalues below it (relative) are reported as ``free_motions``. ``robust``:
        /// Geman–McClure kernel with the scale ``κ·median|Φ|`` (κ from ``robust_kappa_start`` to
        /// ``robust_kappa_end``, at least ``robust_floor``); ``robust_scale`` fixes the scale; without
        /// either, a result with ``fitness`` below ``robust_below_fitness`` is redone with the robust
        /// kernel (and ``multistart_tie`` 0.05), kept if it fits 1.3 times as many points. ``inlier_distance``: for ``fitness``
        /// and ``inlier_rmse``. ``width``, ``depth``, ``beta``, ``init_radius``: the SDF network.
        /// ``prefit_*``, ``refine_*``, ``batch_*``, ``query_pool``, ``sigma_*``, ``lambda_*``,
        /// ``max_source_queries``: the SDF fit. ``initial_lambda``, ``lambda_decrease``,
        /// ``lambda_increase``, ``max_tries``, ``*_tolerance``: the Levenberg–Marquardt solver.
        /// ``polish_*``: the final point-to-plane steps on the target points
        /// (``polish_iterations=0`` turns them off).
        /// ``shift_search_*``: translations (within ``shift_search_radius``, on a grid of
        /// ``shift_search_voxel``) that lay more source points onto the target than the SDF's pose; the
        /// best ``shift_search_candidates`` are polished, and one is kept if it raises the fitness by
        /// ``shift_search_min_gain`` (``shift_search_radius=0`` turns it off).
        ///
        /// Returns:
        ///     The :class:`Registration`.
        ///
        /// Raises:
        ///     ValueError: a cloud is not an (N, 3) float array, has a NaN or infinite coordinate,
        ///         fewer than 10 points or no extent; ``init`` is not a rigid 4×4 transform; a
        ///         setting is out of range.
        #[pyfunction]
        #[pyo3(signature = (source, target, *, init = None, $($name = $default),*))]
        #[allow(clippy::too_many_arguments)]
        fn register(
            py: Python<'_>,
            source: &Bound<'_, PyAny>,
            target: &Bound<'_, PyAny>,
            init: Option<&Bound<'_, PyAny>>,
            $($name: $ty),*
        ) -> PyResult<PyRegistration> {
            let source = convert::points(source, "source")?;
            let target = convert::points(target, "target")?;
            let init = init.map(|m| convert::isometry(m, "init")).transpose()?;
            let mut settings = RegisterSettings::default();
            $(settings.$($path).+ = $name.into_setting(stringify!($name))?;)*
            let result = py
                .detach(|| sdfreg_core::register(&source, &target, init.as_ref(), &settings))
                .map_err(error::registration)?;
            Ok(PyRegistration(result))
        }

        /// The core's defaults of the settings `register` takes, as a dict (for tests).
        #[pyfunction]
        fn _core_defaults(py: Python<'_>) -> PyResult<Bound<'_, pyo3::types::PyDict>> {
            let d = RegisterSettings::default();
            let out = pyo3::types::PyDict::new(py);
            $(out.set_item(stringify!($name), d.$($path).+)?;)*
            Ok(out)
        }
    };
}

register_function! {
    seed: i64 = 0 => seed,
    threads: i64 = 0 => threads,
    alternations: i64 = 10 => alternations,
    lm_steps_per_alternation: i64 = 2 => lm_steps_per_alternation,
    final_lm_steps: i64 = 10 => final_lm_steps,
    multistart: bool = true => multistart,
    multistart_lm_steps: i64 = 5 => multistart_lm_steps,
    multistart_offset: f64 = 0.1 => multistart_offset,
    multistart_points: i64 = 128 => multistart_points,
    multistart_keep: i64 = 4 => multistart_keep,
    multistart_refine_steps: i64 = 15 => multistart_refine_steps,
    multistart_truncation: f64 = 0.05 => multistart_truncation,
    multistart_tie: f64 = 0.25 => multistart_tie,
    hypotheses: i64 = 3 => hypotheses,
    free_motion_ratio: f64 = 0.002 => free_motion_ratio,
    max_source_points: i64 = 4096 => max_source_points,
    max_target_points: i64 = 100000 => max_target_points,
    robust_scale: Option<f64> = None => robust_scale,
    robust: bool = false => robust,
    robust_below_fitness: f64 = 0.35 => robust_below_fitness,
    robust_kappa_start: f64 = 3.0 => robust_kappa_start,
    robust_kappa_end: f64 = 1.0 => robust_kappa_end,
    robust_floor: f64 = 0.002 => robust_floor,
    inlier_distance: f64 = 0.02 => inlier_distance,
    width: i64 = 32 => mlp.width,
    depth: i64 = 3 => mlp.depth,
    beta: f64 = 100.0 => mlp.beta,
    init_radius: f64 = 0.3 => mlp.init_radius,
    prefit_steps: i64 = 500 => fit.prefit_steps,
    prefit_lr: f64 = 0.002 => fit.prefit_lr,
    refine_steps: i64 = 40 => fit.refine_steps,
    refine_lr: f64 = 0.001 => fit.refine_lr,
    batch_queries: i64 = 1024 => fit.batch_queries,
    refine_batch_queries: i64 = 512 => fit.refine_batch_queries,
    batch_source: i64 = 512 => fit.batch_source,
    batch_surface: i64 = 512 => fit.batch_surface,
    query_pool: i64 = 16384 => fit.query_pool,
    sigma_neighbour: i64 = 50 => fit.sigma_neighbour,
    sigma_sample: i64 = 1024 => fit.sigma_sample,
    lambda_surface: f64 = 0.1 => fit.lambda_surface,
    lambda_eikonal: f64 = 0.001 => fit.lambda_eikonal,
    max_source_queries: i64 = 16384 => fit.max_source_queries,
    initial_lambda: f64 = 0.01 => lm.initial_lambda,
    lambda_decrease: f64 = 3.0 => lm.lambda_decrease,
    lambda_increase: f64 = 4.0 => lm.lambda_increase,
    max_tries: i64 = 6 => lm.max_tries,
    rotation_tolerance: f64 = 1e-5 => lm.rotation_tolerance,
    translation_tolerance: f64 = 1e-5 => lm.translation_tolerance,
    polish_iterations: i64 = 50 => polish.iterations,
    polish_neighbours: i64 = 5 => polish.neighbours,
    polish_max_distance: f64 = 0.05 => polish.max_distance,
    polish_max_shift: f64 = 0.05 => polish.max_shift,
    polish_near_spacings: f64 = 3.0 => polish.near_spacings,
    shift_search_radius: f64 = 0.3 => shift_search.radius,
    shift_search_voxel: f64 = 0.02 => shift_search.voxel,
    shift_search_candidates: i64 = 4 => shift_search.candidates,
    shift_search_min_gain: f64 = 0.02 => shift_search.min_gain,
}

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// Reads a point cloud as an (N, 3) float64 array.
///
/// Formats by extension: ``.ply`` (ascii or binary, any numeric type; the ``vertex``
/// element's x, y, z), ``.pcd`` (ascii, binary or binary_compressed; the x, y, z fields),
/// ``.xyz``, ``.txt``, ``.csv``, ``.pts`` (first three columns).
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
///         for text, the line.
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
    if dropped > 0 {
        let message = format!(
            "{}: dropped {dropped} of {} points with a NaN or infinite coordinate",
            path.display(),
            points.len() + dropped
        );
        let warning = py.get_type::<pyo3::exceptions::PyUserWarning>();
        PyErr::warn(py, &warning, &std::ffi::CString::new(message)?, 1)?;
    }
    Ok(convert::points_to_array(py, &points))
}

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// Writes (N, 3) finite points; the format follows the extension (``.ply``: binary
/// float64; text formats: one ``x y z`` line per point, full precision). An existing file is
/// replaced.
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

/// The native part of the `sdfreg` package.
#[pymodule]
fn _sdfreg(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(register, m)?)?;
    m.add_function(wrap_pyfunction!(read_point_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(write_point_cloud, m)?)?;
    m.add_function(wrap_pyfunction!(_core_defaults, m)?)?;
    m.add_class::<PyRegistration>()?;
    m.add_class::<PyFreeMotion>()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}

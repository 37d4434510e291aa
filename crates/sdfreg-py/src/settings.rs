//! The settings groups as Python classes (`sdfreg.LmSettings(...)`, …), one per struct of the
//! core's `RegisterSettings`: keyword-only constructors with the core's defaults, read-only
//! attributes, `==` and a `repr` that reconstructs the object. A constructor checks its group
//! (`ValueError` naming the field, as the core says it).

use pyo3::prelude::*;
use pyo3::types::PyDict;
use pyo3::IntoPyObjectExt;
use sdfreg_core::{RegisterSettings, RobustMode};

use crate::error;

/// A Python keyword argument converted to the core's type of that setting.
pub trait IntoSetting<T> {
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

impl IntoSetting<sdfreg_core::ModelKind> for &str {
    fn into_setting(self, name: &str) -> PyResult<sdfreg_core::ModelKind> {
        sdfreg_core::ModelKind::from_name(self).ok_or_else(|| {
            error::argument(
                name,
                format!(
                    "expected one of {:?}, got {self:?}",
                    sdfreg_core::ModelKind::NAMES
                ),
            )
        })
    }
}

impl IntoSetting<sdfreg_core::LocalSettings> for Option<PyRef<'_, PyLocalSettings>> {
    fn into_setting(self, _: &str) -> PyResult<sdfreg_core::LocalSettings> {
        Ok(self.map(|g| g.0.clone()).unwrap_or_default())
    }
}

impl<T> IntoSetting<T> for T {
    fn into_setting(self, _: &str) -> PyResult<T> {
        Ok(self)
    }
}

/// A core setting's value as a Python object: f32 values by their shortest decimal (0.002, not
/// 0.0020000000949949026), everything else as it is.
trait Expose {
    fn expose<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>>;
}

macro_rules! expose_as_is {
    ($($t:ty),*) => {$(
        impl Expose for $t {
            fn expose<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
                self.into_bound_py_any(py)
            }
        }
    )*};
}
expose_as_is!(usize, u64, bool, f64, Option<f64>);

impl Expose for sdfreg_core::ModelKind {
    fn expose<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        self.name().into_bound_py_any(py)
    }
}

impl Expose for sdfreg_core::LocalSettings {
    fn expose<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        Bound::new(py, PyLocalSettings(self.clone())).map(Bound::into_any)
    }
}

impl Expose for f32 {
    fn expose<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let shortest: f64 = self.to_string().parse().unwrap_or(*self as f64);
        shortest.into_bound_py_any(py)
    }
}

/// `Name(field=value, …)` with each value's Python repr.
fn repr(name: &str, fields: &[(&str, Bound<'_, PyAny>)]) -> PyResult<String> {
    let parts: Vec<String> = fields
        .iter()
        .map(|(k, v)| Ok(format!("{k}={}", v.repr()?)))
        .collect::<PyResult<_>>()?;
    Ok(format!("{name}({})", parts.join(", ")))
}

/// Defines a Python class wrapping a core settings struct: `PyName => CoreType as "Name",
/// "group" { field: python type = default, … }`. The defaults are the core's (the Python tests
/// compare them with `_core_defaults()`).
macro_rules! settings_class {
    (
        $(#[doc = $doc:literal])*
        $py:ident => $core:ident as $name:literal, $group:literal {
            $($field:ident : $ty:ty = $default:tt),* $(,)?
        }
    ) => {
        $(#[doc = $doc])*
        #[pyclass(module = "sdfreg", name = $name, frozen, eq)]
        #[derive(Clone, PartialEq)]
        pub struct $py(pub sdfreg_core::$core);

        impl $py {
            fn check(s: &sdfreg_core::$core) -> PyResult<()> {
                s.validate().map_err(error::registration)
            }
        }

        #[pymethods]
        impl $py {
            #[new]
            #[pyo3(signature = (*, $($field = $default),*))]
            #[allow(clippy::too_many_arguments)]
            fn new($($field: $ty),*) -> PyResult<Self> {
                let mut s = sdfreg_core::$core::default();
                $(s.$field = $field.into_setting(concat!($group, ".", stringify!($field)))?;)*
                s.validate().map_err(error::registration)?;
                Ok(Self(s))
            }

            $(
                #[getter]
                fn $field<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
                    self.0.$field.expose(py)
                }
            )*

            fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
                repr($name, &[$((stringify!($field), self.0.$field.expose(py)?)),*])
            }

            /// Pickles through the core struct's JSON (exact: floats round-trip).
            fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Reduced<'py>> {
                reduce(py, $name, &self.0)
            }
        }
    };
}

/// What `__reduce__` returns: `_settings_from_json` and its arguments.
type Reduced<'py> = (Bound<'py, PyAny>, (&'static str, String));

fn reduce<'py>(
    py: Python<'py>,
    name: &'static str,
    settings: &impl serde::Serialize,
) -> PyResult<Reduced<'py>> {
    let json = serde_json::to_string(settings)
        .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))?;
    let load = py
        .import("sdfreg._sdfreg")?
        .getattr("_settings_from_json")?;
    Ok((load, (name, json)))
}

/// Unpickles a settings object (`__reduce__`): the class `name` from its core struct's JSON,
/// checked as the constructor checks it.
#[pyfunction]
pub fn _settings_from_json(py: Python<'_>, name: &str, json: &str) -> PyResult<Py<PyAny>> {
    fn load<T: serde::de::DeserializeOwned>(json: &str) -> PyResult<T> {
        serde_json::from_str(json)
            .map_err(|e| error::argument("settings", format!("not valid settings JSON: {e}")))
    }
    // Each class from its JSON, validated as its constructor validates.
    macro_rules! arms {
        ($($class:literal => $py:ident),*) => {
            match name {
                $($class => {
                    let settings = load(json)?;
                    $py::check(&settings)?;
                    Py::new(py, $py(settings))?.into_any()
                })*
                _ => return Err(error::argument("settings", format!("no settings class {name:?}"))),
            }
        };
    }
    let object = arms!(
        "MlpSettings" => PyMlpSettings,
        "FitSettings" => PyFitSettings,
        "LocalSettings" => PyLocalSettings,
        "MultistartSettings" => PyMultistartSettings,
        "CoarseToFineSettings" => PyCoarseToFineSettings,
        "LmSettings" => PyLmSettings,
        "PolishSettings" => PyPolishSettings,
        "ShiftSearchSettings" => PyShiftSearchSettings,
        "RobustSettings" => PyRobustSettings
    );
    Ok(object)
}

settings_class! {
    /// The SDF network Φ: an MLP 3 → width × depth → 1 with softplus activations.
    ///
    /// Args:
    ///     width: Neurons per hidden layer.
    ///     depth: Hidden layers.
    ///     beta: Softplus sharpness (1 / normalised length).
    ///     init_radius: Radius of the sphere the geometric initialisation starts from
    ///         (normalised: the target's largest bounding-box side is 1).
    ///     learned_init: A full call's pre-fit of an object's Φ starts from the initialisation
    ///         learned offline on procedural objects instead of the sphere (the ``"learned"``
    ///         preset); only the default architecture (width 32, depth 3, beta 100) has one.
    PyMlpSettings => MlpSettings as "MlpSettings", "mlp" {
        width: i64 = 32,
        depth: i64 = 3,
        beta: f64 = 100.0,
        init_radius: f64 = 0.3,
        learned_init: bool = false,
    }
}

settings_class! {
    /// The self-supervised fit of Φ to the target (Adam; lengths normalised).
    ///
    /// Args:
    ///     prefit_steps: Adam steps before registration starts (a full call).
    ///     model_prefit_steps: Adam steps of a stored model's pre-fit (:func:`fit`; a global
    ///         Φ, fitted once and registered against many times).
    ///     prefit_lr: Learning rate of the pre-fit.
    ///     refine_steps: Adam steps per coarse-to-fine alternation.
    ///     refine_lr: Learning rate of the alternations.
    ///     batch_queries: Perturbation queries per step.
    ///     refine_batch_queries: Perturbation queries per step once moved-source queries exist.
    ///     batch_source: Moved-source queries per step (once any exist).
    ///     batch_surface: Target points per step for the surface term.
    ///     query_pool: Size of the fixed pool of perturbation queries.
    ///     sigma_neighbour: A query's spread is the distance to this neighbour.
    ///     sigma_sample: Target points the spreads and the pool are drawn from.
    ///     lambda_surface: Weight of ``|Φ|`` on target points.
    ///     lambda_eikonal: Weight of the Eikonal term ``(‖∇Φ‖ − 1)²``.
    ///     max_source_queries: Moved-source queries kept at most (oldest dropped).
    ///     local: The local part of Φ, for scenes (:class:`LocalSettings`); None: its defaults.
    PyFitSettings => FitSettings as "FitSettings", "fit" {
        prefit_steps: i64 = 250,
        model_prefit_steps: i64 = 2000,
        prefit_lr: f64 = 0.002,
        refine_steps: i64 = 10,
        refine_lr: f64 = 0.001,
        batch_queries: i64 = 256,
        refine_batch_queries: i64 = 128,
        batch_source: i64 = 128,
        batch_surface: i64 = 128,
        query_pool: i64 = 16384,
        sigma_neighbour: i64 = 50,
        sigma_sample: i64 = 1024,
        lambda_surface: f64 = 0.1,
        lambda_eikonal: f64 = 0.001,
        max_source_queries: i64 = 16384,
        local: Option<PyRef<'_, PyLocalSettings>> = None,
    }
}

settings_class! {
    /// The local part of Φ (scenes): a sparse voxel grid of corrections near the target's
    /// points, added to the MLP (lengths normalised: the target's largest side is 1).
    ///
    /// Args:
    ///     kind: ``"auto"`` (local when the target's largest side is at least ``auto_ratio``
    ///         point spacings), ``"global"`` (the MLP alone) or ``"local"``.
    ///     auto_ratio: Extent in point spacings from which ``"auto"`` is local.
    ///     cells: The voxel is at least the target's largest side over this…
    ///     voxel: The voxel as a fraction of the target's largest side, in place of ``cells``
    ///         and ``spacings`` (makes ``"auto"`` local); None: from them. Above 1: a ValueError.
    ///     voxel_size: The voxel in the target's units (metres for a LiDAR scan), in place of
    ///         ``cells`` and ``spacings`` (makes ``"auto"`` local); None: from them. Above the
    ///         target's largest side: a ValueError.
    ///     spacings: …and at least this many target point spacings.
    ///     band: Voxels around each voxel holding target points that also get corrections.
    ///     batch: Projection queries about the target's points per Adam step (when the
    ///         corrections are trained: ``plane_fit=False``).
    ///     pool: Size of the fixed pool they are drawn from (``plane_fit=False``).
    ///     sigma_voxels: Their spread about the target's points, in voxels (``plane_fit=False``).
    ///     lr_scale: The corrections' learning rate relative to the network's, when trained.
    ///     plane_fit: The corrections are set in closed form (each corner's distance to the
    ///         plane of the target points about it) and not trained; False: trained by Adam.
    ///     prefit_steps: Adam steps of the pre-fit for a local Φ (in place of
    ///         ``FitSettings.prefit_steps``).
    ///     refine_steps: Adam steps of refinement per alternation for a local Φ (in place of
    ///         ``FitSettings.refine_steps``).
    ///     network_batch_divisor: With ``plane_fit``, the network's Adam batches
    ///         (``FitSettings``' query, source and surface batches) are divided by this (the
    ///         network only gives the far field).
    ///     min_voxel_spacings: A voxel below this many target point spacings is refused.
    ///     max_memory_mib: A grid that would take more memory than this (MiB: 32 bytes a
    ///         correction and its voxel map's table) is refused before it is built, with the
    ///         size it would have had.
    ///     global_rerun_below_fitness: A full call whose Φ ``"auto"`` made local (no voxel
    ///         given) and whose result fits less than this share of the source runs again with
    ///         a global Φ, and the result fitting more is returned (``stages["global_rerun"]``):
    ///         two scans overlapping in part; 0 never.
    PyLocalSettings => LocalSettings as "LocalSettings", "fit.local" {
        kind: &str = "auto",
        auto_ratio: f64 = 400.0,
        cells: i64 = 128,
        voxel: Option<f64> = None,
        voxel_size: Option<f64> = None,
        spacings: f64 = 3.0,
        band: i64 = 1,
        batch: i64 = 2048,
        pool: i64 = 65536,
        sigma_voxels: f64 = 0.5,
        lr_scale: f64 = 1.0,
        plane_fit: bool = true,
        prefit_steps: i64 = 200,
        refine_steps: i64 = 40,
        network_batch_divisor: i64 = 1,
        min_voxel_spacings: f64 = 0.5,
        max_memory_mib: f64 = 1024.0,
        global_rerun_below_fitness: f64 = 0.35,
    }
}

settings_class! {
    /// The multi-start: initial hypotheses when no ``init`` is given (lengths normalised).
    ///
    /// Args:
    ///     enabled: Try the 24 rotations of the cube group (False: centroid alignment only).
    ///     offset: Also start with the translation shifted by ± this along each axis.
    ///     points: Source points each start uses at most.
    ///     lm_steps: LM steps per start.
    ///     keep: Starts kept for a second round.
    ///     refine_steps: LM steps per kept start.
    ///     truncation: Starts are scored by nearest-target distances truncated here.
    ///     tie: Scores within this fraction of the best are ties, won by the least rotation.
    ///     distinct_rotation_deg: Starts closer than this (degrees)…
    ///     distinct_translation: …and this count as one.
    ///     hypotheses: Hypotheses carried into the coarse-to-fine loop.
    ///     rescue: With ``init`` given and its result still leaving more than the robust mode's
    ///         ``outside_share`` of the source outside the target's coverage, or lying a distinct
    ///         pose from ``init`` (``distinct_rotation_deg``, ``distinct_translation``), run again
    ///         from the multi-start and return that when it leaves less outside.
    ///     grid_cells: While Φ is being fitted (a full call against an object), the starts'
    ///         first round reads Φ baked into a grid of this many cells a side; 0: Φ itself.
    ///     scene_turn_deg: When Φ is local (a scene), the starts also turn the source about
    ///         its axis of least spread (a scan's vertical) by each multiple of this angle that
    ///         is not one of 90°, degrees; 0 none, else at least 5.
    ///     scene_as_given: When Φ is local (a scene), one more start: the source where it was
    ///         given (the identity, no centroid alignment), as consecutive scans and scans in
    ///         one site frame are.
    PyMultistartSettings => MultistartSettings as "MultistartSettings", "multistart" {
        enabled: bool = true,
        offset: f64 = 0.1,
        points: i64 = 128,
        lm_steps: i64 = 5,
        keep: i64 = 4,
        refine_steps: i64 = 15,
        truncation: f64 = 0.05,
        tie: f64 = 0.25,
        distinct_rotation_deg: f64 = 5.0,
        distinct_translation: f64 = 0.02,
        hypotheses: i64 = 3,
        rescue: bool = true,
        grid_cells: i64 = 32,
        scene_turn_deg: f64 = 30.0,
        scene_as_given: bool = true,
    }
}

settings_class! {
    /// The coarse-to-fine schedule (paper eq. 18-1) and the final LM on the frozen Φ.
    ///
    /// Args:
    ///     alternations: Alternations of Φ refinement and LM steps (an object: a global Φ).
    ///     scene_alternations: The same for a scene (a local Φ).
    ///     lm_steps_per_alternation: LM steps per alternation.
    ///     final_lm_steps: LM steps at most on the final Φ.
    ///     scene_lm_steps_per_alternation: LM steps per alternation in a scene's full call (a
    ///         local Φ, refined; a stored model's frozen Φ keeps ``lm_steps_per_alternation``).
    ///     scene_final_lm_steps: LM steps at most on the final Φ in a scene's full call.
    ///     final_lm_baked: The final LM reads a stored object model's Φ baked into its grid.
    PyCoarseToFineSettings => CoarseToFineSettings as "CoarseToFineSettings", "coarse_to_fine" {
        alternations: i64 = 10,
        scene_alternations: i64 = 5,
        lm_steps_per_alternation: i64 = 2,
        final_lm_steps: i64 = 10,
        scene_lm_steps_per_alternation: i64 = 5,
        scene_final_lm_steps: i64 = 30,
        final_lm_baked: bool = false,
    }
}

settings_class! {
    /// The Levenberg–Marquardt solver on SE(3).
    ///
    /// Args:
    ///     initial_lambda: Initial damping (relative to diag H).
    ///     lambda_decrease: Damping divided by this after an accepted step.
    ///     lambda_increase: Damping multiplied by this after a rejected step.
    ///     max_tries: Rejected tries per iteration before giving up.
    ///     rotation_tolerance: Converged when the rotation step (radians)…
    ///     translation_tolerance: …and the translation step (normalised) are below these.
    PyLmSettings => LmSettings as "LmSettings", "lm" {
        initial_lambda: f64 = 0.01,
        lambda_decrease: f64 = 3.0,
        lambda_increase: f64 = 4.0,
        max_tries: i64 = 6,
        rotation_tolerance: f64 = 1e-5,
        translation_tolerance: f64 = 1e-5,
    }
}

settings_class! {
    /// The final point-to-plane polish against the target points (lengths normalised).
    ///
    /// Args:
    ///     iterations: Gauss–Newton iterations per pass at most; 0 turns the polish off.
    ///     neighbours: Target points each local plane is fitted to.
    ///     scene_neighbours: The same when Φ is local (a scene: LiDAR rings).
    ///     max_distance: Source points farther than this from the target are left out.
    ///     max_shift: The polish is undone if it moves the source more than this (RMS).
    ///     near_spacings: A second pass uses only points within this many target spacings.
    ///     prior_weight: Weight of the prior towards the SDF's pose (relative to trace H).
    ///     scene_prior_weight: The same when Φ is local (a scene).
    ///     tolerance: A pass has converged when its step is below this.
    ///     snap: Try snapping onto the nearest target points (kept when the source lies on them).
    ///     target_planes: An object's planes at the target's points (kept by a model), not at the source's.
    ///     patience: An object's pass also ends when its step has not fallen below its smallest
    ///         for this many iterations; 0 never (the ``"views"`` preset: 10).
    ///     scene_tolerance_spacings: When Φ is local (a scene), a pass has converged when its
    ///         step is below this many target point spacings (the ``"views"`` preset: 0.01).
    ///     scene_kernel_floor_spacings: When Φ is local (a scene), the robust kernel's scale is
    ///         at least this many target point spacings (noise-free scans); 0 none.
    ///     kernel_floor_spacings: The same against an object (a global Φ): independent samples
    ///         of a clean surface would otherwise shrink the scale until the pass stalls.
    ///     scene_points: When Φ is local (a scene), the polish moves this many of the source's
    ///         points, drawn apart from the registration's own; 0 (or no more than
    ///         ``max_source_points``) polishes those (the ``"views"`` preset: 16384).
    ///     scene_iterations: ``iterations`` when Φ is local (a scene), unless that is 0 (the
    ///         ``"views"`` preset: 100).
    PyPolishSettings => PolishSettings as "PolishSettings", "polish" {
        iterations: i64 = 50,
        neighbours: i64 = 5,
        scene_neighbours: i64 = 15,
        max_distance: f64 = 0.05,
        max_shift: f64 = 0.05,
        near_spacings: f64 = 3.0,
        prior_weight: f64 = 1e-4,
        scene_prior_weight: f64 = 1e-6,
        tolerance: f64 = 1e-7,
        snap: bool = true,
        target_planes: bool = false,
        patience: i64 = 0,
        scene_tolerance_spacings: f64 = 0.1,
        scene_kernel_floor_spacings: f64 = 1.0,
        kernel_floor_spacings: f64 = 0.25,
        scene_points: i64 = 0,
        scene_iterations: i64 = 50,
    }
}

settings_class! {
    /// The search for translations that lay more source points onto the target (normalised).
    ///
    /// Args:
    ///     radius: Offsets searched up to this far per axis; 0 turns the search off.
    ///     voxel: Cube side of the occupancy grids.
    ///     candidates: Peaks polished and scored at most.
    ///     min_gain: A peak replaces the pose only if it raises the fitness by this.
    ///     scene_voxel_spacings: When Φ is local (a scene), the cube side and the distance
    ///         within which a source point counts as on the target when peaks are compared, in
    ///         target point spacings (offsets up to 16 cubes); 0 keeps ``voxel`` and the inlier
    ///         distance.
    ///     scene_min_gain: ``min_gain`` when Φ is local (a scene).
    PyShiftSearchSettings => ShiftSearchSettings as "ShiftSearchSettings", "shift_search" {
        radius: f64 = 0.3,
        voxel: f64 = 0.02,
        candidates: i64 = 4,
        min_gain: f64 = 0.02,
        scene_voxel_spacings: f64 = 3.0,
        scene_min_gain: f64 = 0.005,
    }
}

/// The robust (Geman–McClure) kernel and when it is used.
///
/// Args:
///     mode: ``"auto"`` (least squares; a result fitting fewer than ``below_fitness`` of the
///         source points is redone with the kernel and a multi-start tie of ``rerun_tie``,
///         kept if it fits ``gain`` times as many; a result leaving more than
///         ``outside_share`` of the source outside the target's coverage — beyond 10 target
///         point spacings — and fitting less than ``1 - outside_share`` of it is redone too,
///         kept if it fits more points), ``"on"`` (the kernel from the start: scans
///         that overlap in part), ``"off"`` (least squares) or ``"fixed"`` (the kernel with
///         the fixed ``scale``).
///     below_fitness: See ``mode="auto"``.
///     outside_share: See ``mode="auto"``.
///     gain: See ``mode="auto"``.
///     rerun_tie: See ``mode="auto"``.
///     scale: The kernel's scale for ``mode="fixed"`` (normalised).
///     kappa_start: The adaptive scale is κ·median|Φ|, κ from this…
///     kappa_end: …to this over the alternations.
///     floor: Smallest adaptive scale (normalised).
#[pyclass(module = "sdfreg", name = "RobustSettings", frozen, eq)]
#[derive(Clone, PartialEq)]
pub struct PyRobustSettings(pub sdfreg_core::RobustSettings);

impl PyRobustSettings {
    fn check(s: &sdfreg_core::RobustSettings) -> PyResult<()> {
        s.validate().map_err(error::registration)
    }

    /// The re-run's fitness threshold, gain, tie and outside share (``mode="auto"``; the
    /// defaults otherwise).
    fn auto_rule(&self) -> (f64, f64, f64, f64) {
        let auto = |m: RobustMode| match m {
            RobustMode::Auto {
                below_fitness,
                outside_share,
                gain,
                tie,
            } => Some((below_fitness, gain, tie, outside_share)),
            _ => None,
        };
        auto(self.0.mode)
            .or(auto(RobustMode::AUTO))
            .expect("RobustMode::AUTO is Auto")
    }
}

#[pymethods]
impl PyRobustSettings {
    #[new]
    #[pyo3(signature = (*, mode = "auto", below_fitness = 0.35, outside_share = 0.2, gain = 1.3, rerun_tie = 0.05, scale = None, kappa_start = 3.0, kappa_end = 1.0, floor = 0.002))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        mode: &str,
        below_fitness: f64,
        outside_share: f64,
        gain: f64,
        rerun_tie: f64,
        scale: Option<f64>,
        kappa_start: f64,
        kappa_end: f64,
        floor: f64,
    ) -> PyResult<Self> {
        let mode = match (mode, scale) {
            ("fixed", Some(scale)) => RobustMode::Fixed { scale },
            ("fixed", None) => {
                return Err(error::argument(
                    "robust.scale",
                    "mode=\"fixed\" needs a scale",
                ))
            }
            (_, Some(_)) => {
                return Err(error::argument("robust.scale", "only with mode=\"fixed\""));
            }
            ("auto", None) => RobustMode::Auto {
                below_fitness,
                outside_share,
                gain,
                tie: rerun_tie,
            },
            ("on", None) => RobustMode::On,
            ("off", None) => RobustMode::Off,
            (other, None) => {
                return Err(error::argument(
                    "robust.mode",
                    format!("expected \"auto\", \"on\", \"off\" or \"fixed\", got {other:?}"),
                ));
            }
        };
        let s = sdfreg_core::RobustSettings {
            mode,
            kappa_start,
            kappa_end,
            floor,
        };
        s.validate().map_err(error::registration)?;
        Ok(Self(s))
    }

    /// ``"auto"``, ``"on"``, ``"off"`` or ``"fixed"``.
    #[getter]
    fn mode(&self) -> &'static str {
        self.0.mode.name()
    }

    /// The fixed scale (``mode="fixed"``), else None.
    #[getter]
    fn scale(&self) -> Option<f64> {
        match self.0.mode {
            RobustMode::Fixed { scale } => Some(scale),
            _ => None,
        }
    }

    /// See ``mode="auto"``.
    #[getter]
    fn below_fitness(&self) -> f64 {
        self.auto_rule().0
    }

    /// See ``mode="auto"``.
    #[getter]
    fn outside_share(&self) -> f64 {
        self.auto_rule().3
    }

    /// See ``mode="auto"``.
    #[getter]
    fn gain(&self) -> f64 {
        self.auto_rule().1
    }

    /// See ``mode="auto"``.
    #[getter]
    fn rerun_tie(&self) -> f64 {
        self.auto_rule().2
    }

    /// κ at the first alternation.
    #[getter]
    fn kappa_start(&self) -> f64 {
        self.0.kappa_start
    }

    /// κ at the last alternation.
    #[getter]
    fn kappa_end(&self) -> f64 {
        self.0.kappa_end
    }

    /// Smallest adaptive scale.
    #[getter]
    fn floor(&self) -> f64 {
        self.0.floor
    }

    /// Pickles through the core struct's JSON (exact: floats round-trip).
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Reduced<'py>> {
        reduce(py, "RobustSettings", &self.0)
    }

    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        let (below_fitness, gain, tie, outside_share) = self.auto_rule();
        repr(
            "RobustSettings",
            &[
                ("mode", self.mode().into_bound_py_any(py)?),
                ("below_fitness", below_fitness.expose(py)?),
                ("outside_share", outside_share.expose(py)?),
                ("gain", gain.expose(py)?),
                ("rerun_tie", tie.expose(py)?),
                ("scale", self.scale().into_bound_py_any(py)?),
                ("kappa_start", self.0.kappa_start.expose(py)?),
                ("kappa_end", self.0.kappa_end.expose(py)?),
                ("floor", self.0.floor.expose(py)?),
            ],
        )
    }
}

/// The robust argument of `register`: a mode name or a `RobustSettings`.
pub fn robust_argument(obj: &Bound<'_, PyAny>) -> PyResult<sdfreg_core::RobustSettings> {
    if let Ok(s) = obj.cast::<PyRobustSettings>() {
        return Ok(s.get().0.clone());
    }
    let Ok(mode) = obj.extract::<String>() else {
        return Err(error::argument(
            "robust",
            format!(
                "expected \"auto\", \"on\", \"off\" or a RobustSettings, got {}",
                obj.repr()?
            ),
        ));
    };
    let kwargs = PyDict::new(obj.py());
    kwargs.set_item("mode", mode)?;
    let built = obj
        .py()
        .get_type::<PyRobustSettings>()
        .call((), Some(&kwargs))?;
    Ok(built.cast::<PyRobustSettings>()?.get().0.clone())
}

/// The core's defaults of every settings group, as nested dicts (for the tests that check the
/// Python defaults against them).
pub fn core_defaults(py: Python<'_>) -> PyResult<Bound<'_, PyAny>> {
    let json = serde_json::to_string(&RegisterSettings::default())
        .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))?;
    py.import("json")?.call_method1("loads", (json,))
}

/// The functions that take settings keywords. `SdfModel.register` and `MeshModel.register`
/// forward to `register`, so they take its keywords.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Caller {
    /// `register(source, target, *, init, refine, **settings)`.
    Register,
    /// `register_many(pairs, *, threads, progress, **settings)` (threads is its own argument).
    RegisterMany,
    /// `SdfModel.track(frames, *, init, **settings)`, from the `"tracking"` preset.
    Track,
    /// `fit(target, **settings)`: the keywords of the target's fit.
    Fit,
    /// `align(scans, *, init, anchor, joint_rounds, **settings)`: the pairs' settings, from the
    /// `"scans"` preset (no scale: the views of one scan campaign share their units).
    Align,
}

impl Caller {
    /// The function's name, as Python errors give it.
    pub fn name(self) -> &'static str {
        match self {
            Caller::Register => "register",
            Caller::RegisterMany => "register_many",
            Caller::Track => "track",
            Caller::Fit => "fit",
            Caller::Align => "align",
        }
    }
}

/// One settings keyword: its name, which functions take it, and where its value goes.
pub struct Keyword {
    /// The keyword.
    pub name: &'static str,
    /// The functions that take it.
    pub callers: &'static [Caller],
    /// Stores a value (not None) in the arguments; a wrong type is a `TypeError`.
    set: for<'py> fn(&mut SettingsArgs<'py>, &Bound<'py, PyAny>) -> PyResult<()>,
}

use Caller::{Align, Fit, Register, RegisterMany, Track};
const ALL: &[Caller] = &[Register, RegisterMany, Track, Fit, Align];
const REGISTER: &[Caller] = &[Register, RegisterMany, Align];
const SIMILARITY: &[Caller] = &[Register, RegisterMany];
const FULL_CALL: &[Caller] = &[Register, RegisterMany];
const SOURCE: &[Caller] = &[Register, RegisterMany, Track, Align];
const TARGET: &[Caller] = &[Register, RegisterMany, Fit, Align];
const ONE_CALL: &[Caller] = &[Register, Track, Fit, Align];

/// The [`KEYWORDS`] table: `name: callers, how;` stores the value of keyword `name` in the
/// field of [`SettingsArgs`] of the same name — `value` as it is, `some` wrapped in `Some`,
/// `object` the Python object itself (`robust` is read later), `(Class)` a settings group.
macro_rules! keywords {
    ($($name:ident: $callers:ident, $how:tt;)*) => {
        &[$(Keyword {
            name: stringify!($name),
            callers: $callers,
            set: |a, v| {
                a.$name = keywords!(@ $how v);
                Ok(())
            },
        },)*]
    };
    (@ value $v:ident) => { $v.extract()? };
    (@ some $v:ident) => { Some($v.extract()?) };
    (@ object $v:ident) => { Some($v.clone()) };
    (@ ($group:ty) $v:ident) => { Some(group::<$group>($v)?.get().0.clone()) };
}

/// The settings keywords, declared once for `register`, `register_many`, `SdfModel.register`,
/// `MeshModel.register`, `SdfModel.track` and `fit` (the stubs' `_RegisterKeywords` and its
/// relatives in `_sdfreg.pyi` list the same names, a test holds them equal). Each is applied
/// to the preset by [`SettingsArgs::build`]; None keeps the preset's value.
pub const KEYWORDS: &[Keyword] = keywords! {
    preset: REGISTER, some;
    robust: REGISTER, object;
    seed: ALL, value;
    threads: ONE_CALL, value;
    max_source_points: SOURCE, some;
    max_target_points: TARGET, some;
    inlier_distance: REGISTER, some;
    free_motion_ratio: REGISTER, some;
    mlp: TARGET, (PyMlpSettings);
    fit: TARGET, (PyFitSettings);
    multistart: REGISTER, (PyMultistartSettings);
    coarse_to_fine: REGISTER, (PyCoarseToFineSettings);
    lm: SOURCE, (PyLmSettings);
    polish: SOURCE, (PyPolishSettings);
    shift_search: REGISTER, (PyShiftSearchSettings);
    model: TARGET, some;
    scale: SIMILARITY, some;
    scale_range: SIMILARITY, some;
    swap_ratio: FULL_CALL, some;
};

/// The settings keywords of a call, before they are applied to the preset: each `None` keeps
/// the preset's value.
#[derive(Default)]
pub struct SettingsArgs<'py> {
    pub preset: Option<String>,
    pub robust: Option<Bound<'py, PyAny>>,
    pub seed: i64,
    pub threads: i64,
    pub max_source_points: Option<i64>,
    pub max_target_points: Option<i64>,
    pub inlier_distance: Option<f64>,
    pub free_motion_ratio: Option<f64>,
    pub mlp: Option<sdfreg_core::MlpSettings>,
    pub fit: Option<sdfreg_core::FitSettings>,
    pub multistart: Option<sdfreg_core::MultistartSettings>,
    pub coarse_to_fine: Option<sdfreg_core::CoarseToFineSettings>,
    pub lm: Option<sdfreg_core::LmSettings>,
    pub polish: Option<sdfreg_core::PolishSettings>,
    pub shift_search: Option<sdfreg_core::ShiftSearchSettings>,
    pub model: Option<String>,
    pub scale: Option<bool>,
    pub scale_range: Option<(f64, f64)>,
    pub swap_ratio: Option<f64>,
}

impl<'py> SettingsArgs<'py> {
    /// The settings keywords of `kwargs` for `caller` ([`KEYWORDS`]); a keyword the function
    /// does not take is a `TypeError`, as Python raises for any function, and so is a value of
    /// the wrong type (naming the keyword). None keeps the preset's value.
    pub fn from_kwargs(caller: Caller, kwargs: Option<&Bound<'py, PyDict>>) -> PyResult<Self> {
        let mut a = SettingsArgs::default();
        let Some(kwargs) = kwargs else {
            return Ok(a);
        };
        for (key, value) in kwargs.iter() {
            let key: String = key.extract()?;
            let keyword = KEYWORDS
                .iter()
                .find(|k| k.name == key && k.callers.contains(&caller))
                .ok_or_else(|| {
                    pyo3::exceptions::PyTypeError::new_err(format!(
                        "{}() got an unexpected keyword argument '{key}'",
                        caller.name()
                    ))
                })?;
            if value.is_none() {
                continue;
            }
            (keyword.set)(&mut a, &value).map_err(|e| {
                pyo3::exceptions::PyTypeError::new_err(format!(
                    "argument '{key}': {}",
                    e.value(value.py())
                ))
            })?;
        }
        Ok(a)
    }

    /// The preset named (default: `default_preset`) with every given keyword applied; a
    /// `ValueError` names a bad preset or value.
    pub fn build(self, default_preset: &str) -> PyResult<RegisterSettings> {
        let preset = self.preset.as_deref().unwrap_or(default_preset);
        let mut s = RegisterSettings::preset(preset).ok_or_else(|| {
            error::argument(
                "preset",
                format!(
                    "expected one of {:?}, got {preset:?}",
                    RegisterSettings::PRESETS
                ),
            )
        })?;
        s.seed = self.seed.into_setting("seed")?;
        s.threads = self.threads.into_setting("threads")?;
        if let Some(r) = &self.robust {
            s.robust = robust_argument(r)?;
        }
        if let Some(n) = self.max_source_points {
            s.max_source_points = n.into_setting("max_source_points")?;
        }
        if let Some(n) = self.max_target_points {
            s.max_target_points = n.into_setting("max_target_points")?;
        }
        s.inlier_distance = self.inlier_distance.unwrap_or(s.inlier_distance);
        s.free_motion_ratio = self.free_motion_ratio.unwrap_or(s.free_motion_ratio);
        s.swap_ratio = self.swap_ratio.unwrap_or(s.swap_ratio);
        s.mlp = self.mlp.unwrap_or(s.mlp);
        s.fit = self.fit.unwrap_or(s.fit);
        s.multistart = self.multistart.unwrap_or(s.multistart);
        s.coarse_to_fine = self.coarse_to_fine.unwrap_or(s.coarse_to_fine);
        s.lm = self.lm.unwrap_or(s.lm);
        s.polish = self.polish.unwrap_or(s.polish);
        s.shift_search = self.shift_search.unwrap_or(s.shift_search);
        s.scale.enabled = self.scale.unwrap_or(s.scale.enabled);
        if let Some((min, max)) = self.scale_range {
            if !s.scale.enabled {
                return Err(error::argument("scale_range", "needs scale=True"));
            }
            (s.scale.min, s.scale.max) = (Some(min), Some(max));
            s.scale
                .validate()
                .map_err(|e| error::argument("scale_range", e.to_string()))?;
        }
        if let Some(name) = &self.model {
            s.fit.local.kind = sdfreg_core::ModelKind::from_name(name).ok_or_else(|| {
                error::argument(
                    "model",
                    format!(
                        "expected one of {:?}, got {name:?}",
                        sdfreg_core::ModelKind::NAMES
                    ),
                )
            })?;
        }
        Ok(s)
    }
}

/// A settings-group keyword's value as its class `G` (None is handled by the caller); another
/// type is a `TypeError`.
fn group<'a, 'py, G>(value: &'a Bound<'py, PyAny>) -> PyResult<&'a Bound<'py, G>>
where
    G: pyo3::PyClass<Frozen = pyo3::pyclass::boolean_struct::True> + Sync,
{
    value.cast::<G>().map_err(|_| {
        pyo3::exceptions::PyTypeError::new_err(format!(
            "expected a {} or None, got {}",
            G::NAME,
            value
                .get_type()
                .name()
                .map_or("?".into(), |n| n.to_string())
        ))
    })
}

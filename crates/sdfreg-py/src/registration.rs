//! `sdfreg.Registration`: the result of `sdfreg.register`, read-only.

use numpy::{IntoPyArray, PyArray1, PyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert;

/// The outcome of a registration (see `sdfreg.register`).
#[pyclass(frozen, module = "sdfreg", name = "Registration")]
pub struct PyRegistration(pub sdfreg_core::Registration);

#[pymethods]
impl PyRegistration {
    /// 4×4 float64 array mapping source coordinates into the target frame: ``[R | t]``, or
    /// with ``scale=True`` the similarity ``[s R | t]``.
    #[getter]
    fn transformation<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        convert::matrix4(py, &self.0.matrix())
    }

    /// The scale ``s`` of the similarity (target units per source unit); 1.0 when rigid.
    #[getter]
    fn scale(&self) -> f64 {
        self.0.scale
    }

    /// With ``scale=True``: the 7×7 JᵀJ of the step [rotation (rad); translation (units);
    /// log-scale], about the target origin; None when rigid.
    #[getter]
    fn similarity_information<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f64>>> {
        self.0.similarity_information.map(|m| {
            numpy::ndarray::Array2::from_shape_fn((7, 7), |(r, c)| m[(r, c)]).into_pyarray(py)
        })
    }

    /// With ``scale=True``: how well the clouds fix the scale once every rigid motion is free to
    /// compensate (relative to the largest constraint eigenvalue); None when rigid.
    #[getter]
    fn scale_relative_eigenvalue(&self) -> Option<f64> {
        self.0.degeneracy.scale_relative_eigenvalue
    }

    /// With ``scale=True``: whether the clouds leave the scale free (a flat overlap looks the
    /// same at every size); the scale is then arbitrary. False when rigid.
    #[getter]
    fn scale_free(&self) -> bool {
        self.0.degeneracy.scale_free()
    }

    /// Whether the stage that set the final pose converged (the polish's last pass when it was
    /// applied, else the final Levenberg–Marquardt steps).
    #[getter]
    fn converged(&self) -> bool {
        self.0.converged
    }

    /// Why that stage stopped: "small_step", "no_decrease", "max_iterations" or (the polish) "stalled".
    #[getter]
    fn stop_reason(&self) -> &'static str {
        self.0.stop_reason.name()
    }

    /// Fraction of source points within `inlier_distance` of a target point.
    #[getter]
    fn fitness(&self) -> f64 {
        self.0.fitness
    }

    /// Whether the robust kernel produced this result (``robust="on"``, or least squares fitted
    /// poorly and the robust re-run fitted better; ``stages["robust"]`` says which).
    #[getter]
    fn robust(&self) -> bool {
        self.0.robust
    }

    /// RMSE of the inliers' nearest-neighbour distances, in the clouds' units.
    #[getter]
    fn inlier_rmse(&self) -> f64 {
        self.0.inlier_rmse
    }

    /// The inlier distance used, in the clouds' units.
    #[getter]
    fn inlier_distance(&self) -> f64 {
        self.0.inlier_distance
    }

    /// Levenberg–Marquardt iterations (multi-start excluded).
    #[getter]
    fn iterations(&self) -> usize {
        self.0.iterations
    }

    /// Mean squared SDF value of the moved source points, in the clouds' units squared.
    #[getter]
    fn cost(&self) -> f64 {
        self.0.cost
    }

    /// 6×6 JᵀJ in the target frame, twist order [rotation (rad); translation (units)].
    #[getter]
    fn information<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        convert::matrix6(py, &self.0.information)
    }

    /// Eigenvalues (6, ascending) of the normalised constraint matrix, each divided by the largest.
    #[getter]
    fn constraint_eigenvalues<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, &self.0.degeneracy.relative_eigenvalues)
    }

    /// Motions the clouds leave (nearly) free, least constrained first; empty when the pose is
    /// fully determined.
    #[getter]
    fn free_motions(&self) -> Vec<PyFreeMotion> {
        self.0
            .degeneracy
            .free
            .iter()
            .cloned()
            .map(PyFreeMotion)
            .collect()
    }

    /// What each stage did, as a dict: ``initial``, ``coarse_to_fine``, ``final_lm``,
    /// ``robust``, ``polish``, ``shift_search``, ``rescue``, ``global_rerun`` (each stage's ``change``:
    /// ``rotation_deg`` and ``translation``, how far it moved the source), and ``swapped``
    /// (True when the target was registered onto the source and the result inverted:
    /// ``swap_ratio``).
    #[getter]
    fn stages<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let json = serde_json::to_string(&self.0.stages)
            .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))?;
        py.import("json")?.call_method1("loads", (json,))
    }

    /// Wall time of the registration, seconds.
    #[getter]
    fn time_s(&self) -> f64 {
        self.0.time.as_secs_f64()
    }

    /// Wall time of each stage, seconds, as a dict in pipeline order: ``prefit`` (fitting Φ on
    /// the target; 0 against a model), ``initial``, ``coarse_to_fine``, ``final_lm``,
    /// ``polish``, ``shift_search``, ``measure``, and ``other_run`` (the robust re-run's run
    /// that was not returned; 0 when none ran).
    #[getter]
    fn stage_times_s<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let times = PyDict::new(py);
        for (name, t) in self.0.stage_times.named() {
            times.set_item(name, t.as_secs_f64())?;
        }
        Ok(times)
    }

    /// The points left out of each cloud before registering, as a dict: ``{"source":
    /// {"missing_returns": n, "stray": m}, "target": {...}}`` (points at exactly (0, 0, 0), two
    /// or more; stray points far off the rest). The target's are 0 against a model (its fit
    /// left them out).
    #[getter]
    fn points_left_out<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        left_out_dict(py, &self.0.source_left_out, &self.0.target_left_out)
    }

    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyTuple>> {
        convert::reduce_as_json(py, "_registration_from_json", &self.0)
    }

    fn __repr__(&self) -> String {
        let r = &self.0;
        let m = r.matrix();
        let rows: Vec<String> = (0..4)
            .map(|i| {
                let v: Vec<String> = (0..4).map(|j| format!("{:.6}", m[(i, j)])).collect();
                format!("[{}]", v.join(", "))
            })
            .collect();
        format!(
            "Registration(converged={}, stop_reason='{}', fitness={:.4}, inlier_rmse={:.6}, \
             iterations={}, time_s={:.3},\n             transformation=[{}])",
            if r.converged { "True" } else { "False" },
            r.stop_reason.name(),
            r.fitness,
            r.inlier_rmse,
            r.iterations,
            r.time.as_secs_f64(),
            rows.join(",\n                             "),
        )
    }
}

/// A registration from its JSON (unpickling).
#[pyfunction]
pub fn _registration_from_json(json: &str) -> PyResult<PyRegistration> {
    serde_json::from_str(json).map(PyRegistration).map_err(|e| {
        pyo3::exceptions::PyValueError::new_err(format!("not a pickled Registration: {e}"))
    })
}

/// A motion of the source the clouds do not determine (see `Registration.free_motions`).
#[pyclass(frozen, module = "sdfreg", name = "FreeMotion")]
pub struct PyFreeMotion(pub sdfreg_core::FreeMotion);

#[pymethods]
impl PyFreeMotion {
    /// "rotation", "translation" or "screw".
    #[getter]
    fn kind(&self) -> &'static str {
        self.0.kind.name()
    }

    /// Unit direction (3,), target frame: the rotation axis or the translation direction.
    #[getter]
    fn axis<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.0.axis.as_slice())
    }

    /// A point (3,) of the rotation axis, target frame, the clouds' units (for a translation,
    /// the moved source's centroid).
    #[getter]
    fn point<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.0.point.coords.as_slice())
    }

    /// The constraint eigenvalue relative to the largest (0 = unconstrained).
    #[getter]
    fn relative_eigenvalue(&self) -> f64 {
        self.0.relative_eigenvalue
    }

    fn __repr__(&self) -> String {
        format!("FreeMotion({})", self.0)
    }
}

/// `{"source": {"missing_returns": n, "stray": m}, "target": {…}}`.
pub(crate) fn left_out_dict<'py>(
    py: Python<'py>,
    source: &sdfreg_core::LeftOut,
    target: &sdfreg_core::LeftOut,
) -> PyResult<Bound<'py, PyDict>> {
    let both = PyDict::new(py);
    for (role, left_out) in [("source", source), ("target", target)] {
        let counts = PyDict::new(py);
        counts.set_item("missing_returns", left_out.missing_returns)?;
        counts.set_item("stray", left_out.stray)?;
        both.set_item(role, counts)?;
    }
    Ok(both)
}

//! `sdfreg.evaluate_registration` and its result, `sdfreg.Evaluation`.

use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::{convert, error, Target};

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// How well ``source``, moved by ``transformation``, lies on ``target``, at a distance in their
/// units, with no registration run: as Open3D's ``evaluate_registration``.
///
/// Use it to judge a result at your own tolerance (a :class:`Registration`'s ``fitness`` is at
/// ``inlier_distance``, a fraction of the target's size), or to compare another tool's answer
/// with sdfreg's on the same terms.
///
/// Args:
///     source: (N, 3) points to move (array, Open3D ``PointCloud``, …).
///     target: (M, 3) points, fixed, the same units; or an :class:`SdfModel` (against the
///         target points it was fitted to, :attr:`SdfModel.target_points`) or a
///         :class:`MeshModel` (each source point's exact distance to the mesh's faces).
///     max_distance: A source point is an inlier when its nearest target point lies within
///         this distance, in the clouds' units (metres for a LiDAR scan).
///     transformation: 4×4 mapping source into target (``Registration.transformation``, rigid
///         or a similarity ``[s R | t]``); None: the identity, the clouds as they are.
///
/// Missing returns at (0, 0, 0) and stray points are left out of both clouds first, as
/// :func:`register` leaves them out (and warned the same way; a model's fit left out its
/// target's); every other point counts.
///
/// Returns:
///     The :class:`Evaluation`: ``fitness``, ``inlier_rmse``, ``inliers``, ``source_points``.
///
/// Raises:
///     ValueError: a cloud is not an (N, 3) float array, has a NaN or infinite coordinate,
///         fewer than 10 points or no extent; ``max_distance`` is not positive and finite;
///         ``transformation`` is not a 4×4 similarity.
#[pyfunction]
#[pyo3(signature = (source, target, max_distance, transformation = None))]
pub fn evaluate_registration<'py>(
    py: Python<'py>,
    source: &Bound<'py, PyAny>,
    target: &Bound<'py, PyAny>,
    max_distance: f64,
    transformation: Option<&Bound<'py, PyAny>>,
) -> PyResult<PyEvaluation> {
    let source = convert::points(source, "source")?;
    let target = Target::from_python(target)?;
    let matrix = match transformation {
        Some(m) => {
            let (pose, scale) = convert::similarity(m, "transformation")?;
            nalgebra::Similarity3::from_isometry(pose, scale).to_homogeneous()
        }
        None => nalgebra::Matrix4::identity(),
    };
    let e = py
        .detach(|| match &target {
            Target::Cloud(target) => {
                sdfreg_core::evaluate_registration(&source, target, &matrix, max_distance)
            }
            Target::Model(model) => model.evaluate_registration(&source, &matrix, max_distance),
            Target::Mesh(mesh) => mesh.evaluate_registration(&source, &matrix, max_distance),
        })
        .map_err(|e| match e {
            sdfreg_core::Error::InvalidSetting { reason, .. } => {
                error::argument("max_distance", reason)
            }
            e => error::registration(e),
        })?;
    error::warn_left_out(py, "source", source.len(), &e.source_left_out)?;
    if let Target::Cloud(target) = &target {
        error::warn_left_out(py, "target", target.len(), &e.target_left_out)?;
    }
    Ok(PyEvaluation(e))
}

/// How well a transformed source lies on a target (see ``sdfreg.evaluate_registration``).
#[pyclass(frozen, module = "sdfreg", name = "Evaluation")]
pub struct PyEvaluation(pub sdfreg_core::Evaluation);

#[pymethods]
impl PyEvaluation {
    /// Fraction of the source's points within ``max_distance`` of a target point.
    #[getter]
    fn fitness(&self) -> f64 {
        self.0.fitness
    }

    /// RMS distance of those inliers to their nearest target points, the clouds' units; 0.0
    /// when there are none.
    #[getter]
    fn inlier_rmse(&self) -> f64 {
        self.0.inlier_rmse
    }

    /// How many source points are inliers.
    #[getter]
    fn inliers(&self) -> usize {
        self.0.inliers
    }

    /// How many source points were counted (less the missing returns and stray points).
    #[getter]
    fn source_points(&self) -> usize {
        self.0.source_points
    }

    /// The distance asked for, the clouds' units.
    #[getter]
    fn max_distance(&self) -> f64 {
        self.0.max_distance
    }

    /// The points left out of each cloud, as :attr:`Registration.points_left_out`.
    #[getter]
    fn points_left_out<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        crate::registration::left_out_dict(py, &self.0.source_left_out, &self.0.target_left_out)
    }

    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyTuple>> {
        convert::reduce_as_json(py, "_evaluation_from_json", &self.0)
    }

    fn __repr__(&self) -> String {
        let e = &self.0;
        format!(
            "Evaluation(fitness={:.4}, inlier_rmse={:.6}, inliers={}, source_points={}, max_distance={})",
            e.fitness, e.inlier_rmse, e.inliers, e.source_points, e.max_distance
        )
    }
}

/// An evaluation from its JSON (unpickling).
#[pyfunction]
pub fn _evaluation_from_json(json: &str) -> PyResult<PyEvaluation> {
    serde_json::from_str(json).map(PyEvaluation).map_err(|e| {
        pyo3::exceptions::PyValueError::new_err(format!("not a pickled Evaluation: {e}"))
    })
}

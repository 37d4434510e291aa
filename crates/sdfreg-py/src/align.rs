//! `sdfreg.align`: many scans into one frame, and its result `sdfreg.Alignment`.

use std::sync::Arc;

use numpy::PyArray2;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use sdfreg_core::geometry::cloud::LeftOut;
use sdfreg_core::views::poses_file;

use crate::convert;
use crate::error;
use crate::evaluate::PyEvaluation;
use crate::model::PySdfModel;
use crate::registration::PyRegistration;
use crate::settings::{Caller, SettingsArgs};

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// Aligns many scans (views of one object or scene) into the frame of one of them.
///
/// Each scan gets a stored model; the pairs are registered through them (all pairs up to 16
/// scans, else each scan with its next 3 in order, wrapping round, then at most
/// ``closure_pairs`` more per scan between placed scans that overlap far apart along the
/// graph); the registrations that fit (fitness ≥ 0.3), that a cycle through a third scan
/// confirms and that agree with a spanning tree (groups of scans joined where most of the
/// fitness of the edges between them agrees) form a pose graph, solved
/// by robust Gauss–Newton on SE(3); then each scan is registered against one model of all
/// the others (``joint_rounds`` times, none by default). No initial guesses are needed.
///
/// Args:
///     scans: A sequence of (N, 3) point arrays, each in its own frame, the same units.
///     init: Approximate poses, one 4×4 per scan (scan into the anchor's frame: a turntable's
///         angles, odometry; None for a scan without one, whose pairs then start from nothing,
///         as :func:`read_poses` gives a scan left out), or None.
///     anchor: The scan whose frame the poses map into.
///     closure_pairs: Above 16 scans, the pairs each scan joins once the graph has placed
///         them, between scans that overlap and lie at least 5 kept edges apart (loop
///         closures); 0 skips. Default 2.
///     joint_rounds: Joint refinement rounds (each scan against one model of the others);
///         0 skips.
///     consensus_iterations: Iterations of the multi-view point-to-plane refinement after the
///         pose graph (every pose at once, against the other scans' points); 0 (the default)
///         skips it.
///     seen_from: Where each scan was seen from, in its own frame: ``"origin"`` (a LiDAR or
///         depth camera's scan in its sensor's frame), an axis such as ``"+z"`` (a scanner far
///         along +z, as the Stanford scans) or a direction ``(x, y, z)``. A pair that puts more
///         than ``max_in_free_space`` of either scan where the other's sensor saw empty space is
///         then no edge. None (the default): no such check.
///     max_in_free_space: See ``seen_from``; a share of the scan's points. Default 0.02.
///     seed: Seed of every random choice.
///     threads: Worker threads; 0 = one per core.
///     preset: The pairs' preset, ``"views"`` by default (``"scans"``, the robust kernel from
///         the start, with an object's polish pass ending when its steps stop shrinking, against planes at the target's points; a scene's polish on 16384 source points).
///
/// The other keywords are :func:`register`'s (without ``scale``) and apply to every pair.
///
/// Returns:
///     The :class:`Alignment`.
///
/// Raises:
///     ValueError: fewer than two scans can be used, a scan is not an (N, 3) float array, the
///         anchor names no scan, ``init`` has not one rigid 4×4 per scan, or a setting is out
///         of range.
///
/// Warns:
///     UserWarning: points were left out of a scan: missing returns at (0, 0, 0) or stray
///         points, one warning per kind and scan (``scans[k]``) with how many.
#[pyfunction]
#[pyo3(signature = (scans, *, init = None, anchor = 0, closure_pairs = 2, joint_rounds = 0, consensus_iterations = 0, seen_from = None, max_in_free_space = 0.02, **settings))]
#[allow(clippy::too_many_arguments)]
pub fn align<'py>(
    py: Python<'py>,
    scans: &Bound<'py, PyAny>,
    init: Option<&Bound<'py, PyAny>>,
    anchor: i64,
    closure_pairs: i64,
    joint_rounds: i64,
    consensus_iterations: i64,
    seen_from: Option<&Bound<'py, PyAny>>,
    max_in_free_space: f64,
    settings: Option<&Bound<'py, PyDict>>,
) -> PyResult<PyAlignment> {
    let seen_from = seen_from.map(seen_from_arg).transpose()?;
    let scans = scan_list(scans)?;
    let init = init
        .map(|poses| -> PyResult<Vec<Option<nalgebra::Isometry3<f64>>>> {
            poses
                .try_iter()
                .map_err(|_| error::argument("init", "expected a sequence of 4×4 arrays"))?
                .enumerate()
                .map(|(k, m)| {
                    let m = m?;
                    if m.is_none() {
                        return Ok(None);
                    }
                    convert::isometry(&m, &format!("init[{k}]")).map(Some)
                })
                .collect()
        })
        .transpose()?;
    let register = SettingsArgs::from_kwargs(Caller::Align, settings)?.build("views")?;
    let s = sdfreg_core::AlignSettings {
        threads: register.threads,
        register,
        anchor: usize::try_from(anchor)
            .map_err(|_| error::argument("anchor", format!("must be ≥ 0, got {anchor}")))?,
        closure_pairs: usize::try_from(closure_pairs).map_err(|_| {
            error::argument("closure_pairs", format!("must be ≥ 0, got {closure_pairs}"))
        })?,
        joint_rounds: usize::try_from(joint_rounds).map_err(|_| {
            error::argument("joint_rounds", format!("must be ≥ 0, got {joint_rounds}"))
        })?,
        consensus: sdfreg_core::ConsensusSettings {
            iterations: usize::try_from(consensus_iterations).map_err(|_| {
                error::argument(
                    "consensus_iterations",
                    format!("must be ≥ 0, got {consensus_iterations}"),
                )
            })?,
            ..Default::default()
        },
        seen_from,
        max_in_free_space,
        ..Default::default()
    };
    let (alignment, model, left_out) = py
        .detach(|| {
            let a = sdfreg_core::align(&scans, init.as_deref(), &s)?;
            let model = a.merged_model(&scans, &s.register)?;
            let left_out: Vec<_> = scans.iter().map(|scan| LeftOut::of(scan)).collect();
            Ok::<_, sdfreg_core::Error>((a, model, left_out))
        })
        .map_err(error::registration)?;
    for (k, (scan, left_out)) in scans.iter().zip(&left_out).enumerate() {
        error::warn_left_out(py, &format!("scans[{k}]"), scan.len(), left_out)?;
    }
    Ok(PyAlignment {
        alignment,
        model: Arc::new(model),
    })
}

/// `scans`: a sequence of (N, 3) clouds (`ValueError` naming `scans` or `scans[k]`).
fn scan_list(scans: &Bound<'_, PyAny>) -> PyResult<Vec<Vec<nalgebra::Point3<f64>>>> {
    scans
        .try_iter()
        .map_err(|_| error::argument("scans", "expected a sequence of (N, 3) arrays"))?
        .enumerate()
        .map(|(k, s)| convert::points(&s?, &format!("scans[{k}]")))
        .collect()
}

/// `seen_from=`: a string (`"origin"`, `"+z"`, `"1,0,0"`) or three numbers.
fn seen_from_arg(v: &Bound<'_, PyAny>) -> PyResult<sdfreg_core::SeenFrom> {
    let seen = match v.extract::<String>() {
        Ok(text) => text.parse::<sdfreg_core::SeenFrom>(),
        Err(_) => match v
            .extract::<Vec<f64>>()
            .ok()
            .and_then(|d| <[f64; 3]>::try_from(d).ok())
        {
            Some(d) => sdfreg_core::SeenFrom::direction(d),
            None => Err("expected \"origin\", an axis such as \"+z\" or three numbers".into()),
        },
    };
    seen.map_err(|why| error::argument("seen_from", why))
}

/// The outcome of :func:`align`. Read-only.
#[pyclass(frozen, module = "sdfreg", name = "Alignment")]
pub struct PyAlignment {
    alignment: sdfreg_core::Alignment,
    model: Arc<sdfreg_core::SdfModel>,
}

#[pymethods]
impl PyAlignment {
    /// Per scan, the 4×4 mapping its coordinates into the anchor's frame; None for a scan left
    /// out.
    #[getter]
    fn poses<'py>(&self, py: Python<'py>) -> Vec<Option<Bound<'py, PyArray2<f64>>>> {
        self.alignment
            .poses
            .iter()
            .map(|p| p.map(|t| convert::matrix4(py, &t.to_homogeneous())))
            .collect()
    }

    /// The scans left out, as ``(index, why)``.
    #[getter]
    fn left_out(&self) -> Vec<(usize, String)> {
        self.alignment.left_out.clone()
    }

    /// The index of the anchor scan.
    #[getter]
    fn anchor(&self) -> usize {
        self.alignment.anchor
    }

    /// Per scan, the best fitness of a kept pairwise registration it is part of.
    #[getter]
    fn fitness(&self) -> Vec<f64> {
        self.alignment.fitness.clone()
    }

    /// Every pairwise registration, as dicts: ``target``, ``source`` (scan indices; the
    /// source was moved onto the target), ``fitness``, ``kept`` (used by the pose graph),
    /// ``in_free_space`` (with ``seen_from``: the larger share of either scan that it puts in
    /// the other's free space; else None), and ``registration`` (a :class:`Registration`) or
    /// ``error``.
    #[getter]
    fn edges<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let list = PyList::empty(py);
        for e in &self.alignment.edges {
            let d = PyDict::new(py);
            d.set_item("target", e.target)?;
            d.set_item("source", e.source)?;
            d.set_item("fitness", e.fitness())?;
            d.set_item("kept", e.kept)?;
            d.set_item("in_free_space", e.in_free_space)?;
            match &e.registration {
                Ok(r) => d.set_item("registration", PyRegistration(r.clone()))?,
                Err(why) => d.set_item("error", why)?,
            }
            list.append(d)?;
        }
        Ok(list)
    }

    /// One model of all the placed scans in the anchor's frame (mesh it with
    /// ``model.mesh()``, save it with ``model.save(path)``).
    #[getter]
    fn model(&self) -> PySdfModel {
        PySdfModel(self.model.clone())
    }

    /// Wall time, seconds.
    #[getter]
    fn time_s(&self) -> f64 {
        self.alignment.time.as_secs_f64()
    }

    /// What the multi-view refinement (``consensus_iterations``) did: ``pairs`` (ordered pairs
    /// of scans measured), ``iterations``, ``mean_residual_before`` and ``mean_residual_after``
    /// (mean distance of the measured points to the other scans' planes, scan units),
    /// ``undone`` (the graph's poses kept: the residual did not fall). Zeros when it did not run.
    #[getter]
    fn consensus<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let c = &self.alignment.consensus;
        let d = PyDict::new(py);
        d.set_item("pairs", c.pairs)?;
        d.set_item("iterations", c.iterations)?;
        d.set_item("mean_residual_before", c.before)?;
        d.set_item("mean_residual_after", c.after)?;
        d.set_item("undone", c.undone)?;
        Ok(d)
    }

    /// Each stage's wall time, seconds: ``models``, ``pairs``, ``graph``, ``unplaced`` (the
    /// scans the pose graph left unplaced, against one model of their partners),
    /// ``consensus``, ``joint``.
    #[getter]
    fn stage_times_s<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let t = &self.alignment.times;
        let d = PyDict::new(py);
        for (name, v) in [
            ("models", t.models),
            ("pairs", t.pairs),
            ("graph", t.graph),
            ("unplaced", t.unplaced),
            ("consensus", t.consensus),
            ("joint", t.joint),
        ] {
            d.set_item(name, v.as_secs_f64())?;
        }
        Ok(d)
    }

    // The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
    /// How well each placed scan lies on the others once aligned, with no reference: per scan,
    /// :func:`evaluate_registration` of the scan, moved by its pose, against all the other
    /// placed scans in the anchor's frame (those whose bounding boxes come within
    /// ``max_distance``), with missing returns and stray points left out of each. The
    /// distances are measured in one frame for all the scans, so a figure may differ from
    /// :func:`evaluate_registration`'s in the last digits; each point costs about log2(n)
    /// k-d tree look-ups for n scans.
    ///
    /// A scan's parts that no other scan saw count against its fitness: compare the figures
    /// with those of other poses of the same scans (a reference's, another tool's), not with 1.
    ///
    /// Args:
    ///     scans: The scans given to :func:`align`, in the same order.
    ///     max_distance: A point is an inlier when another scan's point lies within this
    ///         distance, in the scans' units.
    ///
    /// Returns:
    ///     Per scan, an :class:`Evaluation`, or None for a scan left out.
    ///
    /// Raises:
    ///     ValueError: ``scans`` are not as many as the alignment's, or one is not an (N, 3)
    ///         float array; ``max_distance`` is not positive and finite.
    fn evaluate(
        &self,
        py: Python<'_>,
        scans: &Bound<'_, PyAny>,
        max_distance: f64,
    ) -> PyResult<Vec<Option<PyEvaluation>>> {
        let scans = scan_list(scans)?;
        let evaluations = py
            .detach(|| self.alignment.evaluate(&scans, max_distance))
            .map_err(|e| match e {
                sdfreg_core::Error::InvalidSetting { name, reason } => {
                    error::argument(name, reason)
                }
                e => error::registration(e),
            })?;
        Ok(evaluations
            .into_iter()
            .map(|e| e.map(PyEvaluation))
            .collect())
    }

    // The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
    /// The poses file of this alignment, as ``sdfreg align --output poses.json`` writes it
    /// (``format`` ``"sdfreg-poses"``; per scan ``file``, ``transformation`` or null,
    /// ``fitness``; ``edges``; the times): write it to a file, read it back with
    /// :func:`read_poses`.
    ///
    /// Args:
    ///     files: A name per scan, in order (default ``"scan 0"``, ``"scan 1"``, …).
    ///
    /// Raises:
    ///     ValueError: ``files`` does not name every scan once.
    #[pyo3(signature = (files = None))]
    fn to_json(&self, files: Option<Vec<String>>) -> PyResult<String> {
        let n = self.alignment.poses.len();
        let files = files.unwrap_or_else(|| (0..n).map(|k| format!("scan {k}")).collect());
        if files.len() != n {
            return Err(error::argument(
                "files",
                format!(
                    "{} names for {n} scans (one per scan, in order)",
                    files.len()
                ),
            ));
        }
        let index: Vec<usize> = (0..n).collect();
        let json = poses_file::poses_json(&self.alignment, &files, &index, &[]);
        Ok(serde_json::to_string_pretty(&json).map_err(|e| error::argument("files", e))? + "\n")
    }

    fn __repr__(&self) -> String {
        let placed = self.alignment.poses.iter().filter(|p| p.is_some()).count();
        format!(
            "Alignment({placed} of {} scans placed, anchor {}, {} of {} pairs kept, time_s={:.2})",
            self.alignment.poses.len(),
            self.alignment.anchor,
            self.alignment.edges.iter().filter(|e| e.kept).count(),
            self.alignment.edges.len(),
            self.alignment.time.as_secs_f64()
        )
    }
}

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// Reads the poses of a poses file (``sdfreg align --output poses.json``,
/// :meth:`Alignment.to_json`): per scan, in order, its 4×4 (scan into the anchor's frame), None
/// for a scan left out. The list passes as ``align(scans, init=...)``.
///
/// Raises:
///     OSError: the file cannot be read (``FileNotFoundError``, …), is not JSON (the message
///         names the line), is another program's or another sdfreg file, of a newer version,
///         or holds a transformation that is not a rigid 4×4 (the message names the scan).
#[pyfunction]
pub fn read_poses(
    py: Python<'_>,
    path: std::path::PathBuf,
) -> PyResult<Vec<Option<Bound<'_, PyArray2<f64>>>>> {
    let poses = py
        .detach(|| poses_file::load_poses(&path))
        .map_err(error::io)?;
    Ok(poses
        .iter()
        .map(|p| p.map(|t| convert::matrix4(py, &t.to_homogeneous())))
        .collect())
}

//! `sdfreg.register_many`: many pairs on every core, one pair per worker, the GIL released
//! while they run. The pairs are converted (copied) first; then the core's `register_each`
//! runs them on its own pool while this thread, holding the GIL only between results, files
//! each result in its slot, reports progress and watches for Ctrl-C.

use std::borrow::Cow;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Mutex};
use std::time::Duration;

use nalgebra::{Isometry3, Point3};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
use sdfreg_core::{register_each, Pair, PairTarget, Registration};

use crate::registration::PyRegistration;
use crate::settings::{Caller, SettingsArgs};
use crate::{convert, error, Target};

// The Python docstring, kept equal to the one in python/sdfreg/_sdfreg.pyi.
/// Registers many pairs at once, on every core: one pair per worker thread, each
/// registration single-threaded, the GIL released while they run.
///
/// Args:
///     pairs: An iterable of ``(source, target)`` or ``(source, target, init)``: clouds as
///         :func:`register` takes them, a target cloud or an :class:`SdfModel` (registered
///         against with Φ frozen; one model may serve many pairs), ``init`` a 4×4 or None.
///     threads: Pairs registered at once; 0 = one per core.
///     progress: True for a progress bar on stderr (tqdm's when it is installed), or a
///         callable ``progress(done, total)`` called after each pair, from this thread.
///     **settings: The settings keywords of :func:`register` (``preset``, ``robust``,
///         ``seed``, ``max_source_points``, …, the settings groups), the same for every pair.
///
/// Returns:
///     A list in the order of ``pairs``: each pair's :class:`Registration`, bit-identical to
///     ``register(source, target, init=init, **settings)``; or, for a pair that failed, the
///     exception ``register`` would have raised (``ValueError``), its message starting with
///     ``pair i:``. The others are not affected.
///
/// Raises:
///     ValueError: a setting is out of range (before any pair runs).
///     TypeError: ``pairs`` is not iterable, or a keyword names no setting.
///     KeyboardInterrupt: Ctrl-C; the pairs already running finish first (at most one per
///         worker).
#[pyfunction]
#[pyo3(signature = (pairs, *, threads = 0, progress = None, **settings), text_signature = "(pairs, *, threads=0, progress=False, **settings)")]
pub fn register_many<'py>(
    py: Python<'py>,
    pairs: &Bound<'py, PyAny>,
    threads: i64,
    progress: Option<&Bound<'py, PyAny>>,
    settings: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyList>> {
    let mut args = SettingsArgs::from_kwargs(Caller::RegisterMany, settings)?;
    args.threads = 1;
    let settings = args.build("default")?;
    let threads: usize = crate::settings::IntoSetting::into_setting(threads, "threads")?;
    let prepared: Vec<Result<Prepared, PyErr>> = pairs
        .try_iter()?
        .map(|item| item.and_then(|p| Prepared::from_python(&p)))
        .collect();
    let total = prepared.len();
    let progress = progress_callback(py, progress, total)?;

    let mut slots: Vec<Option<Py<PyAny>>> = (0..total).map(|_| None).collect();
    let mut ready = Vec::new();
    for (i, p) in prepared.iter().enumerate() {
        match p {
            Ok(p) => ready.push((i, p.pair())),
            Err(e) => slots[i] = Some(in_pair(py, i, e.clone_ref(py))),
        }
    }
    let mut done = total - ready.len();
    if let Some(report) = &progress {
        report.call1((done, total))?;
    }
    let (sender, receiver) = mpsc::channel::<(usize, Result<Registration, sdfreg_core::Error>)>();
    let receiver = Mutex::new(receiver);
    let stop = AtomicBool::new(false);
    let mut raised: Option<PyErr> = None;
    let outcome = std::thread::scope(|scope| {
        let worker = scope.spawn(|| {
            let sender = sender;
            register_each(ready, &settings, threads, &stop, |i, r| {
                // The receiver outlives the batch; a send cannot fail while it waits.
                let _ = sender.send((i, r));
            })
        });
        loop {
            let next = py.detach(|| {
                receiver
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .recv_timeout(Duration::from_millis(100))
            });
            match next {
                Ok((i, r)) => {
                    slots[i] = Some(match r {
                        Ok(r) => Py::new(py, PyRegistration(r))?.into_any(),
                        Err(e) => in_pair(py, i, error::registration(e)),
                    });
                    done += 1;
                    if let (Some(report), None) = (&progress, &raised) {
                        if let Err(e) = report.call1((done, total)) {
                            stop.store(true, Ordering::Relaxed);
                            raised = Some(e);
                        }
                    }
                }
                Err(mpsc::RecvTimeoutError::Timeout) => {}
                Err(mpsc::RecvTimeoutError::Disconnected) => break,
            }
            if raised.is_none() {
                if let Err(e) = py.check_signals() {
                    stop.store(true, Ordering::Relaxed);
                    raised = Some(e);
                }
            }
        }
        worker
            .join()
            .map_err(|_| pyo3::exceptions::PyRuntimeError::new_err("a batch worker panicked"))?
            .map_err(error::registration)
    });
    outcome?;
    if let Some(e) = raised {
        return Err(e);
    }
    PyList::new(
        py,
        slots
            .into_iter()
            .map(|s| s.expect("every pair's result is filed when the batch is not stopped")),
    )
}

/// One pair, converted: the clouds copied out of Python, a model shared.
struct Prepared {
    source: Vec<Point3<f64>>,
    target: Target,
    init: Option<Isometry3<f64>>,
}

impl Prepared {
    fn from_python(item: &Bound<'_, PyAny>) -> PyResult<Self> {
        // A tuple or list of 2 or 3 (not a string, an array or a dict, which also iterate).
        let parts: Vec<Bound<'_, PyAny>> =
            if item.is_instance_of::<PyTuple>() || item.is_instance_of::<PyList>() {
                item.try_iter()?.collect::<PyResult<_>>()?
            } else {
                Vec::new()
            };
        if !(2..=3).contains(&parts.len()) {
            return Err(error::argument(
                "pair",
                format!(
                    "expected (source, target) or (source, target, init), got {}",
                    item.repr()?
                ),
            ));
        }
        let source = convert::points(&parts[0], "source")?;
        let target = Target::from_python(&parts[1])?;
        let init = match parts.get(2) {
            Some(m) if !m.is_none() => Some(convert::isometry(m, "init")?),
            _ => None,
        };
        Ok(Prepared {
            source,
            target,
            init,
        })
    }

    fn pair(&self) -> Pair<'_> {
        Pair {
            source: Cow::Borrowed(&self.source),
            target: match &self.target {
                Target::Cloud(points) => PairTarget::Cloud(Cow::Borrowed(points)),
                Target::Model(model) => PairTarget::Model(model),
                Target::Mesh(mesh) => PairTarget::Mesh(mesh),
            },
            init: self.init,
            seed: None,
        }
    }
}

/// The exception of pair `i`: `e`'s class, its message prefixed with `pair i: `.
fn in_pair(py: Python<'_>, i: usize, e: PyErr) -> Py<PyAny> {
    let message = e
        .value(py)
        .str()
        .map_or_else(|_| String::new(), |s| s.to_string());
    e.get_type(py)
        .call1((format!("pair {i}: {message}"),))
        .map_or_else(|_| e.into_value(py).into_any(), Bound::unbind)
}

/// `progress` as a callable `(done, total)`: None or False none, True a bar on stderr.
fn progress_callback<'py>(
    py: Python<'py>,
    progress: Option<&Bound<'py, PyAny>>,
    total: usize,
) -> PyResult<Option<Bound<'py, PyAny>>> {
    let Some(p) = progress.filter(|p| !p.is_none()) else {
        return Ok(None);
    };
    if p.is_callable() {
        return Ok(Some(p.clone()));
    }
    match p.extract::<bool>() {
        Ok(true) => {
            let bar = py.import("sdfreg._progress")?.getattr("ProgressBar")?;
            Ok(Some(bar.call1((total, "register_many"))?))
        }
        Ok(false) => Ok(None),
        Err(_) => Err(error::argument(
            "progress",
            format!(
                "expected True, False or a callable (done, total), got {}",
                p.repr()?
            ),
        )),
    }
}

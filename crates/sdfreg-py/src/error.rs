//! Every mapping of a core error to a Python exception, and every warning, in one place.
//!
//! - bad arrays, settings and initial guesses → `ValueError` (the core names the cloud and the
//!   point, e.g. "source cloud: point 17 has a non-finite coordinate");
//! - files that cannot be opened, read or parsed → `OSError` (`FileNotFoundError`,
//!   `PermissionError`, `IsADirectoryError` where the system says so), with the path and line.

use pyo3::exceptions::{
    PyFileNotFoundError, PyIsADirectoryError, PyOSError, PyPermissionError, PyRuntimeError,
    PyValueError,
};
use pyo3::PyErr;
use sdfreg_core::{Error, IoError};

/// A registration error as a Python exception.
pub fn registration(e: Error) -> PyErr {
    match e {
        Error::ThreadPool(_) => PyRuntimeError::new_err(e.to_string()),
        _ => PyValueError::new_err(e.to_string()),
    }
}

/// A point-cloud file error as a Python `OSError` (or the subclass the system error names).
pub fn io(e: IoError) -> PyErr {
    let message = e.to_string();
    match &e {
        IoError::Io { source, .. } => match source.kind() {
            std::io::ErrorKind::NotFound => PyFileNotFoundError::new_err(message),
            std::io::ErrorKind::PermissionDenied => PyPermissionError::new_err(message),
            std::io::ErrorKind::IsADirectory => PyIsADirectoryError::new_err(message),
            _ => PyOSError::new_err(message),
        },
        _ => PyOSError::new_err(message),
    }
}

/// A `ValueError` about the argument `name`.
pub fn argument(name: &str, what: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(format!("{name}: {what}"))
}

/// A `UserWarning` with `message`, attributed to the caller of the binding's function.
pub fn warn(py: pyo3::Python<'_>, message: String) -> pyo3::PyResult<()> {
    let warning = py.get_type::<pyo3::exceptions::PyUserWarning>();
    PyErr::warn(py, &warning, &std::ffi::CString::new(message)?, 1)
}

/// One `UserWarning` per kind of point left out of the argument `name` (`total` points): "source:
/// 5 of 800 points are at exactly (0, 0, 0), a scanner's missing returns: left out".
pub fn warn_left_out(
    py: pyo3::Python<'_>,
    name: &str,
    total: usize,
    left_out: &sdfreg_core::geometry::cloud::LeftOut,
) -> pyo3::PyResult<()> {
    for message in left_out.messages(total) {
        warn(py, format!("{name}: {message}"))?;
    }
    Ok(())
}

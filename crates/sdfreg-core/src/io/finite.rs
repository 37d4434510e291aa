//! The check every reader shares: a point with a NaN or infinite coordinate is refused.

use std::path::Path;

use nalgebra::Point3;

use crate::base::error::IoError;

/// The first of `points` with a NaN or infinite coordinate, as an error naming `path` and,
/// when the points are the rows of a text body that begins at line `first_line` (1-based),
/// that point's line.
pub(crate) fn refuse_non_finite(
    path: &Path,
    points: &[Point3<f64>],
    first_line: Option<u64>,
) -> Result<(), IoError> {
    match points
        .iter()
        .position(|p| !p.coords.iter().all(|v| v.is_finite()))
    {
        Some(index) => Err(IoError::NonFinite {
            path: path.into(),
            line: first_line.map(|l| l as usize + index),
            index,
        }),
        None => Ok(()),
    }
}

/// Drops the points with a NaN or infinite coordinate; returns how many.
pub(crate) fn drop_non_finite(points: &mut Vec<Point3<f64>>) -> usize {
    let before = points.len();
    points.retain(|p| p.coords.iter().all(|v| v.is_finite()));
    before - points.len()
}

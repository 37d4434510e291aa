//! Binary bodies shared by the writers.

use nalgebra::Point3;

/// `header` followed by the points as little-endian f64 triples (binary PLY and PCD bodies).
pub(crate) fn with_le_doubles(header: String, points: &[Point3<f64>]) -> Vec<u8> {
    let mut out = header.into_bytes();
    out.reserve(points.len() * 24);
    for p in points {
        for v in [p.x, p.y, p.z] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

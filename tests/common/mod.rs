//! Shared generators for the integration tests.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use sdfreg_core::RegisterSettings;

/// A rigid motion: rotation `deg` degrees about a fixed oblique axis, then translation `t`.
pub fn motion(deg: f64, t: [f64; 3]) -> Isometry3<f64> {
    let axis = nalgebra::Unit::new_normalize(Vector3::new(0.3, -1.0, 0.6));
    Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_axis_angle(&axis, deg.to_radians()),
    )
}

/// Moves `points` by `m`.
pub fn moved(points: &[Point3<f64>], m: &Isometry3<f64>) -> Vec<Point3<f64>> {
    points.iter().map(|p| m * p).collect()
}

/// A shorter schedule than the default, to keep the test suite quick; accuracy bounds in the
/// tests hold for it (the default schedule does better, see `sdfreg eval`).
pub fn quick() -> RegisterSettings {
    shorten(RegisterSettings::default())
}

/// [`quick`]'s schedule on the preset for partial scans.
pub fn partial_scans_quick() -> RegisterSettings {
    shorten(RegisterSettings::partial_scans())
}

fn shorten(mut s: RegisterSettings) -> RegisterSettings {
    s.fit.prefit_steps = 300;
    s.fit.model_prefit_steps = 300;
    s.coarse_to_fine.alternations = 6;
    s.fit.refine_steps = 40;
    s
}

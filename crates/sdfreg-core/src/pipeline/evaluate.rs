//! [`evaluate_registration`]: how well a given transformation lays one cloud onto another at a
//! distance the caller chooses (Open3D's `evaluate_registration`), with no registration run.

use nalgebra::{Matrix4, Point3};
use rayon::prelude::*;

use crate::base::check;
use crate::base::error::{Error, Role};
use crate::base::pool::in_pool;
use crate::geometry::cloud::{usable, LeftOut, Normalization};
use crate::geometry::se3::similarity_from_matrix;
use crate::geometry::tree::build_tree;
use crate::pipeline::settings::MIN_POINTS;
use crate::solve::measure::{inlier_stats_of, nearest_distances2};

/// How well `source`, moved by a transformation, lies on `target`: see
/// [`evaluate_registration`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Evaluation {
    /// Fraction of the source's points (those left after [`Self::source_left_out`]) whose
    /// nearest target point lies within [`Self::max_distance`].
    pub fitness: f64,
    /// RMS distance of those inliers to their nearest target points, target units; 0 when
    /// there are none.
    pub inlier_rmse: f64,
    /// How many source points are inliers.
    pub inliers: usize,
    /// How many source points were counted (the source's, less those left out).
    pub source_points: usize,
    /// The distance asked for, target units.
    pub max_distance: f64,
    /// The source's missing returns and stray points, left out as a registration leaves them
    /// out ([`crate::register()`]).
    pub source_left_out: LeftOut,
    /// The target's, left out likewise.
    pub target_left_out: LeftOut,
}

/// How well `source`, moved by `transformation`, lies on `target`: the share of its points
/// within `max_distance` of a target point (`fitness`) and their RMS distance
/// (`inlier_rmse`), as Open3D's `evaluate_registration` reports them, with no registration
/// run. Use it to judge a result at a tolerance in your units (a [`crate::Registration`]'s own
/// fitness is at [`crate::RegisterSettings::inlier_distance`], a fraction of the target's
/// size), or to compare another tool's answer with sdfreg's on the same terms.
///
/// `transformation` maps source coordinates into the target frame, `p_target = s R p_source +
/// t` (a [`crate::Registration::matrix`], rigid or a similarity); `max_distance` is in the
/// target's units. Missing returns and stray points are left out of both clouds first, as
/// [`crate::register()`] leaves them out; every other point counts (no subsampling). Distances
/// are measured in the target's unit frame (f32, as the registration's own fitness), so
/// coordinates far from the origin (UTM) lose nothing.
///
/// # Errors
/// A cloud with a non-finite coordinate, fewer than [`MIN_POINTS`] points or no extent;
/// `max_distance` not positive and finite ([`Error::InvalidSetting`]); `transformation` not a
/// finite similarity ([`Error::InvalidTransformation`]).
pub fn evaluate_registration(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    transformation: &Matrix4<f64>,
    max_distance: f64,
) -> Result<Evaluation, Error> {
    let moved = MovedSource::new(source, transformation, max_distance)?;
    let (target, target_left_out) = usable(target, Role::Target, MIN_POINTS)?;
    let norm = Normalization::from_target(&target)?;
    moved.measured(&norm, target_left_out, |moved| {
        let unit_target: Vec<[f32; 3]> = target.par_iter().map(|p| norm.to_unit(p)).collect();
        nearest_distances2(&build_tree(&unit_target), moved)
    })
}

/// A source checked for [`evaluate_registration`] (and the models' `evaluate_registration`),
/// with its transformation and distance: what is measured against any target.
pub(crate) struct MovedSource<'a> {
    source: std::borrow::Cow<'a, [Point3<f64>]>,
    left_out: LeftOut,
    pose: nalgebra::Isometry3<f64>,
    scale: f64,
    max_distance: f64,
}

impl<'a> MovedSource<'a> {
    /// Checks `max_distance` (positive, finite), `transformation` (a finite similarity) and
    /// `source` (its missing returns and stray points left out), in that order.
    pub(crate) fn new(
        source: &'a [Point3<f64>],
        transformation: &Matrix4<f64>,
        max_distance: f64,
    ) -> Result<Self, Error> {
        check::positive("max_distance", max_distance)?;
        let (pose, scale) =
            similarity_from_matrix(transformation).ok_or(Error::InvalidTransformation)?;
        let (source, left_out) = usable(source, Role::Source, MIN_POINTS)?;
        Ok(Self {
            source,
            left_out,
            pose,
            scale,
            max_distance,
        })
    }

    /// The figures against a target in the unit frame `norm` (the target's similarity into
    /// it): `distances2` gives each moved source point's squared distance to the target in that
    /// frame (run within the pool); the target's left-out counts are reported as given.
    pub(crate) fn measured(
        &self,
        norm: &Normalization,
        target_left_out: LeftOut,
        distances2: impl FnOnce(&[[f32; 3]]) -> Vec<f32> + Send,
    ) -> Result<Evaluation, Error> {
        let d2 = in_pool(0, || {
            let moved: Vec<[f32; 3]> = self
                .source
                .par_iter()
                .map(|p| norm.to_unit(&(self.pose * Point3::from(p.coords * self.scale))))
                .collect();
            distances2(&moved)
        })?;
        Ok(Evaluation::from_distances2(
            &d2,
            norm.scale,
            self.max_distance,
            self.left_out,
            target_left_out,
        ))
    }
}

impl Evaluation {
    /// The figures from each counted source point's squared distance to the target, `d2`, in
    /// a unit frame whose unit is `scale` user units (`f32::INFINITY` for a point with no target
    /// point near); `max_distance` in user units.
    pub(crate) fn from_distances2(
        d2: &[f32],
        scale: f64,
        max_distance: f64,
        source_left_out: LeftOut,
        target_left_out: LeftOut,
    ) -> Self {
        let threshold = max_distance / scale;
        let (fitness, rms) = inlier_stats_of(d2, threshold * threshold);
        Self {
            fitness,
            inlier_rmse: rms * scale,
            inliers: (fitness * d2.len() as f64).round() as usize,
            source_points: d2.len(),
            max_distance,
            source_left_out,
            target_left_out,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 20 × 20 grid on the plane z = 0, spacing 0.1, far from the origin (UTM-like).
    fn grid() -> Vec<Point3<f64>> {
        (0..400)
            .map(|i| {
                Point3::new(
                    5e5 + (i % 20) as f64 * 0.1,
                    4e6 + (i / 20) as f64 * 0.1,
                    0.0,
                )
            })
            .collect()
    }

    #[test]
    fn counts_the_source_points_within_the_distance_and_their_rms() {
        let target = grid();
        // Half the source 3 cm above the target's points, half 50 cm above.
        let source: Vec<Point3<f64>> = target
            .iter()
            .enumerate()
            .map(|(i, p)| p + nalgebra::Vector3::z() * if i % 2 == 0 { 0.03 } else { 0.5 })
            .collect();
        let e = evaluate_registration(&source, &target, &Matrix4::identity(), 0.05).unwrap();
        assert_eq!((e.fitness, e.inliers, e.max_distance), (0.5, 200, 0.05));
        assert!((e.inlier_rmse - 0.03).abs() < 1e-4, "{}", e.inlier_rmse);
        // Moved down by 3 cm, the near half lies on the target: its RMS is 0 up to f32.
        let down = Matrix4::new_translation(&nalgebra::Vector3::new(0.0, 0.0, -0.03));
        let e = evaluate_registration(&source, &target, &down, 0.05).unwrap();
        assert_eq!(e.inliers, 200);
        assert!(e.inlier_rmse < 1e-4, "{}", e.inlier_rmse);
        // At 0.6 every point is an inlier; at 0.01 none is, and the RMS is 0.
        let all = evaluate_registration(&source, &target, &Matrix4::identity(), 0.6).unwrap();
        assert_eq!((all.fitness, all.inliers), (1.0, 400));
        let none = evaluate_registration(&source, &target, &Matrix4::identity(), 0.01).unwrap();
        assert_eq!(
            (none.fitness, none.inliers, none.inlier_rmse),
            (0.0, 0, 0.0)
        );
    }

    #[test]
    fn a_similarity_scales_the_source_and_missing_returns_are_left_out() {
        let target = grid();
        let half: Vec<Point3<f64>> = target
            .iter()
            .map(|p| Point3::from(p.coords * 0.5))
            .chain([Point3::origin(); 3])
            .collect();
        let twice = Matrix4::new_scaling(2.0);
        let e = evaluate_registration(&half, &target, &twice, 0.01).unwrap();
        assert_eq!((e.fitness, e.inliers, e.source_points), (1.0, 400, 400));
        assert_eq!(e.source_left_out.missing_returns, 3);
        assert_eq!(e.target_left_out, LeftOut::default());
    }

    #[test]
    fn bad_distances_and_transformations_are_refused() {
        let target = grid();
        for d in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let e = evaluate_registration(&target, &target, &Matrix4::identity(), d);
            assert!(
                matches!(
                    e,
                    Err(Error::InvalidSetting {
                        name: "max_distance",
                        ..
                    })
                ),
                "{d}: {e:?}"
            );
        }
        let mut shear = Matrix4::identity();
        shear[(0, 1)] = 0.5;
        let mut nan = Matrix4::identity();
        nan[(2, 3)] = f64::NAN;
        let mut row = Matrix4::identity();
        row[(3, 0)] = 1.0;
        for m in [shear, nan, row, Matrix4::zeros(), -Matrix4::identity()] {
            let e = evaluate_registration(&target, &target, &m, 0.1);
            assert!(matches!(e, Err(Error::InvalidTransformation)), "{m}: {e:?}");
        }
        let e = evaluate_registration(&target[..5], &target, &Matrix4::identity(), 0.1);
        assert!(
            matches!(
                e,
                Err(Error::TooFewPoints {
                    role: Role::Source,
                    ..
                })
            ),
            "{e:?}"
        );
    }
}

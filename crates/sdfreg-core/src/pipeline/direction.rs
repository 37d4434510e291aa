//! Stage 0 of a full call: which cloud Φ represents.
//!
//! Φ is fitted to the target, and the fitness, the polish's planes and the shift search all
//! measure the source against the target's points. A target far sparser than the source is the
//! weak side of every one of them: 2 % of a simulated street scan (≈ 1 100 points, 0.35 m
//! apart) as the target of the dense other scan (55 000 points) ended 1.5–2.1 m along the street
//! in 3 of 6 random draws, even from the true pose — the dense source's shifted rings lay as near
//! the sparse target's points and planes as the true pose's — while the same clouds the other
//! way round (the sparse scan onto the dense one) landed within 3.4 mm in all six. So when the
//! source has [`RegisterSettings::swap_ratio`] times the target's points or more, and is no
//! smaller than [`SWAP_MIN_EXTENT`] of the target (a scan onto a map of a larger area keeps its
//! direction), [`crate::register()`] registers the target onto the source and returns the
//! inverse ([`invert`]): `t_target_source` still maps the source into the target.

use nalgebra::Point3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::base::error::Error;
use crate::geometry::cloud::{bounding_box, subsample, transformed_f32, Normalization};
use crate::geometry::se3::adjoint;
use crate::geometry::tree::build_tree;
use crate::pipeline::registration::Registration;
use crate::pipeline::settings::RegisterSettings;
use crate::solve::degeneracy::FreeMotion;
use crate::solve::measure::inlier_stats;

/// The source is registered the other way round only when its bounding box's largest side is
/// at least this fraction of the target's: a small scan onto a map of a larger area keeps its
/// direction however many points the scan has.
pub const SWAP_MIN_EXTENT: f64 = 0.5;

/// Whether a full call on `source` and `target` (usable points, user frame) registers the
/// target onto the source ([`RegisterSettings::swap_ratio`], [`SWAP_MIN_EXTENT`]). Never with a
/// scale, whose settings bound the source-to-target scale.
pub(crate) fn swaps(s: &RegisterSettings, source: &[Point3<f64>], target: &[Point3<f64>]) -> bool {
    if s.swap_ratio == 0.0 || s.scale.enabled {
        return false;
    }
    if (source.len() as f64) < s.swap_ratio * target.len() as f64 {
        return false;
    }
    let side =
        |points: &[Point3<f64>]| bounding_box(points).map_or(0.0, |(lo, hi)| (hi - lo).max());
    side(source) >= SWAP_MIN_EXTENT * side(target)
}

/// The result `back` of registering `target` onto `source` turned into the result of
/// registering `source` onto `target`:
/// - `t_target_source` is the inverse of `back`'s;
/// - fitness and inlier RMSE are measured anew, as without the swap: the source's subsample
///   (drawn as a full call draws it, from [`RegisterSettings::seed`]) against the target's
///   points, the inlier distance a fraction of the target's extent;
/// - the information matrix is `back`'s carried over by the adjoint of its pose (the same
///   residuals, seen as a left perturbation of the inverse pose about the target origin), and
///   the free motions' axes and points mapped into the target frame;
/// - the cost and every stage's report are those of the run made (Φ of the source at the
///   target's points), with [`crate::Stages::swapped`] set.
pub(crate) fn invert(
    back: Registration,
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    s: &RegisterSettings,
) -> Result<Registration, Error> {
    let start = std::time::Instant::now();
    let t_source_target = back.t_target_source;
    let pose = t_source_target.inverse();
    let norm = Normalization::from_target(target)?;
    let mut rng = ChaCha8Rng::seed_from_u64(s.seed);
    let source = subsample(source, s.max_source_points, &mut rng);
    let target = subsample(target, s.max_target_points, &mut rng);
    let tree = build_tree(&target.iter().map(|p| norm.to_unit(p)).collect::<Vec<_>>());
    let unit: Vec<Point3<f64>> = source.iter().map(|p| norm.to_unit_f64(p)).collect();
    let moved = transformed_f32(&unit, &norm.pose_to_unit(&pose));
    let (fitness, rms) = inlier_stats(&tree, &moved, s.inlier_distance.powi(2));
    // The swapped run's left perturbation of `t_source_target` is ours by −Ad ξ.
    let adjoint = adjoint(&t_source_target);
    let mut degeneracy = back.degeneracy;
    degeneracy.free = degeneracy
        .free
        .into_iter()
        .map(|m| FreeMotion {
            axis: pose.rotation * m.axis,
            point: pose * m.point,
            ..m
        })
        .collect();
    let mut stages = back.stages;
    stages.swapped = true;
    let mut stage_times = back.stage_times;
    stage_times.measure += start.elapsed();
    Ok(Registration {
        t_target_source: pose,
        fitness,
        inlier_rmse: rms * norm.scale,
        inlier_distance: s.inlier_distance * norm.scale,
        information: adjoint.transpose() * back.information * adjoint,
        degeneracy,
        stages,
        stage_times,
        ..back
    })
}

//! Point clouds and the normalisation into the unit frame the network works in.
//!
//! The MLP is fitted in a *unit frame*: the target's bounding-box centre at the origin and its
//! largest side scaled to 1. All learning rates, query spreads and tolerances in the settings
//! that say "normalised units" refer to that frame; results are mapped back to the user's.

use nalgebra::{Isometry3, Point3, Translation3, Vector3};
use rand::seq::index::sample;
use rand_chacha::ChaCha8Rng;

use crate::base::error::{Error, Role};

/// Axis-aligned bounding box of `points` as `(min, max)`; `None` when empty.
pub fn bounding_box(points: &[Point3<f64>]) -> Option<(Point3<f64>, Point3<f64>)> {
    let first = points.first()?;
    let (mut lo, mut hi) = (*first, *first);
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    Some((lo, hi))
}

/// Mean of `points` (the origin when empty).
pub fn centroid(points: &[Point3<f64>]) -> Point3<f64> {
    let sum: Vector3<f64> = points.iter().map(|p| p.coords).sum();
    Point3::from(sum / points.len().max(1) as f64)
}

/// `points` moved by `pose`, as f32 (the network's precision; unit-frame inputs).
pub fn transformed_f32(points: &[Point3<f64>], pose: &Isometry3<f64>) -> Vec<[f32; 3]> {
    points
        .iter()
        .map(|p| {
            let x = pose * p;
            [x.x as f32, x.y as f32, x.z as f32]
        })
        .collect()
}

/// `points` scaled by `scale` about the origin, then moved by `pose` (`x = pose · (scale p)`, a
/// similarity), as f32.
pub fn scaled_f32(points: &[Point3<f64>], scale: f64, pose: &Isometry3<f64>) -> Vec<[f32; 3]> {
    points
        .iter()
        .map(|p| {
            let x = pose * Point3::from(p.coords * scale);
            [x.x as f32, x.y as f32, x.z as f32]
        })
        .collect()
}

/// At most `max` of `points`, drawn without replacement by `rng` and kept in their order; all of
/// them when there are no more.
pub(crate) fn subsample(
    points: &[Point3<f64>],
    max: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<Point3<f64>> {
    if points.len() <= max {
        return points.to_vec();
    }
    let mut idx = sample(rng, points.len(), max).into_vec();
    idx.sort_unstable();
    idx.into_iter().map(|i| points[i]).collect()
}

/// How many of `points` are scanner missing returns: points at exactly (0, 0, 0), counted only
/// when there are at least two of them (one point at the origin can be a real vertex; many
/// identical ones are how spinning LiDARs and range cameras write the beams that returned
/// nothing, 7 % of each scan of the outdoor pair in `../shared/data/lidar`). Left in, they pile
/// up in both clouds at the sensor's origin and hold a registration at the identity.
pub fn missing_returns(points: &[Point3<f64>]) -> usize {
    missing_returns_of(
        points
            .iter()
            .filter(|p| p.coords == Vector3::zeros())
            .count(),
    )
}

/// Of `at_origin` points at exactly (0, 0, 0), how many are [`missing_returns`]: all of them
/// when there are at least two, else none.
pub fn missing_returns_of(at_origin: usize) -> usize {
    if at_origin >= 2 {
        at_origin
    } else {
        0
    }
}

/// `points` without their [`missing_returns`] (borrowed when there are none).
pub fn without_missing_returns(points: &[Point3<f64>]) -> std::borrow::Cow<'_, [Point3<f64>]> {
    if missing_returns(points) == 0 {
        std::borrow::Cow::Borrowed(points)
    } else {
        std::borrow::Cow::Owned(
            points
                .iter()
                .filter(|p| p.coords != Vector3::zeros())
                .copied()
                .collect(),
        )
    }
}

/// A point is stray when it lies more than this many times as far from the cloud's middle
/// (its coordinate-wise median) as 99 % of the points do. The unit frame is the target's
/// bounding box: one return far off an object shrinks the object to a speck in it, and the
/// registration ends off at a fitness of 1 (every point an inlier at that scale). Measured on a
/// 2 × 1.2 × 0.8 ellipsoid of 800 points (99 % within about 1 of its middle) and its moved half:
/// with one more target point 10, 20 or 30 from the middle it registers within 10⁻⁶, at 50 and
/// 100 0.3° and 0.4° off, at 1000 and beyond anywhere. Real scans stay far below the factor:
/// the farthest return of the outdoor LiDAR pair in `../shared/data/lidar` lies 2.9 times as
/// far out as the 99th percentile, of the KITTI frames 1.4 times, of the 3DMatch fragments,
/// Stanford scans and ModelNet shapes there at most 1.3 times.
pub const STRAY_FACTOR: f64 = 30.0;

/// The indices of `points`' stray points ([`STRAY_FACTOR`]), in order; none when 99 % of the
/// points coincide with the middle (a cloud without extent, refused elsewhere). The middle and
/// the 99th percentile come from every `⌈n / 4096⌉`-th point (a LiDAR scan's 100,000 points
/// cost one pass over them, not four sorts).
pub fn stray_points(points: &[Point3<f64>]) -> Vec<usize> {
    if points.len() < 2 {
        return Vec::new();
    }
    let sample: Vec<&Point3<f64>> = points.iter().step_by(points.len().div_ceil(4096)).collect();
    let mut v = vec![0.0; sample.len()];
    let mut median = |axis: usize| {
        v.iter_mut().zip(&sample).for_each(|(v, p)| *v = p[axis]);
        let mid = v.len() / 2;
        *v.select_nth_unstable_by(mid, f64::total_cmp).1
    };
    let middle = Point3::new(median(0), median(1), median(2));
    let mut squared: Vec<f64> = sample
        .iter()
        .map(|p| (*p - middle).norm_squared())
        .collect();
    let k = ((squared.len() - 1) as f64 * 0.99).floor() as usize;
    let reach = *squared.select_nth_unstable_by(k, f64::total_cmp).1;
    if reach <= 0.0 {
        return Vec::new();
    }
    let beyond = STRAY_FACTOR * STRAY_FACTOR * reach;
    (0..points.len())
        .filter(|&i| (points[i] - middle).norm_squared() > beyond)
        .collect()
}

/// How many points of one cloud a registration or a fit left out before using it: its
/// [`missing_returns`] and, of the rest, its [`stray_points`]. Reported on each result
/// ([`crate::Registration::source_left_out`]) so that a caller can tell its users.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct LeftOut {
    /// Points at exactly (0, 0, 0) ([`missing_returns`]; 0 when fewer than two).
    pub missing_returns: usize,
    /// Of the other points, those more than [`STRAY_FACTOR`] times as far from the cloud's
    /// middle as 99 % of them ([`stray_points`]).
    pub stray: usize,
}

impl LeftOut {
    /// What a registration or a fit leaves out of `points` (one pass for the missing returns,
    /// one over a sample and one over the rest for the strays).
    pub fn of(points: &[Point3<f64>]) -> Self {
        let kept = without_missing_returns(points);
        Self {
            missing_returns: points.len() - kept.len(),
            stray: stray_points(&kept).len(),
        }
    }

    /// Whether nothing was left out.
    pub fn is_empty(&self) -> bool {
        self.missing_returns == 0 && self.stray == 0
    }

    /// One sentence per kind of point left out of a cloud of `total` points (none when nothing
    /// was), as the CLI prints them after the file's name and Python warns them after the
    /// argument's: "5 of 800 points are at exactly (0, 0, 0), a scanner's missing returns:
    /// left out".
    pub fn messages(&self, total: usize) -> Vec<String> {
        let mut messages = Vec::new();
        if self.missing_returns > 0 {
            messages.push(format!(
                "{} of {total} points are at exactly (0, 0, 0), a scanner's missing returns: \
                 left out",
                self.missing_returns
            ));
        }
        if self.stray > 0 {
            messages.push(format!(
                "{} of {total} points lie more than {STRAY_FACTOR} times as far from the \
                 cloud's middle as 99 % of them, stray returns: left out",
                self.stray
            ));
        }
        messages
    }
}

/// The points [`usable`] keeps (borrowed when it leaves none out) and how many it left out.
pub(crate) type Usable<'a> = (std::borrow::Cow<'a, [Point3<f64>]>, LeftOut);

/// `points` checked ([`validate`]: indices in errors are the caller's) and without their
/// [`missing_returns`], which must leave at least `min`, and their [`stray_points`]; with how
/// many of each were left out.
pub(crate) fn usable(points: &[Point3<f64>], role: Role, min: usize) -> Result<Usable<'_>, Error> {
    validate(points, role, min)?;
    let kept = without_missing_returns(points);
    let mut left_out = LeftOut {
        missing_returns: points.len() - kept.len(),
        stray: 0,
    };
    if kept.len() < min {
        return Err(Error::TooFewBesidesMissingReturns {
            role,
            found: kept.len(),
            missing: points.len() - kept.len(),
            min,
        });
    }
    let stray = stray_points(&kept);
    if stray.is_empty() {
        return Ok((kept, left_out));
    }
    left_out.stray = stray.len();
    let mut stray = stray.into_iter().peekable();
    let near: Vec<Point3<f64>> = kept
        .iter()
        .enumerate()
        .filter(|&(i, _)| stray.next_if_eq(&i).is_none())
        .map(|(_, p)| *p)
        .collect();
    if near.len() < min {
        return Err(Error::TooFewPoints {
            role,
            found: near.len(),
            min,
        });
    }
    Ok((std::borrow::Cow::Owned(near), left_out))
}

/// Checks that every coordinate is finite and that there are at least `min` points.
pub fn validate(points: &[Point3<f64>], role: Role, min: usize) -> Result<(), Error> {
    if let Some(index) = points
        .iter()
        .position(|p| !p.coords.iter().all(|v| v.is_finite()))
    {
        let p = points[index];
        return Err(Error::NonFinite {
            role,
            index,
            point: [p.x, p.y, p.z],
        });
    }
    if points.len() < min {
        return Err(Error::TooFewPoints {
            role,
            found: points.len(),
            min,
        });
    }
    Ok(())
}

/// The similarity `x ↦ (x − centre) / scale` from the user's frame to the unit frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Normalization {
    /// Bounding-box centre of the target, user units.
    pub centre: Vector3<f64>,
    /// Largest bounding-box side of the target, user units.
    pub scale: f64,
}

/// The bounding-box centre and largest side of `points` (the `role` cloud); an
/// [`Error::NoExtent`] when that side is not above 10⁻⁹ of the coordinates' magnitude (a cloud
/// 1e-9 wide at 1e6 is a single point), [`Error::TooFewPoints`] when there are none.
pub(crate) fn centre_and_extent(
    points: &[Point3<f64>],
    role: Role,
) -> Result<(Vector3<f64>, f64), Error> {
    let (lo, hi) = bounding_box(points).ok_or(Error::TooFewPoints {
        role,
        found: 0,
        min: 1,
    })?;
    let extent = (hi - lo).max();
    let centre = (lo.coords + hi.coords) * 0.5;
    if extent.is_nan() || extent <= 1e-9 * (1.0 + centre.amax()) {
        return Err(Error::NoExtent { role, extent });
    }
    Ok((centre, extent))
}

impl Normalization {
    /// The normalisation defined by the target cloud.
    pub fn from_target(target: &[Point3<f64>]) -> Result<Self, Error> {
        let (centre, scale) = centre_and_extent(target, Role::Target)?;
        Ok(Self { centre, scale })
    }

    /// A point in the unit frame, as f32 (computed in f64 first, so large offsets are harmless).
    pub fn to_unit(&self, p: &Point3<f64>) -> [f32; 3] {
        let q = (p.coords - self.centre) / self.scale;
        [q.x as f32, q.y as f32, q.z as f32]
    }

    /// A point in the unit frame, as f64.
    pub fn to_unit_f64(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from((p.coords - self.centre) / self.scale)
    }

    /// A unit-frame point back in the user's frame: `x · scale + centre`.
    pub fn to_user(&self, x: &Vector3<f64>) -> Point3<f64> {
        Point3::from(x * self.scale + self.centre)
    }

    /// A rigid transform between user frames expressed between unit frames: `N T N⁻¹`.
    pub fn pose_to_unit(&self, t: &Isometry3<f64>) -> Isometry3<f64> {
        let r = t.rotation;
        let tr = (t.translation.vector + r * self.centre - self.centre) / self.scale;
        Isometry3::from_parts(Translation3::from(tr), r)
    }

    /// Inverse of [`Normalization::pose_to_unit`]: `N⁻¹ T N`.
    pub fn pose_from_unit(&self, t: &Isometry3<f64>) -> Isometry3<f64> {
        let r = t.rotation;
        let tr = t.translation.vector * self.scale + self.centre - r * self.centre;
        Isometry3::from_parts(Translation3::from(tr), r)
    }

    /// A similarity `x = s R p + t` between unit frames (`t` the isometry's translation) in
    /// the user's frames: the same `R` and `s`, the translation returned. `N⁻¹ S N`.
    pub fn similarity_from_unit(&self, t: &Isometry3<f64>, s: f64) -> Isometry3<f64> {
        let r = t.rotation;
        let tr = t.translation.vector * self.scale + self.centre - r * self.centre * s;
        Isometry3::from_parts(Translation3::from(tr), r)
    }

    /// Inverse of [`Normalization::similarity_from_unit`]: `N S N⁻¹`.
    pub fn similarity_to_unit(&self, t: &Isometry3<f64>, s: f64) -> Isometry3<f64> {
        let r = t.rotation;
        let tr = (t.translation.vector + r * self.centre * s - self.centre) / self.scale;
        Isometry3::from_parts(Translation3::from(tr), r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    #[test]
    fn a_point_thirty_times_as_far_out_as_the_rest_is_stray_and_left_out() {
        // A 2 × 1 × 0.5 grid of 1000 points (99 % within about 1 of its middle), a return 180
        // from it and one 24 from it on the other side: the first is stray.
        let mut points: Vec<Point3<f64>> = (0..1000)
            .map(|i| {
                let (a, b, c) = (i % 10, (i / 10) % 10, i / 100);
                Point3::new(a as f64 * 0.2, b as f64 * 0.1, c as f64 * 0.05)
            })
            .collect();
        assert!(stray_points(&points).is_empty());
        points.insert(17, Point3::new(1.0, 0.5, 150.0 * 1.2));
        points.push(Point3::new(-20.0 * 1.2, 0.5, 0.25));
        assert_eq!(stray_points(&points), vec![17]);
        let (kept, left_out) = usable(&points, Role::Target, 10).unwrap();
        assert_eq!(kept.len(), 1001);
        assert_eq!(left_out, LeftOut::of(&points));
        assert_eq!(
            left_out,
            LeftOut {
                missing_returns: 0,
                stray: 1
            }
        );
        assert!(!kept.iter().any(|p| p.z > 10.0));
        // Clouds without strays come back borrowed, unchanged.
        points.remove(17);
        assert!(matches!(
            usable(&points, Role::Target, 10).unwrap(),
            (
                std::borrow::Cow::Borrowed(_),
                LeftOut {
                    missing_returns: 0,
                    stray: 0
                }
            )
        ));
        // A cloud whose points nearly all coincide has no strays to tell (refused as without
        // extent later).
        let mut same = vec![Point3::new(1.0, 2.0, 3.0); 200];
        same.push(Point3::new(1e6, 0.0, 0.0));
        assert!(stray_points(&same).is_empty());
    }

    #[test]
    fn pose_round_trip_and_meaning() {
        let target = vec![
            Point3::new(1e6, 2e6, 3.0),
            Point3::new(1e6 + 4.0, 2e6 + 1.0, 5.0),
        ];
        let n = Normalization::from_target(&target).unwrap();
        assert_eq!(n.scale, 4.0);
        let t = Isometry3::from_parts(
            Translation3::new(0.3, -2.0, 1.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.2, 0.5, -0.1)),
        );
        let u = n.pose_to_unit(&t);
        let back = n.pose_from_unit(&u);
        assert!((back.to_homogeneous() - t.to_homogeneous()).norm() < 1e-6);
        // Mapping a point in unit frames equals mapping it in user frames.
        let p = Point3::new(1e6 + 1.0, 2e6 - 3.0, 7.0);
        let via_unit = n.to_unit_f64(&(t * p));
        let direct = u * n.to_unit_f64(&p);
        assert!((via_unit - direct).norm() < 1e-9);
    }

    #[test]
    fn similarity_round_trip_and_meaning() {
        let target = vec![Point3::new(10.0, -3.0, 2.0), Point3::new(14.0, 0.0, 5.0)];
        let n = Normalization::from_target(&target).unwrap();
        let t = Isometry3::from_parts(
            Translation3::new(0.3, -2.0, 1.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.2, 0.5, -0.1)),
        );
        let s = 1e-3;
        let u = n.similarity_to_unit(&t, s);
        let back = n.similarity_from_unit(&u, s);
        assert!((back.to_homogeneous() - t.to_homogeneous()).norm() < 1e-12);
        // x = s R p + t in user frames equals u (s p) in unit frames (the source in the
        // target's unit frame, as the registration puts it).
        let p = Point3::new(1234.0, -567.0, 89.0);
        let user = t * Point3::from(p.coords * s);
        let unit = u * Point3::from(n.to_unit_f64(&p).coords * s);
        assert!((n.to_unit_f64(&user) - unit).norm() < 1e-9);
    }

    #[test]
    fn rejects_single_point_and_non_finite() {
        let same = vec![Point3::new(1.0, 1.0, 1.0); 10];
        assert!(matches!(
            Normalization::from_target(&same),
            Err(Error::NoExtent { .. })
        ));
        let bad = vec![Point3::new(0.0, 0.0, 0.0), Point3::new(f64::NAN, 0.0, 0.0)];
        assert!(matches!(
            validate(&bad, Role::Source, 1),
            Err(Error::NonFinite { index: 1, .. })
        ));
        assert!(matches!(
            validate(&same, Role::Source, 20),
            Err(Error::TooFewPoints {
                found: 10,
                min: 20,
                ..
            })
        ));
    }
}

//! The ModelNet40 evaluation protocol of the paper (Sec. 4.1–4.4, after PointNetLK and FMR), and
//! the error measures used to score a registration.
//!
//! A shape is centred on its bounding box and scaled so the box's largest side is 1. A pair is
//! made by moving a sample of it by a random rigid motion (Euler angles `U[0°, 45°]` per axis,
//! `R = Rx·Ry·Rz`, translation `U[−0.5, 0.5]` per axis); the ground truth
//! `t_target_source` is the inverse of that motion.
//! - `Clean`: 1024 points; the source is the moved target sample.
//! - `Noise`: as clean, then `N(0, 0.02²)` added to every target coordinate.
//! - `Partial`: as clean, then the source is cut by a random plane keeping 70 % of its points.
//! - `Density`: 10,000 target points; the source is the moved 10,000-point sample with 95 % of
//!   its points removed at random.

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::seq::index::sample;
use rand::Rng;
use rand_distr::{Distribution, Normal, StandardNormal};

use crate::cloud::bounding_box;
use crate::se3::rotation_angle;

/// A perturbation protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Protocol {
    /// Exact copy, moved.
    Clean,
    /// Gaussian noise σ = 0.02 on the target.
    Noise,
    /// Source cut to 70 % by a random plane.
    Partial,
    /// 10,000 target points against 5 % of a 10,000-point source.
    Density,
}

impl Protocol {
    /// All four, in the paper's order.
    pub const ALL: [Protocol; 4] = [
        Protocol::Clean,
        Protocol::Noise,
        Protocol::Partial,
        Protocol::Density,
    ];

    /// Lower-case name.
    pub fn name(&self) -> &'static str {
        match self {
            Protocol::Clean => "clean",
            Protocol::Noise => "noise",
            Protocol::Partial => "partial",
            Protocol::Density => "density",
        }
    }
}

impl std::str::FromStr for Protocol {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Protocol::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| {
                format!("unknown protocol {s:?} (expected clean, noise, partial or density)")
            })
    }
}

/// A source/target pair with its ground truth.
#[derive(Clone, Debug)]
pub struct Pair {
    /// The cloud to move.
    pub source: Vec<Point3<f64>>,
    /// The fixed cloud.
    pub target: Vec<Point3<f64>>,
    /// Ground truth mapping source into target.
    pub t_target_source: Isometry3<f64>,
}

/// Centres `points` on their bounding box and scales the largest side to 1.
pub fn normalize_unit_box(points: &[Point3<f64>]) -> Vec<Point3<f64>> {
    let Some((lo, hi)) = bounding_box(points) else {
        return Vec::new();
    };
    let c = (lo.coords + hi.coords) * 0.5;
    let s = (hi - lo).max().max(f64::MIN_POSITIVE);
    points
        .iter()
        .map(|p| Point3::from((p.coords - c) / s))
        .collect()
}

/// A random motion of the protocol: Euler angles `U[0, max_deg]` per axis (`R = Rx·Ry·Rz`) and
/// translation `U[−max_t, max_t]` per axis.
pub fn random_motion<R: Rng>(rng: &mut R, max_deg: f64, max_t: f64) -> Isometry3<f64> {
    let a: [f64; 3] = [0, 1, 2].map(|_| rng.random_range(0.0..=max_deg).to_radians());
    let r = Rotation3::from_axis_angle(&Vector3::x_axis(), a[0])
        * Rotation3::from_axis_angle(&Vector3::y_axis(), a[1])
        * Rotation3::from_axis_angle(&Vector3::z_axis(), a[2]);
    let t = Vector3::new(
        rng.random_range(-max_t..=max_t),
        rng.random_range(-max_t..=max_t),
        rng.random_range(-max_t..=max_t),
    );
    Isometry3::from_parts(
        Translation3::from(t),
        UnitQuaternion::from_rotation_matrix(&r),
    )
}

fn pick(points: &[Point3<f64>], n: usize, rng: &mut impl Rng) -> Vec<Point3<f64>> {
    if points.len() <= n {
        return points.to_vec();
    }
    sample(rng, points.len(), n)
        .into_iter()
        .map(|i| points[i])
        .collect()
}

/// Makes one pair of `protocol` from `shape` (any frame; it is normalised first).
pub fn make_pair<R: Rng>(shape: &[Point3<f64>], protocol: Protocol, rng: &mut R) -> Pair {
    let shape = normalize_unit_box(shape);
    let motion = random_motion(rng, 45.0, 0.5);
    let n = if protocol == Protocol::Density {
        10_000
    } else {
        1024
    };
    let mut target = pick(&shape, n, rng);
    let mut source: Vec<Point3<f64>> = target.iter().map(|p| motion * p).collect();
    match protocol {
        Protocol::Clean => {}
        Protocol::Noise => {
            let noise = Normal::new(0.0, 0.02).unwrap();
            for p in &mut target {
                for k in 0..3 {
                    p[k] += noise.sample(rng);
                }
            }
        }
        Protocol::Partial => {
            // A random plane through the source's centre, moved along its normal so 70 % remain.
            let normal = Vector3::<f64>::new(
                StandardNormal.sample(rng),
                StandardNormal.sample(rng),
                StandardNormal.sample(rng),
            )
            .normalize();
            let c = crate::cloud::centroid(&source);
            let mut order: Vec<(f64, usize)> = source
                .iter()
                .enumerate()
                .map(|(i, p)| ((p - c).dot(&normal), i))
                .collect();
            order.sort_by(|a, b| b.0.total_cmp(&a.0));
            let keep = (source.len() as f64 * 0.7).round() as usize;
            let mut idx: Vec<usize> = order[..keep].iter().map(|o| o.1).collect();
            idx.sort_unstable();
            source = idx.into_iter().map(|i| source[i]).collect();
        }
        Protocol::Density => {
            source = pick(&source, source.len() / 20, rng);
        }
    }
    Pair {
        source,
        target,
        t_target_source: motion.inverse(),
    }
}

/// Rotation error (geodesic, degrees) and translation error (Euclidean, units) of `estimate`
/// against `truth`.
pub fn pose_errors(estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> (f64, f64) {
    let r = rotation_angle(
        &estimate.rotation.to_rotation_matrix(),
        &truth.rotation.to_rotation_matrix(),
    )
    .to_degrees();
    let t = (estimate.translation.vector - truth.translation.vector).norm();
    (r, t)
}

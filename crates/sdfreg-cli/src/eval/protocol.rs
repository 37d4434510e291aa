//! The ModelNet40 evaluation protocols of the paper (Sec. 4.1–4.4, after PointNetLK and FMR),
//! variants closer to real scans, and the error measures used to score a registration.
//!
//! A shape is centred on its bounding box and scaled so the box's largest side is 1. A pair is
//! made by moving a sample of it by a random rigid motion (Euler angles `U[0°, 45°]` per axis,
//! `R = Rx·Ry·Rz`, translation `U[−0.5, 0.5]` per axis); the ground truth
//! `t_target_source` is the inverse of that motion. [`Perturbation`]s:
//! - `Clean`: 1024 points; the source is the moved target sample.
//! - `Noise`: as clean, then `N(0, 0.02²)` added to every target coordinate.
//! - `Partial`: as clean, then the source is cut by a random plane keeping 70 % of its points.
//! - `Density`: 10,000 target points; the source is the moved 10,000-point sample with 95 % of
//!   its points removed at random.
//! - `AnyRot`: as clean, with the rotation drawn uniformly over SO(3) (not in the paper).
//! - `Scaled`: as clean, then the source scaled by `σ ~ U[0.5, 2]` about the origin (not in the
//!   paper); the truth is a similarity of scale `1/σ`, registered with a scale estimated.
//!
//! A [`Protocol`] is a perturbation plus the sampling: the paper's (the source is the target's
//! own sample, moved, so every source point has an exact counterpart) or independent (source and
//! target are disjoint samples of the shape, as two scans of one object would be).
//!
//! Error measures: [`sdfreg_core::geometry::se3::pose_errors`] (geodesic rotation angle, translation
//! distance, in the core for every user) and
//! [`euler_errors`] (per-axis Euler-angle differences, the DCP-style measure of the paper's
//! tables).

use nalgebra::{Isometry3, Point3, Quaternion, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::seq::index::sample;
use rand::Rng;
use rand_distr::{Distribution, Normal, StandardNormal};

use sdfreg_core::geometry::cloud::{bounding_box, centroid};

/// How a pair's clouds are perturbed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Perturbation {
    /// Exact copy, moved.
    Clean,
    /// Gaussian noise σ = 0.02 on the target.
    Noise,
    /// Source cut to 70 % by a random plane.
    Partial,
    /// 10,000 target points against 5 % of a 10,000-point source.
    Density,
    /// As clean, with a rotation drawn uniformly over SO(3).
    AnyRot,
    /// As clean, the source scaled by σ ~ U[0.5, 2] (a similarity).
    Scaled,
}

impl Perturbation {
    /// Lower-case name.
    pub fn name(&self) -> &'static str {
        match self {
            Perturbation::Clean => "clean",
            Perturbation::Noise => "noise",
            Perturbation::Partial => "partial",
            Perturbation::Density => "density",
            Perturbation::AnyRot => "anyrot",
            Perturbation::Scaled => "scaled",
        }
    }
}

/// A pair-making protocol: a perturbation and whether source and target are sampled
/// independently (disjoint samples) or the source is the target's own sample (the paper).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Protocol {
    /// The perturbation.
    pub perturbation: Perturbation,
    /// Source and target are disjoint samples of the shape.
    pub independent: bool,
}

impl Protocol {
    const fn paper(perturbation: Perturbation) -> Self {
        Protocol {
            perturbation,
            independent: false,
        }
    }

    const fn independent(perturbation: Perturbation) -> Self {
        Protocol {
            perturbation,
            independent: true,
        }
    }

    /// The paper's four: clean, noise, partial, density.
    pub const PAPER: [Protocol; 4] = [
        Protocol::paper(Perturbation::Clean),
        Protocol::paper(Perturbation::Noise),
        Protocol::paper(Perturbation::Partial),
        Protocol::paper(Perturbation::Density),
    ];

    /// Every protocol, in a fixed order (evaluation seeds depend on the position): the paper's
    /// four, `anyrot`, then the paper's four with independent sampling.
    pub const ALL: [Protocol; 9] = [
        Protocol::paper(Perturbation::Clean),
        Protocol::paper(Perturbation::Noise),
        Protocol::paper(Perturbation::Partial),
        Protocol::paper(Perturbation::Density),
        Protocol::paper(Perturbation::AnyRot),
        Protocol::independent(Perturbation::Clean),
        Protocol::independent(Perturbation::Noise),
        Protocol::independent(Perturbation::Partial),
        Protocol::independent(Perturbation::Density),
    ];

    /// The similarity protocols (`scaled`, `scaled-indep`): registered with a scale estimated;
    /// not among [`Self::ALL`], whose pairs stay as they were.
    pub const SCALED: [Protocol; 2] = [
        Protocol::paper(Perturbation::Scaled),
        Protocol::independent(Perturbation::Scaled),
    ];

    /// Every protocol: [`Self::ALL`], then [`Self::SCALED`] (a pair's seed is its protocol's
    /// position here).
    pub fn every() -> impl Iterator<Item = Protocol> {
        Protocol::ALL.into_iter().chain(Protocol::SCALED)
    }

    /// Whether the pair's truth is a similarity (registered with a scale).
    pub fn scaled(&self) -> bool {
        self.perturbation == Perturbation::Scaled
    }

    /// The name: the perturbation's, with `-indep` for independent sampling.
    pub fn name(&self) -> String {
        let suffix = if self.independent { "-indep" } else { "" };
        format!("{}{suffix}", self.perturbation.name())
    }
}

impl std::fmt::Display for Protocol {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.name())
    }
}

impl std::str::FromStr for Protocol {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Protocol::every().find(|p| p.name() == s).ok_or_else(|| {
            let names: Vec<String> = Protocol::every().map(|p| p.name()).collect();
            format!(
                "unknown protocol {s:?} (expected one of {})",
                names.join(", ")
            )
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
    /// Ground truth mapping source into target (the rigid part of a similarity).
    pub t_target_source: Isometry3<f64>,
    /// The truth's scale, target units per source unit (`p_target = s R p_source + t`); 1 but
    /// for the scaled protocols.
    pub scale: f64,
}

impl Pair {
    /// The ground truth as a 4×4 `[s R | t]`.
    pub fn matrix(&self) -> nalgebra::Matrix4<f64> {
        let mut m = self.t_target_source.to_homogeneous();
        m.fixed_view_mut::<3, 3>(0, 0).scale_mut(self.scale);
        m
    }
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

/// A motion with the rotation drawn uniformly over SO(3) (a normalised 4-D Gaussian quaternion)
/// and the translation `U[−max_t, max_t]` per axis.
pub fn uniform_motion<R: Rng>(rng: &mut R, max_t: f64) -> Isometry3<f64> {
    let g: [f64; 4] = [0, 1, 2, 3].map(|_| StandardNormal.sample(rng));
    let q = UnitQuaternion::from_quaternion(Quaternion::new(g[0], g[1], g[2], g[3]));
    let t = Vector3::new(
        rng.random_range(-max_t..=max_t),
        rng.random_range(-max_t..=max_t),
        rng.random_range(-max_t..=max_t),
    );
    Isometry3::from_parts(Translation3::from(t), q)
}

/// Disjoint random samples of `points`: (`n_target`, `n_source`) points, fewer when the shape
/// has fewer than `n_target + n_source` (the target then gets what the source leaves).
fn disjoint(
    points: &[Point3<f64>],
    n_target: usize,
    n_source: usize,
    rng: &mut impl Rng,
) -> (Vec<Point3<f64>>, Vec<Point3<f64>>) {
    let n_source = n_source.min(points.len() / 2);
    let n_target = n_target.min(points.len() - n_source);
    let idx = sample(rng, points.len(), n_source + n_target).into_vec();
    let (s, t) = idx.split_at(n_source);
    (
        t.iter().map(|&i| points[i]).collect(),
        s.iter().map(|&i| points[i]).collect(),
    )
}

/// Makes one pair of `protocol` from `shape` (any frame; it is normalised first).
pub fn make_pair<R: Rng>(shape: &[Point3<f64>], protocol: Protocol, rng: &mut R) -> Pair {
    let shape = normalize_unit_box(shape);
    let motion = match protocol.perturbation {
        Perturbation::AnyRot => uniform_motion(rng, 0.5),
        _ => random_motion(rng, 45.0, 0.5),
    };
    let density = protocol.perturbation == Perturbation::Density;
    let n = if density { 10_000 } else { 1024 };
    let (mut target, source_sample) = if protocol.independent {
        // Density: the 5 % source first, the target from the rest (9,500 of a 10,000-point
        // shape), so that no source point lies on a target point.
        disjoint(&shape, n, if density { n / 20 } else { n }, rng)
    } else {
        let t = pick(&shape, n, rng);
        (t.clone(), t)
    };
    let mut source: Vec<Point3<f64>> = source_sample.iter().map(|p| motion * p).collect();
    let mut scale = 1.0;
    match protocol.perturbation {
        Perturbation::Clean | Perturbation::AnyRot => {}
        Perturbation::Scaled => {
            let sigma = rng.random_range(0.5..=2.0);
            for p in &mut source {
                p.coords *= sigma;
            }
            scale = 1.0 / sigma;
        }
        Perturbation::Noise => {
            let noise = Normal::new(0.0, 0.02).unwrap();
            for p in &mut target {
                for k in 0..3 {
                    p[k] += noise.sample(rng);
                }
            }
        }
        Perturbation::Partial => {
            // A random plane through the source's centre, moved along its normal so 70 % remain.
            let normal = Vector3::<f64>::new(
                StandardNormal.sample(rng),
                StandardNormal.sample(rng),
                StandardNormal.sample(rng),
            )
            .normalize();
            let c = centroid(&source);
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
        Perturbation::Density => {
            if !protocol.independent {
                source = pick(&source, source.len() / 20, rng);
            }
        }
    }
    Pair {
        source,
        target,
        t_target_source: motion.inverse(),
        scale,
    }
}

/// Euler angles (degrees) of `r = Rx(a)·Ry(b)·Rz(c)`, the protocol's convention: `[a, b, c]`.
pub fn euler_xyz_deg(r: &Rotation3<f64>) -> [f64; 3] {
    let m = r.matrix();
    let b = m[(0, 2)].clamp(-1.0, 1.0).asin();
    let a = (-m[(1, 2)]).atan2(m[(2, 2)]);
    let c = (-m[(0, 1)]).atan2(m[(0, 0)]);
    [a.to_degrees(), b.to_degrees(), c.to_degrees()]
}

/// Per-axis Euler-angle errors (degrees, each wrapped to `[−180°, 180°)`) of `estimate` against
/// `truth`, in the `Rx·Ry·Rz` convention: the measure behind the MAE/RMSE of the paper's tables
/// (after DCP). Unlike [`sdfreg_core::geometry::se3::pose_errors`] it depends on the convention and on the axes.
pub fn euler_errors(estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> [f64; 3] {
    let e = euler_xyz_deg(&estimate.rotation.to_rotation_matrix());
    let t = euler_xyz_deg(&truth.rotation.to_rotation_matrix());
    [0, 1, 2].map(|k| (e[k] - t[k] + 180.0).rem_euclid(360.0) - 180.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use sdfreg_core::geometry::se3::rotation_angle;

    fn sphere(n: usize) -> Vec<Point3<f64>> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        (0..n)
            .map(|_| {
                let v = Vector3::<f64>::new(
                    StandardNormal.sample(&mut rng),
                    StandardNormal.sample(&mut rng),
                    StandardNormal.sample(&mut rng),
                );
                Point3::from(v.normalize())
            })
            .collect()
    }

    #[test]
    fn euler_angles_round_trip_in_the_protocol_convention() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for _ in 0..100 {
            let m = random_motion(&mut rng, 45.0, 0.5);
            let [a, b, c] = euler_xyz_deg(&m.rotation.to_rotation_matrix());
            let r = Rotation3::from_axis_angle(&Vector3::x_axis(), a.to_radians())
                * Rotation3::from_axis_angle(&Vector3::y_axis(), b.to_radians())
                * Rotation3::from_axis_angle(&Vector3::z_axis(), c.to_radians());
            assert!(rotation_angle(&r, &m.rotation.to_rotation_matrix()) < 1e-12);
            assert!([a, b, c].iter().all(|v| (0.0..=45.0 + 1e-9).contains(v)));
            let e = euler_errors(&m, &m);
            assert!(e.iter().all(|v| v.abs() < 1e-9));
        }
    }

    #[test]
    fn sizes_and_sampling_of_every_protocol() {
        let shape = sphere(10_000);
        for (i, protocol) in Protocol::ALL.into_iter().enumerate() {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(i as u64);
            let pair = make_pair(&shape, protocol, &mut rng);
            let expected = match (protocol.perturbation, protocol.independent) {
                (Perturbation::Density, false) => (500, 10_000),
                (Perturbation::Density, true) => (500, 9_500),
                (Perturbation::Partial, _) => (717, 1024),
                _ => (1024, 1024),
            };
            assert_eq!(
                (pair.source.len(), pair.target.len()),
                expected,
                "{protocol}"
            );
            // Moved back, a source point lies on a target point only with shared sampling.
            let back: Vec<Point3<f64>> = pair
                .source
                .iter()
                .map(|p| pair.t_target_source * p)
                .collect();
            let on_target = back
                .iter()
                .filter(|p| pair.target.iter().any(|q| (*p - q).norm() < 1e-9))
                .count();
            match (protocol.perturbation, protocol.independent) {
                (_, true) | (Perturbation::Noise, false) => assert_eq!(on_target, 0, "{protocol}"),
                _ => assert_eq!(on_target, back.len(), "{protocol}"),
            }
            assert_eq!(protocol.name().parse::<Protocol>(), Ok(protocol));
        }
    }
}

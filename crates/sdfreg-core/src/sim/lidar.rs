//! A procedural LiDAR simulator for tests and benches (no data files): a spinning multi-beam
//! sensor ([`Sensor`]) ray-cast with parry3d into a procedural [`Scene`] — a street (ground,
//! building facades, poles, parked cars) or a room (floor, ceiling, walls, furniture). Each
//! beam returns its first hit, so every scan has the occlusions of its own viewpoint; ranges get
//! Gaussian noise along the beam.
//!
//! Units are metres; the world frame has z up. A sensor pose maps sensor coordinates into the
//! world (`p_world = pose · p_sensor`), and [`scan`] returns points in the sensor frame, as a
//! real LiDAR does: for scans `a` and `b` taken at poses `A` and `B`, the transform that moves
//! scan `b` onto scan `a` (`t_target_source` with `b` the source) is `A⁻¹ · B`.

use nalgebra::{Isometry3, Point3, Vector3};
use parry3d::math::{Pose, Vector};
use parry3d::query::{PointQuery, Ray, RayCast};
use parry3d::shape::{Compound, SharedShape};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

/// A spinning multi-beam LiDAR: `rings` beams spread evenly over the elevation range, turning
/// about the sensor's z axis in steps of `azimuth_step_deg`.
#[derive(Clone, Debug, PartialEq)]
pub struct Sensor {
    /// Beams (rings).
    pub rings: usize,
    /// Elevation of the lowest and the highest beam, degrees (0 = horizontal).
    pub elevation_deg: (f64, f64),
    /// Azimuth step of a revolution, degrees.
    pub azimuth_step_deg: f64,
    /// Returns nearer than this are dropped, metres.
    pub min_range: f64,
    /// Beams that hit nothing within this range return nothing, metres.
    pub max_range: f64,
    /// Standard deviation of the range noise, metres.
    pub range_noise: f64,
}

impl Sensor {
    /// A 32-beam outdoor sensor: elevations −25° to +15°, 0.2° azimuth steps (1800 per
    /// revolution), 0.5–100 m, 2 cm range noise.
    pub fn spinning_32() -> Self {
        Sensor {
            rings: 32,
            elevation_deg: (-25.0, 15.0),
            azimuth_step_deg: 0.2,
            min_range: 0.5,
            max_range: 100.0,
            range_noise: 0.02,
        }
    }

    /// A 64-beam sensor: elevations −22.5° to +22.5°, 0.2° azimuth steps, 0.3–120 m, 1 cm
    /// range noise.
    pub fn spinning_64() -> Self {
        Sensor {
            rings: 64,
            elevation_deg: (-22.5, 22.5),
            azimuth_step_deg: 0.2,
            min_range: 0.3,
            max_range: 120.0,
            range_noise: 0.01,
        }
    }

    /// The unit direction of beam `ring` at azimuth step `step`, sensor frame.
    fn direction(&self, ring: usize, step: usize) -> Vector3<f64> {
        let (lo, hi) = self.elevation_deg;
        let t = if self.rings > 1 {
            ring as f64 / (self.rings - 1) as f64
        } else {
            0.5
        };
        let elevation = (lo + t * (hi - lo)).to_radians();
        let azimuth = (step as f64 * self.azimuth_step_deg).to_radians();
        Vector3::new(
            elevation.cos() * azimuth.cos(),
            elevation.cos() * azimuth.sin(),
            elevation.sin(),
        )
    }

    /// Azimuth steps in one revolution.
    fn steps(&self) -> usize {
        (360.0 / self.azimuth_step_deg).round().max(1.0) as usize
    }
}

/// A procedural scene: boxes and cylinders in one parry3d compound (its BVH answers the rays).
#[derive(Clone)]
pub struct Scene {
    compound: Compound,
    /// What was placed, for tests: (kind, world pose, half extents or (half height, radius, 0)).
    parts: Vec<Part>,
}

/// One solid of a [`Scene`].
#[derive(Clone, Debug, PartialEq)]
pub struct Part {
    /// `"ground"`, `"facade"`, `"pole"`, `"car"`, `"floor"`, `"ceiling"`, `"wall"` or
    /// `"furniture"`.
    pub kind: &'static str,
    /// The solid's centre, world frame, metres.
    pub centre: Point3<f64>,
    /// A box's half extents along x, y, z; a (vertical) cylinder's (radius, radius, half
    /// height).
    pub half_extents: Vector3<f64>,
}

impl std::fmt::Debug for Scene {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Scene")
            .field("parts", &self.parts.len())
            .finish()
    }
}

/// Builds a scene from axis-aligned boxes and vertical cylinders.
struct Builder {
    shapes: Vec<(Pose, SharedShape)>,
    parts: Vec<Part>,
}

impl Builder {
    fn new() -> Self {
        Builder {
            shapes: Vec::new(),
            parts: Vec::new(),
        }
    }

    /// An axis-aligned box from its min corner and its size.
    fn cuboid(&mut self, kind: &'static str, min: [f64; 3], size: [f64; 3]) {
        let half = Vector3::new(size[0], size[1], size[2]) / 2.0;
        let centre = Point3::new(min[0], min[1], min[2]) + half;
        self.shapes.push((
            Pose::translation(centre.x as f32, centre.y as f32, centre.z as f32),
            SharedShape::cuboid(half.x as f32, half.y as f32, half.z as f32),
        ));
        self.parts.push(Part {
            kind,
            centre,
            half_extents: half,
        });
    }

    /// A vertical cylinder standing on `base`.
    fn pole(&mut self, base: [f64; 3], radius: f64, height: f64) {
        let centre = Point3::new(base[0], base[1], base[2] + height / 2.0);
        // parry's cylinders stand along y: turned a quarter about x to stand along z.
        let pose = Pose::new(
            Vector::new(centre.x as f32, centre.y as f32, centre.z as f32),
            Vector::new(std::f32::consts::FRAC_PI_2, 0.0, 0.0),
        );
        self.shapes.push((
            pose,
            SharedShape::cylinder((height / 2.0) as f32, radius as f32),
        ));
        self.parts.push(Part {
            kind: "pole",
            centre,
            half_extents: Vector3::new(radius, radius, height / 2.0),
        });
    }

    fn build(self) -> Scene {
        Scene {
            compound: Compound::new(self.shapes),
            parts: self.parts,
        }
    }
}

impl Scene {
    /// A street `length` metres long along x (centred on the origin), 3.5 m lanes either side
    /// of y = 0: the ground (z = 0), building blocks on both sides (6–20 m wide, 6–22 m high,
    /// set back 8–10 m, gaps between them), a pole every 10–15 m on each side (y = ±6 m) and
    /// cars parked along both kerbs (y ≈ ±4.5 m), some spaces empty. Seeded by `rng`.
    pub fn street<R: Rng>(length: f64, rng: &mut R) -> Scene {
        let mut b = Builder::new();
        let half = length / 2.0;
        b.cuboid(
            "ground",
            [-half - 30.0, -40.0, -0.2],
            [length + 60.0, 80.0, 0.2],
        );
        for side in [-1.0, 1.0] {
            let mut x = -half - 20.0;
            while x < half + 20.0 {
                let width = rng.random_range(6.0..20.0);
                let setback = rng.random_range(8.0..10.0);
                let depth = 12.0;
                let height = rng.random_range(6.0..22.0);
                let y0 = if side > 0.0 {
                    setback
                } else {
                    -setback - depth
                };
                b.cuboid("facade", [x, y0, 0.0], [width, depth, height]);
                x += width + rng.random_range(0.0..4.0);
            }
            let mut x = -half + rng.random_range(0.0..5.0);
            while x < half {
                b.pole([x, side * 6.0, 0.0], 0.12, 5.0);
                x += rng.random_range(10.0..15.0);
            }
            let mut x = -half;
            while x < half {
                if rng.random_bool(0.7) {
                    let y = side * rng.random_range(4.2..4.8);
                    b.cuboid("car", [x, y - 0.9, 0.2], [4.5, 1.8, 1.4]);
                }
                x += rng.random_range(5.5..7.5);
            }
        }
        b.build()
    }

    /// A room 6 × 4 m (x from −3 to 3, y from −2 to 2), 2.8 m high: floor, ceiling, four walls
    /// and furniture — a table, a shelf and a cabinet against the walls, a sofa, a pillar —
    /// placed with some randomness. Seeded by `rng`.
    pub fn room<R: Rng>(rng: &mut R) -> Scene {
        let mut b = Builder::new();
        let t = 0.1;
        b.cuboid(
            "floor",
            [-3.0 - t, -2.0 - t, -t],
            [6.0 + 2.0 * t, 4.0 + 2.0 * t, t],
        );
        b.cuboid(
            "ceiling",
            [-3.0 - t, -2.0 - t, 2.8],
            [6.0 + 2.0 * t, 4.0 + 2.0 * t, t],
        );
        b.cuboid("wall", [-3.0 - t, -2.0 - t, 0.0], [t, 4.0 + 2.0 * t, 2.8]);
        b.cuboid("wall", [3.0, -2.0 - t, 0.0], [t, 4.0 + 2.0 * t, 2.8]);
        b.cuboid("wall", [-3.0, -2.0 - t, 0.0], [6.0, t, 2.8]);
        b.cuboid("wall", [-3.0, 2.0, 0.0], [6.0, t, 2.8]);
        let jitter = |rng: &mut R| rng.random_range(-0.3..0.3);
        let (tx, ty) = (1.0 + jitter(rng), -0.6 + jitter(rng));
        b.cuboid("furniture", [tx, ty, 0.0], [1.6, 0.9, 0.75]);
        b.cuboid(
            "furniture",
            [-2.6, -1.2 + jitter(rng), 0.0],
            [0.4, 1.4, 2.0],
        );
        b.cuboid("furniture", [-1.0 + jitter(rng), 1.5, 0.0], [1.2, 0.5, 0.9]);
        b.cuboid("furniture", [0.8 + jitter(rng), 1.0, 0.0], [2.0, 0.9, 0.45]);
        b.pole([-0.8 + jitter(rng), -1.0, 0.0], 0.15, 2.8);
        b.build()
    }

    /// The solids placed.
    pub fn parts(&self) -> &[Part] {
        &self.parts
    }

    /// The distance from the world point `p` to the nearest surface of the scene, metres.
    pub fn distance(&self, p: &Point3<f64>) -> f64 {
        let q = Vector::new(p.x as f32, p.y as f32, p.z as f32);
        self.compound.distance_to_local_point(q, false) as f64
    }

    /// The range along the world-frame ray `origin + t · dir` (`dir` a unit vector) to the first
    /// surface within `max_range`, metres.
    pub fn cast(&self, origin: &Point3<f64>, dir: &Vector3<f64>, max_range: f64) -> Option<f64> {
        let ray = Ray::new(
            Vector::new(origin.x as f32, origin.y as f32, origin.z as f32),
            Vector::new(dir.x as f32, dir.y as f32, dir.z as f32),
        );
        self.compound
            .cast_local_ray(&ray, max_range as f32, true)
            .map(|t| t as f64)
    }
}

/// One revolution of `sensor` at `pose` (sensor into world) in `scene`: each beam's first
/// return within range, with N(0, range_noise²) added to its range, in the sensor frame.
/// Deterministic for a given `seed`, whatever the thread count.
pub fn scan(scene: &Scene, sensor: &Sensor, pose: &Isometry3<f64>, seed: u64) -> Vec<Point3<f64>> {
    let origin = Point3::from(pose.translation.vector);
    let noise = Normal::new(0.0, sensor.range_noise.max(0.0)).expect("a finite deviation");
    let steps = sensor.steps();
    let rings: Vec<Vec<Point3<f64>>> = (0..sensor.rings)
        .into_par_iter()
        .map(|ring| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed ^ (ring as u64).wrapping_mul(0x9E37_79B9));
            (0..steps)
                .filter_map(|step| {
                    let d = sensor.direction(ring, step);
                    let range = scene.cast(&origin, &(pose.rotation * d), sensor.max_range)?;
                    let noisy = range + noise.sample(&mut rng);
                    (range >= sensor.min_range).then(|| Point3::from(d * noisy))
                })
                .collect()
        })
        .collect();
    rings.into_iter().flatten().collect()
}

/// Two scans of one scene from nearby sensor poses, for tests and benches: `source` taken at
/// pose B, `target` at pose A, and `t_target_source` = A⁻¹ · B, the transform that moves the
/// source onto the target (metres).
#[derive(Clone, Debug)]
pub struct ScanPair {
    /// A short name (`street`, `room`).
    pub name: &'static str,
    /// What the pair is.
    pub description: &'static str,
    /// The scan to move.
    pub source: Vec<Point3<f64>>,
    /// The scan that stays.
    pub target: Vec<Point3<f64>>,
    /// Maps source coordinates into the target's.
    pub t_target_source: Isometry3<f64>,
}

impl ScanPair {
    /// Writes `dir/source.ply`, `dir/target.ply` and `dir/gt.txt` (the 4×4 `t_target_source`,
    /// four lines of four numbers), creating `dir`.
    pub fn write(&self, dir: &std::path::Path) -> Result<(), crate::base::error::IoError> {
        let io = |path: std::path::PathBuf| {
            move |source: std::io::Error| crate::base::error::IoError::Io { path, source }
        };
        std::fs::create_dir_all(dir).map_err(io(dir.to_path_buf()))?;
        crate::io::write_point_cloud(dir.join("source.ply"), &self.source)?;
        crate::io::write_point_cloud(dir.join("target.ply"), &self.target)?;
        let m = self.t_target_source.to_homogeneous();
        let rows: Vec<String> = (0..4)
            .map(|i| format!("{} {} {} {}", m[(i, 0)], m[(i, 1)], m[(i, 2)], m[(i, 3)]))
            .collect();
        let gt = dir.join("gt.txt");
        std::fs::write(&gt, rows.join("\n") + "\n").map_err(io(gt))
    }
}

/// A level sensor pose at `(x, y, z)` metres, turned by `yaw_deg` about z.
fn level_pose(x: f64, y: f64, z: f64, yaw_deg: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        nalgebra::Translation3::new(x, y, z),
        nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_deg.to_radians()),
    )
}

/// Scans of `scene` by `sensor` at poses `a` (target, noise seed 1) and `b` (source, seed 2).
fn pair(
    name: &'static str,
    description: &'static str,
    scene: &Scene,
    sensor: &Sensor,
    a: Isometry3<f64>,
    b: Isometry3<f64>,
) -> ScanPair {
    ScanPair {
        name,
        description,
        source: scan(scene, sensor, &b, 2),
        target: scan(scene, sensor, &a, 1),
        t_target_source: a.inverse() * b,
    }
}

/// The street pair: a 100 m street (seed 1) scanned by [`Sensor::spinning_32`] 1.8 m above
/// the ground from two poses 1.2 m along the street and 0.2 m across, 3° apart (about 55 000
/// returns each).
pub fn street_pair() -> ScanPair {
    street_pair_with(&Sensor::spinning_32())
}

/// [`street_pair`] scanned by `sensor` (another range noise, another number of beams).
pub fn street_pair_with(sensor: &Sensor) -> ScanPair {
    pair(
        "street",
        "street (100 m, 32 beams), 1.2 m and 3° apart",
        &Scene::street(100.0, &mut ChaCha8Rng::seed_from_u64(1)),
        sensor,
        level_pose(0.0, -1.5, 1.8, 0.0),
        level_pose(1.2, -1.3, 1.8, 3.0),
    )
}

/// The room pair: a 6 × 4 m room (seed 2) scanned by [`Sensor::spinning_64`] 1.2 m above the
/// floor from two poses 0.58 m and 4° apart (about 115 000 returns each).
pub fn room_pair() -> ScanPair {
    room_pair_with(&Sensor::spinning_64())
}

/// [`room_pair`] scanned by `sensor` (another range noise, another number of beams).
pub fn room_pair_with(sensor: &Sensor) -> ScanPair {
    pair(
        "room",
        "room (6 × 4 m, 64 beams), 0.58 m and 4° apart",
        &Scene::room(&mut ChaCha8Rng::seed_from_u64(2)),
        sensor,
        level_pose(0.0, 0.0, 1.2, 0.0),
        level_pose(0.5, 0.3, 1.2, 4.0),
    )
}

/// A loop of `views` scans of the room of [`room_pair`] by `sensor`, 1.2 m above the floor at
/// poses around an ellipse (1.6 × 0.9 m semi-axes about (0.2, 0.1)), each turned 360°/`views`
/// further: the scans (each in its sensor's frame, noise seed `k + 1`) and each scan's true pose
/// in the first scan's frame.
pub fn room_loop(views: usize, sensor: &Sensor) -> (Vec<Vec<Point3<f64>>>, Vec<Isometry3<f64>>) {
    room_loop_seeded(views, sensor, 0)
}

/// [`room_loop`] with another draw of the range noise: scan `k`'s noise seed is
/// `k + 1 + 1000 · noise_draw` (draw 0 is [`room_loop`]'s). The scene, poses and rays are the same
/// for every draw.
pub fn room_loop_seeded(
    views: usize,
    sensor: &Sensor,
    noise_draw: u64,
) -> (Vec<Vec<Point3<f64>>>, Vec<Isometry3<f64>>) {
    let scene = Scene::room(&mut ChaCha8Rng::seed_from_u64(2));
    let poses: Vec<Isometry3<f64>> = (0..views)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / views.max(1) as f64;
            level_pose(
                0.2 + 1.6 * a.cos(),
                0.1 + 0.9 * a.sin(),
                1.2,
                (360.0 * k as f64 / views.max(1) as f64) + 20.0 * (3.0 * a).sin(),
            )
        })
        .collect();
    let scans = poses
        .iter()
        .enumerate()
        .map(|(k, p)| scan(&scene, sensor, p, k as u64 + 1 + 1000 * noise_draw))
        .collect();
    let first = poses[0].inverse();
    (scans, poses.iter().map(|p| first * p).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn quiet(mut s: Sensor) -> Sensor {
        s.range_noise = 0.0;
        s
    }

    #[test]
    fn every_return_lies_on_a_surface_of_the_street_within_range() {
        let scene = Scene::street(60.0, &mut ChaCha8Rng::seed_from_u64(1));
        let sensor = quiet(Sensor::spinning_32());
        let pose = Isometry3::from_parts(
            Translation3::new(2.0, -1.0, 1.8),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3),
        );
        let points = scan(&scene, &sensor, &pose, 7);
        assert!(points.len() > 20_000, "{} returns", points.len());
        assert!(points.len() <= sensor.rings * sensor.steps());
        let mut worst: f64 = 0.0;
        for p in points.iter().step_by(37) {
            let r = p.coords.norm();
            assert!(r >= sensor.min_range && r <= sensor.max_range, "range {r}");
            worst = worst.max(scene.distance(&(pose * p)));
        }
        assert!(worst < 1e-3, "a return {worst} m off the surfaces");
        // Each beam keeps its elevation: the rings are the sensor's.
        let mut elevations: Vec<i64> = points
            .iter()
            .map(|p| (p.z.atan2(p.coords.xy().norm()).to_degrees() * 100.0).round() as i64)
            .collect();
        elevations.sort_unstable();
        elevations.dedup();
        assert!(
            elevations.len() <= 32 && elevations.len() > 20,
            "{elevations:?}"
        );
    }

    #[test]
    fn a_box_in_front_of_a_wall_shadows_it() {
        let scene = Scene::room(&mut ChaCha8Rng::seed_from_u64(3));
        let sensor = quiet(Sensor::spinning_64());
        let pose = Isometry3::translation(0.5, 0.0, 1.2);
        let points: Vec<Point3<f64>> = scan(&scene, &sensor, &pose, 1)
            .iter()
            .map(|p| pose * p)
            .collect();
        // Every return is the first surface along its beam: no solid lies between the sensor
        // and it (tested against each solid alone).
        let solids: Vec<Scene> = scene
            .parts()
            .iter()
            .map(|part| {
                let mut alone = Builder::new();
                if part.kind == "pole" {
                    let base = part.centre - Vector3::z() * part.half_extents.z;
                    alone.pole(
                        [base.x, base.y, base.z],
                        part.half_extents.x,
                        2.0 * part.half_extents.z,
                    );
                } else {
                    let min = part.centre - part.half_extents;
                    let size = part.half_extents * 2.0;
                    alone.cuboid(part.kind, [min.x, min.y, min.z], [size.x, size.y, size.z]);
                }
                alone.build()
            })
            .collect();
        let origin = Point3::from(pose.translation.vector);
        let mut shadowed = 0;
        for p in points.iter().step_by(11) {
            let to = p - origin;
            let range = to.norm();
            for solid in &solids {
                let hit = solid.cast(&origin, &(to / range), range);
                if hit.is_some_and(|t| t < range - 1e-3) {
                    shadowed += 1;
                }
            }
        }
        assert_eq!(shadowed, 0, "returns behind a solid");
        assert!(points.len() > 30_000);
        // The room's inside only: nothing beyond the walls.
        assert!(points
            .iter()
            .all(|p| p.x.abs() <= 3.0 + 1e-3 && p.y.abs() <= 2.0 + 1e-3));
    }

    #[test]
    fn range_noise_is_as_set_and_seeded() {
        let scene = Scene::room(&mut ChaCha8Rng::seed_from_u64(2));
        let mut sensor = Sensor::spinning_32();
        sensor.range_noise = 0.01;
        let pose = Isometry3::translation(0.0, 0.3, 1.0);
        let a = scan(&scene, &sensor, &pose, 5);
        let b = scan(&scene, &sensor, &pose, 5);
        assert_eq!(a, b, "same seed, same scan");
        let exact = scan(&scene, &quiet(sensor.clone()), &pose, 5);
        assert_eq!(a.len(), exact.len());
        let errors: Vec<f64> = a
            .iter()
            .zip(&exact)
            .map(|(p, q)| p.coords.norm() - q.coords.norm())
            .collect();
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let sd =
            (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / errors.len() as f64).sqrt();
        assert!(
            mean.abs() < 1e-3 && (sd - 0.01).abs() < 1e-3,
            "mean {mean}, sd {sd}"
        );
    }

    #[test]
    fn another_noise_draw_of_the_room_loop_moves_each_return_along_its_own_ray_only() {
        let sensor = Sensor::spinning_32();
        let (a, truth_a) = room_loop_seeded(2, &sensor, 0);
        let (b, truth_b) = room_loop_seeded(2, &sensor, 3);
        assert_eq!(
            (a.clone(), truth_a.clone()),
            room_loop(2, &sensor),
            "draw 0 is room_loop's"
        );
        assert_eq!(truth_a, truth_b, "the same poses");
        for (sa, sb) in a.iter().zip(&b) {
            assert_eq!(sa.len(), sb.len(), "the same rays");
            let mut worst_turn: f64 = 0.0;
            let mut diffs = Vec::with_capacity(sa.len());
            for (p, q) in sa.iter().zip(sb) {
                worst_turn =
                    worst_turn.max(p.coords.normalize().cross(&q.coords.normalize()).norm());
                diffs.push(p.coords.norm() - q.coords.norm());
            }
            assert!(
                worst_turn < 1e-9,
                "a return left its ray by {worst_turn} rad"
            );
            // Two independent N(0, σ²) draws differ by N(0, 2σ²).
            let sd = (diffs.iter().map(|d| d * d).sum::<f64>() / diffs.len() as f64).sqrt();
            let expected = sensor.range_noise * 2f64.sqrt();
            assert!(
                (sd / expected - 1.0).abs() < 0.05,
                "range differences {sd} m, expected {expected} m"
            );
        }
    }
}

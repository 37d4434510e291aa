//! Procedural test shapes (no data files needed): used by the demo, the tests and the benches.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

/// A closed, asymmetric "potato": the unit sphere with radial bumps, scaled to about 1 across.
/// `n` surface points (not exactly area-uniform, which the method does not need).
pub fn blob<R: Rng>(n: usize, rng: &mut R) -> Vec<Point3<f64>> {
    (0..n)
        .map(|_| {
            let d = Vector3::<f64>::new(
                StandardNormal.sample(rng),
                StandardNormal.sample(rng),
                StandardNormal.sample(rng),
            )
            .normalize();
            blob_point(&d)
        })
        .collect()
}

/// The point of the blob's surface in the unit direction `d` (for tests: the surface exactly).
#[cfg(test)]
pub(crate) fn blob_point_for_tests(d: &Vector3<f64>) -> Point3<f64> {
    blob_point(d)
}

/// The point of the blob's surface in the unit direction `d`.
fn blob_point(d: &Vector3<f64>) -> Point3<f64> {
    let r = 1.0
        + 0.25 * (3.0 * d.x + 1.0).sin() * (2.0 * d.y).cos()
        + 0.2 * d.z * d.z * d.z
        + 0.15 * d.x * d.y;
    Point3::from(d.component_mul(&Vector3::new(0.55, 0.4, 0.3)) * r)
}

/// `n` partial views of `shape` (its points centred near the origin), as a scan campaign gives
/// them: the k-th keeps the 70 % of the points farthest along the direction at k/n of a turn
/// about z (tilted up by 0.3), and lies in a frame of its own. Returns each view's points in its
/// frame and its pose: the map from the view's frame into `shape`'s.
pub fn partial_views(shape: &[Point3<f64>], n: usize) -> Vec<(Vec<Point3<f64>>, Isometry3<f64>)> {
    (0..n)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / n as f64;
            let d = Vector3::new(a.cos(), a.sin(), 0.3);
            let mut dots: Vec<f64> = shape.iter().map(|p| p.coords.dot(&d)).collect();
            dots.sort_by(f64::total_cmp);
            let cut = dots[dots.len() * 3 / 10];
            let pose = Isometry3::from_parts(
                Translation3::new(0.1 * k as f64, -0.2, 0.05 * k as f64),
                UnitQuaternion::from_scaled_axis(Vector3::new(0.2, -0.1 * k as f64, 0.3)),
            );
            let view = shape
                .iter()
                .filter(|p| p.coords.dot(&d) > cut)
                .map(|p| pose.inverse() * p)
                .collect();
            (view, pose)
        })
        .collect()
}

/// The [`blob`]'s surface as a closed triangle mesh, outward normals by the right-hand rule:
/// a latitude–longitude grid of `rings` rings (≥ 2) of `2 rings` vertices and the two poles.
/// Returns (vertices, triangles as vertex indices).
pub fn blob_mesh(rings: usize) -> (Vec<Point3<f64>>, Vec<[usize; 3]>) {
    let rings = rings.max(2);
    let around = 2 * rings;
    let mut vertices = vec![blob_point(&Vector3::z())];
    for i in 1..rings {
        let theta = std::f64::consts::PI * i as f64 / rings as f64;
        for j in 0..around {
            let phi = 2.0 * std::f64::consts::PI * j as f64 / around as f64;
            let d = Vector3::new(
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            );
            vertices.push(blob_point(&d));
        }
    }
    vertices.push(blob_point(&-Vector3::z()));
    let south = vertices.len() - 1;
    let at = |i: usize, j: usize| 1 + (i - 1) * around + j % around;
    let mut triangles = Vec::new();
    for j in 0..around {
        triangles.push([0, at(1, j), at(1, j + 1)]);
        triangles.push([south, at(rings - 1, j + 1), at(rings - 1, j)]);
        for i in 1..rings - 1 {
            triangles.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            triangles.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    (vertices, triangles)
}

/// `n` nearly evenly spread unit vectors (a Fibonacci sphere, polar axis z): the unit sphere's
/// points, and their normals.
pub fn fibonacci_sphere(n: usize) -> Vec<Vector3<f64>> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let t = golden * i as f64;
            Vector3::new(r * t.cos(), r * t.sin(), z)
        })
        .collect()
}

/// An asymmetric bracket: the surfaces of three boxes of different sizes joined in an L with a
/// post; about 1 across. `n` points, uniform by area.
pub fn bracket<R: Rng>(n: usize, rng: &mut R) -> Vec<Point3<f64>> {
    // (min corner, size) of each box.
    let boxes = [
        (Vector3::new(-0.5, -0.2, -0.1), Vector3::new(1.0, 0.3, 0.2)),
        (Vector3::new(-0.5, 0.1, -0.1), Vector3::new(0.25, 0.45, 0.2)),
        (
            Vector3::new(0.25, -0.2, 0.1),
            Vector3::new(0.15, 0.15, 0.35),
        ),
    ];
    let mut faces = Vec::new();
    for (lo, size) in boxes {
        for axis in 0..3 {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            for side in [0.0, 1.0] {
                faces.push((lo, size, axis, u, v, side, size[u] * size[v]));
            }
        }
    }
    let areas: Vec<f64> = faces.iter().map(|f| f.6).collect();
    (0..n)
        .map(|_| {
            let (lo, size, axis, u, v, side, _) = faces[pick_weighted(&areas, rng)];
            let mut p = lo;
            p[axis] += side * size[axis];
            p[u] += rng.random::<f64>() * size[u];
            p[v] += rng.random::<f64>() * size[v];
            Point3::from(p)
        })
        .collect()
}

/// The index of one of `weights` (positive) drawn with probability proportional to it: one
/// `rng.random::<f64>()` scaled by their sum, walked down them in order (the last when
/// rounding leaves it past them all). Not `rand`'s `WeightedIndex`, which draws differently:
/// the shapes keep their random streams, and with them the learned initialisation trained on
/// [`assembly`] (`examples/learn_init.rs`) stays reproducible.
fn pick_weighted<R: Rng>(weights: &[f64], rng: &mut R) -> usize {
    let total: f64 = weights.iter().sum();
    let mut a = rng.random::<f64>() * total;
    for (i, &w) in weights.iter().enumerate() {
        if a < w {
            return i;
        }
        a -= w;
    }
    weights.len() - 1
}

/// One part of an [`assembly`], in its own frame (centred at the origin, axis z).
#[derive(Clone, Copy, Debug)]
enum Part {
    /// A box of these half sides.
    Cuboid(Vector3<f64>),
    /// An ellipsoid of these radii.
    Ellipsoid(Vector3<f64>),
    /// A capped cylinder about z: radius, half height.
    Cylinder(f64, f64),
    /// An open tube about z (no caps, no inside): radius, half height.
    Tube(f64, f64),
}

impl Part {
    /// A part of random kind and size (each size in 0.03–0.5).
    fn random<R: Rng>(rng: &mut R) -> Self {
        let mut size = || rng.random_range(0.03..0.5);
        let (a, b, c) = (size(), size(), size());
        match rng.random_range(0..4) {
            0 => Part::Cuboid(Vector3::new(a, b, c)),
            1 => Part::Ellipsoid(Vector3::new(a, b, c)),
            2 => Part::Cylinder(a.min(0.35), b),
            _ => Part::Tube(a.min(0.35), b),
        }
    }

    /// Its surface area, approximate for the ellipsoid (Knud Thomsen's formula).
    fn area(&self) -> f64 {
        use std::f64::consts::PI;
        match *self {
            Part::Cuboid(h) => 8.0 * (h.x * h.y + h.y * h.z + h.z * h.x),
            Part::Ellipsoid(r) => {
                let p = 1.6075;
                let m = ((r.x * r.y).powf(p) + (r.y * r.z).powf(p) + (r.z * r.x).powf(p)) / 3.0;
                4.0 * PI * m.powf(1.0 / p)
            }
            Part::Cylinder(r, h) => 2.0 * PI * r * 2.0 * h + 2.0 * PI * r * r,
            Part::Tube(r, h) => 2.0 * PI * r * 2.0 * h,
        }
    }

    /// A random point of its surface (uniform by area but on the ellipsoid, where it is
    /// uniform by direction).
    fn sample<R: Rng>(&self, rng: &mut R) -> Point3<f64> {
        use std::f64::consts::PI;
        match *self {
            Part::Cuboid(h) => {
                let axis = pick_weighted(&[h.y * h.z, h.z * h.x, h.x * h.y], rng);
                let mut p = Vector3::from_fn(|i, _| rng.random_range(-h[i]..h[i]));
                p[axis] = if rng.random::<bool>() {
                    h[axis]
                } else {
                    -h[axis]
                };
                Point3::from(p)
            }
            Part::Ellipsoid(r) => {
                let d = Vector3::<f64>::from_fn(|_, _| StandardNormal.sample(rng)).normalize();
                Point3::from(d.component_mul(&r))
            }
            Part::Cylinder(r, h) | Part::Tube(r, h) => {
                let side = 2.0 * PI * r * 2.0 * h;
                let phi = rng.random_range(0.0..2.0 * PI);
                // The side's share of the area ([`Self::area`]: the tube's is the side alone).
                if rng.random::<f64>() * self.area() < side {
                    Point3::new(r * phi.cos(), r * phi.sin(), rng.random_range(-h..h))
                } else {
                    let rho = r * rng.random::<f64>().sqrt();
                    let z = if rng.random::<bool>() { h } else { -h };
                    Point3::new(rho * phi.cos(), rho * phi.sin(), z)
                }
            }
        }
    }

    /// Whether `p` (its frame) lies inside it by more than `margin`; a tube has no inside.
    fn contains(&self, p: &Point3<f64>, margin: f64) -> bool {
        match *self {
            Part::Cuboid(h) => (0..3).all(|i| p[i].abs() < h[i] - margin),
            Part::Ellipsoid(r) => {
                let s = r.map(|v| (v - margin).max(1e-9));
                (p.x / s.x).powi(2) + (p.y / s.y).powi(2) + (p.z / s.z).powi(2) < 1.0
            }
            Part::Cylinder(r, h) => p.x.hypot(p.y) < r - margin && p.z.abs() < h - margin,
            Part::Tube(..) => false,
        }
    }
}

/// A random object: the outer surface of 1–5 parts (boxes, ellipsoids, capped cylinders and
/// open tubes of random sizes, turned and placed at random, overlapping or not), `n` points
/// spread by area; a point inside another part is left out. Training and test shapes for the
/// fit (the learned initialisation, [`crate::field::learned_init`]): their variety — thin plates, rods,
/// surfaces of revolution, open shells, several pieces — stands in for real objects'.
pub fn assembly<R: Rng>(n: usize, rng: &mut R) -> Vec<Point3<f64>> {
    let count = rng.random_range(1..=5);
    let parts: Vec<(Part, nalgebra::Isometry3<f64>)> = (0..count)
        .map(|_| {
            let part = Part::random(rng);
            let axis = Vector3::<f64>::from_fn(|_, _| StandardNormal.sample(rng));
            let angle = rng.random_range(0.0..std::f64::consts::PI);
            let centre = Vector3::from_fn(|_, _| rng.random_range(-0.3..0.3));
            let pose = nalgebra::Isometry3::new(centre, axis.normalize() * angle);
            (part, pose)
        })
        .collect();
    let areas: Vec<f64> = parts.iter().map(|(p, _)| p.area()).collect();
    let mut points = Vec::with_capacity(n);
    // At most 50 draws a point, so parts hidden inside others cannot loop forever.
    for _ in 0..50 * n {
        if points.len() == n {
            break;
        }
        let k = pick_weighted(&areas, rng);
        let x = parts[k].1 * parts[k].0.sample(rng);
        let hidden = parts
            .iter()
            .enumerate()
            .any(|(i, (p, pose))| i != k && p.contains(&pose.inverse_transform_point(&x), 1e-3));
        if !hidden {
            points.push(x);
        }
    }
    points
}

//! Procedural test shapes (no data files needed): used by the demo, the tests and the benches.

use nalgebra::{Point3, Vector3};
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
            let r = 1.0
                + 0.25 * (3.0 * d.x + 1.0).sin() * (2.0 * d.y).cos()
                + 0.2 * d.z * d.z * d.z
                + 0.15 * d.x * d.y;
            Point3::from(d.component_mul(&Vector3::new(0.55, 0.4, 0.3)) * r)
        })
        .collect()
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
    let total: f64 = faces.iter().map(|f| f.6).sum();
    (0..n)
        .map(|_| {
            let mut a = rng.random::<f64>() * total;
            let mut f = faces[faces.len() - 1];
            for face in &faces {
                if a < face.6 {
                    f = *face;
                    break;
                }
                a -= face.6;
            }
            let (lo, size, axis, u, v, side, _) = f;
            let mut p = lo;
            p[axis] += side * size[axis];
            p[u] += rng.random::<f64>() * size[u];
            p[v] += rng.random::<f64>() * size[v];
            Point3::from(p)
        })
        .collect()
}

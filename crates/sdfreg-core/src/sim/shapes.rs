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

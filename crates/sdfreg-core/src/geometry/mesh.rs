//! Triangle meshes: uniform sampling of their surface (for targets given as meshes).

use nalgebra::Point3;
use rand::Rng;

/// `n` points drawn uniformly by area over the `triangles` (indices into `vertices`), with
/// uniform barycentric coordinates inside each; `None` when the triangles have no area.
pub fn sample_surface<R: Rng>(
    vertices: &[Point3<f64>],
    triangles: &[[usize; 3]],
    n: usize,
    rng: &mut R,
) -> Option<Vec<Point3<f64>>> {
    // Cumulative areas; a triangle is picked by binary search on a uniform draw.
    let mut cumulative = Vec::with_capacity(triangles.len());
    let mut total = 0.0;
    for t in triangles {
        let [a, b, c] = t.map(|i| vertices[i]);
        total += 0.5 * (b - a).cross(&(c - a)).norm();
        cumulative.push(total);
    }
    if !(total > 0.0 && total.is_finite()) {
        return None;
    }
    Some(
        (0..n)
            .map(|_| {
                let u: f64 = rng.random::<f64>() * total;
                let i = cumulative
                    .partition_point(|&c| c <= u)
                    .min(triangles.len() - 1);
                let [a, b, c] = triangles[i].map(|k| vertices[k]);
                // Uniform in the triangle: √r₁ folds the square onto it.
                let (r1, r2): (f64, f64) = (rng.random(), rng.random());
                let s = r1.sqrt();
                Point3::from(
                    a.coords * (1.0 - s) + b.coords * (s * (1.0 - r2)) + c.coords * (s * r2),
                )
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn samples_lie_on_the_faces_in_proportion_to_their_area() {
        // Two triangles in z = 0 (area 0.5) and x = 3 (area 1.5).
        let v = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(3.0, 0.0, 0.0),
            Point3::new(3.0, 3.0, 0.0),
            Point3::new(3.0, 0.0, 1.0),
        ];
        let t = [[0, 1, 2], [3, 4, 5]];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let pts = sample_surface(&v, &t, 20_000, &mut rng).unwrap();
        let on_first = pts
            .iter()
            .filter(|p| p.z == 0.0 && p.x + p.y <= 1.0 + 1e-12)
            .count();
        let on_second = pts
            .iter()
            .filter(|p| (p.x - 3.0).abs() < 1e-12 && p.y + 3.0 * p.z <= 3.0 + 1e-9)
            .count();
        assert_eq!(on_first + on_second, pts.len());
        let share = on_second as f64 / pts.len() as f64;
        assert!((share - 0.75).abs() < 0.02, "{share}");
        // Uniform inside: a quarter of the first triangle's samples lie in its corner half-size triangle.
        let corner = pts
            .iter()
            .filter(|p| p.z == 0.0 && p.x + p.y <= 0.5)
            .count();
        assert!((corner as f64 / on_first as f64 - 0.25).abs() < 0.03);
        assert!(sample_surface(&v, &[[0, 1, 1]], 10, &mut rng).is_none());
    }
}

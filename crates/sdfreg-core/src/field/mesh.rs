//! A target mesh as its own exact distance field: Φ(x) is the distance from x to the nearest
//! triangle (parry3d's BVH), negative inside when the mesh is closed and consistently oriented
//! (pseudo-normals decide), unsigned otherwise; ∇Φ points from the nearest surface point to x.
//! Registering against it needs no fitting: scans onto CAD models or reconstructions.
//!
//! Far from the surface — farther from the nearest vertex than [`MeshField::FAR_EDGES`] times
//! the longest edge at that vertex — the distance to that vertex stands in for the exact one
//! (within about an edge length; the sign from the vertex's pseudo-normal): there a BVH query visits much of the mesh
//! (≈ 10 µs a point on the bunny's 70k triangles) and the multi-start's wrong starts put most
//! points there. Near the surface, where the solver converges, the distance is exact.
//!
//! Entry point: [`crate::MeshModel`].

use parry3d::math::Vector;
use parry3d::query::PointQueryWithLocation;
use parry3d::shape::{TriMesh, TriMeshFlags};

use crate::base::error::Error;
use crate::field::Field;
use crate::geometry::tree::{build_tree, Tree};

/// The exact distance to a triangle mesh, unit frame.
#[derive(Clone)]
pub struct MeshField {
    mesh: TriMesh,
    signed: bool,
    /// The k-d tree of the vertices that triangles use (`used[i]` is item i's vertex): the
    /// nearest one bounds the distance to the surface (pruning the BVH search) and stands in
    /// for it far away.
    vertices: Tree,
    used: Vec<u32>,
    /// Per vertex: beyond this distance (unit frame) from it, when it is the nearest vertex,
    /// its distance is used.
    far: Vec<f32>,
}

impl std::fmt::Debug for MeshField {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MeshField")
            .field("triangles", &self.mesh.indices().len())
            .field("signed", &self.signed)
            .finish()
    }
}

impl MeshField {
    /// Points farther from their nearest vertex than this many times the longest edge at that
    /// vertex take that vertex's distance.
    pub const FAR_EDGES: f32 = 4.0;

    /// The field of the mesh `vertices` (unit frame) and `triangles` (vertex indices); fails
    /// on an index out of range or no triangles.
    pub fn new(vertices: &[[f32; 3]], triangles: &[[u32; 3]]) -> Result<Self, Error> {
        if triangles.is_empty() {
            return Err(Error::InvalidMesh("no triangles".into()));
        }
        for (k, t) in triangles.iter().enumerate() {
            if let Some(&bad) = t.iter().find(|&&i| i as usize >= vertices.len()) {
                return Err(Error::InvalidMesh(format!(
                    "triangle {k} refers to vertex {bad}, but there are {} vertices",
                    vertices.len()
                )));
            }
        }
        let mut is_used = vec![false; vertices.len()];
        for t in triangles {
            for &i in t {
                is_used[i as usize] = true;
            }
        }
        let used: Vec<u32> = (0..vertices.len() as u32)
            .filter(|&i| is_used[i as usize])
            .collect();
        let tree = build_tree(
            &used
                .iter()
                .map(|&i| vertices[i as usize])
                .collect::<Vec<_>>(),
        );
        let mut far = vec![0.0f32; vertices.len()];
        for t in triangles {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                let (a, b) = (a as usize, b as usize);
                let (p, q) = (vertices[a], vertices[b]);
                let len = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2))
                    .sqrt()
                    * Self::FAR_EDGES;
                far[a] = far[a].max(len);
                far[b] = far[b].max(len);
            }
        }
        let vertices: Vec<Vector> = vertices
            .iter()
            .map(|v| Vector::new(v[0], v[1], v[2]))
            .collect();
        // Oriented: pseudo-normals give the sign when the mesh is closed and consistently
        // wound; parry leaves them out (and the field unsigned) when it is not.
        let mesh = TriMesh::with_flags(vertices, triangles.to_vec(), TriMeshFlags::ORIENTED)
            .map_err(|e| Error::InvalidMesh(e.to_string()))?;
        let signed = mesh.pseudo_normals().is_some() && closed_and_oriented(triangles);
        Ok(MeshField {
            mesh,
            signed,
            vertices: tree,
            used,
            far,
        })
    }

    /// Whether Φ is signed (negative inside): the mesh is closed and consistently oriented.
    pub fn is_signed(&self) -> bool {
        self.signed
    }

    /// Φ and ∇Φ at `x` (unit frame).
    fn at(&self, x: &[f32; 3]) -> (f32, [f32; 3]) {
        let p = Vector::new(x[0], x[1], x[2]);
        let nearest = self.vertices.nearest_one::<kiddo::SquaredEuclidean>(x);
        let bound = nearest.distance.sqrt();
        let vertex = self.used[nearest.item as usize] as usize;
        if bound > self.far[vertex] {
            let v = self.mesh.vertices()[vertex];
            let d = (p - v) / bound;
            let outside = match self.mesh.pseudo_normals() {
                Some(normals) if self.signed => {
                    d.dot(normals.vertices_pseudo_normal[vertex]) >= 0.0
                }
                _ => true,
            };
            let sign = if outside { 1.0 } else { -1.0 };
            return (sign * bound, [sign * d.x, sign * d.y, sign * d.z]);
        }
        let (proj, (triangle, _)) = self
            .mesh
            .project_local_point_and_get_location_with_max_dist(p, false, bound * 1.001 + 1e-6)
            .unwrap_or_else(|| self.mesh.project_local_point_and_get_location(p, false));
        let d = p - proj.point;
        let len = d.length();
        let sign = if self.signed && proj.is_inside {
            -1.0
        } else {
            1.0
        };
        let n = if len > 1e-7 {
            d / len * sign
        } else {
            // On the surface: the triangle's normal (its winding's side).
            self.mesh
                .triangle(triangle)
                .normal()
                .unwrap_or(Vector::new(0.0, 0.0, 1.0))
        };
        (sign * len, [n.x, n.y, n.z])
    }
}

impl Field for MeshField {
    fn eval_block(
        &self,
        xs: &[[f32; 3]],
        values: &mut Vec<f32>,
        gradients: Option<&mut Vec<[f32; 3]>>,
    ) {
        values.clear();
        match gradients {
            Some(g) => {
                g.clear();
                for x in xs {
                    let (v, n) = self.at(x);
                    values.push(v);
                    g.push(n);
                }
            }
            None => values.extend(xs.iter().map(|x| self.at(x).0)),
        }
    }
}

/// Whether every edge is shared by exactly two triangles that run along it in opposite
/// directions: the mesh is closed and consistently wound, so inside and outside exist.
fn closed_and_oriented(triangles: &[[u32; 3]]) -> bool {
    let mut directed: std::collections::HashMap<(u32, u32), u32> =
        std::collections::HashMap::with_capacity(triangles.len() * 3);
    for t in triangles {
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            *directed.entry((a, b)).or_default() += 1;
        }
    }
    directed
        .iter()
        .all(|(&(a, b), &n)| n == 1 && directed.get(&(b, a)) == Some(&1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
    use parry3d::query::PointQuery;
    use parry3d::shape::Triangle;
    use rand::Rng;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    /// The blob mesh in its unit frame, and the field.
    fn blob() -> (Vec<[f32; 3]>, Vec<[u32; 3]>, MeshField) {
        let (v, t) = crate::sim::shapes::blob_mesh(20);
        let v: Vec<[f32; 3]> = v
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        let t: Vec<[u32; 3]> = t.iter().map(|t| t.map(|i| i as u32)).collect();
        let field = MeshField::new(&v, &t).unwrap();
        (v, t, field)
    }

    /// The distance to the nearest triangle, by brute force.
    fn brute(v: &[[f32; 3]], t: &[[u32; 3]], x: &[f32; 3]) -> f32 {
        let p = Vector::new(x[0], x[1], x[2]);
        let at = |i: u32| Vector::new(v[i as usize][0], v[i as usize][1], v[i as usize][2]);
        t.iter()
            .map(|t| Triangle::new(at(t[0]), at(t[1]), at(t[2])).distance_to_local_point(p, false))
            .fold(f32::INFINITY, f32::min)
    }

    #[test]
    fn exact_near_the_surface_within_an_edge_far_from_it_and_signed() {
        let (v, t, field) = blob();
        let longest = field.far.iter().fold(0.0f32, |a, &b| a.max(b)) / MeshField::FAR_EDGES;
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let (mut near, mut far) = (0, 0);
        for _ in 0..3000 {
            let x = [
                rng.random_range(-1.2..1.2f32),
                rng.random_range(-1.2..1.2f32),
                rng.random_range(-1.2..1.2f32),
            ];
            let (phi, _) = field.at(&x);
            let exact = brute(&v, &t, &x);
            let nearest = field.vertices.nearest_one::<kiddo::SquaredEuclidean>(&x);
            let vertex = field.used[nearest.item as usize] as usize;
            if nearest.distance.sqrt() > field.far[vertex] {
                far += 1;
                assert!(
                    (phi.abs() - exact).abs() <= longest,
                    "{x:?}: {phi} vs {exact}"
                );
            } else {
                near += 1;
                assert!((phi.abs() - exact).abs() < 1e-5, "{x:?}: {phi} vs {exact}");
            }
            // Inside the star-shaped blob or outside it (clear of its surface), the sign says so.
            if exact > 0.02 {
                let x = Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64);
                // The blob's surface point in the direction of x (blob_point scales its
                // direction by (0.55, 0.4, 0.3)).
                let u = x.component_div(&Vector3::new(0.55, 0.4, 0.3)).normalize();
                let surface = crate::sim::shapes::blob_point_for_tests(&u).coords.norm();
                assert_eq!(phi < 0.0, x.norm() < surface, "{x:?}: {phi}");
            }
        }
        assert!(near > 200 && far > 200, "near {near}, far {far}");
    }

    #[test]
    fn the_gradient_is_the_distances_derivative() {
        let (v, _, field) = blob();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let exact = |x: &[f32; 3]| {
            let nearest = field.vertices.nearest_one::<kiddo::SquaredEuclidean>(x);
            nearest.distance.sqrt() <= field.far[field.used[nearest.item as usize] as usize]
        };
        let h = 1e-3f32;
        let mut mismatch = Vec::new();
        for _ in 0..300 {
            // Off the surface by 0.02–0.05 in a random direction, in and out: clear of the
            // surface's kink and of the medial axis.
            let p = v[rng.random_range(0..v.len())];
            let dir = Vector3::new(
                rng.random_range(-1.0..1.0f32),
                rng.random_range(-1.0..1.0f32),
                rng.random_range(-1.0..1.0f32),
            )
            .normalize()
                * rng.random_range(0.02..0.05f32);
            let x = [p[0] + dir.x, p[1] + dir.y, p[2] + dir.z];
            let (phi, g) = field.at(&x);
            if phi.abs() < 0.01 {
                continue;
            }
            for k in 0..3 {
                let (mut a, mut b) = (x, x);
                a[k] += h;
                b[k] -= h;
                if !(exact(&a) && exact(&b)) {
                    continue;
                }
                let fd = (field.at(&a).0 - field.at(&b).0) / (2.0 * h);
                mismatch.push((fd - g[k]).abs());
            }
        }
        assert!(
            mismatch.len() > 300,
            "{} components checked",
            mismatch.len()
        );
        mismatch.sort_by(f32::total_cmp);
        let at = |q: f64| mismatch[((mismatch.len() - 1) as f64 * q) as usize];
        // The distance's kinks (where two faces are equally near, the medial axis, which comes
        // close to the surface in the blob's folds) take a few points; elsewhere the gradient
        // matches the central difference to its truncation error.
        assert!(
            at(0.5) < 1e-4 && at(0.95) < 2e-3,
            "median {}, 95 % {}",
            at(0.5),
            at(0.95)
        );
    }

    #[test]
    fn bad_meshes_are_refused() {
        let v = [[0.0f32; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let e = MeshField::new(&v, &[[0, 1, 3]]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "target mesh: triangle 0 refers to vertex 3, but there are 3 vertices"
        );
        assert_eq!(
            MeshField::new(&v, &[]).unwrap_err().to_string(),
            "target mesh: no triangles"
        );
        // An open mesh (one triangle) gives an unsigned field.
        let open = MeshField::new(&v, &[[0, 1, 2]]).unwrap();
        assert!(!open.is_signed());
        assert!(open.at(&[0.2, 0.2, -0.5]).0 > 0.0);
    }
}

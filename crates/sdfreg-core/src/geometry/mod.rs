//! Layer 1, geometry: poses, clouds, meshes and the neighbourhoods of points, with no
//! distance field in sight.
//!
//! - [`se3`]: exp/log maps on SE(3), rigid checks, pose errors;
//! - [`cloud`]: bounding box, centroid, subsampling, the unit-frame normalisation;
//! - [`mesh`]: sampling points on triangles;
//! - [`tree`]: the k-d tree over a cloud and its point spacing;
//! - `planes` (crate-private): local PCA planes at query points and at a cloud's own points.

pub mod cloud;
pub mod mesh;
pub(crate) mod planes;
pub mod se3;
pub mod tree;

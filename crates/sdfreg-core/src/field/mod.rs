//! Layer 2, distance fields: what the solver registers against, a distance field Φ of the
//! target in its unit frame ([`Field`]).
//!
//! - [`mlp`]: the network with hand-written first and second derivatives
//!   ([`mlp::Mlp`], its softplus kernels in `activation`), started from [`learned_init`];
//! - [`local_grid`]: a scene's sparse voxel grid of corrections; [`sdf`]: the fitted Φ, the
//!   MLP plus, for a local model, that grid ([`sdf::SdfField`]);
//! - [`baked`]: Φ sampled on a grid and read by trilinear interpolation;
//! - [`mesh`]: a mesh's exact distance ([`mesh::MeshField`]).
//!
//! The target points the polish and the quality figures use join Φ one layer up, in the
//! pipeline's `Surface`.

pub(crate) mod activation;
pub mod baked;
pub mod learned_init;
pub mod local_grid;
pub mod mesh;
pub mod mlp;
pub mod sdf;

use rayon::prelude::*;

/// Points per block in the parallel loops: large enough for efficient products,
/// small enough that a block's activations stay in cache.
pub const BLOCK: usize = 256;

/// A distance field of the target, unit frame (the target's largest bounding-box side is 1):
/// the value Φ(x), zero on the surface, and its gradient.
pub trait Field: Sync {
    /// Φ at each of `xs` (at most [`BLOCK`] points) into `values` and, when asked, ∇Φ into
    /// `gradients` (both cleared first).
    fn eval_block(
        &self,
        xs: &[[f32; 3]],
        values: &mut Vec<f32>,
        gradients: Option<&mut Vec<[f32; 3]>>,
    );

    /// Φ (and ∇Φ when `gradients`, else an empty vector) at any number of points, in parallel.
    fn eval_points(&self, xs: &[[f32; 3]], gradients: bool) -> (Vec<f32>, Vec<[f32; 3]>) {
        let parts: Vec<(Vec<f32>, Vec<[f32; 3]>)> = xs
            .par_chunks(BLOCK)
            .map(|chunk| {
                let (mut v, mut g) = (Vec::new(), Vec::new());
                self.eval_block(chunk, &mut v, gradients.then_some(&mut g));
                (v, g)
            })
            .collect();
        let mut values = Vec::with_capacity(xs.len());
        let mut grads = Vec::with_capacity(if gradients { xs.len() } else { 0 });
        for (v, g) in parts {
            values.extend(v);
            grads.extend(g);
        }
        (values, grads)
    }
}

/// Φ (user units) and ∇Φ at `points` (user units and frame) of a field in the unit frame of
/// `norm`, in parallel.
pub(crate) fn evaluate_user<F: Field + ?Sized>(
    norm: &crate::geometry::cloud::Normalization,
    field: &F,
    points: &[nalgebra::Point3<f64>],
) -> (Vec<f64>, Vec<nalgebra::Vector3<f64>>) {
    let unit: Vec<[f32; 3]> = points.iter().map(|p| norm.to_unit(p)).collect();
    let (phi, grad) = field.eval_points(&unit, true);
    let phi = phi.iter().map(|&v| v as f64 * norm.scale).collect();
    let grad = grad
        .iter()
        .map(|g| nalgebra::Vector3::new(g[0] as f64, g[1] as f64, g[2] as f64))
        .collect();
    (phi, grad)
}

/// The closest surface point of each of `points` (user units and frame), `p − Φ ∇Φ/‖∇Φ‖`, with
/// `(Φ, ∇Φ)` from [`evaluate_user`].
pub(crate) fn closest_user(
    points: &[nalgebra::Point3<f64>],
    (phi, grad): (Vec<f64>, Vec<nalgebra::Vector3<f64>>),
) -> Vec<nalgebra::Point3<f64>> {
    points
        .iter()
        .zip(phi.iter().zip(&grad))
        .map(|(p, (d, g))| p - g.normalize() * *d)
        .collect()
}

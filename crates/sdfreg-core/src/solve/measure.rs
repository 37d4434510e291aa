//! Quality of a pose against the target: fitness, inlier RMS, the 6×6 information matrix, the
//! final cost and the motions the data leave free ([`crate::solve::degeneracy`]).
//!
//! Entry points: [`inlier_stats`], [`quality`].

use kiddo::SquaredEuclidean;
use nalgebra::{Matrix6, SMatrix, Vector3};
use rayon::prelude::*;

use crate::field::Field;
use crate::geometry::cloud::Normalization;
use crate::geometry::tree::Tree;
use crate::solve::degeneracy::Degeneracy;
use crate::solve::lm::{jacobian_row, similarity_row};

/// Fitness — the fraction of the (already moved) `points` within `sqrt(thr2)` of a target
/// point — and the RMS distance of those inliers, normalised units.
pub(crate) fn inlier_stats(tree: &Tree, points: &[[f32; 3]], thr2: f64) -> (f64, f64) {
    inlier_stats_of(&nearest_distances2(tree, points), thr2)
}

/// The squared distance of each of `points` to its nearest target point (`tree`).
pub(crate) fn nearest_distances2(tree: &Tree, points: &[[f32; 3]]) -> Vec<f32> {
    points
        .par_iter()
        .map(|x| tree.nearest_one::<SquaredEuclidean>(x).distance)
        .collect()
}

/// Each of `points`' nearest target point (`tree`): its squared distance and its index.
pub(crate) fn nearest_points(tree: &Tree, points: &[[f32; 3]]) -> Vec<(f32, u32)> {
    points
        .par_iter()
        .map(|x| {
            let nn = tree.nearest_one::<SquaredEuclidean>(x);
            (nn.distance, nn.item)
        })
        .collect()
}

/// [`inlier_stats`] from the points' squared nearest distances `d2`
/// ([`nearest_distances2`]).
pub(crate) fn inlier_stats_of(d2: &[f32], thr2: f64) -> (f64, f64) {
    let thr2 = thr2 as f32;
    let inliers: Vec<f64> = d2
        .iter()
        .filter(|&&d| d <= thr2)
        .map(|&d| d as f64)
        .collect();
    let fitness = inliers.len() as f64 / d2.len().max(1) as f64;
    let rms = if inliers.is_empty() {
        0.0
    } else {
        (inliers.iter().sum::<f64>() / inliers.len() as f64).sqrt()
    };
    (fitness, rms)
}

/// Figures of the moved source against Φ, in the user's frame.
pub(crate) struct Quality {
    /// `JᵀJ` at the pose, twist `[ω; v]` about the target origin, user units.
    pub information: Matrix6<f64>,
    /// Mean squared Φ, user units².
    pub cost: f64,
    /// The motions the data leave free.
    pub degeneracy: Degeneracy,
    /// With a scale: `JᵀJ` (7×7) of the step `[ω; v; σ]`, about the target origin, user units.
    pub similarity_information: Option<SMatrix<f64, 7, 7>>,
}

/// [`Quality`] of the unit-frame `moved` source points against `phi`; with `scaled` (a
/// similarity), also the 7×7 information and whether the scale is free.
pub(crate) fn quality<F: Field + ?Sized>(
    field: &F,
    moved: &[[f32; 3]],
    norm: &Normalization,
    ratio: f64,
    scaled: bool,
) -> Quality {
    let (phi, grads) = field.eval_points(moved, true);
    let mut information = Matrix6::zeros();
    let mut cost = 0.0;
    let mut moved_user = Vec::with_capacity(moved.len());
    let mut normals = Vec::with_capacity(moved.len());
    for ((x, g), r) in moved.iter().zip(&grads).zip(&phi) {
        let xu = norm.to_user(&Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64));
        let n = Vector3::new(g[0] as f64, g[1] as f64, g[2] as f64);
        let j = jacobian_row(&xu.coords, &n);
        information += j * j.transpose();
        cost += (*r as f64 * norm.scale).powi(2);
        moved_user.push(xu);
        normals.push(n);
    }
    let mut degeneracy = Degeneracy::analyse(&moved_user, &normals, ratio);
    let similarity_information = scaled.then(|| {
        degeneracy.analyse_scale(&moved_user, &normals);
        moved_user
            .iter()
            .zip(&normals)
            .map(|(x, n)| {
                let j = similarity_row(&x.coords, n, 0.0);
                j * j.transpose()
            })
            .sum()
    });
    Quality {
        information,
        cost: cost / moved.len() as f64,
        degeneracy,
        similarity_information,
    }
}

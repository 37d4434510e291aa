//! The k-d tree over a cloud's points in the unit frame, and the point spacing measured with
//! it.

use std::num::NonZeroUsize;

use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;

/// k-d tree over f32 points in the unit frame.
pub type Tree = ImmutableKdTree<f32, u32, 3, 32>;

/// Relative margin on a squared bound that a [`Tree`] is searched within (a bounded search's
/// radius): far above the rounding of the tree's f32 distances, so that a point not found
/// within the bound certainly lies beyond it (a wider bound only costs time).
pub(crate) const SEARCH_BOUND_MARGIN: f64 = 1e-3;

/// Builds a [`Tree`] over `points`.
pub fn build_tree(points: &[[f32; 3]]) -> Tree {
    ImmutableKdTree::new_from_slice(points)
}

/// Median over `points` of the distance to the nearest target point (excluding a point's own
/// entry when `skip_self`).
pub(crate) fn median_nn(
    points: impl Iterator<Item = [f32; 3]>,
    tree: &Tree,
    skip_self: bool,
) -> f64 {
    let k = NonZeroUsize::new(if skip_self { 2 } else { 1 }).unwrap();
    let mut d: Vec<f64> = points
        .map(|q| {
            let nn = tree.nearest_n::<SquaredEuclidean>(&q, k);
            (nn.last().map_or(f64::INFINITY, |n| n.distance as f64)).sqrt()
        })
        .collect();
    if d.is_empty() {
        return f64::INFINITY;
    }
    d.sort_by(f64::total_cmp);
    d[d.len() / 2]
}

/// The target points' median spacing (distance to the nearest other target point), over at
/// most about 2048 of them.
pub(crate) fn target_spacing(target: &[[f32; 3]], tree: &Tree) -> f64 {
    let step = (target.len() / 1024).max(1);
    median_nn(target.iter().step_by(step).copied(), tree, true)
}

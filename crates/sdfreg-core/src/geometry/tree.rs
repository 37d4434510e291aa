//! The k-d tree over a cloud's points in the unit frame, and the point spacing measured with
//! it.

use std::num::NonZeroUsize;

use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;
use rayon::prelude::*;

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

/// An axis-aligned box in the unit frame: its lowest and highest corner.
pub(crate) type UnitBox = ([f32; 3], [f32; 3]);

/// For every point of every set, its squared distance to the nearest point of the **other**
/// sets (`f32::INFINITY` when none lies within `reach` of it; beyond `reach` a point's distance
/// may be left at infinity). `boxes[k]` is set `k`'s bounding box. All in one unit frame.
///
/// Exact, and cheaper than a tree of "all but `k`" per set (`n` trees of nearly every point):
/// the sets are halved, each half's points looked up in one tree of the other half, and each
/// half then halved again, so every point is in about `log₂ n` trees of fewer points and looked
/// up once in each; a set or a point farther than `reach` from the other half's box skips it.
pub(crate) fn nearest_in_others(
    sets: &[Vec<[f32; 3]>],
    boxes: &[UnitBox],
    reach: f32,
) -> Vec<Vec<f32>> {
    let mut d2: Vec<Vec<f32>> = sets.iter().map(|s| vec![f32::INFINITY; s.len()]).collect();
    halves(sets, boxes, &mut d2, reach);
    d2
}

/// [`nearest_in_others`] within `sets`: each half against the other, then each half alone.
fn halves(sets: &[Vec<[f32; 3]>], boxes: &[UnitBox], d2: &mut [Vec<f32>], reach: f32) {
    if sets.len() < 2 {
        return;
    }
    let h = sets.len() / 2;
    let (sa, sb) = sets.split_at(h);
    let (ba, bb) = boxes.split_at(h);
    let (da, db) = d2.split_at_mut(h);
    rayon::join(
        || nearer_in(sa, ba, da, sb, bb, reach),
        || nearer_in(sb, bb, db, sa, ba, reach),
    );
    rayon::join(|| halves(sa, ba, da, reach), || halves(sb, bb, db, reach));
}

/// Lowers each `from` point's squared distance `d2` to that of its nearest `to` point, for the
/// points within `reach` of the box of the `to` sets that come within `reach` of a `from` set
/// (a tree of those alone: along a street, the halves meet only where they join).
fn nearer_in(
    from: &[Vec<[f32; 3]>],
    from_boxes: &[UnitBox],
    d2: &mut [Vec<f32>],
    to: &[Vec<[f32; 3]>],
    to_boxes: &[UnitBox],
    reach: f32,
) {
    let meet = |a: &UnitBox, b: &UnitBox| {
        (0..3).all(|i| a.0[i] - reach <= b.1[i] && b.0[i] <= a.1[i] + reach)
    };
    let used: Vec<usize> = (0..to.len())
        .filter(|&j| from_boxes.iter().any(|b| meet(&to_boxes[j], b)))
        .collect();
    let Some(&first) = used.first() else {
        return;
    };
    let (mut lo, mut hi) = to_boxes[first];
    for &j in &used {
        let (l, h) = to_boxes[j];
        for i in 0..3 {
            lo[i] = lo[i].min(l[i]);
            hi[i] = hi[i].max(h[i]);
        }
    }
    let reached = (lo, hi);
    let inside = |p: &[f32; 3]| (0..3).all(|i| lo[i] - reach <= p[i] && p[i] <= hi[i] + reach);
    let points: Vec<[f32; 3]> = used.iter().flat_map(|&j| to[j].iter().copied()).collect();
    let tree = build_tree(&points);
    for ((points, d2), _) in from
        .iter()
        .zip(d2)
        .zip(from_boxes)
        .filter(|(_, b)| meet(&reached, b))
    {
        points
            .par_iter()
            .zip(d2.par_iter_mut())
            .filter(|(p, _)| inside(p))
            .for_each(|(p, d)| *d = d.min(tree.nearest_one::<SquaredEuclidean>(p).distance));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn nearest_in_others_is_the_nearest_point_of_all_the_other_sets() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        // Seven sets of different sizes, side by side along x, overlapping their neighbours.
        let sets: Vec<Vec<[f32; 3]>> = (0..7)
            .map(|k| {
                (0..50 + 30 * k)
                    .map(|_| {
                        [
                            0.1 * k as f32 + rng.random_range(0.0..0.15),
                            rng.random_range(0.0..0.1),
                            rng.random_range(0.0..0.1),
                        ]
                    })
                    .collect()
            })
            .collect();
        let boxes: Vec<UnitBox> = sets
            .iter()
            .map(|s| {
                let lo = std::array::from_fn(|i| s.iter().map(|p| p[i]).fold(f32::MAX, f32::min));
                let hi = std::array::from_fn(|i| s.iter().map(|p| p[i]).fold(f32::MIN, f32::max));
                (lo, hi)
            })
            .collect();
        let d2_of = |p: &[f32; 3], q: &[f32; 3]| (0..3).map(|i| (p[i] - q[i]).powi(2)).sum::<f32>();
        for reach in [10.0, 0.02] {
            let got = nearest_in_others(&sets, &boxes, reach);
            let mut within = 0;
            for (k, set) in sets.iter().enumerate() {
                for (p, d) in set.iter().zip(&got[k]) {
                    let exact = (0..sets.len())
                        .filter(|&j| j != k)
                        .flat_map(|j| sets[j].iter())
                        .map(|q| d2_of(p, q))
                        .fold(f32::INFINITY, f32::min);
                    if exact <= reach * reach {
                        within += 1;
                        assert!(
                            (d - exact).abs() <= 1e-5 * exact.max(1e-6),
                            "{k}: {d} {exact}"
                        );
                    } else {
                        assert!(*d >= exact * (1.0 - 1e-6), "{k}: {d} below {exact}");
                    }
                }
            }
            assert!(within > 500, "{within}");
        }
        // A single set has no others.
        let alone = nearest_in_others(&sets[..1], &boxes[..1], 10.0);
        assert!(alone[0].iter().all(|d| d.is_infinite()));
    }
}

//! Local planes of a cloud: the PCA plane of a point's nearest cloud points, cached while the
//! nearest points stay the same ([`PlaneCache`]), and planes at the cloud's own points
//! ([`TargetPlanes`], shared across registrations by [`SharedPlanes`]).

use std::num::NonZeroUsize;
use std::sync::OnceLock;

use kiddo::SquaredEuclidean;
use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};

use crate::geometry::tree::{Tree, SEARCH_BOUND_MARGIN};

/// What a source point's last local plane was made of, so that the next iterations, which move
/// the point by ever smaller steps, need neither the k-d tree nor the plane fit while its
/// nearest target points stay the same — with the same numbers as querying and fitting anew.
///
/// `base` is where the `k + 1` nearest target points were last found, at the (square-root)
/// distances `radii`, strictly increasing. A point `x` within `δ` of `base` is within `δ` of
/// its old distance to every target point, so while each gap `radiiᵢ₊₁ − radiiᵢ` exceeds `2δ`
/// (and a rounding margin) the `k` nearest are the same points in the same order, and the
/// plane fitted to them is the same. The plane is also kept across a new query that finds the
/// same points in the same order.
#[derive(Clone, Default)]
pub(crate) struct PlaneCache {
    /// The `k` nearest target points of the last query, in order.
    items: Vec<u32>,
    /// Their plane: centroid and normal; `None` when the last query found no target point
    /// within the gate.
    plane: Option<(Vector3<f64>, Vector3<f64>)>,
    /// The last query point, when its `k + 1` distances were strictly increasing.
    base: Option<Vector3<f64>>,
    /// Distances from `base` to its `k + 1` nearest target points.
    radii: Vec<f64>,
}

/// A local plane: a centroid and a unit normal.
type Plane = (Vector3<f64>, Vector3<f64>);

/// Margin for rounding when the k-d tree's f32 distances are compared through [`PlaneCache`]:
/// far above f32's relative precision at unit scale.
const ORDER_MARGIN: f64 = 1e-5;

impl PlaneCache {
    /// Whether the last plane certainly holds for `x`: `Some(true)` the same nearest points,
    /// the nearest within `max_d`; `Some(false)` the nearest certainly beyond `max_d` (the last
    /// nearest distance less the move: whatever the order of the farther ones, so a point
    /// outside the gate is not searched again while it stays there — on the bunny's
    /// bun180→bun090, half of it unseen in the other scan, 72 % of the searches were for such
    /// points); `None` when only a query can tell.
    fn holds(&self, x: &Vector3<f64>, max_d: f64) -> Option<bool> {
        if self.beyond(&Point3::from(*x), max_d * max_d) {
            return Some(false);
        }
        let base = self.base?;
        let delta = (x - base).norm();
        let nearest = self.radii[0];
        let margin = |r: f64| 2.0 * delta + ORDER_MARGIN * (1.0 + r);
        let ordered = self.radii.windows(2).all(|w| w[1] - w[0] > margin(w[1]));
        if ordered && nearest + delta + ORDER_MARGIN * (1.0 + nearest) < max_d {
            // The plane is that of `base`'s points unless `base` was beyond the gate.
            self.plane.map(|_| true)
        } else {
            None
        }
    }
}

impl PlaneCache {
    /// The `n` nearest target points of `x` (`xf` in f32), sorted. After a query from `base`
    /// whose `n` distances were `radii`, the `n` nearest of a point `δ` away lie within the
    /// largest of them plus `δ` (the old `n` points do), so the k-d tree is searched within
    /// that bound, without visiting (or sorting in) the points beyond it — most of the polish's
    /// time on a range scan of 40 000 points, whose points move too far between iterations
    /// for the cache to hold while the polish turns them. Whatever the bound, `n` points found
    /// within it are the `n` nearest, in the same order as an unbounded search; should it
    /// (with a margin for the f32 distances) find fewer, or without such a query, the search
    /// is unbounded.
    fn nearest(
        &self,
        tree: &Tree,
        xf: &[f32; 3],
        x: &Point3<f64>,
        n: usize,
    ) -> Vec<kiddo::NearestNeighbour<f32, u32>> {
        let count = NonZeroUsize::new(n).unwrap();
        if let Some(bound2) = self.bound2(x, n) {
            let found = tree.nearest_n_within::<SquaredEuclidean>(xf, bound2, count, true);
            if found.len() == n {
                return found;
            }
        }
        tree.nearest_n::<SquaredEuclidean>(xf, count)
    }

    /// The squared bound within which the `n` nearest target points of `x` lie, after a query
    /// from `base` whose `n`-th nearest lay at `radii[n - 1]`: that distance plus the move,
    /// with a margin for the k-d tree's f32 distances; `None` without such a query.
    fn bound2(&self, x: &Point3<f64>, n: usize) -> Option<f32> {
        let (base, far) = (self.base?, *self.radii.get(n - 1)?);
        let bound = far + (x.coords - base).norm();
        Some((bound * bound * (1.0 + SEARCH_BOUND_MARGIN) + f64::MIN_POSITIVE) as f32)
    }

    /// The nearest target point of `x` when it lies within `√max_d2`, else `None` — without a
    /// search while [`Self::beyond`] says so, else by [`Self::nearest_one`].
    pub(crate) fn nearest_within(
        &mut self,
        tree: &Tree,
        x: &Point3<f64>,
        max_d2: f64,
    ) -> Option<kiddo::NearestNeighbour<f32, u32>> {
        if self.beyond(x, max_d2) {
            return None;
        }
        let nn = self.nearest_one(tree, x);
        if nn.distance as f64 > max_d2 {
            None
        } else {
            Some(nn)
        }
    }

    /// The nearest target point of `x`, for [`TargetPlanes::residual`] and the polish's snap
    /// (a cache used for one of them only, not for [`local_plane`]): after a query from
    /// `base` whose nearest lay at `radii[0]`, the nearest of a point `δ` away lies within
    /// `radii[0] + δ`, and the k-d tree is searched within that bound (the same point an
    /// unbounded search finds; unbounded when nothing is found within it, with the f32
    /// margin).
    fn nearest_one(&mut self, tree: &Tree, x: &Point3<f64>) -> kiddo::NearestNeighbour<f32, u32> {
        let xf = [x.x as f32, x.y as f32, x.z as f32];
        let bounded = self.bound2(x, 1).and_then(|bound2| {
            tree.nearest_n_within::<SquaredEuclidean>(&xf, bound2, NonZeroUsize::MIN, true)
                .first()
                .copied()
        });
        let nn = bounded.unwrap_or_else(|| tree.nearest_one::<SquaredEuclidean>(&xf));
        self.base = Some(Vector3::new(xf[0] as f64, xf[1] as f64, xf[2] as f64));
        self.radii.clear();
        self.radii.push((nn.distance as f64).sqrt());
        nn
    }

    /// Whether, by the last query ([`Self::nearest_one`] or [`Self::refresh`]), the nearest
    /// target point of `x` certainly lies farther than `√max_d2` (the last nearest distance
    /// less the move, with the f32 margin): a point outside the gate need not be searched again
    /// while it stays there.
    fn beyond(&self, x: &Point3<f64>, max_d2: f64) -> bool {
        match (self.base, self.radii.first()) {
            (Some(base), Some(&near)) => {
                let low = near - (x.coords - base).norm() - ORDER_MARGIN * (1.0 + near);
                low > 0.0 && low * low > max_d2
            }
            _ => false,
        }
    }

    /// Queries the `k` (and, for the next iterations' gap, `k + 1`) nearest target points of
    /// `x` and refits the plane unless they are the same points in the same order; `None`
    /// (and no plane) when the nearest is farther than `max_d2` (squared).
    fn refresh(
        &mut self,
        target: &[[f32; 3]],
        tree: &Tree,
        x: &Point3<f64>,
        k: usize,
        max_d2: f64,
    ) -> Option<()> {
        let xf = [x.x as f32, x.y as f32, x.z as f32];
        // The first k of k + 1 are the k nearest in the same order when the distances
        // strictly increase.
        let more = self.nearest(tree, &xf, x, k + 1);
        let increasing =
            more.len() == k + 1 && more.windows(2).all(|w| w[0].distance < w[1].distance);
        let nn = if increasing {
            more
        } else {
            tree.nearest_n::<SquaredEuclidean>(&xf, NonZeroUsize::new(k).unwrap())
        };
        self.base = increasing.then(|| Vector3::new(xf[0] as f64, xf[1] as f64, xf[2] as f64));
        self.radii.clear();
        if increasing {
            self.radii
                .extend(nn.iter().map(|n| (n.distance as f64).sqrt()));
        }
        let nn = &nn[..k.min(nn.len())];
        if nn.first()?.distance as f64 > max_d2 {
            // No plane for `base`: the next iterations may skip the query only to say so again.
            self.plane = None;
            self.items.clear();
            return None;
        }
        let same = self.plane.is_some()
            && self.items.len() == nn.len()
            && self.items.iter().zip(nn).all(|(&a, b)| a == b.item);
        if !same {
            let (plane, _) = pca_plane(nn.iter().map(|n| target[n.item as usize]))?;
            self.items.clear();
            self.items.extend(nn.iter().map(|n| n.item));
            self.plane = Some(plane);
        }
        Some(())
    }
}

/// Distance of `x` to the plane fitted (PCA) through its `k` nearest target points, signed along
/// that plane's normal, and the normal; `None` when `x` is farther than `max_d2` (squared) from
/// every target point. `cache` holds what this point's last plane was made of
/// ([`PlaneCache`]).
pub(crate) fn local_plane(
    target: &[[f32; 3]],
    tree: &Tree,
    x: &Point3<f64>,
    k: usize,
    max_d2: f64,
    cache: &mut PlaneCache,
) -> Option<(f64, Vector3<f64>)> {
    match cache.holds(&x.coords, max_d2.sqrt()) {
        Some(true) => {}
        Some(false) => return None,
        None => cache.refresh(target, tree, x, k.max(3), max_d2)?,
    }
    let (mean, n) = cache.plane?;
    Some((n.dot(&(x.coords - mean)), n))
}

/// The normal (PCA of `k` target points nearest to `target[i]`) at a target point.
pub(crate) fn point_normal(
    target: &[[f32; 3]],
    tree: &Tree,
    i: usize,
    k: usize,
) -> Option<Vector3<f64>> {
    point_plane(target, tree, i, k).map(|(_, n)| n)
}

/// A neighbourhood is a line, not a patch of surface, when the spread of its points across
/// their main direction is below this share of the spread along it (ratio of the PCA's middle
/// to largest eigenvalue). A spinning LiDAR's returns lie on rings far denser along the ring
/// than across: on the procedural room's floor (64 beams, 1 cm range noise) the 15 nearest
/// points of a return are one ring's (ratio 0.01–0.05) and their PCA normal lies across the
/// beam, not across the floor — tilted by the beam's elevation (19° median). Two rings give a
/// ratio of 0.3 or more; a range scan's grid about 1. A ring with 2 cm of range noise (the
/// 32-beam room) reads 0.1–0.3 for 7 % of the points, a ribbon along the beam that this test
/// keeps: 0.3 made neighbouring views' edges 0.21° → 0.05° but no aligned pose, real LiDAR pair
/// or ModelNet figure better (docs/views.md, "Why the neighbours' edges are weak").
const LINE_RATIO: f64 = 0.1;

/// A target point's plane takes at most this many times its `k` points, doubling while they
/// are a line ([`LINE_RATIO`]).
const MAX_LINE_GROWTH: usize = 16;

/// The plane (PCA centroid and normal) of the `k` target points nearest target point `i`; of
/// twice as many while those are a line ([`LINE_RATIO`]: one ring of a LiDAR scan), up to
/// [`MAX_LINE_GROWTH`] times `k`, so that the plane spans the surface between the rings.
fn point_plane(target: &[[f32; 3]], tree: &Tree, i: usize, k: usize) -> Option<Plane> {
    let k = k.max(3);
    let mut n = k;
    loop {
        let nn = tree.nearest_n::<SquaredEuclidean>(&target[i], NonZeroUsize::new(n)?);
        let (plane, line) = pca_plane(nn.iter().map(|m| target[m.item as usize]))?;
        if !line || n >= k * MAX_LINE_GROWTH || nn.len() < n {
            return Some(plane);
        }
        n *= 2;
    }
}

/// The PCA plane of `points` (centroid and normal), and whether they are a line rather than a
/// patch ([`LINE_RATIO`]); `None` for no points.
fn pca_plane(points: impl Iterator<Item = [f32; 3]>) -> Option<(Plane, bool)> {
    let pts: Vec<Vector3<f64>> = points
        .map(|p| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .collect();
    if pts.is_empty() {
        return None;
    }
    let mean = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
    let cov: Matrix3<f64> = pts
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum();
    let (n, mid, max) = pca_normal(cov);
    Some(((mean, n), mid < LINE_RATIO * max))
}

/// The normal of the points whose covariance is `cov` (its least eigenvector, unit length,
/// unoriented), and its middle and largest eigenvalues (the spread across and along the
/// points' main direction: a line has the middle one near 0).
pub(crate) fn pca_normal(cov: Matrix3<f64>) -> (Vector3<f64>, f64, f64) {
    let eig = SymmetricEigen::new(cov);
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let n: Vector3<f64> = eig.eigenvectors.column(order[0]).into_owned();
    (n, eig.eigenvalues[order[1]], eig.eigenvalues[order[2]])
}

/// Local planes at the target's own points, for scenes: the plane (PCA centroid and normal) of
/// each target point's `k` nearest target points (more while those are a line, as
/// `point_plane` grows them), computed once when first asked for and then
/// shared by every iteration, pass and shift-search candidate. A moved source point's residual
/// is its distance to the plane of its nearest target point: one nearest-point query an
/// iteration instead of a `k`-nearest query and a fit at the source point. Used when Φ is local
/// ([`crate::ModelKind::Local`]), whose planes take [`PolishSettings::scene_neighbours`] points:
/// on the procedural street pair the polish took 70 % of a registration against a stored model
/// with planes at the source points.
#[derive(Debug)]
pub(crate) struct TargetPlanes {
    k: usize,
    planes: Vec<OnceLock<Option<Plane>>>,
}

impl TargetPlanes {
    /// No plane computed yet, for the `target` points (and their `tree`) and planes of `k`
    /// points.
    pub(crate) fn new(target: &[[f32; 3]], k: usize) -> Self {
        Self {
            k: k.max(3),
            planes: (0..target.len()).map(|_| OnceLock::new()).collect(),
        }
    }

    /// The plane at target point `i`: its centroid and unit normal.
    pub(crate) fn plane(
        &self,
        target: &[[f32; 3]],
        tree: &Tree,
        i: usize,
    ) -> Option<(Vector3<f64>, Vector3<f64>)> {
        *self.planes[i].get_or_init(|| point_plane(target, tree, i, self.k))
    }

    /// Distance of `x` to the plane of its nearest target point, signed along that plane's
    /// normal, and the normal; `None` when that point is farther than `max_d2` (squared).
    /// One nearest-point query each call, bounded by the last one's distance plus the move
    /// ([`PlaneCache::nearest_one`]); `cache` keeps the plane of the last nearest point.
    /// (Skipping the query while the nearest certainly stays the same, by the gap between the
    /// two nearest distances as [`PlaneCache`] does for `k` points, gave the same numbers but
    /// cost more: the two-nearest query outweighed the queries saved — a bunny pair's polish
    /// 374 → 494 ms, the outdoor LiDAR pair's through its model 86–109 → 101–124 ms.)
    pub(crate) fn residual(
        &self,
        target: &[[f32; 3]],
        tree: &Tree,
        x: &Point3<f64>,
        max_d2: f64,
        cache: &mut PlaneCache,
    ) -> Option<(f64, Vector3<f64>)> {
        let nn = cache.nearest_within(tree, x, max_d2)?;
        if cache.items.first() != Some(&nn.item) {
            cache.items.clear();
            cache.items.push(nn.item);
            cache.plane = self.plane(target, tree, nn.item as usize);
        }
        let (mean, n) = cache.plane?;
        Some((n.dot(&(x.coords - mean)), n))
    }
}

/// A target's [`TargetPlanes`] kept across registrations (a stored model's: fit once, register
/// many): the planes computed by one registration serve the next, unless it asks for another
/// number of points per plane.
#[derive(Debug, Default)]
pub(crate) struct SharedPlanes(std::sync::Mutex<Option<std::sync::Arc<TargetPlanes>>>);

impl Clone for SharedPlanes {
    fn clone(&self) -> Self {
        Self(std::sync::Mutex::new(
            self.0.lock().ok().and_then(|g| g.clone()),
        ))
    }
}

impl SharedPlanes {
    /// The planes of the `target` points of `k` points each: the kept ones when they fit,
    /// else new ones (kept from now on).
    pub(crate) fn get(&self, target: &[[f32; 3]], k: usize) -> std::sync::Arc<TargetPlanes> {
        let n = target.len();
        let fresh = || std::sync::Arc::new(TargetPlanes::new(target, k));
        let Ok(mut kept) = self.0.lock() else {
            return fresh();
        };
        match &*kept {
            Some(p) if p.k == k.max(3) && p.planes.len() == n => p.clone(),
            _ => kept.insert(fresh()).clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// A plane from the cache (`kept`) is a fresh query's (`fresh`) to the bit: the same
    /// signed distance and normal, or no plane for either.
    fn assert_same_plane(
        fresh: Option<(f64, Vector3<f64>)>,
        kept: Option<(f64, Vector3<f64>)>,
        i: usize,
        step: impl std::fmt::Display,
    ) {
        match (fresh, kept) {
            (None, None) => {}
            (Some((r, n)), Some((r2, n2))) => {
                assert_eq!(r.to_bits(), r2.to_bits(), "point {i} step {step}");
                assert_eq!(n, n2, "point {i} step {step}");
            }
            other => panic!("point {i} step {step}: {other:?}"),
        }
    }

    #[test]
    fn a_kept_plane_is_bit_identical_to_a_fresh_query_and_fit() {
        // Source points walked towards the target by ever smaller steps, as the polish moves
        // them, some across the gate; the cache must skip queries and change no number.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let target: Vec<[f32; 3]> = crate::sim::shapes::blob(3000, &mut rng)
            .iter()
            .map(|p| [p.x as f32 * 0.8, p.y as f32 * 0.8, p.z as f32 * 0.8])
            .collect();
        let tree = crate::geometry::tree::build_tree(&target);
        let k = 5; // the polish's default neighbours
        let max_d2 = 0.03f64 * 0.03;
        let mut skipped = 0;
        let mut total = 0;
        for (i, p) in target.iter().step_by(37).enumerate() {
            let dir = Vector3::new(1.0, (i as f64 * 0.7).sin(), (i as f64 * 1.3).cos()).normalize();
            let q = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            let mut cache = PlaneCache::default();
            for step in 0..40 {
                let off = 0.05 * 0.8f64.powi(step) + 1e-4 * (step as f64 * 2.1).sin();
                let x = Point3::from(q + dir * off);
                let fresh = local_plane(&target, &tree, &x, k, max_d2, &mut PlaneCache::default());
                let was = cache.holds(&x.coords, max_d2.sqrt());
                let kept = local_plane(&target, &tree, &x, k, max_d2, &mut cache);
                total += 1;
                skipped += usize::from(was.is_some());
                assert_same_plane(fresh, kept, i, step);
            }
        }
        assert!(skipped * 3 > total, "{skipped} of {total} queries skipped");
    }

    /// One point's positions, step by step.
    type Walk = Vec<Point3<f64>>;

    /// A blob of 4000 target points (seeded), and points carried round by a turn from every
    /// 53rd of them pushed out by `1.02 + spread · i` (start `i`), as the polish moves a
    /// source turned 40° off: 30 steps from a hundredth to a tenth of the extent each.
    fn turned_walks(seed: u64, spread: f64) -> (Vec<[f32; 3]>, Tree, Vec<Walk>) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let target: Vec<[f32; 3]> = crate::sim::shapes::blob(4000, &mut rng)
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        let tree = crate::geometry::tree::build_tree(&target);
        let walks = (target.iter().step_by(53).enumerate())
            .map(|(i, p)| {
                let q = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)
                    * (1.02 + spread * i as f64);
                let axis = nalgebra::Unit::new_normalize(Vector3::new(0.3, 1.0, (i as f64).sin()));
                let mut turned = 0.0;
                (0..30)
                    .map(|step| {
                        turned += 0.005 + 0.05 * ((step * 7 + i) % 5) as f64 / 4.0;
                        Point3::from(nalgebra::Rotation3::from_axis_angle(&axis, turned) * q)
                    })
                    .collect()
            })
            .collect();
        (target, tree, walks)
    }

    #[test]
    fn a_search_bounded_by_the_last_query_finds_what_an_unbounded_one_does() {
        // Points carried round by a turn, as the polish moves a source turned 40° off: steps
        // from a hundredth to a tenth of the extent, too large for the cache to hold, each
        // searched within the last query's farthest distance plus the step. The same target
        // points, in the same order, at the same distances as an unbounded search.
        let (target, tree, walks) = turned_walks(11, 0.0);
        let n = 6; // k + 1 for the polish's 5 neighbours
        let (mut bounded, mut total) = (0, 0);
        for (i, walk) in walks.iter().enumerate() {
            let mut cache = PlaneCache::default();
            for (step, &x) in walk.iter().enumerate() {
                let xf = [x.x as f32, x.y as f32, x.z as f32];
                let fresh = tree.nearest_n::<SquaredEuclidean>(&xf, NonZeroUsize::new(n).unwrap());
                bounded += usize::from(cache.base.is_some());
                total += 1;
                let found = cache.nearest(&tree, &xf, &x, n);
                let key = |v: &[kiddo::NearestNeighbour<f32, u32>]| {
                    v.iter()
                        .map(|m| (m.item, m.distance.to_bits()))
                        .collect::<Vec<_>>()
                };
                assert_eq!(key(&found), key(&fresh), "point {i} step {step}");
                cache.refresh(&target, &tree, &x, n - 1, f64::INFINITY);
            }
        }
        assert!(
            bounded * 10 > total * 9,
            "{bounded} of {total} searches bounded"
        );
    }

    #[test]
    fn the_nearest_point_searched_within_the_last_distance_plus_the_move_is_the_unbounded_ones() {
        // The same walk for the nearest point alone (a scene's planes at the target's points,
        // the snap): searched within the last nearest distance plus the step, the same point
        // at the same distance as an unbounded search, also from outside the target; and a
        // point said to lie beyond a gate without a search does.
        let (_, tree, walks) = turned_walks(12, 0.01);
        let (mut bounded, mut total, mut beyond) = (0, 0, 0);
        for (i, walk) in walks.iter().enumerate() {
            let mut cache = PlaneCache::default();
            for (step, &x) in walk.iter().enumerate() {
                let fresh =
                    tree.nearest_one::<SquaredEuclidean>(&[x.x as f32, x.y as f32, x.z as f32]);
                bounded += usize::from(cache.base.is_some());
                total += 1;
                // A point said to be beyond a gate is beyond it.
                for gate in [0.02f64, 0.05, 0.1] {
                    if cache.beyond(&x, gate * gate) {
                        beyond += 1;
                        assert!(fresh.distance as f64 > gate * gate, "point {i} step {step}");
                    }
                }
                let found = cache.nearest_one(&tree, &x);
                assert_eq!(
                    (found.item, found.distance.to_bits()),
                    (fresh.item, fresh.distance.to_bits()),
                    "point {i} step {step}"
                );
            }
        }
        assert!(
            bounded * 10 > total * 9,
            "{bounded} of {total} searches bounded"
        );
        assert!(
            beyond > total / 10,
            "{beyond} of {total} said beyond a gate"
        );
    }

    #[test]
    fn a_point_that_stays_beyond_the_gate_is_not_searched_again_however_far_it_moves() {
        // Points carried round outside the target (pushed out 2–40 % beyond it) by steps too
        // large for their k + 1 nearest to keep their order: while the last nearest distance
        // less the step is beyond the gate, the plane is refused without a search, and the
        // answer is a fresh search's (no plane) every time.
        let (target, tree, walks) = turned_walks(13, 0.005);
        let (k, gate) = (5, 0.05f64);
        let (mut refused, mut beyond, mut total) = (0, 0, 0);
        for (i, walk) in walks.iter().enumerate() {
            let mut cache = PlaneCache::default();
            for (step, x) in walk.iter().enumerate() {
                let fresh = local_plane(
                    &target,
                    &tree,
                    x,
                    k,
                    gate * gate,
                    &mut PlaneCache::default(),
                );
                let said = cache.holds(&x.coords, gate);
                let kept = local_plane(&target, &tree, x, k, gate * gate, &mut cache);
                total += 1;
                beyond += usize::from(fresh.is_none());
                if said == Some(false) {
                    refused += 1;
                    assert!(fresh.is_none(), "point {i} step {step}");
                }
                assert_same_plane(fresh, kept, i, step);
            }
        }
        assert!(beyond * 2 > total, "{beyond} of {total} beyond the gate");
        assert!(
            refused * 3 > beyond * 2,
            "{refused} of the {beyond} beyond the gate refused without a search ({total} in all)"
        );
    }

    /// The planes at a simulated LiDAR scan's floor returns (64 beams, with and without 1 cm
    /// range noise; the sensor 1.2 m above the floor): the floor's normal, where with noise
    /// the 15 nearest returns alone (one ring, its points spread along the beams) give a normal
    /// across the beam, tilted by its elevation.
    #[test]
    fn a_plane_at_a_lidar_ring_spans_the_rings_and_has_the_floors_normal() {
        use crate::sim::lidar::{scan, Scene, Sensor};
        let scene = Scene::room(&mut rand_chacha::ChaCha8Rng::seed_from_u64(2));
        let pose = nalgebra::Isometry3::translation(0.2, 0.1, 1.2);
        for noise in [0.01, 0.0] {
            let mut sensor = Sensor::spinning_64();
            sensor.range_noise = noise;
            let points: Vec<[f32; 3]> = scan(&scene, &sensor, &pose, 1)
                .iter()
                .map(|p| [p.x as f32, p.y as f32, p.z as f32])
                .collect();
            let tree = crate::geometry::tree::build_tree(&points);
            // Floor returns (1.2 m below the sensor), 15 cm or more from the walls.
            let floor: Vec<usize> = (0..points.len())
                .filter(|&i| {
                    let p = points[i];
                    (p[2] + 1.2).abs() < 0.03
                        && (p[0] + 0.2).abs() < 2.85
                        && (p[1] + 0.1).abs() < 1.85
                })
                .collect();
            assert!(floor.len() > 200, "{} floor returns", floor.len());
            let tilt = |n: Vector3<f64>| n.z.abs().min(1.0).acos().to_degrees();
            let median = |mut v: Vec<f64>| {
                v.sort_by(f64::total_cmp);
                v[v.len() / 2]
            };
            let one_ring = median(
                floor
                    .iter()
                    .map(|&i| {
                        let nn = tree.nearest_n::<SquaredEuclidean>(
                            &points[i],
                            NonZeroUsize::new(15).unwrap(),
                        );
                        let (plane, _) =
                            pca_plane(nn.iter().map(|m| points[m.item as usize])).unwrap();
                        tilt(plane.1)
                    })
                    .collect(),
            );
            let planes = TargetPlanes::new(&points, 15);
            let spanning = median(
                floor
                    .iter()
                    .map(|&i| tilt(planes.plane(&points, &tree, i).unwrap().1))
                    .collect(),
            );
            assert!(
                noise == 0.0 || one_ring > 10.0,
                "noise {noise}: one ring's normal tilted {one_ring}°"
            );
            assert!(
                spanning < 2.0,
                "noise {noise}: the plane's normal tilted {spanning}°"
            );
        }
    }
}

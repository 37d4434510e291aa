//! Initial hypotheses without an initial guess: a multi-start over the cube group's rotations.
//!
//! LM on Φ has a basin of a few tens of degrees; the paper's protocols reach 45° per axis and
//! real scans any rotation. Each start aligns the centroids with one of the 24 rotations of the
//! cube group ([`cube_rotations`]), also with the translation shifted by
//! ±[`MultistartSettings::offset`] along each axis (a partial source's centroid is biased):
//! 168 starts by default. Against a scene (a local Φ) the rotations also include turns about
//! the source's axis of least spread, its vertical ([`MultistartSettings::scene_turn_deg`]):
//! 224 starts, and the source where it was given ([`MultistartSettings::scene_as_given`]). Each is refined by a few LM steps on the pre-fitted Φ and scored on the
//! target points themselves ([`nn_score`]: the pre-fitted Φ is too coarse to separate
//! near-symmetric poses). The identity start and the best distinct starts are refined further;
//! among near-ties the least rotation wins ([`least_motion`], a prior for symmetric shapes). The
//! hypotheses carried on are that pick, the identity start and the best score, when distinct.
//! The first round of the starts reads [`Surface::coarse`]: a stored model's baked grid, or in
//! a full call against an object Φ baked for it ([`MultistartSettings::grid_cells`]).
//!
//! Entry point: [`initial_hypotheses`].

use std::num::NonZeroUsize;

use kiddo::SquaredEuclidean;
use nalgebra::{
    Isometry3, Matrix3, Point3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3,
};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::base::check;
use crate::base::error::Error;
use crate::field::Field;
use crate::geometry::cloud::{subsample, transformed_f32};
use crate::geometry::planes::pca_normal;
use crate::geometry::tree::{Tree, SEARCH_BOUND_MARGIN};
use crate::pipeline::surface::Surface;
use crate::solve::kernel::Kernel;
use crate::solve::lm::{Lm, LmSettings};

/// The smallest [`MultistartSettings::scene_turn_deg`] but 0: 68 turns, 644 starts.
const MIN_SCENE_TURN_DEG: f64 = 5.0;

/// The multi-start: initial hypotheses when no initial guess is given.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MultistartSettings {
    /// Try the 24 rotations of the cube group about the centroids. Default true (false:
    /// centroid alignment only, refined like a start).
    pub enabled: bool,
    /// Besides the centroid alignment, starts shifted by this much along ±x, ±y, ±z
    /// (normalised units); 0 disables. Default 0.1 (a partial source's centroid is biased).
    pub offset: f64,
    /// Source points each start uses at most (seeded subsample). Default 128.
    pub points: usize,
    /// LM steps per start on the pre-fitted Φ. Default 5.
    pub lm_steps: usize,
    /// Starts kept after the first round, for further refinement (the identity start always
    /// among them). Default 4.
    pub keep: usize,
    /// LM steps per kept start in the second round. Default 15.
    pub refine_steps: usize,
    /// Starts are scored by the mean squared distance of the moved points to their nearest
    /// target point, each truncated at this distance (normalised units). Default 0.05.
    pub truncation: f64,
    /// Starts whose score is within this fraction of the best are ties, and the one with the
    /// smallest rotation wins (a least-motion prior for symmetric shapes); also the margin by
    /// which a hypothesis may fit worse than the best and survive halfway through the
    /// coarse-to-fine loop. Default 0.25.
    pub tie: f64,
    /// Two starts are the same pose unless their rotations differ by more than this, degrees…
    /// Default 5.
    pub distinct_rotation_deg: f64,
    /// …or their translations by more than this, normalised units. Default 0.02.
    pub distinct_translation: f64,
    /// Pose hypotheses carried into the coarse-to-fine loop (the least-motion pick, the identity
    /// start and the best-scoring start, when distinct); the best-fitting one wins. Default 3.
    pub hypotheses: usize,
    /// When an initial guess was given and its result, after the robust re-run of
    /// [`crate::RobustMode::Auto`], still leaves more than that mode's `outside_share` of the
    /// source outside the target's coverage, or lies far from the guess (a distinct pose by
    /// [`Self::distinct_rotation_deg`] or [`Self::distinct_translation`]: the guess was not a
    /// close one), the registration runs again from the multi-start as if no guess had been
    /// given, and that result is returned when it leaves less of the source outside and its
    /// fitness does not fall by more than its outside share does ([`crate::RescueReport`]: a
    /// wrong pose of a partial overlap can leave a little less outside and fit far less). Only
    /// with `Auto` and [`Self::enabled`].
    /// Default true. Measured on the real LiDAR pairs from 56 starts 3 m and 20° off
    /// (`benches/lidar_compare.py --real --far-starts`): every start that ended in a wrong
    /// minimum left 24–80 % of the source outside (those that landed: 5–19 %). The same pairs
    /// the other way round (each KITTI frame onto its predecessor) ended 5 of 112 such starts
    /// slid 0.13–0.30 m along the street with 6–16 % outside (7 % at the truth): those results
    /// lie 20° from their guess, and the multi-start's run, which lands, leaves less outside.
    #[serde(default = "default_rescue")]
    pub rescue: bool,
    /// When Φ is being fitted (a full call against an object: a global Φ), its starts' first
    /// round reads Φ baked into a grid of this many cells a side
    /// ([`crate::field::baked::BakedGrid`], over the stored model's extent), as against a stored
    /// model (whose grid has [`crate::field::baked::BAKED_CELLS`]); 0 reads Φ itself. Default
    /// 32: 33³ nodes baked in ≈ 8 ms, against ≈ 30 ms for the 168 starts' 5 LM steps on the MLP
    /// (2-core AVX-512). Measured with `sdfreg eval --shapes ../shared/data/modelnet40-half1
    /// --pairs 36 --protocol all`: the multi-start 34.7 → 17.0 ms (median), the same errors on
    /// every shape but a few surfaces of revolution and near-symmetric ones, whose ties go
    /// either way (24 cells: 13.6 ms, two more of those flipped). A scene's Φ (local) and a
    /// stored model's keep theirs; settings written before this field read 0.
    #[serde(default)]
    pub grid_cells: usize,
    /// When Φ is local (a scene), the starts also turn the source about its axis of least
    /// spread by each multiple of this angle that is not one of 90°, degrees; 0 none, else at
    /// least 5. Default 30 (32 rotations, 224 starts). A scene's scans mostly differ by a turn
    /// about the vertical, which is that axis for a room or a street, and the cube group's 24
    /// rotations leave starts up to 45° from such a turn. Registered from nothing with the
    /// views preset, 5 of the 28 pairs of the procedural room's loop of 8 views (`cargo bench
    /// --bench views -- --write DIR`) ended wrong with a good fitness: four turned 180° (the
    /// room's near-symmetry; fitness 0.73–0.76 against 0.85–0.87 at the truth) and one 8.7° /
    /// 86 mm off; with these turns none. (The cube group's 24 rotations each composed with the
    /// turns, 72, left one other pair 10° off.) Objects (a global Φ) keep the cube group.
    #[serde(default = "default_scene_turn_deg")]
    pub scene_turn_deg: f64,
    /// When Φ is local (a scene), one more start: the source where it was given (the identity,
    /// no centroid alignment), scored like the others. Default true. Consecutive scans of one
    /// sensor, and scans in one site frame, are given near their pose; the centroids of two
    /// scans of different density are not near each other. On the real outdoor LiDAR pair
    /// (`../shared/data/lidar`), the source filtered to one point per 5 cm voxel (as GICP
    /// pipelines do) has its centroid 1.9 m from the raw target's along the street (0.4 m
    /// unfiltered); from the centroid-aligned starts the registration ended 1.05 m and 0.38°
    /// off (with 7 cm voxels 1.04 m), from this start 28 mm and 0.27° (27 mm, 0.21°), as the
    /// unfiltered source (29 mm, 0.21°). Objects (a global Φ) keep the centroid alignment.
    #[serde(default = "default_scene_as_given")]
    pub scene_as_given: bool,
}

fn default_rescue() -> bool {
    true
}

fn default_scene_turn_deg() -> f64 {
    30.0
}

fn default_scene_as_given() -> bool {
    true
}

impl Default for MultistartSettings {
    fn default() -> Self {
        Self {
            enabled: true,
            offset: 0.1,
            points: 128,
            lm_steps: 5,
            keep: 4,
            refine_steps: 15,
            truncation: 0.05,
            tie: 0.25,
            distinct_rotation_deg: 5.0,
            distinct_translation: 0.02,
            hypotheses: 3,
            rescue: default_rescue(),
            grid_cells: 32,
            scene_turn_deg: default_scene_turn_deg(),
            scene_as_given: default_scene_as_given(),
        }
    }
}

impl MultistartSettings {
    /// Checks every field; the error names it (`multistart.keep`, …).
    pub fn validate(&self) -> Result<(), Error> {
        check::non_negative("multistart.offset", self.offset)?;
        check::count_at_least("multistart.points", self.points, 1)?;
        check::count_at_least("multistart.keep", self.keep, 1)?;
        check::positive("multistart.truncation", self.truncation)?;
        check::non_negative("multistart.tie", self.tie)?;
        check::non_negative(
            "multistart.distinct_rotation_deg",
            self.distinct_rotation_deg,
        )?;
        check::non_negative("multistart.distinct_translation", self.distinct_translation)?;
        check::count_at_least("multistart.hypotheses", self.hypotheses, 1)?;
        check::off_or_at_least(
            "multistart.scene_turn_deg",
            self.scene_turn_deg,
            MIN_SCENE_TURN_DEG,
            "no turns",
        )
    }
}

/// The 24 rotations of the cube group: signed permutation matrices with determinant +1,
/// the identity first.
pub fn cube_rotations() -> Vec<Rotation3<f64>> {
    let perms = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    let mut out = Vec::with_capacity(24);
    for p in perms {
        for signs in 0..8 {
            let mut m = Matrix3::zeros();
            for (row, &col) in p.iter().enumerate() {
                m[(row, col)] = if signs >> row & 1 == 1 { -1.0 } else { 1.0 };
            }
            if m.determinant() > 0.0 {
                out.push(Rotation3::from_matrix_unchecked(m));
            }
        }
    }
    out
}

/// The direction along which `points` spread least (their PCA normal, [`pca_normal`]): the
/// vertical of a room's or a street's scan. `None` for fewer than three points.
fn least_spread_axis(points: &[Point3<f64>]) -> Option<Unit<Vector3<f64>>> {
    if points.len() < 3 {
        return None;
    }
    let c = crate::geometry::cloud::centroid(points);
    let cov: Matrix3<f64> = points.iter().map(|p| (p - c) * (p - c).transpose()).sum();
    Unit::try_new(pca_normal(cov).0, 1e-12)
}

/// Mean squared distance from `points` moved by `pose` to their nearest target point, each
/// truncated at `tau2` (normalised units²): how well a pose fits the target points themselves.
pub(crate) fn nn_score(
    tree: &Tree,
    points: &[Point3<f64>],
    pose: &Isometry3<f64>,
    tau2: f64,
) -> f64 {
    moved_score(tree, &transformed_f32(points, pose), 1.0, tau2)
}

/// [`nn_score`] of a solver's pose (and scale: distances in the source's units, see
/// [`Lm::distance_factor`]).
pub(crate) fn solver_score(tree: &Tree, points: &[Point3<f64>], lm: &Lm, tau2: f64) -> f64 {
    moved_score(tree, &lm.moved(points), lm.distance_factor(), tau2)
}

/// Mean of the `moved` points' squared nearest-target distances times `factor`, each truncated at
/// `tau2`. The k-d tree is searched within the truncation only (with a margin for its f32
/// distances): a point with no target point there scores `tau2` whatever its nearest, and a
/// wrong start's points far from the target no longer search the whole tree.
fn moved_score(tree: &Tree, moved: &[[f32; 3]], factor: f64, tau2: f64) -> f64 {
    let bound2 = (tau2 / factor * (1.0 + SEARCH_BOUND_MARGIN)) as f32;
    let sum: f64 = moved
        .iter()
        .map(|x| {
            tree.nearest_n_within::<SquaredEuclidean>(x, bound2, NonZeroUsize::MIN, false)
                .first()
                .map_or(tau2, |nn| (nn.distance as f64 * factor).min(tau2))
        })
        .sum();
    sum / moved.len().max(1) as f64
}

/// Index of the candidate with the least rotation among those whose score is within
/// `(1 + tie)` of the best (the least-motion prior for symmetric shapes).
pub(crate) fn least_motion(candidates: &[(f64, Isometry3<f64>)], tie: f64) -> usize {
    let best = candidates.iter().map(|c| c.0).fold(f64::INFINITY, f64::min);
    (0..candidates.len())
        .filter(|&i| candidates[i].0 <= best * (1.0 + tie))
        .min_by(|&a, &b| {
            candidates[a]
                .1
                .rotation
                .angle()
                .total_cmp(&candidates[b].1.rotation.angle())
        })
        .unwrap_or(0)
}

impl MultistartSettings {
    /// Whether two poses differ by more than [`Self::distinct_rotation_deg`] or
    /// [`Self::distinct_translation`].
    pub(crate) fn distinct(&self, a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
        a.rotation.angle_to(&b.rotation) > self.distinct_rotation_deg.to_radians()
            || (a.translation.vector - b.translation.vector).norm() > self.distinct_translation
    }

    /// The starts: each rotation about the centroids (`c_src` onto `c_tgt`), plus (when
    /// enabled and [`Self::offset`] > 0) the same with the translation shifted by ±offset along
    /// each axis. The rotations are the cube group's and, with a `turn` axis (the source's, a
    /// scene's), the turns about it by each multiple of [`Self::scene_turn_deg`] that is not
    /// one of 90°. The identity start comes first.
    fn starts(
        &self,
        c_src: Vector3<f64>,
        c_tgt: Vector3<f64>,
        turn: Option<Unit<Vector3<f64>>>,
    ) -> Vec<Isometry3<f64>> {
        let rotations = if self.enabled {
            let mut rotations = cube_rotations();
            let step = self.scene_turn_deg;
            if let Some(axis) = turn.filter(|_| step > 0.0) {
                let quarter = |deg: f64| (deg / 90.0 - (deg / 90.0).round()).abs() < 1e-9;
                rotations.extend(
                    (1..)
                        .map(|k| k as f64 * step)
                        .take_while(|deg| *deg < 360.0 - 1e-6)
                        .filter(|deg| !quarter(*deg))
                        .map(|deg| Rotation3::from_axis_angle(&axis, deg.to_radians())),
                );
            }
            rotations
        } else {
            vec![Rotation3::identity()]
        };
        let mut offsets = vec![Vector3::zeros()];
        if self.enabled && self.offset > 0.0 {
            for k in 0..3 {
                for sign in [1.0, -1.0] {
                    let mut v = Vector3::zeros();
                    v[k] = sign * self.offset;
                    offsets.push(v);
                }
            }
        }
        offsets
            .iter()
            .flat_map(|d| {
                rotations.iter().map(move |r| {
                    let q = UnitQuaternion::from_rotation_matrix(r);
                    Isometry3::from_parts(Translation3::from(c_tgt - r * c_src + d), q)
                })
            })
            .collect()
    }
}

/// What the multi-start produced.
pub(crate) struct Hypotheses {
    /// Poses (unit frame) for the coarse-to-fine loop: the least-motion pick first.
    pub poses: Vec<Isometry3<f64>>,
    /// Starts tried.
    pub starts: usize,
}

/// The initial hypotheses for the unit-frame `source` against the pre-fitted Φ of `fit`, with
/// `kernel` on the LM steps. The starts' steps read [`Surface::coarse`] (but the identity
/// start's), the finalists' Φ.
/// `rng` draws the starts' source subsample.
pub(crate) fn initial_hypotheses<S: Surface>(
    fit: &S,
    source: &[Point3<f64>],
    s: &MultistartSettings,
    lm: &LmSettings,
    kernel: impl Fn(&dyn Field, &[Point3<f64>], &Isometry3<f64>) -> Kernel + Sync,
    rng: &mut ChaCha8Rng,
) -> Hypotheses {
    let c_src = crate::geometry::cloud::centroid(source).coords;
    let c_tgt: Vector3<f64> = fit
        .target()
        .iter()
        .map(|p| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .sum::<Vector3<f64>>()
        / fit.target().len() as f64;
    let points = subsample(source, s.points, rng);
    let tau2 = s.truncation * s.truncation;
    let refine = |phi: &dyn Field, pose: Isometry3<f64>, steps: usize| {
        let mut solver = Lm::new(pose, lm);
        solver.run(phi, &points, kernel(phi, &points, &pose), steps);
        (
            nn_score(fit.tree(), &points, &solver.pose, tau2),
            solver.pose,
        )
    };
    let turn = fit.is_local().then(|| least_spread_axis(source)).flatten();
    let mut starts = s.starts(c_src, c_tgt, turn);
    if fit.is_local() && s.scene_as_given {
        // The source where it was given (no centroid alignment): see `scene_as_given`.
        starts.push(Isometry3::identity());
    }
    // Read once before the starts run side by side: a stored model's grid is baked on its
    // first read, and each start reading it first would bake a copy.
    fit.coarse();
    let mut candidates: Vec<(f64, Isometry3<f64>)> = starts
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            // The identity start, which the least-motion prior favours among ties, reads Φ.
            let phi: &dyn Field = if i == 0 { fit.phi() } else { fit.coarse() };
            refine(phi, *p, s.lm_steps)
        })
        .collect();
    // The identity start (plain centroid alignment) is always a finalist: with the least-motion
    // tie-break it wins whenever nothing fits clearly better. The others follow by score
    // (stable sort); starts that converged to the same pose count once.
    let identity = candidates[0].1;
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut kept: Vec<Isometry3<f64>> = vec![identity];
    for (_, p) in &candidates {
        if kept.iter().all(|k| s.distinct(k, p)) && kept.len() < s.keep {
            kept.push(*p);
        }
    }
    let finalists: Vec<(f64, Isometry3<f64>)> = kept
        .par_iter()
        .map(|p| refine(fit.phi(), *p, s.refine_steps))
        .collect();
    // Hypotheses: the least-motion pick among near-ties, the identity start and the best score
    // (distinct ones, at most `hypotheses`). The pre-fitted Φ is often too coarse to decide.
    let pick = least_motion(&finalists, s.tie);
    let best = (0..finalists.len())
        .min_by(|&a, &b| finalists[a].0.total_cmp(&finalists[b].0))
        .unwrap_or(0);
    let mut poses: Vec<Isometry3<f64>> = Vec::new();
    for i in [pick, 0, best] {
        let p = finalists[i].1;
        if poses.len() < s.hypotheses && poses.iter().all(|q| s.distinct(q, &p)) {
            poses.push(p);
        }
    }
    Hypotheses {
        poses,
        starts: starts.len(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn a_score_searched_within_the_truncation_is_the_unbounded_ones_to_the_bit() {
        // Source points from on the target to far beyond the truncation, at scale factors
        // about 1 and far from it: the truncated mean of the nearest distances, searched
        // within the truncation only, is that of unbounded searches, with points on both
        // sides of it.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let target: Vec<[f32; 3]> = crate::sim::shapes::blob(3000, &mut rng)
            .iter()
            .map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect();
        let tree = crate::geometry::tree::build_tree(&target);
        let moved: Vec<[f32; 3]> = (0..2000)
            .map(|i| {
                let p = target[(i * 7) % target.len()];
                let out = 1.0 + rng.random::<f32>().powi(2);
                [p[0] * out, p[1] * out, p[2] * out + 1e-3 * (i % 5) as f32]
            })
            .collect();
        for (factor, tau) in [(1.0, 0.05), (1.0, 0.2), (2.3, 0.05), (0.37, 0.1)] {
            let tau2: f64 = tau * tau;
            let unbounded: Vec<f64> = moved
                .iter()
                .map(|x| {
                    (tree.nearest_one::<SquaredEuclidean>(x).distance as f64 * factor).min(tau2)
                })
                .collect();
            let beyond = unbounded.iter().filter(|&&d| d == tau2).count();
            assert!(beyond > 100 && beyond < 1900, "{beyond} of 2000 truncated");
            let expected = unbounded.iter().sum::<f64>() / moved.len() as f64;
            let got = moved_score(&tree, &moved, factor, tau2);
            assert_eq!(
                got.to_bits(),
                expected.to_bits(),
                "factor {factor}, τ {tau}"
            );
        }
    }

    #[test]
    fn cube_group_has_24_distinct_proper_rotations() {
        let rs = cube_rotations();
        assert_eq!(rs.len(), 24);
        assert_eq!(rs[0], Rotation3::identity());
        for (i, a) in rs.iter().enumerate() {
            assert!((a.matrix().determinant() - 1.0).abs() < 1e-12);
            for b in &rs[i + 1..] {
                assert!(crate::geometry::se3::rotation_angle(a, b) > 1.0);
            }
        }
    }

    #[test]
    fn starts_shift_each_rotation_along_each_axis() {
        let s = MultistartSettings::default();
        let starts = s.starts(Vector3::new(0.1, 0.0, 0.0), Vector3::zeros(), None);
        assert_eq!(starts.len(), 24 * 7);
        assert_eq!(starts[0].translation.vector, Vector3::new(-0.1, 0.0, 0.0));
        let off = MultistartSettings {
            enabled: false,
            ..Default::default()
        };
        let z = Some(Vector3::z_axis());
        assert_eq!(off.starts(Vector3::zeros(), Vector3::zeros(), z).len(), 1);
    }

    #[test]
    fn a_scenes_starts_come_within_half_the_turn_step_of_every_turn_about_its_axis() {
        // A scene's vertical: the least spread of a flat box of points.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let flat: Vec<Point3<f64>> = (0..500)
            .map(|_| {
                let (x, y, z): (f64, f64, f64) = (rng.random(), rng.random(), rng.random());
                Point3::new(6.0 * x, 4.0 * y, 0.5 * z)
            })
            .collect();
        let axis = least_spread_axis(&flat).unwrap();
        assert!(axis.z.abs() > 0.99, "{axis:?}");
        let s = MultistartSettings::default();
        let rotations: Vec<UnitQuaternion<f64>> = s
            .starts(Vector3::zeros(), Vector3::zeros(), Some(axis))
            .iter()
            .map(|p| p.rotation)
            .collect();
        assert_eq!(rotations.len(), 32 * 7);
        let nearest = |deg: f64| {
            let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), deg.to_radians());
            rotations
                .iter()
                .map(|r| r.angle_to(&turn).to_degrees())
                .fold(f64::INFINITY, f64::min)
        };
        let worst = (0..360).map(|d| nearest(d as f64)).fold(0.0, f64::max);
        assert!(worst <= 15.5, "{worst}°");
        // The cube group alone leaves a turn of 45° 45° from every start.
        let cube = s.starts(Vector3::zeros(), Vector3::zeros(), None);
        let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 45f64.to_radians());
        let alone = cube
            .iter()
            .map(|p| p.rotation.angle_to(&turn).to_degrees())
            .fold(f64::INFINITY, f64::min);
        assert!(alone > 44.0, "{alone}°");
    }

    #[test]
    fn least_motion_prefers_the_smaller_rotation_among_ties() {
        let small = Isometry3::rotation(Vector3::new(0.0, 0.0, 0.1));
        let large = Isometry3::rotation(Vector3::new(0.0, 0.0, 2.0));
        assert_eq!(least_motion(&[(1.0, large), (1.1, small)], 0.25), 1);
        assert_eq!(least_motion(&[(1.0, large), (1.5, small)], 0.25), 0);
    }
}

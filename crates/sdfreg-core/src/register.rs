//! Registration: the coarse-to-fine loop that moves the source onto the target's neural SDF.
//!
//! Steps of [`register`] (paper Sec. 3.4; schedule from the prototype's measurements):
//! 1. validate both clouds; normalise with the target's bounding-box centre and largest side;
//! 2. pre-fit Φ on the target ([`FitSettings::prefit_steps`]);
//! 3. initial pose: the caller's guess, or centroid alignment plus a multi-start over the 24
//!    rotations of the cube group, each also with the translation shifted by
//!    ±[`RegisterSettings::multistart_offset`] along each axis, each start refined by a few LM
//!    steps on the frozen Φ and scored on
//!    the target points (truncated nearest-neighbour distance); near-ties go to the least
//!    rotation; up to [`RegisterSettings::hypotheses`] distinct poses go on;
//! 4. `alternations` times: add the moved source(s) to Φ's queries (eq. 18-1), refine Φ, take
//!    `lm_steps_per_alternation` LM steps per hypothesis; halfway, hypotheses that fit clearly
//!    worse are dropped, and at the end the best-fitting one is kept;
//! 5. final LM steps on the frozen Φ until converged;
//! 6. a robust point-to-plane polish against the target points ([`crate::polish`]);
//! 7. a search for translations that lay clearly more source points onto the target (a slide
//!    along a scene's walls that the smooth Φ does not see; [`crate::shift_search`]), each
//!    polished, kept only on a fitness gain;
//! 8. map the pose back to the user's frame and measure fitness, inlier RMSE, JᵀJ and the
//!    motions the data leave free ([`crate::degeneracy`]) there.
//!
//! **Frames**: the result's `t_target_source` maps source coordinates into the target frame,
//! `p_target = R p_source + t`, in the units of the inputs.

use std::time::{Duration, Instant};

use kiddo::SquaredEuclidean;
use nalgebra::{
    Isometry3, Matrix3, Matrix4, Matrix6, Point3, Rotation3, Translation3, UnitQuaternion, Vector3,
};
use rand::seq::index::sample;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::cloud::{centroid, transformed_f32, validate, Normalization};
use crate::degeneracy::{Degeneracy, FREE_MOTION_RATIO};
use crate::error::{Error, Role};
use crate::lm::{jacobian_row, Kernel, Lm, LmSettings, StepOutcome};
use crate::mlp::{Mlp, MlpSettings};
use crate::polish::{polish, PolishSettings};
use crate::sdf_fit::{FitSettings, SdfFitter, Tree};
use crate::shift_search::{occupancy_peaks, ShiftSearchSettings};

/// The robust re-run ([`RegisterSettings::robust_below_fitness`]) replaces the least-squares
/// result only if its fitness is at least this many times as high.
pub const ROBUST_GAIN: f64 = 1.3;

/// Fewest points accepted in either cloud.
pub const MIN_POINTS: usize = 10;

/// All settings of a registration. Lengths marked "normalised" are relative to the target's
/// largest bounding-box side (1 = the whole target).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RegisterSettings {
    /// The SDF network.
    pub mlp: MlpSettings,
    /// The SDF fit.
    pub fit: FitSettings,
    /// The Levenberg–Marquardt solver.
    pub lm: LmSettings,
    /// The final point-to-plane polish against the target points ([`crate::polish`]).
    pub polish: PolishSettings,
    /// The search for translations that lay more source points onto the target than the SDF's
    /// pose does ([`crate::shift_search`]).
    pub shift_search: ShiftSearchSettings,
    /// Coarse-to-fine alternations of SDF refinement and LM steps. Default 10.
    pub alternations: usize,
    /// LM steps per alternation. Default 2.
    pub lm_steps_per_alternation: usize,
    /// LM steps at most on the final, frozen SDF. Default 10.
    pub final_lm_steps: usize,
    /// Without an initial guess: try the 24 cube-group rotations about the centroid.
    /// Default true (false: centroid alignment only).
    pub multistart: bool,
    /// LM steps per multi-start candidate. Default 5.
    pub multistart_lm_steps: usize,
    /// Multi-start translations: besides the centroid alignment, starts shifted by this much
    /// along ±x, ±y, ±z (normalised units); 0 disables. Default 0.1.
    pub multistart_offset: f64,
    /// Source points used by each multi-start candidate at most. Default 128.
    pub multistart_points: usize,
    /// Candidates kept after the first multi-start round, for further refinement. Default 4.
    pub multistart_keep: usize,
    /// LM steps per kept candidate in the second round. Default 15.
    pub multistart_refine_steps: usize,
    /// Finalists' scores truncate each point's squared nearest-neighbour distance at this
    /// distance, normalised units. Default 0.05.
    pub multistart_truncation: f64,
    /// Candidates whose score is within this fraction of the best are ties, and the one with the
    /// smallest rotation wins (a least-motion prior for symmetric shapes). Default 0.25.
    pub multistart_tie: f64,
    /// Pose hypotheses carried through the coarse-to-fine loop (the multi-start's pick, the
    /// identity start and the best-scoring start, when distinct); the best-fitting one wins.
    /// Default 3.
    pub hypotheses: usize,
    /// A motion whose constraint eigenvalue is below this fraction of the largest is reported as
    /// free in [`Registration::degeneracy`] (see [`crate::degeneracy`]). Default
    /// [`FREE_MOTION_RATIO`] (2·10⁻³).
    pub free_motion_ratio: f64,
    /// Source points used by the LM at most; more are subsampled (seeded). Default 4096.
    pub max_source_points: usize,
    /// Target points used by the fit at most; more are subsampled (seeded). Default 100000.
    pub max_target_points: usize,
    /// A fixed Geman–McClure scale, normalised units; overrides [`Self::robust`]. Default None.
    pub robust_scale: Option<f64>,
    /// Geman–McClure kernel with its scale from the residuals: `c = κ · median |Φ(xᵢ)|` of the
    /// moved source points (at least [`Self::robust_floor`]), recomputed at every alternation
    /// with κ annealed geometrically from [`Self::robust_kappa_start`] to
    /// [`Self::robust_kappa_end`]. Source points
    /// with `|Φ| ≥ c` (outside the target's coverage) do not join Φ's query set. `false`: plain
    /// least squares. Default false: real partial scans need it (see `benches/realscans.py`),
    /// but on the ModelNet density protocol (500 source points) it loses 3 of 36 pairs.
    pub robust: bool,
    /// When [`Self::robust`] is off and the result's fitness is below this, the registration is
    /// run again with the robust kernel and [`Self::multistart_tie`] at most 0.05 (the settings
    /// that real partial scans need); its result is returned if it fits at least
    /// [`ROBUST_GAIN`] times as many source points ([`Registration::robust`] says which).
    /// 0 disables. Default 0.35, measured: least squares lands 12–42° off the bunny's
    /// neighbouring views at fitness 0.23–0.32 and 8° / 0.5 m off the 3DMatch pair at 0.343,
    /// where the robust kernel fits 1.4–2.5 times as many points; the paper's noisy ModelNet
    /// pairs fit at 0.369 and above (they are not run twice). A low fitness also comes from
    /// noise or sparse independent samples (ModelNet `-indep` pairs fit at 0.16–0.9): those
    /// run twice, and the robust result, within 1.22 times the fitness there, is not taken.
    pub robust_below_fitness: f64,
    /// κ at the first alternation (and in the multi-start). Default 3.
    pub robust_kappa_start: f64,
    /// κ at the last alternation and in the final LM. Default 1.
    pub robust_kappa_end: f64,
    /// Smallest scale, normalised units. Default 0.002.
    pub robust_floor: f64,
    /// A source point counts as an inlier (fitness, inlier RMSE) when its nearest target point
    /// is closer than this, normalised units. Default 0.02.
    pub inlier_distance: f64,
    /// Seed of every random choice; equal seeds give identical results. Default 0.
    pub seed: u64,
    /// Worker threads, 0 = one per core. The result does not depend on it. Default 0.
    pub threads: usize,
}

impl Default for RegisterSettings {
    fn default() -> Self {
        Self {
            mlp: MlpSettings::default(),
            fit: FitSettings::default(),
            lm: LmSettings::default(),
            polish: PolishSettings::default(),
            shift_search: ShiftSearchSettings::default(),
            alternations: 10,
            lm_steps_per_alternation: 2,
            final_lm_steps: 10,
            multistart: true,
            multistart_lm_steps: 5,
            multistart_offset: 0.1,
            multistart_points: 128,
            hypotheses: 3,
            multistart_keep: 4,
            multistart_refine_steps: 15,
            multistart_truncation: 0.05,
            multistart_tie: 0.25,
            free_motion_ratio: FREE_MOTION_RATIO,
            max_source_points: 4096,
            max_target_points: 100_000,
            robust_scale: None,
            robust: false,
            robust_below_fitness: 0.35,
            robust_kappa_start: 3.0,
            robust_kappa_end: 1.0,
            robust_floor: 0.002,
            inlier_distance: 0.02,
            seed: 0,
            threads: 0,
        }
    }
}

impl RegisterSettings {
    fn validate(&self) -> Result<(), Error> {
        let bad = |name, reason: &str| {
            Err(Error::InvalidSetting {
                name,
                reason: reason.into(),
            })
        };
        if self.mlp.width == 0 || self.mlp.depth == 0 {
            return bad("mlp", "width and depth must be at least 1");
        }
        if !(self.mlp.beta > 0.0 && self.mlp.beta.is_finite()) {
            return bad("mlp.beta", "must be a positive finite number");
        }
        if !(self.fit.prefit_lr > 0.0 && self.fit.refine_lr > 0.0) {
            return bad("fit.*_lr", "learning rates must be positive");
        }
        if self.fit.batch_queries == 0 || self.fit.query_pool == 0 {
            return bad("fit.batch_queries", "needs at least one query");
        }
        if self.max_source_points < MIN_POINTS || self.max_target_points < MIN_POINTS {
            return bad("max_*_points", "must be at least 10");
        }
        let p = &self.polish;
        if p.neighbours < 3 {
            return bad("polish.neighbours", "a local plane needs at least 3 points");
        }
        if !(p.max_distance > 0.0 && p.max_shift >= 0.0 && p.near_spacings >= 0.0) {
            return bad(
                "polish.max_*",
                "max_distance must be positive, max_shift and near_spacings ≥ 0",
            );
        }
        let h = &self.shift_search;
        if !(h.radius >= 0.0 && h.radius.is_finite() && h.voxel > 0.0 && h.voxel.is_finite()) {
            return bad(
                "shift_search.*",
                "radius must be ≥ 0 and voxel positive, both finite",
            );
        }
        if !(0.0..=1.0).contains(&h.min_gain) {
            return bad("shift_search.min_gain", "must be in [0, 1]");
        }
        if !(0.0..1.0).contains(&self.free_motion_ratio) {
            return bad("free_motion_ratio", "must be in [0, 1)");
        }
        if self.inlier_distance.is_nan() || self.inlier_distance <= 0.0 {
            return bad("inlier_distance", "must be positive");
        }
        let (k0, k1) = (self.robust_kappa_start, self.robust_kappa_end);
        if !(k0 > 0.0 && k1 > 0.0 && k0.is_finite() && k1.is_finite()) {
            return bad("robust_kappa_*", "must be positive finite numbers");
        }
        if !(0.0..=1.0).contains(&self.robust_below_fitness) {
            return bad("robust_below_fitness", "must be in [0, 1]");
        }
        if !(self.robust_floor > 0.0 && self.robust_floor.is_finite()) {
            return bad("robust_floor", "must be a positive finite number");
        }
        if let Some(c) = self.robust_scale {
            if !(c > 0.0 && c.is_finite()) {
                return bad("robust_scale", "must be a positive finite number");
            }
        }
        Ok(())
    }
}

/// Why the registration stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub enum StopReason {
    /// The last LM step was below both tolerances.
    SmallStep,
    /// No damping lowered the cost any more: a (local) minimum.
    NoDecrease,
    /// `final_lm_steps` ran out before convergence.
    MaxIterations,
}

impl StopReason {
    /// Snake-case name: `small_step`, `no_decrease` or `max_iterations`.
    pub fn name(&self) -> &'static str {
        match self {
            StopReason::SmallStep => "small_step",
            StopReason::NoDecrease => "no_decrease",
            StopReason::MaxIterations => "max_iterations",
        }
    }
}

/// Progress reported while registering.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Stage {
    /// Pre-fitting the SDF (Adam steps done, total).
    Prefit(usize, usize),
    /// Multi-start over initial rotations.
    Multistart,
    /// Coarse-to-fine alternation (done, total).
    Alternation(usize, usize),
    /// Final LM on the frozen SDF.
    Final,
}

/// The outcome of [`register`].
#[derive(Clone, Debug, PartialEq)]
pub struct Registration {
    /// Maps source coordinates into the target frame (`p_target = R p_source + t`), user units.
    pub t_target_source: Isometry3<f64>,
    /// Whether the final LM converged (small step or no further decrease).
    pub converged: bool,
    /// Why it stopped.
    pub stop_reason: StopReason,
    /// LM iterations in total (multi-start excluded).
    pub iterations: usize,
    /// Mean squared SDF value of the moved source points, user units².
    pub cost: f64,
    /// Fraction of source points whose nearest target point is within the inlier distance.
    pub fitness: f64,
    /// RMSE of the inliers' nearest-neighbour distances, user units.
    pub inlier_rmse: f64,
    /// The inlier distance used, user units.
    pub inlier_distance: f64,
    /// `JᵀJ` (6×6) at the result in the target frame, twist `[ω (rad); v (user units)]` about the
    /// target origin: the information matrix of a left perturbation of `t_target_source`.
    pub information: Matrix6<f64>,
    /// Which motions the data leave (nearly) free — e.g. the spin of a surface of revolution
    /// about its axis. When [`Degeneracy::is_degenerate`], the pose along those motions is
    /// arbitrary. Points in the target frame, user units.
    pub degeneracy: Degeneracy,
    /// Whether the robust kernel produced this result: [`RegisterSettings::robust`] was on, or
    /// least squares fitted below [`RegisterSettings::robust_below_fitness`] and the robust run
    /// fitted better.
    pub robust: bool,
    /// Wall time (both runs when the robust kernel was tried after least squares).
    pub time: Duration,
}

impl Registration {
    /// `t_target_source` as a homogeneous 4×4 matrix.
    pub fn matrix(&self) -> Matrix4<f64> {
        self.t_target_source.to_homogeneous()
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

fn subsample(points: &[Point3<f64>], max: usize, rng: &mut ChaCha8Rng) -> Vec<Point3<f64>> {
    if points.len() <= max {
        return points.to_vec();
    }
    let mut idx = sample(rng, points.len(), max).into_vec();
    idx.sort_unstable();
    idx.into_iter().map(|i| points[i]).collect()
}

/// Mean squared distance from `points` moved by `pose` to their nearest target point, each
/// truncated at `tau2` (normalised units²): how well a pose fits the target points themselves.
fn nn_score(
    tree: &crate::sdf_fit::Tree,
    points: &[Point3<f64>],
    pose: &Isometry3<f64>,
    tau2: f64,
) -> f64 {
    let sum: f64 = transformed_f32(points, pose)
        .iter()
        .map(|x| (tree.nearest_one::<SquaredEuclidean>(x).distance as f64).min(tau2))
        .sum();
    sum / points.len().max(1) as f64
}

/// Fitness — the fraction of the (already moved) `points` within `sqrt(thr2)` of a target
/// point — and the RMS distance of those inliers, normalised units.
fn inlier_stats(tree: &Tree, points: &[[f32; 3]], thr2: f64) -> (f64, f64) {
    let thr2 = thr2 as f32;
    let d2: Vec<f32> = points
        .par_iter()
        .map(|x| tree.nearest_one::<SquaredEuclidean>(x).distance)
        .collect();
    let inliers: Vec<f64> = d2
        .iter()
        .filter(|&&d| d <= thr2)
        .map(|&d| d as f64)
        .collect();
    let fitness = inliers.len() as f64 / points.len().max(1) as f64;
    let rms = if inliers.is_empty() {
        0.0
    } else {
        (inliers.iter().sum::<f64>() / inliers.len() as f64).sqrt()
    };
    (fitness, rms)
}

/// Index of the candidate with the least rotation among those whose score is within
/// `(1 + tie)` of the best (the least-motion prior for symmetric shapes).
fn least_motion(candidates: &[(f64, Isometry3<f64>)], tie: f64) -> usize {
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

/// Whether two poses differ by more than 5° or 0.02 normalised units.
fn distinct(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
    a.rotation.angle_to(&b.rotation) > 5f64.to_radians()
        || (a.translation.vector - b.translation.vector).norm() > 0.02
}

/// Registers `source` onto `target`; see the module docs. `init` (user frame, maps source into
/// target) replaces the multi-start when given.
pub fn register(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    init: Option<&Isometry3<f64>>,
    settings: &RegisterSettings,
) -> Result<Registration, Error> {
    register_with_progress(source, target, init, settings, &|_| {})
}

/// [`register`] with a progress callback (called from the calling thread).
pub fn register_with_progress(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    init: Option<&Isometry3<f64>>,
    settings: &RegisterSettings,
    progress: &(dyn Fn(Stage) + Sync),
) -> Result<Registration, Error> {
    settings.validate()?;
    validate(source, Role::Source, MIN_POINTS)?;
    validate(target, Role::Target, MIN_POINTS)?;
    if let Some(t) = init {
        if !t.to_homogeneous().iter().all(|v| v.is_finite()) {
            return Err(Error::InvalidInit);
        }
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(settings.threads)
        .build()
        .map_err(|e| Error::ThreadPool(e.to_string()))?;
    pool.install(|| {
        let first = run(source, target, init, settings, progress)?;
        if settings.robust
            || settings.robust_scale.is_some()
            || first.fitness >= settings.robust_below_fitness
        {
            return Ok(first);
        }
        // A poor fit with least squares: most likely partial overlap (points beyond the
        // target's coverage pull); try what real scans need.
        let scans = RegisterSettings {
            robust: true,
            multistart_tie: settings.multistart_tie.min(0.05),
            ..settings.clone()
        };
        let second = run(source, target, init, &scans, progress)?;
        let time = first.time + second.time;
        let best = if second.fitness >= ROBUST_GAIN * first.fitness {
            second
        } else {
            first
        };
        Ok(Registration { time, ..best })
    })
}

fn run(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    init: Option<&Isometry3<f64>>,
    s: &RegisterSettings,
    progress: &(dyn Fn(Stage) + Sync),
) -> Result<Registration, Error> {
    let start = Instant::now();
    let norm = Normalization::from_target(target)?;
    let mut rng = ChaCha8Rng::seed_from_u64(s.seed);
    let src_unit: Vec<Point3<f64>> = subsample(source, s.max_source_points, &mut rng)
        .iter()
        .map(|p| norm.to_unit_f64(p))
        .collect();
    let tgt_unit: Vec<[f32; 3]> = subsample(target, s.max_target_points, &mut rng)
        .iter()
        .map(|p| norm.to_unit(p))
        .collect();
    let (src_lo, src_hi) = crate::cloud::bounding_box(&src_unit).expect("validated non-empty");
    if (src_hi - src_lo).max() < 1e-9 {
        return Err(Error::NoExtent {
            role: Role::Source,
            extent: (src_hi - src_lo).max() * norm.scale,
        });
    }
    // The Geman–McClure scale from the residuals Φ of the moved source, with κ (see
    // `RegisterSettings::robust`).
    let adaptive_scale = |phi: &[f32], kappa: f64| {
        let mut a: Vec<f32> = phi.iter().map(|v| v.abs()).collect();
        let mid = a.len() / 2;
        let median = *a.select_nth_unstable_by(mid, f32::total_cmp).1 as f64;
        (kappa * median).max(s.robust_floor)
    };
    // The kernel at a pose, with κ.
    let kernel_at = |mlp: &Mlp, points: &[Point3<f64>], pose: &Isometry3<f64>, kappa: f64| match (
        s.robust_scale,
        s.robust,
    ) {
        (Some(c), _) => Kernel::GemanMcClure(c),
        (None, false) => Kernel::L2,
        (None, true) => {
            let (phi, _) = mlp.eval(&transformed_f32(points, pose), false);
            Kernel::GemanMcClure(adaptive_scale(&phi, kappa))
        }
    };
    let (kappa0, kappa1) = (s.robust_kappa_start, s.robust_kappa_end);
    let kappa = |k: usize| {
        let f = k as f64 / (s.alternations.max(2) - 1) as f64;
        kappa0 * (kappa1 / kappa0).powf(f.min(1.0))
    };

    let mut fit = SdfFitter::new(tgt_unit, &s.mlp, &s.fit, s.seed ^ 0x5DF);
    let chunk = 50.max(s.fit.prefit_steps / 10);
    let mut done = 0;
    while done < s.fit.prefit_steps {
        let n = chunk.min(s.fit.prefit_steps - done);
        fit.train(n, s.fit.prefit_lr);
        done += n;
        progress(Stage::Prefit(done, s.fit.prefit_steps));
    }

    let tau2 = s.multistart_truncation * s.multistart_truncation;
    // Initial pose, unit frame.
    let hypotheses: Vec<Isometry3<f64>> = match init {
        Some(t) => vec![norm.pose_to_unit(t)],
        None => {
            progress(Stage::Multistart);
            let c_src = centroid(&src_unit).coords;
            let c_tgt: Vector3<f64> = fit
                .target()
                .iter()
                .map(|p| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64))
                .sum::<Vector3<f64>>()
                / fit.target().len() as f64;
            let rotations = if s.multistart {
                cube_rotations()
            } else {
                vec![Rotation3::identity()]
            };
            let mlp = fit.mlp();
            let ms_source = subsample(&src_unit, s.multistart_points, &mut rng);
            // Candidates are scored on the target points themselves (the pre-fitted SDF is too
            // coarse to separate near-symmetric poses): mean squared distance of the moved
            // points to their nearest target point, truncated at `multistart_truncation`.
            let tree = fit.tree();
            let refine = |pose: Isometry3<f64>, steps: usize| {
                let kernel = kernel_at(mlp, &ms_source, &pose, kappa0);
                let mut lm = Lm::new(pose, &s.lm);
                for _ in 0..steps {
                    let outcome = lm.step(mlp, &ms_source, kernel);
                    if lm.is_converged(&outcome) {
                        break;
                    }
                }
                let score = nn_score(tree, &ms_source, &lm.pose, tau2);
                (score, lm.pose)
            };
            // Starts: each rotation about the centroids, plus (when `multistart_offset` > 0) the
            // same with the translation shifted by ±offset along each axis, because a partial
            // source's centroid is biased. The identity start comes first.
            let o = s.multistart_offset;
            let mut offsets = vec![Vector3::zeros()];
            if s.multistart && o > 0.0 {
                for k in 0..3 {
                    for sign in [1.0, -1.0] {
                        let mut v = Vector3::zeros();
                        v[k] = sign * o;
                        offsets.push(v);
                    }
                }
            }
            let starts: Vec<Isometry3<f64>> = offsets
                .iter()
                .flat_map(|d| {
                    rotations.iter().map(move |r| {
                        let q = UnitQuaternion::from_rotation_matrix(r);
                        Isometry3::from_parts(Translation3::from(c_tgt - r * c_src + d), q)
                    })
                })
                .collect();
            let mut candidates: Vec<(f64, Isometry3<f64>)> = starts
                .par_iter()
                .map(|p| refine(*p, s.multistart_lm_steps))
                .collect();
            // The identity start (plain centroid alignment) is always a finalist: with the
            // least-motion tie-break it wins whenever nothing fits clearly better. The others
            // follow by score (stable sort); starts that converged to the same pose count once.
            let identity = candidates[0].1;
            candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mut kept: Vec<Isometry3<f64>> = vec![identity];
            for (_, p) in &candidates {
                if kept.iter().all(|k| distinct(k, p)) && kept.len() < s.multistart_keep.max(1) {
                    kept.push(*p);
                }
            }
            let finalists: Vec<(f64, Isometry3<f64>)> = kept
                .par_iter()
                .map(|p| refine(*p, s.multistart_refine_steps))
                .collect();
            // Hypotheses carried through the coarse-to-fine loop: the least-motion pick among
            // near-ties, the identity start and the best score (distinct ones, at most
            // `hypotheses`). The pre-fitted SDF is often too coarse to decide between them.
            let pick = least_motion(&finalists, s.multistart_tie);
            let best = (0..finalists.len())
                .min_by(|&a, &b| finalists[a].0.total_cmp(&finalists[b].0))
                .unwrap_or(0);
            let mut out: Vec<Isometry3<f64>> = Vec::new();
            for i in [pick, 0, best] {
                let p = finalists[i].1;
                if out.len() < s.hypotheses.max(1) && out.iter().all(|q| distinct(q, &p)) {
                    out.push(p);
                }
            }
            out
        }
    };

    // Coarse-to-fine (eq. 18-1). Every hypothesis's moved source joins the query set: queries
    // carry their true nearest target point, so extra ones only teach Φ more of the far field.
    // With a robust kernel, points at |Φ| ≥ c (outside the target's coverage) are left out.
    let mut lms: Vec<Lm> = hypotheses.iter().map(|p| Lm::new(*p, &s.lm)).collect();
    for k in 0..s.alternations {
        // One evaluation of Φ at the moved source serves the kernel's scale and the gate.
        let mut kernels = Vec::with_capacity(lms.len());
        for lm in &lms {
            let moved = transformed_f32(&src_unit, &lm.pose);
            if s.robust_scale.is_none() && !s.robust {
                fit.add_source_queries(&moved);
                kernels.push(Kernel::L2);
                continue;
            }
            let (phi, _) = fit.mlp().eval(&moved, false);
            let c = s
                .robust_scale
                .unwrap_or_else(|| adaptive_scale(&phi, kappa(k)));
            let near: Vec<[f32; 3]> = moved
                .iter()
                .zip(&phi)
                .filter(|(_, v)| (v.abs() as f64) < c)
                .map(|(x, _)| *x)
                .collect();
            fit.add_source_queries(&near);
            kernels.push(Kernel::GemanMcClure(c));
        }
        fit.train(s.fit.refine_steps, s.fit.refine_lr);
        for (lm, &kernel) in lms.iter_mut().zip(&kernels) {
            lm.lambda = s.lm.initial_lambda;
            for _ in 0..s.lm_steps_per_alternation {
                let outcome = lm.step(fit.mlp(), &src_unit, kernel);
                if lm.is_converged(&outcome) {
                    break;
                }
            }
        }
        progress(Stage::Alternation(k + 1, s.alternations));
        // Halfway, hypotheses that fit clearly worse than the best are dropped.
        if k + 1 == s.alternations / 2 && lms.len() > 1 {
            let scores: Vec<f64> = lms
                .iter()
                .map(|lm| nn_score(fit.tree(), &src_unit, &lm.pose, tau2))
                .collect();
            let best = scores.iter().copied().fold(f64::INFINITY, f64::min);
            lms = lms
                .into_iter()
                .zip(scores)
                .filter(|(_, score)| *score <= best * (1.0 + s.multistart_tie))
                .map(|(lm, _)| lm)
                .collect();
        }
    }
    let scored: Vec<(f64, Isometry3<f64>)> = lms
        .iter()
        .map(|lm| (nn_score(fit.tree(), &src_unit, &lm.pose, tau2), lm.pose))
        .collect();
    let mut lm = lms.swap_remove(least_motion(&scored, s.multistart_tie));
    progress(Stage::Final);
    let kernel = kernel_at(fit.mlp(), &src_unit, &lm.pose, kappa1);
    let mut stop = StopReason::MaxIterations;
    lm.lambda = s.lm.initial_lambda;
    for _ in 0..s.final_lm_steps {
        let outcome = lm.step(fit.mlp(), &src_unit, kernel);
        if lm.is_converged(&outcome) {
            stop = if outcome == StepOutcome::NoDecrease {
                StopReason::NoDecrease
            } else {
                StopReason::SmallStep
            };
            break;
        }
    }

    let mut pose_unit = polish(&src_unit, fit.target(), fit.tree(), &lm.pose, &s.polish).pose;
    // Translations that lay clearly more source points onto the target (a slide along a
    // scene's walls that the smooth Φ does not see), each polished, kept on a fitness gain.
    // The kept pose's fitness and inlier RMS are also the result's.
    let thr2 = s.inlier_distance * s.inlier_distance;
    let mut moved = transformed_f32(&src_unit, &pose_unit);
    let (mut fitness, mut inlier_rms) = inlier_stats(fit.tree(), &moved, thr2);
    let mut best = fitness + s.shift_search.min_gain;
    for peak in occupancy_peaks(&moved, fit.target(), &s.shift_search) {
        let start = Translation3::from(peak.offset) * pose_unit;
        let candidate = polish(&src_unit, fit.target(), fit.tree(), &start, &s.polish).pose;
        let candidate_moved = transformed_f32(&src_unit, &candidate);
        let (f, rms) = inlier_stats(fit.tree(), &candidate_moved, thr2);
        if f >= best {
            best = f;
            (fitness, inlier_rms) = (f, rms);
            pose_unit = candidate;
            moved = candidate_moved;
        }
    }

    // Quality measures in the user's frame.
    let (phi, grads) = fit.mlp().eval(&moved, true);
    let mut information = Matrix6::zeros();
    let mut cost = 0.0;
    let mut moved_user = Vec::with_capacity(moved.len());
    let mut normals = Vec::with_capacity(moved.len());
    for ((x, g), r) in moved.iter().zip(&grads).zip(&phi) {
        let xu = Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64) * norm.scale + norm.centre;
        let n = Vector3::new(g[0] as f64, g[1] as f64, g[2] as f64);
        let j = jacobian_row(&xu, &n);
        information += j * j.transpose();
        cost += (*r as f64 * norm.scale).powi(2);
        moved_user.push(Point3::from(xu));
        normals.push(n);
    }
    let degeneracy = Degeneracy::analyse(&moved_user, &normals, s.free_motion_ratio);

    Ok(Registration {
        t_target_source: norm.pose_from_unit(&pose_unit),
        converged: stop != StopReason::MaxIterations,
        stop_reason: stop,
        iterations: lm.iterations,
        cost: cost / moved.len() as f64,
        fitness,
        inlier_rmse: inlier_rms * norm.scale,
        inlier_distance: s.inlier_distance * norm.scale,
        information,
        degeneracy,
        robust: s.robust || s.robust_scale.is_some(),
        time: start.elapsed(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cube_group_has_24_distinct_proper_rotations() {
        let rs = cube_rotations();
        assert_eq!(rs.len(), 24);
        assert_eq!(rs[0], Rotation3::identity());
        for (i, a) in rs.iter().enumerate() {
            assert!((a.matrix().determinant() - 1.0).abs() < 1e-12);
            for b in &rs[i + 1..] {
                assert!(crate::se3::rotation_angle(a, b) > 1.0);
            }
        }
    }
}

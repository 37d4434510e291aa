//! Registration: the paper's stages (Sec. 3.4) as one list, and its result.
//!
//! [`register`] moves the source onto the target's neural SDF Φ in these stages, each a function
//! of its own:
//! 1. **normalise** — validate; both clouds into the target's unit frame (bounding-box centre,
//!    largest side 1), subsampled to [`RegisterSettings::max_source_points`] /
//!    [`RegisterSettings::max_target_points`] ([`crate::cloud`]);
//! 2. **pre-fit Φ** on the target ([`crate::FitSettings::prefit_steps`] Adam steps, eq. 18–20);
//! 3. **initial hypotheses** — the caller's guess, or the multi-start ([`crate::multistart`]);
//! 4. **coarse-to-fine** (eq. 18-1) — alternate Φ refinement with the moved source among its
//!    queries and LM steps (eq. 9–13) per hypothesis; keep the best ([`crate::coarse_to_fine`]);
//! 5. **final LM** on the frozen Φ until converged;
//! 6. **robust re-run** when needed — [`crate::RobustMode::Auto`] redoes a poorly fitting
//!    least-squares result with the Geman–McClure kernel ([`crate::robust`]);
//! 7. **polish** — robust point-to-plane steps against the target points ([`crate::polish`]);
//! 8. **shift search** — translations that lay clearly more source points onto the target, each
//!    polished, kept on a fitness gain ([`crate::shift_search`]);
//! 9. **measure** — fitness, inlier RMSE, JᵀJ and the free motions, in the user's frame
//!    ([`crate::degeneracy`]).
//!
//! [`Registration::stages`] records what each stage did.
//!
//! **Frames**: the result's `t_target_source` maps source coordinates into the target frame,
//! `p_target = R p_source + t`, in the units of the inputs.

use std::borrow::Cow;
use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Matrix4, Matrix6, Point3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::cloud::{subsample, validate, Normalization};
use crate::coarse_to_fine::{alternate, final_lm, kernel_at, Alternated};
use crate::degeneracy::Degeneracy;
use crate::error::{Error, Role};
use crate::field::{Field, Surface};
use crate::lm::{Lm, StopReason};
use crate::measure::quality;
use crate::model::SdfModel;
use crate::multistart::initial_hypotheses;
use crate::polish::{polish, PolishOutcome};
use crate::report::{
    CoarseToFineReport, FinalLmReport, InitialReport, PolishReport, PolishResult, PoseChange,
    RobustReport, ShiftSearchReport, Stages,
};
use crate::robust::{
    keep_rerun, outside_share, rerun_settings, KernelPolicy, LeastSquaresFit, RobustMode,
};
use crate::settings::{RegisterSettings, MIN_POINTS};
use crate::shift_search::{search, Searched};

/// Progress reported while registering.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
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

/// The outcome of [`register`]. Serialises with serde (the Python binding pickles it that way).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Registration {
    /// Maps source coordinates into the target frame (`p_target = R p_source + t`), user units.
    pub t_target_source: Isometry3<f64>,
    /// Whether the stage that set the final pose converged (the polish's last pass when it was
    /// applied, else the final LM): see [`Self::stop_reason`].
    pub converged: bool,
    /// Why the stage that set the final pose stopped, judged by the LM's tolerances
    /// ([`crate::LmSettings::rotation_tolerance`], [`crate::LmSettings::translation_tolerance`]):
    /// a polish that ran out of iterations with a last step below them counts as
    /// [`StopReason::SmallStep`] ([`Stages::polish`] keeps its own stop reason, under its
    /// tighter tolerance).
    pub stop_reason: StopReason,
    /// LM iterations of the winning hypothesis (coarse-to-fine and final; multi-start excluded).
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
    /// Whether the robust kernel produced this result (see [`Stages::robust`]).
    pub robust: bool,
    /// What each stage did.
    pub stages: Stages,
    /// Wall time (both runs when the robust kernel was tried after least squares).
    pub time: Duration,
}

impl Registration {
    /// `t_target_source` as a homogeneous 4×4 matrix.
    pub fn matrix(&self) -> Matrix4<f64> {
        self.t_target_source.to_homogeneous()
    }
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
    let start = Instant::now();
    check_inputs(source, init, settings)?;
    validate(target, Role::Target, MIN_POINTS)?;
    let mut r = in_pool(settings.threads, || {
        let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
        let source = subsample(source, settings.max_source_points, &mut rng);
        let model = SdfModel::fit_drawing(target, settings, &mut rng, progress)?;
        register_drawn(
            &model.norm,
            &model.fitter,
            &source,
            rng,
            init,
            settings,
            true,
            progress,
        )
    })??;
    r.time = start.elapsed();
    Ok(r)
}

/// [`crate::SdfModel::register`] (`refine` false), [`crate::SdfModel::register_refined`] and
/// [`crate::MeshModel::register`]: `source` against `surface`, the target in the unit frame of
/// `norm`.
pub(crate) fn against<S: Surface>(
    norm: &Normalization,
    surface: &S,
    source: &[Point3<f64>],
    init: Option<&Isometry3<f64>>,
    settings: &RegisterSettings,
    refine: bool,
    progress: &(dyn Fn(Stage) + Sync),
) -> Result<Registration, Error> {
    check_inputs(source, init, settings)?;
    in_pool(settings.threads, || {
        against_in_pool(norm, surface, source, init, settings, refine, progress)
    })?
}

/// [`against`] within the current pool, `settings` already checked.
fn against_in_pool<S: Surface>(
    norm: &Normalization,
    surface: &S,
    source: &[Point3<f64>],
    init: Option<&Isometry3<f64>>,
    settings: &RegisterSettings,
    refine: bool,
    progress: &(dyn Fn(Stage) + Sync),
) -> Result<Registration, Error> {
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let source = subsample(source, settings.max_source_points, &mut rng);
    register_drawn(
        norm, surface, &source, rng, init, settings, refine, progress,
    )
}

/// [`crate::SdfModel::track`]: every frame in one worker pool, each from the last good frame's
/// pose. (A constant-velocity prediction from the last two was tried: on the procedural
/// sequence of the tests it fed the registrations' jitter of a few tenths of a degree along the
/// shape's least constrained rotation back into the next start, and the error grew by half per
/// frame from frame 28 on.)
pub(crate) fn track<'a>(
    model: &SdfModel,
    frames: impl IntoIterator<Item = &'a [Point3<f64>]> + Send,
    init: &Isometry3<f64>,
    settings: &RegisterSettings,
) -> Result<Vec<Result<Registration, Error>>, Error> {
    check_settings(Some(init), settings)?;
    let frames: Vec<&[Point3<f64>]> = frames.into_iter().collect();
    in_pool(settings.threads, || {
        let frozen = model.frozen();
        let mut last = *init;
        frames
            .into_iter()
            .map(|frame| {
                let start = Instant::now();
                let r = validate(frame, Role::Source, MIN_POINTS).and_then(|()| {
                    against_in_pool(
                        &model.norm,
                        &frozen,
                        frame,
                        Some(&last),
                        settings,
                        false,
                        &|_| {},
                    )
                });
                if let Ok(r) = &r {
                    last = r.t_target_source;
                }
                r.map(|mut r| {
                    r.time = start.elapsed();
                    r
                })
            })
            .collect()
    })
}

/// Checks the settings, the source and the initial guess.
fn check_inputs(
    source: &[Point3<f64>],
    init: Option<&Isometry3<f64>>,
    settings: &RegisterSettings,
) -> Result<(), Error> {
    check_settings(init, settings)?;
    validate(source, Role::Source, MIN_POINTS)
}

/// Checks the settings and the initial guess.
fn check_settings(init: Option<&Isometry3<f64>>, settings: &RegisterSettings) -> Result<(), Error> {
    settings.validate()?;
    if init.is_some_and(|t| !t.to_homogeneous().iter().all(|v| v.is_finite())) {
        return Err(Error::InvalidInit);
    }
    Ok(())
}

/// Runs `f` in a pool of `threads` workers (0 = one per core), never rayon's global one.
pub(crate) fn in_pool<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> Result<R, Error> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| Error::ThreadPool(e.to_string()))?;
    Ok(pool.install(f))
}

/// Stages 3–9 for the already subsampled `source` against `surface` (the target in the unit
/// frame of `norm`), `rng` being the registration's random stream after the subsampling; the
/// robust re-run (stage 6) starts again from the same surface and stream.
#[allow(clippy::too_many_arguments)]
fn register_drawn<S: Surface>(
    norm: &Normalization,
    surface: &S,
    source: &[Point3<f64>],
    rng: ChaCha8Rng,
    init: Option<&Isometry3<f64>>,
    s: &RegisterSettings,
    refine: bool,
    progress: &(dyn Fn(Stage) + Sync),
) -> Result<Registration, Error> {
    let start = Instant::now();
    let unit = in_unit_frame(norm, source)?;
    let run = |s: &RegisterSettings, policy| {
        let mut rng = rng.clone();
        run(surface, &unit, &mut rng, init, s, policy, refine, progress)
    };
    let first = run(s, s.robust.first_run());
    let outside = |r: &Registration| {
        let pose = unit.norm.pose_to_unit(&r.t_target_source);
        let moved = crate::cloud::transformed_f32(&unit.source, &pose);
        outside_share(&moved, surface.target(), surface.tree())
    };
    let mut r = robust_rerun(first, s, outside, run);
    r.time = start.elapsed();
    Ok(r)
}

/// Stage 6: the robust re-run of [`RobustMode::Auto`] after a least-squares result that fits
/// poorly (most likely partial overlap: points beyond the target's coverage pull); the better
/// fit is returned, with [`Stages::robust`] saying what happened. `outside` gives the share of
/// the source a result leaves outside the target's coverage (asked in that mode only).
fn robust_rerun(
    first: Registration,
    settings: &RegisterSettings,
    outside: impl FnOnce(&Registration) -> f64,
    rerun: impl FnOnce(&RegisterSettings, KernelPolicy) -> Registration,
) -> Registration {
    match settings.robust.mode {
        RobustMode::Auto { .. } => {}
        RobustMode::Off => return with_robust(first, RobustReport::Off),
        _ => return with_robust(first, RobustReport::FromStart),
    }
    let least = LeastSquaresFit {
        fitness: first.fitness,
        outside_share: outside(&first),
    };
    let least_squares_fitness = least.fitness;
    let least_squares_outside = least.outside_share;
    let Some((scans, policy, cause)) = rerun_settings(settings, least) else {
        let report = RobustReport::NotNeeded {
            least_squares_fitness,
            least_squares_outside,
        };
        return with_robust(first, report);
    };
    let second = rerun(&scans, policy);
    let robust_fitness = second.fitness;
    if keep_rerun(
        &settings.robust.mode,
        cause,
        least_squares_fitness,
        robust_fitness,
    ) {
        let report = RobustReport::RerunKept {
            least_squares_fitness,
            least_squares_outside,
            robust_fitness,
        };
        with_robust(second, report)
    } else {
        let report = RobustReport::RerunRejected {
            least_squares_fitness,
            least_squares_outside,
            robust_fitness,
        };
        with_robust(first, report)
    }
}

/// `r` with its robust report.
fn with_robust(mut r: Registration, report: RobustReport) -> Registration {
    r.stages.robust = report;
    r
}

/// One registration run with the kernel `policy` against `surface` (a private copy of Φ refined
/// when `refine`): stages 3–9 of the module docs, less the robust re-run (which calls it again).
#[allow(clippy::too_many_arguments)]
fn run<S: Surface>(
    surface: &S,
    unit: &Unit,
    rng: &mut ChaCha8Rng,
    init: Option<&Isometry3<f64>>,
    s: &RegisterSettings,
    policy: KernelPolicy,
    refine: bool,
    progress: &(dyn Fn(Stage) + Sync),
) -> Registration {
    let mut fit = Cow::Borrowed(surface);
    let (hypotheses, initial) = initial_pose(&*fit, unit, init, s, policy, rng, progress);
    let Alternated {
        mut lm,
        survivors,
        winner,
    } = alternate(
        &mut fit,
        &unit.source,
        &hypotheses,
        s,
        policy,
        refine,
        progress,
    );
    let after_alternations = lm.pose;
    progress(Stage::Final);
    let lm_stop = final_lm(&*fit, &unit.source, &mut lm, &s.coarse_to_fine, policy);
    let polish_settings = s.polish.for_target(fit.is_local());
    let planes = fit
        .is_local()
        .then(|| fit.target_planes(polish_settings.neighbours));
    let polish_from = |start: &Isometry3<f64>| {
        polish(
            &unit.source,
            fit.target(),
            fit.tree(),
            start,
            &polish_settings,
            planes.as_deref(),
        )
    };
    let polished = polish_from(&lm.pose);
    let searched = search(
        &unit.source,
        fit.target(),
        fit.tree(),
        &polished.pose,
        &s.shift_search,
        polish_from,
        s.inlier_distance,
    );
    let trace = Trace {
        start: hypotheses[winner],
        initial,
        survivors,
        winner,
        after_alternations,
        lm,
        lm_stop,
        polished,
        searched,
    };
    measure(unit, &*fit, s, policy, trace)
}

/// What the stages of one run produced, in order.
struct Trace {
    /// The winning hypothesis's starting pose (unit frame).
    start: Isometry3<f64>,
    initial: InitialReport,
    /// Hypotheses alive at the end of the alternations, and the winner's index.
    survivors: usize,
    winner: usize,
    /// The winner's pose after the alternations (unit frame).
    after_alternations: Isometry3<f64>,
    /// The solver after the final LM.
    lm: Lm,
    lm_stop: StopReason,
    polished: PolishOutcome,
    searched: Searched,
}

/// Stage 9: the result in the user's frame — its quality against the target and Φ, and what
/// each stage did.
fn measure<S: Surface>(
    unit: &Unit,
    fit: &S,
    s: &RegisterSettings,
    policy: KernelPolicy,
    t: Trace,
) -> Registration {
    let change = |a: &Isometry3<f64>, b: &Isometry3<f64>| {
        PoseChange::between(&unit.source, a, b, unit.norm.scale)
    };
    let after_alternations = t.after_alternations;
    let polish_enabled = s.polish.iterations > 0;
    let setter = t.searched.taken.as_ref().unwrap_or(&t.polished);
    let stop_reason = if polish_enabled && !setter.undone {
        settled(setter, &s.lm)
    } else {
        t.lm_stop
    };
    let stages = Stages {
        initial: InitialReport {
            rotation_deg: t.start.rotation.angle().to_degrees(),
            ..t.initial
        },
        coarse_to_fine: CoarseToFineReport {
            survivors: t.survivors,
            winner: t.winner,
            change: change(&t.start, &after_alternations),
        },
        final_lm: FinalLmReport {
            stop_reason: t.lm_stop,
            change: change(&after_alternations, &t.lm.pose),
        },
        robust: RobustReport::Off,
        polish: polish_report(
            &t.polished,
            polish_enabled,
            change(&t.lm.pose, &t.polished.pose),
        ),
        shift_search: ShiftSearchReport {
            peaks: t.searched.peaks,
            taken: t.searched.taken.is_some(),
            fitness_gain: t.searched.fitness - t.searched.start_fitness,
            change: change(&t.polished.pose, &t.searched.pose),
        },
    };
    let q = quality(
        fit.phi(),
        &t.searched.moved,
        &unit.norm,
        s.free_motion_ratio,
    );
    Registration {
        t_target_source: unit.norm.pose_from_unit(&t.searched.pose),
        converged: stop_reason.converged(),
        stop_reason,
        iterations: t.lm.iterations,
        cost: q.cost,
        fitness: t.searched.fitness,
        inlier_rmse: t.searched.inlier_rms * unit.norm.scale,
        inlier_distance: s.inlier_distance * unit.norm.scale,
        information: q.information,
        degeneracy: q.degeneracy,
        robust: policy.is_robust(),
        stages,
        time: Duration::ZERO,
    }
}

/// The source in the target's unit frame.
struct Unit {
    /// The similarity from the user's frame into the unit frame.
    norm: Normalization,
    /// Source points (subsampled), unit frame.
    source: Vec<Point3<f64>>,
}

/// Stage 1 for the source: the (subsampled) source in the target's unit frame; a source with no
/// extent there is refused. (The target's part is [`SdfModel::fit`]'s.)
fn in_unit_frame(norm: &Normalization, source: &[Point3<f64>]) -> Result<Unit, Error> {
    let source: Vec<Point3<f64>> = source.iter().map(|p| norm.to_unit_f64(p)).collect();
    let (lo, hi) = crate::cloud::bounding_box(&source).expect("validated non-empty");
    if (hi - lo).max() < 1e-9 {
        return Err(Error::NoExtent {
            role: Role::Source,
            extent: (hi - lo).max() * norm.scale,
        });
    }
    Ok(Unit {
        norm: *norm,
        source,
    })
}

/// Stage 3: the hypotheses (unit frame) the coarse-to-fine loop starts from — the caller's
/// guess, or the multi-start's — and the report of where they came from.
fn initial_pose<S: Surface>(
    fit: &S,
    unit: &Unit,
    init: Option<&Isometry3<f64>>,
    s: &RegisterSettings,
    policy: KernelPolicy,
    rng: &mut ChaCha8Rng,
    progress: &(dyn Fn(Stage) + Sync),
) -> (Vec<Isometry3<f64>>, InitialReport) {
    if let Some(t) = init {
        let given = InitialReport {
            given: true,
            starts: 0,
            hypotheses: 1,
            rotation_deg: 0.0,
        };
        return (vec![unit.norm.pose_to_unit(t)], given);
    }
    progress(Stage::Multistart);
    let kernel = |phi: &dyn Field, points: &[Point3<f64>], pose: &Isometry3<f64>| {
        kernel_at(phi, points, pose, policy, policy.kappa_start())
    };
    let found = initial_hypotheses(fit, &unit.source, &s.multistart, &s.lm, kernel, rng);
    let report = InitialReport {
        given: false,
        starts: found.starts,
        hypotheses: found.poses.len(),
        rotation_deg: 0.0,
    };
    (found.poses, report)
}

/// Why the polish stopped, judged by the registration's convergence tolerances (the LM's): its
/// own tolerance is far tighter ([`crate::PolishSettings::tolerance`]), so a polish that ran out
/// of iterations with a last step below the LM's tolerances has settled as far as the
/// registration asks ([`StopReason::SmallStep`]).
fn settled(p: &PolishOutcome, lm: &crate::LmSettings) -> StopReason {
    let small = p.last_step[0] < lm.rotation_tolerance && p.last_step[1] < lm.translation_tolerance;
    match p.stop_reason {
        StopReason::MaxIterations if small => StopReason::SmallStep,
        reason => reason,
    }
}

/// Stage 7's report: what the polish did, `change` being how far it moved the source.
fn polish_report(p: &PolishOutcome, enabled: bool, change: PoseChange) -> PolishReport {
    let result = match (enabled, p.undone, p.snapped) {
        (false, _, _) => PolishResult::Off,
        (true, true, _) => PolishResult::Undone,
        (true, false, true) => PolishResult::Snapped,
        (true, false, false) => PolishResult::Applied,
    };
    PolishReport {
        result,
        iterations: p.iterations,
        stop_reason: p.stop_reason,
        change,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn outcome(stop_reason: StopReason, last_step: [f64; 2]) -> PolishOutcome {
        PolishOutcome {
            pose: Isometry3::identity(),
            iterations: 50,
            stop_reason,
            last_step,
            snapped: false,
            undone: false,
        }
    }

    #[test]
    fn a_polish_at_its_cap_has_settled_when_its_last_step_is_below_the_lm_tolerances() {
        let lm = crate::LmSettings::default();
        let capped = |step| settled(&outcome(StopReason::MaxIterations, step), &lm);
        assert_eq!(capped([4e-7, 2e-7]), StopReason::SmallStep);
        assert_eq!(capped([1.2e-5, 5e-6]), StopReason::MaxIterations);
        assert_eq!(capped([1e-6, 2e-5]), StopReason::MaxIterations);
        let stuck = outcome(StopReason::NoDecrease, [f64::INFINITY; 2]);
        assert_eq!(settled(&stuck, &lm), StopReason::NoDecrease);
    }
}

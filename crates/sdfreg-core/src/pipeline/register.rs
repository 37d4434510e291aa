//! Registration: the paper's stages (Sec. 3.4) as one list; the entry points.
//!
//! [`register`] moves the source onto the target's neural SDF Φ in these stages, each a function
//! of its own:
//! 0. **direction** — a source with many times the target's points is registered the other
//!    way round, the denser cloud as Φ's, and the result inverted ([`crate::pipeline::direction`]);
//! 1. **normalise** — validate; both clouds into the target's unit frame (bounding-box centre,
//!    largest side 1), subsampled to [`RegisterSettings::max_source_points`] /
//!    [`RegisterSettings::max_target_points`] ([`crate::geometry::cloud`]);
//! 2. **pre-fit Φ** on the target ([`crate::FitSettings::prefit_steps`] Adam steps, eq. 18–20);
//! 3. **initial hypotheses** — the caller's guess, or the multi-start ([`crate::pipeline::multistart`]);
//!    a guess whose result leaves too much of the source outside the target's coverage, or
//!    lies far from the guess, is run again from the multi-start
//!    ([`crate::MultistartSettings::rescue`]);
//! 4. **coarse-to-fine** (eq. 18-1) — alternate Φ refinement with the moved source among its
//!    queries and LM steps (eq. 9–13) per hypothesis; keep the best ([`crate::pipeline::coarse_to_fine`]);
//! 5. **final LM** on the frozen Φ until converged;
//! 6. **robust re-run** when needed — [`crate::RobustMode::Auto`] redoes a poorly fitting
//!    least-squares result with the Geman–McClure kernel ([`crate::pipeline::rerun`]);
//! 7. **polish** — robust point-to-plane steps against the target points ([`crate::pipeline::polish`];
//!    a scene's with more of the source's points when [`crate::PolishSettings::scene_points`] asks);
//! 8. **shift search** — translations that lay clearly more source points onto the target, each
//!    polished, kept on a fitness gain ([`crate::pipeline::shift_search`]);
//! 9. **measure** — fitness, inlier RMSE, JᵀJ and the free motions, in the user's frame
//!    ([`crate::pipeline::registration`], [`crate::solve::degeneracy`]).
//!
//! [`Registration::stages`] records what each stage did.
//!
//! **Frames**: the result's `t_target_source` maps source coordinates into the target frame,
//! `p_target = R p_source + t`, in the units of the inputs. With a scale
//! ([`crate::ScaleSettings::enabled`], [`crate::pipeline::scale`]) it is the rigid part of the
//! similarity `p_target = s R p_source + t`, `s` in [`Registration::scale`]: stage 3 starts from
//! each scale start, and stages 4–7 carry the scale as a seventh unknown.

use std::borrow::Cow;
use std::sync::OnceLock;
use std::time::Instant;

use nalgebra::{Isometry3, Point3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::base::error::{Error, Role};
use crate::base::pool::in_pool;
use crate::field::baked::{BakedGrid, BAKED_HALF_EXTENT};
use crate::field::local_grid::ModelKind;
use crate::field::Field;
use crate::geometry::cloud::{scaled_f32, subsample, usable, Normalization};
use crate::pipeline::coarse_to_fine::{alternate, final_lm, kernel_at, Alternated};
use crate::pipeline::direction::{invert, swaps};
use crate::pipeline::multistart::initial_hypotheses;
use crate::pipeline::polish::polish;
use crate::pipeline::registration::{measure, Registration, Trace};
use crate::pipeline::report::{GlobalRerunReport, InitialReport, RescueReport, Stage, StageTimes};
use crate::pipeline::rerun::{robust_rerun, with_other_run};
use crate::pipeline::robust::{outside_share, KernelPolicy, RobustMode};
use crate::pipeline::scale::scale_starts;
use crate::pipeline::settings::{RegisterSettings, MIN_POINTS};
use crate::pipeline::shift_search::search;
use crate::pipeline::surface::{Surface, WithGrid};
use crate::pipeline::target::prefit;
use crate::solve::lm::{Lm, ScaleDof};

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
    check_settings(init, settings)?;
    let (source, source_left_out) = usable(source, Role::Source, MIN_POINTS)?;
    let (target, target_left_out) = usable(target, Role::Target, MIN_POINTS)?;
    let mut r = in_pool(settings.threads, || {
        // Stage 0: the denser cloud as the target ([`crate::pipeline::direction`]).
        if swaps(settings, &source, &target) {
            let init = init.map(|t| t.inverse());
            let back = one_way(&target, &source, init.as_ref(), settings, progress)
                .map_err(Error::with_roles_swapped)?;
            return invert(back, &source, &target, settings);
        }
        one_way(&source, &target, init, settings, progress)
    })??;
    r.time = start.elapsed();
    r.source_left_out = source_left_out;
    r.target_left_out = target_left_out;
    Ok(r)
}

/// Stages 1–9 of a full call, `source` onto `target` (usable points).
fn one_way(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    init: Option<&Isometry3<f64>>,
    settings: &RegisterSettings,
    progress: &(dyn Fn(Stage) + Sync),
) -> Result<Registration, Error> {
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let drawn = subsample(source, settings.max_source_points, &mut rng);
    let prefit_start = Instant::now();
    let (norm, fitter) = prefit(target, settings, false, &mut rng, progress)?;
    let prefit_time = prefit_start.elapsed();
    let mut r = register_drawn(
        &norm, &fitter, &drawn, source, rng, init, settings, true, progress,
    )?;
    r.stage_times.prefit = prefit_time;
    let local = &settings.fit.local;
    if fitter.is_local() && local.chosen_by_auto() && r.fitness < local.global_rerun_below_fitness {
        let mut global = settings.clone();
        global.fit.local.kind = ModelKind::Global;
        let other = one_way(source, target, init, &global, progress)?;
        r = global_rerun(r, other);
    }
    Ok(r)
}

/// Of a scene's full call with a local Φ (`local`) and its run with a global Φ (`global`), the
/// one fitting more of the source (the local one on a tie), with
/// [`Stages::global_rerun`](crate::Stages) saying which and the other's time in `other_run`.
fn global_rerun(local: Registration, global: Registration) -> Registration {
    let (local_fitness, global_fitness) = (local.fitness, global.fitness);
    let (kept, other, report) = if global_fitness > local_fitness {
        let report = GlobalRerunReport::Kept {
            local_fitness,
            global_fitness,
        };
        (global, local, report)
    } else {
        let report = GlobalRerunReport::Rejected {
            local_fitness,
            global_fitness,
        };
        (local, global, report)
    };
    let mut kept = with_other_run(kept, &other);
    kept.stage_times.other_run += other.stage_times.prefit;
    kept.stages.global_rerun = report;
    kept
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
    check_settings(init, settings)?;
    let (source, left_out) = usable(source, Role::Source, MIN_POINTS)?;
    let mut r = in_pool(settings.threads, || {
        against_in_pool(norm, surface, &source, init, settings, refine, progress)
    })??;
    r.source_left_out = left_out;
    Ok(r)
}

/// [`against`] within the current pool, `settings` already checked.
pub(crate) fn against_in_pool<S: Surface>(
    norm: &Normalization,
    surface: &S,
    source: &[Point3<f64>],
    init: Option<&Isometry3<f64>>,
    settings: &RegisterSettings,
    refine: bool,
    progress: &(dyn Fn(Stage) + Sync),
) -> Result<Registration, Error> {
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let drawn = subsample(source, settings.max_source_points, &mut rng);
    register_drawn(
        norm, surface, &drawn, source, rng, init, settings, refine, progress,
    )
}

/// Checks the settings and the initial guess.
pub(crate) fn check_settings(
    init: Option<&Isometry3<f64>>,
    settings: &RegisterSettings,
) -> Result<(), Error> {
    settings.validate()?;
    if init.is_some_and(|t| !t.to_homogeneous().iter().all(|v| v.is_finite())) {
        return Err(Error::InvalidInit);
    }
    Ok(())
}

/// Stages 3–9 for the already subsampled `source` against `surface` (the target in the unit
/// frame of `norm`), `rng` being the registration's random stream after the subsampling; the
/// robust re-run (stage 6) starts again from the same surface and stream. `dense` is the usable
/// source the subsample was drawn from: a scene's polish may move more of its points
/// ([`crate::PolishSettings::scene_points`]).
#[allow(clippy::too_many_arguments)]
fn register_drawn<S: Surface>(
    norm: &Normalization,
    surface: &S,
    source: &[Point3<f64>],
    dense: &[Point3<f64>],
    rng: ChaCha8Rng,
    init: Option<&Isometry3<f64>>,
    s: &RegisterSettings,
    refine: bool,
    progress: &(dyn Fn(Stage) + Sync),
) -> Result<Registration, Error> {
    let start = Instant::now();
    let mut unit = in_unit_frame(norm, source)?;
    unit.polished = polish_points(norm, surface.is_local(), dense, source, s);
    // Baked at most once: the robust re-run and the rescue's run start from the same Φ.
    let grid = OnceLock::new();
    let run_from = |init: Option<&Isometry3<f64>>, s: &RegisterSettings, policy| {
        let mut rng = rng.clone();
        let runs = Runs {
            surface,
            grid: &grid,
            refine,
        };
        run(&runs, &unit, &mut rng, init, s, policy, progress)
    };
    let outside = |r: &Registration| {
        let moved = if s.scale.enabled {
            let pose = unit.norm.similarity_to_unit(&r.t_target_source, r.scale);
            scaled_f32(&unit.source, r.scale, &pose)
        } else {
            let pose = unit.norm.pose_to_unit(&r.t_target_source);
            crate::geometry::cloud::transformed_f32(&unit.source, &pose)
        };
        outside_share(&moved, surface.tree(), surface.spacing())
    };
    // Stage 6: the run, and its robust re-run when least squares fitted poorly.
    let from = |init: Option<&Isometry3<f64>>| {
        let first = run_from(init, s, s.robust.first_run());
        robust_rerun(first, s, outside, |s, policy| run_from(init, s, policy))
    };
    let mut r = from(init);
    if let Some(share) = rescue_share(init, s) {
        let far = init.is_some_and(|guess| {
            let to_unit = |t: &Isometry3<f64>| unit.norm.pose_to_unit(t);
            s.multistart
                .distinct(&to_unit(guess), &to_unit(&r.t_target_source))
        });
        r = rescue(r, share, far, outside, || from(None));
    }
    r.time = start.elapsed();
    Ok(r)
}

/// The share of the source outside the target's coverage above which a given guess's result
/// is rescued by the multi-start ([`crate::MultistartSettings::rescue`]), when it may be.
fn rescue_share(init: Option<&Isometry3<f64>>, s: &RegisterSettings) -> Option<f64> {
    match s.robust.mode {
        RobustMode::Auto { outside_share, .. }
            if init.is_some() && s.multistart.enabled && s.multistart.rescue =>
        {
            Some(outside_share)
        }
        _ => None,
    }
}

/// A given guess's result `given` when it leaves at most `share` of the source outside the
/// target's coverage (`outside`) and does not lie `far` from the guess; else the result from
/// the multi-start (`from_scratch`) when that leaves less outside without fitting
/// correspondingly less ([`rescued`]), with
/// [`Stages::rescue`](crate::Stages) saying which, and the time of the run not returned in
/// `other_run`. The fitness matters where the overlap is partial: a wrong pose can leave a
/// little less outside and fit far less (3DMatch's 06→00 from the published pose, `--model
/// local`: the guess's result 0.84° off, 0.439 outside, fitness 0.485; the multi-start's 8.6°
/// off, 0.428 outside, fitness 0.324).
fn rescue(
    given: Registration,
    share: f64,
    far: bool,
    outside: impl Fn(&Registration) -> f64,
    from_scratch: impl FnOnce() -> Registration,
) -> Registration {
    let given_outside = given
        .stages
        .robust
        .returned_outside()
        .unwrap_or_else(|| outside(&given));
    let within = given_outside <= share;
    if within && !far {
        return given;
    }
    // Run for lying far from the guess alone: its outside share was within the bound.
    let far_from_guess = within;
    let scratch = from_scratch();
    let rescue_outside = outside(&scratch);
    let (given_fitness, rescue_fitness) = (given.fitness, scratch.fitness);
    let (kept, other, report) = if rescued(
        [given_outside, given_fitness],
        [rescue_outside, rescue_fitness],
    ) {
        let report = RescueReport::Kept {
            given_outside,
            rescue_outside,
            given_fitness,
            rescue_fitness,
            far_from_guess,
        };
        (scratch, given, report)
    } else {
        let report = RescueReport::Rejected {
            given_outside,
            rescue_outside,
            given_fitness,
            rescue_fitness,
            far_from_guess,
        };
        (given, scratch, report)
    };
    let mut kept = with_other_run(kept, &other);
    kept.stages.rescue = report;
    kept
}

/// Whether the multi-start's result (`[outside share, fitness]`) replaces the guess's: it leaves
/// less of the source outside the target's coverage, and its fitness falls by less than that
/// (its fitness minus its outside share is larger). On a street the fitness saturates (a pose
/// slid 1.4 m along KITTI's street fits 0.998 of the source, the truth 0.996) and the outside
/// share tells them apart (0.39 against 0.16); with a partial overlap the outside share barely
/// moves and the fitness does (3DMatch, below).
fn rescued(given: [f64; 2], rescue: [f64; 2]) -> bool {
    rescue[0] < given[0] && rescue[1] - rescue[0] > given[1] - given[0]
}

/// What every run of one registration shares.
struct Runs<'a, S> {
    /// The target (a private copy of its Φ refined by each run when `refine`).
    surface: &'a S,
    /// Φ as the target came, baked into the multi-start's grid by the first run that reads it
    /// ([`crate::MultistartSettings::grid_cells`]; the re-runs change neither it nor Φ).
    grid: &'a OnceLock<BakedGrid>,
    /// Whether Φ is refined (a full call, [`crate::SdfModel::register_refined`]).
    refine: bool,
}

/// One registration run with the kernel `policy` against `runs.surface`: stages 3–9 of the
/// module docs, less the robust re-run (which calls it again).
fn run<S: Surface>(
    runs: &Runs<'_, S>,
    unit: &Unit,
    rng: &mut ChaCha8Rng,
    init: Option<&Isometry3<f64>>,
    s: &RegisterSettings,
    policy: KernelPolicy,
    progress: &(dyn Fn(Stage) + Sync),
) -> Registration {
    let (surface, refine) = (runs.surface, runs.refine);
    let mut times = StageTimes::default();
    let mut clock = Instant::now();
    let mut lap = |time: &mut std::time::Duration| {
        *time = clock.elapsed();
        clock = Instant::now();
    };
    let mut fit = Cow::Borrowed(surface);
    // The multi-start on a Φ being fitted reads it baked into a coarse grid
    // (`MultistartSettings::grid_cells`); a stored model's surface has its own grid already.
    let grid = (refine && init.is_none() && s.multistart.enabled && !surface.is_local())
        .then_some(s.multistart.grid_cells)
        .filter(|&cells| cells > 0)
        .map(|cells| {
            runs.grid
                .get_or_init(|| BakedGrid::bake(surface.phi(), cells, BAKED_HALF_EXTENT))
        });
    let (hypotheses, initial) = match grid {
        Some(grid) => {
            let baked = WithGrid::new(surface, grid);
            initial_pose(&baked, unit, init, s, policy, rng, progress)
        }
        None => initial_pose(surface, unit, init, s, policy, rng, progress),
    };
    let starts: Vec<Isometry3<f64>> = hypotheses.iter().map(|lm| lm.pose).collect();
    lap(&mut times.initial);
    let Alternated {
        mut lm,
        survivors,
        winner,
    } = alternate(
        &mut fit,
        &unit.source,
        hypotheses,
        &s.schedule(surface.is_local()),
        policy,
        refine,
        progress,
    );
    lap(&mut times.coarse_to_fine);
    let after_alternations = lm.pose;
    progress(Stage::Final);
    let lm_stop = final_lm(
        &*fit,
        &unit.source,
        &mut lm,
        &s.coarse_to_fine,
        policy,
        refine,
    );
    lap(&mut times.final_lm);
    let polish_settings = s.polish.for_target(fit.is_local());
    let planes = (fit.is_local() || polish_settings.target_planes)
        .then(|| fit.target_planes(polish_settings.neighbours));
    let polish_with = |source: &[Point3<f64>], start: &Isometry3<f64>, scale| {
        polish(
            source,
            fit.target(),
            fit.tree(),
            fit.spacing(),
            start,
            &polish_settings,
            planes.as_deref(),
            scale,
        )
    };
    let free_scale = lm.scale.map(|d| (d.s, (d.min, d.max)));
    let points = unit.polished.as_deref().unwrap_or(&unit.source);
    let polished = polish_with(points, &lm.pose, free_scale);
    lap(&mut times.polish);
    // With a scale, the search moves the source at the polished scale.
    let source: Cow<'_, [Point3<f64>]> = match free_scale {
        None => Cow::Borrowed(&unit.source),
        Some(_) => Cow::Owned(unit.source.iter().map(|p| p * polished.scale).collect()),
    };
    let polish_from = |start: &Isometry3<f64>| polish_with(&source, start, None);
    let plan =
        s.shift_search
            .for_target(fit.is_local(), fit.spacing(), s.inlier_distance, &polished);
    let searched = search(
        &source,
        fit.target(),
        fit.tree(),
        planes.as_deref(),
        &polished.pose,
        &plan,
        polish_from,
        s.inlier_distance,
    );
    lap(&mut times.shift_search);
    let trace = Trace {
        start: starts[winner],
        initial,
        survivors,
        winner,
        after_alternations,
        lm,
        lm_stop,
        polished,
        searched,
        times,
        scale: free_scale.map(|_| polished.scale),
    };
    measure(&source, &unit.norm, &*fit, s, policy.is_robust(), trace)
}

/// The source in the target's unit frame.
struct Unit {
    /// The similarity from the user's frame into the unit frame.
    norm: Normalization,
    /// Source points (subsampled), unit frame.
    source: Vec<Point3<f64>>,
    /// A scene's polish points ([`crate::PolishSettings::scene_points`]), unit frame; `None`
    /// polishes [`Self::source`].
    polished: Option<Vec<Point3<f64>>>,
}

/// Seed offset of the draw of a scene's polish points, apart from the registration's stream.
const POLISH_DRAW: u64 = 0x5ce7_e9a1;

/// A scene's polish points in the unit frame of `norm`: [`crate::PolishSettings::scene_points`]
/// of `dense` (the usable source) drawn by their own stream; `None` for an object, with a scale
/// (whose polish moves the registration's own points), when the setting is 0 or no more than
/// the registration's own points `drawn`.
fn polish_points(
    norm: &Normalization,
    local: bool,
    dense: &[Point3<f64>],
    drawn: &[Point3<f64>],
    s: &RegisterSettings,
) -> Option<Vec<Point3<f64>>> {
    let n = s.polish.scene_points.min(dense.len());
    if !local || s.scale.enabled || n <= drawn.len() {
        return None;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(s.seed ^ POLISH_DRAW);
    let points = subsample(dense, n, &mut rng);
    Some(points.iter().map(|p| norm.to_unit_f64(p)).collect())
}

/// Stage 1 for the source: the (subsampled) source in the target's unit frame; a source with no
/// extent there, or more than 10⁹ times the target's, is refused ([`Error::NoExtent`] for a
/// point, else [`Error::ScalesApart`]). (The target's part is [`SdfModel::fit`]'s.)
fn in_unit_frame(norm: &Normalization, source_points: &[Point3<f64>]) -> Result<Unit, Error> {
    let source: Vec<Point3<f64>> = source_points.iter().map(|p| norm.to_unit_f64(p)).collect();
    let (lo, hi) = crate::geometry::cloud::bounding_box(&source).expect("validated non-empty");
    let unit_extent = (hi - lo).max();
    if !(1e-9..=1e9).contains(&unit_extent) {
        // Its own size: a cloud of one point (refused as the target would be), or one whose
        // size the target's unit frame swallows (the centre's subtraction) or blows up.
        let (_, extent) = crate::geometry::cloud::centre_and_extent(source_points, Role::Source)?;
        return Err(Error::ScalesApart {
            role: Role::Source,
            extent,
            other_extent: norm.scale,
        });
    }
    Ok(Unit {
        norm: *norm,
        source,
        polished: None,
    })
}

/// Stage 3: the hypotheses (unit frame; a solver each, with the scale when it is estimated) the
/// coarse-to-fine loop starts from — the caller's guess, or the multi-start's, from each scale
/// start — and the report of where they came from.
fn initial_pose<S: Surface>(
    fit: &S,
    unit: &Unit,
    init: Option<&Isometry3<f64>>,
    s: &RegisterSettings,
    policy: KernelPolicy,
    rng: &mut ChaCha8Rng,
    progress: &(dyn Fn(Stage) + Sync),
) -> (Vec<Lm>, InitialReport) {
    let mut report = InitialReport {
        given: init.is_some(),
        starts: 0,
        hypotheses: 0,
        rotation_deg: 0.0,
    };
    if !s.scale.enabled {
        let poses = match init {
            Some(t) => vec![unit.norm.pose_to_unit(t)],
            None => {
                let found = multistart(fit, &unit.source, s, policy, rng, progress);
                report.starts = found.starts;
                found.poses
            }
        };
        report.hypotheses = poses.len();
        return (
            poses.into_iter().map(|p| Lm::new(p, &s.lm)).collect(),
            report,
        );
    }
    let (scales, (min, max)) = scale_starts(&s.scale, &unit.source, fit.target());
    let dof = |s: f64| ScaleDof {
        s,
        min,
        max,
        reference: scales[0],
    };
    let mut solvers = Vec::new();
    for &scale in &scales {
        let poses = match init {
            Some(t) => vec![unit.norm.similarity_to_unit(t, scale)],
            None => {
                let scaled: Vec<Point3<f64>> = unit.source.iter().map(|p| p * scale).collect();
                let found = multistart(fit, &scaled, s, policy, rng, progress);
                report.starts += found.starts;
                found.poses
            }
        };
        solvers.extend(
            poses
                .into_iter()
                .map(|p| Lm::with_scale(p, dof(scale), &s.lm)),
        );
    }
    report.hypotheses = solvers.len();
    (solvers, report)
}

/// The multi-start's hypotheses for `source` (unit frame) against `fit`.
fn multistart<S: Surface>(
    fit: &S,
    source: &[Point3<f64>],
    s: &RegisterSettings,
    policy: KernelPolicy,
    rng: &mut ChaCha8Rng,
    progress: &(dyn Fn(Stage) + Sync),
) -> crate::pipeline::multistart::Hypotheses {
    progress(Stage::Multistart);
    let kernel = |phi: &dyn Field, points: &[Point3<f64>], pose: &Isometry3<f64>| {
        kernel_at(phi, points, pose, policy, policy.kappa_start())
    };
    initial_hypotheses(fit, source, &s.multistart, &s.lm, kernel, rng)
}

#[cfg(test)]
mod tests {
    use super::rescued;

    #[test]
    fn a_rescue_must_leave_less_outside_without_fitting_less() {
        // A guess whose result leaves most of the source outside and fits little, and a
        // multi-start that lands (illustrative shares, of the kind of the street a quarter
        // turn off in `tests/scenes.rs`): rescued.
        assert!(rescued([0.62, 0.31], [0.08, 0.86]));
        // 3DMatch 06→00 from the published pose with a local Φ: the multi-start's wrong pose
        // leaves 1 % less outside but fits a third less: the guess's result stays.
        assert!(!rescued([0.439, 0.485], [0.428, 0.324]));
        // KITTI 0→5 from 3 m and 20° off: the guess's result slid 1.4 m along the street; the
        // fitness saturates on a street, the outside share does not: rescued.
        assert!(rescued([0.387, 0.998], [0.161, 0.996]));
        // No less outside: the guess's result stays, whatever the fitness.
        assert!(!rescued([0.3, 0.5], [0.3, 0.9]));
        // Equal fitness, less outside: rescued.
        assert!(rescued([0.3, 0.5], [0.2, 0.5]));
    }
}

//! Stage 6, the robust re-run of [`RobustMode::Auto`]: a least-squares result that fits poorly
//! (most likely partial overlap: points beyond the target's coverage pull) is redone with the
//! Geman–McClure kernel, and the better fit kept.

use crate::pipeline::registration::Registration;
use crate::pipeline::report::RobustReport;
use crate::pipeline::robust::{KernelPolicy, RobustMode};
use crate::pipeline::settings::RegisterSettings;

/// How a least-squares result looked, for [`RobustMode::Auto`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct LeastSquaresFit {
    /// Its fitness.
    pub fitness: f64,
    /// The share of the source outside the target's coverage ([`outside_share`]).
    pub outside_share: f64,
}

/// Why a robust re-run was tried.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum RerunCause {
    /// The fitness was below `below_fitness`: kept at `gain` times the fitness.
    LowFitness,
    /// Only the share outside the coverage was above `outside_share`: kept on any gain.
    Outside,
}

/// The settings of the robust re-run when `mode` asks for one after the least-squares result
/// `least`: the kernel from the start and the multi-start tie at most the mode's.
pub(crate) fn rerun_settings(
    settings: &RegisterSettings,
    least: LeastSquaresFit,
) -> Option<(RegisterSettings, KernelPolicy, RerunCause)> {
    let RobustMode::Auto {
        below_fitness,
        outside_share,
        tie,
        ..
    } = settings.robust.mode
    else {
        return None;
    };
    // Points outside the coverage that the fitness counts as inliers (within the inlier
    // distance, as a LiDAR scan's far returns between the other scan's rings are) give a
    // kernel nothing to weigh down and a re-run no fitness to gain.
    let cause = if least.fitness < below_fitness {
        RerunCause::LowFitness
    } else if least.outside_share > outside_share && least.fitness < 1.0 - outside_share {
        RerunCause::Outside
    } else {
        return None;
    };
    let mut scans = settings.clone();
    scans.multistart.tie = scans.multistart.tie.min(tie);
    let policy = settings.robust.adaptive();
    Some((scans, policy, cause))
}

/// Whether the re-run's result (fitness `robust`) replaces the least-squares one (`least`).
pub(crate) fn keep_rerun(mode: &RobustMode, cause: RerunCause, least: f64, robust: f64) -> bool {
    match (*mode, cause) {
        (RobustMode::Auto { gain, .. }, RerunCause::LowFitness) => robust >= gain * least,
        (RobustMode::Auto { .. }, RerunCause::Outside) => robust > least,
        _ => false,
    }
}

/// Stage 6: the robust re-run of [`RobustMode::Auto`] after a least-squares result that fits
/// poorly (most likely partial overlap: points beyond the target's coverage pull); the better
/// fit is returned, with [`Stages::robust`] saying what happened. `outside` gives the share of
/// the source a result leaves outside the target's coverage (asked in that mode only).
pub(crate) fn robust_rerun(
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
        with_robust(with_other_run(second, &first), report)
    } else {
        let report = RobustReport::RerunRejected {
            least_squares_fitness,
            least_squares_outside,
            robust_fitness,
        };
        with_robust(with_other_run(first, &second), report)
    }
}

/// `r` with the time of the `other` registration, which was not returned (its own runs not
/// returned included), added to its `other_run`.
pub(crate) fn with_other_run(mut r: Registration, other: &Registration) -> Registration {
    r.stage_times.other_run += other.stage_times.run() + other.stage_times.other_run;
    r
}

/// `r` with its robust report.
fn with_robust(mut r: Registration, report: RobustReport) -> Registration {
    r.stages.robust = report;
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_least_squares_result_half_outside_the_target_is_redone_and_kept_on_any_gain() {
        let s = crate::RegisterSettings::default();
        let fit = |fitness, outside_share| LeastSquaresFit {
            fitness,
            outside_share,
        };
        // Well fitted, inside the coverage: no re-run.
        assert!(rerun_settings(&s, fit(0.5, 0.0)).is_none());
        // A poor fit: re-run, kept at 1.3 times the fitness.
        let (_, _, cause) = rerun_settings(&s, fit(0.2, 0.0)).unwrap();
        assert_eq!(cause, RerunCause::LowFitness);
        assert!(!keep_rerun(&s.robust.mode, cause, 0.2, 0.25));
        assert!(keep_rerun(&s.robust.mode, cause, 0.2, 0.26));
        // A fair fit with 37 % of the source outside (3DMatch 06→00): re-run, kept when
        // better at all (0.418 → 0.485 there).
        let (rerun, _, cause) = rerun_settings(&s, fit(0.418, 0.37)).unwrap();
        assert_eq!(cause, RerunCause::Outside);
        assert_eq!(rerun.multistart.tie, 0.05);
        assert!(keep_rerun(&s.robust.mode, cause, 0.418, 0.485));
        assert!(!keep_rerun(&s.robust.mode, cause, 0.418, 0.418));
        // A quarter outside the coverage yet 0.99 within the inlier distance (the outdoor
        // LiDAR pair's source filtered to 5 cm voxels, at the right pose): no re-run.
        assert!(rerun_settings(&s, fit(0.99, 0.25)).is_none());
        assert!(rerun_settings(&s, fit(0.79, 0.25)).is_some());
        // Not in the other modes.
        let mut off = s.clone();
        off.robust.mode = RobustMode::Off;
        assert!(rerun_settings(&off, fit(0.1, 0.9)).is_none());
        // Old settings files without the field read the default.
        let old = r#"{"kind":"auto","below_fitness":0.35,"gain":1.3,"tie":0.05}"#;
        let mode: RobustMode = serde_json::from_str(old).unwrap();
        assert_eq!(mode, RobustMode::AUTO);
    }

    #[test]
    fn auto_mode_reruns_below_its_fitness_only() {
        let s = crate::RegisterSettings::default();
        let fit = |fitness| LeastSquaresFit {
            fitness,
            outside_share: 0.0,
        };
        assert!(rerun_settings(&s, fit(0.2)).is_some());
        assert!(rerun_settings(&s, fit(0.5)).is_none());
        let (scans, policy, cause) = rerun_settings(&s, fit(0.2)).unwrap();
        assert_eq!(scans.multistart.tie, 0.05);
        assert!(policy.is_robust());
        assert!(keep_rerun(&s.robust.mode, cause, 0.2, 0.27));
        assert!(!keep_rerun(&s.robust.mode, cause, 0.2, 0.25));
        let on = crate::RegisterSettings::partial_scans();
        assert!(rerun_settings(&on, fit(0.01)).is_none());
    }
}

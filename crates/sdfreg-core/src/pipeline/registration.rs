//! The outcome of a registration ([`Registration`]) and stage 9, which makes it: the result in
//! the user's frame, its quality against the target and Φ, and what each stage did.

use std::time::Duration;

use nalgebra::{Isometry3, Matrix4, Matrix6, Point3, SMatrix, Similarity3};

use crate::geometry::cloud::{LeftOut, Normalization};
use crate::pipeline::polish::PolishOutcome;
use crate::pipeline::report::{
    CoarseToFineReport, FinalLmReport, GlobalRerunReport, InitialReport, PolishReport,
    PolishResult, PoseChange, RescueReport, RobustReport, ShiftSearchReport, StageTimes, Stages,
};
use crate::pipeline::settings::RegisterSettings;
use crate::pipeline::shift_search::Searched;
use crate::pipeline::surface::Surface;
use crate::solve::degeneracy::Degeneracy;
use crate::solve::lm::{Lm, LmSettings, StopReason};
use crate::solve::measure::quality;

/// The outcome of [`crate::register()`]. Serialises with serde (the Python binding pickles it that way).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Registration {
    /// Maps source coordinates into the target frame (`p_target = R p_source + t`), user units.
    /// With a scale ([`crate::ScaleSettings::enabled`]) the rigid part of the similarity
    /// `p_target = s R p_source + t` ([`Self::scale`], [`Self::similarity`]).
    pub t_target_source: Isometry3<f64>,
    /// The scale `s` of the similarity, target units per source unit; 1 when rigid.
    #[serde(default = "unit_scale")]
    pub scale: f64,
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
    /// With a scale: `JᵀJ` (7×7) of the left step `[ω; v; σ]` (σ the change of `ln s`, about the
    /// target origin, user units); `None` when rigid.
    #[serde(default)]
    pub similarity_information: Option<SMatrix<f64, 7, 7>>,
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
    /// Wall time of each stage (results written before it existed read as zeros).
    #[serde(default)]
    pub stage_times: StageTimes,
    /// The source's points left out before registering it: missing returns and stray points
    /// ([`LeftOut`]).
    #[serde(default)]
    pub source_left_out: LeftOut,
    /// The target's points left out before fitting Φ to it; all zero against a model (its
    /// fit left them out: [`LeftOut::of`] the cloud it was fitted to tells how many).
    #[serde(default)]
    pub target_left_out: LeftOut,
}

fn unit_scale() -> f64 {
    1.0
}

impl Registration {
    /// The result as a homogeneous 4×4 matrix `[s R | t]` (`s` = 1 when rigid).
    pub fn matrix(&self) -> Matrix4<f64> {
        let mut m = self.t_target_source.to_homogeneous();
        if self.scale != 1.0 {
            m.fixed_view_mut::<3, 3>(0, 0).scale_mut(self.scale);
        }
        m
    }

    /// The result as a similarity (`p_target = s R p_source + t`; `s` = 1 when rigid).
    pub fn similarity(&self) -> Similarity3<f64> {
        Similarity3::from_isometry(self.t_target_source, self.scale)
    }
}

/// What the stages of one run produced, in order.
pub(crate) struct Trace {
    /// The winning hypothesis's starting pose (unit frame).
    pub(crate) start: Isometry3<f64>,
    pub(crate) initial: InitialReport,
    /// Hypotheses alive at the end of the alternations, and the winner's index.
    pub(crate) survivors: usize,
    pub(crate) winner: usize,
    /// The winner's pose after the alternations (unit frame).
    pub(crate) after_alternations: Isometry3<f64>,
    /// The solver after the final LM.
    pub(crate) lm: Lm,
    pub(crate) lm_stop: StopReason,
    pub(crate) polished: PolishOutcome,
    pub(crate) searched: Searched,
    /// Stages 3–8's wall times (the measure's is added by [`measure`]).
    pub(crate) times: StageTimes,
    /// The scale, when it is estimated (`source` then enters [`measure`] scaled by it).
    pub(crate) scale: Option<f64>,
}

/// Stage 9: the result in the user's frame — its quality against the target and Φ, and what
/// each stage did. `source`: unit frame, scaled by the scale when there is one.
pub(crate) fn measure<S: Surface>(
    source: &[Point3<f64>],
    norm: &Normalization,
    fit: &S,
    s: &RegisterSettings,
    robust: bool,
    t: Trace,
) -> Registration {
    let start = std::time::Instant::now();
    let change =
        |a: &Isometry3<f64>, b: &Isometry3<f64>| PoseChange::between(source, a, b, norm.scale);
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
        rescue: RescueReport::NotTried,
        global_rerun: GlobalRerunReport::NotTried,
        swapped: false,
    };
    let q = quality(
        fit.phi(),
        &t.searched.moved,
        norm,
        s.free_motion_ratio,
        t.scale.is_some(),
    );
    Registration {
        t_target_source: match t.scale {
            None => norm.pose_from_unit(&t.searched.pose),
            Some(scale) => norm.similarity_from_unit(&t.searched.pose, scale),
        },
        scale: t.scale.unwrap_or(1.0),
        similarity_information: q.similarity_information,
        converged: stop_reason.converged(),
        stop_reason,
        iterations: t.lm.iterations,
        cost: q.cost,
        fitness: t.searched.fitness,
        inlier_rmse: t.searched.inlier_rms * norm.scale,
        inlier_distance: s.inlier_distance * norm.scale,
        information: q.information,
        degeneracy: q.degeneracy,
        robust,
        stages,
        time: Duration::ZERO,
        stage_times: StageTimes {
            measure: start.elapsed(),
            ..t.times
        },
        source_left_out: LeftOut::default(),
        target_left_out: LeftOut::default(),
    }
}

/// Why the polish stopped, judged by the registration's convergence tolerances (the LM's): its
/// own tolerance is far tighter ([`crate::PolishSettings::tolerance`]), so a polish that ran out
/// of iterations with a last step below the LM's tolerances has settled as far as the
/// registration asks ([`StopReason::SmallStep`]).
fn settled(p: &PolishOutcome, lm: &LmSettings) -> StopReason {
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
            scale: 1.0,
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

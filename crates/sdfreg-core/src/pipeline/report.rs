//! What each stage of a registration did: [`Stages`], part of [`crate::Registration`].
//!
//! Every stage that can move the pose says how far it moved the source ([`PoseChange`], in the
//! user's units), and the stages that decide something say what they decided: the hypotheses of
//! the multi-start and which one won, why the final LM stopped, whether the polish was applied,
//! snapped or undone, whether the shift search moved the pose, and whether the robust re-run ran
//! and was kept. Serialises to JSON with snake_case names (the CLI's `stages`, Python's
//! `Registration.stages`).

use std::time::Duration;

use nalgebra::{Isometry3, Point3};

use crate::solve::lm::StopReason;

/// How far a stage moved the source: the rotation between the poses before and after, and the
/// RMS displacement of the (subsampled) source points, in the inputs' units.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PoseChange {
    /// Rotation angle between the two poses, degrees.
    pub rotation_deg: f64,
    /// RMS displacement of the source points, the inputs' units.
    pub translation: f64,
}

impl PoseChange {
    /// The change from `a` to `b` of the unit-frame `source` points; `scale` maps unit lengths
    /// into the user's units.
    pub(crate) fn between(
        source: &[Point3<f64>],
        a: &Isometry3<f64>,
        b: &Isometry3<f64>,
        scale: f64,
    ) -> Self {
        if a == b {
            // Exactly zero (the rotation angle of q⁻¹q is not, in floating point).
            return Self::default();
        }
        let d2: f64 = source.iter().map(|p| (b * p - a * p).norm_squared()).sum();
        Self {
            rotation_deg: a.rotation.angle_to(&b.rotation).to_degrees(),
            translation: (d2 / source.len().max(1) as f64).sqrt() * scale,
        }
    }

    /// Whether the pose moved at all.
    pub fn moved(&self) -> bool {
        self.rotation_deg > 0.0 || self.translation > 0.0
    }
}

/// Where the starting pose came from.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct InitialReport {
    /// The caller's initial guess was used (no multi-start).
    pub given: bool,
    /// Multi-start starts tried (0 with an initial guess).
    pub starts: usize,
    /// Hypotheses carried into the coarse-to-fine loop.
    pub hypotheses: usize,
    /// Rotation angle of the winning hypothesis's starting pose, degrees: for the multi-start,
    /// how far its pick turned the source away from plain centroid alignment; with an initial
    /// guess, that guess's rotation.
    pub rotation_deg: f64,
}

/// The coarse-to-fine loop.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CoarseToFineReport {
    /// Hypotheses still in the race at the end (the others fitted clearly worse halfway).
    pub survivors: usize,
    /// Which hypothesis won: 0 is the multi-start's least-motion pick, then the identity start
    /// and the best-scoring start (in that order, when distinct).
    pub winner: usize,
    /// From the winner's starting pose to its pose after the alternations.
    pub change: PoseChange,
}

/// The final LM on the frozen Φ.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FinalLmReport {
    /// Why it stopped.
    pub stop_reason: StopReason,
    /// How far it moved the source.
    pub change: PoseChange,
}

/// What the point-to-plane polish did ([`crate::PolishSettings`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum PolishResult {
    /// Disabled (`polish.iterations = 0`).
    Off,
    /// Local planes refined the pose.
    Applied,
    /// The source lay on the target's own points and was snapped onto them.
    Snapped,
    /// It moved the source further than `polish.max_shift` without laying clearly more of it
    /// onto the target's points; the SDF's pose was kept.
    Undone,
}

/// The polish.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PolishReport {
    /// What it did.
    pub result: PolishResult,
    /// Gauss–Newton iterations, all passes.
    pub iterations: usize,
    /// Why the pass that set the pose stopped.
    pub stop_reason: StopReason,
    /// How far it moved the source (zero when off or undone).
    pub change: PoseChange,
}

/// The translation search ([`crate::ShiftSearchSettings`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ShiftSearchReport {
    /// Peaks of the occupancy correlation polished and scored.
    pub peaks: usize,
    /// Whether one replaced the pose.
    pub taken: bool,
    /// Fitness gained by it (0 when none was taken).
    pub fitness_gain: f64,
    /// How far it moved the source.
    pub change: PoseChange,
}

/// Whether the robust kernel ran, and why ([`crate::RobustMode`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
#[non_exhaustive]
pub enum RobustReport {
    /// Least squares only (`RobustMode::Off`).
    Off,
    /// The kernel from the start (`RobustMode::On` or `Fixed`).
    FromStart,
    /// Least squares fitted well enough; no re-run.
    NotNeeded {
        /// The least-squares fitness.
        least_squares_fitness: f64,
        /// The share of the source the least-squares result left outside the target's
        /// coverage (beyond [`crate::OUTSIDE_SPACINGS`] target spacings).
        least_squares_outside: f64,
    },
    /// The robust re-run fitted enough better and was returned.
    RerunKept {
        /// The least-squares fitness.
        least_squares_fitness: f64,
        /// The share of the source outside the target's coverage at least squares.
        least_squares_outside: f64,
        /// The robust run's fitness.
        robust_fitness: f64,
    },
    /// The robust re-run did not fit enough better; the least-squares result was returned.
    RerunRejected {
        /// The least-squares fitness.
        least_squares_fitness: f64,
        /// The share of the source outside the target's coverage at least squares.
        least_squares_outside: f64,
        /// The robust run's fitness.
        robust_fitness: f64,
    },
}

impl RobustReport {
    /// The share of the source the returned result leaves outside the target's coverage, when
    /// the decision measured it: the least-squares result was returned (no re-run, or the
    /// re-run rejected).
    pub(crate) fn returned_outside(&self) -> Option<f64> {
        match *self {
            Self::NotNeeded {
                least_squares_outside,
                ..
            }
            | Self::RerunRejected {
                least_squares_outside,
                ..
            } => Some(least_squares_outside),
            _ => None,
        }
    }
}

/// Whether a given initial guess was rescued by the multi-start
/// ([`crate::MultistartSettings::rescue`]): its result left too much of the source outside the
/// target's coverage, or lay far from the guess, and the registration ran again as if no guess
/// had been given.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
#[non_exhaustive]
pub enum RescueReport {
    /// Not tried: no guess given, or its result within the coverage and near the guess.
    #[default]
    NotTried,
    /// The run from the multi-start left less of the source outside, without fitting
    /// correspondingly less of it (its fitness minus its outside share larger), and was
    /// returned.
    Kept {
        /// The share of the source the guess's result left outside the target's coverage.
        given_outside: f64,
        /// The share the multi-start's result left outside.
        rescue_outside: f64,
        /// The guess's result's fitness ([`crate::Registration::fitness`]; 0 in reports
        /// written before it was recorded).
        #[serde(default)]
        given_fitness: f64,
        /// The multi-start's result's fitness.
        #[serde(default)]
        rescue_fitness: f64,
        /// Whether it was tried because the guess's result lay far from the guess (a distinct
        /// pose by [`crate::MultistartSettings::distinct_rotation_deg`] or
        /// [`crate::MultistartSettings::distinct_translation`]) while its outside share was
        /// within the bound (false in reports written before this was recorded).
        #[serde(default)]
        far_from_guess: bool,
    },
    /// The run from the multi-start did not leave less outside, or its fitness fell by more
    /// than its outside share; the guess's result was returned.
    Rejected {
        /// The share of the source the guess's result left outside the target's coverage.
        given_outside: f64,
        /// The share the multi-start's result left outside.
        rescue_outside: f64,
        /// The guess's result's fitness ([`crate::Registration::fitness`]; 0 in reports
        /// written before it was recorded).
        #[serde(default)]
        given_fitness: f64,
        /// The multi-start's result's fitness.
        #[serde(default)]
        rescue_fitness: f64,
        /// Whether it was tried because the guess's result lay far from the guess (a distinct
        /// pose by [`crate::MultistartSettings::distinct_rotation_deg`] or
        /// [`crate::MultistartSettings::distinct_translation`]) while its outside share was
        /// within the bound (false in reports written before this was recorded).
        #[serde(default)]
        far_from_guess: bool,
    },
}

/// Whether a full call whose Φ was local by [`crate::ModelKind::Auto`]'s choice ran again with a
/// global Φ ([`crate::LocalSettings::global_rerun_below_fitness`]): its result fitted poorly.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
#[non_exhaustive]
pub enum GlobalRerunReport {
    /// Not tried: Φ global, or given as local, or the local result fitted well enough.
    #[default]
    NotTried,
    /// The global Φ's result fitted more of the source and was returned.
    Kept {
        /// The local Φ's result's fitness.
        local_fitness: f64,
        /// The global Φ's result's fitness.
        global_fitness: f64,
    },
    /// The global Φ's result fitted no more; the local one was returned.
    Rejected {
        /// The local Φ's result's fitness.
        local_fitness: f64,
        /// The global Φ's result's fitness.
        global_fitness: f64,
    },
}

/// What each stage of the returned run did, in pipeline order.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Stages {
    /// The initial pose (multi-start or the caller's guess).
    pub initial: InitialReport,
    /// The coarse-to-fine alternations.
    pub coarse_to_fine: CoarseToFineReport,
    /// The final LM.
    pub final_lm: FinalLmReport,
    /// The robust re-run decision.
    pub robust: RobustReport,
    /// The polish.
    pub polish: PolishReport,
    /// The shift search.
    pub shift_search: ShiftSearchReport,
    /// The multi-start's rescue of a given guess.
    #[serde(default)]
    pub rescue: RescueReport,
    /// A scene's full call run again with a global Φ.
    #[serde(default)]
    pub global_rerun: GlobalRerunReport,
    /// Whether the call registered the target onto the source and returned the inverse (a
    /// source with many times the target's points, [`crate::RegisterSettings::swap_ratio`]):
    /// then the reports above are of that run.
    #[serde(default)]
    pub swapped: bool,
}

/// Wall time of each stage of a registration ([`crate::Registration::stage_times`]): where the
/// time went. The stages of the returned run, plus the target's pre-fit and the robust re-run's
/// other run; what they leave out of [`crate::Registration::time`] is validation and
/// subsampling.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StageTimes {
    /// Stages 1–2 on the target: normalising it and pre-fitting Φ (zero against a stored
    /// model, whose fit was paid once by [`crate::SdfModel::fit`]).
    pub prefit: Duration,
    /// Stage 3: the multi-start (next to nothing with an initial guess).
    pub initial: Duration,
    /// Stage 4: the coarse-to-fine alternations (Φ refinement and LM steps, every hypothesis).
    pub coarse_to_fine: Duration,
    /// Stage 5: the final LM on the frozen Φ.
    pub final_lm: Duration,
    /// Stage 7: the point-to-plane polish (the target's planes included).
    pub polish: Duration,
    /// Stage 8: the shift search.
    pub shift_search: Duration,
    /// Stage 9: fitness, inlier RMSE, JᵀJ and the free motions.
    pub measure: Duration,
    /// Stage 6: the run that was not returned when the robust re-run ran (the least-squares
    /// run when the re-run was kept, else the re-run); zero when there was none.
    pub other_run: Duration,
}

impl StageTimes {
    /// Each stage's name (as in [`Stages`] and the CLI's `stage_ms`) and time, in pipeline
    /// order.
    pub fn named(&self) -> [(&'static str, Duration); 8] {
        [
            ("prefit", self.prefit),
            ("initial", self.initial),
            ("coarse_to_fine", self.coarse_to_fine),
            ("final_lm", self.final_lm),
            ("polish", self.polish),
            ("shift_search", self.shift_search),
            ("measure", self.measure),
            ("other_run", self.other_run),
        ]
    }

    /// The sum of the stages 3–9 of one run (the pre-fit and the other run left out).
    pub(crate) fn run(&self) -> Duration {
        self.initial
            + self.coarse_to_fine
            + self.final_lm
            + self.polish
            + self.shift_search
            + self.measure
    }
}

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

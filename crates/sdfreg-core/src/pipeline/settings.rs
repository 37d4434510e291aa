//! Every setting of a registration, grouped by stage, with named presets.
//!
//! [`RegisterSettings`] holds one plain struct per stage of [`crate::register()`]:
//! [`MlpSettings`] and [`FitSettings`] (Φ), [`MultistartSettings`] (initial hypotheses),
//! [`CoarseToFineSettings`] (the alternation schedule and the final LM), [`LmSettings`] (the
//! solver), [`RobustSettings`] (the kernel and when it is used), [`PolishSettings`] and
//! [`ShiftSearchSettings`]. Lengths marked "normalised" are relative to the target's largest
//! bounding-box side (1 = the whole target). Each struct's `validate` names the field at fault
//! (`lm.max_tries must be ≥ 1, got 0`).
//!
//! Presets: [`RegisterSettings::default`] (objects, clouds that overlap fully or nearly; a poor
//! least-squares fit is redone with the robust kernel) and [`RegisterSettings::partial_scans`]
//! (scans known to overlap only in part).

use crate::base::check;
use crate::base::error::Error;
use crate::field::mlp::MlpSettings;
use crate::fit::settings::FitSettings;
use crate::pipeline::coarse_to_fine::{CoarseToFineSettings, Schedule};
use crate::pipeline::multistart::MultistartSettings;
use crate::pipeline::polish::PolishSettings;
use crate::pipeline::robust::{RobustMode, RobustSettings};
use crate::pipeline::scale::ScaleSettings;
use crate::pipeline::shift_search::ShiftSearchSettings;
use crate::solve::degeneracy::FREE_MOTION_RATIO;
use crate::solve::lm::LmSettings;

/// [`PolishSettings::scene_points`] of [`RegisterSettings::views`].
const VIEWS_SCENE_POINTS: usize = 16384;

/// [`PolishSettings::scene_tolerance_spacings`] of [`RegisterSettings::views`].
const VIEWS_SCENE_TOLERANCE_SPACINGS: f64 = 0.01;

/// [`PolishSettings::scene_iterations`] of [`RegisterSettings::views`].
const VIEWS_SCENE_ITERATIONS: usize = 100;

/// Fewest points accepted in either cloud.
pub const MIN_POINTS: usize = 10;

/// Default [`RegisterSettings::swap_ratio`].
pub const DEFAULT_SWAP_RATIO: f64 = 4.0;

fn default_swap_ratio() -> f64 {
    DEFAULT_SWAP_RATIO
}

/// All settings of a registration. Lengths marked "normalised" are relative to the target's
/// largest bounding-box side (1 = the whole target).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RegisterSettings {
    /// The SDF network.
    pub mlp: MlpSettings,
    /// The SDF fit.
    pub fit: FitSettings,
    /// The initial hypotheses without an initial guess.
    pub multistart: MultistartSettings,
    /// The alternation schedule and the final LM.
    pub coarse_to_fine: CoarseToFineSettings,
    /// The Levenberg–Marquardt solver.
    pub lm: LmSettings,
    /// The robust kernel and when it is used.
    pub robust: RobustSettings,
    /// The final point-to-plane polish against the target points.
    pub polish: PolishSettings,
    /// The search for translations that lay more source points onto the target than the SDF's
    /// pose does.
    pub shift_search: ShiftSearchSettings,
    /// Similarity registration: a scale estimated with the pose. Off by default.
    #[serde(default)]
    pub scale: ScaleSettings,
    /// A motion whose constraint eigenvalue is below this fraction of the largest is reported as
    /// free in [`crate::Registration::degeneracy`]. Default [`FREE_MOTION_RATIO`] (2·10⁻³).
    pub free_motion_ratio: f64,
    /// Source points used by the LM at most; more are subsampled (seeded). Default 4096.
    pub max_source_points: usize,
    /// Target points used by the fit at most; more are subsampled (seeded). Default 100000.
    pub max_target_points: usize,
    /// A source point counts as an inlier (fitness, inlier RMSE) when its nearest target point
    /// is closer than this, normalised units. Default 0.02.
    pub inlier_distance: f64,
    /// A full call ([`crate::register()`]) registers the target onto the source and returns the
    /// inverse when the source has at least this many times the target's points (usable
    /// points, before subsampling) and its largest bounding-box side is at least
    /// [`crate::SWAP_MIN_EXTENT`] of the target's: Φ, the polish's planes and the shift search's
    /// shares are then made from the denser cloud, the fitness still measured as without the
    /// swap ([`crate::Stages::swapped`]). 0 = never; otherwise at least 1. Rigid registration only.
    /// Default 4.
    #[serde(default = "default_swap_ratio")]
    pub swap_ratio: f64,
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
            multistart: MultistartSettings::default(),
            coarse_to_fine: CoarseToFineSettings::default(),
            lm: LmSettings::default(),
            robust: RobustSettings::default(),
            polish: PolishSettings::default(),
            shift_search: ShiftSearchSettings::default(),
            scale: ScaleSettings::default(),
            free_motion_ratio: FREE_MOTION_RATIO,
            max_source_points: 4096,
            max_target_points: 100_000,
            inlier_distance: 0.02,
            swap_ratio: DEFAULT_SWAP_RATIO,
            seed: 0,
            threads: 0,
        }
    }
}

/// [`FitSettings::prefit_steps`] of the `learned` preset ([`RegisterSettings::learned`]).
pub const LEARNED_PREFIT_STEPS: usize = 150;

impl RegisterSettings {
    /// The preset for scans known to overlap only in part (real scan pairs): the robust kernel
    /// from the start ([`RobustMode::On`]) and a multi-start tie of 0.05 (views far apart are
    /// not symmetric near-ties). Measured on the bunny's neighbouring views and the 3DMatch pair
    /// (`benches/realscans.py`); on the ModelNet density protocol (500 source points) the
    /// kernel from the start loses pairs that the default keeps.
    pub fn partial_scans() -> Self {
        Self {
            multistart: MultistartSettings {
                tie: 0.05,
                ..Default::default()
            },
            robust: RobustSettings {
                mode: RobustMode::On,
                ..Default::default()
            },
            ..Default::default()
        }
    }

    /// The preset for the pairs of many views ([`crate::align`]): [`Self::partial_scans`] with
    /// a polish pass that ends when its steps stop shrinking for 10 iterations
    /// ([`PolishSettings::patience`]), against planes at the target's points
    /// ([`PolishSettings::target_planes`]). Measured on the bunny's 10 scans (45 pairs through
    /// stored models): past 10–20 iterations the polish's steps no longer shrink but wander about
    /// 10⁻⁴ rad (its planes and robust weights change with every step), so the 50 iterations ran
    /// to the end in most pairs. Planes at the target's points (fitted once per model) instead of
    /// at each moved source point (one nearest-point query a point and iteration instead of a
    /// `k`-nearest query and a plane fit): the right pairs' polish converges in 10–26
    /// iterations, and the pairs' summed time fell to 0.56 of what it was (the polish, with the
    /// shift search's, from 84 % of it to 68 %); every pose of the bunny's 10 scans stayed within
    /// 0.03° / 0.05 mm of where it was, in either order and with a scan of something else
    /// (`benches/multiway.py`).
    ///
    /// A scene's polish (a local Φ: LiDAR scans of a room or a site) moves 16384 of the
    /// source's points ([`PolishSettings::scene_points`]) until its steps are below 0.01 target
    /// point spacings ([`PolishSettings::scene_tolerance_spacings`]), so that the views' poses
    /// agree to a millimetre where the surfaces pin a direction with few points: on the
    /// procedural room's loop of 8 views (`cargo bench --bench views`, 1 cm range noise) every
    /// pose within 0.029° / 1.0 mm of the truth instead of 0.037° / 2.3 mm, in 1.5 times the
    /// time; without noise within 0.0016° / 0.23 mm instead of 0.0038° / 0.60 mm. Either alone
    /// did less (16384 points: 0.043° / 1.6 mm; 0.01 spacings: 0.050° / 2.3 mm). Its passes
    /// run up to 100 iterations ([`PolishSettings::scene_iterations`]): from 9–14 cm too low, a
    /// room scan's height is climbed a few millimetres an iteration. Objects are polished as
    /// before.
    pub fn views() -> Self {
        let scans = Self::partial_scans();
        Self {
            polish: PolishSettings {
                patience: 10,
                target_planes: true,
                scene_iterations: VIEWS_SCENE_ITERATIONS,
                scene_points: VIEWS_SCENE_POINTS,
                scene_tolerance_spacings: VIEWS_SCENE_TOLERANCE_SPACINGS,
                ..scans.polish.clone()
            },
            ..scans
        }
    }

    /// The preset for tracking ([`crate::SdfModel::track`]): each frame starts from the previous
    /// frame's pose, so no multi-start, no Φ refinement, 5 LM steps on the frozen Φ, a polish of
    /// 2 iterations without the narrow second pass and without the snap, no shift search, least
    /// squares, at most 1024 source points. Measured on the 200-frame sequence of
    /// `benches/track.py`: the polish's 2 iterations give the accuracy of 5 (mean 0.144°) at
    /// about half the time; without a polish the mean error is 0.33°.
    pub fn tracking() -> Self {
        Self {
            multistart: MultistartSettings {
                enabled: false,
                ..Default::default()
            },
            coarse_to_fine: CoarseToFineSettings {
                alternations: 0,
                scene_alternations: 0,
                lm_steps_per_alternation: 0,
                final_lm_steps: 5,
                scene_lm_steps_per_alternation: 0,
                scene_final_lm_steps: 5,
                final_lm_baked: true,
            },
            robust: RobustSettings {
                mode: RobustMode::Off,
                ..Default::default()
            },
            polish: PolishSettings {
                iterations: 2,
                scene_iterations: 2,
                near_spacings: 0.0,
                snap: false,
                target_planes: true,
                ..Default::default()
            },
            shift_search: ShiftSearchSettings {
                radius: 0.0,
                ..Default::default()
            },
            max_source_points: 1024,
            ..Default::default()
        }
    }

    /// The preset for many full calls against objects, where time counts more than the last
    /// pairs of hard real scans: Φ's pre-fit starts from the learned initialisation
    /// ([`crate::MlpSettings::learned_init`]) and takes 150 Adam steps instead of 250 from the
    /// sphere. Measured (`sdfreg eval --shapes ../shared/data/modelnet40-half1 --pairs 36
    /// --protocol all`, 2-core AVX-512): median per pair 0.71 of the default's, 21 failures
    /// at 5°/0.05 of 324 against the default's 24 (all but two on surfaces of revolution,
    /// whose turn about the axis the data do not fix); on the 27 other shapes every
    /// protocol's mean within 0.11° of the binary's before the one-shot work (32b1854), where
    /// the default's `partial-indep` and `density-indep` means are 9.4° and 3.5° (a bookshelf
    /// turned 180°, a lamp 90°). But on the bunny's six real scan pairs
    /// (`benches/realscans.py --only bunny`) bun270→bun180 (fitness 0.58 at the truth) ends
    /// 83° off, where the default lands at 0.35°: the multi-start's hypothesis on the learned
    /// start's Φ is the wrong one (83° off before the polish; the default's 2.2°). Over seeds
    /// 0–5 that pair lands 4 times with this preset, 6 times with the default.
    pub fn learned() -> Self {
        let mut s = Self::default();
        s.mlp.learned_init = true;
        s.fit.prefit_steps = LEARNED_PREFIT_STEPS;
        s
    }

    /// A preset by name: `default`, `scans` ([`Self::partial_scans`]), `views`
    /// ([`Self::views`]), `tracking` ([`Self::tracking`]) or `learned` ([`Self::learned`]).
    pub fn preset(name: &str) -> Option<Self> {
        match name {
            "default" => Some(Self::default()),
            "scans" => Some(Self::partial_scans()),
            "views" => Some(Self::views()),
            "tracking" => Some(Self::tracking()),
            "learned" => Some(Self::learned()),
            _ => None,
        }
    }

    /// The preset names [`Self::preset`] knows.
    pub const PRESETS: [&'static str; 5] = ["default", "scans", "views", "tracking", "learned"];

    /// Adam steps of Φ's pre-fit — the whole policy in one place: a `local` Φ (a scene's)
    /// [`crate::LocalSettings::prefit_steps`], a `stored` model
    /// [`FitSettings::model_prefit_steps`], with a scale [`ScaleSettings::prefit_steps`], else
    /// (a full call against an object) [`FitSettings::prefit_steps`].
    pub(crate) fn prefit_steps(&self, local: bool, stored: bool) -> usize {
        if local {
            self.fit.local.prefit_steps
        } else if stored {
            self.fit.model_prefit_steps
        } else if self.scale.enabled {
            self.scale.prefit_steps
        } else {
            self.fit.prefit_steps
        }
    }

    /// Whether Φ's pre-fit starts from the learned initialisation
    /// ([`crate::MlpSettings::learned_init`]): only a full call's against an object without a
    /// scale, the fit whose steps [`FitSettings::prefit_steps`] counts.
    pub(crate) fn starts_learned(&self, local: bool, stored: bool) -> bool {
        self.mlp.learned_init && !local && !stored && !self.scale.enabled
    }

    /// Adam steps of Φ's refinement per alternation: a `local` Φ (a scene's)
    /// [`crate::LocalSettings::refine_steps`], with a scale [`ScaleSettings::refine_steps`], else
    /// [`FitSettings::refine_steps`].
    pub(crate) fn refine_steps(&self, local: bool) -> usize {
        if local {
            self.fit.local.refine_steps
        } else if self.scale.enabled {
            self.scale.refine_steps
        } else {
            self.fit.refine_steps
        }
    }

    /// The groups the coarse-to-fine alternations read, for a `local` Φ or not.
    pub(crate) fn schedule(&self, local: bool) -> Schedule<'_> {
        Schedule {
            coarse_to_fine: &self.coarse_to_fine,
            multistart: &self.multistart,
            refine_lr: self.fit.refine_lr,
            refine_steps: self.refine_steps(local),
        }
    }

    /// Checks every field of every group; the error names the field at fault.
    pub fn validate(&self) -> Result<(), Error> {
        self.mlp.validate()?;
        self.fit.validate()?;
        self.multistart.validate()?;
        self.coarse_to_fine.validate()?;
        self.lm.validate()?;
        self.robust.validate()?;
        self.polish.validate()?;
        self.shift_search.validate()?;
        self.scale.validate()?;
        check::count_at_least("max_source_points", self.max_source_points, MIN_POINTS)?;
        check::count_at_least("max_target_points", self.max_target_points, MIN_POINTS)?;
        check::fraction_below_one("free_motion_ratio", self.free_motion_ratio)?;
        check::positive("inlier_distance", self.inlier_distance)?;
        check::off_or_at_least("swap_ratio", self.swap_ratio, 1.0, "never swap")?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message(s: &RegisterSettings) -> String {
        s.validate().unwrap_err().to_string()
    }

    #[test]
    fn defaults_and_presets_are_valid() {
        for name in RegisterSettings::PRESETS {
            RegisterSettings::preset(name).unwrap().validate().unwrap();
        }
        assert!(RegisterSettings::preset("fast").is_none());
    }

    #[test]
    fn errors_name_the_field_and_the_value() {
        let mut s = RegisterSettings::default();
        s.lm.max_tries = 0;
        assert_eq!(
            message(&s),
            "invalid setting `lm.max_tries`: must be ≥ 1, got 0"
        );
        let mut s = RegisterSettings::default();
        s.multistart.keep = 0;
        assert!(message(&s).contains("`multistart.keep`"));
        let mut s = RegisterSettings::default();
        s.multistart.scene_turn_deg = 1e-6;
        assert!(message(&s).contains("`multistart.scene_turn_deg`"));
        let mut s = RegisterSettings::default();
        s.robust.mode = RobustMode::Fixed { scale: -1.0 };
        assert!(
            message(&s).contains("`robust.mode.scale`: must be a positive finite number, got -1")
        );
        let mut s = RegisterSettings::default();
        s.lm.rotation_tolerance = f64::NAN;
        assert!(message(&s).contains("`lm.rotation_tolerance`"));
        let mut s = RegisterSettings::default();
        s.fit.refine_lr = 0.0;
        assert!(message(&s).contains("`fit.refine_lr`"));
        let mut s = RegisterSettings::default();
        s.polish.neighbours = 2;
        assert!(message(&s).contains("`polish.neighbours`"));
        let mut s = RegisterSettings {
            swap_ratio: 0.5,
            ..Default::default()
        };
        assert!(message(&s)
            .contains("`swap_ratio`: must be 0 (never swap) or a finite number ≥ 1, got 0.5"));
        s.swap_ratio = 0.0;
        s.validate().unwrap();
    }
}

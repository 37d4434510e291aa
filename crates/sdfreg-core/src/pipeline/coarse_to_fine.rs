//! Coarse-to-fine (paper eq. 18-1) and the final LM on the frozen Φ.
//!
//! [`CoarseToFineSettings::alternations`] times: every hypothesis's moved source joins Φ's query
//! set (queries carry their true nearest target point, so extra ones only teach Φ more of the far
//! field; with a robust kernel, points at `|Φ| ≥ c`, outside the target's coverage, are left
//! out), Φ is refined for [`crate::FitSettings::refine_steps`] Adam steps
//! ([`crate::LocalSettings::refine_steps`] for a scene's local Φ), and each hypothesis
//! takes [`CoarseToFineSettings::lm_steps_per_alternation`] LM steps
//! ([`CoarseToFineSettings::scene_lm_steps_per_alternation`] in a scene's full call). Halfway,
//! hypotheses that fit clearly worse than the best are dropped (each judged where one more
//! alternation at its last one's gain would take it); at the end the best-fitting one
//! is kept (near-ties to the least rotation). Then LM on the frozen Φ until converged
//! ([`final_lm`]).
//!
//! Entry points: [`alternate`], [`final_lm`].

use std::borrow::Cow;

use nalgebra::{Isometry3, Point3};

use crate::base::error::Error;
use crate::field::Field;
use crate::geometry::cloud::transformed_f32;
use crate::pipeline::multistart::{least_motion, solver_score, MultistartSettings};
use crate::pipeline::report::Stage;
use crate::pipeline::robust::KernelPolicy;
use crate::pipeline::surface::Surface;
use crate::solve::kernel::Kernel;
use crate::solve::lm::{Lm, StopReason};

/// The coarse-to-fine schedule (paper eq. 18-1) and the final LM on the frozen Φ.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CoarseToFineSettings {
    /// Alternations of Φ refinement ([`crate::FitSettings::refine_steps`] Adam steps) and LM steps.
    /// Default 10.
    pub alternations: usize,
    /// Alternations when Φ is local (a scene, [`crate::ModelKind::Local`]) and refined (a full
    /// call, not a stored model's frozen Φ), in place of [`Self::alternations`]: there the
    /// planes give the surface and the refinement only the MLP's far field. Default 5, with
    /// [`LocalSettings::prefit_steps`](crate::LocalSettings::prefit_steps) 200: on the KITTI
    /// frames 3→4 from 3 m / 20° off, 100 steps and 3 alternations end 7.3° / 0.81 m off, 200
    /// and 3 2.9° / 0.37 m, 200 and 5 land (0.06° / 3 mm from small_gicp's answer from the
    /// identity) as 500 and 10 do, in 1.4 s instead of 1.7 s.
    pub scene_alternations: usize,
    /// LM steps per alternation. Default 2.
    pub lm_steps_per_alternation: usize,
    /// LM steps at most on the final, frozen Φ. Default 10.
    pub final_lm_steps: usize,
    /// [`Self::lm_steps_per_alternation`] when Φ is local (a scene) and refined (a full call;
    /// a stored model's frozen Φ keeps the objects' steps and its 10 alternations). Default 5,
    /// with [`Self::scene_final_lm_steps`] 30: from 96 starts 3 m and 20° off on the real
    /// LiDAR pairs (the outdoor pair and five KITTI steps, four directions, both yaw signs, two
    /// seeds) the full call landed from 63 with 2 and 10, from 77 with 5 and 30 (79 with 10 and
    /// 60); from the identity the answers are the same (the polish gives them). The failures
    /// left are wrong minima, not steps cut short. A stored model went from 77 to 88 of the 96
    /// with them, but from the identity it took 1.28 times small_gicp's time on the outdoor
    /// pair instead of 1.03 (`benches/lidar_compare.py --real`), so it keeps 2 and 10.
    #[serde(default = "default_scene_lm_steps")]
    pub scene_lm_steps_per_alternation: usize,
    /// [`Self::final_lm_steps`] when Φ is local and refined (a scene's full call). Default 30:
    /// see [`Self::scene_lm_steps_per_alternation`].
    #[serde(default = "default_scene_final_lm_steps")]
    pub scene_final_lm_steps: usize,
    /// The final LM reads a frozen Φ (a stored model's) baked into its grid
    /// ([`crate::field::baked`]: trilinear value and gradient, ≈ 30 times cheaper than the MLP)
    /// instead of Φ itself; the polish that follows lays the source onto the target's points.
    /// A refined Φ (a full call) is never baked, and a local Φ (a scene) is read at its own
    /// corners already, whose cells are far finer than the grid's: there it reads Φ either
    /// way. Default false;
    /// [`crate::RegisterSettings::tracking`] sets it.
    #[serde(default)]
    pub final_lm_baked: bool,
}

impl Default for CoarseToFineSettings {
    fn default() -> Self {
        Self {
            alternations: 10,
            scene_alternations: 5,
            lm_steps_per_alternation: 2,
            final_lm_steps: 10,
            scene_lm_steps_per_alternation: default_scene_lm_steps(),
            scene_final_lm_steps: default_scene_final_lm_steps(),
            final_lm_baked: false,
        }
    }
}

fn default_scene_lm_steps() -> usize {
    5
}

fn default_scene_final_lm_steps() -> usize {
    30
}

impl CoarseToFineSettings {
    /// Checks every field (every count is valid: 0 alternations or final steps skip the stage).
    pub fn validate(&self) -> Result<(), Error> {
        Ok(())
    }

    /// Alternations, LM steps per alternation and LM steps at most on the final Φ: a scene's
    /// when Φ is local and refined (`scene`, a full call), else the objects'.
    fn counts(&self, scene: bool) -> (usize, usize, usize) {
        if scene {
            (
                self.scene_alternations,
                self.scene_lm_steps_per_alternation,
                self.scene_final_lm_steps,
            )
        } else {
            (
                self.alternations,
                self.lm_steps_per_alternation,
                self.final_lm_steps,
            )
        }
    }
}

/// What the alternations did.
pub(crate) struct Alternated {
    /// The winning hypothesis's solver.
    pub lm: Lm,
    /// Hypotheses still alive at the end (before the pick).
    pub survivors: usize,
    /// Index of the winner among the hypotheses as they came in (0 = the multi-start's pick).
    pub winner: usize,
}

/// The settings groups the alternations read (of [`crate::RegisterSettings`]).
pub(crate) struct Schedule<'a> {
    /// The schedule itself.
    pub coarse_to_fine: &'a CoarseToFineSettings,
    /// The tie margin and truncation of the halfway drop and the final pick.
    pub multistart: &'a MultistartSettings,
    /// Φ's refinement learning rate ([`crate::FitSettings::refine_lr`]).
    pub refine_lr: f32,
    /// Adam steps of Φ's refinement per alternation (`RegisterSettings::refine_steps`).
    pub refine_steps: usize,
}

/// The alternations of Φ refinement and LM steps over every hypothesis (unit frame), from
/// `hypotheses` (a solver each, rigid or with a scale); returns the best-fitting one's solver. Without `refine`, Φ stays as it is (a
/// stored model's) and only the LM steps run; with it, `fit` becomes a private copy the first
/// time it is trained. [`crate::MultistartSettings::tie`] decides the halfway drop and the
/// final pick.
pub(crate) fn alternate<S: Surface>(
    fit: &mut Cow<'_, S>,
    source: &[Point3<f64>],
    hypotheses: Vec<Lm>,
    s: &Schedule<'_>,
    policy: KernelPolicy,
    refine: bool,
    progress: &(dyn Fn(Stage) + Sync),
) -> Alternated {
    let c = &s.coarse_to_fine;
    let (alternations, lm_steps, _) = c.counts(refine && fit.is_local());
    let (tie, tau2) = (s.multistart.tie, s.multistart.truncation.powi(2));
    let mut lms: Vec<(usize, Lm)> = hypotheses.into_iter().enumerate().collect();
    let half = alternations / 2;
    let score_all = |fit: &S, lms: &[(usize, Lm)]| -> Vec<f64> {
        lms.iter()
            .map(|(_, lm)| solver_score(fit.tree(), source, lm, tau2))
            .collect()
    };
    // The scores one alternation before the halfway drop, to tell a hypothesis still closing
    // in from one that has settled.
    let mut before_half = Vec::new();
    for k in 0..alternations {
        if k + 1 == half && lms.len() > 1 {
            before_half = score_all(fit, &lms);
        }
        let kappa = policy.kappa(k, alternations);
        // One evaluation of Φ at the moved source serves the kernel's scale and the gate.
        let mut kernels = Vec::with_capacity(lms.len());
        for (_, lm) in &lms {
            let moved = lm.moved(source);
            if !policy.is_robust() {
                if refine {
                    fit.to_mut().add_source_queries(&moved);
                }
                kernels.push(Kernel::L2);
                continue;
            }
            let (phi, _) = fit.phi().eval_points(&moved, false);
            let kernel = policy.kernel(&phi, kappa);
            if refine {
                let scale = kernel.scale().unwrap_or(f64::INFINITY);
                let near: Vec<[f32; 3]> = moved
                    .iter()
                    .zip(&phi)
                    .filter(|(_, v)| (v.abs() as f64) < scale)
                    .map(|(x, _)| *x)
                    .collect();
                fit.to_mut().add_source_queries(&near);
            }
            kernels.push(kernel);
        }
        if refine {
            fit.to_mut().refine(s.refine_steps, s.refine_lr);
        }
        for ((_, lm), &kernel) in lms.iter_mut().zip(&kernels) {
            lm.run(fit.phi(), source, kernel, lm_steps);
        }
        progress(Stage::Alternation(k + 1, alternations));
        // Halfway, hypotheses that fit clearly worse than the best are dropped: a hypothesis
        // is judged by where one more alternation at its last one's gain would take it, so
        // that one still closing in on the right pose (slowly, under a robust kernel's small
        // scale) is not dropped for a settled wrong one.
        if k + 1 == half && lms.len() > 1 {
            let scores = score_all(fit, &lms);
            let best = scores.iter().copied().fold(f64::INFINITY, f64::min);
            lms = lms
                .into_iter()
                .zip(scores.iter().zip(&before_half))
                .filter(|(_, (&score, &before))| {
                    score - (before - score).max(0.0) <= best * (1.0 + tie)
                })
                .map(|(lm, _)| lm)
                .collect();
        }
    }
    let survivors = lms.len();
    // One hypothesis (an initial guess, tracking) wins without being scored.
    let pick = if lms.len() == 1 {
        0
    } else {
        let scored: Vec<(f64, Isometry3<f64>)> = lms
            .iter()
            .map(|(_, lm)| (solver_score(fit.tree(), source, lm, tau2), lm.pose))
            .collect();
        least_motion(&scored, tie)
    };
    let (winner, lm) = lms.swap_remove(pick);
    Alternated {
        lm,
        survivors,
        winner,
    }
}

/// LM on the frozen Φ from `lm`'s pose until converged, at most
/// [`CoarseToFineSettings::final_lm_steps`] steps
/// ([`CoarseToFineSettings::scene_final_lm_steps`] for a local Φ that was `refined`), with
/// the policy's final κ: Φ itself, or with [`CoarseToFineSettings::final_lm_baked`] the grid a
/// frozen global Φ is baked into.
pub(crate) fn final_lm<S: Surface>(
    fit: &S,
    source: &[Point3<f64>],
    lm: &mut Lm,
    c: &CoarseToFineSettings,
    policy: KernelPolicy,
    refined: bool,
) -> StopReason {
    fn on<F: Field>(
        phi: &F,
        source: &[Point3<f64>],
        lm: &mut Lm,
        steps: usize,
        policy: KernelPolicy,
    ) -> StopReason {
        let kernel = kernel_of(phi, || lm.moved(source), policy, policy.kappa_end());
        lm.run(phi, source, kernel, steps)
    }
    let (_, _, steps) = c.counts(refined && fit.is_local());
    if c.final_lm_baked && !fit.is_local() {
        on(fit.coarse(), source, lm, steps, policy)
    } else {
        on(fit.phi(), source, lm, steps, policy)
    }
}

/// The policy's kernel for `source` (unit frame) moved by `pose`, with `kappa`: Φ is evaluated
/// only when the scale is adaptive.
pub(crate) fn kernel_at<F: Field + ?Sized>(
    phi: &F,
    source: &[Point3<f64>],
    pose: &Isometry3<f64>,
    policy: KernelPolicy,
    kappa: f64,
) -> Kernel {
    kernel_of(phi, || transformed_f32(source, pose), policy, kappa)
}

/// The policy's kernel for the points `moved` gives (unit frame, asked only when the scale is
/// adaptive), with `kappa`.
fn kernel_of<F: Field + ?Sized>(
    phi: &F,
    moved: impl FnOnce() -> Vec<[f32; 3]>,
    policy: KernelPolicy,
    kappa: f64,
) -> Kernel {
    if matches!(policy, KernelPolicy::Adaptive { .. }) {
        let (values, _) = phi.eval_points(&moved(), false);
        policy.kernel(&values, kappa)
    } else {
        policy.kernel(&[], kappa)
    }
}

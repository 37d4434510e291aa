//! Damped Levenberg–Marquardt on SE(3) against a fixed SDF (paper eq. 9–13).
//!
//! Residual of source point `pᵢ` at pose `T`: `rᵢ = Φ(xᵢ)` with `xᵢ = T pᵢ` (unit frame).
//! With the left update `T ← exp(δ^) T` and `δ = [ω; v]`, the Jacobian row is
//! `Jᵢ = [xᵢ × ∇Φ(xᵢ); ∇Φ(xᵢ)]ᵀ`. A step solves `(H + λ diag H) δ = −g` with
//! `H = Σ wᵢ JᵢᵀJᵢ`, `g = Σ wᵢ rᵢ Jᵢᵀ` (weights `wᵢ` from the robust kernel, 1 for least
//! squares), is accepted when the cost drops (then λ shrinks) and retried with a larger λ
//! otherwise.
//!
//! `H` and `g` are summed over fixed chunks of [`BLOCK`] points, in chunk order, so the
//! result is bit-identical for any number of threads.
//!
//! Entry points: [`LmSettings`], [`linearize`], [`cost`], [`Lm`] (one iteration:
//! [`Lm::step`]; iterations until converged or a cap: [`Lm::run`], the one loop every stage
//! uses). Kernels: [`crate::solve::kernel::Kernel`].

use nalgebra::{Isometry3, Matrix6, Point3, Vector3, Vector6};
use rayon::prelude::*;

use crate::base::check;
use crate::base::error::Error;
use crate::field::{Field, BLOCK};
use crate::geometry::cloud::transformed_f32;
use crate::geometry::se3::exp_se3;

pub use crate::solve::kernel::Kernel;

/// Settings of the Levenberg–Marquardt solver.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LmSettings {
    /// Initial damping λ (relative to diag H). Default 1e-2.
    pub initial_lambda: f64,
    /// λ is divided by this after an accepted step. Default 3.
    pub lambda_decrease: f64,
    /// λ is multiplied by this after a rejected step. Default 4.
    pub lambda_increase: f64,
    /// Rejected tries per iteration before giving up. Default 6.
    pub max_tries: usize,
    /// Converged when the rotation step is below this (radians)… Default 1e-5.
    pub rotation_tolerance: f64,
    /// …and the translation step below this (normalised units). Default 1e-5.
    pub translation_tolerance: f64,
}

impl Default for LmSettings {
    fn default() -> Self {
        Self {
            initial_lambda: 1e-2,
            lambda_decrease: 3.0,
            lambda_increase: 4.0,
            max_tries: 6,
            rotation_tolerance: 1e-5,
            translation_tolerance: 1e-5,
        }
    }
}

impl LmSettings {
    /// Checks every field; the error names it (`lm.max_tries`, …).
    pub fn validate(&self) -> Result<(), Error> {
        check::positive("lm.initial_lambda", self.initial_lambda)?;
        check::at_least("lm.lambda_decrease", self.lambda_decrease, 1.0)?;
        check::at_least("lm.lambda_increase", self.lambda_increase, 1.0)?;
        check::count_at_least("lm.max_tries", self.max_tries, 1)?;
        check::non_negative("lm.rotation_tolerance", self.rotation_tolerance)?;
        check::non_negative("lm.translation_tolerance", self.translation_tolerance)
    }
}

/// Why an iterative stage (the LM, the polish's Gauss–Newton) stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum StopReason {
    /// The last step was below both tolerances.
    SmallStep,
    /// No damping lowered the cost any more (a local minimum), or the system could not be
    /// solved.
    NoDecrease,
    /// The iteration cap ran out before convergence.
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

    /// Whether the stage converged (anything but running out of iterations).
    pub fn converged(&self) -> bool {
        *self != StopReason::MaxIterations
    }
}

/// Normal equations at a pose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Linearization {
    /// `Σ wᵢ JᵢᵀJᵢ` (6×6, twist order `[ω; v]`).
    pub h: Matrix6<f64>,
    /// `Σ wᵢ rᵢ Jᵢᵀ`.
    pub g: Vector6<f64>,
    /// `Σ ρ(rᵢ)`.
    pub cost: f64,
}

/// The Jacobian row of a residual `Φ(x)` with respect to a left twist `[ω; v]` applied to the
/// pose that produced `x`: `[x × n; n]`, where `n = ∇Φ(x)` (paper eq. 13). `x` and `n` in the
/// frame the twist acts in.
pub fn jacobian_row(x: &Vector3<f64>, n: &Vector3<f64>) -> Vector6<f64> {
    let c = x.cross(n);
    Vector6::new(c.x, c.y, c.z, n.x, n.y, n.z)
}

/// Normal equations of the points `source` (unit frame) moved by `pose`, against `phi`.
pub fn linearize<F: Field + ?Sized>(
    phi: &F,
    source: &[Point3<f64>],
    pose: &Isometry3<f64>,
    kernel: Kernel,
) -> Linearization {
    let parts: Vec<Linearization> = source
        .par_chunks(BLOCK)
        .map(|chunk| {
            let xs = transformed_f32(chunk, pose);
            let (mut values, mut grads) = (Vec::new(), Vec::new());
            phi.eval_block(&xs, &mut values, Some(&mut grads));
            let mut h = Matrix6::zeros();
            let mut g = Vector6::zeros();
            let mut cost = 0.0;
            for ((x, &r), n) in xs.iter().zip(&values).zip(&grads) {
                let r = r as f64;
                let n = Vector3::new(n[0] as f64, n[1] as f64, n[2] as f64);
                let x = Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64);
                let jrow = jacobian_row(&x, &n);
                let (rho, w) = kernel.rho_weight(r);
                h += w * jrow * jrow.transpose();
                g += (w * r) * jrow;
                cost += rho;
            }
            Linearization { h, g, cost }
        })
        .collect();
    parts.into_iter().fold(
        Linearization {
            h: Matrix6::zeros(),
            g: Vector6::zeros(),
            cost: 0.0,
        },
        |a, b| Linearization {
            h: a.h + b.h,
            g: a.g + b.g,
            cost: a.cost + b.cost,
        },
    )
}

/// `Σ ρ(Φ(T pᵢ))` over `source` (unit frame), summed in fixed chunk order.
pub fn cost<F: Field + ?Sized>(
    phi: &F,
    source: &[Point3<f64>],
    pose: &Isometry3<f64>,
    kernel: Kernel,
) -> f64 {
    let parts: Vec<f64> = source
        .par_chunks(BLOCK)
        .map(|chunk| {
            let xs = transformed_f32(chunk, pose);
            let mut values = Vec::new();
            phi.eval_block(&xs, &mut values, None);
            values
                .iter()
                .map(|&v| kernel.rho_weight(v as f64).0)
                .sum::<f64>()
        })
        .collect();
    parts.into_iter().sum()
}

/// How one LM iteration ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StepOutcome {
    /// The step lowered the cost and was taken.
    Accepted {
        /// Rotation part of the step (radians).
        rotation: f64,
        /// Translation part of the step (normalised units).
        translation: f64,
    },
    /// No damping within `max_tries` lowered the cost; the pose is unchanged.
    NoDecrease,
}

/// A Levenberg–Marquardt solver state: the pose and the damping.
#[derive(Clone, Debug)]
pub struct Lm {
    /// Current pose mapping the (unit-frame) source into the (unit-frame) target.
    pub pose: Isometry3<f64>,
    /// Current damping (reset to the initial one by [`Lm::run`]).
    lambda: f64,
    /// Cost at `pose` after the last iteration.
    pub cost: f64,
    /// Iterations run.
    pub iterations: usize,
    settings: LmSettings,
}

impl Lm {
    /// A solver starting at `pose`.
    pub fn new(pose: Isometry3<f64>, settings: &LmSettings) -> Self {
        Self {
            pose,
            lambda: settings.initial_lambda,
            cost: f64::INFINITY,
            iterations: 0,
            settings: settings.clone(),
        }
    }

    /// Whether a step of this size counts as converged.
    fn is_converged(&self, outcome: &StepOutcome) -> bool {
        match outcome {
            StepOutcome::Accepted {
                rotation,
                translation,
            } => {
                *rotation < self.settings.rotation_tolerance
                    && *translation < self.settings.translation_tolerance
            }
            StepOutcome::NoDecrease => true,
        }
    }

    /// Up to `max_steps` iterations against `phi`, from the initial damping, until a step is
    /// below both tolerances or no damping lowers the cost. `MaxIterations` when the cap ran out
    /// (also for `max_steps` = 0).
    pub fn run<F: Field + ?Sized>(
        &mut self,
        phi: &F,
        source: &[Point3<f64>],
        kernel: Kernel,
        max_steps: usize,
    ) -> StopReason {
        self.lambda = self.settings.initial_lambda;
        for _ in 0..max_steps {
            match self.step(phi, source, kernel) {
                StepOutcome::NoDecrease => return StopReason::NoDecrease,
                outcome if self.is_converged(&outcome) => return StopReason::SmallStep,
                _ => {}
            }
        }
        StopReason::MaxIterations
    }

    /// One LM iteration against `phi`.
    pub fn step<F: Field + ?Sized>(
        &mut self,
        phi: &F,
        source: &[Point3<f64>],
        kernel: Kernel,
    ) -> StepOutcome {
        self.iterations += 1;
        let lin = linearize(phi, source, &self.pose, kernel);
        self.cost = lin.cost;
        for _ in 0..self.settings.max_tries.max(1) {
            let mut a = lin.h;
            for i in 0..6 {
                a[(i, i)] += self.lambda * lin.h[(i, i)].max(1e-12);
            }
            let Some(delta) = a.cholesky().map(|c| c.solve(&(-lin.g))) else {
                self.lambda *= self.settings.lambda_increase;
                continue;
            };
            let candidate = exp_se3(&delta) * self.pose;
            let c = cost(phi, source, &candidate, kernel);
            if c < lin.cost {
                self.pose = candidate;
                self.cost = c;
                self.lambda = (self.lambda / self.settings.lambda_decrease).max(1e-12);
                return StepOutcome::Accepted {
                    rotation: Vector3::new(delta[0], delta[1], delta[2]).norm(),
                    translation: Vector3::new(delta[3], delta[4], delta[5]).norm(),
                };
            }
            self.lambda *= self.settings.lambda_increase;
        }
        StepOutcome::NoDecrease
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::mlp::{Mlp, MlpSettings};
    use rand::SeedableRng;

    #[test]
    fn jacobian_matches_finite_differences_of_the_residual() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        let mlp = Mlp::new(
            &MlpSettings {
                beta: 10.0,
                ..Default::default()
            },
            &mut rng,
        );
        let p = [Point3::new(0.3, -0.2, 0.1)];
        let pose = exp_se3(&Vector6::new(0.2, -0.1, 0.3, 0.05, 0.1, -0.02));
        let lin = linearize(&mlp, &p, &pose, Kernel::L2);
        // g = r J ⇒ J = g / r (single point).
        let r = mlp
            .eval(
                &[{
                    let x = pose * p[0];
                    [x.x as f32, x.y as f32, x.z as f32]
                }],
                false,
            )
            .0[0] as f64;
        let jac = lin.g / r;
        let h = 1e-3;
        for k in 0..6 {
            let mut d = Vector6::zeros();
            d[k] = h;
            let f = |pose: Isometry3<f64>| {
                let x = pose * p[0];
                mlp.eval(&[[x.x as f32, x.y as f32, x.z as f32]], false).0[0] as f64
            };
            let fd = (f(exp_se3(&d) * pose) - f(exp_se3(&-d) * pose)) / (2.0 * h);
            assert!(
                (fd - jac[k]).abs() < 2e-3 * (1.0 + fd.abs()),
                "column {k}: fd {fd} vs {}",
                jac[k]
            );
        }
        assert!((lin.h - jac * jac.transpose()).norm() < 1e-6 * (1.0 + lin.h.norm()));
    }
}

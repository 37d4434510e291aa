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
//! Entry points: [`LmSettings`], [`Kernel`], [`linearize`], [`cost`], [`Lm`].

use nalgebra::{Isometry3, Matrix6, Point3, Vector3, Vector6};
use rayon::prelude::*;

use crate::cloud::transformed_f32;
use crate::mlp::{with_workspace, Mlp, BLOCK};
use crate::se3::exp_se3;

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

/// Robust kernel applied to the residuals (iteratively reweighted least squares).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Kernel {
    /// Plain least squares, `ρ(r) = r²`.
    L2,
    /// Geman–McClure with scale `c` (normalised units): `ρ(r) = c² r² / (c² + r²)`,
    /// weight `w = (c² / (c² + r²))²`.
    GemanMcClure(f64),
}

impl Kernel {
    #[inline]
    fn rho_weight(&self, r: f64) -> (f64, f64) {
        match *self {
            Kernel::L2 => (r * r, 1.0),
            Kernel::GemanMcClure(c) => {
                let c2 = c * c;
                let q = c2 / (c2 + r * r);
                (r * r * q, q * q)
            }
        }
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

/// Normal equations of the points `source` (unit frame) moved by `pose`.
pub fn linearize(
    mlp: &Mlp,
    source: &[Point3<f64>],
    pose: &Isometry3<f64>,
    kernel: Kernel,
) -> Linearization {
    let parts: Vec<Linearization> = source
        .par_chunks(BLOCK)
        .map(|chunk| {
            with_workspace(|ws| {
                let xs = transformed_f32(chunk, pose);
                mlp.forward_block(&xs, true, ws);
                let mut h = Matrix6::zeros();
                let mut g = Vector6::zeros();
                let mut cost = 0.0;
                for (j, x) in xs.iter().enumerate() {
                    let r = ws.value(j) as f64;
                    let n = ws.gradient(j);
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
pub fn cost(mlp: &Mlp, source: &[Point3<f64>], pose: &Isometry3<f64>, kernel: Kernel) -> f64 {
    let parts: Vec<f64> = source
        .par_chunks(BLOCK)
        .map(|chunk| {
            with_workspace(|ws| {
                let xs = transformed_f32(chunk, pose);
                mlp.forward_block(&xs, false, ws);
                (0..xs.len())
                    .map(|j| kernel.rho_weight(ws.value(j) as f64).0)
                    .sum::<f64>()
            })
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
    /// Current damping.
    pub lambda: f64,
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
    pub fn is_converged(&self, outcome: &StepOutcome) -> bool {
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

    /// One LM iteration against `mlp`.
    pub fn step(&mut self, mlp: &Mlp, source: &[Point3<f64>], kernel: Kernel) -> StepOutcome {
        self.iterations += 1;
        let lin = linearize(mlp, source, &self.pose, kernel);
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
            let c = cost(mlp, source, &candidate, kernel);
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
    use crate::mlp::MlpSettings;
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

    #[test]
    fn robust_weights_are_the_derivative_of_rho() {
        let k = Kernel::GemanMcClure(0.05);
        for r in [-0.2, -0.01, 0.0, 0.03, 0.4] {
            let h = 1e-6;
            let drho = (k.rho_weight(r + h).0 - k.rho_weight(r - h).0) / (2.0 * h);
            // IRLS: ρ'(r) = 2 w r.
            assert!((drho - 2.0 * k.rho_weight(r).1 * r).abs() < 1e-6, "r = {r}");
        }
    }
}

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
//! **Similarity** ([`Lm::with_scale`]): the moved point is `xᵢ = T (s pᵢ)` and the step gains a
//! seventh component σ, the left update `x ↦ e^σ exp(δ^) x` (`s ← e^σ s`). The residual is
//! `Φ(xᵢ) · s₀ / s`: the distance measured in the source's units (times the fixed reference
//! `s₀`, so the kernel's thresholds keep the target's units near it). Without the division the
//! cost has its minimum at `s → 0`, where every point collapses onto one surface point; with it
//! that limit costs `Σ (n·R pᵢ)² s₀²` (the source's spread along one normal), far above a true
//! fit. Row: `(s₀/s) [xᵢ × ∇Φ; ∇Φ; ∇Φ·xᵢ − Φ(xᵢ)]`.
//!
//! Entry points: [`LmSettings`], [`linearize`], [`cost`], [`Lm`] (one iteration:
//! [`Lm::step`]; iterations until converged or a cap: [`Lm::run`], the one loop every stage
//! uses). Kernels: [`crate::solve::kernel::Kernel`].

use nalgebra::{Isometry3, Matrix6, Point3, SMatrix, SVector, Vector3, Vector6};
use rayon::prelude::*;

use crate::base::check;
use crate::base::error::Error;
use crate::field::{Field, BLOCK};
use crate::geometry::cloud::{scaled_f32, transformed_f32};
use crate::geometry::se3::{exp_se3, similarity_step};

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
    /// The polish's steps stopped shrinking: none fell below the smallest so far for
    /// [`crate::PolishSettings::patience`] iterations (its planes and weights change with every
    /// step, and the steps wander instead of converging).
    Stalled,
}

impl StopReason {
    /// Snake-case name: `small_step`, `no_decrease`, `max_iterations` or `stalled`.
    pub fn name(&self) -> &'static str {
        match self {
            StopReason::SmallStep => "small_step",
            StopReason::NoDecrease => "no_decrease",
            StopReason::MaxIterations => "max_iterations",
            StopReason::Stalled => "stalled",
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

/// The Jacobian row of a similarity's residual `Φ(x)` (unscaled by `s₀/s`) with respect to
/// the left step `[ω; v; σ]`: `[x × n; n; n·x − Φ]` (see the module docs).
pub fn similarity_row(x: &Vector3<f64>, n: &Vector3<f64>, phi: f64) -> SVector<f64, 7> {
    let c = x.cross(n);
    SVector::<f64, 7>::from([c.x, c.y, c.z, n.x, n.y, n.z, n.dot(x) - phi])
}

/// The scale of a similarity solve ([`Lm::with_scale`]): the moved point is `x = T (s p)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaleDof {
    /// The current scale (target units per source unit).
    pub s: f64,
    /// The solver keeps `s` at or above this…
    pub min: f64,
    /// …and at or below this.
    pub max: f64,
    /// The fixed reference `s₀` of the residual `Φ(x) s₀ / s` (see the module docs).
    pub reference: f64,
}

impl ScaleDof {
    /// `s₀ / s`: the residual's factor.
    pub fn factor(&self) -> f64 {
        self.reference / self.s
    }
}

/// Normal equations of a similarity solve (7×7, step order `[ω; v; σ]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScaledLinearization {
    /// `Σ wᵢ JᵢᵀJᵢ`.
    pub h: SMatrix<f64, 7, 7>,
    /// `Σ wᵢ rᵢ Jᵢᵀ`.
    pub g: SVector<f64, 7>,
    /// `Σ ρ(rᵢ)`.
    pub cost: f64,
}

/// [`linearize`] for a similarity: the points `source` (unit frame) scaled by `dof.s` and moved
/// by `pose`, residuals `Φ(x) s₀ / s`.
pub fn linearize_scaled<F: Field + ?Sized>(
    phi: &F,
    source: &[Point3<f64>],
    pose: &Isometry3<f64>,
    dof: &ScaleDof,
    kernel: Kernel,
) -> ScaledLinearization {
    let f = dof.factor();
    let zero = ScaledLinearization {
        h: SMatrix::zeros(),
        g: SVector::zeros(),
        cost: 0.0,
    };
    let parts: Vec<ScaledLinearization> = source
        .par_chunks(BLOCK)
        .map(|chunk| {
            let xs = scaled_f32(chunk, dof.s, pose);
            let (mut values, mut grads) = (Vec::new(), Vec::new());
            phi.eval_block(&xs, &mut values, Some(&mut grads));
            let mut part = zero;
            for ((x, &v), n) in xs.iter().zip(&values).zip(&grads) {
                let n = Vector3::new(n[0] as f64, n[1] as f64, n[2] as f64);
                let x = Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64);
                let jrow = similarity_row(&x, &n, v as f64) * f;
                let r = v as f64 * f;
                let (rho, w) = kernel.rho_weight(r);
                part.h += w * jrow * jrow.transpose();
                part.g += (w * r) * jrow;
                part.cost += rho;
            }
            part
        })
        .collect();
    parts.into_iter().fold(zero, |a, b| ScaledLinearization {
        h: a.h + b.h,
        g: a.g + b.g,
        cost: a.cost + b.cost,
    })
}

/// [`cost`] for a similarity: `Σ ρ(Φ(T (s pᵢ)) s₀ / s)`.
pub fn cost_scaled<F: Field + ?Sized>(
    phi: &F,
    source: &[Point3<f64>],
    pose: &Isometry3<f64>,
    dof: &ScaleDof,
    kernel: Kernel,
) -> f64 {
    let f = dof.factor();
    let parts: Vec<f64> = source
        .par_chunks(BLOCK)
        .map(|chunk| {
            let xs = scaled_f32(chunk, dof.s, pose);
            let mut values = Vec::new();
            phi.eval_block(&xs, &mut values, None);
            values
                .iter()
                .map(|&v| kernel.rho_weight(v as f64 * f).0)
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
        /// Rotation part of the step (radians); for a similarity, the larger of it and the
        /// change of `ln s`.
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
    /// The scale of a similarity solve ([`Self::with_scale`]); `None`: rigid.
    pub scale: Option<ScaleDof>,
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
            scale: None,
            settings: settings.clone(),
        }
    }

    /// A similarity solver starting at `pose` and `scale.s` (see the module docs).
    pub fn with_scale(pose: Isometry3<f64>, scale: ScaleDof, settings: &LmSettings) -> Self {
        Self {
            scale: Some(scale),
            ..Self::new(pose, settings)
        }
    }

    /// The scale, 1 for a rigid solve.
    pub fn s(&self) -> f64 {
        self.scale.map_or(1.0, |d| d.s)
    }

    /// `source` moved by the current pose (and scale), as f32.
    pub fn moved(&self, source: &[Point3<f64>]) -> Vec<[f32; 3]> {
        match &self.scale {
            None => transformed_f32(source, &self.pose),
            Some(d) => scaled_f32(source, d.s, &self.pose),
        }
    }

    /// The factor on a squared distance that puts it in the residual's units: 1 when rigid,
    /// `(s₀/s)²` for a similarity (distances in the source's units).
    pub fn distance_factor(&self) -> f64 {
        self.scale.map_or(1.0, |d| d.factor().powi(2))
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
        if let Some(dof) = self.scale {
            return self.step_scaled(phi, source, kernel, dof);
        }
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

    /// [`Self::step`] of a similarity solve.
    fn step_scaled<F: Field + ?Sized>(
        &mut self,
        phi: &F,
        source: &[Point3<f64>],
        kernel: Kernel,
        dof: ScaleDof,
    ) -> StepOutcome {
        self.iterations += 1;
        let lin = linearize_scaled(phi, source, &self.pose, &dof, kernel);
        self.cost = lin.cost;
        for _ in 0..self.settings.max_tries.max(1) {
            let mut a = lin.h;
            for i in 0..7 {
                a[(i, i)] += self.lambda * lin.h[(i, i)].max(1e-12);
            }
            let Some(delta) = a.cholesky().map(|c| c.solve(&(-lin.g))) else {
                self.lambda *= self.settings.lambda_increase;
                continue;
            };
            let (pose, s) = similarity_step(&delta, &self.pose, dof.s, (dof.min, dof.max));
            let moved = ScaleDof { s, ..dof };
            let c = cost_scaled(phi, source, &pose, &moved, kernel);
            if c < lin.cost {
                self.pose = pose;
                self.scale = Some(moved);
                self.cost = c;
                self.lambda = (self.lambda / self.settings.lambda_decrease).max(1e-12);
                let rotation = Vector3::new(delta[0], delta[1], delta[2]).norm();
                return StepOutcome::Accepted {
                    rotation: rotation.max((s / dof.s).ln().abs()),
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

    /// A random MLP (seed `seed`) with a smooth activation (β = 10), for the finite differences.
    fn smooth_mlp(seed: u64) -> Mlp {
        Mlp::new(
            &MlpSettings {
                beta: 10.0,
                ..Default::default()
            },
            &mut rand_chacha::ChaCha8Rng::seed_from_u64(seed),
        )
    }

    #[test]
    fn jacobian_matches_finite_differences_of_the_residual() {
        let mlp = smooth_mlp(2);
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

    /// The signed distance to an axis-aligned box of half-sides `half` (exact, analytic).
    struct BoxField {
        half: Vector3<f64>,
    }

    impl Field for BoxField {
        fn eval_block(
            &self,
            xs: &[[f32; 3]],
            values: &mut Vec<f32>,
            gradients: Option<&mut Vec<[f32; 3]>>,
        ) {
            values.clear();
            let mut grads = Vec::new();
            for x in xs {
                let x = Vector3::new(x[0] as f64, x[1] as f64, x[2] as f64);
                let q = x.abs() - self.half;
                let outside = q.map(|v| v.max(0.0));
                let (phi, g) = if outside.norm() > 0.0 {
                    (outside.norm(), outside.normalize())
                } else {
                    let k = q.imax();
                    let mut g = Vector3::zeros();
                    g[k] = 1.0;
                    (q[k], g)
                };
                let g = g.component_mul(&x.map(|v| if v < 0.0 { -1.0 } else { 1.0 }));
                values.push(phi as f32);
                grads.push([g.x as f32, g.y as f32, g.z as f32]);
            }
            if let Some(out) = gradients {
                *out = grads;
            }
        }
    }

    #[test]
    fn without_the_source_units_the_scale_collapses_and_with_them_it_does_not() {
        use rand::Rng;
        let half = Vector3::new(0.5, 0.3, 0.2);
        let field = BoxField { half };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        // Points on the box's faces, 0.01 of noise along the normal, in a source frame whose
        // unit is 1/0.7 of the target's: the truth is s = 0.7, R = I, t = 0.
        let truth = 0.7;
        let source: Vec<Point3<f64>> = (0..1200)
            .map(|i| {
                let k = i % 3;
                let mut p = Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
                .component_mul(&half);
                p[k] = half[k] * if i % 2 == 0 { 1.0 } else { -1.0 };
                p[k] += rng.random_range(-0.01..0.01);
                Point3::from(p / truth)
            })
            .collect();
        let settings = LmSettings::default();
        // For each scale, the rigid pose that fits best (from the truth's pose, and from the
        // source's centroid on the largest face): the plain cost Σ Φ² and the cost in the
        // source's units, Σ (Φ s₀/s)².
        let scales: Vec<f64> = (0..=30)
            .map(|i| 0.007 * 10f64.powf(i as f64 / 10.0))
            .collect();
        let costs: Vec<(f64, f64)> = scales
            .iter()
            .map(|&s| {
                let scaled: Vec<Point3<f64>> = source.iter().map(|p| p * s).collect();
                let plain = [Vector3::zeros(), Vector3::new(0.0, 0.0, half.z)]
                    .iter()
                    .map(|t| {
                        let mut lm = Lm::new(Isometry3::translation(t.x, t.y, t.z), &settings);
                        lm.run(&field, &scaled, Kernel::L2, 50);
                        cost(&field, &scaled, &lm.pose, Kernel::L2)
                    })
                    .fold(f64::INFINITY, f64::min);
                (plain, plain * (truth / s).powi(2))
            })
            .collect();
        let argmin = |f: fn(&(f64, f64)) -> f64| {
            let i = (0..costs.len())
                .min_by(|&a, &b| f(&costs[a]).total_cmp(&f(&costs[b])))
                .unwrap();
            scales[i]
        };
        assert_eq!(argmin(|c| c.0), scales[0], "plain cost: {costs:?}");
        let guarded = argmin(|c| c.1);
        assert!((guarded / truth - 1.0).abs() < 0.1, "{guarded}: {costs:?}");
        // The similarity solver, from twice the scale, 10° and an offset, lands on the truth.
        let start = exp_se3(&Vector6::new(0.1, -0.12, 0.08, 0.03, -0.02, 0.02));
        let dof = ScaleDof {
            s: 2.0 * truth,
            min: 0.007,
            max: 7.0,
            reference: 2.0 * truth,
        };
        let mut lm = Lm::with_scale(start, dof, &settings);
        lm.run(&field, &source, Kernel::L2, 100);
        assert!((lm.s() / truth - 1.0).abs() < 0.005, "scale {}", lm.s());
        assert!(lm.pose.rotation.angle().to_degrees() < 0.5, "{:?}", lm.pose);
    }

    #[test]
    fn similarity_jacobian_matches_finite_differences_of_the_residual() {
        let mlp = smooth_mlp(3);
        let p = [Point3::new(0.3, -0.2, 0.1)];
        let pose = exp_se3(&Vector6::new(0.2, -0.1, 0.3, 0.05, 0.1, -0.02));
        let dof = ScaleDof {
            s: 1.3,
            min: 0.1,
            max: 10.0,
            reference: 0.9,
        };
        let lin = linearize_scaled(&mlp, &p, &pose, &dof, Kernel::L2);
        let residual = |pose: &Isometry3<f64>, s: f64| {
            let x = pose * Point3::from(p[0].coords * s);
            mlp.eval(&[[x.x as f32, x.y as f32, x.z as f32]], false).0[0] as f64 * 0.9 / s
        };
        let jac = lin.g / residual(&pose, dof.s);
        let h = 1e-3;
        for k in 0..7 {
            let mut d = SVector::<f64, 7>::zeros();
            d[k] = h;
            let (plus, s_plus) = similarity_step(&d, &pose, dof.s, (0.1, 10.0));
            let (minus, s_minus) = similarity_step(&-d, &pose, dof.s, (0.1, 10.0));
            let fd = (residual(&plus, s_plus) - residual(&minus, s_minus)) / (2.0 * h);
            assert!(
                (fd - jac[k]).abs() < 2e-3 * (1.0 + fd.abs()),
                "column {k}: fd {fd} vs {}",
                jac[k]
            );
        }
    }
}

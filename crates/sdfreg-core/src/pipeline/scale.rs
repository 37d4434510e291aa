//! Similarity registration: a scale estimated with the pose (`p_target = s R p_source + t`).
//!
//! Off by default ([`ScaleSettings::enabled`]): a rigid registration never reads this module.
//! When on, every LM step has a seventh component, `ln s` ([`crate::solve::lm::Lm::with_scale`]),
//! whose residual is the SDF measured in the *source's* units, `Φ(x) s₀/s`: the plain
//! `Σ Φ(s R pᵢ + t)²` is smallest at `s → 0`, every point collapsed onto one surface point (the
//! shrink trap). The polish gains the same seventh component, the hypotheses are scored on the
//! same scale-free distances, and the scale stays within [`ScaleSettings::min`] and
//! [`ScaleSettings::max`].
//!
//! **Why not a two-sided cost** (the source's own field at the target's points as well): it needs
//! a second field fitted to the source, which doubles the pre-fit (half of a call's time), and a
//! partial source (a scan against a full model) is not covered by the target's points, so that
//! half of the cost pulls the wrong way. Measuring distances in the source's units removes the
//! collapse with no second field: at `s → 0` the cost tends to the source's spread along one
//! normal (times `s₀²`), which only a flat source can bring to zero — and a flat source's scale is
//! truly free, flagged by [`crate::Degeneracy::scale_free`].
//!
//! **Starts** ([`scale_starts`]): the ratio of the clouds' RMS radii about their centroids, the
//! geometric mean of their principal spreads' ratios, and a unit factor (1000, 0.001: mm ↔ m) when
//! one lies within [`ScaleSettings::unit_ratio`] of those; each start runs the multi-start over
//! rotations, and all hypotheses meet in the coarse-to-fine loop.

use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};

use crate::base::check;
use crate::base::error::Error;

/// The unit factors tried as scale starts (mm → m, m → mm).
pub const UNIT_FACTORS: [f64; 2] = [1e-3, 1e3];

/// Similarity registration: whether a scale is estimated, and its bounds and starts.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ScaleSettings {
    /// Estimate a scale with the pose. Default false (rigid; every result as without this
    /// group).
    pub enabled: bool,
    /// Smallest scale accepted, target units per source unit. Default 0.1; `None` with
    /// [`Self::max`] `None` too: 0.1 to 10 times the unit factor the extents point to (1, 1000
    /// or 0.001), so millimetres against metres work without a range.
    pub min: Option<f64>,
    /// Largest scale accepted (see [`Self::min`]). Default `None`.
    pub max: Option<f64>,
    /// The scale to start from instead of the extents' estimate (with an initial pose, the
    /// scale of its 3×3 block). Default `None`.
    pub initial: Option<f64>,
    /// A unit factor ([`UNIT_FACTORS`]) is tried as a start too when the extents' estimate lies
    /// within this ratio of it. Default 3.
    pub unit_ratio: f64,
    /// Starts closer than this ratio to an earlier one are dropped. Default 1.05.
    pub distinct_ratio: f64,
    /// Adam steps of the pre-fit of a full call with a scale, in place of
    /// [`FitSettings::prefit_steps`](crate::FitSettings::prefit_steps). Default 2000: see
    /// [`Self::refine_steps`].
    #[serde(default = "default_prefit_steps")]
    pub prefit_steps: usize,
    /// Adam steps of refinement per alternation with a scale, in place of
    /// [`FitSettings::refine_steps`](crate::FitSettings::refine_steps) (an object's; a scene
    /// keeps its own). Default 40. The scale is pinned by Φ off the surface, so with a scale
    /// the fit keeps the work it had before the one-shot speed-up (500 pre-fit steps of four
    /// times today's batches, 40 steps of refinement). Measured with `sdfreg eval --shapes
    /// ../shared/data/modelnet40-half1 --pairs 36 --protocol scaled-indep`: mean scale error
    /// 0.74 % before the speed-up, 2.14 % with the rigid 250 and 10 (a chair, a curtain and a
    /// keyboard 17–22 % off, their rotations right), 1.09 % with 2000 and 10, 0.57 % with 2000
    /// and 40. Settings written before these fields read them.
    #[serde(default = "default_refine_steps")]
    pub refine_steps: usize,
}

fn default_prefit_steps() -> usize {
    2000
}

fn default_refine_steps() -> usize {
    40
}

impl Default for ScaleSettings {
    fn default() -> Self {
        Self {
            enabled: false,
            min: None,
            max: None,
            initial: None,
            unit_ratio: 3.0,
            distinct_ratio: 1.05,
            prefit_steps: default_prefit_steps(),
            refine_steps: default_refine_steps(),
        }
    }
}

/// The default range's ends, relative to the unit factor the extents point to.
pub const DEFAULT_RANGE: (f64, f64) = (0.1, 10.0);

impl ScaleSettings {
    /// Checks every field; the error names it (`scale.min`, …). A range needs both ends, each
    /// positive, `min < max`.
    pub fn validate(&self) -> Result<(), Error> {
        match (self.min, self.max) {
            (None, None) => {}
            (Some(min), Some(max)) => {
                check::positive("scale.min", min)?;
                check::positive("scale.max", max)?;
                if min >= max {
                    return Err(Error::InvalidSetting {
                        name: "scale.min",
                        reason: format!("must be below scale.max ({max}), got {min}"),
                    });
                }
            }
            (Some(_), None) | (None, Some(_)) => {
                return Err(Error::InvalidSetting {
                    name: "scale.min",
                    reason: "scale.min and scale.max go together (both or neither)".into(),
                })
            }
        }
        if let Some(s) = self.initial {
            check::positive("scale.initial", s)?;
        }
        check::at_least("scale.unit_ratio", self.unit_ratio, 1.0)?;
        check::at_least("scale.distinct_ratio", self.distinct_ratio, 1.0)
    }

    /// The range the scale stays in, given the extents' estimate `estimate`.
    pub fn range(&self, estimate: f64) -> (f64, f64) {
        match (self.min, self.max) {
            (Some(min), Some(max)) => (min, max),
            _ => {
                let unit = unit_factor(estimate);
                (DEFAULT_RANGE.0 * unit, DEFAULT_RANGE.1 * unit)
            }
        }
    }
}

/// The unit factor (1, 1000 or 0.001) nearest to `estimate` on a log scale.
fn unit_factor(estimate: f64) -> f64 {
    [1.0, UNIT_FACTORS[0], UNIT_FACTORS[1]]
        .into_iter()
        .min_by(|a, b| {
            (estimate / a)
                .ln()
                .abs()
                .total_cmp(&(estimate / b).ln().abs())
        })
        .unwrap_or(1.0)
}

/// Centroid and covariance eigenvalues (ascending) of `points`.
fn spread(points: impl Iterator<Item = Vector3<f64>> + Clone) -> (f64, [f64; 3]) {
    let n = points.clone().count().max(1) as f64;
    let c = points.clone().sum::<Vector3<f64>>() / n;
    let cov = points.fold(Matrix3::zeros(), |m, p| m + (p - c) * (p - c).transpose()) / n;
    let mut e: Vec<f64> = SymmetricEigen::new(cov)
        .eigenvalues
        .iter()
        .map(|v| v.max(0.0))
        .collect();
    e.sort_by(f64::total_cmp);
    (e.iter().sum::<f64>(), [e[0], e[1], e[2]])
}

/// The scale starts and the range for `source` against `target` (any frame shared by both; the
/// ratio is frame-free): see the module docs. The first start is the extents' estimate (or
/// [`ScaleSettings::initial`]).
pub fn scale_starts(
    s: &ScaleSettings,
    source: &[Point3<f64>],
    target: &[[f32; 3]],
) -> (Vec<f64>, (f64, f64)) {
    let (src_var, src_axes) = spread(source.iter().map(|p| p.coords));
    let (tgt_var, tgt_axes) = spread(
        target
            .iter()
            .map(|p| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)),
    );
    let rms = (tgt_var / src_var.max(f64::MIN_POSITIVE)).sqrt();
    let axes = (0..3)
        .map(|k| (tgt_axes[k].max(1e-30) / src_axes[k].max(1e-30)).ln())
        .sum::<f64>()
        / 6.0;
    let mut estimates = vec![rms];
    if axes.is_finite() {
        estimates.push(axes.exp());
    }
    let range = s.range(s.initial.unwrap_or(rms));
    let mut starts: Vec<f64> = Vec::new();
    let mut push = |v: f64| {
        let v = v.clamp(range.0, range.1);
        if v.is_finite()
            && starts
                .iter()
                .all(|&u| (v / u).ln().abs() > s.distinct_ratio.ln())
        {
            starts.push(v);
        }
    };
    if let Some(initial) = s.initial {
        push(initial);
        return (starts, range);
    }
    for &e in &estimates {
        push(e);
    }
    for unit in UNIT_FACTORS {
        if (rms / unit).ln().abs() <= s.unit_ratio.ln() {
            push(unit);
        }
    }
    (starts, range)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn starts_follow_the_extents_and_the_unit_factor() {
        let target: Vec<[f32; 3]> = (0..200)
            .map(|i| {
                let t = i as f32 * 0.1;
                [t.sin() * 0.05, t.cos() * 0.03, (t * 0.3).sin() * 0.02]
            })
            .collect();
        // The same shape in millimetres, cropped to 80 % (a partial view reads a bit smaller).
        let source: Vec<Point3<f64>> = target[..160]
            .iter()
            .map(|p| Point3::new(p[0] as f64, p[1] as f64, p[2] as f64) * 1000.0)
            .collect();
        let (starts, range) = scale_starts(&ScaleSettings::default(), &source, &target);
        assert!((starts[0] / 1e-3 - 1.0).abs() < 0.3, "{starts:?}");
        // The unit factor itself, unless an estimate lies within 5 % of it already.
        assert!(
            starts.iter().any(|s| (s / 1e-3 - 1.0).abs() < 0.05),
            "{starts:?}"
        );
        assert!((range.0 / 1e-4 - 1.0).abs() < 1e-12 && (range.1 / 1e-2 - 1.0).abs() < 1e-12);
        let given = ScaleSettings {
            min: Some(0.5),
            max: Some(2.0),
            ..Default::default()
        };
        let (starts, range) = scale_starts(&given, &source, &target);
        assert_eq!(range, (0.5, 2.0));
        assert!(starts.iter().all(|&s| s == 0.5), "{starts:?}");
    }

    #[test]
    fn a_bad_range_names_the_setting() {
        let bad = |min, max| {
            ScaleSettings {
                min,
                max,
                ..Default::default()
            }
            .validate()
            .unwrap_err()
            .to_string()
        };
        assert!(bad(Some(2.0), Some(1.0)).contains("`scale.min`"));
        assert!(bad(Some(1.0), Some(1.0)).contains("must be below"));
        assert!(bad(Some(-1.0), Some(1.0)).contains("`scale.min`"));
        assert!(bad(Some(0.5), None).contains("both or neither"));
    }
}

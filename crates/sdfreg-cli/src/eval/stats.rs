//! The evaluation's statistics: per-pair numbers, per-protocol summaries and the paper's
//! robustness figures.

use nalgebra::Isometry3;
use sdfreg_core::geometry::se3::pose_errors;
use sdfreg_core::Registration;

use super::protocol::{euler_errors, Protocol};

/// One registered pair's numbers.
#[derive(serde::Serialize)]
pub struct PairResult {
    pub protocol: String,
    pub index: usize,
    pub shape: String,
    pub source_points: usize,
    pub target_points: usize,
    pub rotation_error_deg: f64,
    pub translation_error: f64,
    /// Per-axis Euler-angle errors (Rx·Ry·Rz convention), degrees.
    pub euler_error_deg: [f64; 3],
    /// Per-axis translation errors.
    pub translation_error_xyz: [f64; 3],
    /// The scale found (target units per source unit) and its error against the truth's,
    /// percent (`|ŝ/s − 1|·100`): the scaled protocols only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scale: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scale_error_pct: Option<f64>,
    pub converged: bool,
    pub fitness: f64,
    pub iterations: usize,
    /// Whether the robust kernel produced the result.
    pub robust: bool,
    /// Why the stage that set the final pose stopped.
    pub stop_reason: &'static str,
    /// The motions sdfreg reported as free (the data do not determine them), described.
    pub free_motions: Vec<String>,
    pub time_s: f64,
    /// Each stage's wall time, milliseconds (`Registration::stage_times`).
    pub stage_ms: std::collections::BTreeMap<&'static str, f64>,
}

impl PairResult {
    /// The numbers of registration `r` of pair `index` (`shape`, `source_points` and
    /// `target_points` big) against the ground truth `truth`.
    pub fn new(
        protocol: Protocol,
        index: usize,
        shape: &str,
        points: (usize, usize),
        r: &Registration,
        truth: &Isometry3<f64>,
        truth_scale: Option<f64>,
    ) -> Self {
        let (re, te) = pose_errors(&r.t_target_source, truth);
        let dt = r.t_target_source.translation.vector - truth.translation.vector;
        Self {
            protocol: protocol.name(),
            index,
            shape: shape.to_string(),
            source_points: points.0,
            target_points: points.1,
            rotation_error_deg: re,
            translation_error: te,
            euler_error_deg: euler_errors(&r.t_target_source, truth),
            translation_error_xyz: [dt.x, dt.y, dt.z],
            scale: truth_scale.map(|_| r.scale),
            scale_error_pct: truth_scale.map(|s| (r.scale / s - 1.0).abs() * 100.0),
            converged: r.converged,
            fitness: r.fitness,
            iterations: r.iterations,
            robust: r.robust,
            stop_reason: r.stop_reason.name(),
            free_motions: r.degeneracy.free.iter().map(|f| f.to_string()).collect(),
            time_s: r.time.as_secs_f64(),
            stage_ms: r
                .stage_times
                .named()
                .iter()
                .map(|(name, t)| (*name, t.as_secs_f64() * 1e3))
                .collect(),
        }
    }
}

/// The per-protocol figures of the table.
#[derive(serde::Serialize)]
pub struct Summary {
    pub protocol: String,
    pub pairs: usize,
    pub rotation_mean_deg: f64,
    pub rotation_rmse_deg: f64,
    pub rotation_median_deg: f64,
    pub translation_mean: f64,
    pub translation_rmse: f64,
    pub translation_median: f64,
    /// Mean |Euler-angle error| over pairs and axes (the paper's "MAE", after DCP), degrees.
    pub euler_mae_deg: f64,
    /// RMS Euler-angle error over pairs and axes (the paper's "RMSE"), degrees.
    pub euler_rmse_deg: f64,
    /// Mean |translation error| over pairs and axes.
    pub translation_mae: f64,
    /// RMS translation error over pairs and axes.
    pub translation_axis_rmse: f64,
    pub recall_5deg_005: f64,
    pub recall_1deg_001: f64,
    /// Pairs whose result reports a free motion (see `sdfreg_core::solve::degeneracy`).
    pub flagged: usize,
    /// Rotation error mean over the pairs not flagged, degrees.
    pub rotation_mean_unflagged_deg: f64,
    /// Scale error (percent) mean, median and maximum: the scaled protocols only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scale_error_pct: Option<[f64; 3]>,
    pub median_time_s: f64,
}

/// The median (the mean of the two middle values for an even count); NaN when empty.
pub fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

/// Population standard deviation.
fn sd(v: &[f64]) -> f64 {
    let m = mean(v);
    (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / v.len() as f64).sqrt()
}

pub fn summarise(protocol: &Protocol, results: &[PairResult]) -> Summary {
    let rot: Vec<f64> = results.iter().map(|r| r.rotation_error_deg).collect();
    let tr: Vec<f64> = results.iter().map(|r| r.translation_error).collect();
    let euler: Vec<f64> = results.iter().flat_map(|r| r.euler_error_deg).collect();
    let t_axes: Vec<f64> = results
        .iter()
        .flat_map(|r| r.translation_error_xyz)
        .collect();
    let abs = |v: &[f64]| v.iter().map(|x| x.abs()).collect::<Vec<_>>();
    let time: Vec<f64> = results.iter().map(|r| r.time_s).collect();
    let unflagged: Vec<f64> = results
        .iter()
        .filter(|r| r.free_motions.is_empty())
        .map(|r| r.rotation_error_deg)
        .collect();
    let scale: Vec<f64> = results.iter().filter_map(|r| r.scale_error_pct).collect();
    let under = |r: f64, t: f64| {
        results
            .iter()
            .filter(|x| x.rotation_error_deg < r && x.translation_error < t)
            .count() as f64
            / results.len() as f64
    };
    Summary {
        protocol: protocol.name(),
        pairs: results.len(),
        rotation_mean_deg: mean(&rot),
        rotation_rmse_deg: rms(&rot),
        rotation_median_deg: median(&rot),
        translation_mean: mean(&tr),
        translation_rmse: rms(&tr),
        translation_median: median(&tr),
        euler_mae_deg: mean(&abs(&euler)),
        euler_rmse_deg: rms(&euler),
        translation_mae: mean(&abs(&t_axes)),
        translation_axis_rmse: rms(&t_axes),
        recall_5deg_005: under(5.0, 0.05),
        recall_1deg_001: under(1.0, 0.01),
        flagged: results.len() - unflagged.len(),
        rotation_mean_unflagged_deg: mean(&unflagged),
        scale_error_pct: (!scale.is_empty()).then(|| {
            [
                mean(&scale),
                median(&scale),
                scale.iter().copied().fold(0.0, f64::max),
            ]
        }),
        median_time_s: median(&time),
    }
}

/// The paper's robustness figures (its Table 3): mean and standard deviation, across its four
/// protocols, of the per-protocol Euler MAE of rotation and MAE of translation; also of the
/// geodesic rotation mean.
#[derive(serde::Serialize)]
pub struct Robustness {
    pub avg_r_deg: f64,
    pub sd_r_deg: f64,
    pub avg_t: f64,
    pub sd_t: f64,
    pub geodesic_avg_deg: f64,
    pub geodesic_sd_deg: f64,
}

/// [`Robustness`] over the paper's four protocols, when all four are among `summaries`.
pub fn robustness(summaries: &[Summary]) -> Option<Robustness> {
    let paper: Vec<&Summary> = Protocol::PAPER
        .iter()
        .filter_map(|p| summaries.iter().find(|s| s.protocol == p.name()))
        .collect();
    (paper.len() == Protocol::PAPER.len()).then(|| {
        let r: Vec<f64> = paper.iter().map(|s| s.euler_mae_deg).collect();
        let t: Vec<f64> = paper.iter().map(|s| s.translation_mae).collect();
        let g: Vec<f64> = paper.iter().map(|s| s.rotation_mean_deg).collect();
        Robustness {
            avg_r_deg: mean(&r),
            sd_r_deg: sd(&r),
            avg_t: mean(&t),
            sd_t: sd(&t),
            geodesic_avg_deg: mean(&g),
            geodesic_sd_deg: sd(&g),
        }
    })
}

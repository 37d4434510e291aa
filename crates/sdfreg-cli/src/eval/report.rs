//! The evaluation's printed report: a Markdown table row per protocol, its failures and flagged
//! pairs, and the paper's robustness line.

use super::stats::{median, PairResult, Robustness, Summary};

/// The table's header.
pub fn header() {
    println!("| protocol | pairs | rot mean (°) | rot RMSE | rot median | t mean | t RMSE | t median | Euler MAE(R) | Euler RMSE(R) | MAE(t) | RMSE(t) | <5°/0.05 | <1°/0.01 | median time (s) |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
}

/// One protocol's row, then its pairs over 5° and those flagged with a free motion.
pub fn protocol(s: &Summary, results: &[PairResult]) {
    println!(
        "| {} | {} | {:.3} | {:.3} | {:.3} | {:.4} | {:.4} | {:.4} | {:.3} | {:.3} | {:.4} | {:.4} | {:.2} | {:.2} | {:.3} |",
        s.protocol,
        s.pairs,
        s.rotation_mean_deg,
        s.rotation_rmse_deg,
        s.rotation_median_deg,
        s.translation_mean,
        s.translation_rmse,
        s.translation_median,
        s.euler_mae_deg,
        s.euler_rmse_deg,
        s.translation_mae,
        s.translation_axis_rmse,
        s.recall_5deg_005,
        s.recall_1deg_001,
        s.median_time_s
    );
    if let Some([mean, median, max]) = s.scale_error_pct {
        println!("  scale error: mean {mean:.3} %, median {median:.3} %, max {max:.3} %");
    }
    for r in results.iter().filter(|r| r.rotation_error_deg > 5.0) {
        println!(
            "  failure: pair {} ({}) rotation error {:.1}°, translation error {:.3}",
            r.index, r.shape, r.rotation_error_deg, r.translation_error
        );
    }
    if s.flagged > 0 {
        println!(
            "  {} of {} pairs flagged with a free motion; rotation error mean without them {:.3}°",
            s.flagged, s.pairs, s.rotation_mean_unflagged_deg
        );
        for r in results.iter().filter(|r| !r.free_motions.is_empty()) {
            println!(
                "  flagged: pair {} ({}) rotation error {:.2}°: {}",
                r.index,
                r.shape,
                r.rotation_error_deg,
                r.free_motions.join("; ")
            );
        }
    }
}

/// Where the time went: each stage's median over `results`, milliseconds, in pipeline order.
pub fn stage_times(results: &[PairResult]) {
    let Some(first) = results.first() else {
        return;
    };
    let parts: Vec<String> = sdfreg_core::StageTimes::default()
        .named()
        .iter()
        .map(|(name, _)| name)
        .filter(|name| first.stage_ms.contains_key(*name))
        .map(|name| {
            let ms: Vec<f64> = results.iter().map(|r| r.stage_ms[name]).collect();
            format!("{name} {:.1}", median(&ms))
        })
        .collect();
    println!(
        "time per stage, median over the {} pairs (ms): {}",
        results.len(),
        parts.join(", ")
    );
}

/// `--via-model`'s figures of one protocol, besides the table's (which are the registrations
/// against the model).
#[derive(Default)]
pub struct ViaModel {
    /// Each pair's fit of its target as a model, seconds.
    pub fit_times: Vec<f64>,
    /// Each pair's full `register` call (fit and register in one), seconds.
    pub full_times: Vec<f64>,
    /// Its rotation error, degrees.
    pub full_errors: Vec<f64>,
}

impl ViaModel {
    /// Prints the median fit, the median full call and the registration against the model as
    /// a share of it; returns them for the JSON file.
    pub fn print(&self, protocol: &str, median_register_s: f64) -> serde_json::Value {
        let fit = median(&self.fit_times);
        let full = median(&self.full_times);
        let full_mean = self.full_errors.iter().sum::<f64>() / self.full_errors.len().max(1) as f64;
        println!(
            "  via the model: median fit {fit:.3} s once per target; median registration against it {median_register_s:.3} s = {:.1} % of a full register call on the same pairs (median {full:.3} s, rotation error mean {full_mean:.3}°)",
            100.0 * median_register_s / full
        );
        serde_json::json!({
            "protocol": protocol,
            "median_fit_s": fit,
            "median_register_against_model_s": median_register_s,
            "median_full_register_s": full,
            "share_of_full_register": median_register_s / full,
            "full_register_rotation_error_mean_deg": full_mean,
        })
    }
}

/// The paper's robustness line.
pub fn robustness(r: &Robustness) {
    println!(
        "robustness over clean/noise/partial/density (paper's Table 3): AVG(R) {:.3}°, SD(R) {:.3}°, AVG(t) {:.4}, SD(t) {:.4} (Euler MAE); geodesic mean {:.3}° ± {:.3}°",
        r.avg_r_deg, r.sd_r_deg, r.avg_t, r.sd_t, r.geodesic_avg_deg, r.geodesic_sd_deg
    );
}

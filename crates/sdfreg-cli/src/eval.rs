//! `sdfreg eval`: the paper's ModelNet40 protocols (and variants) over a folder of shapes.
//!
//! Pairs are seeded by the protocol's position in [`Protocol::ALL`] and the pair index, so a
//! pair does not depend on which other protocols were asked for. Per protocol it prints the
//! geodesic rotation and translation errors (mean, RMSE, median), the paper's per-axis Euler
//! MAE/RMSE, recall and the median time; then the paper's robustness figures over its four
//! protocols. `--write-pairs` keeps the pairs for other programs (`benches/compare.py`).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use nalgebra::Point3;
use rand::SeedableRng;
use sdfreg_core::io::{read_point_cloud, write_point_cloud};
use sdfreg_core::protocol::{euler_errors, make_pair, pose_errors, Pair, Protocol};

use crate::args::EvalArgs;
use crate::{matrix_lines, matrix_rows};

fn find_shapes(dir: &Path, out: &mut Vec<PathBuf>) -> Result<()> {
    let entries = std::fs::read_dir(dir).with_context(|| format!("{}", dir.display()))?;
    for e in entries {
        let p = e?.path();
        if p.is_dir() {
            find_shapes(&p, out)?;
        } else if p.extension().is_some_and(|e| e.eq_ignore_ascii_case("ply")) {
            out.push(p);
        }
    }
    Ok(())
}

/// The protocols named by `--protocol`.
fn parse_protocols(spec: &str) -> Result<Vec<Protocol>> {
    let mut out: Vec<Protocol> = Vec::new();
    for name in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let more = match name {
            "all" => Protocol::ALL.to_vec(),
            "paper" => Protocol::PAPER.to_vec(),
            _ => vec![name
                .parse::<Protocol>()
                .map_err(|e| anyhow::anyhow!("--protocol: {e}, paper or all"))?],
        };
        for p in more {
            if !out.contains(&p) {
                out.push(p);
            }
        }
    }
    if out.is_empty() {
        bail!("--protocol: no protocol named");
    }
    Ok(out)
}

/// One registered pair's numbers.
#[derive(serde::Serialize)]
struct PairResult {
    protocol: String,
    index: usize,
    shape: String,
    source_points: usize,
    target_points: usize,
    rotation_error_deg: f64,
    translation_error: f64,
    /// Per-axis Euler-angle errors (Rx·Ry·Rz convention), degrees.
    euler_error_deg: [f64; 3],
    /// Per-axis translation errors.
    translation_error_xyz: [f64; 3],
    converged: bool,
    fitness: f64,
    iterations: usize,
    /// The motions sdfreg reported as free (the data do not determine them), described.
    free_motions: Vec<String>,
    time_s: f64,
}

/// The per-protocol figures of the table.
#[derive(serde::Serialize)]
struct Summary {
    protocol: String,
    pairs: usize,
    rotation_mean_deg: f64,
    rotation_rmse_deg: f64,
    rotation_median_deg: f64,
    translation_mean: f64,
    translation_rmse: f64,
    translation_median: f64,
    /// Mean |Euler-angle error| over pairs and axes (the paper's "MAE", after DCP), degrees.
    euler_mae_deg: f64,
    /// RMS Euler-angle error over pairs and axes (the paper's "RMSE"), degrees.
    euler_rmse_deg: f64,
    /// Mean |translation error| over pairs and axes.
    translation_mae: f64,
    /// RMS translation error over pairs and axes.
    translation_axis_rmse: f64,
    recall_5deg_005: f64,
    recall_1deg_001: f64,
    /// Pairs whose result reports a free motion (see `sdfreg_core::degeneracy`).
    flagged: usize,
    /// Rotation error mean over the pairs not flagged, degrees.
    rotation_mean_unflagged_deg: f64,
    median_time_s: f64,
}

fn median(v: &[f64]) -> f64 {
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

fn summarise(protocol: &Protocol, results: &[PairResult]) -> Summary {
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
        median_time_s: median(&time),
    }
}

/// Writes one pair as `dir/source.ply`, `dir/target.ply` and `dir/gt.txt` (4×4 source into
/// target, the convention of ../shared/data).
fn write_pair(dir: &Path, pair: &Pair) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}", dir.display()))?;
    write_point_cloud(dir.join("source.ply"), &pair.source)?;
    write_point_cloud(dir.join("target.ply"), &pair.target)?;
    // Every digit, so the ground truth reads back exactly.
    let gt = matrix_lines(&pair.t_target_source.to_homogeneous(), |v| {
        format!("{v:.17e}")
    });
    std::fs::write(dir.join("gt.txt"), gt)
        .with_context(|| format!("{}", dir.join("gt.txt").display()))?;
    Ok(())
}

pub fn run(a: EvalArgs) -> Result<()> {
    let protocols = parse_protocols(&a.protocol)?;
    if let Some(j) = &a.json {
        if j.exists() && !a.force {
            bail!("{}: exists; pass --force to overwrite", j.display());
        }
    }
    if let Some(dir) = &a.write_pairs {
        if dir.join("pairs.json").exists() && !a.force {
            bail!(
                "{}: holds pairs already; pass --force to overwrite",
                dir.display()
            );
        }
    }
    let mut paths = Vec::new();
    find_shapes(&a.shapes, &mut paths)?;
    paths.sort();
    if paths.is_empty() {
        bail!("{}: no .ply shapes found", a.shapes.display());
    }
    let shapes: Vec<(String, Vec<Point3<f64>>)> = paths
        .iter()
        .map(|p| {
            Ok((
                p.strip_prefix(&a.shapes).unwrap_or(p).display().to_string(),
                read_point_cloud(p)?,
            ))
        })
        .collect::<Result<_>>()?;
    let settings = a.common.settings();
    println!(
        "sdfreg eval: {} shapes from {}, {} pairs per protocol, seed {}",
        shapes.len(),
        a.shapes.display(),
        a.pairs,
        a.common.seed
    );
    if !a.pairs_only {
        println!("| protocol | pairs | rot mean (°) | rot RMSE | rot median | t mean | t RMSE | t median | Euler MAE(R) | Euler RMSE(R) | MAE(t) | RMSE(t) | <5°/0.05 | <1°/0.01 | median time (s) |");
        println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    }
    let mut all = Vec::new();
    let mut summaries = Vec::new();
    let mut written = Vec::new();
    for protocol in &protocols {
        let pi = Protocol::ALL
            .iter()
            .position(|p| p == protocol)
            .unwrap_or(0);
        let bar = crate::progress_bar(a.pairs as u64);
        bar.set_message(protocol.name());
        let mut results = Vec::new();
        for i in 0..a.pairs {
            let (name, shape) = &shapes[i % shapes.len()];
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
                a.common
                    .seed
                    .wrapping_mul(1_000_003)
                    .wrapping_add((pi * 100_000 + i) as u64),
            );
            let pair = make_pair(shape, *protocol, &mut rng);
            if let Some(dir) = &a.write_pairs {
                let stem = Path::new(name)
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default();
                let rel = PathBuf::from(protocol.name()).join(format!("{i:03}_{stem}"));
                write_pair(&dir.join(&rel), &pair)?;
                written.push(serde_json::json!({
                    "protocol": protocol.name(),
                    "index": i,
                    "shape": name,
                    "dir": rel,
                    "source_points": pair.source.len(),
                    "target_points": pair.target.len(),
                    "t_target_source": matrix_rows(&pair.t_target_source.to_homogeneous()),
                }));
            }
            if a.pairs_only {
                bar.inc(1);
                continue;
            }
            let r = sdfreg_core::register(&pair.source, &pair.target, None, &settings)
                .with_context(|| format!("pair {i} ({name})"))?;
            let (re, te) = pose_errors(&r.t_target_source, &pair.t_target_source);
            let dt = r.t_target_source.translation.vector - pair.t_target_source.translation.vector;
            results.push(PairResult {
                protocol: protocol.name(),
                index: i,
                shape: name.clone(),
                source_points: pair.source.len(),
                target_points: pair.target.len(),
                rotation_error_deg: re,
                translation_error: te,
                euler_error_deg: euler_errors(&r.t_target_source, &pair.t_target_source),
                translation_error_xyz: [dt.x, dt.y, dt.z],
                converged: r.converged,
                fitness: r.fitness,
                iterations: r.iterations,
                free_motions: r.degeneracy.free.iter().map(|f| f.to_string()).collect(),
                time_s: r.time.as_secs_f64(),
            });
            bar.inc(1);
        }
        bar.finish_and_clear();
        if a.pairs_only {
            continue;
        }
        let s = summarise(protocol, &results);
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
        summaries.push(s);
        all.extend(results);
    }
    // The paper's robustness figures (its Table 3): mean and standard deviation, across its four
    // protocols, of the per-protocol Euler MAE of rotation and MAE of translation.
    let paper: Vec<&Summary> = Protocol::PAPER
        .iter()
        .filter_map(|p| summaries.iter().find(|s| s.protocol == p.name()))
        .collect();
    let robustness = (paper.len() == Protocol::PAPER.len()).then(|| {
        let r: Vec<f64> = paper.iter().map(|s| s.euler_mae_deg).collect();
        let t: Vec<f64> = paper.iter().map(|s| s.translation_mae).collect();
        let g: Vec<f64> = paper.iter().map(|s| s.rotation_mean_deg).collect();
        println!(
            "robustness over clean/noise/partial/density (paper's Table 3): AVG(R) {:.3}°, SD(R) {:.3}°, AVG(t) {:.4}, SD(t) {:.4} (Euler MAE); geodesic mean {:.3}° ± {:.3}°",
            mean(&r), sd(&r), mean(&t), sd(&t), mean(&g), sd(&g)
        );
        serde_json::json!({
            "avg_r_deg": mean(&r), "sd_r_deg": sd(&r), "avg_t": mean(&t), "sd_t": sd(&t),
            "geodesic_avg_deg": mean(&g), "geodesic_sd_deg": sd(&g),
        })
    });
    if let Some(dir) = &a.write_pairs {
        let index = serde_json::json!({
            "shapes": a.shapes,
            "seed": a.common.seed,
            "convention": "t_target_source maps source into target: p_target = R p_source + t",
            "pairs": written,
        });
        let path = dir.join("pairs.json");
        std::fs::write(&path, serde_json::to_string_pretty(&index)? + "\n")
            .with_context(|| format!("{}", path.display()))?;
        println!("pairs written to {}", dir.display());
    }
    if let Some(path) = &a.json {
        let json = serde_json::json!({
            "shapes": a.shapes,
            "seed": a.common.seed,
            "settings": settings,
            "summary": summaries,
            "robustness": robustness,
            "pairs": all,
        });
        std::fs::write(path, serde_json::to_string_pretty(&json)? + "\n")
            .with_context(|| format!("{}", path.display()))?;
    }
    Ok(())
}

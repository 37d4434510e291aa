//! `sdfreg eval`: the paper's ModelNet40 protocols over a folder of shapes.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use rand::SeedableRng;
use sdfreg_core::io::read_point_cloud;
use sdfreg_core::protocol::{make_pair, pose_errors, Protocol};

use crate::args::EvalArgs;

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

/// One registered pair's numbers.
#[derive(serde::Serialize)]
struct PairResult {
    protocol: &'static str,
    index: usize,
    shape: String,
    source_points: usize,
    target_points: usize,
    rotation_error_deg: f64,
    translation_error: f64,
    converged: bool,
    fitness: f64,
    iterations: usize,
    time_s: f64,
}

fn median(v: &mut [f64]) -> f64 {
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

pub fn run(a: EvalArgs) -> Result<()> {
    let protocols: Vec<Protocol> = if a.protocol == "all" {
        Protocol::ALL.to_vec()
    } else {
        vec![a.protocol.parse::<Protocol>().map_err(anyhow::Error::msg)?]
    };
    if let Some(j) = &a.json {
        if j.exists() && !a.force {
            bail!("{}: exists; pass --force to overwrite", j.display());
        }
    }
    let mut paths = Vec::new();
    find_shapes(&a.shapes, &mut paths)?;
    paths.sort();
    if paths.is_empty() {
        bail!("{}: no .ply shapes found", a.shapes.display());
    }
    let shapes: Vec<(String, Vec<nalgebra::Point3<f64>>)> = paths
        .iter()
        .map(|p| {
            Ok((
                p.strip_prefix(&a.shapes).unwrap_or(p).display().to_string(),
                read_point_cloud(p)?,
            ))
        })
        .collect::<Result<_>>()?;
    let settings = a.common.settings();
    let mut all = Vec::new();
    println!(
        "sdfreg eval: {} shapes from {}, {} pairs per protocol, seed {}",
        shapes.len(),
        a.shapes.display(),
        a.pairs,
        a.common.seed
    );
    println!("| protocol | pairs | rot mean (°) | rot RMSE | rot median | t mean | t RMSE | t median | <5°/0.05 | <1°/0.01 | median time (s) |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for protocol in &protocols {
        // Pairs depend on the protocol itself, not on which others were asked for.
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
            let r = sdfreg_core::register(&pair.source, &pair.target, None, &settings)
                .with_context(|| format!("pair {i} ({name})"))?;
            let (re, te) = pose_errors(&r.t_target_source, &pair.t_target_source);
            results.push(PairResult {
                protocol: protocol.name(),
                index: i,
                shape: name.clone(),
                source_points: pair.source.len(),
                target_points: pair.target.len(),
                rotation_error_deg: re,
                translation_error: te,
                converged: r.converged,
                fitness: r.fitness,
                iterations: r.iterations,
                time_s: r.time.as_secs_f64(),
            });
            bar.inc(1);
        }
        bar.finish_and_clear();
        let n = results.len() as f64;
        let mut rot: Vec<f64> = results.iter().map(|r| r.rotation_error_deg).collect();
        let mut tr: Vec<f64> = results.iter().map(|r| r.translation_error).collect();
        let mut time: Vec<f64> = results.iter().map(|r| r.time_s).collect();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / n;
        let rmse = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
        let under = |r: f64, t: f64| {
            results
                .iter()
                .filter(|x| x.rotation_error_deg < r && x.translation_error < t)
                .count() as f64
                / n
        };
        println!(
            "| {} | {} | {:.3} | {:.3} | {:.3} | {:.4} | {:.4} | {:.4} | {:.2} | {:.2} | {:.3} |",
            protocol.name(),
            results.len(),
            mean(&rot),
            rmse(&rot),
            median(&mut rot),
            mean(&tr),
            rmse(&tr),
            median(&mut tr),
            under(5.0, 0.05),
            under(1.0, 0.01),
            median(&mut time)
        );
        for r in results.iter().filter(|r| r.rotation_error_deg > 5.0) {
            println!(
                "  failure: pair {} ({}) rotation error {:.1}°, translation error {:.3}",
                r.index, r.shape, r.rotation_error_deg, r.translation_error
            );
        }
        all.extend(results);
    }
    if let Some(path) = &a.json {
        let json = serde_json::json!({ "shapes": a.shapes, "seed": a.common.seed, "settings": settings, "pairs": all });
        std::fs::write(path, serde_json::to_string_pretty(&json)? + "\n")
            .with_context(|| format!("{}", path.display()))?;
    }
    Ok(())
}

//! `sdfreg eval`: the paper's ModelNet40 protocols (and variants) over a folder of shapes.
//!
//! Evaluation code, kept out of the engine: [`protocol`] makes the pairs (and the paper's Euler
//! error measure), [`pairs`] finds shapes, seeds and writes pairs, [`stats`] summarises, [`report`]
//! prints. Per protocol it prints the geodesic rotation and translation errors (mean, RMSE,
//! median), the paper's per-axis Euler MAE/RMSE, recall and the median time; then the paper's
//! robustness figures over its four protocols. The scaled protocols (`scaled`, `scaled-indep`)
//! register with a scale estimated and print the scale error too. `--write-pairs` keeps the pairs for other
//! programs (`benches/compare.py`).

mod pairs;
mod protocol;
mod report;
mod stats;

use anyhow::{bail, Context, Result};
use sdfreg_core::SdfModel;

use crate::args::EvalArgs;
use stats::{robustness, summarise, PairResult};

pub fn run(a: EvalArgs) -> Result<()> {
    let protocols = pairs::parse_protocols(&a.protocol)?;
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
    let shapes = pairs::load_shapes(&a.shapes)?;
    let settings = a.common.settings()?;
    println!(
        "sdfreg eval: {} shapes from {}, {} pairs per protocol, seed {}",
        shapes.len(),
        a.shapes.display(),
        a.pairs,
        a.common.seed
    );
    if !a.pairs_only {
        report::header();
    }
    let mut all = Vec::new();
    let mut summaries = Vec::new();
    let mut written = Vec::new();
    let mut via_models = Vec::new();
    for &protocol in &protocols {
        let bar = crate::progress_bar(a.pairs as u64);
        bar.set_message(protocol.name());
        let mut results = Vec::new();
        let mut via = report::ViaModel::default();
        // The scaled protocols estimate a scale; the others as the flags say.
        let mut settings = settings.clone();
        settings.scale.enabled |= protocol.scaled();
        for i in 0..a.pairs {
            let (name, shape) = &shapes[i % shapes.len()];
            let pair = pairs::seeded_pair(shape, protocol, i, a.common.seed);
            if let Some(dir) = &a.write_pairs {
                written.push(pairs::write_indexed(dir, protocol, i, name, &pair)?);
            }
            bar.inc(1);
            if a.pairs_only {
                continue;
            }
            let points = (pair.source.len(), pair.target.len());
            let truth_scale = protocol.scaled().then_some(pair.scale);
            let r = if a.via_model {
                // The full call on the same pair, for the time against a stored model as a
                // share of it, measured in the same run.
                let full = sdfreg_core::register(&pair.source, &pair.target, None, &settings)
                    .with_context(|| format!("pair {i} ({name})"))?;
                via.full_times.push(full.time.as_secs_f64());
                let full = PairResult::new(
                    protocol,
                    i,
                    name,
                    points,
                    &full,
                    &pair.t_target_source,
                    truth_scale,
                );
                via.full_errors.push(full.rotation_error_deg);
                let start = std::time::Instant::now();
                let model = SdfModel::fit(&pair.target, &settings);
                via.fit_times.push(start.elapsed().as_secs_f64());
                model.and_then(|m| m.register(&pair.source, None, &settings))
            } else {
                sdfreg_core::register(&pair.source, &pair.target, None, &settings)
            }
            .with_context(|| format!("pair {i} ({name})"))?;
            results.push(PairResult::new(
                protocol,
                i,
                name,
                points,
                &r,
                &pair.t_target_source,
                truth_scale,
            ));
        }
        bar.finish_and_clear();
        if a.pairs_only {
            continue;
        }
        let s = summarise(&protocol, &results);
        report::protocol(&s, &results);
        if a.via_model {
            via_models.push(via.print(&protocol.name(), s.median_time_s));
        }
        summaries.push(s);
        all.extend(results);
    }
    let robustness = robustness(&summaries);
    if let Some(r) = &robustness {
        report::robustness(r);
    }
    report::stage_times(&all);
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
            "via_model": a.via_model.then_some(via_models),
            "pairs": all,
        });
        std::fs::write(path, serde_json::to_string_pretty(&json)? + "\n")
            .with_context(|| format!("{}", path.display()))?;
    }
    Ok(())
}

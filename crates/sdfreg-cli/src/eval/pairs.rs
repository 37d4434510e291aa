//! The pairs of an evaluation: shapes found under a folder, the protocols asked for, each pair
//! seeded by its protocol's position in [`Protocol::ALL`] and its index (so a pair does not
//! depend on which other protocols were asked for), and pairs written for other programs.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use nalgebra::Point3;
use rand::SeedableRng;
use sdfreg_core::io::{read_point_cloud, write_point_cloud};

use super::protocol::{make_pair, Pair, Protocol};
use crate::output::{matrix_lines, matrix_rows};

/// The `.ply` shapes under `dir` (recursively, sorted), each named by its path below `dir`.
pub fn load_shapes(dir: &Path) -> Result<Vec<(String, Vec<Point3<f64>>)>> {
    let mut paths = Vec::new();
    find_shapes(dir, &mut paths)?;
    paths.sort();
    if paths.is_empty() {
        bail!("{}: no .ply shapes found", dir.display());
    }
    paths
        .iter()
        .map(|p| {
            Ok((
                p.strip_prefix(dir).unwrap_or(p).display().to_string(),
                read_point_cloud(p)?,
            ))
        })
        .collect()
}

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
pub fn parse_protocols(spec: &str) -> Result<Vec<Protocol>> {
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

/// Pair `index` of `protocol` made from `shape` with the evaluation's `seed`.
pub fn seeded_pair(shape: &[Point3<f64>], protocol: Protocol, index: usize, seed: u64) -> Pair {
    let pi = Protocol::every().position(|p| p == protocol).unwrap_or(0);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
        seed.wrapping_mul(1_000_003)
            .wrapping_add((pi * 100_000 + index) as u64),
    );
    make_pair(shape, protocol, &mut rng)
}

/// Writes one pair as `dir/source.ply`, `dir/target.ply` and `dir/gt.txt` (4×4 source into
/// target, the convention of ../shared/data).
fn write_pair(dir: &Path, pair: &Pair) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}", dir.display()))?;
    write_point_cloud(dir.join("source.ply"), &pair.source)?;
    write_point_cloud(dir.join("target.ply"), &pair.target)?;
    // Every digit, so the ground truth reads back exactly.
    let gt = matrix_lines(&pair.matrix(), |v| format!("{v:.17e}"));
    std::fs::write(dir.join("gt.txt"), gt)
        .with_context(|| format!("{}", dir.join("gt.txt").display()))?;
    Ok(())
}

/// Writes pair `index` of `protocol` under `root` as `PROTOCOL/NNN_SHAPE/` and returns its
/// entry of `pairs.json`.
pub fn write_indexed(
    root: &Path,
    protocol: Protocol,
    index: usize,
    shape: &str,
    pair: &Pair,
) -> Result<serde_json::Value> {
    let stem = Path::new(shape)
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let rel = PathBuf::from(protocol.name()).join(format!("{index:03}_{stem}"));
    write_pair(&root.join(&rel), pair)?;
    Ok(serde_json::json!({
        "protocol": protocol.name(),
        "index": index,
        "shape": shape,
        "dir": rel,
        "source_points": pair.source.len(),
        "target_points": pair.target.len(),
        "t_target_source": matrix_rows(&pair.matrix()),
        "scale": pair.scale,
    }))
}

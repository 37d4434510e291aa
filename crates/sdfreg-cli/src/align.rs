//! `sdfreg align`: many scans into one frame (`sdfreg_core::align`), written as poses.json, with
//! the merged model and its mesh on request.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use nalgebra::{Isometry3, Point3};
use sdfreg_core::io::{
    read_e57_scans, write_e57_scans, write_mesh, write_point_cloud, E57ScanRef, Format,
};
use sdfreg_core::views::poses_file;
use sdfreg_core::AlignSettings;

use crate::args::AlignArgs;

/// Some scans were left out (exit code 3, as a batch with failed rows).
#[derive(Debug, thiserror::Error)]
#[error("{left} of {total} scans left out (see {output})")]
pub struct SomeLeftOut {
    pub left: usize,
    pub total: usize,
    pub output: String,
}

pub fn run(a: AlignArgs) -> Result<()> {
    let inputs: Vec<&Path> = a.scans.iter().map(PathBuf::as_path).collect();
    for out in [
        Some(&a.output),
        a.save_model.as_ref(),
        a.mesh.as_ref(),
        a.aligned.as_ref(),
    ]
    .into_iter()
    .flatten()
    {
        crate::refuse_overwrite(out, &inputs, a.force)?;
    }
    if let Some(path) = &a.aligned {
        Format::of(path)?;
    }
    if let Some(d) = a.max_distance.filter(|d| !(d.is_finite() && *d > 0.0)) {
        bail!(
            "--max-distance {}: must be a positive finite number (the scans' units)",
            crate::args::shown(d)
        );
    }
    if a.common.scale {
        bail!(
            "--scale: align registers rigidly (the views of one scan campaign share their units)"
        );
    }
    let mut settings = AlignSettings {
        register: a.common.settings_from("views")?,
        anchor: a.anchor,
        closure_pairs: a.closure_pairs,
        joint_rounds: a.joint_rounds,
        consensus: sdfreg_core::ConsensusSettings {
            iterations: a.consensus_iterations,
            ..Default::default()
        },
        threads: a.common.threads,
        seen_from: a.seen_from,
        max_in_free_space: a.max_in_free_space,
        ..Default::default()
    };
    settings.register.threads = a.common.threads;
    // A scan that cannot be read is left out by name, as one that fits nowhere.
    let mut unreadable: Vec<(usize, String)> = Vec::new();
    let mut index = Vec::new();
    let mut scans = Vec::new();
    let mut views = Vec::new();
    for path in &a.scans {
        for (view, points) in read_views(path, &a.input, a.common.seed) {
            match points {
                Ok(points) => {
                    index.push(views.len());
                    scans.push(points);
                }
                Err(e) => {
                    eprintln!("sdfreg: {}: left out: {e:#}", view.label);
                    unreadable.push((views.len(), format!("{e:#}")));
                }
            }
            views.push(view);
        }
    }
    if !index.contains(&a.anchor) {
        bail!(
            "--anchor {}: scan {} ({}) is not among the readable scans",
            a.anchor,
            a.anchor,
            views.get(a.anchor).map_or("none", |v| v.label.as_str())
        );
    }
    settings.anchor = index.iter().position(|&k| k == a.anchor).expect("checked");
    let init = a
        .init
        .as_deref()
        .map(|path| read_poses(path, views.len()))
        .transpose()?
        .map(|poses| index.iter().map(|&k| poses[k]).collect::<Vec<_>>());
    let alignment = sdfreg_core::align(&scans, init.as_deref(), &settings)
        .map_err(|e| anyhow::anyhow!("{e}").context(format!("{} scans", views.len())))?;
    for (k, why) in &alignment.left_out {
        eprintln!("sdfreg: {}: left out: {why}", views[index[*k]].label);
    }
    let labels: Vec<String> = views.iter().map(|v| v.label.clone()).collect();
    let mut json = poses_file::poses_json(&alignment, &labels, &index, &unreadable);
    for (k, view) in views.iter().enumerate() {
        if let Some((scan, name)) = &view.in_file {
            let entry = &mut json["scans"][k];
            entry["file"] = view.file.display().to_string().into();
            entry["scan"] = (*scan).into();
            if let Some(name) = name {
                entry["name"] = name.clone().into();
            }
        }
    }
    if let Some(d) = a.max_distance {
        let evaluations = alignment.evaluate(&scans, d)?;
        for (k, e) in evaluations.iter().enumerate() {
            if let Some(e) = e {
                json["scans"][index[k]]["evaluation"] = crate::evaluation_json(e);
            }
        }
        let measured: Vec<(usize, f64)> = evaluations
            .iter()
            .enumerate()
            .filter_map(|(k, e)| e.map(|e| (k, e.fitness)))
            .collect();
        if let Some(&(worst, lowest)) = measured.iter().min_by(|x, y| x.1.total_cmp(&y.1)) {
            eprintln!(
                "sdfreg: within {} of the other scans: {:.3} of a scan's points on average, lowest {lowest:.3} ({})",
                crate::args::shown(d),
                measured.iter().map(|m| m.1).sum::<f64>() / measured.len() as f64,
                views[index[worst]].label,
            );
        }
    }
    std::fs::write(&a.output, serde_json::to_string_pretty(&json)? + "\n")
        .with_context(|| format!("{}", a.output.display()))?;
    if let Some(path) = &a.aligned {
        write_aligned(path, &alignment, &scans, &index, &views)?;
    }
    if a.save_model.is_some() || a.mesh.is_some() {
        let model = alignment.merged_model(&scans, &settings.register)?;
        if let Some(path) = &a.save_model {
            model.save(path)?;
        }
        if let Some(path) = &a.mesh {
            let (vertices, triangles) = model.mesh(a.mesh_resolution)?;
            write_mesh(path, &vertices, &triangles)?;
        }
    }
    let placed = alignment.poses.iter().filter(|p| p.is_some()).count();
    let t = &alignment.times;
    eprintln!(
        "sdfreg: {placed} of {} scans aligned into the frame of {} in {:.1} s (models {:.1} s, pairs {:.1} s, graph {:.2} s, unplaced {:.1} s, consensus {:.1} s, joint refinement {:.1} s); {} of {} pairs kept",
        views.len(),
        views[a.anchor].label,
        alignment.time.as_secs_f64(),
        t.models.as_secs_f64(),
        t.pairs.as_secs_f64(),
        t.graph.as_secs_f64(),
        t.unplaced.as_secs_f64(),
        t.consensus.as_secs_f64(),
        t.joint.as_secs_f64(),
        alignment.edges.iter().filter(|e| e.kept).count(),
        alignment.edges.len(),
    );
    let left = views.len() - placed;
    if left > 0 {
        return Err(SomeLeftOut {
            left,
            total: views.len(),
            output: a.output.display().to_string(),
        }
        .into());
    }
    Ok(())
}

/// `--aligned`: the placed scans, as the scans of an E57 file (each its points as read and its
/// pose into the anchor's frame, named as in its E57 file or by its file) or, in another format,
/// their points moved into the anchor's frame as one cloud.
fn write_aligned(
    path: &Path,
    alignment: &sdfreg_core::Alignment,
    scans: &[Vec<Point3<f64>>],
    index: &[usize],
    views: &[View],
) -> Result<()> {
    let placed: Vec<E57ScanRef<'_>> = alignment
        .poses
        .iter()
        .zip(scans)
        .zip(index)
        .filter_map(|((pose, points), &k)| {
            let view = &views[k];
            let name = match &view.in_file {
                Some((_, Some(name))) => name.as_str(),
                _ => view.label.as_str(),
            };
            pose.map(|pose| E57ScanRef {
                name: Some(name),
                pose,
                points,
            })
        })
        .collect();
    if matches!(Format::of(path), Ok(Format::E57)) {
        write_e57_scans(path, &placed)?;
    } else {
        let moved: Vec<Point3<f64>> = placed
            .iter()
            .flat_map(|s| s.points.iter().map(move |p| s.pose * p))
            .collect();
        write_point_cloud(path, &moved)?;
    }
    Ok(())
}

/// One scan given to the alignment: a cloud file, or one scan of an E57 file that holds several.
struct View {
    file: PathBuf,
    /// For one scan of an E57 file: its index in the file and its name there.
    in_file: Option<(usize, Option<String>)>,
    /// How messages and poses.json's edges name it: the file, `#k` after it for the k-th scan
    /// of an E57 file.
    label: String,
}

/// The scans in `path`: its cloud, or each scan of an E57 file that holds more than one, in
/// its own frame (the file's poses are not used: they are what the alignment finds), each
/// with its points or why it cannot be read. An E57 file of one scan is that scan placed by its
/// pose, as `read_point_cloud` reads it.
fn read_views(
    path: &Path,
    input: &crate::args::InputArgs,
    seed: u64,
) -> Vec<(View, Result<Vec<Point3<f64>>>)> {
    let view = |in_file, label: String| View {
        file: path.into(),
        in_file,
        label,
    };
    let whole = |points| vec![(view(None, path.display().to_string()), points)];
    if !matches!(Format::of(path), Ok(Format::E57)) {
        return whole(crate::read_cloud(path, input, seed));
    }
    let scans = match read_e57_scans(path, input.drop_non_finite) {
        Ok((scans, dropped)) => {
            let kept: usize = scans.iter().map(|s| s.points.len()).sum();
            crate::say_dropped(&path.display().to_string(), dropped, kept + dropped);
            scans
        }
        Err(e) => return whole(Err(e.into())),
    };
    if let [scan] = scans.as_slice() {
        let placed: Vec<Point3<f64>> = scan.points.iter().map(|p| scan.pose * p).collect();
        crate::say_left_out(&path.display().to_string(), &placed);
        return whole(Ok(placed));
    }
    scans
        .into_iter()
        .enumerate()
        .map(|(k, scan)| {
            let label = format!("{}#{k}", path.display());
            let points = if scan.points.is_empty() {
                Err(anyhow::anyhow!("scan {k} has no points"))
            } else {
                crate::say_left_out(&label, &scan.points);
                Ok(scan.points)
            };
            (view(Some((k, scan.name)), label), points)
        })
        .collect()
}

/// Initial poses from a poses file (its `scans[].transformation`, in order; one per scan, `None`
/// for a scan written without one: its pairs are registered from nothing).
fn read_poses(path: &Path, n: usize) -> Result<Vec<Option<Isometry3<f64>>>> {
    let poses = poses_file::load_poses(path)?;
    if poses.len() != n {
        bail!(
            "{}: {} poses for {n} scans (one per scan, in order)",
            path.display(),
            poses.len()
        );
    }
    Ok(poses)
}

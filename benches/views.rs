//! Many views of the procedural room (`sdfreg_core::sim::lidar::room_loop`): N scans from
//! sensor poses in a loop, aligned into the first scan's frame from no guesses; prints each
//! pose's error against the simulator's truth, the loop's closure (the last pose's error
//! against the first non-anchor's), the kept edges' mean rotation error in their targets'
//! frames (a bias every pose inherits), the time per stage and the edges kept.
//!
//!     cargo bench --bench views                 # 8 views, 64 beams
//!     cargo bench --bench views -- --views 100  # peak memory: run under /usr/bin/time -v
//!     cargo bench --bench views -- --write DIR  # also DIR/scan_NNN.ply and DIR/truth.json
//!     cargo bench --bench views -- --joint 0    # without the joint refinement
//!     cargo bench --bench views -- --consensus 30  # with the multi-view refinement
//!     cargo bench --bench views -- --consensus 30 --consensus-points 16384  # its sample per scan
//!     cargo bench --bench views -- --reference-consensus ../shared/data
//!     cargo bench --bench views -- --range-noise 0   # the sensor's range noise, metres
//!
//! `--reference-consensus DATA` instead starts the multi-view refinement
//! (`sdfreg_core::views::consensus`) from the Stanford bunny's reference poses
//! (`DATA/stanford/bunny/data/gt_scan_to_world.txt`) and prints how far the poses its scans'
//! points agree on lie from them: what the reference is worth at this precision.

use nalgebra::{Isometry3, Matrix4};
use sdfreg_core::geometry::se3::{isometry_from_matrix, pose_errors};
use sdfreg_core::sim::lidar::{room_loop, Sensor};
use sdfreg_core::views::consensus::consensus;
use sdfreg_core::{align, AlignSettings, ConsensusSettings};

/// The value after `flag` on the command line (cargo bench passes `--bench` too).
fn arg(flag: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    let i = args.iter().position(|a| a == flag)?;
    args.get(i + 1).cloned()
}

fn main() {
    if let Some(data) = arg("--reference-consensus") {
        return reference_consensus(std::path::Path::new(&data));
    }
    let views: usize = arg("--views").map_or(8, |v| v.parse().expect("--views N"));
    let mut sensor = if views > 16 {
        Sensor::spinning_32()
    } else {
        Sensor::spinning_64()
    };
    if let Some(noise) = arg("--range-noise") {
        sensor.range_noise = noise.parse().expect("--range-noise METRES");
    }
    let (scans, truth) = room_loop(views, &sensor);
    if let Some(dir) = arg("--write") {
        std::fs::create_dir_all(&dir).expect("the folder");
        for (k, s) in scans.iter().enumerate() {
            let path = std::path::Path::new(&dir).join(format!("scan_{k:03}.ply"));
            sdfreg_core::io::write_point_cloud(path, s).expect("a scan written");
        }
        let rows: Vec<Vec<[f64; 4]>> = truth
            .iter()
            .map(|t| {
                let m = t.to_homogeneous();
                (0..4)
                    .map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)], m[(r, 3)]])
                    .collect()
            })
            .collect();
        std::fs::write(
            std::path::Path::new(&dir).join("truth.json"),
            serde_json::to_string(&rows).expect("json"),
        )
        .expect("truth.json written");
    }
    let points: usize = scans.iter().map(Vec::len).sum();
    println!(
        "room loop: {views} views, {points} points ({} per scan), sensor {} rings",
        points / views,
        sensor.rings
    );
    let settings = AlignSettings {
        joint_rounds: arg("--joint").map_or(AlignSettings::default().joint_rounds, |v| {
            v.parse().expect("--joint N")
        }),
        consensus: ConsensusSettings {
            iterations: arg("--consensus").map_or(0, |v| v.parse().expect("--consensus N")),
            points: arg("--consensus-points").map_or(ConsensusSettings::default().points, |v| {
                v.parse().expect("--consensus-points N")
            }),
            ..Default::default()
        },
        ..Default::default()
    };
    let a = align(&scans, None, &settings).expect("aligned");
    let mut errors = Vec::new();
    for (k, (pose, t)) in a.poses.iter().zip(&truth).enumerate() {
        match pose {
            Some(p) => {
                let (r, tr) = pose_errors(p, t);
                errors.push((r, tr));
                let d = (p.translation.vector - t.translation.vector) * 1e3;
                println!(
                    "  view {k:3}: {r:.4}° / {:.2} mm ({:.1}, {:.1}, {:.1})",
                    tr * 1e3,
                    d.x,
                    d.y,
                    d.z
                );
            }
            None => println!("  view {k:3}: left out"),
        }
    }
    let worst = errors
        .iter()
        .fold((0.0f64, 0.0f64), |w, e| (w.0.max(e.0), w.1.max(e.1)));
    println!(
        "worst {:.4}° / {:.2} mm; loop: first non-anchor view {:.4}° / {:.2} mm, last {:.4}° / {:.2} mm",
        worst.0,
        worst.1 * 1e3,
        errors.get(1).map_or(0.0, |e| e.0),
        errors.get(1).map_or(0.0, |e| e.1 * 1e3),
        errors.last().map_or(0.0, |e| e.0),
        errors.last().map_or(0.0, |e| e.1 * 1e3)
    );
    edge_bias(&a, &truth);
    let t = a.times;
    println!(
        "time {:.1} s: models {:.1} s, pairs {:.1} s, graph {:.3} s, unplaced {:.1} s, consensus {:.1} s, joint {:.1} s; {} of {} pairs kept",
        a.time.as_secs_f64(),
        t.models.as_secs_f64(),
        t.pairs.as_secs_f64(),
        t.graph.as_secs_f64(),
        t.unplaced.as_secs_f64(),
        t.consensus.as_secs_f64(),
        t.joint.as_secs_f64(),
        a.edges.iter().filter(|e| e.kept).count(),
        a.edges.len()
    );
}

/// The kept edges' rotation errors, each in its target scan's frame (rotation vector of
/// `measured · truth⁻¹`, degrees): their mean, and its standard error. Of two room scans with as
/// many points the earlier is the target, so every edge with the anchor has the anchor as its
/// target, and a mean well away from zero is a bias of registering onto a scan that every pose
/// inherits (the loop's closure compares two poses that share it).
fn edge_bias(a: &sdfreg_core::Alignment, truth: &[Isometry3<f64>]) {
    let errors: Vec<nalgebra::Vector3<f64>> = a
        .edges
        .iter()
        .filter(|e| e.kept)
        .filter_map(|e| {
            let r = e.registration.as_ref().ok()?;
            let exact = truth[e.target].inverse() * truth[e.source];
            let d = r.t_target_source * exact.inverse();
            Some(d.rotation.scaled_axis().map(f64::to_degrees))
        })
        .collect();
    if errors.len() < 2 {
        return;
    }
    let n = errors.len() as f64;
    let mean = errors.iter().sum::<nalgebra::Vector3<f64>>() / n;
    let sd = (errors
        .iter()
        .map(|e| (e - mean).component_mul(&(e - mean)))
        .sum::<nalgebra::Vector3<f64>>()
        / (n - 1.0))
        .map(f64::sqrt);
    let se = sd / n.sqrt();
    println!(
        "kept edges' rotation error in the target's frame: mean ({:.4}, {:.4}, {:.4})° ± ({:.4}, {:.4}, {:.4})° (standard error, {} edges)",
        mean.x, mean.y, mean.z, se.x, se.y, se.z, errors.len()
    );
}

/// The bunny's 10 scans at their reference poses (relative to bun000), refined by the multi-view
/// refinement: each pose's move, and the mean residual before and after.
fn reference_consensus(data: &std::path::Path) {
    let dir = data.join("stanford/bunny/data");
    let Ok(text) = std::fs::read_to_string(dir.join("gt_scan_to_world.txt")) else {
        println!("skipped: no {}", dir.join("gt_scan_to_world.txt").display());
        return;
    };
    let lines: Vec<&str> = text
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .collect();
    let mut names = Vec::new();
    let mut reference: Vec<Isometry3<f64>> = Vec::new();
    for block in lines.chunks(5) {
        let values: Vec<f64> = block[1..]
            .iter()
            .flat_map(|l| {
                l.split_whitespace()
                    .map(|v| v.parse::<f64>().expect("a number"))
            })
            .collect();
        names.push(block[0].trim().to_string());
        reference.push(isometry_from_matrix(&Matrix4::from_row_slice(&values)).expect("rigid"));
    }
    let scans: Vec<_> = names
        .iter()
        .map(|n| sdfreg_core::io::read_point_cloud(dir.join(n)).expect("a bunny scan"))
        .collect();
    let start: Vec<Isometry3<f64>> = reference
        .iter()
        .map(|t| reference[0].inverse() * t)
        .collect();
    let mut poses: Vec<Option<Isometry3<f64>>> = start.iter().copied().map(Some).collect();
    let settings = ConsensusSettings {
        iterations: 30,
        ..Default::default()
    };
    let out = consensus(&scans, &mut poses, 0, &settings);
    println!(
        "the bunny's {} scans from their reference poses: {} pairs, {} iterations, mean residual {:.4} mm -> {:.4} mm",
        scans.len(),
        out.pairs,
        out.iterations,
        out.before * 1e3,
        out.after * 1e3
    );
    let mut worst = (0.0f64, 0.0f64);
    for ((name, pose), s) in names.iter().zip(&poses).zip(&start) {
        let (r, t) = pose_errors(&pose.expect("placed"), s);
        worst = (worst.0.max(r), worst.1.max(t));
        println!("  {name:12} moved {r:.3}° / {:.3} mm", t * 1e3);
    }
    println!(
        "worst move {:.3}° / {:.3} mm from the reference",
        worst.0,
        worst.1 * 1e3
    );
}

//! Many views of the procedural room (`sdfreg_core::sim::lidar::room_loop`): N scans from
//! sensor poses in a loop, aligned into the first scan's frame from no guesses; prints each
//! pose's error against the simulator's truth, the loop's closure (the last pose's error
//! against the first non-anchor's), the kept edges' mean rotation error in their targets'
//! frames, their errors by how far apart along the loop their views are, what chaining the
//! consecutive pairs would give, the time per stage and the edges kept; with `--draws N`, each
//! view's mean over N draws of the range noise.
//!
//!     cargo bench --bench views                 # 8 views, 64 beams
//!     cargo bench --bench views -- --views 100  # peak memory: run under /usr/bin/time -v
//!     cargo bench --bench views -- --write DIR  # also DIR/scan_NNN.ply and DIR/truth.json
//!     cargo bench --bench views -- --joint 0    # without the joint refinement
//!     cargo bench --bench views -- --consensus 30  # with the multi-view refinement
//!     cargo bench --bench views -- --consensus 30 --consensus-points 16384  # its sample per scan
//!     cargo bench --bench views -- --reference-consensus ../shared/data
//!     cargo bench --bench views -- --range-noise 0   # the sensor's range noise, metres
//!     cargo bench --bench views -- --noise-draw 3    # another draw of that noise (0: the default)
//!     cargo bench --bench views -- --reverse         # the loop the other way round (view 7 second)
//!     cargo bench --bench views -- --draws 12        # draws 0..11 of the noise, and their means
//!     cargo bench --bench views -- --seen-from origin   # with the free-space check
//!     cargo bench --bench views -- --evaluate 0.01   # the no-reference measure, aligned and exact
//!     cargo bench --bench views -- --views 100 --evaluate-truth 0.01  # Alignment::evaluate's cost
//!
//! `--reference-consensus DATA` instead starts the multi-view refinement
//! (`sdfreg_core::views::consensus`) from the Stanford bunny's reference poses
//! (`DATA/stanford/bunny/data/gt_scan_to_world.txt`) and prints how far the poses its scans'
//! points agree on lie from them: what the reference is worth at this precision.

use nalgebra::{Isometry3, Matrix4};
use sdfreg_core::geometry::se3::{isometry_from_matrix, pose_errors};
use sdfreg_core::sim::lidar::{room_loop_seeded, Sensor};
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
        seen_from: arg("--seen-from").map(|v| v.parse().expect("--seen-from origin|+z|x,y,z")),
        ..Default::default()
    };
    if let Some(d) = arg("--evaluate-truth") {
        return evaluate_truth(views, &sensor, d.parse().expect("--evaluate-truth METRES"));
    }
    let first: u64 = arg("--noise-draw").map_or(0, |v| v.parse().expect("--noise-draw N"));
    let draws: u64 = arg("--draws").map_or(1, |v| v.parse().expect("--draws N"));
    let runs: Vec<Run> = (first..first + draws.max(1))
        .map(|draw| {
            if draws > 1 {
                println!("noise draw {draw}:");
            }
            one_draw(views, &sensor, draw, &settings)
        })
        .collect();
    if runs.len() > 1 {
        summary(&runs);
    }
}

/// Times `Alignment::evaluate` of the loop's scans at the simulator's exact poses, within
/// `max_distance` metres, and prints each view's fitness / inlier RMSE (mm).
fn evaluate_truth(views: usize, sensor: &Sensor, max_distance: f64) {
    let (scans, truth) = room_loop_seeded(views, sensor, 0);
    let a = at_truth(&truth);
    let clock = std::time::Instant::now();
    let evaluations = a.evaluate(&scans, max_distance).expect("evaluated");
    let time = clock.elapsed().as_secs_f64();
    let points: usize = scans.iter().map(Vec::len).sum();
    let figures: Vec<String> = evaluations
        .iter()
        .flatten()
        .map(|e| format!("{:.5}/{:.4}", e.fitness, e.inlier_rmse * 1e3))
        .collect();
    println!(
        "evaluate {views} views at the truth ({points} points) within {max_distance} m: {time:.2} s"
    );
    println!("fitness / inlier RMSE (mm) per view: {}", figures.join(" "));
}

/// An alignment that holds the simulator's exact poses (in the first scan's frame), and nothing
/// else: what `Alignment::evaluate` reads.
fn at_truth(truth: &[Isometry3<f64>]) -> sdfreg_core::Alignment {
    sdfreg_core::Alignment {
        anchor: 0,
        fitness: vec![0.0; truth.len()],
        poses: truth.iter().map(|t| Some(truth[0].inverse() * t)).collect(),
        left_out: Vec::new(),
        edges: Vec::new(),
        consensus: Default::default(),
        times: Default::default(),
        time: std::time::Duration::ZERO,
    }
}

/// The mean fitness and mean inlier RMSE of the placed scans' evaluations.
fn means(evaluations: &[Option<sdfreg_core::Evaluation>]) -> (f64, f64) {
    let placed: Vec<_> = evaluations.iter().flatten().collect();
    let n = placed.len().max(1) as f64;
    (
        placed.iter().map(|e| e.fitness).sum::<f64>() / n,
        placed.iter().map(|e| e.inlier_rmse).sum::<f64>() / n,
    )
}

/// One alignment's figures against the truth, per view (the anchor's included): the aligned
/// pose's error and the chained consecutive edges' (degrees, metres; `None` where unplaced or
/// a link is missing), and the kept edges' mean rotation error in their targets' frames.
struct Run {
    aligned: Vec<Option<(f64, f64)>>,
    chained: Vec<Option<(f64, f64)>>,
    pitch: Option<nalgebra::Vector3<f64>>,
}

/// Scans the loop with noise draw `draw`, aligns it and prints the figures.
fn one_draw(views: usize, sensor: &Sensor, draw: u64, settings: &AlignSettings) -> Run {
    let (mut scans, mut truth) = room_loop_seeded(views, sensor, draw);
    if std::env::args().any(|a| a == "--reverse") {
        scans[1..].reverse();
        truth[1..].reverse();
    }
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
    let a = align(&scans, None, settings).expect("aligned");
    let mut aligned = Vec::new();
    for (k, (pose, t)) in a.poses.iter().zip(&truth).enumerate() {
        match pose {
            Some(p) => {
                let (r, tr) = pose_errors(p, t);
                aligned.push(Some((r, tr)));
                let d = (p.translation.vector - t.translation.vector) * 1e3;
                println!(
                    "  view {k:3}: {r:.4}° / {:.2} mm ({:.1}, {:.1}, {:.1})",
                    tr * 1e3,
                    d.x,
                    d.y,
                    d.z
                );
            }
            None => {
                aligned.push(None);
                println!("  view {k:3}: left out");
            }
        }
    }
    let errors: Vec<(f64, f64)> = aligned.iter().flatten().copied().collect();
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
    if let Some(d) = arg("--evaluate") {
        // The reference-free measure of the aligned poses beside that of the exact ones.
        let d: f64 = d.parse().expect("--evaluate METRES");
        let clock = std::time::Instant::now();
        let (fitness, rmse) = means(&a.evaluate(&scans, d).expect("evaluated"));
        let time = clock.elapsed().as_secs_f64();
        let (exact, exact_rmse) = means(&at_truth(&truth).evaluate(&scans, d).expect("evaluated"));
        println!(
            "with no reference, within {d} m: the aligned poses lay {fitness:.5} of a scan's points on the others (RMS {:.4} mm), the exact poses {exact:.5} ({:.4} mm); {time:.1} s each",
            rmse * 1e3,
            exact_rmse * 1e3
        );
    }
    let pitch = edge_bias(&a, &truth);
    edges_by_gap(&a, &truth);
    let chained = chained(&a, &truth);
    let checked: Vec<String> = a
        .edges
        .iter()
        .filter_map(|e| Some(format!("{}→{} {:.3}", e.source, e.target, e.in_free_space?)))
        .collect();
    if !checked.is_empty() {
        println!("in free space: {}", checked.join(", "));
    }
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
    Run {
        aligned,
        chained,
        pitch,
    }
}

/// Over several noise draws: each view's mean error, aligned and chained; how often the loop's
/// last view is no worse than its first; the spread of the edges' mean rotation error.
fn summary(runs: &[Run]) {
    let n = runs.len();
    println!("over {n} noise draws, mean error per view (aligned | chained consecutive edges):");
    let views = runs.iter().map(|r| r.aligned.len()).max().unwrap_or(0);
    let mean = |values: Vec<(f64, f64)>| {
        let k = values.len().max(1) as f64;
        let s = values
            .iter()
            .fold((0.0, 0.0), |a, v| (a.0 + v.0, a.1 + v.1));
        (s.0 / k, s.1 / k, values.len())
    };
    for k in 1..views {
        let a = mean(runs.iter().filter_map(|r| *r.aligned.get(k)?).collect());
        let c = mean(runs.iter().filter_map(|r| *r.chained.get(k)?).collect());
        println!(
            "  view {k:3}: {:.4}° / {:.2} mm ({} placed) | {:.4}° / {:.2} mm",
            a.0,
            a.1 * 1e3,
            a.2,
            c.0,
            c.1 * 1e3
        );
    }
    let ends: Vec<((f64, f64), (f64, f64))> = runs
        .iter()
        .filter_map(|r| Some(((*r.aligned.get(1)?)?, (*r.aligned.last()?)?)))
        .collect();
    let no_worse = |f: fn(&(f64, f64)) -> f64| ends.iter().filter(|(a, b)| f(b) <= f(a)).count();
    println!(
        "last view no worse than the first: rotation in {} of {}, translation in {} of {}",
        no_worse(|e| e.0),
        ends.len(),
        no_worse(|e| e.1),
        ends.len()
    );
    let pitches: Vec<f64> = runs.iter().filter_map(|r| Some(r.pitch?.y)).collect();
    if pitches.len() > 1 {
        let m = pitches.iter().sum::<f64>() / pitches.len() as f64;
        let sd = (pitches.iter().map(|p| (p - m) * (p - m)).sum::<f64>()
            / (pitches.len() - 1) as f64)
            .sqrt();
        println!(
            "kept edges' mean rotation error about the target's y: {m:.4}° ± {:.4}° (standard error over the draws; per draw {:.4}° to {:.4}°)",
            sd / (pitches.len() as f64).sqrt(),
            pitches.iter().copied().fold(f64::INFINITY, f64::min),
            pitches.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        );
    }
}

/// The kept edges that registered: each with its measured pose (source into target) and the
/// true one.
fn kept_edges<'a>(
    a: &'a sdfreg_core::Alignment,
    truth: &'a [Isometry3<f64>],
) -> impl Iterator<Item = (&'a sdfreg_core::Edge, Isometry3<f64>, Isometry3<f64>)> + 'a {
    a.edges.iter().filter(|e| e.kept).filter_map(|e| {
        let r = e.registration.as_ref().ok()?;
        let exact = truth[e.target].inverse() * truth[e.source];
        Some((e, r.t_target_source, exact))
    })
}

/// The kept edges' rotation errors, each in its target scan's frame (rotation vector of
/// `measured · truth⁻¹`, degrees): their mean, and its standard error. A mean well away from
/// zero is a bias of registering onto a scan (the one-sided objective); the room's scans have
/// as many points each, so each is the target of about half its pairs and the poses do not
/// pile it up along the loop.
fn edge_bias(
    a: &sdfreg_core::Alignment,
    truth: &[Isometry3<f64>],
) -> Option<nalgebra::Vector3<f64>> {
    let errors: Vec<nalgebra::Vector3<f64>> = kept_edges(a, truth)
        .map(|(_, measured, exact)| {
            let d = measured * exact.inverse();
            d.rotation.scaled_axis().map(f64::to_degrees)
        })
        .collect();
    if errors.len() < 2 {
        return None;
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
    Some(mean)
}

/// The kept edges' errors against the truth by how far apart along the loop their two views
/// are (1: neighbours; the loop closures of a long loop lie farther apart): count, mean
/// rotation and translation error.
fn edges_by_gap(a: &sdfreg_core::Alignment, truth: &[Isometry3<f64>]) {
    let n = truth.len();
    let mut by_gap: std::collections::BTreeMap<usize, Vec<(f64, f64)>> = Default::default();
    for (e, measured, exact) in kept_edges(a, truth) {
        let d = e.target.abs_diff(e.source);
        by_gap
            .entry(d.min(n - d))
            .or_default()
            .push(pose_errors(&measured, &exact));
    }
    let row: Vec<String> = by_gap
        .iter()
        .map(|(gap, errors)| {
            let m = errors.len() as f64;
            let rot = errors.iter().map(|e| e.0).sum::<f64>() / m;
            let trans = errors.iter().map(|e| e.1).sum::<f64>() / m;
            format!("{gap}: {} at {rot:.4}°/{:.2}", errors.len(), trans * 1e3)
        })
        .collect();
    println!(
        "kept edges by views apart along the loop (mm): {}",
        row.join(", ")
    );
}

/// What chaining the pairs by hand would give: each view's pose composed from the consecutive
/// edges `1 → 0`, `2 → 1`, …, `k → k−1` (whatever the graph made of them), beside the aligned
/// poses. A chain's error grows along the loop; the graph's, which registers every pair, stays at
/// the edges' own scatter, so its first and last views differ by that scatter alone.
fn chained(a: &sdfreg_core::Alignment, truth: &[Isometry3<f64>]) -> Vec<Option<(f64, f64)>> {
    let mut pose = Some(Isometry3::identity());
    let mut errors = vec![Some((0.0, 0.0))];
    for (k, exact) in truth.iter().enumerate().skip(1) {
        let step = a.edges.iter().find_map(|e| {
            let r = e.registration.as_ref().ok()?;
            match (e.source, e.target) {
                (s, t) if s == k && t == k - 1 => Some(r.t_target_source),
                (s, t) if s == k - 1 && t == k => Some(r.t_target_source.inverse()),
                _ => None,
            }
        });
        pose = pose.zip(step).map(|(p, s)| p * s);
        errors.push(pose.map(|p| pose_errors(&p, exact)));
    }
    let row: Vec<String> = errors[1..]
        .iter()
        .map(|e| e.map_or("-".into(), |(r, t)| format!("{r:.4}°/{:.2}", t * 1e3)))
        .collect();
    println!(
        "chained consecutive edges, views 1..: {} (mm)",
        row.join(" ")
    );
    errors
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

//! Many views of the procedural room (`sdfreg_core::sim::lidar::room_loop`): N scans from
//! sensor poses in a loop, aligned into the first scan's frame from no guesses; prints each
//! pose's error against the simulator's truth, the loop's closure (the last pose's error
//! against the first non-anchor's), the time per stage and the edges kept.
//!
//!     cargo bench --bench views                 # 8 views, 64 beams
//!     cargo bench --bench views -- --views 100  # peak memory: run under /usr/bin/time -v
//!     cargo bench --bench views -- --write DIR  # also DIR/scan_NNN.ply and DIR/truth.json
//!     cargo bench --bench views -- --joint 0    # without the joint refinement

use sdfreg_core::geometry::se3::pose_errors;
use sdfreg_core::sim::lidar::{room_loop, Sensor};
use sdfreg_core::{align, AlignSettings};

/// The value after `flag` on the command line (cargo bench passes `--bench` too).
fn arg(flag: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    let i = args.iter().position(|a| a == flag)?;
    args.get(i + 1).cloned()
}

fn main() {
    let views: usize = arg("--views").map_or(8, |v| v.parse().expect("--views N"));
    let sensor = if views > 16 {
        Sensor::spinning_32()
    } else {
        Sensor::spinning_64()
    };
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
    let t = a.times;
    println!(
        "time {:.1} s: models {:.1} s, pairs {:.1} s, graph {:.3} s, joint {:.1} s; {} of {} pairs kept",
        a.time.as_secs_f64(),
        t.models.as_secs_f64(),
        t.pairs.as_secs_f64(),
        t.graph.as_secs_f64(),
        t.joint.as_secs_f64(),
        a.edges.iter().filter(|e| e.kept).count(),
        a.edges.len()
    );
}

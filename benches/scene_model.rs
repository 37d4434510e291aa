//! The local scene model's size and cost against the street's length: one procedural street of
//! `--length` metres (default 100) scanned from its middle, fitted as a model with the defaults
//! (which choose the local kind), then a second scan 1.2 m and 3° away registered against it.
//! Prints the returns, the model's kind, voxel and corrections, the bytes of its grid, the fit
//! and registration times, the error, and this process's peak resident memory (VmHWM), so one
//! run per length compares memory against the scan's extent:
//!
//!     for l in 50 100 200; do cargo bench --bench scene_model -- --length $l; done
//!
//! `--cells N` sets the voxel to 1/N of the target's extent (default: the settings' 128);
//! `--voxel-m M` to M metres whatever the extent; `--write DIR` also writes the pair as
//! `DIR/{source,target}.ply` and `DIR/gt.txt` (source into target).

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sdfreg_core::geometry::se3::pose_errors;
use sdfreg_core::sim::lidar::{scan, ScanPair, Scene, Sensor};
use sdfreg_core::{RegisterSettings, SdfModel};

/// The positive number after `flag` on the command line (cargo bench passes `--bench` too).
fn option(flag: &str) -> Option<f64> {
    let args: Vec<String> = std::env::args().collect();
    let i = args.iter().position(|a| a == flag)?;
    match args.get(i + 1).and_then(|v| v.parse::<f64>().ok()) {
        Some(v) if v > 0.0 => Some(v),
        _ => {
            eprintln!("scene_model: {flag} needs a positive number");
            std::process::exit(2);
        }
    }
}

/// This process's peak resident set (kB), from /proc/self/status; `None` elsewhere.
fn peak_rss_kb() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

fn main() {
    let length = option("--length").unwrap_or(100.0).max(20.0);
    let scene = Scene::street(length, &mut ChaCha8Rng::seed_from_u64(1));
    // A sensor that sees the whole street: the range covers its length.
    let sensor = Sensor {
        max_range: length.max(100.0),
        ..Sensor::spinning_32()
    };
    let pose = |x: f64, y: f64, yaw: f64| {
        Isometry3::from_parts(
            Translation3::new(x, y, 1.8),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw.to_radians()),
        )
    };
    let (a, b) = (pose(0.0, -1.5, 0.0), pose(1.2, -1.3, 3.0));
    let target = scan(&scene, &sensor, &a, 1);
    let source = scan(&scene, &sensor, &b, 2);
    let args: Vec<String> = std::env::args().collect();
    if let Some(dir) = args
        .iter()
        .position(|a| a == "--write")
        .and_then(|i| args.get(i + 1))
    {
        let pair = ScanPair {
            name: "street",
            description: "street scanned from its middle, 1.2 m and 3° apart",
            source: source.clone(),
            target: target.clone(),
            t_target_source: a.inverse() * b,
        };
        pair.write(std::path::Path::new(dir))
            .expect("write the pair");
    }
    let mut settings = RegisterSettings::default();
    if let Some(cells) = option("--cells") {
        settings.fit.local.cells = cells as usize;
    }
    if let Some(voxel) = option("--voxel-m") {
        let extent = (0..3)
            .map(|k| {
                let (lo, hi) = target.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| {
                    (lo.min(p[k]), hi.max(p[k]))
                });
                hi - lo
            })
            .fold(0.0, f64::max);
        settings.fit.local.cells = (extent / voxel).round().max(1.0) as usize;
        settings.fit.local.spacings = 0.0;
    }
    let before = peak_rss_kb();
    let t0 = std::time::Instant::now();
    let model = SdfModel::fit(&target, &settings).expect("a valid scan");
    let fit = t0.elapsed();
    let r = model
        .register(&source, None, &settings)
        .expect("a valid scan");
    let (rot, trans) = pose_errors(&r.t_target_source, &(a.inverse() * b));
    let extent = model.normalization().scale;
    println!(
        "street {length:.0} m: {} returns, extent {extent:.1} m; {:?} model, voxel {:.2} m, {} corrections ({:.1} MB with the optimiser's moments); fit {:.2} s; registration against it {:.3} s, {rot:.3}° {trans:.4} m; peak RSS {} MB (after the scans {} MB)",
        target.len(),
        model.kind(),
        model.voxel().unwrap_or(0.0),
        model.local_parameters(),
        model.local_parameters() as f64 * 12.0 / 1e6,
        fit.as_secs_f64(),
        r.time.as_secs_f64(),
        peak_rss_kb().map_or("?".into(), |k| format!("{:.0}", k as f64 / 1024.0)),
        before.map_or("?".into(), |k| format!("{:.0}", k as f64 / 1024.0)),
    );
}

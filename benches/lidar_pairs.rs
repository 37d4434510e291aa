//! Procedural LiDAR pairs (`sdfreg_core::sim::lidar`): two scans of a street and of a room from
//! nearby poses, registered with the default settings, from no guess and from the identity.
//! Prints each pair's rotation and translation error, time and fitness: the baseline for the
//! scene work (issue 13).
//!
//!     cargo bench --bench lidar_pairs
//!     cargo bench --bench lidar_pairs -- --write DIR   # also DIR/{street,room}/{source,target}.ply
//!                                                      # and gt.txt, for benches/lidar_compare.py
//!     cargo bench --bench lidar_pairs -- --range-noise 0   # the sensors' range noise, metres

use nalgebra::Isometry3;
use sdfreg_core::geometry::se3::pose_errors;
use sdfreg_core::sim::lidar::{room_pair_with, street_pair_with, Sensor};
use sdfreg_core::{register, RegisterSettings};

/// The value after `flag` on the command line (cargo bench passes `--bench` too).
fn arg(flag: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    let i = args.iter().position(|a| a == flag)?;
    match args.get(i + 1) {
        Some(value) => Some(value.clone()),
        None => {
            eprintln!("lidar_pairs: {flag} needs a value");
            std::process::exit(2);
        }
    }
}

fn main() {
    let write = arg("--write").map(std::path::PathBuf::from);
    let noise = arg("--range-noise").map(|v| {
        v.parse::<f64>().unwrap_or_else(|_| {
            eprintln!("lidar_pairs: --range-noise needs metres, got {v}");
            std::process::exit(2);
        })
    });
    let sensor = |s: Sensor| Sensor {
        range_noise: noise.unwrap_or(s.range_noise),
        ..s
    };
    let settings = RegisterSettings::default();
    for pair in [
        street_pair_with(&sensor(Sensor::spinning_32())),
        room_pair_with(&sensor(Sensor::spinning_64())),
    ] {
        let (source, target, truth) = (&pair.source, &pair.target, pair.t_target_source);
        println!(
            "{}: {} / {} points",
            pair.description,
            source.len(),
            target.len()
        );
        if let Some(dir) = &write {
            pair.write(&dir.join(pair.name)).expect("write the pair");
        }
        for (start, init) in [
            ("no guess", None),
            ("identity", Some(Isometry3::identity())),
        ] {
            let r = register(source, target, init.as_ref(), &settings).expect("valid clouds");
            let (rot, trans) = pose_errors(&r.t_target_source, &truth);
            println!(
                "  {start:>8}: {rot:.3}° {trans:.3} m, fitness {:.3}, {:.2} s",
                r.fitness,
                r.time.as_secs_f64()
            );
        }
    }
}

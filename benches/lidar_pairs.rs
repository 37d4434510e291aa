//! Procedural LiDAR pairs (`sdfreg_core::sim::lidar`): two scans of a street and of a room from
//! nearby poses, registered with the default settings, from no guess and from the identity.
//! Prints each pair's rotation and translation error, time and fitness: the baseline for the
//! scene work (issue 13).
//!
//!     cargo bench --bench lidar_pairs
//!     cargo bench --bench lidar_pairs -- --write DIR   # also DIR/{street,room}/{source,target}.ply
//!                                                      # and gt.txt, for benches/lidar_compare.py

use nalgebra::Isometry3;
use sdfreg_core::geometry::se3::pose_errors;
use sdfreg_core::sim::lidar::{room_pair, street_pair};
use sdfreg_core::{register, RegisterSettings};

/// `--write DIR` from the command line (cargo bench passes `--bench` too).
fn write_dir() -> Option<std::path::PathBuf> {
    let args: Vec<String> = std::env::args().collect();
    let i = args.iter().position(|a| a == "--write")?;
    match args.get(i + 1) {
        Some(dir) => Some(dir.into()),
        None => {
            eprintln!("lidar_pairs: --write needs a directory");
            std::process::exit(2);
        }
    }
}

fn main() {
    let write = write_dir();
    let settings = RegisterSettings::default();
    for pair in [street_pair(), room_pair()] {
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

//! Procedural LiDAR pairs (`sdfreg_core::lidar`): two scans of a street and of a room from
//! nearby poses, registered with the default settings, from no guess and from the identity.
//! Prints each pair's rotation and translation error, time and fitness: the baseline for the
//! scene work (issue 13).
//!
//!     cargo bench --bench lidar_pairs

use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sdfreg_core::lidar::{scan, Scene, Sensor};
use sdfreg_core::se3::pose_errors;
use sdfreg_core::{register, RegisterSettings};

fn pose(x: f64, y: f64, z: f64, yaw_deg: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_deg.to_radians()),
    )
}

fn main() {
    let cases = [
        (
            "street (100 m, 32 beams), 1.2 m and 3° apart",
            Scene::street(100.0, &mut ChaCha8Rng::seed_from_u64(1)),
            Sensor::spinning_32(),
            pose(0.0, -1.5, 1.8, 0.0),
            pose(1.2, -1.3, 1.8, 3.0),
        ),
        (
            "room (6 × 4 m, 64 beams), 0.58 m and 4° apart",
            Scene::room(&mut ChaCha8Rng::seed_from_u64(2)),
            Sensor::spinning_64(),
            pose(0.0, 0.0, 1.2, 0.0),
            pose(0.5, 0.3, 1.2, 4.0),
        ),
    ];
    let settings = RegisterSettings::default();
    for (name, scene, sensor, a, b) in cases {
        let target = scan(&scene, &sensor, &a, 1);
        let source = scan(&scene, &sensor, &b, 2);
        let truth = a.inverse() * b;
        println!("{name}: {} / {} points", source.len(), target.len());
        for (start, init) in [
            ("no guess", None),
            ("identity", Some(Isometry3::identity())),
        ] {
            let r = register(&source, &target, init.as_ref(), &settings).expect("valid clouds");
            let (rot, trans) = pose_errors(&r.t_target_source, &truth);
            println!(
                "  {start:>8}: {rot:.3}° {trans:.3} m, fitness {:.3}, {:.2} s",
                r.fitness,
                r.time.as_secs_f64()
            );
        }
    }
}

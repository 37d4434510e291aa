//! Any bytes given as a cloud file to be written moved, in its own format (its fields kept),
//! give a written file or a typed error, never a panic. The first byte picks the format.
#![no_main]

use libfuzzer_sys::fuzz_target;
use nalgebra::{Similarity3, Vector3};
use sdfreg_core::io::write_moved_point_cloud;

fuzz_target!(|data: &[u8]| {
    let Some((&pick, bytes)) = data.split_first() else {
        return;
    };
    let ext = ["ply", "pcd", "xyz", "pts", "las", "laz"][pick as usize % 6];
    let dir = std::env::temp_dir().join(format!("sdfreg-fuzz-moved-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let (input, output) = (dir.join(format!("in.{ext}")), dir.join(format!("out.{ext}")));
    if std::fs::write(&input, bytes).is_err() {
        return;
    }
    let motion = Similarity3::new(Vector3::new(1.0, -2.0, 0.5), Vector3::new(0.1, 0.2, 0.3), 1.5);
    let _ = write_moved_point_cloud(&input, &output, &motion);
});

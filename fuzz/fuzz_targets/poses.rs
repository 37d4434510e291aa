//! Any bytes given to the poses file reader (what `sdfreg align --init` and `sdfreg.read_poses`
//! read) give poses or a typed error, never a panic; every pose read is rigid. Seed the corpus
//! with a real poses file (`sdfreg align a.ply b.ply c.ply --output fuzz/corpus/poses/poses.json`).
#![no_main]

use libfuzzer_sys::fuzz_target;
use sdfreg_core::views::poses_file::read_poses;

fuzz_target!(|data: &[u8]| {
    if let Ok(poses) = read_poses(data, std::path::Path::new("fuzz.json")) {
        for pose in poses.into_iter().flatten() {
            assert!(pose.to_homogeneous().iter().all(|v| v.is_finite()));
            assert!((pose.rotation.norm() - 1.0).abs() < 1e-9);
        }
    }
});

//! Damaged copies of a valid LAZ file given to the LAS reader give points or a typed error, never
//! a panic nor an allocation sized by a damaged chunk table or layer size. The input edits a
//! LAZ file of 3,000 points written by the crate: each 5 bytes XOR one byte (4 bytes of offset,
//! 1 of value); a leftover byte cuts the file at that share of its length.
//!
//! Run it as the crate ships, without debug assertions: `cargo +nightly fuzz run -O laz`. The
//! LASzip decoder (the `laz` crate) asserts, in debug builds only, on a damaged arithmetic-coded
//! stream; a release build decodes such a stream to wrong points, as any LAZ reader must (the
//! format has no checksum).
#![no_main]

use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use nalgebra::Point3;
use sdfreg_core::io::{parse_point_cloud, write_point_cloud, Format};

fn seed() -> &'static [u8] {
    static SEED: OnceLock<Vec<u8>> = OnceLock::new();
    SEED.get_or_init(|| {
        let points: Vec<Point3<f64>> = (0..3000)
            .map(|i| {
                let t = i as f64;
                Point3::new((t * 0.01).sin(), 0.001 * t, (t * 0.37).cos())
            })
            .collect();
        let path =
            std::env::temp_dir().join(format!("sdfreg-fuzz-seed-{}.laz", std::process::id()));
        write_point_cloud(&path, &points).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let _ = std::fs::remove_file(&path);
        bytes
    })
}

fuzz_target!(|data: &[u8]| {
    let mut bytes = seed().to_vec();
    let mut edits = data.chunks_exact(5);
    for e in &mut edits {
        let at = u32::from_le_bytes([e[0], e[1], e[2], e[3]]) as usize % bytes.len();
        bytes[at] ^= e[4];
    }
    if let [cut] = edits.remainder() {
        bytes.truncate(bytes.len() * (*cut as usize) / 256);
    }
    let _ = parse_point_cloud(&bytes, Format::Las, std::path::Path::new("fuzz.laz"));
});

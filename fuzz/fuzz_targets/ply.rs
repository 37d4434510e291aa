//! Any bytes given to the ply reader give points or a typed error, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sdfreg_core::io::{parse_point_cloud, Format};

fuzz_target!(|data: &[u8]| {
    let _ = parse_point_cloud(data, Format::Ply, std::path::Path::new("fuzz.ply"));
});

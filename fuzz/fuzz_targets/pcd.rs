//! Any bytes given to the pcd reader give points or a typed error, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sdfreg_core::io::{parse_point_cloud, Format};

fuzz_target!(|data: &[u8]| {
    let _ = parse_point_cloud(data, Format::Pcd, std::path::Path::new("fuzz.pcd"));
});

//! Any bytes given to the LAS reader give points or a typed error, never a panic (nor an
//! allocation sized by a header's point count).
#![no_main]

use libfuzzer_sys::fuzz_target;
use sdfreg_core::io::{parse_point_cloud, Format};

fuzz_target!(|data: &[u8]| {
    let _ = parse_point_cloud(data, Format::Las, std::path::Path::new("fuzz.las"));
});

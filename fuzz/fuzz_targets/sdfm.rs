//! Any bytes given to the model reader give a model or a typed error, never a panic. Seed the
//! corpus with a real model (`sdfreg fit … --output fuzz/corpus/sdfm/blob.sdfm`) so mutations
//! reach past the container's checks.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sdfreg_core::SdfModel;

fuzz_target!(|data: &[u8]| {
    let _ = SdfModel::from_bytes(data, std::path::Path::new("fuzz.sdfm"));
});

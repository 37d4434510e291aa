//! Any bytes given to the batch results reader (what `sdfreg batch` reads to resume) give a
//! log or a typed error, never a panic. Seed the corpus with a real results file
//! (`sdfreg batch pairs.csv --output fuzz/corpus/batch_log/results.jsonl`).
#![no_main]

use libfuzzer_sys::fuzz_target;
use sdfreg_core::batch::log::read_batch_log;

fuzz_target!(|data: &[u8]| {
    if let Ok(Some(log)) = read_batch_log(data, std::path::Path::new("fuzz.jsonl")) {
        assert!(log.complete_len <= data.len());
    }
});

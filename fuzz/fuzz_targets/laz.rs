//! Damaged copies of a valid LAZ file given to the LAS reader give points or a typed error, never
//! a panic nor an allocation sized by a damaged chunk table or layer size. The input edits a
//! LAZ file of 3,000 points written by the crate, its points re-compressed in three chunks of 1,000
//! (so that the decoder's parallel form, which splits a read among the chunk table's entries,
//! is what reads it): each 5 bytes XOR one byte (4 bytes of offset, 1 of value); a leftover
//! byte cuts the file at that share of its length.
//!
//! Run it as the crate ships, without debug assertions: `cargo +nightly fuzz run -O laz`. The
//! LASzip decoder (the `laz` crate) asserts, in debug builds only, on a damaged arithmetic-coded
//! stream; a release build decodes such a stream to wrong points, as any LAZ reader must (the
//! format has no checksum).
#![no_main]

use std::io::{Cursor, Seek, SeekFrom};
use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use nalgebra::Point3;
use sdfreg_core::io::{parse_point_cloud, write_point_cloud, Format};

/// Points per chunk of the seed.
const CHUNK: u32 = 1000;

/// `laz` (as the crate writes it: one chunk of up to 50,000 points) with its points compressed
/// again in chunks of [`CHUNK`]: the same header and records, the LASzip record's chunk size
/// changed, a new chunk table.
fn in_small_chunks(laz: &[u8]) -> Vec<u8> {
    let data = u32::from_le_bytes(laz[96..100].try_into().unwrap()) as usize;
    let mut reader = las::Reader::new(Cursor::new(laz.to_vec())).unwrap();
    let n = reader.header().number_of_points();
    let records = reader.read_points(n).unwrap();
    // The LASzip record's data: after its VLR header (reserved 2, user id 16, record id 2,
    // length 2, description 32); its chunk size is a u32 12 bytes in.
    let id = laz
        .windows(14)
        .position(|w| w == b"laszip encoded")
        .unwrap();
    let record = id - 2 + 54;
    let mut out = laz[..data].to_vec();
    out[record + 12..record + 16].copy_from_slice(&CHUNK.to_le_bytes());
    let vlr = laz::LazVlr::from_buffer(&out[record..]).unwrap();
    let mut stream = Cursor::new(out);
    stream.seek(SeekFrom::End(0)).unwrap();
    let mut compressor = laz::LasZipCompressor::new(stream, vlr).unwrap();
    compressor.compress_many(records.raw_bytes()).unwrap();
    compressor.done().unwrap();
    compressor.into_inner().into_inner()
}

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
        let bytes = in_small_chunks(&std::fs::read(&path).unwrap());
        let _ = std::fs::remove_file(&path);
        let read = parse_point_cloud(&bytes, Format::Las, std::path::Path::new("seed.laz")).unwrap();
        let worst = read
            .iter()
            .zip(&points)
            .map(|(a, b)| (a - b).amax())
            .fold(0.0, f64::max);
        assert!(read.len() == points.len() && worst < 1e-6, "the seed reads back");
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

//! Damaged copies of a valid E57 file given to the E57 reader give points or a typed error, never
//! a panic nor an allocation sized by a damaged field. The input's first byte chooses whether the
//! damaged pages get their CRC-32C recomputed (odd: the damage then reaches the XML, the packet
//! and the bit-unpacking code behind the checksums); the rest edits the file: each 5 bytes XOR
//! one byte (4 bytes of offset, 1 of value); a leftover byte cuts the file at that share of its
//! length. The seed holds two scans written by the `e57` crate: Cartesian doubles with an
//! invalid-state field and a pose, and spherical scaled integers with an intensity.
#![no_main]

use std::io::Cursor;
use std::sync::OnceLock;

use e57::{E57Writer, Record, RecordDataType, RecordName, RecordValue, Transform};
use libfuzzer_sys::fuzz_target;
use sdfreg_core::io::{parse_point_cloud, Format};

/// E57's page: 1,020 bytes of data, then their CRC-32C, big-endian.
const PAGE: usize = 1024;

fn seed() -> &'static [u8] {
    static SEED: OnceLock<Vec<u8>> = OnceLock::new();
    SEED.get_or_init(|| {
        let mut bytes = Cursor::new(Vec::new());
        {
            let mut writer = E57Writer::new(&mut bytes, "{fuzz}").unwrap();
            let prototype = vec![
                Record::CARTESIAN_X_F64,
                Record::CARTESIAN_Y_F64,
                Record::CARTESIAN_Z_F64,
                Record::CARTESIAN_INVALID_STATE,
            ];
            let mut scan = writer.add_pointcloud("{fuzz-0}", prototype).unwrap();
            scan.set_transform(Some(Transform::default()));
            for i in 0..600 {
                let t = f64::from(i);
                let v = |x: f64| RecordValue::Double(x);
                scan.add_point(vec![
                    v((t * 0.01).sin()),
                    v(0.001 * t),
                    v((t * 0.37).cos()),
                    RecordValue::Integer(i64::from(i % 7 == 0)),
                ])
                .unwrap();
            }
            scan.finalize().unwrap();
            let scaled = |name| Record {
                name,
                data_type: RecordDataType::ScaledInteger {
                    min: -100_000,
                    max: 100_000,
                    scale: 0.001,
                    offset: 0.0,
                },
            };
            let prototype = vec![
                scaled(RecordName::SphericalRange),
                scaled(RecordName::SphericalAzimuth),
                scaled(RecordName::SphericalElevation),
                Record {
                    name: RecordName::Intensity,
                    data_type: RecordDataType::U16,
                },
            ];
            let mut scan = writer.add_pointcloud("{fuzz-1}", prototype).unwrap();
            for i in 0..600 {
                let t = f64::from(i);
                let s = |x: f64| RecordValue::ScaledInteger((x * 1000.0).round() as i64);
                scan.add_point(vec![
                    s(5.0 + t * 0.01),
                    s(t * 0.01 - 3.0),
                    s(0.5 - t * 0.001),
                    RecordValue::Integer(i64::from(i)),
                ])
                .unwrap();
            }
            scan.finalize().unwrap();
            writer.finalize().unwrap();
        }
        bytes.into_inner()
    })
}

fuzz_target!(|data: &[u8]| {
    let Some((&reseal, data)) = data.split_first() else {
        return;
    };
    let mut bytes = seed().to_vec();
    let mut edits = data.chunks_exact(5);
    for e in &mut edits {
        let at = u32::from_le_bytes([e[0], e[1], e[2], e[3]]) as usize % bytes.len();
        bytes[at] ^= e[4];
    }
    if reseal & 1 == 1 {
        for page in bytes.chunks_exact_mut(PAGE) {
            let crc = crc32c::crc32c(&page[..PAGE - 4]);
            page[PAGE - 4..].copy_from_slice(&crc.to_be_bytes());
        }
    }
    if let [cut] = edits.remainder() {
        bytes.truncate(bytes.len() * (*cut as usize) / 256);
    }
    let _ = parse_point_cloud(&bytes, Format::E57, std::path::Path::new("fuzz.e57"));
});

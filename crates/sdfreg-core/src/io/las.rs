//! LAS (the ASPRS LiDAR exchange format) via las-rs: every version and point format; each point's
//! `x`, `y`, `z` with the file's scale and offset applied, in its units (metres for nearly every
//! survey). Other point fields are skipped.
//!
//! LAZ (LASzip-compressed LAS) is refused with what to do: the decoder las-rs uses for it panics
//! or aborts the process on some corrupted files (found by feeding it damaged copies), and a
//! damaged input must give an error, not a crash.
//!
//! Written files are LAS 1.2, point format 0, with an offset at the cloud's middle and the
//! finest power-of-ten scale whose integers fit LAS's 32 bits with room: between 10⁻⁹ and 10⁻⁸
//! of the cloud's extent (an 80 m scan to 0.1 µm, a 15 cm object to 1 nm).

use std::io::{Cursor, Read, Seek, SeekFrom};
use std::path::Path;

use las::{Builder, Point, Transform, Vector};
use nalgebra::Point3;

use crate::base::error::IoError;

/// Why a LAZ file (or a LAS file whose points are compressed) is not read, and what to do.
pub(super) const LAZ_REFUSED: &str =
    "LAZ (compressed LAS) is not read: decompress it to .las first \
     (`pdal translate in.laz out.las`, or `laszip -i in.laz -o out.las`)";

/// Bytes of points read at a time: a header's point count is not trusted to size an allocation.
const CHUNK_BYTES: u64 = 4 << 20;

/// An error of `path` that las-rs reported while reading `what`: the end of the file, a foreign
/// file's first bytes, or las-rs's own words.
fn las_error(path: &Path, what: &str, e: las::Error) -> IoError {
    let message = match e {
        las::Error::Io(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
            format!("the file ends inside {what}")
        }
        las::Error::InvalidFileSignature(first) => format!(
            "not a LAS file: it begins with {:?}, where LAS files begin with \"LASF\"",
            String::from_utf8_lossy(&first)
        ),
        las::Error::LaszipNotEnabled => LAZ_REFUSED.into(),
        e => format!("{what}: {e}"),
    };
    IoError::Parse {
        path: path.into(),
        line: None,
        message,
    }
}

/// Refuses a LAS 1.4 file whose extended record (EVLR) declares more bytes than the file has:
/// las-rs sizes that record's buffer by the declared length before reading it, so a damaged
/// length would exhaust the memory. Leaves `stream` at its start.
fn refuse_oversized_evlr(path: &Path, stream: &mut (impl Read + Seek)) -> Result<(), IoError> {
    let io = |e: std::io::Error| las_error(path, "the LAS header", las::Error::Io(e));
    let len = stream.seek(SeekFrom::End(0)).map_err(io)?;
    stream.seek(SeekFrom::Start(0)).map_err(io)?;
    let raw = las::raw::Header::read_from(&mut *stream)
        .map_err(|e| las_error(path, "the LAS header", e))?;
    if let Some(evlr) = raw.evlr {
        // An EVLR: reserved (2), user id (16), record id (2), then its length (8).
        let at = evlr.start_of_first_evlr.saturating_add(20);
        let mut length = [0u8; 8];
        if at.saturating_add(8) <= len {
            stream.seek(SeekFrom::Start(at)).map_err(io)?;
            stream.read_exact(&mut length).map_err(io)?;
            let declared = u64::from_le_bytes(length);
            if declared > len {
                return Err(IoError::Parse {
                    path: path.into(),
                    line: None,
                    message: format!(
                        "the extended record at byte {} declares {declared} bytes; the file has {len}",
                        evlr.start_of_first_evlr
                    ),
                });
            }
        }
    }
    stream.seek(SeekFrom::Start(0)).map_err(io)?;
    Ok(())
}

/// The points of a LAS stream; `path` names it in errors. A file whose points stop
/// before the count its header declares is refused, naming the points it ends among.
pub(super) fn read(
    path: &Path,
    mut stream: impl Read + Seek + Send + Sync + 'static,
) -> Result<Vec<Point3<f64>>, IoError> {
    refuse_oversized_evlr(path, &mut stream)?;
    let mut reader = las::Reader::new(stream).map_err(|e| las_error(path, "the LAS header", e))?;
    let declared = reader.header().number_of_points();
    let chunk_points =
        (CHUNK_BYTES / u64::from(reader.header().point_format().len()).max(1)).max(1);
    let mut points = Vec::with_capacity(declared.min(chunk_points) as usize);
    while (points.len() as u64) < declared {
        let from = points.len() as u64;
        let chunk = reader.read_points(chunk_points).map_err(|e| {
            let to = (from + chunk_points).min(declared);
            las_error(
                path,
                &format!("points {from}..{to} of the {declared} the header declares"),
                e,
            )
        })?;
        if chunk.is_empty() {
            return Err(IoError::Parse {
                path: path.into(),
                line: None,
                message: format!(
                    "the file ends after {from} of the {declared} points the header declares"
                ),
            });
        }
        points.extend(
            chunk
                .x()
                .zip(chunk.y())
                .zip(chunk.z())
                .map(|((x, y), z)| Point3::new(x, y, z)),
        );
    }
    Ok(points)
}

/// The coordinate transform of one axis for values in `lo..=hi`: the offset at their middle
/// (rounded to the scale) and the smallest power-of-ten scale at least 10⁻⁹ of the cloud's
/// `extent`, so the stored integers stay within ±5·10⁸ (LAS's are 32-bit).
fn transform(lo: f64, hi: f64, extent: f64) -> Transform {
    let scale = 10f64.powf((extent.max(f64::MIN_POSITIVE) * 1e-9).log10().ceil());
    let offset = ((lo + hi) / 2.0 / scale).round() * scale;
    Transform { scale, offset }
}

/// `points` as a LAS file's bytes; `path` names it in errors.
pub(super) fn encode(path: &Path, points: &[Point3<f64>]) -> Result<Vec<u8>, IoError> {
    let mut lo = Point3::from([f64::INFINITY; 3]);
    let mut hi = Point3::from([f64::NEG_INFINITY; 3]);
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let extent = (hi - lo).max();
    let mut builder = Builder::from((1, 2));
    builder.generating_software = format!("sdfreg {}", env!("CARGO_PKG_VERSION"));
    if !points.is_empty() {
        builder.transforms = Vector {
            x: transform(lo.x, hi.x, extent),
            y: transform(lo.y, hi.y, extent),
            z: transform(lo.z, hi.z, extent),
        };
    }
    let writing = |e: las::Error| las_error(path, "cannot write LAS", e);
    let header = builder.into_header().map_err(writing)?;
    let mut writer = las::Writer::new(Cursor::new(Vec::new()), header).map_err(writing)?;
    for p in points {
        writer
            .write_point(Point {
                x: p.x,
                y: p.y,
                z: p.z,
                ..Default::default()
            })
            .map_err(writing)?;
    }
    Ok(writer.into_inner().map_err(writing)?.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud() -> Vec<Point3<f64>> {
        // A survey's coordinates: large offsets (UTM), centimetres to metres apart.
        (0..1000)
            .map(|i| {
                let t = i as f64;
                Point3::new(
                    512_345.0 + 40.0 * (t * 0.01).sin(),
                    4_123_456.0 + 0.05 * t,
                    250.0 + (t * 0.37).cos(),
                )
            })
            .collect()
    }

    #[test]
    fn las_keeps_a_surveys_coordinates_to_the_scale() {
        let points = cloud();
        let bytes = encode(Path::new("a.las"), &points).unwrap();
        let read = read(Path::new("a.las"), Cursor::new(bytes)).unwrap();
        assert_eq!(read.len(), points.len());
        // extent ≈ 80 m: scale 1e-7 m, so each coordinate within half of it.
        let worst = read
            .iter()
            .zip(&points)
            .map(|(a, b)| (a - b).amax())
            .fold(0.0, f64::max);
        assert!(worst <= 0.5e-7 * (1.0 + 1e-6), "{worst}");
    }

    #[test]
    fn truncated_and_foreign_files_are_refused_by_name() {
        let bytes = encode(Path::new("a.las"), &cloud()).unwrap();
        // Point format 0 rows are 20 bytes: cut the file inside point 600.
        let cut = bytes.len() - 400 * 20 - 7;
        let err = read(Path::new("cut.las"), Cursor::new(bytes[..cut].to_vec()))
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with(
                "cut.las: the file ends inside points 0..1000 of the 1000 the header declares"
            ),
            "{err}"
        );
        let err = read(
            Path::new("ply.las"),
            Cursor::new(b"ply\nformat ascii 1.0\n".to_vec()),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.starts_with("ply.las: not a LAS file: it begins with \"ply\\n\""),
            "{err}"
        );
    }

    #[test]
    fn an_extended_record_longer_than_the_file_is_refused_before_it_is_read() {
        let mut builder = Builder::from((1, 4));
        builder.evlrs.push(las::Vlr {
            user_id: "sdfreg".into(),
            record_id: 1,
            description: "test".into(),
            data: vec![7; 100],
        });
        let header = builder.into_header().unwrap();
        let mut writer = las::Writer::new(Cursor::new(Vec::new()), header).unwrap();
        writer.write_point(Point::default()).unwrap();
        let mut bytes = writer.into_inner().unwrap().into_inner();
        assert_eq!(
            read(Path::new("a.las"), Cursor::new(bytes.clone()))
                .unwrap()
                .len(),
            1
        );
        // The EVLR's length, 8 bytes at 20 past its start (the file's last 160 bytes).
        let at = bytes.len() - 160 + 20;
        assert_eq!(bytes[at..at + 8], 100u64.to_le_bytes());
        bytes[at..at + 8].copy_from_slice(&(1u64 << 62).to_le_bytes());
        let err = read(Path::new("big.las"), Cursor::new(bytes))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("big.las: the extended record at byte")
                && err.contains(&format!("declares {} bytes", 1u64 << 62)),
            "{err}"
        );
    }

    #[test]
    fn the_scale_is_the_finest_power_of_ten_whose_integers_fit() {
        let t = transform(-0.07, 0.08, 0.15);
        assert!((t.scale - 1e-9).abs() < 1e-21, "{}", t.scale);
        assert!((t.offset - 0.005).abs() < 1e-12);
        assert!((transform(0.0, 84.0, 84.0).scale - 1e-7).abs() < 1e-19);
    }
}

//! LAS (the ASPRS LiDAR exchange format) via las-rs: every version and point format; each point's
//! `x`, `y`, `z` with the file's scale and offset applied, in its units (metres for nearly every
//! survey). Other point fields are skipped.
//!
//! LAZ (LASzip-compressed LAS) is read through las-rs's LASzip decoder (the `laz` crate), after
//! what that decoder sizes buffers by or indexes with is checked against the file: its chunk
//! table, and each layered chunk's layer sizes. Without those checks damaged copies of a LAZ file
//! made the decoder panic or abort the process. A file whose chunk table holds the header's
//! points as writers lay them out is decoded on every core, many chunks at a time (the decoder's
//! parallel form; [`parallel_if_it_holds`]); any other a chunk after the other.
//!
//! Written files are LAS 1.2, point format 0, with an offset at the cloud's middle and the
//! finest power-of-ten scale whose integers fit LAS's 32 bits with room: between 10⁻⁹ and 10⁻⁸
//! of the cloud's extent (an 80 m scan to 0.1 µm, a 15 cm object to 1 nm); LASzip-compressed
//! when the path ends in `.laz`.

use std::io::{Cursor, Read, Seek, SeekFrom};
use std::path::Path;

use las::{
    Builder, LazParallelism, Point, PointData, PointDataBuilder, ReaderOptions, Transform, Vector,
    WriterOptions,
};
use nalgebra::{Point3, Similarity3, Vector3};

use crate::base::error::IoError;
use crate::base::pool::in_a_pool;
use crate::io::moved::{Fields, MovedCloud, Mover};

/// Bytes of points read at a time: a header's point count is not trusted to size an allocation.
const CHUNK_BYTES: u64 = 4 << 20;

/// Bytes of points read at a time from a LAZ file decoded in parallel: 32 MiB, some 40 LASzip
/// chunks of 50,000 points in LAS's smaller formats, so that every core has chunks to decode.
const PARALLEL_CHUNK_BYTES: u64 = 32 << 20;

/// How a LAS stream's points are to be decoded, as [`preflight`] found the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Decoding {
    /// Uncompressed LAS, or LAZ decoded a chunk after the other.
    Sequential,
    /// LAZ whose chunk table holds the header's points ([`parallel_if_it_holds`]): many
    /// chunks at once, on every core.
    Parallel,
}

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
        las::Error::ReturnNumber {
            return_number,
            version: Some(v),
        } => format!(
            "{what}: a record claims return {return_number}, which a LAS {}.{} header cannot count (LAS 1.4 counts up to 15)",
            v.major, v.minor
        ),
        e => format!("{what}: {e}"),
    };
    IoError::parse(path, message)
}

/// Checks what las-rs and its LASzip decoder would size a buffer by, or index with, against the
/// file before they read it: a LAS 1.4 extended record (EVLR) declaring more bytes than the file
/// has (las-rs sizes its buffer by that length) and, in a LAZ file, the chunk table and the
/// layered chunks' sizes ([`check_laz`]). Leaves `stream` at its start; says how the points
/// can be decoded.
fn preflight(path: &Path, stream: &mut (impl Read + Seek)) -> Result<Decoding, IoError> {
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
                return Err(IoError::parse(
                    path,
                    format!(
                        "the extended record at byte {} declares {declared} bytes; the file has {len}",
                        evlr.start_of_first_evlr
                    ),
                ));
            }
        }
    }
    stream.seek(SeekFrom::Start(0)).map_err(io)?;
    let header =
        las::Header::new(&mut *stream).map_err(|e| las_error(path, "the LAS header", e))?;
    let decoding = if header.point_format().is_compressed {
        check_laz(
            path,
            stream,
            &header,
            u64::from(raw.offset_to_point_data),
            len,
        )?
    } else {
        Decoding::Sequential
    };
    stream.seek(SeekFrom::Start(0)).map_err(io)?;
    Ok(decoding)
}

/// LASzip's compressor kind (the first two bytes of its record) for one stream of points, not
/// chunked: no chunk table.
const POINTWISE: u16 = 1;
/// LASzip's compressor kind for layered chunks (a stream per field; LAS 1.4's point formats 6 to
/// 10). Kind 2, chunks of one stream each, lies between.
const LAYERED: u16 = 3;

/// The most points in one chunk of a LAZ file decoded in parallel: that decoder decodes the
/// whole of a read's last chunk, and keeps what the read did not ask for, so a chunk's point
/// count sizes a buffer. Writers use 50,000 (LASzip's default) or COPC's nodes of up to some
/// 100,000; a file of larger chunks is decoded a chunk after the other.
const MAX_PARALLEL_CHUNK: u64 = 1 << 20;

/// [`Decoding::Parallel`] when the chunk `table` holds the header's `points` as a writer lays
/// them out: its chunks (of `chunk_size` points each, or each entry's own count when
/// `variable`) cover the points, the last one holds some of them, and none exceeds
/// [`MAX_PARALLEL_CHUNK`]. The parallel decoder splits every read among the table's chunks by
/// those counts: a table short of the points makes it run past its last entry, and a damaged
/// count allocates that many points. The sequential decoder needs no table for fixed chunks.
fn parallel_if_it_holds(
    table: &laz::laszip::ChunkTable,
    chunk_size: u32,
    variable: bool,
    points: u64,
) -> Decoding {
    let counts: Vec<u64> = if variable {
        table.as_ref().iter().map(|e| e.point_count).collect()
    } else {
        vec![u64::from(chunk_size); table.len()]
    };
    let covered = counts.iter().fold(0u64, |s, &c| s.saturating_add(c));
    let last = counts.last().copied().unwrap_or(0);
    if points > 0
        && covered >= points
        && covered - last < points
        && counts.iter().all(|&c| c <= MAX_PARALLEL_CHUNK)
    {
        Decoding::Parallel
    } else {
        Decoding::Sequential
    }
}

/// Checks a LAZ file against what its LASzip record and chunk table declare, before the decoder
/// trusts them: the record describes the header's point size; the chunk table lies inside the
/// file, its entries could fit there, their bytes do and their points cover the header's count
/// (the decoder indexes the table by chunk); each layered chunk's layers fit in the bytes left
/// (the decoder sizes a buffer by each). `data` is the offset of the point data, `len` the file's
/// length.
fn check_laz(
    path: &Path,
    stream: &mut (impl Read + Seek),
    header: &las::Header,
    data: u64,
    len: u64,
) -> Result<Decoding, IoError> {
    let io = |e: std::io::Error| las_error(path, "the LASzip chunks", las::Error::Io(e));
    let vlr = header
        .laz_vlr()
        .map_err(|e| las_error(path, "the LASzip record", e))?;
    let record = u64::from(header.point_format().len());
    if vlr.items_size() != record {
        return Err(IoError::parse(
            path,
            format!(
                "the LASzip record describes points of {} bytes, the header's point format {record}",
                vlr.items_size()
            ),
        ));
    }
    let kind = header
        .vlrs()
        .iter()
        .find(|v| las::laz::is_laszip_vlr(v))
        .and_then(|v| v.data.get(..2))
        .map_or(0, |b| u16::from_le_bytes([b[0], b[1]]));
    if kind == POINTWISE {
        return Ok(Decoding::Sequential);
    }
    let points = header.number_of_points();
    // The chunk table's offset: first in the point data, or (when the writer could not go back)
    // in the file's last 8 bytes, as the decoder looks for it.
    let mut offset = [0u8; 8];
    stream.seek(SeekFrom::Start(data)).map_err(io)?;
    stream.read_exact(&mut offset).map_err(io)?;
    let mut table_at = i64::from_le_bytes(offset);
    if table_at <= data as i64 && len >= 8 {
        stream.seek(SeekFrom::Start(len - 8)).map_err(io)?;
        stream.read_exact(&mut offset).map_err(io)?;
        table_at = i64::from_le_bytes(offset);
    }
    let variable = vlr.uses_variable_size_chunks();
    let table = if table_at > data as i64 {
        let at = table_at as u64;
        let mut head = [0u8; 8];
        if at.saturating_add(8) > len {
            return Err(IoError::parse(
                path,
                format!("the LASzip chunk table is said to begin at byte {at}; the file has {len}"),
            ));
        }
        stream.seek(SeekFrom::Start(at)).map_err(io)?;
        stream.read_exact(&mut head).map_err(io)?;
        // The table's own entries take some bytes each, and so does a chunk: no more than a
        // quarter as many chunks as the file has bytes.
        let count = u64::from(u32::from_le_bytes([head[4], head[5], head[6], head[7]]));
        if count > len / 4 {
            return Err(IoError::parse(
                path,
                format!("the LASzip chunk table declares {count} chunks in a file of {len} bytes"),
            ));
        }
        stream.seek(SeekFrom::Start(at)).map_err(io)?;
        let table = laz::laszip::ChunkTable::read(&mut *stream, variable)
            .map_err(|e| las_error(path, "the LASzip chunk table", las::Error::Io(e)))?;
        let bytes = table
            .as_ref()
            .iter()
            .fold(0u64, |s, e| s.saturating_add(e.byte_count));
        if bytes > at - data {
            return Err(IoError::parse(
                path,
                format!(
                    "the LASzip chunk table declares {bytes} bytes of chunks; {} lie before it",
                    at - data
                ),
            ));
        }
        if variable {
            let covered = table
                .as_ref()
                .iter()
                .fold(0u64, |s, e| s.saturating_add(e.point_count));
            if covered < points {
                return Err(IoError::parse(
                    path,
                    format!(
                        "the LASzip chunk table holds {covered} points; the header declares {points}"
                    ),
                ));
            }
        }
        Some(table)
    } else if variable {
        return Err(IoError::parse(
            path,
            "the LASzip chunks vary in size, and the file has no chunk table",
        ));
    } else {
        None
    };
    let decoding = match &table {
        Some(t) => parallel_if_it_holds(t, vlr.chunk_size(), variable, points),
        None => Decoding::Sequential,
    };
    if kind != LAYERED {
        return Ok(decoding);
    }
    // A layered chunk: its first point as is, its point count, each layer's size (u32), then
    // the layers. Walked as the decoder reads them, a chunk after the other.
    let layers: u64 = vlr
        .items()
        .iter()
        .map(|item| match item.item_type() {
            laz::LazItemType::Point14 => 9,
            laz::LazItemType::RGBNIR14 => 2,
            laz::LazItemType::Byte14(n) => u64::from(n),
            _ => 1,
        })
        .sum();
    let mut at = data + 8;
    let mut seen = 0u64;
    let mut chunk = 0usize;
    while seen < points {
        let in_chunk = match &table {
            Some(t) if variable => t.as_ref().get(chunk).map_or(0, |e| e.point_count),
            _ => u64::from(vlr.chunk_size()),
        };
        let head = record + 4 + 4 * layers;
        if at.saturating_add(head) > len {
            return Err(IoError::parse(
                path,
                format!("the file ends inside LASzip chunk {chunk}, at byte {at}"),
            ));
        }
        stream.seek(SeekFrom::Start(at + record + 4)).map_err(io)?;
        let mut sizes = vec![0u8; 4 * layers as usize];
        stream.read_exact(&mut sizes).map_err(io)?;
        let body: u64 = sizes
            .chunks_exact(4)
            .map(|b| u64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])))
            .sum();
        if body > len - at - head {
            return Err(IoError::parse(
                path,
                format!(
                    "LASzip chunk {chunk} at byte {at} declares {body} bytes of layers; {} follow",
                    len - at - head
                ),
            ));
        }
        if in_chunk == 0 {
            break;
        }
        at += head + body;
        seen = seen.saturating_add(in_chunk);
        chunk += 1;
    }
    Ok(decoding)
}

/// The points of a LAS stream; `path` names it in errors. A file whose points stop
/// before the count its header declares is refused, naming the points it ends among.
pub(super) fn read(
    path: &Path,
    mut stream: impl Read + Seek + Send + Sync + 'static,
) -> Result<Vec<Point3<f64>>, IoError> {
    match preflight(path, &mut stream)? {
        Decoding::Parallel => in_a_pool(|parallel| {
            if parallel {
                decode(path, stream, Decoding::Parallel, PARALLEL_CHUNK_BYTES)
            } else {
                decode(path, stream, Decoding::Sequential, CHUNK_BYTES)
            }
        }),
        Decoding::Sequential => decode(path, stream, Decoding::Sequential, CHUNK_BYTES),
    }
}

/// The points of a LAS stream that [`preflight`] has checked, decoded as it said, `bytes` of
/// points at a time.
fn decode(
    path: &Path,
    stream: impl Read + Seek + Send + Sync + 'static,
    decoding: Decoding,
    bytes: u64,
) -> Result<Vec<Point3<f64>>, IoError> {
    let mut points = Vec::new();
    decode_chunks(path, stream, decoding, bytes, |_, chunk| {
        points.extend(points_of(&chunk));
        Ok(())
    })?;
    Ok(points)
}

/// The points of a chunk of records, scaled and offset.
fn points_of(chunk: &PointData) -> impl Iterator<Item = Point3<f64>> + '_ {
    chunk
        .x()
        .zip(chunk.y())
        .zip(chunk.z())
        .map(|((x, y), z)| Point3::new(x, y, z))
}

/// The records of a LAS stream that [`preflight`] has checked, decoded as it said, `bytes` of
/// points at a time: each chunk handed to `each` with the file's header, in the file's order.
fn decode_chunks(
    path: &Path,
    stream: impl Read + Seek + Send + Sync + 'static,
    decoding: Decoding,
    bytes: u64,
    mut each: impl FnMut(&las::Header, PointData) -> Result<(), IoError>,
) -> Result<(), IoError> {
    let parallelism = match decoding {
        Decoding::Parallel => LazParallelism::Yes,
        Decoding::Sequential => LazParallelism::No,
    };
    let options = ReaderOptions::default().with_laz_parallelism(parallelism);
    let mut reader = las::Reader::with_options(stream, options)
        .map_err(|e| las_error(path, "the LAS header", e))?;
    let header = reader.header().clone();
    let declared = header.number_of_points();
    let chunk_points = (bytes / u64::from(header.point_format().len()).max(1)).max(1);
    let mut read = 0u64;
    while read < declared {
        let from = read;
        let chunk = reader.read_points(chunk_points).map_err(|e| {
            let to = (from + chunk_points).min(declared);
            las_error(
                path,
                &format!("points {from}..{to} of the {declared} the header declares"),
                e,
            )
        })?;
        if chunk.is_empty() {
            return Err(IoError::parse(
                path,
                format!("the file ends after {from} of the {declared} points the header declares"),
            ));
        }
        read += chunk.len() as u64;
        each(&header, chunk)?;
    }
    Ok(())
}

/// The coordinate transform of one axis for values in `lo..=hi`: the offset at their middle
/// (rounded to the scale) and the smallest power-of-ten scale at least 10⁻⁹ of the cloud's
/// `extent`, so the stored integers stay within ±5·10⁸ (LAS's are 32-bit).
fn transform(lo: f64, hi: f64, extent: f64) -> Transform {
    let scale = 10f64.powf((extent.max(f64::MIN_POSITIVE) * 1e-9).log10().ceil());
    let offset = ((lo + hi) / 2.0 / scale).round() * scale;
    Transform { scale, offset }
}

/// `points` as a LAS file's bytes, LASzip-compressed when `path` ends in `.laz`; `path` names it
/// in errors.
pub(super) fn encode(path: &Path, points: &[Point3<f64>]) -> Result<Vec<u8>, IoError> {
    let mut lo = Point3::from([f64::INFINITY; 3]);
    let mut hi = Point3::from([f64::NEG_INFINITY; 3]);
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let extent = (hi - lo).max();
    let mut builder = Builder::from((1, 2));
    builder.point_format.is_compressed = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("laz"));
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
    let batch = PointDataBuilder::new().for_header(&header);
    let record = header.point_format().len().max(1) as usize;
    let compressed = header.point_format().is_compressed;
    let write = |parallel: bool| {
        let laz = if parallel {
            LazParallelism::Yes
        } else {
            LazParallelism::No
        };
        let options = WriterOptions::default().with_laz_parallelism(laz);
        let mut writer =
            las::Writer::with_options(Cursor::new(Vec::new()), header, options).map_err(writing)?;
        // Many points a call, so that a LAZ file's chunks are compressed on every core.
        for slab in points.chunks(PARALLEL_CHUNK_BYTES as usize / record) {
            let data = batch
                .clone()
                .build_from_points(slab.iter().map(|p| Point {
                    x: p.x,
                    y: p.y,
                    z: p.z,
                    ..Default::default()
                }))
                .map_err(writing)?;
            writer.write_points(&data).map_err(writing)?;
        }
        Ok(writer.into_inner().map_err(writing)?.into_inner())
    };
    // Plain LAS has nothing to compress: no pool is needed to write it.
    if compressed {
        in_a_pool(write)
    } else {
        write(false)
    }
}

/// A las-rs writer that never panics: las-rs's closes itself when dropped and panics when that
/// fails (a LAS 1.2 header cannot count the records of a return above the fifth, which a
/// damaged or non-conforming file's records may claim); this one is closed by hand, and left
/// unclosed (forgotten) when closing fails.
struct Closing(Option<las::Writer<Cursor<Vec<u8>>>>);

impl Closing {
    /// Writes `points` (see [`las::Writer::write_points`]).
    fn write_points(&mut self, points: &PointData) -> Result<(), las::Error> {
        match &mut self.0 {
            Some(w) => w.write_points(points),
            None => Err(las::Error::ClosedWriter),
        }
    }

    /// The file's bytes, the writer closed.
    fn finish(mut self) -> Result<Vec<u8>, las::Error> {
        let Some(mut w) = self.0.take() else {
            return Err(las::Error::ClosedWriter);
        };
        match w.close() {
            Ok(()) => Ok(w.into_inner()?.into_inner()),
            Err(e) => {
                std::mem::forget(w);
                Err(e)
            }
        }
    }
}

impl Drop for Closing {
    fn drop(&mut self) {
        if let Some(mut w) = self.0.take() {
            if w.close().is_err() {
                std::mem::forget(w);
            }
        }
    }
}

/// Whether `vlr` is the LASzip record that a LAZ file's writer adds for its compression.
fn is_laszip(vlr: &las::Vlr) -> bool {
    vlr.user_id == "laszip encoded" && vlr.record_id == 22204
}

/// The transform of one axis for the moved values `lo..=hi`: the file's `scale` (its
/// resolution) coarsened by powers of ten until the stored integers fit LAS's 32 bits with room
/// (a turn can carry a fine axis across a long one), the offset at their middle.
fn moved_transform(scale: f64, lo: f64, hi: f64) -> Transform {
    let mut scale = if scale.is_finite() && scale > 0.0 {
        scale
    } else {
        1e-3
    };
    while (hi - lo) / scale > 2e9 {
        scale *= 10.0;
    }
    let offset = if lo <= hi {
        ((lo + hi) / 2.0 / scale).round() * scale
    } else {
        0.0
    };
    Transform { scale, offset }
}

/// The LAS file `input` with each point moved by `transform` (see [`Mover`]), as the bytes of
/// `output`, and what was written: every record's other fields byte for byte (intensity,
/// returns, classification, GPS time, colour, extra bytes), the header's point format, version
/// and records (VLRs, EVLRs) as they are; each axis keeps its scale unless the moved extent
/// needs a coarser one, with the offset at the moved points' middle. LASzip-compressed when
/// `output` ends in `.laz`, whatever the input was. The file is decoded once (checked as
/// [`read`] checks it), its records held until they are written.
pub(super) fn rewrite_moved(
    input: &Path,
    output: &Path,
    transform: &Similarity3<f64>,
) -> Result<(Vec<u8>, MovedCloud), IoError> {
    let file = std::fs::File::open(input).map_err(|source| IoError::Io {
        path: input.to_path_buf(),
        source,
    })?;
    let mut stream = std::io::BufReader::with_capacity(1 << 20, file);
    let decoding = preflight(input, &mut stream)?;
    let writing = |e: las::Error| las_error(output, "cannot write LAS", e);
    let compressed = output
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("laz"));
    in_a_pool(|parallel| {
        let (decoding, bytes) = match (parallel, decoding) {
            (true, Decoding::Parallel) => (Decoding::Parallel, PARALLEL_CHUNK_BYTES),
            _ => (Decoding::Sequential, CHUNK_BYTES),
        };
        let mut header = None;
        let mut chunks = Vec::new();
        decode_chunks(input, stream, decoding, bytes, |h, chunk| {
            header.get_or_insert_with(|| h.clone());
            chunks.push(chunk);
            Ok(())
        })?;
        let header = header.ok_or_else(|| IoError::Empty {
            path: input.to_path_buf(),
        })?;
        // A header before LAS 1.4 counts five returns: a record claiming a later one (a
        // damaged or non-conforming file) could be read but not written back.
        if header.version() < las::Version::new(1, 4) {
            let mut at = 0usize;
            for c in &chunks {
                if let Some(k) = c.return_number().position(|r| r > 5) {
                    let v = header.version();
                    return Err(IoError::parse(
                        input,
                        format!(
                            "point {}: a record claims return {}, which its LAS {}.{} header cannot count: it cannot be written back as it is",
                            at + k,
                            c.return_number().nth(k).unwrap_or_default(),
                            v.major,
                            v.minor
                        ),
                    ));
                }
                at += c.len();
            }
        }
        // The moved points' bounds, and how many lie at the origin (missing returns when
        // there are at least two: they stay there), in one pass.
        let mut at_origin = 0;
        let mut lo = Point3::from([f64::INFINITY; 3]);
        let mut hi = Point3::from([f64::NEG_INFINITY; 3]);
        for p in chunks.iter().flat_map(points_of) {
            if p.coords == Vector3::zeros() {
                at_origin += 1;
                continue;
            }
            let q = transform * p;
            lo = lo.inf(&q);
            hi = hi.sup(&q);
        }
        let mover = Mover::with_origins(transform, at_origin);
        if at_origin > 0 {
            let q = mover.point(&Point3::origin());
            lo = lo.inf(&q);
            hi = hi.sup(&q);
        }
        let mut builder = Builder::from(header.clone());
        let t = header.transforms();
        builder.transforms = Vector {
            x: moved_transform(t.x.scale, lo.x, hi.x),
            y: moved_transform(t.y.scale, lo.y, hi.y),
            z: moved_transform(t.z.scale, lo.z, hi.z),
        };
        builder.point_format.is_compressed = compressed;
        builder.vlrs.retain(|v| !is_laszip(v));
        builder.evlrs.retain(|v| !is_laszip(v));
        let out = builder.into_header().map_err(writing)?;
        let laz = if parallel {
            LazParallelism::Yes
        } else {
            LazParallelism::No
        };
        let options = WriterOptions::default().with_laz_parallelism(laz);
        let mut writer = Closing(Some(
            las::Writer::with_options(Cursor::new(Vec::new()), out.clone(), options)
                .map_err(writing)?,
        ));
        let (from, to) = (t, *out.transforms());
        let (mut at, mut left) = (0usize, 0usize);
        for chunk in chunks {
            let record = chunk.record_len();
            let mut raw = chunk.raw_bytes().to_vec();
            drop(chunk);
            for r in raw.chunks_exact_mut(record) {
                let int = |k: usize| i32::from_le_bytes([r[k], r[k + 1], r[k + 2], r[k + 3]]);
                let p = Point3::new(
                    from.x.direct(int(0)),
                    from.y.direct(int(4)),
                    from.z.direct(int(8)),
                );
                left += usize::from(mover.stays(&p));
                let q = mover.point(&p);
                for (k, (v, t)) in [(q.x, to.x), (q.y, to.y), (q.z, to.z)]
                    .into_iter()
                    .enumerate()
                {
                    let n = t.inverse(v).map_err(|e| {
                        let what = format!("point {at} moved to ({}, {}, {})", q.x, q.y, q.z);
                        las_error(output, &what, e)
                    })?;
                    r[4 * k..4 * k + 4].copy_from_slice(&n.to_le_bytes());
                }
                at += 1;
            }
            let data = PointDataBuilder::new()
                .for_header(&out)
                .build_from_bytes(raw)
                .map_err(writing)?;
            writer.write_points(&data).map_err(writing)?;
        }
        let bytes = writer.finish().map_err(writing)?;
        Ok((
            bytes,
            MovedCloud {
                points: at,
                left_in_place: left,
                fields: Fields::Kept,
            },
        ))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A LAZ file of `n` points in LAS point format `format` (LAS 1.4 from format 6 on: layered
    /// chunks), as las-rs writes it: chunks of 50,000 points.
    pub(super) fn laz(format: u8, n: usize) -> Vec<u8> {
        let mut builder = Builder::from((1, if format >= 6 { 4 } else { 2 }));
        builder.point_format = las::point::Format::new(format).unwrap();
        builder.point_format.is_compressed = true;
        let header = builder.into_header().unwrap();
        let mut writer = las::Writer::new(Cursor::new(Vec::new()), header).unwrap();
        for i in 0..n {
            let t = i as f64;
            let mut p = Point {
                x: (t * 0.01).sin(),
                y: 0.001 * t,
                z: (t * 0.37).cos(),
                ..Default::default()
            };
            if format == 7 || format == 3 {
                p.color = Some(las::Color::new(i as u16, 3, 4));
            }
            if format >= 6 || format == 1 || format == 3 {
                p.gps_time = Some(t);
            }
            writer.write_point(p).unwrap();
        }
        writer.into_inner().unwrap().into_inner()
    }

    /// `laz` (of `n` points) with chunks of variable size, as COPC files and some writers have:
    /// the same chunks, the LASzip record's chunk size 0 (variable), each entry of the chunk
    /// table carrying its point count.
    pub(super) fn variable_chunks(laz: &[u8], n: u64) -> Vec<u8> {
        let id = laz
            .windows(14)
            .position(|w| w == b"laszip encoded")
            .unwrap();
        // A VLR: reserved (2), user id (16), record id (2), length (2), description (32).
        let record = id - 2 + 54;
        let fixed = u32::from_le_bytes(laz[record + 12..record + 16].try_into().unwrap());
        let mut out = laz.to_vec();
        out[record + 12..record + 16].copy_from_slice(&0u32.to_le_bytes());
        let vlr = laz::LazVlr::from_buffer(&out[record..]).unwrap();
        assert!(vlr.uses_variable_size_chunks());
        let data = u32::from_le_bytes(laz[96..100].try_into().unwrap()) as usize;
        let at = i64::from_le_bytes(laz[data..data + 8].try_into().unwrap()) as usize;
        let fixed_table =
            laz::laszip::ChunkTable::read(&mut Cursor::new(&laz[at..]), false).unwrap();
        let mut table = laz::laszip::ChunkTable::with_capacity(fixed_table.len());
        let mut left = n;
        for entry in &fixed_table {
            let point_count = left.min(u64::from(fixed));
            left -= point_count;
            table.push(laz::laszip::ChunkTableEntry {
                point_count,
                byte_count: entry.byte_count,
            });
        }
        out.truncate(at);
        table.write_to(&mut out, &vlr).unwrap();
        out
    }

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

    /// The expected coordinates of `laz(_, n)`'s points, at its scale (0.001).
    fn laz_expected(n: usize) -> Vec<Point3<f64>> {
        (0..n)
            .map(|i| {
                let t = i as f64;
                Point3::new((t * 0.01).sin(), 0.001 * t, (t * 0.37).cos())
            })
            .collect()
    }

    #[test]
    fn laz_reads_its_chunks_pointwise_and_layered_fixed_and_variable() {
        // Point format 0 is compressed point by point, format 6 (LAS 1.4) in layers; 120,000
        // points make three chunks of 50,000 or fewer.
        let n = 120_000;
        let expected = laz_expected(n);
        for format in [0, 6] {
            let fixed = laz(format, n);
            for bytes in [variable_chunks(&fixed, n as u64), fixed] {
                let read = read(Path::new("a.laz"), Cursor::new(bytes)).unwrap();
                assert_eq!(read.len(), n);
                let worst = read
                    .iter()
                    .zip(&expected)
                    .map(|(a, b)| (a - b).amax())
                    .fold(0.0, f64::max);
                assert!(worst <= 0.0005 + 1e-9, "format {format}: {worst}");
            }
        }
        // Written by the crate: compressed when the name says so, to the same scale as LAS.
        let points = cloud();
        let bytes = encode(Path::new("a.laz"), &points).unwrap();
        let plain = encode(Path::new("a.las"), &points).unwrap();
        assert!(
            bytes.len() < plain.len() / 2,
            "{} {}",
            bytes.len(),
            plain.len()
        );
        let read = read(Path::new("a.laz"), Cursor::new(bytes)).unwrap();
        assert_eq!(
            read,
            super::read(Path::new("a.las"), Cursor::new(plain)).unwrap()
        );
    }

    #[test]
    fn a_laz_file_with_a_chunk_table_is_decoded_in_parallel_to_the_same_bits() {
        // Reads of 1 MiB end inside the 50,000-point chunks (format 0's 20 bytes: 52,428
        // points), so each read after the first starts from the rest of a chunk.
        let n = 120_000;
        for format in [0, 6] {
            let fixed = laz(format, n);
            for bytes in [variable_chunks(&fixed, n as u64), fixed] {
                let mut stream = Cursor::new(bytes.clone());
                let decoding = preflight(Path::new("a.laz"), &mut stream).unwrap();
                assert_eq!(decoding, Decoding::Parallel, "format {format}");
                let at_once = |decoding, size| {
                    decode(
                        Path::new("a.laz"),
                        Cursor::new(bytes.clone()),
                        decoding,
                        size,
                    )
                    .unwrap()
                };
                let sequential = at_once(Decoding::Sequential, CHUNK_BYTES);
                assert_eq!(sequential.len(), n);
                for size in [1 << 20, PARALLEL_CHUNK_BYTES] {
                    assert!(
                        at_once(Decoding::Parallel, size) == sequential,
                        "format {format}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_laz_file_whose_chunk_table_falls_short_of_its_points_is_decoded_a_chunk_at_a_time() {
        // Fixed chunks of 50,000: a table of two entries covers 100,000 of the 120,000 points.
        // The parallel decoder splits a read by the table and runs past its last entry (an
        // error in a release build, a failed assertion in a debug one); the sequential one needs
        // no table for fixed chunks and reads every point.
        let n = 120_000;
        let whole = laz(0, n);
        let mut bytes = whole.clone();
        let (_, table) = laz_offsets(&bytes);
        bytes[table + 4..table + 8].copy_from_slice(&2u32.to_le_bytes());
        let mut stream = Cursor::new(bytes.clone());
        assert_eq!(
            preflight(Path::new("a.laz"), &mut stream).unwrap(),
            Decoding::Sequential
        );
        let short = read(Path::new("a.laz"), Cursor::new(bytes)).unwrap();
        assert_eq!(short.len(), n);
        assert!(short == read(Path::new("a.laz"), Cursor::new(whole)).unwrap());
    }

    #[test]
    fn only_a_chunk_table_laid_out_as_writers_do_is_decoded_in_parallel() {
        let table = |counts: &[u64]| {
            let mut t = laz::laszip::ChunkTable::with_capacity(counts.len());
            for &point_count in counts {
                t.push(laz::laszip::ChunkTableEntry {
                    point_count,
                    byte_count: 100,
                });
            }
            t
        };
        let fixed = |entries: usize, size: u32, points: u64| {
            parallel_if_it_holds(&table(&vec![0; entries]), size, false, points)
        };
        use Decoding::{Parallel, Sequential};
        // Fixed chunks of 50,000: 120,000 points take three.
        assert_eq!(fixed(3, 50_000, 120_000), Parallel);
        assert_eq!(fixed(2, 50_000, 120_000), Sequential, "short of the points");
        assert_eq!(
            fixed(4, 50_000, 120_000),
            Sequential,
            "a chunk with none of them"
        );
        assert_eq!(fixed(1, 1 << 21, 120_000), Sequential, "a chunk too large");
        assert_eq!(fixed(0, 50_000, 0), Sequential, "no points");
        // Variable chunks: each entry's own count.
        let variable =
            |counts: &[u64], points| parallel_if_it_holds(&table(counts), 0, true, points);
        assert_eq!(variable(&[40_000, 60_000, 20_000], 120_000), Parallel);
        assert_eq!(variable(&[40_000, 60_000, 10_000], 120_000), Sequential);
        assert_eq!(variable(&[40_000, u64::MAX, 1], 120_000), Sequential);
    }

    /// `laz`'s point-data offset and where its chunk table begins.
    fn laz_offsets(laz: &[u8]) -> (usize, usize) {
        let data = u32::from_le_bytes(laz[96..100].try_into().unwrap()) as usize;
        let table = i64::from_le_bytes(laz[data..data + 8].try_into().unwrap()) as usize;
        (data, table)
    }

    #[test]
    fn a_laz_file_is_checked_against_what_its_chunks_declare_before_it_is_decoded() {
        // Each damage below made the decoder abort the process (a buffer sized by the count)
        // or index past its chunk table, before these checks.
        let n = 120_000;
        let refused = |name: &str, bytes: Vec<u8>, says: &str| {
            let err = read(Path::new(name), Cursor::new(bytes))
                .unwrap_err()
                .to_string();
            assert!(
                err.starts_with(&format!("{name}: ")) && err.contains(says),
                "{err}"
            );
        };
        let good = laz(0, n);
        let (_, table) = laz_offsets(&good);
        // The table's chunk count (after its 4-byte version).
        let mut many = good.clone();
        many[table + 4..table + 8].copy_from_slice(&u32::MAX.to_le_bytes());
        refused(
            "many.laz",
            many,
            &format!("chunk table declares {} chunks in a file of", u32::MAX),
        );
        // Cut short: the table's offset now lies past the end.
        refused(
            "cut.laz",
            good[..good.len() / 2].to_vec(),
            &format!("chunk table is said to begin at byte {table}"),
        );
        // A variable-size table that holds fewer points than the header declares.
        let short = variable_chunks(&good, n as u64 - 20_000);
        refused(
            "short.laz",
            short,
            &format!("chunk table holds 100000 points; the header declares {n}"),
        );
        // A layered chunk whose first layer declares 4 GB: the decoder sizes a buffer by it.
        let mut layered = laz(6, n);
        let (data6, _) = laz_offsets(&layered);
        // Chunk 0: the chunk table's offset (8), the first point as is (30), its count (4).
        let at = data6 + 8 + 30 + 4;
        layered[at..at + 4].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
        refused(
            "layers.laz",
            layered,
            &format!("LASzip chunk 0 at byte {} declares", data6 + 8),
        );
    }
}

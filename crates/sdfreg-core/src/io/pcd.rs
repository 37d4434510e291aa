//! PCD (Point Cloud Library) via pcd-rs: `DATA ascii`, `binary` and `binary_compressed`, any
//! field types and counts; the `x`, `y`, `z` fields are read, every other field is skipped.

use std::io::{BufRead, Read};
use std::path::Path;

use nalgebra::Point3;
use pcd_rs::metas::{DataKind, FieldDef, Schema, ValueKind};
use pcd_rs::record::PcdDeserialize;
use pcd_rs::Reader;

use crate::base::error::IoError;
use crate::io::moved::{spelled, Mover};

/// One record as read: only the coordinates are kept.
struct Xyz([f64; 3]);

/// Which coordinate (0, 1, 2) a field holds, if any.
fn axis(def: &FieldDef) -> Option<usize> {
    match def.name.as_str() {
        "x" => Some(0),
        "y" => Some(1),
        "z" => Some(2),
        _ => None,
    }
}

fn binary_value<R: Read>(reader: &mut R, kind: ValueKind) -> std::io::Result<f64> {
    fn bytes<const N: usize, R: Read>(r: &mut R) -> std::io::Result<[u8; N]> {
        let mut b = [0u8; N];
        r.read_exact(&mut b)?;
        Ok(b)
    }
    Ok(match kind {
        ValueKind::I8 => i8::from_le_bytes(bytes(reader)?) as f64,
        ValueKind::U8 => u8::from_le_bytes(bytes(reader)?) as f64,
        ValueKind::I16 => i16::from_le_bytes(bytes(reader)?) as f64,
        ValueKind::U16 => u16::from_le_bytes(bytes(reader)?) as f64,
        ValueKind::I32 => i32::from_le_bytes(bytes(reader)?) as f64,
        ValueKind::U32 => u32::from_le_bytes(bytes(reader)?) as f64,
        ValueKind::I64 => i64::from_le_bytes(bytes(reader)?) as f64,
        ValueKind::U64 => u64::from_le_bytes(bytes(reader)?) as f64,
        ValueKind::F32 => f32::from_le_bytes(bytes(reader)?) as f64,
        ValueKind::F64 => f64::from_le_bytes(bytes(reader)?),
    })
}

impl PcdDeserialize for Xyz {
    fn is_dynamic() -> bool {
        true // any schema; `read` checks that x, y and z are there
    }

    fn read_spec() -> Vec<(Option<String>, ValueKind, Option<usize>)> {
        Vec::new()
    }

    fn read_chunk<R: BufRead>(reader: &mut R, field_defs: &Schema) -> pcd_rs::Result<Self> {
        let mut xyz = [0.0; 3];
        for def in field_defs.iter() {
            for k in 0..def.count {
                let v = binary_value(reader, def.kind)?;
                if k == 0 {
                    if let Some(a) = axis(def) {
                        xyz[a] = v;
                    }
                }
            }
        }
        Ok(Xyz(xyz))
    }

    fn read_line<R: BufRead>(reader: &mut R, field_defs: &Schema) -> pcd_rs::Result<Self> {
        let mut line = String::new();
        reader.read_line(&mut line)?;
        let mut tokens = line.split_ascii_whitespace();
        let mut xyz = [0.0; 3];
        for def in field_defs.iter() {
            for k in 0..def.count {
                let token = tokens.next().ok_or_else(|| {
                    pcd_rs::Error::new_parse_error(0, &format!("field `{}` is missing", def.name))
                })?;
                if k == 0 {
                    if let Some(a) = axis(def) {
                        xyz[a] = token.parse::<f64>().map_err(|_| {
                            pcd_rs::Error::new_parse_error(
                                0,
                                &format!("field `{}`: {token:?} is not a number", def.name),
                            )
                        })?;
                    }
                }
            }
        }
        Ok(Xyz(xyz))
    }
}

/// For `DATA binary_compressed`: the block's two sizes (compressed, uncompressed) must fit the
/// `available` bytes, so that a hostile header cannot make the reader allocate gigabytes.
/// `head` is the start of the stream (the header and what follows).
fn check_compressed_sizes(head: &[u8], available: u64) -> Result<(), String> {
    const KEY: &[u8] = b"DATA binary_compressed";
    let Some(at) = head.windows(KEY.len()).position(|w| w == KEY) else {
        return Ok(());
    };
    let Some(nl) = head[at..].iter().position(|&b| b == b'\n') else {
        return Ok(());
    };
    let start = at + nl + 1;
    let Some(sizes) = head.get(start..start + 8) else {
        return Ok(()); // too short: pcd-rs reports the truncation
    };
    let compressed = u32::from_le_bytes(sizes[..4].try_into().unwrap()) as u64;
    let uncompressed = u32::from_le_bytes(sizes[4..].try_into().unwrap()) as u64;
    let rest = available.saturating_sub(start as u64 + 8);
    if compressed > rest {
        return Err(format!(
            "the binary_compressed block claims {compressed} bytes, the file has {rest} after the header"
        ));
    }
    // LZF expands at most about 100-fold.
    if uncompressed > 100 * compressed + 4096 {
        return Err(format!(
            "the binary_compressed block claims {uncompressed} bytes from {compressed} compressed"
        ));
    }
    Ok(())
}

/// Reads the `x`, `y`, `z` fields of a PCD stream of `available` bytes; `path` names it in
/// errors.
pub(super) fn read(
    path: &Path,
    mut reader: impl BufRead,
    available: u64,
) -> Result<Vec<Point3<f64>>, IoError> {
    let parse = |message: String| IoError::parse(path, message);
    let head = reader.fill_buf().map_err(|source| IoError::Io {
        path: path.into(),
        source,
    })?;
    check_compressed_sizes(head, available)
        .map_err(|e| parse(format!("not a valid PCD file: {e}")))?;
    // Where the body starts (after the DATA line), for byte offsets in errors.
    let body = head.windows(5).position(|w| w == b"DATA ").and_then(|at| {
        head[at..]
            .iter()
            .position(|&b| b == b'\n')
            .map(|nl| at + nl + 1)
    });
    let reader = Reader::<Xyz, _>::from_reader(reader)
        .map_err(|e| parse(format!("not a valid PCD file: {e}")))?;
    let fields = &reader.meta().field_defs;
    for name in ["x", "y", "z"] {
        if !fields.iter().any(|d| d.name == name) {
            return Err(parse(format!("no `{name}` field in FIELDS")));
        }
    }
    let declared = reader.meta().num_points;
    let record: u64 = fields
        .iter()
        .map(|d| d.kind.byte_size() as u64 * d.count)
        .sum();
    // In a binary body, point i starts at a known byte.
    let binary = matches!(reader.meta().data, DataKind::Binary);
    let place = |i: usize| match (binary, body) {
        (true, Some(b)) => format!(
            "byte {}: point {i} of the {declared} declared ({record} bytes each, from byte {b})",
            b as u64 + i as u64 * record
        ),
        _ => format!("point {i} of the {declared} declared"),
    };
    let mut points = Vec::with_capacity(declared.min(1 << 26) as usize);
    for (i, record) in reader.enumerate() {
        let Xyz(p) = record.map_err(|e| {
            let e = e.to_string();
            let what = if e.contains("fill whole buffer") {
                "the file ends inside it"
            } else {
                &e
            };
            parse(format!("{}: {what}", place(i)))
        })?;
        points.push(Point3::from(p));
    }
    Ok(points)
}

pub(super) fn encode(points: &[Point3<f64>]) -> Vec<u8> {
    let n = points.len();
    let header = format!("# .PCD v0.7 - written by sdfreg\nVERSION 0.7\nFIELDS x y z\nSIZE 8 8 8\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n");
    crate::io::bytes::with_le_doubles(header, points)
}

/// The PCD file `path` (its `bytes`, in which [`read`] found `n` points) with each point moved
/// by `mover` and its normal (`normal_x`, `normal_y`, `normal_z`) turned, in their own types,
/// and its `VIEWPOINT` (the sensor's pose) moved with them; every other field, header line and
/// byte as they are. An ascii row is written with its numbers one space apart. `Ok(Err(why))`
/// when the body cannot be rewritten in place: `binary_compressed`, or a coordinate or normal
/// that is not one float.
pub(super) fn rewrite_moved(
    path: &Path,
    bytes: &[u8],
    n: usize,
    mover: &Mover,
) -> Result<Result<Vec<u8>, String>, IoError> {
    let parse = |message: String| IoError::parse(path, message);
    let meta = pcd_rs::metas::PcdMeta::from_reader(bytes)
        .map_err(|e| parse(format!("not a valid PCD file: {e}")))?;
    if matches!(meta.data, DataKind::BinaryCompressed) {
        return Ok(Err("its body is binary_compressed".to_string()));
    }
    // The body follows the header's DATA line.
    let mut body = None;
    let mut at = 0;
    for line in bytes.split_inclusive(|&b| b == b'\n') {
        at += line.len();
        if line.trim_ascii_start().starts_with(b"DATA") {
            body = Some(at);
            break;
        }
    }
    let body = body.ok_or_else(|| parse("no DATA line".into()))?;
    // Each field's first column (ascii) and byte (binary) in a row.
    let fields = &meta.field_defs.fields;
    let (mut column, mut byte) = (Vec::new(), Vec::new());
    let (mut c, mut b) = (0usize, 0usize);
    for f in fields {
        column.push(c);
        byte.push(b);
        c += f.count as usize;
        b += f.kind.byte_size() * f.count as usize;
    }
    let (columns, record) = (c, b);
    let place = |name: &str| -> Result<Option<usize>, String> {
        match fields.iter().position(|f| f.name == name) {
            None => Ok(None),
            Some(k)
                if fields[k].count == 1
                    && matches!(fields[k].kind, ValueKind::F32 | ValueKind::F64) =>
            {
                Ok(Some(k))
            }
            Some(_) => Err(format!("its field `{name}` is not one float")),
        }
    };
    let mut places = Vec::new();
    for name in ["x", "y", "z", "normal_x", "normal_y", "normal_z"] {
        match place(name) {
            Ok(k) => places.push(k),
            Err(why) => return Ok(Err(why)),
        }
    }
    let [Some(x), Some(y), Some(z), a, b, c] = places[..] else {
        return Err(parse("no `x`, `y` or `z` field in FIELDS".into()));
    };
    let normal = a.zip(b).zip(c).map(|((a, b), c)| [a, b, c]);
    let read: Vec<usize> = [x, y, z]
        .into_iter()
        .chain(normal.into_iter().flatten())
        .collect();
    let single = |k: usize| matches!(fields[k].kind, ValueKind::F32);
    let moved = |get: &dyn Fn(usize) -> f64| mover.record([x, y, z], normal, get);
    let mut out = viewpoint_moved(&bytes[..body], &meta.viewpoint, mover);
    if matches!(meta.data, DataKind::Ascii) {
        let mut rows = bytes[body..].split_inclusive(|&b| b == b'\n');
        for row in 0..n {
            let raw = rows
                .next()
                .ok_or_else(|| parse(format!("the file ends before point {row}")))?;
            let text =
                std::str::from_utf8(raw).map_err(|_| parse(format!("point {row} is not text")))?;
            let line = text.trim_end_matches(['\r', '\n']);
            let mut tokens: Vec<String> = line.split_whitespace().map(str::to_string).collect();
            if tokens.len() != columns {
                return Err(parse(format!(
                    "point {row}: {} numbers where FIELDS and COUNT declare {columns}: {line:?}",
                    tokens.len()
                )));
            }
            let mut olds = vec![0.0; fields.len()];
            for &k in &read {
                olds[k] = tokens[column[k]].parse::<f64>().map_err(|_| {
                    parse(format!(
                        "point {row}: `{}` is not a number: {:?}",
                        fields[k].name, tokens[column[k]]
                    ))
                })?;
            }
            match moved(&|k| olds[k]) {
                None => out.extend_from_slice(raw),
                Some(new) => {
                    for (k, v) in new {
                        tokens[column[k]] = spelled(v, single(k));
                    }
                    out.extend_from_slice(tokens.join(" ").as_bytes());
                    out.extend_from_slice(&raw[line.len()..]);
                }
            }
        }
        rows.for_each(|rest| out.extend_from_slice(rest));
        return Ok(Ok(out));
    }
    let rows = bytes.get(body..body + record * n).ok_or_else(|| {
        parse(format!(
            "the file ends inside its {n} points of {record} bytes"
        ))
    })?;
    for row in rows.chunks_exact(record.max(1)) {
        let get = |k: usize| {
            let r = &row[byte[k]..];
            if single(k) {
                f32::from_le_bytes([r[0], r[1], r[2], r[3]]) as f64
            } else {
                f64::from_le_bytes(r[..8].try_into().unwrap_or_default())
            }
        };
        let mut row = row.to_vec();
        for (k, v) in moved(&get).unwrap_or_default() {
            let o = byte[k];
            if single(k) {
                row[o..o + 4].copy_from_slice(&(v as f32).to_le_bytes());
            } else {
                row[o..o + 8].copy_from_slice(&v.to_le_bytes());
            }
        }
        out.extend_from_slice(&row);
    }
    out.extend_from_slice(&bytes[body + rows.len()..]);
    Ok(Ok(out))
}

/// A PCD `header` (up to its body) with its `VIEWPOINT` line, the sensor's pose in the cloud's
/// frame (`viewpoint`), moved by `mover`'s transform; the other lines as they are.
fn viewpoint_moved(header: &[u8], viewpoint: &pcd_rs::metas::ViewPoint, mover: &Mover) -> Vec<u8> {
    let v = viewpoint;
    let t = mover.transform();
    let at = t * Point3::new(v.tx, v.ty, v.tz);
    let q = nalgebra::Quaternion::new(v.qw, v.qx, v.qy, v.qz);
    // A header's zero quaternion is no orientation: taken as none.
    let q = if q.norm() > 0.0 {
        nalgebra::UnitQuaternion::from_quaternion(q)
    } else {
        nalgebra::UnitQuaternion::identity()
    };
    let q = t.isometry.rotation * q;
    let line = format!(
        "VIEWPOINT {} {} {} {} {} {} {}",
        at.x, at.y, at.z, q.w, q.i, q.j, q.k
    );
    let mut out = Vec::with_capacity(header.len() + 64);
    for raw in header.split_inclusive(|&b| b == b'\n') {
        if raw.starts_with(b"VIEWPOINT") {
            let end = raw
                .iter()
                .rev()
                .take_while(|&&b| b == b'\n' || b == b'\r')
                .count();
            out.extend_from_slice(line.as_bytes());
            out.extend_from_slice(&raw[raw.len() - end..]);
        } else {
            out.extend_from_slice(raw);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read_all(path: &Path, bytes: &[u8]) -> Result<Vec<Point3<f64>>, IoError> {
        read(path, bytes, bytes.len() as u64)
    }

    #[test]
    fn fuzz_regression_a_huge_compressed_size_is_refused_before_allocating() {
        // Found by `cargo fuzz run pcd`: the header claims a 3.2 GB compressed block.
        let bytes = include_bytes!("fuzz_regressions/pcd-huge-compressed-size.pcd");
        let err = read_all(Path::new("f.pcd"), bytes).unwrap_err().to_string();
        assert!(err.contains("claims") && err.contains("bytes"), "{err}");
    }

    const HEADER: &str = "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n";

    #[test]
    fn reads_ascii_with_extra_fields_and_counts() {
        let text = format!("{HEADER}FIELDS x y z normal rgb\nSIZE 4 4 4 4 4\nTYPE F F F F U\nCOUNT 1 1 1 3 1\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n1 2 3 0 0 1 255\n-4.5 5 6e-1 1 0 0 7\n");
        let pts = read_all(Path::new("a.pcd"), text.as_bytes()).unwrap();
        assert_eq!(
            pts,
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-4.5, 5.0, 0.6)]
        );
    }

    #[test]
    fn reads_binary_doubles_after_a_padding_field() {
        let mut b = format!("{HEADER}FIELDS intensity x y z\nSIZE 2 8 8 8\nTYPE U F F F\nCOUNT 1 1 1 1\nWIDTH 1\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 1\nDATA binary\n").into_bytes();
        b.extend_from_slice(&7u16.to_le_bytes());
        for v in [1e6 + 0.25, -2.0, 0.5f64] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        let pts = read_all(Path::new("b.pcd"), &b[..]).unwrap();
        assert_eq!(pts, vec![Point3::new(1e6 + 0.25, -2.0, 0.5)]);
    }

    #[test]
    fn explains_what_is_wrong() {
        let no_z = format!("{HEADER}FIELDS x y\nSIZE 4 4\nTYPE F F\nCOUNT 1 1\nWIDTH 1\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 1\nDATA ascii\n1 2\n");
        let err = read_all(Path::new("c.pcd"), no_z.as_bytes())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("c.pcd") && err.contains("no `z` field"),
            "{err}"
        );
        let short = format!("{HEADER}FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA binary\n").into_bytes();
        let mut truncated = short.clone();
        truncated.extend_from_slice(&[0u8; 14]);
        let err = read_all(Path::new("d.pcd"), &truncated[..])
            .unwrap_err()
            .to_string();
        assert!(err.contains("d.pcd") && err.contains("point 1"), "{err}");
        let bad = format!("{HEADER}FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 1\nDATA ascii\n1 two 3\n");
        let err = read_all(Path::new("e.pcd"), bad.as_bytes())
            .unwrap_err()
            .to_string();
        assert!(err.contains("point 0") && err.contains("\"two\""), "{err}");
        let err = read_all(Path::new("f.pcd"), &b"not a pcd\n"[..])
            .unwrap_err()
            .to_string();
        assert!(err.starts_with("f.pcd: not a valid PCD file"), "{err}");
    }
}

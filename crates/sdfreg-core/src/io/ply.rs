//! PLY via ply-rs: ascii and binary (both endiannesses), any numeric property type; the
//! `vertex` element's `x`, `y`, `z` are read and every other property or element is ignored.
//!
//! Errors name the place: the line for the header and ascii bodies, the byte offset for binary
//! bodies (counted by [`Counting`] as the parser consumes the stream), and what the header
//! declared. Data after the last declared element is an error (the counts are wrong).

use std::io::{BufRead, Read};
use std::path::Path;

use nalgebra::Point3;
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{
    ElementDef, Encoding, Header, Property, PropertyAccess, PropertyType, ScalarType,
};

use crate::base::error::IoError;

fn number(p: &Property) -> Option<f64> {
    Some(match *p {
        Property::Char(v) => v as f64,
        Property::UChar(v) => v as f64,
        Property::Short(v) => v as f64,
        Property::UShort(v) => v as f64,
        Property::Int(v) => v as f64,
        Property::UInt(v) => v as f64,
        Property::Float(v) => v as f64,
        Property::Double(v) => v,
        _ => return None,
    })
}

/// Indices of a list property (a face's vertices), as i64.
fn indices(p: Property) -> Option<Vec<i64>> {
    Some(match p {
        Property::ListChar(v) => v.into_iter().map(i64::from).collect(),
        Property::ListUChar(v) => v.into_iter().map(i64::from).collect(),
        Property::ListShort(v) => v.into_iter().map(i64::from).collect(),
        Property::ListUShort(v) => v.into_iter().map(i64::from).collect(),
        Property::ListInt(v) => v.into_iter().map(i64::from).collect(),
        Property::ListUInt(v) => v.into_iter().map(i64::from).collect(),
        _ => return None,
    })
}

/// What the reader needs of a parsed element.
trait Row: PropertyAccess {
    /// The coordinates and which were read (bit k for coordinate k).
    fn xyz(&self) -> ([f64; 3], u8);
    /// A face's vertex indices (empty for an element that keeps none).
    fn indices(&self) -> &[i64] {
        &[]
    }
}

/// Stores coordinate `name` into `xyz`/`seen` when it is one; returns whether it was.
fn set_xyz(xyz: &mut [f64; 3], seen: &mut u8, name: &str, property: &Property) -> bool {
    let k = match name {
        "x" => 0,
        "y" => 1,
        "z" => 2,
        _ => return false,
    };
    if let Some(v) = number(property) {
        xyz[k] = v;
        *seen |= 1 << k;
    }
    true
}

/// One element as the parser fills it for a point cloud: only `x`, `y`, `z` are kept (32 bytes
/// per element, so a 5-million-point file costs 160 MB while parsing, not a map per vertex).
struct Xyz {
    xyz: [f64; 3],
    seen: u8,
}

impl PropertyAccess for Xyz {
    fn new() -> Self {
        Xyz {
            xyz: [0.0; 3],
            seen: 0,
        }
    }

    fn set_property(&mut self, name: &str, property: Property) {
        set_xyz(&mut self.xyz, &mut self.seen, name, &property);
    }
}

impl Row for Xyz {
    fn xyz(&self) -> ([f64; 3], u8) {
        (self.xyz, self.seen)
    }
}

/// One element for a mesh: the coordinates and a face's `vertex_indices` (or `vertex_index`).
struct MeshRow {
    xyz: [f64; 3],
    seen: u8,
    indices: Vec<i64>,
}

impl PropertyAccess for MeshRow {
    fn new() -> Self {
        MeshRow {
            xyz: [0.0; 3],
            seen: 0,
            indices: Vec::new(),
        }
    }

    fn set_property(&mut self, name: &str, property: Property) {
        if name == "vertex_indices" || name == "vertex_index" {
            self.indices = indices(property).unwrap_or_default();
        } else {
            set_xyz(&mut self.xyz, &mut self.seen, name, &property);
        }
    }
}

impl Row for MeshRow {
    fn xyz(&self) -> ([f64; 3], u8) {
        (self.xyz, self.seen)
    }

    fn indices(&self) -> &[i64] {
        &self.indices
    }
}

/// Vertices and triangles (indices into the vertices).
pub type MeshData = (Vec<Point3<f64>>, Vec<[usize; 3]>);

/// Vertices and triangles (polygons split into fans) of a PLY stream; `path` names it in errors.
pub(super) fn read_mesh(path: &Path, reader: impl BufRead) -> Result<MeshData, IoError> {
    read_elements::<MeshRow>(path, reader)
}

/// Reads the `vertex` element's `x`, `y`, `z` from a PLY stream; `path` names it in errors.
/// Every element is parsed (a truncated file is an error even after its vertices), but only the
/// coordinates are kept.
pub(super) fn read(path: &Path, reader: impl BufRead) -> Result<Vec<Point3<f64>>, IoError> {
    Ok(read_elements::<Xyz>(path, reader)?.0)
}

/// A stream that counts the bytes and, while `lines` is on, the line ends the parser consumed.
struct Counting<R> {
    inner: R,
    bytes: u64,
    line_ends: u64,
    lines: bool,
}

impl<R: BufRead> Counting<R> {
    fn count(&mut self, consumed: usize) {
        self.bytes += consumed as u64;
    }
}

impl<R: BufRead> Read for Counting<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        if self.lines {
            self.line_ends += buf[..n].iter().filter(|&&b| b == b'\n').count() as u64;
        }
        self.count(n);
        Ok(n)
    }
}

impl<R: BufRead> BufRead for Counting<R> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        self.inner.fill_buf()
    }

    fn consume(&mut self, amt: usize) {
        if self.lines {
            // The bytes consumed are those fill_buf returned; this call does no I/O.
            if let Ok(buf) = self.inner.fill_buf() {
                let n = amt.min(buf.len());
                self.line_ends += buf[..n].iter().filter(|&&b| b == b'\n').count() as u64;
            }
        }
        self.inner.consume(amt);
        self.count(amt);
    }
}

/// Bytes per row of an element without list properties.
fn row_size(def: &ElementDef) -> Option<u64> {
    def.properties
        .values()
        .map(|p| match &p.data_type {
            PropertyType::Scalar(t) => Some(match t {
                ScalarType::Char | ScalarType::UChar => 1,
                ScalarType::Short | ScalarType::UShort => 2,
                ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
                ScalarType::Double => 8,
            }),
            PropertyType::List(..) => None,
        })
        .sum()
}

/// The part of a ply-rs message before its debug details, and the offending text it quotes.
fn ply_rs_message(e: &std::io::Error) -> (String, Option<String>) {
    let text = e.to_string();
    let head = text.split(['\t', '\n']).next().unwrap_or("").trim();
    let quoted = text
        .split_once("String: '")
        .and_then(|(_, rest)| rest.split_once('\'').map(|(q, _)| q.trim().to_string()));
    (head.to_string(), quoted)
}

/// A parse error of `path` at `line` (one-based, when known).
fn parse_error(path: &Path, line: Option<u64>, message: String) -> IoError {
    IoError::Parse {
        path: path.into(),
        line: line.map(|l| l as usize),
        message,
    }
}

/// Points and triangles (fans of the polygons) of a PLY file: the header, each element's rows,
/// nothing after the last element.
fn read_elements<E: Row>(path: &Path, reader: impl BufRead) -> Result<MeshData, IoError> {
    let parse = |message: String| parse_error(path, None, message);
    let mut reader = Counting {
        inner: reader,
        bytes: 0,
        line_ends: 0,
        lines: true,
    };
    let parser = Parser::<E>::new();
    let header = parser
        .read_header(&mut reader)
        .map_err(|e| header_error(path, &e))?;
    let ascii = header.encoding == Encoding::Ascii;
    reader.lines = ascii;
    let vertex = header
        .elements
        .get("vertex")
        .ok_or_else(|| parse("no `vertex` element in the header".into()))?;
    for axis in ["x", "y", "z"] {
        if !vertex.properties.contains_key(axis) {
            return Err(parse(format!(
                "the `vertex` element has no `{axis}` property"
            )));
        }
    }
    let mut points = Vec::new();
    let mut face_rows = Vec::new();
    for (name, def) in &header.elements {
        let start = (reader.bytes, reader.line_ends);
        let rows = parser
            .read_payload_for_element(&mut reader, def, &header)
            .map_err(|e| payload_error(path, &e, def, ascii, start, &reader))?;
        match name.as_str() {
            "face" => face_rows = rows,
            "vertex" => points = vertices(&rows).map_err(parse)?,
            _ => {}
        }
    }
    refuse_trailing_data(path, &mut reader, &header, ascii)?;
    let triangles = triangles(&face_rows, points.len()).map_err(parse)?;
    Ok((points, triangles))
}

/// ply-rs's header error, with the line it names.
fn header_error(path: &Path, e: &std::io::Error) -> IoError {
    let (head, _) = ply_rs_message(e);
    // ply-rs counts header lines from 1 as "Line N: ...".
    let line = head
        .strip_prefix("Line ")
        .and_then(|r| r.split_once(':'))
        .and_then(|(n, _)| n.trim().parse::<u64>().ok());
    let what = match line {
        Some(_) => head
            .split_once(':')
            .map_or(head.as_str(), |(_, m)| m.trim()),
        None => head.as_str(),
    };
    parse_error(path, line, format!("not a valid PLY header: {what}"))
}

/// ply-rs's error inside the rows of element `def`, which started at `start` (byte, line ends):
/// the line and row (ascii) or the byte, row and the element's extent (binary).
fn payload_error<R: BufRead>(
    path: &Path,
    e: &std::io::Error,
    def: &ElementDef,
    ascii: bool,
    (start_byte, start_line): (u64, u64),
    reader: &Counting<R>,
) -> IoError {
    let (head, quoted) = ply_rs_message(e);
    let eof = head.contains("end of file");
    let (name, declared) = (&def.name, def.count);
    match (ascii, eof) {
        (true, true) => parse_error(
            path,
            Some(reader.line_ends + 1),
            format!(
                "the file ends after {} of the {declared} `{name}` rows the header declares",
                reader.line_ends - start_line
            ),
        ),
        (true, false) => parse_error(
            path,
            Some(reader.line_ends),
            format!(
                "`{name}` row {}: expected {} numbers as the header declares{}",
                (reader.line_ends - start_line).saturating_sub(1),
                def.properties.len(),
                quoted.map(|q| format!(", found {q:?}")).unwrap_or_default()
            ),
        ),
        (false, _) => {
            let size = row_size(def);
            let row = size
                .map(|b| {
                    let row = (reader.bytes - start_byte) / b;
                    format!(" row {row} (0-based) of the {declared} declared")
                })
                .unwrap_or_default();
            let what = if eof {
                "the file ends"
            } else {
                "unreadable data"
            };
            let extent = size
                .map(|b| {
                    format!(
                        " and needs {declared} rows of {b} bytes = {} bytes",
                        declared as u64 * b
                    )
                })
                .unwrap_or_default();
            parse_error(
                path,
                None,
                format!(
                    "byte {}: {what} inside `{name}`{row}; the element starts at byte \
                     {start_byte}{extent}",
                    reader.bytes
                ),
            )
        }
    }
}

/// The `vertex` rows as points; a row without a numeric x, y or z is refused.
fn vertices<E: Row>(rows: &[E]) -> Result<Vec<Point3<f64>>, String> {
    let mut points = Vec::with_capacity(rows.len());
    for (i, row) in rows.iter().enumerate() {
        let (xyz, seen) = row.xyz();
        if seen != 0b111 {
            let k = (0..3).find(|k| seen & (1 << k) == 0).unwrap_or(0);
            return Err(format!(
                "vertex {i}: `{}` is missing or not a number",
                ["x", "y", "z"][k]
            ));
        }
        points.push(Point3::from(xyz));
    }
    Ok(points)
}

/// Refuses anything but white space after the last element: the header's counts are wrong.
fn refuse_trailing_data<R: BufRead>(
    path: &Path,
    reader: &mut Counting<R>,
    header: &Header,
    ascii: bool,
) -> Result<(), IoError> {
    loop {
        let bytes = reader.bytes;
        let buf = reader
            .fill_buf()
            .map_err(|e| parse_error(path, None, format!("byte {bytes}: {e}")))?;
        let n = buf.len();
        if n == 0 {
            return Ok(());
        }
        let Some(k) = buf.iter().position(|b| !b.is_ascii_whitespace()) else {
            reader.consume(n);
            continue;
        };
        reader.consume(k);
        let counts: Vec<String> = header
            .elements
            .values()
            .map(|d| format!("{} `{}`", d.count, d.name))
            .collect();
        let message = format!(
            "data after the last element: the header declares {} rows",
            counts.join(", ")
        );
        return Err(if ascii {
            parse_error(path, Some(reader.line_ends + 1), message)
        } else {
            parse_error(path, None, format!("byte {}: {message}", reader.bytes))
        });
    }
}

/// The `face` rows as triangles (polygons as fans) over `n` vertices; indices out of range and
/// faces of fewer than 3 vertices are refused.
fn triangles<E: Row>(faces: &[E], n: usize) -> Result<Vec<[usize; 3]>, String> {
    let n = n as i64;
    let mut out = Vec::new();
    for (i, face) in faces.iter().enumerate() {
        let v = face.indices();
        if v.is_empty() {
            continue; // a cloud's faces are not asked for
        }
        if let Some(&bad) = v.iter().find(|&&k| k < 0 || k >= n) {
            return Err(format!(
                "face {i}: vertex index {bad} is out of range (the file has {n} vertices)"
            ));
        }
        if v.len() < 3 {
            return Err(format!(
                "face {i}: {} vertex indices, a face needs at least 3",
                v.len()
            ));
        }
        for k in 1..v.len() - 1 {
            out.push([v[0] as usize, v[k] as usize, v[k + 1] as usize]);
        }
    }
    Ok(out)
}

pub(super) fn encode(points: &[Point3<f64>]) -> Vec<u8> {
    encode_mesh(points, &[])
}

/// A binary little-endian PLY of `points` (doubles) and, when there are any, `triangles`
/// (`face` rows of a uchar count and three uint indices).
pub(super) fn encode_mesh(points: &[Point3<f64>], triangles: &[[usize; 3]]) -> Vec<u8> {
    let faces = if triangles.is_empty() {
        String::new()
    } else {
        format!(
            "element face {}\nproperty list uchar uint vertex_indices\n",
            triangles.len()
        )
    };
    let header = format!("ply\nformat binary_little_endian 1.0\ncomment written by sdfreg\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\n{faces}end_header\n", points.len());
    let mut out = crate::io::bytes::with_le_doubles(header, points);
    out.reserve(triangles.len() * 13);
    for t in triangles {
        out.push(3);
        for &i in t {
            out.extend_from_slice(&(i as u32).to_le_bytes());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_ascii_with_extra_properties_and_elements() {
        let text = "ply\nformat ascii 1.0\ncomment hi\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n1 2 3 255\n4.5 5 6 0\n3 0 1 1\n";
        let pts = read(Path::new("a.ply"), text.as_bytes()).unwrap();
        assert_eq!(
            pts,
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(4.5, 5.0, 6.0)]
        );
    }

    #[test]
    fn reads_binary_big_endian_integers() {
        let mut b = b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty short x\nproperty int y\nproperty double z\nend_header\n".to_vec();
        b.extend_from_slice(&(-3i16).to_be_bytes());
        b.extend_from_slice(&7i32.to_be_bytes());
        b.extend_from_slice(&0.5f64.to_be_bytes());
        assert_eq!(
            read(Path::new("b.ply"), &b[..]).unwrap(),
            vec![Point3::new(-3.0, 7.0, 0.5)]
        );
    }

    #[test]
    fn explains_what_is_missing() {
        let text = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n";
        let err = read(Path::new("c.ply"), text.as_bytes())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("c.ply") && err.contains("no `z` property"),
            "{err}"
        );
        let err = read(Path::new("d.ply"), &b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n"[..]).unwrap_err().to_string();
        assert!(
            err.starts_with("d.ply:9: the file ends after 1 of the 3 `vertex` rows"),
            "{err}"
        );
        // CRLF line ends and a comment read the same.
        let crlf = "ply\r\nformat ascii 1.0\r\ncomment c\r\nelement vertex 2\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\nend_header\r\n1 2 3\r\n4 5 6\r\n";
        assert_eq!(
            read(Path::new("e.ply"), crlf.as_bytes()).unwrap(),
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(4.0, 5.0, 6.0)]
        );
    }
}

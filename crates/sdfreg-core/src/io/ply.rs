//! PLY via ply-rs: ascii and binary (both endiannesses), any numeric property type; the
//! `vertex` element's `x`, `y`, `z` are read and every other property or element is ignored.
//!
//! Errors name the place: the line for the header and ascii bodies, the byte offset for binary
//! bodies (counted by [`Counting`] as the parser consumes the stream), and what the header
//! declared. Data after the last declared element is an error (the counts are wrong).
//!
//! An ascii body may spell a number in ways ply-rs's grammar refuses but a float parser reads:
//! `nan`, `-nan`, `inf`, `infinity` in any case (Open3D's and PCL's ascii writers put them where a
//! scanner had no return or a normal is undefined), `.5`, `5.`. [`respelled_line`] spells each
//! such number so that the grammar reads the same value, and a point with a NaN or infinite
//! coordinate is then refused by its line, or dropped, as in any other format.

use std::borrow::Cow;
use std::io::{BufRead, Read};
use std::path::Path;

use nalgebra::Point3;
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{
    ElementDef, Encoding, Header, Property, PropertyAccess, PropertyType, ScalarType,
};

use crate::base::error::IoError;
use crate::io::finite::refuse_non_finite;
use crate::io::moved::{spelled, Mover};

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
/// A vertex with a NaN or infinite coordinate is an error naming it.
pub(super) fn read_mesh(path: &Path, reader: impl BufRead) -> Result<MeshData, IoError> {
    let ((vertices, triangles), first_line) = read_elements::<MeshRow>(path, reader)?;
    refuse_non_finite(path, &vertices, first_line)?;
    Ok((vertices, triangles))
}

/// Reads the `vertex` element's `x`, `y`, `z` from a PLY stream; `path` names it in errors.
/// Every element is parsed (a truncated file is an error even after its vertices), but only the
/// coordinates are kept. A point with a NaN or infinite coordinate is an error naming it (and,
/// in an ascii file, its line) unless `keep_non_finite`.
pub(super) fn read(
    path: &Path,
    reader: impl BufRead,
    keep_non_finite: bool,
) -> Result<Vec<Point3<f64>>, IoError> {
    let ((points, _), first_line) = read_elements::<Xyz>(path, reader)?;
    if !keep_non_finite {
        refuse_non_finite(path, &points, first_line)?;
    }
    Ok(points)
}

/// `line` of an ascii body with each number that ply-rs's grammar
/// (`[+-]?D+(.D+)?([eE][+-]?D+)?`) refuses but Rust's float parser reads spelled anew with the
/// same value: a missing integer part as `0`, a missing fraction without its point, NaN and
/// infinities as `1e999` or `-1e999` (which ply-rs reads as infinite: a point with either is
/// non-finite, and is refused or dropped as such). Other text is left as it is, for the parser
/// to refuse.
fn respelled_line(line: &str) -> Cow<'_, str> {
    if !mendable(line.as_bytes()) {
        return Cow::Borrowed(line);
    }
    let mut out = String::with_capacity(line.len() + 8);
    let mut rest = line;
    while !rest.is_empty() {
        let token_at = rest
            .find(|c: char| !c.is_ascii_whitespace())
            .unwrap_or(rest.len());
        out.push_str(&rest[..token_at]);
        rest = &rest[token_at..];
        let gap_at = rest
            .find(|c: char| c.is_ascii_whitespace())
            .unwrap_or(rest.len());
        let token = &rest[..gap_at];
        match respelled(token.as_bytes()) {
            Some(number) => out.push_str(&number),
            None => out.push_str(token),
        }
        rest = &rest[gap_at..];
    }
    Cow::Owned(out)
}

/// Whether `line` holds what a respelling can mend: a letter other than an exponent's (`nan`,
/// `inf`), or a point without a digit on either side (`.5`, `5.`). Most lines have neither; two
/// passes over the bytes without early exits tell (about a fifth of the time ply-rs's grammar takes
/// on the same lines).
fn mendable(line: &[u8]) -> bool {
    let digit = |b: u8| b.wrapping_sub(b'0') < 10;
    let letter = |b: u8| {
        let lower = b | 0x20;
        (lower.wrapping_sub(b'a') < 26) & (lower != b'e')
    };
    let mut found = line.iter().fold(false, |found, &b| found | letter(b));
    for k in 1..line.len().saturating_sub(1) {
        found |= (line[k] == b'.') & !(digit(line[k - 1]) & digit(line[k + 1]));
    }
    found | (line.first() == Some(&b'.')) | (line.len() > 1 && line[line.len() - 1] == b'.')
}

/// Whether ply-rs's ascii grammar reads `token` as a number: `[+-]?D+(.D+)?([eE][+-]?D+)?`.
fn in_grammar(token: &[u8]) -> bool {
    fn digits(s: &[u8]) -> usize {
        s.iter().take_while(|b| b.is_ascii_digit()).count()
    }
    let mut s = token
        .strip_prefix(b"-")
        .or(token.strip_prefix(b"+"))
        .unwrap_or(token);
    let n = digits(s);
    if n == 0 {
        return false;
    }
    s = &s[n..];
    if let Some(fraction) = s.strip_prefix(b".") {
        let n = digits(fraction);
        if n == 0 {
            return false;
        }
        s = &fraction[n..];
    }
    if let Some(exponent) = s.strip_prefix(b"e").or(s.strip_prefix(b"E")) {
        let exponent = exponent
            .strip_prefix(b"-")
            .or(exponent.strip_prefix(b"+"))
            .unwrap_or(exponent);
        let n = digits(exponent);
        return n > 0 && n == exponent.len();
    }
    s.is_empty()
}

/// `token` spelled so that the grammar reads the value Rust's float parser reads from it (see
/// [`respelled_line`]); `None` when that parser refuses it too, or the grammar would still.
fn respelled(token: &[u8]) -> Option<String> {
    let text = std::str::from_utf8(token).ok()?;
    let value: f64 = text.parse().ok()?;
    if !value.is_finite() {
        let negative = value.is_sign_negative() || text.starts_with('-');
        return Some(if negative { "-1e999" } else { "1e999" }.into());
    }
    let (sign, unsigned) = match text.as_bytes()[0] {
        b'-' | b'+' => text.split_at(1),
        _ => ("", text),
    };
    let (mantissa, exponent) = match unsigned.find(['e', 'E']) {
        Some(k) => (&unsigned[..k], &unsigned[k..]),
        None => (unsigned, ""),
    };
    let (whole, fraction) = mantissa.split_once('.').unwrap_or((mantissa, ""));
    let whole = if whole.is_empty() { "0" } else { whole };
    let point = if fraction.is_empty() { "" } else { "." };
    let number = format!("{sign}{whole}{point}{fraction}{exponent}");
    in_grammar(number.as_bytes()).then_some(number)
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

/// The part of a ply-rs message before its debug details.
fn ply_rs_message(e: &std::io::Error) -> String {
    let text = e.to_string();
    text.split(['\t', '\n'])
        .next()
        .unwrap_or("")
        .trim()
        .to_string()
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
/// nothing after the last element; with the line of the first `vertex` row when the body is
/// ascii (a row a line).
fn read_elements<E: Row>(
    path: &Path,
    reader: impl BufRead,
) -> Result<(MeshData, Option<u64>), IoError> {
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
    // Lines read so far (ascii): the body's are counted by the rows, not by the reader.
    let mut lines = reader.line_ends;
    reader.lines = false;
    let mut points = Vec::new();
    let mut face_rows = Vec::new();
    let mut first_line = None;
    for (name, def) in &header.elements {
        let start = (reader.bytes, lines);
        let rows = if ascii {
            ascii_rows(path, &parser, &mut reader, def, &mut lines)?
        } else {
            parser
                .read_payload_for_element(&mut reader, def, &header)
                .map_err(|e| binary_error(path, &e, def, start.0, reader.bytes))?
        };
        match name.as_str() {
            "face" => face_rows = rows,
            "vertex" => {
                points = vertices(&rows).map_err(parse)?;
                first_line = ascii.then_some(start.1 + 1);
            }
            _ => {}
        }
    }
    (reader.lines, reader.line_ends) = (ascii, lines);
    refuse_trailing_data(path, &mut reader, &header, ascii)?;
    let triangles = triangles(&face_rows, points.len()).map_err(parse)?;
    Ok(((points, triangles), first_line))
}

/// ply-rs's header error, with the line it names.
fn header_error(path: &Path, e: &std::io::Error) -> IoError {
    let head = ply_rs_message(e);
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

/// The `count` rows of element `def` in an ascii body, a line each, read from the line after
/// `lines` (the lines read so far, advanced by those read here); each line's numbers are spelled
/// for ply-rs's grammar first ([`respelled_line`]).
fn ascii_rows<E: Row>(
    path: &Path,
    parser: &Parser<E>,
    reader: &mut impl BufRead,
    def: &ElementDef,
    lines: &mut u64,
) -> Result<Vec<E>, IoError> {
    let (name, declared) = (&def.name, def.count);
    // As ply-rs: a header's count does not size one allocation.
    let mut rows = Vec::with_capacity(declared.min(1 << 16));
    let mut line = String::new();
    for row in 0..declared {
        line.clear();
        let read = reader
            .read_line(&mut line)
            .map_err(|e| parse_error(path, Some(*lines + 1), format!("`{name}` row {row}: {e}")))?;
        if read == 0 {
            return Err(parse_error(
                path,
                Some(*lines + 1),
                format!(
                    "the file ends after {row} of the {declared} `{name}` rows the header declares"
                ),
            ));
        }
        *lines += 1;
        let element = parser
            .read_ascii_element(&respelled_line(&line), def)
            .map_err(|_| {
                parse_error(
                    path,
                    Some(*lines),
                    format!(
                        "`{name}` row {row}: expected {} numbers as the header declares, found {:?}",
                        def.properties.len(),
                        line.trim()
                    ),
                )
            })?;
        rows.push(element);
    }
    Ok(rows)
}

/// ply-rs's error inside the binary rows of element `def`, which started at byte `start`, when
/// the reader stopped at byte `at`: the byte, the row and the element's extent.
fn binary_error(path: &Path, e: &std::io::Error, def: &ElementDef, start: u64, at: u64) -> IoError {
    let head = ply_rs_message(e);
    let (name, declared) = (&def.name, def.count);
    let size = row_size(def);
    let row = size
        .map(|b| {
            let row = (at - start) / b;
            format!(" row {row} (0-based) of the {declared} declared")
        })
        .unwrap_or_default();
    let what = if head.contains("end of file") {
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
            "byte {at}: {what} inside `{name}`{row}; the element starts at byte {start}{extent}"
        ),
    )
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

/// The size of a scalar property in bytes.
fn scalar_size(t: &ScalarType) -> usize {
    match t {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

/// The PLY file `path` (its `bytes`, whose `vertex` element [`read`] found to hold `n` rows)
/// with each vertex moved by `mover` and its normal (`nx`, `ny`, `nz`) turned, in their own
/// types; every other property, element, header line and byte as they are. An ascii row is
/// written with its numbers one space apart. `Ok(Err(why))` when the layout cannot be
/// rewritten in place: a list property in `vertex`, an integer coordinate or normal, or (binary)
/// an element of lists before `vertex`.
pub(super) fn rewrite_moved(
    path: &Path,
    bytes: &[u8],
    n: usize,
    mover: &Mover,
) -> Result<Result<Vec<u8>, String>, IoError> {
    let mut reader = Counting {
        inner: bytes,
        bytes: 0,
        line_ends: 0,
        lines: true,
    };
    let header = Parser::<Xyz>::new()
        .read_header(&mut reader)
        .map_err(|e| header_error(path, &e))?;
    let (start, mut line) = (reader.bytes as usize, reader.line_ends);
    let Some(vertex) = header.elements.get("vertex") else {
        return Err(parse_error(
            path,
            None,
            "no `vertex` element in the header".into(),
        ));
    };
    // Each property's type, and the rewritten ones' places among them.
    let mut types = Vec::new();
    for p in vertex.properties.values() {
        match &p.data_type {
            PropertyType::Scalar(t) => types.push(t.clone()),
            PropertyType::List(..) => {
                return Ok(Err(format!(
                    "its `vertex` element has a list property ({})",
                    p.name
                )))
            }
        }
    }
    let place = |name: &str| vertex.properties.keys().position(|k| k == name);
    let xyz = [place("x"), place("y"), place("z")];
    let normal = [place("nx"), place("ny"), place("nz")];
    let normal = normal.iter().all(Option::is_some).then_some(normal);
    for k in xyz.iter().chain(normal.iter().flatten()).flatten() {
        if !matches!(types[*k], ScalarType::Float | ScalarType::Double) {
            return Ok(Err(format!(
                "its `vertex` property `{}` is an integer",
                vertex.properties.keys().nth(*k).map_or("", |s| s.as_str())
            )));
        }
    }
    let [Some(x), Some(y), Some(z)] = xyz else {
        return Err(parse_error(
            path,
            None,
            "the `vertex` element lacks x, y or z".into(),
        ));
    };
    let normal = normal.map(|[a, b, c]| [a.unwrap_or(0), b.unwrap_or(0), c.unwrap_or(0)]);
    let read: Vec<usize> = [x, y, z]
        .into_iter()
        .chain(normal.into_iter().flatten())
        .collect();
    let moved = |get: &dyn Fn(usize) -> f64| mover.record([x, y, z], normal, get);
    let mut out = bytes[..start].to_vec();
    let body = &bytes[start..];
    if header.encoding == Encoding::Ascii {
        let mut rows = body.split_inclusive(|&b| b == b'\n');
        for (name, def) in &header.elements {
            for row in 0..def.count {
                line += 1;
                let Some(raw) = rows.next() else {
                    return Err(parse_error(
                        path,
                        Some(line),
                        format!("the file ends inside `{name}` row {row}"),
                    ));
                };
                if name != "vertex" {
                    out.extend_from_slice(raw);
                    continue;
                }
                let text = std::str::from_utf8(raw).map_err(|_| {
                    parse_error(path, Some(line), format!("`vertex` row {row} is not text"))
                })?;
                let body = text.trim_end_matches(['\r', '\n']);
                let mut tokens: Vec<Cow<'_, str>> =
                    body.split_whitespace().map(Cow::Borrowed).collect();
                let value = |k: usize| {
                    tokens
                        .get(k)
                        .and_then(|t| t.parse::<f64>().ok())
                        .ok_or_else(|| {
                            parse_error(
                                path,
                                Some(line),
                                format!(
                                    "`vertex` row {row}: expected a number for `{}`, found {:?}",
                                    vertex.properties.keys().nth(k).map_or("", |s| s.as_str()),
                                    body
                                ),
                            )
                        })
                };
                let mut olds = vec![0.0; types.len()];
                for &k in &read {
                    olds[k] = value(k)?;
                }
                match moved(&|k| olds[k]) {
                    None => out.extend_from_slice(raw),
                    Some(new) => {
                        for (k, v) in new {
                            tokens[k] = Cow::Owned(spelled(v, types[k] == ScalarType::Float));
                        }
                        out.extend_from_slice(tokens.join(" ").as_bytes());
                        out.extend_from_slice(&raw[body.len()..]);
                    }
                }
            }
        }
        for rest in rows {
            out.extend_from_slice(rest);
        }
        return Ok(Ok(out));
    }
    let big = header.encoding == Encoding::BinaryBigEndian;
    let mut at = 0usize;
    for (name, def) in &header.elements {
        let Some(size) = row_size(def) else {
            if name == "vertex" {
                break;
            }
            return Ok(Err(format!(
                "its element `{name}`, before `vertex`, has lists"
            )));
        };
        if name != "vertex" {
            at += (size as usize).saturating_mul(def.count);
            continue;
        }
        let offsets: Vec<usize> = types
            .iter()
            .scan(0, |o, t| {
                let here = *o;
                *o += scalar_size(t);
                Some(here)
            })
            .collect();
        let rows = body.get(at..at + size as usize * n).ok_or_else(|| {
            parse_error(
                path,
                None,
                format!("the file ends inside its {n} `vertex` rows"),
            )
        })?;
        out.extend_from_slice(&body[..at]);
        for row in rows.chunks_exact(size as usize) {
            let get = |k: usize| {
                let b = &row[offsets[k]..];
                match (&types[k], big) {
                    (ScalarType::Float, false) => {
                        f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64
                    }
                    (ScalarType::Float, true) => {
                        f32::from_be_bytes([b[0], b[1], b[2], b[3]]) as f64
                    }
                    (_, false) => f64::from_le_bytes(b[..8].try_into().unwrap_or_default()),
                    (_, true) => f64::from_be_bytes(b[..8].try_into().unwrap_or_default()),
                }
            };
            let mut row = row.to_vec();
            for (k, v) in moved(&get).unwrap_or_default() {
                let o = offsets[k];
                match (&types[k], big) {
                    (ScalarType::Float, false) => {
                        row[o..o + 4].copy_from_slice(&(v as f32).to_le_bytes())
                    }
                    (ScalarType::Float, true) => {
                        row[o..o + 4].copy_from_slice(&(v as f32).to_be_bytes())
                    }
                    (_, false) => row[o..o + 8].copy_from_slice(&v.to_le_bytes()),
                    (_, true) => row[o..o + 8].copy_from_slice(&v.to_be_bytes()),
                }
            }
            out.extend_from_slice(&row);
        }
        out.extend_from_slice(&body[at + rows.len()..]);
        return Ok(Ok(out));
    }
    Ok(Err("its `vertex` rows could not be found".to_string()))
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
        let pts = read(Path::new("a.ply"), text.as_bytes(), false).unwrap();
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
            read(Path::new("b.ply"), &b[..], false).unwrap(),
            vec![Point3::new(-3.0, 7.0, 0.5)]
        );
    }

    #[test]
    fn explains_what_is_missing() {
        let text = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n";
        let err = read(Path::new("c.ply"), text.as_bytes(), false)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("c.ply") && err.contains("no `z` property"),
            "{err}"
        );
        let err = read(Path::new("d.ply"), &b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n"[..], false).unwrap_err().to_string();
        assert!(
            err.starts_with("d.ply:9: the file ends after 1 of the 3 `vertex` rows"),
            "{err}"
        );
        // CRLF line ends and a comment read the same.
        let crlf = "ply\r\nformat ascii 1.0\r\ncomment c\r\nelement vertex 2\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\nend_header\r\n1 2 3\r\n4 5 6\r\n";
        assert_eq!(
            read(Path::new("e.ply"), crlf.as_bytes(), false).unwrap(),
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(4.0, 5.0, 6.0)]
        );
    }

    /// An ascii header of `n` vertices with double `x y z` and float normals.
    fn with_normals(n: usize) -> String {
        format!("ply\nformat ascii 1.0\ncomment Created by Open3D\nelement vertex {n}\nproperty double x\nproperty double y\nproperty double z\nproperty float nx\nproperty float ny\nproperty float nz\nend_header\n")
    }

    #[test]
    fn reads_the_nan_and_inf_that_open3d_and_pcl_write_in_ascii() {
        // Open3D's ascii writer (through rply's printf) writes a missing return as `nan nan nan`
        // and PCL an undefined normal as `nan`; glibc spells a negative NaN `-nan`.
        let text = with_normals(4)
            + "0.511822 0.950464 0.14416 0 0 1\n"
            + "nan nan nan nan nan nan\n"
            + "1 -inf 2 0 1 0\n"
            + "0.25 0.5 -0.75 -nan NaN Infinity\n";
        let path = Path::new("o3d.ply");
        // 11 header lines: the second vertex row is line 13. A cloud's point and a mesh's
        // vertex are refused alike, by that line.
        for err in [
            read(path, text.as_bytes(), false).unwrap_err(),
            read_mesh(path, text.as_bytes()).unwrap_err(),
        ] {
            assert!(
                matches!(
                    err,
                    IoError::NonFinite {
                        line: Some(13),
                        index: 1,
                        ..
                    }
                ),
                "{err:?}"
            );
            assert_eq!(
                err.to_string(),
                "o3d.ply:13: point 1 has a non-finite coordinate"
            );
        }
        let points = read(path, text.as_bytes(), true).unwrap();
        assert_eq!(points.len(), 4);
        assert_eq!(points[0], Point3::new(0.511822, 0.950464, 0.14416));
        assert!(points[1].coords.iter().all(|v| v.is_infinite()));
        assert_eq!(
            (points[2].x, points[2].y, points[2].z),
            (1.0, f64::NEG_INFINITY, 2.0)
        );
        // Undefined normals beside finite coordinates: the point is read as written.
        assert_eq!(points[3], Point3::new(0.25, 0.5, -0.75));
    }

    #[test]
    fn reads_numbers_without_an_integer_part_or_a_fraction_as_a_float_parser_does() {
        let text = with_normals(2) + ".5 5. -.25e1 +5.e-1 1E2 -0.\n0.1 1e-3 +.0 0 0 0\n";
        let points = read(Path::new("forms.ply"), text.as_bytes(), false).unwrap();
        assert_eq!(
            points,
            vec![Point3::new(0.5, 5.0, -2.5), Point3::new(0.1, 1e-3, 0.0)]
        );
        for token in ["1", "-2.5", "+3e4", "7.25E-3", "0.0"] {
            assert!(in_grammar(token.as_bytes()), "{token}");
            assert_eq!(respelled(token.as_bytes()).as_deref(), Some(token));
        }
        for token in [
            ".5", "5.", "-.5e1", "nan", "inf", "x", "1.2.3", "e5", "1e", "--1", "",
        ] {
            assert!(!in_grammar(token.as_bytes()), "{token}");
        }
        for (token, spelled) in [
            (".5", "0.5"),
            ("5.", "5"),
            ("-.5e1", "-0.5e1"),
            ("+5.e-1", "+5e-1"),
        ] {
            assert_eq!(respelled(token.as_bytes()).as_deref(), Some(spelled));
        }
        for token in ["x", "1.2.3", "0x10", "1,5", "nan(0x1)"] {
            assert_eq!(respelled(token.as_bytes()), None, "{token}");
        }
    }

    #[test]
    fn a_row_still_unreadable_is_quoted_as_the_file_has_it() {
        let text = with_normals(2) + "1 2 3 0 0 1\n.5 nan x 0 0 1\n";
        let err = read(Path::new("bad.ply"), text.as_bytes(), true)
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with("bad.ply:13: `vertex` row 1: expected 6 numbers")
                && err.contains("found \".5 nan x 0 0 1\""),
            "{err}"
        );
        // An integer property holding NaN is no integer.
        let ints = "ply\nformat ascii 1.0\nelement vertex 1\nproperty int x\nproperty int y\nproperty int z\nend_header\n1 nan 3\n";
        let err = read(Path::new("int.ply"), ints.as_bytes(), true)
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with("int.ply:8: `vertex` row 0") && err.contains("found \"1 nan 3\""),
            "{err}"
        );
    }
}

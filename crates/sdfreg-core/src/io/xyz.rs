//! Text clouds: one point per line, `x y z [more columns]`, separated by whitespace or commas.
//! Empty lines and lines starting with `#` or `//` are skipped; a first line that is not
//! numeric is taken as a column header.
//!
//! Leica's `.pts` begins each scan's block of rows with a line holding its point count (`5`,
//! then five `x y z intensity r g b` rows; a file may hold several blocks): in a `.pts` file
//! such a line is read as that count and checked against the rows that follow it.

use std::path::Path;

use nalgebra::Point3;

use crate::base::error::IoError;
use crate::io::moved::{spelled, Mover};

/// Parses `x y z` lines; a non-finite coordinate is an error naming its line unless
/// `keep_non_finite`.
pub(super) fn read(
    path: &Path,
    bytes: &[u8],
    keep_non_finite: bool,
) -> Result<Vec<Point3<f64>>, IoError> {
    let text = std::str::from_utf8(bytes)
        .map_err(|e| IoError::parse(path, format!("not UTF-8 text (byte {})", e.valid_up_to())))?;
    let pts = is_pts(path);
    let mut points = Vec::new();
    let mut seen_data_line = false;
    // The open `.pts` block: its count line and count, and the points before it.
    let mut block: Option<Block> = None;
    for (i, raw) in text.lines().enumerate() {
        let fields = match classify(raw, pts, seen_data_line) {
            Kind::Skipped => continue,
            Kind::Count(count) => {
                close_block(path, block.take(), points.len())?;
                block = Some(Block {
                    line: i + 1,
                    count,
                    before: points.len(),
                });
                seen_data_line = true;
                continue;
            }
            Kind::Header => {
                seen_data_line = true;
                continue;
            }
            Kind::Row(fields) => fields,
        };
        seen_data_line = true;
        let Some(p) = coordinates(&fields) else {
            return Err(IoError::Parse {
                path: path.into(),
                line: Some(i + 1),
                message: format!("expected three numbers (x y z), found {:?}", raw.trim()),
            });
        };
        if !keep_non_finite && !p.coords.iter().all(|v| v.is_finite()) {
            return Err(IoError::NonFinite {
                path: path.into(),
                line: Some(i + 1),
                index: points.len(),
            });
        }
        points.push(p);
    }
    close_block(path, block, points.len())?;
    Ok(points)
}

/// What a line of a text cloud is ([`classify`]).
enum Kind<'a> {
    /// Empty, or a comment (`#`, `//`).
    Skipped,
    /// A `.pts` block's point count.
    Count(usize),
    /// A column header: the first line that is not skipped, when its first three fields are
    /// not numbers.
    Header,
    /// A point's row: its fields.
    Row(Vec<&'a str>),
}

/// What `raw` (a line without its end) is, in a `.pts` file (`pts`) or not, after a line that
/// was not skipped (`seen`) or not.
fn classify(raw: &str, pts: bool, seen: bool) -> Kind<'_> {
    let line = raw.trim();
    if line.is_empty() || line.starts_with('#') || line.starts_with("//") {
        return Kind::Skipped;
    }
    let fields: Vec<&str> = line
        .split(|c: char| c == ',' || c.is_whitespace())
        .filter(|f| !f.is_empty())
        .collect();
    if let (true, [count]) = (pts, fields.as_slice()) {
        if let Ok(count) = count.parse::<usize>() {
            return Kind::Count(count);
        }
    }
    if !seen && fields.iter().take(3).all(|f| f.parse::<f64>().is_err()) {
        return Kind::Header;
    }
    Kind::Row(fields)
}

/// The point of a row's `fields` (its first three), if they are three numbers.
fn coordinates(fields: &[&str]) -> Option<Point3<f64>> {
    let [x, y, z] = [0, 1, 2].map(|k| fields.get(k).and_then(|f| f.parse::<f64>().ok()));
    Some(Point3::new(x?, y?, z?))
}

/// The text cloud `path` (its `bytes`, which [`read`] accepted) with each row's first three
/// columns moved by `mover`; every other column, separator, comment, header and count line as
/// written (a text file does not say which columns are normals: they are not turned).
pub(super) fn rewrite_moved(path: &Path, bytes: &[u8], mover: &Mover) -> Result<Vec<u8>, IoError> {
    let text = std::str::from_utf8(bytes)
        .map_err(|e| IoError::parse(path, format!("not UTF-8 text (byte {})", e.valid_up_to())))?;
    let pts = is_pts(path);
    let mut out = String::with_capacity(text.len() + text.len() / 4);
    let mut seen = false;
    for (i, raw) in text.split_inclusive('\n').enumerate() {
        let line = raw.trim_end_matches(['\r', '\n']);
        let fields = match classify(line, pts, seen) {
            Kind::Skipped => {
                out.push_str(raw);
                continue;
            }
            Kind::Count(_) | Kind::Header => {
                seen = true;
                out.push_str(raw);
                continue;
            }
            Kind::Row(fields) => fields,
        };
        seen = true;
        let p = coordinates(&fields).ok_or_else(|| IoError::Parse {
            path: path.into(),
            line: Some(i + 1),
            message: format!("expected three numbers (x y z), found {:?}", line.trim()),
        })?;
        if mover.stays(&p) {
            out.push_str(raw);
            continue;
        }
        let q = mover.point(&p);
        // The three fields' places in the line (they are slices of it).
        let mut at = 0;
        for (f, v) in fields.iter().zip([q.x, q.y, q.z]) {
            let start = f.as_ptr() as usize - line.as_ptr() as usize;
            out.push_str(&line[at..start]);
            out.push_str(&spelled(v, false));
            at = start + f.len();
        }
        out.push_str(&raw[at..]);
    }
    Ok(out.into_bytes())
}

/// A `.pts` block: the line of its count, the count, and the points read before it.
struct Block {
    line: usize,
    count: usize,
    before: usize,
}

/// Checks that `block` (if any) holds the points its count line says, `read` points having been
/// read when it ends.
fn close_block(path: &Path, block: Option<Block>, read: usize) -> Result<(), IoError> {
    match block {
        Some(b) if read - b.before != b.count => Err(IoError::Parse {
            path: path.into(),
            line: Some(b.line),
            message: format!(
                "point count {}, but {} rows follow it",
                b.count,
                read - b.before
            ),
        }),
        _ => Ok(()),
    }
}

/// Whether `path` is a Leica `.pts` file (by its extension, in any case).
pub(super) fn is_pts(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("pts"))
}

/// `x y z` lines of `points`, after a line of their count when `count_line` (`.pts`).
pub(super) fn encode(points: &[Point3<f64>], count_line: bool) -> Vec<u8> {
    let mut s = String::with_capacity(points.len() * 48 + 24);
    if count_line {
        s.push_str(&format!("{}\n", points.len()));
    }
    for p in points {
        // `{}` prints the shortest representation that reads back exactly.
        s.push_str(&format!("{} {} {}\n", p.x, p.y, p.z));
    }
    s.into_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read_strict(path: &Path, bytes: &[u8]) -> Result<Vec<Point3<f64>>, IoError> {
        read(path, bytes, false)
    }

    #[test]
    fn reads_separators_headers_comments_and_extra_columns() {
        let text = "x,y,z,intensity\n# comment\n1,2,3,9\n\n4 5\t6 7 8\r\n";
        let pts = read_strict(Path::new("t.csv"), text.as_bytes()).unwrap();
        assert_eq!(
            pts,
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(4.0, 5.0, 6.0)]
        );
    }

    #[test]
    fn reads_leicas_pts_with_a_count_line_before_each_block() {
        let text = "2\n1 2 3 -1200 255 0 0\n4 5 6 -1100 0 255 0\n1\n7 8 9 -900 0 0 255\n";
        let pts = read_strict(Path::new("scan.PTS"), text.as_bytes()).unwrap();
        assert_eq!(
            pts,
            vec![
                Point3::new(1.0, 2.0, 3.0),
                Point3::new(4.0, 5.0, 6.0),
                Point3::new(7.0, 8.0, 9.0)
            ]
        );
        // A block cut short, or longer than its count, names its count line.
        for (name, text, says) in [
            (
                "cut.pts",
                "3\n1 2 3\n4 5 6\n",
                "cut.pts:1: point count 3, but 2 rows follow it",
            ),
            (
                "two.pts",
                "1\n1 2 3\n1\n4 5 6\n7 8 9\n",
                "two.pts:3: point count 1, but 2 rows follow it",
            ),
        ] {
            let err = read_strict(Path::new(name), text.as_bytes()).unwrap_err();
            assert_eq!(err.to_string(), says);
        }
        // Written with its count line, read back to the bit.
        let written = encode(&pts, true);
        assert!(written.starts_with(b"3\n"));
        assert_eq!(read_strict(Path::new("w.pts"), &written).unwrap(), pts);
        // Elsewhere a lone number is a malformed row, as before.
        let err = read_strict(Path::new("a.xyz"), b"2\n1 2 3\n4 5 6\n").unwrap_err();
        assert!(matches!(err, IoError::Parse { line: Some(1), .. }), "{err}");
    }

    #[test]
    fn names_the_line_of_bad_data() {
        let err = read_strict(Path::new("t.xyz"), b"1 2 3\n4 5\n").unwrap_err();
        assert!(matches!(err, IoError::Parse { line: Some(2), .. }), "{err}");
        assert_eq!(
            err.to_string(),
            "t.xyz:2: expected three numbers (x y z), found \"4 5\""
        );
        let err = read_strict(Path::new("t.xyz"), b"1 2 3\n4 nan 6\n").unwrap_err();
        assert!(
            matches!(
                err,
                IoError::NonFinite {
                    line: Some(2),
                    index: 1,
                    ..
                }
            ),
            "{err}"
        );
    }
}

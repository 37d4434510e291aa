//! Text clouds: one point per line, `x y z [more columns]`, separated by whitespace or commas.
//! Empty lines and lines starting with `#` or `//` are skipped; a first line that is not
//! numeric is taken as a column header.

use std::path::Path;

use nalgebra::Point3;

use crate::base::error::IoError;

/// Parses `x y z` lines; a non-finite coordinate is an error naming its line unless
/// `keep_non_finite`.
pub(super) fn read(
    path: &Path,
    bytes: &[u8],
    keep_non_finite: bool,
) -> Result<Vec<Point3<f64>>, IoError> {
    let text = std::str::from_utf8(bytes).map_err(|e| IoError::Parse {
        path: path.into(),
        line: None,
        message: format!("not UTF-8 text (byte {})", e.valid_up_to()),
    })?;
    let mut points = Vec::new();
    let mut seen_data_line = false;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with("//") {
            continue;
        }
        let fields: Vec<&str> = line
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|f| !f.is_empty())
            .collect();
        let parsed: Vec<Option<f64>> = fields
            .iter()
            .take(3)
            .map(|f| f.parse::<f64>().ok())
            .collect();
        if !seen_data_line && parsed.iter().all(|v| v.is_none()) {
            seen_data_line = true; // a header
            continue;
        }
        seen_data_line = true;
        if parsed.len() < 3 || parsed.iter().any(|v| v.is_none()) {
            return Err(IoError::Parse {
                path: path.into(),
                line: Some(i + 1),
                message: format!("expected three numbers (x y z), found {line:?}"),
            });
        }
        let p = Point3::new(parsed[0].unwrap(), parsed[1].unwrap(), parsed[2].unwrap());
        if !keep_non_finite && !p.coords.iter().all(|v| v.is_finite()) {
            return Err(IoError::NonFinite {
                path: path.into(),
                line: Some(i + 1),
                index: points.len(),
            });
        }
        points.push(p);
    }
    Ok(points)
}

pub(super) fn encode(points: &[Point3<f64>]) -> Vec<u8> {
    let mut s = String::with_capacity(points.len() * 48);
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

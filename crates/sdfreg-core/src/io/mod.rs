//! Reading and writing point clouds: PLY (ascii and binary, via ply-rs) and XYZ/TXT/CSV text.
//!
//! Entry points: [`read_point_cloud`] and [`write_point_cloud`], which choose the format from
//! the file's extension (case-insensitive).

mod ply;
mod xyz;

use std::path::Path;

use nalgebra::Point3;

pub use crate::error::IoError;

/// File formats known by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Stanford PLY: the `vertex` element's `x`, `y`, `z` (any numeric type).
    Ply,
    /// Text, one point per line, first three columns separated by spaces, tabs or commas.
    Xyz,
}

impl Format {
    /// The format of `path` by its extension.
    pub fn of(path: &Path) -> Result<Self, IoError> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        match ext.as_str() {
            "ply" => Ok(Format::Ply),
            "xyz" | "txt" | "csv" | "pts" => Ok(Format::Xyz),
            _ => Err(IoError::UnknownFormat {
                path: path.to_path_buf(),
                extension: ext,
            }),
        }
    }
}

/// Reads the points of a cloud file. Refuses empty clouds and non-finite coordinates.
pub fn read_point_cloud(path: impl AsRef<Path>) -> Result<Vec<Point3<f64>>, IoError> {
    let path = path.as_ref();
    let format = Format::of(path)?;
    let io_error = |source| IoError::Io {
        path: path.to_path_buf(),
        source,
    };
    let points = match format {
        // Streamed: a large binary PLY is never held in memory twice.
        Format::Ply => {
            let file = std::fs::File::open(path).map_err(io_error)?;
            ply::read(path, std::io::BufReader::with_capacity(1 << 20, file))?
        }
        Format::Xyz => xyz::read(path, &std::fs::read(path).map_err(io_error)?)?,
    };
    if points.is_empty() {
        return Err(IoError::Empty {
            path: path.to_path_buf(),
        });
    }
    if let Some(index) = points
        .iter()
        .position(|p| !p.coords.iter().all(|v| v.is_finite()))
    {
        return Err(IoError::NonFinite {
            path: path.to_path_buf(),
            line: None,
            index,
        });
    }
    Ok(points)
}

/// Writes points to `path` (PLY: binary little-endian doubles; text: `x y z` lines with full
/// precision). Overwrites an existing file: callers decide whether that is wanted.
pub fn write_point_cloud(path: impl AsRef<Path>, points: &[Point3<f64>]) -> Result<(), IoError> {
    let path = path.as_ref();
    let bytes = match Format::of(path)? {
        Format::Ply => ply::encode(points),
        Format::Xyz => xyz::encode(points),
    };
    std::fs::write(path, bytes).map_err(|source| IoError::Io {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_through_every_format() {
        let dir = std::env::temp_dir().join(format!("sdfreg-io-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let pts = vec![
            Point3::new(1.0, -2.5, 3.25),
            Point3::new(1e6 + 0.125, 2e-7, -4.0),
        ];
        for name in ["a.ply", "a.xyz", "a.TXT", "a.csv"] {
            let p = dir.join(name);
            write_point_cloud(&p, &pts).unwrap();
            assert_eq!(read_point_cloud(&p).unwrap(), pts, "{name}");
        }
        assert!(matches!(
            read_point_cloud(dir.join("a.obj")),
            Err(IoError::UnknownFormat { .. })
        ));
        assert!(matches!(
            read_point_cloud(dir.join("missing.ply")),
            Err(IoError::Io { .. })
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

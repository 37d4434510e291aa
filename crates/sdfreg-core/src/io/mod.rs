//! Reading and writing point clouds: PLY (ascii and binary, via ply-rs), PCD (ascii, binary and
//! binary_compressed, via pcd-rs), LAS and LAZ (via las-rs and its LASzip decoder), E57 (via
//! the e57 crate) and XYZ/TXT/CSV/PTS text.
//!
//! Entry points: [`read_point_cloud`] and [`write_point_cloud`], which choose the format from
//! the file's extension (case-insensitive).

mod bytes;
mod e57;
mod finite;
mod las;
mod moved;
mod pcd;
mod ply;
mod xyz;

pub use e57::{E57Scan, E57ScanRef};
pub use moved::{Fields, MovedCloud};
pub use ply::MeshData;

use std::path::Path;

use nalgebra::{Point3, Similarity3};

pub use crate::base::error::IoError;
use finite::{drop_non_finite, refuse_non_finite};
use moved::Mover;

/// File formats known by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Stanford PLY: the `vertex` element's `x`, `y`, `z` (any numeric type).
    Ply,
    /// Point Cloud Library PCD: the `x`, `y`, `z` fields (any type).
    Pcd,
    /// ASPRS LAS (`.las`) and LASzip-compressed LAS (`.laz`): each point's scaled `x`, `y`,
    /// `z`. Written compressed when the path ends in `.laz`. LAZ is decoded and compressed
    /// on the current rayon pool's threads when its chunk table allows.
    Las,
    /// ASTM E57 (`.e57`), as terrestrial laser scanners export: every scan's points placed by
    /// its pose in the file's frame, spherical scans converted, points without coordinates
    /// skipped.
    E57,
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
            "pcd" => Ok(Format::Pcd),
            "las" | "laz" => Ok(Format::Las),
            "e57" => Ok(Format::E57),
            "xyz" | "txt" | "csv" | "pts" => Ok(Format::Xyz),
            _ => Err(IoError::UnknownFormat {
                path: path.to_path_buf(),
                extension: ext,
            }),
        }
    }
}

/// Reads the points of a cloud file. Refuses empty clouds and non-finite coordinates (see
/// [`read_point_cloud_dropping_non_finite`] for scans that mark missing returns with NaN).
pub fn read_point_cloud(path: impl AsRef<Path>) -> Result<Vec<Point3<f64>>, IoError> {
    let path = path.as_ref();
    let points = read_any(path, false)?;
    refuse_non_finite(path, &points, None)?;
    Ok(points)
}

/// Reads the points of a cloud file without those with a NaN or infinite coordinate (organised
/// PCL clouds and range scanners write NaN for missing returns); returns the points and how many
/// were dropped. Refuses a cloud with no finite point.
pub fn read_point_cloud_dropping_non_finite(
    path: impl AsRef<Path>,
) -> Result<(Vec<Point3<f64>>, usize), IoError> {
    let path = path.as_ref();
    let mut points = read_any(path, true)?;
    let dropped = drop_non_finite(&mut points);
    if points.is_empty() {
        return Err(IoError::NonFinite {
            path: path.to_path_buf(),
            line: None,
            index: 0,
        });
    }
    Ok((points, dropped))
}

/// Reads each scan of an E57 file apart: its name, its pose (into the file's frame) and its
/// points in its own frame ([`read_point_cloud`] gives them all in the file's frame instead).
/// A point with a NaN or infinite coordinate is refused, naming its scan, or with
/// `drop_non_finite_points` dropped and counted (the second value). Refuses a file with no point in
/// any scan.
pub fn read_e57_scans(
    path: impl AsRef<Path>,
    drop_non_finite_points: bool,
) -> Result<(Vec<E57Scan>, usize), IoError> {
    let path = path.as_ref();
    let (file, _) = open(path)?;
    let reader = std::io::BufReader::with_capacity(e57::PAGE_BYTES, file);
    let mut scans = e57::read_scans(path, reader)?;
    let mut dropped = 0;
    for (k, scan) in scans.iter_mut().enumerate() {
        if drop_non_finite_points {
            dropped += drop_non_finite(&mut scan.points);
        } else if let Err(IoError::NonFinite { index, .. }) =
            refuse_non_finite(path, &scan.points, None)
        {
            let message = format!("scan {k}: point {index} has a non-finite coordinate");
            return Err(IoError::parse(path, message));
        }
    }
    if scans.iter().all(|s| s.points.is_empty()) {
        return Err(IoError::Empty {
            path: path.to_path_buf(),
        });
    }
    Ok((scans, dropped))
}

/// Reads a PLY file's vertices and triangles (polygons split into fans; none for a point
/// cloud). Refuses other formats and non-finite vertices (naming the vertex and, in an ascii
/// file, its line).
pub fn read_mesh(path: impl AsRef<Path>) -> Result<MeshData, IoError> {
    let path = path.as_ref();
    if Format::of(path)? != Format::Ply {
        let message = "meshes are read from PLY files (a `face` element)";
        return Err(IoError::parse(path, message));
    }
    let (file, _) = open(path)?;
    ply::read_mesh(path, std::io::BufReader::with_capacity(1 << 20, file))
}

/// Reads a PLY mesh and samples `n` points uniformly by area on its faces (seeded) instead of
/// using its vertices — for targets given as CAD or reconstructed meshes, whose vertices are far
/// from uniform. Refuses files without faces or whose faces have no area.
pub fn read_mesh_surface(
    path: impl AsRef<Path>,
    n: usize,
    seed: u64,
) -> Result<Vec<Point3<f64>>, IoError> {
    use rand::SeedableRng;
    let path = path.as_ref();
    let parse = |message: &str| IoError::parse(path, message);
    let (vertices, triangles) = read_mesh(path)?;
    if triangles.is_empty() {
        return Err(parse("no faces to sample (a point cloud, not a mesh)"));
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    crate::geometry::mesh::sample_surface(&vertices, &triangles, n.max(1), &mut rng)
        .ok_or_else(|| parse("the faces have no area"))
}

/// Parses a cloud held in memory, in `format`; `name` stands for the file in error messages.
/// Same checks as [`read_point_cloud`] (no empty clouds, no non-finite coordinates).
pub fn parse_point_cloud(
    bytes: &[u8],
    format: Format,
    name: &Path,
) -> Result<Vec<Point3<f64>>, IoError> {
    let stream = std::io::Cursor::new(bytes.to_vec());
    let points = parse(format, name, stream, bytes.len() as u64, false)?;
    refuse_non_finite(name, &points, None)?;
    Ok(points)
}

/// Reads every point of a cloud file; refuses an empty one. Text files refuse a non-finite
/// coordinate with its line number unless `keep_non_finite`.
fn read_any(path: &Path, keep_non_finite: bool) -> Result<Vec<Point3<f64>>, IoError> {
    let format = Format::of(path)?;
    let (file, available) = open(path)?;
    // Streamed: a large binary file is never held in memory twice. The E57 reader seeks to
    // each page it reads, which empties a buffer: it reads them through one of a page.
    let capacity = if format == Format::E57 {
        e57::PAGE_BYTES
    } else {
        1 << 20
    };
    let reader = std::io::BufReader::with_capacity(capacity, file);
    parse(format, path, reader, available, keep_non_finite)
}

/// Opens a cloud or mesh file; refuses a directory and an empty file. Returns it and its length
/// (`u64::MAX` when the system does not say).
fn open(path: &Path) -> Result<(std::fs::File, u64), IoError> {
    let file = std::fs::File::open(path).map_err(|source| IoError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let meta = file.metadata().ok();
    if meta.as_ref().is_some_and(|m| m.is_dir()) {
        return Err(IoError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(
                std::io::ErrorKind::IsADirectory,
                "a directory, not a file",
            ),
        });
    }
    let available = meta.map_or(u64::MAX, |m| m.len());
    if available == 0 {
        return Err(IoError::Empty {
            path: path.to_path_buf(),
        });
    }
    Ok((file, available))
}

fn parse(
    format: Format,
    path: &Path,
    mut reader: impl std::io::BufRead + std::io::Seek + Send + Sync + 'static,
    available: u64,
    keep_non_finite: bool,
) -> Result<Vec<Point3<f64>>, IoError> {
    let points = match format {
        Format::Ply => ply::read(path, reader, keep_non_finite)?,
        Format::Pcd => pcd::read(path, reader, available)?,
        Format::Las => las::read(path, reader)?,
        Format::E57 => e57::read(path, reader)?,
        Format::Xyz => {
            let mut bytes = Vec::new();
            reader
                .read_to_end(&mut bytes)
                .map_err(|source| IoError::Io {
                    path: path.to_path_buf(),
                    source,
                })?;
            xyz::read(path, &bytes, keep_non_finite)?
        }
    };
    if points.is_empty() {
        return Err(IoError::Empty {
            path: path.to_path_buf(),
        });
    }
    Ok(points)
}

/// Writes points to `path` (PLY and PCD: binary little-endian doubles; text: `x y z` lines with
/// full precision, after a point-count line in `.pts`; LAS: 32-bit integers at a scale of
/// 10⁻⁹–10⁻⁸ of the cloud's extent, LASzip-compressed in `.laz`; E57: one scan of doubles).
/// Overwrites an existing file: callers decide whether that is wanted.
pub fn write_point_cloud(path: impl AsRef<Path>, points: &[Point3<f64>]) -> Result<(), IoError> {
    let path = path.as_ref();
    let bytes = match Format::of(path)? {
        Format::Ply => ply::encode(points),
        Format::Pcd => pcd::encode(points),
        Format::Las => las::encode(path, points)?,
        Format::E57 => e57::encode(path, points)?,
        Format::Xyz => xyz::encode(points, xyz::is_pts(path)),
    };
    std::fs::write(path, bytes).map_err(|source| IoError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes the points of the cloud file `input` moved by `transform` (input coordinates into
/// output ones: a registration's `[s R | t]`, source into target) to `output`.
///
/// When `output` has `input`'s format, the input's records are rewritten in place: the
/// coordinates moved in their own type, the normals turned, every other field and element as
/// the input holds it. PLY (ascii and binary: `x`, `y`, `z`, and `nx`, `ny`, `nz`), PCD (ascii
/// and binary: `x`, `y`, `z`, `normal_x`, `normal_y`, `normal_z`, and the `VIEWPOINT`), LAS and
/// LAZ (each record's other bytes, the header's records; each axis's scale unless the moved
/// extent needs a coarser one) and text (the first three columns; the others as written).
/// Otherwise, or when the layout does not allow it (a PCD's `binary_compressed` body, list or
/// integer coordinates in a PLY, an E57 file), the moved coordinates alone, as
/// [`write_point_cloud`] writes them, and [`MovedCloud::fields`] says why.
///
/// Missing returns at exactly (0, 0, 0) (when there are at least two, as
/// [`crate::geometry::cloud::missing_returns`] counts them) and points with a NaN or infinite
/// coordinate stay as they are, so an organised cloud keeps its marks. `input` is read in full
/// (and checked as [`read_point_cloud`] checks it) before `output` is written, so they may be
/// the same file. Overwrites an existing `output`: callers decide whether that is wanted.
pub fn write_moved_point_cloud(
    input: impl AsRef<Path>,
    output: impl AsRef<Path>,
    transform: &Similarity3<f64>,
) -> Result<MovedCloud, IoError> {
    let (input, output) = (input.as_ref(), output.as_ref());
    let (from, to) = (Format::of(input)?, Format::of(output)?);
    let (bytes, moved) = if (from, to) == (Format::Las, Format::Las) {
        // Decoded once: the records kept as they are read, then rewritten.
        las::rewrite_moved(input, output, transform)?
    } else {
        let points = read_any(input, true)?;
        let mover = Mover::new(transform, &points);
        let left_in_place = points.iter().filter(|p| mover.stays(p)).count();
        let read = || {
            std::fs::read(input).map_err(|source| IoError::Io {
                path: input.to_path_buf(),
                source,
            })
        };
        let n = points.len();
        let rewritten = match (from == to).then_some(from) {
            None => Err(format!(
                "{} holds coordinates only: its format is not that of {}",
                output.display(),
                input.display()
            )),
            Some(Format::Ply) => ply::rewrite_moved(input, &read()?, n, &mover)?,
            Some(Format::Pcd) => pcd::rewrite_moved(input, &read()?, n, &mover)?,
            Some(Format::Xyz) => Ok(xyz::rewrite_moved(input, &read()?, &mover)?),
            // E57 (LAS is rewritten above).
            Some(_) => Err("E57 scans are written with their coordinates only".to_string()),
        };
        let bytes = match rewritten {
            Ok(bytes) => bytes,
            Err(reason) => {
                let moved: Vec<Point3<f64>> = points.iter().map(|p| mover.point(p)).collect();
                write_point_cloud(output, &moved)?;
                return Ok(MovedCloud {
                    points: n,
                    left_in_place,
                    fields: Fields::CoordinatesOnly(reason),
                });
            }
        };
        let moved = MovedCloud {
            points: n,
            left_in_place,
            fields: Fields::Kept,
        };
        (bytes, moved)
    };
    std::fs::write(output, bytes).map_err(|source| IoError::Io {
        path: output.to_path_buf(),
        source,
    })?;
    Ok(moved)
}

/// Writes scans as the scans of one E57 file, each with its name, its pose (into the file's
/// frame) and its points in its own frame as 64-bit floats: what [`read_e57_scans`] reads back,
/// to the bit. Overwrites an existing file: callers decide whether that is wanted.
pub fn write_e57_scans(path: impl AsRef<Path>, scans: &[E57ScanRef<'_>]) -> Result<(), IoError> {
    let path = path.as_ref();
    let bytes = e57::encode_scans(path, scans)?;
    std::fs::write(path, bytes).map_err(|source| IoError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes a triangle mesh as a binary little-endian PLY (`vertex` doubles, `face` lists of
/// three `uint` indices; `.ply` only). Overwrites an existing file: callers decide whether that
/// is wanted.
pub fn write_mesh(
    path: impl AsRef<Path>,
    vertices: &[Point3<f64>],
    triangles: &[[usize; 3]],
) -> Result<(), IoError> {
    let path = path.as_ref();
    if !matches!(Format::of(path), Ok(Format::Ply)) {
        return Err(IoError::MeshFormat {
            path: path.to_path_buf(),
        });
    }
    std::fs::write(path, ply::encode_mesh(vertices, triangles)).map_err(|source| IoError::Io {
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
        for name in ["a.ply", "a.pcd", "a.xyz", "a.TXT", "a.csv"] {
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

    #[test]
    fn a_mesh_is_sampled_on_its_faces() {
        let dir = std::env::temp_dir().join(format!("sdfreg-mesh-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // The cube [−1, 1]³ with quad faces.
        let mut text = String::from("ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\nelement face 6\nproperty list uchar int vertex_indices\nend_header\n");
        for i in 0..8 {
            let c = |b: usize| if i >> b & 1 == 1 { 1 } else { -1 };
            text += &format!("{} {} {}\n", c(0), c(1), c(2));
        }
        text += "4 0 1 3 2\n4 4 5 7 6\n4 0 1 5 4\n4 2 3 7 6\n4 0 2 6 4\n4 1 3 7 5\n";
        let p = dir.join("cube.ply");
        std::fs::write(&p, &text).unwrap();
        let pts = read_mesh_surface(&p, 6000, 3).unwrap();
        assert_eq!(pts.len(), 6000);
        for axis in 0..3 {
            let on = pts
                .iter()
                .filter(|q| (q[axis].abs() - 1.0).abs() < 1e-12)
                .count();
            assert!(
                (on as f64 / 6000.0 - 1.0 / 3.0).abs() < 0.03,
                "axis {axis}: {on}"
            );
        }
        assert!(pts.iter().all(|q| q.coords.amax() <= 1.0 + 1e-12));
        // A cloud has no faces; a face may not point past the vertices.
        write_point_cloud(dir.join("cloud.ply"), &pts[..10]).unwrap();
        let err = read_mesh_surface(dir.join("cloud.ply"), 10, 0).unwrap_err();
        assert!(err.to_string().contains("no faces to sample"), "{err}");
        std::fs::write(&p, text.replace("4 1 3 7 5", "4 1 3 7 9")).unwrap();
        let err = read_mesh_surface(&p, 10, 0).unwrap_err();
        assert!(
            err.to_string()
                .contains("face 5: vertex index 9 is out of range"),
            "{err}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn non_finite_points_are_refused_or_dropped_on_request() {
        let dir = std::env::temp_dir().join(format!("sdfreg-nan-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("n.xyz");
        std::fs::write(&p, "1 2 3\nnan 0 0\n4 5 6\n0 inf 0\n").unwrap();
        assert!(matches!(
            read_point_cloud(&p),
            Err(IoError::NonFinite {
                index: 1,
                line: Some(2),
                ..
            })
        ));
        let (pts, dropped) = read_point_cloud_dropping_non_finite(&p).unwrap();
        assert_eq!(dropped, 2);
        assert_eq!(
            pts,
            vec![Point3::new(1.0, 2.0, 3.0), Point3::new(4.0, 5.0, 6.0)]
        );
        std::fs::write(&p, "nan 0 0\n").unwrap();
        assert!(read_point_cloud_dropping_non_finite(&p).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

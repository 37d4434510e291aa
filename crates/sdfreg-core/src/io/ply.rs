//! PLY via ply-rs: ascii and binary (both endiannesses), any numeric property type; the
//! `vertex` element's `x`, `y`, `z` are read and every other property or element is ignored.

use std::io::BufRead;
use std::path::Path;

use nalgebra::Point3;
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{Property, PropertyAccess};

use crate::error::IoError;

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

/// Vertices and triangles (polygons split into fans) of a PLY stream; `path` names it in errors.
pub(super) fn read_mesh(path: &Path, reader: impl BufRead) -> Result<super::MeshData, IoError> {
    read_elements::<MeshRow>(path, reader)
}

/// Reads the `vertex` element's `x`, `y`, `z` from a PLY stream; `path` names it in errors.
/// Every element is parsed (a truncated file is an error even after its vertices), but only the
/// coordinates are kept.
pub(super) fn read(path: &Path, reader: impl BufRead) -> Result<Vec<Point3<f64>>, IoError> {
    Ok(read_elements::<Xyz>(path, reader)?.0)
}

fn read_elements<E: Row>(
    path: &Path,
    mut reader: impl BufRead,
) -> Result<super::MeshData, IoError> {
    let parse = |message: String| IoError::Parse {
        path: path.into(),
        line: None,
        message,
    };
    let parser = Parser::<E>::new();
    let header = parser
        .read_header(&mut reader)
        .map_err(|e| parse(format!("not a valid PLY file: {e}")))?;
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
        let rows = parser
            .read_payload_for_element(&mut reader, def, &header)
            .map_err(|e| parse(format!("not a valid PLY file: element `{name}`: {e}")))?;
        if name == "face" {
            face_rows = rows;
            continue;
        }
        if name != "vertex" {
            continue;
        }
        points.reserve_exact(rows.len());
        for (i, row) in rows.iter().enumerate() {
            let (xyz, seen) = row.xyz();
            if seen != 0b111 {
                let k = (0..3).find(|k| seen & (1 << k) == 0).unwrap_or(0);
                return Err(parse(format!(
                    "vertex {i}: `{}` is missing or not a number",
                    ["x", "y", "z"][k]
                )));
            }
            points.push(Point3::from(xyz));
        }
    }
    let mut triangles = Vec::new();
    for (i, face) in face_rows.iter().enumerate() {
        let n = points.len() as i64;
        let v = face.indices();
        if v.is_empty() {
            continue; // a cloud's faces are not asked for
        }
        if let Some(&bad) = v.iter().find(|&&k| k < 0 || k >= n) {
            return Err(parse(format!(
                "face {i}: vertex index {bad} is out of range (the file has {n} vertices)"
            )));
        }
        if v.len() < 3 {
            return Err(parse(format!(
                "face {i}: {} vertex indices, a face needs at least 3",
                v.len()
            )));
        }
        for k in 1..v.len() - 1 {
            triangles.push([v[0] as usize, v[k] as usize, v[k + 1] as usize]);
        }
    }
    Ok((points, triangles))
}

pub(super) fn encode(points: &[Point3<f64>]) -> Vec<u8> {
    let header = format!("ply\nformat binary_little_endian 1.0\ncomment written by sdfreg\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nend_header\n", points.len());
    super::with_le_doubles(header, points)
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
        assert!(err.starts_with("d.ply: not a valid PLY file"), "{err}");
    }
}

//! PLY via ply-rs: ascii and binary (both endiannesses), any numeric property type; the
//! `vertex` element's `x`, `y`, `z` are read and every other property or element is ignored.

use std::path::Path;

use nalgebra::Point3;
use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Property};

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

pub(super) fn read(path: &Path, bytes: &[u8]) -> Result<Vec<Point3<f64>>, IoError> {
    let parse = |message: String| IoError::Parse {
        path: path.into(),
        line: None,
        message,
    };
    let parser = Parser::<DefaultElement>::new();
    let ply = parser
        .read_ply(&mut &bytes[..])
        .map_err(|e| parse(format!("not a valid PLY file: {e}")))?;
    let vertex = ply
        .header
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
    let rows = ply.payload.get("vertex").map(Vec::as_slice).unwrap_or(&[]);
    let mut points = Vec::with_capacity(rows.len());
    for (i, row) in rows.iter().enumerate() {
        let get = |k: &str| {
            row.get(k)
                .and_then(number)
                .ok_or_else(|| parse(format!("vertex {i}: `{k}` is missing or not a number")))
        };
        points.push(Point3::new(get("x")?, get("y")?, get("z")?));
    }
    Ok(points)
}

pub(super) fn encode(points: &[Point3<f64>]) -> Vec<u8> {
    let header = format!("ply\nformat binary_little_endian 1.0\ncomment written by sdfreg\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nend_header\n", points.len());
    let mut out = header.into_bytes();
    out.reserve(points.len() * 24);
    for p in points {
        for v in [p.x, p.y, p.z] {
            out.extend_from_slice(&v.to_le_bytes());
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
            read(Path::new("b.ply"), &b).unwrap(),
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
        let err = read(Path::new("d.ply"), b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n").unwrap_err().to_string();
        assert!(err.starts_with("d.ply: not a valid PLY file"), "{err}");
    }
}

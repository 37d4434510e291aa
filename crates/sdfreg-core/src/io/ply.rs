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

/// One element as the parser fills it: only `x`, `y`, `z` are kept (32 bytes per element, so
/// a 5-million-point file costs 160 MB while parsing, not a map per vertex).
struct Xyz {
    xyz: [f64; 3],
    /// Bit k set once coordinate k was read as a number.
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
        let k = match name {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ => return,
        };
        if let Some(v) = number(&property) {
            self.xyz[k] = v;
            self.seen |= 1 << k;
        }
    }
}

/// Reads the `vertex` element's `x`, `y`, `z` from a PLY stream; `path` names it in errors.
/// Every element is parsed (a truncated file is an error even after its vertices), but only the
/// coordinates are kept.
pub(super) fn read(path: &Path, mut reader: impl BufRead) -> Result<Vec<Point3<f64>>, IoError> {
    let parse = |message: String| IoError::Parse {
        path: path.into(),
        line: None,
        message,
    };
    let parser = Parser::<Xyz>::new();
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
    for (name, def) in &header.elements {
        let rows = parser
            .read_payload_for_element(&mut reader, def, &header)
            .map_err(|e| parse(format!("not a valid PLY file: element `{name}`: {e}")))?;
        if name != "vertex" {
            continue;
        }
        points.reserve_exact(rows.len());
        for (i, row) in rows.iter().enumerate() {
            if row.seen != 0b111 {
                let k = (0..3).find(|k| row.seen & (1 << k) == 0).unwrap_or(0);
                return Err(parse(format!(
                    "vertex {i}: `{}` is missing or not a number",
                    ["x", "y", "z"][k]
                )));
            }
            points.push(Point3::from(row.xyz));
        }
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

//! E57 (ASTM E2807, the exchange format of terrestrial and handheld laser scanners: FARO,
//! Leica, Trimble, RIEGL and the software around them) via the `e57` crate.
//!
//! Read: every scan (`data3D` entry) of the file, each placed in the file's frame by its pose
//! (the rotation quaternion, normalised, then the translation, in metres), as one cloud.
//! Spherical scans are converted to Cartesian points. Points the file marks as having no
//! coordinates (a missing return, a direction without a range) are not points and are skipped.
//! Colour, intensity, row and column are skipped. Every 1,020-byte page is checked against its
//! CRC-32C before it is used, so a damaged file is refused rather than read to wrong points.
//!
//! Written: a cloud as one scan with the identity pose, or scans each with its name and pose;
//! points as 64-bit float `x`, `y`, `z`, read back to the bit.

use std::io::{Cursor, Read, Seek, SeekFrom};
use std::path::Path;

use e57::{CartesianCoordinate, E57Reader, E57Writer, Record, RecordValue};
use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion};
use uuid::Uuid;

use crate::base::error::IoError;

/// One scan (`data3D` entry) of an E57 file.
#[derive(Clone, Debug)]
pub struct E57Scan {
    /// The scan's name in the file, if it has one (a scanner's station name).
    pub name: Option<String>,
    /// Maps the scan's coordinates into the file's frame (identity when the file gives none).
    pub pose: Isometry3<f64>,
    /// The scan's points in its own frame, in metres; points the file marks as having no
    /// coordinates are left out, so a scan may have none.
    pub points: Vec<Point3<f64>>,
}

/// The bytes of an E57 page (1,020 of data and their CRC-32C), as the format fixes them: the
/// reader reads one page at a time, each after a seek.
pub(super) const PAGE_BYTES: usize = 1024;

/// The bytes every E57 file begins with.
const SIGNATURE: &[u8; 8] = b"ASTM-E57";

/// Reads every scan of an E57 file into the file's frame, as one cloud.
pub(super) fn read(path: &Path, stream: impl Read + Seek) -> Result<Vec<Point3<f64>>, IoError> {
    let mut points = Vec::new();
    for scan in read_scans(path, stream)? {
        points.extend(scan.points.iter().map(|p| scan.pose * p));
    }
    Ok(points)
}

/// Reads every scan of an E57 file, each in its own frame with its pose. Refuses a file that
/// does not begin with E57's signature, one whose pages fail their checksum or end early, and a
/// scan whose pose is not a rotation (a zero or non-finite quaternion).
pub(super) fn read_scans(
    path: &Path,
    mut stream: impl Read + Seek,
) -> Result<Vec<E57Scan>, IoError> {
    let io = |source: std::io::Error| IoError::Io {
        path: path.into(),
        source,
    };
    let mut first = [0u8; 8];
    let got = stream.read(&mut first).map_err(io)?;
    if &first[..got] != SIGNATURE {
        return Err(IoError::parse(
            path,
            format!(
                "not an E57 file: it begins with {:?}, where E57 files begin with \"ASTM-E57\"",
                String::from_utf8_lossy(&first[..got])
            ),
        ));
    }
    stream.seek(SeekFrom::Start(0)).map_err(io)?;
    let e57 = |e: e57::Error| IoError::parse(path, e.to_string());
    let mut file = E57Reader::new(stream).map_err(e57)?;
    let mut scans = Vec::new();
    for (k, cloud) in file.pointclouds().iter().enumerate() {
        let pose = pose(cloud).ok_or_else(|| {
            IoError::parse(
                path,
                format!("scan {k}'s pose has a zero or non-finite rotation quaternion"),
            )
        })?;
        let mut reader = file.pointcloud_simple(cloud).map_err(e57)?;
        reader.apply_pose(false);
        reader.spherical_to_cartesian(true);
        let mut points = Vec::new();
        for point in reader {
            if let CartesianCoordinate::Valid { x, y, z } = point.map_err(e57)?.cartesian {
                points.push(Point3::new(x, y, z));
            }
        }
        scans.push(E57Scan {
            name: cloud.name.clone(),
            pose,
            points,
        });
    }
    Ok(scans)
}

/// A scan's pose, from its frame into the file's: the rotation quaternion normalised (writers
/// round it), then the translation. `None` for a quaternion that has no direction.
fn pose(cloud: &e57::PointCloud) -> Option<Isometry3<f64>> {
    let Some(t) = &cloud.transform else {
        return Some(Isometry3::identity());
    };
    let q = &t.rotation;
    let q = Quaternion::new(q.w, q.x, q.y, q.z);
    let norm = q.norm();
    if !(norm.is_finite() && norm > 1e-12) {
        return None;
    }
    let v = &t.translation;
    Some(Isometry3::from_parts(
        Translation3::new(v.x, v.y, v.z),
        UnitQuaternion::new_normalize(q),
    ))
}

/// One scan to write to an E57 file: its name, its pose (into the file's frame) and its points
/// in its own frame, borrowed.
#[derive(Clone, Copy, Debug)]
pub struct E57ScanRef<'a> {
    /// The scan's name in the file (written as its `name`), if any.
    pub name: Option<&'a str>,
    /// Maps the scan's coordinates into the file's frame.
    pub pose: Isometry3<f64>,
    /// The scan's points in its own frame.
    pub points: &'a [Point3<f64>],
}

/// Encodes points as an E57 file: one scan of 64-bit float Cartesian coordinates, identity pose.
pub(super) fn encode(path: &Path, points: &[Point3<f64>]) -> Result<Vec<u8>, IoError> {
    let scan = E57ScanRef {
        name: None,
        pose: Isometry3::identity(),
        points,
    };
    encode_scans(path, &[scan])
}

/// Encodes scans as an E57 file: each of 64-bit float Cartesian coordinates, with its name and
/// its pose (the quaternion and translation as E57 stores them). The file's and the scans'
/// GUIDs are drawn from the points and poses, so the same scans write the same bytes.
pub(super) fn encode_scans(path: &Path, scans: &[E57ScanRef<'_>]) -> Result<Vec<u8>, IoError> {
    let e57 = |e: e57::Error| IoError::parse(path, format!("writing E57: {e}"));
    let guid = guid_of(scans);
    let mut bytes = Cursor::new(Vec::new());
    {
        let mut writer = E57Writer::new(&mut bytes, &guid.braced().to_string()).map_err(e57)?;
        for (k, s) in scans.iter().enumerate() {
            let prototype = vec![
                Record::CARTESIAN_X_F64,
                Record::CARTESIAN_Y_F64,
                Record::CARTESIAN_Z_F64,
            ];
            let scan_guid = Uuid::new_v5(&guid, format!("scan {k}").as_bytes());
            let mut scan = writer
                .add_pointcloud(&scan_guid.braced().to_string(), prototype)
                .map_err(e57)?;
            scan.set_name(s.name.map(str::to_owned));
            if s.pose != Isometry3::identity() {
                // E57 keeps the quaternion's scalar part non-negative (q and −q turn alike).
                let q = s.pose.rotation.quaternion();
                let q = if q.w < 0.0 { -q } else { *q };
                let t = s.pose.translation.vector;
                scan.set_transform(Some(e57::Transform {
                    rotation: e57::Quaternion {
                        w: q.w,
                        x: q.i,
                        y: q.j,
                        z: q.k,
                    },
                    translation: e57::Translation {
                        x: t.x,
                        y: t.y,
                        z: t.z,
                    },
                }));
            }
            for p in s.points {
                scan.add_point(vec![
                    RecordValue::Double(p.x),
                    RecordValue::Double(p.y),
                    RecordValue::Double(p.z),
                ])
                .map_err(e57)?;
            }
            scan.finalize().map_err(e57)?;
        }
        writer.finalize().map_err(e57)?;
    }
    Ok(bytes.into_inner())
}

/// The file's GUID: a name-based UUID of the SHA-1 of the scans' poses and points (streamed,
/// not copied), so that writing is repeatable.
fn guid_of(scans: &[E57ScanRef<'_>]) -> Uuid {
    let mut sha = sha1_smol::Sha1::new();
    for s in scans {
        let pose = s.pose.to_homogeneous();
        let points = s.points.iter().flat_map(|p| p.coords.iter());
        for v in pose.iter().chain(points) {
            sha.update(&v.to_le_bytes());
        }
    }
    Uuid::new_v5(&Uuid::NAMESPACE_OID, &sha.digest().bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use e57::{Quaternion as Q, RawValues, Transform, Translation};

    /// An E57 file of `scans`, each its prototype, pose and rows, written by the `e57` crate.
    fn file(scans: Vec<(Vec<Record>, Option<Transform>, Vec<RawValues>)>) -> Vec<u8> {
        let mut bytes = Cursor::new(Vec::new());
        {
            let mut writer = E57Writer::new(&mut bytes, "{test-file}").unwrap();
            for (i, (prototype, pose, rows)) in scans.into_iter().enumerate() {
                let mut scan = writer
                    .add_pointcloud(&format!("{{test-scan-{i}}}"), prototype)
                    .unwrap();
                scan.set_transform(pose);
                scan.set_name(Some(format!("station {i}")));
                for row in rows {
                    scan.add_point(row).unwrap();
                }
                scan.finalize().unwrap();
            }
            writer.finalize().unwrap();
        }
        bytes.into_inner()
    }

    fn cartesian_scan(pose: Option<Transform>) -> (Vec<Record>, Option<Transform>, Vec<RawValues>) {
        let row = |x: f64, y: f64, z: f64, state: i64| {
            vec![
                RecordValue::Double(x),
                RecordValue::Double(y),
                RecordValue::Double(z),
                RecordValue::Integer(state),
            ]
        };
        let prototype = vec![
            Record::CARTESIAN_X_F64,
            Record::CARTESIAN_Y_F64,
            Record::CARTESIAN_Z_F64,
            Record::CARTESIAN_INVALID_STATE,
        ];
        // State 1: a direction without a range; 2: no coordinates. Neither is a point.
        let rows = vec![
            row(1.0, 0.0, 0.0, 0),
            row(0.0, 2.0, 0.5, 0),
            row(0.3, 0.4, 0.0, 1),
            row(9.0, 9.0, 9.0, 2),
            row(-1.5, 0.25, 3.0, 0),
        ];
        (prototype, pose, rows)
    }

    #[test]
    fn e57_reads_every_scan_placed_by_its_pose_spherical_ones_converted() {
        let (s, c) = (
            std::f64::consts::FRAC_PI_4.sin(),
            std::f64::consts::FRAC_PI_4.cos(),
        );
        // 90° about z, then (1, 2, 3) m; written as twice a unit quaternion, as a sloppy writer
        // might: the reader normalises it.
        let pose = Transform {
            rotation: Q {
                w: 2.0 * c,
                x: 0.0,
                y: 0.0,
                z: 2.0 * s,
            },
            translation: Translation {
                x: 1.0,
                y: 2.0,
                z: 3.0,
            },
        };
        let spherical = (
            vec![
                Record::SPHERICAL_RANGE_F64,
                Record::SPHERICAL_AZIMUTH_F64,
                Record::SPHERICAL_ELEVATION_F64,
            ],
            None,
            vec![
                vec![
                    RecordValue::Double(2.0),
                    RecordValue::Double(0.5),
                    RecordValue::Double(0.25),
                ],
                vec![
                    RecordValue::Double(4.0),
                    RecordValue::Double(-2.0),
                    RecordValue::Double(-0.1),
                ],
            ],
        );
        let bytes = file(vec![cartesian_scan(Some(pose)), spherical]);
        let points = read(Path::new("site.e57"), Cursor::new(&bytes)).unwrap();
        let polar = |r: f64, az: f64, el: f64| {
            Point3::new(
                r * el.cos() * az.cos(),
                r * el.cos() * az.sin(),
                r * el.sin(),
            )
        };
        // (x, y, z) turned 90° about z is (−y, x, z).
        let expected = [
            Point3::new(1.0, 3.0, 3.0),
            Point3::new(-1.0, 2.0, 3.5),
            Point3::new(0.75, 0.5, 6.0),
            polar(2.0, 0.5, 0.25),
            polar(4.0, -2.0, -0.1),
        ];
        assert_eq!(points.len(), expected.len(), "{points:?}");
        for (p, e) in points.iter().zip(&expected) {
            assert!((p - e).norm() < 1e-12, "{p} against {e}");
        }
        // Apart: each scan in its own frame, with its name and its pose.
        let scans = read_scans(Path::new("site.e57"), Cursor::new(&bytes)).unwrap();
        let names: Vec<_> = scans.iter().map(|s| s.name.as_deref()).collect();
        assert_eq!(names, [Some("station 0"), Some("station 1")]);
        assert_eq!(scans[0].points[0], Point3::new(1.0, 0.0, 0.0));
        assert_eq!(scans[1].pose, Isometry3::identity());
        let placed: Vec<_> = scans
            .iter()
            .flat_map(|s| s.points.iter().map(|p| s.pose * p))
            .collect();
        assert_eq!(placed, points);
    }

    #[test]
    fn e57_written_reads_back_to_the_bit_and_the_same_cloud_writes_the_same_bytes() {
        let points: Vec<_> = (0..5000)
            .map(|i| {
                let t = f64::from(i) * 0.013;
                Point3::new(t.sin() * 40.0 + 512_345.0, t.cos() * 3.1, t * 1e-3 - 7.0)
            })
            .collect();
        let bytes = encode(Path::new("a.e57"), &points).unwrap();
        assert_eq!(
            read(Path::new("a.e57"), Cursor::new(&bytes)).unwrap(),
            points
        );
        assert_eq!(encode(Path::new("b.e57"), &points).unwrap(), bytes);
        let moved: Vec<_> = points.iter().map(|p| p + nalgebra::Vector3::x()).collect();
        assert_ne!(encode(Path::new("a.e57"), &moved).unwrap(), bytes);
    }

    #[test]
    fn scans_written_with_names_and_poses_read_back_apart() {
        let points: Vec<Vec<Point3<f64>>> = (0..3)
            .map(|k| {
                (0..200)
                    .map(|i| {
                        Point3::new(
                            f64::from(i) * 0.01,
                            f64::from(k),
                            (f64::from(i) * 0.3).sin(),
                        )
                    })
                    .collect()
            })
            .collect();
        let poses = [
            Isometry3::identity(),
            Isometry3::new(
                nalgebra::Vector3::new(3.0, -1.0, 0.2),
                nalgebra::Vector3::new(0.1, 0.4, -2.0),
            ),
            // A quaternion with a negative scalar part: written as its opposite.
            Isometry3::from_parts(
                Translation3::new(-7.5, 0.0, 1.0),
                UnitQuaternion::from_quaternion(Quaternion::new(-0.5, 0.5, -0.5, 0.5)),
            ),
        ];
        let names = [Some("first"), None, Some("third")];
        let scans: Vec<E57ScanRef<'_>> = (0..3)
            .map(|k| E57ScanRef {
                name: names[k],
                pose: poses[k],
                points: &points[k],
            })
            .collect();
        let bytes = encode_scans(Path::new("a.e57"), &scans).unwrap();
        let back = read_scans(Path::new("a.e57"), Cursor::new(&bytes)).unwrap();
        assert_eq!(back.len(), 3);
        for (k, scan) in back.iter().enumerate() {
            assert_eq!(scan.name.as_deref(), names[k]);
            assert_eq!(scan.points, points[k]);
            let off = (scan.pose.to_homogeneous() - poses[k].to_homogeneous()).amax();
            assert!(off < 1e-14, "scan {k}: pose {off} off");
        }
        assert_eq!(encode_scans(Path::new("b.e57"), &scans).unwrap(), bytes);
        let file = E57Reader::new(Cursor::new(&bytes)).unwrap();
        let w: Vec<f64> = file
            .pointclouds()
            .iter()
            .filter_map(|c| c.transform.as_ref())
            .map(|t| t.rotation.w)
            .collect();
        assert!(w.len() == 2 && w.iter().all(|&w| w >= 0.0), "{w:?}");
    }

    #[test]
    fn a_foreign_damaged_or_cut_e57_file_is_refused_by_name() {
        let good = file(vec![cartesian_scan(None)]);
        let mut flipped = good.clone();
        flipped[1500] ^= 0x10;
        let zero = Transform {
            rotation: Q {
                w: 0.0,
                x: 0.0,
                y: 0.0,
                z: 0.0,
            },
            translation: Translation::default(),
        };
        let cases = [
            (
                "cloud.e57",
                b"ply\nformat ascii 1.0\n".to_vec(),
                "not an E57 file: it begins with \"ply\\nform\"",
            ),
            ("cut.e57", good[..good.len() - 1024].to_vec(), "truncated"),
            ("flipped.e57", flipped, "invalid checksum"),
            (
                "pose.e57",
                file(vec![cartesian_scan(Some(zero))]),
                "scan 0's pose has a zero or non-finite rotation quaternion",
            ),
        ];
        for (name, bytes, expected) in cases {
            let error = read(Path::new(name), Cursor::new(bytes))
                .unwrap_err()
                .to_string();
            assert!(
                error.starts_with(&format!("{name}: ")) && error.contains(expected),
                "{name}: {error}"
            );
        }
    }
}

//! A cloud file written moved, with everything else it holds: how each point moves, for the
//! formats' rewriters and [`crate::io::write_moved_point_cloud`] (whose notes say what each
//! format keeps).

use nalgebra::{Point3, Similarity3, Vector3};

use crate::geometry::cloud::{missing_returns, missing_returns_of};

/// How each point of a file is moved ([`crate::io::write_moved_point_cloud`]).
#[derive(Clone, Debug)]
pub(crate) struct Mover {
    /// Maps the input's coordinates into the output's.
    transform: Similarity3<f64>,
    /// Points at exactly (0, 0, 0) are missing returns, left there.
    origin_stays: bool,
}

impl Mover {
    /// `transform` applied to the `points` of a file (as read, non-finite ones included).
    pub(crate) fn new(transform: &Similarity3<f64>, points: &[Point3<f64>]) -> Self {
        Self {
            transform: *transform,
            origin_stays: missing_returns(points) > 0,
        }
    }

    /// `transform` applied to the points of a file of which `at_origin` lie at exactly
    /// (0, 0, 0).
    pub(crate) fn with_origins(transform: &Similarity3<f64>, at_origin: usize) -> Self {
        Self {
            transform: *transform,
            origin_stays: missing_returns_of(at_origin) > 0,
        }
    }

    /// Whether the point `p` stays where it is: not finite, or a missing return.
    pub(crate) fn stays(&self, p: &Point3<f64>) -> bool {
        !p.coords.iter().all(|c| c.is_finite())
            || (self.origin_stays && p.coords == Vector3::zeros())
    }

    /// Where `p` goes.
    pub(crate) fn point(&self, p: &Point3<f64>) -> Point3<f64> {
        if self.stays(p) {
            *p
        } else {
            self.transform * p
        }
    }

    /// The normal `n` turned (the transform's rotation alone: a unit normal stays unit).
    pub(crate) fn normal(&self, n: &Vector3<f64>) -> Vector3<f64> {
        if n.iter().all(|c| c.is_finite()) {
            self.transform.isometry.rotation * n
        } else {
            *n
        }
    }

    /// A record's new coordinates and normal, as (field place, value) pairs, from its old
    /// values (`get`, by field place): its coordinates at places `xyz`, its normal's at
    /// `normal` (if it has one). `None` leaves the record as it is (a point that [`Self::stays`]).
    pub(crate) fn record(
        &self,
        xyz: [usize; 3],
        normal: Option<[usize; 3]>,
        get: &dyn Fn(usize) -> f64,
    ) -> Option<Vec<(usize, f64)>> {
        let [x, y, z] = xyz;
        let p = Point3::new(get(x), get(y), get(z));
        if self.stays(&p) {
            return None;
        }
        let q = self.point(&p);
        let mut out = vec![(x, q.x), (y, q.y), (z, q.z)];
        if let Some([a, b, c]) = normal {
            let m = self.normal(&Vector3::new(get(a), get(b), get(c)));
            out.extend([(a, m.x), (b, m.y), (c, m.z)]);
        }
        Some(out)
    }

    /// The transform.
    pub(crate) fn transform(&self) -> &Similarity3<f64> {
        &self.transform
    }
}

/// What [`crate::io::write_moved_point_cloud`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct MovedCloud {
    /// Points written (every point of the input, in its order).
    pub points: usize,
    /// Of them, left where they were: missing returns at (0, 0, 0) and non-finite points.
    pub left_in_place: usize,
    /// Whether the input's other fields came along.
    pub fields: Fields,
}

/// Whether a moved file kept its input's other fields ([`MovedCloud::fields`]).
#[derive(Clone, Debug, PartialEq)]
pub enum Fields {
    /// Every record with all its fields, the normals turned; the file's other elements and
    /// header records as they were.
    Kept,
    /// The moved coordinates alone, for this reason (the output's format is not the input's,
    /// or the input's layout cannot be rewritten in place).
    CoordinatesOnly(String),
}

/// A number of a text body (PLY or PCD ascii, text clouds) written anew: the shortest spelling
/// that reads back to the value, in `f32` when the field is 4 bytes.
pub(crate) fn spelled(v: f64, single: bool) -> String {
    if single {
        format!("{}", v as f32)
    } else {
        format!("{v}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::write_moved_point_cloud;
    use nalgebra::{Translation3, UnitQuaternion};
    use ply_rs_bw::ply::{DefaultElement, Property};
    use std::path::Path;

    /// A turn of 30° about (1, 2, 3), a shift, and `scale`.
    fn transform(scale: f64) -> Similarity3<f64> {
        Similarity3::from_parts(
            Translation3::new(1.5, -2.0, 0.25),
            UnitQuaternion::from_axis_angle(
                &nalgebra::Unit::new_normalize(Vector3::new(1.0, 2.0, 3.0)),
                0.5,
            ),
            scale,
        )
    }

    /// Points, two of them missing returns at the origin, and their unit normals.
    fn cloud() -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
        let points: Vec<Point3<f64>> = (0..20)
            .map(|i| {
                if i == 4 || i == 9 {
                    return Point3::origin();
                }
                let t = i as f64;
                Point3::new((0.3 * t).sin() * 4.0, t * 0.25 - 1.0, (0.7 * t).cos())
            })
            .collect();
        let normals = (0..20)
            .map(|i| Vector3::new(1.0, i as f64 * 0.1, -0.5).normalize())
            .collect();
        (points, normals)
    }

    fn dir(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("sdfreg-moved-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    /// Asserts `got` is `points` moved by `t` (the two at the origin left there) within `tol`.
    fn assert_moved(got: &[Point3<f64>], points: &[Point3<f64>], t: &Similarity3<f64>, tol: f64) {
        assert_eq!(got.len(), points.len());
        for (i, (g, p)) in got.iter().zip(points).enumerate() {
            let want = if p.coords == Vector3::zeros() {
                *p
            } else {
                t * p
            };
            assert!((g - want).norm() <= tol, "point {i}: {g} against {want}");
        }
    }

    /// A PLY of the cloud with normals, colours and a face element, ascii or binary.
    fn ply(ascii: bool) -> Vec<u8> {
        let (points, normals) = cloud();
        let format = if ascii {
            "ascii"
        } else {
            "binary_little_endian"
        };
        let mut out = format!("ply\nformat {format} 1.0\ncomment made by a test\nelement vertex 20\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty float nx\nproperty float ny\nproperty float nz\nproperty double quality\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n").into_bytes();
        for (i, (p, n)) in points.iter().zip(&normals).enumerate() {
            let f = [p.x, p.y, p.z].map(|v| v as f32);
            let m = [n.x, n.y, n.z].map(|v| v as f32);
            if ascii {
                out.extend(
                    format!(
                        "{} {} {} {} {} {} {} {}\n",
                        f[0],
                        f[1],
                        f[2],
                        i * 10,
                        m[0],
                        m[1],
                        m[2],
                        i as f64 + 0.5
                    )
                    .bytes(),
                );
            } else {
                f.iter().for_each(|v| out.extend(v.to_le_bytes()));
                out.push(i as u8 * 10);
                m.iter().for_each(|v| out.extend(v.to_le_bytes()));
                out.extend((i as f64 + 0.5).to_le_bytes());
            }
        }
        if ascii {
            out.extend(b"3 0 1 2\n");
        } else {
            out.push(3);
            [0i32, 1, 2]
                .iter()
                .for_each(|v| out.extend(v.to_le_bytes()));
        }
        out
    }

    /// Every vertex row and the face of a PLY file, as ply-rs reads them.
    fn ply_rows(path: &Path) -> (Vec<DefaultElement>, Vec<DefaultElement>) {
        let mut f = std::io::BufReader::new(std::fs::File::open(path).unwrap());
        let ply = ply_rs_bw::parser::Parser::<DefaultElement>::new()
            .read_ply(&mut f)
            .unwrap();
        (ply.payload["vertex"].clone(), ply.payload["face"].clone())
    }

    fn float(e: &DefaultElement, k: &str) -> f64 {
        match e[k] {
            Property::Float(v) => v as f64,
            Property::Double(v) => v,
            ref other => panic!("{k}: {other:?}"),
        }
    }

    #[test]
    fn a_ply_keeps_its_colours_faces_and_quality_and_turns_its_normals() {
        let d = dir("ply");
        let (points, normals) = cloud();
        let t = transform(1.0);
        for ascii in [false, true] {
            let (input, output) = (d.join("in.ply"), d.join("out.ply"));
            std::fs::write(&input, ply(ascii)).unwrap();
            let moved = write_moved_point_cloud(&input, &output, &t).unwrap();
            assert_eq!(
                moved,
                MovedCloud {
                    points: 20,
                    left_in_place: 2,
                    fields: Fields::Kept
                }
            );
            let as_read: Vec<Point3<f64>> = crate::io::read_point_cloud(&input).unwrap();
            assert_moved(
                &crate::io::read_point_cloud(&output).unwrap(),
                &as_read,
                &t,
                1e-5,
            );
            let ((before, face_before), (after, face_after)) =
                (ply_rows(&input), ply_rows(&output));
            assert_eq!(face_after, face_before, "ascii {ascii}");
            for (i, (b, a)) in before.iter().zip(&after).enumerate() {
                assert_eq!(a["red"], b["red"]);
                assert_eq!(a["quality"], b["quality"]);
                let n = Vector3::new(float(a, "nx"), float(a, "ny"), float(a, "nz"));
                let want = if points[i].coords == Vector3::zeros() {
                    normals[i]
                } else {
                    t.isometry.rotation * normals[i]
                };
                assert!((n - want).norm() < 1e-6, "normal {i}: {n} against {want}");
            }
            // The header as it was.
            let text = String::from_utf8_lossy(&std::fs::read(&output).unwrap()).to_string();
            assert!(text.starts_with("ply\nformat"), "{}", &text[..40]);
            assert!(text.contains("comment made by a test\n"));
        }
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_pcd_keeps_its_intensities_turns_its_normals_and_moves_its_viewpoint() {
        let d = dir("pcd");
        let (points, normals) = cloud();
        let t = transform(2.0);
        for ascii in [true, false] {
            let data = if ascii { "ascii" } else { "binary" };
            let mut bytes = format!("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z intensity normal_x normal_y normal_z\nSIZE 4 4 4 2 4 4 4\nTYPE F F F U F F F\nCOUNT 1 1 1 1 1 1 1\nWIDTH 20\nHEIGHT 1\nVIEWPOINT 1 2 3 1 0 0 0\nPOINTS 20\nDATA {data}\n").into_bytes();
            for (i, (p, n)) in points.iter().zip(&normals).enumerate() {
                let f = [p.x, p.y, p.z].map(|v| v as f32);
                let m = [n.x, n.y, n.z].map(|v| v as f32);
                if ascii {
                    bytes.extend(
                        format!(
                            "{} {} {} {} {} {} {}\r\n",
                            f[0],
                            f[1],
                            f[2],
                            7 * i,
                            m[0],
                            m[1],
                            m[2]
                        )
                        .bytes(),
                    );
                } else {
                    f.iter().for_each(|v| bytes.extend(v.to_le_bytes()));
                    bytes.extend((7 * i as u16).to_le_bytes());
                    m.iter().for_each(|v| bytes.extend(v.to_le_bytes()));
                }
            }
            let (input, output) = (d.join("in.pcd"), d.join("out.pcd"));
            std::fs::write(&input, &bytes).unwrap();
            let moved = write_moved_point_cloud(&input, &output, &t).unwrap();
            assert_eq!(moved.fields, Fields::Kept);
            let as_read = crate::io::read_point_cloud(&input).unwrap();
            assert_moved(
                &crate::io::read_point_cloud(&output).unwrap(),
                &as_read,
                &t,
                1e-5,
            );
            let meta = pcd_rs::metas::PcdMeta::from_path(&output).unwrap();
            let vp = t * Point3::new(1.0, 2.0, 3.0);
            assert!(
                (Point3::new(meta.viewpoint.tx, meta.viewpoint.ty, meta.viewpoint.tz) - vp).norm()
                    < 1e-12
            );
            let q = t.isometry.rotation;
            assert!(
                (meta.viewpoint.qw - q.w).abs() < 1e-12 && (meta.viewpoint.qx - q.i).abs() < 1e-12
            );
            let reader = pcd_rs::DynReader::open(&output).unwrap();
            for (i, r) in reader.enumerate() {
                let r = r.unwrap();
                let v = |k: usize| r.0[k].to_value::<f32>().map(|v| v as f64).unwrap();
                assert_eq!(r.0[3].to_value::<u16>(), Some(7 * i as u16), "point {i}");
                let n = Vector3::new(v(4), v(5), v(6));
                let want = if points[i].coords == Vector3::zeros() {
                    normals[i]
                } else {
                    q * normals[i]
                };
                assert!((n - want).norm() < 1e-6, "normal {i}");
            }
            if ascii {
                let text = String::from_utf8(std::fs::read(&output).unwrap()).unwrap();
                assert_eq!(text.matches("\r\n").count(), 20, "row ends kept");
            }
        }
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_las_and_a_laz_keep_every_field_of_every_record() {
        let d = dir("las");
        let (points, _) = cloud();
        let t = transform(1.0);
        let mut builder = las::Builder::from((1, 2));
        builder.point_format = las::point::Format::new(3).unwrap();
        builder.transforms = las::Vector {
            x: las::Transform {
                scale: 0.001,
                offset: 100.0,
            },
            y: las::Transform {
                scale: 0.001,
                offset: 0.0,
            },
            z: las::Transform {
                scale: 0.0001,
                offset: 0.0,
            },
        };
        builder.system_identifier = "a test".into();
        for laz in [false, true] {
            builder.point_format.is_compressed = laz;
            let header = builder.clone().into_header().unwrap();
            let mut w = las::Writer::new(std::io::Cursor::new(Vec::new()), header).unwrap();
            for (i, p) in points.iter().enumerate() {
                w.write_point(las::Point {
                    x: p.x,
                    y: p.y,
                    z: p.z,
                    intensity: 100 + i as u16,
                    classification: las::point::Classification::Ground,
                    gps_time: Some(1e5 + i as f64),
                    color: Some(las::Color::new(i as u16, 2, 3)),
                    return_number: 1,
                    number_of_returns: 2,
                    ..Default::default()
                })
                .unwrap();
            }
            let ext = if laz { "laz" } else { "las" };
            let (input, output) = (d.join(format!("in.{ext}")), d.join(format!("out.{ext}")));
            std::fs::write(&input, w.into_inner().unwrap().into_inner()).unwrap();
            let moved = write_moved_point_cloud(&input, &output, &t).unwrap();
            assert_eq!(moved.fields, Fields::Kept);
            assert_eq!(moved.left_in_place, 2);
            let as_read = crate::io::read_point_cloud(&input).unwrap();
            // The file's own resolution: 1 mm across, 0.1 mm in z (turned: 1 mm).
            assert_moved(
                &crate::io::read_point_cloud(&output).unwrap(),
                &as_read,
                &t,
                1e-3,
            );
            let mut before = las::Reader::from_path(&input).unwrap();
            let mut after = las::Reader::from_path(&output).unwrap();
            assert_eq!(
                after.header().point_format(),
                before.header().point_format()
            );
            assert_eq!(after.header().system_identifier(), "a test");
            assert_eq!(after.header().transforms().x.scale, 0.001);
            let (before, after) = (before.read_all().unwrap(), after.read_all().unwrap());
            for (b, a) in before.points().zip(after.points()) {
                let (mut a0, mut b0) = (a.unwrap(), b.unwrap());
                (a0.x, a0.y, a0.z, b0.x, b0.y, b0.z) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
                assert_eq!(a0, b0);
            }
        }
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_text_cloud_keeps_its_columns_comments_header_and_counts() {
        let d = dir("xyz");
        let t = transform(1.0);
        let text = "x,y,z,intensity\n# a comment\n1,2,3,0.5\n0,0,0,1\n0, 0, 0 ,2\n4,5,6,7\r\n";
        let (input, output) = (d.join("in.csv"), d.join("out.csv"));
        std::fs::write(&input, text).unwrap();
        let moved = write_moved_point_cloud(&input, &output, &t).unwrap();
        assert_eq!((moved.points, moved.left_in_place), (4, 2));
        let out = std::fs::read_to_string(&output).unwrap();
        let lines: Vec<&str> = out.split_inclusive('\n').collect();
        assert_eq!(lines[0], "x,y,z,intensity\n");
        assert_eq!(lines[1], "# a comment\n");
        assert!(lines[2].ends_with(",0.5\n"), "{}", lines[2]);
        assert_eq!(lines[3], "0,0,0,1\n");
        assert_eq!(lines[4], "0, 0, 0 ,2\n");
        assert!(lines[5].ends_with(",7\r\n"), "{}", lines[5]);
        let got = crate::io::read_point_cloud(&output).unwrap();
        assert_moved(
            &got,
            &crate::io::read_point_cloud(&input).unwrap(),
            &t,
            1e-12,
        );
        // A Leica .pts: each block's count line kept.
        let (input, output) = (d.join("in.pts"), d.join("out.pts"));
        std::fs::write(
            &input,
            "2\n1 2 3 9 1 2 3\n4 5 6 9 1 2 3\n1\n7 8 9 9 1 2 3\n",
        )
        .unwrap();
        write_moved_point_cloud(&input, &output, &t).unwrap();
        let out = std::fs::read_to_string(&output).unwrap();
        let lines: Vec<&str> = out.lines().collect();
        assert_eq!((lines[0], lines[3]), ("2", "1"));
        assert!(lines
            .iter()
            .skip(1)
            .filter(|l| l.len() > 2)
            .all(|l| l.ends_with(" 9 1 2 3")));
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn fuzz_regression_a_las_record_of_a_sixth_return_is_an_error_not_a_panic() {
        // Found by `cargo fuzz run moved`: a LAS 1.2 file whose record claims return 6, which
        // its header cannot count; las-rs's writer panicked when dropped unclosed.
        let d = dir("fuzz");
        let input = d.join("six.las");
        let bytes = include_bytes!("fuzz_regressions/las-return-six-in-1.2.las");
        std::fs::write(&input, bytes).unwrap();
        let err = write_moved_point_cloud(&input, d.join("out.las"), &transform(1.0))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("six.las") && err.contains("claims return"),
            "{err}"
        );
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn another_format_gets_the_coordinates_alone_and_says_why() {
        let d = dir("cross");
        let t = transform(1.0);
        let (input, output) = (d.join("in.ply"), d.join("out.xyz"));
        std::fs::write(&input, ply(false)).unwrap();
        let moved = write_moved_point_cloud(&input, &output, &t).unwrap();
        assert!(
            matches!(&moved.fields, Fields::CoordinatesOnly(why) if why.contains("its format is not that of")),
            "{moved:?}"
        );
        let as_read = crate::io::read_point_cloud(&input).unwrap();
        assert_moved(
            &crate::io::read_point_cloud(&output).unwrap(),
            &as_read,
            &t,
            1e-12,
        );
        // A truncated input is refused by name before anything is written.
        let cut = ply(false);
        std::fs::write(&input, &cut[..cut.len() - 30]).unwrap();
        let (bad, target) = (input.clone(), d.join("never.ply"));
        let err = write_moved_point_cloud(&bad, &target, &t).unwrap_err();
        assert!(err.to_string().contains("in.ply"), "{err}");
        assert!(!target.exists());
        std::fs::remove_dir_all(&d).unwrap();
    }
}

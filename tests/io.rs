//! Reading clouds: formats, and errors that name the file and the place.

use sdfreg_core::io::{read_mesh, read_point_cloud, write_point_cloud};
use sdfreg_core::IoError;

#[test]
fn errors_name_the_file_and_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty.xyz");
    std::fs::write(&empty, "# nothing\n").unwrap();
    let err = read_point_cloud(&empty).unwrap_err();
    assert!(matches!(err, IoError::Empty { .. }));
    assert!(err.to_string().contains("empty.xyz"), "{err}");

    let truncated = dir.path().join("cut.ply");
    let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n".to_vec();
    bytes.extend_from_slice(&[0u8; 20]);
    std::fs::write(&truncated, &bytes).unwrap();
    let err = read_point_cloud(&truncated).unwrap_err().to_string();
    // 3 rows of 12 bytes declared after a 115-byte header; the file ends 20 bytes in.
    assert!(
        err.starts_with(&format!(
            "{}: byte 135: the file ends inside `vertex` row 1",
            truncated.display()
        )),
        "{err}"
    );

    // A mesh is refused for the same reasons as a cloud, in the same words.
    let folder = dir.path().join("folder.ply");
    std::fs::create_dir(&folder).unwrap();
    let blank = dir.path().join("blank.ply");
    std::fs::write(&blank, "").unwrap();
    for path in [&folder, &blank] {
        let as_mesh = read_mesh(path).unwrap_err().to_string();
        assert_eq!(as_mesh, read_point_cloud(path).unwrap_err().to_string());
    }
    assert!(matches!(read_mesh(&blank), Err(IoError::Empty { .. })));

    let nan = dir.path().join("nan.ply");
    write_point_cloud(&nan, &[nalgebra::Point3::new(0.0, f64::NAN, 1.0)]).unwrap();
    assert!(matches!(
        read_point_cloud(&nan),
        Err(IoError::NonFinite { index: 0, .. })
    ));
}

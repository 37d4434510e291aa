//! The `sdfreg` binary: output formats, exit codes and one-line errors.

use std::path::Path;
use std::process::Command;

use nalgebra::{Isometry3, Matrix4, Point3, Translation3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use sdfreg_core::geometry::se3::isometry_from_matrix;
use sdfreg_core::geometry::se3::pose_errors;

fn sdfreg() -> Command {
    Command::new(env!("CARGO_BIN_EXE_sdfreg"))
}

/// `sdfreg register SRC TGT` on the pair that [`pair`] wrote into `dir`.
fn register_cmd(dir: &Path) -> Command {
    let mut c = sdfreg();
    c.arg("register")
        .arg(dir.join("src.xyz"))
        .arg(dir.join("tgt.ply"));
    c
}

fn write_xyz(path: &Path, pts: &[Point3<f64>]) {
    sdfreg_core::io::write_point_cloud(path, pts).unwrap();
}

fn pair(dir: &Path) -> Isometry3<f64> {
    let target =
        sdfreg_core::sim::shapes::blob(800, &mut rand_chacha::ChaCha8Rng::seed_from_u64(9));
    let m = Isometry3::from_parts(
        Translation3::new(0.2, 0.1, -0.3),
        UnitQuaternion::from_scaled_axis(Vector3::new(0.3, 0.4, -0.2)),
    );
    write_xyz(&dir.join("tgt.ply"), &target);
    write_xyz(
        &dir.join("src.xyz"),
        &target.iter().map(|p| m * p).collect::<Vec<_>>(),
    );
    m.inverse()
}

fn parse_matrix(text: &str) -> Matrix4<f64> {
    let v: Vec<f64> = text
        .split_whitespace()
        .map(|s| s.parse().unwrap())
        .collect();
    assert_eq!(v.len(), 16, "{text}");
    Matrix4::from_row_slice(&v)
}

const QUICK: [&str; 6] = [
    "--prefit-steps",
    "300",
    "--model-prefit-steps",
    "300",
    "--alternations",
    "5",
];

/// `--aligned` in the source's own format writes the source file moved: each row's other
/// columns as they were, its comment and header lines too, the missing returns at the origin
/// left there; in another format the coordinates alone, and stderr says so.
#[test]
fn the_aligned_source_keeps_its_other_columns_in_its_own_format() {
    let dir = tempfile::tempdir().unwrap();
    pair(dir.path());
    let moved = sdfreg_core::io::read_point_cloud(dir.path().join("src.xyz")).unwrap();
    let mut text = String::from("x y z intensity\n# from a test\n0 0 0 0\n0 0 0 0\n");
    for (i, p) in moved.iter().enumerate() {
        text += &format!("{} {} {} {}\n", p.x, p.y, p.z, i);
    }
    let source = dir.path().join("scan.txt");
    std::fs::write(&source, &text).unwrap();
    let (matrix, aligned) = (dir.path().join("m.json"), dir.path().join("aligned.txt"));
    let run = |aligned: &Path| {
        sdfreg()
            .arg("register")
            .arg(&source)
            .arg(dir.path().join("tgt.ply"))
            .args(QUICK)
            .arg("--force")
            .arg("-o")
            .arg(&matrix)
            .arg("--aligned")
            .arg(aligned)
            .output()
            .unwrap()
    };
    let out = run(&aligned);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("coordinates only"), "{stderr}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&matrix).unwrap()).unwrap();
    let m = sdfreg_core::geometry::se3::matrix_from_rows(&v["transformation"]).unwrap();
    let written = std::fs::read_to_string(&aligned).unwrap();
    let lines: Vec<&str> = written.lines().collect();
    assert_eq!(
        lines[..4],
        ["x y z intensity", "# from a test", "0 0 0 0", "0 0 0 0"]
    );
    assert_eq!(lines.len(), 4 + moved.len());
    for (i, (line, p)) in lines[4..].iter().zip(&moved).enumerate() {
        let v: Vec<f64> = line.split(' ').map(|f| f.parse().unwrap()).collect();
        let want = (m * p.to_homogeneous()).xyz();
        assert_eq!(v[3], i as f64, "row {i}: {line}");
        assert!(
            (Vector3::new(v[0], v[1], v[2]) - want).norm() < 1e-12,
            "row {i}: {line} against {want}"
        );
    }
    let out = run(&dir.path().join("aligned.ply"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("holds coordinates only"), "{stderr}");
}

#[test]
fn register_prints_the_matrix_and_writes_json_and_aligned_cloud() {
    let dir = tempfile::tempdir().unwrap();
    let truth = pair(dir.path());
    let out = register_cmd(dir.path()).args(QUICK).output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let m = parse_matrix(&String::from_utf8(out.stdout).unwrap());
    let err = (m - truth.to_homogeneous()).amax();
    assert!(err < 0.02, "matrix off by {err}");

    let json = dir.path().join("r.json");
    let aligned = dir.path().join("aligned.ply");
    let out = register_cmd(dir.path())
        .args(QUICK)
        .arg("-o")
        .arg(&json)
        .arg("--aligned")
        .arg(&aligned)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.stdout.is_empty());
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    for key in [
        "transformation",
        "converged",
        "fitness",
        "inlier_rmse",
        "iterations",
        "time_ms",
    ] {
        assert!(v.get(key).is_some(), "missing {key} in {v}");
    }
    let rows: Vec<Vec<f64>> = serde_json::from_value(v["transformation"].clone()).unwrap();
    assert!((rows[0][3] - truth.translation.vector.x).abs() < 0.01);
    // A blob constrains every motion: six constraint eigenvalues, the largest 1, none free.
    let ev: Vec<f64> = serde_json::from_value(v["constraint_eigenvalues"].clone()).unwrap();
    assert!(ev.len() == 6 && ev[5] == 1.0 && ev[0] > 0.002, "{ev:?}");
    assert_eq!(v["free_motions"], serde_json::json!([]));
    // Python's names: snake_case stop reasons, and what each stage did.
    let stop = v["stop_reason"].as_str().unwrap();
    assert!(
        ["small_step", "no_decrease", "max_iterations"].contains(&stop),
        "{stop}"
    );
    assert_eq!(v["stages"]["initial"]["starts"], 168);
    assert_eq!(v["stages"]["robust"]["kind"], "not_needed");
    let polish = v["stages"]["polish"]["result"].as_str().unwrap();
    assert!(["applied", "snapped"].contains(&polish), "{polish}");
    assert!(v["stages"]["final_lm"]["change"]["rotation_deg"].is_f64());
    // Where the time went: every stage timed, the pre-fit and the alternations not zero, and
    // the stages within the call's own time.
    let ms: std::collections::BTreeMap<String, f64> =
        serde_json::from_value(v["stage_ms"].clone()).unwrap();
    let names = [
        "prefit",
        "initial",
        "coarse_to_fine",
        "final_lm",
        "polish",
        "shift_search",
        "measure",
        "other_run",
    ];
    assert_eq!(ms.len(), names.len(), "{ms:?}");
    assert!(ms["prefit"] > 0.0 && ms["coarse_to_fine"] > 0.0, "{ms:?}");
    assert_eq!(ms["other_run"], 0.0, "no robust re-run ran: {ms:?}");
    let total: f64 = names.iter().map(|n| ms[*n]).sum();
    assert!(total <= v["time_ms"].as_f64().unwrap(), "{ms:?} {v}");
    assert!(!String::from_utf8_lossy(&out.stderr).contains("warning"));
    let moved = sdfreg_core::io::read_point_cloud(&aligned).unwrap();
    assert_eq!(moved.len(), 800);

    // The preset for scans: the robust kernel from the start, said on stderr and in the JSON.
    let scans = dir.path().join("scans.json");
    let out = register_cmd(dir.path())
        .args(QUICK)
        .args(["--preset", "scans", "-o"])
        .arg(&scans)
        .output()
        .unwrap();
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("(robust kernel)"));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&scans).unwrap()).unwrap();
    assert_eq!(v["robust"], true);
    assert_eq!(v["stages"]["robust"]["kind"], "from_start");
    // A threshold for a re-run that the mode does not make is refused.
    let out = register_cmd(dir.path())
        .args(["--robust-mode", "on", "--robust-below-fitness", "0.5"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&out.stderr)
            .contains("--robust-below-fitness: only with --robust-mode auto"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    // Refuses to overwrite without --force, and never over an input.
    let again = register_cmd(dir.path())
        .arg("-o")
        .arg(&json)
        .output()
        .unwrap();
    assert_eq!(again.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&again.stderr).contains("exists; pass --force"));
    let over_input = register_cmd(dir.path())
        .arg("--aligned")
        .arg(dir.path().join("tgt.ply"))
        .arg("--force")
        .output()
        .unwrap();
    assert_eq!(over_input.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&over_input.stderr)
        .contains("refusing to write the output over an input"));
}

/// PLY text of `rows` (x y z lines) under a header declaring `declared` float vertices.
fn ply_ascii(declared: usize, rows: &str) -> Vec<u8> {
    format!("ply\nformat ascii 1.0\nelement vertex {declared}\nproperty float x\nproperty float y\nproperty float z\nend_header\n{rows}").into_bytes()
}

/// Binary PLY of `n` float vertices, cut to `keep` body bytes.
fn ply_binary(big_endian: bool, n: usize, keep: usize) -> Vec<u8> {
    let order = if big_endian { "big" } else { "little" };
    let mut b = format!("ply\nformat binary_{order}_endian 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nend_header\n").into_bytes();
    let body: Vec<u8> = (0..n * 3)
        .flat_map(|i| {
            let v = (i as f32 * 0.37).sin();
            if big_endian {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            }
        })
        .collect();
    b.extend_from_slice(&body[..keep.min(body.len())]);
    b
}

/// A bad-input case: its name, the file name, the contents (None: not created) and fragments the
/// message must contain.
type BadInput = (
    &'static str,
    &'static str,
    Option<Vec<u8>>,
    Vec<&'static str>,
);

/// Every kind of bad input tried: exit code 2 and one line naming the file, the place (line or
/// byte) and what was expected. `cargo test -p sdfreg-cli --test cli bad_input -- --nocapture`
/// prints the table of messages.
#[test]
fn bad_input_exits_2_with_one_line_naming_the_file_and_the_place() {
    let dir = tempfile::tempdir().unwrap();
    pair(dir.path());
    let rows: String = (0..50)
        .map(|i| {
            format!(
                "{} {} {}\n",
                i as f64 * 0.1,
                (i * i % 7) as f64,
                (i % 5) as f64
            )
        })
        .collect();
    let rows_with = |k: usize, line: &str| -> String {
        let mut v: Vec<&str> = rows.lines().collect();
        v[k] = line;
        v.join("\n") + "\n"
    };
    let pcd = |body: &[u8]| -> Vec<u8> {
        let mut b = b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 50\nHEIGHT 1\nPOINTS 50\nDATA binary\n".to_vec();
        b.extend_from_slice(body);
        b
    };
    // A LAS file of the source's points, cut 100 bytes short.
    let src = sdfreg_core::io::read_point_cloud(dir.path().join("src.xyz")).unwrap();
    sdfreg_core::io::write_point_cloud(dir.path().join("full.las"), &src).unwrap();
    let las = std::fs::read(dir.path().join("full.las")).unwrap();
    // The same compressed (LAZ), cut in half: its chunk table lies past the end.
    sdfreg_core::io::write_point_cloud(dir.path().join("full.laz"), &src).unwrap();
    let laz = std::fs::read(dir.path().join("full.laz")).unwrap();
    // The same as E57, one byte of its points flipped: the page's checksum fails.
    sdfreg_core::io::write_point_cloud(dir.path().join("full.e57"), &src).unwrap();
    let mut e57 = std::fs::read(dir.path().join("full.e57")).unwrap();
    e57[100] ^= 1;
    let las_points: &'static str = format!(
        "the file ends inside points 0..{0} of the {0} the header declares",
        src.len()
    )
    .leak();
    let cases: Vec<BadInput> = vec![
        ("empty PLY", "empty.ply", Some(vec![]), vec!["empty.ply", "no points"]),
        ("empty XYZ", "empty.xyz", Some(vec![]), vec!["empty.xyz", "no points"]),
        ("empty PCD", "empty.pcd", Some(vec![]), vec!["empty.pcd", "no points"]),
        ("PLY header only (ascii)", "header.ply", Some(ply_ascii(50, "")), vec!["header.ply:8", "ends after 0 of the 50 `vertex` rows"]),
        ("PLY header only (binary)", "header_bin.ply", Some(ply_binary(false, 50, 0)), vec!["byte 116", "row 0", "50 rows of 12 bytes"]),
        ("truncated binary PLY (LE)", "cut_le.ply", Some(ply_binary(false, 50, 593)), vec!["byte 709", "row 49", "starts at byte 116"]),
        ("truncated binary PLY (BE)", "cut_be.ply", Some(ply_binary(true, 50, 580)), vec!["byte 693", "row 48"]),
        ("PLY declares more rows", "more.ply", Some(ply_ascii(60, &rows)), vec!["more.ply:58", "50 of the 60"]),
        ("PLY declares fewer rows", "fewer.ply", Some(ply_ascii(40, &rows)), vec!["fewer.ply:48", "data after the last element", "40 `vertex`"]),
        ("binary PLY with extra bytes", "extra.ply", Some([ply_binary(false, 50, 600), b"junk".to_vec()].concat()), vec!["byte 716", "data after the last element"]),
        ("PLY row not numbers", "token.ply", Some(ply_ascii(50, &rows_with(20, "1 two 3"))), vec!["token.ply:28", "row 20", "expected 3 numbers", "\"1 two 3\""]),
        ("PLY without z", "noz.ply", Some(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n".to_vec()), vec!["noz.ply", "no `z` property"]),
        ("not a PLY", "text.ply", Some(b"hello\n".to_vec()), vec!["text.ply:1", "magic number"]),
        ("NaN in XYZ", "nan.xyz", Some(rows_with(10, "1 nan 2").into_bytes()), vec!["nan.xyz:11", "point 10", "non-finite"]),
        ("Inf in binary PLY", "inf.ply", Some({ let mut b = ply_binary(false, 50, 600); let n = b.len(); b[n - 4..].copy_from_slice(&f32::INFINITY.to_le_bytes()); b }), vec!["inf.ply", "point 49", "non-finite"]),
        ("XYZ line of two numbers", "two.xyz", Some(rows_with(10, "1 2").into_bytes()), vec!["two.xyz:11", "expected three numbers"]),
        ("binary junk as XYZ", "junk.xyz", Some((0..=255u8).cycle().take(1024).collect()), vec!["junk.xyz", "not UTF-8"]),
        ("truncated binary PCD", "cut.pcd", Some(pcd(&[0u8; 591])), vec!["cut.pcd", "byte 687", "point 49 of the 50"]),
        ("PCD without z", "noz.pcd", Some(b"VERSION 0.7\nFIELDS x y\nSIZE 4 4\nTYPE F F\nCOUNT 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2\n".to_vec()), vec!["noz.pcd", "no `z` field"]),
        ("NaN in ascii PLY", "nan.ply", Some(ply_ascii(50, &rows_with(10, "1 nan 2"))), vec!["nan.ply:18", "point 10", "non-finite"]),
        ("truncated LAS", "cut.las", Some(las[..las.len() - 100].to_vec()), vec!["cut.las", las_points]),
        ("not a LAS", "text.las", Some(b"hello\n".to_vec()), vec!["text.las", "not a LAS file", "\"hell\""]),
        ("truncated LAZ", "cut.laz", Some(laz[..laz.len() / 2].to_vec()), vec!["cut.laz", "LASzip chunk table is said to begin at byte"]),
        ("damaged E57", "flipped.e57", Some(e57), vec!["flipped.e57", "invalid checksum", "for page 0"]),
        ("PTS cut short", "cut.pts", Some(format!("60\n{rows}").into_bytes()), vec!["cut.pts:1", "point count 60, but 50 rows follow"]),
        ("fewer than 10 points", "few.xyz", Some(rows.lines().take(5).map(|l| format!("{l}\n")).collect::<String>().into_bytes()), vec!["few.xyz", "5 points; at least 10"]),
        ("one repeated point", "same.xyz", Some("1 2 3\n".repeat(50).into_bytes()), vec!["same.xyz", "no extent"]),
        ("unknown extension", "cloud.obj", Some(b"v 1 2 3\n".to_vec()), vec!["cloud.obj", "unknown point-cloud format", ".ply, .pcd"]),
        ("missing file", "missing.ply", None, vec!["missing.ply", "No such file"]),
        ("a directory", "folder.ply", None, vec!["folder.ply", "a directory, not a file"]),
    ];
    std::fs::create_dir(dir.path().join("folder.ply")).unwrap();
    println!("| case | message (exit code 2) |\n|---|---|");
    for (case, name, contents, expected) in cases {
        let path = dir.path().join(name);
        if let Some(bytes) = contents {
            std::fs::write(&path, bytes).unwrap();
        }
        let out = sdfreg()
            .arg("register")
            .arg(&path)
            .arg(dir.path().join("tgt.ply"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        let line = err
            .trim_end()
            .replace(&format!("{}/", dir.path().display()), "");
        println!("| {case} | `` {line} `` |");
        assert_eq!(out.status.code(), Some(2), "{case}: {err}");
        for e in expected {
            assert!(line.contains(e), "{case}: expected {e:?} in {line:?}");
        }
        assert_eq!(line.lines().count(), 1, "{case}: one line: {err:?}");
        assert!(!err.contains("panicked"), "{case}: {err}");
    }
    let init = dir.path().join("init.txt");
    std::fs::write(&init, "1 0 0 0\n0 2 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
    let out = register_cmd(dir.path())
        .arg("--init")
        .arg(&init)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("not a rigid transform"));
}

#[test]
fn nan_points_are_refused_or_dropped_on_request_and_pcd_is_read() {
    let dir = tempfile::tempdir().unwrap();
    let truth = pair(dir.path());
    // The source as PCD, LAZ and E57, and a copy with two NaN rows (as a range scanner writes
    // them).
    let src = sdfreg_core::io::read_point_cloud(dir.path().join("src.xyz")).unwrap();
    sdfreg_core::io::write_point_cloud(dir.path().join("src.pcd"), &src).unwrap();
    sdfreg_core::io::write_point_cloud(dir.path().join("src.laz"), &src).unwrap();
    sdfreg_core::io::write_point_cloud(dir.path().join("src.e57"), &src).unwrap();
    let mut text = std::fs::read_to_string(dir.path().join("src.xyz")).unwrap();
    text.insert_str(0, "nan nan nan\n");
    text.push_str("1 NaN 2\n");
    std::fs::write(dir.path().join("holes.xyz"), &text).unwrap();
    // The same as an ascii PLY as Open3D writes it: `nan` for a missing return.
    let ply = ply_ascii(text.lines().count(), &text);
    std::fs::write(dir.path().join("holes.ply"), ply).unwrap();
    let tgt = dir.path().join("tgt.ply");
    // Refused without `--drop-non-finite`, naming the row's line.
    for (source, line) in [("holes.xyz", 1), ("holes.ply", 8)] {
        let refused = sdfreg()
            .arg("register")
            .arg(dir.path().join(source))
            .arg(&tgt)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&refused.stderr);
        assert_eq!(refused.status.code(), Some(2), "{err}");
        assert!(
            err.contains(&format!(
                "{source}:{line}: point 0 has a non-finite coordinate"
            )),
            "{err}"
        );
    }
    for (source, extra) in [
        ("holes.xyz", Some("--drop-non-finite")),
        ("holes.ply", Some("--drop-non-finite")),
        ("src.pcd", None),
        ("src.laz", None),
        ("src.e57", None),
    ] {
        let out = sdfreg()
            .arg("register")
            .arg(dir.path().join(source))
            .arg(&tgt)
            .args(extra)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{err}");
        if extra.is_some() {
            assert!(
                err.contains(&format!("{source}: dropped 2 of 802 points")),
                "{err}"
            );
        }
        let m = parse_matrix(&String::from_utf8_lossy(&out.stdout));
        let (rot, tr) = pose_errors(&isometry_from_matrix(&m).unwrap(), &truth);
        assert!(rot < 1.0 && tr < 0.01, "{source}: {rot}°, {tr}");
    }
    // Missing returns written as (0, 0, 0), as spinning LiDARs write them, then a stray return
    // far off the cloud among them: each left out, said so, and the same matrix as without them.
    let register = |name: &str| {
        sdfreg()
            .arg("register")
            .arg(dir.path().join(name))
            .arg(&tgt)
            .output()
            .unwrap()
    };
    let clean = register("src.xyz");
    for (from, added, name, says) in [
        ("src.xyz", "0 0 0\n".repeat(40), "zeros.xyz", "zeros.xyz: 40 of 840 points are at exactly (0, 0, 0), a scanner's missing returns: left out"),
        ("zeros.xyz", "400 -300 2000\n".into(), "stray.xyz", "stray.xyz: 1 of 841 points lie more than 30 times as far from the cloud's middle as 99 % of them, stray returns: left out"),
    ] {
        let mut text = std::fs::read_to_string(dir.path().join(from)).unwrap();
        text.push_str(&added);
        std::fs::write(dir.path().join(name), text).unwrap();
        let out = register(name);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{name}: {err}");
        assert!(err.contains(says), "{err}");
        assert_eq!(out.stdout, clean.stdout, "{name}");
    }
    // The JSON result counts them.
    let json = dir.path().join("stray.json");
    let out = sdfreg()
        .arg("register")
        .arg(dir.path().join("stray.xyz"))
        .arg(&tgt)
        .arg("--output")
        .arg(&json)
        .output()
        .unwrap();
    assert!(out.status.success());
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(
        r["points_left_out"],
        serde_json::json!({"source": {"missing_returns": 40, "stray": 1},
                           "target": {"missing_returns": 0, "stray": 0}})
    );
}

#[test]
fn demo_reports_a_small_error() {
    let out = sdfreg().arg("demo").args(QUICK).output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let line = text
        .lines()
        .find(|l| l.starts_with("rotation error"))
        .unwrap();
    let deg: f64 = line
        .split_whitespace()
        .nth(2)
        .unwrap()
        .trim_end_matches('°')
        .trim_end_matches(',')
        .trim_end_matches('°')
        .parse()
        .unwrap();
    assert!(deg < 1.0, "{line}");
}

#[test]
fn demo_writes_its_pair_for_the_other_commands_and_never_over_a_file() {
    let dir = tempfile::tempdir().unwrap();
    let pair = dir.path().join("pair");
    let out = sdfreg()
        .args(["demo", "--points", "600", "--write-pair"])
        .arg(&pair)
        .args(QUICK)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // gt.txt moves source.ply exactly onto target.ply.
    let gt = parse_matrix(&std::fs::read_to_string(pair.join("gt.txt")).unwrap());
    let src = sdfreg_core::io::read_point_cloud(pair.join("source.ply")).unwrap();
    let tgt = sdfreg_core::io::read_point_cloud(pair.join("target.ply")).unwrap();
    assert_eq!((src.len(), tgt.len()), (600, 600));
    let worst = src
        .iter()
        .zip(&tgt)
        .map(|(p, q)| (gt.transform_point(p) - q).norm())
        .fold(0.0, f64::max);
    assert!(worst < 1e-6, "{worst}");
    // Again into the same folder: refused, naming the file, nothing rewritten.
    let before = std::fs::read(pair.join("source.ply")).unwrap();
    let out = sdfreg()
        .args(["demo", "--points", "50", "--write-pair"])
        .arg(&pair)
        .args(QUICK)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("source.ply: exists"), "{err}");
    assert_eq!(std::fs::read(pair.join("source.ply")).unwrap(), before);
}

#[test]
fn eval_writes_pairs_others_can_rerun_and_scores_every_protocol() {
    let dir = tempfile::tempdir().unwrap();
    let shapes = dir.path().join("shapes");
    std::fs::create_dir_all(shapes.join("b")).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
    write_xyz(
        &shapes.join("a.ply"),
        &sdfreg_core::sim::shapes::blob(3000, &mut rng),
    );
    write_xyz(
        &shapes.join("b").join("bracket.ply"),
        &sdfreg_core::sim::shapes::bracket(3000, &mut rng),
    );
    let pairs = dir.path().join("pairs");
    let json = dir.path().join("eval.json");
    let out = sdfreg()
        .args([
            "eval",
            "--pairs",
            "2",
            "--protocol",
            "clean,anyrot,partial-indep,scaled",
        ])
        .arg("--shapes")
        .arg(&shapes)
        .arg("--write-pairs")
        .arg(&pairs)
        .arg("--json")
        .arg(&json)
        .args(QUICK)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for name in [
        "| clean | 2 |",
        "| anyrot | 2 |",
        "| partial-indep | 2 |",
        "| scaled | 2 |",
        "  scale error: mean ",
    ] {
        assert!(stdout.contains(name), "{stdout}");
    }
    // Every written pair: the ground truth moves the source onto the target's surface.
    let index: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(pairs.join("pairs.json")).unwrap()).unwrap();
    let listed = index["pairs"].as_array().unwrap();
    assert_eq!(listed.len(), 8);
    for p in listed {
        let d = pairs.join(p["dir"].as_str().unwrap());
        let gt = parse_matrix(&std::fs::read_to_string(d.join("gt.txt")).unwrap());
        let src = sdfreg_core::io::read_point_cloud(d.join("source.ply")).unwrap();
        let tgt = sdfreg_core::io::read_point_cloud(d.join("target.ply")).unwrap();
        assert_eq!(src.len(), p["source_points"].as_u64().unwrap() as usize);
        let moved = gt.transform_point(&src[0]);
        let nearest = tgt
            .iter()
            .map(|q| (q - moved).norm())
            .fold(f64::MAX, f64::min);
        assert!(nearest < 0.05, "{} {nearest}", d.display());
    }
    // The scores: every pair registered well on these asymmetric shapes.
    let eval: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    for s in eval["summary"].as_array().unwrap() {
        assert!(s["rotation_mean_deg"].as_f64().unwrap() < 2.0, "{s}");
        assert!(s["euler_mae_deg"].as_f64().unwrap() < 2.0, "{s}");
        assert_eq!(s["recall_5deg_005"].as_f64().unwrap(), 1.0, "{s}");
        // The scaled protocol: the scale found within 0.5 %; the rigid ones have none.
        let scaled = s["protocol"] == "scaled";
        assert_eq!(s.get("scale_error_pct").is_some(), scaled, "{s}");
        if scaled {
            assert!(s["scale_error_pct"][0].as_f64().unwrap() < 0.5, "{s}");
        }
    }
    // Where the time went: every pair's stages, and their medians printed.
    for p in eval["pairs"].as_array().unwrap() {
        let fit = p["stage_ms"]["prefit"].as_f64().unwrap();
        assert!(
            fit > 0.0 && fit < 1e3 * p["time_s"].as_f64().unwrap(),
            "{p}"
        );
    }
    assert!(
        stdout.contains("time per stage, median over the 8 pairs (ms): prefit "),
        "{stdout}"
    );
    // Pairs are not overwritten without --force; an unknown protocol is a one-line error.
    let again = sdfreg()
        .args(["eval", "--pairs-only", "--shapes"])
        .arg(&shapes)
        .arg("--write-pairs")
        .arg(&pairs)
        .output()
        .unwrap();
    assert_eq!(again.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&again.stderr).contains("pass --force"));
    let bad = sdfreg()
        .args(["eval", "--protocol", "clean,wobbly", "--shapes"])
        .arg(&shapes)
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2));
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        err.contains("unknown protocol \"wobbly\"") && err.lines().count() == 1,
        "{err}"
    );
}

#[test]
fn fit_once_then_register_mesh_and_track_against_the_model() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let truth = pair(d);
    let model = d.join("tgt.sdfm");
    let out = sdfreg()
        .args(["fit", "--model-prefit-steps", "300", "-o"])
        .arg(&model)
        .arg(d.join("tgt.ply"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("fitted 800 target points") && err.contains("|Φ| on them"),
        "{err}"
    );
    // The model replaces the target cloud; with --refine it gives the cloud's own numbers
    // (the model's pre-fit as long as the cloud call's).
    let against = |extra: &[&str]| {
        let out = sdfreg()
            .arg("register")
            .arg(d.join("src.xyz"))
            .arg(&model)
            .args(["--prefit-steps", "300"])
            .args(extra)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        parse_matrix(&String::from_utf8(out.stdout).unwrap())
    };
    let frozen = isometry_from_matrix(&against(&[])).unwrap();
    let (rot, tr) = pose_errors(&frozen, &truth);
    assert!(rot < 1.0 && tr < 0.01, "against the model: {rot}°, {tr}");
    let cloud = register_cmd(d)
        .args(["--prefit-steps", "300"])
        .output()
        .unwrap();
    assert_eq!(
        against(&["--refine"]),
        parse_matrix(&String::from_utf8(cloud.stdout).unwrap())
    );
    let refine_cloud = register_cmd(d).arg("--refine").output().unwrap();
    assert_eq!(refine_cloud.status.code(), Some(2));

    // The mesh of the model, as PLY faces.
    let mesh = d.join("mesh.ply");
    let out = sdfreg()
        .arg("mesh")
        .arg(&model)
        .args(["--resolution", "32", "-o"])
        .arg(&mesh)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (vertices, triangles) = sdfreg_core::io::read_mesh(&mesh).unwrap();
    assert!(vertices.len() > 100 && triangles.len() > 200);

    // Tracking: the source moved a little more each frame; one bad frame is reported in its line.
    let frames: Vec<_> = (0..4)
        .map(|k| {
            let step = Isometry3::rotation(Vector3::z() * (2.0 * k as f64).to_radians());
            let path = d.join(format!("frame{k}.xyz"));
            let src = sdfreg_core::io::read_point_cloud(d.join("src.xyz")).unwrap();
            write_xyz(&path, &src.iter().map(|p| step * p).collect::<Vec<_>>());
            (path, truth * step.inverse())
        })
        .collect();
    let init: Vec<String> = truth
        .to_homogeneous()
        .transpose()
        .iter()
        .map(|v| format!("{v:.17e}"))
        .collect();
    std::fs::write(d.join("init.txt"), init.join(" ")).unwrap();
    let poses = d.join("poses.jsonl");
    let mut track = sdfreg();
    track.arg("track").arg(&model);
    track
        .arg(&frames[0].0)
        .arg(&frames[1].0)
        .arg(d.join("missing.xyz"));
    track.arg(&frames[2].0).arg(&frames[3].0);
    let out = track
        .arg("--init")
        .arg(d.join("init.txt"))
        .arg("-o")
        .arg(&poses)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("1 of 5 frames failed"), "{err}");
    let lines: Vec<serde_json::Value> = std::fs::read_to_string(&poses)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 5);
    assert!(lines[2]["error"].as_str().unwrap().contains("missing.xyz"));
    let good: Vec<&serde_json::Value> = lines.iter().filter(|l| l.get("error").is_none()).collect();
    for ((_, expected), line) in frames.iter().zip(good) {
        let rows: Vec<Vec<f64>> = serde_json::from_value(line["transformation"].clone()).unwrap();
        let m = Matrix4::from_fn(|r, c| rows[r][c]);
        let (rot, tr) = pose_errors(&isometry_from_matrix(&m).unwrap(), expected);
        assert!(rot < 0.5 && tr < 0.005, "tracked frame: {rot}°, {tr}");
    }
}

/// `sdfreg batch PAIRS --output OUT` in `dir` with the quick settings.
fn batch_cmd(dir: &Path, extra: &[&str]) -> Command {
    let mut c = sdfreg();
    c.current_dir(dir)
        .args(["batch", "pairs.csv", "--output", "out.jsonl"])
        .args(QUICK)
        .args(extra);
    c
}

fn matrix_text_of(m: &Matrix4<f64>) -> String {
    (0..4)
        .map(|r| {
            format!(
                "{:e} {:e} {:e} {:e}\n",
                m[(r, 0)],
                m[(r, 1)],
                m[(r, 2)],
                m[(r, 3)]
            )
        })
        .collect()
}

/// The complete records of a batch output (header and a line cut short left out), by row.
fn batch_records(path: &Path) -> std::collections::BTreeMap<u64, serde_json::Value> {
    let text = std::fs::read_to_string(path).unwrap();
    let complete = &text[..text.rfind('\n').map_or(0, |i| i + 1)];
    let mut lines = complete.lines();
    let header: serde_json::Value = serde_json::from_str(lines.next().unwrap()).unwrap();
    assert_eq!(header["format"], "sdfreg-batch-results");
    let mut records = std::collections::BTreeMap::new();
    for line in lines {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        let row = v["row"].as_u64().unwrap();
        assert!(records.insert(row, v).is_none(), "row {row} twice");
    }
    records
}

fn transformation(v: &serde_json::Value) -> Vec<f64> {
    v["transformation"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|row| row.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()))
        .collect()
}

#[test]
fn batch_registers_each_row_as_register_does_records_failures_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let truth = pair(d);
    let fit = sdfreg()
        .current_dir(d)
        .args([
            "fit",
            "tgt.ply",
            "-o",
            "model.sdfm",
            "--prefit-steps",
            "300",
        ])
        .output()
        .unwrap();
    assert!(fit.status.success());
    std::fs::write(d.join("init.txt"), matrix_text_of(&truth.to_homogeneous())).unwrap();
    std::fs::write(
        d.join("pairs.csv"),
        "source,target,init,seed\n\
         src.xyz,tgt.ply\n\
         # a comment\n\
         src.xyz,model.sdfm,,3\n\
         missing.xyz,tgt.ply\n\
         src.xyz, tgt.ply , init.txt\n",
    )
    .unwrap();
    let out = batch_cmd(d, &[]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(err.contains("1 of 4 pairs failed"), "{err}");
    // stderr is not a terminal here: progress comes as lines, the last at 4 of 4.
    assert!(
        err.contains("sdfreg batch: 4/4 pairs (1 failed), "),
        "{err}"
    );
    assert!(err.contains(" pairs/s, "), "{err}");
    let records = batch_records(&d.join("out.jsonl"));
    assert_eq!(records.keys().copied().collect::<Vec<_>>(), [1, 2, 3, 4]);
    let ok: Vec<bool> = records
        .values()
        .map(|v| v["ok"].as_bool().unwrap())
        .collect();
    assert_eq!(ok, [true, true, false, true]);
    assert!(
        records[&3]["error"]
            .as_str()
            .unwrap()
            .contains("missing.xyz"),
        "{}",
        records[&3]
    );
    assert_eq!(records[&2]["seed"], 3);
    // Each row equals `register` of that pair with its seed, bit for bit.
    for (row, target, seed) in [(1, "tgt.ply", "0"), (2, "model.sdfm", "3")] {
        let json = d.join(format!("alone{row}.json"));
        let alone = sdfreg()
            .current_dir(d)
            .args(["register", "src.xyz", target, "--seed", seed])
            .args(QUICK)
            .arg("-o")
            .arg(&json)
            .output()
            .unwrap();
        assert!(alone.status.success());
        let alone: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert_eq!(transformation(&records[&row]), transformation(&alone));
        assert_eq!(records[&row]["stages"], alone["stages"]);
    }
    let m = Matrix4::from_row_slice(&transformation(&records[&4]));
    assert!((m - truth.to_homogeneous()).amax() < 0.02);

    // Resume after a kill that cut row 2's line short: only row 2 runs again, to the same pose.
    let text = std::fs::read_to_string(d.join("out.jsonl")).unwrap();
    let kept: Vec<&str> = text.lines().filter(|l| !l.contains("\"row\":2,")).collect();
    let row2 = text.lines().find(|l| l.contains("\"row\":2,")).unwrap();
    std::fs::write(
        d.join("out.jsonl"),
        kept.join("\n") + "\n" + &row2[..row2.len() / 2],
    )
    .unwrap();
    let out = batch_cmd(d, &[]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(err.contains("3 of 4 pairs already done, 1 to go"), "{err}");
    assert!(err.contains("dropping an incomplete last line"), "{err}");
    let resumed = batch_records(&d.join("out.jsonl"));
    assert_eq!(resumed.len(), 4);
    assert_eq!(transformation(&resumed[&2]), transformation(&records[&2]));

    // Other settings, another pairs file or a foreign output: refused, naming the file.
    let out = batch_cmd(d, &["--refine-steps", "30"]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("out.jsonl: was begun with other settings (differing: fit)"),
        "{err}"
    );
    std::fs::write(d.join("out.jsonl"), "x,y,z\n1,2,3\n").unwrap();
    let out = batch_cmd(d, &[]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("out.jsonl:1: not an sdfreg batch results file"),
        "{err}"
    );
    std::fs::write(
        d.join("pairs.csv"),
        "src.xyz,tgt.ply\nsrc.xyz,tgt.ply,a,1,extra\n",
    )
    .unwrap();
    let out = batch_cmd(d, &["--force"]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("pairs.csv:2: expected 2 to 4 fields (source,target[,init[,seed]]), found 5"),
        "{err}"
    );
    // A line of blanks is skipped; a row of empty fields is refused by line.
    std::fs::write(d.join("pairs.csv"), "src.xyz,tgt.ply\n   \n , \n").unwrap();
    let out = batch_cmd(d, &["--force"]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("pairs.csv:3: the source and the target must both be given"),
        "{err}"
    );
}

#[test]
fn a_killed_batch_loses_no_finished_pair_and_resumes_to_the_end() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    pair(d);
    let rows = 30;
    std::fs::write(d.join("pairs.csv"), "src.xyz,tgt.ply\n".repeat(rows)).unwrap();
    let mut child = batch_cmd(d, &["--threads", "2"])
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let out = d.join("out.jsonl");
    // Kill it once a few pairs are in (or let it finish on a very fast machine).
    let start = std::time::Instant::now();
    while std::fs::read_to_string(&out).map_or(0, |t| t.lines().count()) < 4
        && start.elapsed().as_secs() < 120
    {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let before = batch_records(&out);
    assert!(
        before.len() >= 3 && before.len() < rows,
        "{} done",
        before.len()
    );
    let out_status = batch_cmd(d, &["--threads", "2"]).output().unwrap();
    assert!(
        out_status.status.success(),
        "{}",
        String::from_utf8_lossy(&out_status.stderr)
    );
    let after = batch_records(&out);
    assert_eq!(
        after.keys().copied().collect::<Vec<_>>(),
        (1..=rows as u64).collect::<Vec<_>>()
    );
    // The rows done before the kill are kept as they were; every row gives the same pose.
    for (row, v) in &before {
        assert_eq!(&after[row], v);
    }
    let first = transformation(&after[&1]);
    assert!(after.values().all(|v| transformation(v) == first));
}

#[test]
fn register_onto_a_meshs_exact_distance_field() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (vertices, triangles) = sdfreg_core::sim::shapes::blob_mesh(40);
    sdfreg_core::io::write_mesh(d.join("mesh.ply"), &vertices, &triangles).unwrap();
    let m = Isometry3::from_parts(
        Translation3::new(0.1, -0.05, 0.08),
        UnitQuaternion::from_scaled_axis(Vector3::new(0.2, -0.3, 0.25)),
    );
    let cloud =
        sdfreg_core::sim::shapes::blob(1200, &mut rand_chacha::ChaCha8Rng::seed_from_u64(2));
    write_xyz(
        &d.join("scan.xyz"),
        &cloud.iter().map(|p| m * p).collect::<Vec<_>>(),
    );
    let out = sdfreg()
        .current_dir(d)
        .args(["register", "scan.xyz", "mesh.ply", "--exact-mesh"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let estimate =
        isometry_from_matrix(&parse_matrix(&String::from_utf8(out.stdout).unwrap())).unwrap();
    let (rot, trans) = pose_errors(&estimate, &m.inverse());
    assert!(rot < 0.1 && trans < 1e-3, "{rot}° {trans}");
    // A cloud is not a mesh.
    let out = sdfreg()
        .current_dir(d)
        .args(["register", "scan.xyz", "scan.xyz", "--exact-mesh"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("scan.xyz"), "{err}");
}

#[test]
fn a_local_voxel_finer_than_the_points_is_refused_at_once_naming_the_flag() {
    // The blob's 800 points are about 0.05 of its side apart: a voxel of 1e-6 would give each
    // point voxels of its own (millions of corrections); it is refused before any is built.
    let dir = tempfile::tempdir().unwrap();
    pair(dir.path());
    for command in ["fit", "register"] {
        let mut c = sdfreg();
        c.arg(command);
        if command == "register" {
            c.arg(dir.path().join("src.xyz"));
        }
        let out = c
            .arg(dir.path().join("tgt.ply"))
            .args(["--model", "local", "--local-voxel", "1e-6"])
            .args(["-o", dir.path().join("m.sdfm").to_str().unwrap()])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{command}: {err}");
        assert!(
            err.starts_with("sdfreg: --local-voxel 1e-6: invalid setting `fit.local.cells`: a local voxel of 1.000e-6"),
            "{command}: {err}"
        );
        assert!(err.contains("use a voxel of at least"), "{command}: {err}");
        assert!(!dir.path().join("m.sdfm").exists());
    }
    // The same in the target's units, named by its own flag and said in those units.
    let out = sdfreg()
        .arg("fit")
        .arg(dir.path().join("tgt.ply"))
        .args(["--local-voxel-size", "1e-7"])
        .args(["-o", dir.path().join("m.sdfm").to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.starts_with("sdfreg: --local-voxel-size 1e-7: invalid setting `fit.local.voxel_size`: a local voxel of 1.000e-7 in the target's units"),
        "{err}"
    );
    // Larger than the target: a fraction above 1, or a size above the blob's largest side.
    for (flag, value, says) in [
        ("--local-voxel", "1.5", "--local-voxel: a fraction of the target's largest side, in (0, 1]; got 1.5"),
        ("--local-voxel-size", "1e300", "--local-voxel-size 1e300: invalid setting `fit.local.voxel_size`: a local voxel of 1.000e300 in the target's units is above the target's largest side"),
    ] {
        let out = sdfreg()
            .arg("fit")
            .arg(dir.path().join("tgt.ply"))
            .args(["--model", "local", flag, value])
            .args(["-o", dir.path().join("m.sdfm").to_str().unwrap()])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{flag}: {err}");
        assert!(err.contains(says), "{flag}: {err}");
        assert!(!dir.path().join("m.sdfm").exists());
    }
}

#[test]
fn register_with_scale_finds_millimetres_against_metres_and_writes_the_scaled_source() {
    let dir = tempfile::tempdir().unwrap();
    let truth = pair(dir.path());
    // The source in millimetres: the truth is the similarity [R/1000 | t].
    let src: Vec<Point3<f64>> = sdfreg_core::io::read_point_cloud(dir.path().join("src.xyz"))
        .unwrap()
        .iter()
        .map(|p| p * 1000.0)
        .collect();
    write_xyz(&dir.path().join("src.xyz"), &src);
    let (json, aligned) = (dir.path().join("r.json"), dir.path().join("aligned.ply"));
    let out = register_cmd(dir.path())
        .args(QUICK)
        .args(["--scale", "-o"])
        .arg(&json)
        .arg("--aligned")
        .arg(&aligned)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let scale = v["scale"].as_f64().unwrap();
    assert!((scale / 1e-3 - 1.0).abs() < 0.005, "scale {scale}");
    let rows: Vec<Vec<f64>> = serde_json::from_value(v["transformation"].clone()).unwrap();
    let m = Matrix4::from_fn(|r, c| rows[r][c]);
    let mut expected = truth.to_homogeneous();
    expected.fixed_view_mut::<3, 3>(0, 0).scale_mut(1e-3);
    assert!((m - expected).amax() < 0.01, "{m} vs {expected}");
    assert_eq!(v["similarity_information"].as_array().unwrap().len(), 7);
    assert_eq!(v["scale_free"], false);
    // The aligned cloud is the source moved by the similarity: on the target, in metres.
    let moved = sdfreg_core::io::read_point_cloud(&aligned).unwrap();
    let target = sdfreg_core::io::read_point_cloud(dir.path().join("tgt.ply")).unwrap();
    let off = moved
        .iter()
        .zip(&target)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(off < 0.01, "aligned source {off} off the target");
    // A bad range is refused naming the flag; a range needs --scale.
    let out = register_cmd(dir.path())
        .args(["--scale", "--scale-range", "2", "1"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--scale-range 2 1") && err.contains("must be below"),
        "{err}"
    );
    let out = register_cmd(dir.path())
        .args(["--scale-range", "0.5", "2"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--scale"));
}

/// `n` partial views of a blob (70 % each, cut by planes of different directions), each in a
/// frame of its own, written as `view_K.ply` into `dir`; returns each view's true pose in the
/// first view's frame.
fn blob_views(dir: &Path, n: usize) -> Vec<Isometry3<f64>> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
    let shape = sdfreg_core::sim::shapes::blob(6000, &mut rng);
    let views = sdfreg_core::sim::shapes::partial_views(&shape, n);
    for (k, (view, _)) in views.iter().enumerate() {
        write_xyz(&dir.join(format!("view_{k}.ply")), view);
    }
    let first = views[0].1.inverse();
    views.iter().map(|(_, pose)| first * pose).collect()
}

#[test]
fn align_takes_each_scan_of_an_e57_file_as_a_view_in_its_own_frame() {
    let dir = tempfile::tempdir().unwrap();
    let truth = blob_views(dir.path(), 3);
    // The three views as the scans of one E57 file, as a scanner's software exports a campaign:
    // each with a name and a pose (here a wrong one: the alignment does not use it), then a scan
    // without points.
    let path = dir.path().join("campaign.e57");
    let views: Vec<Vec<Point3<f64>>> = (0..3)
        .map(|k| {
            let view = dir.path().join(format!("view_{k}.ply"));
            sdfreg_core::io::read_point_cloud(view).unwrap()
        })
        .collect();
    let names: Vec<String> = (0..4).map(|k| format!("station {k}")).collect();
    let scans: Vec<sdfreg_core::io::E57ScanRef<'_>> = (0..4)
        .map(|k| sdfreg_core::io::E57ScanRef {
            name: Some(&names[k]),
            pose: Isometry3::from_parts(
                Translation3::new(5.0 * k as f64, 1.0, 0.0),
                UnitQuaternion::from_scaled_axis(Vector3::new(1.85, 0.0, 0.0)),
            ),
            points: views.get(k).map_or(&[], Vec::as_slice),
        })
        .collect();
    sdfreg_core::io::write_e57_scans(&path, &scans).unwrap();
    let (poses, aligned) = (
        dir.path().join("poses.json"),
        dir.path().join("aligned.e57"),
    );
    let out = sdfreg()
        .arg("align")
        .arg(&path)
        .args(QUICK)
        .arg("-o")
        .arg(&poses)
        .arg("--aligned")
        .arg(&aligned)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(
        err.contains("campaign.e57#3: left out: scan 3 has no points"),
        "{err}"
    );
    assert!(
        err.contains("3 of 4 scans aligned into the frame of"),
        "{err}"
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&poses).unwrap()).unwrap();
    let scans = v["scans"].as_array().unwrap();
    let placed = sdfreg_core::views::poses_file::load_poses(&poses).unwrap();
    assert_eq!((scans.len(), placed.len()), (4, 4));
    for (k, t) in truth.iter().enumerate() {
        assert_eq!(scans[k]["file"], path.display().to_string());
        assert_eq!(
            (scans[k]["scan"].as_u64(), scans[k]["name"].as_str()),
            (Some(k as u64), Some(format!("station {k}").as_str()))
        );
        let m = placed[k].unwrap().to_homogeneous();
        assert!((m - t.to_homogeneous()).amax() < 0.01, "scan {k}: {m}");
    }
    assert!(placed[3].is_none() && scans[3]["scan"] == 3);
    let edge = &v["edges"][0];
    let named = format!("{}#", path.display());
    assert!(
        edge["target"].as_str().unwrap().starts_with(&named),
        "{edge}"
    );
    // --aligned: the placed scans as a registered campaign, each its points as read, its name
    // and its pose into the anchor's frame.
    let (back, _) = sdfreg_core::io::read_e57_scans(&aligned, false).unwrap();
    assert_eq!(back.len(), 3);
    for (k, scan) in back.iter().enumerate() {
        let view = format!("view_{k}.ply");
        let points = sdfreg_core::io::read_point_cloud(dir.path().join(view)).unwrap();
        assert_eq!(scan.points, points);
        assert_eq!(scan.name, Some(format!("station {k}")));
        let off = (scan.pose.to_homogeneous() - truth[k].to_homogeneous()).amax();
        assert!(off < 0.01, "scan {k}: {off}");
    }
    // An E57 file of one scan is that scan placed by its pose, as every command reads it: the
    // anchor's frame is the placed one, so --aligned writes its points placed.
    let placing = Isometry3::from_parts(
        Translation3::new(2.0, 0.0, -1.0),
        UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.5, 0.0)),
    );
    let first = &back[0];
    let one = sdfreg_core::io::E57ScanRef {
        name: None,
        pose: placing,
        points: &first.points,
    };
    sdfreg_core::io::write_e57_scans(dir.path().join("one.e57"), &[one]).unwrap();
    let placed = dir.path().join("placed.ply");
    let out = sdfreg()
        .arg("align")
        .arg(dir.path().join("one.e57"))
        .arg(dir.path().join("view_1.ply"))
        .args(QUICK)
        .arg("-o")
        .arg(dir.path().join("one.json"))
        .arg("--aligned")
        .arg(&placed)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let placed = sdfreg_core::io::read_point_cloud(&placed).unwrap();
    let off = first
        .points
        .iter()
        .zip(&placed)
        .map(|(p, q)| (placing * p - q).norm())
        .fold(0.0, f64::max);
    assert!(off < 1e-12, "the one scan {off} off its placed points");
}

#[test]
fn align_puts_views_into_one_frame_and_leaves_out_an_unreadable_scan_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let truth = blob_views(dir.path(), 3);
    std::fs::write(dir.path().join("broken.xyz"), "1 2 3\n4 five 6\n").unwrap();
    let (poses, model, mesh) = (
        dir.path().join("poses.json"),
        dir.path().join("merged.sdfm"),
        dir.path().join("merged.ply"),
    );
    let mut cmd = sdfreg();
    cmd.arg("align");
    for f in ["view_0.ply", "view_1.ply", "broken.xyz", "view_2.ply"] {
        cmd.arg(dir.path().join(f));
    }
    let out = cmd
        .args(QUICK)
        .arg("-o")
        .arg(&poses)
        .arg("--save-model")
        .arg(&model)
        .arg("--mesh")
        .arg(&mesh)
        .args(["--mesh-resolution", "48", "--max-distance", "0.02"])
        .arg("--aligned")
        .arg(dir.path().join("placed.xyz"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(
        err.contains("broken.xyz: left out") && err.contains("broken.xyz:2: expected three"),
        "{err}"
    );
    assert!(
        err.contains("sdfreg: within 0.02 of the other scans: "),
        "{err}"
    );
    let text = std::fs::read_to_string(&poses).unwrap();
    // The header first, as written (`head -3 poses.json` tells what the file is).
    let keys: Vec<&str> = text.lines().skip(1).take(3).map(|l| l.trim()).collect();
    assert!(
        keys[0].starts_with("\"format\": \"sdfreg-poses\"") && keys[1].starts_with("\"version\""),
        "{keys:?}"
    );
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let scans = v["scans"].as_array().unwrap();
    assert_eq!(scans.len(), 4);
    assert!(scans[2]["transformation"].is_null() && scans[2]["left_out"].is_string());
    for (k, t) in [(0, truth[0]), (1, truth[1]), (3, truth[2])] {
        let rows: Vec<Vec<f64>> =
            serde_json::from_value(scans[k]["transformation"].clone()).unwrap();
        let m = Matrix4::from_fn(|r, c| rows[r][c]);
        let err = (m - t.to_homogeneous()).amax();
        assert!(err < 0.01, "scan {k}: {m} vs {}", t.to_homogeneous());
        assert!(scans[k]["fitness"].as_f64().unwrap() > 0.5);
        // --max-distance: how well the view lies on the other two, as evaluate_registration.
        let e = &scans[k]["evaluation"];
        assert_eq!(e["max_distance"], 0.02);
        assert!(e["fitness"].as_f64().unwrap() > 0.8, "{e}");
        assert!(e["inlier_rmse"].as_f64().unwrap() < 0.02, "{e}");
    }
    assert!(scans[2].get("evaluation").is_none());
    // --aligned in a cloud format: the three placed views' points in view 0's frame, in order.
    let placed = sdfreg_core::io::read_point_cloud(dir.path().join("placed.xyz")).unwrap();
    let mut expected = Vec::new();
    for (k, t) in truth.iter().enumerate() {
        let view = sdfreg_core::io::read_point_cloud(dir.path().join(format!("view_{k}.ply")));
        expected.extend(view.unwrap().into_iter().map(|p| t * p));
    }
    assert_eq!(placed.len(), expected.len());
    let off = placed
        .iter()
        .zip(&expected)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(off < 0.02, "placed points {off} off");
    assert!(!v["edges"].as_array().unwrap().is_empty());
    assert!(v["stage_ms"]["pairs"].as_f64().unwrap() > 0.0);
    assert_eq!(
        (v["format"].as_str(), v["version"].as_u64()),
        (Some("sdfreg-poses"), Some(1))
    );
    // Read back as --init: the left-out scan has no pose to start from (its pairs would start
    // from nothing; unreadable, it is left out again); a foreign file is refused by name; the
    // three views' poses start a run that keeps them.
    let init = |scans: &[&str], file: &std::path::Path| {
        let mut cmd = sdfreg();
        cmd.arg("align");
        for f in scans {
            cmd.arg(dir.path().join(f));
        }
        let out = dir.path().join("again.json");
        let _ = std::fs::remove_file(&out);
        let run = cmd
            .args(QUICK)
            .arg("--init")
            .arg(file)
            .arg("-o")
            .arg(&out)
            .output()
            .unwrap();
        (run, out)
    };
    let views = ["view_0.ply", "view_1.ply", "view_2.ply"];
    let (run, out) = init(
        &["view_0.ply", "view_1.ply", "broken.xyz", "view_2.ply"],
        &poses,
    );
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(3), "{err}");
    let again = sdfreg_core::views::poses_file::load_poses(&out).unwrap();
    assert!(again[2].is_none());
    for (k, t) in [(0, truth[0]), (1, truth[1]), (3, truth[2])] {
        let m = again[k].unwrap().to_homogeneous();
        assert!((m - t.to_homogeneous()).amax() < 0.01, "scan {k}: {m}");
    }
    let (run, _) = init(&views, &model);
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{err}");
    assert!(
        err.contains("merged.sdfm:") && err.contains("not a poses file"),
        "{err}"
    );
    let mut readable = v.clone();
    readable["scans"] = serde_json::json!([scans[0], scans[1], scans[3]]);
    let three = dir.path().join("three.json");
    std::fs::write(&three, readable.to_string()).unwrap();
    let (run, out) = init(&views, &three);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let again = sdfreg_core::views::poses_file::load_poses(&out).unwrap();
    for (k, t) in truth.iter().enumerate() {
        let m = again[k].unwrap().to_homogeneous();
        assert!((m - t.to_homogeneous()).amax() < 0.01, "scan {k}: {m}");
    }
    // A bad --max-distance is refused before any registration, naming the flag.
    let out = sdfreg()
        .current_dir(dir.path())
        .args(["align", "view_0.ply", "view_1.ply", "-o", "bad.json"])
        .arg("--max-distance=-1")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--max-distance -1: must be a positive finite number"),
        "{err}"
    );
    assert!(!dir.path().join("bad.json").exists());
    // The merged model loads, and its mesh is a surface.
    assert!(sdfreg_core::SdfModel::load(&model).is_ok());
    let (vertices, triangles) = sdfreg_core::io::read_mesh(&mesh).unwrap();
    assert!(vertices.len() > 100 && !triangles.is_empty());
    // Fewer than two readable scans: a clear error, exit 2; outputs are not overwritten.
    let out = sdfreg()
        .arg("align")
        .arg(dir.path().join("view_0.ply"))
        .arg(dir.path().join("broken.xyz"))
        .arg("-o")
        .arg(dir.path().join("other.json"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("at least two scans"));
    let out = sdfreg()
        .arg("align")
        .arg(dir.path().join("view_0.ply"))
        .arg(dir.path().join("view_1.ply"))
        .args(["--scale", "-o"])
        .arg(dir.path().join("other.json"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--scale: align registers rigidly"));
    // A view the free-space check cannot read is refused by the flag's name.
    let out = sdfreg()
        .arg("align")
        .arg(dir.path().join("view_0.ply"))
        .arg(dir.path().join("view_1.ply"))
        .args(["--seen-from", "0,0,0", "-o"])
        .arg(dir.path().join("other.json"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--seen-from") && err.contains("not zero"),
        "{err}"
    );
    let out = sdfreg()
        .arg("align")
        .arg(dir.path().join("view_0.ply"))
        .arg(dir.path().join("view_1.ply"))
        .arg("-o")
        .arg(&poses)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn a_source_that_fits_a_local_model_poorly_gets_a_warning_naming_the_global_kind() {
    use rand::Rng;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    pair(d);
    // Points drawn anywhere in the blob's box: they lie on no surface of it.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
    let scattered: Vec<Point3<f64>> = (0..600)
        .map(|_| Point3::from(Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0))))
        .collect();
    write_xyz(&d.join("scattered.xyz"), &scattered);
    for kind in ["local", "global"] {
        let out = sdfreg()
            .args(["fit", "--model-prefit-steps", "200", "--model", kind, "-o"])
            .arg(d.join(format!("{kind}.sdfm")))
            .arg(d.join("tgt.ply"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{err}");
    }
    let warned = |kind: &str, source: &str| {
        let model = d.join(format!("{kind}.sdfm"));
        let out = sdfreg()
            .arg("register")
            .arg(d.join(source))
            .arg(&model)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(out.status.success(), "{err}");
        err.contains("warning: the source fits") && err.contains("sdfreg fit --model global")
    };
    assert!(warned("local", "scattered.xyz"));
    assert!(!warned("global", "scattered.xyz"));
    assert!(!warned("local", "src.xyz"));
}

#[test]
fn fitness_measures_a_transformation_at_a_distance_in_the_clouds_units() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let truth = pair(d);
    let fitness = |extra: &[&str]| {
        sdfreg()
            .arg("fitness")
            .arg(d.join("src.xyz"))
            .arg(d.join("tgt.ply"))
            .args(extra)
            .output()
            .unwrap()
    };
    // The true transformation as text: every point on its counterpart.
    std::fs::write(d.join("truth.txt"), matrix_text_of(&truth.to_homogeneous())).unwrap();
    let out = fitness(&[
        "-t",
        d.join("truth.txt").to_str().unwrap(),
        "--max-distance",
        "1e-6",
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.starts_with("fitness 1.000000 (800 of 800 source points within 1e-6)"),
        "{text}"
    );
    // The clouds as they are (identity), as JSON: few points near, the same count in the file.
    let json = d.join("f.json");
    let out = fitness(&["--max-distance", "0.05", "-o", json.to_str().unwrap()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let f: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(f["source_points"], 800);
    assert_eq!(f["max_distance"], 0.05);
    let fit = f["fitness"].as_f64().unwrap();
    assert!(fit < 0.5, "{fit}");
    assert_eq!(f["inliers"].as_f64().unwrap(), (fit * 800.0).round());
    // register's JSON serves as the transformation.
    let result = d.join("r.json");
    let out = register_cmd(d)
        .args(QUICK)
        .arg("-o")
        .arg(&result)
        .output()
        .unwrap();
    assert!(out.status.success());
    let out = fitness(&["-t", result.to_str().unwrap(), "--max-distance", "0.01"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.starts_with("fitness 1.000000 (800 of 800"), "{text}");
    // Refused by name: an existing output, a distance, a matrix that is no similarity, a JSON
    // without a transformation.
    std::fs::write(
        d.join("shear.txt"),
        "1 0.5 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
    )
    .unwrap();
    std::fs::write(d.join("other.json"), "{\"x\": 1}").unwrap();
    for (extra, says) in [
        (
            vec!["--max-distance", "0.05", "-o", json.to_str().unwrap()],
            "f.json: exists; pass --force to overwrite",
        ),
        (
            vec!["--max-distance=-1"],
            "--max-distance -1: invalid setting `max_distance`: must be a positive finite number",
        ),
        (
            vec![
                "--max-distance",
                "1",
                "-t",
                d.join("shear.txt").to_str().unwrap(),
            ],
            "shear.txt: transformation is not a finite similarity",
        ),
        (
            vec![
                "--max-distance",
                "1",
                "-t",
                d.join("other.json").to_str().unwrap(),
            ],
            "other.json: expected a `transformation` of 4 rows of 4 numbers",
        ),
    ] {
        let out = fitness(&extra);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{extra:?}: {err}");
        assert!(err.contains(says), "{err}");
    }
}

#[test]
fn fitness_against_a_model_or_a_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let truth = pair(d);
    std::fs::write(d.join("truth.txt"), matrix_text_of(&truth.to_homogeneous())).unwrap();
    let run = |args: &[&str]| sdfreg().current_dir(d).args(args).output().unwrap();
    let stdout = |out: &std::process::Output| {
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    // A model holds the target points it was fitted to: the same figures as the cloud.
    let fit = run(&[&["fit", "tgt.ply", "-o", "tgt.sdfm"][..], &QUICK[..]].concat());
    stdout(&fit);
    for distance in ["1e-6", "0.05"] {
        let args = ["-t", "truth.txt", "--max-distance", distance];
        let by_cloud = run(&[&["fitness", "src.xyz", "tgt.ply"][..], &args[..]].concat());
        let by_model = run(&[&["fitness", "src.xyz", "tgt.sdfm"][..], &args[..]].concat());
        let (by_cloud, by_model) = (stdout(&by_cloud), stdout(&by_model));
        assert_eq!(by_cloud, by_model);
        assert!(
            by_model.starts_with("fitness 1.000000 (800 of 800"),
            "{by_model}"
        );
    }
    // A mesh's exact distance: the blob mesh's vertices, 0.01 out along the normals.
    let (vertices, triangles) = sdfreg_core::sim::shapes::blob_mesh(40);
    sdfreg_core::io::write_mesh(d.join("mesh.ply"), &vertices, &triangles).unwrap();
    let mesh = sdfreg_core::MeshModel::new(
        &vertices,
        &triangles,
        &sdfreg_core::RegisterSettings::default(),
    )
    .unwrap();
    let (_, normals) = mesh.evaluate(&vertices);
    let off: Vec<Point3<f64>> = vertices
        .iter()
        .zip(&normals)
        .map(|(p, n)| p + n.normalize() * 0.01)
        .collect();
    write_xyz(&d.join("off.xyz"), &off);
    let against_mesh = |extra: &[&str]| {
        let fixed = [
            "fitness",
            "off.xyz",
            "mesh.ply",
            "--exact-mesh",
            "--max-distance",
        ];
        stdout(&run(&[&fixed[..], extra].concat()))
    };
    let out = against_mesh(&["0.012", "-o", "m.json"]);
    assert!(out.starts_with("fitness 1.000000"), "{out}");
    let f: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("m.json")).unwrap()).unwrap();
    let rmse = f["inlier_rmse"].as_f64().unwrap();
    assert!((rmse - 0.01).abs() < 5e-4, "{rmse}");
    let out = against_mesh(&["0.008"]);
    assert!(out.starts_with("fitness 0.0"), "{out}");
    // Refused by name: a cloud given as a mesh; a source too small, named by its file.
    write_xyz(&d.join("few.xyz"), &off[..4]);
    for (args, says) in [
        (
            vec![
                "fitness",
                "off.xyz",
                "src.xyz",
                "--exact-mesh",
                "--max-distance",
                "1",
            ],
            "src.xyz: meshes are read from PLY files",
        ),
        (
            vec!["fitness", "few.xyz", "tgt.sdfm", "--max-distance", "1"],
            "few.xyz: source cloud has 4 points",
        ),
    ] {
        let out = run(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(says), "{err}");
    }
}

/// `sdfreg transform` writes a file moved by a 4×4 with its other fields, and back with
/// `--inverse`; it refuses to overwrite without --force and names a matrix that is no
/// similarity.
#[test]
fn transform_moves_a_file_with_its_fields_and_back() {
    let dir = tempfile::tempdir().unwrap();
    let mut ply = String::from("ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\nproperty uchar red\nend_header\n");
    let points = [[1.0, 2.0, 3.0], [-0.5, 0.25, 4.0], [0.0, 1.0, -2.0]];
    for (i, p) in points.iter().enumerate() {
        ply += &format!("{} {} {} {}\n", p[0], p[1], p[2], 10 + i);
    }
    let (input, moved, back) = (
        dir.path().join("in.ply"),
        dir.path().join("moved.ply"),
        dir.path().join("back.ply"),
    );
    std::fs::write(&input, &ply).unwrap();
    // 2 × a quarter turn about z, then a shift.
    let matrix = dir.path().join("m.txt");
    std::fs::write(&matrix, "0 -2 0 1\n2 0 0 -1\n0 0 2 0.5\n0 0 0 1\n").unwrap();
    let run = |from: &Path, to: &Path, extra: &[&str]| {
        sdfreg()
            .arg("transform")
            .arg(from)
            .arg(to)
            .arg("-t")
            .arg(&matrix)
            .args(extra)
            .output()
            .unwrap()
    };
    let out = run(&input, &moved, &[]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("3 points of") && stderr.contains("every other field kept"),
        "{stderr}"
    );
    // Each row: the point moved (to the rounding of the matrix's decomposition), its colour.
    let rows = |path: &Path| -> Vec<Vec<f64>> {
        let text = std::fs::read_to_string(path).unwrap();
        assert!(text.starts_with(&ply[..ply.find("end_header").unwrap()]));
        text.lines()
            .skip(8)
            .map(|row| row.split(' ').map(|f| f.parse().unwrap()).collect())
            .collect()
    };
    for (v, (p, i)) in rows(&moved).iter().zip(points.iter().zip(10..)) {
        let want = [-2.0 * p[1] + 1.0, 2.0 * p[0] - 1.0, 2.0 * p[2] + 0.5];
        assert!(
            (0..3).all(|k| (v[k] - want[k]).abs() < 1e-12),
            "{v:?} against {want:?}"
        );
        assert_eq!(v[3], i as f64);
    }
    let out = run(&moved, &back, &["--inverse"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for (v, (p, i)) in rows(&back).iter().zip(points.iter().zip(10..)) {
        assert!(
            (0..3).all(|k| (v[k] - p[k]).abs() < 1e-12),
            "{v:?} against {p:?}"
        );
        assert_eq!(v[3], i as f64);
    }
    let out = run(&moved, &back, &["--inverse"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("back.ply: exists; pass --force"));
    // From a poses file (`sdfreg align --output`): the pose of the scan whose file is INPUT,
    // or of scan K; a scan left out has none, a file that is none of its scans is named.
    let poses = dir.path().join("poses.json");
    let turn = "[[0, -1, 0, 0.5], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]";
    let file = input.display().to_string().replace('\\', "/");
    std::fs::write(&poses, format!("{{\"format\": \"sdfreg-poses\", \"version\": 1, \"scans\": [{{\"file\": \"other.ply\", \"transformation\": null, \"left_out\": \"fits nowhere\"}}, {{\"file\": \"{file}\", \"transformation\": {turn}}}]}}")).unwrap();
    let run_poses = |to: &Path, extra: &[&str]| {
        sdfreg()
            .arg("transform")
            .arg(&input)
            .arg(to)
            .arg("-t")
            .arg(&poses)
            .args(extra)
            .output()
            .unwrap()
    };
    let posed = dir.path().join("posed.ply");
    let out = run_poses(&posed, &[]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for (v, p) in rows(&posed).iter().zip(&points) {
        let want = [-p[1] + 0.5, p[0], p[2]];
        assert!(
            (0..3).all(|k| (v[k] - want[k]).abs() < 1e-12),
            "{v:?} against {want:?}"
        );
    }
    let out = run_poses(&posed, &["--force", "--scan", "0"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("scan 0 (other.ply) was left out"),
        "{stderr}"
    );
    let out = sdfreg()
        .arg("transform")
        .arg(&moved)
        .arg(dir.path().join("x.ply"))
        .arg("-t")
        .arg(&poses)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("no scan of") && stderr.contains("--scan K"),
        "{stderr}"
    );
    std::fs::write(&matrix, "1 0 0 0\n0 2 0 0\n0 0 1 0\n0 0 0 1\n").unwrap();
    let out = run(&input, &back, &["--force"]);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("m.txt: the matrix is not a similarity"),
        "{stderr}"
    );
}

//! The `sdfreg` binary: output formats, exit codes and one-line errors.

use std::path::Path;
use std::process::Command;

use nalgebra::{Isometry3, Matrix4, Point3, Translation3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use sdfreg_core::protocol::pose_errors;
use sdfreg_core::se3::isometry_from_matrix;

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
    let target = sdfreg_core::shapes::blob(800, &mut rand_chacha::ChaCha8Rng::seed_from_u64(9));
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

const QUICK: [&str; 4] = ["--prefit-steps", "300", "--alternations", "5"];

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
    assert!(!String::from_utf8_lossy(&out.stderr).contains("warning"));
    let moved = sdfreg_core::io::read_point_cloud(&aligned).unwrap();
    assert_eq!(moved.len(), 800);

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

#[test]
fn bad_input_exits_2_with_one_line_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    pair(dir.path());
    let bad = dir.path().join("bad.xyz");
    std::fs::write(&bad, "1 2 3\n4 five 6\n").unwrap();
    let cases: Vec<(Vec<std::ffi::OsString>, &str)> = vec![
        (
            vec![bad.clone().into(), dir.path().join("tgt.ply").into()],
            "bad.xyz:2: expected three numbers",
        ),
        (
            vec![
                dir.path().join("missing.ply").into(),
                dir.path().join("tgt.ply").into(),
            ],
            "missing.ply",
        ),
        (
            vec![
                dir.path().join("src.obj").into(),
                dir.path().join("tgt.ply").into(),
            ],
            "unknown point-cloud format",
        ),
    ];
    for (args, expected) in cases {
        let out = sdfreg().arg("register").args(&args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{err}");
        assert!(err.contains(expected), "expected {expected:?} in {err:?}");
        assert_eq!(err.trim_end().lines().count(), 1, "one line: {err:?}");
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
    // The source as PCD, and a copy with two NaN rows (as a range scanner writes them).
    let src = sdfreg_core::io::read_point_cloud(dir.path().join("src.xyz")).unwrap();
    sdfreg_core::io::write_point_cloud(dir.path().join("src.pcd"), &src).unwrap();
    let mut text = std::fs::read_to_string(dir.path().join("src.xyz")).unwrap();
    text.insert_str(0, "nan nan nan\n");
    text.push_str("1 NaN 2\n");
    std::fs::write(dir.path().join("holes.xyz"), text).unwrap();
    let tgt = dir.path().join("tgt.ply");
    let refused = sdfreg()
        .arg("register")
        .arg(dir.path().join("holes.xyz"))
        .arg(&tgt)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(2), "{err}");
    assert!(
        err.contains("holes.xyz:1: point 0 has a non-finite coordinate"),
        "{err}"
    );
    for (source, extra) in [("holes.xyz", Some("--drop-non-finite")), ("src.pcd", None)] {
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
            assert!(err.contains("holes.xyz: dropped 2 of 802 points"), "{err}");
        }
        let m = parse_matrix(&String::from_utf8_lossy(&out.stdout));
        let (rot, tr) = pose_errors(&isometry_from_matrix(&m).unwrap(), &truth);
        assert!(rot < 1.0 && tr < 0.01, "{source}: {rot}°, {tr}");
    }
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
fn eval_writes_pairs_others_can_rerun_and_scores_every_protocol() {
    let dir = tempfile::tempdir().unwrap();
    let shapes = dir.path().join("shapes");
    std::fs::create_dir_all(shapes.join("b")).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
    write_xyz(
        &shapes.join("a.ply"),
        &sdfreg_core::shapes::blob(3000, &mut rng),
    );
    write_xyz(
        &shapes.join("b").join("bracket.ply"),
        &sdfreg_core::shapes::bracket(3000, &mut rng),
    );
    let pairs = dir.path().join("pairs");
    let json = dir.path().join("eval.json");
    let out = sdfreg()
        .args([
            "eval",
            "--pairs",
            "2",
            "--protocol",
            "clean,anyrot,partial-indep",
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
    for name in ["| clean | 2 |", "| anyrot | 2 |", "| partial-indep | 2 |"] {
        assert!(stdout.contains(name), "{stdout}");
    }
    // Every written pair: the ground truth moves the source onto the target's surface.
    let index: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(pairs.join("pairs.json")).unwrap()).unwrap();
    let listed = index["pairs"].as_array().unwrap();
    assert_eq!(listed.len(), 6);
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
    }
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

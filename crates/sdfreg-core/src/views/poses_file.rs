//! The poses file of an alignment (`sdfreg align SCAN... --output poses.json`,
//! `Alignment.to_json()` in Python): JSON, written by [`poses_json`], read back by
//! [`load_poses`] (`sdfreg align --init`, `sdfreg.read_poses`) through [`read_poses`].
//!
//! Layout (version 1), one object:
//! - `"format": "sdfreg-poses"`, `"version": 1`, `"sdfreg"` (the version that wrote it),
//!   `"convention"` (in words: each transformation maps its scan's coordinates into the anchor
//!   scan's frame), `"anchor"` (the anchor scan's name);
//! - `"scans"`: per input scan, in the order given, `"file"` (its name), `"transformation"` (the
//!   4×4 as row-major nested lists; `null` for a scan left out, with `"left_out"` saying why) and
//!   `"fitness"` (the best fitness of a kept edge it is part of; absent for a scan that could
//!   not be read), and with `sdfreg align --max-distance` its `"evaluation"` (how well it lies on
//!   the others: [`crate::Alignment::evaluate`]'s `"fitness"`, `"inlier_rmse"`, `"inliers"`,
//!   `"source_points"`, `"max_distance"`);
//! - `"edges"`: every pairwise registration tried, `"target"`, `"source"` (names), `"fitness"`,
//!   `"kept"` (whether the pose graph kept it), `"transformation"` (source into target) or
//!   `"error"`, and `"in_free_space"` when that check ran;
//! - `"time_ms"`, `"stage_ms"` (models, pairs, graph, unplaced, consensus, joint) and
//!   `"consensus"` (what the multi-view refinement did; zeros when it did not run).
//!
//! [`read_poses`] takes the `"scans"` list's transformations. It refuses a file that is not
//! JSON (naming the line), another program's or another sdfreg file (a `"format"` other than
//! this one, or no `"scans"` list), a newer version, and a transformation that is not a rigid
//! 4×4 of finite numbers, naming the file and the scan. A file without `"format"` is read as
//! long as its `"scans"` hold transformations: a poses file written by hand (a turntable's
//! angles, odometry) and those of sdfreg before the header.

use std::path::Path;

use nalgebra::Isometry3;
use serde_json::Value;

use crate::base::error::IoError;
use crate::geometry::se3::{isometry_from_matrix, matrix_from_rows, matrix_rows};
use crate::views::align::Alignment;

/// The `"format"` of a poses file.
pub const FORMAT: &str = "sdfreg-poses";
/// The newest version this build reads and the one it writes.
pub const VERSION: u64 = 1;

/// The poses file of `alignment` (see the module docs). `files` names every input scan, in the
/// order given (readable or not); `index[k]` is the input position of the `k`-th scan given to
/// [`crate::align`]; `unreadable` lists the input positions that could not be read, with why.
/// Scans given to [`crate::align`] directly: `index` is `0..n`, `unreadable` empty.
pub fn poses_json(
    alignment: &Alignment,
    files: &[String],
    index: &[usize],
    unreadable: &[(usize, String)],
) -> Value {
    let name = |k: usize| files[index[k]].clone();
    let scans: Vec<Value> = files
        .iter()
        .enumerate()
        .map(|(f, file)| {
            if let Some((_, why)) = unreadable.iter().find(|(k, _)| *k == f) {
                return serde_json::json!({"file": file, "transformation": null, "left_out": why});
            }
            let Some(k) = index.iter().position(|&i| i == f) else {
                return serde_json::json!({"file": file, "transformation": null,
                    "left_out": "not given to the alignment"});
            };
            let mut v = serde_json::json!({
                "file": file,
                "transformation": alignment.poses[k].map(|p| matrix_rows(&p.to_homogeneous())),
                "fitness": alignment.fitness[k],
            });
            if let Some((_, why)) = alignment.left_out.iter().find(|(i, _)| *i == k) {
                v["left_out"] = why.clone().into();
            }
            v
        })
        .collect();
    let edges: Vec<Value> = alignment
        .edges
        .iter()
        .map(|e| {
            let mut v = serde_json::json!({
                "target": name(e.target),
                "source": name(e.source),
                "fitness": e.fitness(),
                "kept": e.kept,
            });
            match &e.registration {
                Ok(r) => v["transformation"] = matrix_rows(&r.matrix()).into(),
                Err(why) => v["error"] = why.clone().into(),
            }
            if let Some(share) = e.in_free_space {
                v["in_free_space"] = share.into();
            }
            v
        })
        .collect();
    let t = &alignment.times;
    let c = &alignment.consensus;
    serde_json::json!({
        "format": FORMAT,
        "version": VERSION,
        "sdfreg": env!("CARGO_PKG_VERSION"),
        "convention": "transformation maps the scan's coordinates into the anchor scan's frame",
        "anchor": name(alignment.anchor),
        "scans": scans,
        "edges": edges,
        "time_ms": alignment.time.as_secs_f64() * 1e3,
        "stage_ms": {
            "models": t.models.as_secs_f64() * 1e3,
            "pairs": t.pairs.as_secs_f64() * 1e3,
            "graph": t.graph.as_secs_f64() * 1e3,
            "unplaced": t.unplaced.as_secs_f64() * 1e3,
            "consensus": t.consensus.as_secs_f64() * 1e3,
            "joint": t.joint.as_secs_f64() * 1e3,
        },
        "consensus": {
            "pairs": c.pairs,
            "iterations": c.iterations,
            "mean_residual_before": c.before,
            "mean_residual_after": c.after,
            "undone": c.undone,
        },
    })
}

/// Per scan of the poses file at `path`, its transformation or `None` ([`read_poses`] of the
/// file's bytes); an [`IoError::Io`] when the file cannot be read.
pub fn load_poses(path: &Path) -> Result<Vec<Option<Isometry3<f64>>>, IoError> {
    let bytes = std::fs::read(path).map_err(|source| IoError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    read_poses(&bytes, path)
}

/// Per scan of a poses file's contents (`path` names it in errors), in order, its
/// transformation (scan into the anchor's frame), `None` for a scan written without one (left
/// out). See the module docs for what is refused.
pub fn read_poses(bytes: &[u8], path: &Path) -> Result<Vec<Option<Isometry3<f64>>>, IoError> {
    let bad = |line: Option<usize>, message: String| IoError::Parse {
        path: path.to_path_buf(),
        line,
        message,
    };
    let v: Value = serde_json::from_slice(bytes).map_err(|e| {
        bad(
            (e.line() > 0).then_some(e.line()),
            format!("not a poses file ({FORMAT} JSON): {e}"),
        )
    })?;
    let Some(top) = v.as_object() else {
        return Err(bad(
            None,
            format!("not a poses file ({FORMAT}): the JSON is not an object"),
        ));
    };
    if let Some(format) = top.get("format") {
        if format.as_str() != Some(FORMAT) {
            return Err(bad(
                None,
                format!("\"format\" is {format}, not {FORMAT:?}: not a poses file"),
            ));
        }
        match top.get("version").and_then(Value::as_u64) {
            Some(v) if (1..=VERSION).contains(&v) => {}
            Some(0) => {
                return Err(bad(
                    None,
                    "poses file version 0: no sdfreg writes it".into(),
                ))
            }
            Some(v) => {
                return Err(bad(
                    None,
                    format!("poses file version {v} is newer than this build reads ({VERSION})"),
                ))
            }
            None => return Err(bad(None, "no \"version\" number".into())),
        }
    }
    let Some(scans) = top.get("scans").and_then(Value::as_array) else {
        return Err(bad(
            None,
            format!("no \"scans\" list: not a poses file ({FORMAT})"),
        ));
    };
    scans
        .iter()
        .enumerate()
        .map(|(k, s)| match s.get("transformation") {
            Some(Value::Null) => Ok(None),
            Some(m) => matrix_from_rows(m)
                .and_then(|m| isometry_from_matrix(&m))
                .map(Some)
                .ok_or_else(|| {
                    bad(
                        None,
                        format!(
                            "scans[{k}].transformation is not a rigid 4×4 matrix of finite numbers"
                        ),
                    )
                }),
            None => Err(bad(None, format!("scans[{k}] has no \"transformation\""))),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn read(text: &str) -> Result<Vec<Option<Isometry3<f64>>>, IoError> {
        read_poses(text.as_bytes(), Path::new("poses.json"))
    }

    fn message(text: &str) -> String {
        read(text).expect_err(text).to_string()
    }

    #[test]
    fn a_written_pose_reads_back_to_the_last_bit_and_a_left_out_scan_as_none() {
        let pose = Isometry3::from_parts(
            Translation3::new(0.1, -2.5, 3e-7),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.3, -0.2, 1.1)),
        );
        let file = serde_json::json!({
            "format": FORMAT, "version": VERSION,
            "scans": [
                {"file": "a.ply", "transformation": matrix_rows(&Isometry3::identity().to_homogeneous())},
                {"file": "b.ply", "transformation": matrix_rows(&pose.to_homogeneous())},
                {"file": "c.ply", "transformation": null, "left_out": "fits nowhere"},
            ],
        });
        let poses = read(&file.to_string()).unwrap();
        assert_eq!(poses.len(), 3);
        assert_eq!(poses[0], Some(Isometry3::identity()));
        let back = poses[1].unwrap();
        assert!((back.to_homogeneous() - pose.to_homogeneous()).amax() < 1e-15);
        assert_eq!(poses[2], None);
    }

    #[test]
    fn a_hand_written_file_without_the_header_is_read() {
        let eye = "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]";
        let poses = read(&format!(r#"{{"scans": [{{"transformation": {eye}}}]}}"#)).unwrap();
        assert_eq!(poses, vec![Some(Isometry3::identity())]);
    }

    #[test]
    fn truncated_foreign_newer_and_malformed_files_are_refused_by_name() {
        let eye = "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]";
        let good = format!(
            r#"{{"format": "sdfreg-poses", "version": 1, "scans": [{{"transformation": {eye}}}]}}"#
        );
        assert!(read(&good).is_ok());
        // Cut short anywhere: refused, naming the file.
        for n in 0..good.len() {
            assert!(message(&good[..n]).starts_with("poses.json"), "{n}");
        }
        assert!(message("{\n\"scans\": [1,\n2,,]}").starts_with("poses.json:3: not a poses file"));
        assert!(message("[1, 2]").contains("not an object"));
        // Another sdfreg file: a batch log's header, a registration's result.
        assert!(
            message(r#"{"format": "sdfreg-batch-results", "version": 1}"#)
                .contains("not a poses file")
        );
        assert!(
            message(&format!(r#"{{"transformation": {eye}, "fitness": 1}}"#))
                .contains("no \"scans\" list")
        );
        assert!(message(&good.replace("\"version\": 1", "\"version\": 2")).contains("newer"));
        assert!(message(&good.replace("\"version\": 1", "\"version\": 0")).contains("version 0"));
        assert!(message(&good.replace("\"version\": 1", "\"version\": \"1\"")).contains("version"));
        // Not rigid, not 4×4, not numbers, missing.
        for m in [
            "[[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]",
            "[[1,0,0],[0,1,0],[0,0,1]]",
            "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1],[0,0,0,1]]",
            "[[1,0,0,\"x\"],[0,1,0,0],[0,0,1,0],[0,0,0,1]]",
            "\"identity\"",
        ] {
            let text =
                format!(r#"{{"scans": [{{"transformation": {eye}}}, {{"transformation": {m}}}]}}"#);
            let e = message(&text);
            assert!(
                e.starts_with("poses.json") && e.contains("scans[1].transformation"),
                "{m}: {e}"
            );
        }
        assert!(message(r#"{"scans": [{"file": "a.ply"}]}"#).contains("scans[0] has no"));
        // An infinite number is not JSON: refused by the parser, naming the file.
        assert!(message(&good.replace("[1,0,0,0]", "[1,0,0,1e999]")).starts_with("poses.json:1"));
    }
}

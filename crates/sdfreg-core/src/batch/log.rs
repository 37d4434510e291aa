//! The results file of a batch (`sdfreg batch PAIRS.csv --output RESULTS.jsonl`): JSON Lines,
//! one object per line, appended one finished pair at a time so that a crash or a kill loses
//! no finished result, and read back to resume.
//!
//! Layout (version 1):
//! - line 1, the header: `{"format": "sdfreg-batch-results", "version": 1, "sdfreg": "0.1.0",
//!   "pairs": "<the pairs file as given>", "settings": {…every RegisterSettings field…}}`;
//! - then one line per finished pair, in the order they finished: `"row"` (1-based data row of
//!   the pairs file), `"source"`, `"target"` (paths as written in the pairs file), `"seed"`,
//!   `"ok"`; a pair that registered adds the registration's fields (`"transformation"`, the
//!   4×4 `t_target_source` as row-major nested lists, `"fitness"`, `"stages"`, …, as
//!   `sdfreg register --output FILE.json` writes them); one that failed adds `"error"`, the
//!   message.
//!
//! [`read_batch_log`] refuses a file that is not such a log (naming the file and the line), of
//! a newer version, or with a malformed or repeated record; a last line without its newline is
//! a record cut short by a kill and is left out ([`BatchLog::complete_len`]).

use std::collections::HashMap;
use std::path::Path;

use serde_json::Value;

use crate::base::error::IoError;
use crate::pipeline::settings::RegisterSettings;

/// The `"format"` of a batch results file's header.
pub const FORMAT: &str = "sdfreg-batch-results";
/// The newest version this build reads and the one it writes.
pub const VERSION: u64 = 1;

/// The header line (with its newline) of a new results file for the pairs file `pairs` and
/// `settings`.
pub fn header_line(pairs: &str, settings: &RegisterSettings) -> String {
    let header = serde_json::json!({
        "format": FORMAT,
        "version": VERSION,
        "sdfreg": env!("CARGO_PKG_VERSION"),
        "pairs": pairs,
        "settings": settings,
    });
    header.to_string() + "\n"
}

/// A finished pair as its results line records it.
#[derive(Clone, Debug, PartialEq)]
pub struct Finished {
    /// 1-based data row of the pairs file.
    pub row: u64,
    /// The source path as the pairs file wrote it.
    pub source: String,
    /// The target (cloud or model) path as the pairs file wrote it.
    pub target: String,
    /// Whether it registered (false: its line holds the error).
    pub ok: bool,
    /// 1-based line of the results file.
    pub line: usize,
}

/// What a results file holds.
#[derive(Clone, Debug)]
pub struct BatchLog {
    /// The pairs file named in the header.
    pub pairs: String,
    /// The settings named in the header.
    pub settings: RegisterSettings,
    /// The finished pairs, in file order.
    pub finished: Vec<Finished>,
    /// Bytes up to the end of the last complete line; a resumed batch appends from here.
    pub complete_len: usize,
}

/// Reads a batch results file's contents (`path` names it in errors). An empty file has no
/// log: `Ok(None)`.
pub fn read_batch_log(bytes: &[u8], path: &Path) -> Result<Option<BatchLog>, IoError> {
    let bad = |line: usize, message: String| IoError::Parse {
        path: path.to_path_buf(),
        line: Some(line),
        message,
    };
    // A last line without its newline was cut short while being written: leave it out.
    let complete_len = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
    let text = std::str::from_utf8(&bytes[..complete_len]).map_err(|e| {
        let line = 1 + bytes[..e.valid_up_to()]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        bad(
            line,
            "not UTF-8 text: not an sdfreg batch results file".into(),
        )
    })?;
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l));
    let Some((_, first)) = lines.next() else {
        if bytes.is_empty() {
            return Ok(None);
        }
        return Err(bad(1, "the header line is cut short".into()));
    };
    let (pairs, settings) = header(first).map_err(|m| bad(1, m))?;
    let mut finished = Vec::new();
    let mut seen: HashMap<u64, usize> = HashMap::new();
    for (n, line) in lines {
        let record = record(line, n).map_err(|m| bad(n, m))?;
        if let Some(first) = seen.insert(record.row, n) {
            return Err(bad(
                n,
                format!(
                    "row {} is recorded twice (first on line {first})",
                    record.row
                ),
            ));
        }
        finished.push(record);
    }
    Ok(Some(BatchLog {
        pairs,
        settings,
        finished,
        complete_len,
    }))
}

fn header(line: &str) -> Result<(String, RegisterSettings), String> {
    let foreign =
        || format!("not an sdfreg batch results file (its first line is not a {FORMAT:?} header)");
    let v: Value = serde_json::from_str(line).map_err(|_| foreign())?;
    if v.get("format").and_then(Value::as_str) != Some(FORMAT) {
        return Err(foreign());
    }
    let version = v
        .get("version")
        .and_then(Value::as_u64)
        .ok_or("the header has no integer \"version\"")?;
    if version > VERSION {
        return Err(format!(
            "results file version {version} is newer than this sdfreg reads ({VERSION}); upgrade sdfreg"
        ));
    }
    let pairs = v
        .get("pairs")
        .and_then(Value::as_str)
        .ok_or("the header has no \"pairs\" path")?
        .to_string();
    let settings = v
        .get("settings")
        .cloned()
        .ok_or_else(|| "the header has no \"settings\"".to_string())
        .and_then(|s| {
            serde_json::from_value::<RegisterSettings>(s)
                .map_err(|e| format!("the header's settings are not valid: {e}"))
        })?;
    Ok((pairs, settings))
}

fn record(line: &str, n: usize) -> Result<Finished, String> {
    let v: Value = serde_json::from_str(line)
        .map_err(|e| format!("not a JSON record ({e}); the file is corrupted"))?;
    let field = |name: &str| v.get(name).ok_or(format!("the record has no {name:?}"));
    let text = |name: &str| {
        field(name)?
            .as_str()
            .map(str::to_string)
            .ok_or(format!("{name:?} is not a string"))
    };
    let row = field("row")?
        .as_u64()
        .filter(|&r| r >= 1)
        .ok_or("\"row\" is not a row number (an integer ≥ 1)")?;
    let ok = field("ok")?
        .as_bool()
        .ok_or("\"ok\" is not true or false")?;
    if ok && v.get("transformation").is_none() {
        return Err("a record with \"ok\": true has no \"transformation\"".into());
    }
    if !ok && v.get("error").and_then(Value::as_str).is_none() {
        return Err("a record with \"ok\": false has no \"error\" message".into());
    }
    Ok(Finished {
        row,
        source: text("source")?,
        target: text("target")?,
        ok,
        line: n,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn log(records: &[&str]) -> String {
        let mut text = header_line("pairs.csv", &RegisterSettings::default());
        for r in records {
            text += r;
            text += "\n";
        }
        text
    }

    const OK: &str = r#"{"row":2,"source":"a.ply","target":"m.sdfm","seed":0,"ok":true,"transformation":[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}"#;
    const FAILED: &str = r#"{"row":1,"source":"b.ply","target":"m.sdfm","seed":0,"ok":false,"error":"b.ply: no points found"}"#;

    fn read(text: &str) -> Result<Option<BatchLog>, String> {
        read_batch_log(text.as_bytes(), Path::new("out.jsonl")).map_err(|e| e.to_string())
    }

    #[test]
    fn a_log_reads_back_with_its_header_and_records() {
        let text = log(&[OK, FAILED]);
        let log = read(&text).unwrap().unwrap();
        assert_eq!(log.pairs, "pairs.csv");
        assert_eq!(log.settings, RegisterSettings::default());
        assert_eq!(log.complete_len, text.len());
        let rows: Vec<(u64, bool, usize)> =
            log.finished.iter().map(|f| (f.row, f.ok, f.line)).collect();
        assert_eq!(rows, [(2, true, 2), (1, false, 3)]);
        assert_eq!(log.finished[1].source, "b.ply");
        assert!(read("").unwrap().is_none());
    }

    #[test]
    fn a_line_cut_short_by_a_kill_is_left_out() {
        let whole = log(&[OK]);
        let text = whole.clone() + &FAILED[..40];
        let log = read(&text).unwrap().unwrap();
        assert_eq!(log.complete_len, whole.len());
        assert_eq!(log.finished.len(), 1);
    }

    #[test]
    fn foreign_corrupted_newer_and_repeated_logs_are_refused_by_name_and_line() {
        let cases = [
            (
                "row,source\n".to_string(),
                "out.jsonl:1: not an sdfreg batch results file",
            ),
            (
                "{\"format\":\"other\"}\n".into(),
                "out.jsonl:1: not an sdfreg batch results file",
            ),
            (
                log(&[]).replace("\"version\":1", "\"version\":2"),
                "out.jsonl:1: results file version 2 is newer",
            ),
            (log(&[OK, "{\"row\":3,"]), "out.jsonl:3: not a JSON record"),
            (
                log(&[OK, OK]),
                "out.jsonl:3: row 2 is recorded twice (first on line 2)",
            ),
            (
                log(&[&OK.replace("\"row\":2", "\"row\":0")]),
                "out.jsonl:2: \"row\" is not a row number",
            ),
            (
                log(&[&FAILED.replace(",\"error\":\"b.ply: no points found\"", "")]),
                "out.jsonl:2: a record with \"ok\": false has no \"error\"",
            ),
            (
                "{\"format\":\"sdfreg-batch".into(),
                "out.jsonl:1: the header line is cut short",
            ),
            (
                String::from_utf8_lossy(b"\xff\xfe\n")
                    .into_owned()
                    .replace('\u{fffd}', "\u{1}"),
                "out.jsonl:1: not an sdfreg batch results file",
            ),
        ];
        for (text, expected) in cases {
            let message = read(&text).unwrap_err();
            assert!(message.starts_with(expected), "{message:?} for {text:?}");
        }
        let raw = read_batch_log(b"\xff\xfe\n", Path::new("out.jsonl")).unwrap_err();
        assert!(
            raw.to_string().starts_with("out.jsonl:1: not UTF-8 text"),
            "{raw}"
        );
    }

    #[test]
    fn mutated_logs_never_panic() {
        use rand::{Rng, SeedableRng};
        let valid = log(&[OK, FAILED]).into_bytes();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        for _ in 0..3000 {
            let mut bytes = valid.clone();
            for _ in 0..rng.random_range(1..4) {
                let i = rng.random_range(0..bytes.len());
                match rng.random_range(0..3) {
                    0 => bytes[i] = rng.random(),
                    1 => bytes.truncate(i),
                    _ => bytes.insert(i, b"{}\n\",:0"[rng.random_range(0..7)]),
                }
                if bytes.is_empty() {
                    break;
                }
            }
            if let Ok(Some(log)) = read_batch_log(&bytes, Path::new("m.jsonl")) {
                assert!(log.complete_len <= bytes.len());
            }
        }
    }
}

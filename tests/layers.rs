//! The core's layers (`crates/sdfreg-core/src/lib.rs`, "The layers, bottom-up"): a module's own
//! code (its `#[cfg(test)] mod tests` aside) names through `crate::…` only modules of its own
//! layer or of lower ones, and no two modules reach each other, directly or around a loop.
//!
//! Paths are read as text: every `crate::a::b::…` path outside comments, and in a `mod.rs`
//! every path through one of its own child modules (`ply::read`). A path is resolved to the
//! deepest file it names (`crate::field::mlp::Mlp` → `field/mlp.rs`). `lib.rs` only re-exports
//! and is left out; `super::` and `crate::{…}` at the root are refused, so every edge is seen.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Each folder of `src/` with its rank, bottom-up. `io` sits beside the layers above
/// `geometry` (a mesh file is sampled into a cloud); `sim` beside them at the top (procedural
/// data for tests and benches: nothing below may need it).
const LAYERS: [(&str, u32); 11] = [
    ("base", 0),
    ("geometry", 1),
    ("io", 2),
    ("field", 3),
    ("fit", 4),
    ("solve", 5),
    ("pipeline", 6),
    ("model", 7),
    ("batch", 8),
    ("views", 9),
    ("sim", 10),
];

/// One module: its path under `src/` and its own code, tests and comments removed.
struct Module {
    file: String,
    code: String,
}

fn rank(file: &str) -> Option<u32> {
    let folder = file.split('/').next()?;
    LAYERS.iter().find(|(l, _)| *l == folder).map(|(_, r)| *r)
}

/// The code of `text` before its `#[cfg(test)] mod tests`, without comments.
fn own_code(text: &str) -> String {
    let mut out = String::new();
    let mut lines = text.lines().peekable();
    while let Some(line) = lines.next() {
        if line.trim() == "#[cfg(test)]"
            && lines
                .peek()
                .is_some_and(|l| l.trim_start().starts_with("mod tests"))
        {
            break;
        }
        let code = line.find("//").map_or(line, |i| &line[..i]);
        out.push_str(code);
        out.push('\n');
    }
    out
}

/// The file (relative to `src/`) that `segments` (after `crate::`) name.
fn resolve(files: &BTreeSet<String>, segments: &[&str]) -> Option<String> {
    let mut dir = String::new();
    let mut found = None;
    for seg in segments {
        let folder = format!("{dir}{seg}/mod.rs");
        let file = format!("{dir}{seg}.rs");
        if files.contains(&folder) {
            found = Some(folder);
            dir = format!("{dir}{seg}/");
        } else if files.contains(&file) {
            found = Some(file);
            break;
        } else {
            break;
        }
    }
    found
}

/// Every `crate::…` path of `code` as its segments (a `{` group ends it).
fn crate_paths(code: &str) -> Vec<Vec<&str>> {
    let mut out = Vec::new();
    let mut rest = code;
    while let Some(i) = rest.find("crate::") {
        let before = rest[..i].chars().last();
        rest = &rest[i + "crate::".len()..];
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue;
        }
        let end = rest
            .find(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
            .unwrap_or(rest.len());
        let path: Vec<&str> = rest[..end].split("::").filter(|s| !s.is_empty()).collect();
        out.push(if rest[end..].starts_with('{') && path.is_empty() {
            vec!["{"]
        } else {
            path
        });
    }
    out
}

/// The child modules a `mod.rs` declares (`mod ply;`, `pub(crate) mod tree;`).
fn children(code: &str) -> Vec<String> {
    code.lines()
        .filter_map(|l| {
            let l = l.trim();
            let rest = l.split("mod ").nth(1)?;
            let name = rest.strip_suffix(';')?;
            (l.starts_with("mod ") || l.starts_with("pub")).then(|| name.trim().to_string())
        })
        .collect()
}

/// The violations of the layer rule and the loops among `modules`, one line each.
fn check(modules: &[Module]) -> Vec<String> {
    let files: BTreeSet<String> = modules.iter().map(|m| m.file.clone()).collect();
    let mut problems = Vec::new();
    let mut edges: BTreeMap<&str, BTreeSet<String>> = BTreeMap::new();
    for m in modules {
        let Some(own) = rank(&m.file) else {
            problems.push(format!(
                "{}: its folder is not a layer (add it to LAYERS in tests/layers.rs)",
                m.file
            ));
            continue;
        };
        if m.code.contains("super::") {
            problems.push(format!("{}: `super::` path; write `crate::…`", m.file));
        }
        let mut targets = BTreeSet::new();
        for path in crate_paths(&m.code) {
            match resolve(&files, &path) {
                Some(t) => {
                    targets.insert(t);
                }
                None => problems.push(format!(
                    "{}: `crate::{}` names no module; import from the module that defines it",
                    m.file,
                    path.join("::")
                )),
            }
        }
        if let Some(dir) = m.file.strip_suffix("mod.rs") {
            for child in children(&m.code) {
                let used = m.code.match_indices(&format!("{child}::")).any(|(i, _)| {
                    !m.code[..i]
                        .chars()
                        .last()
                        .is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':')
                });
                let child_file = [format!("{dir}{child}.rs"), format!("{dir}{child}/mod.rs")]
                    .into_iter()
                    .find(|f| files.contains(f));
                if let (true, Some(f)) = (used, child_file) {
                    targets.insert(f);
                }
            }
        }
        targets.remove(&m.file);
        for t in &targets {
            if let Some(r) = rank(t).filter(|&r| r > own) {
                problems.push(format!(
                    "{} (layer {own}) imports {t} (layer {r}): an import must point down",
                    m.file
                ));
            }
        }
        edges.insert(&m.file, targets);
    }
    for cycle in loops(&edges) {
        problems.push(format!("loop: {}", cycle.join(" -> ")));
    }
    problems
}

/// The import loops of `edges`: one per strongly connected set of two or more modules, drawn
/// as a path through it back to its start.
fn loops(edges: &BTreeMap<&str, BTreeSet<String>>) -> Vec<Vec<String>> {
    let reach = |from: &str| {
        let mut seen = BTreeSet::new();
        let mut stack = vec![from.to_string()];
        while let Some(f) = stack.pop() {
            for t in edges.get(f.as_str()).into_iter().flatten() {
                if seen.insert(t.clone()) {
                    stack.push(t.clone());
                }
            }
        }
        seen
    };
    let mut reported = BTreeSet::new();
    let mut out = Vec::new();
    for &start in edges.keys() {
        if reported.contains(start) || !reach(start).contains(start) {
            continue;
        }
        // Walk back to `start` along edges that can reach it.
        let mut cycle = vec![start.to_string()];
        let mut at = start.to_string();
        loop {
            let next = edges[at.as_str()]
                .iter()
                .find(|t| *t == start || (!cycle.contains(t) && reach(t).contains(start)))
                .cloned()
                .expect("a module on a loop has an edge that stays on it");
            if next == start {
                break;
            }
            cycle.push(next.clone());
            at = next;
        }
        reported.extend(cycle.iter().cloned());
        cycle.push(start.to_string());
        out.push(cycle);
    }
    out
}

fn core_modules(src: &Path) -> Vec<Module> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).expect("readable source folder") {
            let path = entry.expect("readable entry").path();
            if path.is_dir() {
                walk(&path, out);
            } else if path.extension().is_some_and(|e| e == "rs") {
                out.push(path);
            }
        }
    }
    let mut paths = Vec::new();
    walk(src, &mut paths);
    paths
        .into_iter()
        .filter_map(|p| {
            let file = p
                .strip_prefix(src)
                .ok()?
                .to_string_lossy()
                .replace('\\', "/");
            (file != "lib.rs").then(|| Module {
                code: own_code(&std::fs::read_to_string(&p).expect("readable source file")),
                file,
            })
        })
        .collect()
}

#[test]
fn every_core_import_points_down_and_none_closes_a_loop() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/sdfreg-core/src");
    let modules = core_modules(&src);
    assert!(modules.len() > 40, "read {} modules", modules.len());
    let problems = check(&modules);
    assert!(
        problems.is_empty(),
        "the core's layers are broken:\n{}",
        problems.join("\n")
    );
}

#[test]
fn the_check_names_an_upward_import_and_a_loop() {
    let m = |file: &str, code: &str| Module {
        file: file.into(),
        code: own_code(code),
    };
    let modules = [
        m("geometry/cloud.rs", "use crate::field::mlp::Mlp;\n"),
        m(
            "field/mod.rs",
            "pub mod mlp;\npub mod sdf;\nfn f() { sdf::g(); }\n",
        ),
        m(
            "field/mlp.rs",
            "// crate::pipeline::x in a comment\nuse crate::field::Field;\n",
        ),
        m("field/sdf.rs", "use crate::field::X;\n"),
        m(
            "pipeline/register.rs",
            "use crate::Stage;\n#[cfg(test)]\nmod tests { use crate::batch::x; }\n",
        ),
    ];
    let problems = check(&modules);
    assert_eq!(
        problems,
        [
            "geometry/cloud.rs (layer 1) imports field/mlp.rs (layer 3): an import must point down",
            "pipeline/register.rs: `crate::Stage` names no module; import from the module that \
             defines it",
            "loop: field/mod.rs -> field/sdf.rs -> field/mod.rs",
        ]
    );
}

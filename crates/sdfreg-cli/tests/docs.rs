//! The guide cannot drift from the code: every flag of every command is on the command-line
//! page, every `sdfreg` line of every page uses flags that exist, and every Rust block is an
//! example file that cargo builds. A failure names the page.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// README.md and every page of docs/, as (name relative to the root, text).
fn pages() -> Vec<(String, String)> {
    let mut names = vec!["README.md".to_string()];
    let mut guide: Vec<String> = std::fs::read_dir(root().join("docs"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".md"))
        .map(|n| format!("docs/{n}"))
        .collect();
    guide.sort();
    names.extend(guide);
    names
        .into_iter()
        .map(|n| {
            let text = std::fs::read_to_string(root().join(&n)).unwrap();
            (n, text)
        })
        .collect()
}

/// The fenced blocks of `text` in `language` (the fence's first word), dedented.
fn blocks(text: &str, language: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut current: Option<(usize, Vec<String>)> = None;
    for line in text.lines() {
        let indent = line.len() - line.trim_start().len();
        let trimmed = line.trim_start();
        match &mut current {
            None => {
                if let Some(info) = trimmed.strip_prefix("```") {
                    let lang = info.split_whitespace().next().unwrap_or("");
                    current = Some((indent, Vec::new()));
                    if lang != language {
                        current.as_mut().unwrap().1.push("\u{0}skip".into());
                    }
                }
            }
            Some((fence, lines)) => {
                if trimmed.starts_with("```") && indent == *fence {
                    let (_, lines) = current.take().unwrap();
                    if lines.first().map(String::as_str) != Some("\u{0}skip") {
                        out.push(lines.join("\n"));
                    }
                } else {
                    let cut = line.len().min(*fence);
                    lines.push(line[cut..].to_string());
                }
            }
        }
    }
    out
}

fn help(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_sdfreg"))
        .args(args)
        .arg("--help")
        .output()
        .unwrap();
    assert!(out.status.success(), "sdfreg {args:?} --help failed");
    String::from_utf8(out.stdout).unwrap()
}

/// The subcommands `sdfreg --help` lists (but `help`).
fn commands() -> Vec<String> {
    let top = help(&[]);
    let list = top.split("Commands:").nth(1).expect("a Commands: section");
    list.lines()
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|c| *c != "help")
        .map(str::to_string)
        .collect()
}

/// The long flags of `sdfreg COMMAND --help`, `--help` and `--version` aside.
fn flags(command: &str) -> BTreeSet<String> {
    help(&[command])
        .split(|c: char| c.is_whitespace() || c == ',' || c == '[' || c == ']' || c == '=')
        .filter(|w| w.starts_with("--") && w.len() > 2)
        .map(|w| {
            w.trim_end_matches(|c: char| !c.is_alphanumeric())
                .to_string()
        })
        .filter(|w| w != "--help" && w != "--version")
        .collect()
}

/// Whether `text` names `flag` as a whole word (not as the start of a longer flag).
fn names(text: &str, flag: &str) -> bool {
    text.match_indices(flag).any(|(i, _)| {
        let next = text[i + flag.len()..].chars().next();
        !next.is_some_and(|c| c.is_alphanumeric() || c == '-' || c == '_')
    })
}

#[test]
fn every_flag_of_every_command_is_on_the_command_line_page() {
    let page = "docs/cli.md";
    let text = std::fs::read_to_string(root().join(page)).unwrap();
    let commands = commands();
    assert!(
        commands.len() >= 7 && commands.iter().any(|c| c == "register"),
        "{commands:?}"
    );
    let mut missing = Vec::new();
    for command in &commands {
        if !names(&text, &format!("sdfreg {command}")) {
            missing.push(format!("the command `sdfreg {command}`"));
        }
        for flag in flags(command) {
            if !names(&text, &flag) {
                missing.push(format!("sdfreg {command} {flag}"));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "{page} does not document: {}",
        missing.join(", ")
    );
    // And every flag the page names is one (a renamed flag leaves its old name behind).
    let all: BTreeSet<String> = commands.iter().flat_map(|c| flags(c)).collect();
    let stale: BTreeSet<&str> = text
        .split(|c: char| !(c.is_alphanumeric() || c == '-' || c == '_'))
        .filter(|w| w.starts_with("--") && w.len() > 2 && w.as_bytes()[2].is_ascii_lowercase())
        .filter(|w| !all.contains(*w) && !NOT_SDFREG_FLAGS.contains(w))
        .collect();
    assert!(
        stale.is_empty(),
        "{page} names flags no command has: {stale:?}"
    );
}

/// Flags the command-line page names that belong to other programs (cargo, pip).
const NOT_SDFREG_FLAGS: &[&str] = &["--release", "--help", "--version"];

#[test]
fn every_sdfreg_line_of_every_page_uses_flags_that_exist() {
    let commands = commands();
    let known: Vec<(String, BTreeSet<String>)> =
        commands.iter().map(|c| (c.clone(), flags(c))).collect();
    let mut checked = 0;
    let mut wrong = Vec::new();
    for (page, text) in pages() {
        for block in blocks(&text, "sh") {
            for line in block.lines() {
                let words: Vec<&str> = line.split('#').next().unwrap().split_whitespace().collect();
                // `sdfreg CMD …`, or `cargo run … -- CMD …`.
                let start = match words.iter().position(|w| *w == "sdfreg" || *w == "--") {
                    Some(i)
                        if words[..i].iter().all(|w| {
                            ["cargo", "run", "--release", "-p", "sdfreg-cli"].contains(w)
                        }) =>
                    {
                        i + 1
                    }
                    _ => continue,
                };
                let Some(command) = words.get(start) else {
                    continue;
                };
                let Some((_, flags)) = known.iter().find(|(c, _)| c == command) else {
                    wrong.push(format!("{page}: `{line}`: no command `{command}`"));
                    continue;
                };
                for w in &words[start + 1..] {
                    let flag = w.trim_start_matches('[').trim_end_matches([']', ',', ')']);
                    let flag = flag.split('=').next().unwrap();
                    if flag.starts_with("--") && flag.len() > 2 && flag != "--help" {
                        checked += 1;
                        if !flags.contains(flag) {
                            wrong.push(format!(
                                "{page}: `{line}`: `sdfreg {command}` has no {flag}"
                            ));
                        }
                    }
                }
            }
        }
    }
    assert!(
        checked > 20,
        "only {checked} flags found in the pages' sdfreg lines"
    );
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}

#[test]
fn every_rust_block_is_an_example_that_cargo_builds() {
    let mut seen = 0;
    for (page, text) in pages() {
        for (k, block) in blocks(&text, "rust").iter().enumerate() {
            let first = block.lines().next().unwrap_or("");
            let file = first
                .strip_prefix("// ")
                .and_then(|l| l.split(':').next())
                .filter(|f| f.starts_with("crates/") && f.contains("/examples/"))
                .unwrap_or_else(|| {
                    panic!(
                        "{page}: rust block {} does not start with `// crates/…/examples/NAME.rs: …`",
                        k + 1
                    )
                });
            let source = std::fs::read_to_string(root().join(file))
                .unwrap_or_else(|e| panic!("{page}: rust block {}: {file}: {e}", k + 1));
            assert_eq!(
                block.trim_end(),
                source.trim_end(),
                "{page}: rust block {} differs from {file}",
                k + 1
            );
            seen += 1;
        }
    }
    assert!(seen >= 3, "{seen} rust blocks");
}

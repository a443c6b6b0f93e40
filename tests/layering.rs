//! The dependency rule between the layers, checked on the source tree:
//! the adapters (REST in `src/api`, CiA 309-3 in `src/ascii`, the command
//! line in `src/cli`) sit on the gateway service and never on each other;
//! the gateway and the layers below it know no adapter and no HTTP. Only
//! the wiring of `candeck serve` puts REST and CiA 309-3 side by side.
//!
//! A line breaks a rule when its code (comments are left out) names a
//! forbidden module path (`crate::api`, `candeck::api`, `crate::{api, ..}`)
//! or crate; each failure names the file, the line and the rule.

use std::path::{Path, PathBuf};

/// A rule: files under any of `dirs` (except `allowed`) must not name any of
/// `forbidden`.
struct Rule {
    why: &'static str,
    dirs: &'static [&'static str],
    allowed: &'static [&'static str],
    forbidden: &'static [Forbidden],
}

/// What a line must not name.
#[derive(Debug, Clone, Copy)]
enum Forbidden {
    /// A module of this crate: `crate::NAME`, `candeck::NAME`, or `NAME`
    /// inside `crate::{...}` / `candeck::{...}`.
    Module(&'static str),
    /// An external crate: `NAME::` at a path's start.
    Crate(&'static str),
}

/// The gateway and everything below it.
const CORE: &[&str] = &[
    "src/gateway",
    "src/cia309",
    "src/profiles",
    "src/canopen",
    "src/can",
    "src/sim",
];

const RULES: &[Rule] = &[
    Rule {
        why: "only the HTTP layer (and the wiring of `candeck serve`) may use the REST adapter",
        dirs: &[
            "src/gateway",
            "src/cia309",
            "src/ascii",
            "src/cli",
            "src/profiles",
            "src/canopen",
            "src/can",
            "src/sim",
        ],
        allowed: &["src/cli/serve/"],
        forbidden: &[Forbidden::Module("api"), Forbidden::Module("web")],
    },
    Rule {
        why: "the CiA 309-3 adapter is used by no other adapter and by no lower layer",
        dirs: &[
            "src/api",
            "src/web",
            "src/gateway",
            "src/cia309",
            "src/profiles",
            "src/canopen",
            "src/can",
            "src/sim",
        ],
        allowed: &[],
        forbidden: &[Forbidden::Module("ascii")],
    },
    Rule {
        why: "the gateway service and the layers below it know none of their adapters",
        dirs: &[
            "src/gateway",
            "src/profiles",
            "src/canopen",
            "src/can",
            "src/sim",
        ],
        allowed: &[],
        forbidden: &[
            Forbidden::Module("cia309"),
            Forbidden::Module("cli"),
            Forbidden::Module("web"),
        ],
    },
    Rule {
        why: "no HTTP under the adapters: the gateway and below use no axum or http types",
        dirs: CORE,
        allowed: &[],
        forbidden: &[
            Forbidden::Crate("axum"),
            Forbidden::Crate("http"),
            Forbidden::Crate("hyper"),
            Forbidden::Crate("tower"),
            Forbidden::Crate("tower_http"),
            Forbidden::Crate("utoipa_axum"),
        ],
    },
    Rule {
        why: "the CAN and CANopen layers know nothing above them",
        dirs: &["src/can", "src/canopen"],
        allowed: &[],
        forbidden: &[
            Forbidden::Module("gateway"),
            Forbidden::Module("profiles"),
            Forbidden::Module("sim"),
        ],
    },
];

/// The code of a line: without a `//` comment, and with the text of its
/// string literals blanked (`"http://crate::api"` names nothing).
fn code(line: &str) -> String {
    let mut out = String::with_capacity(line.len());
    let mut in_string = false;
    let mut escaped = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        if in_string {
            match c {
                _ if escaped => escaped = false,
                '\\' => escaped = true,
                '"' => in_string = false,
                _ => {}
            }
            out.push(if in_string { ' ' } else { c });
            continue;
        }
        match c {
            '"' => in_string = true,
            '/' if chars.peek() == Some(&'/') => break,
            _ => {}
        }
        out.push(c);
    }
    out
}

fn is_ident(byte: u8) -> bool {
    byte.is_ascii_alphanumeric() || byte == b'_'
}

/// Whether `word` is at `at` in `text` as a whole identifier.
fn word_at(text: &str, at: usize, word: &str) -> bool {
    let bytes = text.as_bytes();
    text[at..].starts_with(word)
        && (at == 0 || !is_ident(bytes[at - 1]))
        && bytes.get(at + word.len()).is_none_or(|&b| !is_ident(b))
}

/// Whether the code of a line names `forbidden`.
fn names(code: &str, forbidden: Forbidden) -> bool {
    match forbidden {
        Forbidden::Module(module) => ["crate", "candeck"].iter().any(|root| {
            code.match_indices(&format!("{root}::")).any(|(at, found)| {
                if at > 0 && is_ident(code.as_bytes()[at - 1]) {
                    return false;
                }
                let rest = &code[at + found.len()..];
                if word_at(rest, 0, module) {
                    return true;
                }
                // A group: `crate::{api, gateway::Gateway}`.
                rest.strip_prefix('{').is_some_and(|group| {
                    let group = group.split('}').next().unwrap_or(group);
                    group
                        .split(',')
                        .any(|item| word_at(item.trim_start(), 0, module))
                })
            })
        }),
        Forbidden::Crate(name) => code.match_indices(&format!("{name}::")).any(|(at, _)| {
            let before = code[..at].trim_end();
            word_at(code, at, name) && !before.ends_with("::") && !before.ends_with('.')
        }),
    }
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|ext| ext == "rs") {
            out.push(path);
        }
    }
}

/// Every breach of `rules` in the tree at `root`, as `file:line: ...`.
fn breaches(root: &Path, rules: &[Rule]) -> Vec<String> {
    let mut found = Vec::new();
    for rule in rules {
        for dir in rule.dirs {
            let mut files = Vec::new();
            rust_files(&root.join(dir), &mut files);
            files.sort();
            for file in files {
                let relative = file
                    .strip_prefix(root)
                    .unwrap_or(&file)
                    .to_string_lossy()
                    .replace('\\', "/");
                if rule
                    .allowed
                    .iter()
                    .any(|allowed| relative == *allowed || relative.starts_with(allowed))
                {
                    continue;
                }
                let text = std::fs::read_to_string(&file)
                    .unwrap_or_else(|err| panic!("{relative}: {err}"));
                for (number, line) in text.lines().enumerate() {
                    let code = code(line);
                    for forbidden in rule.forbidden {
                        if names(&code, *forbidden) {
                            found.push(format!(
                                "{relative}:{}: uses {forbidden:?}: {} ({})",
                                number + 1,
                                line.trim(),
                                rule.why
                            ));
                        }
                    }
                }
            }
        }
    }
    found
}

#[test]
fn the_layers_depend_only_downwards() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    assert!(
        root.join("src/gateway").is_dir(),
        "no source tree at {}",
        root.display()
    );
    let found = breaches(root, RULES);
    assert!(
        found.is_empty(),
        "the dependency rule is broken ({} lines):\n{}",
        found.len(),
        found.join("\n")
    );
}

#[test]
fn a_forbidden_path_is_found_in_every_spelling_and_comments_are_not() {
    let api = Forbidden::Module("api");
    for line in [
        "use crate::api::AppState;",
        "use crate::api;",
        "    let app = crate::api::app(state);",
        "use candeck::api::auth::Role;",
        "use crate::{api, gateway::Gateway};",
        "use crate::{gateway::Gateway, api::AppError};",
        "fn f() -> crate::api::AppError { todo!() }",
    ] {
        assert!(names(&code(line), api), "not found in: {line}");
    }
    for line in [
        "//! as the REST API does (crate::api::od)",
        "    // crate::api::AppState used to be here",
        "use crate::apis::Thing;",
        "use crate::gateway::api_types;",
        "use other_crate::api::Thing;",
        "let url = \"http://crate::api\"; ",
    ] {
        assert!(!names(&code(line), api), "found in: {line}");
    }
    let axum = Forbidden::Crate("axum");
    assert!(names("use axum::Router;", axum));
    assert!(names("    axum::http::StatusCode::OK", axum));
    assert!(!names("use crate::not_axum::Thing;", axum));
    assert!(!names("use crate::api::axum::Thing;", axum));
    let http = Forbidden::Crate("http");
    assert!(names("use http::HeaderMap;", http));
    assert!(!names(&code("let url = \"http://127.0.0.1\";"), http));
    assert!(!names("use axum::http::HeaderMap;", http));
}

#[test]
fn a_breach_names_its_file_and_line() {
    let root = std::env::temp_dir().join(format!("candeck-layering-{}", std::process::id()));
    let dir = root.join("src/gateway");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(
        dir.join("service.rs"),
        "//! crate::api in a comment is fine\nuse crate::can::Bus;\nuse crate::api::AppError;\n",
    )
    .unwrap();
    let found = breaches(&root, RULES);
    std::fs::remove_dir_all(&root).unwrap();
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(
        found[0].starts_with(
            "src/gateway/service.rs:3: uses Module(\"api\"): use crate::api::AppError;"
        ),
        "{}",
        found[0]
    );
}

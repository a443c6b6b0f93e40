//! The dependency rule between the layers.
//!
//! The layers below the doors are crates of the workspace (`crates/`), so
//! the compiler keeps them apart; this test checks their manifests: which
//! of the workspace's crates each one may build on, and that none below the
//! doors takes a door's dependency (HTTP, the OpenAPI derive, MQTT, the
//! command line). Inside this package the doors (REST and the dashboard in
//! `src/api` and `src/web`, CiA 309-3 in `src/ascii`, what the CiA 309
//! doors share in `src/cia309`, Sparkplug B in `src/sparkplug`) sit on the
//! gateway and never on each other; only the command line (`src/cli`),
//! which wires them, uses them all. That rule is checked on the source: a
//! file breaks it when its code (comments and string literals left out)
//! names a forbidden module in any spelling: `crate::api`, `candeck::api`,
//! a group `crate::{…, api::…}` over one or several lines, or `super::…`
//! climbing to it.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The workspace's crates below the doors, and which of the workspace's
/// crates each may depend on (`[dependencies]`; a test may use more).
const CRATES: &[(&str, &[&str])] = &[
    ("can", &[]),
    ("canopen", &["candeck-can"]),
    ("profiles", &["candeck-canopen"]),
    (
        "sim",
        &["candeck-can", "candeck-canopen", "candeck-profiles"],
    ),
    (
        "gateway",
        &["candeck-can", "candeck-canopen", "candeck-profiles"],
    ),
];

/// Dependencies that belong to a door or to the command line: no crate
/// below the doors may take one, not even for its tests.
const DOOR_DEPENDENCIES: &[&str] = &[
    "axum",
    "hyper",
    "hyper-util",
    "http",
    "tower",
    "tower-service",
    "tower-http",
    "utoipa",
    "utoipa-axum",
    "utoipa-swagger-ui",
    "askama",
    "rumqttc",
    "prost",
    "clap",
    "tokio-tungstenite",
    "async-opcua",
    "candeck",
];

/// The doors of this package (`src/NAME`), and the other modules of the
/// package each may use.
const DOORS: &[(&str, &[&str])] = &[
    // The REST door merges the dashboard's routes and serves CiA 309-5.
    ("api", &["web", "cia309"]),
    // The dashboard's pages are served by the HTTP door, with its errors.
    ("web", &["api"]),
    ("ascii", &["cia309"]),
    ("cia309", &[]),
    ("sparkplug", &[]),
    ("opcua", &[]),
];

/// The modules of this package a door might name.
const PACKAGE_MODULES: &[&str] = &["api", "web", "ascii", "cia309", "sparkplug", "opcua", "cli"];

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The names of the dependencies in `table` (`[dependencies]` or
/// `[dev-dependencies]`) of a manifest, with `package = "…"` renames
/// resolved to the package's name.
fn dependencies(manifest: &toml::Table, table: &str) -> BTreeSet<String> {
    let Some(deps) = manifest.get(table).and_then(|deps| deps.as_table()) else {
        return BTreeSet::new();
    };
    deps.iter()
        .map(|(name, spec)| {
            spec.get("package")
                .and_then(|package| package.as_str())
                .unwrap_or(name)
                .to_string()
        })
        .collect()
}

/// Every breach of the crate rule in the manifests under `root/crates`.
fn crate_breaches(root: &Path) -> Vec<String> {
    let mut found = Vec::new();
    for (name, allowed) in CRATES {
        let path = root.join("crates").join(name).join("Cargo.toml");
        let text = std::fs::read_to_string(&path)
            .unwrap_or_else(|err| panic!("{}: {err}", path.display()));
        let manifest: toml::Table = text
            .parse()
            .unwrap_or_else(|err| panic!("{}: {err}", path.display()));
        let normal = dependencies(&manifest, "dependencies");
        let dev = dependencies(&manifest, "dev-dependencies");
        for dep in &normal {
            if dep.starts_with("candeck-") && !allowed.contains(&dep.as_str()) {
                found.push(format!(
                    "crates/{name} depends on {dep}: it may build on {allowed:?} only"
                ));
            }
        }
        for dep in normal.iter().chain(&dev) {
            if DOOR_DEPENDENCIES.contains(&dep.as_str()) {
                found.push(format!(
                    "crates/{name} depends on {dep}: a door's dependency, below the doors"
                ));
            }
        }
    }
    found
}

#[test]
fn the_crates_below_the_doors_build_only_on_the_layers_beneath_them() {
    let found = crate_breaches(root());
    assert!(found.is_empty(), "{}", found.join("\n"));
}

#[test]
fn every_crate_of_the_workspace_is_checked() {
    let manifest: toml::Table = std::fs::read_to_string(root().join("Cargo.toml"))
        .unwrap()
        .parse()
        .unwrap();
    let members: BTreeSet<String> = manifest["workspace"]["members"]
        .as_array()
        .unwrap()
        .iter()
        .map(|member| member.as_str().unwrap().to_string())
        .collect();
    let checked: BTreeSet<String> = CRATES
        .iter()
        .map(|(name, _)| format!("crates/{name}"))
        .collect();
    assert_eq!(members, checked);
}

/// The code of a file: its comments (`//` to the end of a line, `/* */`)
/// and the text of its string and character literals blanked, the lines
/// kept where they were.
fn code(text: &str) -> String {
    #[derive(PartialEq)]
    enum State {
        Code,
        LineComment,
        BlockComment(usize),
        Str,
    }
    let mut out = String::with_capacity(text.len());
    let mut state = State::Code;
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        match state {
            State::Code => match c {
                '/' if chars.peek() == Some(&'/') => {
                    state = State::LineComment;
                    out.push(' ');
                }
                '/' if chars.peek() == Some(&'*') => {
                    chars.next();
                    state = State::BlockComment(1);
                    out.push_str("  ");
                }
                '"' => {
                    state = State::Str;
                    out.push('"');
                }
                _ => out.push(c),
            },
            State::LineComment => {
                if c == '\n' {
                    state = State::Code;
                    out.push('\n');
                } else {
                    out.push(' ');
                }
            }
            State::BlockComment(depth) => {
                if c == '*' && chars.peek() == Some(&'/') {
                    chars.next();
                    state = if depth == 1 {
                        State::Code
                    } else {
                        State::BlockComment(depth - 1)
                    };
                    out.push_str("  ");
                } else if c == '/' && chars.peek() == Some(&'*') {
                    chars.next();
                    state = State::BlockComment(depth + 1);
                    out.push_str("  ");
                } else {
                    out.push(if c == '\n' { '\n' } else { ' ' });
                }
            }
            State::Str => match c {
                '\\' => {
                    out.push(' ');
                    if let Some(next) = chars.next() {
                        out.push(if next == '\n' { '\n' } else { ' ' });
                    }
                }
                '"' => {
                    state = State::Code;
                    out.push('"');
                }
                '\n' => out.push('\n'),
                _ => out.push(' '),
            },
        }
    }
    out
}

fn is_ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// The identifier that starts `text`, if any.
fn ident(text: &str) -> &str {
    let end = text.find(|c: char| !is_ident(c)).unwrap_or(text.len());
    &text[..end]
}

/// The first segment of each path a use-tree names: for `{a::b, c}` after
/// a `crate::`, `a` and `c`; nested groups and line breaks allowed.
fn group_heads(group: &str) -> Vec<&str> {
    let mut heads = Vec::new();
    let mut depth = 0;
    let mut at_item_start = true;
    for (at, c) in group.char_indices() {
        match c {
            '{' => {
                depth += 1;
                at_item_start = depth == 1;
            }
            '}' => {
                if depth <= 1 {
                    break;
                }
                depth -= 1;
            }
            ',' if depth == 1 => at_item_start = true,
            c if c.is_whitespace() => {}
            _ if at_item_start && depth == 1 => {
                heads.push(ident(&group[at..]));
                at_item_start = false;
            }
            _ => at_item_start = false,
        }
    }
    heads
}

/// The modules of this package that `code` names from the file at
/// `module` (its path in the package: `["ascii", "serve"]`), each with
/// the line it is named on.
fn named_modules(code: &str, module: &[&str]) -> Vec<(usize, String)> {
    let line_of = |at: usize| code[..at].matches('\n').count() + 1;
    // The modules a path names: its first segment, or each head of a group.
    let heads = |rest: &str| -> Vec<String> {
        match rest.strip_prefix('{') {
            Some(_) => group_heads(rest).into_iter().map(str::to_string).collect(),
            None => vec![ident(rest).to_string()],
        }
    };
    let mut found = Vec::new();
    for root in ["crate::", "candeck::"] {
        for (at, _) in code.match_indices(root) {
            if code[..at].ends_with(|c: char| is_ident(c) || c == ':') {
                continue;
            }
            let rest = code[at + root.len()..].trim_start();
            found.extend(heads(rest).into_iter().map(|name| (line_of(at), name)));
        }
    }
    // `super::super::x` from `a/b/c.rs` (module a::b::c) is `crate::a::x`.
    for (at, _) in code.match_indices("super::") {
        if code[..at].ends_with(|c: char| is_ident(c) || c == ':') {
            continue;
        }
        let mut rest = &code[at..];
        let mut up = 0;
        while let Some(next) = rest.strip_prefix("super::") {
            up += 1;
            rest = next.trim_start();
        }
        if up >= module.len() {
            found.extend(heads(rest).into_iter().map(|name| (line_of(at), name)));
        } else if up == module.len() - 1 {
            found.push((line_of(at), module[0].to_string()));
        }
    }
    found
}

/// A scratch tree of `files` (path relative to its root, text) for a
/// detector's own test; removed when dropped.
struct ScratchTree(PathBuf);

impl ScratchTree {
    fn new(name: &str, files: &[(&str, &str)]) -> Self {
        let root = std::env::temp_dir().join(format!("candeck-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        for (path, text) in files {
            let path = root.join(path);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(path, text).unwrap();
        }
        Self(root)
    }
}

impl Drop for ScratchTree {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
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

/// The module path of a file under `src/`: `src/ascii/serve.rs` is
/// `ascii::serve`, `src/api/tests/mod.rs` is `api::tests`.
fn module_path(relative: &Path) -> Vec<String> {
    let mut parts: Vec<String> = relative
        .iter()
        .map(|part| part.to_string_lossy().into_owned())
        .collect();
    if let Some(last) = parts.pop() {
        let stem = last.trim_end_matches(".rs").to_string();
        if stem != "mod" {
            parts.push(stem);
        }
    }
    parts
}

/// Every breach of the door rule in the package's sources under
/// `root/src`, as `file:line: ...`.
fn door_breaches(root: &Path) -> Vec<String> {
    let mut found = Vec::new();
    for (door, allowed) in DOORS {
        let mut files = Vec::new();
        rust_files(&root.join("src").join(door), &mut files);
        let file = root.join("src").join(format!("{door}.rs"));
        if file.is_file() {
            files.push(file);
        }
        files.sort();
        for file in files {
            let relative = file.strip_prefix(root.join("src")).unwrap().to_path_buf();
            let module = module_path(&relative);
            let module: Vec<&str> = module.iter().map(String::as_str).collect();
            let text = std::fs::read_to_string(&file).unwrap();
            for (line, named) in named_modules(&code(&text), &module) {
                if named != *door
                    && PACKAGE_MODULES.contains(&named.as_str())
                    && !allowed.contains(&named.as_str())
                {
                    found.push(format!(
                        "src/{}:{line}: the {door} door uses {named}, another door (it may use {allowed:?} only)",
                        relative.display()
                    ));
                }
            }
        }
    }
    found
}

#[test]
fn the_doors_sit_on_the_gateway_and_never_on_each_other() {
    assert!(root().join("src/api").is_dir(), "no source tree");
    let found = door_breaches(root());
    assert!(found.is_empty(), "{}", found.join("\n"));
}

/// Every place where a door's code (its tests left out) holds a node's SDO
/// channel: a call of `.sdo(…)` or the name `SdoChannel`. The gateway's
/// node operations do the transfers; `NodeRegistry::sdo` is the gateway's
/// own (`pub(crate)`), so the compiler refuses the call already, and this
/// catches a door that would build a channel of its own instead. The
/// command line (`candeck od`, a master of its own on a bus) is no door.
fn sdo_channel_breaches(root: &Path) -> Vec<String> {
    let mut found = Vec::new();
    for (door, _) in DOORS {
        let mut files = Vec::new();
        rust_files(&root.join("src").join(door), &mut files);
        let file = root.join("src").join(format!("{door}.rs"));
        if file.is_file() {
            files.push(file);
        }
        files.sort();
        for file in files {
            let relative = file.strip_prefix(root.join("src")).unwrap().to_path_buf();
            let is_test = relative.iter().any(|part| part == "tests")
                || relative.file_name().is_some_and(|name| name == "tests.rs");
            if is_test {
                continue;
            }
            let code = code(&std::fs::read_to_string(&file).unwrap());
            let code = code.split("#[cfg(test)]").next().unwrap_or_default();
            for (n, line) in code.lines().enumerate() {
                let named = line.match_indices("SdoChannel").any(|(at, _)| {
                    !line[..at].ends_with(is_ident)
                        && !line[at + "SdoChannel".len()..].starts_with(is_ident)
                });
                if named || line.contains(".sdo(") {
                    found.push(format!(
                        "src/{}:{}: the {door} door holds a node's SDO channel: \
                         a node operation of the gateway does the transfers",
                        relative.display(),
                        n + 1
                    ));
                }
            }
        }
    }
    found
}

#[test]
fn no_door_holds_a_nodes_sdo_channel() {
    assert!(root().join("src/api").is_dir(), "no source tree");
    let found = sdo_channel_breaches(root());
    assert!(found.is_empty(), "{}", found.join("\n"));
}

#[test]
fn an_sdo_channel_in_a_doors_code_is_found_and_in_its_tests_or_comments_is_not() {
    let tree = ScratchTree::new(
        "layering-sdo",
        &[
            (
                "src/api/segments.rs",
                "//! served.registry.sdo(id) in a comment is fine\nfn f() {\n    let channel = served.registry.sdo(info.id)?;\n}\n#[cfg(test)]\nmod tests { fn g() { let _ = SdoChannel::new(bus, id, config); } }\n",
            ),
            (
                "src/api/program.rs",
                "use crate::gateway::sdo::SdoChannel;\nuse crate::gateway::sdo::SdoChannelStats;\n",
            ),
            (
                "src/api/tests/pdos.rs",
                "let channel = SdoChannel::new(bus, id, config);\n",
            ),
        ],
    );
    let found = sdo_channel_breaches(&tree.0);
    assert_eq!(found.len(), 2, "{found:?}");
    assert!(
        found[0].starts_with("src/api/program.rs:1: "),
        "{}",
        found[0]
    );
    assert!(
        found[1].starts_with("src/api/segments.rs:3: "),
        "{}",
        found[1]
    );
}

#[test]
fn a_module_is_found_in_every_spelling_and_comments_and_strings_are_not() {
    let names = |text: &str, module: &[&str]| -> Vec<String> {
        named_modules(&code(text), module)
            .into_iter()
            .map(|(_, name)| name)
            .collect()
    };
    let at = ["ascii", "serve"];
    for text in [
        "use crate::api::AppState;",
        "use crate::api;",
        "    let app = crate::api::app(state);",
        "use candeck::api::auth::Role;",
        "use crate::{api, gateway::Gateway};",
        "use crate::{gateway::Gateway, api::AppError};",
        "use crate::{\n    gateway::Gateway,\n    api::{AppError, AppState},\n};",
        "use crate::{gateway::{Gateway, ServedBus}, api::AppError};",
        "use super::super::api::AppError;",
        "fn f() -> crate::api::AppError { todo!() }",
    ] {
        assert!(
            names(text, &at).contains(&"api".to_string()),
            "not found in: {text}"
        );
    }
    for text in [
        "//! as the REST API does (crate::api::od)",
        "    // crate::api::AppState used to be here",
        "/* crate::api::x\n crate::api::y */ use crate::gateway::Gateway;",
        "use crate::apis::Thing;",
        "use crate::gateway::api_types;",
        "use other_crate::api::Thing;",
        "let url = \"http://crate::api\"; ",
        "let s = \"a \\\" crate::api\";",
        "use super::command::Line;",
    ] {
        assert!(
            !names(text, &at).contains(&"api".to_string()),
            "found in: {text}"
        );
    }
    // `super::` from `ascii/serve.rs` is `ascii`: the door itself.
    assert_eq!(names("use super::Line;", &at), vec!["ascii".to_string()]);
    assert_eq!(
        named_modules(&code("// x\n\nuse crate::{\n  sparkplug::Node,\n};"), &at),
        vec![(3, "sparkplug".to_string())]
    );
}

#[test]
fn a_breach_names_its_file_and_line() {
    let tree = ScratchTree::new(
        "layering-doors",
        &[(
            "src/ascii/serve.rs",
            "//! crate::api in a comment is fine\nuse crate::cia309::Line;\nuse crate::{\n    gateway::Gateway,\n    api::AppError,\n};\n",
        )],
    );
    let found = door_breaches(&tree.0);
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(
        found[0].starts_with("src/ascii/serve.rs:3: the ascii door uses api"),
        "{}",
        found[0]
    );
}

#[test]
fn a_crate_that_builds_on_a_layer_above_it_is_named() {
    let root = std::env::temp_dir().join(format!("candeck-crates-{}", std::process::id()));
    for (name, _) in CRATES {
        let dir = root.join("crates").join(name);
        std::fs::create_dir_all(&dir).unwrap();
        let deps = match *name {
            "sim" => "candeck-gateway = { path = \"../gateway\" }\n",
            "gateway" => "web = { package = \"axum\", version = \"0.8\" }\n",
            _ => "",
        };
        std::fs::write(
            dir.join("Cargo.toml"),
            format!("[package]\nname = \"candeck-{name}\"\n[dependencies]\n{deps}"),
        )
        .unwrap();
    }
    let found = crate_breaches(&root);
    std::fs::remove_dir_all(&root).unwrap();
    let found: BTreeMap<_, _> = found.iter().map(|line| (&line[..12], line)).collect();
    assert_eq!(found.len(), 2, "{found:?}");
    assert!(found["crates/sim d"].contains("candeck-gateway"));
    assert!(found["crates/gatew"].contains("axum: a door's dependency"));
}

/// Every place outside `crates/can` whose code depends on a cargo feature
/// (`cfg(feature = ...)`, `cfg!(feature = ...)`), as `file:line`.
fn feature_gates_outside_can(root: &Path) -> Vec<String> {
    let mut files = Vec::new();
    for dir in ["src", "tests", "benches", "crates"] {
        rust_files(&root.join(dir), &mut files);
    }
    files.sort();
    let mut found = Vec::new();
    for file in files {
        let relative = file.strip_prefix(root).unwrap();
        if relative.starts_with("crates/can") {
            continue;
        }
        let text = std::fs::read_to_string(&file).unwrap();
        // The code blanks string literals, lines kept: the feature's name
        // is read from the line as written.
        for (n, (line, written)) in code(&text).lines().zip(text.lines()).enumerate() {
            let compact: String = line.chars().filter(|c| !c.is_whitespace()).collect();
            let written: String = written.chars().filter(|c| !c.is_whitespace()).collect();
            if compact.contains("feature=")
                && compact.contains("cfg")
                && !names_default_features_only(&written)
            {
                found.push(format!("{}:{}", relative.display(), n + 1));
            }
        }
    }
    found
}

/// Whether every feature a gate names is one of the root package's default
/// features (`opcua`): the default build has it as the all-features build
/// does, so clippy with every feature checks the default build's code.
fn names_default_features_only(compact: &str) -> bool {
    let manifest: toml::Table =
        toml::from_str(&std::fs::read_to_string(root().join("Cargo.toml")).expect("Cargo.toml"))
            .expect("Cargo.toml is TOML");
    let defaults: Vec<&str> = manifest["features"]["default"]
        .as_array()
        .map(|list| list.iter().filter_map(|f| f.as_str()).collect())
        .unwrap_or_default();
    let named: Vec<&str> = compact
        .split("feature=")
        .skip(1)
        // A quote spelt as its code: a quote in this file's own code would
        // throw `code`'s reading of literals off.
        .filter_map(|rest| {
            rest.strip_prefix(char::from(34))?
                .split(char::from(34))
                .next()
        })
        .collect();
    !named.is_empty() && named.iter().all(|feature| defaults.contains(feature))
}

/// scripts/test checks the workspace with every feature and only
/// candeck-can with its defaults: that is the whole default build as long
/// as no other crate's code changes with a feature.
#[test]
fn only_the_can_crate_has_code_that_a_feature_changes() {
    let found = feature_gates_outside_can(root());
    assert!(
        found.is_empty(),
        "code outside crates/can depends on a feature (scripts/test's clippy checks only candeck-can with its defaults):\n{}",
        found.join("\n")
    );
}

#[test]
fn a_feature_gate_outside_the_can_crate_is_named() {
    let tree = ScratchTree::new(
        "layering-features",
        &[
            (
                "crates/can/src/lib.rs",
                "#[cfg(feature = \"socketcan\")]\nmod socketcan;\n",
            ),
            (
                "src/api/bus.rs",
                "// cfg(feature = \"x\") in a comment is not code\nfn a() {}\n#[cfg(not(feature= \"socketcan\"))]\nfn b() {}\n",
            ),
        ],
    );
    let found = feature_gates_outside_can(&tree.0);
    assert_eq!(found, ["src/api/bus.rs:3"]);
}

/// Words of HTTP that the crates below the doors never use in code, their
/// strings or their documentation: the doors' frameworks, a status code
/// type, a REST route.
const DOOR_WORDS: &[&str] = &["axum", "utoipa", "StatusCode", "/api/v1", "/cia309-5/"];

/// The one file and word allowed: the history's migration of version 1
/// audit rows, which named their door only by the request's path.
const DOOR_WORDS_ALLOWED: &[(&str, &str)] = &[("crates/gateway/src/history.rs", "/cia309-5/")];

/// Every line of a crate under `crates/` (tests excepted: a test may
/// quote a migrated row) that names one of [`DOOR_WORDS`], as
/// `file:line: word`.
fn door_words_below_the_doors(root: &Path) -> Vec<String> {
    let mut files = Vec::new();
    rust_files(&root.join("crates"), &mut files);
    files.sort();
    let mut found = Vec::new();
    for file in files {
        let relative = file.strip_prefix(root).unwrap();
        let name = relative.to_string_lossy();
        if name.ends_with("/tests.rs") || name.contains("/tests/") {
            continue;
        }
        let text = std::fs::read_to_string(&file).unwrap();
        for (n, line) in text.lines().enumerate() {
            for word in DOOR_WORDS {
                if line.contains(word) && !DOOR_WORDS_ALLOWED.contains(&(name.as_ref(), *word)) {
                    found.push(format!("{}:{}: {word}", relative.display(), n + 1));
                }
            }
        }
    }
    found
}

#[test]
fn nothing_below_the_doors_names_http_a_status_type_or_a_route() {
    let found = door_words_below_the_doors(root());
    assert!(found.is_empty(), "{}", found.join("\n"));
}

#[test]
fn a_route_named_below_the_doors_is_found() {
    let tree = ScratchTree::new(
        "layering-words",
        &[
            (
                "crates/gateway/src/recording.rs",
                "fn a() {}\n// see POST /api/v1/buses\n",
            ),
            (
                "crates/gateway/src/recording/tests.rs",
                "// '/api/v1/buses' in a migrated row\n",
            ),
        ],
    );
    let found = door_words_below_the_doors(&tree.0);
    assert_eq!(found, ["crates/gateway/src/recording.rs:2: /api/v1"]);
}

/// The `pub mod` lines of a crate root: a crate whose modules are public
/// has every `pub` item of them in its API, and `unreachable_pub` never
/// fires there.
fn public_modules(lib_rs: &str) -> Vec<String> {
    code(lib_rs)
        .lines()
        .filter_map(|line| line.trim().strip_prefix("pub mod "))
        .map(|rest| ident(rest).to_string())
        .collect()
}

/// The gateway's surface is the list its root re-exports
/// (crates/gateway/src/lib.rs): its modules are private.
#[test]
fn the_gateway_crate_keeps_its_modules_private() {
    let lib = std::fs::read_to_string(root().join("crates/gateway/src/lib.rs")).unwrap();
    let public = public_modules(&lib);
    assert!(
        public.is_empty(),
        "crates/gateway/src/lib.rs declares public modules: {public:?}; re-export what the doors use instead"
    );
}

#[test]
fn a_public_module_is_found_and_a_comment_naming_one_is_not() {
    let lib = "//! pub mod in the docs\nmod node;\npub mod service;\n    pub mod inner {}\n";
    assert_eq!(public_modules(lib), ["service", "inner"]);
}

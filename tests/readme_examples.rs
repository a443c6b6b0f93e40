//! Every example of the documentation (`README.md` and each page of
//! `docs/`) runs and gives what the page shows.
//!
//! An example is a fenced block opened with ```` ```sh example ````: its
//! `curl` commands (a line ending in `\` goes on) run in order, each file's
//! against one fresh `candeck serve` (the demo bus) of its own, with
//! `localhost:8080` replaced by the test server's address, so that an
//! example may build on the ones before it in the same file, as a reader
//! typing them would. After each command, a line
//! `# → JSON` (continued on lines starting `#   `) is what it prints. The
//! comparison is of JSON values and leaves out what changes from run to run:
//! an object shows only the keys it means (others are not compared), a
//! string `"…"` stands for any value, and an array ending in `"…"` for any
//! more elements after the ones shown. A line `# keep NAME = /json/pointer`
//! after an output keeps that value of the answer for the commands after
//! it, which name it `$NAME` (they run in `sh`, with it in their
//! environment): a lease id, say. Other `#` lines are comments, and so is
//! the rest of a command line after two spaces and `#`.

mod common;

use serde_json::Value;

/// One command of an example, and what the page shows it prints.
struct Example {
    line: usize,
    command: String,
    shown: String,
    /// `(NAME, JSON pointer)`: values of the answer kept for later commands.
    keep: Vec<(String, String)>,
}

/// The examples of `text`, the file `file` (for messages), in order.
fn examples(file: &str, text: &str) -> Vec<Example> {
    let mut examples: Vec<Example> = Vec::new();
    let mut in_block = false;
    let mut command: Option<(usize, String)> = None;
    let mut continuing_output = false;
    for (number, line) in text.lines().enumerate() {
        let number = number + 1;
        if !in_block {
            in_block = line.trim() == "```sh example";
            continue;
        }
        if line.trim() == "```" {
            in_block = false;
            assert!(
                command.is_none(),
                "{file} line {number}: a command without its output"
            );
            continue;
        }
        // A comment at the end of a command line.
        let line = line.split_once("  #").map_or(line, |(code, _)| code);
        if let Some((start, text)) = &mut command {
            // A continued command line.
            let part = line.trim();
            text.push(' ');
            text.push_str(part.trim_end_matches('\\').trim());
            if !part.ends_with('\\') {
                examples.push(Example {
                    line: *start,
                    command: std::mem::take(text),
                    shown: String::new(),
                    keep: Vec::new(),
                });
                command = None;
            }
            continue;
        }
        if let Some(shown) = line.strip_prefix("# → ") {
            let example = examples
                .last_mut()
                .unwrap_or_else(|| panic!("{file} line {number}: output without a command"));
            assert!(
                example.shown.is_empty(),
                "{file} line {number}: two outputs"
            );
            example.shown = shown.to_string();
            continuing_output = true;
            continue;
        }
        if continuing_output && let Some(more) = line.strip_prefix("#   ") {
            examples.last_mut().unwrap().shown.push_str(more.trim());
            continue;
        }
        continuing_output = false;
        if let Some(kept) = line.trim().strip_prefix("# keep ") {
            let (name, pointer) = kept
                .split_once(" = ")
                .unwrap_or_else(|| panic!("{file} line {number}: '# keep NAME = /pointer'"));
            examples
                .last_mut()
                .unwrap_or_else(|| panic!("{file} line {number}: keep without a command"))
                .keep
                .push((name.trim().to_string(), pointer.trim().to_string()));
            continue;
        }
        let trimmed = line.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        assert!(
            trimmed.starts_with("curl "),
            "{file} line {number}: an example runs curl only: {trimmed}"
        );
        let text = trimmed.trim_end_matches('\\').trim().to_string();
        if trimmed.ends_with('\\') {
            command = Some((number, text));
        } else {
            examples.push(Example {
                line: number,
                command: text,
                shown: String::new(),
                keep: Vec::new(),
            });
        }
    }
    examples
}

/// Whether `actual` is what `shown` shows (see the module's comment);
/// where not, the path of the first difference.
fn matches(shown: &Value, actual: &Value, path: &str) -> Result<(), String> {
    match (shown, actual) {
        (Value::String(text), _) if text == "…" => Ok(()),
        (Value::Object(shown), Value::Object(actual)) => {
            for (key, value) in shown {
                let actual = actual
                    .get(key)
                    .ok_or_else(|| format!("{path}.{key}: not in the answer"))?;
                matches(value, actual, &format!("{path}.{key}"))?;
            }
            Ok(())
        }
        (Value::Array(shown), Value::Array(actual)) => {
            let open = shown.last() == Some(&Value::String("…".to_string()));
            let shown = if open {
                &shown[..shown.len() - 1]
            } else {
                &shown[..]
            };
            if actual.len() < shown.len() || (!open && actual.len() != shown.len()) {
                return Err(format!(
                    "{path}: {} elements shown, {} in the answer",
                    shown.len(),
                    actual.len()
                ));
            }
            for (at, (shown, actual)) in shown.iter().zip(actual).enumerate() {
                matches(shown, actual, &format!("{path}[{at}]"))?;
            }
            Ok(())
        }
        _ if shown == actual => Ok(()),
        _ => Err(format!("{path}: shown {shown}, answered {actual}")),
    }
}

#[test]
fn the_matching_elides_what_it_says_and_nothing_else() {
    let actual: Value = serde_json::json!({"id": "3f2a", "items": [1, 2, 3], "n": 1});
    let ok = |shown: &str| matches(&serde_json::from_str(shown).unwrap(), &actual, "");
    assert!(ok(r#"{"id":"…","n":1}"#).is_ok());
    assert!(ok(r#"{"items":[1,"…"]}"#).is_ok());
    assert!(ok(r#"{"items":[1,2]}"#).is_err());
    assert!(ok(r#"{"n":2}"#).is_err());
    assert!(ok(r#"{"missing":1}"#).is_err());
    let parsed = examples(
        "test.md",
        "```sh example\ncurl -X PUT \\\n  localhost:8080/a   # a note\n# → {\"a\":\n#   1}\n# keep A = /a\n# a note\ncurl localhost:8080/b\n# → []\n```\n",
    );
    assert_eq!(parsed[0].keep, [("A".to_string(), "/a".to_string())]);
    assert!(parsed[1].keep.is_empty());
    let commands: Vec<(&str, &str)> = parsed
        .iter()
        .map(|example| (example.command.as_str(), example.shown.as_str()))
        .collect();
    assert_eq!(
        commands,
        [
            ("curl -X PUT localhost:8080/a", "{\"a\":1}"),
            ("curl localhost:8080/b", "[]")
        ]
    );
}

/// The files whose examples run: the README, then every page of `docs/`
/// by name.
fn documentation() -> Vec<std::path::PathBuf> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut pages: Vec<std::path::PathBuf> = std::fs::read_dir(root.join("docs"))
        .expect("docs/ is there")
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.extension().is_some_and(|ext| ext == "md"))
        .collect();
    pages.sort();
    let mut files = vec![root.join("README.md")];
    files.extend(pages);
    files
}

#[test]
fn the_examples_are_where_the_text_they_check_is() {
    let count = |page: &str| {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(page);
        examples(page, &std::fs::read_to_string(path).unwrap()).len()
    };
    // The README keeps one example; the API's live in its reference.
    assert!(count("README.md") >= 1);
    assert!(
        count("docs/rest-api.md") >= 30,
        "{}",
        count("docs/rest-api.md")
    );
    for page in ["docs/websocket.md", "docs/security.md", "docs/cia309.md"] {
        assert!(count(page) >= 1, "{page}");
    }
}

#[tokio::test]
async fn every_documented_example_gives_what_the_documentation_shows() {
    let mut failures = Vec::new();
    let mut total = 0;
    for path in documentation() {
        let text = std::fs::read_to_string(&path).unwrap();
        let file = path
            .strip_prefix(env!("CARGO_MANIFEST_DIR"))
            .unwrap()
            .display()
            .to_string();
        let examples = examples(&file, &text);
        if examples.is_empty() {
            continue;
        }
        total += examples.len();
        failures.extend(run(&file, &examples).await);
    }
    assert!(total >= 40, "examples found: {total}");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Runs the examples of one file against a fresh gateway; the failures.
async fn run(file: &str, examples: &[Example]) -> Vec<String> {
    let (server, _) = common::start(&["serve"]);
    // The demo as the reader finds it: the three nodes identified.
    let (_, nodes) = common::poll(&server.address, "/api/v1/buses/demo/nodes", |_, nodes| {
        nodes.as_array().is_some_and(|nodes| {
            nodes.len() == 3
                && nodes
                    .iter()
                    .all(|node| node["identification"]["state"] == "done")
        })
    })
    .await;
    assert_eq!(nodes.as_array().map(Vec::len), Some(3), "{nodes}");

    let mut failures = Vec::new();
    let mut kept: Vec<(String, String)> = Vec::new();
    for example in examples {
        assert!(
            !example.shown.is_empty(),
            "{file} line {}: no '# →' output",
            example.line
        );
        let command = example.command.replace("localhost:8080", &server.address);
        let output = tokio::process::Command::new("sh")
            .args(["-c", &format!("{command} --silent --show-error")])
            .envs(
                kept.iter()
                    .map(|(name, value)| (name.as_str(), value.as_str())),
            )
            .output()
            .await
            .expect("sh and curl run (Debian: apt-get install curl)");
        let printed = String::from_utf8_lossy(&output.stdout).trim().to_string();
        for (name, pointer) in &example.keep {
            let value = serde_json::from_str::<Value>(&printed)
                .ok()
                .and_then(|answer| answer.pointer(pointer).cloned());
            match value {
                Some(Value::String(text)) => kept.push((name.clone(), text)),
                Some(other) => kept.push((name.clone(), other.to_string())),
                None => failures.push(format!(
                    "{file} line {}: nothing at {pointer} to keep as {name} in {printed}",
                    example.line
                )),
            }
        }
        let result = match serde_json::from_str::<Value>(&example.shown) {
            Ok(shown) => serde_json::from_str::<Value>(&printed)
                .map_err(|err| format!("not JSON ({err})"))
                .and_then(|actual| matches(&shown, &actual, "")),
            Err(_) if printed == example.shown => Ok(()),
            Err(_) => Err("not the text shown".to_string()),
        };
        if let Err(why) = result {
            failures.push(format!(
                "{file} line {}: {}\n  {why}\n  shown:   {}\n  printed: {printed} {}",
                example.line,
                example.command,
                example.shown,
                String::from_utf8_lossy(&output.stderr)
            ));
        }
    }
    failures
}

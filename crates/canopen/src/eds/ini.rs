//! The INI dialect of CiA 306, as vendors really write it: `[section]`
//! headers and `key=value` lines, names compared without case, `;` comment
//! lines, CR LF or LF or CR line ends, an optional UTF-8 byte order mark.
//! What CiA 306 does not define but INI readers take is read the same way,
//! with a warning: a line that starts with `#` is a comment (one warning
//! for all of them), and so is `;` after white space at the end of a value
//! (a warning each: the value is read without it). A `#` after a value is
//! for `read` to judge: it is part of names and strings as often as a
//! comment.
//!
//! Nothing here refuses a file: what is ambiguous or malformed becomes a
//! warning with its line, and the sensible reading goes on. A section that
//! appears twice keeps its first copy (the second is dropped), a key that
//! appears twice in a section keeps its first value, a header without `]`
//! is read up to the end of the line, and a line that is neither header nor
//! `key=value` (or carries control characters) is dropped. Whether what is
//! left is an EDS at all is for `read` to say.

use std::collections::HashMap;

use crate::od::snippet;

#[derive(Debug)]
pub(super) struct Ini {
    pub sections: Vec<Section>,
    /// Lower-case section name to its position in `sections`.
    by_name: HashMap<String, usize>,
    /// The number of lines, for warnings about what is missing.
    pub lines: usize,
}

#[derive(Debug)]
pub(super) struct Section {
    /// As written, without the brackets.
    pub name: String,
    pub line: usize,
    pub entries: Vec<Entry>,
}

#[derive(Debug)]
pub(super) struct Entry {
    /// As written, trimmed.
    pub key: String,
    /// Trimmed, without a trailing comment; quotes kept.
    pub value: String,
    pub line: usize,
}

/// Something the INI reader got past: the line, the section or key it is
/// about (empty when none), what was wrong and what was done.
#[derive(Debug, PartialEq, Eq)]
pub(super) struct IniWarning {
    pub line: usize,
    pub key: String,
    pub message: String,
    pub dropped: bool,
}

impl Ini {
    pub(super) fn section(&self, name: &str) -> Option<&Section> {
        self.by_name
            .get(&name.to_ascii_lowercase())
            .map(|&i| &self.sections[i])
    }
}

impl Section {
    pub(super) fn get(&self, key: &str) -> Option<&Entry> {
        self.entries
            .iter()
            .find(|entry| entry.key.eq_ignore_ascii_case(key))
    }
}

/// Splits at CR LF, LF or a lone CR, numbering lines from 1. Searches one
/// character at a time, which the standard library does with memchr: lines
/// can be megabytes long.
fn lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    let mut rest = text;
    let mut number = 0;
    std::iter::from_fn(move || {
        if rest.is_empty() {
            return None;
        }
        number += 1;
        let newline = rest.find('\n').unwrap_or(rest.len());
        let (line, next) = match rest[..newline].find('\r') {
            Some(cr) if cr + 1 == newline => (&rest[..cr], newline + 1),
            Some(cr) => (&rest[..cr], cr + 1),
            None => (&rest[..newline], newline + 1),
        };
        rest = rest.get(next..).unwrap_or("");
        Some((number, line))
    })
}

/// The value of a `key=value` line: trimmed, a quoted string kept whole with
/// its quotes, and a comment (`;` after white space) cut off; the comment,
/// trimmed, beside it.
fn clean_value(raw: &str) -> (&str, Option<&str>) {
    let value = raw.trim();
    if value.starts_with('"')
        && let Some(close) = value.rfind('"').filter(|&close| close > 0)
    {
        let after = value[close + 1..].trim_start();
        if after.is_empty() {
            return (&value[..=close], None);
        }
        if after.starts_with(';') {
            return (&value[..=close], Some(after.trim_end()));
        }
    }
    let bytes = raw.as_bytes();
    let comment =
        (1..bytes.len()).find(|&i| bytes[i] == b';' && matches!(bytes[i - 1], b' ' | b'\t'));
    match comment {
        Some(start) => (raw[..start].trim(), Some(raw[start..].trim())),
        None => (value, None),
    }
}

/// C0 controls but tab, and DEL. Byte by byte, as lines can be megabytes
/// long. (C1 controls, U+0080 to U+009F, are not looked for: the bytes 0x80
/// to 0x9F of a Windows code page are read as the characters they print.)
fn has_control_characters(line: &str) -> bool {
    line.bytes().any(|b| (b < 0x20 && b != b'\t') || b == 0x7F)
}

pub(super) fn parse(text: &str) -> (Ini, Vec<IniWarning>) {
    let text = text.strip_prefix('\u{FEFF}').unwrap_or(text);
    let mut ini = Ini {
        sections: Vec::new(),
        by_name: HashMap::new(),
        lines: 0,
    };
    let mut warnings = Vec::new();
    // Lower-case key to its line, for the current section.
    let mut keys: HashMap<String, usize> = HashMap::new();
    // False while the lines belong to a section that is dropped (a repeated
    // or unnamed one), or before the first section.
    let mut in_section = false;
    let mut seen_header = false;
    // The first line that starts with `#`, and how many do: one warning
    // says them all, as a comment changes nothing that is read.
    let mut hash_lines: Option<(usize, usize)> = None;
    for (number, line) in lines(text) {
        ini.lines = number;
        let mut warn = |key: &str, message: String, dropped: bool| {
            warnings.push(IniWarning {
                line: number,
                key: key.to_string(),
                message,
                dropped,
            })
        };
        if has_control_characters(line) {
            warn(
                "",
                "control characters in a text line; line dropped".into(),
                true,
            );
            continue;
        }
        let line = line.trim();
        if line.is_empty() || line.starts_with(';') {
            continue;
        }
        if line.starts_with('#') {
            hash_lines.get_or_insert((number, 0)).1 += 1;
            continue;
        }
        if let Some(header) = line.strip_prefix('[') {
            let name = match header.split_once(']') {
                Some((name, after)) => {
                    let after = after.trim();
                    if !after.is_empty() && !after.starts_with(';') {
                        warn(
                            name.trim(),
                            format!(
                                "text after the section header: '{}'; ignored",
                                snippet(after)
                            ),
                            false,
                        );
                    }
                    name
                }
                None => {
                    warn(
                        header.trim(),
                        format!(
                            "section header '{}' has no ']'; read up to the end of the line",
                            snippet(line)
                        ),
                        false,
                    );
                    header
                }
            };
            let name = name.trim();
            keys.clear();
            in_section = false;
            seen_header = true;
            if name.is_empty() {
                warn(
                    "",
                    "empty section name; the section is dropped".into(),
                    true,
                );
                continue;
            }
            let folded = name.to_ascii_lowercase();
            if let Some(&first) = ini.by_name.get(&folded) {
                let first_line = ini.sections[first].line;
                warn(
                    name,
                    format!(
                        "section [{}] appears twice (first at line {first_line}); the second is dropped",
                        snippet(name)
                    ),
                    true,
                );
                continue;
            }
            ini.by_name.insert(folded, ini.sections.len());
            ini.sections.push(Section {
                name: name.to_string(),
                line: number,
                entries: Vec::new(),
            });
            in_section = true;
            continue;
        }
        let Some((key, value)) = line.split_once('=') else {
            warn(
                "",
                format!(
                    "expected [section] or key=value, found '{}'; line dropped",
                    snippet(line)
                ),
                true,
            );
            continue;
        };
        let key = key.trim();
        if key.is_empty() {
            warn("", "key=value with no key; line dropped".into(), true);
            continue;
        }
        let Some(section) = ini.sections.last_mut().filter(|_| in_section) else {
            if !seen_header {
                warn(
                    key,
                    format!("'{}' comes before any [section]; dropped", snippet(key)),
                    true,
                );
            }
            continue;
        };
        if let Some(first) = keys.get(&key.to_ascii_lowercase()) {
            warn(
                key,
                format!(
                    "{} appears twice in [{}] (first at line {first}); the first counts",
                    snippet(key),
                    section.name
                ),
                true,
            );
            continue;
        }
        keys.insert(key.to_ascii_lowercase(), number);
        let (value, comment) = clean_value(value);
        if let Some(comment) = comment {
            warn(
                &format!("[{}] {key}", section.name),
                format!(
                    "{}={}: '{}' after the value is read as a comment",
                    snippet(key),
                    snippet(value),
                    snippet(comment)
                ),
                false,
            );
        }
        section.entries.push(Entry {
            key: key.to_string(),
            value: value.to_string(),
            line: number,
        });
    }
    if let Some((line, count)) = hash_lines {
        let more = match count {
            1 => String::new(),
            n => format!(", and so are the {} more below", n - 1),
        };
        warnings.push(IniWarning {
            line,
            key: String::new(),
            message: format!(
                "a line that starts with '#' is read as a comment (CiA 306 comments start with \
                 ';'){more}"
            ),
            dropped: false,
        });
    }
    (ini, warnings)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sections_keys_and_comments() {
        let (ini, warnings) = parse(
            "\u{FEFF}; written by hand\r\n[FileInfo]\r\nFileName = x.eds \r\n\r\n\
             [1000]\nParameterName=Device Type ; the device profile\nDefaultValue=\"a ; b\"\n\
             Odd=\"quoted\" trailing\nNoComment=a;b\n  ;indented comment\n[Empty]\rKey=\r",
        );
        // The comment after a value (`;` after white space) is cut off and
        // said; the `;` of a quoted string or with no space before is kept.
        assert_eq!(
            warnings,
            [IniWarning {
                line: 6,
                key: "[1000] ParameterName".into(),
                message: "ParameterName=Device Type: '; the device profile' after the value \
                          is read as a comment"
                    .into(),
                dropped: false,
            }]
        );
        assert_eq!(ini.lines, 12);
        let names: Vec<_> = ini
            .sections
            .iter()
            .map(|s| (s.name.as_str(), s.line))
            .collect();
        assert_eq!(names, [("FileInfo", 2), ("1000", 5), ("Empty", 11)]);
        assert_eq!(
            ini.section("fileinfo")
                .unwrap()
                .get("FILENAME")
                .unwrap()
                .value,
            "x.eds"
        );
        let object = ini.section("1000").unwrap();
        assert_eq!(object.get("parametername").unwrap().value, "Device Type");
        assert_eq!(object.get("DefaultValue").unwrap().value, "\"a ; b\"");
        assert_eq!(object.get("DefaultValue").unwrap().line, 7);
        assert_eq!(object.get("Odd").unwrap().value, "\"quoted\" trailing");
        assert_eq!(object.get("NoComment").unwrap().value, "a;b");
        assert_eq!(ini.section("EMPTY").unwrap().get("key").unwrap().value, "");
        assert!(ini.section("missing").is_none());
    }

    #[test]
    fn hash_lines_are_comments_said_once_and_a_hash_after_a_value_is_kept() {
        let (ini, warnings) = parse(
            "[A]\n# Category: Mandatory\nk=1\n  #k=2\nName=Heartbeat #1\n\
             Quoted=\"x ; y\" ; a comment\n# last\n",
        );
        assert_eq!(
            warnings,
            [
                IniWarning {
                    line: 6,
                    key: "[A] Quoted".into(),
                    message: "Quoted=\"x ; y\": '; a comment' after the value is read as a \
                              comment"
                        .into(),
                    dropped: false,
                },
                IniWarning {
                    line: 2,
                    key: String::new(),
                    message: "a line that starts with '#' is read as a comment (CiA 306 \
                              comments start with ';'), and so are the 2 more below"
                        .into(),
                    dropped: false,
                },
            ]
        );
        let section = ini.section("A").unwrap();
        // `#k=2` is a comment, not a second `k`.
        assert_eq!(section.get("k").unwrap().value, "1");
        assert_eq!(section.entries.len(), 3);
        // A `#` after a value is for the reader to judge.
        assert_eq!(section.get("Name").unwrap().value, "Heartbeat #1");
        assert_eq!(section.get("Quoted").unwrap().value, "\"x ; y\"");
        // One line: no count.
        let (_, warnings) = parse("[A]\n#x\n");
        assert_eq!(
            warnings[0].message,
            "a line that starts with '#' is read as a comment (CiA 306 comments start with ';')"
        );
    }

    #[test]
    fn ambiguity_is_a_warning_with_its_line_and_the_first_counts() {
        let warned = |text: &str| {
            let (ini, warnings) = parse(text);
            assert_eq!(warnings.len(), 1, "{text:?}: {warnings:?}");
            (ini, warnings.into_iter().next().unwrap())
        };
        let (ini, warning) = warned("[A]\nx=1\n[a]\nx=2\ny=3\n");
        assert_eq!(
            warning,
            IniWarning {
                line: 3,
                key: "a".into(),
                message: "section [a] appears twice (first at line 1); the second is dropped"
                    .into(),
                dropped: true,
            }
        );
        assert_eq!(ini.sections.len(), 1);
        assert_eq!(ini.section("A").unwrap().get("x").unwrap().value, "1");
        assert!(ini.section("A").unwrap().get("y").is_none());

        let (ini, warning) = warned("[A]\nKey=1\nkey=2\n");
        assert_eq!(warning.line, 3);
        assert_eq!(
            warning.message,
            "key appears twice in [A] (first at line 2); the first counts"
        );
        assert_eq!(ini.section("A").unwrap().get("KEY").unwrap().value, "1");

        assert_eq!(warned("x=1\n[A]\n").1.line, 1);
        let (ini, warning) = warned("[A]\njunk\ny=1\n");
        assert_eq!((warning.line, warning.dropped), (2, true));
        assert_eq!(ini.section("A").unwrap().get("y").unwrap().value, "1");
        // A header without `]` is read to the end of its line.
        let (ini, warning) = warned("[A\nk=1\n");
        assert_eq!((warning.line, warning.dropped), (1, false));
        assert_eq!(ini.section("A").unwrap().get("k").unwrap().value, "1");
        // An unnamed section is dropped with its keys.
        let (ini, warning) = warned("[]\nk=1\n[B]\n");
        assert_eq!(warning.line, 1);
        assert_eq!(ini.sections.len(), 1);
        assert_eq!(warned("[A] x\n").1.line, 1);
        assert_eq!(warned("[A]\n=1\n").1.line, 2);
        assert_eq!(warned("[A]\nk=\u{0}\n").1.line, 2);
        // The same key in two sections is fine, and so are code-page
        // characters (0x80-0x9F of Windows-1252, decoded before).
        assert_eq!(parse("[A]\nk=1\n[B]\nk=2\n").1, []);
        assert_eq!(parse("[A]\nk=Sch\u{F6}naich \u{2019}\u{80}\n").1, []);
        assert_eq!(parse("").0.lines, 0);
    }
}

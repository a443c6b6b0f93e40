//! The INI dialect of CiA 306, as vendors really write it: `[section]`
//! headers and `key=value` lines, names compared without case, `;` comment
//! lines, CR LF or LF or CR line ends, an optional UTF-8 byte order mark.
//!
//! Anything ambiguous is an error with its line rather than a guess: a
//! section or key that appears twice (which copy would count?), a line that is
//! neither header nor `key=value`, control characters (a binary file).

use std::collections::HashMap;

use crate::canopen::od::snippet;

#[derive(Debug)]
pub(super) struct Ini {
    pub sections: Vec<Section>,
    /// Lower-case section name to its position in `sections`.
    by_name: HashMap<String, usize>,
    /// The number of lines, for errors about what is missing.
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

#[derive(Debug, PartialEq, Eq)]
pub(super) struct IniError {
    pub line: usize,
    pub message: String,
}

impl Ini {
    pub fn section(&self, name: &str) -> Option<&Section> {
        self.by_name
            .get(&name.to_ascii_lowercase())
            .map(|&i| &self.sections[i])
    }
}

impl Section {
    pub fn get(&self, key: &str) -> Option<&Entry> {
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
/// its quotes, and a comment (`;` after white space) cut off.
fn clean_value(raw: &str) -> &str {
    let value = raw.trim();
    if value.starts_with('"')
        && let Some(close) = value.rfind('"').filter(|&close| close > 0)
    {
        let after = value[close + 1..].trim_start();
        if after.is_empty() || after.starts_with(';') {
            return &value[..=close];
        }
    }
    let bytes = raw.as_bytes();
    let comment =
        (1..bytes.len()).find(|&i| bytes[i] == b';' && matches!(bytes[i - 1], b' ' | b'\t'));
    match comment {
        Some(start) => raw[..start].trim(),
        None => value,
    }
}

/// C0 controls but tab, DEL, and C1 controls (U+0080 to U+009F, which is
/// what stray bytes 0x80 to 0x9F become when a file is read as Latin-1).
/// Byte by byte, as lines can be megabytes long.
fn has_control_characters(line: &str) -> bool {
    let bytes = line.as_bytes();
    bytes.iter().enumerate().any(|(i, &b)| {
        (b < 0x20 && b != b'\t')
            || b == 0x7F
            || (b == 0xC2
                && bytes
                    .get(i + 1)
                    .is_some_and(|next| (0x80..=0x9F).contains(next)))
    })
}

pub(super) fn parse(text: &str) -> Result<Ini, IniError> {
    let text = text.strip_prefix('\u{FEFF}').unwrap_or(text);
    let mut ini = Ini {
        sections: Vec::new(),
        by_name: HashMap::new(),
        lines: 0,
    };
    // Lower-case key to its line, for the current section.
    let mut keys: HashMap<String, usize> = HashMap::new();
    for (number, line) in lines(text) {
        ini.lines = number;
        let error = |message: String| IniError {
            line: number,
            message,
        };
        if has_control_characters(line) {
            return Err(error("control characters: this is not a text file".into()));
        }
        let line = line.trim();
        if line.is_empty() || line.starts_with(';') {
            continue;
        }
        if let Some(header) = line.strip_prefix('[') {
            let Some((name, after)) = header.split_once(']') else {
                return Err(error(format!(
                    "section header '{}' has no ']'",
                    snippet(line)
                )));
            };
            let after = after.trim();
            if !after.is_empty() && !after.starts_with(';') {
                return Err(error(format!(
                    "text after the section header: '{}'",
                    snippet(after)
                )));
            }
            let name = name.trim();
            if name.is_empty() {
                return Err(error("empty section name".into()));
            }
            let folded = name.to_ascii_lowercase();
            if let Some(&first) = ini.by_name.get(&folded) {
                let first_line = ini.sections[first].line;
                return Err(error(format!(
                    "section [{}] appears twice (first at line {first_line})",
                    snippet(name)
                )));
            }
            ini.by_name.insert(folded, ini.sections.len());
            ini.sections.push(Section {
                name: name.to_string(),
                line: number,
                entries: Vec::new(),
            });
            keys.clear();
            continue;
        }
        let Some((key, value)) = line.split_once('=') else {
            return Err(error(format!(
                "expected [section] or key=value, found '{}'",
                snippet(line)
            )));
        };
        let key = key.trim();
        if key.is_empty() {
            return Err(error("key=value with no key".into()));
        }
        let Some(section) = ini.sections.last_mut() else {
            return Err(error(format!(
                "'{}' comes before any [section]",
                snippet(key)
            )));
        };
        if let Some(first) = keys.insert(key.to_ascii_lowercase(), number) {
            return Err(error(format!(
                "{} appears twice in [{}] (first at line {first})",
                snippet(key),
                section.name
            )));
        }
        section.entries.push(Entry {
            key: key.to_string(),
            value: clean_value(value).to_string(),
            line: number,
        });
    }
    Ok(ini)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sections_keys_and_comments() {
        let ini = parse(
            "\u{FEFF}; written by hand\r\n[FileInfo]\r\nFileName = x.eds \r\n\r\n\
             [1000]\nParameterName=Device Type ; the device profile\nDefaultValue=\"a ; b\"\n\
             Odd=\"quoted\" trailing\nNoComment=a;b\n  ;indented comment\n[Empty]\rKey=\r",
        )
        .unwrap();
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
    fn ambiguity_is_an_error_with_its_line() {
        let error = |text: &str| parse(text).unwrap_err();
        assert_eq!(
            error("[A]\nx=1\n[a]\n"),
            IniError {
                line: 3,
                message: "section [a] appears twice (first at line 1)".into()
            }
        );
        assert_eq!(
            error("[A]\nKey=1\nkey=2\n"),
            IniError {
                line: 3,
                message: "key appears twice in [A] (first at line 2)".into()
            }
        );
        assert_eq!(error("x=1\n").line, 1);
        assert_eq!(error("[A]\njunk\n").line, 2);
        assert_eq!(error("[A\n").line, 1);
        assert_eq!(error("[]\n").line, 1);
        assert_eq!(error("[A] x\n").line, 1);
        assert_eq!(error("[A]\n=1\n").line, 2);
        assert_eq!(error("[A]\nk=\u{0}\n").line, 2);
        // The same key in two sections is fine.
        assert!(parse("[A]\nk=1\n[B]\nk=2\n").is_ok());
        assert_eq!(parse("").unwrap().lines, 0);
    }
}

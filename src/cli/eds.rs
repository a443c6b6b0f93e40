//! `candeck eds check`: EDS and DCF files (CiA 306) read as the gateway
//! reads them, with every warning and error of each file and one summary
//! line per file (docs/eds.md).

use std::fmt::Write as _;
use std::path::PathBuf;

use clap::{Args, Subcommand};
use serde_json::{Value as Json, json};

use super::CliError;
use crate::canopen::NodeId;
use crate::canopen::eds::{Eds, EdsError, read_eds_file};
use crate::canopen::od::{ObjectDictionary, SubObject};

#[derive(Debug, Args)]
pub struct EdsArgs {
    #[command(subcommand)]
    pub command: EdsCommand,
}

#[derive(Debug, Subcommand)]
pub enum EdsCommand {
    /// Reads EDS/DCF files: every warning and error with file:line, one
    /// summary line per file. Exit status 0 when every file is usable
    /// (warnings allowed), 1 otherwise.
    Check(CheckArgs),
}

#[derive(Debug, Args)]
pub struct CheckArgs {
    /// Fail (exit status 1) on warnings too, not only on files that cannot
    /// be read.
    #[arg(long)]
    pub strict: bool,
    /// One JSON document on stdout: an array with one object per file.
    #[arg(long)]
    pub json: bool,
    /// With --json: each file's dictionary too (every entry's object type,
    /// data type, access type, PDO mapping, default and limits; the default
    /// also as a value).
    #[arg(long, requires = "json")]
    pub dictionary: bool,
    /// The EDS or DCF files.
    #[arg(value_name = "FILE", required = true)]
    pub files: Vec<PathBuf>,
}

/// What one file gave.
struct Checked {
    file: String,
    result: Result<Eds, EdsError>,
}

impl Checked {
    fn usable(&self, strict: bool) -> bool {
        match &self.result {
            Ok(eds) => self.unusable(eds).is_none() && (!strict || eds.warnings.is_empty()),
            Err(_) => false,
        }
    }

    /// Why a file that read is not usable (it yields no object).
    fn unusable(&self, eds: &Eds) -> Option<EdsError> {
        eds.why_unusable(&self.file)
    }
}

pub async fn run(args: EdsArgs) -> Result<(), CliError> {
    match args.command {
        EdsCommand::Check(args) => check(args),
    }
}

fn check(args: CheckArgs) -> Result<(), CliError> {
    let checked: Vec<Checked> = args
        .files
        .iter()
        .map(|path| Checked {
            file: path.display().to_string(),
            result: read_eds_file(path),
        })
        .collect();
    let out = if args.json {
        let files: Vec<Json> = checked
            .iter()
            .map(|c| file_json(c, args.strict, args.dictionary))
            .collect();
        let mut text = serde_json::to_string_pretty(&files).map_err(CliError::new)?;
        text.push('\n');
        text
    } else {
        checked.iter().map(report).collect()
    };
    {
        use std::io::Write as _;
        let mut stdout = std::io::stdout().lock();
        stdout
            .write_all(out.as_bytes())
            .and_then(|()| stdout.flush())
            .map_err(CliError::new)?;
    }
    let failed = checked.iter().filter(|c| !c.usable(args.strict)).count();
    match failed {
        0 => Ok(()),
        n => {
            let why = if args.strict {
                "not usable or with warnings (--strict)"
            } else {
                "not usable"
            };
            Err(CliError::new(format!(
                "{n} of {} files {why}",
                checked.len()
            )))
        }
    }
}

/// The number of the device type (object 0x1000's default), if it has one.
fn device_type(dictionary: &ObjectDictionary) -> Option<u32> {
    dictionary
        .sub(0x1000, 0)
        .and_then(|entry| entry.default_value(None).ok().flatten())
        .and_then(|value| value.as_i128())
        .and_then(|value| u32::try_from(value).ok())
}

fn hex(value: Option<u32>) -> String {
    value.map_or_else(|| "none".to_string(), |value| format!("0x{value:08X}"))
}

/// Every warning, then the summary line: `FILE: ok|usable|refused: ...`.
fn report(checked: &Checked) -> String {
    let mut out = String::new();
    match &checked.result {
        Err(error) => {
            let _ = writeln!(out, "{error}");
            let _ = writeln!(out, "{}: refused: not an EDS or DCF", checked.file);
        }
        Ok(eds) => {
            for warning in &eds.warnings {
                let _ = writeln!(out, "{warning} [{}]", warning.action);
            }
            if let Some(error) = checked.unusable(eds) {
                let at = match error.line {
                    0 => String::new(),
                    line => format!(" (line {line})"),
                };
                let _ = writeln!(
                    out,
                    "{}: not usable, {} warnings: {}{at}",
                    checked.file,
                    eds.warnings.len(),
                    error.message
                );
                return out;
            }
            let info = &eds.device_info;
            let name = |name: &Option<String>| {
                name.as_deref()
                    .map_or_else(String::new, |name| format!(" ({name})"))
            };
            let verdict = if eds.warnings.is_empty() {
                "ok".to_string()
            } else {
                format!("usable, {} warnings", eds.warnings.len())
            };
            let kind = if eds.is_dcf() { "DCF" } else { "EDS" };
            let _ = writeln!(
                out,
                "{}: {verdict}: {kind}, {} objects, {} sub-entries, vendor {}{}, product {}{}, \
                 revision {}, device type {}",
                checked.file,
                eds.dictionary.len(),
                eds.dictionary.subs().count(),
                hex(info.vendor_number),
                name(&info.vendor_name),
                hex(info.product_number),
                name(&info.product_name),
                hex(info.revision_number),
                hex(device_type(&eds.dictionary)),
            );
        }
    }
    out
}

fn file_json(checked: &Checked, strict: bool, dictionary: bool) -> Json {
    let usable = checked.usable(strict);
    match &checked.result {
        Err(error) => json!({
            "file": checked.file,
            "usable": false,
            "errors": [{"line": error.line, "message": error.message}],
            "warnings": [],
        }),
        Ok(eds) => {
            let info = &eds.device_info;
            let warnings: Vec<Json> = eds
                .warnings
                .iter()
                .map(|w| {
                    json!({"line": w.line, "key": w.key, "action": w.action, "message": w.message})
                })
                .collect();
            let errors: Vec<Json> = checked
                .unusable(eds)
                .map(|error| json!({"line": error.line, "message": error.message}))
                .into_iter()
                .collect();
            let mut file = json!({
                "file": checked.file,
                "usable": usable,
                "kind": if eds.is_dcf() { "dcf" } else { "eds" },
                "objects": eds.dictionary.len(),
                "sub_entries": eds.dictionary.subs().count(),
                "vendor_number": info.vendor_number,
                "vendor_name": info.vendor_name,
                "product_number": info.product_number,
                "product_name": info.product_name,
                "revision_number": info.revision_number,
                "device_type": device_type(&eds.dictionary),
                "errors": errors,
                "warnings": warnings,
            });
            if dictionary {
                file["dictionary"] = dictionary_json(&eds.dictionary, eds.node_id());
            }
            file
        }
    }
}

/// Each object with its entries, as read: what a comparison with another
/// reader needs.
fn dictionary_json(dictionary: &ObjectDictionary, node: Option<NodeId>) -> Json {
    let entry = |sub: &SubObject| {
        json!({
            "sub_index": sub.sub_index,
            "name": sub.name,
            "data_type": sub.data_type.raw(),
            "access": sub.access.as_str(),
            "pdo_mappable": sub.pdo_mappable,
            "default": sub.default,
            // As a value (REST JSON form), `$NODEID` resolved with a DCF's
            // node id; null when there is none or it depends on a node id
            // the file does not give.
            "default_value": sub
                .default_value(node)
                .ok()
                .flatten()
                .map(|value| value.to_json()),
            "low": sub.low,
            "high": sub.high,
            "parameter_value": sub.parameter_value,
        })
    };
    Json::Array(
        dictionary
            .iter()
            .map(|object| {
                json!({
                    "index": object.index,
                    "name": object.name,
                    "object_type": object.object_type.raw(),
                    "subs": object.subs.values().map(entry).collect::<Vec<_>>(),
                })
            })
            .collect(),
    )
}

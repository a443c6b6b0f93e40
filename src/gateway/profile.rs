//! Which product a node is, and which EDS describes it: the identity a node
//! reports (device type 0x1000, identity object 0x1018, CiA 301 §7.5.2.1 and
//! §7.5.2.28) matched against the EDS files the gateway knows (CiA 306
//! `[DeviceInfo]`).
//!
//! The [`EdsCatalog`] holds the built-in EDS files of candeck's products and
//! the users' EDS files of an `--eds-dir`, each parsed once and shared. A
//! node's identity picks the best entry: the exact revision first, else the
//! highest revision of the same vendor and product that is not above the
//! device's (a newer firmware usually keeps the objects of an older one),
//! else any revision of the product (the highest). At equal rank a user's
//! file wins over a built-in one: whoever put it there knows their device.
//!
//! The [`Profile`] says what the gateway can do with the node beyond SDO:
//! candeck's own products are known by vendor and product, whichever file
//! describes them; any other device whose device type is CiA 402 is driven
//! as a generic CiA 402 drive; everything else is generic.

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::canopen::eds::{Eds, EdsWarning, read_eds_file};
use crate::profiles::builtin;

use super::registry::RegistryError;

/// What the gateway knows how to do with a node. The API names are
/// `umc`, `jmc_stepper`, `uioled`, `cia402`, `generic`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Profile {
    /// UniSwarm UMC motion controllers (axis offsets, Q15.16 units).
    Umc,
    /// JMC CANopen stepper drives (mode numbers, 16-bit accelerations).
    JmcStepper,
    /// UniSwarm UIO1LED LED strip controllers (segments, effects).
    Uioled,
    /// Any other CiA 402 drive (device type 402 in its low 16 bits).
    Cia402,
    /// SDO, PDO, NMT and EMCY only.
    Generic,
}

/// The CiA 402 device profile number, in the low 16 bits of 0x1000.
const CIA402_PROFILE: u32 = 402;

impl Profile {
    pub const ALL: [Profile; 5] = [
        Self::Umc,
        Self::JmcStepper,
        Self::Uioled,
        Self::Cia402,
        Self::Generic,
    ];

    /// The name in the HTTP API.
    pub fn name(self) -> &'static str {
        match self {
            Self::Umc => "umc",
            Self::JmcStepper => "jmc_stepper",
            Self::Uioled => "uioled",
            Self::Cia402 => "cia402",
            Self::Generic => "generic",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|profile| profile.name() == name)
    }

    /// The profile of a device that is none of candeck's products, from its
    /// device type (0x1000): bits 0–15 are the device profile number, so
    /// both 402 and 0x00020192 (a CiA 402 servo drive) are CiA 402.
    pub fn from_device_type(device_type: u32) -> Self {
        if device_type & 0xFFFF == CIA402_PROFILE {
            Self::Cia402
        } else {
            Self::Generic
        }
    }

    /// Whether the node is a CiA 402 drive (axes endpoints).
    pub fn is_drive(self) -> bool {
        matches!(self, Self::Umc | Self::JmcStepper | Self::Cia402)
    }
}

impl fmt::Display for Profile {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The identity object 0x1018 of a node. Sub 1 (vendor) is mandatory in
/// CiA 301; the others are optional and `None` when the node does not have
/// them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
pub struct Identity {
    pub vendor_id: u32,
    pub product_code: Option<u32>,
    pub revision: Option<u32>,
    pub serial: Option<u32>,
}

/// Where an EDS of the catalog comes from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum EdsSource {
    /// Carried in the binary (`eds/` in the repository).
    BuiltIn,
    /// A user's file from the EDS directory.
    File(PathBuf),
}

/// One EDS of the catalog, with the identity it describes.
#[derive(Debug)]
pub struct EdsEntry {
    /// The file name (`umc1bds32.eds`, or the user's file name): what the
    /// API shows as the node's `eds`.
    pub name: String,
    pub source: EdsSource,
    pub vendor_id: u32,
    pub product_code: u32,
    /// `None` when the file names no revision: it then matches any revision
    /// of its product, ranked below every file that names one.
    pub revision: Option<u32>,
    pub profile: Profile,
    /// The parsed file, shared by every node it describes.
    pub eds: Arc<Eds>,
}

/// How well an entry fits an identity; higher is better.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Rank {
    /// Same product, a revision above the device's or none given.
    AnyRevision,
    /// Same product, a revision not above the device's (or the device gave
    /// none): the closer, the better.
    NotAbove,
    /// Same vendor, product and revision.
    Exact,
}

impl EdsEntry {
    fn rank(&self, identity: &Identity) -> Option<Rank> {
        if self.vendor_id != identity.vendor_id || Some(self.product_code) != identity.product_code
        {
            return None;
        }
        Some(match (self.revision, identity.revision) {
            (Some(ours), Some(theirs)) if ours == theirs => Rank::Exact,
            (Some(ours), Some(theirs)) if ours < theirs => Rank::NotAbove,
            (Some(_), None) => Rank::NotAbove,
            _ => Rank::AnyRevision,
        })
    }

    fn is_user_file(&self) -> bool {
        matches!(self.source, EdsSource::File(_))
    }
}

/// The EDS files the gateway matches nodes against. Cheap to share behind
/// an `Arc`; every file is parsed once, when the catalog is made.
#[derive(Debug)]
pub struct EdsCatalog {
    entries: Vec<Arc<EdsEntry>>,
    /// The users' files that could not join the catalog, in file name order.
    skipped: Vec<SkippedFile>,
}

/// A file of the EDS directory the catalog left out, and why (it is no EDS,
/// or it names no vendor or product to match a device by).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SkippedFile {
    pub path: PathBuf,
    pub message: String,
    /// The reader's warnings, when the file is an EDS at all.
    pub warnings: Vec<EdsWarning>,
}

/// The built-in files: name, text, and the profile of the product.
const BUILT_IN: [(&str, &str, Profile); 4] = [
    ("umc1bds32.eds", builtin::UMC1BDS32, Profile::Umc),
    ("umc1bd90.eds", builtin::UMC1BD90, Profile::Umc),
    ("jmc_stepper.eds", builtin::JMC_STEPPER, Profile::JmcStepper),
    ("uio1led.eds", builtin::UIO1LED, Profile::Uioled),
];

/// File extensions read from an EDS directory (any case).
const EDS_EXTENSIONS: [&str; 2] = ["eds", "dcf"];

impl EdsCatalog {
    /// The built-in EDS files of candeck's products.
    pub fn builtin() -> Result<Self, RegistryError> {
        let mut entries = Vec::with_capacity(BUILT_IN.len());
        for (name, text, profile) in BUILT_IN {
            let file = format!("{name} (built in)");
            let eds = Eds::parse(text, &file)?;
            entries.push(Arc::new(entry(
                name.to_string(),
                EdsSource::BuiltIn,
                eds,
                Some(profile),
            )?));
        }
        Ok(Self {
            entries,
            skipped: Vec::new(),
        })
    }

    /// The built-in files and every `*.eds` and `*.dcf` file of `dir` (not
    /// its subdirectories). A bad file never stops the gateway: a file that
    /// is no EDS, or that names no vendor and product, is left out, logged
    /// with its reason and listed in [`EdsCatalog::skipped`]; a file's
    /// warnings are logged. Only a directory that cannot be read is an
    /// error.
    pub fn with_dir(dir: impl AsRef<Path>) -> Result<Self, RegistryError> {
        let mut catalog = Self::builtin()?;
        let dir = dir.as_ref();
        let io_error = |error: std::io::Error| RegistryError::EdsDir {
            dir: dir.to_path_buf(),
            message: error.to_string(),
        };
        let mut paths = Vec::new();
        for item in std::fs::read_dir(dir).map_err(io_error)? {
            let path = item.map_err(io_error)?.path();
            let is_eds = path
                .extension()
                .and_then(|ext| ext.to_str())
                .is_some_and(|ext| EDS_EXTENSIONS.iter().any(|e| ext.eq_ignore_ascii_case(e)));
            if is_eds && path.is_file() {
                paths.push(path);
            }
        }
        // Directory order is the file system's; sorted, the result is the
        // same everywhere.
        paths.sort();
        for path in paths {
            match catalog.add_file(&path) {
                Ok(entry) if !entry.eds.warnings.is_empty() => tracing::warn!(
                    "EDS {}: {} warnings, read anyway (candeck eds check {0} lists them)",
                    path.display(),
                    entry.eds.warnings.len()
                ),
                Ok(_) => {}
                Err(error) => {
                    tracing::error!("EDS {} left out: {error}", path.display());
                    let warnings = read_eds_file(&path)
                        .map(|eds| eds.warnings)
                        .unwrap_or_default();
                    catalog.skipped.push(SkippedFile {
                        path,
                        message: error.to_string(),
                        warnings,
                    });
                }
            }
        }
        Ok(catalog)
    }

    /// Adds a user's EDS file.
    pub fn add_file(&mut self, path: &Path) -> Result<Arc<EdsEntry>, RegistryError> {
        let eds = read_eds_file(path)?;
        let name = path
            .file_name()
            .map(|name| name.to_string_lossy().into_owned())
            .unwrap_or_else(|| path.display().to_string());
        // A user's file of one of our products keeps the product's profile.
        let known = |vendor: u32, product: u32| {
            self.entries
                .iter()
                .find(|e| !e.is_user_file() && e.vendor_id == vendor && e.product_code == product)
                .map(|e| e.profile)
        };
        let (vendor, product, _) = identity_of(&eds, &path.display().to_string())?;
        let profile = known(vendor, product);
        let added = Arc::new(entry(
            name,
            EdsSource::File(path.to_path_buf()),
            eds,
            profile,
        )?);
        self.entries.push(added.clone());
        Ok(added)
    }

    /// The files of the EDS directory that were left out, with why.
    pub fn skipped(&self) -> &[SkippedFile] {
        &self.skipped
    }

    /// Every entry: the built-in ones first, then the users' in file name
    /// order.
    pub fn entries(&self) -> &[Arc<EdsEntry>] {
        &self.entries
    }

    /// The EDS that best describes a node with `identity` (see the module
    /// documentation for the order); `None` when no file is of its vendor
    /// and product.
    pub fn lookup(&self, identity: &Identity) -> Option<Arc<EdsEntry>> {
        self.entries
            .iter()
            .filter_map(|entry| Some((entry, entry.rank(identity)?)))
            .max_by_key(|(entry, rank)| (*rank, entry.revision, entry.is_user_file()))
            .map(|(entry, _)| entry.clone())
    }

    /// The profile of a node: its EDS's if one matches, else from its
    /// device type, else generic.
    pub fn profile(&self, identity: Option<&Identity>, device_type: Option<u32>) -> Profile {
        identity
            .and_then(|identity| self.lookup(identity))
            .map(|entry| entry.profile)
            .or_else(|| device_type.map(Profile::from_device_type))
            .unwrap_or(Profile::Generic)
    }
}

/// The vendor, product and revision an EDS describes: `[DeviceInfo]`, or
/// the defaults of its 0x1018 when `[DeviceInfo]` lacks them.
fn identity_of(eds: &Eds, file: &str) -> Result<(u32, u32, Option<u32>), RegistryError> {
    let from_dictionary = |sub: u8| -> Option<u32> {
        let value = eds
            .dictionary
            .sub(0x1018, sub)?
            .default_value(None)
            .ok()??;
        u32::try_from(value.as_i128()?).ok()
    };
    let info = &eds.device_info;
    let missing = |what: &str| RegistryError::EdsUnmatchable {
        file: file.to_string(),
        message: format!(
            "names no {what} ([DeviceInfo] or 0x1018), so no device can be matched to it"
        ),
    };
    let vendor = info
        .vendor_number
        .or_else(|| from_dictionary(1))
        .ok_or_else(|| missing("vendor number"))?;
    let product = info
        .product_number
        .or_else(|| from_dictionary(2))
        .ok_or_else(|| missing("product number"))?;
    let revision = info.revision_number.or_else(|| from_dictionary(3));
    Ok((vendor, product, revision))
}

/// The device type (0x1000) an EDS gives as default.
fn device_type_of(eds: &Eds) -> Option<u32> {
    let value = eds.dictionary.sub(0x1000, 0)?.default_value(None).ok()??;
    u32::try_from(value.as_i128()?).ok()
}

fn entry(
    name: String,
    source: EdsSource,
    eds: Eds,
    profile: Option<Profile>,
) -> Result<EdsEntry, RegistryError> {
    let file = match &source {
        EdsSource::BuiltIn => format!("{name} (built in)"),
        EdsSource::File(path) => path.display().to_string(),
    };
    let (vendor_id, product_code, revision) = identity_of(&eds, &file)?;
    let profile = profile.unwrap_or_else(|| {
        device_type_of(&eds)
            .map(Profile::from_device_type)
            .unwrap_or(Profile::Generic)
    });
    Ok(EdsEntry {
        name,
        source,
        vendor_id,
        product_code,
        revision,
        profile,
        eds: Arc::new(eds),
    })
}

#[cfg(test)]
mod tests;

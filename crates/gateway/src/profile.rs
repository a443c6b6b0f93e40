//! Which product a node is, and which EDS describes it: the identity a node
//! reports (device type 0x1000, identity object 0x1018, CiA 301 §7.5.2.1 and
//! §7.5.2.28) matched against the EDS files the gateway knows (CiA 306
//! `[DeviceInfo]`).
//!
//! The [`EdsCatalog`] holds the built-in EDS files of candeck's products,
//! the users' EDS files of an `--eds-dir` and those uploaded while the
//! gateway runs (kept in the data directory's `eds/`, or in memory), each
//! parsed once and shared. A file that names no vendor or product is in the
//! catalog too, but describes only the nodes it is assigned to by hand
//! ([`super::registry::NodeRegistry::assign_eds`]). A node's identity picks
//! the best entry: the exact revision first, else the
//! highest revision of the same vendor and product that is not above the
//! device's (a newer firmware usually keeps the objects of an older one),
//! else any revision of the product (the highest). At equal rank a user's
//! file wins over a built-in one: whoever put it there knows their device.
//!
//! The [`Profile`] says what the gateway can do with the node beyond SDO:
//! candeck's own products are known by vendor and product, whichever file
//! describes them; any other device whose device type is CiA 402 is driven
//! as a generic CiA 402 drive, one of CiA 401 is a generic I/O module;
//! everything else is generic.

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, RwLock};

use crate::canopen::eds::{Eds, EdsError, EdsWarning, read_eds_file};
use crate::profiles::builtin;

use super::registry::RegistryError;

/// What the gateway knows how to do with a node. The API names are
/// `umc`, `jmc_stepper`, `uioled`, `cia402`, `cia401`, `generic`.
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
    /// A CiA 401 generic I/O module (device type 401 in its low 16 bits):
    /// digital and analogue inputs and outputs.
    Cia401,
    /// SDO, PDO, NMT and EMCY only.
    Generic,
}

/// The CiA 402 device profile number, in the low 16 bits of 0x1000.
const CIA402_PROFILE: u32 = 402;
/// The CiA 401 device profile number (generic I/O modules).
const CIA401_PROFILE: u32 = 401;

impl Profile {
    pub const ALL: [Profile; 6] = [
        Self::Umc,
        Self::JmcStepper,
        Self::Uioled,
        Self::Cia402,
        Self::Cia401,
        Self::Generic,
    ];

    /// The name in the HTTP API.
    pub fn name(self) -> &'static str {
        match self {
            Self::Umc => "umc",
            Self::JmcStepper => "jmc_stepper",
            Self::Uioled => "uioled",
            Self::Cia402 => "cia402",
            Self::Cia401 => "cia401",
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
        match device_type & 0xFFFF {
            CIA402_PROFILE => Self::Cia402,
            CIA401_PROFILE => Self::Cia401,
            _ => Self::Generic,
        }
    }

    /// Whether the node is a CiA 402 drive (axes endpoints).
    pub fn is_drive(self) -> bool {
        matches!(self, Self::Umc | Self::JmcStepper | Self::Cia402)
    }

    /// The axis an EMCY with these manufacturer bytes belongs to, where
    /// the product says (the UMC: [`crate::profiles::umc::emcy_axis`]);
    /// `None` for a node-wide EMCY or a product that does not say.
    pub fn emcy_axis(self, manufacturer: &[u8; 5]) -> Option<u8> {
        match self {
            Self::Umc => crate::profiles::umc::emcy_axis(manufacturer),
            _ => None,
        }
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
    /// Uploaded through a door: kept in the data directory's `eds/`
    /// (the path), or in memory only when the gateway has no data
    /// directory (`None`).
    Uploaded(Option<PathBuf>),
}

impl EdsSource {
    /// The API's name: `built_in`, `dir` or `uploaded`.
    pub fn name(&self) -> &'static str {
        match self {
            Self::BuiltIn => "built_in",
            Self::File(_) => "dir",
            Self::Uploaded(_) => "uploaded",
        }
    }
}

/// One EDS of the catalog, with the identity it describes.
#[derive(Debug)]
pub struct EdsEntry {
    /// The file name (`umc1bds32.eds`, or the user's file name): what the
    /// API shows as the node's `eds`.
    pub name: String,
    pub source: EdsSource,
    /// The vendor and product the file describes (`[DeviceInfo]`, else the
    /// defaults of 0x1018 sub 1 and 2); `None` when it names none: such a
    /// file matches no device by identity, and describes a node only when
    /// it is assigned to it by hand.
    pub vendor_id: Option<u32>,
    pub product_code: Option<u32>,
    /// `None` when the file names no revision: it then matches any revision
    /// of its product, ranked below every file that names one.
    pub revision: Option<u32>,
    /// The device type (0x1000's default), when the file gives one.
    pub device_type: Option<u32>,
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
        if self.vendor_id != Some(identity.vendor_id)
            || self.product_code.is_none()
            || self.product_code != identity.product_code
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
        !matches!(self.source, EdsSource::BuiltIn)
    }

    /// Whether a device can be matched to the file by its identity.
    pub fn matches_by_identity(&self) -> bool {
        self.vendor_id.is_some() && self.product_code.is_some()
    }

    /// The profile of a node described by this file when it is assigned by
    /// hand: the file's (one of candeck's products, or its device type),
    /// else, when the file gives no device type, the device's own 0x1000.
    pub fn profile_for(&self, device_type: Option<u32>) -> Profile {
        if self.device_type.is_none() && self.profile == Profile::Generic {
            device_type.map_or(Profile::Generic, Profile::from_device_type)
        } else {
            self.profile
        }
    }
}

/// The EDS files the gateway matches nodes against. Cheap to share behind
/// an `Arc`; every file is parsed once, when it joins the catalog. Files
/// uploaded while the gateway runs join (and leave) it through `&self`.
#[derive(Debug)]
pub struct EdsCatalog {
    entries: RwLock<Vec<Arc<EdsEntry>>>,
    /// The users' files that could not join the catalog, in file name order.
    skipped: Vec<SkippedFile>,
    /// Where uploaded files are kept (`DATA/eds`); `None`: in memory only.
    uploads: Option<PathBuf>,
    /// How many uploaded files, and how many bytes of them, the catalog
    /// takes.
    quota: Mutex<EdsQuota>,
    /// The size of every uploaded file in the catalog, by name.
    upload_bytes: Mutex<BTreeMap<String, u64>>,
}

/// Uploaded EDS files the catalog takes at most (issue 30, finding 7:
/// 2,044 uploads took 850 MB and made `GET /eds` 60 MB): their count and
/// their bytes together (config keys `eds_max_files`, `eds_max_mb`). Files
/// of the EDS directory and the built-in ones do not count.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EdsQuota {
    pub max_files: usize,
    pub max_bytes: u64,
}

/// Uploaded EDS files at most, by default.
pub const DEFAULT_EDS_MAX_FILES: usize = 256;
/// Bytes of uploaded EDS files at most, by default (64 MiB).
pub const DEFAULT_EDS_MAX_BYTES: u64 = 64 * 1024 * 1024;

impl Default for EdsQuota {
    fn default() -> Self {
        Self {
            max_files: DEFAULT_EDS_MAX_FILES,
            max_bytes: DEFAULT_EDS_MAX_BYTES,
        }
    }
}

/// A file of the EDS directory the catalog left out, and why (it is no EDS,
/// or no object could be read from it).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SkippedFile {
    pub path: PathBuf,
    pub message: String,
    /// The reader's warnings, when the file is an EDS at all.
    pub warnings: Vec<EdsWarning>,
}

/// Why an upload or a removal was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CatalogError {
    /// The name is no plain file name ending in `.eds` or `.dcf`.
    #[error("{0}")]
    InvalidName(String),
    /// The file is no EDS, or no object could be read from it (the
    /// reader's error, with its line).
    #[error(transparent)]
    NotEds(#[from] EdsError),
    /// Another file of the catalog has the name.
    #[error("{0}")]
    Exists(String),
    /// No file of the catalog has the name.
    #[error("no EDS file is named '{0}'")]
    Unknown(String),
    /// Only uploaded files can be removed.
    #[error("{0}")]
    NotUploaded(String),
    /// The upload would take the uploaded files over [`EdsQuota`].
    #[error("{0}")]
    Quota(String),
    /// The file could not be kept or removed (disk full, permissions).
    #[error("{0}")]
    Io(String),
}

/// The built-in files: name, text, and the profile of the product.
const BUILT_IN: [(&str, &str, Profile); 5] = [
    ("umc1bds32.eds", builtin::UMC1BDS32, Profile::Umc),
    ("umc1bd90.eds", builtin::UMC1BD90, Profile::Umc),
    ("jmc_stepper.eds", builtin::JMC_STEPPER, Profile::JmcStepper),
    ("uio1led.eds", builtin::UIO1LED, Profile::Uioled),
    ("io401.eds", builtin::IO401, Profile::Cia401),
];

/// File extensions read from an EDS directory (any case).
const EDS_EXTENSIONS: [&str; 2] = ["eds", "dcf"];

/// The longest name of an uploaded file.
const MAX_NAME_LEN: usize = 100;

fn is_eds_path(path: &Path) -> bool {
    path.extension()
        .and_then(|ext| ext.to_str())
        .is_some_and(|ext| EDS_EXTENSIONS.iter().any(|e| ext.eq_ignore_ascii_case(e)))
}

/// The `*.eds` and `*.dcf` files of `dir` (not its subdirectories), in
/// name order (directory order is the file system's; sorted, the result is
/// the same everywhere).
fn eds_files(dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut paths = Vec::new();
    for item in std::fs::read_dir(dir)? {
        let path = item?.path();
        if is_eds_path(&path) && path.is_file() {
            paths.push(path);
        }
    }
    paths.sort();
    Ok(paths)
}

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
            )));
        }
        Ok(Self {
            entries: RwLock::new(entries),
            skipped: Vec::new(),
            uploads: None,
            quota: Mutex::new(EdsQuota::default()),
            upload_bytes: Mutex::new(BTreeMap::new()),
        })
    }

    /// The built-in files and every `*.eds` and `*.dcf` file of `dir` (not
    /// its subdirectories). A bad file never stops the gateway: a file that
    /// is no EDS, or yields no object, is left out, logged with its reason
    /// and listed in [`EdsCatalog::skipped`]; a file that names no vendor
    /// or product joins the catalog to be assigned to nodes by hand (it
    /// matches no device by identity); a file's warnings are logged. Only
    /// a directory that cannot be read is an error.
    pub fn with_dir(dir: impl AsRef<Path>) -> Result<Self, RegistryError> {
        let mut catalog = Self::builtin()?;
        let dir = dir.as_ref();
        let paths = eds_files(dir).map_err(|error| RegistryError::EdsDir {
            dir: dir.to_path_buf(),
            message: error.to_string(),
        })?;
        for path in paths {
            catalog.load(&path, EdsSource::File(path.clone()));
        }
        Ok(catalog)
    }

    /// The same catalog, keeping uploaded files in `dir` (`DATA/eds`, made
    /// `0700` at the first upload): the files found there now (uploaded
    /// before a restart) join the catalog as uploaded ones. Without it,
    /// uploads are kept in memory only, until the gateway stops.
    pub fn with_uploads(mut self, dir: impl Into<PathBuf>) -> Result<Self, RegistryError> {
        let dir = dir.into();
        if dir.is_dir() {
            let paths = eds_files(&dir).map_err(|error| RegistryError::EdsDir {
                dir: dir.clone(),
                message: error.to_string(),
            })?;
            for path in paths {
                self.load(&path, EdsSource::Uploaded(Some(path.clone())));
                let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
                if let Some(name) = name.filter(|name| self.find(name).is_some()) {
                    let size = std::fs::metadata(&path).map_or(0, |meta| meta.len());
                    self.sizes().insert(name, size);
                }
            }
        }
        self.uploads = Some(dir);
        Ok(self)
    }

    /// Reads a user's file into the catalog, or into the skipped ones.
    fn load(&mut self, path: &Path, source: EdsSource) {
        match self.add(path, source) {
            Ok(entry) => {
                if !entry.matches_by_identity() {
                    tracing::warn!(
                        "EDS {}: names no vendor or product number; matches no device by identity (assign it to a node by hand)",
                        path.display()
                    );
                }
                if !entry.eds.warnings.is_empty() {
                    tracing::warn!(
                        "EDS {}: {} warnings, read anyway (candeck eds check {0} lists them)",
                        path.display(),
                        entry.eds.warnings.len()
                    );
                }
            }
            Err(error) => {
                tracing::error!("EDS {} left out: {error}", path.display());
                let warnings = read_eds_file(path)
                    .map(|eds| eds.warnings)
                    .unwrap_or_default();
                self.skipped.push(SkippedFile {
                    path: path.to_path_buf(),
                    message: error.to_string(),
                    warnings,
                });
            }
        }
    }

    /// Adds a user's EDS file.
    pub fn add_file(&mut self, path: &Path) -> Result<Arc<EdsEntry>, RegistryError> {
        self.add(path, EdsSource::File(path.to_path_buf()))
    }

    fn add(&mut self, path: &Path, source: EdsSource) -> Result<Arc<EdsEntry>, RegistryError> {
        let eds = read_eds_file(path)?;
        // A file that yields no object would describe a node as empty.
        if let Some(error) = eds.why_unusable(&path.display().to_string()) {
            return Err(error.into());
        }
        let name = path
            .file_name()
            .map(|name| name.to_string_lossy().into_owned())
            .unwrap_or_else(|| path.display().to_string());
        let added = Arc::new(self.user_entry(name, source, eds));
        self.entries
            .get_mut()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
            .push(added.clone());
        Ok(added)
    }

    /// A user's file: one of our products keeps the product's profile.
    fn user_entry(&self, name: String, source: EdsSource, eds: Eds) -> EdsEntry {
        let (vendor, product, _) = identity_of(&eds);
        let profile = self
            .read()
            .iter()
            .find(|e| {
                !e.is_user_file()
                    && vendor.is_some()
                    && product.is_some()
                    && e.vendor_id == vendor
                    && e.product_code == product
            })
            .map(|e| e.profile);
        entry(name, source, eds, profile)
    }

    fn read(&self) -> std::sync::RwLockReadGuard<'_, Vec<Arc<EdsEntry>>> {
        // Nothing panics while holding the lock; the list stays whole.
        self.entries
            .read()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    fn write(&self) -> std::sync::RwLockWriteGuard<'_, Vec<Arc<EdsEntry>>> {
        self.entries
            .write()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Where uploads are kept; `None`: in memory.
    pub fn uploads_dir(&self) -> Option<&Path> {
        self.uploads.as_deref()
    }

    fn sizes(&self) -> std::sync::MutexGuard<'_, BTreeMap<String, u64>> {
        self.upload_bytes
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// The quota of uploaded files.
    pub fn quota(&self) -> EdsQuota {
        *self
            .quota
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Sets the quota of uploaded files from now on (the files already in
    /// the catalog stay, even beyond it).
    pub fn set_quota(&self, quota: EdsQuota) {
        *self
            .quota
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner()) = quota;
    }

    /// The uploaded files in the catalog: how many, and their bytes.
    pub fn uploaded(&self) -> (usize, u64) {
        let sizes = self.sizes();
        (sizes.len(), sizes.values().sum())
    }

    /// Whether one more upload of `size` bytes fits the quota.
    fn check_quota(&self, name: &str, size: u64) -> Result<(), CatalogError> {
        let quota = self.quota();
        let (files, bytes) = self.uploaded();
        if files >= quota.max_files {
            return Err(CatalogError::Quota(format!(
                "{name}: the catalog holds {files} uploaded files, its quota (eds_max_files {}): delete one first",
                quota.max_files
            )));
        }
        if bytes.saturating_add(size) > quota.max_bytes {
            return Err(CatalogError::Quota(format!(
                "{name}: {size} bytes more than the {} the uploaded files may take together (eds_max_mb), {bytes} taken: delete files first",
                quota.max_bytes
            )));
        }
        Ok(())
    }

    /// Takes an uploaded file: `name` must be a plain file name ending in
    /// `.eds` or `.dcf` and no other file's; a file that is no EDS, or
    /// that yields no object, is refused with the reader's error; one with
    /// warnings is kept (they
    /// are in its entry). With a data directory it is written there
    /// (`0600`, to a temporary name first, then renamed: a crash leaves the
    /// old state or the new, never half a file).
    pub fn upload(&self, name: &str, bytes: &[u8]) -> Result<Arc<EdsEntry>, CatalogError> {
        check_name(name)?;
        // Before the file is read, and again under the lock below.
        self.check_quota(name, bytes.len() as u64)?;
        let eds = Eds::parse_bytes(bytes, name)?;
        if let Some(error) = eds.why_unusable(name) {
            return Err(error.into());
        }
        let mut entry = self.user_entry(name.to_string(), EdsSource::Uploaded(None), eds);
        // Held from the check to the insertion: two uploads of one name
        // cannot both pass.
        let mut entries = self.write();
        if self.name_taken(&entries, name) {
            return Err(CatalogError::Exists(format!(
                "an EDS file named '{name}' is in the catalog already (delete it first)"
            )));
        }
        self.check_quota(name, bytes.len() as u64)?;
        if let Some(dir) = &self.uploads {
            let path = write_private(dir, name, bytes).map_err(|error| {
                CatalogError::Io(format!("cannot keep {name} in {}: {error}", dir.display()))
            })?;
            entry.source = EdsSource::Uploaded(Some(path));
        }
        let entry = Arc::new(entry);
        entries.push(entry.clone());
        self.sizes().insert(name.to_string(), bytes.len() as u64);
        Ok(entry)
    }

    fn name_taken(&self, entries: &[Arc<EdsEntry>], name: &str) -> bool {
        entries.iter().any(|e| e.name.eq_ignore_ascii_case(name))
            || self.skipped.iter().any(|file| {
                file.path
                    .file_name()
                    .is_some_and(|n| n.to_string_lossy().eq_ignore_ascii_case(name))
            })
    }

    /// Removes an uploaded file (from the data directory too). Whether a
    /// node still uses it is for the caller to decide
    /// ([`crate::Gateway::delete_eds`]).
    pub fn remove(&self, name: &str) -> Result<Arc<EdsEntry>, CatalogError> {
        let mut entries = self.write();
        let position = entries
            .iter()
            .position(|e| e.name == name)
            .ok_or_else(|| CatalogError::Unknown(name.to_string()))?;
        let EdsSource::Uploaded(path) = &entries[position].source else {
            return Err(CatalogError::NotUploaded(format!(
                "{name} is {}, not uploaded: only uploaded files can be deleted",
                match entries[position].source {
                    EdsSource::BuiltIn => "built in",
                    _ => "a file of the EDS directory",
                }
            )));
        };
        if let Some(path) = path {
            match std::fs::remove_file(path) {
                Ok(()) => {}
                Err(error) if error.kind() == std::io::ErrorKind::NotFound => {}
                Err(error) => {
                    return Err(CatalogError::Io(format!(
                        "cannot remove {}: {error}",
                        path.display()
                    )));
                }
            }
        }
        self.sizes().remove(name);
        Ok(entries.remove(position))
    }

    /// The file named `name`.
    pub fn find(&self, name: &str) -> Option<Arc<EdsEntry>> {
        self.read().iter().find(|e| e.name == name).cloned()
    }

    /// The files of the EDS directory that were left out, with why.
    pub fn skipped(&self) -> &[SkippedFile] {
        &self.skipped
    }

    /// Every entry: the built-in ones first, then the users' in file name
    /// order, then the uploaded ones in the order they came.
    pub fn entries(&self) -> Vec<Arc<EdsEntry>> {
        self.read().clone()
    }

    /// The EDS that best describes a node with `identity` (see the module
    /// documentation for the order); `None` when no file is of its vendor
    /// and product.
    pub fn lookup(&self, identity: &Identity) -> Option<Arc<EdsEntry>> {
        self.read()
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

/// An uploaded file's name: a plain file name (no path, no leading dot),
/// of letters, digits, `.`, `_`, `-` and `+`, ending in `.eds` or `.dcf`.
fn check_name(name: &str) -> Result<(), CatalogError> {
    let plain = !name.is_empty()
        && name.len() <= MAX_NAME_LEN
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-' | '+'));
    if plain && is_eds_path(Path::new(name)) {
        Ok(())
    } else {
        Err(CatalogError::InvalidName(format!(
            "'{name}' is no EDS file name: letters, digits, '.', '_', '-', '+', at most {MAX_NAME_LEN} characters, ending in .eds or .dcf"
        )))
    }
}

/// Writes `bytes` to `dir/name`, `0600`, through a temporary file renamed
/// over it.
fn write_private(dir: &Path, name: &str, bytes: &[u8]) -> std::io::Result<PathBuf> {
    use std::io::Write;
    super::files::create_private_dir(dir)?;
    let path = dir.join(name);
    let temporary = dir.join(format!(".{name}.{}.part", std::process::id()));
    let written = super::files::private_file_options()
        .write(true)
        .create(true)
        .truncate(true)
        .open(&temporary)
        .and_then(|mut file| {
            file.write_all(bytes)?;
            file.sync_all()
        })
        .and_then(|()| std::fs::rename(&temporary, &path));
    if let Err(error) = written {
        let _ = std::fs::remove_file(&temporary);
        return Err(error);
    }
    Ok(path)
}

/// The vendor, product and revision an EDS describes: `[DeviceInfo]`, or
/// the defaults of its 0x1018 when `[DeviceInfo]` lacks them.
fn identity_of(eds: &Eds) -> (Option<u32>, Option<u32>, Option<u32>) {
    let from_dictionary = |sub: u8| -> Option<u32> {
        let value = eds
            .dictionary
            .sub(0x1018, sub)?
            .default_value(None)
            .ok()??;
        u32::try_from(value.as_i128()?).ok()
    };
    let info = &eds.device_info;
    (
        info.vendor_number.or_else(|| from_dictionary(1)),
        info.product_number.or_else(|| from_dictionary(2)),
        info.revision_number.or_else(|| from_dictionary(3)),
    )
}

/// The device type (0x1000) an EDS gives as default.
pub(crate) fn device_type_of(eds: &Eds) -> Option<u32> {
    let value = eds.dictionary.sub(0x1000, 0)?.default_value(None).ok()??;
    u32::try_from(value.as_i128()?).ok()
}

fn entry(name: String, source: EdsSource, eds: Eds, profile: Option<Profile>) -> EdsEntry {
    let (vendor_id, product_code, revision) = identity_of(&eds);
    let device_type = device_type_of(&eds);
    let profile = profile.unwrap_or_else(|| {
        device_type
            .map(Profile::from_device_type)
            .unwrap_or(Profile::Generic)
    });
    EdsEntry {
        name,
        source,
        vendor_id,
        product_code,
        revision,
        device_type,
        profile,
        eds: Arc::new(eds),
    }
}

#[cfg(test)]
mod tests;

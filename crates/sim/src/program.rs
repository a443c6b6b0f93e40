//! Program download (CiA 302-3) on a virtual device: the program object
//! 0x1F50 sub 1 (DOMAIN, written by block or segmented download), program
//! control 0x1F51 sub 1, program software identification 0x1F56 sub 1 and
//! flash status identification 0x1F57 sub 1. A device has them when its
//! dictionary lists 0x1F50.
//!
//! - 0x1F51 written: 0 stops the program, 1 starts it, 2 resets it (stops
//!   and starts it again), 3 clears it (only when stopped). Read: 0
//!   stopped, 1 started, 3 no program (cleared). Starting without a program
//!   is refused with 0x08000022, as is a clear or a download while the
//!   program runs.
//! - 0x1F50 takes at most [`MAX_PROGRAM_SIZE`] bytes; a larger image is
//!   refused with 0x05040005 (out of memory), at the initiate when the
//!   client indicates the size.
//! - 0x1F56 is the image's CRC-32 (IEEE) once downloaded, 0 for the factory
//!   program and after a clear. 0x1F57: 0 no error, 2 no valid program
//!   (error 1 in bits 1–7) after a clear.
//! - The software version (0x100A) is the running program's: when a
//!   program with an [image header](ImageHeader) starts (1, 2, or the next
//!   power-on or reset node), 0x100A becomes the header's version; an
//!   image without one leaves 0x100A as it was.

use crate::canopen::crc32::crc32;
use crate::canopen::od::Value;
use crate::canopen::sdo::AbortCode;

use super::objects::ObjectStore;

/// 0x1F50: program data.
pub const PROGRAM_DATA: u16 = 0x1F50;
/// 0x1F51: program control.
pub const PROGRAM_CONTROL: u16 = 0x1F51;
/// 0x1F56: program software identification.
pub const PROGRAM_SOFTWARE_ID: u16 = 0x1F56;
/// 0x1F57: flash status identification.
pub const FLASH_STATUS: u16 = 0x1F57;
/// 0x100A: manufacturer software version.
const SOFTWARE_VERSION: u16 = 0x100A;

/// The largest image a virtual device takes: 512 KiB, a UniSwarm board's
/// program flash.
pub const MAX_PROGRAM_SIZE: usize = 512 * 1024;

/// 0x1F57 after a clear: error 1 "no valid program" in bits 1–7.
const FLASH_NO_VALID_PROGRAM: u32 = 1 << 1;

/// The header an image may start with to name its software version:
/// the four bytes `CDKI`, one byte n (1–64), then n bytes of printable
/// ASCII, the version (`CDKI` `\x05` `2.1.0`). The rest of the image is the
/// program; what it holds does not matter to the virtual device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ImageHeader {
    pub version: String,
}

impl ImageHeader {
    /// The magic the header starts with.
    pub const MAGIC: [u8; 4] = *b"CDKI";
    /// The longest version a header holds.
    pub const MAX_VERSION_LEN: usize = 64;

    /// The header at the start of `image`, if it has a valid one.
    pub fn parse(image: &[u8]) -> Option<ImageHeader> {
        let rest = image.strip_prefix(&Self::MAGIC)?;
        let (&len, rest) = rest.split_first()?;
        let len = usize::from(len);
        if len == 0 || len > Self::MAX_VERSION_LEN {
            return None;
        }
        let version = rest.get(..len)?;
        if !version.iter().all(|byte| (0x20..0x7F).contains(byte)) {
            return None;
        }
        Some(ImageHeader {
            version: String::from_utf8(version.to_vec()).ok()?,
        })
    }

    /// The header's bytes, for an image to start with.
    pub fn encode(version: &str) -> Vec<u8> {
        let mut bytes = Self::MAGIC.to_vec();
        bytes.push(version.len() as u8);
        bytes.extend_from_slice(version.as_bytes());
        bytes
    }
}

/// What the program does (0x1F51 read).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProgramState {
    /// 0: stopped.
    Stopped,
    /// 1: started.
    Started,
    /// 3: no program (cleared).
    NoProgram,
}

impl ProgramState {
    pub fn raw(self) -> u8 {
        match self {
            ProgramState::Stopped => 0,
            ProgramState::Started => 1,
            ProgramState::NoProgram => 3,
        }
    }
}

/// A device's program memory. See the module documentation.
#[derive(Debug, Clone)]
pub struct ProgramMemory {
    /// The device lists 0x1F50.
    supported: bool,
    /// The downloaded image; `None`: the factory program (or none after a
    /// clear).
    image: Option<Vec<u8>>,
    state: ProgramState,
    /// The version of the program running, when its image named one.
    running_version: Option<String>,
    /// The image's CRC-32, 0 without one.
    crc: u32,
    /// Changes whenever `image` does, so that a runner knows to persist it.
    version: u64,
}

impl ProgramMemory {
    /// The program memory of a device with `store`'s dictionary: the
    /// factory program, started.
    pub fn new(store: &ObjectStore) -> Self {
        Self {
            supported: store.dictionary().get(PROGRAM_DATA).is_some(),
            image: None,
            state: ProgramState::Started,
            running_version: None,
            crc: 0,
            version: 0,
        }
    }

    pub fn is_supported(&self) -> bool {
        self.supported
    }

    pub fn image(&self) -> Option<&[u8]> {
        self.image.as_deref()
    }

    pub fn state(&self) -> ProgramState {
        self.state
    }

    /// A number that changes whenever [`ProgramMemory::image`] does.
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Takes an image kept before a restart (it runs from the next boot).
    pub fn load(&mut self, image: Option<Vec<u8>>) {
        self.crc = image.as_deref().map_or(0, crc32);
        self.image = image;
    }

    /// The image's CRC-32 (0x1F56 sub 1), 0 without one.
    pub fn crc(&self) -> u32 {
        self.crc
    }

    /// Power-on and reset node: the stored program starts.
    pub fn boot(&mut self) {
        if self.state == ProgramState::NoProgram && self.image.is_none() {
            return;
        }
        self.start();
    }

    fn start(&mut self) {
        self.state = ProgramState::Started;
        if let Some(header) = self.image.as_deref().and_then(ImageHeader::parse) {
            self.running_version = Some(header.version);
        }
    }

    /// Whether this is one of the objects [`ProgramMemory::write`] handles.
    pub fn handles(&self, index: u16, sub: u8) -> bool {
        self.supported && matches!(index, PROGRAM_DATA | PROGRAM_CONTROL) && sub == 1
    }

    /// Checks a download to 0x1F50 or 0x1F51 before its data arrives.
    pub fn check_write(&self, index: u16, size: Option<usize>) -> Result<(), AbortCode> {
        if index == PROGRAM_DATA {
            if self.state == ProgramState::Started {
                return Err(AbortCode::CannotStoreDeviceState);
            }
            if size.is_some_and(|size| size > MAX_PROGRAM_SIZE) {
                return Err(AbortCode::OutOfMemory);
            }
        }
        Ok(())
    }

    /// A download to 0x1F50 sub 1 (the image) or 0x1F51 sub 1 (a command).
    pub fn write(&mut self, index: u16, data: &[u8]) -> Result<(), AbortCode> {
        self.check_write(index, Some(data.len()))?;
        if index == PROGRAM_DATA {
            self.image = Some(data.to_vec());
            self.crc = crc32(data);
            self.state = ProgramState::Stopped;
            self.version += 1;
            return Ok(());
        }
        let [command] = data else {
            return Err(AbortCode::LengthMismatch);
        };
        let has_program = self.state != ProgramState::NoProgram;
        match command {
            0 => {
                if has_program {
                    self.state = ProgramState::Stopped;
                }
            }
            1 | 2 => {
                if !has_program {
                    return Err(AbortCode::CannotStoreDeviceState);
                }
                if *command == 1 && self.state == ProgramState::Started {
                    return Ok(());
                }
                self.start();
            }
            3 => {
                if self.state == ProgramState::Started {
                    return Err(AbortCode::CannotStoreDeviceState);
                }
                self.image = None;
                self.crc = 0;
                self.state = ProgramState::NoProgram;
                self.version += 1;
            }
            _ => return Err(AbortCode::InvalidValue),
        }
        Ok(())
    }

    /// Puts 0x1F51, 0x1F56, 0x1F57 and the running version (0x100A) in
    /// `store`, after a write or a reset reloaded it.
    pub fn sync(&self, store: &mut ObjectStore) {
        if !self.supported {
            return;
        }
        let flash = match self.state {
            ProgramState::NoProgram => FLASH_NO_VALID_PROGRAM,
            _ => 0,
        };
        let _ = store.set(PROGRAM_CONTROL, 1, Value::Unsigned8(self.state.raw()));
        let _ = store.set(PROGRAM_SOFTWARE_ID, 1, Value::Unsigned32(self.crc));
        let _ = store.set(FLASH_STATUS, 1, Value::Unsigned32(flash));
        if let Some(version) = &self.running_version {
            let _ = store.set(SOFTWARE_VERSION, 0, Value::VisibleString(version.clone()));
        }
    }
}

#[cfg(test)]
mod tests;

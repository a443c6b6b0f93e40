//! Program download (CiA 302-3 §4.2): a new program image into a node's
//! program object, verified and started. The sequence: stop the program
//! (0x1F51 sub 1 = 0), clear it (3), download the image to 0x1F50 sub 1 by
//! SDO block transfer (with the block CRC), read the program software
//! identification 0x1F56 sub 1 and compare it with the image's CRC-32
//! (IEEE) computed here, then start the program (1) unless asked to leave
//! it stopped. Each step's failure is reported with the step's name, and
//! the device's abort code when it refused.

use std::time::Instant;

use crate::canopen::crc32::crc32;
use crate::canopen::sdo::ClientConfig;

use super::error::GatewayError;
use super::sdo::SdoChannel;

/// 0x1F50 sub 1: the program data.
const PROGRAM_DATA: (u16, u8) = (0x1F50, 1);
/// 0x1F51 sub 1: program control.
const PROGRAM_CONTROL: (u16, u8) = (0x1F51, 1);
/// 0x1F56 sub 1: program software identification.
const PROGRAM_SOFTWARE_ID: (u16, u8) = (0x1F56, 1);

/// The steps of a program download, by the name an error reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProgramStep {
    /// 0x1F51 = 0.
    Stop,
    /// 0x1F51 = 3.
    Clear,
    /// The image to 0x1F50.
    Download,
    /// 0x1F56 read and compared.
    Verify,
    /// 0x1F51 = 1.
    Start,
}

impl ProgramStep {
    pub fn name(self) -> &'static str {
        match self {
            ProgramStep::Stop => "stop program (0x1F51 = 0)",
            ProgramStep::Clear => "clear program (0x1F51 = 3)",
            ProgramStep::Download => "download image (0x1F50)",
            ProgramStep::Verify => "verify (0x1F56)",
            ProgramStep::Start => "start program (0x1F51 = 1)",
        }
    }
}

impl std::fmt::Display for ProgramStep {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A program download that stopped at a step.
#[derive(Debug, thiserror::Error)]
#[error("step {step}: {error}")]
pub struct ProgramError {
    pub step: ProgramStep,
    pub error: GatewayError,
}

/// What a program download did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProgramReport {
    /// The image's size.
    pub bytes: usize,
    /// The image's CRC-32, which 0x1F56 sub 1 gave back.
    pub crc32: u32,
    /// Whether the program was started at the end.
    pub started: bool,
    /// The whole sequence, and the download of 0x1F50 alone, in ms.
    pub elapsed_ms: u64,
    pub download_ms: u64,
}

/// Downloads `image` to the node of `channel` (see the module
/// documentation); `start`: start the program at the end.
pub async fn download_program(
    channel: &SdoChannel,
    image: &[u8],
    start: bool,
) -> Result<ProgramReport, ProgramError> {
    let began = Instant::now();
    // One procedure on the node at a time.
    let _procedure = channel.procedure().await;
    let at = |step: ProgramStep| move |error: GatewayError| ProgramError { step, error };
    let control = |command: u8| async move {
        channel
            .download(PROGRAM_CONTROL.0, PROGRAM_CONTROL.1, &[command])
            .await
            .map_err(GatewayError::from)
    };
    control(0).await.map_err(at(ProgramStep::Stop))?;
    control(3).await.map_err(at(ProgramStep::Clear))?;
    let block = ClientConfig {
        use_block_download_from: Some(1),
        crc: true,
        ..channel.config().clone()
    };
    let download_began = Instant::now();
    channel
        .download_with(PROGRAM_DATA.0, PROGRAM_DATA.1, image, Some(&block))
        .await
        .map_err(|error| at(ProgramStep::Download)(error.into()))?;
    let download_ms = download_began.elapsed().as_millis() as u64;
    let expected = crc32(image);
    let raw = channel
        .upload(PROGRAM_SOFTWARE_ID.0, PROGRAM_SOFTWARE_ID.1)
        .await
        .map_err(|error| at(ProgramStep::Verify)(error.into()))?;
    let given = <[u8; 4]>::try_from(raw.as_slice())
        .map(u32::from_le_bytes)
        .map_err(|_| {
            at(ProgramStep::Verify)(GatewayError::ProgramNotVerified(format!(
                "0x1F56 sub 1 gave {} bytes, not the 4 of a CRC-32",
                raw.len()
            )))
        })?;
    if given != expected {
        return Err(at(ProgramStep::Verify)(GatewayError::ProgramNotVerified(
            format!(
                "0x1F56 sub 1 is 0x{given:08X}, the image's CRC-32 is 0x{expected:08X}; the program was left stopped"
            ),
        )));
    }
    if start {
        control(1).await.map_err(at(ProgramStep::Start))?;
    }
    Ok(ProgramReport {
        bytes: image.len(),
        crc32: expected,
        started: start,
        elapsed_ms: began.elapsed().as_millis() as u64,
        download_ms,
    })
}

#[cfg(test)]
mod tests;

//! A node's SDO sequences that the doors ran by themselves until now (an
//! LED controller's segments, a program download, a batch of checked
//! writes), as node operations: the check that SDO can reach the node, the
//! transfers in a task of their own (a caller that goes away does not cut
//! them half way), one procedure not interleaved with another request's.
//! The doors keep their parsing; the node's SDO channel stays here.

use super::NodeHandle;
use super::transfer::spawned;
use crate::GatewayError;
use crate::profiles::uioled::{Field, Segment};
use crate::program::{ProgramError, ProgramReport, download_program};
use crate::service::check_sdo_allowed;
use crate::uioled::{self, ReadSegment};

impl NodeHandle {
    /// The node's SDO channel, once SDO is allowed to reach it.
    fn checked_channel(&self) -> Result<crate::sdo::SdoChannel, GatewayError> {
        check_sdo_allowed(&self.served, &self.info)?;
        Ok(self.served.registry.sdo(self.info.id)?)
    }

    /// Every segment of an LED controller, read now.
    pub async fn read_led_segments(&self) -> Result<Vec<Segment>, GatewayError> {
        let channel = self.checked_channel()?;
        spawned(async move { Ok(uioled::read_segments(&channel).await?) }).await
    }

    /// Every segment's parameters as the strip's renderer takes them.
    pub async fn read_led_preview(&self) -> Result<Vec<ReadSegment>, GatewayError> {
        let channel = self.checked_channel()?;
        spawned(async move { Ok(uioled::read_preview(&channel).await?) }).await
    }

    /// Writes each segment's fields in order (planned and checked by the
    /// caller), then reads `segment` back (`None`: every segment). The LED
    /// preview follows every write the node confirms, even of a sequence
    /// that stops half way.
    pub async fn write_led_segments(
        &self,
        writes: Vec<(u8, Vec<(Field, i64)>)>,
        read_back: Option<u8>,
    ) -> Result<Vec<Segment>, GatewayError> {
        let channel = self.checked_channel()?;
        spawned(async move {
            let _procedure = channel.procedure().await;
            for (segment, fields) in &writes {
                uioled::write_fields(&channel, *segment, fields).await?;
            }
            Ok(match read_back {
                Some(segment) => vec![uioled::read_segment(&channel, segment).await?],
                None => uioled::read_segments(&channel).await?,
            })
        })
        .await
    }

    /// Downloads values already encoded (`(index, sub, bytes)`) in order,
    /// as one procedure.
    pub async fn download_objects(
        &self,
        writes: Vec<(u16, u8, Vec<u8>)>,
    ) -> Result<(), GatewayError> {
        let channel = self.checked_channel()?;
        spawned(async move {
            let _procedure = channel.procedure().await;
            for (index, sub, bytes) in writes {
                channel.download(index, sub, &bytes).await?;
            }
            Ok(())
        })
        .await
    }

    /// Downloads a program image (CiA 302-3) and starts it if `start`,
    /// its progress published on the node's `program` topic; the run's
    /// number and the report.
    pub async fn download_program(
        &self,
        image: impl AsRef<[u8]> + Send + 'static,
        start: bool,
    ) -> Result<(u64, ProgramReport), GatewayError> {
        let channel = self.checked_channel()?;
        let run = self.served.programs.begin(self.info.id);
        let number = run.run;
        spawned(async move {
            download_program(&channel, image.as_ref(), start, &|progress| {
                run.publish(progress)
            })
            .await
            .map_err(|ProgramError { step, error }| GatewayError::FailedAt {
                step: step.to_string(),
                source: Box::new(error),
            })
        })
        .await
        .map(|report| (number, report))
    }
}

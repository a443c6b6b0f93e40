use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::*;
use crate::can::VirtualHub;
use crate::canopen::NodeId;
use crate::canopen::sdo::AbortCode;
use crate::sim::device::run_device;
use crate::sim::products::Product;

fn channel(product: Product) -> (SdoChannel, tokio::task::JoinHandle<()>) {
    let hub = VirtualHub::new("test");
    let node = NodeId::new(4).unwrap();
    let device = Arc::new(Mutex::new(product.device(node).unwrap()));
    let task = tokio::spawn(run_device(hub.attach(), device));
    let config = ClientConfig {
        timeout: Duration::from_millis(200),
        ..ClientConfig::default()
    };
    (SdoChannel::new(hub.attach(), node, config), task)
}

/// The whole sequence on a virtual UIO1LED: the report gives the image's
/// CRC-32, and the device is left running it.
#[tokio::test(start_paused = true)]
async fn a_program_is_stopped_cleared_downloaded_verified_and_started() {
    let (channel, task) = channel(Product::Uio1led);
    let image: Vec<u8> = (0..20_000u32).map(|i| (i % 251) as u8).collect();
    let report = download_program(&channel, &image, true).await.unwrap();
    assert_eq!(
        (report.bytes, report.crc32, report.started),
        (20_000, crc32(&image), true)
    );
    assert_eq!(channel.upload(0x1F51, 1).await.unwrap(), [1]);
    let report = download_program(&channel, &image[..100], false)
        .await
        .unwrap();
    assert_eq!(report.crc32, crc32(&image[..100]));
    assert_eq!(channel.upload(0x1F51, 1).await.unwrap(), [0]);
    task.abort();
}

/// A device without program objects fails at the first step, with its
/// abort code.
#[tokio::test(start_paused = true)]
async fn a_device_without_program_control_fails_at_the_stop() {
    let (channel, task) = channel(Product::Jmc);
    let error = download_program(&channel, &[1, 2, 3], true)
        .await
        .unwrap_err();
    assert_eq!(error.step, ProgramStep::Stop);
    assert_eq!(
        error.error.abort_code(),
        Some(AbortCode::ObjectDoesNotExist)
    );
    task.abort();
}

use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::*;
use crate::can::VirtualHub;
use crate::canopen::NodeId;
use crate::canopen::sdo::AbortCode;
use candeck_sim::device::run_device;
use candeck_sim::products::Product;

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
    let report = download_program(&channel, &image, true, &|_| {})
        .await
        .unwrap();
    assert_eq!(
        (report.bytes, report.crc32, report.started),
        (20_000, crc32(&image), true)
    );
    assert_eq!(channel.upload(0x1F51, 1).await.unwrap(), [1]);
    let report = download_program(&channel, &image[..100], false, &|_| {})
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
    let error = download_program(&channel, &[1, 2, 3], true, &|_| {})
        .await
        .unwrap_err();
    assert_eq!(error.step, ProgramStep::Stop);
    assert_eq!(
        error.error.abort_code(),
        Some(AbortCode::ObjectDoesNotExist)
    );
    task.abort();
}

/// Collects every progress report of a download.
fn reports() -> (
    Arc<Mutex<Vec<ProgramProgress>>>,
    impl Fn(&ProgramProgress) + Sync,
) {
    let seen = Arc::new(Mutex::new(Vec::new()));
    let into = seen.clone();
    (seen, move |progress: &ProgramProgress| {
        into.lock().unwrap().push(progress.clone())
    })
}

/// The progress goes through the steps in order, the bytes confirmed
/// block by block (20,000 bytes are 23 blocks of 127 segments), and ends
/// done with every byte.
#[tokio::test(start_paused = true)]
async fn the_progress_reports_each_step_and_the_bytes_block_by_block() {
    let (channel, task) = channel(Product::Uio1led);
    let image: Vec<u8> = (0..20_000u32).map(|i| (i % 253) as u8).collect();
    let (seen, report) = reports();
    download_program(&channel, &image, true, &report)
        .await
        .unwrap();
    let seen = seen.lock().unwrap().clone();
    let steps: Vec<&str> = seen.iter().map(|p| p.step.key()).collect::<Vec<_>>();
    let mut order = steps.clone();
    order.dedup();
    assert_eq!(
        order,
        ["stop", "clear", "download", "verify", "start"],
        "{steps:?}"
    );
    let sent: Vec<usize> = seen
        .iter()
        .filter(|p| p.step == ProgramStep::Download)
        .map(|p| p.bytes_sent)
        .collect();
    assert!(sent.windows(2).all(|w| w[0] < w[1]), "{sent:?}");
    assert_eq!(sent.first(), Some(&0));
    assert_eq!(sent.last(), Some(&20_000));
    // A block is 127 segments of 7 bytes.
    assert!(
        sent.contains(&(127 * 7)) && sent.contains(&(5 * 127 * 7)),
        "{sent:?}"
    );
    assert!(sent.len() >= 20_000 / (127 * 7), "{sent:?}");
    let last = seen.last().unwrap();
    assert_eq!(
        (
            last.state.clone(),
            last.step,
            last.bytes_sent,
            last.bytes_total
        ),
        (ProgramState::Done, ProgramStep::Start, 20_000, 20_000)
    );
    assert!(
        seen[..seen.len() - 1]
            .iter()
            .all(|p| p.state == ProgramState::Running)
    );
    let json = last.to_json(7);
    assert_eq!(
        (
            &json["run"],
            &json["state"],
            &json["step"],
            &json["percent"],
            &json["abort_code"]
        ),
        (
            &serde_json::json!(7),
            &serde_json::json!("done"),
            &serde_json::json!("start"),
            &serde_json::json!(100),
            &serde_json::Value::Null
        )
    );
    task.abort();
}

/// A step the device refuses ends the progress as failed at that step,
/// with the abort code.
#[tokio::test(start_paused = true)]
async fn a_refused_step_ends_the_progress_as_failed_with_the_abort_code() {
    let (channel, task) = channel(Product::Jmc);
    let (seen, report) = reports();
    download_program(&channel, &[1, 2, 3], true, &report)
        .await
        .unwrap_err();
    let last = seen.lock().unwrap().last().unwrap().clone();
    assert_eq!(
        (last.step, last.bytes_sent, last.bytes_total),
        (ProgramStep::Stop, 0, 3)
    );
    assert!(matches!(
        last.state,
        ProgramState::Failed {
            abort_code: Some(AbortCode::ObjectDoesNotExist),
            ..
        }
    ));
    let json = last.to_json(1);
    assert_eq!(json["state"], "failed");
    assert_eq!(json["step"], "stop");
    assert_eq!(json["abort_code"], "0x06020000");
    assert_eq!(json["abort_text"], AbortCode::ObjectDoesNotExist.text());
    assert!(json["error"].is_string(), "{json}");
    task.abort();
}

/// Each download on a node is a new run of its topic, whose newest report
/// a late reader still gets.
#[test]
fn each_download_is_a_new_run_on_the_nodes_topic() {
    let topics = ProgramTopics::default();
    let node = NodeId::new(3).unwrap();
    let topic = topics.topic(node);
    let first = topics.begin(node);
    let second = topics.begin(node);
    assert_eq!((first.run, second.run), (1, 2));
    assert_eq!(topics.begin(NodeId::new(4).unwrap()).run, 1);
    second.publish(&ProgramProgress {
        step: ProgramStep::Download,
        state: ProgramState::Running,
        bytes_sent: 889,
        bytes_total: 1778,
    });
    let latest = topic.subscribe(1.0).take().unwrap();
    assert_eq!(latest.data["run"], 2);
    assert_eq!(latest.data["percent"], 50);
    assert_eq!(latest.data["bytes_sent"], 889);
}

use std::time::Duration;

use super::*;
use crate::can::VirtualHub;
use crate::canopen::NodeId;
use crate::service::BusDevices;
use crate::test_rig::{self, config};

/// The error of a start that must fail (a gateway has no `Debug`).
async fn start_error(config: GatewayConfig, attach: AttachDevices<'_>) -> StartError {
    match Gateway::start(config, attach).await {
        Ok(_) => panic!("the gateway started"),
        Err(error) => error,
    }
}

fn no_devices(_: &str, _: &str, _: &VirtualHub) -> Result<Option<BusDevices>, String> {
    Ok(None)
}

fn running(gateway: &Gateway) -> usize {
    let tasks = gateway.background.0.lock().unwrap();
    tasks.iter().filter(|task| !task.is_finished()).count()
}

#[tokio::test(start_paused = true)]
async fn a_started_gateway_serves_its_buses_in_order_and_scans_them_once_up() {
    let gateway = Gateway::start(
        config(&[("line", "virtual:demo"), ("spare", "virtual:empty")]),
        &test_rig::rack,
    )
    .await
    .unwrap();
    let order: Vec<String> = gateway
        .buses_in_order()
        .iter()
        .map(|bus| bus.name.clone())
        .collect();
    assert_eq!(order, ["line", "spare"]);
    // Every bus has its network manager from the start.
    assert!(gateway.buses.values().all(|bus| bus.machine.is_some()));
    // Two pruners and a first scan per bus.
    assert_eq!(running(&gateway), 4);
    tokio::time::sleep(Duration::from_secs(5)).await;
    let found: Vec<u8> = gateway.buses["line"]
        .registry
        .nodes()
        .iter()
        .map(|node| node.id.get())
        .collect();
    assert!(
        [1, 2, 3].iter().all(|id| found.contains(id)),
        "the demo's nodes are found: {found:?}"
    );
    // The scans are over; the pruners run until the end.
    assert_eq!(running(&gateway), 2);
    let report = gateway.shutdown().await;
    assert!(report.failed.is_empty());
    tokio::task::yield_now().await;
    assert_eq!(running(&gateway), 0);
}

#[tokio::test(start_paused = true)]
async fn a_start_that_cannot_be_made_names_the_setting() {
    let mut described = config(&[("demo", "virtual:empty")]);
    let mut node = crate::canopen::manager::NodeDescription::new(NodeId::new(4).unwrap());
    node.eds = Some("nope.eds".to_string());
    described
        .machine_nodes
        .insert("demo".to_string(), vec![node]);
    let error = start_error(described, &no_devices).await;
    assert!(
        error
            .0
            .contains("[[nodes]] bus demo id 4: eds \"nope.eds\" is no file"),
        "{error}"
    );

    let error = start_error(config(&[("demo", "virtual:demo")]), &|_, _, _| {
        Err("no such preset".to_string())
    })
    .await;
    assert_eq!(error.0, "bus demo: no such preset");

    let file = std::env::temp_dir().join(format!("candeck-start-{}", std::process::id()));
    std::fs::write(&file, "not a directory").unwrap();
    let mut in_a_file = config(&[]);
    in_a_file.data_dir = Some(file.join("data"));
    let error = start_error(in_a_file, &no_devices).await;
    std::fs::remove_file(&file).unwrap();
    assert!(error.0.starts_with("--data-dir "), "{error}");
}

#[tokio::test]
async fn an_sdo_sampling_bound_out_of_range_is_refused_at_start() {
    for bound in [0, crate::MAX_SDO_SAMPLES_PER_S + 1] {
        let config = GatewayConfig {
            sdo_samples_per_s: bound,
            ..config(&[("line", "virtual:empty")])
        };
        let error = start_error(config, &no_devices).await;
        assert!(
            error.0.contains("sdo_samples_per_s") && error.0.contains("between 1 and 1000"),
            "{error}"
        );
    }
}

#[tokio::test(start_paused = true)]
async fn a_started_gateway_samples_a_nodes_objects_with_its_bound() {
    let gateway = Gateway::start(
        GatewayConfig {
            sdo_samples_per_s: 7,
            ..config(&[("line", "virtual:demo")])
        },
        &test_rig::rack,
    )
    .await
    .unwrap();
    assert_eq!(gateway.sdo_samples_per_s(), 7);
    tokio::time::sleep(Duration::from_secs(5)).await;
    let received = Arc::new(Mutex::new(Vec::new()));
    let sink: crate::SampleSink = {
        let received = received.clone();
        Arc::new(move |sample| received.lock().unwrap().push(sample))
    };
    let request = gateway
        .sample_objects(
            &test_rig::operator("sampler"),
            "line",
            1,
            vec![(0x1000, 0)],
            Duration::from_millis(500),
            sink,
        )
        .unwrap();
    tokio::time::sleep(Duration::from_millis(1_200)).await;
    assert_eq!(gateway.sampled_nodes(), vec![("line".to_string(), 1)]);
    {
        let received = received.lock().unwrap();
        // Read at once, then at 500 and 1000 ms: the device type's four bytes.
        assert_eq!(received.len(), 3, "{received:?}");
        for sample in received.iter() {
            assert_eq!(sample.object, (0x1000, 0));
            assert_eq!(sample.data.as_ref().map(Vec::len), Ok(4), "{sample:?}");
            assert!(!sample.slowed && !sample.carried);
        }
    }
    drop(request);
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert!(gateway.sampled_nodes().is_empty());
    gateway.shutdown().await;
}

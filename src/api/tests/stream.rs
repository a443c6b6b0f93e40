//! The stream's sessions driven through channels (no socket), on the demo
//! bus with a paused clock: the protocol's replies and errors, node
//! supervision and EMCY events, frames, and what a client that stops
//! reading does (and does not do) to the others.

use std::time::Duration;

use axum::http::StatusCode;
use futures_util::StreamExt;
use serde_json::{Value as Json, json};
use tokio::sync::mpsc;
use tokio::time::Instant;

use crate::api::AppState;
use crate::api::stream::{EVENT_QUEUE, FRAME_QUEUE, Inbound, MAX_TOPICS, run_session};
use crate::api::tests::support::{delete_text, demo, demo_at, get, post_text};
use crate::can::{CanId, Frame};
use crate::gateway::Identification;

/// A session reading its requests from `inbound`, its messages into a
/// channel of `capacity` (a client that does not read blocks the session
/// once that many wait): the channel's receiving end.
fn spawn_session(
    state: &AppState,
    inbound: impl futures_util::Stream<Item = Inbound> + Send + 'static,
    capacity: usize,
) -> mpsc::Receiver<String> {
    let (outbound, messages) = mpsc::channel::<String>(capacity);
    let sink = futures_util::sink::unfold(outbound, |tx, message: String| async move {
        tx.send(message).await.map(|()| tx)
    });
    tokio::spawn(run_session(
        state.clone(),
        Box::pin(inbound),
        Box::pin(sink),
    ));
    messages
}

/// A client of a session: what it sends, what it gets.
pub(super) struct Client {
    requests: mpsc::Sender<Inbound>,
    messages: mpsc::Receiver<String>,
}

impl Client {
    /// A session whose outgoing channel holds `capacity` messages: a client
    /// that does not read blocks its session once that many wait.
    pub(super) fn start(state: &AppState, capacity: usize) -> Self {
        let (requests, inbound) = mpsc::channel::<Inbound>(16);
        let inbound = futures_util::stream::unfold(inbound, |mut rx| async move {
            rx.recv().await.map(|request| (request, rx))
        });
        let messages = spawn_session(state, inbound, capacity);
        Self { requests, messages }
    }

    pub(super) async fn send(&self, text: &str) {
        self.requests
            .send(Inbound::Text(text.to_string()))
            .await
            .unwrap();
    }

    pub(super) async fn next(&mut self) -> Json {
        let text = tokio::time::timeout(Duration::from_secs(30), self.messages.recv())
            .await
            .expect("a message within 30 s")
            .expect("the session is running");
        serde_json::from_str(&text).unwrap()
    }

    /// Messages until one satisfies `wanted`, which it returns.
    pub(super) async fn until(&mut self, wanted: impl Fn(&Json) -> bool) -> Json {
        loop {
            let message = self.next().await;
            if wanted(&message) {
                return message;
            }
        }
    }

    pub(super) async fn subscribe(&mut self, topics: &[&str], rate: Option<f64>) -> Json {
        let mut request = json!({"op": "subscribe", "topics": topics});
        if let Some(rate) = rate {
            request["max_rate_hz"] = json!(rate);
        }
        self.send(&request.to_string()).await;
        self.next().await
    }
}

#[tokio::test(start_paused = true)]
async fn requests_are_acknowledged_and_bad_ones_get_the_apis_error_codes() {
    let (_, state) = demo().await;
    let mut client = Client::start(&state, 64);

    let ack = client.subscribe(&["nodes", "emcy"], Some(20.0)).await;
    assert_eq!(
        ack,
        json!({"op": "subscribed", "topics": ["nodes", "emcy"], "max_rate_hz": 20.0})
    );

    // Good topics are subscribed, each bad one named with its error.
    client
        .send(
            &json!({"op": "subscribe", "topics": [
                "buses/demo/frames?ids=0x701",
                "buses/nowhere/frames",
                "buses/demo/nodes/99/values",
                "buses/demo/nodes/x/values",
                "buses/demo/frames?ids=0x2000000000",
                "buses/demo/frames?speed=1",
                "nodes?x=1",
                "weather",
            ]})
            .to_string(),
        )
        .await;
    assert_eq!(
        client.next().await,
        json!({"op": "subscribed", "topics": ["buses/demo/frames?ids=0x701"], "max_rate_hz": 20.0})
    );
    let expected = [
        ("buses/nowhere/frames", "unknown_bus"),
        ("buses/demo/nodes/99/values", "unknown_node"),
        ("buses/demo/nodes/x/values", "invalid_request"),
        ("buses/demo/frames?ids=0x2000000000", "invalid_request"),
        ("buses/demo/frames?speed=1", "invalid_request"),
        ("nodes?x=1", "invalid_request"),
        ("weather", "invalid_request"),
    ];
    for (topic, code) in expected {
        let error = client.next().await;
        assert_eq!(error["op"], "error", "{error}");
        assert_eq!(error["topic"], topic, "{error}");
        assert_eq!(error["error"]["code"], code, "{error}");
        assert!(error["error"]["message"].as_str().unwrap().len() > 10);
    }

    for (request, code) in [
        ("not json", "invalid_request"),
        (r#"{"op": "publish", "topics": []}"#, "invalid_request"),
        (r#"{"op": "subscribe"}"#, "invalid_request"),
        (
            r#"{"op": "subscribe", "topics": "nodes"}"#,
            "invalid_request",
        ),
        (
            r#"{"op": "subscribe", "topics": ["nodes"], "extra": 1}"#,
            "invalid_request",
        ),
        (
            r#"{"op": "subscribe", "topics": ["nodes"], "max_rate_hz": 0}"#,
            "value_out_of_range",
        ),
        (
            r#"{"op": "subscribe", "topics": ["nodes"], "max_rate_hz": 5000}"#,
            "value_out_of_range",
        ),
    ] {
        client.send(request).await;
        let error = client.next().await;
        assert_eq!(
            (error["op"].as_str(), error["error"]["code"].as_str()),
            (Some("error"), Some(code)),
            "{request}: {error}"
        );
    }
    client.requests.send(Inbound::Binary).await.unwrap();
    let error = client.next().await;
    assert_eq!(error["error"]["code"], "invalid_request", "{error}");

    client
        .send(r#"{"op": "unsubscribe", "topics": ["emcy", "buses/demo/frames"]}"#)
        .await;
    assert_eq!(
        client.next().await,
        json!({"op": "unsubscribed", "topics": ["emcy"]})
    );
    let error = client.next().await;
    assert_eq!(
        (&error["topic"], &error["error"]["code"]),
        (&json!("buses/demo/frames"), &json!("invalid_request")),
        "{error}"
    );

    // At most MAX_TOPICS topics: distinct frame filters count one each.
    let many: Vec<String> = (1..=MAX_TOPICS)
        .map(|id| format!("buses/demo/frames?ids={id}"))
        .collect();
    client
        .send(&json!({"op": "subscribe", "topics": many}).to_string())
        .await;
    let ack = client.next().await;
    // Two are held already (nodes, the 0x701 frames).
    assert_eq!(
        ack["topics"].as_array().unwrap().len(),
        MAX_TOPICS - 2,
        "{ack}"
    );
    for _ in 0..2 {
        let error = client.next().await;
        assert_eq!(error["error"]["code"], "invalid_request", "{error}");
    }
}

#[tokio::test(start_paused = true)]
async fn an_unplugged_node_goes_offline_within_three_heartbeat_periods_and_comes_back() {
    let (app, state) = demo().await;
    // The JMC is the demo device that sends heartbeats (its EDS's 0x1017).
    let jmc = state
        .gateway
        .bus("demo")
        .unwrap()
        .node(2.try_into().unwrap())
        .unwrap();
    let period = Duration::from_millis(jmc.heartbeat_ms.expect("the JMC sends heartbeats"));
    let mut client = Client::start(&state, 64);
    client.subscribe(&["nodes"], None).await;

    let (status, _) = delete_text(&app, "/api/v1/buses/demo/sim/nodes/2", None).await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    let unplugged = Instant::now();
    let offline = client.until(|m| m["data"]["event"] == "offline").await;
    let after = unplugged.elapsed();
    // heartbeat_consumer_factor: 3 periods after its last heartbeat.
    assert!(
        after <= 3 * period,
        "offline after {after:?}, period {period:?}"
    );
    assert_eq!(offline["topic"], "nodes");
    assert_eq!(
        offline["data"],
        json!({"bus": "demo", "node": 2, "event": "offline", "reason": "heartbeat_lost"})
    );
    assert!(
        offline["ts"].as_u64().unwrap() > 1_700_000_000_000,
        "{offline}"
    );

    let (status, _) = post_text(
        &app,
        "/api/v1/buses/demo/sim/nodes",
        r#"{"product": "jmc", "id": 2}"#,
    )
    .await;
    assert_eq!(status, StatusCode::CREATED);
    let online = client.until(|m| m["data"]["event"] == "online").await;
    assert_eq!(
        online["data"],
        json!({"bus": "demo", "node": 2, "event": "online"})
    );
}

#[tokio::test(start_paused = true)]
async fn an_injected_fault_arrives_as_an_emcy_with_its_code_and_text() {
    let (app, state) = demo().await;
    let mut client = Client::start(&state, 64);
    client.subscribe(&["emcy"], None).await;
    let (status, _) = post_text(
        &app,
        "/api/v1/buses/demo/sim/nodes/1/faults",
        r#"{"kind": "over_temperature"}"#,
    )
    .await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    let emcy = client.next().await;
    assert_eq!(emcy["topic"], "emcy");
    let data = &emcy["data"];
    assert_eq!(
        (&data["bus"], &data["node"], &data["code"]),
        (&json!("demo"), &json!(1), &json!("0x4310")),
        "{emcy}"
    );
    assert_eq!(data["text"], "Excess temperature drive", "{emcy}");
    assert_eq!(data["register"], 9, "{emcy}");
    assert_eq!(data["manufacturer"].as_str().unwrap().len(), 10, "{emcy}");
    // A board fault faults both axes of the UMC: each axis's EMCY says
    // whose it is, as the node's history does.
    let second = client.next().await;
    let mut axes = [&data["axis"], &second["data"]["axis"]].map(|axis| {
        axis.as_u64()
            .unwrap_or_else(|| panic!("no axis: {emcy} {second}"))
    });
    axes.sort_unstable();
    assert_eq!(axes, [1, 2], "{emcy} {second}");
    assert_eq!(
        data["manufacturer"].as_str().unwrap()[..2],
        format!("{:02x}", data["axis"].as_u64().unwrap())
    );
    let (status, body) = get(&app, "/api/v1/buses/demo/nodes/1").await;
    assert_eq!(status, StatusCode::OK);
    let history: Vec<_> = body["emcy"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| (e["code"].clone(), e["axis"].clone()))
        .collect();
    assert!(
        history.contains(&(json!("0x4310"), json!(1))),
        "{history:?}"
    );
    assert!(
        history.contains(&(json!("0x4310"), json!(2))),
        "{history:?}"
    );
}

/// A demo bus without wire timing: the stream tests send floods far beyond
/// what a 500 kbit/s bus carries, to load the stream hub, not the wire.
const UNLIMITED: &str = "virtual:demo?bitrate=unlimited";

/// Sends `count` frames with id 0x555 in bursts, letting the gateway's
/// tasks run between them.
async fn traffic(state: &AppState, count: usize) {
    let served = state.gateway.bus("demo").unwrap();
    for n in 0..count {
        let frame = Frame::new(CanId::standard(0x555).unwrap(), &(n as u32).to_le_bytes()).unwrap();
        served.send_frame(frame).await.unwrap();
        if n % 100 == 99 {
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
    }
    tokio::time::sleep(Duration::from_millis(20)).await;
}

/// The frames of 0x555 in the messages a client has waiting (and how many
/// it was told it lost).
fn frames_and_lagged(messages: &mut mpsc::Receiver<String>) -> (Vec<u32>, u64) {
    let mut seen = Vec::new();
    let mut lagged = 0;
    while let Ok(text) = messages.try_recv() {
        let message: Json = serde_json::from_str(&text).unwrap();
        if let Some(n) = message["lagged"].as_u64() {
            lagged += n;
        }
        for frame in message["data"].as_array().into_iter().flatten() {
            let data = frame["data"].as_str().unwrap();
            let bytes: Vec<u8> = (0..4)
                .map(|i| u8::from_str_radix(&data[2 * i..2 * i + 2], 16).unwrap())
                .collect();
            seen.push(u32::from_le_bytes(bytes.try_into().unwrap()));
        }
    }
    (seen, lagged)
}

#[tokio::test(start_paused = true)]
async fn a_client_that_stops_reading_loses_frames_counted_and_delays_no_one() {
    let (_, state) = demo_at(UNLIMITED).await;
    let topic = "buses/demo/frames?ids=0x555";
    // The reader's channel is large enough to take everything it is sent.
    let mut reader = Client::start(&state, 100_000);
    reader.subscribe(&[topic], Some(100.0)).await;
    // The stuck client's holds two messages, then its session blocks.
    let mut stuck = Client::start(&state, 2);
    stuck.subscribe(&[topic], Some(100.0)).await;

    let sent = FRAME_QUEUE * 3;
    traffic(&state, sent).await;

    // The reader got every frame, in order, with no loss.
    let (seen, lagged) = frames_and_lagged(&mut reader.messages);
    assert_eq!(lagged, 0);
    assert_eq!(seen, (0..sent as u32).collect::<Vec<_>>());

    // The stuck one kept at most FRAME_QUEUE of them waiting; when it reads
    // again it is told how many it lost, and lost no more than that.
    let Client {
        requests: _requests,
        messages: mut stuck_messages,
    } = stuck;
    let mut seen = Vec::new();
    let mut lagged = 0;
    for _ in 0..50 {
        let (more, lost) = frames_and_lagged(&mut stuck_messages);
        seen.extend(more);
        lagged += lost;
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert!(lagged >= FRAME_QUEUE as u64, "lagged {lagged}");
    assert_eq!(
        seen.len() as u64 + lagged,
        sent as u64,
        "seen {}",
        seen.len()
    );
    assert!(seen.windows(2).all(|pair| pair[0] < pair[1]));
    assert!(
        state
            .stream_counters
            .lagged
            .load(std::sync::atomic::Ordering::Relaxed)
            >= lagged
    );
}

/// Issue 30: a frames topic sends its frames in batches at most
/// `MAX_PUBLISH_HZ` (100) times a second, whatever rate the client asked
/// (each session used to wake, and send, up to 1000 times a second), and
/// still every frame, in order.
#[tokio::test(start_paused = true)]
async fn a_frames_topic_sends_at_most_100_batches_a_second_whatever_the_rate_asked() {
    let (_, state) = demo_at(UNLIMITED).await;
    let mut client = Client::start(&state, 100_000);
    client
        .subscribe(&["buses/demo/frames?ids=0x555"], Some(1000.0))
        .await;
    let served = state.gateway.bus("demo").unwrap();
    let sent = 1000u32;
    for n in 0..sent {
        let frame = Frame::new(CanId::standard(0x555).unwrap(), &n.to_le_bytes()).unwrap();
        served.send_frame(frame).await.unwrap();
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    tokio::time::sleep(Duration::from_millis(50)).await;
    let mut messages = 0;
    let mut seen = Vec::new();
    while let Ok(text) = client.messages.try_recv() {
        let message: Json = serde_json::from_str(&text).unwrap();
        assert!(message.get("lagged").is_none(), "{message}");
        messages += 1;
        for frame in message["data"].as_array().unwrap() {
            let data = frame["data"].as_str().unwrap();
            let bytes: Vec<u8> = (0..4)
                .map(|i| u8::from_str_radix(&data[2 * i..2 * i + 2], 16).unwrap())
                .collect();
            seen.push(u32::from_le_bytes(bytes.try_into().unwrap()));
        }
    }
    assert_eq!(seen, (0..sent).collect::<Vec<_>>());
    // One second of frames, one batch every 10 ms at most (and the first at
    // once).
    assert!(messages <= 102, "{messages} messages");
}

/// Issue 30: a session asks its client's socket for a message only when
/// the socket woke it, not each time it sends a batch (the WebSocket layer
/// zeroes a 128 KiB read buffer at each ask: a fifth of the gateway's time
/// with 32 streams of frames).
#[tokio::test(start_paused = true)]
async fn a_session_reads_its_client_only_when_the_client_sent_something() {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};
    let (_, state) = demo_at(UNLIMITED).await;
    let polls = Arc::new(AtomicUsize::new(0));
    let mut subscribe = Some(Inbound::Text(
        json!({"op": "subscribe", "topics": ["buses/demo/frames"], "max_rate_hz": 1000})
            .to_string(),
    ));
    // The subscribe request, then nothing (and no wake-up) ever again.
    let inbound = futures_util::stream::poll_fn({
        let polls = polls.clone();
        move |_| {
            polls.fetch_add(1, Ordering::Relaxed);
            match subscribe.take() {
                Some(request) => std::task::Poll::Ready(Some(request)),
                None => std::task::Poll::Pending,
            }
        }
    });
    let mut messages = spawn_session(&state, inbound, 100_000);
    traffic(&state, 2000).await;
    let mut batches = 0;
    while let Ok(text) = messages.try_recv() {
        if text.contains("\"data\"") {
            batches += 1;
        }
    }
    assert!(batches >= 2, "{batches} batches");
    let polls = polls.load(Ordering::Relaxed);
    assert!(
        polls <= 3,
        "{polls} reads of the client for {batches} batches sent"
    );
}

#[tokio::test(start_paused = true)]
async fn events_beyond_the_queue_are_reported_as_lagged_not_dropped() {
    let (app, state) = demo_at(UNLIMITED).await;
    let mut stuck = Client::start(&state, 1);
    stuck.subscribe(&["nodes"], None).await;
    // Each add and remove of a device is an appeared or NMT and offline
    // event; more of them than the queue holds.
    let mut toggles = 0;
    while toggles < EVENT_QUEUE {
        post_text(
            &app,
            "/api/v1/buses/demo/sim/nodes",
            r#"{"product": "uio1led", "id": 50}"#,
        )
        .await;
        tokio::time::sleep(Duration::from_millis(2)).await;
        delete_text(&app, "/api/v1/buses/demo/sim/nodes/50", None).await;
        tokio::time::sleep(Duration::from_millis(2)).await;
        toggles += 1;
    }
    let Client {
        messages: mut stuck_messages,
        requests: _requests,
    } = stuck;
    let mut lagged = 0;
    let mut events = 0;
    for _ in 0..20 {
        while let Ok(text) = stuck_messages.try_recv() {
            let message: Json = serde_json::from_str(&text).unwrap();
            if let Some(n) = message["lagged"].as_u64() {
                assert_eq!(message["topic"], "nodes");
                lagged += n;
            } else if message["topic"] == "nodes" {
                events += 1;
            }
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert!(lagged > 0, "events {events}");
    assert!(events <= EVENT_QUEUE + 2, "events {events}");
}

#[tokio::test(start_paused = true)]
async fn a_session_ends_with_its_client_and_is_counted_meanwhile() {
    let (_, state) = demo().await;
    let counters = state.stream_counters.clone();
    let clients = || counters.clients.load(std::sync::atomic::Ordering::Relaxed);
    let mut client = Client::start(&state, 8);
    client
        .subscribe(&["nodes", "buses/demo/frames"], None)
        .await;
    assert_eq!(clients(), 1);
    drop(client.requests);
    // The session sees its inbound end and stops; its topics' tasks with it.
    tokio::time::sleep(Duration::from_millis(50)).await;
    assert_eq!(clients(), 0);
    let rest: Vec<String> = futures_util::stream::poll_fn(|cx| client.messages.poll_recv(cx))
        .collect()
        .await;
    assert!(rest.len() < 10, "{}", rest.len());
}

#[tokio::test(start_paused = true)]
async fn an_axis_topic_comes_at_the_rate_asked_for_beside_a_client_that_never_reads() {
    let (app, state) = demo().await;
    let axis = "/api/v1/buses/demo/nodes/1/axes/1";
    let (status, body) = post_text(
        &app,
        &format!("{axis}/state"),
        r#"{"target":"operation_enabled"}"#,
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let (status, body) = post_text(
        &app,
        &format!("{axis}/move"),
        r#"{"mode":"velocity","velocity":200}"#,
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");

    let topic = "buses/demo/nodes/1/axes/1";
    let mut stuck = Client::start(&state, 1);
    stuck
        .subscribe(
            &[
                topic,
                "buses/demo/nodes/3/segments",
                "buses/demo/frames",
                "nodes",
            ],
            Some(1000.0),
        )
        .await;
    let mut reader = Client::start(&state, 10_000);
    reader.subscribe(&[topic], Some(20.0)).await;
    tokio::time::sleep(Duration::from_secs(3)).await;

    let mut positions = Vec::new();
    while let Ok(text) = reader.messages.try_recv() {
        let message: Json = serde_json::from_str(&text).unwrap();
        assert_eq!(message["topic"], topic, "{message}");
        assert_eq!(message["data"]["state"], "operation_enabled", "{message}");
        positions.push(message["data"]["position"].as_i64().unwrap());
    }
    // 20 Hz for 3 s: 60, ±20 % (and the sample the topic had at once).
    assert!((48..=73).contains(&positions.len()), "{}", positions.len());
    assert!(positions.windows(2).all(|p| p[0] < p[1]), "{positions:?}");
}

#[tokio::test(start_paused = true)]
async fn value_topics_of_the_wrong_kind_of_node_are_refused_with_the_apis_codes() {
    let (_, state) = demo().await;
    let mut client = Client::start(&state, 64);
    client
        .send(
            &json!({"op": "subscribe", "topics": [
                "buses/demo/nodes/1/values",
                "buses/demo/nodes/3/segments",
                "buses/demo/nodes/3/axes/1",
                "buses/demo/nodes/1/axes/9",
                "buses/demo/nodes/1/axes/x",
                "buses/demo/nodes/1/segments",
            ]})
            .to_string(),
        )
        .await;
    assert_eq!(
        client.next().await,
        json!({"op": "subscribed", "topics": ["buses/demo/nodes/1/values", "buses/demo/nodes/3/segments"], "max_rate_hz": 10.0})
    );
    for (topic, code) in [
        ("buses/demo/nodes/3/axes/1", "not_a_drive"),
        ("buses/demo/nodes/1/axes/9", "unknown_axis"),
        ("buses/demo/nodes/1/axes/x", "unknown_axis"),
        ("buses/demo/nodes/1/segments", "not_an_led_controller"),
    ] {
        let error = client.next().await;
        assert_eq!(
            (&error["topic"], &error["error"]["code"]),
            (&json!(topic), &json!(code)),
            "{error}"
        );
    }
    // The LED preview comes at the default 10 Hz: one strip of pixels per
    // update.
    let preview = client
        .until(|m| m["topic"] == "buses/demo/nodes/3/segments")
        .await;
    assert!(
        preview["data"].is_object() || preview["data"].is_array(),
        "{preview}"
    );
}

/// Issue 19, point 8: a viewer's `max_rate_hz` of 1e-300 was accepted, and
/// `Duration::from_secs_f64(1e300)` panicked in the session's forwarding
/// task and in the axis's producer. Every rate outside 0.01 to 1000 (and
/// every number JSON cannot carry) is refused, and the session goes on.
#[tokio::test(start_paused = true)]
async fn a_rate_that_is_no_sleepable_period_is_refused_and_the_session_goes_on() {
    let (_, state) = demo().await;
    let topic = "buses/demo/nodes/1/axes/1";
    let mut client = Client::start(&state, 1024);
    for rate in [
        "1e-300", "5e-324", "0.0099", "0", "-0", "-1", "-1e300", "1000.001", "1e9", "1e308",
    ] {
        let request = format!(r#"{{"op":"subscribe","topics":["{topic}"],"max_rate_hz":{rate}}}"#);
        client.send(&request).await;
        let answer = client.next().await;
        assert_eq!(
            (answer["op"].as_str(), answer["error"]["code"].as_str()),
            (Some("error"), Some("value_out_of_range")),
            "{request}: {answer}"
        );
        let message = answer["error"]["message"].as_str().unwrap();
        assert!(
            message.contains("0.01") && message.contains("1000"),
            "{message}"
        );
    }
    // Not numbers JSON knows (serde_json refuses them): not a request.
    for rate in ["NaN", "Infinity", "-Infinity", "1e400", "\"fast\""] {
        let request = format!(r#"{{"op":"subscribe","topics":["{topic}"],"max_rate_hz":{rate}}}"#);
        client.send(&request).await;
        let answer = client.next().await;
        assert_eq!(
            (answer["op"].as_str(), answer["error"]["code"].as_str()),
            (Some("error"), Some("invalid_request")),
            "{request}: {answer}"
        );
    }
    // Nothing was subscribed, no producer was started by the refusals...
    assert!(
        !state
            .gateway
            .bus("demo")
            .unwrap()
            .axes()
            .is_running(crate::canopen::NodeId::new(1).unwrap(), 1)
    );
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert!(
        client.messages.try_recv().is_err(),
        "updates of a refused topic"
    );

    // ... and the session is whole: the bounds themselves are rates, and
    // updates come.
    for (rate, expected) in [(0.01, 0.01), (1000.0, 1000.0)] {
        let ack = client.subscribe(&[topic], Some(rate)).await;
        assert_eq!(
            ack,
            json!({"op": "subscribed", "topics": [topic], "max_rate_hz": expected})
        );
        let update = client.until(|message| message["topic"] == topic).await;
        assert_eq!(update["data"]["axis"], 1, "{update}");
    }
}

/// Issue 19, point 11: the soak's steady readers, subscribing as the
/// gateway started, got one message of each value topic and then nothing
/// for the whole run. The nodes were listed but still being identified
/// (the soak then waited for 3 nodes, not for their identification), so
/// each axis was "no drive" and the preview "no LED controller": one error
/// each, which the soak counted as that topic's message, and no retry. A
/// node still being identified is no drive *yet*: its value topics are
/// subscribed and wait for it.
#[tokio::test(start_paused = true)]
async fn a_value_topic_of_a_node_still_being_identified_waits_for_it() {
    let (app, state) = demo().await;
    let served = state.gateway.bus("demo").unwrap().clone();
    // Two nodes boot, as the demo's do when the gateway starts; their
    // identification is under way (and nothing answers it yet).
    let peer = served.hub().as_ref().unwrap().attach();
    for id in [20u32, 21] {
        let boot_up = Frame::new(CanId::standard(0x700 + id).unwrap(), &[0]).unwrap();
        peer.send(boot_up).await.unwrap();
    }
    let pending = |id: u8| {
        served
            .node(crate::canopen::NodeId::new(id).unwrap())
            .is_some_and(|info| info.identification == Identification::Pending)
    };
    for _ in 0..100 {
        if pending(20) && pending(21) {
            break;
        }
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    assert!(pending(20) && pending(21));

    let axis = "buses/demo/nodes/20/axes/2";
    let preview = "buses/demo/nodes/21/segments";
    let mut client = Client::start(&state, 100_000);
    client
        .send(
            &json!({"op": "subscribe", "topics": [axis, preview, "buses/demo/nodes/20/axes/9"],
                    "max_rate_hz": 20})
            .to_string(),
        )
        .await;
    assert_eq!(
        client.next().await,
        json!({"op": "subscribed", "topics": [axis, preview], "max_rate_hz": 20.0})
    );
    // An axis no drive can have is refused all the same.
    let error = client.next().await;
    assert_eq!(error["error"]["code"], "unknown_axis", "{error}");
    assert!(
        pending(20) && pending(21),
        "identified before the subscription"
    );

    // The devices answer (a UMC with two axes, an LED controller): the
    // topics come.
    for body in [
        r#"{"product": "umc1bds32", "id": 20}"#,
        r#"{"product": "uio1led", "id": 21}"#,
    ] {
        let (status, answer) = post_text(&app, "/api/v1/buses/demo/sim/nodes", body).await;
        assert!(status.is_success(), "{status} {answer}");
    }
    let update = client.until(|message| message["topic"] == axis).await;
    assert_eq!(update["data"]["axis"], 2, "{update}");
    assert!(update["data"]["statusword"].is_u64(), "{update}");
    let update = client.until(|message| message["topic"] == preview).await;
    assert!(update["data"]["pixels"].is_array(), "{update}");
    // And they go on at the rate asked: 20 Hz for 2 s.
    tokio::time::sleep(Duration::from_secs(2)).await;
    let mut counts = std::collections::BTreeMap::<String, usize>::new();
    while let Ok(text) = client.messages.try_recv() {
        let message: Json = serde_json::from_str(&text).unwrap();
        *counts
            .entry(message["topic"].as_str().unwrap_or("").to_string())
            .or_default() += 1;
    }
    for topic in [axis, preview] {
        let n = counts.get(topic).copied().unwrap_or(0);
        assert!((30..=45).contains(&n), "{topic}: {n} in 2 s: {counts:?}");
    }
}

#[tokio::test(start_paused = true)]
async fn a_bus_off_node_goes_offline_and_the_gateways_controller_state_is_an_event() {
    let (app, state) = demo().await;
    state.gateway.bus("demo").unwrap().scan().await.unwrap();
    let mut client = Client::start(&state, 256);
    client.subscribe(&["nodes", "emcy"], None).await;

    // The JMC (node 2) bus-off: it sends nothing, its heartbeat is missed.
    let uri = "/api/v1/buses/demo/sim/nodes/2/faults";
    let (status, _) = post_text(&app, uri, r#"{"kind": "bus_off"}"#).await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    let offline = client.until(|m| m["data"]["event"] == "offline").await;
    assert_eq!(
        offline["data"],
        json!({"bus": "demo", "node": 2, "event": "offline", "reason": "heartbeat_lost"})
    );
    // Recovered on request: EMCY 0x8140, then online again.
    let (status, _) = delete_text(&app, uri, Some(r#"{"kind": "bus_off"}"#)).await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    let recovered = client.until(|m| m["data"]["code"] == "0x8140").await;
    assert_eq!(recovered["data"]["node"], 2);
    client.until(|m| m["data"]["event"] == "online").await;

    // The gateway's own controller: a bus_state event for each change.
    let uri = "/api/v1/buses/demo/sim/faults";
    let (status, _) = post_text(&app, uri, r#"{"kind": "bus_off"}"#).await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    let event = client.until(|m| m["data"]["event"] == "bus_state").await;
    assert_eq!(event["topic"], "nodes");
    assert_eq!(
        event["data"],
        json!({
            "bus": "demo", "event": "bus_state", "state": "down", "error_state": "bus_off",
            "reason": "controller is bus-off (too many transmit errors)",
            "tx_error_counter": 256, "rx_error_counter": 0,
        })
    );
    let (status, _) = delete_text(&app, uri, Some(r#"{"kind": "bus_off"}"#)).await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    let event = client.until(|m| m["data"]["event"] == "bus_state").await;
    assert_eq!(
        event["data"],
        json!({
            "bus": "demo", "event": "bus_state", "state": "up", "error_state": "error_active",
            "reason": null, "tx_error_counter": 0, "rx_error_counter": 0,
        })
    );
}

//! The connection limit's refusals, counted for `/metrics` and logged once
//! per interval, against the server on a loopback port.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

use super::*;
use crate::api::{AppState, app};

const WAIT: Duration = Duration::from_secs(10);

/// What the server answers to `request` before it closes.
async fn ask(stream: &mut TcpStream, request: &str) -> String {
    stream.write_all(request.as_bytes()).await.unwrap();
    let mut answer = Vec::new();
    tokio::time::timeout(WAIT, stream.read_to_end(&mut answer))
        .await
        .expect("answered and closed in time")
        .unwrap();
    String::from_utf8_lossy(&answer).into_owned()
}

#[tokio::test]
async fn refused_connections_are_counted_for_the_metrics() {
    let state = AppState::new([]);
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    // One general place; the rest is the reserve.
    let limits = Limits::new(WAIT, WAIT, RESERVED_CONNECTIONS + 1).unwrap();
    let server = tokio::spawn(serve(
        listener,
        app(state.clone()),
        limits,
        state.connection_refusals.clone(),
        std::future::pending(),
    ));
    let _general = TcpStream::connect(addr).await.unwrap();
    // A reserve place asked for something else than /health or stop-all.
    let mut reserve = TcpStream::connect(addr).await.unwrap();
    let answer = ask(
        &mut reserve,
        &format!("GET /api/v1/buses HTTP/1.1\r\nHost: {addr}\r\n\r\n"),
    )
    .await;
    assert!(answer.starts_with("HTTP/1.1 503"), "{answer}");
    assert!(answer.contains("too_many_connections"), "{answer}");
    let refusals = &state.connection_refusals;
    assert_eq!(refusals.answered_503.load(Ordering::Relaxed), 1);
    // Reserve places held by clients that send nothing: one more pushes
    // the oldest out.
    let mut idle = Vec::new();
    for _ in 0..=RESERVED_CONNECTIONS {
        idle.push(TcpStream::connect(addr).await.unwrap());
    }
    let mut oldest = idle.remove(0);
    let mut rest = Vec::new();
    tokio::time::timeout(WAIT, oldest.read_to_end(&mut rest))
        .await
        .expect("the oldest idle reserve connection is closed")
        .unwrap();
    assert_eq!(refusals.evicted.load(Ordering::Relaxed), 1);
    let metrics = crate::api::metrics::render(&state);
    for line in [
        "candeck_http_connections_refused_total{how=\"answered_503\"} 1",
        "candeck_http_connections_refused_total{how=\"evicted\"} 1",
        "candeck_http_connections_refused_total{how=\"closed\"} 0",
    ] {
        assert!(metrics.contains(line), "no '{line}' in\n{metrics}");
    }
    server.abort();
}

#[test]
fn refusals_are_logged_once_per_interval_with_the_count_since() {
    let refusals = Arc::new(ConnectionRefusals::default());
    let start = Instant::now();
    assert_eq!(refusals.log_due(start), Some(1));
    for _ in 0..999 {
        assert_eq!(refusals.log_due(start + Duration::from_secs(1)), None);
    }
    assert_eq!(
        refusals.log_due(start + REFUSAL_LOG_EVERY - Duration::from_millis(1)),
        None
    );
    assert_eq!(refusals.log_due(start + REFUSAL_LOG_EVERY), Some(1001));
    assert_eq!(refusals.log_due(start + REFUSAL_LOG_EVERY), None);
}

//! The ingest and live WebSockets through real TCP connections.

mod common;

use std::time::{Duration, Instant};

use common::{TestServer, drive, post_ndjson, put_machine, server_with_machine};
use futures_util::{SinkExt, StreamExt};
use serde_json::Value;
use tokio_tungstenite::tungstenite::Message;
use tunnelnav::server::settings::Limits;

type Socket =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn connect(url: String) -> Socket {
    tokio_tungstenite::connect_async(url)
        .await
        .expect("websocket connects")
        .0
}

/// The next JSON text frame, within `timeout`.
async fn next_json(socket: &mut Socket, timeout: Duration) -> Value {
    loop {
        let message = tokio::time::timeout(timeout, socket.next())
            .await
            .expect("a frame within the timeout")
            .expect("socket open")
            .expect("frame readable");
        match message {
            Message::Text(text) => return serde_json::from_str(&text).unwrap(),
            Message::Ping(_) | Message::Pong(_) => continue,
            other => panic!("unexpected frame {other:?}"),
        }
    }
}

/// The next estimate (or `gap`), skipping `ping` and alarm events (these
/// drives are in the past, so the server clock finds their sensors stale).
async fn next_estimate(socket: &mut Socket) -> Value {
    loop {
        let frame = next_json(socket, Duration::from_secs(5)).await;
        if !["ping", "alarm", "alarm_gap"].contains(&frame["event"].as_str().unwrap_or_default()) {
            return frame;
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn readings_sent_on_the_ingest_socket_come_back_as_estimates_on_the_live_socket() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start_with(
        dir.path(),
        Limits {
            live_ping_interval: Duration::from_millis(300),
            ..Limits::default()
        },
    )
    .await;
    let client = reqwest::Client::new();
    put_machine(&client, &server.url(""), "ws").await;
    let lines = drive(0.5, 2, vec![]);
    // Some history first, so `hello` has a latest estimate.
    post_ndjson(&client, &server.url(""), "ws", &lines[..100]).await;

    let mut live = connect(server.ws_url("/api/v1/machines/ws/live")).await;
    let hello = next_json(&mut live, Duration::from_secs(5)).await;
    assert_eq!(hello["event"], "hello");
    assert_eq!(hello["machine"], "ws");
    assert_eq!(hello["engines"][0], "attitude");
    let latest_t = hello["latest"]["attitude"]["t"].as_f64().unwrap();

    let mut ingest = connect(server.ws_url("/api/v1/machines/ws/ingest")).await;
    let mut latencies = Vec::new();
    for chunk in lines[100..].chunks(7) {
        let frame = format!("[{}]", chunk.join(","));
        let sent = Instant::now();
        ingest.send(Message::Text(frame.into())).await.unwrap();
        let ack = next_json(&mut ingest, Duration::from_secs(5)).await;
        assert_eq!(ack["accepted"], chunk.len(), "{ack}");
        for line in chunk {
            let reading: Value = serde_json::from_str(line).unwrap();
            if reading["sensor"] != "inclinometer" {
                continue;
            }
            let estimate = next_estimate(&mut live).await;
            assert_eq!(
                estimate["t"], reading["t"],
                "one estimate per inclinometer reading, in order"
            );
            assert!(estimate["t"].as_f64().unwrap() > latest_t);
            latencies.push(sent.elapsed());
        }
    }
    latencies.sort();
    let p99 = latencies[latencies.len() * 99 / 100];
    assert!(
        p99 < Duration::from_secs(1),
        "post to live estimate p99 {p99:?}"
    );

    // A bad frame is answered, not fatal.
    ingest
        .send(Message::Text("[{\"t\":1}]".into()))
        .await
        .unwrap();
    let ack = next_json(&mut ingest, Duration::from_secs(5)).await;
    assert_eq!(ack["status"], 400);
    assert!(
        ack["rejected"][0]["error"]
            .as_str()
            .unwrap()
            .contains("`t`")
    );
    ingest.send(Message::Text("nonsense".into())).await.unwrap();
    let ack = next_json(&mut ingest, Duration::from_secs(5)).await;
    assert_eq!(ack["status"], 400);
    ingest
        .send(Message::Binary(vec![1, 2, 3].into()))
        .await
        .unwrap();
    let ack = next_json(&mut ingest, Duration::from_secs(5)).await;
    assert!(ack["error"].as_str().unwrap().contains("binary"));

    // Idle: pings keep coming (alarm events about the past drive's stale
    // sensors may come between them).
    let ping = loop {
        let frame = next_json(&mut live, Duration::from_secs(5)).await;
        if !["alarm", "alarm_gap"].contains(&frame["event"].as_str().unwrap_or_default()) {
            break frame;
        }
    };
    assert_eq!(ping["event"], "ping");

    // Shutdown closes the live socket with a close frame.
    server.stop().await;
    let closing = tokio::time::timeout(Duration::from_secs(5), async {
        loop {
            match live.next().await {
                Some(Ok(Message::Close(frame))) => return frame,
                Some(Ok(_)) => continue,
                other => panic!("expected a close frame, got {other:?}"),
            }
        }
    })
    .await
    .unwrap();
    assert!(closing.unwrap().reason.contains("shutting down"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_live_client_gets_a_gap_and_blocks_nobody() {
    let dir = tempfile::tempdir().unwrap();
    let (server, client, base) = server_with_machine(dir.path(), "gap").await;

    // 40 hours of readings in small batches: far more estimates than the
    // live buffer (4096) and the stalled socket's TCP buffers hold.
    let lines = drive(40.0, 9, vec![]);
    let estimates_posted = lines.iter().filter(|l| l.contains("inclinometer")).count();

    // One client reads promptly, one reads nothing for a while.
    let mut stalled = connect(server.ws_url("/api/v1/machines/gap/live")).await;
    let prompt = connect(server.ws_url("/api/v1/machines/gap/live")).await;
    let reader = tokio::spawn(async move {
        let mut prompt = prompt;
        let mut estimates = 0usize;
        let mut gaps = 0usize;
        let mut last_t = 0.0;
        while estimates < estimates_posted && gaps == 0 {
            let Some(Ok(message)) = prompt.next().await else {
                break;
            };
            let Message::Text(text) = message else {
                continue;
            };
            let frame: Value = serde_json::from_str(&text).unwrap();
            match frame["event"].as_str() {
                Some("gap") => gaps += 1,
                Some(_) => {}
                None => {
                    let t = frame["t"].as_f64().unwrap();
                    assert!(t > last_t);
                    last_t = t;
                    estimates += 1;
                }
            }
        }
        (estimates, gaps)
    });

    let started = Instant::now();
    for chunk in lines.chunks(500) {
        post_ndjson(&client, &base, "gap", chunk).await;
    }
    let ingest_time = started.elapsed();

    // The stalled client now reads: a gap with its time range, then more.
    let hello = next_json(&mut stalled, Duration::from_secs(5)).await;
    assert_eq!(hello["event"], "hello");
    let mut seen = 0usize;
    let gap = loop {
        let frame = next_json(&mut stalled, Duration::from_secs(5)).await;
        if frame["event"] == "gap" {
            break frame;
        }
        seen += 1;
    };
    assert!(gap["missed"].as_u64().unwrap() > 0, "{gap}");
    let (from_t, to_t) = (gap["from_t"].as_f64(), gap["to_t"].as_f64().unwrap());
    assert!(from_t.is_none_or(|from| from < to_t), "{gap}");
    let after = next_json(&mut stalled, Duration::from_secs(5)).await;
    assert_eq!(
        after["t"].as_f64(),
        Some(to_t),
        "the gap ends where the stream resumes"
    );
    assert!(seen < estimates_posted);

    let (estimates, gaps) = tokio::time::timeout(Duration::from_secs(30), reader)
        .await
        .expect("the prompt client receives everything")
        .unwrap();
    assert_eq!(gaps, 0, "the prompt client kept up");
    assert_eq!(estimates, estimates_posted);
    server.stop().await;
    eprintln!(
        "ingest of {} readings took {ingest_time:?} with a stalled live client",
        lines.len()
    );
}

/// An ingest socket outlives a redeclaration of its machine: the frames
/// after it are stored by the restarted machine.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_ingest_socket_goes_on_across_a_redeclaration() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let declare =
        |name: &str| serde_json::json!({"name": name, "engines": {"attitude": {}}}).to_string();
    common::declare_machine(&client, &base, "tbm-ws", &declare("before")).await;
    let mut socket = connect(server.ws_url("/api/v1/machines/tbm-ws/ingest")).await;
    let t0 = tunnelnav::clock::wall_clock_s().floor() - 100.0;
    // A reading, a redeclaration, a reading, another, a last reading.
    for (i, redeclared) in [Some("after"), Some("after again"), None]
        .into_iter()
        .enumerate()
    {
        let reading = serde_json::json!({"t": t0 + i as f64, "sensor": "inclinometer",
                                          "pitch_deg": 0.1, "roll_deg": 0.2});
        socket
            .send(Message::Text(reading.to_string().into()))
            .await
            .unwrap();
        let ack = next_json(&mut socket, Duration::from_secs(5)).await;
        assert_eq!(ack["accepted"], 1, "{ack}");
        if let Some(name) = redeclared {
            common::declare_machine(&client, &base, "tbm-ws", &declare(name)).await;
        }
    }
    assert_eq!(
        common::exported_readings(&client, &base, "tbm-ws")
            .await
            .len(),
        3
    );
    server.stop().await;
}

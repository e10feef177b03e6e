//! Bad input changes nothing. The batch parser is fuzzed with proptest
//! (arbitrary bytes, and valid readings mutated field by field): it never
//! panics, every reading it accepts is valid, every refusal names the
//! reading. Then a running server is hammered with thousands of hostile
//! bodies between valid posts: every hostile request gets a 4xx with a JSON
//! `error` (or a 200 that rejects each bad reading by index), the server
//! stays healthy, and the stored readings are exactly the valid ones, each
//! once.

mod common;

use proptest::prelude::*;
use tunnelnav::server::{BatchRules, parse_batch};

const NOW_S: f64 = 1_800_000_000.0;

fn rules() -> BatchRules {
    BatchRules {
        max_readings: 1000,
        now_s: NOW_S,
        max_future_s: 600.0,
    }
}

/// A valid reading's fields, as JSON text pieces to mutate.
const VALID: [(&str, &str); 4] = [
    ("t", "1772431200.5"),
    ("sensor", "\"inclinometer\""),
    ("pitch_deg", "0.25"),
    ("roll_deg", "-1.5"),
];

/// Values that are wrong somewhere: types, non-finite, out of range, huge.
const HOSTILE_VALUES: [&str; 18] = [
    "NaN",
    "Infinity",
    "-Infinity",
    "1e308",
    "1e309",
    "-1e400",
    "\"0.5\"",
    "null",
    "true",
    "[]",
    "{}",
    "946684799",
    "4102444801",
    "95",
    "-181",
    "\"laser\"",
    "\"gyroscope\"",
    "[[[[[[[[[[1]]]]]]]]]]",
];

fn mutated_reading() -> impl Strategy<Value = String> {
    (
        0..VALID.len(),
        0..HOSTILE_VALUES.len(),
        any::<bool>(),
        any::<bool>(),
    )
        .prop_map(|(field, value, drop_field, extra)| {
            let mut parts: Vec<String> = VALID
                .iter()
                .enumerate()
                .filter(|(i, _)| !(drop_field && *i == field))
                .map(|(i, (k, v))| {
                    let v = if i == field { HOSTILE_VALUES[value] } else { v };
                    format!("\"{k}\": {v}")
                })
                .collect();
            if extra {
                parts.push("\"surprise\": 1".into());
            }
            format!("{{{}}}", parts.join(", "))
        })
}

fn check_batch(body: &[u8], ndjson: bool) {
    if let Ok(batch) = parse_batch(body, ndjson, &rules()) {
        for reading in &batch.readings {
            assert!(reading.t.is_finite() && reading.t >= 946_684_800.0);
            assert!(reading.t <= NOW_S + 600.0);
            let json = reading.to_json();
            assert!(!json.contains("null") && !json.contains("NaN"), "{json}");
        }
        for rejected in &batch.rejected {
            assert!(!rejected.error.is_empty());
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 20_000,
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    #[test]
    fn arbitrary_bytes_never_panic_the_parser(body in proptest::collection::vec(any::<u8>(), 0..300)) {
        check_batch(&body, false);
        check_batch(&body, true);
    }

    #[test]
    fn mutated_readings_are_refused_by_index_or_valid(
        lines in proptest::collection::vec(mutated_reading(), 1..8),
    ) {
        let ndjson = lines.join("\n");
        check_batch(ndjson.as_bytes(), true);
        let array = format!("[{}]", lines.join(","));
        check_batch(array.as_bytes(), false);
        // Each line alone: accepted only if it is a valid reading.
        for line in &lines {
            if let Ok(batch) = parse_batch(line.as_bytes(), false, &rules()) {
                prop_assert_eq!(batch.readings.len() + batch.rejected.len(), 1);
            }
        }
    }
}

/// A small deterministic generator for the hammer.
struct Noise(u64);

impl Noise {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| self.next() as u8).collect()
    }
}

/// The hostile bodies: (what, body, content type).
fn hostile(noise: &mut Noise, i: usize) -> (String, Vec<u8>, &'static str) {
    let reading = |field: &str, value: &str| {
        let parts: Vec<String> = VALID
            .iter()
            .map(|(k, v)| format!("\"{k}\": {}", if *k == field { value } else { v }))
            .collect();
        format!("{{{}}}", parts.join(", ")).into_bytes()
    };
    match i % 12 {
        0 => (
            "random bytes".into(),
            {
                let n = 1 + (noise.next() % 400) as usize;
                noise.bytes(n)
            },
            "application/json",
        ),
        1 => (
            "non-UTF-8".into(),
            vec![b'{', 0xff, 0xfe, b'}'],
            "application/json",
        ),
        2 => (
            "deep nesting".into(),
            "[".repeat(100_000).into_bytes(),
            "application/json",
        ),
        3 => (
            "NaN".into(),
            reading("pitch_deg", "NaN"),
            "application/json",
        ),
        4 => (
            "1e308 pitch".into(),
            reading("pitch_deg", "1e308"),
            "application/json",
        ),
        5 => (
            "wrong type".into(),
            reading("roll_deg", "\"level\""),
            "application/json",
        ),
        6 => (
            "far future".into(),
            reading("t", "4000000000"),
            "application/json",
        ),
        7 => (
            "before 2000".into(),
            reading("t", "900000000"),
            "application/json",
        ),
        8 => (
            "unknown sensor".into(),
            reading("sensor", "\"sonar\""),
            "application/json",
        ),
        9 => (
            "out of range".into(),
            reading("pitch_deg", "91"),
            "application/json",
        ),
        10 => (
            "too many readings".into(),
            format!("[{}]", vec!["{}"; 100_001].join(",")).into_bytes(),
            "application/json",
        ),
        _ => (
            "bad NDJSON".into(),
            b"{\"t\": 1}\n\n[[[\n\x00\x01".to_vec(),
            "application/x-ndjson",
        ),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hammered_server_stays_healthy_and_keeps_only_valid_data() {
    let dir = tempfile::tempdir().unwrap();
    let server = common::TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    common::put_machine(&client, &base, "h1").await;
    let url = format!("{base}/api/v1/machines/h1/readings");
    let mut noise = Noise(0x5eed_1234_abcd_ef01);
    let mut valid = Vec::new();
    let mut hostile_sent = 0;
    for round in 0..300 {
        // A valid reading, sent twice: acknowledged both times, stored once
        // (the second is counted as a duplicate).
        let line = format!(
            r#"{{"t": {}.5, "sensor": "inclinometer", "pitch_deg": 0.1, "roll_deg": 0.2}}"#,
            1_772_431_200 + round
        );
        for copy in 0..2 {
            let response = client.post(&url).body(line.clone()).send().await.unwrap();
            assert_eq!(response.status(), 200);
            let ack: serde_json::Value =
                serde_json::from_slice(&response.bytes().await.unwrap()).unwrap();
            assert_eq!(ack["accepted"], 1, "{ack}");
            assert_eq!(ack["duplicates"], copy, "{ack}");
        }
        valid.push(line);
        // Ten hostile bodies, all at once.
        let requests = (0..10).map(|k| {
            let (what, body, content_type) = hostile(&mut noise, round * 10 + k);
            let (client, url) = (client.clone(), url.clone());
            async move {
                let response = client
                    .post(&url)
                    .header("content-type", content_type)
                    .body(body)
                    .send()
                    .await
                    .unwrap();
                let status = response.status().as_u16();
                let body: serde_json::Value =
                    serde_json::from_slice(&response.bytes().await.unwrap())
                        .unwrap_or_else(|e| panic!("{what}: not JSON ({e})"));
                (what, status, body)
            }
        });
        for (what, status, body) in futures_util::future::join_all(requests).await {
            hostile_sent += 1;
            match status {
                400 | 413 | 415 | 422 => {
                    assert!(
                        body["error"].as_str().is_some_and(|e| !e.is_empty()),
                        "{what}: {body}"
                    )
                }
                200 => {
                    // A batch with nothing valid cannot be a 200 here: every
                    // hostile body carries no valid reading.
                    panic!("{what}: accepted {body}");
                }
                other => panic!("{what}: {other} {body}"),
            }
        }
    }
    // Healthy, and exactly the valid readings stored, once each.
    let health = client.get(format!("{base}/healthz")).send().await.unwrap();
    assert_eq!(health.status(), 200);
    let stored = common::exported_readings(&client, &base, "h1").await;
    assert_eq!(stored.len(), valid.len());
    for (s, v) in stored.iter().zip(&valid) {
        let (s, v): (serde_json::Value, serde_json::Value) = (
            serde_json::from_str(s).unwrap(),
            serde_json::from_str(v).unwrap(),
        );
        assert_eq!(s, v);
    }
    eprintln!(
        "{hostile_sent} hostile requests refused; {} valid readings intact",
        valid.len()
    );
    server.stop().await;
}

//! Every HTTP endpoint, success and failure, against a real server on an
//! ephemeral port with a temporary store.

mod common;

use common::{
    TestServer, all_estimates, drive, exported_readings, post_ndjson, put_machine, replay,
    server_with_machine,
};
use serde_json::{Value, json};
use tunnelnav::server::settings::Limits;
use tunnelnav::sim::tbm::Dropout;

const INCL: &str = r#"{"t":1772431200,"sensor":"inclinometer","pitch_deg":0.5,"roll_deg":1}"#;

async fn json_of(response: reqwest::Response) -> (u16, Value) {
    let status = response.status().as_u16();
    let bytes = response.bytes().await.unwrap();
    let body = serde_json::from_slice(&bytes)
        .unwrap_or_else(|e| panic!("not JSON ({e}): {}", String::from_utf8_lossy(&bytes)));
    (status, body)
}

#[tokio::test]
async fn machines_are_declared_validated_listed_and_shown() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let url = |p: &str| server.url(p);

    let (status, body) = json_of(
        client
            .put(url("/api/v1/machines/tbm-1"))
            .body(r#"{"name":"TBM 1","engines":{"attitude":{"fusion_gain_pitch":0.05}}}"#)
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 201, "{body}");
    assert_eq!(body["created"], true);
    assert_eq!(
        body["config"]["engines"]["attitude"]["fusion_gain_pitch"],
        0.05
    );

    // The same declaration again changes nothing; a different one replaces.
    let (status, body) = json_of(
        client
            .put(url("/api/v1/machines/tbm-1"))
            .body(r#"{"name":"TBM 1","engines":{"attitude":{"fusion_gain_pitch":0.05}}}"#)
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!((status, &body["changed"]), (200, &json!(false)));

    for (body, expect) in [
        (r#"{"engines":{"gps":{}}}"#, "unknown engine `gps`"),
        (
            r#"{"engines":{"attitude":{"fusion_gain_pitch":9}}}"#,
            "fusion_gain_pitch",
        ),
        (
            r#"{"engines":{"attitude":{"nope":1}}}"#,
            "unknown parameter `nope`",
        ),
        (r#"{"engines":{}}"#, "declares no engine"),
        (r#"{"name":"x"}"#, "missing field `engines`"),
        ("not json", "not a machine declaration"),
    ] {
        let (status, error) = json_of(
            client
                .put(url("/api/v1/machines/tbm-2"))
                .body(body)
                .send()
                .await
                .unwrap(),
        )
        .await;
        assert_eq!(status, 400, "{body}: {error}");
        let message = error["error"].as_str().unwrap();
        assert!(message.contains(expect), "{body}: {message}");
    }
    let (status, _) = json_of(
        client
            .put(url("/api/v1/machines/bad%20id"))
            .body(r#"{"engines":{"attitude":{}}}"#)
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 400);

    let (status, list) = json_of(client.get(url("/api/v1/machines")).send().await.unwrap()).await;
    assert_eq!(status, 200);
    let machines = list["machines"].as_array().unwrap();
    assert_eq!(machines.len(), 1, "refused declarations create nothing");
    assert_eq!(machines[0]["machine"], "tbm-1");
    assert_eq!(machines[0]["name"], "TBM 1");

    post_ndjson(&client, &server.url(""), "tbm-1", &drive(0.2, 3, vec![])).await;
    let (status, one) = json_of(
        client
            .get(url("/api/v1/machines/tbm-1"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 200);
    assert_eq!(one["latest"]["attitude"]["engine"], "attitude");
    assert_eq!(one["laser"]["ok"], true);
    assert!(one["sensors"]["inclinometer"]["last_t"].as_f64().unwrap() > 1.77e9);
    assert!(one["sensors"]["laser"]["readings"].as_u64().unwrap() > 0);

    let (status, missing) = json_of(
        client
            .get(url("/api/v1/machines/nope"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 404);
    assert_eq!(missing["error"], "unknown machine `nope`");
    server.stop().await;
}

#[tokio::test]
async fn ingest_accepts_every_body_shape_and_names_each_bad_reading() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start_with(
        dir.path(),
        Limits {
            max_body_bytes: 64 * 1024,
            max_readings_per_request: 100,
            ..Limits::default()
        },
    )
    .await;
    let client = reqwest::Client::new();
    put_machine(&client, &server.url(""), "m").await;
    let post = |body: String, content_type: &'static str| {
        client
            .post(server.url("/api/v1/machines/m/readings"))
            .header("content-type", content_type)
            .body(body)
            .send()
    };

    // One object.
    let (status, ack) = json_of(post(INCL.to_string(), "application/json").await.unwrap()).await;
    assert_eq!((status, &ack["accepted"]), (200, &json!(1)), "{ack}");
    // The same again: accepted, stored once.
    let (_, ack) = json_of(post(INCL.to_string(), "application/json").await.unwrap()).await;
    assert_eq!(
        (&ack["accepted"], &ack["duplicates"]),
        (&json!(1), &json!(1))
    );

    // An array with bad readings among good ones.
    let body = r#"[
        {"t":1772431201,"sensor":"inclinometer","pitch_deg":0.5,"roll_deg":1},
        {"t":1772431202,"sensor":"sonar"},
        {"t":1772431203,"sensor":"inclinometer","pitch_deg":95,"roll_deg":1},
        {"t":1772431204,"sensor":"laser","pitch_deg":0.4},
        {"t":1e308,"sensor":"laser","pitch_deg":0.4,"roll_deg":1},
        {"t":1772431205,"sensor":"inclinometer","pitch_deg":0.5,"roll_deg":1},
        {"t":4000000000,"sensor":"level","height_m":1}
    ]"#;
    let (status, ack) = json_of(post(body.into(), "application/json").await.unwrap()).await;
    assert_eq!(status, 200);
    assert_eq!(ack["accepted"], 2);
    let rejected = ack["rejected"].as_array().unwrap();
    let summary: Vec<(u64, &str)> = rejected
        .iter()
        .map(|r| (r["index"].as_u64().unwrap(), r["error"].as_str().unwrap()))
        .collect();
    assert_eq!(summary.len(), 5, "{ack}");
    assert_eq!(summary[0].0, 1);
    assert!(summary[0].1.contains("unknown sensor `sonar`"));
    assert_eq!(summary[1].0, 2);
    assert!(summary[1].1.contains("`pitch_deg` = 95"));
    assert_eq!(summary[2].0, 3);
    assert!(summary[2].1.contains("missing field `roll_deg`"));
    assert_eq!(summary[3].0, 4);
    assert!(summary[3].1.contains("`t`"));
    // Before 2100, but far ahead of the server clock.
    assert_eq!(summary[4].0, 6);
    assert!(
        summary[4].1.contains("ahead of the server clock"),
        "{}",
        summary[4].1
    );

    // NDJSON.
    let body = format!(
        "{}\n\n{}\n",
        r#"{"t":1772431206,"sensor":"inclinometer","pitch_deg":0.5,"roll_deg":1}"#,
        r#"{"t":1772431207,"sensor":"level","height_m":12.5}"#
    );
    let (status, ack) = json_of(post(body, "application/x-ndjson").await.unwrap()).await;
    assert_eq!((status, &ack["accepted"]), (200, &json!(2)), "{ack}");

    // Nothing valid: 400 with the reasons.
    let (status, ack) = json_of(
        post(r#"[{"t":1}]"#.into(), "application/json")
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 400);
    assert_eq!(ack["rejected"][0]["index"], 0);
    // Malformed bodies: 400.
    for body in ["[{", "hello", "", "\u{0}"] {
        let (status, error) = json_of(post(body.into(), "application/json").await.unwrap()).await;
        assert_eq!(status, 400, "{body:?}: {error}");
        assert!(error["error"].is_string());
    }
    // Too many readings, too large a body: 413.
    let many = format!("[{}]", vec![INCL; 101].join(","));
    let (status, error) = json_of(post(many, "application/json").await.unwrap()).await;
    assert_eq!(status, 413, "{error}");
    let huge = format!("[{}]", " ".repeat(70 * 1024));
    let (status, error) = json_of(post(huge, "application/json").await.unwrap()).await;
    assert_eq!(status, 413, "{error}");
    // Unknown machine: 404.
    let (status, error) = json_of(
        client
            .post(server.url("/api/v1/machines/ghost/readings"))
            .body(INCL)
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!((status, error["machine"].as_str()), (404, Some("ghost")));

    // Nothing refused was stored; everything accepted was, once.
    let export = exported_readings(&client, &server.url(""), "m").await;
    let times: Vec<f64> = export
        .iter()
        .map(|l| {
            serde_json::from_str::<Value>(l).unwrap()["t"]
                .as_f64()
                .unwrap()
        })
        .collect();
    assert_eq!(
        times,
        vec![
            1772431200.0,
            1772431201.0,
            1772431205.0,
            1772431206.0,
            1772431207.0
        ]
    );

    let metrics = client
        .get(server.url("/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(
        metrics.contains(r#"tunnelnav_readings_accepted_total{machine="m",sensor="inclinometer"}"#),
        "{metrics}"
    );
    assert!(
        metrics.contains(r#"tunnelnav_readings_rejected_total{machine="m",sensor="laser"} 2"#),
        "{metrics}"
    );
    assert!(metrics.contains(r#"tunnelnav_readings_rejected_total{machine="m",sensor="unknown"}"#));
    assert!(metrics.contains("tunnelnav_ingest_duration_seconds_bucket"));
    assert!(metrics.contains("tunnelnav_store_bytes"));
    assert!(metrics.contains(r#"tunnelnav_live_clients{machine="m"} 0"#));
    server.stop().await;
}

#[tokio::test]
async fn history_exports_model_and_health() {
    let dir = tempfile::tempdir().unwrap();
    let (server, client, base) = server_with_machine(dir.path(), "m").await;
    // Two hours with a spike the downsampling must keep.
    let mut lines = drive(
        2.0,
        5,
        vec![Dropout {
            start_h: 1.5,
            minutes: 20.0,
        }],
    );
    // A step of 5° held for four readings: the engine's inclinometer
    // monitor rejects the first three as spikes (no estimate) and fuses
    // the fourth, a change that persists.
    let spike_t = 1772431200.0 + 3000.0;
    let mut stepped = 0;
    for line in lines.iter_mut() {
        let mut reading: Value = serde_json::from_str(line).unwrap();
        if stepped < 4
            && reading["t"].as_f64().unwrap() >= spike_t
            && reading["sensor"] == "inclinometer"
        {
            reading["pitch_deg"] = json!(5.0);
            *line = reading.to_string();
            stepped += 1;
        }
    }
    post_ndjson(&client, &base, "m", &lines).await;
    let get = |path: String| client.get(format!("{base}{path}")).send();

    let all = all_estimates(&client, &base, "m").await;
    assert_eq!(all.len(), 7200 - 3);
    let (status, page) = json_of(
        get("/api/v1/machines/m/estimates?max_points=200".into())
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 200);
    assert_eq!(page["downsampled"], true);
    let points = page["estimates"].as_array().unwrap();
    assert!(
        points.len() <= 200 && points.len() >= 100,
        "{}",
        points.len()
    );
    let max_pitch = points
        .iter()
        .map(|e| e["pitch_deg"].as_f64().unwrap())
        .fold(f64::MIN, f64::max);
    let true_max = all
        .iter()
        .map(|e| e["pitch_deg"].as_f64().unwrap())
        .fold(f64::MIN, f64::max);
    assert_eq!(max_pitch, true_max, "the spike survives downsampling");
    assert!(
        points
            .windows(2)
            .all(|w| w[0]["t"].as_f64() < w[1]["t"].as_f64())
    );

    // A range, in both time notations.
    let (status, page) = json_of(
        get(
            "/api/v1/machines/m/estimates?engine=attitude&from=2026-03-02T06:00:00Z&to=1772431259"
                .into(),
        )
        .await
        .unwrap(),
    )
    .await;
    assert_eq!(status, 200, "{page}");
    assert_eq!(page["estimates"].as_array().unwrap().len(), 60);
    assert_eq!(page["from"], 1772431200.0);
    for (query, expect) in [
        ("engine=warp", "unknown engine"),
        ("from=yesterday", "`from` = `yesterday` is not a time"),
        ("from=1772431259&to=1772431200", "is after"),
        ("max_points=0", "max_points"),
        ("max_points=-3", "bad query"),
        ("colour=red", "bad query"),
    ] {
        let (status, error) = json_of(
            get(format!("/api/v1/machines/m/estimates?{query}"))
                .await
                .unwrap(),
        )
        .await;
        assert_eq!(status, 400, "{query}");
        assert!(
            error["error"].as_str().unwrap().contains(expect),
            "{query}: {error}"
        );
    }

    // Raw readings: NDJSON replays as-is; CSV has a header and one row each.
    let export = get("/api/v1/machines/m/readings?sensor=laser".into())
        .await
        .unwrap();
    assert_eq!(export.headers()["content-type"], "application/x-ndjson");
    let export = export.text().await.unwrap();
    let lasers: Vec<&String> = lines.iter().filter(|l| l.contains("\"laser\"")).collect();
    assert_eq!(export.lines().count(), lasers.len());
    let csv = get("/api/v1/machines/m/readings?format=csv&from=1772431200&to=1772431209".into())
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert!(rows[0].starts_with("t,sensor,pitch_deg,roll_deg"));
    let in_range = lines
        .iter()
        .filter(|l| {
            let t = serde_json::from_str::<Value>(l).unwrap()["t"]
                .as_f64()
                .unwrap();
            (1772431200.0..=1772431209.0).contains(&t)
        })
        .count();
    assert_eq!(rows.len(), 1 + in_range, "{csv}");
    assert!(rows[1].starts_with("1772431200,inclinometer,"));
    let full = get("/api/v1/machines/m/readings".into())
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert_eq!(
        replay("m", &full.lines().map(str::to_string).collect::<Vec<_>>()),
        all
    );
    for query in ["sensor=sonar", "format=xml", "to=soon"] {
        let (status, _) = json_of(
            get(format!("/api/v1/machines/m/readings?{query}"))
                .await
                .unwrap(),
        )
        .await;
        assert_eq!(status, 400, "{query}");
    }

    // The learned model.
    let (status, model) = json_of(get("/api/v1/machines/m/model".into()).await.unwrap()).await;
    assert_eq!(status, 200);
    assert_eq!(model["machine"], "m");
    assert_eq!(model["memberships"].as_array().unwrap().len(), 3);
    assert!(model["curve"].as_array().unwrap().len() > 10);
    assert!(model["samples"].as_array().unwrap().len() > 10);
    assert!(model["fit_rmse_deg"].as_f64().unwrap() < 0.05);
    assert_eq!(model["frozen"], false);
    let (status, _) = json_of(get("/api/v1/machines/ghost/model".into()).await.unwrap()).await;
    assert_eq!(status, 404);

    let (status, health) = json_of(get("/healthz".into()).await.unwrap()).await;
    assert_eq!((status, &health["status"]), (200, &json!("ok")));
    let (status, _) = json_of(get("/api/v2/anything".into()).await.unwrap()).await;
    assert_eq!(status, 404);
    let (status, error) = json_of(
        client
            .delete(format!("{base}/healthz"))
            .send()
            .await
            .unwrap(),
    )
    .await;
    assert_eq!(status, 405);
    assert!(error["error"].as_str().unwrap().contains("DELETE"));
    // The sockets answer plain HTTP with JSON too: unknown machine, not an upgrade.
    for socket in ["live", "ingest"] {
        let (status, _) = json_of(
            get(format!("/api/v1/machines/ghost/{socket}"))
                .await
                .unwrap(),
        )
        .await;
        assert_eq!(status, 404, "{socket}");
        let (status, error) =
            json_of(get(format!("/api/v1/machines/m/{socket}")).await.unwrap()).await;
        assert_eq!(status, 400, "{socket}: {error}");
        assert!(error["error"].as_str().unwrap().contains("WebSocket"));
    }
    server.stop().await;
}

#[tokio::test]
async fn server_estimates_equal_replay_of_the_same_readings() {
    let dir = tempfile::tempdir().unwrap();
    let (server, client, base) = server_with_machine(dir.path(), "eq").await;
    let lines = drive(
        3.0,
        11,
        vec![Dropout {
            start_h: 2.0,
            minutes: 30.0,
        }],
    );
    // In requests of assorted sizes, as gateways would post.
    let mut rest = &lines[..];
    let mut size = 1;
    while !rest.is_empty() {
        let n = size.min(rest.len());
        post_ndjson(&client, &base, "eq", &rest[..n]).await;
        rest = &rest[n..];
        size = size * 3 % 997 + 1;
    }
    let served = all_estimates(&client, &base, "eq").await;
    let replayed = replay("eq", &lines);
    assert_eq!(served.len(), 3 * 3600);
    assert_eq!(served, replayed);
    server.stop().await;
}

/// A redeclaration restarts the machine; readings posted meanwhile go to
/// its successor instead of being refused (each is stored once).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn readings_posted_while_the_machine_is_redeclared_are_all_stored() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let declaration = |name: &str| json!({"name": name, "engines": {"attitude": {}}}).to_string();
    common::declare_machine(&client, &base, "tbm-r", &declaration("A")).await;
    let t0 = tunnelnav::clock::wall_clock_s().floor() - 1000.0;
    let posting = {
        let (client, base) = (client.clone(), base.clone());
        tokio::spawn(async move {
            let mut statuses = Vec::new();
            for i in 0..200 {
                let reading = json!({"t": t0 + f64::from(i), "sensor": "inclinometer",
                                     "pitch_deg": 0.1, "roll_deg": 0.2});
                let response = client
                    .post(format!("{base}/api/v1/machines/tbm-r/readings"))
                    .body(reading.to_string())
                    .send()
                    .await
                    .unwrap();
                let status = response.status().as_u16();
                let (_, ack) = json_of(response).await;
                statuses.push((status, ack["duplicates"].clone()));
            }
            statuses
        })
    };
    for i in 0..10 {
        let body = declaration(&format!("name {i}"));
        let response = client
            .put(format!("{base}/api/v1/machines/tbm-r"))
            .body(body)
            .send()
            .await
            .unwrap();
        assert_eq!(response.status(), 200);
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
    }
    // Each answered 200, none stored twice.
    let statuses = posting.await.unwrap();
    assert!(
        statuses.iter().all(|(s, d)| *s == 200 && *d == json!(0)),
        "{statuses:?}"
    );
    let stored = common::exported_readings(&client, &base, "tbm-r").await;
    assert_eq!(stored.len(), 200);
    server.stop().await;
}

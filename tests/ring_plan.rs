//! Issue 60: a machine that declares its universal rings is served the
//! next rings' key positions (`GET .../rings/plan`) from the `ring_plan`
//! stage, after a tail clearance and a ring built with its key; the
//! declaration is checked.

mod common;

use common::{TestServer, declare_machine, get_json, post_ndjson, stream_estimates};
use serde_json::json;

const MACHINE: &str = "tbm-rings";

fn rings() -> serde_json::Value {
    json!({"taper_mm": 40.0, "diameter_m": 6.0, "width_m": 1.5, "key_positions": 16,
           "forbidden_keys": [7, 8, 9], "nominal_clearance_mm": 50.0, "min_clearance_mm": 20.0})
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_next_rings_are_planned_after_a_clearance_and_a_ring() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let mut declaration = common::on_an_axis("Segmental TBM");
    declaration["rings"] = rings();
    declare_machine(&client, &base, MACHINE, &declaration.to_string()).await;
    let path = format!("{base}/api/v1/machines/{MACHINE}/rings/plan");
    let refused = client.get(&path).send().await.unwrap();
    assert_eq!(refused.status(), 404, "no plan yet");
    let body: serde_json::Value = serde_json::from_str(&refused.text().await.unwrap()).unwrap();
    assert!(
        body["error"].as_str().unwrap().contains("no ring plan yet"),
        "{body}"
    );

    // The machine 50 mm right of the axis, level, standing; then the gaps
    // round the ring (the ring 8.5 mm right of the tail's centre: less
    // gap on the right) and ring 101 built with key 4.
    let now = tunnelnav::clock::wall_clock_s().floor();
    let mut lines = common::laser_pairs(now - 40.0, 10, 0.05);
    lines.push(
        json!({"t": now - 5.0, "sensor": "tail_clearance",
               "clearance_mm": [50, 45, 40, 45, 50, 55, 60, 55]})
        .to_string(),
    );
    lines.push(json!({"t": now - 4.0, "sensor": "advance", "ring": 101, "key": 4}).to_string());
    post_ndjson(&client, &base, MACHINE, &lines).await;

    let plan = get_json(
        &client,
        &base,
        &format!("/api/v1/machines/{MACHINE}/rings/plan"),
    )
    .await;
    let stream = stream_estimates(&client, &base, MACHINE, "ring_plan").await;
    assert_eq!(
        stream.len(),
        2,
        "one per clearance and per ring: {stream:?}"
    );
    assert_eq!(plan["t"], now - 4.0);
    assert_eq!(plan["built"]["ring"], 101);
    assert_eq!(plan["built"]["key"], 4);
    // The lining: the tail 50 mm right, the ring 8.5 mm right of it.
    let built_h = plan["built"]["horizontal_mm"].as_f64().unwrap();
    assert!((45.0..70.0).contains(&built_h), "{plan}");
    let rings = plan["rings"].as_array().unwrap();
    assert_eq!(rings.len(), 4, "{plan}");
    let mut previous = 4;
    for (i, ring) in rings.iter().enumerate() {
        assert_eq!(ring["ring"], 102 + i as u64);
        let key = ring["key"].as_u64().unwrap();
        assert!(![7, 8, 9].contains(&key), "a forbidden key: {ring}");
        assert_ne!(key, previous, "joints in line: {plan}");
        previous = key;
        let gaps = ring["predicted_clearance_mm"].as_array().unwrap();
        assert_eq!(gaps.len(), 8, "as many points as measured");
        assert!(!ring["reason"].as_str().unwrap().is_empty());
    }
    // No correction curve declared: toward the axis, so the plan's rings
    // end nearer it than the ring built.
    let last = rings.last().unwrap()["off_target_horizontal_mm"]
        .as_f64()
        .unwrap();
    assert!(last.abs() < built_h.abs(), "{plan}");
    assert_eq!(plan["on_correction_curve"], false);
    assert_eq!(plan["declared"]["key_positions"], 16);
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bad_ring_declaration_is_refused_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    for (change, field) in [
        (json!({"forbidden_keys": [16]}), "rings.forbidden_keys[0]"),
        (json!({"min_clearance_mm": 60.0}), "rings.min_clearance_mm"),
        (json!({"overlap_m": 1.0}), "rings.overlap_m"),
        (json!({"key_positions": 1}), "rings.key_positions"),
    ] {
        let mut declaration = common::on_an_axis("Segmental TBM");
        let mut rings = rings();
        for (k, v) in change.as_object().unwrap() {
            rings[k] = v.clone();
        }
        declaration["rings"] = rings;
        let answer = client
            .put(format!("{base}/api/v1/machines/{MACHINE}"))
            .body(declaration.to_string())
            .header("content-type", "application/json")
            .send()
            .await
            .unwrap();
        assert_eq!(answer.status(), 400, "{change}");
        let text = answer.text().await.unwrap();
        assert!(text.contains(field), "{change}: {text}");
    }
    server.stop().await;
}

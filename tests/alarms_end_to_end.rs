//! Alarms end to end against the real binary: a simulated drive crosses
//! its horizontal tolerance and is steered back, loses its laser, then
//! goes silent → a deviation warning, a laser dropout and a stale
//! inclinometer are raised once each (stored and announced live on the
//! fleet's and the machine's sockets), acknowledged with a read token's
//! name, cleared when the gateway forwards what it buffered, and still
//! listed as they were after a SIGKILL and a restart.

mod common;

use std::time::Duration;

use common::ServerProcess;
use futures_util::StreamExt;
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tunnelnav::clock::wall_clock_s;
use tunnelnav::fusion::alignment::AlignmentSpec;
use tunnelnav::sim::axis_drive::{AxisDrive, AxisDriveScenario, AxisEvent};

type Socket =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// The declared horizontal warn tolerance, mm: the simulated path peaks at
/// 50 mm, so it crosses 40 mm and comes back.
const WARN_H_MM: f64 = 40.0;
/// Laser lost this long before the gateway falls silent (dropout warns
/// at 300 s).
const LASER_LOST_S: f64 = 420.0;

fn axis() -> Value {
    json!({"name": "E-1", "start_station_m": 0.0,
           "start": {"easting_m": 3000.0, "northing_m": 7000.0, "azimuth_deg": 30.0},
           "horizontal": [{"type": "line", "length_m": 2000.0}],
           "vertical": {"start_height_m": 40.0, "end_grade_pct": -0.3}})
}

/// The drive: 50/30 mm peaks (the scenario's tolerances at peak fraction
/// 1), 1.5 m strokes every ~4 minutes, inclinometer at 1 Hz, laser every
/// 10 s.
fn scenario(seed: u64) -> AxisDriveScenario {
    let alignment: AlignmentSpec = serde_json::from_value(axis()).unwrap();
    AxisDriveScenario {
        hours: 3.0,
        peak_fraction: 1.0,
        stroke_min: (2.0, 3.0),
        ring_build_min: (1.0, 2.0),
        incl_period_s: 1.0,
        laser_period_s: 10.0,
        start_t: 1_800_000_000.0,
        ..AxisDriveScenario::on(alignment, seed)
    }
}

/// The machine as declared: the scenario's shield, 40/100 mm horizontal
/// and 100/200 mm vertical tolerances (so only the horizontal crosses).
fn declaration(scenario: &AxisDriveScenario) -> Value {
    json!({
        "name": "TBM E-1",
        "engines": {"attitude": {}},
        "geometry": scenario.geometry,
        "tolerances": {"horizontal_mm": {"warn": WARN_H_MM, "alarm": 100},
                       "vertical_mm": {"warn": 100, "alarm": 200}},
        "alignment": axis(),
    })
}

/// The truth's worst horizontal deviation as a fraction of the warn
/// tolerance at each laser reading.
fn ratios(events: &[AxisEvent]) -> Vec<(f64, f64)> {
    events
        .iter()
        .filter_map(|e| {
            let truth = e.truth.as_ref()?;
            let worst = truth
                .front
                .horizontal_mm
                .abs()
                .max(truth.rear.horizontal_mm.abs());
            Some((e.reading.t, worst / WARN_H_MM))
        })
        .collect()
}

/// Raise/clear pairs of a plain hysteresis on the ratios (raise above
/// `raise`, clear below `clear`): (raised_t, cleared_t or the end).
fn excursions(ratios: &[(f64, f64)], raise: f64, clear: f64) -> Vec<(f64, f64)> {
    let mut found: Vec<(f64, f64)> = Vec::new();
    let mut open: Option<f64> = None;
    for &(t, r) in ratios {
        match open {
            None if r > raise => open = Some(t),
            Some(from) if r < clear => {
                found.push((from, t));
                open = None;
            }
            _ => {}
        }
    }
    found.extend(open.map(|from| (from, f64::INFINITY)));
    found
}

/// The drive has one clear excursion within its first `used_s` after the
/// excursion: the rule (raise above 1.0, clear under 0.9) with the limits
/// moved 6 % either way (the laser's millimetres of noise) finds one raise
/// and one clear both times, the clear at least `calm_s` before the end.
/// The time the truth is back under 84 %.
fn one_excursion(ratios: &[(f64, f64)], calm_s: f64) -> Option<f64> {
    let early = excursions(ratios, 0.94, 0.84);
    let late = excursions(ratios, 1.06, 0.96);
    let back_t = early.first()?.1;
    let end_t = back_t + calm_s;
    let within = |e: &Vec<(f64, f64)>| e.iter().filter(|(from, _)| *from < end_t).count();
    let lasts = ratios.last()?.0 > end_t;
    (within(&early) == 1 && within(&late) == 1 && lasts).then_some(back_t)
}

async fn connect(url: &str, token: &str) -> Socket {
    let mut request = url.into_client_request().unwrap();
    request
        .headers_mut()
        .insert("authorization", format!("Bearer {token}").parse().unwrap());
    tokio_tungstenite::connect_async(request).await.unwrap().0
}

/// The next frame with an `event` of `event` within `timeout`, skipping
/// estimates and pings.
async fn next_event(socket: &mut Socket, event: &str, timeout: Duration) -> Value {
    let deadline = tokio::time::Instant::now() + timeout;
    loop {
        let message = tokio::time::timeout_at(deadline, socket.next())
            .await
            .unwrap_or_else(|_| panic!("no `{event}` event within {timeout:?}"))
            .expect("socket open")
            .expect("frame readable");
        if let Message::Text(text) = message {
            let frame: Value = serde_json::from_str(&text).unwrap();
            if frame["event"] == event {
                return frame;
            }
        }
    }
}

/// Alarm events until `count` of them are `transition`s: all of them, in
/// order, each a ((kind, severity), transition) with its body.
async fn alarm_events(
    socket: &mut Socket,
    transition: &str,
    count: usize,
) -> Vec<((String, String), String, Value)> {
    let mut seen = Vec::new();
    while seen.iter().filter(|(_, t, _)| t == transition).count() < count {
        let event = next_event(socket, "alarm", Duration::from_secs(30)).await;
        let key = (
            event["kind"].as_str().unwrap().to_string(),
            event["severity"].as_str().unwrap().to_string(),
        );
        let change = event["transition"].as_str().unwrap().to_string();
        assert!(
            !seen.iter().any(|(k, t, _)| *k == key && *t == change),
            "announced twice: {event}"
        );
        seen.push((key, change, event));
    }
    seen
}

/// The body of the `transition` event of `kind`.
fn find<'a>(
    events: &'a [((String, String), String, Value)],
    kind: &str,
    transition: &str,
) -> &'a Value {
    &events
        .iter()
        .find(|((k, _), t, _)| k == kind && t == transition)
        .unwrap_or_else(|| panic!("no {transition} {kind}: {events:#?}"))
        .2
}

async fn alarms(client: &reqwest::Client, base: &str, token: &str) -> Vec<Value> {
    let response = client
        .get(format!("{base}/api/v1/alarms?state=all"))
        .bearer_auth(token)
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200);
    let body: Value = serde_json::from_slice(&response.bytes().await.unwrap()).unwrap();
    body["alarms"].as_array().unwrap().clone()
}

async fn post(client: &reqwest::Client, base: &str, token: &str, readings: &[AxisEvent]) {
    let body: String = readings
        .iter()
        .map(|e| e.reading.to_json() + "\n")
        .collect();
    let response = client
        .post(format!("{base}/api/v1/machines/tbm-e1/readings"))
        .bearer_auth(token)
        .header("content-type", "application/x-ndjson")
        .body(body)
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200);
    let ack: Value = serde_json::from_slice(&response.bytes().await.unwrap()).unwrap();
    assert_eq!(ack["accepted"], readings.len(), "{ack}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_drive_off_its_axis_without_laser_then_silent_raises_three_alarms_once_each() {
    // The first seed whose drive has one clear excursion before its end.
    let (events, back_t) = (1..50)
        .find_map(|seed| {
            let events: Vec<AxisEvent> = AxisDrive::new(scenario(seed)).unwrap().collect();
            // Calm until well after the gateway's return.
            let back_t = one_excursion(&ratios(&events), 60.0 + LASER_LOST_S + 600.0)?;
            Some((events, back_t))
        })
        .expect("a seed with one excursion");
    let silent_from_t = back_t + 60.0 + LASER_LOST_S;
    let laser_lost_t = back_t + 60.0;

    let dir = tempfile::tempdir().unwrap();
    let (admin, reader) = {
        let conn = tunnelnav::store::Store::connect(dir.path()).unwrap();
        let token = |name, scope| {
            tunnelnav::store::sqlite::tokens::create(&conn, name, scope, None, wall_clock_s())
                .unwrap()
                .1
        };
        (
            token("site-admin", tunnelnav::auth::Scope::Admin),
            token("night-shift", tunnelnav::auth::Scope::Operator),
        )
    };
    let server = ServerProcess::start(dir.path());
    let base = server.url("");
    let client = reqwest::Client::new();
    let declared = client
        .put(format!("{base}/api/v1/machines/tbm-e1"))
        .bearer_auth(&admin)
        .body(declaration(&scenario(0)).to_string())
        .send()
        .await
        .unwrap();
    assert!(
        declared.status().is_success(),
        "{:?}",
        declared.text().await
    );
    let ws = base.replace("http://", "ws://");
    let mut fleet = connect(&format!("{ws}/api/v1/alarms/live"), &reader).await;
    let hello = next_event(&mut fleet, "hello", Duration::from_secs(5)).await;
    assert_eq!(hello["alarms"], json!([]));
    let mut machine = connect(&format!("{ws}/api/v1/machines/tbm-e1/live"), &reader).await;
    next_event(&mut machine, "hello", Duration::from_secs(5)).await;

    // Shift the drive so the gateway falls silent one second ago; post
    // everything up to then (without the laser's last minutes) at once.
    let shift = (wall_clock_s() - 1.0).floor() - silent_from_t;
    let shifted: Vec<AxisEvent> = events
        .into_iter()
        .map(|mut e| {
            e.reading.t += shift;
            e
        })
        .collect();
    let (laser_lost_t, silent_from_t) = (laser_lost_t + shift, silent_from_t + shift);
    let is_laser = |e: &AxisEvent| e.truth.is_some();
    let before: Vec<AxisEvent> = shifted
        .iter()
        .filter(|e| e.reading.t < silent_from_t && !(is_laser(e) && e.reading.t >= laser_lost_t))
        .cloned()
        .collect();
    post(&client, &base, &admin, &before).await;

    // Raised, each once, on both sockets: the deviation (and its clear)
    // and the dropout from the readings, the stale inclinometer 10 s into
    // the silence.
    let raised = alarm_events(&mut fleet, "raised", 3).await;
    let on_machine = alarm_events(&mut machine, "raised", 3).await;
    assert_eq!(raised, on_machine);
    let mut keys: Vec<(&str, &str, &str)> = raised
        .iter()
        .map(|((k, s), t, _)| (k.as_str(), s.as_str(), t.as_str()))
        .collect();
    keys.sort();
    assert_eq!(
        keys,
        [
            ("deviation", "warn", "cleared"),
            ("deviation", "warn", "raised"),
            ("laser_dropout", "warn", "raised"),
            ("stale_sensor", "alarm", "raised")
        ]
    );
    assert_eq!(
        find(&raised, "stale_sensor", "raised")["subject"],
        "inclinometer"
    );
    let dropout = find(&raised, "laser_dropout", "raised");
    let dropout_t = dropout["raised_t"].as_f64().unwrap();
    assert!(
        (dropout_t - laser_lost_t - 300.0).abs() < 11.0,
        "the dropout is dated 5 min after the last laser sample: {dropout}"
    );
    let deviation = find(&raised, "deviation", "raised");
    assert!(
        deviation["message"].as_str().unwrap().contains("±40 mm"),
        "{deviation}"
    );
    let listed = alarms(&client, &base, &reader).await;
    assert_eq!(listed.len(), 3, "raised once each: {listed:#?}");
    // The deviation was steered back within the drive: already cleared.
    let stored_deviation = listed.iter().find(|a| a["kind"] == "deviation").unwrap();
    assert!(
        stored_deviation["cleared_t"].as_f64().unwrap() < back_t + shift,
        "{stored_deviation}"
    );

    // Acknowledged by the night shift's token: announced once each.
    for alarm in &listed {
        let acked = client
            .post(format!("{base}/api/v1/alarms/{}/ack", alarm["id"]))
            .bearer_auth(&reader)
            .send()
            .await
            .unwrap();
        assert_eq!(acked.status(), 200);
        let again = client
            .post(format!("{base}/api/v1/alarms/{}/ack", alarm["id"]))
            .bearer_auth(&admin)
            .send()
            .await
            .unwrap();
        let again: Value = serde_json::from_slice(&again.bytes().await.unwrap()).unwrap();
        assert_eq!(again["acked_by"], "night-shift", "the first ack stands");
    }
    let acked = alarm_events(&mut fleet, "acknowledged", 3).await;
    assert_eq!(acked.len(), 3, "{acked:#?}");
    assert!(acked.iter().all(|(_, _, a)| a["acked_by"] == "night-shift"));

    // The gateway comes back and forwards what it buffered, laser and
    // all, up to now: the dropout and the stale inclinometer clear.
    let now_t = wall_clock_s();
    let after: Vec<AxisEvent> = shifted
        .iter()
        .filter(|e| e.reading.t >= silent_from_t && e.reading.t <= now_t)
        .cloned()
        .collect();
    assert!(after.iter().any(is_laser));
    post(&client, &base, &admin, &after).await;
    let cleared = alarm_events(&mut fleet, "cleared", 2).await;
    assert_eq!(cleared.len(), 2, "{cleared:#?}");
    find(&cleared, "laser_dropout", "cleared");
    find(&cleared, "stale_sensor", "cleared");
    let done = alarms(&client, &base, &reader).await;
    assert_eq!(done.len(), 3, "{done:#?}");
    for alarm in &done {
        assert!(alarm["cleared_t"].is_f64(), "{alarm}");
        assert!(
            alarm["cleared_t"].as_f64() >= alarm["raised_t"].as_f64(),
            "{alarm}"
        );
        assert_eq!(alarm["acked_by"], "night-shift");
    }

    // SIGKILL, restart: the same three alarms as they were (the readings
    // fed again raise nothing twice). The gateway is silent again, so a
    // new stale alarm may follow; it is new, not one of these.
    server.kill();
    let server = ServerProcess::start(dir.path());
    let base = server.url("");
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let kept = alarms(&client, &base, &reader).await;
    for alarm in &done {
        let same = kept.iter().find(|a| a["id"] == alarm["id"]);
        assert_eq!(same, Some(alarm), "kept as it was");
    }
    // Only a new silence (after the forwarded readings, which end at
    // `now_t`) may have raised something since.
    for other in kept.iter().filter(|a| !done.contains(a)) {
        assert_eq!(other["kind"], "stale_sensor", "{other}");
        assert!(other["raised_t"].as_f64().unwrap() >= now_t, "{other}");
    }
    server.kill();
}

//! The dashboard in a real browser: Debian's headless Chromium driven over
//! WebDriver (chromedriver). A server with one `attitude` machine gets a
//! simulated drive posted in phases while the machine page is open; the
//! test asserts what a driver would see, then that the console is clean.
//! Screenshots go to `target/browser-*.png`.
//!
//! Skipped (and says so) when chromedriver or chromium is missing, unless
//! `TUNNELNAV_BROWSER_TEST=required` (set by `.ci/run`): then it fails.

mod common;

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use fantoccini::wd::WebDriverCompatibleCommand;
use fantoccini::{Client, ClientBuilder};
use serde_json::{Value, json};
use tunnelnav::fusion::SensorData;
use tunnelnav::sim::pipejack::{PipeJackDrive, PipeJackScenario};
use tunnelnav::sim::tbm::{TbmDrive, TbmScenario};
use tunnelnav::sim::vehicle::{VehicleDrive, VehicleScenario};

use common::{post_ndjson, server_with_machine};

const MACHINE: &str = "tbm-browser";

fn find_program(candidates: &[&str]) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    candidates.iter().find_map(|name| {
        std::env::split_paths(&path)
            .map(|dir| dir.join(name))
            .find(|p| p.is_file())
    })
}

/// chromedriver on a free port, killed when dropped.
struct Driver {
    child: Child,
    url: String,
}

impl Driver {
    fn start(program: &Path) -> Driver {
        let port = TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("a free port")
            .port();
        let child = Command::new(program)
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("chromedriver starts");
        Driver {
            child,
            url: format!("http://127.0.0.1:{port}"),
        }
    }
}

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// chromedriver's browser log (`goog:loggingPrefs`), which holds console
/// messages and uncaught errors; not part of W3C WebDriver.
#[derive(Debug)]
struct BrowserLog;

impl WebDriverCompatibleCommand for BrowserLog {
    fn endpoint(
        &self,
        base: &url::Url,
        session: Option<&str>,
    ) -> Result<url::Url, url::ParseError> {
        base.join(&format!("session/{}/se/log", session.unwrap_or_default()))
    }

    fn method_and_body(&self, _: &url::Url) -> (http::Method, Option<String>) {
        (
            http::Method::POST,
            Some(json!({"type": "browser"}).to_string()),
        )
    }
}

async fn connect(driver: &Driver, chromium: Option<&Path>) -> Client {
    let mut chrome = json!({
        "args": ["--headless=new", "--no-sandbox", "--disable-gpu",
                 "--disable-dev-shm-usage", "--window-size=1400,1900",
                 // A control-room screen is set up once to allow sound.
                 "--autoplay-policy=no-user-gesture-required"],
    });
    if let Some(binary) = chromium {
        chrome["binary"] = binary.display().to_string().into();
    }
    let capabilities = json!({
        "browserName": "chrome",
        "goog:chromeOptions": chrome,
        "goog:loggingPrefs": {"browser": "ALL"},
    });
    let Value::Object(capabilities) = capabilities else {
        unreachable!()
    };
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let mut builder =
            ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new());
        builder.capabilities(capabilities.clone());
        match builder.connect(&driver.url).await {
            Ok(client) => return client,
            Err(e) if Instant::now() < deadline => {
                eprintln!("waiting for chromedriver: {e}");
                tokio::time::sleep(Duration::from_millis(250)).await;
            }
            Err(e) => panic!("no WebDriver session: {e}"),
        }
    }
}

async fn js(browser: &Client, script: &str) -> Value {
    browser
        .execute(script, Vec::new())
        .await
        .unwrap_or_else(|e| panic!("script failed: {e}\n{script}"))
}

/// Polls `script` until it returns true; panics with `what` after `secs`.
async fn wait_for(browser: &Client, what: &str, script: &str, secs: u64) {
    let deadline = Instant::now() + Duration::from_secs(secs);
    loop {
        if js(browser, script).await == Value::Bool(true) {
            return;
        }
        if Instant::now() > deadline {
            let state = js(
                browser,
                "const text = (id) => document.getElementById(id)?.textContent; \
                 return {laser: document.getElementById('laser-status')?.dataset.state, \
                 conn: text('conn-state'), pitch: text('pitch-value'), \
                 note: text('history-note'), alarms: text('alarm-bar'), \
                 lost: text('conn-lost'), clock: text('server-clock'), \
                 bar_hidden: document.getElementById('alarm-bar')?.hidden, \
                 card: document.querySelector('.machine-card')?.textContent};",
            )
            .await;
            save_screenshot(browser, "browser-failure.png").await;
            panic!("timed out waiting for {what}; page: {state}");
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

async fn save_screenshot(browser: &Client, name: &str) -> PathBuf {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("target")
        .join(name);
    let png = browser.screenshot().await.expect("screenshot");
    std::fs::write(&path, png).expect("screenshot written");
    path
}

/// A 40-minute drive ending now: 1 Hz inclinometer, 60 s laser.
fn drive_ending_now() -> Vec<tunnelnav::fusion::Reading> {
    let now = tunnelnav::clock::wall_clock_s();
    TbmDrive::new(TbmScenario {
        seed: 5,
        start_t: (now - 2400.0).floor(),
        hours: 2400.0 / 3600.0,
        incl_period_s: 1.0,
        laser_period_s: 60.0,
        dropouts: Vec::new(),
    })
    .unwrap()
    .map(|e| e.reading)
    .collect()
}

/// chromedriver and chromium, or `None` (the test is skipped, and says
/// so) when they are missing and the test is not required.
fn browser_programs() -> Option<(PathBuf, Option<PathBuf>)> {
    let required = std::env::var("TUNNELNAV_BROWSER_TEST").as_deref() == Ok("required");
    let driver_program = find_program(&["chromedriver"]);
    let chromium = find_program(&["chromium", "chromium-browser", "google-chrome"]);
    let Some(driver_program) = driver_program.filter(|_| chromium.is_some()) else {
        assert!(
            !required,
            "TUNNELNAV_BROWSER_TEST=required but chromedriver/chromium are not installed \
             (apt-get install -y chromium chromium-driver)"
        );
        eprintln!(
            "SKIPPED: the browser test needs chromium and chromedriver \
             (apt-get install -y chromium chromium-driver); none found on PATH"
        );
        return None;
    };
    Some((driver_program, chromium))
}

/// Fails on any SEVERE entry in the browser's console log (since the
/// last look).
async fn assert_clean_console(browser: &Client) {
    assert_console_clean_but(browser, &[]).await;
}

/// Fails on any SEVERE entry in the browser's console log (since the last
/// look) that contains none of `expected`.
async fn assert_console_clean_but(browser: &Client, expected: &[&str]) {
    let log = browser
        .issue_cmd(BrowserLog)
        .await
        .expect("chromedriver returns the browser log");
    let errors: Vec<&Value> = log
        .as_array()
        .map(|entries| {
            entries
                .iter()
                .filter(|e| e["level"] == "SEVERE")
                .filter(|e| {
                    let message = e["message"].as_str().unwrap_or_default();
                    !expected.iter().any(|x| message.contains(x))
                })
                .collect()
        })
        .unwrap_or_default();
    assert!(errors.is_empty(), "console errors: {errors:#?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn machine_page_shows_live_attitude_dropout_and_model() {
    let Some((driver_program, chromium)) = browser_programs() else {
        return;
    };

    let dir = tempfile::tempdir().unwrap();
    let (server, client, base) = server_with_machine(dir.path(), MACHINE).await;
    let readings = drive_ending_now();
    let start_t = readings[0].t;
    let phase = |from_s: f64, to_s: f64, laser: bool| -> Vec<String> {
        readings
            .iter()
            .filter(|r| r.t >= start_t + from_s && r.t < start_t + to_s)
            .filter(|r| laser || !matches!(r.data, SensorData::Laser { .. }))
            .map(|r| r.to_json())
            .collect()
    };
    // Posts a phase a simulated minute at a time, as a gateway would.
    let post_live = |lines: Vec<String>| {
        let (client, base) = (client.clone(), base.clone());
        async move {
            for chunk in lines.chunks(60) {
                post_ndjson(&client, &base, MACHINE, chunk).await;
                tokio::time::sleep(Duration::from_millis(150)).await;
            }
        }
    };

    // History: the first 20 minutes before the page opens.
    post_ndjson(&client, &base, MACHINE, &phase(0.0, 1200.0, true)).await;

    let driver = Driver::start(&driver_program);
    let browser = connect(&driver, chromium.as_deref()).await;
    browser
        .goto(&format!("{base}/machines/{MACHINE}"))
        .await
        .expect("page loads");

    wait_for(
        &browser,
        "the live socket",
        "return document.getElementById('conn-state').dataset.state === 'live';",
        15,
    )
    .await;
    wait_for(
        &browser,
        "readouts from history",
        "return /^-?\\d+\\.\\d{3}$/.test(document.getElementById('pitch-value').textContent);",
        15,
    )
    .await;
    // The history ends 20 minutes ago: the 15-minute window is empty, the
    // 2-hour one is not.
    wait_for(
        &browser,
        "an empty 15-minute window",
        "return /no estimates/.test(document.getElementById('history-note').textContent);",
        15,
    )
    .await;
    browser
        .find(fantoccini::Locator::Css(
            "#windows button[data-window='7200']",
        ))
        .await
        .expect("the 2 h button")
        .click()
        .await
        .expect("click");
    wait_for(
        &browser,
        "charts with history",
        "const c = window.tunnelnav.charts; \
         return c.pitch.data[0].length > 100 && c.roll.data[0].length > 100 \
           && c.pitch.data[4].some(v => v !== null);",
        15,
    )
    .await;
    let first = js(
        &browser,
        "return document.getElementById('est-time').textContent \
           + ' ' + document.getElementById('pitch-value').textContent;",
    )
    .await;

    // Live: ten more minutes, laser on; the readouts move, the model trains.
    post_live(phase(1200.0, 1800.0, true)).await;
    wait_for(
        &browser,
        "the readouts to change",
        &format!(
            "return (document.getElementById('est-time').textContent + ' ' + \
             document.getElementById('pitch-value').textContent) !== {first};"
        ),
        15,
    )
    .await;
    wait_for(
        &browser,
        "laser OK",
        "return document.getElementById('laser-status').dataset.state === 'ok';",
        15,
    )
    .await;
    wait_for(
        &browser,
        "the ANFIS curve",
        "const m = window.tunnelnav.state.model; const a = window.tunnelnav.charts.anfis; \
         return !!m && m.version > 0 && m.curve.length > 0 && m.memberships.length > 0 \
           && !!a && a.data[0].length > 0 && a.data[1].some(v => v !== null) \
           && a.data.length === 3 + m.memberships.length;",
        20,
    )
    .await;
    // The self-tuned noise is shown beside the model.
    wait_for(
        &browser,
        "the self-tuned noise",
        "return /^0\\.\\d{4}° cutting · 0\\.\\d{4}° standing$/.test( \
             document.getElementById('noise-pitch').textContent) \
           && /measured from the readings/.test(document.getElementById('noise-note').textContent) \
           && /(vibrating|quiet)/.test(document.getElementById('noise-phase').textContent);",
        10,
    )
    .await;
    let live_points = js(
        &browser,
        "return window.tunnelnav.charts.pitch.data[1].filter(v => v !== null).length;",
    )
    .await;
    assert!(
        live_points.as_u64().unwrap_or(0) > 1500,
        "fused pitch points after live: {live_points}"
    );
    // The ±2σ band around the fused pitch, and the readout's ±2σ.
    let band = js(
        &browser,
        "const d = window.tunnelnav.charts.pitch.data; \
         const n = d[5].filter((v, i) => v !== null && d[6][i] !== null && v > d[6][i]).length; \
         return [n, document.getElementById('pitch-sigma').textContent];",
    )
    .await;
    assert!(
        band[0].as_u64().unwrap_or(0) > 1500
            && band[1].as_str().is_some_and(|s| s.parse::<f64>().is_ok()),
        "the pitch band and its readout: {band}"
    );
    save_screenshot(&browser, "browser-machine.png").await;

    // The theme switch redraws the charts in the other palette.
    let theme = js(&browser, "return document.documentElement.dataset.theme;").await;
    browser
        .find(fantoccini::Locator::Css("#theme-toggle"))
        .await
        .expect("the theme button")
        .click()
        .await
        .expect("click");
    wait_for(
        &browser,
        "the other theme with charts redrawn",
        &format!(
            "return document.documentElement.dataset.theme !== {theme} \
               && window.tunnelnav.charts.pitch.data[0].length > 100;"
        ),
        10,
    )
    .await;

    // The laser stops for five minutes: the banner appears, the model freezes.
    post_live(phase(1800.0, 2100.0, false)).await;
    wait_for(
        &browser,
        "the dropout banner",
        "const s = document.getElementById('laser-status'); \
         return s.dataset.state === 'dropout' \
           && /LASER DROPOUT/.test(s.textContent) && /inclinometer/.test(s.textContent) \
           && /out for \\d+ min/.test(s.textContent) \
           && /good to ±\\d+\\.\\d{3}° \\(2σ\\)/.test(s.textContent);",
        20,
    )
    .await;
    wait_for(
        &browser,
        "the frozen model",
        "return /frozen/.test(document.getElementById('anfis-state').textContent);",
        20,
    )
    .await;
    let dropout_png = save_screenshot(&browser, "browser-dropout.png").await;

    // The connection drops while the laser returns: on reconnecting the
    // page fetches what it missed from the history API.
    js(&browser, "window.tunnelnav.socket.close(); return true;").await;
    post_ndjson(&client, &base, MACHINE, &phase(2100.0, 2220.0, true)).await;
    wait_for(
        &browser,
        "the gap to be backfilled",
        "const c = document.getElementById('conn-state'); \
         return c.dataset.state === 'backfilled' \
           && /reconnected: [1-9]\\d* estimates backfilled/.test(c.textContent);",
        20,
    )
    .await;
    let backfilled = js(&browser, "return window.tunnelnav.state.backfilled;").await;
    assert!(
        backfilled.as_u64().unwrap_or(0) >= 100,
        "backfilled {backfilled}"
    );

    // The laser is back: the banner clears.
    post_live(phase(2220.0, 2400.0, true)).await;
    wait_for(
        &browser,
        "the banner to clear",
        "return document.getElementById('laser-status').dataset.state === 'ok';",
        20,
    )
    .await;

    // The fleet page shows the machine live with its laser state.
    browser
        .goto(&format!("{base}/"))
        .await
        .expect("fleet loads");
    wait_for(
        &browser,
        "the fleet card",
        &format!(
            "const c = document.querySelector('[data-machine=\"{MACHINE}\"]'); \
             return !!c && /pitch/.test(c.textContent) && /laser OK/.test(c.textContent) \
               && /live/.test(c.querySelector('[data-field=state]').textContent);"
        ),
        15,
    )
    .await;
    save_screenshot(&browser, "browser-fleet.png").await;

    assert_clean_console(&browser).await;
    eprintln!(
        "browser test passed; screenshots in {}",
        dropout_png.parent().unwrap().display()
    );

    browser.close().await.ok();
    server.stop().await;
}

/// A `zupt` machine's page: the trolley run's first minutes are posted, the
/// page opens, the rest arrives live; the detector state, the readouts,
/// plan and profile, distance with the rests shaded, and the uncertainty
/// are all drawn, and a dropped socket is backfilled.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn zupt_page_shows_the_drive_and_the_detector() {
    let Some((driver_program, chromium)) = browser_programs() else {
        return;
    };
    const INS: &str = "pj-browser";
    let dir = tempfile::tempdir().unwrap();
    let server = common::TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    common::declare_machine(
        &client,
        &base,
        INS,
        r#"{"name": "Trolley", "engines": {"zupt": {"initial_yaw_deg": 30}}}"#,
    )
    .await;
    // Seven minutes of the trolley run, ending now.
    let now = tunnelnav::clock::wall_clock_s();
    let drive = PipeJackDrive::new(PipeJackScenario {
        start_t: (now - 420.0).floor(),
        ..PipeJackScenario::default()
    })
    .unwrap();
    let lines: Vec<String> = drive
        .take_while(|e| e.reading.t < now)
        .map(|e| e.reading.to_json())
        .collect();
    let (history, live) = lines.split_at(lines.len() / 2);
    for chunk in history.chunks(5000) {
        post_ndjson(&client, &base, INS, chunk).await;
    }

    let driver = Driver::start(&driver_program);
    let browser = connect(&driver, chromium.as_deref()).await;
    browser
        .goto(&format!("{base}/machines/{INS}"))
        .await
        .expect("page loads");
    wait_for(
        &browser,
        "the live socket and the aligned INS",
        "return document.getElementById('conn-state').dataset.state === 'live' \
           && document.getElementById('z-aligned').textContent === 'aligned' \
           && ['still', 'moving'].includes(document.getElementById('zv-status').dataset.state);",
        15,
    )
    .await;
    let first = js(
        &browser,
        "return document.getElementById('z-distance').textContent;",
    )
    .await;
    for chunk in live.chunks(2000) {
        post_ndjson(&client, &base, INS, chunk).await;
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    wait_for(
        &browser,
        "the distance to grow, the rests shaded, the drive drawn",
        &format!(
            "const z = window.tunnelnavZupt; \
             const points = [...z.state.points.values()]; \
             return document.getElementById('z-distance').textContent !== {first} \
               && parseFloat(document.getElementById('z-distance').textContent) > 3 \
               && points.some(p => p.zv) && points.some(p => !p.zv) \
               && z.charts.distance.data[0].length > 200 \
               && z.charts.sigma.data[1].some(v => v > 0) \
               && z.state.track.length > 20 \
               && /^\\d+(\\.\\d+)?$/.test(document.getElementById('ratio-mv').textContent) \
               && /^\\d+\\.\\d+$/.test(document.getElementById('z-yaw-sigma').textContent);"
        ),
        20,
    )
    .await;
    save_screenshot(&browser, "browser-zupt.png").await;

    // A dropped socket is backfilled from the history API.
    js(
        &browser,
        "window.tunnelnavZupt.socket.close(); return true;",
    )
    .await;
    wait_for(
        &browser,
        "the socket to come back",
        "return document.getElementById('conn-state').dataset.state === 'live' \
           || document.getElementById('conn-state').dataset.state === 'backfilled';",
        20,
    )
    .await;

    // The fleet card shows the INS's distance and state.
    browser
        .goto(&format!("{base}/"))
        .await
        .expect("fleet loads");
    wait_for(
        &browser,
        "the INS fleet card",
        &format!(
            "const c = document.querySelector('[data-machine=\"{INS}\"]'); \
             return !!c && /distance/.test(c.textContent) && /heading/.test(c.textContent);"
        ),
        15,
    )
    .await;
    assert_clean_console(&browser).await;
    browser.close().await.ok();
    server.stop().await;
}

/// A `fuzzy` machine's page: the vehicle's first two minutes (parked, the
/// calibration turn) are posted, the page opens, the next three minutes
/// arrive live; the motion status, the compass rose, the calibration
/// state, and the static degree and gyro bias over time are all shown.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fuzzy_page_shows_compass_motion_and_calibration() {
    let Some((driver_program, chromium)) = browser_programs() else {
        return;
    };
    const VAN: &str = "van-browser";
    let dir = tempfile::tempdir().unwrap();
    let server = common::TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    common::declare_machine(
        &client,
        &base,
        VAN,
        r#"{"name": "Service van", "engines": {"fuzzy": {"declination_deg": 2.5}}}"#,
    )
    .await;
    // Five minutes of the vehicle drive, ending now.
    let now = tunnelnav::clock::wall_clock_s();
    let start_t = (now - 300.0).floor();
    let drive = VehicleDrive::new(VehicleScenario {
        start_t,
        ..VehicleScenario::default()
    })
    .unwrap();
    let lines: Vec<(f64, String)> = drive
        .take_while(|e| e.reading.t < now)
        .map(|e| (e.reading.t, e.reading.to_json()))
        .collect();
    let split = lines.partition_point(|(t, _)| *t < start_t + 125.0);
    let (history, live) = lines.split_at(split);
    let history: Vec<String> = history.iter().map(|(_, l)| l.clone()).collect();
    for chunk in history.chunks(5000) {
        post_ndjson(&client, &base, VAN, chunk).await;
    }

    let driver = Driver::start(&driver_program);
    let browser = connect(&driver, chromium.as_deref()).await;
    browser
        .goto(&format!("{base}/machines/{VAN}"))
        .await
        .expect("page loads");
    wait_for(
        &browser,
        "the live socket, the motion status and the calibration",
        "return document.getElementById('conn-state').dataset.state === 'live' \
           && ['static', 'moving'].includes(document.getElementById('fz-status').dataset.state) \
           && document.getElementById('f-calibration').textContent === 'planar' \
           && /^\\d+\\.\\d$/.test(document.getElementById('f-heading').textContent) \
           && /^\\d+\\.\\d$/.test(document.getElementById('f-compass').textContent);",
        15,
    )
    .await;
    let live: Vec<String> = live.iter().map(|(_, l)| l.clone()).collect();
    for chunk in live.chunks(2000) {
        post_ndjson(&client, &base, VAN, chunk).await;
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    wait_for(
        &browser,
        "static and moving spans, the static degree, the bias and the compass rose",
        "const f = window.tunnelnavFuzzy; \
         const points = [...f.state.points.values()]; \
         const rose = document.getElementById('compass-canvas'); \
         const pixels = rose.getContext('2d').getImageData(0, 0, rose.width, rose.height).data; \
         let painted = 0; for (let i = 3; i < pixels.length; i += 4) if (pixels[i] > 0) painted++; \
         return points.some(p => p.still) && points.some(p => !p.still) \
           && f.charts.degree.data[1].some(v => v > 0.9) && f.charts.degree.data[1].some(v => v < 0.1) \
           && f.charts.bias.data[1].length > 200 \
           && f.charts.attitude.data[3].some(v => v > 0) \
           && painted > 500 \
           && /^-?\\d+\\.\\d{4}$/.test(document.getElementById('f-bias-z').textContent) \
           && /^\\d+\\.\\d{4}$/.test(document.getElementById('f-bias-sigma').textContent) \
           && /^\\d+\\.\\d$/.test(document.getElementById('f-heading-sigma').textContent) \
           && /^\\d+\\.\\d{2}$/.test(document.getElementById('f-tilt-sigma').textContent) \
           && /^compass .+ since .*\\d\\d:\\d\\d:\\d\\d$/.test(document.getElementById('f-compass-state').textContent);",
        20,
    )
    .await;
    save_screenshot(&browser, "browser-fuzzy.png").await;

    // The fleet card shows the vehicle's heading.
    browser
        .goto(&format!("{base}/"))
        .await
        .expect("fleet loads");
    wait_for(
        &browser,
        "the vehicle's fleet card",
        &format!(
            "const c = document.querySelector('[data-machine=\"{VAN}\"]'); \
             return !!c && /heading/.test(c.textContent);"
        ),
        15,
    )
    .await;
    assert_clean_console(&browser).await;
    browser.close().await.ok();
    server.stop().await;
}

/// With tokens in force the dashboard signs in through the login form
/// (the token goes in a POST body and an HttpOnly cookie, never a URL):
/// the fleet page, a machine page and its live socket then work.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_dashboard_signs_in_when_tokens_are_required() {
    let Some((driver_program, chromium)) = browser_programs() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (admin, reader) = {
        let conn = tunnelnav::store::Store::connect(dir.path()).unwrap();
        let admin = tunnelnav::store::sqlite::tokens::create(
            &conn,
            "admin",
            tunnelnav::auth::Scope::Admin,
            None,
            0.0,
        )
        .unwrap()
        .1;
        let reader = tunnelnav::store::sqlite::tokens::create(
            &conn,
            "control room",
            tunnelnav::auth::Scope::Read,
            None,
            0.0,
        )
        .unwrap()
        .1;
        (admin, reader)
    };
    let server = common::TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let declared = client
        .put(format!("{base}/api/v1/machines/tbm-auth"))
        .bearer_auth(&admin)
        .body(r#"{"name": "TBM behind a login", "engines": {"attitude": {}}}"#)
        .send()
        .await
        .unwrap();
    assert_eq!(declared.status(), 201);

    let driver = Driver::start(&driver_program);
    let browser = connect(&driver, chromium.as_deref()).await;
    browser.goto(&format!("{base}/")).await.expect("page loads");
    wait_for(
        &browser,
        "the login form",
        "return location.pathname === '/login' && !!document.getElementById('token');",
        10,
    )
    .await;
    js(
        &browser,
        &format!(
            "document.getElementById('token').value = '{reader}'; \
             document.querySelector('form').submit(); return true;"
        ),
    )
    .await;
    wait_for(
        &browser,
        "the fleet page with the machine's card",
        "return location.pathname === '/' \
           && !!document.querySelector('[data-machine=\"tbm-auth\"]');",
        10,
    )
    .await;
    let url = js(&browser, "return location.href;").await;
    assert!(!url.as_str().unwrap().contains("tnv_"), "{url}");
    browser
        .goto(&format!("{base}/machines/tbm-auth"))
        .await
        .expect("machine page loads");
    wait_for(
        &browser,
        "the live socket",
        "return document.getElementById('conn-state').dataset.state === 'live';",
        10,
    )
    .await;
    assert_clean_console(&browser).await;

    // The token is revoked: the page says the connection is lost (not
    // live), offers to sign in again, and the clock stops.
    {
        let conn = tunnelnav::store::Store::connect(dir.path()).unwrap();
        let tokens = tunnelnav::store::sqlite::tokens::list(&conn).unwrap();
        let id = tokens.iter().find(|t| t.name == "control room").unwrap().id;
        tunnelnav::store::sqlite::tokens::revoke(&conn, id, tunnelnav::clock::wall_clock_s())
            .unwrap();
    }
    wait_for(
        &browser,
        "connection lost after the token was revoked",
        "const lost = document.getElementById('conn-lost'); \
         return !lost.hidden && /connection lost — data as of/.test(lost.textContent) \
           && /401/.test(lost.textContent) && !!lost.querySelector('a[href=\"/login\"]') \
           && document.getElementById('server-clock').classList.contains('stopped');",
        10,
    )
    .await;
    browser.close().await.ok();
    server.stop().await;
}

/// What the `dta` panel shows, read from the page: the readouts and their
/// statuses, the computed colours of the values and of the status
/// variables, where the target drew the front mark and the canvas's pixel
/// there, and the deviation-against-station chart's data.
const DTA_VIEW: &str = r#"
const d = window.tunnelnavDta;
if (!d) return null;
const $ = (id) => document.getElementById(id);
const probe = (name) => {
  const el = document.createElement('span');
  el.style.color = `var(${name})`;
  document.body.appendChild(el);
  const colour = getComputedStyle(el).color;
  el.remove();
  return colour;
};
const mm = (id) => parseFloat($(id).textContent.replace('\u2212', '-'));
const colour = (id) => getComputedStyle($(id).closest('.readout-value')).color;
let pixel = null;
if (d.marks.front) {
  const canvas = $('dta-target');
  const r = canvas.width / canvas.clientWidth;
  const p = canvas.getContext('2d')
    .getImageData(Math.round(d.marks.front.x * r), Math.round(d.marks.front.y * r), 1, 1).data;
  pixel = `rgb(${p[0]}, ${p[1]}, ${p[2]})`;
}
const values = (i) => d.charts.h ? d.charts.h.data[i].filter((v) => v !== null) : [];
return {
  conn: $('conn-state').dataset.state,
  latest: !!d.state.latest,
  front_h: mm('dta-front-h'), front_v: mm('dta-front-v'),
  rear_h: mm('dta-rear-h'), rear_v: mm('dta-rear-v'),
  front_h_status: $('dta-front-h-box').dataset.status,
  front_v_status: $('dta-front-v-box').dataset.status,
  rear_h_status: $('dta-rear-h-box').dataset.status,
  rear_v_status: $('dta-rear-v-box').dataset.status,
  badge: $('dta-status').dataset.status,
  badge_class: $('dta-status').className,
  badge_text: $('dta-status').textContent,
  front_h_colour: colour('dta-front-h'), front_v_colour: colour('dta-front-v'),
  rear_h_colour: colour('dta-rear-h'),
  ok: probe('--ok'), warn: probe('--warn'), bad: probe('--bad'), fused: probe('--fused'),
  chainage: $('dta-chainage').textContent,
  target_draws: d.draws.target, plan_draws: d.draws.plan, profile_draws: d.draws.profile,
  front_x: d.marks.front ? d.marks.front.x : null,
  front_y: d.marks.front ? d.marks.front.y : null,
  pixel,
  stations: d.charts.h ? d.charts.h.data[0].length : 0,
  most_front_h: Math.max(0, ...values(1)),
  axis_points: d.state.axis.length,
  steer_t: d.state.steering ? d.state.steering.t : null,
  steer_rows: $('dta-steer-table') ? [...$('dta-steer-table').tBodies[0].rows].map((r) => [...r.cells].map((c) => c.textContent)) : null,
  steer_badge: $('dta-steer-status') ? $('dta-steer-status').textContent : null,
  steer_words: $('dta-steer-words') ? $('dta-steer-words').textContent : null,
  report_links: [...document.querySelectorAll('#ring-log a')].map((a) => a.getAttribute('href')),
  ring_rows: [...document.querySelectorAll('#ring-log-table tbody tr')].map((r) => [...r.cells].map((c) => c.textContent)),
  next: d.marks.next,
  curve_points: d.charts.h ? d.charts.h.data[3].filter((v) => v !== null).length : 0,
};
"#;

/// A station as the page writes it: "1+234.500".
fn tunnelnav_chainage(station_m: f64) -> String {
    let km = (station_m / 1000.0).floor();
    format!("{km}+{:07.3}", station_m - km * 1000.0)
}

/// Polls [`DTA_VIEW`] until `done` holds; panics with the view (and saves
/// a screenshot) after `secs`.
async fn wait_for_dta(
    browser: &Client,
    what: &str,
    secs: u64,
    done: impl Fn(&Value) -> bool,
) -> Value {
    let deadline = Instant::now() + Duration::from_secs(secs);
    loop {
        let view = js(browser, DTA_VIEW).await;
        if !view.is_null() && done(&view) {
            return view;
        }
        if Instant::now() > deadline {
            save_screenshot(browser, "browser-dta-failure.png").await;
            panic!("timed out waiting for {what}; dta panel: {view:#}");
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

/// A TBM on the S-1 axis (tests/fixtures/alignment/s1.json: a straight
/// first 40 m at azimuth 30°, rising at 0.5 %) with tolerances H 50/100,
/// V 30/60 mm. Its laser puts it on the axis (history), then 70 mm right
/// and 10 mm high (live: warn), then 100 mm right and 40 mm low yawed
/// 0.3° right (live: the front 122 mm right, alarm; the rear 73 mm, warn).
/// The panel's readouts, their colours, the badge and the target's front
/// mark follow each step; the fleet card shows the alarm.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dta_panel_draws_moves_and_shows_warn_and_alarm_colours() {
    let Some((driver_program, chromium)) = browser_programs() else {
        return;
    };
    const TBM: &str = "tbm-dta-browser";
    let dir = tempfile::tempdir().unwrap();
    let server = common::TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/alignment/s1.json");
    let alignment: Value =
        serde_json::from_str(&std::fs::read_to_string(fixture).unwrap()).unwrap();
    let declaration = json!({
        "name": "TBM on S-1",
        "engines": {"attitude": {}},
        "geometry": {"front_m": [4.2, 0.0, 0.0], "rear_m": [-5.1, 0.0, 0.0]},
        "tolerances": {"horizontal_mm": {"warn": 50, "alarm": 100},
                       "vertical_mm": {"warn": 30, "alarm": 60}},
        "alignment": alignment,
        "steering": {"min_radius_m": 300.0, "step_m": 1.5, "cylinder_circle_m": 6.0},
    });
    common::declare_machine(&client, &base, TBM, &declaration.to_string()).await;

    // Ten minutes from five minutes ago (what is posted live later is
    // stamped ahead: a position minutes old is not drawn as live): 1 Hz
    // inclinometer, the laser every 30 s. The machine pitches with the
    // 0.5 % grade and advances 10 → 19 m.
    let now = tunnelnav::clock::wall_clock_s();
    let t0 = (now - 300.0).floor();
    let (azimuth, grade) = (30f64.to_radians(), 0.005f64);
    let pitch_deg = grade.atan().to_degrees();
    // (right offset m, height offset m, yaw error °) of each phase.
    let phase_of = |s: u32| match s {
        0..300 => (0.0, 0.0, 0.0),
        300..450 => (0.070, 0.010, 0.0),
        _ => (0.100, -0.040, 0.3),
    };
    let readings = |from: u32, to: u32| -> Vec<String> {
        let mut lines = Vec::new();
        for s in from..to {
            let t = t0 + f64::from(s);
            lines.push(
                json!({"t": t, "sensor": "inclinometer", "pitch_deg": pitch_deg, "roll_deg": 0.0})
                    .to_string(),
            );
            if s % 30 == 0 {
                let (right, up, yaw) = phase_of(s);
                let station = 10.0 + 0.015 * f64::from(s);
                let (sin, cos) = azimuth.sin_cos();
                lines.push(
                    json!({"t": t, "sensor": "laser", "pitch_deg": pitch_deg, "roll_deg": 0.0,
                           "yaw_deg": 30.0 + yaw,
                           "easting_m": 1000.0 + station * sin + right * cos,
                           "northing_m": 5000.0 + station * cos - right * sin,
                           "height_m": 50.0 + grade * station + up})
                    .to_string(),
                );
            }
            // A ring every 100 s (1.5 m), with its strokes.
            if s % 100 == 50 {
                lines.push(
                    json!({"t": t + 0.5, "sensor": "advance", "ring": 200 + s / 100,
                           "strokes_mm": [1500.0, 1504.0, 1500.0, 1496.0]})
                    .to_string(),
                );
            }
        }
        lines
    };
    let post_live = |lines: Vec<String>| {
        let (client, base) = (client.clone(), base.clone());
        async move {
            for chunk in lines.chunks(31) {
                post_ndjson(&client, &base, TBM, chunk).await;
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
    };
    post_ndjson(&client, &base, TBM, &readings(0, 300)).await;

    let driver = Driver::start(&driver_program);
    let browser = connect(&driver, chromium.as_deref()).await;
    browser
        .goto(&format!("{base}/machines/{TBM}"))
        .await
        .expect("page loads");
    let near = |v: &Value, key: &str, want: f64| {
        v[key].as_f64().is_some_and(|got| (got - want).abs() <= 3.0)
    };
    let is = |v: &Value, key: &str, want: &str| v[key] == want;

    // On the axis: everything ok, the target drawn with the front mark at
    // the centre.
    let ok = wait_for_dta(&browser, "the panel on the axis", 15, |v| {
        is(v, "conn", "live")
            && near(v, "front_h", 0.0)
            && near(v, "front_v", 0.0)
            && near(v, "rear_h", 0.0)
            && near(v, "rear_v", 0.0)
            && [
                "front_h_status",
                "front_v_status",
                "rear_h_status",
                "rear_v_status",
            ]
            .iter()
            .all(|k| is(v, k, "ok"))
            && is(v, "badge", "ok")
            && v["badge_class"].as_str().unwrap_or("").contains("ok")
            && v["front_h_colour"] == v["ok"]
            && v["target_draws"].as_u64() > Some(0)
            && v["plan_draws"].as_u64() > Some(0)
            && v["profile_draws"].as_u64() > Some(0)
            && v["pixel"] == v["fused"]
            && v["stations"].as_u64() > Some(5)
            && v["axis_points"].as_u64() > Some(40)
    })
    .await;
    assert_ne!(ok["ok"], ok["warn"], "{ok:#}");
    assert_ne!(ok["warn"], ok["bad"], "{ok:#}");
    save_screenshot(&browser, "browser-dta-ok.png").await;
    let centre_x = ok["front_x"].as_f64().unwrap();

    // 70 mm right, 10 mm high: the horizontal readouts warn, the vertical
    // ones stay ok, the front mark moves right.
    post_live(readings(300, 450)).await;
    let warn = wait_for_dta(&browser, "the warning", 15, |v| {
        near(v, "front_h", 70.0)
            && near(v, "rear_h", 70.0)
            && near(v, "front_v", 10.0)
            && is(v, "front_h_status", "warn")
            && is(v, "rear_h_status", "warn")
            && is(v, "front_v_status", "ok")
            && is(v, "badge", "warn")
            && v["badge_class"].as_str().unwrap_or("").contains("warn")
            && v["badge_text"]
                .as_str()
                .unwrap_or("")
                .contains("horizontal +70")
            && v["front_h_colour"] == v["warn"]
            && v["front_v_colour"] == v["ok"]
            && v["front_x"].as_f64().is_some_and(|x| x > centre_x + 40.0)
            && v["pixel"] == v["fused"]
            && v["chainage"] != ok["chainage"]
    })
    .await;
    assert_ne!(warn["front_h_colour"], ok["front_h_colour"], "{warn:#}");

    // 100 mm right, 40 mm low, yawed right: the front alarms, the rear
    // warns, the mark moves further right and down.
    post_live(readings(450, 600)).await;
    let alarm = wait_for_dta(&browser, "the alarm", 15, |v| {
        near(v, "front_h", 122.0)
            && near(v, "rear_h", 73.3)
            && near(v, "front_v", -40.0)
            && is(v, "front_h_status", "alarm")
            && is(v, "rear_h_status", "warn")
            && is(v, "front_v_status", "warn")
            && is(v, "badge", "alarm")
            && v["badge_class"].as_str().unwrap_or("").contains("bad")
            && v["front_h_colour"] == v["bad"]
            && v["rear_h_colour"] == v["warn"]
            && v["front_x"].as_f64() > warn["front_x"].as_f64()
            && v["front_y"].as_f64() > warn["front_y"].as_f64()
            && v["pixel"] == v["fused"]
            && v["most_front_h"].as_f64().is_some_and(|h| h > 115.0)
    })
    .await;
    assert_ne!(alarm["front_h_colour"], warn["front_h_colour"], "{alarm:#}");

    // The correction curve from the newest estimate: a row per step with
    // the served targets and stroke differences, the next step ringed on
    // the target, the curve dashed on the charts.
    let served =
        common::get_json(&client, &base, &format!("/api/v1/machines/{TBM}/steering")).await;
    let steps = served["steps"].as_u64().expect("a curve back") as usize;
    let one = |v: &Value| {
        let v = v.as_f64().unwrap();
        let text = format!("{:.1}", v.abs());
        match v {
            v if v > 0.0 => format!("+{text}"),
            v if v < 0.0 => format!("\u{2212}{text}"),
            _ => text,
        }
    };
    let (h, v) = (
        &served["horizontal"]["points"],
        &served["vertical"]["points"],
    );
    let first_row = json!([
        "1",
        tunnelnav_chainage(h[1]["station_m"].as_f64().unwrap()),
        one(&h[1]["deviation_mm"]),
        one(&v[1]["deviation_mm"]),
        one(&h[0]["stroke_difference_mm"]),
        one(&v[0]["stroke_difference_mm"]),
        if h[1]["outside_warn"] == true || v[1]["outside_warn"] == true {
            "\u{26a0} beyond warn"
        } else {
            ""
        },
    ]);
    let curve = wait_for_dta(&browser, "the correction curve", 15, |view| {
        view["steer_t"].as_f64() == served["t"].as_f64()
            && view["steer_rows"].as_array().map(Vec::len) == Some(steps)
            && view["steer_rows"][0] == first_row
            && view["curve_points"].as_u64() == Some(steps as u64 + 1)
            && view["next"].is_object()
    })
    .await;
    assert_eq!(curve["next"]["h"], h[1]["deviation_mm"], "{curve:#}");
    // The next step in words, as served; the shift report and the
    // as-built report linked from the machine page.
    assert_eq!(curve["steer_words"], served["words"], "{curve:#}");
    let links: Vec<&str> = curve["report_links"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_str)
        .collect();
    for wanted in [
        "/report?format=pdf",
        "/report?format=html",
        "/as-built?format=pdf",
        "engine=rings",
    ] {
        assert!(
            links.iter().any(|l| l.contains(wanted)),
            "{wanted}: {links:?}"
        );
    }
    // The ring log: the rings posted so far (one every 100 s from 50 s),
    // newest first, with their strokes.
    let rings = wait_for_dta(&browser, "the ring log", 10, |v| {
        v["ring_rows"]
            .as_array()
            .is_some_and(|rows| rows.len() >= 3)
    })
    .await;
    let rows = rings["ring_rows"].as_array().unwrap();
    assert_eq!(
        rows[0][0],
        format!("{}", 200 + (rows.len() - 1)),
        "{rows:?}"
    );
    assert_eq!(rows[0][8], "1500 1504 1500 1496", "{rows:?}");
    assert_eq!(rows.last().unwrap()[0], "200", "{rows:?}");
    assert!(
        curve["steer_badge"]
            .as_str()
            .unwrap()
            .contains(&format!("{steps} steps")),
        "{curve:#}"
    );
    save_screenshot(&browser, "browser-dta.png").await;

    // The other theme redraws the target.
    let draws = alarm["target_draws"].as_u64().unwrap();
    browser
        .find(fantoccini::Locator::Css("#theme-toggle"))
        .await
        .expect("the theme button")
        .click()
        .await
        .expect("click");
    wait_for_dta(&browser, "the target redrawn in the other theme", 10, |v| {
        v["target_draws"].as_u64() > Some(draws)
            && v["pixel"] == v["fused"]
            && v["fused"] != alarm["fused"]
    })
    .await;
    save_screenshot(&browser, "browser-dta-theme.png").await;

    // The fleet card: the deviations and the alarm, coloured.
    browser
        .goto(&format!("{base}/"))
        .await
        .expect("fleet loads");
    wait_for(
        &browser,
        "the fleet card's deviation rows",
        &format!(
            "const c = document.querySelector('[data-machine=\"{TBM}\"]'); \
             const flag = c && c.querySelector('.dta-flag'); \
             return !!flag && flag.dataset.status === 'alarm' && /ALARM/.test(flag.textContent) \
               && /DTA front/.test(c.textContent) && /H \\+12\\d/.test(c.textContent) \
               && getComputedStyle(flag).color !== getComputedStyle(c).color;"
        ),
        15,
    )
    .await;
    save_screenshot(&browser, "browser-dta-fleet.png").await;
    assert_clean_console(&browser).await;
    browser.close().await.ok();
    server.stop().await;
}

/// Issue 54: a deviation whose position is 15 minutes old (the laser out
/// since) is not drawn as live: the panel's badge says NOT LIVE with the
/// age, the readouts are struck and uncoloured, the age is highlighted; the
/// laser dropout is said in a banner at the top of the page, above every
/// panel; the fleet card strikes the deviation and gives its age.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stale_deviation_is_struck_with_its_age_and_the_dropout_is_said_at_the_top() {
    let Some((driver_program, chromium)) = browser_programs() else {
        return;
    };
    const TBM: &str = "tbm-stale";
    let dir = tempfile::tempdir().unwrap();
    let server = common::TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let declaration = common::on_an_axis("TBM with a stale position");
    common::declare_machine(&client, &base, TBM, &declaration.to_string()).await;
    // 20 minutes of a 1 Hz inclinometer to now; the laser every 20 s,
    // 70 mm right of the axis (a warning), only until 15 minutes ago.
    let now = tunnelnav::clock::wall_clock_s().floor();
    let lines: Vec<String> = (-1200..=0)
        .flat_map(|s: i32| {
            let t = now + f64::from(s);
            let mut lines =
                vec![json!({"t": t, "sensor": "inclinometer", "pitch_deg": 0.0, "roll_deg": 0.0})];
            if s % 20 == 0 && s <= -900 {
                lines.push(json!({"t": t, "sensor": "laser", "pitch_deg": 0.0,
                    "roll_deg": 0.0, "yaw_deg": 0.0, "easting_m": 1000.07,
                    "northing_m": 5020.0, "height_m": 50.0}));
            }
            lines
        })
        .map(|line| line.to_string())
        .collect();
    post_ndjson(&client, &base, TBM, &lines).await;

    let driver = Driver::start(&driver_program);
    let browser = connect(&driver, chromium.as_deref()).await;
    browser
        .goto(&format!("{base}/machines/{TBM}"))
        .await
        .expect("machine page loads");
    wait_for(
        &browser,
        "the stale deviation struck with its age, the dropout banner at the top",
        "const badge = document.getElementById('dta-status');          const box = document.getElementById('dta-front-h-box');          const banner = document.getElementById('trust-banner');          const panel = document.querySelector('.dta-panel');          return /NOT LIVE/.test(badge.textContent) && /1[45] min [0-9][0-9] s old/.test(badge.textContent)            && box.dataset.status === 'stale'            && getComputedStyle(box.querySelector('.readout-value')).textDecorationLine === 'line-through'            && document.getElementById('dta-age').classList.contains('age-stale')            && !banner.hidden && /LASER DROPOUT/.test(banner.textContent)            && banner.getBoundingClientRect().top < panel.getBoundingClientRect().top            && banner.getBoundingClientRect().top < window.innerHeight / 3            && badge.textContent.match(/(1[45] min [0-9][0-9] s) old/)[1] === document.getElementById('dta-age').textContent.replace(/ ago$/, '');",
        15,
    )
    .await;
    save_screenshot(&browser, "browser-stale-deviation.png").await;

    browser
        .goto(&format!("{base}/"))
        .await
        .expect("fleet loads");
    wait_for(
        &browser,
        "the fleet card's deviation struck with its age",
        &format!(
            "const c = document.querySelector('[data-machine=\"{TBM}\"]'); \
             const struck = c && c.querySelector('.figures .not-live'); \
             return !!struck && /DTA front/.test(c.textContent) \
               && /1[45] min \\d\\d s old/.test(c.textContent) \
               && getComputedStyle(struck).textDecorationLine === 'line-through';"
        ),
        15,
    )
    .await;
    assert_clean_console(&browser).await;
    browser.close().await.ok();
    server.stop().await;
}

/// Issue 54: the alarm bar lists alarms before warnings, then the newest
/// first: machine A beyond its alarm limit (an alarm and a warning, raised
/// together), then machine B beyond its warn limit later. Newest first
/// alone would put B's warning on top.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_alarm_bar_lists_alarms_before_warnings_then_the_newest_first_with_what_they_read_now()
{
    let Some((driver_program, chromium)) = browser_programs() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let server = common::TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let now = tunnelnav::clock::wall_clock_s().floor();
    for (machine, right_mm, from_s) in [("tbm-a", 120.0, -80), ("tbm-b", 70.0, -40)] {
        let mut declaration = common::on_an_axis(machine);
        declaration["alarms"] = json!({"stale_min_s": 3600});
        common::declare_machine(&client, &base, machine, &declaration.to_string()).await;
        let lines = common::laser_pairs(now + f64::from(from_s), 15, right_mm / 1000.0);
        post_ndjson(&client, &base, machine, &lines).await;
    }
    let driver = Driver::start(&driver_program);
    let browser = connect(&driver, chromium.as_deref()).await;
    browser
        .goto(&format!("{base}/"))
        .await
        .expect("fleet loads");
    wait_for(
        &browser,
        "three alarms: A's alarm, then B's warning, then A's warning",
        "const rows = [...document.querySelectorAll('#alarm-list li')].map((li) => \
           `${li.querySelector('a').textContent} ${li.querySelector('.badge').textContent}`); \
         return rows.join(' | ') === 'tbm-a ALARM | tbm-b warn | tbm-a warn';",
        15,
    )
    .await;
    // Machine A swings from 120 to 150 mm right: its alarm keeps the value
    // at the raise and says what it reads now, without a reload.
    let lines = common::laser_pairs(now - 40.0, 5, 0.15);
    post_ndjson(&client, &base, "tbm-a", &lines).await;
    wait_for(
        &browser,
        "A's alarm: raised at +120 mm, now +150 mm",
        "const li = document.querySelector('#alarm-list li'); \
         const now = li && li.querySelector('.now'); \
         return !!now && li.querySelector('.message').textContent.includes('+120 mm') \
           && now.textContent.includes('+150 mm');",
        15,
    )
    .await;
    assert_clean_console(&browser).await;
    browser.close().await.ok();
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_alarm_bar_rings_is_acknowledged_and_the_page_says_when_the_server_is_gone() {
    let Some((driver_program, chromium)) = browser_programs() else {
        return;
    };
    const TBM: &str = "tbm-alarm-browser";
    let dir = tempfile::tempdir().unwrap();
    let server = common::TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    // Due north from (1000, 5000) at 50 m; ±50/100 mm horizontally.
    let declaration = json!({
        "name": "TBM with alarms",
        "engines": {"attitude": {}},
        "geometry": {"front_m": [4.0, 0.0, 0.0], "rear_m": [-5.0, 0.0, 0.0]},
        "tolerances": {"horizontal_mm": {"warn": 50, "alarm": 100},
                       "vertical_mm": {"warn": 30, "alarm": 60}},
        "alignment": {"start": {"easting_m": 1000.0, "northing_m": 5000.0, "azimuth_deg": 0.0},
                      "horizontal": [{"type": "line", "length_m": 100.0}],
                      "vertical": {"start_height_m": 50.0, "end_grade_pct": 0.0}},
        // No gateway keeps posting here: sensors are not judged stale.
        "alarms": {"stale_min_s": 3600}
    });
    common::declare_machine(&client, &base, TBM, &declaration.to_string()).await;
    // Seconds `from..to` before now: 1 Hz inclinometer and a laser every
    // 2 s, `right_mm` right of the axis.
    let readings = |from: i32, to: i32, right_mm: f64| -> Vec<String> {
        let now = tunnelnav::clock::wall_clock_s().floor();
        (from..to)
            .flat_map(|s| {
                let t = now + f64::from(s);
                let mut lines = vec![
                    json!({"t": t, "sensor": "inclinometer", "pitch_deg": 0.0, "roll_deg": 0.0}),
                ];
                if s % 2 == 0 {
                    lines.push(json!({"t": t, "sensor": "laser", "pitch_deg": 0.0,
                        "roll_deg": 0.0, "yaw_deg": 0.0, "easting_m": 1000.0 + right_mm / 1000.0,
                        "northing_m": 5020.0, "height_m": 50.0}));
                }
                lines
            })
            .map(|line| line.to_string())
            .collect()
    };
    // On the axis from 60 to 30 s ago.
    post_ndjson(&client, &base, TBM, &readings(-60, -30, 0.0)).await;

    let driver = Driver::start(&driver_program);
    let browser = connect(&driver, chromium.as_deref()).await;
    browser
        .goto(&format!("{base}/"))
        .await
        .expect("fleet loads");
    wait_for(
        &browser,
        "the fleet page, no alarm",
        "return document.getElementById('alarm-bar').hidden \
           && /server clock/.test(document.getElementById('server-clock').textContent) \
           && /\\d/.test(document.querySelector('.machine-card [data-field=sensors]').textContent);",
        10,
    )
    .await;

    // 70 mm right from 28 to 10 s ago: a deviation warning. The bar shows
    // it within 2 s, and the chime starts.
    post_ndjson(&client, &base, TBM, &readings(-28, -10, 70.0)).await;
    let posted = Instant::now();
    wait_for(
        &browser,
        "the alarm bar with the deviation warning",
        "const bar = document.getElementById('alarm-bar'); \
         const row = document.querySelector('#alarm-list li'); \
         return !bar.hidden && bar.dataset.worst === 'warn' && !!row \
           && /deviation from the design axis/.test(row.textContent) \
           && /WARNING · 1 active alarm · 1 unacknowledged/.test(bar.textContent);",
        2,
    )
    .await;
    let shown_after = posted.elapsed();
    assert!(shown_after < Duration::from_secs(2), "{shown_after:?}");
    wait_for(
        &browser,
        "the chime started",
        "return Number(document.getElementById('alarm-chime').dataset.started || 0) === 1;",
        5,
    )
    .await;
    let state = js(
        &browser,
        &format!(
            "const card = document.querySelector('.machine-card[data-machine=\"{TBM}\"]'); \
             return {{card: card.dataset.alarm, line: card.querySelector('[data-field=alarms]').textContent, \
                      border: getComputedStyle(card).borderTopColor, \
                      warn: getComputedStyle(document.documentElement).getPropertyValue('--warn').trim(), \
                      live: document.getElementById('alarm-summary').getAttribute('aria-live')}};"
        ),
    )
    .await;
    assert_eq!(state["card"], "warn", "{state}");
    assert_eq!(state["line"], "⚠ 1 active alarm", "{state}");
    assert_eq!(state["live"], "assertive", "{state}");
    save_screenshot(&browser, "browser-alarm-bar.png").await;

    // Acknowledged from the bar: off the list, folded into the
    // acknowledged line, stored with the (open access) name.
    browser
        .find(fantoccini::Locator::Css("#alarm-list button.ack"))
        .await
        .expect("an acknowledge button")
        .click()
        .await
        .expect("click");
    wait_for(
        &browser,
        "the alarm acknowledged",
        "const bar = document.getElementById('alarm-bar'); \
         return document.querySelectorAll('#alarm-list li').length === 0 \
           && bar.dataset.worst === 'acked' && !document.getElementById('alarms-acked').hidden \
           && /1 acknowledged, still active/.test(bar.textContent) \
           && /0 unacknowledged/.test(bar.textContent);",
        5,
    )
    .await;
    let stored = common::get_json(&client, &base, "/api/v1/alarms").await;
    assert_eq!(stored["alarms"][0]["acked_by"], "anonymous", "{stored}");

    // The chime toggle is remembered: off, a new alarm (100 mm: the alarm
    // tolerance) rings no more.
    browser
        .find(fantoccini::Locator::Css("#chime-toggle"))
        .await
        .expect("the chime toggle")
        .click()
        .await
        .expect("click");
    browser.refresh().await.expect("reload");
    wait_for(
        &browser,
        "the toggle still off after a reload",
        "return document.getElementById('chime-toggle').getAttribute('aria-pressed') === 'false' \
           && !document.getElementById('alarm-bar').hidden;",
        10,
    )
    .await;
    post_ndjson(&client, &base, TBM, &readings(-9, 3, 130.0)).await;
    wait_for(
        &browser,
        "the deviation alarm listed, silently",
        "const bar = document.getElementById('alarm-bar'); \
         return bar.dataset.worst === 'alarm' && /ALARM/.test(bar.textContent);",
        5,
    )
    .await;
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert_eq!(
        js(
            &browser,
            "return document.getElementById('alarm-chime').dataset.started || '0';"
        )
        .await,
        "0",
        "no chime while it is off"
    );
    assert_clean_console(&browser).await;

    // The server stops: within 5 s the page says so and the clock stops.
    let address = server.address;
    let stopped = Instant::now();
    server.stop().await;
    wait_for(
        &browser,
        "connection lost",
        "const lost = document.getElementById('conn-lost'); \
         return !lost.hidden && /connection lost — data as of \\d\\d:\\d\\d:\\d\\d/.test(lost.textContent) \
           && document.getElementById('server-clock').classList.contains('stopped') \
           && document.querySelector('[data-field=state]').textContent === 'no connection';",
        5,
    )
    .await;
    let lost_after = stopped.elapsed();
    assert!(lost_after < Duration::from_secs(5), "{lost_after:?}");
    eprintln!(
        "alarm bar shown {:.0} ms after the post; connection lost shown {:.0} ms after the server stopped",
        shown_after.as_secs_f64() * 1000.0,
        lost_after.as_secs_f64() * 1000.0
    );
    let clock_text = "return document.getElementById('server-clock').textContent;";
    let clock = js(&browser, clock_text).await;
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert_eq!(clock, js(&browser, clock_text).await, "the clock stopped");
    save_screenshot(&browser, "browser-connection-lost.png").await;

    // The server is back on the same address: the page recovers (every
    // link reconnects, the banner goes, the clock runs, the alarms return).
    let server = common::TestServer::start_at(dir.path(), address).await;
    wait_for(
        &browser,
        "the page live again",
        "return document.getElementById('conn-lost').hidden \
           && !document.getElementById('server-clock').classList.contains('stopped') \
           && !document.body.classList.contains('offline') \
           && document.getElementById('alarm-bar').dataset.worst === 'alarm';",
        20,
    )
    .await;
    let clock = js(&browser, clock_text).await;
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert_ne!(
        clock,
        js(&browser, clock_text).await,
        "the clock runs again"
    );
    // Only the browser's own notes on the refused connections meanwhile.
    assert_console_clean_but(
        &browser,
        &["ERR_CONNECTION_REFUSED", "WebSocket connection to"],
    )
    .await;
    browser.close().await.ok();
    server.stop().await;
}

/// The API docs page: the bundled Swagger UI draws every operation of the
/// server's OpenAPI document, and "Try it out" on `GET /healthz` gets its
/// answer from the server.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_api_docs_page_draws_every_operation_and_tries_one() {
    let Some((driver_program, chromium)) = browser_programs() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let server = common::TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let document = common::get_json(&client, &base, "/api/v1/openapi.json").await;
    let operations: usize = document["paths"]
        .as_object()
        .unwrap()
        .values()
        .map(|item| item.as_object().unwrap().len())
        .sum();
    // Every operation the document holds (tests/openapi.rs counts them).
    assert!(operations > 20, "{operations} operations");

    let driver = Driver::start(&driver_program);
    let browser = connect(&driver, chromium.as_deref()).await;
    browser
        .goto(&format!("{base}/api/docs"))
        .await
        .expect("page loads");
    wait_for(
        &browser,
        "every operation drawn",
        &format!("return document.querySelectorAll('.opblock').length === {operations};"),
        20,
    )
    .await;
    let title = js(
        &browser,
        "return document.querySelector('.info .title')?.textContent;",
    )
    .await;
    assert!(title.as_str().unwrap().starts_with("tunnelnav"), "{title}");
    // Open GET /healthz, try it out, execute.
    js(
        &browser,
        "document.querySelector('#operations-service-healthz .opblock-summary-control').click(); \
         return true;",
    )
    .await;
    wait_for(
        &browser,
        "the try-out button",
        "return !!document.querySelector('#operations-service-healthz .try-out__btn');",
        10,
    )
    .await;
    js(
        &browser,
        "document.querySelector('#operations-service-healthz .try-out__btn').click(); return true;",
    )
    .await;
    wait_for(
        &browser,
        "the execute button",
        "return !!document.querySelector('#operations-service-healthz .execute');",
        10,
    )
    .await;
    js(
        &browser,
        "document.querySelector('#operations-service-healthz .execute').click(); return true;",
    )
    .await;
    wait_for(
        &browser,
        "the server's answer",
        "const live = document.querySelector('#operations-service-healthz .live-responses-table'); \
         return !!live && live.textContent.includes('200') && live.textContent.includes('\"ok\"');",
        10,
    )
    .await;
    save_screenshot(&browser, "browser-api-docs.png").await;
    assert_clean_console(&browser).await;
    browser.close().await.unwrap();
    server.stop().await;
}

/// An office's fleet page (issue 38): its own machines, then each site's
/// under the site's link, which goes down when the site falls silent.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_office_fleet_page_shows_each_sites_machines_under_its_link() {
    let Some((driver_program, chromium)) = browser_programs() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let server = common::TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    common::put_machine(&client, &base, "own-tbm").await;
    // Site `north` forwards its machine `tbm`: the declaration with its
    // engines' state, then readings.
    let spec = serde_json::from_value::<tunnelnav::config::MachineDeclaration>(
        json!({"name": "North TBM", "engines": {"attitude": {}}}),
    )
    .unwrap()
    .validate("tbm")
    .unwrap();
    let snapshot = tunnelnav::machine::MachineCore::new(&spec)
        .unwrap()
        .snapshot();
    let now = tunnelnav::clock::wall_clock_s().floor();
    let readings: Vec<Value> = (0..20)
        .map(|i| json!({"t": now - 20.0 + f64::from(i), "sensor": "inclinometer", "pitch_deg": 0.1, "roll_deg": 0.2}))
        .collect();
    let forwarded = json!({"site": "north", "after": null, "items": [
        {"sequence": 1, "machine": {"spec": spec, "snapshot": snapshot}},
        {"sequence": 2, "readings": readings}
    ]});
    let answer = client
        .post(format!("{base}/api/v1/machines/north.tbm/forward"))
        .header("content-type", "application/json")
        .body(forwarded.to_string())
        .send()
        .await
        .unwrap();
    assert_eq!(answer.status(), 200);
    let answer: Value = serde_json::from_slice(&answer.bytes().await.unwrap()).unwrap();
    assert_eq!(answer["applied"], 2);
    let report = json!({"backlog_items": 3, "backlog_readings": 1500, "oldest_unsent_s": 42.0});
    let reported = client
        .put(format!("{base}/api/v1/sites/north"))
        .header("content-type", "application/json")
        .body(report.to_string())
        .send()
        .await
        .unwrap();
    assert_eq!(reported.status(), 200);

    let driver = Driver::start(&driver_program);
    let browser = connect(&driver, chromium.as_deref()).await;
    browser
        .goto(&format!("{base}/"))
        .await
        .expect("fleet loads");
    wait_for(
        &browser,
        "the site's group under its link",
        "const group = document.querySelector('.site-group[data-site=\"north\"]'); \
         if (!group) return false; \
         const link = group.querySelector('[data-site-field=link]').textContent; \
         const backlog = group.querySelector('[data-site-field=backlog]').textContent; \
         const own = document.querySelector('.site-group:not([data-site]) .machine-card'); \
         return link === 'link up' && /1,500 readings unsent, oldest/.test(backlog) \
           && !!group.querySelector('.machine-card[data-machine=\"north.tbm\"]') \
           && !!own && own.dataset.machine === 'own-tbm' \
           && /\\d/.test(group.querySelector('.machine-card [data-field=sensors]').textContent);",
        10,
    )
    .await;
    save_screenshot(&browser, "browser-office-fleet.png").await;
    // The site falls silent: after 10 s the page says its link is down.
    wait_for(
        &browser,
        "the site's link down",
        "const link = document.querySelector('.site-group[data-site=\"north\"] [data-site-field=link]'); \
         return link.textContent === 'LINK DOWN' && link.classList.contains('bad');",
        20,
    )
    .await;
    assert_clean_console(&browser).await;
    browser.close().await.unwrap();
    server.stop().await;
}

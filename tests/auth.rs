//! Access tokens end to end: `tunnelnav token` creates, lists and revokes
//! them in a server's database; the server (the real binary) then demands
//! them: 401 without or with an unknown token, 403 with the wrong scope or
//! machine, JSON either way; the dashboard signs in with a cookie (never a
//! token in a URL); beyond loopback a server without tokens refuses to
//! start unless told to serve openly.

mod common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use common::ServerProcess;
use futures_util::StreamExt;
use serde_json::Value;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

fn tunnelnav() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
}

/// `tunnelnav token create ...`: the printed token.
fn create(dir: &Path, args: &[&str]) -> String {
    let out = tunnelnav()
        .args(["token", "create", "--data-dir"])
        .arg(dir)
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap().trim().to_string()
}

const READING: &str =
    r#"{"t": 1772431200, "sensor": "inclinometer", "pitch_deg": 0.5, "roll_deg": 1.0}"#;
const DECLARATION: &str = r#"{"name": "TBM", "engines": {"attitude": {}}}"#;

async fn call(
    client: &reqwest::Client,
    method: reqwest::Method,
    url: String,
    token: Option<&str>,
    body: Option<&str>,
) -> (u16, Value) {
    let mut request = client.request(method, &url);
    if let Some(token) = token {
        request = request.bearer_auth(token);
    }
    if let Some(body) = body {
        request = request.body(body.to_string());
    }
    let response = request.send().await.unwrap();
    let status = response.status().as_u16();
    let bytes = response.bytes().await.unwrap();
    (
        status,
        serde_json::from_slice(&bytes).unwrap_or(Value::Null),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_gate_every_route_by_scope_and_machine() {
    let dir = tempfile::tempdir().unwrap();
    let admin = create(dir.path(), &["--scope", "admin", "--name", "site office"]);
    let reader = create(dir.path(), &["--scope", "read"]);
    let gateway = create(dir.path(), &["--scope", "ingest", "--machine", "tbm-1"]);
    let operator = create(
        dir.path(),
        &["--scope", "operator", "--name", "night shift"],
    );
    assert!(admin.starts_with("tnv_") && admin != reader && reader != gateway);
    let db = std::fs::read(dir.path().join("tunnelnav.sqlite3")).unwrap();
    assert!(
        !db.windows(gateway.len()).any(|w| w == gateway.as_bytes()),
        "the token itself is not stored"
    );

    let server = ServerProcess::start(dir.path());
    let client = reqwest::Client::new();
    use reqwest::Method;
    let machine = |path: &str| server.url(&format!("/api/v1/machines/{path}"));

    // Missing and unknown tokens: 401 with a JSON body saying so.
    let (status, body) = call(
        &client,
        Method::GET,
        server.url("/api/v1/machines"),
        None,
        None,
    )
    .await;
    assert_eq!(status, 401, "{body}");
    assert!(
        body["error"]
            .as_str()
            .unwrap()
            .contains("token is required"),
        "{body}"
    );
    let (status, body) = call(
        &client,
        Method::GET,
        server.url("/api/v1/machines"),
        Some("tnv_0000"),
        None,
    )
    .await;
    assert_eq!(status, 401, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains("not valid"),
        "{body}"
    );
    // Liveness needs nothing.
    assert_eq!(
        call(&client, Method::GET, server.url("/healthz"), None, None)
            .await
            .0,
        200
    );

    // Declaring machines: admin only.
    for m in ["tbm-1", "tbm-2"] {
        let (status, body) = call(
            &client,
            Method::PUT,
            machine(m),
            Some(&reader),
            Some(DECLARATION),
        )
        .await;
        assert_eq!(status, 403, "{body}");
        assert!(
            body["error"]
                .as_str()
                .unwrap()
                .contains("admin scope needed"),
            "{body}"
        );
        let (status, body) = call(
            &client,
            Method::PUT,
            machine(m),
            Some(&admin),
            Some(DECLARATION),
        )
        .await;
        assert!(status == 201 || status == 200, "{status} {body}");
    }

    // Ingest: the gateway's own machine only; readers cannot post.
    let (status, body) = call(
        &client,
        Method::POST,
        machine("tbm-1/readings"),
        Some(&gateway),
        Some(READING),
    )
    .await;
    assert_eq!(status, 200, "{body}");
    assert_eq!(body["accepted"], 1);
    let (status, body) = call(
        &client,
        Method::POST,
        machine("tbm-2/readings"),
        Some(&gateway),
        Some(READING),
    )
    .await;
    assert_eq!(status, 403, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains("machine `tbm-2`"),
        "{body}"
    );
    let (status, _) = call(
        &client,
        Method::POST,
        machine("tbm-1/readings"),
        Some(&reader),
        Some(READING),
    )
    .await;
    assert_eq!(status, 403);
    // A gateway cannot read.
    let (status, _) = call(&client, Method::GET, machine("tbm-1"), Some(&gateway), None).await;
    assert_eq!(status, 403);
    // Readers and admins read.
    for token in [&reader, &admin] {
        let (status, body) = call(&client, Method::GET, machine("tbm-1"), Some(token), None).await;
        assert_eq!(status, 200, "{body}");
        let (status, _) = call(
            &client,
            Method::GET,
            server.url("/metrics"),
            Some(token),
            None,
        )
        .await;
        assert_eq!(status, 200);
    }

    // Every route declares what it needs: nothing, read, the ingest of its
    // own machine, or admin. Without a token, 401 where it needs anything;
    // with a token of the wrong scope, 403; with the right one, past the
    // gate (whatever the route then answers).
    let routes = [
        (Method::GET, "/", "read"),
        (Method::GET, "/machines/tbm-1", "read"),
        (Method::GET, "/static/app.css", "nothing"),
        (Method::GET, "/healthz", "nothing"),
        (Method::GET, "/login", "nothing"),
        (Method::GET, "/metrics", "read"),
        (Method::GET, "/api/v1/machines", "read"),
        (Method::GET, "/api/v1/machines/tbm-1", "read"),
        (Method::PUT, "/api/v1/machines/tbm-1", "admin"),
        (Method::GET, "/api/v1/machines/tbm-1/readings", "read"),
        (Method::POST, "/api/v1/machines/tbm-1/readings", "ingest"),
        (Method::GET, "/api/v1/machines/tbm-1/ingest", "ingest"),
        (Method::GET, "/api/v1/machines/tbm-1/live", "read"),
        (Method::GET, "/api/v1/machines/tbm-1/estimates", "read"),
        (Method::GET, "/api/v1/machines/tbm-1/model", "read"),
        (Method::GET, "/api/v1/machines/tbm-1/alignment", "read"),
        (Method::PUT, "/api/v1/machines/tbm-1/alignment", "admin"),
        (Method::GET, "/api/v1/machines/tbm-1/alignment/axis", "read"),
        (Method::GET, "/api/v1/alarms", "read"),
        (Method::GET, "/api/v1/alarms/live", "read"),
        (Method::POST, "/api/v1/alarms/1/ack", "operator"),
        (Method::GET, "/nowhere", "read"),
        (Method::DELETE, "/api/v1/machines/tbm-1", "read"),
    ];
    for (method, path, need) in routes {
        let url = server.url(path);
        let anonymous = call(&client, method.clone(), url.clone(), None, None)
            .await
            .0;
        let as_reader = call(&client, method.clone(), url.clone(), Some(&reader), None)
            .await
            .0;
        let as_gateway = call(&client, method.clone(), url.clone(), Some(&gateway), None)
            .await
            .0;
        let (past, gated) = (|s: u16| s != 401 && s != 403, |s: u16| s == 403);
        let what = format!("{method} {path} needs {need}: {anonymous} {as_reader} {as_gateway}");
        match need {
            "nothing" => assert!(
                past(anonymous) && past(as_reader) && past(as_gateway),
                "{what}"
            ),
            "read" => assert!(
                anonymous == 401 && past(as_reader) && gated(as_gateway),
                "{what}"
            ),
            "ingest" => assert!(
                anonymous == 401 && gated(as_reader) && past(as_gateway),
                "{what}"
            ),
            _ => assert!(
                anonymous == 401 && gated(as_reader) && gated(as_gateway),
                "{what}"
            ),
        }
    }

    // An operator reads and acknowledges (past the gate: alarm 1 does not
    // exist), and does nothing else.
    for (method, path, past_gate) in [
        (Method::GET, "/api/v1/machines/tbm-1", true),
        (Method::POST, "/api/v1/alarms/1/ack", true),
        (Method::PUT, "/api/v1/machines/tbm-1", false),
        (Method::POST, "/api/v1/machines/tbm-1/readings", false),
    ] {
        let (status, body) = call(
            &client,
            method.clone(),
            server.url(path),
            Some(&operator),
            None,
        )
        .await;
        assert_eq!(status != 403, past_gate, "{method} {path}: {status} {body}");
    }

    // The ingest WebSocket takes the bearer header too; without it, 401.
    let url = server
        .url("/api/v1/machines/tbm-1/ingest")
        .replace("http://", "ws://");
    assert!(
        tokio_tungstenite::connect_async(url.as_str())
            .await
            .is_err()
    );
    let mut request = url.as_str().into_client_request().unwrap();
    request.headers_mut().insert(
        "authorization",
        format!("Bearer {gateway}").parse().unwrap(),
    );
    let (mut socket, _) = tokio_tungstenite::connect_async(request).await.unwrap();
    use futures_util::SinkExt;
    socket
        .send(tokio_tungstenite::tungstenite::Message::text(
            r#"{"t": 1772431201, "sensor": "inclinometer", "pitch_deg": 0.5, "roll_deg": 1.0}"#,
        ))
        .await
        .unwrap();
    let ack = socket.next().await.unwrap().unwrap();
    assert!(ack.to_text().unwrap().contains("\"accepted\":1"), "{ack}");

    // Revoked: refused within the server's 2 s reread.
    let out = tunnelnav()
        .args(["token", "list", "--data-dir"])
        .arg(dir.path())
        .output()
        .unwrap();
    let list = String::from_utf8(out.stdout).unwrap();
    assert!(
        list.contains("site office") && !list.contains(&reader),
        "{list}"
    );
    let reader_id = list
        .lines()
        .find(|l| l.contains(" read "))
        .and_then(|l| l.split_whitespace().next())
        .unwrap()
        .to_string();
    let status = tunnelnav()
        .args(["token", "revoke", "--data-dir"])
        .arg(dir.path())
        .arg(&reader_id)
        .status()
        .unwrap();
    assert!(status.success());
    tokio::time::sleep(Duration::from_millis(2500)).await;
    let (status, _) = call(&client, Method::GET, machine("tbm-1"), Some(&reader), None).await;
    assert_eq!(status, 401);
    server.terminate();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_dashboard_signs_in_with_a_cookie_not_a_url() {
    let dir = tempfile::tempdir().unwrap();
    let reader = create(dir.path(), &["--scope", "read"]);
    let server = ServerProcess::start(dir.path());
    let client = reqwest::Client::builder()
        .redirect(reqwest::redirect::Policy::none())
        .build()
        .unwrap();

    // A page without a token goes to the login form.
    let response = client
        .get(server.url("/"))
        .header("accept", "text/html")
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 303);
    assert_eq!(response.headers()["location"], "/login");
    let form = client.get(server.url("/login")).send().await.unwrap();
    assert_eq!(form.status(), 200);
    assert!(form.text().await.unwrap().contains("method=\"post\""));

    // A wrong token is refused; the right one sets an HttpOnly cookie.
    let refused = client
        .post(server.url("/login"))
        .header("content-type", "application/x-www-form-urlencoded")
        .body("token=tnv_nope")
        .send()
        .await
        .unwrap();
    assert_eq!(refused.status(), 401);
    let signed_in = client
        .post(server.url("/login"))
        .header("content-type", "application/x-www-form-urlencoded")
        .body(format!("token={reader}"))
        .send()
        .await
        .unwrap();
    assert_eq!(signed_in.status(), 303);
    let cookie = signed_in.headers()["set-cookie"]
        .to_str()
        .unwrap()
        .to_string();
    assert!(
        cookie.contains("HttpOnly") && cookie.contains("SameSite=Strict"),
        "{cookie}"
    );
    let pair = cookie.split(';').next().unwrap().to_string();
    let page = client
        .get(server.url("/"))
        .header("cookie", &pair)
        .header("accept", "text/html")
        .send()
        .await
        .unwrap();
    assert_eq!(page.status(), 200);

    // The live socket authenticates with the same cookie.
    let url = server
        .url("/api/v1/machines/nope/live")
        .replace("http://", "ws://");
    let mut request = url.as_str().into_client_request().unwrap();
    request
        .headers_mut()
        .insert("cookie", pair.parse().unwrap());
    match tokio_tungstenite::connect_async(request).await {
        // Past the gate: the unknown machine answers 404, not 401.
        Err(tokio_tungstenite::tungstenite::Error::Http(response)) => {
            assert_eq!(response.status(), 404)
        }
        other => panic!("expected a 404 for an unknown machine: {other:?}"),
    }
    server.terminate();
}

/// `serve` with `args`, started: the child and its first stdout line.
fn serve(args: &[&str], dir: &Path, stderr: Stdio) -> (std::process::Child, String) {
    let mut child = tunnelnav()
        .arg("serve")
        .args(args)
        .arg("--data-dir")
        .arg(dir)
        .stdout(Stdio::piped())
        .stderr(stderr)
        .spawn()
        .unwrap();
    let mut first = String::new();
    std::io::BufRead::read_line(
        &mut std::io::BufReader::new(child.stdout.take().unwrap()),
        &mut first,
    )
    .unwrap();
    (child, first)
}

#[test]
fn beyond_loopback_a_server_without_tokens_refuses_to_start() {
    let dir = tempfile::tempdir().unwrap();
    let out = tunnelnav()
        .args(["serve", "--listen", "0.0.0.0:0", "--data-dir"])
        .arg(dir.path())
        .stdout(Stdio::null())
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert!(
        stderr.contains("refusing to serve on 0.0.0.0:0 without access tokens"),
        "{stderr}"
    );
    assert!(stderr.contains("--allow-no-auth"), "{stderr}");

    // With the override it starts, and says so.
    let (mut child, first) = serve(
        &["--listen", "0.0.0.0:0", "--allow-no-auth"],
        dir.path(),
        Stdio::piped(),
    );
    assert!(first.starts_with("listening on http://0.0.0.0:"), "{first}");
    child.kill().unwrap();
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert!(
        stderr.contains("WARNING: serving on 0.0.0.0:0 without access tokens"),
        "{stderr}"
    );

    // With a token it starts without the override.
    create(dir.path(), &["--scope", "admin"]);
    let (mut child, first) = serve(&["--listen", "0.0.0.0:0"], dir.path(), Stdio::null());
    assert!(first.starts_with("listening on"), "{first}");
    child.kill().unwrap();
    child.wait().unwrap();
}

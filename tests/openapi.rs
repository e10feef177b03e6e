//! The OpenAPI document: what `GET /api/v1/openapi.json` serves, that
//! docs/api.md lists the same operations, the bundled docs page, and
//! schemathesis run against a real server with it (every operation,
//! positive and negative cases, every check; `tests/schemathesis.toml`).
//! schemathesis comes from PyPI (`.ci/run` installs it in a venv and sets
//! `TUNNELNAV_SCHEMATHESIS` to it); without it that test is skipped,
//! saying so, unless `TUNNELNAV_SCHEMATHESIS_TEST=required` (CI).

mod common;

use std::collections::BTreeSet;
use std::process::Command;

use common::{ServerProcess, TestServer, declare_machine, post_ndjson};
use serde_json::{Value, json};
use tunnelnav::clock::wall_clock_s;

const METHODS: [&str; 5] = ["get", "put", "post", "delete", "patch"];

/// `METHOD path` of every operation in the document.
fn operations(document: &Value) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    for (path, item) in document["paths"].as_object().unwrap() {
        for method in METHODS {
            if item.get(method).is_some() {
                found.insert(format!("{} {path}", method.to_uppercase()));
            }
        }
    }
    found
}

/// `METHOD path` of every operation named in a code span of the first
/// cell of the table under `heading` in `file` (the query string left off).
fn tabled_operations(file: &str, heading: &str) -> BTreeSet<String> {
    let text = std::fs::read_to_string(file).unwrap();
    let table = text
        .split(heading)
        .nth(1)
        .unwrap_or_else(|| panic!("{file} has `{heading}`"));
    table
        .lines()
        .skip_while(|line| !line.starts_with('|'))
        .take_while(|line| line.starts_with('|'))
        .filter_map(|line| line.split('|').nth(1))
        .flat_map(|cell| cell.split('`').skip(1).step_by(2))
        .filter_map(|code| {
            let (method, path) = code.split_once(' ')?;
            let path = path.split('?').next()?;
            METHODS
                .contains(&method.to_lowercase().as_str())
                .then(|| format!("{method} {path}"))
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_document_describes_every_operation_and_the_docs_list_them() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let response = client
        .get(server.url("/api/v1/openapi.json"))
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200);
    assert_eq!(response.headers()["content-type"], "application/json");
    let document: Value = serde_json::from_slice(&response.bytes().await.unwrap()).unwrap();
    assert_eq!(document["openapi"], "3.1.0");
    assert_eq!(document["info"]["version"], env!("CARGO_PKG_VERSION"));
    let schemes = &document["components"]["securitySchemes"];
    assert_eq!(schemes["bearer"]["scheme"], "bearer");
    assert_eq!(schemes["session"]["in"], "cookie");
    assert_eq!(schemes["session"]["name"], "tunnelnav_token");

    let found = operations(&document);
    let ids: Vec<&str> = document["paths"]
        .as_object()
        .unwrap()
        .values()
        .flat_map(|item| METHODS.iter().filter_map(|m| item.get(*m)))
        .map(|operation| operation["operationId"].as_str().unwrap())
        .collect();
    let unique: BTreeSet<&str> = ids.iter().copied().collect();
    assert_eq!(unique.len(), ids.len(), "operation ids repeat: {ids:?}");
    assert_eq!(found.len(), 30, "{found:#?}");
    for (path, item) in document["paths"].as_object().unwrap() {
        for method in METHODS {
            let Some(operation) = item.get(method) else {
                continue;
            };
            let responses = operation["responses"].as_object().unwrap();
            let answers = |status: &str| responses.contains_key(status);
            assert!(
                answers("200") || answers("201") || answers("101"),
                "{method} {path}"
            );
            // Every error answer is the error body (a page's own 404 is a
            // page).
            for (status, response) in responses {
                let page = response["content"].get("text/html").is_some();
                if (status.starts_with('4') || status.starts_with('5')) && !page {
                    assert_eq!(
                        response["content"]["application/json"]["schema"]["$ref"],
                        "#/components/schemas/ErrorBody",
                        "{method} {path} {status}"
                    );
                }
            }
            assert!(answers("503"), "{method} {path}");
            let secured = operation.get("security").is_some();
            assert_eq!(answers("401"), secured, "{method} {path}");
            // Only liveness and this document are open to all.
            assert_eq!(
                !secured,
                ["/healthz", "/api/v1/openapi.json"].contains(&path.as_str()),
                "{method} {path}"
            );
            if path.contains("{machine}") {
                assert!(answers("404"), "{method} {path}");
            }
        }
    }
    // The roles are the ones the router checks.
    let role = |method: &str, path: &str| {
        document["paths"][path][method]["security"][0]["bearer"][0]
            .as_str()
            .unwrap()
            .to_string()
    };
    assert_eq!(role("put", "/api/v1/machines/{machine}"), "admin");
    assert_eq!(
        role("post", "/api/v1/machines/{machine}/readings"),
        "ingest"
    );
    assert_eq!(role("get", "/api/v1/machines/{machine}/readings"), "read");
    assert_eq!(role("post", "/api/v1/alarms/{id}/ack"), "operator");

    // A reading's schema holds the validator's bounds.
    let reading = &document["components"]["schemas"]["Reading"];
    let laser = &reading["oneOf"][0];
    assert_eq!(laser["properties"]["sensor"]["enum"], json!(["laser"]));
    assert_eq!(laser["properties"]["pitch_deg"]["maximum"], 90.0);

    // docs/api.md lists the same operations.
    assert_eq!(tabled_operations("docs/api.md", "### Operations"), found);
    // Every operation of the contract (docs/protocol.md) is in it.
    let contract = tabled_operations("docs/protocol.md", "## HTTP API (v1)");
    assert!(contract.len() >= 10, "{contract:?}");
    for operation in &contract {
        assert!(
            found.contains(operation),
            "{operation} is not in the document"
        );
    }

    // The docs page draws the document with the bundled Swagger UI.
    let page = common::get_text(&client, &server.url(""), "/api/docs").await;
    assert!(page.contains("/static/vendor/swagger-ui/swagger-ui-bundle.js"));
    for asset in [
        "/static/vendor/swagger-ui/swagger-ui-bundle.js",
        "/static/vendor/swagger-ui/swagger-ui.css",
        "/static/api-docs.js",
    ] {
        let response = client.get(server.url(asset)).send().await.unwrap();
        assert_eq!(response.status(), 200, "{asset}");
    }
    server.stop().await;
}

/// The schemathesis command, or `None` (saying so) where it is not
/// installed and not required.
fn schemathesis() -> Option<String> {
    let program = std::env::var("TUNNELNAV_SCHEMATHESIS").unwrap_or_else(|_| "schemathesis".into());
    match Command::new(&program).arg("--version").output() {
        Ok(output) if output.status.success() => Some(program),
        outcome => {
            assert!(
                std::env::var("TUNNELNAV_SCHEMATHESIS_TEST").as_deref() != Ok("required"),
                "TUNNELNAV_SCHEMATHESIS_TEST=required but `{program} --version` fails ({outcome:?}); \
                 pip install schemathesis and set TUNNELNAV_SCHEMATHESIS"
            );
            eprintln!(
                "SKIPPED: schemathesis not found (`{program}`); pip install schemathesis \
                 and set TUNNELNAV_SCHEMATHESIS to run this test"
            );
            None
        }
    }
}

/// A machine on a straight axis, with a deviation alarm raised (so that
/// the alarm and alignment operations have something to find), and an
/// INS machine.
async fn prepare(client: &reqwest::Client, base: &str) {
    let declaration = common::on_an_axis("TBM north");
    declare_machine(client, base, "tbm-north", &declaration.to_string()).await;
    // 42 s 70 mm off the axis, ending 18 s ago: a deviation warning.
    let from_t = (wall_clock_s() - 60.0).floor();
    let lines = common::laser_pairs(from_t, 21, 0.07);
    post_ndjson(client, base, "tbm-north", &lines).await;
    // And an INS machine, so that the status's latest estimates hold every
    // engine's (and are checked against their schemas).
    declare_machine(
        client,
        base,
        "van-1",
        &json!({"engines": {"zupt": {}, "fuzzy": {}}}).to_string(),
    )
    .await;
    let still: Vec<String> = (0..500)
        .flat_map(|i| {
            let t = from_t + 0.01 * f64::from(i);
            let mut lines = vec![json!({"t": t, "sensor": "imu",
                "accel_mps2": [0.0, 0.0, -9.81], "gyro_dps": [0.0, 0.0, 0.0]})];
            if i % 10 == 0 {
                lines
                    .push(json!({"t": t, "sensor": "magnetometer", "field_ut": [20.0, 0.0, 40.0]}));
            }
            lines
        })
        .map(|reading| reading.to_string())
        .collect();
    post_ndjson(client, base, "van-1", &still).await;
    for _ in 0..100 {
        let alarms = common::get_json(client, base, "/api/v1/alarms").await;
        if alarms["alarms"].as_array().is_some_and(|a| !a.is_empty()) {
            return;
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
    panic!("no alarm was raised");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn schemathesis_finds_no_failure_and_no_server_error() {
    let Some(program) = schemathesis() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let server = ServerProcess::start(dir.path());
    let client = reqwest::Client::new();
    let base = server.url("");
    // Open while preparing; then an admin token closes it, so the
    // authentication checks have something to check.
    prepare(&client, &base).await;
    let document = common::get_json(&client, &base, "/api/v1/openapi.json").await;
    let declared = operations(&document).len();
    let created = Command::new(env!("CARGO_BIN_EXE_tunnelnav"))
        .args([
            "token",
            "create",
            "--scope",
            "admin",
            "--name",
            "schemathesis",
            "--data-dir",
        ])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(created.status.success());
    let token = String::from_utf8(created.stdout)
        .unwrap()
        .trim()
        .to_string();
    // The server rereads its tokens every 2 s.
    for _ in 0..50 {
        let status = client
            .get(server.url("/api/v1/machines"))
            .send()
            .await
            .unwrap()
            .status();
        if status == 401 {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }

    // Its cache (of crashes to replay) goes with the test's directory.
    let output = Command::new(&program)
        .current_dir(dir.path())
        .arg("--config-file")
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/schemathesis.toml"
        ))
        .args(["--no-color", "run"])
        .arg(server.url("/api/v1/openapi.json"))
        // One worker: with two, hypothesis's threads share CPython 3.11's
        // AST recursion counter (CPython gh-106905) and it fails spuriously
        // with "AST constructor recursion depth mismatch".
        .args(["--checks", "all", "--max-examples", "60", "--workers", "1"])
        .args(["--header", &format!("Authorization: Bearer {token}")])
        .output()
        .unwrap();
    let report = String::from_utf8_lossy(&output.stdout);
    println!("{report}");
    eprintln!("{}", String::from_utf8_lossy(&output.stderr));
    assert!(
        output.status.success(),
        "schemathesis found failures (above)"
    );
    // As many operations tested as the document declares (not a count
    // written here, which a new route would silently outdate).
    assert!(
        report.contains(&format!("Tested: {declared}\n")),
        "every one of the {declared} operations tested"
    );
    // Nothing the server answered was a 5xx.
    assert!(!report.contains("Server error"), "a server error (above)");
}

//! Issue 57: security headers on every answer, no inline script in any
//! page (the Content-Security-Policy allows none), and errors the framework
//! answers (a path that is not UTF-8) in JSON like every other error.

mod common;

use common::{TestServer, declare_machine};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pages_carry_the_security_headers_and_no_inline_script() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    declare_machine(
        &client,
        &base,
        "tbm-1",
        &common::on_an_axis("TBM").to_string(),
    )
    .await;
    for path in [
        "/",
        "/machines/tbm-1",
        "/api/docs",
        "/api/v1/machines/tbm-1/report?format=html",
        "/api/v1/machines",
        "/static/app.css",
    ] {
        let response = client.get(format!("{base}{path}")).send().await.unwrap();
        assert_eq!(response.status(), 200, "{path}");
        let headers = response.headers().clone();
        let csp = headers["content-security-policy"].to_str().unwrap();
        assert!(
            csp.contains("script-src 'self'") && !csp.contains("script-src 'self' 'unsafe"),
            "{path}: {csp}"
        );
        assert!(csp.contains("frame-ancestors 'none'"), "{path}: {csp}");
        assert_eq!(headers["x-content-type-options"], "nosniff", "{path}");
        assert_eq!(headers["x-frame-options"], "DENY", "{path}");
        assert_eq!(headers["referrer-policy"], "same-origin", "{path}");
        let body = response.text().await.unwrap();
        // Every script a page has is a file of the service's own.
        for script in body.split("<script").skip(1) {
            let tag = script.split('>').next().unwrap();
            assert!(
                tag.contains("src=\"/static/"),
                "{path}: an inline script <script{tag}>"
            );
            assert!(
                !body.contains(" onclick=") && !body.contains(" onload="),
                "{path}"
            );
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_path_that_is_not_utf8_is_answered_in_json() {
    let dir = tempfile::tempdir().unwrap();
    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    let response = client
        .get(format!("{base}/api/v1/machines/%FF%FE"))
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 400);
    assert!(
        response.headers()["content-type"]
            .to_str()
            .unwrap()
            .starts_with("application/json")
    );
    let body: serde_json::Value = serde_json::from_slice(&response.bytes().await.unwrap()).unwrap();
    assert!(
        body["error"]
            .as_str()
            .is_some_and(|e| e.to_lowercase().contains("utf-8")),
        "{body}"
    );
}

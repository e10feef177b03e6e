//! Issue 54, item 8: readings that share a timestamp (a PLC or gateway
//! cycle stamps its sensors alike) are fused in arrival order, live, in a
//! replay of the posted lines, in a replay of the readings API's export,
//! and after a restart.

mod common;

use common::{
    TestServer, all_estimates, exported_readings, post_ndjson, put_machine, reading_key, replay,
};
use serde_json::Value;

/// A TBM drive whose every laser sample is stamped with the time of the
/// inclinometer reading before it; posted one reading a request, the
/// laser after its inclinometer on even samples and before it on odd
/// ones.
fn tied_posts() -> Vec<String> {
    let lines = common::drive(0.25, 7, Vec::new());
    let mut posts: Vec<String> = Vec::new();
    let mut last_incl: Option<usize> = None;
    let mut lasers = 0;
    for line in lines {
        let mut v: Value = serde_json::from_str(&line).unwrap();
        match v["sensor"].as_str().unwrap() {
            "inclinometer" => {
                last_incl = Some(posts.len());
                posts.push(line);
            }
            "laser" => {
                let Some(at) = last_incl else { continue };
                let incl: Value = serde_json::from_str(&posts[at]).unwrap();
                v["t"] = incl["t"].clone();
                let tied = v.to_string();
                if lasers % 2 == 0 {
                    posts.push(tied);
                } else {
                    posts.insert(at, tied);
                }
                lasers += 1;
                last_incl = None;
            }
            _ => posts.push(line),
        }
    }
    assert!(lasers >= 5, "{lasers} laser samples");
    posts
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn readings_sharing_a_time_are_fused_in_arrival_order_everywhere() {
    let dir = tempfile::tempdir().unwrap();
    let posts = tied_posts();
    let (first, second) = posts.split_at(posts.len() / 2);

    let server = TestServer::start(dir.path()).await;
    let client = reqwest::Client::new();
    let base = server.url("");
    put_machine(&client, &base, "tbm-ties").await;
    for line in first {
        post_ndjson(&client, &base, "tbm-ties", std::slice::from_ref(line)).await;
    }
    server.stop().await;
    // After a restart the machine continues from its snapshot and the
    // readings stored after it, in the order they were stored.
    let server = TestServer::start(dir.path()).await;
    let base = server.url("");
    for line in second {
        post_ndjson(&client, &base, "tbm-ties", std::slice::from_ref(line)).await;
    }

    let live = all_estimates(&client, &base, "tbm-ties").await;
    let exported = exported_readings(&client, &base, "tbm-ties").await;
    server.stop().await;
    assert_eq!(exported.len(), posts.len());
    // The export keeps arrival order within a time: the posts, sorted by
    // time alone (a stable sort), are the export.
    let mut by_time: Vec<(f64, String)> = posts
        .iter()
        .map(|l| {
            let v: Value = serde_json::from_str(l).unwrap();
            (v["t"].as_f64().unwrap(), l.clone())
        })
        .collect();
    by_time.sort_by(|a, b| a.0.total_cmp(&b.0));
    let keys =
        |lines: &[String]| -> Vec<(u64, String)> { lines.iter().map(|l| reading_key(l)).collect() };
    let sorted: Vec<String> = by_time.into_iter().map(|(_, l)| l).collect();
    assert_eq!(keys(&exported), keys(&sorted));

    let from_posts = replay("tbm-ties", &posts);
    let from_export = replay("tbm-ties", &exported);
    assert_eq!(live.len(), from_posts.len());
    // Some estimates are made at a laser's time, before or after it.
    let laser_ok = |e: &[Value]| e.iter().filter(|x| x["laser_ok"] == true).count();
    assert!(laser_ok(&live) > 0);
    for (i, ((a, b), c)) in live.iter().zip(&from_posts).zip(&from_export).enumerate() {
        assert_eq!(a, b, "estimate {i}: live against a replay of the posts");
        assert_eq!(a, c, "estimate {i}: live against a replay of the export");
    }
}

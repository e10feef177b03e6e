//! Sites forwarding to an office through cut links and SIGKILLs (issue
//! 38), all real processes: two site servers, each reaching the office
//! through a TCP relay of this test that cuts the line (closing every
//! connection, or swallowing them unanswered) three times for 3–6 s, each
//! site SIGKILLed twice and the office once, while gateways post to the
//! sites and resend what was not acknowledged. Then the office holds
//! every reading each site stored exactly once and in the site's order,
//! the same estimates (max difference 0) and the same alarms.

mod common;

use std::net::SocketAddr;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::{ServerProcess, declare_machine, drive, send_ndjson};
use tokio::net::{TcpListener, TcpStream};

/// How a cut line behaves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Cut {
    /// Open: bytes flow.
    No,
    /// Connections are closed at once (a router that answers).
    Refuse,
    /// Connections are held and nothing ever comes back (a dead line).
    Swallow,
}

/// A TCP relay to the office that the test can cut.
struct Relay {
    address: SocketAddr,
    target: Arc<Mutex<SocketAddr>>,
    cut: Arc<Mutex<Cut>>,
    /// Bumped at each cut: connections of an earlier generation end.
    generation: Arc<AtomicUsize>,
}

impl Relay {
    async fn start(target: SocketAddr) -> Relay {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let relay = Relay {
            address: listener.local_addr().unwrap(),
            target: Arc::new(Mutex::new(target)),
            cut: Arc::new(Mutex::new(Cut::No)),
            generation: Arc::default(),
        };
        let (target, cut, generation) = (
            relay.target.clone(),
            relay.cut.clone(),
            relay.generation.clone(),
        );
        tokio::spawn(async move {
            loop {
                let Ok((mut inbound, _)) = listener.accept().await else {
                    return;
                };
                let now = *cut.lock().unwrap();
                let born = generation.load(Ordering::SeqCst);
                let generation = generation.clone();
                let target = *target.lock().unwrap();
                tokio::spawn(async move {
                    match now {
                        Cut::Refuse => drop(inbound),
                        Cut::Swallow => {
                            // Held unanswered for good: the sender must
                            // give up on it by itself.
                            let _held = inbound;
                            std::future::pending::<()>().await;
                        }
                        Cut::No => {
                            let Ok(mut outbound) = TcpStream::connect(target).await else {
                                return;
                            };
                            let copy = tokio::io::copy_bidirectional(&mut inbound, &mut outbound);
                            let cut_off = async {
                                while generation.load(Ordering::SeqCst) == born {
                                    tokio::time::sleep(Duration::from_millis(20)).await;
                                }
                            };
                            tokio::select! {
                                _ = copy => {}
                                _ = cut_off => {}
                            }
                        }
                    }
                });
            }
        });
        relay
    }

    fn set(&self, cut: Cut) {
        *self.cut.lock().unwrap() = cut;
        self.generation.fetch_add(1, Ordering::SeqCst);
    }

    fn retarget(&self, target: SocketAddr) {
        *self.target.lock().unwrap() = target;
    }

    fn url(&self) -> String {
        format!("http://{}", self.address)
    }
}

/// A site server process, restartable on its data dir.
struct Site {
    name: String,
    dir: tempfile::TempDir,
    relay: Relay,
    process: Mutex<Option<ServerProcess>>,
    /// Where gateways reach it now.
    base: Arc<Mutex<String>>,
}

impl Site {
    /// A site named `name` that reaches the office at `office` through a
    /// relay of its own, started.
    async fn start_new(name: &str, office: SocketAddr) -> Site {
        let site = Site {
            name: name.into(),
            dir: tempfile::tempdir().unwrap(),
            relay: Relay::start(office).await,
            process: Mutex::new(None),
            base: Arc::default(),
        };
        site.start();
        site
    }

    fn start(&self) {
        let process = ServerProcess::start_with_args(
            self.dir.path(),
            &["--forward-to", &self.relay.url(), "--site", &self.name],
        );
        *self.base.lock().unwrap() = process.url("");
        *self.process.lock().unwrap() = Some(process);
    }

    fn kill(&self) {
        if let Some(process) = self.process.lock().unwrap().take() {
            process.kill();
        }
    }

    fn base(&self) -> String {
        self.base.lock().unwrap().clone()
    }
}

/// Posts `lines` to `machine` at the site, 40 a request, resending what
/// was not acknowledged until it is; returns when all are.
async fn gateway(
    client: reqwest::Client,
    base: Arc<Mutex<String>>,
    machine: String,
    lines: Vec<String>,
) {
    let mut from = 0;
    while from < lines.len() {
        let chunk = &lines[from..(from + 40).min(lines.len())];
        let url = base.lock().unwrap().clone();
        let acknowledged = match send_ndjson(&client, &url, &machine, chunk).await {
            Ok(r) if r.status() == 200 => r.bytes().await.is_ok(),
            _ => false,
        };
        if acknowledged {
            from += chunk.len();
            tokio::time::sleep(Duration::from_millis(15)).await;
        } else {
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }
}

/// A machine's readings as stored, in arrival (id) order: (t, sensor,
/// body) of each.
fn stored_readings(dir: &Path, machine: &str) -> Vec<(f64, i64, Vec<u8>)> {
    let conn = rusqlite::Connection::open(dir.join("tunnelnav.sqlite3")).unwrap();
    let mut stmt = conn
        .prepare(
            "SELECT r.t, r.sensor, r.body FROM readings r JOIN machines m ON m.id = r.machine_id \
             WHERE m.machine = ?1 ORDER BY r.id",
        )
        .unwrap();
    stmt.query_map([machine], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))
        .unwrap()
        .collect::<Result<_, _>>()
        .unwrap()
}

/// The office's stored readings of a site's machine, as the export's
/// lines; none while it does not answer them (404 until the machine's
/// declaration has arrived).
async fn office_readings(client: &reqwest::Client, base: &str, machine: &str) -> Vec<String> {
    let response = client
        .get(format!("{base}/api/v1/machines/{machine}/readings"))
        .send()
        .await
        .unwrap();
    match response.status().as_u16() {
        200 => response
            .text()
            .await
            .unwrap()
            .lines()
            .map(str::to_string)
            .collect(),
        _ => Vec::new(),
    }
}

/// Every stored estimate of one of a machine's streams, without the
/// `machine` field (the office names it `{site}.{machine}`).
async fn estimates(
    client: &reqwest::Client,
    base: &str,
    machine: &str,
    stream: &str,
) -> Vec<serde_json::Value> {
    let mut all = common::stream_estimates(client, base, machine, stream).await;
    for e in &mut all {
        e.as_object_mut().unwrap().remove("machine");
    }
    all
}

/// The alarms of a machine as (kind, severity, subject, raised, cleared,
/// message), oldest first.
async fn alarms(client: &reqwest::Client, base: &str, machine: &str) -> Vec<String> {
    let list = common::get_json(
        client,
        base,
        &format!("/api/v1/alarms?machine={machine}&state=all"),
    )
    .await;
    let mut out: Vec<String> = list["alarms"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|a| a["kind"] != "site_link")
        .map(|a| {
            format!(
                "{} {} {} {} {} {} {} {}",
                a["kind"],
                a["severity"],
                a["subject"],
                a["raised_t"],
                a["cleared_t"],
                a["acked_t"],
                a["acked_by"],
                a["message"]
            )
        })
        .collect();
    out.sort();
    out
}

const MACHINES: [&str; 2] = ["tbm-a", "tbm-b"];

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn two_sites_through_cut_links_and_sigkills_lose_nothing_and_match_exactly() {
    let started = Instant::now();
    let client = reqwest::Client::new();
    let office_dir = tempfile::tempdir().unwrap();
    let office = Mutex::new(Some(ServerProcess::start(office_dir.path())));
    let office_address = office.lock().unwrap().as_ref().unwrap().address;
    let mut sites = Vec::new();
    for name in ["north", "south"] {
        let site = Site::start_new(name, office_address).await;
        for (i, machine) in MACHINES.iter().enumerate() {
            let body = if i == 0 {
                common::on_an_axis("Test TBM").to_string()
            } else {
                r#"{"name": "Test TBM", "engines": {"attitude": {}}}"#.to_string()
            };
            declare_machine(&client, &site.base(), machine, &body).await;
        }
        sites.push(Arc::new(site));
    }

    // Gateways post a 3 h drive to each machine of each site.
    let mut gateways = Vec::new();
    for (s, site) in sites.iter().enumerate() {
        for (m, machine) in MACHINES.iter().enumerate() {
            let mut lines = drive(3.0, 100 + 10 * s as u64 + m as u64, vec![]);
            if m == 0 {
                // Positions on the machine's axis, 70 mm off it: `dta`
                // estimates and deviation alarms.
                lines.extend(common::laser_pairs(
                    1_772_431_200.0 + 3.0 * 3600.0 + 10.0,
                    400,
                    0.07,
                ));
            }
            gateways.push(tokio::spawn(gateway(
                client.clone(),
                site.base.clone(),
                machine.to_string(),
                lines,
            )));
        }
    }

    // The troubles, on a fixed schedule (seconds from now): each site's
    // link cut three times for 3–6 s (refused or swallowed), each site
    // killed twice, the office once.
    enum Trouble {
        Cut(usize, Cut, u64),
        KillSite(usize),
        KillOffice,
    }
    let schedule = [
        (1.0, Trouble::Cut(0, Cut::Refuse, 4)),
        (2.0, Trouble::KillSite(1)),
        (3.0, Trouble::Cut(1, Cut::Swallow, 5)),
        (4.0, Trouble::KillSite(0)),
        (7.0, Trouble::KillOffice),
        (9.0, Trouble::Cut(0, Cut::Swallow, 6)),
        (10.0, Trouble::KillSite(0)),
        (11.0, Trouble::Cut(1, Cut::Refuse, 3)),
        (13.0, Trouble::KillSite(1)),
        (16.0, Trouble::Cut(0, Cut::Refuse, 3)),
        (16.5, Trouble::Cut(1, Cut::Swallow, 4)),
    ];
    let mut restores = Vec::new();
    for (at_s, trouble) in schedule {
        let wait = Duration::from_secs_f64(at_s).saturating_sub(started.elapsed());
        tokio::time::sleep(wait).await;
        match trouble {
            Trouble::Cut(s, how, seconds) => {
                sites[s].relay.set(how);
                let site = sites[s].clone();
                restores.push(tokio::spawn(async move {
                    tokio::time::sleep(Duration::from_secs(seconds)).await;
                    site.relay.set(Cut::No);
                }));
            }
            Trouble::KillSite(s) => {
                sites[s].kill();
                tokio::time::sleep(Duration::from_millis(300)).await;
                sites[s].start();
            }
            Trouble::KillOffice => {
                if let Some(process) = office.lock().unwrap().take() {
                    process.kill();
                }
                tokio::time::sleep(Duration::from_millis(500)).await;
                let restarted = ServerProcess::start(office_dir.path());
                for site in &sites {
                    site.relay.retarget(restarted.address);
                }
                *office.lock().unwrap() = Some(restarted);
            }
        }
    }
    for restore in restores {
        restore.await.unwrap();
    }
    for gateway in gateways {
        gateway.await.unwrap();
    }
    let load_s = started.elapsed().as_secs_f64();
    // A shift lead acknowledges every alarm at each site: the
    // acknowledgements travel too.
    let mut acked = 0;
    for site in &sites {
        let list = common::get_json(&client, &site.base(), "/api/v1/alarms?state=all").await;
        for alarm in list["alarms"].as_array().unwrap() {
            let url = format!("{}/api/v1/alarms/{}/ack", site.base(), alarm["id"]);
            assert_eq!(client.post(&url).send().await.unwrap().status(), 200);
            acked += 1;
        }
    }
    assert!(acked > 0, "the drives raised alarms to acknowledge");

    // The office catches up: every site's backlog reported empty.
    let office_base = office.lock().unwrap().as_ref().unwrap().url("");
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let sites_now = common::get_json(&client, &office_base, "/api/v1/sites").await;
        let caught_up = sites_now["sites"].as_array().unwrap().len() == 2
            && sites_now["sites"]
                .as_array()
                .unwrap()
                .iter()
                .all(|s| s["connected"] == true && s["backlog_items"] == 0);
        let mut complete = caught_up;
        if caught_up {
            for site in &sites {
                for machine in MACHINES {
                    let here = common::exported_readings(&client, &site.base(), machine).await;
                    let there = common::exported_readings(
                        &client,
                        &office_base,
                        &format!("{}.{machine}", site.name),
                    )
                    .await;
                    complete &= here.len() == there.len();
                    let office_id = format!("{}.{machine}", site.name);
                    complete &= alarms(&client, &site.base(), machine).await
                        == alarms(&client, &office_base, &office_id).await;
                }
            }
        }
        if complete {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the office did not catch up: {sites_now}"
        );
        tokio::time::sleep(Duration::from_millis(500)).await;
    }

    let caught_up_s = started.elapsed().as_secs_f64() - load_s;

    // Same estimates and alarms, through the API.
    let mut readings_total = 0;
    let mut estimates_total = 0;
    let mut alarms_total = 0;
    for site in &sites {
        for machine in MACHINES {
            let office_id = format!("{}.{machine}", site.name);
            let streams: &[&str] = if machine == "tbm-a" {
                &["attitude", "dta"]
            } else {
                &["attitude"]
            };
            for stream in streams {
                let here = estimates(&client, &site.base(), machine, stream).await;
                let there = estimates(&client, &office_base, &office_id, stream).await;
                assert_eq!(
                    here.len(),
                    there.len(),
                    "{office_id} {stream}: estimate count"
                );
                assert!(here.len() > 300, "{office_id} {stream}: estimates made");
                for (i, (a, b)) in here.iter().zip(&there).enumerate() {
                    assert_eq!(a, b, "{office_id} {stream}: estimate {i} differs");
                }
                estimates_total += here.len();
            }
            let here = alarms(&client, &site.base(), machine).await;
            assert_eq!(
                here,
                alarms(&client, &office_base, &office_id).await,
                "{office_id}: alarms"
            );
            alarms_total += here.len();
        }
    }

    // The office's fleet page groups the machines by site; its lists
    // filter by site.
    let page = common::get_text(&client, &office_base, "/").await;
    for site in &sites {
        let group = page
            .split(&format!("data-site=\"{}\"", site.name))
            .nth(1)
            .unwrap_or_else(|| panic!("no group for site {}:\n{page}", site.name));
        let group = group.split("</section>").next().unwrap();
        for machine in MACHINES {
            assert!(group.contains(&format!("data-machine=\"{}.{machine}\"", site.name)));
        }
        let listed = common::get_json(
            &client,
            &office_base,
            &format!("/api/v1/machines?site={}", site.name),
        )
        .await;
        let listed: Vec<&str> = listed["machines"]
            .as_array()
            .unwrap()
            .iter()
            .map(|m| m["machine"].as_str().unwrap())
            .collect();
        assert_eq!(listed.len(), MACHINES.len(), "{listed:?}");
        assert!(
            listed
                .iter()
                .all(|m| m.starts_with(&format!("{}.", site.name)))
        );
        let alarms = common::get_json(
            &client,
            &office_base,
            &format!("/api/v1/alarms?site={}&state=all", site.name),
        )
        .await;
        assert!(alarms["alarms"].as_array().unwrap().iter().all(|a| {
            a["machine"]
                .as_str()
                .unwrap()
                .starts_with(&format!("{}.", site.name))
        }));
    }

    // Every reading once, in the site's order: the stores themselves,
    // once the servers have stopped.
    for site in &sites {
        if let Some(process) = site.process.lock().unwrap().take() {
            assert!(process.terminate().success());
        }
    }
    if let Some(process) = office.lock().unwrap().take() {
        assert!(process.terminate().success());
    }
    for site in &sites {
        for machine in MACHINES {
            let here = stored_readings(site.dir.path(), machine);
            let there = stored_readings(office_dir.path(), &format!("{}.{machine}", site.name));
            assert!(here.len() > 1000, "{machine}: the drive was posted");
            assert!(
                here == there,
                "{}.{machine}: the office's readings differ from the site's",
                site.name
            );
            readings_total += here.len();
        }
    }
    eprintln!(
        "2 sites × {} machines: {readings_total} readings, {estimates_total} estimates and \
         {alarms_total} alarms equal at the office \
         (max diff 0) after 6 link cuts, 4 site SIGKILLs and 1 office SIGKILL over {load_s:.1} s of load; \
         caught up {caught_up_s:.1} s after the load",
        MACHINES.len(),
    );
}

/// A site offline while it takes a long backlog catches up once its
/// office is back, and keeps answering its gateways and readers meanwhile
/// (the rate is measured by `tools/bench-forward-catchup.sh`, not here).
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_site_offline_for_hours_catches_up_and_keeps_answering() {
    use tunnelnav::sim::tbm::{TbmDrive, TbmScenario};
    let client = reqwest::Client::new();
    // 4 h of inclinometer readings every 0.2 s: 72 000 readings.
    let lines: Vec<String> = TbmDrive::new(TbmScenario {
        seed: 7,
        hours: 4.0,
        incl_period_s: 0.2,
        ..TbmScenario::default()
    })
    .unwrap()
    .map(|event| event.reading.to_json())
    .collect();
    let (backlog, live) = lines.split_at(lines.len() * 3 / 4);
    // The office is not there: the relay refuses.
    let office_dir = tempfile::tempdir().unwrap();
    let site = Site::start_new("east", "127.0.0.1:9".parse().unwrap()).await;
    site.relay.set(Cut::Refuse);
    let base = site.base();
    declare_machine(&client, &base, "tbm", r#"{"engines": {"attitude": {}}}"#).await;
    for chunk in backlog.chunks(5000) {
        let response = send_ndjson(&client, &base, "tbm", chunk).await.unwrap();
        assert_eq!(response.status(), 200);
    }
    // The office comes up; the line with it.
    let office = ServerProcess::start(office_dir.path());
    site.relay.retarget(office.address);
    site.relay.set(Cut::No);
    // Meanwhile the gateway goes on and a reader looks at the machine:
    // every request is answered.
    let mut slowest = Duration::ZERO;
    for chunk in live.chunks(200) {
        let asked = Instant::now();
        let response = send_ndjson(&client, &base, "tbm", chunk).await.unwrap();
        assert_eq!(response.status(), 200);
        let status = client
            .get(format!("{base}/api/v1/machines/tbm"))
            .send()
            .await
            .unwrap();
        assert_eq!(status.status(), 200);
        slowest = slowest.max(asked.elapsed());
    }
    let office_base = office.url("");
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let there = office_readings(&client, &office_base, "east.tbm")
            .await
            .len();
        if there == lines.len() {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "caught up {there} of {}",
            lines.len()
        );
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
    let here = estimates(&client, &base, "tbm", "attitude").await;
    let there = estimates(&client, &office_base, "east.tbm", "attitude").await;
    assert!(
        here == there,
        "the office's estimates differ from the site's"
    );
    eprintln!(
        "{} readings offline, {} more during the catch-up; the site answered every request, \
         the slowest post and status pair in {:.0} ms",
        backlog.len(),
        live.len(),
        slowest.as_secs_f64() * 1000.0
    );
    site.kill();
}

/// The office on PostgreSQL (an office's usual store): a site forwards
/// through a cut and a SIGKILL of the office, and the office holds the
/// same readings, estimates and alarms.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_site_forwards_to_an_office_on_postgres() {
    let Some(cluster) = common::postgres::PgCluster::start() else {
        return;
    };
    let url = cluster.database("office");
    let client = reqwest::Client::new();
    let office_dir = tempfile::tempdir().unwrap();
    let office = ServerProcess::start_with_args(office_dir.path(), &["--store", &url]);
    let site = Site::start_new("west", office.address).await;
    declare_machine(
        &client,
        &site.base(),
        "tbm",
        &common::on_an_axis("Test TBM").to_string(),
    )
    .await;
    let mut lines = drive(2.0, 77, vec![]);
    lines.extend(common::laser_pairs(
        1_772_431_200.0 + 2.0 * 3600.0 + 10.0,
        400,
        0.07,
    ));
    let posting = tokio::spawn(gateway(
        client.clone(),
        site.base.clone(),
        "tbm".into(),
        lines.clone(),
    ));
    tokio::time::sleep(Duration::from_secs(1)).await;
    site.relay.set(Cut::Refuse);
    tokio::time::sleep(Duration::from_secs(3)).await;
    site.relay.set(Cut::No);
    office.kill();
    let office = ServerProcess::start_with_args(office_dir.path(), &["--store", &url]);
    site.relay.retarget(office.address);
    posting.await.unwrap();
    let office_base = office.url("");
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let there = office_readings(&client, &office_base, "west.tbm").await;
        let here = common::exported_readings(&client, &site.base(), "tbm").await;
        if there.len() == here.len()
            && alarms(&client, &site.base(), "tbm").await
                == alarms(&client, &office_base, "west.tbm").await
        {
            assert_eq!(there, here);
            break;
        }
        assert!(Instant::now() < deadline, "the office did not catch up");
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
    for stream in ["attitude", "dta"] {
        let here = estimates(&client, &site.base(), "tbm", stream).await;
        let there = estimates(&client, &office_base, "west.tbm", stream).await;
        assert!(here.len() > 300, "{stream}: estimates made");
        assert_eq!(here.len(), there.len(), "{stream}: estimate count");
        for (i, (a, b)) in here.iter().zip(&there).enumerate() {
            assert_eq!(a, b, "{stream}: estimate {i} differs");
        }
    }
    site.kill();
    office.kill();
}

/// An office raises `site_link` on a site's machines once the site has
/// been silent longer than `[sites] backlog_alarm_s`, shows the link down
/// in `/api/v1/sites` and its metrics, and clears the alarm once the site
/// has caught up.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_silent_site_raises_site_link_at_the_office_until_it_has_caught_up() {
    let client = reqwest::Client::new();
    let office_dir = tempfile::tempdir().unwrap();
    let config = office_dir.path().join("office.toml");
    std::fs::write(&config, "[sites]\nbacklog_alarm_s = 10\n").unwrap();
    let office = ServerProcess::start_with_args(
        &office_dir.path().join("data"),
        &["--config", config.to_str().unwrap()],
    );
    let office_base = office.url("");
    let site = Site::start_new("quiet", office.address).await;
    declare_machine(
        &client,
        &site.base(),
        "tbm",
        r#"{"engines": {"attitude": {}}}"#,
    )
    .await;
    let lines = drive(0.5, 5, vec![]);
    let (before, during) = lines.split_at(lines.len() / 2);
    send_ndjson(&client, &site.base(), "tbm", before)
        .await
        .unwrap();
    // Wait for `predicate` on the office's answer to `path`, up to `s`.
    let wait_for = |path: &'static str, s: u64, predicate: fn(&serde_json::Value) -> bool| {
        let (client, base) = (client.clone(), office_base.clone());
        async move {
            let deadline = Instant::now() + Duration::from_secs(s);
            loop {
                let body = common::get_json(&client, &base, path).await;
                if predicate(&body) {
                    return body;
                }
                if Instant::now() >= deadline {
                    let sites = common::get_json(&client, &base, "/api/v1/sites").await;
                    panic!("{path}: {body}; sites: {sites}");
                }
                tokio::time::sleep(Duration::from_millis(250)).await;
            }
        }
    };
    wait_for("/api/v1/sites", 20, |b| b["sites"][0]["connected"] == true).await;
    // The office has the machine (its declaration and first readings).
    wait_for("/api/v1/machines?site=quiet", 20, |b| {
        b["machines"][0]["machine"] == "quiet.tbm"
    })
    .await;
    // The line goes; the site keeps taking readings.
    site.relay.set(Cut::Refuse);
    let cut_at = Instant::now();
    send_ndjson(&client, &site.base(), "tbm", during)
        .await
        .unwrap();
    let raised = wait_for("/api/v1/alarms?site=quiet", 40, |b| {
        b["alarms"]
            .as_array()
            .unwrap()
            .iter()
            .any(|a| a["kind"] == "site_link" && a["machine"] == "quiet.tbm")
    })
    .await;
    let silent_s = cut_at.elapsed().as_secs_f64();
    // Silent 10 s since its last contact, at most 2 s before the cut.
    assert!(silent_s > 7.5, "raised after {silent_s:.1} s: {raised}");
    let alarm = &raised["alarms"][0];
    assert_eq!(
        (alarm["severity"].as_str(), alarm["subject"].as_str()),
        (Some("alarm"), Some("quiet"))
    );
    let sites = common::get_json(&client, &office_base, "/api/v1/sites").await;
    assert_eq!(sites["sites"][0]["connected"], false, "{sites}");
    assert_eq!(sites["sites"][0]["alarm"], true, "{sites}");
    let metrics = common::get_text(&client, &office_base, "/metrics").await;
    assert!(
        metrics.contains(r#"tunnelnav_forward_connected{site="quiet"} 0"#),
        "{metrics}"
    );
    // The line is back: the site catches up, the alarm clears.
    site.relay.set(Cut::No);
    wait_for("/api/v1/alarms?site=quiet", 40, |b| {
        b["alarms"]
            .as_array()
            .unwrap()
            .iter()
            .all(|a| a["kind"] != "site_link")
    })
    .await;
    let all = common::get_json(&client, &office_base, "/api/v1/alarms?site=quiet&state=all").await;
    let cleared = all["alarms"]
        .as_array()
        .unwrap()
        .iter()
        .find(|a| a["kind"] == "site_link")
        .unwrap()
        .clone();
    assert!(cleared["cleared_t"].as_f64().unwrap() > cleared["raised_t"].as_f64().unwrap());
    let here = common::exported_readings(&client, &site.base(), "tbm").await;
    let there = common::exported_readings(&client, &office_base, "quiet.tbm").await;
    assert_eq!(here, there);
    let metrics = common::get_text(&client, &office_base, "/metrics").await;
    assert!(
        metrics.contains(r#"tunnelnav_forward_connected{site="quiet"} 1"#),
        "{metrics}"
    );
    site.kill();
}

//! The dashboard: server-rendered pages (askama templates in `templates/`)
//! and the static assets they load (`static/`, embedded in the binary so
//! the dashboard needs no internet and no files beside the binary). The
//! pages fetch history from the JSON API and follow the `live` socket.

use askama::Template;
use askama_web::WebTemplate;
use axum::extract::{Path, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};

use super::SharedState;
use crate::fusion::EngineKind;
use crate::fusion::zupt::ZuptConfig;

/// `GET /`: one card per machine.
#[derive(Template, WebTemplate)]
#[template(path = "fleet.html")]
pub struct FleetPage {
    machines: Vec<MachineCard>,
}

struct MachineCard {
    id: String,
    name: String,
    engines: String,
}

/// `GET /machines/{machine}`.
#[derive(Template, WebTemplate)]
#[template(path = "machine.html")]
pub struct MachinePage {
    id: String,
    name: String,
    /// Engine names, comma-separated.
    engines: String,
    /// The machine runs the `attitude` engine (charts, laser, ANFIS).
    attitude: bool,
    /// The `zupt` engine's detector and decision latency (about), if the
    /// machine runs it (plan, profile, distance, detector state).
    zupt: Option<ZuptView>,
    /// The machine runs the `fuzzy` engine (compass, static degree, bias,
    /// magnetometer calibration).
    fuzzy: bool,
}

struct ZuptView {
    detector: String,
    /// Samples the centred windows wait for, and the minimum rest, s.
    lookahead_samples: usize,
    min_zv_s: f64,
}

#[derive(Template, WebTemplate)]
#[template(path = "not_found.html")]
struct NotFoundPage {
    what: String,
}

fn engine_list(engines: impl Iterator<Item = EngineKind>) -> String {
    engines.map(|e| e.as_str()).collect::<Vec<_>>().join(", ")
}

/// `GET /`.
pub async fn fleet(State(state): State<SharedState>) -> FleetPage {
    FleetPage {
        machines: state
            .all_machines()
            .iter()
            .map(|m| MachineCard {
                id: m.spec.id.clone(),
                name: m.spec.name.clone(),
                engines: engine_list(m.spec.engines.keys().copied()),
            })
            .collect(),
    }
}

/// `GET /machines/{machine}`; an HTML 404 for an unknown machine.
pub async fn machine(State(state): State<SharedState>, Path(id): Path<String>) -> Response {
    let Ok(machine) = state.machine(&id) else {
        let page = NotFoundPage {
            what: format!("There is no machine `{id}`."),
        };
        return (StatusCode::NOT_FOUND, page).into_response();
    };
    MachinePage {
        id: machine.spec.id.clone(),
        name: machine.spec.name.clone(),
        engines: engine_list(machine.spec.engines.keys().copied()),
        attitude: machine.spec.engines.contains_key(&EngineKind::Attitude),
        zupt: machine
            .spec
            .engines
            .get(&EngineKind::Zupt)
            .and_then(|params| ZuptConfig::from_params(params).ok())
            .map(|config| {
                let pipeline = &config.pipeline;
                ZuptView {
                    detector: pipeline.detector.as_str().to_string(),
                    lookahead_samples: pipeline.lookahead_samples(),
                    min_zv_s: pipeline.min_run_s,
                }
            }),
        fuzzy: machine.spec.engines.contains_key(&EngineKind::Fuzzy),
    }
    .into_response()
}

/// One embedded file.
struct Asset {
    path: &'static str,
    content_type: &'static str,
    bytes: &'static [u8],
}

macro_rules! asset {
    ($path:literal, $type:literal) => {
        Asset {
            path: $path,
            content_type: $type,
            bytes: include_bytes!(concat!("../../static/", $path)),
        }
    };
}

const ASSETS: &[Asset] = &[
    asset!("app.css", "text/css; charset=utf-8"),
    asset!("common.js", "text/javascript; charset=utf-8"),
    asset!("favicon.svg", "image/svg+xml"),
    asset!("fleet.js", "text/javascript; charset=utf-8"),
    asset!("attitude.js", "text/javascript; charset=utf-8"),
    asset!("zupt.js", "text/javascript; charset=utf-8"),
    asset!("fuzzy.js", "text/javascript; charset=utf-8"),
    asset!(
        "vendor/uplot/uPlot.iife.min.js",
        "text/javascript; charset=utf-8"
    ),
    asset!("vendor/uplot/uPlot.min.css", "text/css; charset=utf-8"),
    asset!("vendor/uplot/LICENSE", "text/plain; charset=utf-8"),
];

/// `GET /static/{*path}`: the embedded assets. Ours are revalidated on
/// every load (they change with the binary); vendored ones are cached.
pub async fn asset(Path(path): Path<String>) -> Response {
    let Some(asset) = ASSETS.iter().find(|a| a.path == path) else {
        let page = NotFoundPage {
            what: format!("There is no static file `{path}`."),
        };
        return (StatusCode::NOT_FOUND, page).into_response();
    };
    let cache = if path.starts_with("vendor/") {
        "public, max-age=86400"
    } else {
        "no-cache"
    };
    (
        [
            (header::CONTENT_TYPE, asset.content_type),
            (header::CACHE_CONTROL, cache),
        ],
        asset.bytes,
    )
        .into_response()
}

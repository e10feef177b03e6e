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
use crate::fusion::zupt::ZuptConfig;
use crate::fusion::{EngineKind, Params};

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

/// `GET /`: one card per machine.
#[derive(Template, WebTemplate)]
#[template(path = "fleet.html")]
pub struct FleetPage {
    machines: Vec<MachineCard>,
    /// Every engine's script: each gives its card rows.
    engine_scripts: Vec<&'static str>,
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
    /// Each engine's section, in the machine's engine order.
    sections: Vec<EngineSection>,
}

/// An engine's part of a machine page: its section (a template in
/// `templates/engines/`) and the script that fills it (in `static/`).
pub struct EngineSection {
    pub html: String,
    pub script: &'static str,
}

/// The `attitude` section: laser state, pitch and roll, the ANFIS, the noise.
#[derive(Template)]
#[template(path = "engines/attitude.html")]
struct AttitudeSection;

/// The `zupt` section; the detector and how far behind it decides.
#[derive(Template)]
#[template(path = "engines/zupt.html")]
struct ZuptSection {
    detector: &'static str,
    /// Samples the centred windows wait for, and the minimum rest, s.
    lookahead_samples: usize,
    min_zv_s: f64,
}

/// The `fuzzy` section: motion status, compass, calibration, bias.
#[derive(Template)]
#[template(path = "engines/fuzzy.html")]
struct FuzzySection;

/// Why an engine's section could not be made.
#[derive(Debug, thiserror::Error)]
pub enum SectionError {
    #[error("the {engine} engine's parameters: {source}")]
    Params {
        engine: EngineKind,
        source: crate::fusion::ParamError,
    },
    #[error("the {engine} engine's section: {source}")]
    Render {
        engine: EngineKind,
        source: askama::Error,
    },
}

/// The section of a machine page for `engine` running with `params`.
/// Adding an engine: its template in `templates/engines/`, its script in
/// `static/` (registering itself with `tn.registerEngine`), its arm here
/// and in [`engine_script`].
pub fn engine_section(engine: EngineKind, params: &Params) -> Result<EngineSection, SectionError> {
    let html = match engine {
        EngineKind::Attitude => AttitudeSection.render(),
        EngineKind::Zupt => {
            let config = ZuptConfig::from_params(params)
                .map_err(|source| SectionError::Params { engine, source })?;
            let pipeline = &config.pipeline;
            ZuptSection {
                detector: pipeline.detector.as_str(),
                lookahead_samples: pipeline.lookahead_samples(),
                min_zv_s: pipeline.min_run_s,
            }
            .render()
        }
        EngineKind::Fuzzy => FuzzySection.render(),
    }
    .map_err(|source| SectionError::Render { engine, source })?;
    Ok(EngineSection {
        html,
        script: engine_script(engine).path,
    })
}

/// The script of an engine's section (also loaded by the fleet page for
/// its card rows).
fn engine_script(engine: EngineKind) -> &'static Asset {
    const ATTITUDE: Asset = asset!("attitude.js", "text/javascript; charset=utf-8");
    const ZUPT: Asset = asset!("zupt.js", "text/javascript; charset=utf-8");
    const FUZZY: Asset = asset!("fuzzy.js", "text/javascript; charset=utf-8");
    match engine {
        EngineKind::Attitude => &ATTITUDE,
        EngineKind::Zupt => &ZUPT,
        EngineKind::Fuzzy => &FUZZY,
    }
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
        engine_scripts: EngineKind::ALL
            .iter()
            .map(|&engine| engine_script(engine).path)
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
    let sections: Result<Vec<EngineSection>, SectionError> = machine
        .spec
        .engines
        .iter()
        .map(|(&engine, params)| engine_section(engine, params))
        .collect();
    match sections {
        Ok(sections) => MachinePage {
            id: machine.spec.id.clone(),
            name: machine.spec.name.clone(),
            engines: engine_list(machine.spec.engines.keys().copied()),
            sections,
        }
        .into_response(),
        // A stored declaration's parameters were validated when declared.
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
    }
}

const ASSETS: &[Asset] = &[
    asset!("app.css", "text/css; charset=utf-8"),
    asset!("common.js", "text/javascript; charset=utf-8"),
    asset!("favicon.svg", "image/svg+xml"),
    asset!("fleet.js", "text/javascript; charset=utf-8"),
    asset!("machine.js", "text/javascript; charset=utf-8"),
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
    let Some(asset) = ASSETS
        .iter()
        .chain(EngineKind::ALL.iter().map(|&engine| engine_script(engine)))
        .find(|a| a.path == path)
    else {
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

//! The dashboard: server-rendered pages (askama templates in `templates/`)
//! and the static assets they load (`static/`, embedded in the binary so
//! the dashboard needs no internet and no files beside the binary). The
//! pages fetch history from the JSON API and follow the `live` socket.

use askama::Template;
use askama_web::WebTemplate;
use axum::extract::{Path, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};

use super::error::ApiError;
use super::state::SharedState;
use crate::config::MachineSpec;
use crate::fusion::zupt::ZuptConfig;
use crate::fusion::{EngineKind, Params, StageKind};

/// One embedded file.
pub(crate) struct Asset {
    pub(crate) path: &'static str,
    pub(crate) content_type: &'static str,
    pub(crate) bytes: &'static [u8],
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
    /// This server's machines, then (an office) each site's.
    groups: Vec<FleetGroup>,
    /// Every engine's script: each gives its card rows.
    engine_scripts: Vec<&'static str>,
}

/// A site's machines (`site`: `None` for this server's own).
struct FleetGroup {
    site: Option<String>,
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

/// The `dta` section: the head/tail target, the deviations, the drive
/// against station, plan and profile. Limits are empty without tolerances.
#[derive(Template)]
#[template(path = "stages/dta.html")]
struct DtaSection {
    axis_name: String,
    warn_h: String,
    alarm_h: String,
    warn_v: String,
    alarm_v: String,
    /// Front to rear along the body's x axis, m.
    length_m: f64,
    /// The declared steering: the correction curve's panel.
    steering: Option<crate::fusion::steering::SteeringSpec>,
}

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
    #[error("the {stage} stage's section: {source}")]
    RenderStage {
        stage: StageKind,
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
        #[cfg(test)]
        EngineKind::Toy => crate::toy_engine::ToySection.render(),
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
        #[cfg(test)]
        EngineKind::Toy => &crate::toy_engine::TOY_SCRIPT,
    }
}

/// The section of a machine page for a stage the machine runs, if it has
/// one (`pushes` is not drawn: its records are in the history API).
pub fn stage_section(
    stage: StageKind,
    spec: &MachineSpec,
) -> Result<Option<EngineSection>, SectionError> {
    let Some(script) = stage_script(stage) else {
        return Ok(None);
    };
    let html = match stage {
        StageKind::Dta => {
            let limit = |v: Option<f64>| v.map(|v| v.to_string()).unwrap_or_default();
            let t = spec.tolerances;
            DtaSection {
                axis_name: spec
                    .built_alignment
                    .as_ref()
                    .map(|a| a.name.clone())
                    .unwrap_or_default(),
                warn_h: limit(t.map(|t| t.horizontal_mm.warn)),
                alarm_h: limit(t.map(|t| t.horizontal_mm.alarm)),
                warn_v: limit(t.map(|t| t.vertical_mm.warn)),
                alarm_v: limit(t.map(|t| t.vertical_mm.alarm)),
                length_m: spec.geometry.map_or(0.0, |g| g.front_m[0] - g.rear_m[0]),
                steering: spec.steering.clone(),
            }
            .render()
        }
        StageKind::Pushes | StageKind::Steer | StageKind::Rings | StageKind::RingPlan => {
            return Ok(None);
        }
    }
    .map_err(|source| SectionError::RenderStage { stage, source })?;
    Ok(Some(EngineSection {
        html,
        script: script.path,
    }))
}

/// The script of a stage's section and fleet card rows, if it has one.
fn stage_script(stage: StageKind) -> Option<&'static Asset> {
    const DTA: Asset = asset!("dta.js", "text/javascript; charset=utf-8");
    match stage {
        StageKind::Dta => Some(&DTA),
        StageKind::Pushes | StageKind::Steer | StageKind::Rings | StageKind::RingPlan => None,
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

/// The fleet page.
///
/// `GET /`: one card per machine. A browser without a token, once tokens
/// exist, is sent to the sign-in page.
#[utoipa::path(get, path = "/", operation_id = "fleet_page", tag = "dashboard",
    responses((status = OK, description = "The fleet page", content_type = "text/html", body = String),
        (status = SEE_OTHER, description = "A browser without a token: to /login")))]
pub async fn fleet(State(state): State<SharedState>) -> Result<FleetPage, ApiError> {
    let specs: Vec<crate::config::MachineSpec> = state
        .all_machines()
        .iter()
        .map(|m| (*m.spec).clone())
        .chain(state.elsewhere().await?.into_iter().map(|m| m.spec))
        .collect();
    let mut machines: Vec<MachineCard> = specs
        .iter()
        .map(|spec| MachineCard {
            id: spec.id.clone(),
            name: spec.name.clone(),
            engines: engine_list(spec.engines.keys().copied()),
        })
        .collect();
    machines.sort_by(|a, b| a.id.cmp(&b.id));
    // This server's own machines first (`None`), then each site's.
    let mut groups: Vec<FleetGroup> = Vec::new();
    for card in machines {
        let site = crate::config::forwarded_site(&card.id).map(str::to_string);
        match groups.iter_mut().find(|g| g.site == site) {
            Some(group) => group.machines.push(card),
            None => groups.push(FleetGroup {
                site,
                machines: vec![card],
            }),
        }
    }
    groups.sort_by(|a, b| a.site.cmp(&b.site));
    Ok(FleetPage {
        groups,
        engine_scripts: EngineKind::ALL
            .iter()
            .map(|&engine| engine_script(engine).path)
            .chain(
                StageKind::ALL
                    .iter()
                    .filter_map(|&s| stage_script(s))
                    .map(|a| a.path),
            )
            .collect(),
    })
}

/// A machine's live page.
///
/// `GET /machines/{machine}`; an HTML 404 for an unknown machine.
#[utoipa::path(get, path = "/machines/{machine}", operation_id = "machine_page", tag = "dashboard",
    params(super::openapi::MachinePath),
    responses((status = OK, description = "The machine's live page", content_type = "text/html", body = String),
        (status = SEE_OTHER, description = "A browser without a token: to /login"),
        (status = NOT_FOUND, description = "No machine has this id (a page saying so)", content_type = "text/html", body = String)))]
pub async fn machine(
    State(state): State<SharedState>,
    Path(super::openapi::MachinePath { machine: id }): Path<super::openapi::MachinePath>,
) -> Response {
    let Ok(machine) = state.machine(&id) else {
        let page = NotFoundPage {
            what: format!("There is no machine `{id}`."),
        };
        return (StatusCode::NOT_FOUND, page).into_response();
    };
    // The stages' sections first: the deviation from the axis is what the
    // driver steers by.
    let spec = &machine.spec;
    let mut names = Vec::new();
    let mut sections = Vec::new();
    let stages = spec.stage_declaration().stages();
    let made: Result<(), SectionError> = stages
        .iter()
        .try_for_each(|&stage| {
            if let Some(section) = stage_section(stage, spec)? {
                names.push(stage.as_str());
                sections.push(section);
            }
            Ok(())
        })
        .and_then(|()| {
            spec.engines.iter().try_for_each(|(&engine, params)| {
                sections.push(engine_section(engine, params)?);
                names.push(engine.as_str());
                Ok(())
            })
        });
    match made {
        Ok(()) => MachinePage {
            id: spec.id.clone(),
            name: spec.name.clone(),
            engines: names.join(", "),
            sections,
        }
        .into_response(),
        // A stored declaration's parameters were validated when declared.
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
    }
}

const ASSETS: &[Asset] = &[
    asset!("app.css", "text/css; charset=utf-8"),
    asset!("alarms.js", "text/javascript; charset=utf-8"),
    asset!("common.js", "text/javascript; charset=utf-8"),
    asset!("favicon.svg", "image/svg+xml"),
    asset!("fleet.js", "text/javascript; charset=utf-8"),
    asset!("machine.js", "text/javascript; charset=utf-8"),
    asset!("theme.js", "text/javascript; charset=utf-8"),
    asset!(
        "vendor/uplot/uPlot.iife.min.js",
        "text/javascript; charset=utf-8"
    ),
    asset!("vendor/uplot/uPlot.min.css", "text/css; charset=utf-8"),
    asset!("vendor/uplot/LICENSE", "text/plain; charset=utf-8"),
    asset!("api-docs.js", "text/javascript; charset=utf-8"),
    asset!(
        "vendor/swagger-ui/swagger-ui-bundle.js",
        "text/javascript; charset=utf-8"
    ),
    asset!(
        "vendor/swagger-ui/swagger-ui.css",
        "text/css; charset=utf-8"
    ),
    asset!("vendor/swagger-ui/LICENSE", "text/plain; charset=utf-8"),
    asset!("vendor/swagger-ui/NOTICE", "text/plain; charset=utf-8"),
    asset!(
        "vendor/swagger-ui/swagger-ui-bundle.js.LICENSE.txt",
        "text/plain; charset=utf-8"
    ),
];

/// `GET /static/{*path}`: the embedded assets. Ours are revalidated on
/// every load (they change with the binary); vendored ones are cached.
pub async fn asset(Path(path): Path<String>) -> Response {
    let Some(asset) = ASSETS
        .iter()
        .chain(EngineKind::ALL.iter().map(|&engine| engine_script(engine)))
        .chain(
            StageKind::ALL
                .iter()
                .filter_map(|&stage| stage_script(stage)),
        )
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

//! The OpenAPI 3.1 description of the HTTP API, generated from the code:
//! each handler carries its `#[utoipa::path]`, the bodies derive their
//! schemas, and the router is built from those handlers (utoipa-axum), so
//! a route cannot exist without its description. Served at
//! `GET /api/v1/openapi.json` and drawn by the page `/api/docs`.
//!
//! What the derives cannot say is written here: a reading's schema (built
//! from the validator's own bounds table), the estimate union, the
//! security schemes and the error answers every operation can give.

use std::borrow::Cow;

use axum::Extension;
use axum::body::Bytes;
use axum::http::header;
use axum::response::{Html, IntoResponse, Response};
use serde::Deserialize;
use utoipa::openapi::path::{Operation, PathItem};
use utoipa::openapi::schema::{
    AllOfBuilder, ArrayBuilder, ObjectBuilder, OneOfBuilder, Schema, SchemaType, Type,
};
use utoipa::openapi::security::{ApiKey, ApiKeyValue, HttpAuthScheme, HttpBuilder, SecurityScheme};
use utoipa::openapi::{Content, HeaderBuilder, OpenApi, Ref, RefOr, ResponseBuilder};
use utoipa::{Modify, PartialSchema, ToSchema};

use crate::fusion::reading::field_bounds;
use crate::fusion::{EngineKind, IntegrityLevel, IntegrityReason, StreamKind};

/// The dashboard's cookie.
pub const COOKIE: &str = "tunnelnav_token";

/// The document's frame: title, tags, security schemes and the schemas no
/// handler names directly.
#[derive(utoipa::OpenApi)]
#[openapi(
    info(
        title = "tunnelnav",
        description = "Live attitude and position of tunnel boring and pipe-jacking machines, \
fused per machine from laser, inclinometer and INS readings. The wire contract is \
docs/protocol.md; docs/api.md has examples.\n\n\
**Access**: while no token exists (a fresh install) every request is allowed. Once one \
does, each operation needs a token of the role its security requirement names \
(`read`, `ingest`, `admin`; an admin token may do everything, an ingest token only \
ingest), sent as `Authorization: Bearer <token>` or in the `tunnelnav_token` cookie \
the sign-in page sets.\n\n\
**Errors** are JSON `{\"error\": \"...\"}` naming what was wrong (see `ErrorBody`). \
A 503 (with `Retry-After`) means the server cannot take the request now and nothing \
of it was stored: retry.\n\n\
**Times** in queries are Unix seconds (numbers above 1e11 are milliseconds, as \
Grafana sends them) or RFC 3339.\n\n\
The WebSocket endpoints (`.../ingest`, `.../live`, `/api/v1/alarms/live`) are listed \
with their upgrade request; their messages are described in docs/protocol.md."
    ),
    modifiers(&SecuritySchemes),
    tags(
        (name = "machines", description = "Declaring machines and reading their status"),
        (name = "readings", description = "Sensor readings in, and their history out"),
        (name = "estimates", description = "What the engines estimate: history, live stream, learned models"),
        (name = "alignment", description = "The design axis a machine's deviation is measured from"),
        (name = "alarms", description = "Alarms raised by the rules, and their acknowledgement"),
        (name = "service", description = "Liveness, metrics and this document"),
        (name = "dashboard", description = "The control room's pages (HTML)"),
    ),
    components(schemas(Estimate, EstimateValues))
)]
pub struct ApiDoc;

/// Bearer tokens and the sign-in cookie.
struct SecuritySchemes;

impl Modify for SecuritySchemes {
    fn modify(&self, doc: &mut OpenApi) {
        let components = doc.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(
                HttpBuilder::new()
                    .scheme(HttpAuthScheme::Bearer)
                    .description(Some(
                        "A token from `tunnelnav token create`; the requirement's list names the role it needs.",
                    ))
                    .build(),
            ),
        );
        components.add_security_scheme(
            "session",
            SecurityScheme::ApiKey(ApiKey::Cookie(ApiKeyValue::with_description(
                COOKIE,
                "The same token, kept by the browser after signing in at /login.",
            ))),
        );
    }
}

/// The path parameter naming a machine.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Path)]
pub struct MachinePath {
    /// The machine's id: 1 to 64 ASCII letters, digits, `-` or `_`; at an
    /// office, a site's machine is `{site}.{machine}`.
    #[param(
        pattern = r"^[A-Za-z0-9_-]{1,64}(\.[A-Za-z0-9_-]{1,64})?$",
        example = "tbm-north"
    )]
    pub machine: String,
}

/// A time in a query: Unix seconds (milliseconds above 1e11) or RFC 3339.
pub fn query_time() -> Schema {
    OneOfBuilder::new()
        .item(
            ObjectBuilder::new()
                .schema_type(Type::Number)
                .description(Some("Unix seconds; above 1e11, Unix milliseconds")),
        )
        .item(
            ObjectBuilder::new()
                .schema_type(Type::String)
                .format(Some(utoipa::openapi::SchemaFormat::KnownFormat(
                    utoipa::openapi::KnownFormat::DateTime,
                )))
                .description(Some("RFC 3339, e.g. 2026-03-02T06:00:00Z")),
        )
        .into()
}

/// A number bounded as the reading validator bounds `field`.
fn bounded(field: &'static str, description: &str) -> ObjectBuilder {
    let (min, max) = field_bounds(field);
    ObjectBuilder::new()
        .schema_type(Type::Number)
        .minimum(Some(min))
        .maximum(Some(max))
        .description(Some(description))
}

/// As [`bounded`], or `null` (an optional field: the same as absent).
fn bounded_or_null(field: &'static str, description: &str) -> ObjectBuilder {
    bounded(field, description).schema_type(SchemaType::from_iter([Type::Number, Type::Null]))
}

/// Three numbers, each bounded as the validator bounds `field`.
fn bounded_triple(field: &'static str, description: &str) -> ArrayBuilder {
    ArrayBuilder::new()
        .items(bounded(field, "one component"))
        .min_items(Some(3))
        .max_items(Some(3))
        .description(Some(description))
}

/// One sensor's reading: its `sensor` name, `t` and its fields (required
/// first, then optional), each bounded as the validator bounds it.
fn sensor_reading(
    sensor: &str,
    description: &str,
    required: &[(&'static str, RefOr<Schema>)],
    optional: &[(&'static str, RefOr<Schema>)],
) -> Schema {
    let mut object = ObjectBuilder::new()
        .schema_type(Type::Object)
        .title(Some(sensor))
        .description(Some(description))
        .property(
            "t",
            bounded(
                "t",
                "Unix seconds (UTC) of the measurement; at most the server's `max_future_s` ahead of its clock",
            ),
        )
        .required("t")
        .property(
            "sensor",
            ObjectBuilder::new()
                .schema_type(Type::String)
                .enum_values(Some([sensor])),
        )
        .required("sensor");
    for (name, schema) in required {
        object = object.property(*name, schema.clone()).required(*name);
    }
    for (name, schema) in optional {
        object = object.property(*name, schema.clone());
    }
    object.into()
}

/// One reading as `POST .../readings` and the ingest socket take it
/// (docs/protocol.md, "Readings"). Readings are parsed by
/// `fusion::reading`; this schema is built from the same bounds table.
pub struct ReadingInput;

impl PartialSchema for ReadingInput {
    fn schema() -> RefOr<Schema> {
        let angle = |field, what: &str| RefOr::T(bounded(field, what).into());
        let triple = |field, what: &str| RefOr::T(bounded_triple(field, what).into());
        let optional = |field, what: &str| RefOr::T(bounded_or_null(field, what).into());
        OneOfBuilder::new()
            .description(Some(
                "A sensor reading, tagged by `sensor`. Unknown fields are ignored.",
            ))
            .item(sensor_reading(
                "laser",
                "Laser targeting system or total station: attitude and, where measured, the reference point's position (all three coordinates or none)",
                &[
                    ("pitch_deg", angle("pitch_deg", "nose up positive")),
                    ("roll_deg", angle("roll_deg", "right side down positive")),
                ],
                &[
                    ("yaw_deg", optional("yaw_deg", "clockwise from grid north")),
                    ("easting_m", optional("easting_m", "project easting")),
                    ("northing_m", optional("northing_m", "project northing")),
                    ("height_m", optional("height_m", "project height")),
                ],
            ))
            .item(sensor_reading(
                "inclinometer",
                "Two-axis gravity inclinometer",
                &[
                    ("pitch_deg", angle("pitch_deg", "nose up positive")),
                    ("roll_deg", angle("roll_deg", "right side down positive")),
                ],
                &[("temp_c", optional("temp_c", "sensor temperature"))],
            ))
            .item(sensor_reading(
                "imu",
                "Specific force and angular rate, body frame (x forward, y right, z down)",
                &[
                    ("accel_mps2", triple("accel_mps2", "specific force, m/s²")),
                    ("gyro_dps", triple("gyro_dps", "angular rate, °/s")),
                ],
                &[],
            ))
            .item(sensor_reading(
                "magnetometer",
                "Magnetic field, body frame",
                &[("field_ut", triple("field_ut", "µT"))],
                &[],
            ))
            .item(sensor_reading(
                "level",
                "Height from a level instrument",
                &[("height_m", angle("height_m", "height, m"))],
                &[],
            ))
            .item(sensor_reading(
                "odometer",
                "Travelled distance from an odometer or encoder",
                &[("distance_m", angle("distance_m", "distance, m"))],
                &[],
            ))
            .item(sensor_reading(
                "advance",
                "A ring built or a pipe pushed home: closes it in the `rings` log",
                &[(
                    "ring",
                    RefOr::T(
                        bounded("ring", "the ring's or pipe's number")
                            .schema_type(Type::Integer)
                            .into(),
                    ),
                )],
                &[
                    (
                        "strokes_mm",
                        RefOr::T(
                            ArrayBuilder::new()
                                .schema_type(SchemaType::from_iter([Type::Array, Type::Null]))
                                .items(bounded("strokes_mm", "one cylinder's stroke, mm"))
                                .min_items(Some(1))
                                .max_items(Some(crate::fusion::reading::MAX_STROKES))
                                .description(Some(
                                    "the thrust cylinders' strokes, in the gateway's order; null: as absent",
                                ))
                                .into(),
                        ),
                    ),
                    (
                        "key",
                        RefOr::T(
                            bounded_or_null(
                                "key",
                                "the key position the ring was built with (universal rings)",
                            )
                            .schema_type(SchemaType::from_iter([Type::Integer, Type::Null]))
                            .into(),
                        ),
                    ),
                ],
            ))
            .item(sensor_reading(
                "tail_clearance",
                "The gap between the shield's tail skin and the ring, evenly round it, clockwise from the top looking forward",
                &[(
                    "clearance_mm",
                    RefOr::T(
                        ArrayBuilder::new()
                            .items(bounded("clearance_mm", "one gap, mm"))
                            .min_items(Some(crate::fusion::reading::CLEARANCE_POINTS.0))
                            .max_items(Some(crate::fusion::reading::CLEARANCE_POINTS.1))
                            .description(Some("the gaps, from the top, clockwise"))
                            .into(),
                    ),
                )],
                &[],
            ))
            .into()
    }
}

impl ToSchema for ReadingInput {
    fn name() -> Cow<'static, str> {
        Cow::Borrowed("Reading")
    }
}

/// The JSON body of `POST .../readings`: one reading or an array of them.
pub struct ReadingsBody;

impl PartialSchema for ReadingsBody {
    fn schema() -> RefOr<Schema> {
        OneOfBuilder::new()
            .item(Ref::from_schema_name(ReadingInput::name()))
            .item(
                ArrayBuilder::new()
                    .items(Ref::from_schema_name(ReadingInput::name()))
                    .description(Some(
                        "At most the server's `max_readings_per_request` (default 100 000)",
                    )),
            )
            .into()
    }
}

impl ToSchema for ReadingsBody {
    fn schemas(schemas: &mut Vec<(String, RefOr<Schema>)>) {
        schemas.push((ReadingInput::name().into(), ReadingInput::schema()));
    }
}

/// A string that is one of `names`.
fn one_of_names(description: &str, names: impl IntoIterator<Item = &'static str>) -> RefOr<Schema> {
    ObjectBuilder::new()
        .schema_type(Type::String)
        .enum_values(Some(names))
        .description(Some(description))
        .into()
}

// The registry's kinds are named by its macro, which the schema derive
// cannot read: their schemas list the protocol names from the registry.
impl PartialSchema for EngineKind {
    fn schema() -> RefOr<Schema> {
        one_of_names(
            "An engine",
            EngineKind::ALL.iter().map(|engine| engine.as_str()),
        )
    }
}

impl ToSchema for EngineKind {}

impl PartialSchema for StreamKind {
    fn schema() -> RefOr<Schema> {
        one_of_names(
            "A stream of estimates: an engine or a stage",
            StreamKind::ALL.iter().map(|stream| stream.as_str()),
        )
    }
}

impl ToSchema for StreamKind {}

/// An estimate's stream-specific part, tagged by `engine` (the stream's
/// name): one of the engines' or stages' estimates.
pub struct EstimateValues;

impl PartialSchema for EstimateValues {
    fn schema() -> RefOr<Schema> {
        let mut union = OneOfBuilder::new().description(Some(
            "The stream's fields, tagged by `engine` (docs/protocol.md, \"Estimates\")",
        ));
        for &stream in StreamKind::ALL {
            let name = stream.schema().name;
            union = union.item(
                AllOfBuilder::new()
                    .item(
                        ObjectBuilder::new()
                            .schema_type(Type::Object)
                            .property(
                                "engine",
                                ObjectBuilder::new()
                                    .schema_type(Type::String)
                                    .enum_values(Some([stream.as_str()])),
                            )
                            .required("engine"),
                    )
                    .item(Ref::from_schema_name(name)),
            );
        }
        union.into()
    }
}

impl ToSchema for EstimateValues {
    fn schemas(schemas: &mut Vec<(String, RefOr<Schema>)>) {
        for &stream in StreamKind::ALL {
            stream.schema().collect(schemas);
        }
    }
}

/// An engine's model report: one of the engines' that have one.
pub struct EngineModelReport;

impl PartialSchema for EngineModelReport {
    fn schema() -> RefOr<Schema> {
        let mut union = OneOfBuilder::new().description(Some(
            "The engine's model report: what it has learned (docs/engines/)",
        ));
        for &engine in EngineKind::ALL {
            if let Some(model) = engine.model_schema() {
                union = union.item(Ref::from_schema_name(model.name));
            }
        }
        union.into()
    }
}

impl ToSchema for EngineModelReport {
    fn schemas(schemas: &mut Vec<(String, RefOr<Schema>)>) {
        for component in EngineKind::ALL.iter().filter_map(|&e| e.model_schema()) {
            component.collect(schemas);
        }
    }
}

/// One estimate as the API and the live stream write it: time, machine and
/// the stream's values.
pub struct Estimate;

impl PartialSchema for Estimate {
    fn schema() -> RefOr<Schema> {
        AllOfBuilder::new()
            .item(
                ObjectBuilder::new()
                    .schema_type(Type::Object)
                    .property(
                        "t",
                        ObjectBuilder::new()
                            .schema_type(Type::Number)
                            .description(Some("Time of the reading it was made at, Unix seconds")),
                    )
                    .required("t")
                    .property("machine", ObjectBuilder::new().schema_type(Type::String))
                    .required("machine")
                    .property("integrity", Ref::from_schema_name(IntegrityLevel::name()))
                    .required("integrity")
                    .property(
                        "integrity_reason",
                        OneOfBuilder::new()
                            .item(Ref::from_schema_name(IntegrityReason::name()))
                            .item(ObjectBuilder::new().schema_type(Type::Null))
                            .description(Some("Why it is not ok; null when ok")),
                    )
                    .required("integrity_reason"),
            )
            .item(Ref::from_schema_name(EstimateValues::name()))
            .into()
    }
}

impl ToSchema for Estimate {
    fn schemas(schemas: &mut Vec<(String, RefOr<Schema>)>) {
        schemas.push((IntegrityLevel::name().into(), IntegrityLevel::schema()));
        schemas.push((IntegrityReason::name().into(), IntegrityReason::schema()));
        schemas.push((EstimateValues::name().into(), EstimateValues::schema()));
        EstimateValues::schemas(schemas);
    }
}

/// Adds to every operation the error answers any of its kind can give, so
/// the handlers' annotations list only their own: 400 (parameters or
/// body), 401/403 (secured), 404 (a machine in the path), 408 (a request
/// that did not arrive in time), 413 (bodies), 503 (refusals: retry).
fn add_common_responses(doc: &mut OpenApi) {
    let error = |description: &str| {
        ResponseBuilder::new().description(description).content(
            "application/json",
            Content::new(Some(Ref::from_schema_name("ErrorBody"))),
        )
    };
    for (path, item) in doc.paths.paths.iter_mut() {
        for operation in operations_mut(item) {
            let input = has_input(operation);
            let body = operation.request_body.is_some();
            let secured = operation.security.as_ref().is_some_and(|s| !s.is_empty());
            let mut add = |status: &str, response: ResponseBuilder| {
                operation
                    .responses
                    .responses
                    .entry(status.to_string())
                    .or_insert_with(|| RefOr::T(response.build()));
            };
            if input {
                add(
                    "400",
                    error("The parameters or the body are not valid; the error says which"),
                );
            }
            if body {
                add(
                    "413",
                    error("The body is larger than the server's `max_body_bytes`"),
                );
            }
            if secured {
                add(
                    "401",
                    error("No token, or an unknown or revoked one (tokens exist)").header(
                        "WWW-Authenticate",
                        HeaderBuilder::new()
                            .schema(Some(ObjectBuilder::new().schema_type(Type::String)))
                            .build(),
                    ),
                );
                add(
                    "403",
                    error("The token's role does not allow this operation"),
                );
            }
            if path.contains("{machine}") {
                add("404", error("No machine has this id"));
            }
            add(
                "408",
                error("The request did not arrive within the server's `request_timeout_s`"),
            );
            add(
                "503",
                error("The server cannot take the request now (shutting down, store full, machine busy or restarting, too many clients, stalled); nothing of it was stored: retry")
                    .header(
                        "Retry-After",
                        HeaderBuilder::new()
                            .schema(Some(ObjectBuilder::new().schema_type(Type::Integer)))
                            .description(Some("Seconds to wait before retrying"))
                            .build(),
                    ),
            );
        }
    }
}

/// The operations of a path, whatever their method.
pub fn operations_mut(item: &mut PathItem) -> impl Iterator<Item = &mut Operation> {
    [
        item.get.as_mut(),
        item.put.as_mut(),
        item.post.as_mut(),
        item.delete.as_mut(),
        item.patch.as_mut(),
    ]
    .into_iter()
    .flatten()
}

/// True for an operation that takes parameters or a body the server checks.
fn has_input(operation: &Operation) -> bool {
    operation.request_body.is_some()
        || operation
            .parameters
            .as_ref()
            .is_some_and(|parameters| !parameters.is_empty())
}

/// The finished document: the routes' operations with the common answers.
pub fn finish(mut doc: OpenApi) -> OpenApi {
    add_common_responses(&mut doc);
    doc
}

/// The served document, serialized once.
#[derive(Debug, Clone)]
pub struct Document(pub Bytes);

/// This document.
///
/// `GET /api/v1/openapi.json`.
#[utoipa::path(get, path = "/api/v1/openapi.json", operation_id = "openapi", tag = "service",
    responses((status = OK, description = "This document (OpenAPI 3.1)", content_type = "application/json", body = Object)))]
pub async fn document(Extension(Document(json)): Extension<Document>) -> Response {
    ([(header::CONTENT_TYPE, "application/json")], json).into_response()
}

/// `GET /api/docs`: the document drawn by the bundled Swagger UI (no
/// network needed).
pub async fn page() -> Html<&'static str> {
    Html(DOCS_PAGE)
}

const DOCS_PAGE: &str = r#"<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>tunnelnav · API</title>
<link rel="icon" href="/static/favicon.svg" type="image/svg+xml">
<link rel="stylesheet" href="/static/vendor/swagger-ui/swagger-ui.css"></head>
<body><div id="api-docs"></div>
<script src="/static/vendor/swagger-ui/swagger-ui-bundle.js"></script>
<script src="/static/api-docs.js"></script>
</body></html>"#;

/// The answer to an ingest request or frame.
#[derive(Debug, serde::Serialize, serde::Deserialize, utoipa::ToSchema)]
pub struct Ack {
    /// Valid readings, now stored (including duplicates).
    pub accepted: usize,
    /// Of those, readings already stored before (same sensor and time).
    pub duplicates: usize,
    pub rejected: Vec<super::error::Rejected>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_stream_has_its_schema() {
        // A new engine or stage must say what its estimates look like.
        let mut schemas = Vec::new();
        EstimateValues::schemas(&mut schemas);
        for &stream in StreamKind::ALL {
            let name = stream.schema().name;
            assert!(schemas.iter().any(|(n, _)| *n == name), "{stream}");
        }
    }

    #[test]
    fn the_axis_schema_holds_the_scale_check_bounds() {
        use crate::fusion::alignment::{
            AlignmentSpec, MAX_COORDINATE_M, MAX_ELEMENT_M, MAX_GRADE_PCT, MAX_HEIGHT_M, Pvi,
            StartPose,
        };
        use crate::fusion::alignment::{ElementSpec, ProfileSpec};
        let json = |schema: RefOr<Schema>| serde_json::to_value(schema).unwrap();
        let start = json(StartPose::schema());
        assert_eq!(
            start["properties"]["easting_m"]["maximum"],
            MAX_COORDINATE_M
        );
        assert_eq!(
            start["properties"]["northing_m"]["minimum"],
            -MAX_COORDINATE_M
        );
        let spec = json(AlignmentSpec::schema());
        assert_eq!(
            spec["properties"]["start_station_m"]["maximum"],
            MAX_COORDINATE_M
        );
        let profile = json(ProfileSpec::schema());
        assert_eq!(
            profile["properties"]["start_height_m"]["maximum"],
            MAX_HEIGHT_M
        );
        assert_eq!(
            profile["properties"]["end_grade_pct"]["maximum"],
            MAX_GRADE_PCT
        );
        let pvi = json(Pvi::schema());
        assert_eq!(pvi["properties"]["station_m"]["maximum"], MAX_COORDINATE_M);
        assert_eq!(pvi["properties"]["height_m"]["minimum"], -MAX_HEIGHT_M);
        assert_eq!(
            pvi["properties"]["curve_length_m"]["maximum"],
            MAX_ELEMENT_M
        );
        let elements = json(ElementSpec::schema());
        for element in elements["oneOf"].as_array().unwrap() {
            assert_eq!(element["properties"]["length_m"]["maximum"], MAX_ELEMENT_M);
        }
    }

    #[test]
    fn reading_bounds_come_from_the_validator() {
        let json = serde_json::to_value(ReadingInput::schema()).unwrap();
        let laser = &json["oneOf"][0]["properties"];
        assert_eq!(laser["pitch_deg"]["minimum"], -90.0);
        assert_eq!(laser["pitch_deg"]["maximum"], 90.0);
        assert_eq!(laser["t"]["minimum"], 946_684_800.0);
        let imu = &json["oneOf"][2];
        assert_eq!(imu["properties"]["gyro_dps"]["items"]["maximum"], 10_000.0);
        assert_eq!(
            imu["required"],
            serde_json::json!(["t", "sensor", "accel_mps2", "gyro_dps"])
        );
    }
}

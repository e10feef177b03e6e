//! Sensor readings of the wire protocol (docs/protocol.md, "Readings").
//!
//! Parsing has a fast path (a strict scanner for the flat object a reading
//! is, [`scan`]), then serde straight into the same flat struct and, only
//! when that fails, a slow diagnostic path that re-reads the JSON to say
//! which field was wrong. Validation turns the flat struct into a typed [`Reading`]
//! or a [`ReadingError`] naming the field.

use serde::{Deserialize, Serialize};

mod scan;

/// Earliest accepted reading time: 2000-01-01T00:00:00Z.
pub const EARLIEST_T_S: f64 = 946_684_800.0;
/// Latest accepted reading time in the core: 2100-01-01T00:00:00Z. The
/// server adds its own "not far ahead of now" check (`max_future_s`); the
/// core has no clock.
pub const LATEST_T_S: f64 = 4_102_444_800.0;

/// The kinds of sensor a reading can come from.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Hash,
    PartialOrd,
    Ord,
    Serialize,
    Deserialize,
    utoipa::ToSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum SensorKind {
    Laser,
    Inclinometer,
    Imu,
    Magnetometer,
    Level,
    Odometer,
    Advance,
    TailClearance,
}

impl SensorKind {
    /// Every sensor kind, in protocol order.
    pub const ALL: [SensorKind; 8] = [
        SensorKind::Laser,
        SensorKind::Inclinometer,
        SensorKind::Imu,
        SensorKind::Magnetometer,
        SensorKind::Level,
        SensorKind::Odometer,
        SensorKind::Advance,
        SensorKind::TailClearance,
    ];

    /// The protocol name (`"laser"`, `"inclinometer"`, ...).
    pub fn as_str(self) -> &'static str {
        match self {
            SensorKind::Laser => "laser",
            SensorKind::Inclinometer => "inclinometer",
            SensorKind::Imu => "imu",
            SensorKind::Magnetometer => "magnetometer",
            SensorKind::Level => "level",
            SensorKind::Odometer => "odometer",
            SensorKind::Advance => "advance",
            SensorKind::TailClearance => "tail_clearance",
        }
    }

    /// Parses a protocol name.
    pub fn from_name(name: &str) -> Option<SensorKind> {
        SensorKind::ALL.into_iter().find(|k| k.as_str() == name)
    }
}

impl std::fmt::Display for SensorKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A point in project coordinates, metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ProjectPoint {
    pub easting_m: f64,
    pub northing_m: f64,
    pub height_m: f64,
}

/// What a sensor measured. Serialised with the protocol's `sensor` tag.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "sensor", rename_all = "snake_case")]
pub enum SensorData {
    /// Laser targeting system / total station: attitude, and where the
    /// system measures it, the position of the machine's reference point.
    Laser {
        pitch_deg: f64,
        roll_deg: f64,
        #[serde(skip_serializing_if = "Option::is_none")]
        yaw_deg: Option<f64>,
        #[serde(flatten, skip_serializing_if = "Option::is_none")]
        position: Option<ProjectPoint>,
    },
    /// Two-axis gravity inclinometer.
    Inclinometer {
        pitch_deg: f64,
        roll_deg: f64,
        #[serde(skip_serializing_if = "Option::is_none")]
        temp_c: Option<f64>,
    },
    /// Specific force (body frame x forward, y right, z down) and angular rate.
    Imu {
        accel_mps2: [f64; 3],
        gyro_dps: [f64; 3],
    },
    /// Magnetic field in the body frame.
    Magnetometer { field_ut: [f64; 3] },
    /// Height from a level instrument.
    Level { height_m: f64 },
    /// Travelled distance from an odometer or encoder.
    Odometer { distance_m: f64 },
    /// A ring built (a TBM) or a pipe pushed home (a jacked string): its
    /// number, the thrust cylinders' strokes if the gateway has them, and
    /// the key position the ring was built with, if it is a universal ring.
    Advance {
        ring: u64,
        #[serde(skip_serializing_if = "Option::is_none")]
        strokes_mm: Option<Vec<f64>>,
        #[serde(skip_serializing_if = "Option::is_none")]
        key: Option<u32>,
    },
    /// The gap between the shield's tail skin and the ring in it, mm, at
    /// 4 or more points evenly round the ring, clockwise from the top,
    /// looking forward.
    TailClearance { clearance_mm: Vec<f64> },
}

impl SensorData {
    /// Which sensor produced this data.
    pub fn kind(&self) -> SensorKind {
        match self {
            SensorData::Laser { .. } => SensorKind::Laser,
            SensorData::Inclinometer { .. } => SensorKind::Inclinometer,
            SensorData::Imu { .. } => SensorKind::Imu,
            SensorData::Magnetometer { .. } => SensorKind::Magnetometer,
            SensorData::Level { .. } => SensorKind::Level,
            SensorData::Odometer { .. } => SensorKind::Odometer,
            SensorData::Advance { .. } => SensorKind::Advance,
            SensorData::TailClearance { .. } => SensorKind::TailClearance,
        }
    }
}

/// One validated reading: a time and what was measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Reading {
    /// Seconds since the Unix epoch (UTC).
    pub t: f64,
    #[serde(flatten)]
    pub data: SensorData,
}

/// Why a reading was rejected. Every variant names the offending field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReadingError {
    #[error("invalid JSON: {0}")]
    Json(String),
    #[error("a reading must be a JSON object")]
    NotAnObject,
    #[error("missing field `{field}`")]
    Missing { field: &'static str },
    #[error("field `{field}` must be {expected}")]
    WrongType {
        field: &'static str,
        expected: &'static str,
    },
    #[error(
        "unknown sensor `{0}` (expected laser, inclinometer, imu, magnetometer, level, odometer or advance)"
    )]
    UnknownSensor(String),
    #[error("field `{field}` is not a finite number")]
    NonFinite { field: &'static str },
    #[error("field `{field}` = {value} is outside [{min}, {max}]")]
    OutOfRange {
        field: &'static str,
        value: f64,
        min: f64,
        max: f64,
    },
}

impl ReadingError {
    /// The field the error is about, if it is about one field.
    pub fn field(&self) -> Option<&'static str> {
        match self {
            ReadingError::Missing { field }
            | ReadingError::WrongType { field, .. }
            | ReadingError::NonFinite { field }
            | ReadingError::OutOfRange { field, .. } => Some(field),
            ReadingError::UnknownSensor(_) => Some("sensor"),
            ReadingError::Json(_) | ReadingError::NotAnObject => None,
        }
    }
}

/// Physical bounds of each numeric field: (field, min, max).
const BOUNDS: &[(&str, f64, f64)] = &[
    ("t", EARLIEST_T_S, LATEST_T_S),
    ("pitch_deg", -90.0, 90.0),
    ("roll_deg", -180.0, 180.0),
    ("yaw_deg", -360.0, 360.0),
    ("temp_c", -80.0, 200.0),
    // ±200 g and ±10 000 °/s: well beyond any machine, well short of garbage.
    ("accel_mps2", -2000.0, 2000.0),
    ("gyro_dps", -10_000.0, 10_000.0),
    // The Earth's field is ~50 µT; steel and motors can add a few mT.
    ("field_ut", -10_000.0, 10_000.0),
    ("height_m", -20_000.0, 20_000.0),
    ("distance_m", -1.0e7, 1.0e7),
    // Project grids (UTM, national grids) stay within 10 000 km.
    ("easting_m", -1.0e7, 1.0e7),
    ("northing_m", -1.0e7, 1.0e7),
    // Ring and pipe numbers: whole, from 0 to ten million.
    ("ring", 0.0, 1.0e7),
    // A thrust cylinder's stroke: up to 10 m.
    ("strokes_mm", 0.0, 10_000.0),
    // A key position: whole, at most 64 round a ring.
    ("key", 0.0, 63.0),
    // A tail clearance: a gap of up to a metre.
    ("clearance_mm", 0.0, 1000.0),
];

/// Points round the ring a `tail_clearance` reading gives, at least and at
/// most.
pub const CLEARANCE_POINTS: (usize, usize) = (4, 64);

/// Thrust cylinders an `advance` reading may give the strokes of.
pub const MAX_STROKES: usize = 64;

/// The bounds the validator holds `field` to, (min, max); unbounded for a
/// field it does not bound. (The OpenAPI document's reading schema reads
/// them too.)
pub fn field_bounds(field: &str) -> (f64, f64) {
    BOUNDS
        .iter()
        .find(|(name, _, _)| *name == field)
        .map(|&(_, lo, hi)| (lo, hi))
        .unwrap_or((f64::NEG_INFINITY, f64::INFINITY))
}

fn check(field: &'static str, value: f64) -> Result<f64, ReadingError> {
    if !value.is_finite() {
        return Err(ReadingError::NonFinite { field });
    }
    let (min, max) = field_bounds(field);
    if value < min || value > max {
        return Err(ReadingError::OutOfRange {
            field,
            value,
            min,
            max,
        });
    }
    Ok(value)
}

fn required(field: &'static str, value: Option<f64>) -> Result<f64, ReadingError> {
    check(field, value.ok_or(ReadingError::Missing { field })?)
}

fn optional(field: &'static str, value: Option<f64>) -> Result<Option<f64>, ReadingError> {
    value.map(|v| check(field, v)).transpose()
}

fn vector(field: &'static str, value: Option<[f64; 3]>) -> Result<[f64; 3], ReadingError> {
    let v = value.ok_or(ReadingError::Missing { field })?;
    for x in v {
        check(field, x)?;
    }
    Ok(v)
}

/// A ring number: a whole number within its bounds.
fn ring_number(value: f64) -> Result<u64, ReadingError> {
    if value.fract() != 0.0 {
        return Err(ReadingError::WrongType {
            field: "ring",
            expected: "a whole number",
        });
    }
    Ok(value as u64)
}

/// A key position: a whole number within bounds.
fn key_position(value: f64) -> Result<u32, ReadingError> {
    check("key", value)?;
    if value.fract() != 0.0 {
        return Err(ReadingError::WrongType {
            field: "key",
            expected: "a whole number",
        });
    }
    Ok(value as u32)
}

/// A tail clearance: 4 to 64 gaps within bounds.
fn clearances(values: Vec<f64>) -> Result<Vec<f64>, ReadingError> {
    if values.len() < CLEARANCE_POINTS.0 || values.len() > CLEARANCE_POINTS.1 {
        return Err(ReadingError::WrongType {
            field: "clearance_mm",
            expected: "an array of 4 to 64 numbers",
        });
    }
    for &v in &values {
        check("clearance_mm", v)?;
    }
    Ok(values)
}

/// Thrust-cylinder strokes: 1 to [`MAX_STROKES`] numbers within bounds.
fn strokes(values: Vec<f64>) -> Result<Vec<f64>, ReadingError> {
    if values.is_empty() || values.len() > MAX_STROKES {
        return Err(ReadingError::WrongType {
            field: "strokes_mm",
            expected: "an array of 1 to 64 numbers",
        });
    }
    for &v in &values {
        check("strokes_mm", v)?;
    }
    Ok(values)
}

/// The `sensor` field, matched without allocating for the known names.
#[derive(Debug)]
enum SensorTag {
    Known(SensorKind),
    Unknown(String),
}

impl<'de> Deserialize<'de> for SensorTag {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl serde::de::Visitor<'_> for Visitor {
            type Value = SensorTag;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a sensor name")
            }
            fn visit_str<E: serde::de::Error>(self, name: &str) -> Result<SensorTag, E> {
                Ok(match SensorKind::from_name(name) {
                    Some(kind) => SensorTag::Known(kind),
                    None => SensorTag::Unknown(name.to_string()),
                })
            }
        }
        deserializer.deserialize_str(Visitor)
    }
}

/// The flat shape every reading is first parsed into (fast path).
#[derive(Debug, Default, Deserialize)]
struct RawReading {
    t: Option<f64>,
    sensor: Option<SensorTag>,
    pitch_deg: Option<f64>,
    roll_deg: Option<f64>,
    yaw_deg: Option<f64>,
    temp_c: Option<f64>,
    accel_mps2: Option<[f64; 3]>,
    gyro_dps: Option<[f64; 3]>,
    field_ut: Option<[f64; 3]>,
    height_m: Option<f64>,
    distance_m: Option<f64>,
    easting_m: Option<f64>,
    northing_m: Option<f64>,
    ring: Option<f64>,
    strokes_mm: Option<Vec<f64>>,
    key: Option<f64>,
    clearance_mm: Option<Vec<f64>>,
}

impl RawReading {
    fn validate(self) -> Result<Reading, ReadingError> {
        let t = required("t", self.t)?;
        let kind = match self.sensor {
            None => return Err(ReadingError::Missing { field: "sensor" }),
            Some(SensorTag::Known(kind)) => kind,
            Some(SensorTag::Unknown(name)) => return Err(ReadingError::UnknownSensor(name)),
        };
        let data = match kind {
            SensorKind::Laser => SensorData::Laser {
                pitch_deg: required("pitch_deg", self.pitch_deg)?,
                roll_deg: required("roll_deg", self.roll_deg)?,
                yaw_deg: optional("yaw_deg", self.yaw_deg)?,
                position: match (self.easting_m, self.northing_m, self.height_m) {
                    (None, None, None) => None,
                    (e, n, h) => Some(ProjectPoint {
                        easting_m: required("easting_m", e)?,
                        northing_m: required("northing_m", n)?,
                        height_m: required("height_m", h)?,
                    }),
                },
            },
            SensorKind::Inclinometer => SensorData::Inclinometer {
                pitch_deg: required("pitch_deg", self.pitch_deg)?,
                roll_deg: required("roll_deg", self.roll_deg)?,
                temp_c: optional("temp_c", self.temp_c)?,
            },
            SensorKind::Imu => SensorData::Imu {
                accel_mps2: vector("accel_mps2", self.accel_mps2)?,
                gyro_dps: vector("gyro_dps", self.gyro_dps)?,
            },
            SensorKind::Magnetometer => SensorData::Magnetometer {
                field_ut: vector("field_ut", self.field_ut)?,
            },
            SensorKind::Level => SensorData::Level {
                height_m: required("height_m", self.height_m)?,
            },
            SensorKind::Odometer => SensorData::Odometer {
                distance_m: required("distance_m", self.distance_m)?,
            },
            SensorKind::Advance => SensorData::Advance {
                ring: ring_number(required("ring", self.ring)?)?,
                strokes_mm: self.strokes_mm.map(strokes).transpose()?,
                key: self.key.map(key_position).transpose()?,
            },
            SensorKind::TailClearance => SensorData::TailClearance {
                clearance_mm: clearances(self.clearance_mm.ok_or(ReadingError::Missing {
                    field: "clearance_mm",
                })?)?,
            },
        };
        Ok(Reading { t, data })
    }
}

/// The JSON type each known field must have, for error messages.
const FIELD_TYPES: &[(&str, FieldType)] = &[
    ("t", FieldType::Number),
    ("sensor", FieldType::Text),
    ("pitch_deg", FieldType::Number),
    ("roll_deg", FieldType::Number),
    ("yaw_deg", FieldType::Number),
    ("temp_c", FieldType::Number),
    ("accel_mps2", FieldType::Vector3),
    ("gyro_dps", FieldType::Vector3),
    ("field_ut", FieldType::Vector3),
    ("height_m", FieldType::Number),
    ("distance_m", FieldType::Number),
    ("ring", FieldType::Number),
    ("strokes_mm", FieldType::Numbers),
    ("key", FieldType::Number),
    ("clearance_mm", FieldType::Numbers),
];

#[derive(Clone, Copy)]
enum FieldType {
    Number,
    Text,
    Vector3,
    Numbers,
}

impl FieldType {
    fn accepts(self, value: &serde_json::Value) -> bool {
        match self {
            FieldType::Number => value.is_number() || value.is_null(),
            FieldType::Text => value.is_string() || value.is_null(),
            FieldType::Vector3 => {
                value.is_null()
                    || value
                        .as_array()
                        .is_some_and(|a| a.len() == 3 && a.iter().all(|x| x.is_number()))
            }
            FieldType::Numbers => {
                value.is_null()
                    || value
                        .as_array()
                        .is_some_and(|a| a.iter().all(|x| x.is_number()))
            }
        }
    }

    fn expected(self) -> &'static str {
        match self {
            FieldType::Number => "a number",
            FieldType::Text => "a string",
            FieldType::Vector3 => "an array of 3 numbers",
            FieldType::Numbers => "an array of numbers",
        }
    }
}

/// Explains why the fast path rejected a reading, naming the field.
fn diagnose(value: &serde_json::Value, fast_path_error: serde_json::Error) -> ReadingError {
    let Some(object) = value.as_object() else {
        return ReadingError::NotAnObject;
    };
    for &(field, ty) in FIELD_TYPES {
        if let Some(v) = object.get(field)
            && !ty.accepts(v)
        {
            return ReadingError::WrongType {
                field,
                expected: ty.expected(),
            };
        }
    }
    ReadingError::Json(fast_path_error.to_string())
}

/// Parses and validates one reading from its JSON text.
///
/// ```
/// use tunnelnav::fusion::{parse_reading, ReadingError, SensorKind};
///
/// let r = parse_reading(br#"{"t":1772431200,"sensor":"laser","pitch_deg":0.4,"roll_deg":1.1}"#).unwrap();
/// assert_eq!(r.sensor(), SensorKind::Laser);
///
/// let e = parse_reading(br#"{"t":1772431200,"sensor":"laser","pitch_deg":120,"roll_deg":1}"#);
/// assert_eq!(e.unwrap_err().field(), Some("pitch_deg"));
/// ```
pub fn parse_reading(bytes: &[u8]) -> Result<Reading, ReadingError> {
    match scan::scan(bytes) {
        Some(raw) => raw.validate(),
        None => parse_with_serde(bytes),
    }
}

/// [`parse_reading`] without the scanner: serde, and the diagnosis of
/// what it refused.
fn parse_with_serde(bytes: &[u8]) -> Result<Reading, ReadingError> {
    match serde_json::from_slice::<RawReading>(bytes) {
        Ok(raw) => raw.validate(),
        Err(e) => match serde_json::from_slice::<serde_json::Value>(bytes) {
            Ok(value) => Err(diagnose(&value, e)),
            Err(e) => Err(ReadingError::Json(e.to_string())),
        },
    }
}

/// Validates an already-parsed JSON value as a reading (elements of an array).
pub fn reading_from_value(value: &serde_json::Value) -> Result<Reading, ReadingError> {
    match RawReading::deserialize(value) {
        Ok(raw) => raw.validate(),
        Err(e) => Err(diagnose(value, e)),
    }
}

impl Reading {
    /// Checks a reading built in Rust against the same rules as a parsed one.
    pub fn validate(&self) -> Result<(), ReadingError> {
        check("t", self.t)?;
        match &self.data {
            SensorData::Laser {
                pitch_deg,
                roll_deg,
                yaw_deg,
                position,
            } => {
                check("pitch_deg", *pitch_deg)?;
                check("roll_deg", *roll_deg)?;
                optional("yaw_deg", *yaw_deg)?;
                if let Some(p) = position {
                    check("easting_m", p.easting_m)?;
                    check("northing_m", p.northing_m)?;
                    check("height_m", p.height_m)?;
                }
            }
            SensorData::Inclinometer {
                pitch_deg,
                roll_deg,
                temp_c,
            } => {
                check("pitch_deg", *pitch_deg)?;
                check("roll_deg", *roll_deg)?;
                optional("temp_c", *temp_c)?;
            }
            SensorData::Imu {
                accel_mps2,
                gyro_dps,
            } => {
                vector("accel_mps2", Some(*accel_mps2))?;
                vector("gyro_dps", Some(*gyro_dps))?;
            }
            SensorData::Magnetometer { field_ut } => {
                vector("field_ut", Some(*field_ut))?;
            }
            SensorData::Level { height_m } => {
                check("height_m", *height_m)?;
            }
            SensorData::Odometer { distance_m } => {
                check("distance_m", *distance_m)?;
            }
            SensorData::Advance {
                ring,
                strokes_mm,
                key,
            } => {
                check("ring", *ring as f64)?;
                if let Some(s) = strokes_mm {
                    strokes(s.clone())?;
                }
                if let Some(key) = key {
                    key_position(f64::from(*key))?;
                }
            }
            SensorData::TailClearance { clearance_mm } => {
                clearances(clearance_mm.clone())?;
            }
        }
        Ok(())
    }

    /// Which sensor produced this reading.
    pub fn sensor(&self) -> SensorKind {
        self.data.kind()
    }

    /// The reading as one line of protocol JSON.
    pub fn to_json(&self) -> String {
        // Serialising plain structs of finite floats cannot fail.
        serde_json::to_string(self).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_each_sensor_kind() {
        let lines = [
            r#"{"t":1772431200,"sensor":"laser","pitch_deg":0.5,"roll_deg":1.2,"yaw_deg":37.0}"#,
            r#"{"t":1772431200.5,"sensor":"inclinometer","pitch_deg":0.8,"roll_deg":1.3,"temp_c":21}"#,
            r#"{"t":1772431200,"sensor":"imu","accel_mps2":[0,0,-9.81],"gyro_dps":[0,0,0.004]}"#,
            r#"{"t":1772431200,"sensor":"magnetometer","field_ut":[20,1,43]}"#,
            r#"{"t":1772431200,"sensor":"level","height_m":12.5}"#,
            r#"{"t":1772431200,"sensor":"odometer","distance_m":3.25}"#,
            r#"{"t":1772431200,"sensor":"advance","ring":412,"strokes_mm":[1510.5,1498,1502.25,1507],"key":5}"#,
            r#"{"t":1772431200,"sensor":"tail_clearance","clearance_mm":[48,51.5,52,47.5,49,50,50.5,49]}"#,
        ];
        for (line, kind) in lines.iter().zip(SensorKind::ALL) {
            let r = parse_reading(line.as_bytes()).unwrap();
            assert_eq!(r.sensor(), kind);
            // The serialised form parses back to the same reading.
            assert_eq!(parse_reading(r.to_json().as_bytes()).unwrap(), r);
        }
    }

    #[test]
    fn a_laser_reading_may_carry_a_position_all_three_or_none() {
        let line = r#"{"t":1772431200,"sensor":"laser","pitch_deg":0.5,"roll_deg":1.2,"easting_m":1012.5,"northing_m":5021.25,"height_m":50.12}"#;
        let r = parse_reading(line.as_bytes()).unwrap();
        let SensorData::Laser { position, .. } = &r.data else {
            panic!("{r:?}")
        };
        assert_eq!(
            *position,
            Some(ProjectPoint {
                easting_m: 1012.5,
                northing_m: 5021.25,
                height_m: 50.12
            })
        );
        assert_eq!(parse_reading(r.to_json().as_bytes()).unwrap(), r);
        let partial = r#"{"t":1772431200,"sensor":"laser","pitch_deg":0.5,"roll_deg":1.2,"easting_m":1012.5,"height_m":50.12}"#;
        assert_eq!(
            parse_reading(partial.as_bytes()).unwrap_err(),
            ReadingError::Missing {
                field: "northing_m"
            }
        );
    }

    #[test]
    fn errors_name_the_field() {
        let cases: &[(&str, ReadingError)] = &[
            (
                r#"{"sensor":"laser","pitch_deg":0,"roll_deg":0}"#,
                ReadingError::Missing { field: "t" },
            ),
            (
                r#"{"t":1772431200,"sensor":"laser","roll_deg":0}"#,
                ReadingError::Missing { field: "pitch_deg" },
            ),
            (
                r#"{"t":1772431200,"sensor":"laser","pitch_deg":"0.1","roll_deg":0}"#,
                ReadingError::WrongType {
                    field: "pitch_deg",
                    expected: "a number",
                },
            ),
            (
                r#"{"t":1772431200,"sensor":"imu","accel_mps2":[0,0],"gyro_dps":[0,0,0]}"#,
                ReadingError::WrongType {
                    field: "accel_mps2",
                    expected: "an array of 3 numbers",
                },
            ),
            (
                r#"{"t":1772431200,"sensor":"laser","pitch_deg":91,"roll_deg":0}"#,
                ReadingError::OutOfRange {
                    field: "pitch_deg",
                    value: 91.0,
                    min: -90.0,
                    max: 90.0,
                },
            ),
            (
                r#"{"t":1772431200,"sensor":"sonar","pitch_deg":1}"#,
                ReadingError::UnknownSensor("sonar".into()),
            ),
            (r#"[1,2]"#, ReadingError::NotAnObject),
        ];
        for (line, expected) in cases {
            assert_eq!(
                &parse_reading(line.as_bytes()).unwrap_err(),
                expected,
                "{line}"
            );
        }
        let early = parse_reading(br#"{"t":100,"sensor":"level","height_m":1}"#).unwrap_err();
        assert_eq!(early.field(), Some("t"));
        assert!(matches!(
            parse_reading(b"{\"t\":1e999}").unwrap_err(),
            ReadingError::Json(_)
        ));
        assert!(matches!(
            parse_reading(b"{not json").unwrap_err(),
            ReadingError::Json(_)
        ));
    }

    #[test]
    fn a_key_is_whole_and_a_tail_clearance_has_4_to_64_gaps() {
        let keyed =
            parse_reading(br#"{"t":1772431200,"sensor":"advance","ring":7,"key":15}"#).unwrap();
        assert_eq!(
            keyed.to_json(),
            r#"{"t":1772431200.0,"sensor":"advance","ring":7,"key":15}"#
        );
        for (line, field) in [
            (
                r#"{"t":1772431200,"sensor":"advance","ring":7,"key":64}"#,
                "key",
            ),
            (
                r#"{"t":1772431200,"sensor":"advance","ring":7,"key":1.5}"#,
                "key",
            ),
            (
                r#"{"t":1772431200,"sensor":"tail_clearance","clearance_mm":[50,50,50]}"#,
                "clearance_mm",
            ),
            (
                r#"{"t":1772431200,"sensor":"tail_clearance","clearance_mm":[50,50,50,-1]}"#,
                "clearance_mm",
            ),
            (
                r#"{"t":1772431200,"sensor":"tail_clearance"}"#,
                "clearance_mm",
            ),
        ] {
            let e = parse_reading(line.as_bytes()).unwrap_err();
            assert_eq!(e.field(), Some(field), "{line}: {e}");
        }
    }

    #[test]
    fn an_advance_has_a_whole_ring_number_and_at_most_64_strokes_in_bounds() {
        let plain = parse_reading(br#"{"t":1772431200,"sensor":"advance","ring":0}"#).unwrap();
        assert_eq!(
            plain.data,
            SensorData::Advance {
                ring: 0,
                strokes_mm: None,
                key: None,
            }
        );
        assert_eq!(
            plain.to_json(),
            r#"{"t":1772431200.0,"sensor":"advance","ring":0}"#
        );
        let wrong = |line: &str| parse_reading(line.as_bytes()).unwrap_err();
        assert_eq!(
            wrong(r#"{"t":1772431200,"sensor":"advance"}"#),
            ReadingError::Missing { field: "ring" }
        );
        assert_eq!(
            wrong(r#"{"t":1772431200,"sensor":"advance","ring":12.5}"#).field(),
            Some("ring")
        );
        assert_eq!(
            wrong(r#"{"t":1772431200,"sensor":"advance","ring":-1}"#).field(),
            Some("ring")
        );
        assert_eq!(
            wrong(r#"{"t":1772431200,"sensor":"advance","ring":3,"strokes_mm":[]}"#).field(),
            Some("strokes_mm")
        );
        assert_eq!(
            wrong(r#"{"t":1772431200,"sensor":"advance","ring":3,"strokes_mm":[1,"2"]}"#),
            ReadingError::WrongType {
                field: "strokes_mm",
                expected: "an array of numbers"
            }
        );
        assert!(matches!(
            wrong(r#"{"t":1772431200,"sensor":"advance","ring":3,"strokes_mm":[1,20000]}"#),
            ReadingError::OutOfRange {
                field: "strokes_mm",
                ..
            }
        ));
        let many = format!(
            r#"{{"t":1772431200,"sensor":"advance","ring":3,"strokes_mm":[{}]}}"#,
            vec!["1"; 65].join(",")
        );
        assert_eq!(wrong(&many).field(), Some("strokes_mm"));
    }

    #[test]
    fn value_path_matches_text_path() {
        let text = r#"{"t":1772431200,"sensor":"laser","pitch_deg":true,"roll_deg":0}"#;
        let value: serde_json::Value = serde_json::from_str(text).unwrap();
        assert_eq!(
            reading_from_value(&value).unwrap_err(),
            parse_reading(text.as_bytes()).unwrap_err()
        );
    }

    #[test]
    fn rust_built_readings_are_checked_too() {
        let r = Reading {
            t: 1_772_431_200.0,
            data: SensorData::Inclinometer {
                pitch_deg: f64::NAN,
                roll_deg: 0.0,
                temp_c: None,
            },
        };
        assert_eq!(
            r.validate().unwrap_err(),
            ReadingError::NonFinite { field: "pitch_deg" }
        );
    }
}

//! What the `fuzzy` engine emits per IMU reading: the protocol's fields,
//! their NDJSON form and their stored form (and the form earlier releases
//! stored).

use serde::{Deserialize, Serialize};

use super::magcal::CalibrationState;
use crate::fusion::descriptor::{SignalKind, Signals, StreamValues};
use crate::fusion::json_fields::JsonFields;

/// The `fuzzy` engine's decision of the motion status.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Motion {
    Static,
    Moving,
}

impl Motion {
    /// The protocol name.
    pub fn as_str(self) -> &'static str {
        match self {
            Motion::Static => "static",
            Motion::Moving => "moving",
        }
    }
}

/// Whether the compass steers the heading now, and if not, why.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum CompassState {
    /// A fresh calibrated reading passed every check: it steers the heading.
    Believed,
    /// Not yet calibrated: the raw compass holds the heading it gave at
    /// alignment while its field is unchanged (its absolute error unknown).
    Raw,
    /// Not yet calibrated and the raw field has changed: not used.
    Collecting,
    /// The field departs from the site's in magnitude or dip: not used.
    Disturbed,
    /// It disagrees with the gyro-carried heading beyond the gate: not
    /// used (believed again if it keeps disagreeing for `heading_gate_s`).
    Gated,
    /// No magnetometer reading young enough.
    Absent,
}

impl CompassState {
    /// The protocol name.
    pub fn as_str(self) -> &'static str {
        match self {
            CompassState::Believed => "believed",
            CompassState::Raw => "raw",
            CompassState::Collecting => "collecting",
            CompassState::Disturbed => "disturbed",
            CompassState::Gated => "gated",
            CompassState::Absent => "absent",
        }
    }
}

/// What the `fuzzy` engine estimates at one IMU reading.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct FuzzyEstimate {
    /// `static` when `static_degree` reaches the engine's threshold.
    pub motion: Motion,
    /// The motion expert's degree of "static", in [0, 1].
    pub static_degree: f64,
    pub pitch_deg: f64,
    pub roll_deg: f64,
    /// True heading (magnetic plus declination), clockwise from north, [0, 360).
    pub heading_deg: f64,
    /// One-sigma uncertainty of `pitch_deg`, `roll_deg` and `heading_deg`;
    /// `null` before alignment. A heading no calibrated compass has given
    /// is unknown: 103.9° (π/√3, uniform over a full turn).
    pub pitch_sigma_deg: Option<f64>,
    pub roll_sigma_deg: Option<f64>,
    pub heading_sigma_deg: Option<f64>,
    /// Current gyro drift estimate, subtracted from every reading.
    pub gyro_bias_dps: [f64; 3],
    /// False until a still window has levelled the platform and fixed the
    /// first gyro bias (tunnelnav extension, as are the fields below).
    pub aligned: bool,
    /// Magnetometer calibration: `collecting`, `planar`, `ellipsoid` or `raw`.
    pub mag_calibration: CalibrationState,
    /// Azimuth of the field seen so far, degrees (of 360).
    pub mag_coverage_deg: f64,
    /// RMS relative radius error of the calibration fit; `null` before one.
    pub mag_fit_rms: Option<f64>,
    /// True heading from the newest calibrated, tilt-compensated
    /// magnetometer reading alone; `null` before calibration.
    pub mag_heading_deg: Option<f64>,
    /// The motion expert's inputs.
    pub accel_dev_mps2: f64,
    pub accel_activity_mps2: f64,
    pub gyro_activity_dps: f64,
    /// One-sigma uncertainty of `gyro_bias_dps` per axis; `null` before
    /// alignment.
    pub gyro_bias_sigma_dps: Option<[f64; 3]>,
    /// True while the magnetometer field departs from the site's in
    /// magnitude or dip (a magnet, steel nearby): the compass is not used.
    pub mag_disturbed: bool,
    /// Whether the compass steers the heading now, and since when (Unix
    /// seconds); `null` in estimates stored before they said so.
    pub compass: Option<CompassState>,
    pub compass_since: Option<f64>,
}

/// Stored estimates of this release: postcard of [`FuzzyEstimate`].
/// 1: before the bias σ and the disturbance flag ([`FuzzyEstimateV1`]);
/// 2: before the attitude σ and the compass state ([`FuzzyEstimateV2`]).
pub const CODEC_VERSION: u32 = 3;

impl StreamValues for FuzzyEstimate {
    const CODEC_VERSION: u32 = CODEC_VERSION;
    const SIGNALS: &'static [SignalKind] = &[];

    fn write_fields(&self, w: &mut JsonFields<'_>) {
        w.word("motion", self.motion.as_str());
        w.number("static_degree", self.static_degree);
        w.number("pitch_deg", self.pitch_deg);
        w.number("roll_deg", self.roll_deg);
        w.number("heading_deg", self.heading_deg);
        w.optional("pitch_sigma_deg", self.pitch_sigma_deg);
        w.optional("roll_sigma_deg", self.roll_sigma_deg);
        w.optional("heading_sigma_deg", self.heading_sigma_deg);
        w.triple("gyro_bias_dps", &self.gyro_bias_dps);
        w.flag("aligned", self.aligned);
        w.word("mag_calibration", self.mag_calibration.as_str());
        w.number("mag_coverage_deg", self.mag_coverage_deg);
        w.optional("mag_fit_rms", self.mag_fit_rms);
        w.optional("mag_heading_deg", self.mag_heading_deg);
        w.number("accel_dev_mps2", self.accel_dev_mps2);
        w.number("accel_activity_mps2", self.accel_activity_mps2);
        w.number("gyro_activity_dps", self.gyro_activity_dps);
        match &self.gyro_bias_sigma_dps {
            Some(sigma) => w.triple("gyro_bias_sigma_dps", sigma),
            None => w.null("gyro_bias_sigma_dps"),
        }
        w.flag("mag_disturbed", self.mag_disturbed);
        match self.compass {
            Some(state) => w.word("compass", state.as_str()),
            None => w.null("compass"),
        }
        w.optional("compass_since", self.compass_since);
    }

    /// 0: stored before rows carried their version: version 2, or 1
    /// where that fails.
    fn decode(version: u32, bytes: &[u8]) -> Result<FuzzyEstimate, postcard::Error> {
        match version {
            0 => postcard::from_bytes::<FuzzyEstimateV2>(bytes)
                .map(FuzzyEstimate::from)
                .or_else(|_| {
                    postcard::from_bytes::<FuzzyEstimateV1>(bytes)
                        .map(FuzzyEstimateV2::from)
                        .map(FuzzyEstimate::from)
                }),
            1 => postcard::from_bytes::<FuzzyEstimateV1>(bytes)
                .map(FuzzyEstimateV2::from)
                .map(FuzzyEstimate::from),
            2 => postcard::from_bytes::<FuzzyEstimateV2>(bytes).map(FuzzyEstimate::from),
            3 => postcard::from_bytes(bytes),
            _ => Err(postcard::Error::DeserializeBadEncoding),
        }
    }

    /// Pitch and roll.
    fn extremes(&self) -> [f64; 2] {
        [self.pitch_deg, self.roll_deg]
    }

    /// None: no alarm rule watches this engine (its tilt and heading σ
    /// are in the estimate itself).
    fn signals(&self) -> Signals {
        Signals::default()
    }
}

/// A `fuzzy` estimate as releases before the gyro bias σ and the
/// disturbance flag stored it (codec version 1).
#[derive(Deserialize)]
struct FuzzyEstimateV1 {
    motion: Motion,
    static_degree: f64,
    pitch_deg: f64,
    roll_deg: f64,
    heading_deg: f64,
    gyro_bias_dps: [f64; 3],
    aligned: bool,
    mag_calibration: CalibrationState,
    mag_coverage_deg: f64,
    mag_fit_rms: Option<f64>,
    mag_heading_deg: Option<f64>,
    accel_dev_mps2: f64,
    accel_activity_mps2: f64,
    gyro_activity_dps: f64,
}

impl From<FuzzyEstimateV1> for FuzzyEstimateV2 {
    fn from(v: FuzzyEstimateV1) -> FuzzyEstimateV2 {
        FuzzyEstimateV2 {
            motion: v.motion,
            static_degree: v.static_degree,
            pitch_deg: v.pitch_deg,
            roll_deg: v.roll_deg,
            heading_deg: v.heading_deg,
            gyro_bias_dps: v.gyro_bias_dps,
            aligned: v.aligned,
            mag_calibration: v.mag_calibration,
            mag_coverage_deg: v.mag_coverage_deg,
            mag_fit_rms: v.mag_fit_rms,
            mag_heading_deg: v.mag_heading_deg,
            accel_dev_mps2: v.accel_dev_mps2,
            accel_activity_mps2: v.accel_activity_mps2,
            gyro_activity_dps: v.gyro_activity_dps,
            gyro_bias_sigma_dps: None,
            mag_disturbed: false,
        }
    }
}

/// A `fuzzy` estimate as releases before the attitude σ and the compass
/// state stored it (codec version 2).
#[derive(Deserialize)]
struct FuzzyEstimateV2 {
    motion: Motion,
    static_degree: f64,
    pitch_deg: f64,
    roll_deg: f64,
    heading_deg: f64,
    gyro_bias_dps: [f64; 3],
    aligned: bool,
    mag_calibration: CalibrationState,
    mag_coverage_deg: f64,
    mag_fit_rms: Option<f64>,
    mag_heading_deg: Option<f64>,
    accel_dev_mps2: f64,
    accel_activity_mps2: f64,
    gyro_activity_dps: f64,
    gyro_bias_sigma_dps: Option<[f64; 3]>,
    mag_disturbed: bool,
}

impl From<FuzzyEstimateV2> for FuzzyEstimate {
    fn from(v: FuzzyEstimateV2) -> FuzzyEstimate {
        FuzzyEstimate {
            motion: v.motion,
            static_degree: v.static_degree,
            pitch_deg: v.pitch_deg,
            roll_deg: v.roll_deg,
            heading_deg: v.heading_deg,
            pitch_sigma_deg: None,
            roll_sigma_deg: None,
            heading_sigma_deg: None,
            gyro_bias_dps: v.gyro_bias_dps,
            aligned: v.aligned,
            mag_calibration: v.mag_calibration,
            mag_coverage_deg: v.mag_coverage_deg,
            mag_fit_rms: v.mag_fit_rms,
            mag_heading_deg: v.mag_heading_deg,
            accel_dev_mps2: v.accel_dev_mps2,
            accel_activity_mps2: v.accel_activity_mps2,
            gyro_activity_dps: v.gyro_activity_dps,
            gyro_bias_sigma_dps: v.gyro_bias_sigma_dps,
            mag_disturbed: v.mag_disturbed,
            compass: None,
            compass_since: None,
        }
    }
}

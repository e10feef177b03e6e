//! Estimates of the wire protocol (`shared/protocol.md`, "Estimates").

use serde::{Deserialize, Serialize};

/// What the `attitude` engine estimates at one inclinometer reading.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AttitudeEstimate {
    /// Fused pitch at `t` (Eq. 19), nose up positive.
    pub pitch_deg: f64,
    /// Fused roll at `t` (Eq. 11), right side down positive.
    pub roll_deg: f64,
    /// One-step-ahead pitch prediction for `pred_t` (Eq. 12).
    pub pitch_pred_deg: f64,
    /// One-step-ahead roll prediction for `pred_t` (Eq. 13).
    pub roll_pred_deg: f64,
    /// The time the predictions are for, Unix seconds.
    pub pred_t: f64,
    /// False while the laser is in dropout or has not been seen yet.
    pub laser_ok: bool,
    /// The modelled inclinometer pitch error ê_a added to the inclinometer (Eq. 18).
    pub pitch_correction_deg: f64,
    /// Age of the held laser sample at `t`; `null` before the first one.
    /// (tunnelnav extension: lets a display say how long the laser is out.)
    pub laser_age_s: Option<f64>,
    /// Number of times the pitch-error model has been trained; a client
    /// refetches the model when it changes. (tunnelnav extension.)
    pub model_version: u64,
    /// The inclinometer reading this estimate was made from, as received
    /// (tunnelnav extension: a display plots raw against fused).
    pub incl_pitch_deg: f64,
    /// See `incl_pitch_deg`.
    pub incl_roll_deg: f64,
}

/// What the `zupt` engine estimates at one IMU reading.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ZuptEstimate {
    /// True where the detector declares zero velocity.
    pub zv: bool,
    /// North, east, down of the start point.
    pub position_m: [f64; 3],
    /// Along-track distance travelled: displacement along the body's x axis.
    pub distance_m: f64,
    /// North, east, down.
    pub velocity_mps: [f64; 3],
    pub pitch_deg: f64,
    pub roll_deg: f64,
    /// Clockwise from north, in [0, 360).
    pub yaw_deg: f64,
    /// False until the first still window levels the platform: until then
    /// position and velocity are zero and the attitude is the raw levelling
    /// (tunnelnav extension, as are the fields below).
    pub aligned: bool,
    /// 1σ of the position error (north, east, down) from the filter's covariance.
    pub position_sigma_m: [f64; 3],
    /// Height from the level datum (start point's height as first levelled
    /// minus `position_m` down); `null` before the first level reading.
    pub height_m: Option<f64>,
    /// The newest odometer distance at `t`; `null` before the first.
    pub odometer_m: Option<f64>,
    /// Each test statistic over its threshold γ (below 1: still).
    pub mv_ratio: f64,
    pub are_ratio: f64,
    pub shoe_ratio: f64,
    pub mag_ratio: f64,
    /// 1σ of the heading from the filter's covariance, degrees; `null`
    /// before alignment (and in estimates stored before it was reported).
    pub yaw_sigma_deg: Option<f64>,
    /// On the estimate at which a push ends (the first epoch decided still
    /// after it): the push's track smoothed over both of its still ends,
    /// from the last still epoch before it, about one point a second;
    /// `null` on every other estimate.
    pub smoothed_push: Option<Vec<TrackPoint>>,
}

/// A point of a smoothed track.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrackPoint {
    pub t: f64,
    /// North, east, down of the start point.
    pub position_m: [f64; 3],
    /// Along-track distance.
    pub distance_m: f64,
    /// 1σ of the smoothed position.
    pub position_sigma_m: [f64; 3],
}

/// The `fuzzy` engine's decision of the motion status.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
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

/// What the `fuzzy` engine estimates at one IMU reading.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FuzzyEstimate {
    /// `static` when `static_degree` reaches the engine's threshold.
    pub motion: Motion,
    /// The motion expert's degree of "static", in [0, 1].
    pub static_degree: f64,
    pub pitch_deg: f64,
    pub roll_deg: f64,
    /// True heading (magnetic plus declination), clockwise from north, [0, 360).
    pub heading_deg: f64,
    /// Current gyro drift estimate, subtracted from every reading.
    pub gyro_bias_dps: [f64; 3],
    /// False until a still window has levelled the platform and fixed the
    /// first gyro bias (tunnelnav extension, as are the fields below).
    pub aligned: bool,
    /// Magnetometer calibration: `collecting`, `planar`, `ellipsoid` or `raw`.
    pub mag_calibration: crate::fusion::fuzzy::magcal::CalibrationState,
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
}

/// The engine-specific part of an estimate, tagged by `engine`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "engine", rename_all = "snake_case")]
pub enum EstimateValues {
    Attitude(AttitudeEstimate),
    Zupt(ZuptEstimate),
    Fuzzy(FuzzyEstimate),
}

impl EstimateValues {
    /// The engine that produced these values.
    pub fn engine(&self) -> super::EngineKind {
        match self {
            EstimateValues::Attitude(_) => super::EngineKind::Attitude,
            EstimateValues::Zupt(_) => super::EngineKind::Zupt,
            EstimateValues::Fuzzy(_) => super::EngineKind::Fuzzy,
        }
    }

    /// The `attitude` engine's values, if these are.
    pub fn as_attitude(&self) -> Option<&AttitudeEstimate> {
        match self {
            EstimateValues::Attitude(a) => Some(a),
            _ => None,
        }
    }

    /// The `zupt` engine's values, if these are.
    pub fn as_zupt(&self) -> Option<&ZuptEstimate> {
        match self {
            EstimateValues::Zupt(z) => Some(z),
            _ => None,
        }
    }

    /// The `fuzzy` engine's values, if these are.
    pub fn as_fuzzy(&self) -> Option<&FuzzyEstimate> {
        match self {
            EstimateValues::Fuzzy(f) => Some(f),
            _ => None,
        }
    }

    /// The two quantities whose extremes history downsampling keeps, so a
    /// spike stays visible at any zoom (attitude: pitch, roll; zupt:
    /// distance, depth; fuzzy: pitch, roll).
    pub fn extremes(&self) -> [f64; 2] {
        match self {
            EstimateValues::Attitude(a) => [a.pitch_deg, a.roll_deg],
            EstimateValues::Zupt(z) => [z.distance_m, z.position_m[2]],
            EstimateValues::Fuzzy(f) => [f.pitch_deg, f.roll_deg],
        }
    }
}

/// What an engine emits: an estimate before it is attributed to a machine.
#[derive(Debug, Clone, PartialEq)]
pub struct EngineOutput {
    /// Time of the reading that produced the estimate, Unix seconds.
    pub t: f64,
    pub values: EstimateValues,
}

/// A complete protocol estimate: time, machine, engine and values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    pub t: f64,
    pub machine: String,
    #[serde(flatten)]
    pub values: EstimateValues,
}

/// Borrowing form of [`Estimate`] for writing without copying the machine id.
#[derive(Serialize)]
pub struct EstimateRef<'a> {
    pub t: f64,
    pub machine: &'a str,
    #[serde(flatten)]
    pub values: &'a EstimateValues,
}

impl EngineOutput {
    /// Attributes the output to a machine, borrowing both.
    pub fn for_machine<'a>(&'a self, machine: &'a str) -> EstimateRef<'a> {
        EstimateRef {
            t: self.t,
            machine,
            values: &self.values,
        }
    }
}

/// Writes estimates as NDJSON lines, byte for byte what serde_json writes
/// for [`EngineOutput::for_machine`], without serde's per-field overhead
/// (the float and integer formatters are the ones serde_json uses). Used
/// on replay's hot path; the tests hold it to serde_json's output.
pub struct EstimateWriter {
    /// `"machine":"<id>"`, escaped once.
    machine_field: Vec<u8>,
    floats: zmij::Buffer,
    integers: itoa::Buffer,
}

impl EstimateWriter {
    /// A writer for one machine's estimates.
    pub fn new(machine: &str) -> EstimateWriter {
        let mut machine_field = b"\"machine\":".to_vec();
        // Serialising a string into a Vec cannot fail.
        let _ = serde_json::to_writer(&mut machine_field, machine);
        EstimateWriter {
            machine_field,
            floats: zmij::Buffer::new(),
            integers: itoa::Buffer::new(),
        }
    }

    /// Appends `output` and a newline to `out`.
    pub fn write_line(&mut self, output: &EngineOutput, out: &mut Vec<u8>) {
        out.push(b'{');
        self.number(out, "t", output.t);
        out.push(b',');
        out.extend_from_slice(&self.machine_field);
        match &output.values {
            EstimateValues::Attitude(a) => {
                out.extend_from_slice(b",\"engine\":\"attitude\"");
                for (key, value) in [
                    ("pitch_deg", a.pitch_deg),
                    ("roll_deg", a.roll_deg),
                    ("pitch_pred_deg", a.pitch_pred_deg),
                    ("roll_pred_deg", a.roll_pred_deg),
                    ("pred_t", a.pred_t),
                ] {
                    out.push(b',');
                    self.number(out, key, value);
                }
                out.extend_from_slice(if a.laser_ok {
                    b",\"laser_ok\":true"
                } else {
                    b",\"laser_ok\":false"
                });
                out.push(b',');
                self.number(out, "pitch_correction_deg", a.pitch_correction_deg);
                out.extend_from_slice(b",\"laser_age_s\":");
                match a.laser_age_s {
                    Some(age) => self.float(out, age),
                    None => out.extend_from_slice(b"null"),
                }
                out.extend_from_slice(b",\"model_version\":");
                out.extend_from_slice(self.integers.format(a.model_version).as_bytes());
                for (key, value) in [
                    ("incl_pitch_deg", a.incl_pitch_deg),
                    ("incl_roll_deg", a.incl_roll_deg),
                ] {
                    out.push(b',');
                    self.number(out, key, value);
                }
            }
            EstimateValues::Zupt(z) => {
                out.extend_from_slice(b",\"engine\":\"zupt\"");
                self.flag(out, "zv", z.zv);
                self.triple(out, "position_m", &z.position_m);
                out.push(b',');
                self.number(out, "distance_m", z.distance_m);
                self.triple(out, "velocity_mps", &z.velocity_mps);
                for (key, value) in [
                    ("pitch_deg", z.pitch_deg),
                    ("roll_deg", z.roll_deg),
                    ("yaw_deg", z.yaw_deg),
                ] {
                    out.push(b',');
                    self.number(out, key, value);
                }
                self.flag(out, "aligned", z.aligned);
                self.triple(out, "position_sigma_m", &z.position_sigma_m);
                self.optional(out, "height_m", z.height_m);
                self.optional(out, "odometer_m", z.odometer_m);
                for (key, value) in [
                    ("mv_ratio", z.mv_ratio),
                    ("are_ratio", z.are_ratio),
                    ("shoe_ratio", z.shoe_ratio),
                    ("mag_ratio", z.mag_ratio),
                ] {
                    out.push(b',');
                    self.number(out, key, value);
                }
                self.optional(out, "yaw_sigma_deg", z.yaw_sigma_deg);
                out.extend_from_slice(b",\"smoothed_push\":");
                match &z.smoothed_push {
                    None => out.extend_from_slice(b"null"),
                    Some(points) => {
                        out.push(b'[');
                        for (i, point) in points.iter().enumerate() {
                            if i > 0 {
                                out.push(b',');
                            }
                            out.push(b'{');
                            self.number(out, "t", point.t);
                            self.triple(out, "position_m", &point.position_m);
                            out.push(b',');
                            self.number(out, "distance_m", point.distance_m);
                            self.triple(out, "position_sigma_m", &point.position_sigma_m);
                            out.push(b'}');
                        }
                        out.push(b']');
                    }
                }
            }
            EstimateValues::Fuzzy(f) => {
                out.extend_from_slice(b",\"engine\":\"fuzzy\",\"motion\":\"");
                out.extend_from_slice(f.motion.as_str().as_bytes());
                out.push(b'"');
                for (key, value) in [
                    ("static_degree", f.static_degree),
                    ("pitch_deg", f.pitch_deg),
                    ("roll_deg", f.roll_deg),
                    ("heading_deg", f.heading_deg),
                ] {
                    out.push(b',');
                    self.number(out, key, value);
                }
                self.triple(out, "gyro_bias_dps", &f.gyro_bias_dps);
                self.flag(out, "aligned", f.aligned);
                out.extend_from_slice(b",\"mag_calibration\":\"");
                out.extend_from_slice(f.mag_calibration.as_str().as_bytes());
                out.extend_from_slice(b"\",");
                self.number(out, "mag_coverage_deg", f.mag_coverage_deg);
                self.optional(out, "mag_fit_rms", f.mag_fit_rms);
                self.optional(out, "mag_heading_deg", f.mag_heading_deg);
                for (key, value) in [
                    ("accel_dev_mps2", f.accel_dev_mps2),
                    ("accel_activity_mps2", f.accel_activity_mps2),
                    ("gyro_activity_dps", f.gyro_activity_dps),
                ] {
                    out.push(b',');
                    self.number(out, key, value);
                }
                match &f.gyro_bias_sigma_dps {
                    Some(sigma) => self.triple(out, "gyro_bias_sigma_dps", sigma),
                    None => out.extend_from_slice(b",\"gyro_bias_sigma_dps\":null"),
                }
                self.flag(out, "mag_disturbed", f.mag_disturbed);
            }
        }
        out.extend_from_slice(b"}\n");
    }

    /// `,"key":true|false`
    fn flag(&mut self, out: &mut Vec<u8>, key: &str, value: bool) {
        out.extend_from_slice(b",\"");
        out.extend_from_slice(key.as_bytes());
        out.extend_from_slice(if value { b"\":true" } else { b"\":false" });
    }

    /// `,"key":[x,y,z]`
    fn triple(&mut self, out: &mut Vec<u8>, key: &str, values: &[f64; 3]) {
        out.extend_from_slice(b",\"");
        out.extend_from_slice(key.as_bytes());
        out.extend_from_slice(b"\":[");
        for (i, value) in values.iter().enumerate() {
            if i > 0 {
                out.push(b',');
            }
            self.float(out, *value);
        }
        out.push(b']');
    }

    /// `,"key":number|null`
    fn optional(&mut self, out: &mut Vec<u8>, key: &str, value: Option<f64>) {
        out.extend_from_slice(b",\"");
        out.extend_from_slice(key.as_bytes());
        out.extend_from_slice(b"\":");
        match value {
            Some(value) => self.float(out, value),
            None => out.extend_from_slice(b"null"),
        }
    }

    fn number(&mut self, out: &mut Vec<u8>, key: &str, value: f64) {
        out.push(b'"');
        out.extend_from_slice(key.as_bytes());
        out.extend_from_slice(b"\":");
        self.float(out, value);
    }

    fn float(&mut self, out: &mut Vec<u8>, value: f64) {
        if value.is_finite() {
            out.extend_from_slice(self.floats.format_finite(value).as_bytes());
        } else {
            out.extend_from_slice(b"null"); // as serde_json writes non-finite floats
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn estimate_writer_matches_serde_json_byte_for_byte() {
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for machine in ["tbm-1", "a \"quoted\" \\ name", "é"] {
            let mut writer = EstimateWriter::new(machine);
            for i in 0..2000 {
                let scale = 10f64.powi((i % 9) as i32 - 4);
                let output = EngineOutput {
                    t: 1.7e9 + next() * 1e6,
                    values: EstimateValues::Attitude(AttitudeEstimate {
                        pitch_deg: (next() - 0.5) * scale,
                        roll_deg: (next() - 0.5) * 360.0,
                        pitch_pred_deg: (next() - 0.5) * scale,
                        roll_pred_deg: -0.0,
                        pred_t: 1.7e9 + (i as f64),
                        laser_ok: i % 3 == 0,
                        pitch_correction_deg: if i % 5 == 0 { f64::NAN } else { next() },
                        laser_age_s: (i % 4 != 0).then(|| next() * 1e4),
                        model_version: i * 7919,
                        incl_pitch_deg: (next() - 0.5) * scale,
                        incl_roll_deg: next() * 10.0,
                    }),
                };
                let mut ours = Vec::new();
                writer.write_line(&output, &mut ours);
                let mut expected = serde_json::to_vec(&output.for_machine(machine)).unwrap();
                expected.push(b'\n');
                assert_eq!(
                    String::from_utf8(ours).unwrap(),
                    String::from_utf8(expected).unwrap()
                );
            }
        }
    }

    #[test]
    fn zupt_estimates_match_serde_json_byte_for_byte() {
        let mut writer = EstimateWriter::new("pj-3");
        for i in 0..500u32 {
            let x = f64::from(i) * 0.37 - 40.0;
            let output = EngineOutput {
                t: 1.7e9 + f64::from(i) * 0.01,
                values: EstimateValues::Zupt(ZuptEstimate {
                    zv: i % 3 == 0,
                    position_m: [x, -x * 1e-3, x.sin()],
                    distance_m: x.abs(),
                    velocity_mps: [x * 1e-4, 0.0, -0.0],
                    pitch_deg: x * 0.01,
                    roll_deg: -x,
                    yaw_deg: 359.999,
                    aligned: i % 7 != 0,
                    position_sigma_m: [1e-3, 2e-3, f64::from(i)],
                    height_m: (i % 2 == 0).then_some(x * 0.5),
                    odometer_m: (i % 5 != 0).then_some(x.abs()),
                    mv_ratio: x.abs() * 10.0,
                    are_ratio: 0.5,
                    shoe_ratio: if i == 9 { f64::INFINITY } else { 1.5 },
                    mag_ratio: 1e-9,
                    yaw_sigma_deg: Some(0.012),
                    smoothed_push: Some(vec![
                        TrackPoint {
                            t: 1.5,
                            position_m: [1.0, -2.5e-7, 3.0],
                            distance_m: 0.25,
                            position_sigma_m: [0.001, 0.002, 1e-9],
                        },
                        TrackPoint {
                            t: 2.5,
                            position_m: [1.5, -2.0, 3.5],
                            distance_m: 0.75,
                            position_sigma_m: [0.003, 0.004, 0.0],
                        },
                    ]),
                }),
            };
            let mut ours = Vec::new();
            writer.write_line(&output, &mut ours);
            let mut expected = serde_json::to_vec(&output.for_machine("pj-3")).unwrap();
            expected.push(b'\n');
            assert_eq!(
                String::from_utf8(ours).unwrap(),
                String::from_utf8(expected).unwrap()
            );
        }
    }

    #[test]
    fn fuzzy_estimates_match_serde_json_byte_for_byte() {
        use crate::fusion::fuzzy::magcal::CalibrationState;
        let mut writer = EstimateWriter::new("van-2");
        let states = [
            CalibrationState::Collecting,
            CalibrationState::Planar,
            CalibrationState::Ellipsoid,
        ];
        for i in 0..300u32 {
            let x = f64::from(i) * 0.731 - 90.0;
            let output = EngineOutput {
                t: 1.7e9 + f64::from(i) * 0.01,
                values: EstimateValues::Fuzzy(FuzzyEstimate {
                    motion: if i % 2 == 0 {
                        Motion::Static
                    } else {
                        Motion::Moving
                    },
                    static_degree: (x * 0.1).sin().abs(),
                    pitch_deg: x * 0.01,
                    roll_deg: -x,
                    heading_deg: x.rem_euclid(360.0),
                    gyro_bias_dps: [x * 1e-3, -0.0, 0.5],
                    aligned: i % 5 != 0,
                    mag_calibration: states[i as usize % 3],
                    mag_coverage_deg: f64::from(i % 37) * 10.0,
                    mag_fit_rms: (i % 3 != 0).then_some(x.abs() * 1e-4),
                    mag_heading_deg: (i % 4 != 0).then_some(x + 180.0),
                    accel_dev_mps2: x.abs() * 1e-3,
                    accel_activity_mps2: if i == 7 { f64::NAN } else { 0.02 },
                    gyro_activity_dps: 1e-7 * f64::from(i),
                    gyro_bias_sigma_dps: (i % 6 != 0).then_some([x * 1e-4, 0.002, 1e-9]),
                    mag_disturbed: i % 7 == 3,
                }),
            };
            let mut ours = Vec::new();
            writer.write_line(&output, &mut ours);
            let mut expected = serde_json::to_vec(&output.for_machine("van-2")).unwrap();
            expected.push(b'\n');
            assert_eq!(
                String::from_utf8(ours).unwrap(),
                String::from_utf8(expected).unwrap()
            );
        }
    }

    #[test]
    fn serialises_with_engine_tag_and_parses_back() {
        let output = EngineOutput {
            t: 1_772_431_200.5,
            values: EstimateValues::Attitude(AttitudeEstimate {
                pitch_deg: 0.25,
                roll_deg: 1.5,
                pitch_pred_deg: 0.26,
                roll_pred_deg: 1.49,
                pred_t: 1_772_431_201.5,
                laser_ok: true,
                pitch_correction_deg: -0.3,
                laser_age_s: Some(12.0),
                model_version: 7,
                incl_pitch_deg: 0.5,
                incl_roll_deg: 1.6,
            }),
        };
        let text = serde_json::to_string(&output.for_machine("tbm-1")).unwrap();
        let value: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(value["engine"], "attitude");
        assert_eq!(value["machine"], "tbm-1");
        assert_eq!(value["pitch_correction_deg"], -0.3);
        let back: Estimate = serde_json::from_str(&text).unwrap();
        assert_eq!(back.values, output.values);
        assert_eq!(back.t, output.t);
    }
}

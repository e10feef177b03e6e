//! Estimates of the wire protocol (docs/protocol.md, "Estimates").

use serde::{Deserialize, Serialize};

pub use super::attitude::estimate::AttitudeEstimate;
pub use super::fuzzy::estimate::{FuzzyEstimate, Motion};
pub use super::integrity::{Integrity, IntegrityLevel, IntegrityReason};
pub use super::json_fields::JsonFields;
pub use super::registry::EstimateValues;
pub use super::zupt::estimate::{TrackPoint, ZuptEstimate};

/// Accessors for code that knows which engine it reads (evaluations, tests).
impl EstimateValues {
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

    /// Pitch and roll, degrees, of an engine that estimates the attitude.
    pub fn pitch_roll_deg(&self) -> Option<(f64, f64)> {
        match self {
            EstimateValues::Attitude(a) => Some((a.pitch_deg, a.roll_deg)),
            EstimateValues::Zupt(z) => Some((z.pitch_deg, z.roll_deg)),
            EstimateValues::Fuzzy(f) => Some((f.pitch_deg, f.roll_deg)),
            _ => None,
        }
    }
}

/// A `zupt` estimate at rest at the origin, for stage tests.
#[cfg(test)]
pub(crate) fn zupt_for_tests(t: f64, smoothed_push: Option<Vec<TrackPoint>>) -> EngineOutput {
    EngineOutput {
        integrity: Integrity::OK,
        t,
        values: EstimateValues::Zupt(ZuptEstimate {
            zv: true,
            position_m: [0.0; 3],
            distance_m: 0.0,
            velocity_mps: [0.0; 3],
            pitch_deg: 0.0,
            roll_deg: 0.0,
            yaw_deg: 0.0,
            aligned: true,
            position_sigma_m: [0.0; 3],
            height_m: None,
            odometer_m: None,
            mv_ratio: 0.0,
            are_ratio: 0.0,
            shoe_ratio: 0.0,
            mag_ratio: 0.0,
            yaw_sigma_deg: None,
            attitude_sigma_deg: None,
            pitch_sigma_deg: None,
            roll_sigma_deg: None,
            smoothed_push,
            odometer_scale: None,
            odometer_scale_sigma: None,
        }),
    }
}

/// The stored form of a plain estimate struct: postcard.
pub(crate) fn postcard_bytes<T: Serialize>(estimate: &T) -> Vec<u8> {
    // postcard fails only on types it cannot express (maps of unknown
    // length, self-describing values); engine estimates are plain structs.
    postcard::to_stdvec(estimate).expect("engine estimates are plain structs postcard can encode")
}

/// What an engine emits: an estimate before it is attributed to a machine.
#[derive(Debug, Clone, PartialEq)]
pub struct EngineOutput {
    /// Time of the reading that produced the estimate, Unix seconds.
    pub t: f64,
    pub values: EstimateValues,
    /// Whether the values can be trusted.
    pub integrity: Integrity,
}

/// A complete protocol estimate: time, machine, engine and values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    pub t: f64,
    pub machine: String,
    #[serde(flatten)]
    pub values: EstimateValues,
    #[serde(flatten)]
    pub integrity: Integrity,
}

/// Borrowing form of [`Estimate`] for writing without copying the machine id.
#[derive(Serialize)]
pub struct EstimateRef<'a> {
    pub t: f64,
    pub machine: &'a str,
    #[serde(flatten)]
    pub values: &'a EstimateValues,
    #[serde(flatten)]
    pub integrity: Integrity,
}

impl EngineOutput {
    /// Attributes the output to a machine, borrowing both.
    pub fn for_machine<'a>(&'a self, machine: &'a str) -> EstimateRef<'a> {
        EstimateRef {
            t: self.t,
            machine,
            values: &self.values,
            integrity: self.integrity,
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
        let mut fields = JsonFields::new(out, &mut self.floats, &mut self.integers);
        fields.number("t", output.t);
        fields.raw(&self.machine_field);
        fields.word("engine", output.values.stream().as_str());
        output.values.write_fields(&mut fields);
        fields.word("integrity", output.integrity.level.as_str());
        match output.integrity.reason {
            Some(reason) => fields.word("integrity_reason", reason.as_str()),
            None => fields.null("integrity_reason"),
        }
        out.extend_from_slice(b"}\n");
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
                    integrity: match i % 3 {
                        0 => Integrity::OK,
                        1 => Integrity::degraded(
                            IntegrityReason::ALL[i as usize % IntegrityReason::ALL.len()],
                        ),
                        _ => Integrity::lost(IntegrityReason::Innovations),
                    },
                    t: 1.7e9 + next() * 1e6,
                    values: EstimateValues::Attitude(AttitudeEstimate {
                        pitch_deg: (next() - 0.5) * scale,
                        roll_deg: (next() - 0.5) * 360.0,
                        pitch_pred_deg: (next() - 0.5) * scale,
                        roll_pred_deg: -0.0,
                        pred_t: 1.7e9 + (i as f64),
                        pitch_sigma_deg: None,
                        roll_sigma_deg: None,
                        pitch_pred_sigma_deg: None,
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
                integrity: Integrity::OK,
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
                    attitude_sigma_deg: Some([0.004, 0.005, 0.012]),
                    pitch_sigma_deg: None,
                    roll_sigma_deg: None,
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
                    odometer_scale: (i % 4 == 0).then_some(1.0 + x * 1e-4),
                    odometer_scale_sigma: (i % 4 == 0).then_some(0.01),
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
        use crate::fusion::fuzzy::estimate::CompassState;
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
                integrity: Integrity::OK,
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
                    pitch_sigma_deg: (i % 5 != 0).then_some(x.abs() * 1e-3),
                    roll_sigma_deg: (i % 5 != 0).then_some(0.25),
                    heading_sigma_deg: (i % 9 != 0).then_some(x.abs()),
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
                    compass: (i % 8 != 0).then_some(CompassState::Gated),
                    compass_since: (i % 8 != 0).then_some(1.7e9 + f64::from(i)),
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
            integrity: Integrity::OK,
            t: 1_772_431_200.5,
            values: EstimateValues::Attitude(AttitudeEstimate {
                pitch_deg: 0.25,
                roll_deg: 1.5,
                pitch_pred_deg: 0.26,
                roll_pred_deg: 1.49,
                pred_t: 1_772_431_201.5,
                pitch_sigma_deg: None,
                roll_sigma_deg: None,
                pitch_pred_sigma_deg: None,
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

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
}

/// The engine-specific part of an estimate, tagged by `engine`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "engine", rename_all = "snake_case")]
pub enum EstimateValues {
    Attitude(AttitudeEstimate),
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

#[cfg(test)]
mod tests {
    use super::*;

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

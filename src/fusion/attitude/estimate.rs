//! What the `attitude` engine emits per inclinometer reading: the
//! protocol's fields, their NDJSON form and their stored form.

use serde::{Deserialize, Serialize};

use crate::fusion::estimate::JsonFields;

/// What the `attitude` engine estimates at one inclinometer reading.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
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

/// Stored estimates of this release: postcard of [`AttitudeEstimate`].
/// Version 1 is the only one there has been.
pub const CODEC_VERSION: u32 = 1;

impl AttitudeEstimate {
    /// The fields after `"engine"`, as serde_json writes them.
    pub fn write_fields(&self, w: &mut JsonFields<'_>) {
        w.number("pitch_deg", self.pitch_deg);
        w.number("roll_deg", self.roll_deg);
        w.number("pitch_pred_deg", self.pitch_pred_deg);
        w.number("roll_pred_deg", self.roll_pred_deg);
        w.number("pred_t", self.pred_t);
        w.flag("laser_ok", self.laser_ok);
        w.number("pitch_correction_deg", self.pitch_correction_deg);
        w.optional("laser_age_s", self.laser_age_s);
        w.integer("model_version", self.model_version);
        w.number("incl_pitch_deg", self.incl_pitch_deg);
        w.number("incl_roll_deg", self.incl_roll_deg);
    }

    /// The stored form, of [`CODEC_VERSION`].
    pub fn encode(&self) -> Vec<u8> {
        crate::fusion::estimate::postcard_bytes(self)
    }

    /// The estimate stored as `bytes` with codec `version` (0: stored
    /// before rows carried their version, which is version 1).
    pub fn decode(version: u32, bytes: &[u8]) -> Result<AttitudeEstimate, postcard::Error> {
        match version {
            0 | 1 => postcard::from_bytes(bytes),
            _ => Err(postcard::Error::DeserializeBadEncoding),
        }
    }

    /// `extreme_a`, `extreme_b` of the stored row: pitch and roll.
    pub fn extremes(&self) -> [f64; 2] {
        [self.pitch_deg, self.roll_deg]
    }
}

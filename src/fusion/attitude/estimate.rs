//! What the `attitude` engine emits per inclinometer reading: the
//! protocol's fields, their NDJSON form and their stored form.

use serde::{Deserialize, Serialize};

use crate::fusion::descriptor::{LaserSignal, SignalKind, Signals, StreamValues};
use crate::fusion::json_fields::JsonFields;

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
    /// 1σ of `pitch_deg`: the filter's covariance plus what the laser has
    /// not yet checked of the correction (time and roll travel since the
    /// last laser sample, roll beyond the trained range); `null` in
    /// estimates stored before the engine said so. (tunnelnav extension.)
    pub pitch_sigma_deg: Option<f64>,
    /// 1σ of `roll_deg` (the roll filter's covariance); `null` as above.
    pub roll_sigma_deg: Option<f64>,
    /// 1σ of `pitch_pred_deg` against the pitch at `pred_t`; `null` as above.
    pub pitch_pred_sigma_deg: Option<f64>,
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
/// 1: before the σ ([`AttitudeEstimateV1`]).
pub const CODEC_VERSION: u32 = 2;

impl StreamValues for AttitudeEstimate {
    const CODEC_VERSION: u32 = CODEC_VERSION;
    const SIGNALS: &'static [SignalKind] = &[SignalKind::Laser, SignalKind::PitchSigma];

    fn write_fields(&self, w: &mut JsonFields<'_>) {
        w.number("pitch_deg", self.pitch_deg);
        w.number("roll_deg", self.roll_deg);
        w.number("pitch_pred_deg", self.pitch_pred_deg);
        w.number("roll_pred_deg", self.roll_pred_deg);
        w.number("pred_t", self.pred_t);
        w.optional("pitch_sigma_deg", self.pitch_sigma_deg);
        w.optional("roll_sigma_deg", self.roll_sigma_deg);
        w.optional("pitch_pred_sigma_deg", self.pitch_pred_sigma_deg);
        w.flag("laser_ok", self.laser_ok);
        w.number("pitch_correction_deg", self.pitch_correction_deg);
        w.optional("laser_age_s", self.laser_age_s);
        w.integer("model_version", self.model_version);
        w.number("incl_pitch_deg", self.incl_pitch_deg);
        w.number("incl_roll_deg", self.incl_roll_deg);
    }

    /// 0: stored before rows carried their version, which is version 1.
    fn decode(version: u32, bytes: &[u8]) -> Result<AttitudeEstimate, postcard::Error> {
        match version {
            0 | 1 => postcard::from_bytes::<AttitudeEstimateV1>(bytes).map(AttitudeEstimate::from),
            2 => postcard::from_bytes(bytes),
            _ => Err(postcard::Error::DeserializeBadEncoding),
        }
    }

    /// Pitch and roll.
    fn extremes(&self) -> [f64; 2] {
        [self.pitch_deg, self.roll_deg]
    }

    /// The laser, and the pitch's σ once the laser has been seen: before,
    /// the pitch is the inclinometer's as installed, and says so (its σ is
    /// the prior's), which is no news to steer by.
    fn signals(&self) -> Signals {
        Signals {
            laser: Some(LaserSignal {
                ok: self.laser_ok,
                age_s: self.laser_age_s,
            }),
            pitch_sigma_deg: self.pitch_sigma_deg.filter(|_| self.laser_age_s.is_some()),
            ..Signals::default()
        }
    }
}

/// An `attitude` estimate as releases before the σ stored it (codec
/// version 1).
#[derive(Deserialize)]
struct AttitudeEstimateV1 {
    pitch_deg: f64,
    roll_deg: f64,
    pitch_pred_deg: f64,
    roll_pred_deg: f64,
    pred_t: f64,
    laser_ok: bool,
    pitch_correction_deg: f64,
    laser_age_s: Option<f64>,
    model_version: u64,
    incl_pitch_deg: f64,
    incl_roll_deg: f64,
}

impl From<AttitudeEstimateV1> for AttitudeEstimate {
    fn from(v: AttitudeEstimateV1) -> AttitudeEstimate {
        AttitudeEstimate {
            pitch_deg: v.pitch_deg,
            roll_deg: v.roll_deg,
            pitch_pred_deg: v.pitch_pred_deg,
            roll_pred_deg: v.roll_pred_deg,
            pred_t: v.pred_t,
            pitch_sigma_deg: None,
            roll_sigma_deg: None,
            pitch_pred_sigma_deg: None,
            laser_ok: v.laser_ok,
            pitch_correction_deg: v.pitch_correction_deg,
            laser_age_s: v.laser_age_s,
            model_version: v.model_version,
            incl_pitch_deg: v.incl_pitch_deg,
            incl_roll_deg: v.incl_roll_deg,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_estimate_stored_before_the_sigma_opens_without_it() {
        // Codec 1 is postcard of the eleven fields in their order; a tuple
        // of the same types encodes the same bytes.
        let v1 = postcard::to_allocvec(&(
            0.25_f64,
            -1.5_f64,
            0.26_f64,
            -1.4_f64,
            1.0e9_f64,
            true,
            0.125_f64,
            Some(30.0_f64),
            7_u64,
            0.3_f64,
            -1.6_f64,
        ))
        .unwrap();
        let e = AttitudeEstimate::decode(1, &v1).unwrap();
        assert_eq!((e.pitch_deg, e.roll_deg, e.pred_t), (0.25, -1.5, 1.0e9));
        assert_eq!(e.laser_age_s, Some(30.0));
        assert_eq!(e.model_version, 7);
        assert_eq!(e.incl_roll_deg, -1.6);
        assert_eq!(
            (e.pitch_sigma_deg, e.roll_sigma_deg, e.pitch_pred_sigma_deg),
            (None, None, None)
        );
        assert_eq!(AttitudeEstimate::decode(0, &v1).unwrap(), e);
        // This release's form keeps the σ.
        let mut now = e.clone();
        now.pitch_sigma_deg = Some(0.004);
        let back = AttitudeEstimate::decode(CODEC_VERSION, &now.encode()).unwrap();
        assert_eq!(back, now);
    }
}

//! What the `zupt` engine emits per IMU reading: the protocol's fields,
//! their NDJSON form and their stored form (and the forms earlier
//! releases stored).

use serde::{Deserialize, Serialize};

use crate::fusion::descriptor::{Navigation, SignalKind, Signals, StreamValues};
use crate::fusion::json_fields::JsonFields;

/// What the `zupt` engine estimates at one IMU reading.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
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
    /// 1σ of the attitude error about north, east and down from the
    /// filter's covariance, degrees (tilt and heading); `null` before
    /// alignment and in estimates stored before it was reported.
    pub attitude_sigma_deg: Option<[f64; 3]>,
    /// 1σ of pitch and of roll, degrees: the attitude covariance about the
    /// machine's level right and forward axes; `null` before alignment and
    /// in estimates stored before they were reported.
    pub pitch_sigma_deg: Option<f64>,
    pub roll_sigma_deg: Option<f64>,
    /// On the estimate at which a push ends (the first epoch decided still
    /// after it): the push's track smoothed over both of its still ends,
    /// from the last still epoch before it, about one point a second;
    /// `null` on every other estimate.
    pub smoothed_push: Option<Vec<TrackPoint>>,
    /// The odometer's scale as the filter estimates it (its distance ÷
    /// the true distance: 1.04 reads 4 % long) and its 1σ; `null` before
    /// alignment, before the first odometer reading, and in estimates
    /// stored before they were reported.
    pub odometer_scale: Option<f64>,
    pub odometer_scale_sigma: Option<f64>,
}

/// A point of a smoothed track.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct TrackPoint {
    pub t: f64,
    /// North, east, down of the start point.
    pub position_m: [f64; 3],
    /// Along-track distance.
    pub distance_m: f64,
    /// 1σ of the smoothed position.
    pub position_sigma_m: [f64; 3],
}

/// Stored estimates of this release: postcard of [`ZuptEstimate`].
/// 1: before the heading σ and the smoothed push ([`ZuptEstimateV1`]);
/// 2: before the attitude σ ([`ZuptEstimateV2`]); 3: before the pitch and
/// roll σ ([`ZuptEstimateV3`]); 4: before the odometer's scale
/// ([`ZuptEstimateV4`]).
pub const CODEC_VERSION: u32 = 5;

impl StreamValues for ZuptEstimate {
    const CODEC_VERSION: u32 = CODEC_VERSION;
    const SIGNALS: &'static [SignalKind] = &[SignalKind::Navigation];

    fn write_fields(&self, w: &mut JsonFields<'_>) {
        w.flag("zv", self.zv);
        w.triple("position_m", &self.position_m);
        w.number("distance_m", self.distance_m);
        w.triple("velocity_mps", &self.velocity_mps);
        w.number("pitch_deg", self.pitch_deg);
        w.number("roll_deg", self.roll_deg);
        w.number("yaw_deg", self.yaw_deg);
        w.flag("aligned", self.aligned);
        w.triple("position_sigma_m", &self.position_sigma_m);
        w.optional("height_m", self.height_m);
        w.optional("odometer_m", self.odometer_m);
        w.number("mv_ratio", self.mv_ratio);
        w.number("are_ratio", self.are_ratio);
        w.number("shoe_ratio", self.shoe_ratio);
        w.number("mag_ratio", self.mag_ratio);
        w.optional("yaw_sigma_deg", self.yaw_sigma_deg);
        match &self.attitude_sigma_deg {
            Some(sigma) => w.triple("attitude_sigma_deg", sigma),
            None => w.null("attitude_sigma_deg"),
        }
        w.optional("pitch_sigma_deg", self.pitch_sigma_deg);
        w.optional("roll_sigma_deg", self.roll_sigma_deg);
        match &self.smoothed_push {
            None => w.null("smoothed_push"),
            Some(points) => w.objects("smoothed_push", points, |point, w| {
                w.number("t", point.t);
                w.triple("position_m", &point.position_m);
                w.number("distance_m", point.distance_m);
                w.triple("position_sigma_m", &point.position_sigma_m);
            }),
        }
        w.optional("odometer_scale", self.odometer_scale);
        w.optional("odometer_scale_sigma", self.odometer_scale_sigma);
    }

    /// 0: stored before rows carried their version: version 2, or 1
    /// where that fails.
    fn decode(version: u32, bytes: &[u8]) -> Result<ZuptEstimate, postcard::Error> {
        let v1 = |bytes| postcard::from_bytes::<ZuptEstimateV1>(bytes).map(ZuptEstimate::from);
        let v2 = |bytes| postcard::from_bytes::<ZuptEstimateV2>(bytes).map(ZuptEstimate::from);
        let v3 = |bytes| postcard::from_bytes::<ZuptEstimateV3>(bytes).map(ZuptEstimate::from);
        let v4 = |bytes| postcard::from_bytes::<ZuptEstimateV4>(bytes).map(ZuptEstimate::from);
        match version {
            0 => v2(bytes).or_else(|_| v1(bytes)),
            1 => v1(bytes),
            2 => v2(bytes),
            3 => v3(bytes),
            4 => v4(bytes),
            5 => postcard::from_bytes(bytes),
            _ => Err(postcard::Error::DeserializeBadEncoding),
        }
    }

    /// Distance and depth.
    fn extremes(&self) -> [f64; 2] {
        [self.distance_m, self.position_m[2]]
    }

    /// The navigation solution: aligned with its horizontal 1σ, or aligning.
    fn signals(&self) -> Signals {
        let navigation = if self.aligned {
            Navigation::Aligned {
                horizontal_sigma_mm: self.position_sigma_m[0].hypot(self.position_sigma_m[1])
                    * 1000.0,
            }
        } else {
            Navigation::Aligning
        };
        Signals {
            navigation: Some(navigation),
            ..Signals::default()
        }
    }
}

/// A `zupt` estimate as releases before the heading σ and the smoothed
/// push stored it (codec version 1). Every later version stores these
/// fields first, in this order; postcard writes a nested struct as its
/// fields, so the later layouts below hold it as `core`.
#[derive(Deserialize)]
struct ZuptEstimateV1 {
    zv: bool,
    position_m: [f64; 3],
    distance_m: f64,
    velocity_mps: [f64; 3],
    pitch_deg: f64,
    roll_deg: f64,
    yaw_deg: f64,
    aligned: bool,
    position_sigma_m: [f64; 3],
    height_m: Option<f64>,
    odometer_m: Option<f64>,
    mv_ratio: f64,
    are_ratio: f64,
    shoe_ratio: f64,
    mag_ratio: f64,
}

impl ZuptEstimateV1 {
    /// The estimate with the fields later versions added (no version
    /// before 4 stored pitch and roll σ).
    fn upgrade(
        self,
        yaw_sigma_deg: Option<f64>,
        attitude_sigma_deg: Option<[f64; 3]>,
        smoothed_push: Option<Vec<TrackPoint>>,
    ) -> ZuptEstimate {
        ZuptEstimate {
            zv: self.zv,
            position_m: self.position_m,
            distance_m: self.distance_m,
            velocity_mps: self.velocity_mps,
            pitch_deg: self.pitch_deg,
            roll_deg: self.roll_deg,
            yaw_deg: self.yaw_deg,
            aligned: self.aligned,
            position_sigma_m: self.position_sigma_m,
            height_m: self.height_m,
            odometer_m: self.odometer_m,
            mv_ratio: self.mv_ratio,
            are_ratio: self.are_ratio,
            shoe_ratio: self.shoe_ratio,
            mag_ratio: self.mag_ratio,
            yaw_sigma_deg,
            attitude_sigma_deg,
            pitch_sigma_deg: None,
            roll_sigma_deg: None,
            smoothed_push,
            odometer_scale: None,
            odometer_scale_sigma: None,
        }
    }
}

impl From<ZuptEstimateV1> for ZuptEstimate {
    fn from(v: ZuptEstimateV1) -> ZuptEstimate {
        v.upgrade(None, None, None)
    }
}

/// A `zupt` estimate as releases before the attitude σ stored it (codec
/// version 2).
#[derive(Deserialize)]
struct ZuptEstimateV2 {
    core: ZuptEstimateV1,
    yaw_sigma_deg: Option<f64>,
    smoothed_push: Option<Vec<TrackPoint>>,
}

impl From<ZuptEstimateV2> for ZuptEstimate {
    fn from(v: ZuptEstimateV2) -> ZuptEstimate {
        v.core.upgrade(v.yaw_sigma_deg, None, v.smoothed_push)
    }
}

/// A `zupt` estimate as releases before the pitch and roll σ stored it
/// (codec version 3).
#[derive(Deserialize)]
struct ZuptEstimateV3 {
    core: ZuptEstimateV1,
    yaw_sigma_deg: Option<f64>,
    attitude_sigma_deg: Option<[f64; 3]>,
    smoothed_push: Option<Vec<TrackPoint>>,
}

impl From<ZuptEstimateV3> for ZuptEstimate {
    fn from(v: ZuptEstimateV3) -> ZuptEstimate {
        v.core
            .upgrade(v.yaw_sigma_deg, v.attitude_sigma_deg, v.smoothed_push)
    }
}

/// A `zupt` estimate as releases before the odometer's scale stored it
/// (codec version 4).
#[derive(Deserialize)]
struct ZuptEstimateV4 {
    core: ZuptEstimateV1,
    yaw_sigma_deg: Option<f64>,
    attitude_sigma_deg: Option<[f64; 3]>,
    pitch_sigma_deg: Option<f64>,
    roll_sigma_deg: Option<f64>,
    smoothed_push: Option<Vec<TrackPoint>>,
}

impl From<ZuptEstimateV4> for ZuptEstimate {
    fn from(v: ZuptEstimateV4) -> ZuptEstimate {
        ZuptEstimate {
            pitch_sigma_deg: v.pitch_sigma_deg,
            roll_sigma_deg: v.roll_sigma_deg,
            ..v.core
                .upgrade(v.yaw_sigma_deg, v.attitude_sigma_deg, v.smoothed_push)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_estimate_stored_before_the_attitude_sigma_still_reads() {
        // Codec 2's layout: the current fields without `attitude_sigma_deg`.
        #[derive(Serialize)]
        struct V2 {
            zv: bool,
            position_m: [f64; 3],
            distance_m: f64,
            velocity_mps: [f64; 3],
            pitch_deg: f64,
            roll_deg: f64,
            yaw_deg: f64,
            aligned: bool,
            position_sigma_m: [f64; 3],
            height_m: Option<f64>,
            odometer_m: Option<f64>,
            mv_ratio: f64,
            are_ratio: f64,
            shoe_ratio: f64,
            mag_ratio: f64,
            yaw_sigma_deg: Option<f64>,
            smoothed_push: Option<Vec<TrackPoint>>,
        }
        let bytes = postcard::to_allocvec(&V2 {
            zv: true,
            position_m: [1.0, 2.0, 3.0],
            distance_m: 2.5,
            velocity_mps: [0.0; 3],
            pitch_deg: 0.5,
            roll_deg: -0.2,
            yaw_deg: 30.0,
            aligned: true,
            position_sigma_m: [0.01, 0.01, 0.002],
            height_m: Some(12.0),
            odometer_m: None,
            mv_ratio: 0.3,
            are_ratio: 0.4,
            shoe_ratio: 0.2,
            mag_ratio: 0.1,
            yaw_sigma_deg: Some(0.4),
            smoothed_push: None,
        })
        .unwrap();
        for version in [0, 2] {
            let z = ZuptEstimate::decode(version, &bytes).unwrap();
            assert_eq!(z.yaw_sigma_deg, Some(0.4));
            assert_eq!(z.height_m, Some(12.0));
            assert_eq!(z.attitude_sigma_deg, None);
        }
        let current = ZuptEstimate {
            attitude_sigma_deg: Some([0.04, 0.05, 0.4]),
            pitch_sigma_deg: Some(0.045),
            roll_sigma_deg: Some(0.046),
            ..ZuptEstimate::decode(2, &bytes).unwrap()
        };
        assert_eq!(
            ZuptEstimate::decode(CODEC_VERSION, &current.encode()).unwrap(),
            current
        );
        // Codec 4's layout is codec 5's without the two odometer fields
        // at the end, each `None` one zero byte in postcard.
        let mut v4 = current.encode();
        assert_eq!(v4.split_off(v4.len() - 2), [0, 0]);
        assert_eq!(ZuptEstimate::decode(4, &v4).unwrap(), current);
        let with_scale = ZuptEstimate {
            odometer_scale: Some(1.04),
            odometer_scale_sigma: Some(0.002),
            ..current
        };
        assert_eq!(
            ZuptEstimate::decode(CODEC_VERSION, &with_scale.encode()).unwrap(),
            with_scale
        );
    }
}

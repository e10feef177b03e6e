//! Whether an estimate can be trusted: every estimate of every engine and
//! stage carries an [`Integrity`] (docs/protocol.md, "Integrity").
//!
//! - `ok`: the σ fields bound the error as stated.
//! - `degraded`: usable, but a check failed and the σ has been widened to
//!   cover it.
//! - `lost`: the engine cannot vouch for the value; a display shows it
//!   greyed or not at all.
//!
//! An engine decides its estimates' integrity from monitors that test what
//! it believes against evidence it did not use (each engine's page in
//! docs/engines/ lists its tests); a stage carries its source's.

use serde::{Deserialize, Serialize};

/// How far an estimate can be trusted, best first.
#[derive(
    Debug,
    Clone,
    Copy,
    Default,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    Serialize,
    Deserialize,
    utoipa::ToSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum IntegrityLevel {
    /// The σ fields bound the error as stated.
    #[default]
    Ok,
    /// Usable, but a check failed; the σ has been widened to cover it.
    Degraded,
    /// The engine cannot vouch for the value.
    Lost,
}

impl IntegrityLevel {
    /// The protocol name.
    pub fn as_str(self) -> &'static str {
        match self {
            IntegrityLevel::Ok => "ok",
            IntegrityLevel::Degraded => "degraded",
            IntegrityLevel::Lost => "lost",
        }
    }
}

/// Why an estimate is not `ok`: a short code (docs/protocol.md lists what
/// each means). The stored form is the variant's index: new codes are
/// appended, never inserted or reordered.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum IntegrityReason {
    /// The estimate's source (an engine's estimate a stage derives from)
    /// is itself degraded or lost; the stage repeats the source's reason
    /// where it has one, this where it has none.
    Source,
    /// The position a stage judges is older than its staleness limit.
    StaleSource,
    /// The accelerometer's tilt at rest disagrees with the tilt the
    /// engine carries.
    TiltDisagrees,
    /// The compass disagrees with the heading the engine carries.
    HeadingDisagrees,
    /// The laser disagrees with the engine's prediction.
    LaserDisagrees,
    /// The odometer disagrees with the distance the engine integrates.
    OdometerDisagrees,
    /// The filter's innovations are too large for its covariance
    /// (windowed χ²).
    Innovations,
    /// The engine is rebuilding its state after losing it (re-levelling,
    /// re-learning a bias); its monitors have not passed again yet.
    Recovering,
    /// A sensor repeats the same value: frozen.
    SensorFrozen,
    /// A sensor's readings jump beyond what the machine can do.
    SensorSpikes,
    /// The readings' clock stepped.
    ClockStep,
    /// The engine has not aligned yet: it has no reference to hold its
    /// values to.
    Unaligned,
    /// The engine's σ has not been checked by independent evidence yet (at
    /// the start: before the laser has checked the inclinometer between
    /// its samples).
    Unverified,
    /// The engine's speed is beyond what the machine can do (its declared
    /// maximum): its velocity, and the position it integrates, have run
    /// away.
    SpeedImplausible,
}

impl IntegrityReason {
    /// The protocol code.
    pub fn as_str(self) -> &'static str {
        match self {
            IntegrityReason::Source => "source",
            IntegrityReason::StaleSource => "stale_source",
            IntegrityReason::TiltDisagrees => "tilt_disagrees",
            IntegrityReason::HeadingDisagrees => "heading_disagrees",
            IntegrityReason::LaserDisagrees => "laser_disagrees",
            IntegrityReason::OdometerDisagrees => "odometer_disagrees",
            IntegrityReason::Innovations => "innovations",
            IntegrityReason::Recovering => "recovering",
            IntegrityReason::SensorFrozen => "sensor_frozen",
            IntegrityReason::SensorSpikes => "sensor_spikes",
            IntegrityReason::ClockStep => "clock_step",
            IntegrityReason::Unaligned => "unaligned",
            IntegrityReason::Unverified => "unverified",
            IntegrityReason::SpeedImplausible => "speed_implausible",
        }
    }

    /// Every code, in stored (declaration) order.
    pub const ALL: &'static [IntegrityReason] = &[
        IntegrityReason::Source,
        IntegrityReason::StaleSource,
        IntegrityReason::TiltDisagrees,
        IntegrityReason::HeadingDisagrees,
        IntegrityReason::LaserDisagrees,
        IntegrityReason::OdometerDisagrees,
        IntegrityReason::Innovations,
        IntegrityReason::Recovering,
        IntegrityReason::SensorFrozen,
        IntegrityReason::SensorSpikes,
        IntegrityReason::ClockStep,
        IntegrityReason::Unaligned,
        IntegrityReason::Unverified,
        IntegrityReason::SpeedImplausible,
    ];
}

/// An estimate's integrity: its level and, when not `ok`, why. On the wire
/// `"integrity"` and `"integrity_reason"` (`null` when ok).
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize, utoipa::ToSchema,
)]
pub struct Integrity {
    #[serde(rename = "integrity", default)]
    pub level: IntegrityLevel,
    #[serde(rename = "integrity_reason", default)]
    pub reason: Option<IntegrityReason>,
}

impl Integrity {
    /// The σ fields bound the error as stated.
    pub const OK: Integrity = Integrity {
        level: IntegrityLevel::Ok,
        reason: None,
    };

    /// Usable, σ widened, because of `reason`.
    pub fn degraded(reason: IntegrityReason) -> Integrity {
        Integrity {
            level: IntegrityLevel::Degraded,
            reason: Some(reason),
        }
    }

    /// Not to be trusted, because of `reason`.
    pub fn lost(reason: IntegrityReason) -> Integrity {
        Integrity {
            level: IntegrityLevel::Lost,
            reason: Some(reason),
        }
    }

    /// Whether the σ fields bound the error as stated.
    pub fn is_ok(self) -> bool {
        self.level == IntegrityLevel::Ok
    }

    /// The worse of the two (the first on a tie).
    pub fn worst(self, other: Integrity) -> Integrity {
        if other.level > self.level {
            other
        } else {
            self
        }
    }

    /// What a stage deriving from an estimate of this integrity carries:
    /// the same level and reason.
    pub fn inherited(self) -> Integrity {
        match (self.level, self.reason) {
            (IntegrityLevel::Ok, _) => Integrity::OK,
            (level, reason) => Integrity {
                level,
                reason: Some(reason.unwrap_or(IntegrityReason::Source)),
            },
        }
    }

    /// The stored form: two bytes, the level's index and the reason's
    /// index plus one (0: none); both are the variants' declaration order.
    pub fn to_bytes(self) -> [u8; 2] {
        [self.level as u8, self.reason.map_or(0, |r| r as u8 + 1)]
    }

    /// Reads [`Integrity::to_bytes`]; `None` for bytes no release wrote.
    pub fn from_bytes(bytes: [u8; 2]) -> Option<Integrity> {
        let level = match bytes[0] {
            0 => IntegrityLevel::Ok,
            1 => IntegrityLevel::Degraded,
            2 => IntegrityLevel::Lost,
            _ => return None,
        };
        let reason = match bytes[1] {
            0 => None,
            i => Some(*IntegrityReason::ALL.get(i as usize - 1)?),
        };
        Some(Integrity { level, reason })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_worst_of_two_and_what_a_stage_inherits() {
        let lost = Integrity::lost(IntegrityReason::TiltDisagrees);
        let degraded = Integrity::degraded(IntegrityReason::Innovations);
        assert_eq!(Integrity::OK.worst(lost), lost);
        assert_eq!(lost.worst(degraded), lost);
        assert_eq!(degraded.worst(Integrity::OK), degraded);
        assert_eq!(lost.inherited(), lost);
        assert_eq!(Integrity::OK.inherited(), Integrity::OK);
        let bare = Integrity {
            level: IntegrityLevel::Degraded,
            reason: None,
        };
        assert_eq!(
            bare.inherited(),
            Integrity::degraded(IntegrityReason::Source)
        );
    }

    #[test]
    fn stored_bytes_round_trip_and_unknown_bytes_are_refused() {
        assert_eq!(Integrity::OK.to_bytes(), [0, 0]);
        assert_eq!(Integrity::lost(IntegrityReason::Source).to_bytes(), [2, 1]);
        for &reason in IntegrityReason::ALL {
            for level in [IntegrityLevel::Degraded, IntegrityLevel::Lost] {
                let i = Integrity {
                    level,
                    reason: Some(reason),
                };
                assert_eq!(Integrity::from_bytes(i.to_bytes()), Some(i));
            }
        }
        for (i, &reason) in IntegrityReason::ALL.iter().enumerate() {
            assert_eq!(reason as usize, i, "{reason:?} out of declaration order");
        }
        assert_eq!(Integrity::from_bytes([3, 0]), None);
        let past_the_end = IntegrityReason::ALL.len() as u8 + 1;
        assert_eq!(Integrity::from_bytes([1, past_the_end]), None);
    }

    #[test]
    fn wire_names_are_the_protocol_codes() {
        for &reason in IntegrityReason::ALL {
            assert_eq!(
                serde_json::to_value(reason).unwrap(),
                serde_json::Value::from(reason.as_str())
            );
        }
        let json = serde_json::to_value(Integrity::degraded(IntegrityReason::ClockStep)).unwrap();
        assert_eq!(
            json,
            serde_json::json!({"integrity": "degraded", "integrity_reason": "clock_step"})
        );
        let ok = serde_json::to_value(Integrity::OK).unwrap();
        assert_eq!(
            ok,
            serde_json::json!({"integrity": "ok", "integrity_reason": null})
        );
    }
}

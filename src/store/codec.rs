//! The stored forms of readings and estimates: compact bytes, because the
//! single writer's work grows with the bytes it stores. The machine, time,
//! sensor or engine of a row are its columns, so they are not repeated in
//! its body; decoding takes them from the columns.
//!
//! - A reading's data: its numbers in protocol field order as little-endian
//!   f64s; an absent optional field (`yaw_deg`, `temp_c`, a laser's
//!   position) is left off (the count tells which are there). An
//!   `advance` with a key position stores its ring as −(ring + 1), then
//!   the key, then the strokes (a release before the key stored no
//!   negative ring); a `tail_clearance` stores its gaps. 16–48 bytes where the JSON is 90–180. Written by hand: the
//!   variant is the `sensor` column and every field is an f64.
//! - An estimate's values: postcard, about 60 bytes for an `attitude`
//!   estimate where its JSON is about 330, of the engine's codec version
//!   (the row's `codec` column); each engine's `estimate.rs` decodes every
//!   version it has had.

use crate::fusion::reading::{CLEARANCE_POINTS, MAX_STROKES, ProjectPoint};
use crate::fusion::{
    EngineOutput, EstimateValues, Integrity, Reading, SensorData, SensorKind, StreamKind,
};

use super::error::StoreError;

/// The stored bytes of a reading's data.
pub fn encode_reading(data: &SensorData) -> Vec<u8> {
    let mut numbers = Vec::with_capacity(6);
    match data {
        SensorData::Laser {
            pitch_deg,
            roll_deg,
            yaw_deg,
            position,
        } => numbers.extend(
            [*pitch_deg, *roll_deg].into_iter().chain(*yaw_deg).chain(
                position
                    .iter()
                    .flat_map(|p| [p.easting_m, p.northing_m, p.height_m]),
            ),
        ),
        SensorData::Inclinometer {
            pitch_deg,
            roll_deg,
            temp_c,
        } => numbers.extend([*pitch_deg, *roll_deg].into_iter().chain(*temp_c)),
        SensorData::Imu {
            accel_mps2,
            gyro_dps,
        } => numbers.extend(accel_mps2.iter().chain(gyro_dps)),
        SensorData::Magnetometer { field_ut } => numbers.extend(field_ut),
        SensorData::Level { height_m } => numbers.push(*height_m),
        SensorData::Odometer { distance_m } => numbers.push(*distance_m),
        // The ring number (exact as an f64 within its bounds; negative,
        // −(ring + 1), when the key follows), the key, then the strokes,
        // if any.
        SensorData::Advance {
            ring,
            strokes_mm,
            key,
        } => {
            match key {
                Some(key) => numbers.extend([-(*ring as f64) - 1.0, f64::from(*key)]),
                None => numbers.push(*ring as f64),
            }
            numbers.extend(strokes_mm.iter().flatten());
        }
        SensorData::TailClearance { clearance_mm } => numbers.extend(clearance_mm),
    }
    numbers.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// The reading stored as `bytes` with its `t` and `sensor` columns.
pub fn decode_reading(t: f64, sensor: SensorKind, bytes: &[u8]) -> Result<Reading, StoreError> {
    let corrupt = || {
        StoreError::Corrupt(format!(
            "stored {sensor} reading at t = {t} has {} bytes",
            bytes.len()
        ))
    };
    if !bytes.len().is_multiple_of(8) {
        return Err(corrupt());
    }
    let n: Vec<f64> = bytes
        .chunks_exact(8)
        .map(|b| f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
        .collect();
    let data = match (sensor, n.as_slice()) {
        // 2 numbers: attitude; 3: with yaw; 5: with a position; 6: both.
        (SensorKind::Laser, [pitch_deg, roll_deg, rest @ ..])
            if rest.len() <= 4 && rest.len() != 2 =>
        {
            let (yaw, position) = rest.split_at(rest.len() % 3);
            SensorData::Laser {
                pitch_deg: *pitch_deg,
                roll_deg: *roll_deg,
                yaw_deg: yaw.first().copied(),
                position: match position {
                    [e, n, h] => Some(ProjectPoint {
                        easting_m: *e,
                        northing_m: *n,
                        height_m: *h,
                    }),
                    _ => None,
                },
            }
        }
        (SensorKind::Inclinometer, [pitch_deg, roll_deg, temp @ ..]) if temp.len() <= 1 => {
            SensorData::Inclinometer {
                pitch_deg: *pitch_deg,
                roll_deg: *roll_deg,
                temp_c: temp.first().copied(),
            }
        }
        (SensorKind::Imu, [ax, ay, az, gx, gy, gz]) => SensorData::Imu {
            accel_mps2: [*ax, *ay, *az],
            gyro_dps: [*gx, *gy, *gz],
        },
        (SensorKind::Magnetometer, [x, y, z]) => SensorData::Magnetometer {
            field_ut: [*x, *y, *z],
        },
        (SensorKind::Level, [height_m]) => SensorData::Level {
            height_m: *height_m,
        },
        (SensorKind::Odometer, [distance_m]) => SensorData::Odometer {
            distance_m: *distance_m,
        },
        (SensorKind::Advance, [marked, key, strokes @ ..])
            if *marked < 0.0
                && marked.fract() == 0.0
                && key.fract() == 0.0
                && (0.0..64.0).contains(key)
                && strokes.len() <= MAX_STROKES =>
        {
            SensorData::Advance {
                ring: (-marked - 1.0) as u64,
                strokes_mm: (!strokes.is_empty()).then(|| strokes.to_vec()),
                key: Some(*key as u32),
            }
        }
        (SensorKind::Advance, [ring, strokes @ ..])
            if ring.fract() == 0.0 && *ring >= 0.0 && strokes.len() <= MAX_STROKES =>
        {
            SensorData::Advance {
                ring: *ring as u64,
                strokes_mm: (!strokes.is_empty()).then(|| strokes.to_vec()),
                key: None,
            }
        }
        (SensorKind::TailClearance, gaps)
            if (CLEARANCE_POINTS.0..=CLEARANCE_POINTS.1).contains(&gaps.len()) =>
        {
            SensorData::TailClearance {
                clearance_mm: gaps.to_vec(),
            }
        }
        _ => return Err(corrupt()),
    };
    Ok(Reading { t, data })
}

/// Set in an estimate row's `codec` column when its body starts with the
/// estimate's integrity ([`Integrity::to_bytes`], two bytes) before the
/// values; the column's low 16 bits are the values' codec version. Rows
/// stored before estimates carried an integrity lack it and read as `ok`,
/// as they were shown.
pub const WITH_INTEGRITY: u32 = 1 << 16;

/// The stored body of `output` and its `codec` column.
pub fn encode_output(output: &EngineOutput) -> (Vec<u8>, u32) {
    let values = output.values.encode();
    let mut body = Vec::with_capacity(2 + values.len());
    body.extend_from_slice(&output.integrity.to_bytes());
    body.extend_from_slice(&values);
    (
        body,
        output.values.stream().codec_version() | WITH_INTEGRITY,
    )
}

/// The estimate `bytes` hold, for an estimate of `engine` at `t` stored
/// with `codec` (see [`WITH_INTEGRITY`]).
pub fn decode_output(
    engine: StreamKind,
    t: f64,
    codec: u32,
    bytes: &[u8],
) -> Result<EngineOutput, StoreError> {
    let (integrity, values) = if codec & WITH_INTEGRITY != 0 {
        let corrupt = || {
            StoreError::Corrupt(format!(
                "stored {engine} estimate at t = {t}: no integrity in its {} bytes",
                bytes.len()
            ))
        };
        let (head, values) = bytes.split_first_chunk::<2>().ok_or_else(corrupt)?;
        (Integrity::from_bytes(*head).ok_or_else(corrupt)?, values)
    } else {
        (Integrity::OK, bytes)
    };
    let version = codec & !WITH_INTEGRITY;
    let values = EstimateValues::decode(engine, version, values)
        .map_err(|e| StoreError::Corrupt(e.to_string()))?;
    Ok(EngineOutput {
        t,
        values,
        integrity,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::{AttitudeEstimate, IntegrityReason};

    #[test]
    fn readings_of_every_sensor_round_trip_exactly() {
        let t = 1_772_431_200.123_456_7;
        for data in [
            SensorData::Laser {
                pitch_deg: 0.1 + 0.2,
                roll_deg: -0.0,
                yaw_deg: Some(359.999_999_999),
                position: None,
            },
            SensorData::Laser {
                pitch_deg: 1.0,
                roll_deg: 2.0,
                yaw_deg: None,
                position: None,
            },
            SensorData::Laser {
                pitch_deg: 1.0,
                roll_deg: 2.0,
                yaw_deg: None,
                position: Some(ProjectPoint {
                    easting_m: 1012.5,
                    northing_m: 5021.25,
                    height_m: -3.5,
                }),
            },
            SensorData::Laser {
                pitch_deg: 1.0,
                roll_deg: 2.0,
                yaw_deg: Some(45.0),
                position: Some(ProjectPoint {
                    easting_m: 612_345.678,
                    northing_m: 5_012_345.5,
                    height_m: 430.25,
                }),
            },
            SensorData::Inclinometer {
                pitch_deg: -89.5,
                roll_deg: 1e-300,
                temp_c: Some(21.5),
            },
            SensorData::Inclinometer {
                pitch_deg: 3.0,
                roll_deg: 4.0,
                temp_c: None,
            },
            SensorData::Imu {
                accel_mps2: [0.01, -0.02, -9.81],
                gyro_dps: [1e-5, 2e-5, -3e-5],
            },
            SensorData::Magnetometer {
                field_ut: [20.0, -3.5, 44.1],
            },
            SensorData::Level { height_m: -12.345 },
            SensorData::Odometer { distance_m: 36.0 },
            SensorData::Advance {
                ring: 412,
                strokes_mm: None,
                key: None,
            },
            SensorData::Advance {
                ring: 9_999_999,
                strokes_mm: Some(vec![1510.5, 0.0, 1e-3]),
                key: None,
            },
            SensorData::Advance {
                ring: 0,
                strokes_mm: None,
                key: Some(0),
            },
            SensorData::Advance {
                ring: 9_999_999,
                strokes_mm: Some(vec![1510.5, 0.0]),
                key: Some(63),
            },
            SensorData::TailClearance {
                clearance_mm: vec![48.0, 51.5, 52.0, 47.25],
            },
        ] {
            let bytes = encode_reading(&data);
            let back = decode_reading(t, data.kind(), &bytes).unwrap();
            let reading = Reading { t, data };
            assert_eq!(back.to_json(), reading.to_json());
            assert_eq!(back, reading);
        }
    }

    /// An `advance` as a release before the key stored it (its ring, then
    /// its strokes) still reads.
    #[test]
    fn an_advance_stored_before_keys_reads() {
        let bytes: Vec<u8> = [412.0f64, 1500.0, 1502.5]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let back = decode_reading(1.0, SensorKind::Advance, &bytes).unwrap();
        assert_eq!(
            back.data,
            SensorData::Advance {
                ring: 412,
                strokes_mm: Some(vec![1500.0, 1502.5]),
                key: None
            }
        );
    }

    #[test]
    fn a_reading_with_the_wrong_number_of_values_is_corrupt() {
        let bytes = encode_reading(&SensorData::Level { height_m: 1.0 });
        assert!(decode_reading(1.0, SensorKind::Imu, &bytes).is_err());
        assert!(decode_reading(1.0, SensorKind::Level, &bytes[..7]).is_err());
        assert!(decode_reading(1.0, SensorKind::Laser, &bytes).is_err());
        let four = [bytes.clone(), bytes.clone(), bytes.clone(), bytes].concat();
        let err = decode_reading(1.0, SensorKind::Inclinometer, &four).unwrap_err();
        assert!(err.to_string().contains("inclinometer"), "{err}");
    }

    /// `values` at `t`, stored and read back.
    fn round_trip(values: &EstimateValues, integrity: Integrity) -> (Vec<u8>, EngineOutput) {
        let output = EngineOutput {
            t: 7.5,
            values: values.clone(),
            integrity,
        };
        let (body, codec) = encode_output(&output);
        assert_eq!(codec, values.stream().codec_version() | WITH_INTEGRITY);
        let back = decode_output(values.stream(), 7.5, codec, &body).unwrap();
        (body, back)
    }

    #[test]
    fn values_round_trip_bit_for_bit_and_small() {
        let values = EstimateValues::Attitude(AttitudeEstimate {
            pitch_deg: 0.1 + 0.2,
            roll_deg: -1.0e-300,
            pitch_pred_deg: f64::MIN_POSITIVE,
            roll_pred_deg: 12.345_678_901_234_567,
            pred_t: 1_772_431_200.123_456_7,
            pitch_sigma_deg: Some(0.004_123),
            roll_sigma_deg: Some(f64::MIN_POSITIVE),
            pitch_pred_sigma_deg: Some(1.0e-300),
            laser_ok: false,
            pitch_correction_deg: -0.0,
            laser_age_s: None,
            model_version: u64::MAX,
            incl_pitch_deg: 0.3,
            incl_roll_deg: -7.25,
        });
        let integrity = Integrity::degraded(IntegrityReason::LaserDisagrees);
        let (bytes, back) = round_trip(&values, integrity);
        // 14 fields, eight of them f64 and three optional ones set, and
        // the integrity's two bytes.
        assert!(bytes.len() <= 115, "{} bytes", bytes.len());
        assert_eq!(format!("{:?}", back.values), format!("{values:?}"));
        assert_eq!(back.integrity, integrity);
        let (a, b) = (
            back.values.as_attitude().unwrap(),
            values.as_attitude().unwrap(),
        );
        assert_eq!(
            a.pitch_correction_deg.to_bits(),
            b.pitch_correction_deg.to_bits()
        );
    }

    /// A plain `attitude` estimate.
    fn attitude_values() -> EstimateValues {
        EstimateValues::Attitude(AttitudeEstimate {
            pitch_deg: 1.0,
            roll_deg: 2.0,
            pitch_pred_deg: 1.0,
            roll_pred_deg: 2.0,
            pred_t: 3.0,
            pitch_sigma_deg: None,
            roll_sigma_deg: None,
            pitch_pred_sigma_deg: None,
            laser_ok: true,
            pitch_correction_deg: 0.5,
            laser_age_s: Some(12.0),
            model_version: 3,
            incl_pitch_deg: 1.1,
            incl_roll_deg: 2.1,
        })
    }

    #[test]
    fn truncated_bytes_are_reported_corrupt() {
        let values = attitude_values();
        let output = EngineOutput {
            t: 1.0,
            values,
            integrity: Integrity::OK,
        };
        let (bytes, codec) = encode_output(&output);
        let err =
            decode_output(StreamKind::Attitude, 1.0, codec, &bytes[..bytes.len() - 3]).unwrap_err();
        assert!(err.to_string().contains("attitude"), "{err}");
        let err = decode_output(StreamKind::Attitude, 1.0, codec, &bytes[..1]).unwrap_err();
        assert!(err.to_string().contains("integrity"), "{err}");
        let mut unknown = bytes.clone();
        unknown[0] = 9;
        assert!(decode_output(StreamKind::Attitude, 1.0, codec, &unknown).is_err());
    }

    #[test]
    fn a_row_stored_before_integrity_reads_as_ok_and_every_code_round_trips() {
        let values = attitude_values();
        let version = StreamKind::Attitude.codec_version();
        let old = decode_output(StreamKind::Attitude, 2.0, version, &values.encode()).unwrap();
        assert_eq!(
            (old.t, &old.values, old.integrity),
            (2.0, &values, Integrity::OK)
        );
        for &reason in IntegrityReason::ALL {
            for integrity in [Integrity::degraded(reason), Integrity::lost(reason)] {
                assert_eq!(round_trip(&values, integrity).1.integrity, integrity);
            }
        }
    }

    #[test]
    fn a_version_newer_than_this_release_is_refused_naming_it() {
        let values = attitude_values();
        let bytes = values.encode();
        let newer = StreamKind::Attitude.codec_version() + 1;
        for codec in [newer, newer | WITH_INTEGRITY] {
            let body = if codec & WITH_INTEGRITY != 0 {
                [&[0u8, 0][..], &bytes].concat()
            } else {
                bytes.clone()
            };
            let err = decode_output(StreamKind::Attitude, 1.0, codec, &body).unwrap_err();
            let text = err.to_string();
            assert!(
                text.contains("attitude") && text.contains(&format!("codec version {newer}")),
                "{text}"
            );
        }
        // This release's rows decode; rows stored before versions existed
        // (0) and before the σ (1) are AttitudeEstimate::decode's tests.
        let back = decode_output(StreamKind::Attitude, 1.0, newer - 1, &bytes).unwrap();
        assert_eq!(back.values, values);
    }
}

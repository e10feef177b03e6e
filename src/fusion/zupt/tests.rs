use super::*;

fn imu(t: f64, accel: V3, gyro_rad: V3) -> Reading {
    Reading {
        t,
        data: SensorData::Imu {
            accel_mps2: [accel.x, accel.y, accel.z],
            gyro_dps: [deg(gyro_rad.x), deg(gyro_rad.y), deg(gyro_rad.z)],
        },
    }
}

/// A perfect IMU standing still at the default latitude, yawed.
fn still_readings(seconds: f64, yaw_deg: f64) -> Vec<Reading> {
    let c = ZuptEngine::with_defaults().config;
    let attitude = attitude_from_euler(0.01, -0.02, rad(yaw_deg));
    let g = normal_gravity_mps2(c.site.lat_rad, c.site.height_m);
    let accel = attitude.inverse() * V3::new(0.0, 0.0, -g);
    let gyro = attitude.inverse() * earth_rate_n(c.site.lat_rad);
    (0..(seconds * 100.0) as usize)
        .map(|k| imu(1.7e9 + k as f64 * 0.01, accel, gyro))
        .collect()
}

#[test]
fn an_odometer_interval_spanning_a_stop_is_compared_over_the_interval() {
    // Level, heading north, a perfect IMU: 20 s standing, then 2 s at
    // +0.04 m/s² (80 mm/s), 3 s cruising, 2 s at −0.04 m/s², 20 s
    // standing. Travelled: 0.08 + 0.24 + 0.08 = 0.40 m. The odometer
    // reads the true distance every second, offset by half a second,
    // and is trusted (σ 0.5 mm/s). Its interval [25.5, 26.5] s is the
    // mean of a decelerating machine, (0.395 − 0.355) / 1 s = 40 mm/s,
    // while the speed at its end is 20 mm/s; the next one, 5 mm/s,
    // ends half a second after the stop. Taken for the speeds at their
    // ends they pull the velocity to speeds the machine did not have
    // then (the live distance, no smoothing, ends 1.9 mm short so);
    // compared with the INS's own mean over each interval, they agree.
    let params = Params::from_assignments(
        PARAMS,
        [
            "initial_yaw_deg=0",
            "odometer_sigma_mps=0.0005",
            "smooth_pushes=false",
        ],
    )
    .unwrap();
    let c = ZuptEngine::new(params.clone()).unwrap().config;
    let g = normal_gravity_mps2(c.site.lat_rad, c.site.height_m);
    let gyro = earth_rate_n(c.site.lat_rad);
    let accel_at = |t: f64| match t {
        t if (20.0..22.0).contains(&t) => 0.04,
        t if (25.0..27.0).contains(&t) => -0.04,
        _ => 0.0,
    };
    let distance_at = |t: f64| {
        let ramp = |s: f64| 0.5 * 0.04 * s.clamp(0.0, 2.0).powi(2);
        ramp(t - 20.0) + 0.08 * (t - 22.0).clamp(0.0, 3.0) + 0.08 * (t - 25.0).clamp(0.0, 2.0)
            - ramp(t - 25.0)
    };
    assert!((distance_at(47.0) - 0.40).abs() < 1e-12);
    assert!((distance_at(25.5) - 0.355).abs() < 1e-12);
    assert!((distance_at(26.5) - 0.395).abs() < 1e-12);
    // Each odometer reading sent with the IMU reading of its time, and
    // each sent 2 s late (after the navigation time has passed it):
    // either way it is compared over its own interval.
    for delay_steps in [0_u32, 200] {
        let mut engine = ZuptEngine::new(params.clone()).unwrap();
        let t0 = 1.7e9;
        let mut out = Vec::new();
        for k in 0..4700_u32 {
            let t = f64::from(k) * 0.01;
            let accel = V3::new(accel_at(t), 0.0, -g);
            engine.feed(&imu(t0 + t, accel, gyro), &mut out);
            if k >= delay_steps && (k - delay_steps) % 100 == 50 {
                let read_t = f64::from(k - delay_steps) * 0.01;
                let reading = Reading {
                    t: t0 + read_t,
                    data: SensorData::Odometer {
                        distance_m: distance_at(read_t),
                    },
                };
                engine.feed(&reading, &mut out);
            }
        }
        engine.flush(&mut out);
        let EstimateValues::Zupt(last) = &out.last().unwrap().values else {
            panic!("not a zupt estimate");
        };
        assert!(engine.stats.odometer_updates > 0);
        assert!(last.zv, "{last:?}");
        assert!(
            (last.distance_m - 0.40).abs() < 0.0005,
            "delay {delay_steps}: {}",
            last.distance_m
        );
    }
}

#[test]
fn a_rest_no_odometer_confirms_widens_the_position_sigma_by_the_creep_it_may_hide() {
    // σ (0.03, 0.04, 0.01) m and a bound of √3·0.04 m north: the creep's
    // RMS is 0.04 m, so north √(0.03² + 0.04²) = 0.05, east and down kept.
    let sigma = with_creep_bound(
        &V3::new(0.03, 0.04, 0.01),
        &V3::new(3f64.sqrt() * 0.04, 0.0, 0.0),
    );
    assert!((sigma.x - 0.05).abs() < 1e-12, "{sigma}");
    assert_eq!((sigma.y, sigma.z), (0.04, 0.01));

    // An engine standing 60 s heading north (yaw 0), max_speed_mps
    // 0.002: aligned within the first seconds, then every still epoch
    // adds 2 mm/s of creep it cannot rule out. Without an odometer the
    // north σ is at least 0.002 × (the still time after alignment)/√3.
    // With an odometer reading the same distance every second, a rest
    // is confirmed once the odometer stood a whole window (10 s): at
    // most 0.002 × 10/√3 = 11.5 mm of creep, and the filter's few mm.
    let params = ["initial_yaw_deg=0", "max_speed_mps=0.002"];
    let run = |odometer: bool| {
        let mut engine =
            ZuptEngine::new(Params::from_assignments(PARAMS, params).unwrap()).unwrap();
        let mut out = Vec::new();
        for reading in still_readings(60.0, 0.0) {
            let t = reading.t;
            engine.feed(&reading, &mut out);
            if odometer && (((t - 1.7e9) * 100.0).round() as u64).is_multiple_of(100) {
                let odo = Reading {
                    t,
                    data: SensorData::Odometer { distance_m: 12.5 },
                };
                engine.feed(&odo, &mut out);
            }
        }
        engine.flush(&mut out);
        let aligned: Vec<_> = out
            .iter()
            .filter_map(|o| match &o.values {
                EstimateValues::Zupt(z) if z.aligned => Some((o.t, V3::from(z.position_sigma_m))),
                _ => None,
            })
            .collect();
        let (first_t, _) = aligned[0];
        let &(last_t, sigma) = aligned.last().unwrap();
        (last_t - first_t, sigma)
    };
    let (still_s, unconfirmed) = run(false);
    assert!(still_s > 40.0, "{still_s}");
    let creep_rms_m = 0.002 * (still_s - 1.0) / 3f64.sqrt();
    assert!(
        unconfirmed.x >= creep_rms_m,
        "{unconfirmed} vs {creep_rms_m}"
    );
    assert!(unconfirmed.y < 0.01, "{unconfirmed}");
    let (_, confirmed) = run(true);
    assert!(confirmed.x < 0.02, "{confirmed}");
}

#[test]
fn one_estimate_per_imu_reading_in_order_with_bounded_latency() {
    let mut engine =
        ZuptEngine::new(Params::from_assignments(PARAMS, ["initial_yaw_deg=40"]).unwrap()).unwrap();
    let readings = still_readings(20.0, 40.0);
    let bound = engine.latency_bound_s(0.01);
    let mut out = Vec::new();
    for reading in &readings {
        engine.feed(reading, &mut out);
        if let Some(last) = out.last() {
            assert!(reading.t - last.t <= bound + 1e-9);
        }
    }
    engine.flush(&mut out);
    assert_eq!(out.len(), readings.len());
    assert!(out.windows(2).all(|w| w[0].t < w[1].t));
    let EstimateValues::Zupt(last) = &out.last().unwrap().values else {
        panic!("not a zupt estimate");
    };
    assert!(last.zv && last.aligned);
    assert!((last.yaw_deg - 40.0).abs() < 1e-6);
    assert!(last.position_m.iter().all(|p| p.abs() < 1e-4));
    // (49 + 49) samples of lookahead, the 3 s run, one period.
    assert!((bound - 3.99).abs() < 1e-9, "{bound}");
}

#[test]
fn snapshot_and_restore_continue_exactly() {
    let readings = still_readings(12.0, 10.0);
    let mut whole = ZuptEngine::with_defaults();
    let mut expected = Vec::new();
    for r in &readings {
        whole.feed(r, &mut expected);
    }
    let mut first = ZuptEngine::with_defaults();
    let mut got = Vec::new();
    for r in &readings[..700] {
        first.feed(r, &mut got);
    }
    let text = serde_json::to_string(&first.snapshot()).unwrap();
    let mut second = ZuptEngine::restore(serde_json::from_str(&text).unwrap()).unwrap();
    for r in &readings[700..] {
        second.feed(r, &mut got);
    }
    assert_eq!(got, expected);
}

#[test]
fn a_gap_ends_the_stream_and_nothing_is_lost() {
    let mut readings = still_readings(10.0, 0.0);
    let mut later = still_readings(10.0, 0.0);
    for r in &mut later {
        r.t += 30.0;
    }
    readings.extend(later);
    let mut engine = ZuptEngine::with_defaults();
    let mut out = Vec::new();
    for r in &readings {
        engine.feed(r, &mut out);
    }
    engine.flush(&mut out);
    assert_eq!(out.len(), readings.len());
    assert_eq!(engine.stats().imu_gaps, 1);
    // Late and repeated readings are dropped and counted.
    engine.feed(&readings[5], &mut out);
    assert_eq!(engine.stats().imu_dropped, 1);
}

#[test]
fn a_sensor_gone_wild_leaves_every_estimate_finite() {
    let mut readings = still_readings(10.0, 0.0);
    let t0 = readings.last().unwrap().t;
    // 2000 m/s² and 10 000 °/s, within the protocol's range, for 10 min.
    for k in 1..60_000 {
        let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
        readings.push(imu(
            t0 + k as f64 * 0.01,
            V3::new(2000.0 * sign, 2000.0, -2000.0),
            V3::new(rad(10_000.0), rad(-10_000.0) * sign, rad(10_000.0)),
        ));
    }
    let mut engine = ZuptEngine::with_defaults();
    let mut out = Vec::new();
    for r in &readings {
        engine.feed(r, &mut out);
    }
    engine.flush(&mut out);
    // An estimate per reading but the spikes the screen refused (the
    // first readings gone wild, until the change persisted).
    let spikes = engine.stats().imu_spikes;
    assert!((1..=3).contains(&spikes), "{spikes}");
    assert_eq!(out.len() as u64 + spikes, readings.len() as u64);
    for o in &out {
        let z = o.values.as_zupt().unwrap();
        assert!(
            z.position_m
                .iter()
                .chain(&z.velocity_mps)
                .all(|x| x.is_finite())
        );
        assert!(z.distance_m.is_finite() && z.yaw_deg.is_finite());
    }
}

#[test]
fn restore_refuses_a_pipeline_that_does_not_match_the_parameters() {
    let engine = ZuptEngine::with_defaults();
    let mut snapshot = engine.snapshot();
    snapshot["params"]["values"]["window_samples"] = serde_json::json!(20);
    assert!(matches!(
        ZuptEngine::restore(snapshot),
        Err(SnapshotError::Invalid(_))
    ));
}

/// Standing 20 s heading north (it aligns), then +0.04 m/s² forward
/// for 10 s, with `max_speed_mps` 0.1: beyond 0.1 m/s (2.5 s in, and
/// 3σ of the filter's velocity, a few mm/s) the machine cannot be
/// going so fast, so the estimate is `lost` (`speed_implausible`),
/// and the INS's advance since then, 0.02 × (9.9² − 2.6²) = 1.83 m by
/// 29.9 s, joins the position's bound (σ north is the bound over √3,
/// the filter's own a few cm): before, the standing since alignment
/// no odometer confirmed, 0.1 m/s × 19–20 s.
#[test]
fn a_speed_the_machine_cannot_have_is_lost_and_widens_the_position() {
    let params =
        Params::from_assignments(PARAMS, ["initial_yaw_deg=0", "max_speed_mps=0.1"]).unwrap();
    let c = ZuptEngine::new(params.clone()).unwrap().config;
    let g = normal_gravity_mps2(c.site.lat_rad, c.site.height_m);
    let gyro = earth_rate_n(c.site.lat_rad);
    let mut engine = ZuptEngine::new(params).unwrap();
    let t0 = 1.7e9;
    let mut out = Vec::new();
    for k in 0..3000_u32 {
        let t = f64::from(k) * 0.01;
        let forward = if t >= 20.0 { 0.04 } else { 0.0 };
        engine.feed(&imu(t0 + t, V3::new(forward, 0.0, -g), gyro), &mut out);
    }
    engine.flush(&mut out);
    let at_t = |t: f64| out.iter().find(|o| o.t >= t0 + t - 1e-6).unwrap().clone();
    let at = [at_t(21.5), at_t(29.9)];
    let sigma_north = |o: &EngineOutput| o.values.as_zupt().unwrap().position_sigma_m[0];
    // 21.5 s: 0.06 m/s, within what the machine can do.
    assert_ne!(
        at[0].integrity.reason,
        Some(IntegrityReason::SpeedImplausible)
    );
    let bound_m = |o: &EngineOutput| sigma_north(o) * 3f64.sqrt();
    assert!((1.9..2.0).contains(&bound_m(&at[0])), "{:?}", at[0]);
    assert_eq!(
        at[1].integrity,
        Integrity::lost(IntegrityReason::SpeedImplausible)
    );
    let run_m = bound_m(&at[1]) - bound_m(&at[0]);
    assert!((1.8..1.95).contains(&run_m), "{run_m} {:?}", at[1]);
}

#[test]
fn only_what_a_wheel_can_have_counted_is_a_slip() {
    // 2 s at most 0.15 m/s: the machine advanced 0 to 0.3 m (scale 1).
    let interval = |advance_m: f64, ins_advance_m: f64| OdometerInterval {
        advance_m,
        ins_advance_m,
        dt_s: 2.0,
    };
    let slip = |i: OdometerInterval| i.possible_slip_m(1.0, 0.15);
    // Counted 0.05 m, the INS 0.01 m: a slip of 0.04 m.
    assert!((slip(interval(0.05, 0.01)) - 0.04).abs() < 1e-12);
    // Counted nothing while the INS ran 0.2 m backward: the INS's
    // drift, no slip (the wheel counted nothing to take back).
    assert_eq!(slip(interval(0.0, -0.2)), 0.0);
    // Counted 0.05 m, the INS 0.1 m backward: at most the 0.05 m counted.
    assert!((slip(interval(0.05, -0.1)) - 0.05).abs() < 1e-12);
    // Counted 0.1 m, the INS 1 m ahead: the wheel missed at most what
    // the fastest machine ran beyond its count, 0.1 − 0.3 = −0.2 m.
    assert!((slip(interval(0.1, 1.0)) + 0.2).abs() < 1e-12);
    // Counted 0.5 m, the INS 0.7 m: faster than the machine goes, so
    // the wheel counted at least 0.5 − 0.3 = 0.2 m too many.
    assert!((slip(interval(0.5, 0.7)) - 0.2).abs() < 1e-12);
    // Counted 0.02 m, the INS 0.03 m: a wheel that missed 0.01 m.
    assert!((slip(interval(0.02, 0.03)) + 0.01).abs() < 1e-12);
    // A wheel reading 5 % long: the fastest count over 2 s is
    // 1.05 × 0.3 = 0.315 m. Counted 0.5 m, the INS 0.1 m: the excess
    // 0.5 − 0.105 = 0.395 m lies within [0.185, 0.5], all of it a slip.
    let i = interval(0.5, 0.1);
    assert!((i.possible_slip_m(1.05, 0.15) - 0.395).abs() < 1e-12);
    // Counted 0.5 m, the INS 0.8 m: the excess −0.34 m is beyond what
    // a wheel can miss; at least 0.5 − 0.315 = 0.185 m was counted too many.
    let i = interval(0.5, 0.8);
    assert!((i.possible_slip_m(1.05, 0.15) - 0.185).abs() < 1e-12);
}

#[test]
fn a_snapshot_from_before_the_state_version_is_outdated() {
    let mut engine = ZuptEngine::with_defaults();
    let mut out = Vec::new();
    for r in still_readings(5.0, 0.0) {
        engine.feed(&r, &mut out);
    }
    let mut old = engine.snapshot();
    assert!(ZuptEngine::restore(old.clone()).is_ok());
    old.as_object_mut().unwrap().remove("state_version");
    assert!(matches!(
        ZuptEngine::restore(old),
        Err(SnapshotError::Outdated {
            found: 1,
            expected: 10,
            ..
        })
    ));
}

#[test]
fn a_snapshot_in_the_middle_of_a_push_continues_exactly_and_smooths_it() {
    // The trolley run's first 75 s: a rest, a push from 30 s, its rest.
    let readings: Vec<Reading> =
        crate::sim::pipejack::PipeJackDrive::new(crate::sim::pipejack::PipeJackScenario::default())
            .unwrap()
            .map(|e| e.reading)
            .take_while(|r| r.t < crate::sim::tbm::DEFAULT_START_T + 75.0)
            .collect();
    let mut whole = ZuptEngine::with_defaults();
    let mut expected = Vec::new();
    for r in &readings {
        whole.feed(r, &mut expected);
    }
    let smoothed: Vec<&Vec<TrackPoint>> = expected
        .iter()
        .filter_map(|o| o.values.as_zupt()?.smoothed_push.as_ref())
        .collect();
    assert_eq!(smoothed.len(), 1, "one push, smoothed once");
    let track = smoothed[0];
    assert!(track.len() > 25, "{}", track.len());
    assert!(track.windows(2).all(|w| w[0].t < w[1].t));
    // Cut during the push (45 s in): the record travels in the snapshot.
    let cut = readings
        .iter()
        .position(|r| r.t >= crate::sim::tbm::DEFAULT_START_T + 45.0)
        .unwrap();
    let mut first = ZuptEngine::with_defaults();
    let mut got = Vec::new();
    for r in &readings[..cut] {
        first.feed(r, &mut got);
    }
    assert!(
        first
            .navigation
            .as_ref()
            .unwrap()
            .push
            .as_ref()
            .unwrap()
            .has_moved()
    );
    let text = serde_json::to_string(&first.snapshot()).unwrap();
    let mut second = ZuptEngine::restore(serde_json::from_str(&text).unwrap()).unwrap();
    for r in &readings[cut..] {
        second.feed(r, &mut got);
    }
    assert_eq!(got, expected);
}

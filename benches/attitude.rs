//! Throughput of `replay` with the `attitude` engine on a 1 Hz inclinometer /
//! 60 s laser drive, and the cost of one ANFIS training step per laser sample.
//!
//! Run: `cargo bench --bench attitude`.

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use tunnelnav::fusion::attitude::anfis::{Anfis, TrainingSample};
use tunnelnav::fusion::attitude::{AttitudeConfig, AttitudeEngine, PARAMS};
use tunnelnav::fusion::pipeline::Pipeline;
use tunnelnav::fusion::{Engine, Params, Reading};
use tunnelnav::replay::{ReplayOptions, replay};
use tunnelnav::sim::tbm::{TbmDrive, TbmScenario};

fn drive(hours: f64) -> Vec<Reading> {
    drive_with(hours, 1.0, 60.0)
}

fn drive_with(hours: f64, incl_period_s: f64, laser_period_s: f64) -> Vec<Reading> {
    TbmDrive::new(TbmScenario {
        hours,
        incl_period_s,
        laser_period_s,
        ..TbmScenario::default()
    })
    .expect("valid scenario")
    .map(|e| e.reading)
    .collect()
}

fn replay_throughput(c: &mut Criterion) {
    let readings = drive(3.0);
    let mut ndjson = Vec::new();
    for r in &readings {
        ndjson.extend_from_slice(r.to_json().as_bytes());
        ndjson.push(b'\n');
    }
    let mut group = c.benchmark_group("attitude");
    group.throughput(Throughput::Elements(readings.len() as u64));
    group.sample_size(20);
    // The whole replay path: parse NDJSON, reorder, fuse, train, write NDJSON.
    group.bench_function("replay_ndjson_1hz_incl_60s_laser", |b| {
        let mut out = Vec::with_capacity(ndjson.len() * 3);
        b.iter(|| {
            out.clear();
            let mut engine =
                Pipeline::with_engines(vec![Box::new(AttitudeEngine::with_defaults())]);
            let summary = replay(
                &ndjson[..],
                &mut out,
                std::io::sink(),
                &mut engine,
                &ReplayOptions::default(),
            )
            .expect("in-memory replay");
            black_box(summary)
        })
    });
    // The engine alone on parsed readings.
    group.bench_function("engine_only_1hz_incl_60s_laser", |b| {
        let mut outputs = Vec::with_capacity(4);
        b.iter(|| {
            let mut engine = AttitudeEngine::with_defaults();
            for r in &readings {
                outputs.clear();
                engine.feed(r, &mut outputs);
            }
            black_box(engine.stats())
        })
    });
    group.finish();
}

/// The time of each reading on its own, on a sparse inclinometer (every
/// 5 s) and a laser every 10 s: the young model trains at every laser
/// sample, so here the training is most of the cost. Printed as mean,
/// 99th percentile and worst over the first hour, best of five runs.
fn per_reading_cost(_: &mut Criterion) {
    const NAME: &str = "attitude/per_reading_5s_incl_10s_laser_first_hour";
    // Criterion's name filter (the first argument not a flag) holds here too.
    let filter = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    if filter.is_some_and(|f| !NAME.contains(f.as_str())) {
        return;
    }
    let readings = drive_with(1.0, 5.0, 10.0);
    let mut best: Option<(f64, f64, f64)> = None;
    for _ in 0..5 {
        let mut engine = AttitudeEngine::with_defaults();
        let mut outputs = Vec::with_capacity(4);
        let mut times_us = Vec::with_capacity(readings.len());
        for r in &readings {
            outputs.clear();
            let started = std::time::Instant::now();
            engine.feed(r, &mut outputs);
            times_us.push(started.elapsed().as_secs_f64() * 1e6);
            black_box(&outputs);
        }
        let mean = times_us.iter().sum::<f64>() / times_us.len() as f64;
        times_us.sort_by(f64::total_cmp);
        let p99 = times_us[times_us.len() * 99 / 100];
        let worst = times_us[times_us.len() - 1];
        if best.is_none_or(|(m, _, _)| mean < m) {
            best = Some((mean, p99, worst));
        }
    }
    if let Some((mean, p99, worst)) = best {
        println!(
            "{NAME}: {} readings, mean {mean:.1} µs, p99 {p99:.1} µs, worst {worst:.1} µs",
            readings.len()
        );
    }
}

fn training_cost(c: &mut Criterion) {
    // A full window of pairs, as after a long drive: the cost per laser
    // sample is one add + train on `training_window_samples` pairs.
    let config = AttitudeConfig::from_params(&Params::defaults(PARAMS))
        .expect("defaults")
        .anfis;
    let mut model = Anfis::new(config);
    let pair = |i: usize| {
        let roll_deg = 1.0 + 1.5 * (i as f64 * 0.05).sin();
        TrainingSample {
            t: i as f64 * 60.0,
            roll_rad: roll_deg.to_radians(),
            error_rad: (0.3 + 0.05 * roll_deg - 0.008 * roll_deg * roll_deg).to_radians(),
            temp_c: Some(18.0 + 3.0 * (i as f64 * 0.013).sin()),
            seq: 0,
        }
    };
    for i in 0..config.window {
        model.add_sample(pair(i));
        model.train();
    }
    let mut i = config.window;
    c.bench_function("anfis_train_per_laser_sample_full_window", |b| {
        b.iter(|| {
            model.add_sample(pair(i));
            i += 1;
            model.train();
            black_box(model.version())
        })
    });
}

criterion_group!(benches, per_reading_cost, replay_throughput, training_cost);
criterion_main!(benches);

//! Throughput of the `fuzzy` engine on the simulated 20-minute vehicle
//! drive (MEMS IMU at 100 Hz, magnetometer at 10 Hz): the engine alone on
//! parsed readings (one core), and the whole `replay` path (parse NDJSON,
//! reorder, fuse, write NDJSON). Target: ≥ 1,000,000 IMU readings/s
//! through the engine.
//!
//! Run: `cargo bench --bench fuzzy`.

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use tunnelnav::fusion::fuzzy::FuzzyEngine;
use tunnelnav::fusion::pipeline::Pipeline;
use tunnelnav::fusion::{Engine, Reading, SensorKind};
use tunnelnav::replay::{ReplayOptions, replay};
use tunnelnav::sim::vehicle::{VehicleDrive, VehicleScenario};

fn drive() -> Vec<Reading> {
    VehicleDrive::new(VehicleScenario::default())
        .expect("valid scenario")
        .map(|e| e.reading)
        .collect()
}

fn throughput(c: &mut Criterion) {
    let readings = drive();
    let imu = readings
        .iter()
        .filter(|r| r.sensor() == SensorKind::Imu)
        .count();
    let mut group = c.benchmark_group("fuzzy");
    // Counted in IMU readings (the magnetometer rides along).
    group.throughput(Throughput::Elements(imu as u64));
    group.sample_size(10);
    group.bench_function("engine_only_vehicle_100hz", |b| {
        let mut outputs = Vec::with_capacity(4);
        b.iter(|| {
            let mut engine = FuzzyEngine::with_defaults();
            for r in &readings {
                outputs.clear();
                engine.feed(r, &mut outputs);
            }
            black_box(outputs.len())
        })
    });
    let mut ndjson = Vec::new();
    for r in &readings {
        ndjson.extend_from_slice(r.to_json().as_bytes());
        ndjson.push(b'\n');
    }
    group.bench_function("replay_ndjson_vehicle_100hz", |b| {
        let mut out = Vec::with_capacity(ndjson.len() * 3);
        b.iter(|| {
            out.clear();
            let mut engine = Pipeline::with_engines(vec![Box::new(FuzzyEngine::with_defaults())]);
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
    group.finish();

    // One inference whose rule strengths change every time (no reuse of
    // the last centroid): the cost during transitions.
    let engine = FuzzyEngine::with_defaults();
    let expert = tunnelnav::fusion::fuzzy::motion::motion_expert(&engine.config().motion)
        .expect("default rule base");
    let mut scratch = tunnelnav::fusion::fuzzy::mamdani::Scratch::default();
    let mut group = c.benchmark_group("fuzzy_inference");
    group.throughput(Throughput::Elements(1000));
    group.bench_function("uncached_1000", |b| {
        b.iter(|| {
            let mut sum = 0.0;
            for i in 0..1000 {
                let x = f64::from(i) * 1e-4;
                sum += expert
                    .infer_with(&[0.1 + x, 0.08 + x, 0.008], &mut scratch)
                    .expect("three inputs")
                    .unwrap_or(0.0);
            }
            black_box(sum)
        })
    });
    group.finish();
}

criterion_group!(benches, throughput);
criterion_main!(benches);

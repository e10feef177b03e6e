//! Throughput of the `zupt` engine on the simulated trolley drive (FOG IMU
//! at 100 Hz, level and odometer at 1 Hz): the engine alone on parsed
//! readings (one core), and the whole `replay` path (parse NDJSON, reorder,
//! fuse, write NDJSON). Target: ≥ 200,000 IMU readings/s through the engine
//! (2,000 machines' worth in real time).
//!
//! Run: `cargo bench --bench zupt`.

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use tunnelnav::fusion::pipeline::Pipeline;
use tunnelnav::fusion::zupt::ZuptEngine;
use tunnelnav::fusion::{Engine, Reading, SensorKind};
use tunnelnav::replay::{ReplayOptions, replay};
use tunnelnav::sim::pipejack::{PipeJackDrive, PipeJackScenario};

fn drive() -> Vec<Reading> {
    PipeJackDrive::new(PipeJackScenario::default())
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
    let mut group = c.benchmark_group("zupt");
    // Counted in IMU readings (the level and odometer ride along).
    group.throughput(Throughput::Elements(imu as u64));
    group.sample_size(10);
    group.bench_function("engine_only_trolley_100hz", |b| {
        let mut outputs = Vec::with_capacity(512);
        b.iter(|| {
            let mut engine = ZuptEngine::with_defaults();
            for r in &readings {
                outputs.clear();
                engine.feed(r, &mut outputs);
            }
            engine.flush(&mut outputs);
            black_box(outputs.len())
        })
    });
    let mut ndjson = Vec::new();
    for r in &readings {
        ndjson.extend_from_slice(r.to_json().as_bytes());
        ndjson.push(b'\n');
    }
    group.bench_function("replay_ndjson_trolley_100hz", |b| {
        let mut out = Vec::with_capacity(ndjson.len() * 3);
        b.iter(|| {
            out.clear();
            let mut engine = Pipeline::with_engines(vec![Box::new(ZuptEngine::with_defaults())]);
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
}

criterion_group!(benches, throughput);
criterion_main!(benches);

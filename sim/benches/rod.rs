//! Criterion benchmark of the rod-mill pass check on the example RSM mill
//! (`models/rod/`): one pass's span status at one finishing speed (what a service does
//! when the PLC's speed changes), one pass's full evaluation (every point with its
//! tongue and margin in a), one pass set up (validation, beams, every source's speed
//! bands: when the pass or configuration changes), the whole 4-pass schedule.
//!
//! Run: `cargo bench -p millgate-sim --bench rod`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use millgate_sim::rod::check::{check_schedule, PassSetup};
use millgate_sim::rod::mill::RodMill;
use millgate_sim::rod::schedule;

fn bench_rod(c: &mut Criterion) {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("models/rod");
    let mill = std::sync::Arc::new(
        RodMill::load(dir.join("rsm-mill.toml")).unwrap_or_else(|e| panic!("{e}")),
    );
    let passes = schedule::load(dir.join("rsm-schedule.csv")).unwrap_or_else(|e| panic!("{e}"));
    let mut group = c.benchmark_group("rod");
    // P1: every point stable; P3: two points inside damped tongues.
    for pass in [&passes[0], &passes[2]] {
        let setup = PassSetup::new(&mill, pass).unwrap_or_else(|e| panic!("{e}"));
        let speed = setup.finishing_speed_m_s;
        let points: usize = setup.spans.iter().map(|s| s.sources.len()).sum();
        group.bench_function(format!("status {} ({points} points)", pass.name), |b| {
            b.iter(|| setup.status(black_box(speed)))
        });
        group.bench_function(format!("evaluate {} ({points} points)", pass.name), |b| {
            b.iter(|| setup.evaluate(black_box(speed)))
        });
        group.bench_function(format!("setup {} (with speed bands)", pass.name), |b| {
            b.iter(|| PassSetup::new(&mill, black_box(pass)).map(|s| s.avoid.len()))
        });
    }
    group.sample_size(20);
    group.bench_function("check_schedule (4 passes)", |b| {
        b.iter(|| check_schedule(&mill, black_box(&passes)).map(|r| r.passes.len()))
    });
    group.finish();
}

criterion_group!(benches, bench_rod);
criterion_main!(benches);

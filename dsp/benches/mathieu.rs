//! Time per Mathieu characteristic value, growth exponent and tongue location.
//!
//! Run: `cargo bench -p millgate-dsp --bench mathieu`.

use criterion::{criterion_group, criterion_main, Criterion};
use millgate_dsp::mathieu::Mathieu;
use std::hint::black_box;

fn mathieu(c: &mut Criterion) {
    let m = Mathieu::default();
    let mut group = c.benchmark_group("mathieu");
    group.bench_function("characteristic_a10_q100", |b| {
        b.iter(|| m.characteristic_a(black_box(10), black_box(100.0)))
    });
    group.bench_function("characteristic_b1_q0.5", |b| {
        b.iter(|| m.characteristic_b(black_box(1), black_box(0.5)))
    });
    // A rod point in the principal tongue: integration needed.
    group.bench_function("exponent_inside_tongue1_q0.3", |b| {
        b.iter(|| m.exponent(black_box(1.02), black_box(0.3), black_box(0.02)))
    });
    group.bench_function("exponent_inside_tongue1_q40", |b| {
        b.iter(|| m.exponent(black_box(1.0), black_box(40.0), black_box(0.02)))
    });
    // A stable point: decided by Sturm counts, no integration.
    group.bench_function("exponent_stable_q0.3", |b| {
        b.iter(|| m.exponent(black_box(2.5), black_box(0.3), black_box(0.02)))
    });
    group.bench_function("locate_undamped_q0.3", |b| {
        b.iter(|| m.locate(black_box(2.5), black_box(0.3), black_box(0.0)))
    });
    group.bench_function("locate_damped_q0.3", |b| {
        b.iter(|| m.locate(black_box(2.5), black_box(0.3), black_box(0.02)))
    });
    // Typical rod points (example RSM pass P1): below tongue 1, and a second mode far up.
    group.bench_function("locate_rod_a0.44_q0.022", |b| {
        b.iter(|| m.locate(black_box(0.443), black_box(0.0221), black_box(0.013)))
    });
    group.bench_function("locate_rod_a17.3_q0.22", |b| {
        b.iter(|| m.locate(black_box(17.27), black_box(0.2159), black_box(0.083)))
    });
    group.bench_function("locate_rod_a233_q2.9", |b| {
        b.iter(|| m.locate(black_box(232.9), black_box(2.91), black_box(0.305)))
    });
    group.finish();
}

criterion_group!(benches, mathieu);
criterion_main!(benches);

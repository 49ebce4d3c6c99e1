//! Criterion benchmark of one full simulation of the Table 2 models (0.6 s at 2 kHz).

use criterion::{criterion_group, criterion_main, Criterion};
use millgate_sim::chain::Simulator;
use millgate_sim::model::Model;

fn bench_simulate(c: &mut Criterion) {
    for name in ["table2-adjusted.toml", "table2-adjusted-backlash.toml"] {
        let path = format!("{}/models/{name}", env!("CARGO_MANIFEST_DIR"));
        let model = match Model::load(&path) {
            Ok(model) => model,
            Err(error) => panic!("{error}"),
        };
        let simulator = match Simulator::new(&model) {
            Ok(simulator) => simulator,
            Err(error) => panic!("{error}"),
        };
        let mut torque = vec![0.0; simulator.sample_count()];
        c.bench_function(&format!("simulate {name}"), |b| {
            b.iter(|| {
                let mut state = simulator.initial_state();
                simulator.run_into(&mut state, &mut torque)
            })
        });
    }
}

criterion_group!(benches, bench_simulate);
criterion_main!(benches);

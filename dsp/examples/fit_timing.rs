//! Times `fit_eq1` on the Table 1 transient with seeded noise and writes the record.
//!
//! `cargo run --release -p millgate-dsp --example fit_timing -- LEN CSV_OUT [REPEATS]`
//! generates LEN samples over 0.5 s (noise RMS 2% of a9, seed 7), writes `t,torque`
//! to CSV_OUT (so another tool fits the very same data), fits it REPEATS times (default
//! 200; raise it to profile the fit under `perf record`) and prints
//! one JSON object: median time per fit, fitted parameters and relative errors.

use millgate_dsp::fit::{eq1, fit_eq1, FitOptions};
use rand::rngs::StdRng;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use std::error::Error;
use std::fmt::Write as _;
use std::time::Instant;

const TABLE1: [f64; 10] = [
    -147.0, 85.0, 191.0, -31.0, 11.99, 20.91, 22.17, 3.65, 112.0, 36.7,
];

fn main() -> Result<(), Box<dyn Error>> {
    let mut args = std::env::args().skip(1);
    let len: usize = args
        .next()
        .ok_or("usage: fit_timing LEN CSV_OUT [REPEATS]")?
        .parse()?;
    let out = args
        .next()
        .ok_or("usage: fit_timing LEN CSV_OUT [REPEATS]")?;
    let repeats: usize = match args.next() {
        Some(text) => text.parse()?,
        None => 200,
    };
    if repeats == 0 {
        return Err("REPEATS must be >= 1".into());
    }
    let rate = len as f64 / 0.5;
    let mut rng = StdRng::seed_from_u64(7);
    let noise = Normal::new(0.0, 0.02 * TABLE1[8])?;
    let samples: Vec<f64> = (0..len)
        .map(|i| eq1(&TABLE1, i as f64 / rate) + noise.sample(&mut rng))
        .collect();
    let mut csv = String::from("t,torque\n");
    for (i, v) in samples.iter().enumerate() {
        writeln!(csv, "{:.9},{:.12}", i as f64 / rate, v)?;
    }
    std::fs::write(&out, csv)?;

    let options = FitOptions::new(rate);
    let fit = fit_eq1(&samples, &options).map_err(|e| format!("fit failed: {e:?}"))?;
    let mut times = Vec::with_capacity(repeats);
    for _ in 0..repeats {
        let start = Instant::now();
        let result = fit_eq1(std::hint::black_box(&samples), &options);
        times.push(start.elapsed().as_secs_f64());
        std::hint::black_box(result.ok());
    }
    times.sort_by(f64::total_cmp);
    let median = times[repeats / 2];
    let params: Vec<String> = fit.params.iter().map(|p| format!("{p:.6}")).collect();
    println!(
        "{{\"len\": {len}, \"median_s\": {median:.9}, \"iterations\": {}, \"params\": [{}], \
         \"f1_rel_error\": {:.6e}, \"f2_rel_error\": {:.6e}, \"rms_residual\": {:.6}}}",
        fit.iterations,
        params.join(", "),
        (fit.f1_hz / TABLE1[4] - 1.0).abs(),
        (fit.f2_hz / TABLE1[5] - 1.0).abs(),
        fit.rms_residual
    );
    Ok(())
}

//! Speed of the physical tandem mill (`sim::tandem`): simulated seconds per wall
//! second for the 5-stand example at 2.5 and 5 kHz output (target >= 100x at 5 kHz),
//! and the time of the characteristic-root computations.
//!
//! ```text
//! cargo bench -p millgate-sim --bench tandem
//! ```

use std::time::Instant;

use millgate_sim::tandem::roots::{is_stable, Characteristic};
use millgate_sim::tandem::simulate::{simulate, Accelerometer, Excitation, RunSettings, SpeedRamp};
use millgate_sim::tandem::truth::mill_critical_speed;
use millgate_sim::tandem::{PassSchedule, TandemMill};

/// Runs per figure; the median is reported.
const REPEATS: usize = 5;

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let mill = TandemMill::new(&PassSchedule::example()?)?;
    for rate in [2500.0, 5000.0] {
        let settings = RunSettings {
            ramp: SpeedRamp {
                start: 0.9,
                end: 1.2,
                hold_s: 10.0,
                accel_m_s2: 1.0,
            },
            excitation: Excitation::default(),
            sensor: Accelerometer {
                sample_rate_hz: rate,
                ..Accelerometer::default()
            },
            duration_s: 20.0,
            seed: 1,
            internal_rate_hz: None,
        };
        let times: Vec<f64> = (0..REPEATS)
            .map(|_| {
                let start = Instant::now();
                let record = simulate(&mill, &settings);
                std::hint::black_box(&record);
                start.elapsed().as_secs_f64()
            })
            .collect();
        let wall = median(times);
        println!(
            "simulate, 5 stands, {rate} Hz output, {} s: {:.1} ms, {:.0}x real time",
            settings.duration_s,
            wall * 1e3,
            settings.duration_s / wall
        );
    }
    let timed = |f: &dyn Fn() -> anyhow::Result<()>| -> anyhow::Result<f64> {
        let mut times = Vec::new();
        for _ in 0..REPEATS {
            let start = Instant::now();
            f()?;
            times.push(start.elapsed().as_secs_f64());
        }
        Ok(median(times))
    };
    for speed in [0.6, 1.0, 1.2] {
        let rightmost = timed(&|| {
            Characteristic::new(&mill.linear_system(speed))?.rightmost()?;
            Ok(())
        })?;
        let stable = timed(&|| {
            is_stable(&mill, speed)?;
            Ok(())
        })?;
        println!(
            "speed factor {speed}: rightmost root (Newton + certificate) {:.0} ms, stability count {:.0} ms",
            rightmost * 1e3,
            stable * 1e3
        );
    }
    let critical = timed(&|| {
        mill_critical_speed(&mill)?;
        Ok(())
    })?;
    println!("critical speed (0.2-4, to 1e-3): {:.2} s", critical);
    Ok(())
}

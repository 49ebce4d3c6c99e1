//! The chatter monitor's per-message path never touches the heap: ring buffers, FFT
//! plans, scratch and spectra are allocated when the monitor is built. A counting
//! global allocator wraps the system one; only the measuring thread is counted.

use std::time::{Duration, Instant};

use millgate::analysis::chatter::{ChatterMonitor, ChatterUpdate};
use millgate_sim::tandem::simulate::{simulate, Accelerometer, Excitation, RunSettings, SpeedRamp};
use millgate_sim::tandem::{PassSchedule, TandemMill};
use millgate_tests::counting_allocator::{allocations_during, CountingAllocator};

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

const FS: f64 = 2500.0;
const BLOCK: usize = 120;

#[test]
fn samples_gaps_and_evaluations_allocate_nothing() -> anyhow::Result<()> {
    let text = format!(
        "name = \"t\"\n[[sources.modbus]]\nname = \"daq\"\naddress = \"127.0.0.1:1\"\npoll_period_ms = 20\n\
         [[channels]]\nname = \"a\"\nkind = \"acceleration\"\nunit = \"g\"\nsample_rate_hz = {FS}\n\
         source = {{ modbus = \"daq\", table = \"input\", block = 0 }}\n\
         [[channels]]\nname = \"b\"\nkind = \"acceleration\"\nunit = \"g\"\nsample_rate_hz = {FS}\n\
         source = {{ modbus = \"daq\", table = \"input\", block = 122 }}\n\
         [[channels]]\nname = \"c\"\nkind = \"acceleration\"\nunit = \"g\"\nsample_rate_hz = {FS}\n\
         source = {{ modbus = \"daq\", table = \"input\", block = 244 }}\n\
         [[tandem_mills]]\nname = \"TCM\"\nstands = [\"a\", \"b\", \"c\"]\n\
         chatter_band_hz = [100.0, 300.0]\nwindow_s = 0.5\nk_max = 0.25\n\
         gain_thresholds = [2.209, 3.087, 3.327]\n"
    );
    let config = millgate_config::from_toml_str(&text, "t.toml", std::path::Path::new("."))
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut monitor = ChatterMonitor::new(&config, 0)?;
    // The physical model's last three stands: stable, then a ramp into chatter.
    let mill = TandemMill::new(&PassSchedule::example()?)?;
    let record = simulate(
        &mill,
        &RunSettings {
            ramp: SpeedRamp {
                start: 1.0,
                end: 1.4,
                hold_s: 3.0,
                accel_m_s2: 2.0,
            },
            excitation: Excitation::default(),
            sensor: Accelerometer {
                sample_rate_hz: FS,
                ..Accelerometer::default()
            },
            duration_s: 10.0,
            seed: 3,
            internal_rate_hz: None,
        },
    )?;
    let signals = &record.acceleration[2..];
    let t0 = Instant::now();
    let period = Duration::from_secs_f64(BLOCK as f64 / FS);

    let (mut evaluated, mut restarted, mut gained) = (0, 0, 0);
    let ((), allocations) = allocations_during(|| {
        for (b, start) in (0..signals[0].len() - BLOCK).step_by(BLOCK).enumerate() {
            if b == 40 {
                restarted += usize::from(monitor.gap(1, Some(0)).is_some());
            }
            for (s, signal) in signals.iter().enumerate() {
                let update =
                    monitor.samples(s, &signal[start..start + BLOCK], t0 + period * b as u32);
                match update {
                    Some(ChatterUpdate::Evaluated(_)) => {
                        evaluated += 1;
                        gained += usize::from(monitor.gain().is_some_and(|g| g.ratio.is_some()));
                    }
                    Some(ChatterUpdate::Restarted(_)) => restarted += 1,
                    _ => {}
                }
            }
        }
    });
    assert!(evaluated > 30, "{evaluated} windows evaluated");
    // The band gain ran too: readings once its 2 s window filled, before and after the gap.
    assert!(
        gained > 10,
        "{gained} of {evaluated} windows with a gain reading"
    );
    assert_eq!(restarted, 1, "the gap");
    assert_eq!(
        allocations, 0,
        "{allocations} allocations in {evaluated} windows"
    );
    // Guards the guard: the allocator is installed and counts this thread.
    let (v, counted) = allocations_during(|| std::hint::black_box(Vec::<u64>::with_capacity(16)));
    drop(v);
    assert!(counted > 0, "the counting allocator sees an allocation");
    Ok(())
}

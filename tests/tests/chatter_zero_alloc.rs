//! The chatter monitor's per-message path never touches the heap: ring buffers, FFT
//! plans, scratch and spectra are allocated when the monitor is built. A counting
//! global allocator wraps the system one; only the measuring thread is counted.

use std::time::{Duration, Instant};

use millgate::analysis::chatter::{ChatterMonitor, ChatterUpdate};
use millgate_tests::kit::counting_allocator::{allocations_during, CountingAllocator};
use millgate_tests::kit::tandem::{modbus_source, reference_ramp, Stands, FS};

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

const BLOCK: usize = 120;

#[test]
fn samples_gaps_and_evaluations_allocate_nothing() -> anyhow::Result<()> {
    let text =
        String::from("name = \"t\"\n") + &modbus_source("daq") + &Stands::modbus(3, "daq").toml();
    let config = millgate_config::from_toml_str(&text, "t.toml", std::path::Path::new("."))
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut monitor = ChatterMonitor::new(&config, 0)?;
    // The reference ramp's last three stands: stable, then a ramp into chatter.
    let record = reference_ramp(0.9, 3.0, 10.0, 3)?;
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

//! The chatter monitor's per-message path never touches the heap: ring buffers, FFT
//! plans, scratch and spectra are allocated when the monitor is built. A counting
//! global allocator wraps the system one; only the measuring thread is counted.
#![allow(unsafe_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::time::{Duration, Instant};

use millgate::analysis::chatter_monitor::{ChatterMonitor, ChatterUpdate};
use millgate_sim::stands::{Regime, Stands, StandsSettings};

struct Counting;

thread_local! {
    /// True while this thread is under measurement (const-initialised: no allocation).
    static MEASURING: Cell<bool> = const { Cell::new(false) };
    /// Allocations made by this thread while measuring.
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

fn count() {
    if MEASURING.try_with(Cell::get).unwrap_or(false) {
        let _ = ALLOCATIONS.try_with(|a| a.set(a.get() + 1));
    }
}

// SAFETY: forwards every call unchanged to `System`, only counting them.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` was allocated by `System` with `layout`.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

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
         chatter_band_hz = [100.0, 300.0]\nwindow_s = 0.5\nk_max = 0.25\n"
    );
    let config = millgate_config::from_toml_str(&text, "t.toml", std::path::Path::new("."))
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut monitor = ChatterMonitor::new(&config, 0)?;
    let stands = Stands::new(
        StandsSettings {
            sample_rate_hz: FS,
            natural_hz: vec![150.0, 190.0, 240.0],
            amplitude: 1.0,
            linewidth_hz: 0.5,
            noise_rms: 0.3,
        },
        Regime::synchronized(5.0, 187.0),
    )?;
    let signals = stands.generate(10.0, 3)?;
    let t0 = Instant::now();
    let period = Duration::from_secs_f64(BLOCK as f64 / FS);

    let (mut evaluated, mut restarted) = (0, 0);
    MEASURING.with(|m| m.set(true));
    for (b, start) in (0..signals[0].len() - BLOCK).step_by(BLOCK).enumerate() {
        if b == 40 {
            restarted += usize::from(monitor.gap(1, Some(0)).is_some());
        }
        for (s, signal) in signals.iter().enumerate() {
            let update = monitor.samples(s, &signal[start..start + BLOCK], t0 + period * b as u32);
            match update {
                Some(ChatterUpdate::Evaluated(_)) => evaluated += 1,
                Some(ChatterUpdate::Restarted(_)) => restarted += 1,
                _ => {}
            }
        }
    }
    MEASURING.with(|m| m.set(false));
    let allocations = ALLOCATIONS.with(Cell::get);
    assert!(evaluated > 30, "{evaluated} windows evaluated");
    assert_eq!(restarted, 1, "the gap");
    assert_eq!(
        allocations, 0,
        "{allocations} allocations in {evaluated} windows"
    );
    Ok(())
}

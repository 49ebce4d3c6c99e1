//! What the chatter unit tests share: a monitor of a few stands, sines, and feeding
//! signals block by block as a DAQ delivers them; the example tandem mill and a
//! recording of its stands.

use std::f64::consts::TAU;
use std::time::{Duration, Instant};

use millgate_dsp::chatter::ChatterResult;

use super::{ChatterMonitor, ChatterUpdate, Recording};

/// Sample rate of the test stands, Hz.
pub(super) const FS: f64 = 2500.0;
/// Samples per simulated DAQ block: 48 ms.
pub(super) const BLOCK: usize = 120;

/// A mill of `stands` stands at 2500 Hz, band 100-300 Hz, window 0.5 s.
pub(super) fn monitor(stands: usize) -> ChatterMonitor {
    let mut text = String::from(
        "name = \"t\"\n[[sources.modbus]]\nname = \"daq\"\naddress = \"127.0.0.1:1\"\npoll_period_ms = 20\n",
    );
    for s in 0..stands {
        text += &format!(
            "[[channels]]\nname = \"s{s}\"\nkind = \"acceleration\"\nunit = \"m/s^2\"\n\
             sample_rate_hz = {FS}\nsource = {{ modbus = \"daq\", table = \"input\", block = {} }}\n",
            s * 122
        );
    }
    let names: Vec<String> = (0..stands).map(|s| format!("\"s{s}\"")).collect();
    // Thresholds 1, 2, 3, ...: the ratio of stand s is its gain / (s + 1).
    let thresholds: Vec<String> = (1..=stands).map(|s| format!("{s}.0")).collect();
    text += &format!(
        "[[tandem_mills]]\nname = \"TCM\"\nstands = [{}]\nchatter_band_hz = [100.0, 300.0]\n\
         window_s = 0.5\nk_max = 0.25\ngain_thresholds = [{}]\n",
        names.join(", "),
        thresholds.join(", ")
    );
    let config = millgate_config::from_toml_str(&text, "t.toml", std::path::Path::new("."))
        .expect("test config");
    ChatterMonitor::new(&config, 0).expect("monitor")
}

/// `amplitude sin(2 pi f_hz k / FS + phase)` for `k` in `samples`.
pub(super) fn sine(
    f_hz: f64,
    phase: f64,
    amplitude: f64,
    samples: std::ops::Range<usize>,
) -> Vec<f64> {
    samples
        .map(|k| amplitude * (TAU * f_hz * k as f64 / FS + phase).sin())
        .collect()
}

/// Feed `signals` (one per stand) block by block, all stands of a block arriving
/// at the same instant, one block period apart; the evaluations in order.
pub(super) fn feed(
    monitor: &mut ChatterMonitor,
    signals: &[Vec<f64>],
    t0: Instant,
) -> Vec<ChatterResult> {
    let mut results = Vec::new();
    let period = Duration::from_secs_f64(BLOCK as f64 / FS);
    for (b, start) in (0..signals[0].len()).step_by(BLOCK).enumerate() {
        let arrival = t0 + period * b as u32;
        for (s, signal) in signals.iter().enumerate() {
            let end = (start + BLOCK).min(signal.len());
            if let Some(ChatterUpdate::Evaluated(r)) =
                monitor.samples(s, &signal[start..end], arrival)
            {
                results.push(r);
            }
        }
    }
    results
}

/// The example tandem mill (five stands at 2500 Hz, window 0.5 s, gain 2 s), its
/// thresholds left out.
pub(crate) fn example_tandem() -> millgate_config::Config {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../config/examples/tandem-5stand.toml");
    millgate_config::load_uncommissioned(&path).expect("example")
}

/// `samples` of a chatter-band line (180 Hz) over a reference-band line (620 Hz) on
/// each of the example mill's five stands, the chatter line `amplitude(t)`, named
/// `lines.csv`.
pub(crate) fn lines_recording(samples: usize, amplitude: impl Fn(f64) -> f64) -> Recording {
    let time_s: Vec<f64> = (0..samples).map(|k| k as f64 / 2500.0).collect();
    let signal: Vec<f64> = time_s
        .iter()
        .map(|&t| amplitude(t) * (TAU * 180.0 * t).sin() + 0.5 * (TAU * 620.0 * t).sin())
        .collect();
    Recording {
        name: "lines.csv".into(),
        time_s,
        stands: vec![signal; 5],
        speed: None,
        context: Default::default(),
    }
}

/// The text of the example tandem mill (`config/examples/tandem-5stand.toml`) with a
/// `product_code` process value, the mill's `context = { CONTEXT }` (e.g. `product =
/// "product_code"`) and the product group "quiet" (product 7, every threshold ten
/// times the mill's).
pub(crate) fn example_with_quiet_group(context: &str) -> String {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../config/examples/tandem-5stand.toml");
    std::fs::read_to_string(path)
        .expect("example")
        .replacen(
            "[[tandem_mills]]",
            &format!(
                "[[channels]]\nname = \"product_code\"\nkind = \"process_value\"\nunit = \"1\"\n\
                 source = {{ modbus = \"mill_plc\", table = \"holding\", address = 11 }}\n\n\
                 [[tandem_mills]]\ncontext = {{ {context} }}"
            ),
            1,
        )
        .replacen(
            "slow_down_hold_s = 5.0\n",
            "slow_down_hold_s = 5.0\n[[tandem_mills.product_groups]]\nname = \"quiet\"\n\
             products = [7]\ngain_thresholds = [11.87, 14.92, 22.09, 30.87, 33.27]\n",
            1,
        )
}

//! A synthetic chatter episode of three stands, stored as the history's writer stores
//! a capture: shared by gateway/tests/web_episodes.rs (the API against numpy) and
//! gateway/tests/web_browser.rs (the tandem mill's page).

use std::path::Path;

use super::tandem::Stands;
use millgate::history::rows::insert;
use millgate::history::writer::{connect, insert_run};
use millgate::history::RunInfo;
use millgate::state::captures::{
    CaptureChannel, CaptureKind, CaptureRecord, ChatterEpisode, KeepClass,
};
use millgate::state::context::{Coil, ContextReading, ProcessContext, StaleTags};
use millgate::state::events::{ChatterWindow, EndedBy, HistoryEvent};
use millgate::state::time::UtcTime;

pub use super::tandem::FS;
/// The band gain's window (`gain_window_s`, the default), s.
pub const GAIN_WINDOW_S: f64 = 2.0;
/// The capture's length, s.
pub const LENGTH_S: f64 = 12.0;
/// The chatter tone of stand `s`, Hz (on the spectra's 2 Hz grid, in the 100..300 Hz
/// band).
pub fn tone_hz(stand: usize) -> f64 {
    180.0 + 20.0 * stand as f64
}
/// Amplitude of stand `s`'s chatter tone at `t`, m/s^2: low, growing from 4 s to 8 s,
/// falling back by 10 s.
pub fn amplitude(stand: usize, t: f64) -> f64 {
    let top = 0.5 + 0.1 * stand as f64;
    let low = 0.05;
    match t {
        t if t < 4.0 => low,
        t if t < 8.0 => low + (top - low) * (t - 4.0) / 4.0,
        t if t < 10.0 => top - (top - low) * (t - 8.0) / 2.0,
        _ => low,
    }
}

/// Stand `stand`'s samples as a 0.01 m/s^2-per-count DAQ gives them: the chatter
/// tone, a 30 Hz roll-eccentricity tone (outside the band) and a little noise.
pub fn stand_samples(stand: usize) -> Vec<f64> {
    let mut state = 0x9e37_79b9_7f4a_7c15u64 ^ stand as u64;
    let n = (LENGTH_S * FS) as usize;
    (0..n)
        .map(|k| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            let noise = ((state >> 33) as f64 / f64::from(1u32 << 31) - 0.5) * 0.02;
            let t = k as f64 / FS;
            let phase = std::f64::consts::TAU * t;
            let value = amplitude(stand, t) * (phase * tone_hz(stand)).sin()
                + 0.1 * (phase * 30.0 + stand as f64).sin()
                + noise;
            (value / 0.01).round() * 0.01
        })
        .collect()
}

/// The episode's three stands (`s1_vib`..`s3_vib` at [`FS`] on Modbus source `source`)
/// and tandem mill `mill` over them, every band-gain threshold 2.
pub fn stands(source: &str, mill: &str) -> Stands {
    Stands::modbus(3, source).mill(mill).thresholds(&[2.0; 3])
}

/// The coil id and product code of the episode's context.
pub const COIL: u32 = 4711;
pub const PRODUCT: u32 = 205;
/// The product group whose thresholds judged the episode.
pub const THRESHOLDS_GROUP: &str = "thin gauge";

/// The episode's capture of tandem mill `mill` (warning at 6 s, cleared at 10.5 s) and
/// its row in `chatter_episodes`, both rolled in coil [`COIL`] of product
/// [`PRODUCT`] at 1200 m/min (a valid context), the episode judged by the thresholds of
/// product group [`THRESHOLDS_GROUP`], written into the history file `db`
/// (created when missing) under a run of its own.
pub fn write_chatter_capture(db: &Path, mill: &str) -> anyhow::Result<()> {
    let window = (0.5 * FS) as usize;
    let episode = ChatterEpisode {
        warning_sample: (6.0 * FS) as usize,
        cleared_sample: Some((10.5 * FS) as usize),
        window_samples: window,
        hop_samples: window / 2,
        cut: false,
    };
    {
        let mut connection = connect(db)?;
        let start = UtcTime::parse("2026-11-27T08:00:00Z").map_err(anyhow::Error::msg)?;
        let run = insert_run(
            &connection,
            start,
            &RunInfo {
                version: "test".into(),
                config_name: "episodes".into(),
                config_hash: String::new(),
                drivelines: vec![],
            },
        )?;
        let context = ContextReading {
            context: Ok(ProcessContext {
                speed_mpm: Some(1200.0),
                coil: Some(Coil::Number(COIL)),
                product: Some(PRODUCT),
                ..ProcessContext::default()
            }),
            stale: StaleTags::default(),
        };
        let capture = CaptureRecord {
            kind: CaptureKind::Chatter,
            subject: mill.into(),
            bite: None,
            first_sample_unix_ns: start.unix_ms() * 1_000_000,
            kernel_time: false,
            sample_rate_hz: FS,
            channels: (0..3)
                .map(|s| CaptureChannel {
                    name: format!("s{}_vib", s + 1),
                    unit: "m/s^2".into(),
                    scale: 0.01,
                    offset: 0.0,
                    samples: stand_samples(s),
                    timing: None,
                })
                .collect(),
            gaps: vec![],
            analysis: None,
            episode: Some(episode),
            keep: KeepClass::Important,
            context: Some(context),
        };
        let warning = UtcTime::from_unix_ms(start.unix_ms() + 6000);
        let transaction = connection.transaction()?;
        insert(
            &transaction,
            run,
            &HistoryEvent::ChatterStarted {
                time: warning,
                mill: mill.into(),
                window: ChatterWindow {
                    sigma_n_hz: 0.4,
                    k_mean: 0.8,
                    frequency_hz: Some(tone_hz(0)),
                    synchronized: false,
                },
                context: Some(context),
                thresholds_group: Some(THRESHOLDS_GROUP.to_owned()),
            },
        )?;
        insert(
            &transaction,
            run,
            &HistoryEvent::ChatterEnded {
                time: UtcTime::from_unix_ms(start.unix_ms() + 10_500),
                mill: mill.into(),
                ended_by: EndedBy::Analysis,
            },
        )?;
        insert(&transaction, run, &HistoryEvent::Capture(Box::new(capture)))?;
        transaction.commit()?;
    }
    Ok(())
}

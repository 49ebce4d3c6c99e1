//! The analysis pool gives the serial analysis' results (issue 42): the load bench's
//! plant (16 drivelines, each a copy of the simulator's seeded bars 0.2 s after the
//! one before, so their bites complete in clumps, the demo's model with gap maps; two
//! tandem mills of 5 stands, seeded noise, the second's stands with a 200 Hz chatter
//! tone that grows over the run) fed block by block with one history file per run:
//!
//! - serially, one message at a time (what the analysis did before the pool);
//! - in rounds (each poll's blocks of every driveline together) with `workers = 1`;
//! - in rounds with `workers = 4`;
//! - taken up as they come with `workers = 4` (what the service does): each poll's
//!   blocks handed over while the shares of the earlier polls may still run, waited
//!   for only at the end.
//!
//! Every bite report (its figures bit for bit, as `{:?}` prints every `f64` exactly,
//! its gap estimate and capture) is the same in the same order per driveline, and so
//! is every history row; the tandem mills' published results (their windows'
//! evaluations, gains, warnings and alarms) are the same after every poll.

mod common;

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use common::scratch;
use millgate::analysis::driveline::BiteReport;
use millgate::analysis::Analysis;
use millgate::field::acquired::Acquired;
use millgate::field::source_health::SourceHealth;
use millgate::history::query::{Filter, HistoryReader};
use millgate::state::board::Board;
use millgate::state::gap_maps::GapMaps;
use millgate::state::history::History;
use rand::SeedableRng as _;
use rand_distr::Distribution as _;

const MODELS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../sim/models");
const DRIVELINES: usize = 16;
const CHANNELS_PER_DAQ: usize = 8;
const RATE_HZ: f64 = 2000.0;
const BLOCK: usize = 100;
/// The bench's delay between two drivelines' copies of the bars, s.
const STAGGER_S: f64 = 0.2;
const BARS_S: f64 = 14.0;
/// Tandem mills, stands each, their rate and samples per poll (50 ms).
const MILLS: usize = 2;
const STANDS_PER_MILL: usize = 5;
const STAND_RATE_HZ: f64 = 2500.0;
const STAND_BLOCK: usize = 125;

/// The load bench's plant: `DRIVELINES` torque channels on DAQs of 8 channels, each
/// driveline with the demo's model (coarse maps, to keep the test short).
fn config(cache: &Path, history: &Path, workers: usize) -> millgate_config::Config {
    let mut text = format!(
        "name = \"parallel analysis\"\ncache_dir = \"{}\"\n\n[analysis]\nworkers = {workers}\n\n",
        cache.display()
    );
    let stands = MILLS * STANDS_PER_MILL;
    let daqs = DRIVELINES.div_ceil(CHANNELS_PER_DAQ) + stands.div_ceil(CHANNELS_PER_DAQ);
    for daq in 0..daqs {
        text.push_str(&format!(
            "[[sources.modbus]]\nname = \"daq{daq}\"\naddress = \"127.0.0.1:{}\"\npoll_period_ms = 20\n\n",
            5020 + daq
        ));
    }
    for k in 0..DRIVELINES {
        let (daq, slot) = (k / CHANNELS_PER_DAQ, k % CHANNELS_PER_DAQ);
        text.push_str(&format!(
            "[[channels]]\nname = \"d{k}_torque\"\nkind = \"torque\"\nunit = \"kN*m\"\n\
             scale = 0.01\nsample_rate_hz = {RATE_HZ:.1}\n\
             source = {{ modbus = \"daq{daq}\", table = \"input\", block = {} }}\n\n\
             [[drivelines]]\nname = \"D{k}\"\ntorque = \"d{k}_torque\"\n\
             model = \"table2-adjusted.toml\"\n\
             bite = {{ threshold_knm = 20.0, pre_trigger_s = 0.1, post_trigger_s = 0.5 }}\n\
             thresholds = {{ taf_warning = 2.2, taf_alarm = 2.6, gap_warning_mrad = 2.0, gap_alarm_mrad = 4.0 }}\n\
             wear = {{ gap_step_mrad = 0.25, torque_points = 10 }}\n\n",
            slot as u16 * millgate_config::layout::BLOCK_REGISTERS
        ));
    }
    // The stands' channels after the drivelines' (channel DRIVELINES + s), on the
    // DAQs after theirs.
    for s in 0..stands {
        let k = DRIVELINES.div_ceil(CHANNELS_PER_DAQ) * CHANNELS_PER_DAQ + s;
        let (daq, slot) = (k / CHANNELS_PER_DAQ, k % CHANNELS_PER_DAQ);
        text.push_str(&format!(
            "[[channels]]\nname = \"s{s}_vib\"\nkind = \"acceleration\"\nunit = \"m/s^2\"\n\
             scale = 0.01\nsample_rate_hz = {STAND_RATE_HZ:.1}\n\
             source = {{ modbus = \"daq{daq}\", table = \"input\", block = {} }}\n\n",
            slot as u16 * millgate_config::layout::BLOCK_REGISTERS
        ));
    }
    // The load bench's tandem mills (band-gain detector).
    for mill in 0..MILLS {
        let names: Vec<String> = (0..STANDS_PER_MILL)
            .map(|stand| format!("\"s{}_vib\"", mill * STANDS_PER_MILL + stand))
            .collect();
        text.push_str(&format!(
            "[[tandem_mills]]\nname = \"TCM{mill}\"\nstands = [{}]\n\
             chatter_band_hz = [100.0, 300.0]\nwindow_s = 0.5\nk_max = 0.25\n\
             detector = \"band_gain\"\nreference_band_hz = [450.0, 900.0]\n\
             gain_window_s = 2.0\ngain_thresholds = [3.0, 3.0, 3.0, 3.0, 3.0]\n\
             slow_down_release = 0.8\nslow_down_hold_s = 5.0\n\n",
            names.join(", ")
        ));
    }
    text.push_str(&format!("[history]\npath = \"{}\"\n", history.display()));
    millgate_config::from_toml_str(&text, "parallel.toml", Path::new(MODELS))
        .unwrap_or_else(|error| panic!("{error}"))
}

/// A health per source, never stale within the test.
fn health(config: &millgate_config::Config) -> Vec<Arc<SourceHealth>> {
    (0..config.modbus_sources.len())
        .map(|_| {
            Arc::new(SourceHealth::new(
                Duration::from_secs(3600),
                Duration::from_secs(3600),
            ))
        })
        .collect()
}

/// How the blocks are handed to the analysis.
#[derive(Debug, Clone, Copy)]
enum Feed {
    /// One message at a time.
    Serial,
    /// Each poll's blocks of every driveline in one round.
    Rounds,
    /// Each poll's blocks taken up without waiting for the shares in flight.
    TakenUp,
}

/// One run: the bites released per driveline (as `{:?}`) and the history's rows per
/// driveline (as `{:?}`, without their row and run ids), both in order; the tandem
/// mills' published results after each poll (as `{:?}`).
struct Run {
    reports: Vec<Vec<String>>,
    rows: Vec<Vec<String>>,
    mills: Vec<String>,
}

/// The plant's channels: the drivelines' torques, then the stands' vibration.
struct Signals {
    torques: Vec<Vec<f64>>,
    stands: Vec<Vec<f64>>,
}

fn run(
    dir: &Path,
    workers: usize,
    feed: Feed,
    signals: &Signals,
    maps: &GapMaps,
    stamps: &(SystemTime, Instant),
) -> Run {
    let history_path = dir.join(format!("history-{workers}-{feed:?}.db"));
    let config = config(&dir.join("cache"), &history_path, workers);
    let history = History::new(config.history.as_ref());
    millgate::history::start(&history, millgate::history::RunInfo::of(&config));
    let board = Arc::new(Board::new(&config, health(&config)).with_history(history.clone()));
    let (bites, _) = tokio::sync::broadcast::channel(16);
    let mut analysis = Analysis::new(&config, Arc::clone(&board), bites).expect("analysis");
    assert_eq!(analysis.take_gap_map_jobs().len(), DRIVELINES);
    for driveline in 0..DRIVELINES {
        analysis.install_gap_maps(driveline, Ok(maps.clone()));
    }
    let mut released: Vec<BiteReport> = Vec::new();
    let (start_time, start_instant) = *stamps;
    let mut mills = Vec::new();
    let polls = signals.torques[0].len() / BLOCK;
    for poll in 0..polls {
        let offset = Duration::from_secs_f64(((poll + 1) * BLOCK) as f64 / RATE_HZ);
        let block = |channel, signal: &Vec<f64>, length: usize| Acquired::Samples {
            channel,
            values: signal[poll * length..(poll + 1) * length].to_vec(),
            received: Some(start_time + offset),
            handed: start_instant + offset,
        };
        let messages: Vec<Acquired> = (signals.torques.iter().enumerate())
            .map(|(channel, signal)| block(channel, signal, BLOCK))
            .chain(
                signals
                    .stands
                    .iter()
                    .enumerate()
                    .map(|(stand, signal)| block(DRIVELINES + stand, signal, STAND_BLOCK)),
            )
            .collect();
        match feed {
            Feed::Serial => {
                for message in messages {
                    released.extend(analysis.handle(message));
                }
            }
            Feed::Rounds => released.extend(analysis.handle_all(messages)),
            Feed::TakenUp => released.extend(analysis.take_up(messages)),
        }
        // Taken up, the mills may be behind a poll: compared once all is done.
        if !matches!(feed, Feed::TakenUp) {
            mills.push(format!("{:?}", board.results().tandem_mills));
        }
    }
    released.extend(analysis.handle_all(Vec::new()));
    if matches!(feed, Feed::TakenUp) {
        mills.push(format!("{:?}", board.results().tandem_mills));
    }
    drop(analysis);
    history.close();
    let mut reports = vec![Vec::new(); DRIVELINES];
    for report in &released {
        reports[report.driveline].push(format!("{report:?}"));
    }
    let reader = HistoryReader::open(&history_path).expect("history");
    let mut rows = vec![Vec::new(); DRIVELINES];
    let mut stored = reader.bites(&Filter::default()).expect("bites");
    stored.sort_by_key(|row| row.id);
    for mut row in stored {
        let driveline: usize = row.driveline[1..].parse().expect("D<k>");
        (row.id, row.run_id) = (0, 0);
        rows[driveline].push(format!("{row:?}"));
    }
    Run {
        reports,
        rows,
        mills,
    }
}

#[test]
fn the_pool_gives_the_serial_analysis_results_bit_for_bit() {
    let dir = scratch("parallel-analysis");
    let dir: PathBuf = dir.path().to_path_buf();
    let bars = millgate_sim::devices::demo::setup(BARS_S, 0.5, 1)
        .expect("demo")
        .schedule
        .torque_knm;
    let stagger = (STAGGER_S * RATE_HZ) as usize;
    let torques: Vec<Vec<f64>> = (0..DRIVELINES)
        .map(|k| {
            let mut signal = bars.clone();
            signal.rotate_right((k * stagger) % bars.len());
            signal
        })
        .collect();
    let stand_samples = torques[0].len() / BLOCK * STAND_BLOCK;
    let noise = rand_distr::Normal::new(0.0, 2.0).expect("noise");
    let stands = (0..MILLS * STANDS_PER_MILL)
        .map(|s| {
            let mut rng = rand::rngs::StdRng::seed_from_u64(1000 + s as u64);
            (0..stand_samples)
                .map(|i| {
                    let t = i as f64 / STAND_RATE_HZ;
                    // The second mill chatters: a 200 Hz tone growing to 8 m/s^2.
                    let tone = if s >= STANDS_PER_MILL {
                        8.0 * (i as f64 / stand_samples as f64)
                            * (2.0 * std::f64::consts::PI * 200.0 * t).sin()
                    } else {
                        0.0
                    };
                    noise.sample(&mut rng) + tone
                })
                .collect()
        })
        .collect();
    let signals = Signals { torques, stands };
    let maps = {
        let config = config(&dir.join("cache"), &dir.join("maps.db"), 1);
        let (bites, _) = tokio::sync::broadcast::channel(1);
        let board = Arc::new(Board::new(&config, health(&config)));
        let mut analysis = Analysis::new(&config, board, bites).expect("analysis");
        let job = analysis.take_gap_map_jobs().remove(0);
        job.run(2, &AtomicBool::new(false), &|_, _| {})
            .unwrap_or_else(|error| panic!("{error}"))
            .0
    };
    let stamps = (
        SystemTime::UNIX_EPOCH + Duration::from_secs(1_795_000_000),
        Instant::now(),
    );
    let serial = run(&dir, 1, Feed::Serial, &signals, &maps, &stamps);
    let bites: usize = serial.reports.iter().map(Vec::len).sum();
    println!("{bites} bites over {DRIVELINES} drivelines");
    for (driveline, reports) in serial.reports.iter().enumerate() {
        assert!(reports.len() >= 5, "D{driveline}: {} bites", reports.len());
        assert_eq!(
            serial.rows[driveline].len(),
            reports.len(),
            "D{driveline}'s rows"
        );
    }
    assert!(
        serial
            .reports
            .iter()
            .flatten()
            .any(|report| report.contains("trend: Some")),
        "the gap estimate is part of what is compared"
    );
    let last = serial.mills.last().expect("polls");
    assert!(
        !last.contains("evaluations: 0,"),
        "both mills evaluated windows: {last}"
    );
    assert!(
        serial
            .mills
            .iter()
            .any(|mills| mills.contains("chatter_warning: true")),
        "the second mill's chatter is part of what is compared"
    );
    for (workers, feed) in [
        (1, Feed::Rounds),
        (4, Feed::Rounds),
        (4, Feed::Serial),
        (4, Feed::TakenUp),
    ] {
        let pooled = run(&dir, workers, feed, &signals, &maps, &stamps);
        for driveline in 0..DRIVELINES {
            assert_eq!(
                pooled.reports[driveline], serial.reports[driveline],
                "D{driveline}'s bites with {workers} workers, {feed:?}"
            );
            assert_eq!(
                pooled.rows[driveline], serial.rows[driveline],
                "D{driveline}'s history rows with {workers} workers, {feed:?}"
            );
        }
        if matches!(feed, Feed::TakenUp) {
            assert_eq!(
                pooled.mills.last(),
                serial.mills.last(),
                "the tandem mills at the end with {workers} workers, {feed:?}"
            );
            continue;
        }
        for (poll, (pooled, serial)) in pooled.mills.iter().zip(&serial.mills).enumerate() {
            assert_eq!(
                pooled, serial,
                "the tandem mills after poll {poll} with {workers} workers, {feed:?}"
            );
        }
        assert_eq!(pooled.mills.len(), serial.mills.len());
    }
}

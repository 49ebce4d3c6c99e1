//! Writes a history file holding a year of bites (one every 30 s) for four drivelines,
//! the fixture of the web page's benchmark (issue 18): 4 x 1 051 200 bites.
//!
//! The file is made as the gateway makes it: the schema by the gateway's own
//! `writer::connect` (WAL, migrations), every event by the writer's own
//! `rows::insert` (bite rows, wear estimates, the restorable state, alarms,
//! outages), in transactions of 50 000 events. Only the run rows (`gateway_runs`,
//! `driveline_settings`) are written here by SQL, because the writer dates a run at
//! its own start and these runs lie in the past.
//!
//! What it holds, per driveline (deterministic for a seed):
//! - a bite every `--every-s` s (staggered between drivelines) with static torque
//!   300-600 kN*m and a TAF of 1.2-1.6 that rises with the gap and falls with the
//!   static torque; 0.2 % degraded windows;
//! - a gap growing over weeks (0.1-0.3 mrad/week, a coupling's own rate) and reset
//!   when the coupling is changed (every 9-16 weeks, a wear reset from the HMI), with
//!   the pooled estimate and its 90 % interval on every bite once 20 bites are pooled,
//!   and the gateway's wear trend of those estimates (growth, forecast of the 4 mrad
//!   alarm, the trend's saved form in the state row);
//! - a latched wear alarm when the gap's interval passes 4 mrad, acknowledged from
//!   the HMI a day later; TAF warnings raised and cleared at 1.55;
//! - a gateway restart every 30 days (a new run, the last ones unclean at times) and
//!   a few outages of each driveline's source (2-6 h without bites).
//!
//! Run with:
//!
//!     cargo run --release -p millgate --example history_year -- --out /tmp/year.sqlite
//!     cargo run --release -p millgate --example history_year -- --out /tmp/small.sqlite \
//!         --drivelines 2 --days 7 --every-s 60

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context};
use clap::Parser;
use millgate::analysis::gap_trend::GapTrend;
use millgate::history::writer;
use millgate::history::{DrivelineSettings, RunInfo};
use millgate::state::commands::CommandOrigin;
use millgate::state::events::{
    AlarmEvent, AlarmKind, AlarmRecord, BiteRecord, EndedBy, HistoryEvent, PooledBite, WearState,
};
use millgate::state::results::{DrivelineResults, GapResults};
use millgate::state::time::UtcTime;
use rusqlite::params;

#[derive(Debug, Parser)]
struct Args {
    /// The history file to write (must not exist).
    #[arg(long)]
    out: PathBuf,
    /// Drivelines F1..Fn, 1..=16.
    #[arg(long, default_value_t = 4)]
    drivelines: u32,
    /// Days of history, 1..=3650, ending now.
    #[arg(long, default_value_t = 365)]
    days: u32,
    /// Seconds between two bites of a driveline, 1..=86400.
    #[arg(long, default_value_t = 30)]
    every_s: u32,
    /// Seed of the pseudo-random values.
    #[arg(long, default_value_t = 18)]
    seed: u64,
}

/// Events per transaction.
const BATCH: usize = 50_000;
const DAY_MS: i64 = 86_400_000;
const WEEK_MS: f64 = 7.0 * 86_400_000.0;
/// The gap thresholds (the configuration's defaults), mrad.
const GAP_WARNING_MRAD: f64 = 2.0;
const GAP_ALARM_MRAD: f64 = 4.0;
const TAF_WARNING: f64 = 1.55;
const TAF_ALARM: f64 = 1.8;
/// Bites pooled at most, and the fewest that give an estimate.
const POOL_BITES: u32 = 200;
const POOL_FIRST: u32 = 20;

/// SplitMix64: a few lines for deterministic values, so the example needs no random
/// crate (millgate has none among its dependencies).
#[derive(Debug)]
struct Random(u64);

impl Random {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in [low, high).
    fn uniform(&mut self, low: f64, high: f64) -> f64 {
        low + (high - low) * ((self.next() >> 11) as f64 / (1u64 << 53) as f64)
    }

    /// Standard normal (Box-Muller).
    fn normal(&mut self) -> f64 {
        let u = self.uniform(f64::MIN_POSITIVE, 1.0);
        let v = self.uniform(0.0, 1.0);
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

/// One driveline's state while its year is generated.
#[derive(Debug)]
struct Driveline {
    name: String,
    source: String,
    counter: u32,
    /// When the coupling in place was fitted, and its gap growth, mrad/week.
    coupling_since_ms: i64,
    growth: f64,
    initial_gap: f64,
    next_change_ms: i64,
    bites_since_reset: u32,
    wear_trend: Option<f64>,
    /// The gap's wear trend, as the gateway keeps it (fed the bites' gap estimates).
    gap_trend: GapTrend,
    gap_alarm: bool,
    gap_ack_at_ms: Option<i64>,
    taf_warning: bool,
    /// The next outage: (start, end), ms.
    outage: (i64, i64),
}

impl Driveline {
    fn new(k: u32, start_ms: i64, random: &mut Random) -> Self {
        Self {
            name: format!("F{k}"),
            source: format!("daq{k}"),
            counter: 0,
            coupling_since_ms: start_ms,
            growth: random.uniform(0.1, 0.3),
            initial_gap: random.uniform(0.3, 0.8),
            next_change_ms: start_ms + (random.uniform(3.0, 16.0) * WEEK_MS) as i64,
            bites_since_reset: 0,
            wear_trend: None,
            gap_trend: GapTrend::new(365.0).expect("a valid horizon"),
            gap_alarm: false,
            gap_ack_at_ms: None,
            taf_warning: false,
            outage: next_outage(start_ms, random),
        }
    }
}

/// An outage of 2-6 h starting 40-120 days after `after_ms`.
fn next_outage(after_ms: i64, random: &mut Random) -> (i64, i64) {
    let start = after_ms + (random.uniform(40.0, 120.0) * DAY_MS as f64) as i64;
    (
        start,
        start + (random.uniform(2.0, 6.0) * 3_600_000.0) as i64,
    )
}

fn hmi() -> CommandOrigin {
    CommandOrigin::Hmi(SocketAddr::from(([10, 0, 0, 20], 50_200)))
}

fn alarm(
    time_ms: i64,
    subject: &str,
    kind: AlarmKind,
    event: AlarmEvent,
    value: Option<f64>,
    threshold: Option<f64>,
) -> HistoryEvent {
    HistoryEvent::Alarm(AlarmRecord {
        time: UtcTime::from_unix_ms(time_ms),
        subject: subject.to_owned(),
        kind,
        event,
        origin: (event == AlarmEvent::Acknowledged).then(hmi),
        value,
        threshold,
    })
}

/// The events of `driveline`'s bite at `time_ms` (and what it changed), into `out`.
fn bite(driveline: &mut Driveline, time_ms: i64, random: &mut Random, out: &mut Vec<HistoryEvent>) {
    // A coupling change: the crew resets the wear trend from the HMI.
    if time_ms >= driveline.next_change_ms {
        out.push(HistoryEvent::WearReset {
            time: UtcTime::from_unix_ms(time_ms - 1),
            driveline: driveline.name.clone(),
            origin: hmi(),
        });
        driveline.coupling_since_ms = time_ms;
        driveline.growth = random.uniform(0.1, 0.3);
        driveline.initial_gap = random.uniform(0.3, 0.8);
        driveline.next_change_ms = time_ms + (random.uniform(9.0, 16.0) * WEEK_MS) as i64;
        driveline.bites_since_reset = 0;
        driveline.wear_trend = None;
        driveline.gap_trend.reset();
    }
    if let Some(at) = driveline.gap_ack_at_ms.filter(|&at| time_ms >= at) {
        out.push(alarm(
            at,
            &driveline.name,
            AlarmKind::GapAlarm,
            AlarmEvent::Acknowledged,
            None,
            None,
        ));
        driveline.gap_ack_at_ms = None;
        driveline.gap_alarm = false;
    }
    driveline.counter += 1;
    driveline.bites_since_reset += 1;
    let weeks = (time_ms - driveline.coupling_since_ms) as f64 / WEEK_MS;
    let true_gap = driveline.initial_gap + driveline.growth * weeks;
    let static_torque_knm = random.uniform(300.0, 600.0);
    let degraded = random.uniform(0.0, 1.0) < 0.002;
    let taf = (1.22 + 0.06 * true_gap * (450.0 / static_torque_knm) + 0.015 * random.normal())
        .clamp(1.15, 1.75);
    let pooled = driveline.bites_since_reset.min(POOL_BITES);
    let gap = (driveline.bites_since_reset >= POOL_FIRST).then(|| {
        // The pooled estimate scatters less the more bites it pools.
        let half_width = 0.25 + 3.0 / f64::from(pooled).sqrt();
        let gap_mrad = (true_gap + 0.03 * random.normal()).max(0.0);
        // The bite's own gap into the trend (0.03 mrad, as it scatters): the growth and
        // the forecast the state keeps.
        let trend = driveline
            .gap_trend
            .fold_gaussian(1, (gap_mrad, 0.03 * 0.03), time_ms)
            .ok()
            .and_then(|_| driveline.gap_trend.results(GAP_ALARM_MRAD));
        let gap_low_mrad = (gap_mrad - half_width).max(0.0);
        let state = if gap_low_mrad >= GAP_ALARM_MRAD {
            WearState::Alarm
        } else if gap_mrad >= GAP_WARNING_MRAD {
            WearState::Warning
        } else {
            WearState::Ok
        };
        (
            GapResults {
                gap_mrad,
                low_mrad: gap_low_mrad,
                high_mrad: gap_mrad + half_width,
                coupling: Some(1),
                likeliest_coupling: None,
                bites_pooled: pooled as usize,
                growth: trend.and_then(|t| t.growth),
                forecast: trend.and_then(|t| t.forecast),
            },
            state,
        )
    });
    let wear_index = taf / 1.25 - 1.0;
    let wear_trend = match driveline.wear_trend {
        Some(trend) => trend + 0.01 * (wear_index - trend),
        None => wear_index,
    };
    driveline.wear_trend = Some(wear_trend);
    let time = UtcTime::from_unix_ms(time_ms);
    // The wear alarm latches until acknowledged (the gap warning is a flag, not an
    // alarm record).
    if let Some((gap, state)) = &gap {
        if *state == WearState::Alarm && !driveline.gap_alarm {
            driveline.gap_alarm = true;
            driveline.gap_ack_at_ms = Some(time_ms + DAY_MS);
            out.push(alarm(
                time_ms,
                &driveline.name,
                AlarmKind::GapAlarm,
                AlarmEvent::Raised,
                Some(gap.low_mrad),
                Some(GAP_ALARM_MRAD),
            ));
        }
    }
    let taf_warning = !degraded && taf >= TAF_WARNING;
    if taf_warning != driveline.taf_warning {
        driveline.taf_warning = taf_warning;
        let event = if taf_warning {
            AlarmEvent::Raised
        } else {
            AlarmEvent::Cleared
        };
        out.push(alarm(
            time_ms,
            &driveline.name,
            AlarmKind::TafWarning,
            event,
            Some(taf),
            Some(TAF_WARNING),
        ));
    }
    let first_period_s = 0.052 + 0.0004 * true_gap + 0.0002 * random.normal();
    let second_period_s = 0.049 + 0.0002 * random.normal();
    let state = DrivelineResults {
        bite_counter: driveline.counter,
        last_bite_unix_ms: Some(time_ms),
        static_torque_knm: Some(static_torque_knm),
        peak_torque_knm: Some(taf * static_torque_knm),
        taf: Some(taf),
        first_period_s: Some(first_period_s),
        first_period_shift_s: Some(first_period_s - second_period_s),
        beta1_hz: Some(1.0 / first_period_s),
        beta2_hz: Some(1.0 / second_period_s),
        wear_index: Some(wear_index),
        wear_trend: Some(wear_trend),
        last_bite_degraded: degraded,
        taf_warning,
        taf_alarm: false,
        gap: gap.map(|(gap, _)| gap),
        gap_alarm: driveline.gap_alarm,
        ..DrivelineResults::default()
    };
    out.push(HistoryEvent::Bite(Box::new(BiteRecord {
        driveline: driveline.name.clone(),
        channel: format!("{}_spindle", driveline.name.to_lowercase()),
        time,
        figures: DrivelineResults {
            beta1_hz: state.beta1_hz.filter(|_| !degraded),
            beta2_hz: state.beta2_hz.filter(|_| !degraded),
            ..state.clone()
        },
        second_period_s: Some(second_period_s),
        quality: "good",
        reference_taf: Some(1.25),
        reference_level_knm: Some(450.0),
        shift_over_linear_s: Some(0.0004 * true_gap),
        gap_state: gap.map(|(_, state)| state),
        gap_trend: gap.is_some().then(|| driveline.gap_trend.saved()),
        fatigue_ledger: None,
        context: None,
        pooled: (!degraded).then_some(PooledBite {
            static_torque_knm,
            taf,
            taf_sigma: 0.015,
            period_shift_s: Some(first_period_s - second_period_s),
            period_shift_sigma_s: 0.0003,
        }),
        state,
    })));
}

/// A run's rows, as the writer's start writes them (dated `start_ms`); the previous
/// run is closed as stopped or, now and then, left unclean.
fn begin_run(
    transaction: &rusqlite::Transaction<'_>,
    start_ms: i64,
    drivelines: &[Driveline],
    random: &mut Random,
) -> rusqlite::Result<i64> {
    let clean = random.uniform(0.0, 1.0) < 0.8;
    transaction.execute(
        "UPDATE gateway_runs SET stopped_at = CASE WHEN ?2 THEN ?1 END,
             ended = CASE WHEN ?2 THEN 'stopped' ELSE 'unclean' END
         WHERE ended IS NULL",
        params![UtcTime::from_unix_ms(start_ms - 60_000).to_string(), clean],
    )?;
    let run = RunInfo {
        version: env!("CARGO_PKG_VERSION").to_owned(),
        config_name: "Year fixture mill".into(),
        config_hash: String::new(),
        drivelines: drivelines
            .iter()
            .map(|driveline| DrivelineSettings {
                name: driveline.name.clone(),
                taf_warning: TAF_WARNING,
                taf_alarm: TAF_ALARM,
                model: Some("driveline-model.toml".into()),
                gap_warning_mrad: Some(GAP_WARNING_MRAD),
                gap_alarm_mrad: Some(GAP_ALARM_MRAD),
            })
            .collect(),
    };
    writer::insert_run(transaction, UtcTime::from_unix_ms(start_ms), &run)
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    if !(1..=16).contains(&args.drivelines) {
        bail!("--drivelines {} is out of range (1..=16)", args.drivelines);
    }
    if !(1..=3650).contains(&args.days) {
        bail!("--days {} is out of range (1..=3650)", args.days);
    }
    if !(1..=86_400).contains(&args.every_s) {
        bail!("--every-s {} is out of range (1..=86400)", args.every_s);
    }
    if args.out.exists() {
        bail!("{} exists: give a new file", args.out.display());
    }
    let mut connection =
        writer::connect(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let mut random = Random(args.seed);
    let every_ms = i64::from(args.every_s) * 1000;
    let end_ms = UtcTime::now().unix_ms() / 1000 * 1000;
    let start_ms = end_ms - i64::from(args.days) * DAY_MS;
    let mut drivelines: Vec<Driveline> = (1..=args.drivelines)
        .map(|k| Driveline::new(k, start_ms, &mut random))
        .collect();
    let steps = (end_ms - start_ms) / every_ms;
    let total = steps * i64::from(args.drivelines);
    println!(
        "writing {} bites ({} drivelines x {steps}, one every {} s over {} days) to {}",
        total,
        args.drivelines,
        args.every_s,
        args.days,
        args.out.display()
    );
    let begun = Instant::now();
    let mut events = Vec::with_capacity(BATCH + 64);
    let mut run_id = 0;
    let mut next_run_ms = start_ms;
    let mut bites = 0i64;
    let mut last_percent = -1;
    for step in 0..steps {
        let step_ms = start_ms + step * every_ms;
        if step_ms >= next_run_ms {
            write(&mut connection, run_id, &mut events)?;
            let transaction = connection.transaction()?;
            run_id = begin_run(&transaction, step_ms, &drivelines, &mut random)?;
            transaction.commit()?;
            next_run_ms = step_ms + 30 * DAY_MS;
        }
        for (k, driveline) in drivelines.iter_mut().enumerate() {
            // Staggered: the drivelines' bites follow each other through the step.
            let time_ms = step_ms + every_ms * k as i64 / i64::from(args.drivelines);
            let (outage_start, outage_end) = driveline.outage;
            if time_ms >= outage_start {
                if time_ms < outage_end {
                    continue;
                }
                events.push(HistoryEvent::OutageStarted {
                    time: UtcTime::from_unix_ms(outage_start),
                    source: driveline.source.clone(),
                    status: "stale",
                });
                events.push(HistoryEvent::OutageWorse {
                    source: driveline.source.clone(),
                });
                events.push(HistoryEvent::OutageEnded {
                    time: UtcTime::from_unix_ms(outage_end),
                    source: driveline.source.clone(),
                    blocks_missed: u64::try_from((outage_end - outage_start) / 100).unwrap_or(0),
                    ended_by: EndedBy::Analysis,
                });
                driveline.outage = next_outage(outage_end, &mut random);
            }
            bite(driveline, time_ms, &mut random, &mut events);
            bites += 1;
        }
        if events.len() >= BATCH {
            write(&mut connection, run_id, &mut events)?;
            let percent = bites * 100 / total.max(1);
            if percent / 5 != last_percent / 5 {
                last_percent = percent;
                println!(
                    "{percent:3} %  {bites} bites  {:.0} s  {:.0} bites/s",
                    begun.elapsed().as_secs_f64(),
                    bites as f64 / begun.elapsed().as_secs_f64()
                );
            }
        }
    }
    write(&mut connection, run_id, &mut events)?;
    connection.execute(
        "UPDATE gateway_runs SET stopped_at = ?1, ended = 'stopped' WHERE ended IS NULL",
        [UtcTime::from_unix_ms(end_ms).to_string()],
    )?;
    connection.query_row("PRAGMA wal_checkpoint(TRUNCATE)", [], |_| Ok(()))?;
    drop(connection);
    let bytes = std::fs::metadata(&args.out)?.len();
    println!(
        "done: {bites} bites in {:.0} s; {} is {:.0} MiB",
        begun.elapsed().as_secs_f64(),
        args.out.display(),
        bytes as f64 / (1024.0 * 1024.0)
    );
    Ok(())
}

/// Write `events` in one transaction through the gateway's writer code, and empty it.
fn write(
    connection: &mut rusqlite::Connection,
    run_id: i64,
    events: &mut Vec<HistoryEvent>,
) -> anyhow::Result<()> {
    if events.is_empty() {
        return Ok(());
    }
    let transaction = connection.transaction()?;
    for event in events.iter() {
        millgate::history::rows::insert(&transaction, run_id, event)?;
    }
    transaction.commit()?;
    events.clear();
    Ok(())
}

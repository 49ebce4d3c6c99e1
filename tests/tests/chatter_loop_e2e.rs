//! The chatter closed loop in real time with the gateway in it, over Modbus: the
//! physical tandem model simulated online one 48 ms PLC cycle at a time
//! (`sim::devices::tandem_rig`), its chock accelerations streamed by a virtual DAQ, the
//! service (`millgate::Service`) computing the band gain with thresholds commissioned
//! on separate stable recordings and writing its register map into a virtual PLC, and
//! the PLC's program reading the slow-down bit from its own holding registers and
//! slowing the mill. The same run with the request ignored (open loop) develops
//! chatter; closed, it does not.
//!
//! The outcome of the loop (chatter never develops, closed) holds when the loop runs in
//! real time: no DAQ block of the stands lost by the gateway, no stand re-anchored on
//! the mill's sample axis (reads late by half a block), no PLC cycle handed over late
//! by the rig. A loaded machine can break any; such a run says so, and is held to what
//! does not depend on the wall clock (the request came near the critical speed and the
//! automation slowed the mill; a capture ends only at a gap of blocks the gateway
//! counted missing, or at a re-anchoring it counted).
//!
//! Each run also measures the request's latency: from the moment the DAQ block that
//! completed the alarming window was published to the moment the bit was in the PLC's
//! register (polled every millisecond), and in PLC cycles to the scan that read it: the
//! delay the offline closed loop (`millgate_tests::experiments::chatter_loop`) is run with.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use millgate::outputs::modbus::register_map::RegisterMap;
use millgate::state::captures::CaptureGap;
use millgate::state::commands::{Command, CommandOrigin};
use millgate_config::layout::to_raw_sample;
use millgate_config::Config;
use millgate_sim::devices::modbus_bank::ServeOptions;
use millgate_sim::devices::tandem_rig::{self, RequestBit, RigRun};
use millgate_sim::devices::virtual_daq::VirtualDaq;
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_sim::tandem::control::{SlowDownPolicy, SpeedControl};
use millgate_sim::tandem::online::OnlineMill;
use millgate_sim::tandem::simulate::{Accelerometer, Excitation, SimulationSetup, SpeedRange};
use millgate_tests::experiments::chatter_loop::{mills, LoopPlan, Mill, CYCLE_SAMPLES};
use millgate_tests::kit::peers::peer;
use millgate_tests::kit::scratch;
use millgate_tests::kit::tandem::{modbus_source, stand_daq_channels, Stands, FS};
use tokio::net::TcpListener;

/// The slow-down request: bit 3 of the mill's flags register.
const SLOW_DOWN_BIT: u16 = 3;
/// Stable rolling before the operator's ramp, s.
const SETTLE_S: f64 = 6.0;
/// The manual capture of the stands taken at the start of a run with a history, s
/// (within the stable rolling before the ramp).
const MANUAL_CAPTURE_S: u16 = 4;
/// The coil id and product code the process PLC serves in a run with a history.
const COIL: u16 = 4711;
const PRODUCT: u16 = 205;

/// Five stands on one DAQ at 2500 Hz (0.01 m/s^2 per bit), the mill commissioned on
/// `mill`'s recordings, a PLC output.
fn config(mill: &Mill, history: Option<&std::path::Path>) -> anyhow::Result<Config> {
    let text = config_text(mill, history);
    millgate_config::from_toml_str(&text, "chatter-loop.toml", std::path::Path::new("."))
        .map_err(|e| anyhow::anyhow!("{e}"))
}

/// [`config`]'s text.
fn config_text(mill: &Mill, history: Option<&std::path::Path>) -> String {
    let mut stands = Stands::modbus(5, "daq")
        .thresholds(&mill.gain_thresholds)
        .keys(&format!("slow_down_release = {}", mill.gain_release));
    let mut process = String::new();
    if history.is_some() {
        // With a history, the mill's coil and product from a process PLC: the
        // context its episodes and captures carry.
        process = "[[sources.modbus]]\nname = \"process_plc\"\naddress = \"127.0.0.1:1\"\n\
                   poll_period_ms = 100\n\n\
                   [[channels]]\nname = \"coil_id\"\nkind = \"process_value\"\nunit = \"1\"\n\
                   source = { modbus = \"process_plc\", table = \"holding\", address = 0 }\n\n\
                   [[channels]]\nname = \"product_code\"\nkind = \"process_value\"\nunit = \"1\"\n\
                   source = { modbus = \"process_plc\", table = \"holding\", address = 1 }\n\n"
            .to_owned();
        stands = stands.keys("context = { coil = \"coil_id\", product = \"product_code\" }");
    }
    let mut text = String::from("name = \"chatter loop\"\n")
        + &modbus_source("daq")
        + &process
        + &stands.toml()
        + "[outputs.plc]\naddress = \"127.0.0.1:1\"\nwrite_period_ms = 50\n";
    if let Some(path) = history {
        text += &format!("[history]\npath = {:?}\n", path.display().to_string());
    }
    text
}

/// One run: the mill held at `start` times its critical speed for [`SETTLE_S`], then
/// the operator's setpoint at `setpoint` times it, approached at `accel_m_s2`.
#[derive(Debug, Clone, Copy)]
struct Scenario {
    start: f64,
    setpoint: f64,
    accel_m_s2: f64,
    seed: u64,
    duration_s: f64,
}

fn online_mill(mill: &Mill, scenario: Scenario) -> anyhow::Result<OnlineMill> {
    let critical = mill.critical_m_s();
    let policy = SlowDownPolicy {
        accel_m_s2: scenario.accel_m_s2,
        ..SlowDownPolicy::default()
    };
    let start = scenario.start * critical;
    let control = SpeedControl::new(policy, start, start)?;
    let setup = SimulationSetup {
        excitation: Excitation::default(),
        sensor: Accelerometer {
            sample_rate_hz: FS,
            ..Accelerometer::default()
        },
        seed: scenario.seed,
        internal_rate_hz: None,
        speeds: SpeedRange {
            lowest: 1.0,
            highest: 1.0,
        },
    };
    Ok(OnlineMill::new(
        &mill.mill,
        &setup,
        control,
        CYCLE_SAMPLES,
        scenario.setpoint * critical,
    )?)
}

/// The operator: the setpoint after the settling time.
fn operator(mill: &Mill, scenario: Scenario) -> impl FnMut(f64, &mut SpeedControl) {
    let setpoint = scenario.setpoint * mill.critical_m_s();
    move |t_s, control| {
        if t_s >= SETTLE_S {
            control.set_setpoint(setpoint);
        }
    }
}

/// The scenario with the request ignored, offline: when chatter develops.
fn open_loop(mill: &Mill, scenario: Scenario) -> anyhow::Result<Option<f64>> {
    let mut online = online_mill(mill, scenario)?;
    let mut operator = operator(mill, scenario);
    let cycles = (scenario.duration_s / online.cycle_s()).round() as usize;
    for _ in 0..cycles {
        operator(online.time_s(), online.control_mut());
        let mut samples = online.record(CYCLE_SAMPLES);
        online.cycle(false, &mut samples)?;
        if online.developed_s().is_some() {
            break;
        }
    }
    Ok(online.developed_s())
}

/// What a real-time run through the gateway gave.
struct LoopRun {
    rig: RigRun,
    /// Each rise of the bit in the PLC's register, wall clock.
    rises: Vec<Instant>,
    /// Per stand, the raw counts the DAQ published, in order (the rest block first).
    sent: Vec<Vec<i16>>,
    /// Per stand, the blocks the gateway counted missed and its sequence restarts.
    missed: Vec<(u64, u64)>,
    /// The mill's window restarts the gateway counted because a stand was re-anchored
    /// against the arrival times (`window_restarts_realigned`).
    realigned: u64,
}

impl LoopRun {
    /// Whether the loop ran in real time: no stand block missed (nor a sequence
    /// restart, nor a stand re-anchored), no cycle handed over late.
    fn in_real_time(&self) -> bool {
        self.rig.late == 0
            && self.realigned == 0
            && self
                .missed
                .iter()
                .all(|&(blocks, restarts)| blocks + restarts == 0)
    }

    /// What broke real time, for the test's output.
    fn timing(&self) -> String {
        format!(
            "{} cycles handed over late, stand blocks missed and sequence restarts {:?}, \
             {} window restarts on a stand re-anchored",
            self.rig.late, self.missed, self.realigned
        )
    }

    /// A capture's `gap` is of whole blocks the gateway counted missing on a stand (a
    /// mill's capture has a gap where any of its stands has one: a rehearsal's run
    /// missed a block on stands 2-5 and not on stand 1), or follows a sequence
    /// restart, or is of unknown length where the gateway counted a stand re-anchored:
    /// said, or the test fails.
    fn accept_gap(&self, what: &str, gap: &CaptureGap) {
        let block = CYCLE_SAMPLES as u64;
        let realigned = gap.missed_samples.is_none() && self.realigned > 0;
        let counted = self.missed.iter().any(|&(blocks, restarts)| {
            let whole_blocks = gap
                .missed_samples
                .is_some_and(|m| m > 0 && m % block == 0 && m / block <= blocks);
            // A restart's gap is the clock's estimate, of any length.
            whole_blocks || restarts > 0
        });
        assert!(
            counted || realigned,
            "{what}: a gap {gap:?} where the gateway counted no block missing nor a stand \
             re-anchored ({})",
            self.timing()
        );
        println!(
            "{what} ends at a gap of {:?} samples, counted by the gateway ({})",
            gap.missed_samples,
            self.timing()
        );
    }
}

async fn closed_loop(
    mill: &Mill,
    scenario: Scenario,
    history: Option<&std::path::Path>,
) -> anyhow::Result<LoopRun> {
    let mut config = config(mill, history)?;
    let stands = config.tandem_mills[0].stands.clone();
    let map = RegisterMap::new(&config);
    let flags = map
        .registers()
        .iter()
        .find(|r| r.name == "TCM.flags")
        .map(|r| usize::from(r.address))
        .ok_or_else(|| anyhow::anyhow!("no TCM.flags register"))?;
    let plc = VirtualPlc::new(usize::from(map.len()) + 16);
    let channels = stand_daq_channels(&vec![Vec::new(); 5], &[0, 1, 2, 3, 4]);
    let mut daq = VirtualDaq::new(FS, CYCLE_SAMPLES as u16, channels);
    // A DAQ answers with a block from power-up: the first, at rest, anchors the stands.
    let rest = vec![0.0; CYCLE_SAMPLES];
    daq.publish(&[&rest, &rest, &rest, &rest, &rest]);
    let mut sent: Vec<Vec<i16>> = vec![vec![0; CYCLE_SAMPLES]; 5];
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    config.modbus_sources[0].address = listener.local_addr()?.to_string();
    let serving_daq = daq.serve(listener, ServeOptions::default());
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    if let Some(output) = config.outputs.plc.as_mut() {
        output.address = listener.local_addr()?.to_string();
        output.register_base = 0;
    }
    let serving_plc = plc.spawn(listener, ServeOptions::default());
    // With a history, the process PLC serving the coil and the product.
    let serving_process = match history {
        Some(_) => {
            let process = VirtualPlc::new(4);
            {
                let bank = process.bank();
                let mut bank = bank.lock();
                bank.holding[0] = COIL;
                bank.holding[1] = PRODUCT;
            }
            let listener = TcpListener::bind("127.0.0.1:0").await?;
            config.modbus_sources[1].address = listener.local_addr()?.to_string();
            Some(process.spawn(listener, ServeOptions::default()))
        }
        None => None,
    };
    let gateway = millgate::Service::new(config)?.spawn().await?;

    // The bit's rises in the PLC's register, polled every millisecond.
    let rises = Arc::new(Mutex::new(Vec::new()));
    let (stop_watch, mut stopped) = tokio::sync::oneshot::channel::<()>();
    let watcher = {
        let (plc, rises) = (plc.clone(), Arc::clone(&rises));
        tokio::spawn(async move {
            let mut was = false;
            loop {
                let set = plc.holding_bit(flags, SLOW_DOWN_BIT);
                if set && !was {
                    rises.lock().map(|mut r| r.push(Instant::now())).ok();
                }
                was = set;
                tokio::select! {
                    _ = &mut stopped => break,
                    () = tokio::time::sleep(Duration::from_millis(1)) => {}
                }
            }
        })
    };
    let mut online = online_mill(mill, scenario)?;
    let request = RequestBit {
        plc: plc.clone(),
        register: flags,
        bit: SLOW_DOWN_BIT,
    };
    let cycles = (scenario.duration_s / online.cycle_s()).round() as usize;
    let rig = tandem_rig::run(
        &mut online,
        &request,
        cycles,
        {
            // With a history, 1 s into the stable rolling before the ramp, a manual
            // capture of the stands.
            let mut manual = history.is_some().then(|| gateway.commands());
            let mut operate = operator(mill, scenario);
            move |t_s, control: &mut SpeedControl| {
                if t_s >= 1.0 {
                    if let Some(commands) = manual.take() {
                        let sent = commands.send(Command::CaptureStands {
                            mill: 0,
                            seconds: MANUAL_CAPTURE_S,
                            origin: CommandOrigin::Local,
                        });
                        assert_eq!(sent, Ok(()), "manual capture command");
                    }
                }
                operate(t_s, control)
            }
        },
        async |samples| {
            let blocks: Vec<&[f64]> = samples.acceleration.iter().map(Vec::as_slice).collect();
            daq.publish(&blocks);
            for (counts, block) in sent.iter_mut().zip(&blocks) {
                counts.extend(block.iter().map(|&v| to_raw_sample(v, 0.01, 0.0)));
            }
            Ok(())
        },
    )
    .await;
    let _ = stop_watch.send(());
    watcher.await?;
    let realigned = gateway.board().results().tandem_mills[0].window_restarts_realigned;
    let missed = stands
        .iter()
        .map(|&channel| {
            let counted = gateway.counters()[channel].snapshot();
            (counted.blocks_missed, counted.sequence_restarts)
        })
        .collect();
    gateway.stop().await?;
    serving_daq.stop().await?;
    serving_plc.stop().await?;
    if let Some(process) = serving_process {
        process.stop().await?;
    }
    let rises = rises.lock().map(|r| r.clone()).unwrap_or_default();
    Ok(LoopRun {
        rig: rig?,
        rises,
        sent,
        missed,
        realigned,
    })
}

/// Per rise of the bit: ms from the last block published before it, and the PLC
/// cycles from that block to the first cycle that read the request (the offline
/// loop's `delay_cycles`).
fn latencies(run: &LoopRun) -> Vec<(f64, usize)> {
    run.rises
        .iter()
        .filter_map(|&rise| {
            let (block, published) = run
                .rig
                .cycles
                .iter()
                .enumerate()
                .filter_map(|(k, c)| c.published.map(|p| (k, p)))
                .rfind(|&(_, p)| p <= rise)?;
            let read = run
                .rig
                .cycles
                .iter()
                .skip(block + 1)
                .position(|c| c.request)?;
            Some((rise.duration_since(published).as_secs_f64() * 1e3, read))
        })
        .collect()
}

async fn check(scenario: Scenario) -> anyhow::Result<()> {
    let plan = LoopPlan::quick();
    let mills = mills(&plan)?;
    let mill = &mills[0];
    let critical = mill.critical_m_s();
    let open = open_loop(mill, scenario)?;
    let developed = open.ok_or_else(|| anyhow::anyhow!("open loop: no developed chatter"))?;
    let run = closed_loop(mill, scenario, None).await?;
    let latencies = latencies(&run);
    let largest_swing = run.rig.cycles.iter().map(|c| c.swing).fold(0.0, f64::max);
    println!(
        "{scenario:?}: critical {critical:.2} m/s; open loop developed at {developed:.2} s; \
         closed loop: slow-downs (s, speed / critical, m/min shed) {:?}; developed {:?}, \
         largest tension swing {largest_swing:.3} of the developed limit; {} late cycles; \
         latency from the block to the PLC register, ms, and cycles to the scan that read \
         it: {latencies:?}",
        run.rig
            .events
            .iter()
            .map(|e| (
                e.requested_s,
                e.speed_at_request_m_s / critical,
                e.shed_m_s() * 60.0
            ))
            .collect::<Vec<_>>(),
        run.rig.developed_s,
        run.rig.late
    );
    let first = run
        .rig
        .events
        .first()
        .ok_or_else(|| anyhow::anyhow!("no slow-down"))?;
    // Requested near the critical speed, and the speed then shed by the automation's
    // drop: whatever the timing.
    assert!(first.speed_at_request_m_s > 0.95 * critical, "{first:?}");
    assert!(
        first.shed_m_s() >= SlowDownPolicy::default().drop_m_s - 1e-9,
        "{first:?}"
    );
    assert!(!latencies.is_empty(), "no rise of the bit seen");
    if !run.in_real_time() {
        println!(
            "not in real time ({}): the closed loop's outcome is not asserted",
            run.timing()
        );
        return Ok(());
    }
    // In real time: requested before chatter developed in the open loop, and chatter
    // never developed with the loop closed.
    assert_eq!(run.rig.developed_s, None, "developed with the loop closed");
    assert!(first.requested_s < developed, "{first:?}");
    assert!(largest_swing < 1.0, "tension swing {largest_swing}");
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fast_ramp_past_the_critical_speed_is_slowed_down_before_chatter_develops(
) -> anyhow::Result<()> {
    check(Scenario {
        start: 0.9,
        setpoint: 1.3,
        accel_m_s2: 2.0,
        seed: 7,
        duration_s: 20.0,
    })
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slower_ramp_past_the_critical_speed_is_slowed_down_before_chatter_develops(
) -> anyhow::Result<()> {
    check(Scenario {
        start: 0.85,
        setpoint: 1.25,
        accel_m_s2: 1.0,
        seed: 22,
        duration_s: 24.0,
    })
    .await
}

/// The chatter-episode capture through the service: the fast ramp with a history,
/// slowed down by the loop so the warning clears; one capture of kind `chatter` spans
/// from whole hops over `capture_before_s` (5 s) before the window that raised the
/// warning to `capture_after_s` (2 s) after the one that cleared it, every stand's
/// samples equal to the counts the DAQ published (at one common offset: the stands
/// aligned), its CSV export through `millgate chatter --input` warns at the
/// capture's warning window, and its Parquet export holds the CSV's samples and header
/// (pyarrow). A manual capture of the stands taken 1 s into the stable rolling
/// commissions thresholds (`millgate chatter commission --db --captures`), which
/// refuses the episode's capture.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_chatter_episode_is_captured_as_the_daq_sent_it_and_reproduces_its_warning(
) -> anyhow::Result<()> {
    use millgate::cli::capture::{export, ExportArgs, KindArg, Picked, Selection};
    use millgate::cli::chatter::commission::CommissionArgs;
    use millgate::cli::chatter::windows::{analyze, WindowsArgs};
    use millgate::history::capture_files::ExportFormat;
    use millgate::history::query::{CaptureRow, ChatterRow, Filter, HistoryReader, StoredCoil};

    let plan = LoopPlan::quick();
    let mills = mills(&plan)?;
    let mill = &mills[0];
    let scenario = Scenario {
        start: 0.9,
        setpoint: 1.3,
        accel_m_s2: 2.0,
        seed: 7,
        duration_s: 24.0,
    };
    let scratch = scratch("chatter-capture");
    let dir = scratch.path();
    let db = dir.join("history.db");
    let run = closed_loop(mill, scenario, Some(&db)).await?;
    println!("the loop's timing: {}", run.timing());
    assert!(!run.rig.events.is_empty(), "no slow-down: no episode");

    let reader = HistoryReader::open(&db)?;
    let rows: Vec<CaptureRow> = reader.rows(&Filter::default())?;
    let chatter: Vec<&CaptureRow> = rows.iter().filter(|r| r.kind == "chatter").collect();
    assert!(!chatter.is_empty(), "chatter captures: {rows:?}");
    let manual: Vec<&CaptureRow> = rows.iter().filter(|r| r.kind == "manual").collect();
    assert_eq!(manual.len(), 1, "manual captures: {rows:?}");
    assert_eq!(manual[0].subject, "TCM");
    // Its seconds whole, or ended by a gap the gateway counted (blocks missing, a stand
    // re-anchored: on this loaded machine) and saying so.
    let manual_capture = reader.capture_of(manual[0].clone())?;
    println!(
        "manual capture: {} samples, gaps {:?}",
        manual[0].samples, manual_capture.meta.gaps
    );
    match manual_capture.meta.gaps[..] {
        [] => assert_eq!(manual[0].samples, i64::from(MANUAL_CAPTURE_S) * FS as i64),
        [gap] => {
            assert_eq!(gap.before_sample as i64, manual[0].samples);
            run.accept_gap("the manual capture", &gap);
        }
        _ => panic!("{:?}", manual_capture.meta.gaps),
    }
    // The episode, its capture and the manual capture carry the coil and product the
    // process PLC served (schema v14).
    let context = |row: &CaptureRow| (row.coil.clone(), row.product, row.context_status.clone());
    let served = (
        Some(StoredCoil::Number(COIL.into())),
        Some(i64::from(PRODUCT)),
        Some("valid".to_owned()),
    );
    assert_eq!(context(chatter[0]), served, "{:?}", chatter[0]);
    assert_eq!(context(manual[0]), served, "{:?}", manual[0]);
    let episodes: Vec<ChatterRow> = reader.rows(&Filter {
        product: Some(u32::from(PRODUCT)),
        ..Filter::default()
    })?;
    assert!(
        !episodes.is_empty(),
        "no chatter episode of product {PRODUCT}"
    );
    for episode in &episodes {
        assert_eq!(
            (
                episode.coil.clone(),
                episode.product,
                episode.context_status.clone()
            ),
            served,
            "{episode:?}"
        );
    }
    let capture = reader.capture_of(chatter[0].clone())?;
    let episode = capture
        .meta
        .episode
        .expect("a chatter capture says where its warning is");
    println!(
        "chatter capture: {:?}, {} samples, {episode:?}",
        capture.row.started_at, capture.row.samples
    );
    assert_eq!(capture.row.subject, "TCM");
    assert_eq!(capture.row.sample_rate_hz, FS);
    assert_eq!(capture.channels.len(), 5);
    // Whole, or ended by a gap the gateway counted.
    let ended_by_gap = match capture.meta.gaps[..] {
        [] => false,
        [gap] => {
            assert_eq!(gap.before_sample as i64, capture.row.samples);
            run.accept_gap("the chatter capture", &gap);
            true
        }
        _ => panic!("{:?}", capture.meta.gaps),
    };
    // One episode: only a gap that ended its capture may leave the warning to start
    // another.
    if !ended_by_gap {
        assert_eq!(chatter.len(), 1, "chatter captures: {rows:?}");
    }
    assert!(!episode.cut);
    let hop = episode.hop_samples;
    let before = (5.0 * FS).ceil() as usize;
    // 5 s in whole hops and the anchoring block before the warning; fewer whole hops
    // only when the stands restarted in the meantime (a block lost or re-anchored on
    // this loaded machine: the capture keeps nothing from before a restart).
    let lead = millgate::analysis::chatter::ANCHOR_BLOCK;
    assert_eq!((episode.warning_sample - lead) % hop, 0, "{episode:?}");
    assert!(
        episode.warning_sample <= before.div_ceil(hop) * hop + lead,
        "{episode:?}"
    );
    if ended_by_gap {
        // Ended before its end: whether the warning cleared in it, it says.
        if let Some(cleared) = episode.cleared_sample {
            assert!(cleared > episode.warning_sample);
        }
    } else {
        let cleared = episode.cleared_sample.expect("the warning cleared");
        assert!(cleared > episode.warning_sample);
        assert_eq!(
            capture.row.samples as usize,
            cleared + (2.0 * FS).ceil() as usize
        );
    }
    // Every stand as the DAQ sent it, at one offset into what it sent.
    let counts = |samples: &[f64]| -> Vec<i16> {
        samples
            .iter()
            .map(|&v| to_raw_sample(v, 0.01, 0.0))
            .collect()
    };
    let first = counts(&capture.channels[0].samples);
    let offset = (0..=run.sent[0].len() - first.len())
        .find(|&at| run.sent[0][at..at + first.len()] == first[..])
        .ok_or_else(|| anyhow::anyhow!("stand 1's capture is not a run of what the DAQ sent"))?;
    for (stand, channel) in capture.channels.iter().enumerate() {
        assert_eq!(channel.name, format!("s{}_vib", stand + 1));
        assert_eq!(
            counts(&channel.samples)[..],
            run.sent[stand][offset..offset + first.len()],
            "stand {}",
            stand + 1
        );
    }

    // Exported, and through `millgate chatter`: the warning at the same window.
    let out = dir.join("export");
    let files = export(&ExportArgs {
        selection: Selection {
            db: db.clone(),
            driveline: Some("TCM".into()),
            kind: Some(KindArg::Chatter),
            since: None,
            until: None,
            product: None,
            coil: None,
        },
        bite: None,
        id: None,
        format: ExportFormat::Csv,
        out: out.clone(),
    })?;
    // The CSV and its header beside it (`<name>.json`).
    assert_eq!(files.len(), 2, "{files:?}");
    assert_eq!(files[1], files[0].with_extension("json"), "{files:?}");
    // The Parquet export holds the CSV's samples, a column per stand, and the header
    // with the episode (pyarrow reads both: the bite captures' script).
    let parquet = export(&ExportArgs {
        selection: Selection {
            db: db.clone(),
            driveline: Some("TCM".into()),
            kind: Some(KindArg::Chatter),
            since: None,
            until: None,
            product: None,
            coil: None,
        },
        bite: None,
        id: None,
        format: ExportFormat::Parquet,
        out: out.clone(),
    })?;
    let script = peer("capture_parquet.py");
    let checked = std::process::Command::new("python3")
        .arg(&script)
        .arg(&files[0])
        .arg(&parquet[0])
        .env(
            "MILLGATE_CONTEXT",
            format!(r#"{{"context_status": "valid", "coil": {COIL}, "product": {PRODUCT}}}"#),
        )
        .output()?;
    assert!(
        checked.status.success(),
        "{}{}",
        String::from_utf8_lossy(&checked.stdout),
        String::from_utf8_lossy(&checked.stderr)
    );
    let csv = std::fs::read_to_string(&files[0])?;
    assert_eq!(
        csv.lines().next(),
        Some("t,s1_vib,s2_vib,s3_vib,s4_vib,s5_vib")
    );
    let header: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&files[1])?)?;
    assert_eq!(
        header["episode"]["warning_sample"], episode.warning_sample,
        "{header}"
    );
    let config_path = dir.join("mill.toml");
    std::fs::write(&config_path, config_text(mill, None))?;
    let report = analyze(&WindowsArgs {
        input: files[0].clone(),
        config: config_path,
        mill: None,
        format: millgate::cli::OutputFormat::Json,
        plot: None,
    })?;
    let warned = report
        .first_warning_s
        .ok_or_else(|| anyhow::anyhow!("no warning"))?;
    println!("millgate chatter on the export: first warning {warned:.4} s");
    let online = (episode.warning_sample - 1) as f64 / FS;
    if episode.warning_sample == before.div_ceil(hop) * hop + lead {
        assert_eq!(warned, online);
    } else {
        // A restart within the 5 s: the gateway's windows started at the restart,
        // with no sample kept before it for the anchoring block, so the export's
        // windows start a hop later (docs/captures.md): the same window or the next.
        let later = (warned - online) * FS;
        assert!(
            later.abs() < 1e-6 || (later - hop as f64).abs() < 1e-6,
            "offline {warned} s, online {online} s, hop {hop}"
        );
    }

    // `millgate chatter commission` from the captures: the manual one of the stable
    // rolling gives thresholds; the chatter episode is refused (the loop slowed the
    // mill before chatter grew past the CSVs' chatter factor: refused as an episode).
    let commission = |ids: String| {
        millgate::cli::chatter::commission::run(&CommissionArgs {
            config: dir.join("mill.toml"),
            inputs: Vec::new(),
            db: Some(db.clone()),
            captures: Some(Picked::captures(&ids).expect("ids")),
            mill: None,
            margin: 10.0,
            speed_column: None,
            min_group_recordings: 2,
            format: millgate::cli::OutputFormat::Text,
        })
    };
    let printed = commission(manual[0].id.to_string())?;
    println!("commissioned from capture {}:\n{printed}", manual[0].id);
    assert!(printed.contains("gain_thresholds = ["), "{printed}");
    let refused = commission(format!("{},{}", manual[0].id, chatter[0].id))
        .expect_err("the chatter episode is refused");
    assert!(
        format!("{refused:#}").contains(&format!("#capture {}: a chatter episode", chatter[0].id)),
        "{refused:#}"
    );
    Ok(())
}

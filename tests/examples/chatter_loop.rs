//! The chatter closed loop's figures (`millgate_tests::experiments::chatter_loop`): seven mills on
//! three pass schedules, 40
//! accelerated runs open and closed loop, an hour of stable rolling at the highest
//! allowed speed and 20 welds per detector, and the plot of one closed-loop run.
//!
//! ```text
//! cargo run --release -p millgate-tests --example chatter_loop -- [--quick] [--plot FILE.svg]
//!     [--delay-cycles N]   # PLC cycles the request takes (default 1, as measured)
//!     [--weld-hold S,F]    # the weld bit's row with this weld_settle_s and
//!                          # weld_alarm_factor (default: the configuration's defaults)
//!     [--gain-only]        # the band gain's rows only
//! ```
//!
//! Besides the table it prints what each weld does to the band gain's figure with the
//! loop open (the peak gain ratio while the weld is in the mill and after it, and how
//! long after it left the ratio last reached the alarm level): what the weld hold's
//! defaults are chosen from.

use millgate::analysis::chatter::WeldHold;
use millgate_tests::experiments::chatter_loop::{
    mills, open_loop_developed, plot, run_loop, runs, score, table_row, weld_transients, Detector,
    LoopPlan, Scenario, TABLE_HEADER,
};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let mut plan = if args.iter().any(|a| a == "--quick") {
        LoopPlan::quick()
    } else {
        LoopPlan::full()
    };
    if let Some(delay) = args
        .iter()
        .position(|a| a == "--delay-cycles")
        .and_then(|i| args.get(i + 1))
    {
        plan.delay_cycles = delay.parse()?;
    }
    let weld_hold = match args
        .iter()
        .position(|a| a == "--weld-hold")
        .and_then(|i| args.get(i + 1))
    {
        Some(pair) => {
            let (settle, factor) = pair
                .split_once(',')
                .ok_or_else(|| anyhow::anyhow!("--weld-hold {pair}: expected S,F"))?;
            Some(WeldHold {
                settle_s: settle.parse()?,
                alarm_factor: factor.parse()?,
            })
        }
        None => None,
    };
    let gain_only = args.iter().any(|a| a == "--gain-only");
    let plot_path = args
        .iter()
        .position(|a| a == "--plot")
        .and_then(|i| args.get(i + 1));
    let started = std::time::Instant::now();
    let mills = mills(&plan)?;
    for m in &mills {
        println!(
            "mill {} friction x{} damping x{}: critical {:.2} m/s ({:.0} m/min, factor {:.3}, {:.1} Hz); \
             gain_thresholds {:?} release {}, band RMS {:?} release {}, k_max {}",
            m.plan.schedule,
            m.plan.friction,
            m.plan.damping,
            m.critical_m_s(),
            m.critical_m_s() * 60.0,
            m.critical.speed,
            m.critical.frequency_hz,
            m.gain_thresholds,
            m.gain_release,
            m.rms_thresholds,
            m.rms_release,
            m.k_max
        );
    }
    let runs = runs(&plan, &mills);
    let simulated: f64 = runs.iter().map(|r| r.duration_s).sum();
    println!(
        "{} runs ({} accelerated, {} stable, {} welds), {simulated:.0} s planned per detector; \
         commissioning {:.1} s wall",
        runs.len(),
        plan.accelerated,
        plan.stable,
        plan.welds,
        started.elapsed().as_secs_f64()
    );
    let default_hold = {
        let config = mills[0].config(Detector::BandGain, None)?;
        let mill = &config.tandem_mills[0];
        WeldHold {
            settle_s: mill.weld_settle_s,
            alarm_factor: mill.weld_alarm_factor,
        }
    };
    let mut transients = weld_transients(&plan, &mills, &runs)?;
    transients.sort_by(|a, b| a.peak_after.total_cmp(&b.peak_after));
    for t in &transients {
        println!(
            "  weld, open loop: peak gain ratio {:.2} in the mill, {:.2} after; last at the \
             alarm level {} after it left",
            t.peak_during,
            t.peak_after,
            t.last_alarm_after_s
                .map_or("never".to_owned(), |s| format!("{s:.2} s"))
        );
    }
    let open = open_loop_developed(&plan, &mills, &runs)?;
    println!(
        "open loop: {}/{} developed; the request read {} PLC cycle(s) after the block",
        open.0, open.1, plan.delay_cycles
    );
    let mut rows = Vec::new();
    let with_bit = LoopPlan {
        weld_bit: Some(weld_hold.unwrap_or(default_hold)),
        ..plan.clone()
    };
    let variants = Detector::ALL
        .iter()
        .filter(|&&d| !gain_only || d == Detector::BandGain)
        .map(|&d| (d, &plan))
        .chain([(Detector::BandGain, &with_bit)]);
    for (detector, plan) in variants {
        let (score, outcomes) = score(plan, &mills, &runs, detector)?;
        for (run, outcome) in runs.iter().zip(&outcomes) {
            let developed = outcome
                .developed_s
                .map_or("-".to_owned(), |t| format!("{t:.1}"));
            let shed: Vec<String> = outcome
                .events
                .iter()
                .map(|e| format!("{:.0}@{:.1}", e.shed_m_s() * 60.0, e.requested_s))
                .collect();
            if matches!(
                run.scenario,
                Scenario::Accelerated { .. } | Scenario::WeldRamp { .. }
            ) || !outcome.events.is_empty()
            {
                println!(
                    "  {:?} mill {} {:?} noise {:.2} decel {:.2}: onset {:?}, developed {developed}, slow-downs {}",
                    detector, run.mill, run.scenario, run.noise, run.decel_m_s2, outcome.onset_s.map(|t| (t * 10.0).round() / 10.0), shed.join(" ")
                );
            }
        }
        rows.push(table_row(&score, open));
        println!(
            "{}{}: {:.1} s wall so far",
            detector.name(),
            plan.weld_bit
                .map_or(String::new(), |h| format!(", weld bit {h:?}")),
            started.elapsed().as_secs_f64()
        );
    }
    println!("\n{TABLE_HEADER}");
    for row in rows {
        println!("{row}");
    }
    if let Some(path) = plot_path {
        // The first accelerated run on the nominal mill, closed loop, band gain.
        let (index, run) = runs
            .iter()
            .enumerate()
            .find(|(_, r)| r.mill == 0 && matches!(r.scenario, Scenario::Accelerated { .. }))
            .ok_or_else(|| anyhow::anyhow!("no accelerated run"))?;
        let mill = &mills[run.mill];
        let outcome = run_loop(&plan, mill, run, Some(Detector::BandGain), true)?;
        let title = format!(
            "closed loop, band gain: run {index}, critical speed {:.0} m/min",
            mill.critical_m_s() * 60.0
        );
        std::fs::write(path, plot(&outcome, mill.critical_m_s() * 60.0, &title)?)?;
        println!("plot of run {index}: {path}");
    }
    println!("{:.1} s wall", started.elapsed().as_secs_f64());
    Ok(())
}

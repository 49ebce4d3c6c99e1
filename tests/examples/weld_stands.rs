//! Weld bits per stand against the mill's weld bit on the tandem model's closed loop
//! (`millgate_tests::experiments::chatter_loop`): the weld passes the stands one after
//! the other (a burst per stand), the band-gain detector with its default weld hold
//! reads no weld bit, the mill's bit, or a bit per stand; per reading the welds at the
//! top speed that slowed the mill and, on ramps whose weld ends 0-3 s before the
//! critical speed, how many developed chatter and how long before the open loop's
//! chatter the first request came. The table in `docs/chatter.md` ("Weld bits per
//! stand").
//!
//! ```text
//! cargo run --release -p millgate-tests --example weld_stands -- [--welds N] [--ramps N]
//! # docs/chatter.md's table: --welds 8 --ramps 8 (the defaults are 10 and 10)
//! ```

use millgate::analysis::chatter::WeldHold;
use millgate_tests::experiments::chatter_loop::{
    mills, open_loop_weld_ramps, runs, weld_bits_row, weld_bits_table, Detector, LoopPlan,
    MillPlan, WeldBits,
};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let count = |flag: &str, default: usize| -> anyhow::Result<usize> {
        match args
            .iter()
            .position(|a| a == flag)
            .and_then(|i| args.get(i + 1))
        {
            Some(value) => Ok(value.parse()?),
            None => Ok(default),
        }
    };
    let plan = LoopPlan {
        mills: vec![MillPlan::new("lu2019-5stand.toml", 1.0, 1.0)],
        commission_recordings: 3,
        commission_s: 30.0,
        accelerated: 0,
        stable: 0,
        welds: count("--welds", 10)?,
        weld_ramps: count("--ramps", 10)?,
        weld_passes: true,
        settle_s: 12.0,
        ..LoopPlan::full()
    };
    let started = std::time::Instant::now();
    let mills = mills(&plan)?;
    let runs = runs(&plan, &mills);
    let hold = {
        let config = mills[0].config(Detector::BandGain, None)?;
        let mill = &config.tandem_mills[0];
        WeldHold {
            settle_s: mill.weld_settle_s,
            alarm_factor: mill.weld_alarm_factor,
        }
    };
    let open = open_loop_weld_ramps(&plan, &mills, &runs)?;
    let mut rows = Vec::new();
    for (bits, weld_bit, weld_bits) in [
        ("none", None, WeldBits::Mill),
        ("mill bit", Some(hold), WeldBits::Mill),
        ("stand bits", Some(hold), WeldBits::Stands),
    ] {
        let plan = LoopPlan {
            weld_bit,
            weld_bits,
            ..plan.clone()
        };
        rows.push(weld_bits_row(bits, &plan, &mills, &runs, &open)?);
    }
    println!(
        "{} weld runs and {} weld ramps on {} (seed {}), weld hold {} s x{}, the weld passing \
         the stands one after the other; {:.0} s wall",
        plan.welds,
        plan.weld_ramps,
        plan.mills[0].schedule,
        plan.seed,
        hold.settle_s,
        hold.alarm_factor,
        started.elapsed().as_secs_f64()
    );
    print!("{}", weld_bits_table(&rows));
    for row in &rows {
        println!("{}: leads {:?}", row.bits, row.leads_s);
    }
    Ok(())
}

//! A gateway that starts while a bar is already in the stand joins the DAQ stream at
//! a loaded level. It must not take that level for the zero: the next bites are
//! measured against the true idle torque.
//!
//! The join is mid-bar whatever the scheduling: the DAQ has played the schedule up to
//! the middle of the first bar (its sequence says so) and holds that block until the
//! gateway's first read, then plays in real time. Before, the test slept 1.2 s after
//! starting the DAQ and the gateway joined whenever its start-up ended: past the bar
//! on a loaded machine, where the test no longer tested a mid-bar join.

use std::time::Duration;

use millgate_config::ChannelSource;
use millgate_sim::devices::demo::{demo_daq, setup, SAMPLES_PER_BLOCK};
use millgate_tests::kit::demo_devices_with;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn joining_mid_bar_measures_the_following_bites_from_the_true_zero() -> anyhow::Result<()> {
    let demo = setup(9.0, 0.5, 11)?;
    let mut config = demo.config;
    // A read the DAQ answered is one the gateway takes (no timeout on a loaded
    // machine): no block of the bites measured is lost.
    config.modbus_sources[0].timeout = Duration::from_secs(20);
    let torque = &config.channels[config.drivelines[0].torque];
    let ChannelSource::ModbusBlock { base, .. } = torque.source else {
        panic!("the demo's torque is a block channel");
    };
    // The first bite is at 0.6 s and the bar rolls for 1.2 s: join at 1.2 s, in the
    // middle of the first bar, on a block boundary.
    let block = usize::from(SAMPLES_PER_BLOCK);
    let onset = demo.schedule.bites[0].onset_sample;
    let join = (onset + (0.6 * torque.sample_rate_hz) as usize) / block * block;
    let first_block = &demo.schedule.torque_knm[join..join + block];
    let level = first_block.iter().sum::<f64>() / block as f64;
    let loaded = demo.schedule.bites[0].static_torque_knm;
    assert!(
        level > 0.8 * loaded,
        "the join block is not in the bar: {level} kN*m, the bar {loaded} kN*m"
    );
    let mut joined = demo.schedule.clone();
    joined.torque_knm.drain(..join);
    // The DAQ's sequence counts the blocks it played before the join.
    let played = u16::try_from(join / block)?;
    let daq = demo_daq(&config, &joined)?
        .with_sequence(played)
        .playing_from_first_read()
        .logging_reads();
    let reads = daq.bank();
    let devices = demo_devices_with(&mut config, daq).await?;
    let mut gateway = millgate::Service::new(config)?.spawn().await?;

    // Two whole bites: a poll a loaded machine delays past a block loses it, and a bite
    // whose window holds the gap is degraded (not a measurement; its values are not
    // published).
    let mut reports = Vec::new();
    while reports.len() < 2 {
        let report =
            tokio::time::timeout(Duration::from_secs(20), gateway.bites().recv()).await??;
        if report.degraded {
            eprintln!("a degraded bite (a block lost): {report:?}");
        } else {
            reports.push(report);
        }
    }
    // After the fact: the gateway's first block was the one in the middle of the bar.
    let first_read = reads
        .take_read_log()
        .into_iter()
        .find(|read| read.address == base)
        .expect("the gateway read the torque block");
    assert_eq!(
        first_read.first_word,
        played + 1,
        "the gateway's first block was not the join block"
    );
    // The bar it joined in is not a bite; the next ones are, from the true zero (the
    // bars' static torques differ: the nearest is the bar).
    let mut after_join = demo.schedule.clone();
    after_join.bites.remove(0);
    for report in &reports {
        let measured = report.transient.static_torque_knm;
        let truth = after_join
            .nearest_truth(measured)
            .expect("bars after the join");
        assert!(
            (measured - truth.static_torque_knm).abs() < 0.02 * truth.static_torque_knm,
            "static {measured} vs truth {}",
            truth.static_torque_knm
        );
        let taf = report.transient.taf.unwrap();
        assert!(
            (taf - truth.taf).abs() < 0.02 * truth.taf,
            "TAF {taf} vs truth {}",
            truth.taf
        );
    }
    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    devices.stop().await?;
    Ok(())
}

//! A gateway that starts while a bar is already in the stand joins the DAQ stream at
//! a loaded level. It must not take that level for the zero: the next bites are
//! measured against the true idle torque.

use std::time::Duration;

use millgate_sim::devices::demo::setup;
use millgate_tests::kit::demo_devices;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn joining_mid_bar_measures_the_following_bites_from_the_true_zero() -> anyhow::Result<()> {
    let demo = setup(5.0, 0.5, 11)?;
    let mut config = demo.config;
    let devices = demo_devices(&mut config, &demo.schedule).await?;
    // The first bite is at 0.6 s; join at 1.2 s, in the middle of the first bar.
    tokio::time::sleep(Duration::from_millis(1200)).await;
    let mut gateway = millgate::Service::new(config)?.spawn().await?;

    let mut reports = Vec::new();
    while reports.len() < 2 {
        reports.push(tokio::time::timeout(Duration::from_secs(10), gateway.bites().recv()).await??);
    }
    for report in &reports {
        let measured = report.transient.static_torque_knm;
        let truth = demo.schedule.nearest_truth(measured).unwrap();
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

//! First end-to-end path over real sockets: virtual DAQ -> gateway -> virtual PLC,
//! all Modbus TCP on loopback. The PLC's registers are checked against the
//! simulated truth of each bite.

use std::time::Duration;

use millgate::outputs::modbus::register_map::{decode_f32, decode_u32, RegisterMap};
use millgate_sim::devices::demo::setup;
use millgate_tests::kit::demo_devices;

fn register(map: &RegisterMap, name: &str) -> usize {
    let found = map.registers().iter().find(|r| r.name == name);
    usize::from(
        found
            .unwrap_or_else(|| panic!("no register {name}"))
            .address,
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn daq_to_gateway_to_plc_registers_match_simulated_truth() -> anyhow::Result<()> {
    // Two bars: about 4 s of real-time streaming.
    let demo = setup(3.0, 0.5, 7)?;
    let mut config = demo.config;
    let schedule = demo.schedule;
    let devices = demo_devices(&mut config, &schedule).await?;
    let mut gateway = millgate::Service::new(config.clone())?.spawn().await?;
    let map = (*gateway.register_map()).clone();

    let mut reports = Vec::new();
    let collected = tokio::time::timeout(Duration::from_secs(20), async {
        while reports.len() < 2 {
            reports.push(gateway.bites().recv().await?);
        }
        anyhow::Ok(())
    })
    .await;
    assert!(
        collected.is_ok(),
        "only {} bites within 20 s",
        reports.len()
    );
    collected??;

    // Wait for a PLC write that carries the second bite.
    let counter = register(&map, "F1.bite_counter");
    let plc_words = tokio::time::timeout(Duration::from_secs(5), async {
        loop {
            let words = devices.plc.holding();
            if decode_u32(&words[counter..]) == Some(2) {
                return words;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await?;

    let last = &reports[1];
    let truth = schedule
        .nearest_truth(last.transient.static_torque_knm)
        .unwrap();
    assert_eq!(
        truth.static_torque_knm, schedule.bites[1].static_torque_knm,
        "second bar"
    );
    let taf = f64::from(decode_f32(&plc_words[register(&map, "F1.taf")..]).unwrap());
    let static_knm =
        f64::from(decode_f32(&plc_words[register(&map, "F1.static_torque_knm")..]).unwrap());
    let peak_knm =
        f64::from(decode_f32(&plc_words[register(&map, "F1.peak_torque_knm")..]).unwrap());
    assert!(
        (taf - truth.taf).abs() <= 0.02 * truth.taf,
        "PLC TAF {taf} vs truth {}",
        truth.taf
    );
    assert!(
        (static_knm - truth.static_torque_knm).abs() <= 0.02 * truth.static_torque_knm,
        "PLC static {static_knm} vs truth {}",
        truth.static_torque_knm
    );
    assert!(
        (peak_knm - truth.peak_torque_knm).abs() <= 0.02 * truth.peak_torque_knm,
        "PLC peak {peak_knm} vs truth {}",
        truth.peak_torque_knm
    );
    let quality = plc_words[register(&map, "F1.quality")];
    assert_eq!(quality & 0b1111, 0b1111, "time, static, peak and TAF valid");
    assert!(
        plc_words[register(&map, "heartbeat")] > 0,
        "heartbeat moves"
    );
    assert_eq!(
        plc_words[register(&map, "gateway_status")] & 1,
        1,
        "running"
    );

    gateway.stop().await?;
    let stopped = devices.plc.holding()[register(&map, "gateway_status")];
    assert_eq!(stopped & 0b10, 0b10, "final write says stopped");
    devices.stop().await?;
    Ok(())
}

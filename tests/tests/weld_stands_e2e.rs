//! Weld bits per stand in the service (issue 39 item 1): a virtual DAQ streams the
//! stable rolling of the physical five-stand tandem model (90% of its critical speed)
//! over Modbus TCP, and a second virtual PLC, polled over Modbus TCP, carries one
//! weld-tracking bit per stand (`tandem_mills[].context.weld_stands`, holding registers
//! 0-4, polled each second: a bit is used for 3 s, so a late poll on a loaded machine
//! does not end a hold). Stand 1's band-gain threshold is a fifth of the race's, so
//! its gain ratio is above the alarm level (the other stands below it); the weld
//! hold's factor is 10 and its settle time 0.5 s. While the weld is in stand 1 (its bit 1)
//! the ratio is held off (counted) and nothing is requested; once the weld has moved
//! on to stand 3 (stand 1's bit 0, stand 3's 1) stand 1 is judged at its plain level
//! again and the alarm and the slow-down request come: a weld holds its own stand
//! only. A bit of 2 is invalid: counted, not used. Read on the page's JSON and on
//! `/metrics`.

use std::time::Duration;

use millgate_config::Config;
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_tests::kit::scrape;
use millgate_tests::kit::tandem::{
    modbus_source, serve_daq_and_plc, stable_rolling_daq, tcm_metric, until_tandem_mill, Stands,
    GAIN_THRESHOLDS,
};

fn config() -> anyhow::Result<Config> {
    let mut thresholds = GAIN_THRESHOLDS;
    thresholds[0] /= 5.0;
    let weld_channels: String = (1..=5)
        .map(|stand| {
            format!(
                "[[channels]]\nname = \"weld_s{stand}\"\nkind = \"process_value\"\nunit = \"1\"\n\
                 source = {{ modbus = \"mill_plc\", table = \"holding\", address = {} }}\n\n",
                stand - 1
            )
        })
        .collect();
    let text = String::from("name = \"weld stands\"\n")
        + &modbus_source("daq")
        + "[[sources.modbus]]\nname = \"mill_plc\"\naddress = \"127.0.0.1:1\"\n\
           poll_period_ms = 1000\ntimeout_ms = 500\n\n"
        + &weld_channels
        + &Stands::modbus(5, "daq")
            .thresholds(&thresholds)
            .keys(
                "weld_settle_s = 0.5\nweld_alarm_factor = 10.0\ncontext = { weld_stands = \
                 [\"weld_s1\", \"weld_s2\", \"weld_s3\", \"weld_s4\", \"weld_s5\"] }\n",
            )
            .toml()
        + "[outputs.metrics]\nbind = \"127.0.0.1:0\"\n[outputs.web]\nbind = \"127.0.0.1:0\"\n";
    millgate_config::from_toml_str(&text, "weld-stands.toml", std::path::Path::new("."))
        .map_err(|e| anyhow::anyhow!("{e}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_weld_holds_the_alarm_of_its_own_stand_only() -> anyhow::Result<()> {
    // 20 s of stable rolling at 90% of the critical speed, played again and again.
    let daq = stable_rolling_daq()?;
    let plc = VirtualPlc::new(8);
    let set_welds = |bits: [u16; 5]| plc.bank().lock().holding[..5].copy_from_slice(&bits);
    // The weld in stand 1 before the gateway starts.
    set_welds([1, 0, 0, 0, 0]);

    let mut config = config()?;
    let (daq_running, plc_running) = serve_daq_and_plc(&mut config, daq, &plc).await?;
    let gateway = millgate::Service::new(config)?.spawn().await?;
    let web = gateway.bound().web.expect("the page");
    let metrics = gateway.bound().metrics.expect("metrics");

    // Waits until the mill's JSON on the page satisfies `done`; returns it.
    let until = |what: &'static str, done: fn(&serde_json::Value) -> bool| {
        until_tandem_mill(web, Duration::from_secs(15), what, done)
    };

    // The weld in stand 1: stand 1's ratio reaches the alarm level, held off.
    let held = until("stand 1's alarm held off", |m| {
        m["weld_held_off"].as_u64().is_some_and(|n| n >= 8)
    })
    .await?;
    assert_eq!(held["worst_stand_channel"], "s1_vib", "{held}");
    let ratio = held["gain_ratio"].as_f64().unwrap_or(f64::NAN);
    assert!(ratio > 1.0 && ratio < 10.0, "{held}");
    assert_eq!(held["chatter_alarm"], false, "{held}");
    assert_eq!(held["slow_down_request"], false, "{held}");
    assert_eq!(held["context_invalid"], 0, "{held}");
    let page = scrape(metrics).await?;
    assert!(
        tcm_metric(&page, "millgate_tandem_mill_weld_held_off_total").is_some_and(|n| n >= 8.0),
        "{page}"
    );

    // The weld moves on to stand 3: stand 1 settles for 0.5 s, then its plain level
    // judges it; the weld at stand 3 holds stand 3 only.
    set_welds([0, 0, 1, 0, 0]);
    let raised = until("stand 1's alarm once the weld has left it", |m| {
        m["chatter_alarm"] == true && m["slow_down_request"] == true
    })
    .await?;
    assert_eq!(raised["worst_stand_channel"], "s1_vib", "{raised}");
    let page = scrape(metrics).await?;
    assert_eq!(
        tcm_metric(&page, "millgate_tandem_mill_slow_down_request"),
        Some(1.0),
        "{page}"
    );

    // A bit of 2 is no bit: counted, not used.
    set_welds([0, 2, 0, 0, 0]);
    let invalid = until("an impossible weld bit counted", |m| {
        m["context_invalid"].as_u64().is_some_and(|n| n > 0)
    })
    .await?;
    assert_eq!(invalid["slow_down_request"], true, "{invalid}");

    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    daq_running.stop().await?;
    plc_running.stop().await?;
    Ok(())
}

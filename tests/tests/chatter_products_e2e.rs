//! Per-product chatter thresholds in the service (issue 39 item 4): a virtual DAQ
//! streams the stable rolling of the physical five-stand tandem model (90% of its
//! critical speed) over Modbus TCP, and a second virtual PLC, polled over Modbus TCP,
//! carries the product code (`tandem_mills[].context.product`). The mill's thresholds
//! are the race's; the product group "tight" (product 7) has a quarter of them. The
//! thresholds in use follow the PLC's product register: product 8 (in no group) is
//! judged by the mill's, product 7 by the group's (the gain ratio four times as high,
//! the alarm), and product 99 (not one of the context's `products`) is invalid: counted,
//! and the mill's thresholds judge again (a counted fallback). Read on the page's JSON
//! and on `/metrics`.

use std::time::Duration;

use millgate_config::Config;
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_tests::kit::scrape;
use millgate_tests::kit::tandem::{
    product_groups_toml, serve_daq_and_plc, stable_rolling_daq, tcm_metric, until_tandem_mill,
};

/// The process PLC's holding register with the product code.
const PRODUCT_REGISTER: usize = 0;

fn config() -> anyhow::Result<Config> {
    let text = product_groups_toml("chatter products")
        + "[outputs.metrics]\nbind = \"127.0.0.1:0\"\n[outputs.web]\nbind = \"127.0.0.1:0\"\n";
    millgate_config::from_toml_str(&text, "chatter-products.toml", std::path::Path::new("."))
        .map_err(|e| anyhow::anyhow!("{e}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_thresholds_in_use_follow_the_plcs_product() -> anyhow::Result<()> {
    // 20 s of stable rolling at 90% of the critical speed, played again and again.
    let daq = stable_rolling_daq()?;
    let process = VirtualPlc::new(4);
    let set_product = |code: u16| process.bank().lock().holding[PRODUCT_REGISTER] = code;
    set_product(8);

    let mut config = config()?;
    let (daq_running, process_running) = serve_daq_and_plc(&mut config, daq, &process).await?;
    let gateway = millgate::Service::new(config)?.spawn().await?;
    let web = gateway.bound().web.expect("the page");
    let metrics = gateway.bound().metrics.expect("metrics");

    // Waits until the mill's JSON on the page satisfies `done`; returns it.
    let until = |what: &'static str, done: fn(&serde_json::Value) -> bool| {
        until_tandem_mill(web, Duration::from_secs(10), what, done)
    };

    // Product 8, in no group: the mill's thresholds, below the alarm.
    let mill = until("a gain ratio by the mill's thresholds", |m| {
        m["thresholds_group"] == 0 && m["gain_ratio"].as_f64().is_some()
    })
    .await?;
    let ratio_8 = mill["gain_ratio"].as_f64().unwrap_or(f64::NAN);
    assert!(ratio_8 > 0.0 && ratio_8 < 1.0, "{mill}");
    assert_eq!(
        mill["thresholds_group_name"],
        serde_json::Value::Null,
        "{mill}"
    );
    assert_eq!(mill["chatter_alarm"], false, "{mill}");
    let page = scrape(metrics).await?;
    assert_eq!(
        tcm_metric(&page, "millgate_tandem_mill_thresholds_group"),
        Some(0.0),
        "{page}"
    );
    assert_eq!(
        tcm_metric(&page, "millgate_tandem_mill_product_fallback_total"),
        Some(0.0)
    );

    // Product 7: the "tight" group's thresholds, a quarter of the mill's.
    set_product(7);
    let tight = until("the tight group's thresholds", |m| {
        m["thresholds_group"] == 1 && m["chatter_alarm"] == true
    })
    .await?;
    assert_eq!(tight["thresholds_group_name"], "tight", "{tight}");
    let ratio_7 = tight["gain_ratio"].as_f64().unwrap_or(f64::NAN);
    assert!(
        ratio_7 > 2.5 * ratio_8,
        "{ratio_7} against {ratio_8}: {tight}"
    );
    let page = scrape(metrics).await?;
    assert_eq!(
        tcm_metric(&page, "millgate_tandem_mill_thresholds_group"),
        Some(1.0),
        "{page}"
    );

    // Product 99 is not a known product: invalid, counted, the mill's thresholds again.
    set_product(99);
    let invalid = until("the fallback on an invalid product", |m| {
        m["thresholds_group"] == 0 && m["product_fallback"].as_u64().is_some_and(|n| n > 0)
    })
    .await?;
    assert!(
        invalid["context_invalid"].as_u64().is_some_and(|n| n > 0),
        "{invalid}"
    );
    assert_eq!(invalid["thresholds_group_name"], serde_json::Value::Null);
    let page = scrape(metrics).await?;
    assert!(
        tcm_metric(&page, "millgate_tandem_mill_product_fallback_total").is_some_and(|n| n > 0.0),
        "{page}"
    );

    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    daq_running.stop().await?;
    process_running.stop().await?;
    Ok(())
}

//! The gap diagnosis end to end: a virtual DAQ streams bars of the Table 2 driveline
//! whose spindle gap opens from 1 to 3 mrad during the run, the gateway builds its gap
//! maps in the background from the model the configuration names, and the PLC's gap
//! registers follow the gap. A second gateway, started with the first one's pooled
//! bites restored and the maps in the cache, publishes the same estimate before any
//! new bite.

use std::path::PathBuf;
use std::time::Duration;

use millgate::outputs::modbus::register_map::{decode_f32, flag_mask, RegisterMap};
use millgate::state::catalogue::DRIVELINE;
use millgate_sim::model::Model;
use millgate_sim::schedule::{rolling_schedule_with_gap, BarTiming};
use millgate_tests::kit::{demo_devices, scratch, wait_for};

const MODEL: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../sim/models/table2-adjusted.toml"
);
const TIMING: BarTiming = BarTiming {
    idle_s: 0.5,
    rolling_s: 0.8,
};
/// Bars: static torque (kN*m) and the gap in the spindles (mrad), growing 0.7 mrad a bar.
const BARS: [(f64, f64); 4] = [(60.0, 1.0), (140.0, 1.7), (50.0, 2.4), (110.0, 3.1)];
/// Quality bits of gap_mrad .. bites_pooled.
const GAP_QUALITY: u16 = 0b11111 << 9;

fn address(map: &RegisterMap, name: &str) -> usize {
    let register = map.registers().iter().find(|r| r.name == name);
    usize::from(
        register
            .unwrap_or_else(|| panic!("no register {name}"))
            .address,
    )
}

fn f32_at(words: &[u16], map: &RegisterMap, name: &str) -> f64 {
    f64::from(decode_f32(&words[address(map, name)..]).expect("f32"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_plc_gap_register_follows_a_growing_gap_and_survives_a_restart() -> anyhow::Result<()> {
    let scratch = scratch("gap-e2e");
    let cache = scratch.path().to_path_buf();
    let model = Model::load(MODEL)?;
    let torques: Vec<f64> = BARS.iter().map(|bar| bar.0).collect();
    let gaps: Vec<f64> = BARS.iter().map(|bar| bar.1 * 1e-3).collect();
    let schedule = rolling_schedule_with_gap(&model, &torques, TIMING, 0.5, 13, 1, &gaps)?;
    let mut config = millgate_sim::devices::demo::setup(1.0, 0.5, 1)?.config;
    config.drivelines[0].model = Some(PathBuf::from(MODEL));
    config.cache_dir = Some(cache.clone());
    let restart_config = config.clone();
    let devices = demo_devices(&mut config, &schedule).await?;
    let mut gateway = millgate::Service::new(config)?.spawn().await?;
    let map = (*gateway.register_map()).clone();
    let plc = devices.plc.clone();
    let quality = address(&map, "F1.quality");
    assert_eq!(
        plc.holding()[quality] & GAP_QUALITY,
        0,
        "invalid until the maps are in"
    );

    let mut saved = None;
    let mut seen = Vec::new();
    for (bar, &(_, gap_mrad)) in BARS.iter().enumerate() {
        let bite = tokio::time::timeout(Duration::from_secs(10), gateway.bites().recv()).await??;
        let gap = bite.gap.as_ref().unwrap_or_else(|| {
            panic!(
                "bar {bar}: no gap observation (degraded window: {})",
                bite.degraded
            )
        });
        saved = gap.saved.clone().or(saved);
        // The maps may still be building at the first bites: wait for the register.
        let counter = address(&map, "F1.bite_counter");
        wait_for(
            "the bite and a valid gap in the PLC",
            Duration::from_secs(15),
            || {
                let words = plc.holding();
                millgate::outputs::modbus::register_map::decode_u32(&words[counter..])
                    == Some(bar as u32 + 1)
                    && words[quality] & GAP_QUALITY == GAP_QUALITY
            },
        )
        .await;
        let words = plc.holding();
        let published = f32_at(&words, &map, "F1.gap_mrad");
        let (low, high) = (
            f32_at(&words, &map, "F1.gap_low_mrad"),
            f32_at(&words, &map, "F1.gap_high_mrad"),
        );
        println!("bar {bar}: truth {gap_mrad} mrad, PLC {published:.3} ({low:.3} .. {high:.3})");
        seen.push((gap_mrad, published, words[address(&map, "F1.flags")]));
        // The trend follows the growing gap: its interval holds the truth at every bite.
        assert!(
            (published - gap_mrad).abs() < 0.3,
            "bar {bar}: {published} vs {gap_mrad}"
        );
        assert!(
            low <= gap_mrad && gap_mrad <= high,
            "bar {bar}: {low} .. {high} vs {gap_mrad}"
        );
        assert_eq!(words[address(&map, "F1.gap_coupling")], 1, "the spindles");
        assert_eq!(
            usize::from(words[address(&map, "F1.bites_pooled")]),
            bar + 1
        );
    }
    let (_, before, flags_before) = seen[1];
    let (_, after, flags_after) = seen[3];
    assert!(
        after > before + 1.0,
        "the register follows the gap: {before} -> {after}"
    );
    assert_eq!(
        flags_before & flag_mask(DRIVELINE, "gap_warning"),
        0,
        "1.7 mrad: no warning"
    );
    assert_ne!(
        flags_after & flag_mask(DRIVELINE, "gap_warning"),
        0,
        "3.1 mrad: warning (2 mrad)"
    );
    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    devices.stop().await?;

    // Restart: the trend's saved form restored (as a history does), the maps from the
    // cache, a DAQ with idle torque only: the same estimate without a new bite.
    let mut config = restart_config;
    let idle = rolling_schedule_with_gap(&model, &[], TIMING, 0.5, 14, 1, &[])?;
    let devices = demo_devices(&mut config, &idle).await?;
    let mut service = millgate::Service::new(config)?;
    service.restore_gap_trend(0, saved.as_deref(), Vec::new());
    let gateway = service.spawn().await?;
    let plc = devices.plc.clone();
    wait_for(
        "the restored gap in the PLC",
        Duration::from_secs(10),
        || plc.holding()[quality] & GAP_QUALITY == GAP_QUALITY,
    )
    .await;
    let restored = f32_at(&plc.holding(), &map, "F1.gap_mrad");
    assert_eq!(restored, after, "the same estimate after the restart");
    tokio::time::timeout(Duration::from_secs(10), gateway.stop()).await??;
    devices.stop().await?;
    Ok(())
}

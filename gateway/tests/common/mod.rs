//! The gateway's integration tests share the test kit (`millgate_tests::kit`, a
//! dev-dependency); this binds it to this package's `millgate` binary, which cargo
//! names for this package's tests only.
// Each test crate uses a part of it.
#![allow(dead_code, unused_imports)]

pub(crate) use millgate_tests::kit::*;

/// The `millgate` binary under test.
pub(crate) const MILLGATE: Millgate = Millgate(env!("CARGO_BIN_EXE_millgate"));

/// `millgate args`, run to its end (no standard input).
pub(crate) fn millgate(args: &[&str]) -> std::process::Output {
    MILLGATE.run(args)
}

/// The u32 at register `address` as the HMI server at `port` answers (Modbus TCP on
/// loopback, unit 1).
pub(crate) async fn hmi_u32(port: u16, address: u16) -> u32 {
    use tokio_modbus::client::Reader;
    let server = std::net::SocketAddr::from(([127, 0, 0, 1], port));
    let mut hmi = tokio_modbus::client::tcp::connect_slave(server, tokio_modbus::Slave(1))
        .await
        .unwrap();
    let words = hmi
        .read_holding_registers(address, 2)
        .await
        .unwrap()
        .unwrap();
    millgate::outputs::modbus::register_map::decode_u32(&words).unwrap()
}

/// `/metrics`' count of configuration reloads with `outcome`.
pub(crate) fn reloads(outcome: &str) -> String {
    format!("millgate_config_reloads_total{{outcome=\"{outcome}\"}}")
}

/// A `SIGHUP` to `service`, answered by `said` in its log and counted (the first
/// time) as `outcome`.
pub(crate) async fn answered_by_sighup(
    setup: &Setup,
    service: &KillOnDrop,
    said: &str,
    outcome: &str,
) {
    hang_up(service.id());
    wait_for(said, std::time::Duration::from_secs(20), || {
        setup.log_text("run.log").contains(said)
    })
    .await;
    setup
        .until_metric(&reloads(outcome), 1.0, std::time::Duration::from_secs(10))
        .await;
}

/// A `SIGHUP` to `service`, answered by `said` in its log (nothing waits for a
/// restart) and counted as applied.
pub(crate) async fn applied_by_sighup(setup: &Setup, service: &KillOnDrop, said: &str) {
    answered_by_sighup(setup, service, said, "applied").await;
    assert!(
        !setup.log_text("run.log").contains("needs a restart"),
        "{}",
        setup.log_text("run.log")
    );
}

/// The bite ids of driveline `name` in `history`, in order.
pub(crate) fn bite_ids(history: &millgate::history::query::HistoryReader, name: &str) -> Vec<u32> {
    let filter = millgate::history::query::Filter {
        name: Some(name.to_owned()),
        ..millgate::history::query::Filter::default()
    };
    let bites = history.bites(&filter).unwrap();
    bites.iter().map(|bite| bite.figures.bite_counter).collect()
}

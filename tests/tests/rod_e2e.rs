//! Rod mill end to end (issue 17 item 5): a virtual process PLC carries the drive
//! configuration, the pass and the finishing speed of the example RSM block
//! (`sim/models/rod`) over Modbus TCP; the gateway evaluates every span and writes
//! the rod mill's block into a second virtual PLC, read back from its bank.
//!
//! The speed ramps through the band of pass P1 (`table3`) in which span 2 (stand 2 -
//! stand 3, bending mode 1 excited at stand 2's roll speed) is unstable. The expected
//! flags come from the band edges of the pass's setup (the speed scan of
//! `PassSetup::new`), the expected margins and exponents from `PassSetup::status` at
//! the speed the gateway read.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use millgate::outputs::modbus::register_map::{decode_f32, flag_mask, RegisterMap};
use millgate::state::catalogue::{ROD_MILL, ROD_SPAN};
use millgate_config::layout::encode_value;
use millgate_config::WebOutput;
use millgate_config::{Config, ValueType, WordOrder};
use millgate_sim::devices::modbus_bank::{Running, ServeOptions};
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_sim::rod::check::PassSetup;
use millgate_sim::rod::mill::RodMill;
use millgate_sim::rod::schedule;
use millgate_tests::kit::{wait_for, web_overview};
use tokio::net::TcpListener;

/// Holding registers of the process PLC: configuration (u16), pass (u16), finishing
/// speed (f32 ABCD).
const CONFIGURATION_REGISTER: usize = 0;
const PASS_REGISTER: usize = 1;
const SPEED_REGISTER: usize = 2;
const NEAR_TONGUE_M_S: f64 = 2.0;
const HYSTERESIS_M_S: f64 = 0.5;
/// The span ramped through its band (0-based: span 2, stand 2 - stand 3).
const SPAN: usize = 1;

fn models() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../sim/models/rod")
}

fn config() -> anyhow::Result<Config> {
    let text = format!(
        "name = \"rod e2e\"\n\
         [[sources.modbus]]\nname = \"process_plc\"\naddress = \"127.0.0.1:1\"\n\
         poll_period_ms = 20\ntimeout_ms = 200\n\
         [[channels]]\nname = \"rsm_configuration\"\nkind = \"process_value\"\nunit = \"1\"\n\
         source = {{ modbus = \"process_plc\", table = \"holding\", address = {CONFIGURATION_REGISTER} }}\n\
         [[channels]]\nname = \"rsm_pass\"\nkind = \"process_value\"\nunit = \"1\"\n\
         source = {{ modbus = \"process_plc\", table = \"holding\", address = {PASS_REGISTER} }}\n\
         [[channels]]\nname = \"rsm_speed\"\nkind = \"process_value\"\nunit = \"m/s\"\n\
         source = {{ modbus = \"process_plc\", table = \"holding\", address = {SPEED_REGISTER}, type = \"f32\" }}\n\
         [[rod_mills]]\nname = \"RSM\"\nmill = \"rsm-mill.toml\"\nschedule = \"rsm-schedule.csv\"\n\
         configuration = \"rsm_configuration\"\nconfigurations = [\"table3\", \"fast\"]\n\
         pass = \"rsm_pass\"\nfinishing_speed = \"rsm_speed\"\n\
         near_tongue_m_s = {NEAR_TONGUE_M_S}\nhysteresis_m_s = {HYSTERESIS_M_S}\n\
         [outputs.plc]\naddress = \"127.0.0.1:1\"\nwrite_period_ms = 50\ntimeout_ms = 200\n"
    );
    millgate_config::from_toml_str(&text, "rod-e2e.toml", &models())
        .map_err(|e| anyhow::anyhow!("{e}"))
}

/// The rod mill's registers and one span's in an output PLC snapshot.
#[derive(Debug, Clone, Copy)]
struct RodWords {
    mill_flags: u16,
    mill_quality: u16,
    configuration: u16,
    pass: u16,
    speed_m_s: f32,
    span_flags: u16,
    span_quality: u16,
    margin_m_s: f32,
    exponent_per_s: f32,
}

struct Devices {
    process: VirtualPlc,
    process_running: Option<Running>,
    output: VirtualPlc,
    output_running: Running,
    map: RegisterMap,
}

impl Devices {
    async fn start(config: &mut Config) -> anyhow::Result<Self> {
        let map = RegisterMap::new(config);
        let process = VirtualPlc::new(16);
        let output = VirtualPlc::new(usize::from(map.len()) + 16);
        let listener = TcpListener::bind("127.0.0.1:0").await?;
        config.modbus_sources[0].address = listener.local_addr()?.to_string();
        let process_running = Some(process.spawn(listener, ServeOptions::default()));
        let listener = TcpListener::bind("127.0.0.1:0").await?;
        if let Some(plc) = config.outputs.plc.as_mut() {
            plc.address = listener.local_addr()?.to_string();
            plc.register_base = 0;
        }
        let output_running = output.spawn(listener, ServeOptions::default());
        Ok(Self {
            process,
            process_running,
            output,
            output_running,
            map,
        })
    }

    /// The PLC sets configuration `configuration`, pass `pass`, speed `speed_m_s`.
    fn set(&self, configuration: u16, pass: u16, speed_m_s: f64) {
        let (speed, _) = encode_value(speed_m_s, ValueType::F32, WordOrder::Abcd);
        let bank = self.process.bank();
        let mut bank = bank.lock();
        bank.holding[CONFIGURATION_REGISTER] = configuration;
        bank.holding[PASS_REGISTER] = pass;
        bank.holding[SPEED_REGISTER..SPEED_REGISTER + 2].copy_from_slice(&speed);
    }

    fn read(&self) -> RodWords {
        let words = self.output.holding();
        let at = |name: &str| {
            let register = self.map.registers().iter().find(|r| r.name == name);
            usize::from(register.unwrap_or_else(|| panic!("{name}")).address)
        };
        let span = |field: &str| at(&format!("RSM.span{}.{field}", SPAN + 1));
        let f32_at = |address: usize| decode_f32(&words[address..]).unwrap_or(f32::NAN);
        RodWords {
            mill_flags: words[at("RSM.flags")],
            mill_quality: words[at("RSM.quality")],
            configuration: words[at("RSM.configuration")],
            pass: words[at("RSM.pass")],
            speed_m_s: f32_at(at("RSM.finishing_speed_m_s")),
            span_flags: words[span("flags")],
            span_quality: words[span("quality")],
            margin_m_s: f32_at(span("speed_margin_m_s")),
            exponent_per_s: f32_at(span("worst_exponent_per_s")),
        }
    }

    /// Set the speed and wait until the output PLC shows it evaluated.
    async fn at_speed(&self, configuration: u16, pass: u16, speed_m_s: f64) -> RodWords {
        self.set(configuration, pass, speed_m_s);
        let mut last = self.read();
        wait_for(
            &format!("registers at {speed_m_s} m/s"),
            Duration::from_secs(3),
            || {
                last = self.read();
                last.speed_m_s == speed_m_s as f32 && last.mill_quality & 0b111 == 0b111
            },
        )
        .await;
        last
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ramp_through_a_tongue_sets_and_clears_the_span_flags() -> anyhow::Result<()> {
    let mut config = config()?;
    let mut devices = Devices::start(&mut config).await?;

    // The expectation, from the library directly.
    let mill = Arc::new(RodMill::load(models().join("rsm-mill.toml"))?);
    let passes = schedule::load(models().join("rsm-schedule.csv"))?;
    let p1 = &passes[0];
    assert_eq!(
        (p1.name.as_str(), p1.configuration.as_str()),
        ("P1", "table3")
    );
    let setup = PassSetup::new(&mill, p1)?;
    let band = setup
        .avoid
        .iter()
        .find(|b| {
            (45.0..60.0).contains(&b.from_m_s)
                && b.sources.iter().any(|s| s.starts_with("stand 2 - stand 3"))
        })
        .expect("P1 has a span 2 band between 45 and 60 m/s")
        .clone();
    // The band is the domain notes' 50.8-52.3 m/s (roll 1x of stand 2).
    assert!(
        (band.from_m_s - 50.8).abs() < 0.1 && (band.to_m_s - 52.3).abs() < 0.1,
        "{band:?}"
    );

    devices.set(0, 1, 47.0);
    config.outputs.web = Some(WebOutput::on("127.0.0.1:0".parse()?));
    let gateway = millgate::Service::new(config)?.spawn().await?;
    let web = gateway
        .bound()
        .web
        .expect("the maintenance page is configured");

    let mut speeds = Vec::new();
    let mut speed = 47.0;
    while speed <= 55.0 {
        speeds.push(speed);
        speed += 0.25;
    }
    let mut inside = 0;
    let mut held = 0;
    let mut near = 0;
    for &speed in &speeds {
        let words = devices.at_speed(0, 1, speed).await;
        let expected = &setup.status(speed)?[SPAN];
        assert_eq!((words.configuration, words.pass), (0, 1), "{words:?}");
        assert_eq!(
            words.span_flags & flag_mask(ROD_SPAN, "invalid"),
            0,
            "{speed}: {words:?}"
        );
        // Margin and exponent as the library gives them (f32 registers).
        let margin = expected
            .speed_margin_m_s
            .expect("span 2 has band edges in range");
        assert!(
            (f64::from(words.margin_m_s) - margin).abs() < 1e-4,
            "{speed}: {words:?} vs {expected:?}"
        );
        let exponent = expected.worst_exponent_per_s.expect("resolved");
        assert!(
            (f64::from(words.exponent_per_s) - exponent).abs() < 1e-4 * exponent.abs().max(1.0),
            "{speed}: {words:?} vs {expected:?}"
        );
        assert_eq!(words.span_quality & 0b111, 0b111, "{speed}: {words:?}");
        let unstable = words.span_flags & flag_mask(ROD_SPAN, "unstable") != 0;
        let near_tongue = words.span_flags & flag_mask(ROD_SPAN, "near_tongue") != 0;
        // The mill's bits are the OR of its spans'.
        assert!(
            !unstable || words.mill_flags & flag_mask(ROD_MILL, "unstable") != 0,
            "{words:?}"
        );
        // The maintenance page: the worst span and its margin as the library gives
        // them at this speed, the state as the PLC's mill flags say.
        let rod = &web_overview(web).await?["rod_mills"][0];
        let (worst, worst_margin) = setup
            .status(speed)?
            .iter()
            .enumerate()
            .filter_map(|(span, status)| Some((span + 1, status.speed_margin_m_s?)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .expect("spans with band edges");
        assert_eq!(
            rod["worst_span"].as_u64(),
            Some(worst as u64),
            "{speed}: {rod}"
        );
        assert!(
            (rod["worst_margin_m_s"].as_f64().unwrap() - worst_margin).abs() < 1e-6,
            "{speed}: {rod}, library {worst_margin}"
        );
        let state = if words.mill_flags & flag_mask(ROD_MILL, "unstable") != 0 {
            "unstable"
        } else if words.mill_flags & flag_mask(ROD_MILL, "near_tongue") != 0 {
            "near_tongue"
        } else {
            "stable"
        };
        assert_eq!(rod["state"], state, "{speed}: {rod} vs {words:?}");
        assert_eq!(rod["pass"], 1);
        assert_eq!(rod["finishing_speed_m_s"].as_f64(), Some(speed), "{rod}");
        let in_band = speed > band.from_m_s && speed < band.to_m_s;
        let distance = (speed - band.from_m_s)
            .abs()
            .min((speed - band.to_m_s).abs());
        if in_band {
            inside += 1;
            assert!(
                unstable && !near_tongue,
                "{speed} m/s inside {band:?}: {words:?}"
            );
            assert!(
                words.exponent_per_s > 0.0 && words.margin_m_s < 0.0,
                "{speed}: {words:?}"
            );
        } else if speed > band.to_m_s && distance < HYSTERESIS_M_S {
            // Just out of the band: the unstable flag holds (hysteresis).
            held += 1;
            assert!(
                unstable && !near_tongue,
                "{speed} m/s after {band:?}: {words:?}"
            );
            assert!(
                words.exponent_per_s <= 0.0 && words.margin_m_s > 0.0,
                "{speed}: {words:?}"
            );
        } else {
            assert!(!unstable, "{speed} m/s outside {band:?}: {words:?}");
            assert!(words.margin_m_s > 0.0, "{speed}: {words:?}");
            // Approaching: near below the threshold; leaving: until threshold + hysteresis.
            let limit = if speed < band.from_m_s {
                NEAR_TONGUE_M_S
            } else {
                NEAR_TONGUE_M_S + HYSTERESIS_M_S
            };
            assert_eq!(near_tongue, margin < limit, "{speed} m/s: {words:?}");
            near += usize::from(near_tongue);
        }
    }
    assert!(
        inside >= 5 && held >= 1 && near >= 8,
        "inside {inside}, held {held}, near {near}"
    );

    // Bad input: a speed of 0, then a configuration the list does not have. The spans
    // go invalid, the service keeps running and recovers with the next good value.
    for (configuration, speed) in [(0, 0.0), (2, 48.0)] {
        devices.set(configuration, 1, speed);
        wait_for("invalid on bad input", Duration::from_secs(3), || {
            let words = devices.read();
            words.mill_flags
                == flag_mask(ROD_MILL, "invalid") | flag_mask(ROD_MILL, "input_refused")
                && words.span_flags == flag_mask(ROD_SPAN, "invalid")
                && words.span_quality == 0
                && words.mill_quality == 0
        })
        .await;
        assert!(!gateway.is_finished());
        let words = devices.at_speed(0, 1, 49.0).await;
        assert_eq!(
            words.span_flags & flag_mask(ROD_SPAN, "invalid"),
            0,
            "{words:?}"
        );
    }

    // The process PLC stops answering: the flags go invalid, never frozen.
    let words = devices.at_speed(0, 1, 51.5).await;
    assert_ne!(
        words.span_flags & flag_mask(ROD_SPAN, "unstable"),
        0,
        "{words:?}"
    );
    if let Some(running) = devices.process_running.take() {
        running.stop().await?;
    }
    wait_for(
        "invalid when the process PLC is stale",
        Duration::from_secs(5),
        || {
            let words = devices.read();
            words.span_flags == flag_mask(ROD_SPAN, "invalid")
                && words.mill_flags
                    == flag_mask(ROD_MILL, "invalid") | flag_mask(ROD_MILL, "source_stale")
                && words.span_quality == 0
                && words.margin_m_s == 0.0
                && words.mill_quality == 0
        },
    )
    .await;
    // The page says stale and shows no margin it cannot trust.
    let rod = &web_overview(web).await?["rod_mills"][0];
    assert_eq!(rod["state"], "stale", "{rod}");
    assert!(rod["worst_margin_m_s"].is_null(), "{rod}");

    gateway.stop().await?;
    devices.output_running.stop().await?;
    Ok(())
}

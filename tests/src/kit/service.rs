//! A gateway between the demo's virtual devices: [`demo_devices`] for a service run
//! in-process (`millgate::Service`), [`Setup`] for `millgate run` as a child process
//! with its configuration file and history in a scratch folder; the PLC's driveline
//! registers ([`Plc`]).

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

use millgate::outputs::modbus::register_map::{decode_f32, decode_u32, RegisterMap};
use millgate_config::Config;
use millgate_sim::devices::demo::{setup, DemoDevices};
use millgate_sim::devices::virtual_daq::VirtualDaq;
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_sim::schedule::Schedule;

use super::cli::{KillOnDrop, Millgate};
use super::net::{free_port, http, metric_line, try_http, wait_for};
use super::scratch::{scratch, TempDir};

/// The demo's virtual DAQ playing `schedule` and a virtual PLC holding `config`'s whole
/// register map, started on loopback; `config` is pointed at them
/// ([`DemoDevices::start`]).
pub async fn demo_devices(config: &mut Config, schedule: &Schedule) -> anyhow::Result<DemoDevices> {
    let daq = millgate_sim::devices::demo::demo_daq(config, schedule)?;
    demo_devices_with(config, daq).await
}

/// As [`demo_devices`], with the caller's DAQ (the demo's, logging the reads or
/// playing from its first read: `VirtualDaq::playing_from_first_read`).
pub async fn demo_devices_with(
    config: &mut Config,
    daq: VirtualDaq,
) -> anyhow::Result<DemoDevices> {
    let plc_registers = usize::from(RegisterMap::new(config).len()) + 16;
    Ok(DemoDevices::start_with(config, daq, plc_registers).await?)
}

/// `schedule`'s torque as the demo's DAQ sends it on `torque`, a block channel: each
/// sample its i16 count (`to_raw_sample`) decoded by the channel's scaling.
pub fn as_daq_sends(schedule: &Schedule, torque: &millgate_config::Channel) -> Vec<f64> {
    schedule
        .torque_knm
        .iter()
        .map(|&v| {
            let raw = millgate_config::layout::to_raw_sample(v, torque.scale, torque.offset);
            torque.scaling().apply(f64::from(raw))
        })
        .collect()
}

/// Registers of the driveline block read from the virtual PLC.
#[derive(Debug)]
pub struct Plc<'a> {
    /// The virtual PLC the gateway writes.
    pub plc: &'a VirtualPlc,
    /// The gateway's register map.
    pub map: &'a RegisterMap,
}

impl Plc<'_> {
    /// The address of register `name` (`F1.taf`).
    pub fn at(&self, name: &str) -> usize {
        let register = self.map.registers().iter().find(|r| r.name == name);
        usize::from(
            register
                .unwrap_or_else(|| panic!("no register {name}"))
                .address,
        )
    }

    /// F1's bite counter (0 before the first write).
    pub fn counter(&self) -> u32 {
        let words = self.plc.holding();
        decode_u32(&words[self.at("F1.bite_counter")..]).unwrap_or(0)
    }

    /// F1's flags word.
    pub fn flags(&self) -> u16 {
        self.plc.holding()[self.at("F1.flags")]
    }

    /// F1's torque amplification factor.
    pub fn taf(&self) -> f32 {
        self.f32_of("F1.taf")
    }

    /// The f32 register `name` as the PLC holds it.
    pub fn f32_of(&self, name: &str) -> f32 {
        decode_f32(&self.plc.holding()[self.at(name)..]).unwrap_or(f32::NAN)
    }

    /// Wait until the PLC shows `more` bites beyond what it shows now.
    pub async fn bites_after_now(&self, more: u32) {
        let now = self.counter();
        wait_for("bites in the PLC", Duration::from_secs(40), || {
            self.counter() >= now + more
        })
        .await;
    }
}

/// Prints a [`Setup`]'s log when dropped by a failing test ([`Setup::log_on_failure`]).
#[derive(Debug)]
pub struct LogOnFailure<'a> {
    setup: &'a Setup,
    name: &'a str,
}

impl Drop for LogOnFailure<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!(
                "--- {} of the failed test:\n{}",
                self.name,
                self.setup.log_text(self.name)
            );
        }
    }
}

/// A scratch folder, the demo's devices and the configuration of a `millgate run`
/// that keeps its history at `history`; the folder is removed when dropped.
#[derive(Debug)]
pub struct Setup {
    /// The scratch folder (configuration, logs, history).
    pub scratch: PathBuf,
    /// The history file.
    pub history: PathBuf,
    /// The configuration file.
    pub config: PathBuf,
    /// The demo's virtual DAQ and PLC.
    pub devices: DemoDevices,
    /// The configuration's register map.
    pub map: RegisterMap,
    /// The HMI server's port.
    pub server_port: u16,
    /// The `/metrics` port.
    pub metrics_port: u16,
    millgate: Millgate,
    _folder: TempDir,
}

impl Setup {
    /// The demo's configuration with the driveline model (wear index and trend), TAF
    /// thresholds every demo bite passes (the alarm latches at the first bite), the
    /// `/metrics` endpoint and the history at `folder/history.db` (`folder` relative to
    /// the scratch folder), for `millgate`. The virtual DAQ plays its 60 s of bars
    /// from the gateway's first read.
    pub async fn new(millgate: Millgate, tag: &str, folder: &str) -> Self {
        Self::with_daq(millgate, tag, folder, |config, schedule| {
            millgate_sim::devices::demo::demo_daq(config, schedule).unwrap()
        })
        .await
    }

    /// As [`Self::new`], with the virtual DAQ `daq` makes from the demo's
    /// configuration and schedule (a DAQ serving more channels than the torque).
    pub async fn with_daq(
        millgate: Millgate,
        tag: &str,
        folder: &str,
        daq: impl FnOnce(&Config, &Schedule) -> VirtualDaq,
    ) -> Self {
        let guard = scratch(tag);
        let scratch = guard.path().to_path_buf();
        std::fs::create_dir_all(scratch.join(folder)).unwrap();
        let history = scratch.join(folder).join("history.db");
        let demo = setup(60.0, 0.5, 5).unwrap();
        let mut config = demo.config;
        let map = RegisterMap::new(&config);
        // Its 60 s of bars from the gateway's first read on: a test that starts a
        // slow peer first (a RabbitMQ cluster on a loaded machine) would otherwise
        // start the gateway after the last bar (CI: "bites in the PLC: not within 40s").
        let daq = daq(&config, &demo.schedule).playing_from_first_read();
        let devices = DemoDevices::start_with(&mut config, daq, usize::from(map.len()) + 16)
            .await
            .unwrap();
        let (server_port, metrics_port) = (free_port(), free_port());
        // The demo's monitoring model (linear; the simulated mill opens a gap).
        let model = super::repo().join("sim/models/table2-adjusted.toml");
        let text = std::fs::read_to_string(super::repo().join("config/examples/demo.toml"))
            .unwrap()
            .replace("127.0.0.1:5020", &config.modbus_sources[0].address)
            .replace(
                "127.0.0.1:5502",
                &config.outputs.plc.as_ref().unwrap().address,
            )
            .replace("127.0.0.1:5503", &format!("127.0.0.1:{server_port}"))
            .replace(
                "model = \"table2-adjusted.toml\"",
                &format!("model = \"{}\"", model.display()),
            )
            .replace(
                "thresholds = { taf_warning = 2.2, taf_alarm = 2.6,",
                "thresholds = { taf_warning = 1.1, taf_alarm = 1.15,",
            )
            + &format!(
                "\n[outputs.metrics]\nbind = \"127.0.0.1:{metrics_port}\"\n\
                 \n[history]\npath = \"{}\"\n",
                history.display()
            );
        assert!(
            text.contains(&model.display().to_string()) && text.contains("taf_alarm = 1.15,"),
            "config/examples/demo.toml changed: the test's edits no longer apply"
        );
        let config = scratch.join("mill.toml");
        std::fs::write(&config, text).unwrap();
        Self {
            scratch,
            history,
            config,
            devices,
            map,
            server_port,
            metrics_port,
            millgate,
            _folder: guard,
        }
    }

    /// Append `text` to the configuration file.
    pub fn append_config(&self, text: &str) {
        let mut config = std::fs::read_to_string(&self.config).unwrap();
        config.push_str(text);
        std::fs::write(&self.config, config).unwrap();
    }

    /// Append driveline `name` to `[[drivelines]]` (before `[outputs.plc]`), on the
    /// torque channel the demo reads for F1 and without a `model`: one a reload can
    /// add live within `outputs.driveline_slots`. The file as written.
    pub fn add_driveline(&self, name: &str) -> String {
        let original = std::fs::read_to_string(&self.config).unwrap();
        let driveline = format!(
            "[[drivelines]]\nname = \"{name}\"\ntorque = \"spindle_top\"\n\
             bite = {{ threshold_knm = 20.0, pre_trigger_s = 0.1, post_trigger_s = 0.5 }}\n\
             thresholds = {{ taf_warning = 2.2, taf_alarm = 2.6 }}\n\n[outputs.plc]"
        );
        let added = original.replacen("[outputs.plc]", &driveline, 1);
        assert_ne!(
            added,
            original,
            "no [outputs.plc] in {}",
            self.config.display()
        );
        std::fs::write(&self.config, &added).unwrap();
        added
    }

    /// The driveline registers the virtual PLC holds.
    pub fn plc(&self) -> Plc<'_> {
        Plc {
            plc: &self.devices.plc,
            map: &self.map,
        }
    }

    /// The file `name` in the scratch folder (a log).
    pub fn log(&self, name: &str) -> PathBuf {
        self.scratch.join(name)
    }

    /// The text of the log `name` written so far.
    pub fn log_text(&self, name: &str) -> String {
        std::fs::read_to_string(self.log(name)).unwrap_or_default()
    }

    /// A guard that prints the log `name` when it is dropped by a failing test (the
    /// scratch folder that holds it goes with the test): what the service said about
    /// an event the test waited for in vain.
    pub fn log_on_failure<'a>(&'a self, name: &'a str) -> LogOnFailure<'a> {
        LogOnFailure { setup: self, name }
    }

    /// `millgate run` on the configuration, its log in the scratch folder.
    pub fn spawn(&self, log: &str) -> KillOnDrop {
        self.spawn_in_namespace(log, None)
    }

    /// `millgate run` in its own user and mount namespace where a tmpfs with `options`
    /// is mounted on the history's folder, or directly for `None`.
    pub fn spawn_in_namespace(&self, log: &str, tmpfs: Option<&str>) -> KillOnDrop {
        let command = match tmpfs {
            Some(options) => {
                let mut command = Command::new("unshare");
                command.args([
                    "-rm",
                    "sh",
                    "-c",
                    "mount -t tmpfs -o \"$1\" tmpfs \"$2\" && shift 2 && exec \"$@\"",
                    "sh",
                    options,
                    self.history.parent().unwrap().to_str().unwrap(),
                    self.millgate.0,
                ]);
                command
            }
            None => self.millgate.command(),
        };
        self.spawn_command(command, log)
    }

    /// `command` (the `millgate` binary, or a program that runs it: `unshare`,
    /// `nsenter`) given `run --config` on the configuration, its log in the scratch
    /// folder.
    pub fn spawn_command(&self, command: Command, log: &str) -> KillOnDrop {
        self.spawn_with(command, log, &[])
    }

    /// As [`Self::spawn_command`], with `more` arguments of `run` (`--pid-file`).
    pub fn spawn_with(&self, mut command: Command, log: &str, more: &[&str]) -> KillOnDrop {
        let log = std::fs::File::create(self.log(log)).unwrap();
        command
            .args(["run", "--config", self.config.to_str().unwrap()])
            .args(more)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .map(KillOnDrop)
            .expect("start millgate run")
    }

    /// The `/metrics` page.
    pub async fn metrics(&self) -> String {
        http(self.metrics_port, "GET", "/metrics").await.body
    }

    /// The value of the metric line starting with `name` (with its labels).
    pub async fn metric(&self, name: &str) -> Option<f64> {
        metric_line(&self.metrics().await, name)
    }

    /// Wait until `/metrics` shows `name` at `value`, at most `limit`; a `/metrics`
    /// not answering yet (the service starting) is waited for too.
    pub async fn until_metric(&self, name: &str, value: f64, limit: Duration) {
        let start = std::time::Instant::now();
        loop {
            let now = try_http(self.metrics_port, "GET", "/metrics")
                .await
                .map(|answer| metric_line(&answer.body, name));
            if matches!(now, Ok(Some(now)) if now == value) {
                return;
            }
            assert!(
                start.elapsed() < limit,
                "{name} {now:?}, not {value} within {limit:?}"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// Stop the devices; the scratch folder goes with `self` (the gateway stopped
    /// already, or its guard kills it).
    pub async fn finish(self) {
        self.devices.stop().await.unwrap();
    }

    /// Kill `service`, then [`Self::finish`].
    pub async fn stop(self, service: KillOnDrop) {
        drop(service);
        self.finish().await;
    }
}

//! What the service tests share: the demo's virtual DAQ and PLC, a configuration for
//! `millgate run` between them, the PLC's driveline registers, `/metrics`.
// Each test crate uses a part of it.
#![allow(dead_code)]

pub(crate) mod episode;

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use millgate::outputs::modbus::register_map::{decode_f32, decode_u32, RegisterMap};
use millgate_sim::devices::demo::{setup, DemoDevices};
use millgate_sim::devices::virtual_plc::VirtualPlc;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

// The support shared with the end-to-end crate: one file, included by both (`pub`
// there, where it is the crate's API).
#[path = "../../../tests/src/net.rs"]
#[allow(unreachable_pub)]
mod net;
pub(crate) use net::{until, HttpAnswer};

/// `millgate args`, run to its end (no standard input).
pub(crate) fn millgate(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_millgate"))
        .args(args)
        .stdin(Stdio::null())
        .output()
        .expect("run millgate")
}

/// What a run printed: its standard output, then its standard error.
pub(crate) fn text(output: &std::process::Output) -> String {
    String::from_utf8_lossy(&output.stdout).to_string() + &String::from_utf8_lossy(&output.stderr)
}

/// `millgate capture export` of F1's bite `bite` from `db` to `out` as `format`: the
/// file written (checked to exist).
pub(crate) fn export_bite(
    db: &std::path::Path,
    out: &std::path::Path,
    bite: u32,
    format: &str,
) -> String {
    let bite = bite.to_string();
    let output = millgate(&[
        "capture",
        "export",
        "--db",
        db.to_str().unwrap(),
        "--driveline",
        "F1",
        "--bite",
        &bite,
        "--format",
        format,
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(output.status.success(), "{}", text(&output));
    let path = String::from_utf8_lossy(&output.stdout).trim().to_owned();
    assert!(std::path::Path::new(&path).is_file(), "{path}");
    path
}

/// A small seeded generator for test cases (xorshift64*).
pub(crate) struct Seeded(pub(crate) u64);

impl Seeded {
    /// The next draw, uniform in [low, high).
    pub(crate) fn uniform(&mut self, low: f64, high: f64) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let unit = (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64;
        low + (high - low) * unit
    }
}

pub(crate) fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Registers of the driveline block read from the virtual PLC.
pub(crate) struct Plc<'a> {
    pub(crate) plc: &'a VirtualPlc,
    pub(crate) map: &'a RegisterMap,
}

impl Plc<'_> {
    pub(crate) fn at(&self, name: &str) -> usize {
        let register = self.map.registers().iter().find(|r| r.name == name);
        usize::from(
            register
                .unwrap_or_else(|| panic!("no register {name}"))
                .address,
        )
    }

    pub(crate) fn counter(&self) -> u32 {
        let words = self.plc.holding();
        decode_u32(&words[self.at("F1.bite_counter")..]).unwrap_or(0)
    }

    pub(crate) fn flags(&self) -> u16 {
        self.plc.holding()[self.at("F1.flags")]
    }

    pub(crate) fn taf(&self) -> f32 {
        self.f32_of("F1.taf")
    }

    /// The f32 register `name` as the PLC holds it.
    pub(crate) fn f32_of(&self, name: &str) -> f32 {
        decode_f32(&self.plc.holding()[self.at(name)..]).unwrap_or(f32::NAN)
    }

    /// Wait until the PLC shows `more` bites beyond what it shows now.
    pub(crate) async fn bites_after_now(&self, more: u32) {
        let now = self.counter();
        until("bites in the PLC", Duration::from_secs(40), || {
            self.counter() >= now + more
        })
        .await;
    }
}

/// A Python peer (a client or host that is not ours) run as `python3 script args`:
/// the child, its stdin for commands and its stdout's JSON lines, read on a thread.
pub(crate) fn json_peer(
    script: &str,
    args: &[&str],
) -> (
    Child,
    std::process::ChildStdin,
    std::sync::mpsc::Receiver<serde_json::Value>,
) {
    use std::io::BufRead;
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests")
        .join(script);
    let mut child = Command::new("python3")
        .arg(script)
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("python3");
    let stdin = child.stdin.take().unwrap();
    let stdout = child.stdout.take().unwrap();
    let (tx, lines) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stdout).lines() {
            let Ok(line) = line else { break };
            let value: serde_json::Value =
                serde_json::from_str(&line).unwrap_or_else(|e| panic!("peer line {line:?}: {e}"));
            if tx.send(value).is_err() {
                break;
            }
        }
    });
    (child, stdin, lines)
}

/// A free loopback port, never the same one twice in this process, and below the
/// kernel's ephemeral range (32768..): a port a test frees for a while (a broker
/// restarted on it) is not handed to another test's listener meanwhile, as the
/// kernel's `:0` can do.
pub(crate) fn free_port() -> u16 {
    use std::sync::atomic::{AtomicU16, Ordering};
    const PER_PROCESS: u16 = 60;
    static NEXT: AtomicU16 = AtomicU16::new(0);
    let base = 20_000 + u16::try_from(std::process::id() % 200).unwrap() * PER_PROCESS;
    loop {
        let port = base + NEXT.fetch_add(1, Ordering::Relaxed) % PER_PROCESS;
        if std::net::TcpListener::bind(("127.0.0.1", port)).is_ok() {
            return port;
        }
    }
}

/// A scratch folder, the demo's devices and the configuration of a service that keeps
/// its history at `history`.
pub(crate) struct Setup {
    pub(crate) scratch: PathBuf,
    pub(crate) history: PathBuf,
    pub(crate) config: PathBuf,
    pub(crate) devices: DemoDevices,
    pub(crate) map: RegisterMap,
    pub(crate) server_port: u16,
    pub(crate) metrics_port: u16,
}

impl Setup {
    /// The demo's configuration with the driveline model (wear index and trend), TAF
    /// thresholds every demo bite passes (the alarm latches at the first bite), the
    /// `/metrics` endpoint and the history at `folder/history.db` (`folder` relative to
    /// the scratch folder).
    pub(crate) async fn new(tag: &str, folder: &str) -> Self {
        Self::with_daq(tag, folder, |config, schedule| {
            millgate_sim::devices::demo::demo_daq(config, schedule).unwrap()
        })
        .await
    }

    /// As [`Self::new`], with the virtual DAQ `daq` makes from the demo's
    /// configuration and schedule (a DAQ serving more channels than the torque).
    pub(crate) async fn with_daq(
        tag: &str,
        folder: &str,
        daq: impl FnOnce(
            &millgate_config::Config,
            &millgate_sim::schedule::Schedule,
        ) -> millgate_sim::devices::virtual_daq::VirtualDaq,
    ) -> Self {
        let scratch =
            std::env::temp_dir().join(format!("millgate-history-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&scratch);
        std::fs::create_dir_all(scratch.join(folder)).unwrap();
        let history = scratch.join(folder).join("history.db");
        let demo = setup(60.0, 0.5, 5).unwrap();
        let mut config = demo.config;
        let map = RegisterMap::new(&config);
        let daq = daq(&config, &demo.schedule);
        let devices = DemoDevices::start_with(&mut config, daq, usize::from(map.len()) + 16)
            .await
            .unwrap();
        let (server_port, metrics_port) = (free_port(), free_port());
        // The demo's monitoring model (linear; the simulated mill opens a gap).
        let model = repo().join("sim/models/table2-adjusted.toml");
        let text = std::fs::read_to_string(repo().join("config/examples/demo.toml"))
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
        }
    }

    /// Append `text` to the configuration file.
    pub(crate) fn append_config(&self, text: &str) {
        let mut config = std::fs::read_to_string(&self.config).unwrap();
        config.push_str(text);
        std::fs::write(&self.config, config).unwrap();
    }

    pub(crate) fn plc(&self) -> Plc<'_> {
        Plc {
            plc: &self.devices.plc,
            map: &self.map,
        }
    }

    pub(crate) fn log(&self, name: &str) -> PathBuf {
        self.scratch.join(name)
    }

    /// `millgate run` on the configuration, its log in the scratch folder.
    pub(crate) fn spawn(&self, log: &str) -> KillOnDrop {
        self.spawn_in_namespace(log, None)
    }

    /// `millgate run` in its own user and mount namespace where a tmpfs with `options`
    /// is mounted on the history's folder, or directly for `None`.
    pub(crate) fn spawn_in_namespace(&self, log: &str, tmpfs: Option<&str>) -> KillOnDrop {
        let log = std::fs::File::create(self.log(log)).unwrap();
        let millgate = env!("CARGO_BIN_EXE_millgate");
        let config = self.config.to_str().unwrap();
        let mut command = match tmpfs {
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
                    millgate,
                ]);
                command
            }
            None => Command::new(millgate),
        };
        command
            .args(["run", "--config", config])
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .map(KillOnDrop)
            .expect("start millgate run")
    }

    /// The `/metrics` page.
    pub(crate) async fn metrics(&self) -> String {
        http(self.metrics_port, "GET", "/metrics").await.body
    }

    /// The value of the metric line starting with `name` (with its labels).
    pub(crate) async fn metric(&self, name: &str) -> Option<f64> {
        let page = self.metrics().await;
        page.lines()
            .find_map(|line| line.strip_prefix(name)?.strip_prefix(' ')?.parse().ok())
    }

    /// Stop the devices and remove the scratch folder (the gateway stopped already,
    /// or its guard kills it).
    pub(crate) async fn finish(self) {
        self.devices.stop().await.unwrap();
        let _ = std::fs::remove_dir_all(&self.scratch);
    }

    pub(crate) async fn stop(self, service: KillOnDrop) {
        drop(service);
        self.devices.stop().await.unwrap();
        let _ = std::fs::remove_dir_all(&self.scratch);
    }
}

/// A `millgate run` child killed and reaped when dropped, so a failing test leaves
/// no gateway behind; derefs to the [`Child`].
pub(crate) struct KillOnDrop(pub(crate) Child);

impl std::ops::Deref for KillOnDrop {
    type Target = Child;
    fn deref(&self) -> &Child {
        &self.0
    }
}

impl std::ops::DerefMut for KillOnDrop {
    fn deref_mut(&mut self) -> &mut Child {
        &mut self.0
    }
}

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Terminate `service` as systemd would, and check it stopped cleanly.
pub(crate) fn terminate(service: &mut Child) {
    let term = Command::new("kill")
        .args(["-TERM", &service.id().to_string()])
        .status()
        .unwrap();
    assert!(term.success());
    let status = service.wait().unwrap();
    assert!(status.success(), "{status:?}");
}

/// `raw` (a whole HTTP/1.1 request) to `127.0.0.1:port`: [`net::http_raw`].
pub(crate) async fn http_raw(port: u16, raw: &[u8]) -> HttpAnswer {
    net::http_raw(([127, 0, 0, 1], port).into(), raw).await
}

/// `method path` on `127.0.0.1:port`: [`net::http`].
pub(crate) async fn http(port: u16, method: &str, path: &str) -> HttpAnswer {
    net::http(([127, 0, 0, 1], port).into(), method, path).await
}

/// Wait until the web page on `port` answers (the service is up), at most 30 s.
pub(crate) async fn web_ready(port: u16) {
    let start = Instant::now();
    loop {
        if let Ok(Ok(mut stream)) = tokio::time::timeout(
            Duration::from_secs(1),
            tokio::net::TcpStream::connect(("127.0.0.1", port)),
        )
        .await
        {
            let request =
                b"GET /api/drivelines HTTP/1.1\r\nhost: localhost\r\nconnection: close\r\n\r\n";
            let mut answer = Vec::new();
            if stream.write_all(request).await.is_ok()
                && stream.read_to_end(&mut answer).await.is_ok()
                && answer.starts_with(b"HTTP/1.1 200")
            {
                return;
            }
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "web page not up within 30 s"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

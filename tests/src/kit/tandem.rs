//! The simulated tandem mill as the chatter tests use it: the reference ramp through
//! the critical speed ([`reference_ramp`]) and the configuration of N stand
//! accelerometers with a tandem mill over them ([`Stands`]).

use millgate_config::RegisterTable;
use millgate_sim::devices::modbus_bank::{Running, ServeOptions};
use millgate_sim::devices::virtual_daq::{DaqChannel, Placement, Publish, VirtualDaq};
use millgate_sim::devices::virtual_plc::VirtualPlc;
use millgate_sim::tandem::roots::CriticalSpeed;
use millgate_sim::tandem::simulate::{simulate, RunSettings};
use millgate_sim::tandem::truth::{ground_truth, mill_critical_speed, GroundTruth};
use millgate_sim::tandem::{PassSchedule, TandemMill};
use tokio::net::TcpListener;

/// The stand accelerometers' sample rate, Hz.
pub const FS: f64 = 2500.0;
/// The band-gain thresholds the race set on the five stands of
/// [`PassSchedule::example`] (`config/examples/tandem-5stand.toml`).
pub const GAIN_THRESHOLDS: [f64; 5] = [1.187, 1.492, 2.209, 3.087, 3.327];
/// The example configuration's `k_max`.
pub const K_MAX: f64 = 0.25;

/// A run of the five-stand mill of [`PassSchedule::example`]: the stands' chock
/// acceleration (m/s^2, at [`FS`]), the mill's critical speed and the run's truth.
#[derive(Debug)]
pub struct RampRun {
    /// Per stand, the chock acceleration, m/s^2.
    pub acceleration: Vec<Vec<f64>>,
    /// The mill's critical speed.
    pub critical: CriticalSpeed,
    /// When chatter set on and developed.
    pub truth: GroundTruth,
}

/// The reference ramp: `duration_s` of the example mill rolling `hold_s` at `start`
/// times its critical speed, then its exit speed ramped at 2 m/s^2 to 1.5 times it;
/// the default excitation and accelerometer at [`FS`], noise seeded with `seed`.
pub fn reference_ramp(
    start: f64,
    hold_s: f64,
    duration_s: f64,
    seed: u64,
) -> anyhow::Result<RampRun> {
    let mill = TandemMill::new(&PassSchedule::example()?)?;
    let critical = mill_critical_speed(&mill)?;
    let settings = RunSettings::reference_ramp(critical.speed, start, hold_s, duration_s, FS, seed);
    let record = simulate(&mill, &settings)?;
    let truth = ground_truth(&mill, &settings.ramp, &record, critical);
    Ok(RampRun {
        acceleration: record.acceleration,
        critical,
        truth,
    })
}

/// Where the stands' samples come from.
#[derive(Debug, Clone)]
enum Wiring {
    /// Stand `i` on the Modbus source `daqs[i]`, its block at input register `122 i`,
    /// 0.01 m/s^2 a count.
    Modbus(Vec<String>),
    /// Stand `i` as signal `S{i+1}Vib` of the CAN source's message (scaled by its DBC).
    Can { source: String, message: String },
}

/// N stand accelerometers `s1_vib`..`sN_vib` (acceleration, m/s^2, [`FS`]) and one
/// tandem mill over them (`TCM`, band 100-300 Hz, 0.5 s windows; unless [`Self::bare`],
/// `k_max` 0.25 and the reference band-gain thresholds of the last N stands): the
/// configuration's `[[channels]]` and `[[tandem_mills]]` entries ([`Self::toml`]), the
/// sources declared elsewhere.
#[derive(Debug, Clone)]
pub struct Stands {
    wiring: Wiring,
    count: usize,
    mill: String,
    /// `k_max` and `gain_thresholds`, unless bare.
    detector: Option<(f64, Vec<f64>)>,
    keys: String,
}

impl Stands {
    /// `count` stands (1..=5) on the Modbus source `daq`.
    pub fn modbus(count: usize, daq: &str) -> Self {
        Self::on_daqs(&vec![daq; count])
    }

    /// One stand on each of the Modbus sources `daqs` (in stand order; a source may
    /// serve several stands).
    pub fn on_daqs(daqs: &[&str]) -> Self {
        Self::new(
            Wiring::Modbus(daqs.iter().map(|daq| (*daq).to_owned()).collect()),
            daqs.len(),
        )
    }

    /// `count` stands as signals `S1Vib`.. of `message` on the CAN source `source`.
    pub fn can(count: usize, source: &str, message: &str) -> Self {
        let wiring = Wiring::Can {
            source: source.to_owned(),
            message: message.to_owned(),
        };
        Self::new(wiring, count)
    }

    fn new(wiring: Wiring, count: usize) -> Self {
        let detector = GAIN_THRESHOLDS
            .len()
            .checked_sub(count)
            .map(|first| (K_MAX, GAIN_THRESHOLDS[first..].to_vec()));
        Self {
            wiring,
            count,
            mill: "TCM".to_owned(),
            detector,
            keys: String::new(),
        }
    }

    /// The stand count.
    pub fn count(&self) -> usize {
        self.count
    }

    /// The stands' channel names, `s1_vib`..
    pub fn names(&self) -> Vec<String> {
        (1..=self.count()).map(|s| format!("s{s}_vib")).collect()
    }

    /// The mill's name (`TCM` unless set).
    pub fn mill(mut self, name: &str) -> Self {
        name.clone_into(&mut self.mill);
        self
    }

    /// The mill's band-gain thresholds, one per stand (`k_max` 0.25).
    pub fn thresholds(mut self, thresholds: &[f64]) -> Self {
        assert_eq!(thresholds.len(), self.count(), "one threshold per stand");
        self.detector = Some((K_MAX, thresholds.to_vec()));
        self
    }

    /// Without `k_max` and `gain_thresholds`: [`Self::keys`] gives the detector's.
    pub fn bare(mut self) -> Self {
        self.detector = None;
        self
    }

    /// More keys of the mill's `[[tandem_mills]]` entry (`slow_down_release = 1.05`).
    pub fn keys(mut self, keys: &str) -> Self {
        self.keys.push_str(keys.trim_end());
        self.keys.push('\n');
        self
    }

    /// The `[[channels]]` of the stands, then the mill's `[[tandem_mills]]` entry.
    pub fn toml(&self) -> String {
        let mut text = String::new();
        for (stand, name) in self.names().iter().enumerate() {
            let source = match &self.wiring {
                Wiring::Modbus(daqs) => format!(
                    "scale = 0.01\nsource = {{ modbus = \"{}\", table = \"input\", block = {} }}",
                    daqs[stand],
                    stand * 122
                ),
                Wiring::Can { source, message } => format!(
                    "source = {{ can = \"{source}\", message = \"{message}\", signal = \"S{}Vib\" }}",
                    stand + 1
                ),
            };
            text += &format!(
                "[[channels]]\nname = \"{name}\"\nkind = \"acceleration\"\nunit = \"m/s^2\"\n\
                 sample_rate_hz = {FS}\n{source}\n\n"
            );
        }
        let list = |items: Vec<String>| items.join(", ");
        let quoted = self.names().iter().map(|n| format!("\"{n}\"")).collect();
        let detector = self
            .detector
            .as_ref()
            .map_or(String::new(), |(k_max, thresholds)| {
                let thresholds = thresholds.iter().map(|t| format!("{t:?}")).collect();
                format!(
                    "k_max = {k_max}\ngain_thresholds = [{}]\n",
                    list(thresholds)
                )
            });
        text + &format!(
            "[[tandem_mills]]\nname = \"{}\"\nstands = [{}]\n\
             chatter_band_hz = [100.0, 300.0]\nwindow_s = 0.5\n{detector}{}\n",
            self.mill,
            list(quoted),
            self.keys
        )
    }
}

/// The virtual DAQ channels of the stands in `stands` (indices into `signals`, one
/// per stand of [`Stands::modbus`]): each stand's block at input register `122 i`,
/// 0.01 m/s^2 a count.
pub fn stand_daq_channels(signals: &[Vec<f64>], stands: &[usize]) -> Vec<DaqChannel> {
    stands
        .iter()
        .map(|&stand| DaqChannel {
            placement: Placement {
                table: RegisterTable::Input,
                address: (stand * 122) as u16,
                scale: 0.01,
                offset: 0.0,
            },
            publish: Publish::Block,
            signal: signals[stand].clone(),
        })
        .collect()
}

/// A Modbus TCP source `name` (to be pointed at its device), polled every 20 ms.
pub fn modbus_source(name: &str) -> String {
    format!(
        "[[sources.modbus]]\nname = \"{name}\"\naddress = \"127.0.0.1:1\"\npoll_period_ms = 20\n\n"
    )
}

/// The configuration's text (before its outputs) of a five-stand mill named `name`
/// read from the Modbus source `daq`, whose product code comes from the PLC source
/// `process_plc` (polled every 100 ms; channel `product_code`, holding register 0):
/// products 7 and 8, product 7 in the group `tight` with [`tight_thresholds`].
pub fn product_groups_toml(name: &str) -> String {
    let tight: Vec<String> = tight_thresholds()
        .iter()
        .map(|t| format!("{t:?}"))
        .collect();
    format!("name = \"{name}\"\n")
        + &modbus_source("daq")
        + "[[sources.modbus]]\nname = \"process_plc\"\naddress = \"127.0.0.1:1\"\n\
           poll_period_ms = 100\ntimeout_ms = 500\n\n\
           [[channels]]\nname = \"product_code\"\nkind = \"process_value\"\nunit = \"1\"\n\
           source = { modbus = \"process_plc\", table = \"holding\", address = 0 }\n\n"
        + &Stands::modbus(5, "daq")
            .keys(&format!(
                "context = {{ product = \"product_code\", products = [7, 8] }}\n\
                 [[tandem_mills.product_groups]]\nname = \"tight\"\nproducts = [7]\n\
                 gain_thresholds = [{}]\n",
                tight.join(", ")
            ))
            .toml()
}

/// The group `tight`'s thresholds in [`product_groups_toml`]: a quarter of
/// [`GAIN_THRESHOLDS`].
pub fn tight_thresholds() -> Vec<f64> {
    GAIN_THRESHOLDS.iter().map(|t| t / 4.0).collect()
}

/// Waits until the first tandem mill's JSON on the page at `web` satisfies `done`,
/// at most `limit` (then an error naming `what` with the last JSON); returns it.
pub async fn until_tandem_mill(
    web: std::net::SocketAddr,
    limit: std::time::Duration,
    what: &str,
    done: impl Fn(&serde_json::Value) -> bool,
) -> anyhow::Result<serde_json::Value> {
    let start = std::time::Instant::now();
    loop {
        let mill = super::web_overview(web).await?["tandem_mills"][0].clone();
        if done(&mill) {
            return Ok(mill);
        }
        anyhow::ensure!(start.elapsed() < limit, "{what}: {mill}");
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
}

/// The virtual DAQ of the five stands' accelerometers ([`stand_daq_channels`], blocks
/// of 120 samples at [`FS`]) playing 20 s of stable rolling at 90% of the critical
/// speed ([`reference_ramp`], seed 21) again and again.
pub fn stable_rolling_daq() -> anyhow::Result<VirtualDaq> {
    let run = reference_ramp(0.9, 60.0, 20.0, 21)?;
    Ok(VirtualDaq::new(
        FS,
        120,
        stand_daq_channels(&run.acceleration, &[0, 1, 2, 3, 4]),
    )
    .looped())
}

/// `daq` and `plc` served on loopback ports, `config`'s first and second Modbus
/// sources pointed at them; their running servers (stop them at the test's end).
pub async fn serve_daq_and_plc(
    config: &mut millgate_config::Config,
    daq: VirtualDaq,
    plc: &VirtualPlc,
) -> std::io::Result<(Running, Running)> {
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    config.modbus_sources[0].address = listener.local_addr()?.to_string();
    let daq = daq.spawn(listener, ServeOptions::default());
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    config.modbus_sources[1].address = listener.local_addr()?.to_string();
    Ok((daq, plc.spawn(listener, ServeOptions::default())))
}

/// The value of `family{tandem_mill="TCM"}` on a `/metrics` page.
pub fn tcm_metric(page: &str, family: &str) -> Option<f64> {
    let prefix = format!("{family}{{tandem_mill=\"TCM\"}} ");
    page.lines()
        .find_map(|line| line.strip_prefix(&prefix))
        .and_then(|value| value.trim().parse().ok())
}

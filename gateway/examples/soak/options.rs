//! The command line: the options with their defaults, and the load points they step
//! through.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{bail, Context as _};

/// The largest bite -> PLC p99 a load point passes with by default, ms.
const P99_LIMIT_MS: f64 = 5.0;

/// What `--help` prints.
const USAGE: &str = "\
Load bench and soak: `millgate run` watching N drivelines (2 kHz) and M tandem-mill
stands streamed by virtual DAQs; prints each load point's samples and a summary row.

usage: soak [options]

  --duration S                 seconds per load point (600)
  --every S                    seconds between samples (10), and one at the warm-up's end
  --warm-up S                  seconds not counted (15)
  --drivelines N[,N...]        drivelines per load point (1)
  --tandem-stands M[,M...]     tandem-mill stands per load point (0)
  --tandem-rate-hz HZ          the stands' sample rate: 2500 or 10000 (2500)
  --cpu K                      pin the gateway to core K (not pinned)
  --p99-limit-ms MS            bite -> PLC p99 a point passes with (5)
  --keep-going                 step on after a failed point
  --millgate PATH              the gateway binary (the one beside this example's folder)
  --analysis-workers N         the gateway's [analysis] workers (its default)
  --plc-requests-in-flight N   the PLC output's requests_in_flight (its default, 1)
  --daq-requests-in-flight N   the DAQ sources' requests_in_flight (their default, 1)
  --help, -h                   this text

Lists are stepped together; a single value is held.
";

/// The command line's options (their defaults: the module docs of `main.rs`).
pub(crate) struct Options {
    pub(crate) duration: Duration,
    pub(crate) every: Duration,
    pub(crate) warm_up: Duration,
    pub(crate) drivelines: Vec<usize>,
    pub(crate) tandem_stands: Vec<usize>,
    pub(crate) tandem_rate_hz: f64,
    pub(crate) cpu: Option<String>,
    pub(crate) p99_limit_ms: f64,
    pub(crate) keep_going: bool,
    pub(crate) millgate: PathBuf,
    /// The gateway's `[analysis] workers` (left out: its default, one per core).
    pub(crate) analysis_workers: Option<u32>,
    /// The PLC output's `requests_in_flight` (left out: its default, 1).
    pub(crate) plc_requests_in_flight: Option<u32>,
    /// The DAQ sources' `requests_in_flight` (left out: their default, 1).
    pub(crate) daq_requests_in_flight: Option<u32>,
}

impl Options {
    /// The options of this process's command line, checked.
    pub(crate) fn from_args() -> anyhow::Result<Options> {
        let mut options = Options {
            duration: Duration::from_secs(600),
            every: Duration::from_secs(10),
            warm_up: Duration::from_secs(15),
            drivelines: vec![1],
            tandem_stands: vec![0],
            tandem_rate_hz: 2500.0,
            cpu: None,
            p99_limit_ms: P99_LIMIT_MS,
            keep_going: false,
            analysis_workers: None,
            plc_requests_in_flight: None,
            daq_requests_in_flight: None,
            millgate: std::env::current_exe()?
                .parent()
                .and_then(Path::parent)
                .map(|dir| dir.join("millgate"))
                .context("no folder above the example")?,
        };
        let mut args = std::env::args().skip(1);
        while let Some(arg) = args.next() {
            if arg == "--keep-going" {
                options.keep_going = true;
                continue;
            }
            if arg == "--help" || arg == "-h" {
                print!("{USAGE}");
                std::process::exit(0);
            }
            let value = args
                .next()
                .with_context(|| format!("{arg} needs a value"))?;
            options.set(&arg, value)?;
        }
        if !options.millgate.is_file() {
            bail!(
                "{}: no millgate binary (build it: cargo build --release -p millgate \
                 --bin millgate)",
                options.millgate.display()
            );
        }
        if options.warm_up >= options.duration {
            bail!("--warm-up must be shorter than --duration");
        }
        Ok(options)
    }

    /// Sets option `arg` (one that takes a value) to `value`, checked.
    fn set(&mut self, arg: &str, value: String) -> anyhow::Result<()> {
        let seconds = |least: f64| -> anyhow::Result<Duration> {
            let s: f64 = value
                .parse()
                .with_context(|| format!("{arg}: {value:?} is not a number of seconds"))?;
            if !(s.is_finite() && s >= least) {
                bail!("{arg}: {value} is not allowed (must be >= {least} s)");
            }
            Ok(Duration::from_secs_f64(s))
        };
        let counts = || -> anyhow::Result<Vec<usize>> {
            value
                .split(',')
                .map(|count| {
                    count.trim().parse().with_context(|| {
                        format!("{arg}: {count:?} is not a count (a list like 4,8,16)")
                    })
                })
                .collect()
        };
        match arg {
            "--duration" => self.duration = seconds(1.0)?,
            "--every" => self.every = seconds(1.0)?,
            "--warm-up" => self.warm_up = seconds(0.0)?,
            "--drivelines" => self.drivelines = counts()?,
            "--tandem-stands" => self.tandem_stands = counts()?,
            "--tandem-rate-hz" => {
                self.tandem_rate_hz = match value.as_str() {
                    "2500" => 2500.0,
                    "10000" => 10000.0,
                    _ => bail!("--tandem-rate-hz: {value} is not allowed (2500 or 10000)"),
                }
            }
            "--cpu" => self.cpu = Some(value),
            "--p99-limit-ms" => {
                self.p99_limit_ms = value
                    .parse()
                    .ok()
                    .filter(|ms: &f64| ms.is_finite() && *ms > 0.0)
                    .with_context(|| format!("--p99-limit-ms: {value:?} is not a time > 0 ms"))?
            }
            "--millgate" => self.millgate = PathBuf::from(&value),
            "--analysis-workers" => {
                // The gateway's check reports a count out of its range.
                self.analysis_workers = Some(value.parse().with_context(|| {
                    format!("--analysis-workers: {value:?} is not a count of threads")
                })?)
            }
            "--plc-requests-in-flight" | "--daq-requests-in-flight" => {
                // The gateway's check reports a count out of its range.
                let count = Some(
                    value
                        .parse()
                        .with_context(|| format!("{arg}: {value:?} is not a count of requests"))?,
                );
                match arg {
                    "--plc-requests-in-flight" => self.plc_requests_in_flight = count,
                    _ => self.daq_requests_in_flight = count,
                }
            }
            _ => bail!(
                "unknown option {arg} (allowed: --duration, --every, --warm-up, --drivelines, \
                 --tandem-stands, --tandem-rate-hz, --cpu, --p99-limit-ms, --keep-going, \
                 --millgate, --analysis-workers, --plc-requests-in-flight, \
                 --daq-requests-in-flight; --help lists them)"
            ),
        }
        Ok(())
    }

    /// The load points (drivelines, stands): the lists stepped together, a single value
    /// held.
    pub(crate) fn load_points(&self) -> anyhow::Result<Vec<(usize, usize)>> {
        let (n, m) = (&self.drivelines, &self.tandem_stands);
        let steps = n.len().max(m.len());
        let at = |list: &Vec<usize>, i: usize| if list.len() == 1 { list[0] } else { list[i] };
        if (n.len() != 1 && n.len() != steps) || (m.len() != 1 && m.len() != steps) {
            bail!("--drivelines and --tandem-stands: lists of equal length, or one value");
        }
        Ok((0..steps).map(|i| (at(n, i), at(m, i))).collect())
    }
}

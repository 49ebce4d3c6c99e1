//! What the bench reads of a process and of the gateway's answers: the figures of
//! `/proc`, HTTP GETs of the web page and `/metrics`, the sums of metric samples, the
//! stalls of the bench's own timers, and the guard that kills the gateway.

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener as StdListener, TcpStream};
use std::process::Child;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context as _;

/// Clock ticks per second of `/proc/<pid>/stat` (USER_HZ, 100 on Linux).
const USER_HZ: f64 = 100.0;

/// A free loopback port (released at once: the gateway binds it right after).
pub(crate) fn free_port() -> anyhow::Result<SocketAddr> {
    Ok(StdListener::bind("127.0.0.1:0")?.local_addr()?)
}

/// What `/proc` tells of a process.
pub(crate) struct ProcessFigures {
    /// Resident set (VmRSS), KiB.
    pub(crate) rss_kib: u64,
    pub(crate) threads: u64,
    /// Open file descriptors.
    pub(crate) fds: usize,
    /// CPU time of all its threads, user and system, s.
    pub(crate) cpu_s: f64,
}

/// The figures of process `pid`.
pub(crate) fn process_figures(pid: u32) -> anyhow::Result<ProcessFigures> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status"))?;
    let field = |name: &str| -> anyhow::Result<u64> {
        let line = status
            .lines()
            .find(|line| line.starts_with(name))
            .with_context(|| format!("no {name} in /proc/{pid}/status"))?;
        Ok(line[name.len()..]
            .split_whitespace()
            .next()
            .unwrap_or("")
            .parse()?)
    };
    let fds = std::fs::read_dir(format!("/proc/{pid}/fd"))?.count();
    // Fields after the command's closing parenthesis: utime and stime are the 12th
    // and 13th (fields 14 and 15 of proc(5)).
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat"))?;
    let after = stat
        .rsplit_once(')')
        .map(|(_, rest)| rest)
        .context("/proc/<pid>/stat without a command")?;
    let ticks: Vec<f64> = after
        .split_whitespace()
        .skip(11)
        .take(2)
        .map(str::parse)
        .collect::<Result<_, _>>()?;
    Ok(ProcessFigures {
        rss_kib: field("VmRSS:")?,
        threads: field("Threads:")?,
        fds,
        cpu_s: ticks.iter().sum::<f64>() / USER_HZ,
    })
}

/// The machine's CPU time in ticks since boot, all cores: the whole (`/proc/stat`'s
/// `cpu` line, user to steal: its `guest` fields are counted in `user` and `nice`
/// already) and what the hypervisor gave other guests while this one wanted to run
/// (`steal`, the 8th field). On a shared virtual machine a load point's latency moves
/// with it; the `steal_%` column shows it beside the figures.
pub(crate) fn machine_ticks() -> anyhow::Result<(u64, u64)> {
    let stat = std::fs::read_to_string("/proc/stat")?;
    let fields: Vec<u64> = stat
        .lines()
        .next()
        .and_then(|line| line.strip_prefix("cpu "))
        .context("/proc/stat without its cpu line")?
        .split_whitespace()
        .map(str::parse)
        .collect::<Result<_, _>>()?;
    let counted = fields
        .get(..8)
        .context("/proc/stat's cpu line without steal")?;
    Ok((counted.iter().sum(), counted[7]))
}

/// Per thread of process `pid` (by thread id), the time it was runnable but waited for
/// a CPU since it started, ns: the second field of `/proc/<pid>/task/<tid>/schedstat`
/// (`run_delay`, counted when the kernel keeps scheduler statistics). A thread that
/// ends between two samples takes its last wait with it. On a machine with cores to
/// spare this stays small beside the CPU time; where it nears the CPU time, a bite's
/// work waited for a core as long as it ran (the `wait_%` column).
pub(crate) fn runnable_waits(pid: u32) -> anyhow::Result<BTreeMap<u32, u64>> {
    let mut waits = BTreeMap::new();
    for task in std::fs::read_dir(format!("/proc/{pid}/task"))? {
        let task = task?;
        let Some(tid) = task.file_name().to_str().and_then(|tid| tid.parse().ok()) else {
            continue;
        };
        // A thread that ended since the listing has no file left: not counted.
        let Ok(schedstat) = std::fs::read_to_string(task.path().join("schedstat")) else {
            continue;
        };
        let waited = schedstat
            .split_whitespace()
            .nth(1)
            .context("/proc/<pid>/task/<tid>/schedstat without run_delay")?
            .parse()?;
        waits.insert(tid, waited);
    }
    Ok(waits)
}

/// One HTTP/1.1 GET over a new connection: the status and the body.
pub(crate) fn get(address: SocketAddr, path: &str) -> anyhow::Result<(u16, String)> {
    let mut stream = TcpStream::connect_timeout(&address, Duration::from_secs(2))?;
    stream.set_read_timeout(Some(Duration::from_secs(5)))?;
    write!(
        stream,
        "GET {path} HTTP/1.1\r\nHost: {address}\r\nConnection: close\r\n\r\n"
    )?;
    let mut text = String::new();
    stream.read_to_string(&mut text)?;
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|code| code.parse().ok())
        .with_context(|| format!("GET {path}: no status line"))?;
    let body = text
        .split_once("\r\n\r\n")
        .map_or(String::new(), |(_, body)| body.to_owned());
    Ok((status, body))
}

/// GETs `/` and `/api/overview` of the web page and `/metrics`: what did not answer
/// 200, and the metrics' text.
pub(crate) fn web_answers(web: SocketAddr, metrics: SocketAddr) -> (Vec<String>, Option<String>) {
    let mut failures = Vec::new();
    let mut metrics_text = None;
    for (address, path) in [(web, "/"), (web, "/api/overview"), (metrics, "/metrics")] {
        match get(address, path) {
            Ok((200, body)) => {
                if path == "/metrics" {
                    metrics_text = Some(body);
                }
            }
            Ok((status, _)) => failures.push(format!("{path}: {status}")),
            Err(error) => failures.push(format!("{path}: {error:#}")),
        }
    }
    (failures, metrics_text)
}

/// The sum of every sample of the Prometheus text whose name (before the labels) is
/// `metric`.
pub(crate) fn metric_sum(text: &str, metric: &str) -> f64 {
    text.lines()
        .filter(|line| {
            line.strip_prefix(metric)
                .is_some_and(|rest| rest.starts_with(['{', ' ']))
        })
        .filter_map(|line| line.rsplit_once(' ')?.1.parse::<f64>().ok())
        .fold(0.0, |sum, value| sum + value)
}

/// A child process killed and reaped when dropped (the gateway, even on an error).
pub(crate) struct Killed(pub(crate) Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A folder removed, with what it holds, when dropped (the load point's, even on an
/// error).
pub(crate) struct Removed(pub(crate) std::path::PathBuf);

impl Drop for Removed {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Records in `stall` (us) the longest lateness of a 5 ms timer of the bench's runtime,
/// the one its virtual DAQs publish on, until aborted.
pub(crate) async fn watch_stalls(stall: Arc<AtomicU64>) {
    let period = Duration::from_millis(5);
    let mut ticks = tokio::time::interval(period);
    ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut expected = tokio::time::Instant::now();
    loop {
        ticks.tick().await;
        let now = tokio::time::Instant::now();
        let late = now.saturating_duration_since(expected).as_micros() as u64;
        stall.fetch_max(late, Ordering::Relaxed);
        expected = now + period;
    }
}

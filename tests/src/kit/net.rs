//! Waiting for a condition ([`wait_for`]), loopback ports ([`free_port`]) and HTTP to a
//! running gateway: its page ([`web_ready`], [`web_overview`]), its `/metrics`
//! ([`scrape`]), any request ([`http`], [`http_raw`]) to a port or an address.

use std::net::{IpAddr, SocketAddr};
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// Poll `done` every 5 ms until it holds; panic naming `what` after `limit`.
pub async fn wait_for(what: &str, limit: Duration, mut done: impl FnMut() -> bool) {
    let start = Instant::now();
    while !done() {
        assert!(start.elapsed() < limit, "{what}: not within {limit:?}");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
}

/// An HTTP answer: status, headers (names lower-case) and body.
#[derive(Debug)]
pub struct HttpAnswer {
    /// The status code.
    pub status: u16,
    /// The headers, names lower-case, in order.
    pub headers: Vec<(String, String)>,
    /// The body, as text.
    pub body: String,
}

impl HttpAnswer {
    /// The first header called `name` (lower-case).
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(key, _)| key == name)
            .map(|(_, value)| value.as_str())
    }

    /// The body as JSON; panics with the body when it is not.
    pub fn json(&self) -> serde_json::Value {
        serde_json::from_str(&self.body).unwrap_or_else(|e| panic!("not JSON ({e}): {}", self.body))
    }
}

/// Where a request goes: a port on `127.0.0.1` (`u16`), an address, or an address
/// reached from a chosen loopback address ([`FromSource`]).
pub trait Endpoint {
    /// The address.
    fn address(&self) -> SocketAddr;

    /// The local address to connect from; the kernel's choice when `None`.
    fn source(&self) -> Option<IpAddr> {
        None
    }
}

/// `to`, connected to from `source` (say `127.0.0.2`): a client the server tells
/// apart by its address from the others on `127.0.0.1`.
#[derive(Debug, Clone, Copy)]
pub struct FromSource {
    /// The local address the connection is made from.
    pub source: IpAddr,
    /// Where it goes.
    pub to: SocketAddr,
}

impl Endpoint for FromSource {
    fn address(&self) -> SocketAddr {
        self.to
    }

    fn source(&self) -> Option<IpAddr> {
        Some(self.source)
    }
}

/// A TCP connection to `to`, from its [`Endpoint::source`] when it names one.
pub async fn connect(to: &impl Endpoint) -> std::io::Result<tokio::net::TcpStream> {
    let Some(source) = to.source() else {
        return tokio::net::TcpStream::connect(to.address()).await;
    };
    let socket = match source {
        IpAddr::V4(_) => tokio::net::TcpSocket::new_v4()?,
        IpAddr::V6(_) => tokio::net::TcpSocket::new_v6()?,
    };
    socket.bind(SocketAddr::new(source, 0))?;
    socket.connect(to.address()).await
}

impl Endpoint for u16 {
    fn address(&self) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], *self))
    }
}

impl Endpoint for SocketAddr {
    fn address(&self) -> SocketAddr {
        *self
    }
}

/// Send `raw` (a whole HTTP/1.x request) to `to` and read the answer until the server
/// closes (the request says `connection: close`, or is HTTP/1.0); the server may be
/// silent for at most [`HTTP_SILENCE`] at a time. Panics when the exchange fails
/// ([`try_http_raw`] says so instead).
pub async fn http_raw(to: impl Endpoint, raw: &[u8]) -> HttpAnswer {
    try_http_raw(to, raw).await.expect("HTTP exchange")
}

/// How long a server may stay silent in an HTTP exchange ([`http_raw`]): to accept
/// the connection, to take the request, and between any two pieces of its answer.
/// A limit on the silence, not on the whole exchange: a large answer (a capture of
/// 300 000 samples a channel) streamed on a loaded machine takes longer than 10 s in
/// all and is no fault (CI: "HTTP answer within 10 s: Elapsed" in capture_faults),
/// a server that stops answering is caught as soon.
pub const HTTP_SILENCE: Duration = Duration::from_secs(10);

/// The longest an HTTP exchange ([`http_raw`]) may take in all, however the answer
/// comes: an answer that never ends (a live stream where a refusal was expected) is
/// an error, not a test that hangs.
pub const HTTP_EXCHANGE_LIMIT: Duration = Duration::from_secs(120);

/// [`http_raw`], with a refused connection, a reset or a silence of [`HTTP_SILENCE`]
/// as an error: for a test that asks while the service may be stopping.
pub async fn try_http_raw(to: impl Endpoint, raw: &[u8]) -> anyhow::Result<HttpAnswer> {
    try_http_raw_within(to, raw, HTTP_SILENCE).await
}

/// [`try_http_raw`], the server silent for at most `silence` at a time instead of
/// [`HTTP_SILENCE`]: for an answer whose head comes only after work that takes longer
/// on a loaded machine (a capture of millions of samples read and decoded first).
pub async fn try_http_raw_within(
    to: impl Endpoint,
    raw: &[u8],
    silence: Duration,
) -> anyhow::Result<HttpAnswer> {
    let address = to.address();
    let silent = |what: &str| anyhow::anyhow!("{address} silent for {silence:?} {what}");
    let failed = |e: std::io::Error| anyhow::anyhow!("HTTP exchange with {address}: {e}");
    let mut stream = tokio::time::timeout(silence, connect(&to))
        .await
        .map_err(|_| silent("at connecting"))?
        .map_err(failed)?;
    tokio::time::timeout(silence, stream.write_all(raw))
        .await
        .map_err(|_| silent("taking the request"))?
        .map_err(failed)?;
    let started = Instant::now();
    let mut bytes = Vec::new();
    let mut piece = vec![0u8; 64 * 1024];
    loop {
        let read = tokio::time::timeout(silence, stream.read(&mut piece))
            .await
            .map_err(|_| silent(&format!("after {} bytes of its answer", bytes.len())))?
            .map_err(failed)?;
        if read == 0 {
            break;
        }
        bytes.extend_from_slice(&piece[..read]);
        anyhow::ensure!(
            started.elapsed() < HTTP_EXCHANGE_LIMIT,
            "{address}'s answer not ended after {HTTP_EXCHANGE_LIMIT:?} ({} bytes)",
            bytes.len()
        );
    }
    let split = bytes
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .map_or((bytes.len(), bytes.len()), |at| (at, at + 4));
    let head = String::from_utf8_lossy(&bytes[..split.0]).into_owned();
    let mut lines = head.lines();
    let status = lines
        .next()
        .and_then(|line| line.split(' ').nth(1))
        .and_then(|code| code.parse().ok())
        .ok_or_else(|| anyhow::anyhow!("no status line in {head:?}"))?;
    let headers: Vec<(String, String)> = lines
        .filter_map(|line| line.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_owned()))
        .collect();
    let chunked = headers
        .iter()
        .any(|(k, v)| k == "transfer-encoding" && v.eq_ignore_ascii_case("chunked"));
    let body = &bytes[split.1..];
    let body = match chunked {
        true => dechunk(body)?,
        false => body.to_vec(),
    };
    Ok(HttpAnswer {
        status,
        headers,
        body: String::from_utf8_lossy(&body).into_owned(),
    })
}

/// The body of a chunked HTTP/1.1 answer (RFC 9112 7.1); an error for a malformed one,
/// or for one cut short (no last chunk: the server ended the answer early).
fn dechunk(mut chunked: &[u8]) -> anyhow::Result<Vec<u8>> {
    let cut = || anyhow::anyhow!("a chunked answer cut short");
    let mut body = Vec::new();
    loop {
        let line_end = chunked
            .windows(2)
            .position(|w| w == b"\r\n")
            .ok_or_else(cut)?;
        let line = std::str::from_utf8(&chunked[..line_end])?;
        let size = usize::from_str_radix(line.split(';').next().unwrap_or("").trim(), 16)
            .map_err(|_| anyhow::anyhow!("chunk size {line:?}"))?;
        chunked = &chunked[line_end + 2..];
        if size == 0 {
            return Ok(body);
        }
        body.extend_from_slice(chunked.get(..size).ok_or_else(cut)?);
        chunked = chunked.get(size + 2..).ok_or_else(cut)?;
    }
}

/// `method path` on `to`.
pub async fn http(to: impl Endpoint, method: &str, path: &str) -> HttpAnswer {
    http_raw(to, request(method, path).as_bytes()).await
}

/// [`http`], the server silent for at most `silence` at a time
/// ([`try_http_raw_within`]); panics when the exchange fails.
pub async fn http_within(
    to: impl Endpoint,
    method: &str,
    path: &str,
    silence: Duration,
) -> HttpAnswer {
    try_http_raw_within(to, request(method, path).as_bytes(), silence)
        .await
        .expect("HTTP exchange")
}

/// [`http`], a failed exchange as an error ([`try_http_raw`]).
pub async fn try_http(to: impl Endpoint, method: &str, path: &str) -> anyhow::Result<HttpAnswer> {
    try_http_raw(to, request(method, path).as_bytes()).await
}

/// A whole HTTP/1.1 request for `method path` that asks the server to close.
fn request(method: &str, path: &str) -> String {
    format!("{method} {path} HTTP/1.1\r\nhost: localhost\r\nconnection: close\r\n\r\n")
}

/// The maintenance page's `/api/overview` at `to`, as JSON.
pub async fn web_overview(to: impl Endpoint) -> anyhow::Result<serde_json::Value> {
    let answer = http(to, "GET", "/api/overview").await;
    anyhow::ensure!(answer.status == 200, "/api/overview: {}", answer.body);
    Ok(serde_json::from_str(&answer.body)?)
}

/// GET /metrics as Prometheus does; checks the status and that every metric family's
/// samples sit in one block after its `# TYPE` line ([`exposition_blocks`]).
/// A refused connection is an error, not a panic.
pub async fn scrape(to: impl Endpoint) -> anyhow::Result<String> {
    let answer = try_http(to, "GET", "/metrics").await?;
    anyhow::ensure!(answer.status == 200, "/metrics: {}", answer.body);
    exposition_blocks(&answer.body).map_err(anyhow::Error::msg)?;
    Ok(answer.body)
}

/// The value of the line of `page` (a `/metrics` page) starting with `name` (with its
/// labels).
pub fn metric_line(page: &str, name: &str) -> Option<f64> {
    page.lines()
        .find_map(|line| line.strip_prefix(name)?.strip_prefix(' ')?.parse().ok())
}

/// Scrape `/metrics` on `to` until the line starting with `name` (with its labels)
/// shows at least `value`, at most `limit`; its value then. A `/metrics` not answering
/// yet (the service starting) is waited for too.
pub async fn until_scraped_at_least(
    to: impl Endpoint,
    name: &str,
    value: f64,
    limit: Duration,
) -> f64 {
    let address = to.address();
    let start = Instant::now();
    loop {
        let now = try_http(address, "GET", "/metrics")
            .await
            .map(|answer| metric_line(&answer.body, name));
        if let Ok(Some(now)) = now {
            if now >= value {
                return now;
            }
        }
        assert!(
            start.elapsed() < limit,
            "{name} {now:?}, not at least {value} within {limit:?}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// Wait until the web page on `to` answers `/api/drivelines` (the service is up), at
/// most 30 s.
pub async fn web_ready(to: impl Endpoint) {
    let address = to.address();
    let start = Instant::now();
    loop {
        // A page that accepts and then says nothing is not up either: the exchange's
        // silence limit ends the try.
        if let Ok(answer) = try_http(address, "GET", "/api/drivelines").await {
            if answer.status == 200 {
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

/// A free loopback port, never the same one twice in this process nor to another test
/// process running at the same time, and below the kernel's ephemeral range
/// (32768..): a port a test frees for a while (a broker restarted on it) is not handed
/// to another test's listener meanwhile, as the kernel's `:0` can do.
///
/// The ports are 20000..32000, taken in turn from an offset of the process id. A
/// process wraps only after all 12000: the window used to be 60 ports, so a test
/// binary that had handed out 60 gave a port again while a slow peer (a RabbitMQ node,
/// seconds to boot) had not bound it yet; another test's broker took it and the node
/// died at boot (CI, issue 41: "port of the cluster not open within 90s"). Test
/// binaries run two at a time (`scripts/test-lanes`), so a port is also claimed across
/// processes: a lock on its file in the `millgate-test-ports` folder of the system's
/// temporary folder, held until this process ends
/// (the kernel releases it however the process ends).
pub fn free_port() -> u16 {
    use std::sync::atomic::{AtomicU32, Ordering};
    const FIRST: u32 = 20_000;
    const PORTS: u32 = 12_000;
    static NEXT: AtomicU32 = AtomicU32::new(0);
    let offset = std::process::id() % 200 * (PORTS / 200);
    loop {
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let port = u16::try_from(FIRST + (offset + n) % PORTS).expect("below 32000");
        if claim(port) && std::net::TcpListener::bind(("127.0.0.1", port)).is_ok() {
            return port;
        }
    }
}

/// The folder (in the system's temporary folder) of the ports' claim files.
const PORT_CLAIMS: &str = "millgate-test-ports";

/// Claim `port` for this process: whether no other process holds it. The claim is an
/// exclusive lock on the port's file, kept open to the end of the process.
fn claim(port: u16) -> bool {
    static HELD: std::sync::Mutex<Vec<std::fs::File>> = std::sync::Mutex::new(Vec::new());
    let folder = std::env::temp_dir().join(PORT_CLAIMS);
    std::fs::create_dir_all(&folder).expect("the ports' claim folder");
    let file = std::fs::File::options()
        .create(true)
        .truncate(false)
        .write(true)
        .open(folder.join(port.to_string()))
        .expect("a port's claim file");
    match file.try_lock() {
        Ok(()) => {
            HELD.lock().unwrap_or_else(|e| e.into_inner()).push(file);
            true
        }
        Err(std::fs::TryLockError::WouldBlock) => false,
        Err(std::fs::TryLockError::Error(error)) => panic!("claiming port {port}: {error}"),
    }
}

/// Whether every metric family's samples on a `/metrics` page sit in one block after
/// its `# TYPE` line (the exposition format's rule, which strict parsers enforce);
/// what breaks it. A histogram's samples are its family's name with `_bucket`, `_sum`
/// or `_count`, a summary's with `_sum` or `_count` (or none).
pub fn exposition_blocks(page: &str) -> Result<(), String> {
    let mut seen = std::collections::HashSet::new();
    let (mut current, mut kind) = ("", "");
    for line in page.lines().filter(|l| !l.is_empty()) {
        if let Some(rest) = line.strip_prefix("# TYPE ") {
            let mut words = rest.split(' ');
            current = words.next().unwrap_or_default();
            kind = words.next().unwrap_or_default();
            if !seen.insert(current.to_owned()) {
                return Err(format!("family {current} twice"));
            }
        } else if !line.starts_with('#') {
            let name = line.split(['{', ' ']).next().unwrap_or_default();
            let suffixes: &[&str] = match kind {
                "histogram" => &["_bucket", "_sum", "_count"],
                "summary" => &["", "_sum", "_count"],
                _ => &[""],
            };
            let of_family = name
                .strip_prefix(current)
                .is_some_and(|suffix| suffixes.contains(&suffix));
            if !of_family {
                return Err(format!("sample {line:?} outside its family block"));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{exposition_blocks, free_port};

    #[test]
    fn a_process_is_not_handed_the_same_port_twice() {
        // More ports than a test binary uses (the sparkplug binary: about 150).
        let ports: Vec<u16> = (0..1000).map(|_| free_port()).collect();
        let distinct: std::collections::HashSet<u16> = ports.iter().copied().collect();
        assert_eq!(distinct.len(), ports.len());
        assert!(
            ports.iter().all(|p| (20_000..32_000).contains(p)),
            "{ports:?}"
        );
    }

    #[test]
    fn a_port_handed_out_is_claimed_against_other_processes() {
        let port = free_port();
        let claim = std::env::temp_dir()
            .join(super::PORT_CLAIMS)
            .join(port.to_string());
        // flock(1) takes the lock that File::try_lock takes (flock(2)), from another process.
        let other = |port_file: &std::path::Path| {
            std::process::Command::new("flock")
                .args(["--nonblock", "--conflict-exit-code", "3"])
                .arg(port_file)
                .arg("true")
                .status()
                .expect("flock(1)")
                .code()
        };
        assert_eq!(other(&claim), Some(3), "port {port} not claimed");
        // A file no process holds is free to the other process.
        let unclaimed = std::env::temp_dir()
            .join(super::PORT_CLAIMS)
            .join(format!("unclaimed-{}", std::process::id()));
        std::fs::write(&unclaimed, b"").unwrap();
        assert_eq!(other(&unclaimed), Some(0));
        std::fs::remove_file(unclaimed).unwrap();
    }

    #[test]
    fn a_histogram_block_holds_its_buckets_sum_and_count_and_nothing_else() {
        let histogram = "# TYPE wait_seconds histogram\n\
                         wait_seconds_bucket{le=\"0.1\"} 1\n\
                         wait_seconds_bucket{le=\"+Inf\"} 2\n\
                         wait_seconds_sum 0.3\n\
                         wait_seconds_count 2\n\
                         # TYPE bites_total counter\n\
                         bites_total 2\n";
        assert_eq!(exposition_blocks(histogram), Ok(()));
        let stray = "# TYPE bites_total counter\nbites_total 2\nwait_seconds_count 2\n";
        assert!(exposition_blocks(stray).is_err());
        let counter_suffix = "# TYPE bites_total counter\nbites_total_bucket 2\n";
        assert!(exposition_blocks(counter_suffix).is_err());
        let twice = "# TYPE a gauge\na 1\n# TYPE b gauge\nb 1\n# TYPE a gauge\na 2\n";
        assert!(exposition_blocks(twice).is_err());
    }
}

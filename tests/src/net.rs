//! Test support shared by the gateway's integration tests (`gateway/tests/common`, which
//! includes this file) and the end-to-end crate (whose module it is): waiting
//! for a condition and talking HTTP to a running gateway (its page, its `/metrics`).
//! A file rather than a crate: it needs nothing of millgate, and a crate that both
//! `millgate` (as a dev-dependency) and `millgate-tests` depend on would be one more
//! member for three functions.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// Poll `done` every 5 ms until it holds; panic naming `what` after `limit`.
pub async fn until(what: &str, limit: Duration, mut done: impl FnMut() -> bool) {
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

/// Send `raw` (a whole HTTP/1.x request) to `address` and read the answer until the
/// server closes (the request says `connection: close`, or is HTTP/1.0); within 10 s.
pub async fn http_raw(address: SocketAddr, raw: &[u8]) -> HttpAnswer {
    let exchange = async {
        let mut stream = tokio::net::TcpStream::connect(address).await?;
        stream.write_all(raw).await?;
        let mut bytes = Vec::new();
        stream.read_to_end(&mut bytes).await?;
        std::io::Result::Ok(bytes)
    };
    let bytes = tokio::time::timeout(Duration::from_secs(10), exchange)
        .await
        .expect("HTTP answer within 10 s")
        .expect("HTTP exchange");
    let text = String::from_utf8_lossy(&bytes).into_owned();
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    let mut lines = head.lines();
    let status = lines
        .next()
        .and_then(|line| line.split(' ').nth(1))
        .and_then(|code| code.parse().ok())
        .unwrap_or_else(|| panic!("no status line in {text:?}"));
    let headers = lines
        .filter_map(|line| line.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_owned()))
        .collect();
    HttpAnswer {
        status,
        headers,
        body: body.to_owned(),
    }
}

/// `method path` on `address`.
pub async fn http(address: SocketAddr, method: &str, path: &str) -> HttpAnswer {
    let request =
        format!("{method} {path} HTTP/1.1\r\nhost: localhost\r\nconnection: close\r\n\r\n");
    http_raw(address, request.as_bytes()).await
}

/// Whether every metric family's samples on a `/metrics` page sit in one block after
/// its `# TYPE` line (the exposition format's rule, which strict parsers enforce);
/// what breaks it.
pub fn exposition_blocks(page: &str) -> Result<(), String> {
    let mut seen = std::collections::HashSet::new();
    let mut current = "";
    for line in page.lines().filter(|l| !l.is_empty()) {
        if let Some(rest) = line.strip_prefix("# TYPE ") {
            current = rest.split(' ').next().unwrap_or_default();
            if !seen.insert(current.to_owned()) {
                return Err(format!("family {current} twice"));
            }
        } else if !line.starts_with('#') {
            let name = line.split(['{', ' ']).next().unwrap_or_default();
            if name != current {
                return Err(format!("sample {line:?} outside its family block"));
            }
        }
    }
    Ok(())
}

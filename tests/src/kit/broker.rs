//! Debian's `mosquitto` on a loopback port, killed when dropped: the broker of the
//! Sparkplug tests, the Sparkplug bench and the examples that need one (`soak`,
//! `sparkplug_scale`).

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A running broker; dropping it kills and reaps the process.
#[derive(Debug)]
pub struct Broker(Child);

impl Broker {
    /// `mosquitto` listening on `127.0.0.1:port` (anonymous, no persistence), its
    /// configuration written into `folder`; returns once it accepts connections.
    /// Panics when it cannot start (a test's or bench's setup).
    pub fn start(folder: &Path, port: u16) -> Self {
        Self::try_start(folder, port).unwrap_or_else(|error| panic!("{error}"))
    }

    /// As [`Self::start`], the failure as a sentence (for the examples).
    pub fn try_start(folder: &Path, port: u16) -> Result<Self, String> {
        // An open port is this mosquitto only if it answers MQTT (and still runs: one
        // that could not bind ends at once, and the port may be another's).
        Self::try_with_listeners(
            folder,
            port,
            &format!("listener {port} 127.0.0.1\nallow_anonymous true\n"),
            ("accepts no MQTT session", |port| {
                connack(port, "millgate-probe") == Some(0)
            }),
        )
    }

    /// mosquitto with the `listeners` configuration (TLS, passwords), no persistence;
    /// returns once `port` accepts connections and mosquitto still runs (a TLS
    /// listener takes no plain CONNECT). Panics when it cannot start.
    pub fn with_listeners(folder: &Path, port: u16, listeners: &str) -> Self {
        let open = |port| std::net::TcpStream::connect(("127.0.0.1", port)).is_ok();
        Self::try_with_listeners(folder, port, listeners, ("not listening", open))
            .unwrap_or_else(|error| panic!("{error}"))
    }

    /// mosquitto with `listeners`, returned once `ready(port)` holds within 10 s while
    /// it runs; the error says it was `not_ready` (or that mosquitto ended).
    fn try_with_listeners(
        folder: &Path,
        port: u16,
        listeners: &str,
        (not_ready, ready): (&str, impl Fn(u16) -> bool),
    ) -> Result<Self, String> {
        let config = folder.join("mosquitto.conf");
        std::fs::write(&config, format!("{listeners}\npersistence false\n"))
            .map_err(|e| format!("{}: {e}", config.display()))?;
        // Debian installs it in /usr/sbin, which a user's PATH may not hold.
        let binary = ["/usr/sbin/mosquitto", "mosquitto"]
            .into_iter()
            .find(|b| Path::new(b).exists())
            .unwrap_or("mosquitto");
        let mut broker = Self(
            Command::new(binary)
                .arg("-c")
                .arg(&config)
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .map_err(|e| format!("Debian's mosquitto (apt install mosquitto): {e}"))?,
        );
        let start = Instant::now();
        while !ready(port) {
            broker.ended()?;
            if start.elapsed() > Duration::from_secs(10) {
                return Err(format!("mosquitto on port {port} {not_ready} within 10 s"));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        broker.ended()?;
        Ok(broker)
    }

    /// An error when mosquitto has ended (it could not bind its port, or its
    /// configuration was refused).
    fn ended(&mut self) -> Result<(), String> {
        match self.0.try_wait() {
            Ok(None) => Ok(()),
            Ok(Some(status)) => Err(format!(
                "mosquitto ended ({status}): its port taken, or its configuration refused"
            )),
            Err(error) => Err(format!("mosquitto: {error}")),
        }
    }
}

/// The return code of the CONNACK that the MQTT server on loopback `port` answers to a
/// clean MQTT 3.1.1 session of client `id` within 2 s (then DISCONNECT); `None` when
/// it does not answer one. 0: the session is accepted.
pub fn connack(port: u16, id: &str) -> Option<u8> {
    use std::io::{Read as _, Write as _};
    let mut stream = std::net::TcpStream::connect(("127.0.0.1", port)).ok()?;
    stream.set_read_timeout(Some(Duration::from_secs(2))).ok()?;
    let mut packet = vec![0x10, u8::try_from(12 + id.len()).expect("a short id")];
    // Protocol "MQTT", level 4, clean session, keep-alive 60 s, then the client id.
    packet.extend([0, 4, b'M', b'Q', b'T', b'T', 4, 0x02, 0, 60]);
    packet.extend(u16::try_from(id.len()).expect("a short id").to_be_bytes());
    packet.extend(id.as_bytes());
    stream.write_all(&packet).ok()?;
    let mut answer = [0u8; 4];
    stream.read_exact(&mut answer).ok()?;
    (answer[0] == 0x20).then_some(answer[3]).inspect(|&code| {
        if code == 0 {
            let _ = stream.write_all(&[0xE0, 0]);
        }
    })
}

impl Drop for Broker {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

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
        Self::try_with_listeners(
            folder,
            port,
            &format!("listener {port} 127.0.0.1\nallow_anonymous true\n"),
        )
    }

    /// mosquitto with the `listeners` configuration (TLS, passwords), no persistence;
    /// returns once `port` accepts connections. Panics when it cannot start.
    pub fn with_listeners(folder: &Path, port: u16, listeners: &str) -> Self {
        Self::try_with_listeners(folder, port, listeners).unwrap_or_else(|error| panic!("{error}"))
    }

    fn try_with_listeners(folder: &Path, port: u16, listeners: &str) -> Result<Self, String> {
        let config = folder.join("mosquitto.conf");
        std::fs::write(&config, format!("{listeners}\npersistence false\n"))
            .map_err(|e| format!("{}: {e}", config.display()))?;
        // Debian installs it in /usr/sbin, which a user's PATH may not hold.
        let binary = ["/usr/sbin/mosquitto", "mosquitto"]
            .into_iter()
            .find(|b| Path::new(b).exists())
            .unwrap_or("mosquitto");
        let broker = Self(
            Command::new(binary)
                .arg("-c")
                .arg(&config)
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .map_err(|e| format!("Debian's mosquitto (apt install mosquitto): {e}"))?,
        );
        let start = Instant::now();
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            if start.elapsed() > Duration::from_secs(10) {
                return Err(format!(
                    "mosquitto not listening on port {port} within 10 s"
                ));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        Ok(broker)
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

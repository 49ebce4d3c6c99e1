//! A Debian `mosquitto` on a loopback port for the examples that need a broker
//! (`sparkplug_scale`, `soak`), killed when dropped.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A running broker; dropping it kills and reaps the process.
pub(crate) struct Mosquitto(Child);

impl Mosquitto {
    /// Starts `mosquitto` listening on `127.0.0.1:port` (anonymous, no persistence),
    /// its configuration written into `folder`, and waits until it accepts connections.
    pub(crate) fn start(folder: &Path, port: u16) -> Result<Self, String> {
        let config = folder.join("mosquitto.conf");
        std::fs::write(
            &config,
            format!("listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n"),
        )
        .map_err(|e| format!("{}: {e}", config.display()))?;
        let broker = Self(
            Command::new("mosquitto")
                .arg("-c")
                .arg(&config)
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .map_err(|e| format!("mosquitto (apt install mosquitto): {e}"))?,
        );
        let start = Instant::now();
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            if start.elapsed() > Duration::from_secs(10) {
                return Err("mosquitto does not listen".into());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        Ok(broker)
    }
}

impl Drop for Mosquitto {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

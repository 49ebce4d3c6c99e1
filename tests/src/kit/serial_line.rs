//! A serial line on loopback for the Modbus RTU tests and benchmark: a pseudo-terminal
//! pair made by socat ([`PtyPair`]), and a pymodbus RTU device on one end of it
//! ([`RtuDevice`], `peers/pymodbus_rtu_device.py`). Both are killed when dropped, so a
//! failing test leaves no process behind. The benchmark's line carries bytes at a baud
//! rate ([`PacedLine`]).
//!
//! A pseudo-terminal refuses parity settings, so the line runs without parity; it
//! also carries bytes at once, whatever the baud rate.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Samples in each of the device's blocks (one every 100 ms: 200 Hz).
pub const BLOCK_SAMPLES: u64 = 20;
/// The device's f32 speed (ABCD) at this register, holding 12.5.
pub const SPEED_REGISTER: u16 = 200;
/// The device's u16 at this register, holding 4242.
pub const COUNT_REGISTER: u16 = 202;

/// The value of the device's sample after `value` in its ramp: samples count up
/// from -1000 to 999 and wrap.
pub fn next_sample(value: i64) -> i64 {
    if value >= 999 {
        -1000
    } else {
        value + 1
    }
}

/// Modbus CRC-16 (polynomial 0xA001 reflected, initial 0xFFFF), low byte first.
pub fn with_crc(frame: &[u8]) -> Vec<u8> {
    let mut crc: u16 = 0xFFFF;
    for &byte in frame {
        crc ^= u16::from(byte);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xA001
            } else {
                crc >> 1
            };
        }
    }
    let mut out = frame.to_vec();
    out.extend(crc.to_le_bytes());
    out
}

/// What a hostile line's far end answers request `turn` (`request` the bytes it read),
/// for a gateway polling unit `unit`: in turn noise that never makes a frame (the read
/// times out), a well-formed reply from another unit (out of step), and the right unit
/// with one register whatever was asked (a length mismatch).
pub fn junk_reply(turn: usize, request: &[u8], unit: u8) -> Vec<u8> {
    let function = request.get(1).copied().unwrap_or(3);
    match turn % 3 {
        0 => (0..17u8).map(|i| i.wrapping_mul(97) ^ 0x5A).collect(),
        1 => with_crc(&[unit + 1, function, 2, 0, 1]),
        _ => with_crc(&[unit, function, 2, 0, 1]),
    }
}

/// Two linked pseudo-terminals: the gateway opens [`PtyPair::gateway`], the device
/// [`PtyPair::device`]. socat holds them until dropped.
#[derive(Debug)]
pub struct PtyPair {
    socat: Child,
    /// Removed when dropped, after socat.
    _folder: super::scratch::TempDir,
    /// The gateway's end (a symbolic link to its `/dev/pts/N`).
    pub gateway: PathBuf,
    /// The device's end.
    pub device: PathBuf,
}

impl PtyPair {
    /// Starts socat with the two ends as links in a new temporary folder; waits
    /// until both exist.
    pub fn open() -> anyhow::Result<Self> {
        let folder = super::scratch::scratch("rtu");
        let gateway = folder.path().join("gateway");
        let device = folder.path().join("device");
        let end = |path: &Path| format!("pty,raw,echo=0,link={}", path.display());
        let socat = Command::new("socat")
            .args([end(&device), end(&gateway)])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|error| {
                anyhow::anyhow!("cannot start socat ({error}): scripts/test installs it")
            })?;
        let pair = Self {
            socat,
            _folder: folder,
            gateway,
            device,
        };
        let start = Instant::now();
        while !(pair.gateway.exists() && pair.device.exists()) {
            anyhow::ensure!(
                start.elapsed() < Duration::from_secs(10),
                "socat made no pseudo-terminals in 10 s"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        Ok(pair)
    }
}

impl Drop for PtyPair {
    fn drop(&mut self) {
        let _ = self.socat.kill();
        let _ = self.socat.wait();
    }
}

/// The pymodbus RTU device (`peers/pymodbus_rtu_device.py`) serving on a serial
/// device: a speed, a count and a sample block that follows the wall clock from an
/// epoch (see the script's documentation).
#[derive(Debug)]
pub struct RtuDevice {
    child: Child,
}

impl RtuDevice {
    /// Starts the device on `device` at `baud` Bd, 8N`stop_bits`, as unit `unit`, its
    /// blocks counted from `epoch` (seconds since 1970); returns once it has opened
    /// the port.
    pub fn start(
        device: &Path,
        baud: u32,
        stop_bits: u8,
        unit: u8,
        epoch: f64,
    ) -> anyhow::Result<Self> {
        Self::spawn(device, (baud, stop_bits, unit), &[format!("{epoch:.6}")])
    }

    /// As [`RtuDevice::start`], but each read of the block is a new block (the
    /// script's "firehose"), so every poll of the block brings new data.
    pub fn firehose(device: &Path, baud: u32, stop_bits: u8, unit: u8) -> anyhow::Result<Self> {
        Self::spawn(
            device,
            (baud, stop_bits, unit),
            &["0".to_owned(), "firehose".to_owned()],
        )
    }

    fn spawn(
        device: &Path,
        (baud, stop_bits, unit): (u32, u8, u8),
        rest: &[String],
    ) -> anyhow::Result<Self> {
        let script = super::peers::peer("pymodbus_rtu_device.py");
        let mut child = Command::new("python3")
            .arg(script)
            .arg(device)
            .args([baud.to_string(), stop_bits.to_string(), unit.to_string()])
            .args(rest)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()?;
        // Owned by the guard from here on: a failed start kills it.
        let stdout = child.stdout.take();
        let device = Self { child };
        let mut line = String::new();
        if let Some(stdout) = stdout {
            BufReader::new(stdout).read_line(&mut line)?;
        }
        anyhow::ensure!(
            line.trim() == "ready",
            "the pymodbus RTU device did not start (pymodbus 3.16.1 and pyserial 3.5 \
             installed? scripts/test installs them)"
        );
        Ok(device)
    }

    /// Kills the device: the line falls silent, as with its cable pulled.
    pub fn stop(mut self) {
        self.kill();
    }

    fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for RtuDevice {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Seconds since 1970 now, for [`RtuDevice::start`]'s epoch.
pub fn unix_now() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |since| since.as_secs_f64())
}

/// A serial line at a baud rate between two pseudo-terminal pairs: bytes written at
/// one end of the line arrive at the other no sooner than the line could carry them
/// (`character_time` each, back to back), in both directions. A pseudo-terminal
/// carries bytes at once; this is the wire of the RTU benchmark. Its threads end when
/// the pairs are dropped.
#[derive(Debug)]
pub struct PacedLine {
    /// The gateway's side: open `gateway_side.gateway`.
    pub gateway_side: PtyPair,
    /// The device's side: the device opens `device_side.device`.
    pub device_side: PtyPair,
}

impl PacedLine {
    /// Two pairs joined by relays that hold each chunk until its last character
    /// would have arrived on the line.
    pub fn open(character_time: Duration) -> anyhow::Result<Self> {
        let gateway_side = PtyPair::open()?;
        let device_side = PtyPair::open()?;
        let open = |path: &Path| {
            std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .open(path)
        };
        let near = open(&gateway_side.device)?;
        let far = open(&device_side.gateway)?;
        relay(near.try_clone()?, far.try_clone()?, character_time);
        relay(far, near, character_time);
        Ok(Self {
            gateway_side,
            device_side,
        })
    }
}

/// Copies `from` to `to` at the line's pace, on a thread of its own.
fn relay(mut from: std::fs::File, mut to: std::fs::File, character_time: Duration) {
    use std::io::{Read, Write};
    std::thread::spawn(move || {
        let mut buffer = [0u8; 512];
        let mut line_free = Instant::now();
        while let Ok(read) = from.read(&mut buffer) {
            if read == 0 {
                break;
            }
            let now = Instant::now();
            line_free = line_free.max(now) + character_time * read as u32;
            std::thread::sleep(line_free.saturating_duration_since(now));
            if to.write_all(&buffer[..read]).is_err() {
                break;
            }
        }
    });
}

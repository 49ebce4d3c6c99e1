//! Modbus RTU: the serial line opened for tokio-modbus' RTU client, and the silence
//! a line needs between frames ([`FrameSpacing`]).
//!
//! An RTU device finds the end of a request by the silence after it, and a frame
//! started before 3.5 character times of silence (1.75 ms above 19 200 Bd) runs into
//! the last one. tokio-modbus' RTU client finds a frame's end by its length and CRC
//! and keeps no silence, so the reader waits [`millgate_config::SerialLine`]'s
//! `inter_frame_delay` after each reply (or timeout) before its next request.

use std::time::Duration;

use millgate_config::{Parity, SerialLine};
use tokio::time::Instant;
use tokio_modbus::client::Context;
use tokio_modbus::prelude::Slave;
use tokio_serial::{ClearBuffer, DataBits, SerialPort, SerialStream, StopBits};

use super::error::ModbusError;

/// Open `device` with the settings of `line` and talk to `unit_id`. Bytes left in
/// the port's buffers (a late reply to a timed-out request) are discarded.
pub(crate) fn connect(
    device: &str,
    line: &SerialLine,
    unit_id: u8,
) -> Result<Context, ModbusError> {
    let parity = match line.parity {
        Parity::None => tokio_serial::Parity::None,
        Parity::Even => tokio_serial::Parity::Even,
        Parity::Odd => tokio_serial::Parity::Odd,
    };
    let stop_bits = if line.stop_bits == 2 {
        StopBits::Two
    } else {
        StopBits::One
    };
    let builder = tokio_serial::new(device, line.baud_rate)
        .data_bits(DataBits::Eight)
        .parity(parity)
        .stop_bits(stop_bits);
    let open = || -> Result<SerialStream, tokio_serial::Error> {
        let port = SerialStream::open(&builder)?;
        port.clear(ClearBuffer::All)?;
        Ok(port)
    };
    let port = open().map_err(|error| ModbusError::Connect {
        address: device.to_owned(),
        source: error.into(),
    })?;
    Ok(tokio_modbus::client::rtu::attach_slave(
        port,
        Slave(unit_id),
    ))
}

/// The silence kept between the end of one frame on a line and the start of the next.
#[derive(Debug)]
pub(crate) struct FrameSpacing {
    silence: Duration,
    /// When the line last fell silent: the last reply, or the last request given up.
    quiet_since: Option<Instant>,
}

impl FrameSpacing {
    /// Spacing of `silence` between frames.
    pub(crate) fn new(silence: Duration) -> Self {
        Self {
            silence,
            quiet_since: None,
        }
    }

    /// Waits until the line has been silent long enough for a request.
    pub(crate) async fn before_request(&self) {
        if let Some(quiet_since) = self.quiet_since {
            tokio::time::sleep_until(quiet_since + self.silence).await;
        }
    }

    /// Marks the line silent from now: a reply was read, or the request given up.
    pub(crate) fn after_reply(&mut self) {
        self.quiet_since = Some(Instant::now());
    }

    /// A new connection: the line is silent since it was opened.
    pub(crate) fn opened(&mut self) {
        self.after_reply();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn a_request_waits_out_the_silence_after_the_last_reply() {
        let silence = Duration::from_micros(4011);
        let mut spacing = FrameSpacing::new(silence);
        let start = Instant::now();
        spacing.before_request().await;
        assert_eq!(Instant::now(), start, "the first request goes at once");
        spacing.after_reply();
        spacing.before_request().await;
        // Never shorter; tokio's timer rounds up to its millisecond tick.
        let waited = Instant::now() - start;
        assert!(
            waited >= silence && waited <= silence + Duration::from_millis(1),
            "{waited:?}"
        );
        // A reply long ago: the line is silent already.
        spacing.after_reply();
        tokio::time::advance(Duration::from_millis(10)).await;
        let later = Instant::now();
        spacing.before_request().await;
        assert_eq!(Instant::now(), later);
    }

    #[test]
    fn a_missing_device_is_a_connect_error_naming_it() {
        let line = SerialLine {
            baud_rate: 9600,
            parity: Parity::None,
            data_bits: 8,
            stop_bits: 2,
            inter_frame_delay: Duration::from_millis(5),
        };
        let Err(error) = connect("/nonexistent/ttyRTU", &line, 1) else {
            panic!("opened a device that does not exist");
        };
        assert!(matches!(error, ModbusError::Connect { .. }), "{error:?}");
        assert!(
            error
                .to_string()
                .starts_with("cannot connect to /nonexistent/ttyRTU: "),
            "{error}"
        );
    }
}

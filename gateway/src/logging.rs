//! The log filter of the `millgate` commands: `RUST_LOG` when set, else the command's
//! level; with either, two libraries' own lines are left out unless `RUST_LOG` names
//! the library:
//!
//! - tokio-modbus' (all): its RTU codec logs a WARN for every frame a device garbles
//!   (a device appending junk made one per poll); the gateway reports each failed
//!   request itself, counted on `/metrics` and rate-limited in the log;
//! - async-opcua server's below WARN: its INFO lines name the internal loopback
//!   listener the front door relays to ("Now listening for connections on
//!   127.0.0.1:..."), an address no client can use; the gateway logs the endpoint
//!   clients connect to itself ("OPC UA server listening").
//!
//! The lines go to stderr (the journal under systemd) as text or, with
//! `log_format = "json"` or `--log-format json`, as one JSON object per line
//! (tracing-subscriber's JSON formatter: `timestamp`, `level`, `target` and `fields`,
//! the message and each field as a JSON value: a bite's TAF a number, not text).

use millgate_config::LogFormat;
use tracing_subscriber::EnvFilter;

/// Send the log lines `filter` lets through to stderr in `format`, for the whole
/// process.
pub fn init(filter: EnvFilter, format: LogFormat) {
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    match format {
        LogFormat::Text => {
            // Colours only on a terminal: journald and log files get plain text.
            let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
            builder.with_ansi(ansi).init();
        }
        LogFormat::Json => builder.json().with_ansi(false).init(),
    }
}

/// The libraries (log targets) whose lines are left out below a level unless
/// `RUST_LOG` names them.
const QUIET: [(&str, &str); 2] = [("tokio_modbus", "off"), ("opcua_server", "warn")];

/// The filter for `rust_log` (the `RUST_LOG` variable, when set and valid) or
/// `default_level`.
pub fn filter(rust_log: Option<&str>, default_level: &str) -> EnvFilter {
    let asked = rust_log.and_then(|text| EnvFilter::try_new(text).ok().map(|f| (text, f)));
    let (text, mut filter) = match asked {
        Some((text, filter)) => (text, filter),
        None => ("", EnvFilter::new(default_level)),
    };
    for (target, level) in QUIET {
        if !text.contains(target) {
            filter = filter.add_directive(
                format!("{target}={level}")
                    .parse()
                    .expect("a valid directive"),
            );
        }
    }
    filter
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use super::filter;

    /// The lines `filter` lets through of a WARN from tokio-modbus' RTU codec and one
    /// from the gateway.
    fn logged(filter: tracing_subscriber::EnvFilter) -> String {
        let buffer = Arc::new(Mutex::new(Vec::<u8>::new()));
        let writer = {
            let buffer = Arc::clone(&buffer);
            move || Writer(Arc::clone(&buffer))
        };
        let subscriber = tracing_subscriber::fmt()
            .with_env_filter(filter)
            .with_writer(writer)
            .with_ansi(false)
            .finish();
        tracing::subscriber::with_default(subscriber, || {
            tracing::warn!(target: "tokio_modbus::codec::rtu", "Failed to decode response frame");
            tracing::warn!(target: "millgate::field::modbus::reader", "DAQ reply rejected");
            tracing::info!(target: "opcua_server::server", "Now listening for connections on 127.0.0.1:40001");
            tracing::warn!(target: "opcua_server::session", "Session timed out");
        });
        let text = String::from_utf8(buffer.lock().unwrap().clone()).unwrap();
        text
    }

    struct Writer(Arc<Mutex<Vec<u8>>>);

    impl std::io::Write for Writer {
        fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(bytes);
            Ok(bytes.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn tokio_modbus_frames_are_quiet_unless_asked_for() {
        for filter in [filter(None, "info"), filter(Some("info"), "warn")] {
            let text = logged(filter);
            assert!(text.contains("DAQ reply rejected"), "{text}");
            assert!(!text.contains("Failed to decode"), "{text}");
        }
        let text = logged(filter(Some("info,tokio_modbus=warn"), "warn"));
        assert!(text.contains("Failed to decode"), "asked for: {text}");
    }

    #[test]
    fn the_opcua_servers_info_lines_are_quiet_unless_asked_for() {
        for filter in [filter(None, "info"), filter(Some("debug"), "warn")] {
            let text = logged(filter);
            assert!(!text.contains("Now listening"), "{text}");
            assert!(
                text.contains("Session timed out"),
                "its warnings stay: {text}"
            );
        }
        let text = logged(filter(Some("info,opcua_server=info"), "warn"));
        assert!(text.contains("Now listening"), "asked for: {text}");
    }
}

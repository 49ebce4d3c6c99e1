//! TEMPORARY (issue 42 item 1, the breakdown of bite -> PLC): stage stamps written as
//! text lines to the file named by `MILLGATE_STAGE_TIMINGS` (nothing without it). Each
//! line: a kind, then numbers (ns since the first stamp, or counts). Reverted after
//! the measurement; `gateway/examples/soak/stages.py` reads the file.

use std::io::Write as _;
use std::sync::{Mutex, OnceLock};
use std::time::Instant;

struct Sink {
    base: Instant,
    out: Mutex<std::io::BufWriter<std::fs::File>>,
}

fn sink() -> Option<&'static Sink> {
    static SINK: OnceLock<Option<Sink>> = OnceLock::new();
    SINK.get_or_init(|| {
        let path = std::env::var_os("MILLGATE_STAGE_TIMINGS")?;
        let file = std::fs::File::create(path).ok()?;
        std::thread::spawn(|| loop {
            std::thread::sleep(std::time::Duration::from_millis(500));
            if let Some(sink) = sink() {
                let _ = crate::lock(&sink.out).flush();
            }
        });
        Some(Sink {
            base: Instant::now(),
            out: Mutex::new(std::io::BufWriter::with_capacity(1 << 20, file)),
        })
    })
    .as_ref()
}

/// Whether stamps are written.
pub fn on() -> bool {
    sink().is_some()
}

/// `at` in ns since the base.
pub fn ns(at: Instant) -> i128 {
    sink().map_or(0, |sink| {
        if at >= sink.base {
            at.duration_since(sink.base).as_nanos() as i128
        } else {
            -(sink.base.duration_since(at).as_nanos() as i128)
        }
    })
}

/// Write one line: `kind` and `fields`.
pub fn line(kind: &str, fields: &[i128]) {
    if let Some(sink) = sink() {
        let mut text = String::from(kind);
        for field in fields {
            text.push(' ');
            text.push_str(&field.to_string());
        }
        text.push('\n');
        let _ = crate::lock(&sink.out).write_all(text.as_bytes());
    }
}

/// Thread id as a number (for the jobs' lines).
pub fn thread() -> i128 {
    let id = format!("{:?}", std::thread::current().id());
    id.trim_start_matches("ThreadId(")
        .trim_end_matches(')')
        .parse()
        .unwrap_or(0)
}

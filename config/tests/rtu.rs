//! Modbus RTU sources: the serial line's keys, their defaults and ranges, and the poll
//! plans a line cannot carry, asserting on the messages (key, value, what is allowed,
//! the arithmetic).

use std::path::Path;
use std::time::Duration;

use millgate_config::{from_toml_str, summary, Config, Parity};

/// A valid file: a drive's speed and a torque block over RTU at 19 200 Bd (defaults
/// otherwise), polled every 40 ms.
const BASE: &str = r#"
name = "RTU mill"

[[sources.modbus]]
name = "drive"
device = "/dev/ttyUSB0"
poll_period_ms = 40

[[channels]]
name = "speed"
kind = "process_value"
unit = "m/s"
source = { modbus = "drive", table = "holding", address = 0, type = "f32" }
"#;

/// A torque block channel on the drive at `rate` Hz.
fn with_block(text: &str, rate: f64) -> String {
    format!(
        "{text}\n[[channels]]\nname = \"torque\"\nkind = \"torque\"\nunit = \"kN*m\"\n\
         sample_rate_hz = {rate:?}\nsource = {{ modbus = \"drive\", table = \"input\", block = 0 }}\n"
    )
}

fn parse(text: &str) -> Result<Config, Vec<String>> {
    from_toml_str(text, "mill.toml", Path::new("."))
        .map_err(|error| error.problems.iter().map(ToString::to_string).collect())
}

/// `BASE` with `from` replaced by `to`.
fn edited(from: &str, to: &str) -> String {
    assert!(BASE.contains(from), "BASE has no {from:?}");
    BASE.replacen(from, to, 1)
}

/// The only problem of `text`.
fn only_problem(text: &str) -> String {
    let problems = parse(text).expect_err("expected problems");
    assert_eq!(problems.len(), 1, "{problems:#?}");
    problems.into_iter().next().unwrap_or_default()
}

/// The specification's silence in whole microseconds, rounded up: 3.5 characters of
/// `bits` at `baud` (written here from the specification, not from the crate).
fn spec_silence_us(baud: f64, bits: f64) -> u64 {
    (3.5 * bits / baud * 1e6).ceil() as u64
}

#[test]
fn defaults_follow_the_serial_line_specification() {
    let config = parse(BASE).expect("valid");
    let source = &config.modbus_sources[0];
    assert_eq!(source.address, "/dev/ttyUSB0");
    assert_eq!(source.unit_id, 1);
    let line = source.serial.expect("an RTU source");
    assert_eq!(
        (line.baud_rate, line.parity, line.data_bits, line.stop_bits),
        (19_200, Parity::Even, 8, 1)
    );
    // 8E1 is 11 bits a character: 3.5 x 11 / 19 200 s = 2005.2 us.
    assert_eq!(
        line.inter_frame_delay,
        Duration::from_micros(spec_silence_us(19_200.0, 11.0))
    );
    assert!(
        summary(&config).contains(
            "drive: Modbus RTU /dev/ttyUSB0 at 19200 Bd 8E1, silence 2006 us, unit 1, poll every 40 ms"
        ),
        "{}",
        summary(&config)
    );
    // Without parity the specification asks for two stop bits: 11 bits again.
    let none = parse(&edited(
        "poll_period_ms = 40",
        "parity = \"none\"\npoll_period_ms = 40",
    ))
    .expect("valid");
    let line = none.modbus_sources[0].serial.expect("RTU");
    assert_eq!((line.parity, line.stop_bits), (Parity::None, 2));
    // Above 19 200 Bd the silence is a fixed 1.75 ms.
    let fast = parse(&edited(
        "poll_period_ms = 40",
        "baud_rate = 115200\nparity = \"odd\"\nstop_bits = 1\npoll_period_ms = 40",
    ))
    .expect("valid");
    let line = fast.modbus_sources[0].serial.expect("RTU");
    assert_eq!(line.inter_frame_delay, Duration::from_micros(1750));
    assert_eq!(line.format(), "8O1");
}

#[test]
fn exactly_one_of_address_and_device() {
    assert_eq!(
        only_problem(&edited(
            "device = \"/dev/ttyUSB0\"",
            "device = \"/dev/ttyUSB0\"\naddress = \"127.0.0.1:502\""
        )),
        "mill.toml: sources.modbus[0]: both address and device are set (must have exactly one: \
         address = \"host:port\" for Modbus TCP, or device = \"/dev/ttyUSB0\" for Modbus RTU on \
         a serial line)"
    );
    assert!(only_problem(&edited("device = \"/dev/ttyUSB0\"\n", ""))
        .starts_with("mill.toml: sources.modbus[0]: neither address nor device is set"));
    // The line's keys do not belong to a TCP source: each is named.
    let problems = parse(&edited(
        "device = \"/dev/ttyUSB0\"",
        "address = \"127.0.0.1:502\"\nbaud_rate = 9600\nparity = \"even\"",
    ))
    .expect_err("serial keys on TCP");
    assert_eq!(
        problems,
        [
            "mill.toml: sources.modbus[0].baud_rate: only for a Modbus RTU source (device = \
             \"/dev/...\"); a Modbus TCP source (address) has no serial line: remove it",
            "mill.toml: sources.modbus[0].parity: only for a Modbus RTU source (device = \
             \"/dev/...\"); a Modbus TCP source (address) has no serial line: remove it",
        ]
    );
}

#[test]
fn every_line_setting_names_its_key_and_range() {
    let cases = [
        (
            "device = \"/dev/ttyUSB0\"",
            "device = \"ttyUSB0\"",
            "mill.toml: sources.modbus[0].device: \"ttyUSB0\" is not allowed (must be the absolute \
             path of a serial device, e.g. /dev/ttyUSB0, /dev/ttyAMA0 or /dev/serial/by-id/...)",
        ),
        (
            "poll_period_ms = 40",
            "baud_rate = 200\npoll_period_ms = 40",
            "mill.toml: sources.modbus[0].baud_rate: 200 is not allowed (must be 300..=1000000 Bd)",
        ),
        (
            "poll_period_ms = 40",
            "parity = \"mark\"\npoll_period_ms = 40",
            "mill.toml: sources.modbus[0].parity: unknown parity \"mark\" (allowed: none, even, odd)",
        ),
        (
            "poll_period_ms = 40",
            "data_bits = 7\npoll_period_ms = 40",
            "mill.toml: sources.modbus[0].data_bits: 7 is not allowed (must be 8: Modbus RTU sends \
             8-bit bytes)",
        ),
        (
            "poll_period_ms = 40",
            "stop_bits = 3\npoll_period_ms = 40",
            "mill.toml: sources.modbus[0].stop_bits: 3 is not allowed (must be 1..=2)",
        ),
        (
            "poll_period_ms = 40",
            "unit_id = 0\npoll_period_ms = 40",
            "mill.toml: sources.modbus[0].unit_id: 0 is not allowed (must be 1..=247)",
        ),
        (
            "poll_period_ms = 40",
            "unit_id = 248\npoll_period_ms = 40",
            "mill.toml: sources.modbus[0].unit_id: 248 is not allowed (must be 1..=247)",
        ),
        (
            "poll_period_ms = 40",
            "inter_frame_delay_us = 1000\npoll_period_ms = 40",
            "mill.toml: sources.modbus[0].inter_frame_delay_us: 1000 is not allowed (must be \
             2006..=100000 us; at least 3.5 characters of 11 bits at 19200 Bd)",
        ),
        (
            "poll_period_ms = 40",
            "baud_rate = 38400\ninter_frame_delay_us = 1749\npoll_period_ms = 40",
            "mill.toml: sources.modbus[0].inter_frame_delay_us: 1749 is not allowed (must be \
             1750..=100000 us; at least the fixed 1.75 ms above 19200 Bd)",
        ),
        (
            "poll_period_ms = 40",
            "requests_in_flight = 2\npoll_period_ms = 40",
            "mill.toml: sources.modbus[0].requests_in_flight: only for a Modbus TCP source \
             (address): a serial line carries one request at a time: remove it",
        ),
    ];
    for (from, to, expected) in cases {
        assert_eq!(only_problem(&edited(from, to)), expected, "{to}");
    }
    // The RTU range holds even when another line setting is wrong.
    let problems = parse(&edited(
        "poll_period_ms = 40",
        "unit_id = 0\nparity = \"space\"\npoll_period_ms = 40",
    ))
    .expect_err("two problems");
    assert_eq!(
        problems,
        [
            "mill.toml: sources.modbus[0].parity: unknown parity \"space\" (allowed: none, even, odd)",
            "mill.toml: sources.modbus[0].unit_id: 0 is not allowed (must be 1..=247)",
        ]
    );
    // A longer silence than the specification's is allowed (slow devices need it).
    let config = parse(&edited(
        "poll_period_ms = 40",
        "inter_frame_delay_us = 5000\npoll_period_ms = 40",
    ))
    .expect("valid");
    assert_eq!(
        config.modbus_sources[0]
            .serial
            .expect("RTU")
            .inter_frame_delay,
        Duration::from_millis(5)
    );
}

#[test]
fn a_poll_plan_the_line_cannot_carry_is_refused_with_the_arithmetic() {
    // A 122-register block read and a 2-register value at 9600 Bd 8E1 every 50 ms
    // (block period at 200 Hz: 600 ms, so the block rule alone would allow it).
    let text = with_block(
        &edited(
            "poll_period_ms = 40",
            "baud_rate = 9600\npoll_period_ms = 50",
        ),
        200.0,
    );
    // Worked out from the specification: frames 8 + 9 + 8 + 249 = 274 bytes of 11
    // bits; 4 silences of 4011 us = 38.5 bit times each at 9600 Bd.
    let frame_bits = 274.0 * 11.0;
    let silence_bits = spec_silence_us(9600.0, 11.0) as f64 * 1e-6 * 9600.0;
    let bits_per_poll = frame_bits + 4.0 * silence_bits;
    let shortest_ms = (bits_per_poll / 9600.0 * 1e3).floor() as u64 + 1;
    let problem = only_problem(&text);
    let expected = format!(
        "mill.toml: sources.modbus[0].poll_period_ms: 50 ms is not allowed at 9600 Bd (must be \
         >= {shortest_ms} ms, or the baud rate higher): one poll = 2 reads (2 + 122 registers): \
         request + response 8 + 9 + 8 + 249 = 274 bytes x 11 bits (8E1) = {frame_bits} bits, \
         plus 4 silences x {:.1} bits (4.011 ms) = {:.0} bits: {:.0} bits per poll x 20 polls/s \
         = {:.0} bit/s against 9600 Bd",
        silence_bits,
        4.0 * silence_bits,
        bits_per_poll,
        20.0 * bits_per_poll
    );
    assert_eq!(problem, expected);
    // The shortest period it names is accepted, one below it is not.
    let at = |ms: u64| text.replacen("poll_period_ms = 50", &format!("poll_period_ms = {ms}"), 1);
    assert!(parse(&at(shortest_ms)).is_ok());
    assert!(parse(&at(shortest_ms - 1)).is_err());
    // At 115 200 Bd the same plan fits: a block channel where the rate allows.
    let fast = text.replacen("baud_rate = 9600", "baud_rate = 115200", 1);
    assert!(parse(&fast).is_ok(), "{:?}", parse(&fast).err());
}

#[test]
fn a_timeout_shorter_than_the_longest_read_is_refused() {
    // A block read at 9600 Bd 8E1: 257 bytes x 11 bits = 294.5 ms, plus two 4.011 ms
    // silences = 302.5 ms.
    let text = with_block(
        &edited(
            "poll_period_ms = 40",
            "baud_rate = 9600\ntimeout_ms = 300\npoll_period_ms = 400",
        ),
        100.0,
    );
    assert_eq!(
        only_problem(&text),
        "mill.toml: sources.modbus[0].timeout_ms: 300 ms is not allowed (must be > 302.501 ms: \
         a read of 122 registers holds the line that long at 9600 Bd 8E1)"
    );
    assert!(parse(&text.replacen("timeout_ms = 300", "timeout_ms = 303", 1)).is_ok());
}

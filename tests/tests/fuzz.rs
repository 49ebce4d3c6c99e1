//! The fuzz suite: every parser that reads what a peer, a file or a user supplies runs
//! on generated inputs, on the stable toolchain (proptest), and none may panic: the HMI
//! server's frame handling, the DAQ reply decoding (the DAQ reader's checked read
//! through tokio-modbus's client, then the acquisition layout), CAN frame decoding,
//! the configuration loader, the CSV reader and the driveline model loader; with the
//! `opcua` feature (`cargo test -p millgate-tests --features opcua --test fuzz`), the
//! OPC UA server's framing check of what clients send.
//!
//! Each harness mixes structure-aware generation (fields of the format, biased to
//! their edges) with mutation of valid seeds (byte flips, insertions, deletions,
//! truncation, line edits and value swaps), so most inputs get past the first check.
//! Each checks what must hold of any answer, not only that nothing panicked.
//!
//! `cargo test --workspace` (a debug build: tokio-modbus's debug assertions on) runs
//! 1 000 cases per harness, a few seconds; `FUZZ_CASES` sets the count. The fuzz stage
//! of `scripts/test` runs 100 000 per harness in that same debug build (overflow checks
//! on; proptest and the parsers optimised by the dev profile: 53 s of CPU for all seven,
//! the configuration's 29 s the slowest) and prints the counts and times:
//! `FUZZ_CASES=100000 cargo test --workspace --features millgate/opcua,millgate-tests/opcua
//! --test fuzz -- --nocapture`.

use std::cell::RefCell;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use millgate::field::can::CanDecoder;
use millgate::field::modbus::{client, ModbusError};
use millgate::field::quality::{split_saturated, SaturationLimits};
use millgate::field::source_health::SourceHealth;
use millgate::outputs::modbus::frame::Served;
use millgate::outputs::modbus::frame::{self, Policy, Reply};
use millgate::outputs::modbus::register_map::RegisterMap;
use millgate::state::board::Board;
use millgate::state::commands::CommandOrigin;
use millgate::state::commands::{Command, CommandReceiver};
use millgate_config::layout::decode_block;
use millgate_config::RegisterTable;
use proptest::prelude::*;
use proptest::test_runner::{Config, TestCaseError, TestRunner};

/// Cases per harness: `FUZZ_CASES`, 1 000 without it.
fn cases() -> u32 {
    match std::env::var("FUZZ_CASES") {
        Ok(value) => value
            .parse()
            .unwrap_or_else(|_| panic!("FUZZ_CASES={value:?} is not a case count")),
        Err(_) => 1_000,
    }
}

/// Run `test` on `cases()` values of `strategy`, print the count and the time.
fn fuzz<S: Strategy>(
    name: &str,
    strategy: S,
    test: impl FnMut(S::Value) -> Result<(), TestCaseError>,
) where
    S::Value: std::fmt::Debug,
{
    let cases = cases();
    let mut runner = TestRunner::new(Config {
        cases,
        failure_persistence: None,
        // Shrinking a failure would take long; the failing input is printed whole.
        max_shrink_iters: 0,
        ..Config::default()
    });
    let started = Instant::now();
    // TestRunner::run takes an Fn; the harnesses count what they saw.
    let test = RefCell::new(test);
    let outcome = runner.run(&strategy, |value| (test.borrow_mut())(value));
    println!(
        "fuzz {name}: {cases} cases in {:.1} s, no panic",
        started.elapsed().as_secs_f64()
    );
    if let Err(error) = outcome {
        panic!("fuzz {name}: {error}");
    }
}

/// A byte-level mutation of a seed: flip, insert, delete, truncate or duplicate.
#[derive(Debug, Clone)]
enum Mutation {
    Flip(usize, u8),
    Insert(usize, u8),
    Delete(usize),
    Truncate(usize),
    Duplicate(usize, usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        (any::<usize>(), 1..=255u8).prop_map(|(at, bits)| Mutation::Flip(at, bits)),
        (any::<usize>(), any::<u8>()).prop_map(|(at, byte)| Mutation::Insert(at, byte)),
        any::<usize>().prop_map(Mutation::Delete),
        any::<usize>().prop_map(Mutation::Truncate),
        (any::<usize>(), 1..64usize).prop_map(|(at, len)| Mutation::Duplicate(at, len)),
    ]
}

fn mutate(seed: &[u8], mutations: &[Mutation]) -> Vec<u8> {
    let mut bytes = seed.to_vec();
    for mutation in mutations {
        let len = bytes.len();
        match *mutation {
            Mutation::Flip(at, bits) if len > 0 => bytes[at % len] ^= bits,
            Mutation::Insert(at, byte) => bytes.insert(at % (len + 1), byte),
            Mutation::Delete(at) if len > 0 => {
                bytes.remove(at % len);
            }
            Mutation::Truncate(at) => bytes.truncate(at % (len + 1)),
            Mutation::Duplicate(at, span) if len > 0 => {
                let start = at % len;
                let piece = bytes[start..(start + span).min(len)].to_vec();
                bytes.splice(start..start, piece);
            }
            _ => {}
        }
    }
    bytes
}

fn workspace() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

// ---------------------------------------------------------------- HMI server frames

/// What the demo's HMI server answers from, and the analysis' end of its commands.
fn demo_served() -> (Served, CommandReceiver) {
    let config = millgate_config::load(&workspace().join("config/examples/demo.toml")).unwrap();
    let health = vec![Arc::new(SourceHealth::new(
        Duration::from_secs(1),
        Duration::from_secs(5),
    ))];
    let (commands, receiver) = millgate::state::commands::channel();
    let served = Served {
        map: Arc::new(RegisterMap::new(&config)),
        board: Arc::new(Board::new(&config, health)),
        commands,
    };
    (served, receiver)
}

/// A Modbus TCP request built field by field, biased to the edges.
fn modbus_request() -> impl Strategy<Value = Vec<u8>> {
    let unit = prop_oneof![Just(0u8), Just(1), Just(7), Just(255), any::<u8>()];
    let function = prop_oneof![
        Just(3u8),
        Just(4),
        Just(6),
        Just(16),
        Just(15),
        Just(5),
        Just(1),
        Just(0x2b),
        Just(0x83),
        any::<u8>()
    ];
    let word = prop_oneof![
        Just(0u16),
        Just(1),
        Just(8),
        Just(9),
        Just(123),
        Just(124),
        Just(125),
        Just(126),
        Just(0x7fff),
        Just(0x8000),
        Just(0xffff),
        any::<u16>()
    ];
    let body = prop::collection::vec(any::<u8>(), 0..300);
    (
        any::<u16>(),
        prop_oneof![4 => Just(0u16), 1 => any::<u16>()],
        unit,
        function,
        word.clone(),
        word,
        prop_oneof![Just(None), any::<u8>().prop_map(Some)],
        body,
        prop_oneof![4 => Just(None), 1 => any::<u16>().prop_map(Some)],
    )
        .prop_map(
            |(
                transaction,
                protocol,
                unit,
                function,
                address,
                quantity,
                byte_count,
                body,
                length,
            )| {
                let mut pdu = vec![function];
                pdu.extend(address.to_be_bytes());
                pdu.extend(quantity.to_be_bytes());
                if let Some(byte_count) = byte_count {
                    pdu.push(byte_count);
                    pdu.extend(body.iter().take(usize::from(byte_count)));
                }
                let length = length.unwrap_or((pdu.len() + 1) as u16);
                let mut frame = transaction.to_be_bytes().to_vec();
                frame.extend(protocol.to_be_bytes());
                frame.extend(length.to_be_bytes());
                frame.push(unit);
                frame.extend(pdu);
                frame
            },
        )
}

/// Valid requests to mutate: reads, commands, a batch of frames.
fn modbus_seeds() -> Vec<Vec<u8>> {
    let frame = |unit: u8, pdu: &[u8]| {
        let mut frame = vec![0, 7, 0, 0];
        frame.extend(((pdu.len() + 1) as u16).to_be_bytes());
        frame.push(unit);
        frame.extend_from_slice(pdu);
        frame
    };
    vec![
        frame(1, &[3, 0, 0, 0, 48]),
        frame(1, &[4, 0, 16, 0, 22]),
        frame(1, &[6, 0, 8, 0, 1]),
        frame(1, &[16, 0, 8, 0, 2, 4, 0, 1, 0, 1]),
        [frame(1, &[3, 0, 0, 0, 1]), frame(255, &[4, 0, 1, 0, 4])].concat(),
    ]
}

/// Feeds `stream` to the server's framing as a connection would (split at `cut`),
/// answering every whole frame. Checks each answer's shape.
fn serve_stream(
    served: &Served,
    policy: Policy,
    stream: &[u8],
    cut: usize,
) -> Result<(), TestCaseError> {
    let mut buffer = Vec::new();
    for chunk in [
        &stream[..cut.min(stream.len())],
        &stream[cut.min(stream.len())..],
    ] {
        buffer.extend_from_slice(chunk);
        loop {
            match frame::frame_len(&buffer) {
                Ok(Some(len)) => {
                    prop_assert!(len <= frame::MAX_FRAME_LEN && len <= buffer.len());
                    let reply = frame::respond(served, policy, &buffer[..len]);
                    if let Reply::Send(bytes) = &reply {
                        prop_assert_eq!(&bytes[..4], &buffer[..4], "transaction echoed");
                        let length = usize::from(u16::from_be_bytes([bytes[4], bytes[5]]));
                        prop_assert_eq!(length + 6, bytes.len());
                        prop_assert_eq!(bytes[6], buffer[6], "unit echoed");
                        prop_assert_eq!(bytes[7] & 0x7f, buffer[7] & 0x7f, "function echoed");
                        if let Some(code) = reply.exception() {
                            prop_assert!([1, 2, 3, 0x0b].contains(&code), "exception {code}");
                        }
                    } else {
                        prop_assert_eq!(buffer[6], 0, "only broadcasts go unanswered");
                    }
                    buffer.drain(..len);
                }
                Ok(None) => break,
                Err(_) => return Ok(()),
            }
        }
    }
    Ok(())
}

#[test]
fn fuzz_hmi_server_frames() {
    let (served, receiver) = demo_served();
    let receiver = std::sync::Mutex::new(receiver);
    let seeds = modbus_seeds();
    let input = prop_oneof![
        prop::collection::vec(modbus_request(), 1..4).prop_map(|frames| frames.concat()),
        (
            prop::sample::select(seeds),
            prop::collection::vec(mutation(), 1..4)
        )
            .prop_map(|(seed, mutations)| mutate(&seed, &mutations)),
        prop::collection::vec(any::<u8>(), 0..64),
    ];
    fuzz(
        "hmi_server_frames",
        (input, any::<usize>(), any::<bool>()),
        |(stream, cut, commands_allowed)| {
            let policy = Policy {
                unit_id: 1,
                commands_allowed,
                origin: CommandOrigin::Local,
            };
            let cut = if stream.is_empty() {
                0
            } else {
                cut % stream.len()
            };
            let served = serve_stream(&served, policy, &stream, cut);
            // The analysis' end: take what the frames commanded, each a valid command.
            let mut receiver = receiver.lock().unwrap_or_else(|e| e.into_inner());
            while let Ok(command) = receiver.try_recv() {
                if let Command::ResetWear { driveline, .. } = command {
                    prop_assert_eq!(driveline, 0, "the demo has one driveline");
                }
            }
            served
        },
    );
    // The commands the fuzzer sent never wrote anything but command registers: every
    // result the map publishes is still unset.
    let results = served.board.results();
    assert!(results.drivelines[0].taf.is_none() && results.drivelines[0].bite_counter == 0);
}

// ---------------------------------------------------------------- DAQ replies

/// An FC 04 reply for transaction 0 (the client's first), biased to the layout's edges.
fn daq_reply() -> impl Strategy<Value = Vec<u8>> {
    let count = prop_oneof![
        Just(0u16),
        Just(1),
        Just(100),
        Just(120),
        Just(121),
        Just(0xffff),
        any::<u16>()
    ];
    let sample = prop_oneof![
        Just(i16::MIN),
        Just(i16::MIN + 1),
        Just(i16::MAX),
        Just(0),
        any::<i16>()
    ];
    (
        prop_oneof![4 => Just(0u16), 1 => any::<u16>()],
        prop_oneof![4 => Just(0x04u8), 1 => Just(0x84), 1 => any::<u8>()],
        any::<u16>(),
        count,
        prop::collection::vec(sample, 0..125),
        prop_oneof![4 => Just(None), 1 => any::<u8>().prop_map(Some)],
        prop_oneof![4 => Just(None), 1 => any::<u16>().prop_map(Some)],
    )
        .prop_map(
            |(transaction, function, sequence, count, samples, byte_count, length)| {
                let mut words = vec![sequence, count];
                words.extend(samples.iter().map(|&s| s as u16));
                let byte_count = byte_count.unwrap_or((words.len() * 2).min(255) as u8);
                let mut pdu = vec![function, byte_count];
                for word in &words {
                    pdu.extend(word.to_be_bytes());
                }
                let length = length.unwrap_or((pdu.len() + 1).min(0xffff) as u16);
                let mut frame = transaction.to_be_bytes().to_vec();
                frame.extend([0, 0]);
                frame.extend(length.to_be_bytes());
                frame.push(1);
                frame.extend(pdu);
                frame
            },
        )
}

/// One poll, as the DAQ reader makes it ([`client::read`]), of a DAQ
/// that answers `reply` and hangs up; a block's registers are then decoded and split
/// at saturated samples.
async fn poll_once(reply: &[u8]) -> Result<(), TestCaseError> {
    use tokio::io::AsyncWriteExt;
    let (client_io, mut daq_io) = tokio::io::duplex(4096);
    daq_io.write_all(reply).await.unwrap();
    daq_io.shutdown().await.unwrap();
    let mut client = tokio_modbus::client::tcp::attach_slave(client_io, tokio_modbus::Slave(1));
    let read = client::read(
        &mut client,
        (RegisterTable::Input, 0, 122),
        Duration::from_secs(1),
    )
    .await;
    prop_assert!(
        !matches!(read, Err(ModbusError::Timeout(_))),
        "the client hung on a reply that ended"
    );
    if let Ok(registers) = read {
        prop_assert_eq!(registers.len(), 122, "only whole replies get through");
        if let Ok(block) = decode_block(&registers) {
            prop_assert!((1..=120).contains(&block.raw.len()));
            let values: Vec<f64> = block
                .values(millgate_config::Scaling::new(0.01, 0.0))
                .collect();
            let limits = SaturationLimits {
                low: -327.67,
                high: 327.67,
            };
            let mut messages = Vec::new();
            let handed = (None, Instant::now());
            let saturated = split_saturated(&limits, 0, values.clone(), handed, &mut messages);
            let saturated_in = values.iter().filter(|&&v| limits.saturated(v)).count() as u64;
            prop_assert_eq!(saturated, saturated_in);
        }
    }
    drop(daq_io);
    Ok(())
}

#[test]
fn fuzz_daq_replies() {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let good = {
        let mut words = vec![5u16, 3, 100, 200, 300];
        words.resize(122, 0);
        let mut frame = vec![0, 0, 0, 0, 0, 247, 1, 4, 244];
        for word in words {
            frame.extend(word.to_be_bytes());
        }
        frame
    };
    let input = prop_oneof![
        3 => daq_reply(),
        2 => prop::collection::vec(mutation(), 1..4).prop_map(move |m| mutate(&good, &m)),
        1 => prop::collection::vec(any::<u8>(), 0..64),
    ];
    fuzz("daq_replies", input, |reply| {
        runtime.block_on(poll_once(&reply))
    });
}

// ---------------------------------------------------------------- CAN frames

#[test]
fn fuzz_can_frames() {
    use millgate_config::frame::parse_frame;
    let config = millgate_config::load(&workspace().join("config/examples/hot-mill.toml")).unwrap();
    let decoder = CanDecoder::for_source(&config, 0);
    // Every id the DBC knows, some it does not.
    let id = prop_oneof![
        Just(257u32),
        Just(258),
        Just(512),
        Just(2566871553 & 0x1fff_ffff),
        any::<u32>()
    ];
    let frame = (
        id,
        any::<bool>(),
        prop::collection::vec(any::<u8>(), 0..=64),
    );
    // Raw socket reads: classic (16 bytes) and FD (72 bytes) frames, and any length.
    let raw = prop_oneof![
        prop::collection::vec(any::<u8>(), 16),
        prop::collection::vec(any::<u8>(), 72),
        prop::collection::vec(any::<u8>(), 0..100),
    ];
    let mut samples = Vec::new();
    fuzz("can_frames", (frame, raw), |((id, extended, data), raw)| {
        samples.clear();
        decoder.decode(id, extended, &data, &mut samples);
        for (channel, value) in &samples {
            prop_assert!(*channel < config.channels.len());
            prop_assert!(value.is_finite(), "channel {channel}: {value}");
        }
        if let Some(frame) = parse_frame(&raw) {
            prop_assert!(frame.data.len() <= 64);
            samples.clear();
            decoder.decode(frame.id, frame.extended, frame.data, &mut samples);
        }
        Ok(())
    });
}

// ---------------------------------------------------------------- text loaders

/// A line-level edit of a text seed.
#[derive(Debug, Clone)]
enum LineEdit {
    Delete(usize),
    Duplicate(usize),
    Swap(usize, usize),
    /// Replace the value after `=` on a line by an edge value.
    Value(usize, &'static str),
}

const EDGE_VALUES: &[&str] = &[
    "0",
    "-1",
    "1e309",
    "-1e309",
    "nan",
    "inf",
    "9223372036854775807",
    "-9223372036854775808",
    "65536",
    "65535",
    "0.0",
    "1e-320",
    "\"\"",
    "\"\\u0000\"",
    "\"a\\nb\"",
    "\"../../../../etc/passwd\"",
    "[]",
    "{}",
    "true",
    "\"0.0.0.0:0\"",
    "\"127.0.0.1:5503\"",
];

fn line_edit() -> impl Strategy<Value = LineEdit> {
    prop_oneof![
        any::<usize>().prop_map(LineEdit::Delete),
        any::<usize>().prop_map(LineEdit::Duplicate),
        (any::<usize>(), any::<usize>()).prop_map(|(a, b)| LineEdit::Swap(a, b)),
        (any::<usize>(), prop::sample::select(EDGE_VALUES))
            .prop_map(|(at, v)| LineEdit::Value(at, v)),
    ]
}

fn edit_lines(text: &str, edits: &[LineEdit]) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    for edit in edits {
        let len = lines.len();
        if len == 0 {
            break;
        }
        match *edit {
            LineEdit::Delete(at) => {
                lines.remove(at % len);
            }
            LineEdit::Duplicate(at) => {
                let line = lines[at % len].clone();
                lines.insert(at % len, line);
            }
            LineEdit::Swap(a, b) => lines.swap(a % len, b % len),
            LineEdit::Value(at, value) => {
                let line = &mut lines[at % len];
                if let Some((key, _)) = line.split_once('=') {
                    *line = format!("{key}= {value}");
                }
            }
        }
    }
    lines.join("\n")
}

/// Seeds edited line by line, then byte by byte.
fn text_input(seeds: Vec<String>) -> impl Strategy<Value = String> {
    (
        prop::sample::select(seeds),
        prop::collection::vec(line_edit(), 0..4),
        prop::collection::vec(mutation(), 0..3),
    )
        .prop_map(|(seed, edits, mutations)| {
            let edited = edit_lines(&seed, &edits);
            String::from_utf8_lossy(&mutate(edited.as_bytes(), &mutations)).into_owned()
        })
}

#[test]
fn fuzz_config_loader() {
    let examples = workspace().join("config/examples");
    let seeds: Vec<String> = ["demo.toml", "hot-mill.toml", "tandem-5stand.toml"]
        .iter()
        .map(|name| std::fs::read_to_string(examples.join(name)).unwrap())
        .collect();
    let mut valid = 0u32;
    fuzz("config_loader", text_input(seeds), |text| {
        match millgate_config::from_toml_str(&text, "fuzz.toml", &examples) {
            Ok(config) => {
                valid += 1;
                // What check and the register export do with a valid file.
                let _ = millgate_config::summary(&config);
                if let Ok(map) =
                    millgate::outputs::modbus::register_map::RegisterMap::try_new(&config)
                {
                    prop_assert!(map.len() >= 16);
                }
            }
            Err(error) => {
                let message = error.to_string();
                prop_assert!(!message.is_empty());
                for line in message.lines() {
                    prop_assert!(line.starts_with("fuzz.toml: "), "{line}");
                }
            }
        }
        Ok(())
    });
    println!("fuzz config_loader: {valid} of the inputs were valid configurations");
}

#[test]
fn fuzz_csv_reader() {
    use millgate::records::csv;
    let cell = prop_oneof![
        "-?[0-9]{1,4}(\\.[0-9]{1,4})?",
        Just(String::new()),
        Just("nan".to_owned()),
        Just("1e400".to_owned()),
        Just(" 1 ".to_owned()),
        Just("t".to_owned()),
        ".{0,3}",
    ];
    let row = prop::collection::vec(cell.clone(), 0..5).prop_map(|cells| cells.join(","));
    let generated = (
        prop::collection::vec(
            prop_oneof![Just("t"), Just("a"), Just("torque"), Just(""), Just("t ")],
            0..5,
        ),
        prop::collection::vec(row, 0..20),
        prop_oneof![Just("\n"), Just("\r\n"), Just("\n\n")],
    )
        .prop_map(|(header, rows, newline)| {
            let mut text = header.join(",");
            for row in rows {
                text.push_str(newline);
                text.push_str(&row);
            }
            text
        });
    let seed: String = std::iter::once("t,torque,speed".to_owned())
        .chain((0..40).map(|k| format!("{},{},{}", f64::from(k) * 5e-4, k * 3, 100 - k)))
        .collect::<Vec<_>>()
        .join("\n");
    let input = prop_oneof![generated, text_input(vec![seed])];
    fuzz("csv_reader", input, |text| {
        if let Ok(table) = csv::parse(&text) {
            prop_assert!(table.time_s.len() >= 2);
            prop_assert!(table.time_s.windows(2).all(|w| w[1] > w[0]));
            prop_assert!(table.channels.iter().all(|c| c.len() == table.time_s.len()));
            if let Ok(rate) = table.sample_rate_hz() {
                prop_assert!(rate > 0.0, "rate {rate}");
            }
        }
        Ok(())
    });
}

#[test]
fn fuzz_model_loader() {
    let models = workspace().join("sim/models");
    let seeds: Vec<String> = [
        "table2-adjusted.toml",
        "table2-adjusted-backlash.toml",
        "table2-drawings.toml",
        "rsm-drive.toml",
    ]
    .iter()
    .map(|name| std::fs::read_to_string(models.join(name)).unwrap())
    .collect();
    let mut valid = 0u32;
    fuzz("model_loader", text_input(seeds), |text| {
        match millgate_sim::model::Model::from_toml_str(&text, "fuzz.toml") {
            Ok(model) => {
                valid += 1;
                // A valid model's modes are computed at start for its wear reference.
                if model.masses.len() <= 8 {
                    let _ = millgate_sim::modal::modes(&model);
                }
            }
            Err(error) => prop_assert!(error.to_string().contains("fuzz.toml")),
        }
        Ok(())
    });
    println!("fuzz model_loader: {valid} of the inputs were valid models");
}

// ---------------------------------------------------------------- OPC UA TCP framing

/// One OPC UA TCP message built field by field: message type and chunk type biased to
/// the known ones, a size field that is right, off by a little, or anything, a body.
#[cfg(feature = "opcua")]
fn opcua_message() -> impl Strategy<Value = Vec<u8>> {
    let kind = prop_oneof![
        Just(*b"HEL"),
        Just(*b"OPN"),
        Just(*b"MSG"),
        Just(*b"CLO"),
        Just(*b"ACK"),
        Just(*b"ERR"),
        Just(*b"RHE"),
        any::<[u8; 3]>()
    ];
    let chunk = prop_oneof![Just(b'F'), Just(b'C'), Just(b'A'), any::<u8>()];
    let size = prop_oneof![
        4 => Just(None),
        1 => prop_oneof![
            Just(0u32),
            Just(7),
            Just(8),
            Just(11),
            Just(12),
            Just(31),
            Just(32),
            Just(4128),
            Just(4129),
            Just(65_535),
            Just(65_536),
            Just(u32::MAX),
            any::<u32>()
        ]
        .prop_map(Some),
    ];
    (
        kind,
        chunk,
        size,
        prop::collection::vec(any::<u8>(), 0..200),
    )
        .prop_map(|(kind, chunk, size, body)| {
            let mut message = kind.to_vec();
            message.push(chunk);
            let size = size.unwrap_or(8 + body.len() as u32);
            message.extend(size.to_le_bytes());
            message.extend(body);
            message
        })
}

#[cfg(feature = "opcua")]
#[test]
fn fuzz_opcua_frames() {
    use millgate::outputs::opcua::front::{FrameScanner, Header};

    let hello = {
        let url = b"opc.tcp://127.0.0.1:4840/";
        let mut message = b"HELF".to_vec();
        message.extend((32 + url.len() as u32).to_le_bytes());
        for word in [0u32, 65_535, 65_535, 0, 0] {
            message.extend(word.to_le_bytes());
        }
        message.extend((url.len() as u32).to_le_bytes());
        message.extend(url);
        message
    };
    let seed = [hello.clone(), {
        let mut open = b"OPNF".to_vec();
        open.extend(132u32.to_le_bytes());
        open.resize(132, 0x5a);
        open
    }]
    .concat();
    let built = prop::collection::vec(opcua_message(), 1..6)
        .prop_map(move |messages| [vec![hello.clone()], messages].concat().concat());
    let mutated = prop::collection::vec(mutation(), 0..8).prop_map(move |m| mutate(&seed, &m));
    let input = (prop_oneof![built, mutated], any::<usize>());
    fuzz("opcua_frames", input, |(stream, split)| {
        // All at once and in two pieces: the same headers, the same verdict.
        let scan = |pieces: &[&[u8]]| {
            let mut scanner = FrameScanner::client(65_535);
            let mut headers: Vec<Header> = Vec::new();
            let mut verdict = Ok(());
            for piece in pieces {
                verdict = scanner.feed(piece, |header| headers.push(header));
                if verdict.is_err() {
                    break;
                }
            }
            (headers, verdict)
        };
        let at = split % (stream.len() + 1);
        let whole = scan(&[&stream]);
        let split = scan(&[&stream[..at], &stream[at..]]);
        prop_assert_eq!(&whole, &split);
        // What it lets through (a header that breaks the framing is refused before it
        // is reported) is framed as a client may send: a Hello first, then OPN, MSG or
        // CLO within the buffer.
        let (headers, _) = whole;
        for (index, header) in headers.iter().enumerate() {
            if index == 0 {
                prop_assert_eq!(&header.message_type, b"HEL");
                prop_assert!((32..=4128).contains(&header.size));
            } else {
                prop_assert!(matches!(&header.message_type, b"OPN" | b"MSG" | b"CLO"));
                prop_assert!((12..=65_535).contains(&header.size));
            }
        }
        Ok(())
    });
}

//! Loading configurations: the example files, defaults, and one test per class of
//! error, asserting on the message (file, key path, value, what is allowed).

use std::path::{Path, PathBuf};

use std::time::Duration;
use tempfile::TempDir;

use millgate_config::text::ByteOrder;
use millgate_config::{
    from_toml_str, from_toml_str_with, load, load_uncommissioned, ChannelKind, ChannelSource,
    ChatterDetectorKind, Config, ConfigError, ContextTags, OpcUaSecurityMode, RegisterTable,
    ServiceDirs, ValueType, WordOrder,
};

fn examples_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples")
}

/// A valid file: one DAQ with two torque blocks, a PLC with a process value, the
/// example DBC on CAN, a driveline, a tandem mill, and outputs.
const BASE: &str = r#"
name = "Test mill"

[[sources.modbus]]
name = "daq1"
address = "127.0.0.1:5020"
poll_period_ms = 20

[[sources.modbus]]
name = "plc"
address = "127.0.0.1:5021"
poll_period_ms = 50

[[sources.can]]
name = "stand_can"
interface = "vcan0"
dbc = "mill.dbc"

[[channels]]
name = "spindle_top"
kind = "torque"
unit = "kN*m"
scale = 0.01
sample_rate_hz = 2000.0
source = { modbus = "daq1", table = "input", block = 0 }

[[channels]]
name = "spindle_bottom"
kind = "torque"
unit = "kN*m"
scale = 0.01
sample_rate_hz = 2000.0
source = { modbus = "daq1", table = "input", block = 122 }

[[channels]]
name = "metal_in"
kind = "process_value"
unit = "1"
source = { modbus = "plc", table = "holding", address = 10 }

[[channels]]
name = "acc0"
kind = "acceleration"
unit = "m/s^2"
sample_rate_hz = 4000.0
source = { can = "stand_can", message = "AccelBurst", signal = "Acc0" }

[[channels]]
name = "acc1"
kind = "acceleration"
unit = "m/s^2"
sample_rate_hz = 4000.0
source = { can = "stand_can", message = "AccelBurst", signal = "Acc1" }

[[drivelines]]
name = "F1"
torque = "spindle_top"
metal_in_stand = "metal_in"
bite = { threshold_knm = 20.0 }
thresholds = { taf_warning = 2.2, taf_alarm = 2.6 }

[[tandem_mills]]
name = "TCM"
stands = ["acc0", "acc1"]
chatter_band_hz = [100.0, 300.0]
window_s = 0.5
k_max = 0.25
gain_thresholds = [1.2, 1.5]

[outputs.plc]
address = "127.0.0.1:5021"
write_period_ms = 100

[outputs.server]
bind = "127.0.0.1:5503"

[outputs.metrics]
"#;

fn parse(text: &str) -> Result<Config, ConfigError> {
    from_toml_str(text, "mill.toml", &examples_dir())
}

/// `BASE` with `from` replaced by `to` (which must change the text).
fn edited(from: &str, to: &str) -> String {
    assert!(BASE.contains(from), "BASE has no {from:?}");
    BASE.replacen(from, to, 1)
}

/// The problems of an invalid text, one string per problem.
fn problems(text: &str) -> Vec<String> {
    match parse(text) {
        Ok(_) => panic!("expected problems, the configuration was accepted"),
        Err(error) => error.problems.iter().map(ToString::to_string).collect(),
    }
}

/// Asserts that each case's text (`text(case)`) is rejected with, among others, a
/// problem starting with `{key}{problem}`.
fn assert_problems_start(text: impl Fn(&str) -> String, key: &str, cases: &[(&str, &str)]) {
    for (case, problem) in cases {
        let found = problems(&text(case));
        assert!(
            found
                .iter()
                .any(|p| p.starts_with(&format!("{key}{problem}"))),
            "{case}: {found:#?}"
        );
    }
}

/// A `process_value` channel `name` at holding register `address` of source `plc`.
fn process_value(name: &str, address: u16) -> String {
    format!(
        "[[channels]]\nname = \"{name}\"\nkind = \"process_value\"\nunit = \"1\"\n\
         source = {{ modbus = \"plc\", table = \"holding\", address = {address} }}\n\n"
    )
}

/// 1-based line number of the first line of `BASE` equal to `line`.
fn line_of(line: &str) -> usize {
    BASE.lines().position(|l| l == line).expect("line in BASE") + 1
}

/// Asserts that `text` is rejected with exactly one problem, equal to `expected`.
fn assert_only_problem(text: &str, expected: &str) {
    assert_eq!(problems(text), vec![expected.to_owned()]);
}

/// Asserts that `text` is rejected with exactly one problem that starts with
/// `start` and contains each of `parts`.
fn assert_problem_like(text: &str, start: &str, parts: &[&str]) {
    let found = problems(text);
    assert_eq!(found.len(), 1, "{found:#?}");
    assert!(
        found[0].starts_with(start),
        "{:?} does not start with {start:?}",
        found[0]
    );
    for part in parts {
        assert!(found[0].contains(part), "{:?} lacks {part:?}", found[0]);
    }
}

#[test]
fn base_is_valid_and_takes_defaults() {
    let config = parse(BASE).unwrap_or_else(|error| panic!("{error}"));
    let daq = &config.modbus_sources[0];
    assert_eq!(daq.unit_id, 1);
    assert_eq!(daq.timeout, Duration::from_millis(1000));
    let metal_in = &config.channels[2];
    assert_eq!((metal_in.scale, metal_in.offset), (1.0, 0.0));
    assert_eq!(metal_in.sample_rate_hz, 20.0, "1 / 50 ms poll period");
    assert_eq!(
        metal_in.source,
        ChannelSource::ModbusValue {
            source: 1,
            table: RegisterTable::Holding,
            address: 10,
            value_type: ValueType::U16,
            word_order: WordOrder::Abcd,
        }
    );
    let bite = config.drivelines[0].bite;
    assert_eq!((bite.pre_trigger_s, bite.post_trigger_s), (0.1, 0.5));
    let thresholds = config.drivelines[0].thresholds;
    assert_eq!(
        (thresholds.gap_warning_mrad, thresholds.gap_alarm_mrad),
        (2.0, 4.0)
    );
    let wear = &config.drivelines[0].wear;
    assert_eq!(wear.couplings, None, "every coupling of the model");
    assert_eq!((wear.max_gap_mrad, wear.gap_step_mrad), (8.0, 0.125));
    assert_eq!(wear.static_torque_knm, None, "from the model");
    assert_eq!((wear.torque_points, wear.horizon_days), (16, 365.0));
    assert_eq!(wear.growth_span_s, 3600.0, "an hour of bites is one gap");
    assert_eq!(config.cache_dir, None, "the user's cache folder");
    let plc = config.outputs.plc.as_ref().expect("plc output");
    assert_eq!((plc.unit_id, plc.register_base), (1, 0));
    assert_eq!(plc.timeout, Duration::from_millis(1000));
    assert!(!plc.extension_blocks, "the first layout only, by default");
    assert_eq!(
        plc.requests_in_flight, 1,
        "one request at a time, by default"
    );
    let server = config.outputs.server.as_ref().expect("server output");
    assert_eq!(server.unit_id, 1);
    assert_eq!(server.max_connections, 8);
    assert_eq!(server.idle_timeout, Duration::from_secs(60));
    assert!(!server.allow_remote_commands);
    let metrics = config.outputs.metrics.as_ref().expect("metrics output");
    assert_eq!(metrics.bind.to_string(), "127.0.0.1:9187");
    assert_eq!(config.channel_index("acc1"), Some(4));
    assert_eq!(config.channel_index("nope"), None);
}

#[test]
fn demo_example() {
    let config = load(&examples_dir().join("demo.toml")).unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(config.modbus_sources.len(), 1);
    let daq = &config.modbus_sources[0];
    assert!(daq.address.starts_with("127.0.0.1:"), "{}", daq.address);
    assert_eq!(config.channels.len(), 1);
    let torque = &config.channels[0];
    assert_eq!(torque.name, "spindle_top");
    assert_eq!(torque.kind, ChannelKind::Torque);
    assert_eq!((torque.scale, torque.sample_rate_hz), (0.01, 2000.0));
    assert_eq!(
        torque.source,
        ChannelSource::ModbusBlock {
            source: 0,
            table: RegisterTable::Input,
            base: 0
        }
    );
    assert_eq!(config.drivelines.len(), 1);
    assert_eq!(config.drivelines[0].torque, 0);
    let plc = config.outputs.plc.as_ref().expect("plc output");
    assert!(plc.address.starts_with("127.0.0.1:"), "{}", plc.address);
    let server = config.outputs.server.as_ref().expect("server output");
    assert!(server.bind.ip().is_loopback());
}

#[test]
fn hot_mill_example() {
    let config =
        load(&examples_dir().join("hot-mill.toml")).unwrap_or_else(|error| panic!("{error}"));
    let driveline = &config.drivelines[0];
    assert_eq!(config.channels[driveline.torque].name, "spindle_top");
    let metal_in = driveline.metal_in_stand.expect("metal in stand");
    assert_eq!(config.channels[metal_in].kind, ChannelKind::ProcessValue);
    assert!(config.can_sources[0].dbc.is_file());
    let ChannelSource::Can { signal_layout, .. } =
        &config.channels[config.channel_index("f1_roll_force").expect("roll force")].source
    else {
        panic!("roll force comes from CAN");
    };
    // RollForce : 35|12@0+ (10,-5000) in BO_ 258 StandStatus: 8.
    assert_eq!(signal_layout.frame_id, 258);
    assert!(!signal_layout.extended && !signal_layout.little_endian && !signal_layout.signed);
    assert_eq!(
        (
            signal_layout.start_bit,
            signal_layout.size,
            signal_layout.frame_len
        ),
        (35, 12, 8)
    );
    assert_eq!(
        (signal_layout.factor, signal_layout.offset),
        (10.0, -5000.0)
    );
    let ChannelSource::Can { signal_layout, .. } =
        &config.channels[config.channel_index("f1_gearbox_oil").expect("oil temp")].source
    else {
        panic!("oil temperature comes from CAN");
    };
    assert_eq!(
        (signal_layout.frame_id, signal_layout.extended),
        (0x18FF_5A01, true)
    );
    let speed = &config.channels[config.channel_index("f1_roll_speed").expect("roll speed")];
    assert!(matches!(
        speed.source,
        ChannelSource::ModbusValue {
            value_type: ValueType::F32,
            word_order: WordOrder::Cdab,
            ..
        }
    ));
    assert!(config.outputs.plc.is_some() && config.outputs.server.is_some());
}

#[test]
fn tandem_example() {
    let config =
        load(&examples_dir().join("tandem-5stand.toml")).unwrap_or_else(|error| panic!("{error}"));
    let mill = &config.tandem_mills[0];
    let stands: Vec<_> = mill
        .stands
        .iter()
        .map(|&i| config.channels[i].name.as_str())
        .collect();
    assert_eq!(stands, ["s1_vib", "s2_vib", "s3_vib", "s4_vib", "s5_vib"]);
    for &stand in &mill.stands {
        assert_eq!(config.channels[stand].kind, ChannelKind::Acceleration);
        assert!(config.channels[stand].sample_rate_hz > 2.0 * mill.chatter_band_hz.1);
    }
    assert_eq!(mill.chatter_band_hz, (100.0, 300.0));
    assert_eq!((mill.window_s, mill.k_max), (0.5, 0.25));
    assert_eq!(mill.detector, ChatterDetectorKind::BandGain);
    assert_eq!(mill.reference_band_hz, (450.0, 900.0));
    assert_eq!(mill.gain_window_s, 2.0);
    assert_eq!(mill.gain_thresholds.len(), 5);
    assert_eq!((mill.slow_down_release, mill.slow_down_hold_s), (0.88, 5.0));
    let metrics = config.outputs.metrics.as_ref().expect("metrics output");
    assert_eq!(
        metrics.bind.to_string(),
        "127.0.0.1:9187",
        "the default bind"
    );
}

#[test]
fn unreadable_file_names_it() {
    let error = load(Path::new("/nonexistent/mill.toml")).expect_err("no such file");
    let text = error.to_string();
    assert!(
        text.starts_with("/nonexistent/mill.toml: cannot read the file: "),
        "{text}"
    );
}

#[test]
fn syntax_errors_give_line_and_column_and_are_all_listed() {
    let text =
        BASE.replacen("poll_period_ms = 20", "poll_period_ms = = 20", 1) + "\n[outputs.extra\n";
    let found = problems(&text);
    assert!(found.len() >= 2, "{found:#?}");
    let line = line_of("poll_period_ms = 20");
    assert!(
        found[0].starts_with(&format!("mill.toml: line {line}, column 18: ")),
        "{found:#?}"
    );
    let last_line = text.lines().count();
    assert!(
        found
            .iter()
            .any(|p| p.starts_with(&format!("mill.toml: line {last_line}, column "))),
        "{found:#?}"
    );
}

#[test]
fn misspelt_keys_are_named_in_every_element() {
    let text = edited("address = \"127.0.0.1:5020\"", "adress = \"127.0.0.1:5020\"")
        .replacen("scale = 0.01\nsample_rate_hz = 2000.0\nsource = { modbus = \"daq1\", table = \"input\", block = 122 }",
                  "scale = 0.01\nsample_rate_hz = 2000.0\nsource = { modbus = \"daq1\", tabel = \"input\", block = 122 }", 1);
    let found = problems(&text);
    assert_eq!(found.len(), 2, "{found:#?}");
    assert!(
        found.iter().any(|p| p.starts_with("mill.toml: sources.modbus[0].adress: unknown field `adress`, expected one of `name`, `address`")),
        "{found:#?}"
    );
    assert!(
        found.iter().any(|p| p
            .starts_with("mill.toml: channels[1].source.tabel: unknown field `tabel`")
            && p.contains("(line ")),
        "{found:#?}"
    );
}

#[test]
fn wrong_types_and_missing_keys_are_named() {
    assert_problem_like(
        &edited("poll_period_ms = 50", "poll_period_ms = \"fast\""),
        "mill.toml: sources.modbus[1].poll_period_ms: invalid type: string \"fast\", expected i64",
        &[&format!(
            "(line {}, column 18)",
            line_of("poll_period_ms = 50")
        )],
    );
    assert_problem_like(
        &edited("unit = \"1\"\n", ""),
        "mill.toml: channels[2]: missing field `unit`",
        &[],
    );
    assert_problem_like(
        &edited("name = \"Test mill\"\n", ""),
        "mill.toml: name: missing",
        &[],
    );
    assert_problem_like(
        &(BASE.to_owned() + "\n[alarms]\nlevel = 1\n"),
        "mill.toml: alarms: unknown key (allowed here: name, sources, channels, drivelines, tandem_mills, rod_mills, outputs, history, cache_dir, log_format, gateway, analysis)",
        &[],
    );
    assert_problem_like(
        &edited("[[sources.can]]", "[[sources.canbus]]"),
        "mill.toml: sources.canbus: unknown key (allowed here: modbus, can)",
        &[],
    );
}

#[test]
fn negative_sample_rate() {
    assert_only_problem(
        &edited("sample_rate_hz = 2000.0\nsource = { modbus = \"daq1\", table = \"input\", block = 122 }",
                "sample_rate_hz = -5\nsource = { modbus = \"daq1\", table = \"input\", block = 122 }"),
        "mill.toml: channels[1].sample_rate_hz: -5 is not allowed (must be > 0 Hz)",
    );
}

#[test]
fn unknown_channel_lists_known_ones() {
    let text = r#"
name = "x"
[[sources.modbus]]
name = "daq1"
address = "127.0.0.1:5020"
poll_period_ms = 20
[[channels]]
name = "spindle_top"
kind = "torque"
unit = "kN*m"
sample_rate_hz = 2000.0
source = { modbus = "daq1", table = "input", block = 0 }
[[channels]]
name = "spindle_bottom"
kind = "torque"
unit = "kN*m"
sample_rate_hz = 2000.0
source = { modbus = "daq1", table = "input", block = 200 }
[[drivelines]]
name = "F1"
torque = "spindel_top"
bite = { threshold_knm = 20.0 }
thresholds = { taf_warning = 2.2, taf_alarm = 2.6 }
"#;
    assert_only_problem(
        text,
        "mill.toml: drivelines[0].torque: unknown channel \"spindel_top\" (known: spindle_top, spindle_bottom)",
    );
}

#[test]
fn unknown_sources_list_known_ones_and_hint_at_the_other_kind() {
    assert_only_problem(
        &edited("{ modbus = \"plc\", table", "{ modbus = \"plcc\", table"),
        "mill.toml: channels[2].source.modbus: unknown Modbus source \"plcc\" (known: daq1, plc)",
    );
    assert_only_problem(
        &edited("{ modbus = \"plc\", table", "{ modbus = \"stand_can\", table"),
        "mill.toml: channels[2].source.modbus: unknown Modbus source \"stand_can\" (known: daq1, plc) \
         (\"stand_can\" is a CAN source: write can = \"stand_can\")",
    );
    let found = problems(&edited(
        "{ can = \"stand_can\", message = \"AccelBurst\", signal = \"Acc0\" }",
        "{ can = \"daq1\", message = \"AccelBurst\", signal = \"Acc0\" }",
    ));
    assert!(
        found.contains(
            &"mill.toml: channels[3].source.can: unknown CAN source \"daq1\" (known: stand_can) \
         (\"daq1\" is a Modbus source: write modbus = \"daq1\")"
                .to_owned()
        ),
        "{found:#?}"
    );
}

#[test]
fn duplicate_names() {
    assert_only_problem(
        &edited("name = \"stand_can\"", "name = \"plc\"")
            .replace("can = \"stand_can\"", "can = \"plc\""),
        "mill.toml: sources.can[0].name: duplicate source name \"plc\" (already used by sources.modbus[1])",
    );
    let found = problems(&edited(
        "name = \"spindle_bottom\"",
        "name = \"spindle_top\"",
    ));
    assert!(found.contains(&"mill.toml: channels[1].name: duplicate channel name \"spindle_top\" (already used by channels[0])".to_owned()), "{found:#?}");
    let two_drivelines = BASE.to_owned()
        + "\n[[drivelines]]\nname = \"F1\"\ntorque = \"spindle_bottom\"\n\
           bite = { threshold_knm = 20.0 }\nthresholds = { taf_warning = 2.2, taf_alarm = 2.6 }\n";
    assert_only_problem(
        &two_drivelines,
        "mill.toml: drivelines[1].name: duplicate driveline name \"F1\" (already used by drivelines[0])",
    );
    let two_mills = BASE.to_owned()
        + "\n[[tandem_mills]]\nname = \"TCM\"\nstands = [\"acc0\", \"acc1\"]\n\
           chatter_band_hz = [100.0, 300.0]\nwindow_s = 0.5\nk_max = 0.25\n\
           detector = \"paper\"\n";
    assert_only_problem(
        &two_mills,
        "mill.toml: tandem_mills[1].name: duplicate tandem mill name \"TCM\" (already used by tandem_mills[0])",
    );
}

#[test]
fn kinds_must_fit_their_use() {
    assert_only_problem(
        &edited("torque = \"spindle_top\"", "torque = \"metal_in\""),
        "mill.toml: drivelines[0].torque: channel \"metal_in\" is a process_value channel (must be torque)",
    );
    assert_only_problem(
        &edited("metal_in_stand = \"metal_in\"", "metal_in_stand = \"spindle_bottom\""),
        "mill.toml: drivelines[0].metal_in_stand: channel \"spindle_bottom\" is a torque channel (must be process_value)",
    );
    assert_only_problem(
        &edited(
            "sample_rate_hz = 4000.0\nsource = { can = \"stand_can\", message = \"AccelBurst\", signal = \"Acc1\" }",
            "sample_rate_hz = 2000.0\nsource = { can = \"stand_can\", message = \"AccelBurst\", signal = \"Acc1\" }",
        ),
        "mill.toml: tandem_mills[0].stands: stand channels \"acc0\" (4000 Hz) and \"acc1\" (2000 Hz) sample at different rates (must share one: the stands are compared sample for sample)",
    );
    assert_only_problem(
        &edited("stands = [\"acc0\", \"acc1\"]", "stands = [\"acc0\", \"spindle_top\"]"),
        "mill.toml: tandem_mills[0].stands[1]: channel \"spindle_top\" is a torque channel (must be acceleration)",
    );
    assert_only_problem(
        &edited("kind = \"process_value\"", "kind = \"process\""),
        "mill.toml: channels[2].kind: unknown kind \"process\" (allowed: torque, acceleration, process_value)",
    );
    assert_problem_like(
        &edited("unit = \"kN*m\"", "unit = \"N*m\""),
        "mill.toml: channels[0].unit: \"N*m\" is not allowed for a torque channel (must be \"kN*m\"",
        &[],
    );
}

#[test]
fn stand_count_and_repeats() {
    assert_only_problem(
        &edited("stands = [\"acc0\", \"acc1\"]", "stands = [\"acc0\"]"),
        "mill.toml: tandem_mills[0].stands: 1 stands is not allowed (must be 2..=8 stand channels)",
    );
    let nine = format!("stands = [{}]", ["\"acc0\""; 9].join(", "));
    let found = problems(&edited("stands = [\"acc0\", \"acc1\"]", &nine));
    assert!(found.contains(&"mill.toml: tandem_mills[0].stands: 9 stands is not allowed (must be 2..=8 stand channels)".to_owned()), "{found:#?}");
    assert_only_problem(
        &edited(
            "stands = [\"acc0\", \"acc1\"]",
            "stands = [\"acc0\", \"acc1\", \"acc0\"]",
        ),
        "mill.toml: tandem_mills[0].stands[2]: channel \"acc0\" is listed twice",
    );
}

#[test]
fn poll_period_must_beat_the_block_period() {
    // 120 samples at 2000 Hz fill a block every 60 ms.
    assert_only_problem(
        &edited("poll_period_ms = 20", "poll_period_ms = 60").replacen("block = 122", "block = 1000", 1)
            .replacen("sample_rate_hz = 2000.0\nsource = { modbus = \"daq1\", table = \"input\", block = 1000 }",
                      "sample_rate_hz = 1000.0\nsource = { modbus = \"daq1\", table = \"input\", block = 1000 }", 1),
        "mill.toml: sources.modbus[0].poll_period_ms: 60 ms is not allowed (must be < 60 ms: \
         channel \"spindle_top\" (channels[0]) fills a 120-sample block every 60 ms at 2000 Hz, \
         and slower polling loses blocks)",
    );
    assert!(parse(&edited("poll_period_ms = 20", "poll_period_ms = 59")).is_ok());
}

#[test]
fn integer_ranges() {
    assert_only_problem(
        &edited("poll_period_ms = 50", "poll_period_ms = 50\nunit_id = 256"),
        "mill.toml: sources.modbus[1].unit_id: 256 is not allowed (must be 0..=255)",
    );
    assert_only_problem(
        &edited("poll_period_ms = 50", "poll_period_ms = 0"),
        "mill.toml: sources.modbus[1].poll_period_ms: 0 is not allowed (must be 1..=60000 ms)",
    );
    assert_only_problem(
        &edited("block = 122", "block = 65415"),
        "mill.toml: channels[1].source.block: 65415 is not allowed (must be 0..=65414)",
    );
    assert!(parse(&edited("block = 122", "block = 65414")).is_ok());
    assert_only_problem(
        &edited("address = 10 }", "address = 65535, type = \"f32\" }"),
        "mill.toml: channels[2].source.address: 65535 is not allowed (must be 0..=65534)",
    );
    assert_only_problem(
        &edited(
            "write_period_ms = 100",
            "write_period_ms = 100\nregister_base = 70000",
        ),
        "mill.toml: outputs.plc.register_base: 70000 is not allowed (must be 0..=65535)",
    );
}

#[test]
fn the_plc_gets_the_extension_blocks_when_asked_and_a_wrong_type_is_named() {
    let config = parse(&edited(
        "write_period_ms = 100",
        "write_period_ms = 100\nextension_blocks = true",
    ))
    .unwrap_or_else(|error| panic!("{error}"));
    assert!(config.outputs.plc.unwrap().extension_blocks);
    let problems = problems(&edited(
        "write_period_ms = 100",
        "write_period_ms = 100\nextension_blocks = \"yes\"",
    ));
    assert!(
        problems
            .iter()
            .any(|p| p.contains("outputs.plc.extension_blocks")),
        "{problems:?}"
    );
}

#[test]
fn the_plc_takes_requests_in_flight_within_their_range() {
    let config = parse(&edited(
        "write_period_ms = 100",
        "write_period_ms = 100\nrequests_in_flight = 16",
    ))
    .unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(config.outputs.plc.unwrap().requests_in_flight, 16);
    for refused in ["0", "17"] {
        assert_only_problem(
            &edited(
                "write_period_ms = 100",
                &format!("write_period_ms = 100\nrequests_in_flight = {refused}"),
            ),
            &format!(
                "mill.toml: outputs.plc.requests_in_flight: {refused} is not allowed (must be 1..=16)"
            ),
        );
    }
}

#[test]
fn a_tcp_source_takes_requests_in_flight_and_a_serial_one_does_not() {
    let config = parse(&edited(
        "poll_period_ms = 20",
        "poll_period_ms = 20\nrequests_in_flight = 8",
    ))
    .unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(config.modbus_sources[0].requests_in_flight, 8);
    assert_eq!(
        parse(BASE).unwrap().modbus_sources[0].requests_in_flight,
        1,
        "one at a time by default"
    );
    assert_only_problem(
        &edited(
            "poll_period_ms = 20",
            "poll_period_ms = 20\nrequests_in_flight = 17",
        ),
        "mill.toml: sources.modbus[0].requests_in_flight: 17 is not allowed (must be 1..=16)",
    );
}

#[test]
fn driveline_slots_reserve_blocks_and_fewer_than_the_drivelines_are_refused() {
    let base = parse(BASE).unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(base.outputs.driveline_slots, None);
    assert_eq!(
        base.driveline_slots(),
        base.drivelines.len(),
        "default: the drivelines"
    );
    let config = parse(&edited(
        "[outputs.plc]",
        "[outputs]\ndriveline_slots = 4\n\n[outputs.plc]",
    ))
    .unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(config.outputs.driveline_slots, Some(4));
    assert_eq!(config.driveline_slots(), 4);
    assert_ne!(config.hash, base.hash, "the key is part of the settings");
    // Fewer slots than drivelines: named with the allowed range.
    let second = "[[tandem_mills]]";
    let f2 = "[[drivelines]]\nname = \"F2\"\ntorque = \"spindle_top\"\n\
              metal_in_stand = \"metal_in\"\nbite = { threshold_knm = 20.0 }\n\
              thresholds = { taf_warning = 2.2, taf_alarm = 2.6 }\n\n";
    let two = edited(second, &format!("{f2}{second}"));
    assert_eq!(parse(&two).map(|c| c.driveline_slots()).ok(), Some(2));
    assert_only_problem(
        &two.replace(
            "[outputs.plc]",
            "[outputs]\ndriveline_slots = 1\n\n[outputs.plc]",
        ),
        "mill.toml: outputs.driveline_slots: 1 is fewer than the 2 drivelines configured \
         (must be 2..=1022: a register block each; raise it, or leave it out for exactly \
         the drivelines)",
    );
    assert_only_problem(
        &edited(
            "[outputs.plc]",
            "[outputs]\ndriveline_slots = 0\n\n[outputs.plc]",
        ),
        "mill.toml: outputs.driveline_slots: 0 is not allowed (must be 1..=1022)",
    );
    assert_only_problem(
        &edited(
            "[outputs.plc]",
            "[outputs]\ndriveline_slots = 1023\n\n[outputs.plc]",
        ),
        "mill.toml: outputs.driveline_slots: 1023 is not allowed (must be 1..=1022)",
    );
}

#[test]
fn value_type_and_word_order_names() {
    assert_only_problem(
        &edited("address = 10 }", "address = 10, type = \"float\" }"),
        "mill.toml: channels[2].source.type: unknown value type (a text is \"ascii\") \"float\" (allowed: u16, i16, u32, i32, f32)",
    );
    assert_only_problem(
        &edited("address = 10 }", "address = 10, type = \"f32\", word_order = \"DCAB\" }"),
        "mill.toml: channels[2].source.word_order: unknown word order \"DCAB\" (allowed: ABCD, CDAB, BADC, DCBA)",
    );
    // A 16-bit value takes a word order too: BADC swaps its two bytes.
    let config = parse(&edited(
        "address = 10 }",
        "address = 10, type = \"i16\", word_order = \"BADC\" }",
    ))
    .unwrap_or_else(|error| panic!("{error}"));
    assert!(matches!(
        config.channels[2].source,
        ChannelSource::ModbusValue {
            value_type: ValueType::I16,
            word_order: WordOrder::Badc,
            ..
        }
    ));
    assert_only_problem(
        &edited("table = \"input\", block = 0 }", "table = \"input\", block = 0, type = \"i16\" }"),
        "mill.toml: channels[0].source.type: does not apply to a block (block samples are i16 in the millgate layout); remove it",
    );
}

#[test]
fn source_forms_must_be_complete_and_exclusive() {
    assert_problem_like(
        &edited(
            "table = \"input\", block = 0 }",
            "table = \"input\", block = 0, address = 5 }",
        ),
        "mill.toml: channels[0].source: must give exactly one of block = <first register>",
        &[],
    );
    assert_problem_like(
        &edited(
            "{ modbus = \"plc\", table = \"holding\", address = 10 }",
            "{ modbus = \"plc\", address = 10 }",
        ),
        "mill.toml: channels[2].source.table: missing (\"input\" for FC 04",
        &[],
    );
    assert_only_problem(
        &edited("{ modbus = \"plc\", table = \"holding\"", "{ modbus = \"plc\", table = \"coils\""),
        "mill.toml: channels[2].source.table: unknown register table \"coils\" (allowed: input, holding)",
    );
    assert_problem_like(
        &edited(
            "{ modbus = \"plc\", table",
            "{ modbus = \"plc\", can = \"stand_can\", table",
        ),
        "mill.toml: channels[2].source: must name exactly one source",
        &[],
    );
    assert_problem_like(
        &edited("unit = \"1\"\n", "unit = \"1\"\nsample_rate_hz = 10.0\n"),
        "mill.toml: channels[2].sample_rate_hz: not used for a register value",
        &[],
    );
    assert_only_problem(
        &edited("unit = \"1\"\n", "unit = \"1\"\nscale = 0.0\n"),
        "mill.toml: channels[2].scale: 0 is not allowed (must be finite and non-zero)",
    );
}

#[test]
fn float_ranges() {
    assert_only_problem(
        &edited("taf_warning = 2.2, taf_alarm = 2.6", "taf_warning = 1.0, taf_alarm = 2.6"),
        "mill.toml: drivelines[0].thresholds.taf_warning: 1 is not allowed (must be > 1: TAF is peak over static torque)",
    );
    assert_only_problem(
        &edited("taf_warning = 2.2, taf_alarm = 2.6", "taf_warning = 2.2, taf_alarm = 2.0"),
        "mill.toml: drivelines[0].thresholds.taf_alarm: 2 is not allowed (must be >= taf_warning = 2.2)",
    );
    assert_only_problem(
        &edited(
            "threshold_knm = 20.0 }",
            "threshold_knm = 20.0, post_trigger_s = 0.0 }",
        ),
        "mill.toml: drivelines[0].bite.post_trigger_s: 0 is not allowed (must be > 0 and <= 10 s)",
    );
    assert_only_problem(
        &edited("threshold_knm = 20.0 }", "threshold_knm = nan }"),
        "mill.toml: drivelines[0].bite.threshold_knm: NaN is not allowed (must be > 0 kN*m)",
    );
    for k_max in ["0.0", "1.0"] {
        assert_problem_like(
            &edited("k_max = 0.25", &format!("k_max = {k_max}")),
            "mill.toml: tandem_mills[0].k_max: ",
            &["is not allowed (must be > 0 and < 1"],
        );
    }
}

#[test]
fn wear_settings_and_gap_thresholds() {
    let text = edited(
        "taf_warning = 2.2, taf_alarm = 2.6 }",
        "taf_warning = 2.2, taf_alarm = 2.6, gap_warning_mrad = 1.5, gap_alarm_mrad = 3 }\n\
         wear = { couplings = [1], max_gap_mrad = 6, gap_step_mrad = 0.25, \
         static_torque_knm = [30, 200], torque_points = 8, pool_bites = 10, \
         horizon_days = 90, growth_span_s = 0 }",
    )
    .replacen(
        "name = \"Test mill\"",
        "name = \"Test mill\"\ncache_dir = \"cache\"",
        1,
    );
    let config = parse(&text).unwrap_or_else(|error| panic!("{error}"));
    let driveline = &config.drivelines[0];
    assert_eq!(driveline.thresholds.gap_warning_mrad, 1.5);
    assert_eq!(driveline.thresholds.gap_alarm_mrad, 3.0);
    assert_eq!(driveline.wear.couplings, Some(vec![1]));
    assert_eq!(driveline.wear.max_gap_mrad, 6.0);
    assert_eq!(driveline.wear.gap_step_mrad, 0.25);
    assert_eq!(driveline.wear.static_torque_knm, Some((30.0, 200.0)));
    assert_eq!(driveline.wear.torque_points, 8);
    // pool_bites is deprecated: accepted, checked, without effect.
    assert_eq!(driveline.wear.horizon_days, 90.0);
    assert_eq!(driveline.wear.growth_span_s, 0.0);
    assert_eq!(config.cache_dir, Some(examples_dir().join("cache")));

    let wear = |table: &str| {
        edited(
            "taf_warning = 2.2, taf_alarm = 2.6 }",
            &format!("taf_warning = 2.2, taf_alarm = 2.6 }}\nwear = {{ {table} }}"),
        )
    };
    assert_only_problem(
        &wear("couplings = [0, 0]"),
        "mill.toml: drivelines[0].wear.couplings[1]: 0 is listed twice",
    );
    assert_only_problem(
        &wear("couplings = [-1]"),
        "mill.toml: drivelines[0].wear.couplings[0]: -1 is not allowed (must be a coupling index of the model, >= 0)",
    );
    assert_only_problem(
        &wear("couplings = []"),
        "mill.toml: drivelines[0].wear.couplings: must name at least one coupling (leave the key out for all of them)",
    );
    assert_only_problem(
        &wear("max_gap_mrad = 0"),
        "mill.toml: drivelines[0].wear.max_gap_mrad: 0 is not allowed (must be > 0 and <= 100 mrad)",
    );
    assert_problem_like(
        &wear("gap_step_mrad = 0.01"),
        "mill.toml: drivelines[0].wear.gap_step_mrad: 0.01 is not allowed (must be > 0 mrad",
        &["max_gap_mrad / 400"],
    );
    assert_only_problem(
        &wear("static_torque_knm = [100, 50]"),
        "mill.toml: drivelines[0].wear.static_torque_knm: [100.0, 50.0] is not allowed (must be [low, high] in kN*m with 0 < low < high)",
    );
    assert_only_problem(
        &wear("torque_points = 2"),
        "mill.toml: drivelines[0].wear.torque_points: 2 is not allowed (must be 3..=64)",
    );
    assert_only_problem(
        &wear("pool_bites = 0"),
        "mill.toml: drivelines[0].wear.pool_bites: 0 is not allowed (must be 1..=1000 bites)",
    );
    assert_only_problem(
        &wear("horizon_days = 0.5"),
        "mill.toml: drivelines[0].wear.horizon_days: 0.5 is not allowed (must be >= 1 and <= 3650 days)",
    );
    assert_only_problem(
        &wear("growth_span_s = -1"),
        "mill.toml: drivelines[0].wear.growth_span_s: -1 is not allowed (must be >= 0 and <= 2592000 s (30 days))",
    );
    assert_problem_like(
        &wear("pool = 3"),
        "mill.toml: drivelines[0].wear.pool: unknown field `pool`",
        &["pool_bites"],
    );
    assert_only_problem(
        &edited(
            "taf_warning = 2.2, taf_alarm = 2.6",
            "taf_warning = 2.2, taf_alarm = 2.6, gap_warning_mrad = 3, gap_alarm_mrad = 2",
        ),
        "mill.toml: drivelines[0].thresholds.gap_alarm_mrad: 2 is not allowed (must be >= gap_warning_mrad = 3 mrad)",
    );
    assert_only_problem(
        &edited(
            "taf_warning = 2.2, taf_alarm = 2.6",
            "taf_warning = 2.2, taf_alarm = 2.6, gap_warning_mrad = -1",
        ),
        "mill.toml: drivelines[0].thresholds.gap_warning_mrad: -1 is not allowed (must be > 0 mrad)",
    );
    // A warning above the default alarm moves the alarm's default up with it.
    let config = parse(&edited(
        "taf_warning = 2.2, taf_alarm = 2.6",
        "taf_warning = 2.2, taf_alarm = 2.6, gap_warning_mrad = 5",
    ))
    .unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(config.drivelines[0].thresholds.gap_alarm_mrad, 5.0);
}

#[test]
fn chatter_band() {
    assert_only_problem(
        &edited("chatter_band_hz = [100.0, 300.0]", "chatter_band_hz = [300.0, 100.0]"),
        "mill.toml: tandem_mills[0].chatter_band_hz: [300.0, 100.0] is not allowed (must be [low, high] with 0 < low < high, Hz)",
    );
    assert_problem_like(
        &edited(
            "chatter_band_hz = [100.0, 300.0]",
            "chatter_band_hz = [100.0]",
        ),
        "mill.toml: tandem_mills[0].chatter_band_hz: [100.0] is not allowed",
        &[],
    );
    // The stands sample at 4000 Hz: the band must stay below 2000 Hz.
    assert_only_problem(
        &edited("chatter_band_hz = [100.0, 300.0]", "chatter_band_hz = [500.0, 2000.0]"),
        "mill.toml: tandem_mills[0].chatter_band_hz: upper edge 2000 Hz is not allowed (must be < 2000 Hz, \
         half the 4000 Hz sample rate of stand channel \"acc0\")",
    );
}

#[test]
fn band_gain_keys() {
    let config = parse(BASE).unwrap_or_else(|error| panic!("{error}"));
    let mill = &config.tandem_mills[0];
    assert_eq!(mill.detector, ChatterDetectorKind::BandGain);
    // Defaults: reference band 1.5-3x the chatter band's top, 2 s, release 0.8 for 5 s.
    assert_eq!(mill.reference_band_hz, (450.0, 900.0));
    assert_eq!(mill.gain_window_s, 2.0);
    assert_eq!(mill.gain_thresholds, [1.2, 1.5]);
    assert_eq!((mill.slow_down_release, mill.slow_down_hold_s), (0.8, 5.0));
    let paper = parse(&edited(
        "gain_thresholds = [1.2, 1.5]",
        "detector = \"paper\"\nreference_band_hz = [400.0, 1500.0]\nslow_down_hold_s = 0.0",
    ))
    .unwrap_or_else(|error| panic!("{error}"));
    let mill = &paper.tandem_mills[0];
    assert_eq!(mill.detector, ChatterDetectorKind::Paper);
    assert!(mill.gain_thresholds.is_empty());
    assert_eq!(mill.reference_band_hz, (400.0, 1500.0));
    assert_eq!(mill.slow_down_hold_s, 0.0);
    assert_eq!(
        (
            mill.capture_before_s,
            mill.capture_after_s,
            mill.capture_max_s
        ),
        (5.0, 2.0, 120.0),
        "the capture keys' defaults"
    );

    let key = "mill.toml: tandem_mills[0].";
    for (from, to, problem) in [
        ("gain_thresholds = [1.2, 1.5]", "", "gain_thresholds: missing (the band-gain detector, the default, needs one alarm threshold per stand"),
        ("gain_thresholds = [1.2, 1.5]", "gain_thresholds = [1.2]", "gain_thresholds: 1 values is not allowed (must be one per stand: 2)"),
        ("gain_thresholds = [1.2, 1.5]", "gain_thresholds = [1.2, 0.0]", "gain_thresholds[1]: 0 is not allowed (must be > 0"),
        ("gain_thresholds = [1.2, 1.5]", "gain_thresholds = [1.2, 1.5]\ndetector = \"rms\"", "detector: \"rms\" is not allowed (must be \"band_gain\" or \"paper\")"),
        ("gain_thresholds = [1.2, 1.5]", "gain_thresholds = [1.2, 1.5]\nreference_band_hz = [250.0, 900.0]", "reference_band_hz: lower edge 250 Hz is not allowed (must be >= 300 Hz"),
        ("gain_thresholds = [1.2, 1.5]", "gain_thresholds = [1.2, 1.5]\nreference_band_hz = [900.0, 450.0]", "reference_band_hz: [900.0, 450.0] is not allowed (must be [low, high] with 0 < low < high, Hz)"),
        ("gain_thresholds = [1.2, 1.5]", "gain_thresholds = [1.2, 1.5]\nreference_band_hz = [450.0, 2000.0]", "reference_band_hz: upper edge 2000 Hz is not allowed (must be < 2000 Hz"),
        ("gain_thresholds = [1.2, 1.5]", "gain_thresholds = [1.2, 1.5]\ngain_window_s = 0.0", "gain_window_s: 0 is not allowed (must be > 0 and <= 10 s)"),
        ("gain_thresholds = [1.2, 1.5]", "gain_thresholds = [1.2, 1.5]\nslow_down_release = 1.0", "slow_down_release: 1 is not allowed (must be > 0 and < 1"),
        ("gain_thresholds = [1.2, 1.5]", "gain_thresholds = [1.2, 1.5]\nslow_down_hold_s = -1.0", "slow_down_hold_s: -1 is not allowed (must be >= 0 and <= 600 s)"),
        ("gain_thresholds = [1.2, 1.5]", "gain_thresholds = [1.2, 1.5]\ncapture_before_s = 61.0", "capture_before_s: 61 is not allowed (must be >= 0 and <= 60 s)"),
        ("gain_thresholds = [1.2, 1.5]", "gain_thresholds = [1.2, 1.5]\ncapture_after_s = -0.5", "capture_after_s: -0.5 is not allowed (must be >= 0 and <= 60 s)"),
        ("gain_thresholds = [1.2, 1.5]", "gain_thresholds = [1.2, 1.5]\ncapture_before_s = 10.0\ncapture_max_s = 8.0", "capture_max_s: 8 is not allowed (must be > capture_before_s (10 s) and <= 600 s)"),
    ] {
        assert_problem_like(&edited(from, to), &format!("{key}{problem}"), &[]);
    }
    // A chatter band near Nyquist leaves no room for the default reference band.
    assert_problem_like(
        &edited("chatter_band_hz = [100.0, 300.0]", "chatter_band_hz = [100.0, 1500.0]"),
        "mill.toml: tandem_mills[0].reference_band_hz: upper edge 4500 Hz is not allowed (must be < 2000 Hz",
        &["the default is 1.5 to 3 times the chatter band's upper edge"],
    );
}

#[test]
fn context_tags_and_the_weld_hold() {
    let config = parse(BASE).unwrap_or_else(|error| panic!("{error}"));
    let mill = &config.tandem_mills[0];
    // Defaults: no tags; the weld hold from the closed loop (docs/chatter.md).
    assert_eq!(mill.context, ContextTags::default());
    assert_eq!((mill.weld_settle_s, mill.weld_alarm_factor), (10.0, 2.0));
    let with_tags = |tags: &str| {
        edited(
            "[[tandem_mills]]",
            &format!(
                "{}{}{}[[tandem_mills]]\ncontext = {{ {tags} }}",
                process_value("weld_bit", 20),
                process_value("product_code", 21),
                process_value("line_speed", 22)
            ),
        )
    };
    let config = parse(&with_tags(
        "weld = \"weld_bit\", product = \"product_code\", speed_mpm = \"line_speed\", products = [101, 205]",
    ))
    .unwrap_or_else(|error| panic!("{error}"));
    let mill = &config.tandem_mills[0];
    let name = |index: Option<usize>| index.map(|i| config.channels[i].name.as_str());
    assert_eq!(name(mill.context.weld), Some("weld_bit"));
    assert_eq!(name(mill.context.product), Some("product_code"));
    assert_eq!(name(mill.context.speed_mpm), Some("line_speed"));
    assert_eq!(mill.context.coil, None);
    assert_eq!(mill.context.products, [101, 205]);
    let listed: Vec<&str> = mill.context.tags().map(|(key, _)| key).collect();
    assert_eq!(listed, ["weld", "speed_mpm", "product"]);
    let summary = millgate_config::summary(&config);
    assert!(
        summary.contains(
            "context from the PLC: weld <- weld_bit, speed_mpm <- line_speed, product <- \
             product_code; products 101, 205"
        ) && summary
            .contains("weld hold: the alarm needs 2 times its level during a weld and 10 s after"),
        "{summary}"
    );

    let key = "mill.toml: tandem_mills[0].";
    assert_problems_start(
        with_tags,
        key,
        &[
            ("weld = \"acc0\"", "context.weld: channel \"acc0\" is a acceleration channel (must be process_value)"),
            ("weld = \"nothing\"", "context.weld: unknown channel \"nothing\""),
            ("weld = \"weld_bit\", state = \"weld_bit\"", "context.state: channel \"weld_bit\" is already the weld tag (each tag needs its own process value)"),
            ("product = \"product_code\", products = [101, 101]", "context.products[1]: product 101 is listed twice"),
            ("product = \"product_code\", products = [-1]", "context.products[0]: -1 is not allowed (must be a product code 0..=4294967295)"),
            ("products = [101]", "context.products: needs the product tag"),
            ("weld = \"weld_bit\", colour = \"x\"", "context.colour: unknown field `colour`, expected one of `weld`"),
        ],
    );
    for (to, problem) in [
        (
            "weld_settle_s = 61.0",
            "weld_settle_s: 61 is not allowed (must be >= 0 and <= 60 s)",
        ),
        (
            "weld_alarm_factor = 0.5",
            "weld_alarm_factor: 0.5 is not allowed (must be >= 1 and <= 10",
        ),
    ] {
        assert_problem_like(
            &edited(
                "gain_thresholds = [1.2, 1.5]",
                &format!("gain_thresholds = [1.2, 1.5]\n{to}"),
            ),
            &format!("{key}{problem}"),
            &[],
        );
    }
}

#[test]
fn a_coil_id_as_text_in_registers() {
    let text_channel = |source: &str| {
        format!(
            "[[channels]]\nname = \"coil_text\"\nkind = \"process_value\"\nunit = \"1\"\n\
             source = {{ modbus = \"plc\", table = \"holding\", address = 30{source} }}\n\n"
        )
    };
    let with = |source: &str, tags: &str| {
        edited(
            "[[tandem_mills]]",
            &format!(
                "{}{}[[tandem_mills]]\ncontext = {{ {tags} }}",
                text_channel(source),
                process_value("product_code", 21)
            ),
        )
    };
    let config = parse(&with(
        ", type = \"ascii\", registers = 8",
        "coil = \"coil_text\"",
    ))
    .unwrap_or_else(|error| panic!("{error}"));
    let coil = config.tandem_mills[0].context.coil.expect("the coil tag");
    assert_eq!(
        config.channels[coil].source,
        ChannelSource::ModbusText {
            source: 1,
            table: RegisterTable::Holding,
            address: 30,
            registers: 8,
            byte_order: ByteOrder::HighFirst,
        }
    );
    let summary = millgate_config::summary(&config);
    assert!(
        summary.contains("holding registers 30..=37 (ascii high_first)"),
        "{summary}"
    );
    let config = parse(&with(
        ", type = \"ascii\", registers = 16, byte_order = \"low_first\"",
        "coil = \"coil_text\"",
    ))
    .unwrap_or_else(|error| panic!("{error}"));
    let coil = config.tandem_mills[0].context.coil.expect("the coil tag");
    assert!(matches!(
        config.channels[coil].source,
        ChannelSource::ModbusText {
            registers: 16,
            byte_order: ByteOrder::LowFirst,
            ..
        }
    ));

    let coil_tag = |source: &str| with(source, "coil = \"coil_text\"");
    let key = "mill.toml: channels[5].";
    assert_problems_start(
        coil_tag,
        key,
        &[
            (", type = \"ascii\"", "source.registers: missing (the registers the text spans, 1..=16, two characters each)"),
            (", type = \"ascii\", registers = 17", "source.registers: 17 is not allowed (must be 1..=16 registers, two characters each)"),
            (", type = \"ascii\", registers = 0", "source.registers: 0 is not allowed (must be 1..=16 registers"),
            (", type = \"ascii\", registers = 4, byte_order = \"little\"", "source.byte_order: unknown byte order \"little\" (allowed: high_first, low_first)"),
            (", type = \"ascii\", registers = 4, word_order = \"CDAB\"", "source.word_order: does not apply to a text"),
            (", type = \"u32\", registers = 4", "source.registers: does not apply to a number"),
            (", byte_order = \"low_first\"", "source.byte_order: does not apply to a number"),
        ],
    );
    assert_problems_start(
        |source| {
            coil_tag(source).replace("unit = \"1\"\nsource = { modbus = \"plc\", table = \"holding\", address = 30", "unit = \"1\"\nscale = 2.0\nsource = { modbus = \"plc\", table = \"holding\", address = 30")
        },
        key,
        &[(
            ", type = \"ascii\", registers = 4",
            "scale: does not apply to a text channel (type = \"ascii\")",
        )],
    );
    // Only as the coil tag.
    assert_problems_start(
        |tags| with(", type = \"ascii\", registers = 4", tags),
        "mill.toml: tandem_mills[0].",
        &[
            ("product = \"coil_text\"", "context.product: channel \"coil_text\" is a text channel (type = \"ascii\"): allowed only as a context tag `coil` (context = { coil = \"coil_text\" }), not here"),
            ("speed_mpm = \"coil_text\"", "context.speed_mpm: channel \"coil_text\" is a text channel"),
        ],
    );
}

#[test]
fn weld_bits_per_stand_one_per_stand_and_not_with_the_mills_bit() {
    let with_tags = |tags: &str| {
        edited(
            "[[tandem_mills]]",
            &format!(
                "{}{}{}[[tandem_mills]]\ncontext = {{ {tags} }}",
                process_value("weld_1", 20),
                process_value("weld_2", 21),
                process_value("weld_bit", 22)
            ),
        )
    };
    let config = parse(&with_tags("weld_stands = [\"weld_1\", \"weld_2\"]"))
        .unwrap_or_else(|error| panic!("{error}"));
    let context = &config.tandem_mills[0].context;
    let names: Vec<&str> = context
        .weld_stands
        .iter()
        .map(|&c| config.channels[c].name.as_str())
        .collect();
    assert_eq!(names, ["weld_1", "weld_2"]);
    assert_eq!(context.weld, None);
    assert!(context.has_weld_bits());
    assert_eq!(
        context.tags().count(),
        0,
        "the stands' bits are not mill tags"
    );
    let summary = millgate_config::summary(&config);
    assert!(
        summary.contains("context from the PLC: weld_stands <- weld_1, weld_2")
            && summary.contains("weld hold: the alarm needs 2 times its level"),
        "{summary}"
    );

    let key = "mill.toml: tandem_mills[0].context.";
    assert_problems_start(
        with_tags,
        key,
        &[
            ("weld_stands = []", "weld_stands: [] is not allowed (must be one weld bit per stand"),
            ("weld_stands = [\"weld_1\"]", "weld_stands: 1 channels are not allowed (must be one weld bit per stand: 2, in the order of `stands`)"),
            ("weld_stands = [\"weld_1\", \"weld_2\", \"weld_bit\"]", "weld_stands: 3 channels are not allowed (must be one weld bit per stand: 2"),
            ("weld = \"weld_bit\", weld_stands = [\"weld_1\", \"weld_2\"]", "weld_stands: is not allowed with `weld` (give the mill's weld bit or one per stand, not both)"),
            ("weld_stands = [\"weld_1\", \"nothing\"]", "weld_stands[1]: unknown channel \"nothing\""),
            ("weld_stands = [\"weld_1\", \"acc0\"]", "weld_stands[1]: channel \"acc0\" is a acceleration channel (must be process_value)"),
            ("weld_stands = [\"weld_1\", \"weld_1\"]", "weld_stands[1]: channel \"weld_1\" is already the weld_stands[0] tag (each tag needs its own process value)"),
            ("weld_stands = [\"weld_1\", \"weld_2\"], state = \"weld_2\"", "state: channel \"weld_2\" is already the weld_stands[1] tag"),
        ],
    );
}

#[test]
fn product_groups_and_their_checks() {
    let product_tag = "[[channels]]\nname = \"product_code\"\nkind = \"process_value\"\n\
                       unit = \"1\"\nsource = { modbus = \"plc\", table = \"holding\", \
                       address = 21 }\n\n[[tandem_mills]]\ncontext = { product = \"product_code\" }";
    let with_groups = |context: &str, groups: &str| {
        let text = edited("[[tandem_mills]]", context);
        text.replacen(
            "gain_thresholds = [1.2, 1.5]",
            &format!("gain_thresholds = [1.2, 1.5]\n{groups}"),
            1,
        )
    };
    let group = |name: &str, products: &str, thresholds: &str| {
        format!(
            "[[tandem_mills.product_groups]]\nname = \"{name}\"\nproducts = {products}\n\
             gain_thresholds = {thresholds}\n"
        )
    };
    let two = group("thin", "[101, 102]", "[2.0, 2.5]") + &group("thick", "[201]", "[1.1, 1.3]");
    let config = parse(&with_groups(product_tag, &two)).unwrap_or_else(|error| panic!("{error}"));
    let mill = &config.tandem_mills[0];
    assert_eq!(mill.product_groups.len(), 2);
    assert_eq!(mill.product_groups[0].name, "thin");
    assert_eq!(mill.product_groups[0].products, [101, 102]);
    // A product picks its group's thresholds; any other product the mill's.
    assert_eq!(mill.product_group(102), Some(0));
    assert_eq!(mill.product_group(201), Some(1));
    assert_eq!(mill.product_group(999), None);
    assert_eq!(mill.thresholds_of(Some(0)), [2.0, 2.5]);
    assert_eq!(mill.thresholds_of(Some(1)), [1.1, 1.3]);
    assert_eq!(mill.thresholds_of(None), [1.2, 1.5]);
    let summary = millgate_config::summary(&config);
    assert!(
        summary.contains("product group thin: products [101, 102], thresholds [2.0, 2.5]"),
        "{summary}"
    );
    // Left out: no groups.
    assert!(parse(BASE).unwrap().tandem_mills[0]
        .product_groups
        .is_empty());

    let key = "mill.toml: tandem_mills[0].product_groups";
    for (context, groups, problem) in [
        (
            "[[tandem_mills]]",
            two.clone(),
            format!("{key}: needs the product tag"),
        ),
        (
            product_tag,
            group("thin", "[101]", "[2.0, 2.5]") + &group("thick", "[201, 101]", "[1.1, 1.3]"),
            format!(
                "{key}[1].products[1]: product 101 is already in group \"thin\" (a product is in \
                 one group at most)"
            ),
        ),
        (
            product_tag,
            group("thin", "[101, 101]", "[2.0, 2.5]"),
            format!("{key}[0].products[1]: product 101 is listed twice"),
        ),
        (
            product_tag,
            group("thin", "[]", "[2.0, 2.5]"),
            format!("{key}[0].products: must not be empty"),
        ),
        (
            product_tag,
            group("thin", "[-4]", "[2.0, 2.5]"),
            format!("{key}[0].products[0]: -4 is not allowed (must be a product code 0..=4294967295)"),
        ),
        (
            product_tag,
            group("thin", "[101]", "[2.0, 0.0]"),
            format!("{key}[0].gain_thresholds[1]: 0 is not allowed (must be > 0, a ratio of band RMS values)"),
        ),
        (
            product_tag,
            group("thin", "[101]", "[2.0]"),
            format!("{key}[0].gain_thresholds: 1 values is not allowed (must be one per stand: 2)"),
        ),
        (
            product_tag,
            "[[tandem_mills.product_groups]]\nname = \"thin\"\nproducts = [101]\n".to_owned(),
            format!("{key}[0].gain_thresholds: missing"),
        ),
        (
            product_tag,
            group("thin", "[101]", "[2.0, 2.5]") + &group("thin", "[102]", "[2.0, 2.5]"),
            format!("{key}[1].name: duplicate product group name \"thin\""),
        ),
        (
            &product_tag.replace("product_code\" }", "product_code\", products = [101, 205] }"),
            group("thin", "[101, 102]", "[2.0, 2.5]"),
            format!(
                "{key}[0].products[1]: product 102 is not one of the context's products \
                 (tandem_mills[0].context.products)"
            ),
        ),
    ] {
        let found = problems(&with_groups(context, &groups));
        assert!(
            found.iter().any(|p| p.starts_with(&problem)),
            "{groups}: {found:#?}"
        );
    }
}

#[test]
fn driveline_context_and_the_pooled_speed_range() {
    let config = parse(BASE).unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(config.drivelines[0].context, ContextTags::default());
    assert_eq!(config.drivelines[0].pool_speed_range_mpm, None);
    let with = |keys: &str| {
        edited(
            "[[drivelines]]",
            &format!(
                "[[channels]]\nname = \"mill_state\"\nkind = \"process_value\"\nunit = \"1\"\n\
                 source = {{ modbus = \"plc\", table = \"holding\", address = 30 }}\n\n\
                 [[channels]]\nname = \"mill_speed\"\nkind = \"process_value\"\nunit = \"m/min\"\n\
                 source = {{ modbus = \"plc\", table = \"holding\", address = 31 }}\n\n\
                 [[drivelines]]\n{keys}\n"
            ),
        )
    };
    let config = parse(&with(
        "context = { state = \"mill_state\", speed_mpm = \"mill_speed\" }\npool_speed_range_mpm = [60.0, 400.0]",
    ))
    .unwrap_or_else(|error| panic!("{error}"));
    let driveline = &config.drivelines[0];
    let name = |index: Option<usize>| index.map(|i| config.channels[i].name.as_str());
    assert_eq!(name(driveline.context.state), Some("mill_state"));
    assert_eq!(name(driveline.context.speed_mpm), Some("mill_speed"));
    assert_eq!(driveline.pool_speed_range_mpm, Some((60.0, 400.0)));
    let summary = millgate_config::summary(&config);
    assert!(
        summary
            .contains("    context from the PLC: speed_mpm <- mill_speed, state <- mill_state\n")
            && summary.contains("wear trend pools bites rolled at 60 to 400 m/min"),
        "{summary}"
    );
    let key = "mill.toml: drivelines[0].";
    assert_problems_start(
        with,
        key,
        &[
            ("context = { weld = \"mill_state\" }", "context.weld: is not allowed on a driveline"),
            ("context = { weld_stands = [\"mill_state\"] }", "context.weld_stands: is not allowed on a driveline"),
            ("context = { state = \"spindle_top\" }", "context.state: channel \"spindle_top\" is a torque channel (must be process_value)"),
            ("pool_speed_range_mpm = [60.0, 400.0]", "pool_speed_range_mpm: needs the speed tag"),
            ("context = { speed_mpm = \"mill_speed\" }\npool_speed_range_mpm = [400.0, 60.0]", "pool_speed_range_mpm: [400.0, 60.0] is not allowed (must be [low, high] in m/min with 0 <= low < high)"),
            ("context = { speed_mpm = \"mill_speed\" }\npool_speed_range_mpm = [-1.0, 60.0]", "pool_speed_range_mpm: [-1.0, 60.0] is not allowed"),
        ],
    );
}

#[test]
fn addresses() {
    assert_only_problem(
        &edited("address = \"127.0.0.1:5020\"", "address = \"127.0.0.1\""),
        "mill.toml: sources.modbus[0].address: \"127.0.0.1\" is not allowed (must be host:port with a port 1..=65535, e.g. 192.168.0.10:502 or plc1.local:502)",
    );
    for bad in ["plc.local:0", ":502", "::1:502", "plc:502x"] {
        assert_problem_like(
            &edited(
                "address = \"127.0.0.1:5021\"\nwrite_period_ms",
                &format!("address = \"{bad}\"\nwrite_period_ms"),
            ),
            "mill.toml: outputs.plc.address: ",
            &[&format!("\"{bad}\" is not allowed")],
        );
    }
    for good in ["plc1.local:502", "[::1]:502", "10.0.0.7:65535"] {
        let text = edited(
            "address = \"127.0.0.1:5021\"\nwrite_period_ms",
            &format!("address = \"{good}\"\nwrite_period_ms"),
        );
        assert!(parse(&text).is_ok(), "{good}");
    }
    assert_only_problem(
        &edited("bind = \"127.0.0.1:5503\"", "bind = \"localhost:5503\""),
        "mill.toml: outputs.server.bind: \"localhost:5503\" is not allowed (must be an IP address and port, e.g. 0.0.0.0:502 or 127.0.0.1:5503)",
    );
    assert_problem_like(
        &edited("[outputs.metrics]", "[outputs.metrics]\nbind = \"9187\""),
        "mill.toml: outputs.metrics.bind: \"9187\" is not allowed",
        &[],
    );
}

#[test]
fn listeners_on_the_same_port_are_refused() {
    // The HMI server and the metrics endpoint on one port: the second bind fails at
    // run time, after `check` said OK.
    assert_only_problem(
        &edited(
            "[outputs.metrics]",
            "[outputs.metrics]\nbind = \"127.0.0.1:5503\"",
        ),
        "mill.toml: outputs.metrics.bind: 127.0.0.1:5503 is not allowed: outputs.server.bind \
         (127.0.0.1:5503) listens on the same port; each listener needs its own port",
    );
    // The wildcard covers every address of its family.
    assert_problem_like(
        &edited(
            "[outputs.metrics]",
            "[outputs.metrics]\nbind = \"0.0.0.0:5503\"",
        ),
        "mill.toml: outputs.metrics.bind: 0.0.0.0:5503 is not allowed",
        &[],
    );
    // Another address, another family, or port 0 (the OS picks): no clash.
    for bind in ["127.0.0.2:5503", "[::1]:5503", "127.0.0.1:0"] {
        let text = edited(
            "[outputs.metrics]",
            &format!("[outputs.metrics]\nbind = \"{bind}\""),
        );
        assert!(parse(&text).is_ok(), "{bind}");
    }
    let both_zero = edited("bind = \"127.0.0.1:5503\"", "bind = \"127.0.0.1:0\"").replace(
        "[outputs.metrics]",
        "[outputs.metrics]\nbind = \"127.0.0.1:0\"",
    );
    assert!(parse(&both_zero).is_ok());
}

#[test]
fn server_limits_and_unit_id() {
    let text = edited(
        "bind = \"127.0.0.1:5503\"",
        "bind = \"127.0.0.1:5503\"\nmax_connections = 2\nidle_timeout_ms = 500\n\
         allow_remote_commands = true",
    );
    let config = parse(&text).unwrap_or_else(|error| panic!("{error}"));
    let server = config.outputs.server.unwrap();
    assert_eq!(server.max_connections, 2);
    assert_eq!(
        server.max_connections_per_peer, 2,
        "the default, at most max_connections"
    );
    assert_eq!(server.idle_timeout, Duration::from_millis(500));
    let defaults = parse(BASE).unwrap_or_else(|error| panic!("{error}"));
    let default_server = defaults.outputs.server.unwrap();
    assert_eq!(
        (
            default_server.max_connections,
            default_server.max_connections_per_peer
        ),
        (8, 4)
    );
    assert_only_problem(
        &edited(
            "bind = \"127.0.0.1:5503\"",
            "bind = \"127.0.0.1:5503\"\nmax_connections = 2\nmax_connections_per_peer = 3",
        ),
        "mill.toml: outputs.server.max_connections_per_peer: 3 is not allowed (must be 1..=2, \
         at most outputs.server.max_connections)",
    );
    assert!(server.allow_remote_commands);
    assert_only_problem(
        &edited(
            "bind = \"127.0.0.1:5503\"",
            "bind = \"127.0.0.1:5503\"\nunit_id = 0",
        ),
        "mill.toml: outputs.server.unit_id: 0 is not allowed (must be 1..=255; 0 is the \
         broadcast address, which a server never answers)",
    );
    assert_only_problem(
        &edited(
            "bind = \"127.0.0.1:5503\"",
            "bind = \"127.0.0.1:5503\"\nmax_connections = 0",
        ),
        "mill.toml: outputs.server.max_connections: 0 is not allowed (must be 1..=64)",
    );
    assert_only_problem(
        &edited(
            "bind = \"127.0.0.1:5503\"",
            "bind = \"127.0.0.1:5503\"\nidle_timeout_ms = 50",
        ),
        "mill.toml: outputs.server.idle_timeout_ms: 50 is not allowed (must be 100..=3600000 ms)",
    );
}

#[test]
fn names_with_control_characters_are_refused() {
    // A NUL or a line break in a name would cut or forge log lines, register names
    // and Prometheus labels.
    assert_only_problem(
        &edited("name = \"F1\"", "name = \"F1\\nF2\""),
        "mill.toml: drivelines[0].name: \"F1\\nF2\" is not allowed (must not contain control \
         characters; U+000A at byte 2)",
    );
    assert_problem_like(
        &edited("name = \"Test mill\"", "name = \"Test\\u0000mill\""),
        "mill.toml: name: ",
        &["U+0000 at byte 4"],
    );
    let found = problems(&edited("name = \"daq1\"", "name = \"daq\\r1\""));
    assert!(
        found
            .iter()
            .any(|p| p.starts_with("mill.toml: sources.modbus[0].name: ") && p.contains("U+000D")),
        "{found:#?}"
    );
    // Other problems quote the refused name (in a list of known sources): escaped, so
    // every line of the report still names the file (found by the fuzz suite).
    let found = problems(&edited("name = \"daq1\"", "name = \"daq\n1\""));
    assert!(found.len() > 1, "{found:#?}");
    let report = found.join("\n");
    for line in report.lines() {
        assert!(line.starts_with("mill.toml: "), "{line:?} in {found:#?}");
    }
}

#[test]
fn overlapping_registers() {
    assert_only_problem(
        &edited("block = 122", "block = 100"),
        "mill.toml: channels[1].source.block: registers 100..=221 overlap registers 0..=121 of channel \
         \"spindle_top\" in the input registers of source \"daq1\"",
    );
    // The same registers in the other table do not overlap.
    assert!(parse(&edited(
        "table = \"input\", block = 122",
        "table = \"holding\", block = 100"
    ))
    .is_ok());
    // A 32-bit value reaches into the next register.
    let text = edited("address = 10 }", "address = 10, type = \"u32\" }")
        + "\n[[channels]]\nname = \"speed\"\nkind = \"process_value\"\nunit = \"rpm\"\n\
           source = { modbus = \"plc\", table = \"holding\", address = 11 }\n";
    assert_only_problem(
        &text,
        "mill.toml: channels[5].source.address: registers 11..=11 overlap registers 10..=11 of channel \
         \"metal_in\" in the holding registers of source \"plc\"",
    );
}

#[test]
fn can_channels() {
    assert_only_problem(
        &edited(
            "message = \"AccelBurst\", signal = \"Acc0\"",
            "message = \"AccBurst\", signal = \"Acc0\"",
        ),
        "mill.toml: channels[3].source.message: unknown message \"AccBurst\" in mill.dbc \
         (known: SpindleTorque, StandStatus, AccelBurst, GearboxTemp)",
    );
    assert_only_problem(
        &edited("message = \"AccelBurst\", signal = \"Acc0\"", "message = \"AccelBurst\", signal = \"Acc9\""),
        "mill.toml: channels[3].source.signal: unknown signal \"Acc9\" in message AccelBurst of mill.dbc \
         (known: Seq, Acc0, Acc1, Acc2, Acc3, TimestampUs)",
    );
    assert_problem_like(
        &edited("unit = \"m/s^2\"\nsample_rate_hz = 4000.0\nsource = { can = \"stand_can\", message = \"AccelBurst\", signal = \"Acc0\" }",
                "unit = \"m/s^2\"\nscale = 0.5\nsample_rate_hz = 4000.0\nsource = { can = \"stand_can\", message = \"AccelBurst\", signal = \"Acc0\" }"),
        "mill.toml: channels[3].scale: not allowed on a CAN channel: the DBC's factor and offset give the engineering value",
        &[],
    );
    assert_only_problem(
        &edited("signal = \"Acc0\" }", "signal = \"Acc0\", table = \"input\" }"),
        "mill.toml: channels[3].source.table: does not apply to a CAN source (the DBC describes the signal); remove it",
    );
    assert_only_problem(
        &edited(
            "message = \"AccelBurst\", signal = \"Acc0\"",
            "message = \"AccelBurst\"",
        ),
        "mill.toml: channels[3].source.signal: missing (the DBC signal name)",
    );
    let config = parse(BASE).unwrap_or_else(|error| panic!("{error}"));
    let ChannelSource::Can { signal_layout, .. } = &config.channels[3].source else {
        panic!("acc0 comes from CAN");
    };
    // Acc0 : 8|16@1- (0.001,0) in BO_ 512 AccelBurst: 64.
    assert_eq!((signal_layout.frame_id, signal_layout.frame_len), (512, 64));
    assert!(signal_layout.little_endian && signal_layout.signed);
    assert_eq!(
        (
            signal_layout.start_bit,
            signal_layout.size,
            signal_layout.factor
        ),
        (8, 16, 0.001)
    );
    assert_eq!(
        (config.channels[3].scale, config.channels[3].offset),
        (1.0, 0.0)
    );
}

/// A scratch directory `millgate-config-<tag>-XXXXXX`, removed on drop.
fn scratch(tag: &str) -> TempDir {
    tempfile::Builder::new()
        .prefix(&format!("millgate-config-{tag}-"))
        .tempdir()
        .expect("create a scratch directory")
}

/// Write `contents` as `name` in `scratch`.
fn write(scratch: &TempDir, name: &str, contents: &str) {
    std::fs::write(scratch.path().join(name), contents).expect("write a scratch file");
}

const SMALL_DBC: &str = r#"VERSION ""

BS_:

BU_: A

BO_ 100 Muxed: 8 A
 SG_ Mode M : 0|8@1+ (1,0) [0|255] "" A
 SG_ Speed m1 : 8|16@1+ (1,0) [0|0] "" A
 SG_ Level : 24|16@1+ (0,0) [0|0] "" A
 SG_ Wide : 56|16@1+ (1,0) [0|0] "" A

BO_ 101 Floaty: 8 A
 SG_ Temp : 0|32@1- (1,0) [0|0] "" A

SIG_VALTYPE_ 101 Temp : 1;
"#;

fn can_config(signal: (&str, &str)) -> String {
    format!(
        "name = \"x\"\n[[sources.can]]\nname = \"bus\"\ninterface = \"vcan0\"\ndbc = \"small.dbc\"\n\
         [[channels]]\nname = \"c\"\nkind = \"process_value\"\nunit = \"1\"\nsample_rate_hz = 10.0\n\
         source = {{ can = \"bus\", message = \"{}\", signal = \"{}\" }}\n",
        signal.0, signal.1
    )
}

#[test]
fn unsupported_dbc_signals() {
    let scratch = scratch("dbc");
    write(&scratch, "small.dbc", SMALL_DBC);
    let problems_of = |signal| {
        from_toml_str(&can_config(signal), "mill.toml", scratch.path())
            .expect_err("unsupported")
            .to_string()
    };
    assert_eq!(
        problems_of(("Muxed", "Speed")),
        "mill.toml: channels[0].source.signal: signal \"Speed\" of message Muxed in small.dbc: \
         multiplexed signals are not supported"
    );
    assert_eq!(
        problems_of(("Floaty", "Temp")),
        "mill.toml: channels[0].source.signal: signal \"Temp\" of message Floaty in small.dbc: \
         IEEE float signals are not supported"
    );
    assert!(problems_of(("Muxed", "Level")).contains("the factor non-zero"));
    assert!(problems_of(("Muxed", "Wide"))
        .contains("signal needs 9 bytes but the message is 8 bytes long"));
}

#[test]
fn dbc_file_problems_name_the_file() {
    let scratch = scratch("baddbc");
    assert_problem_like_in(
        scratch.path(),
        &can_config(("M", "S")),
        "mill.toml: sources.can[0].dbc: file \"small.dbc\" not found",
    );
    write(&scratch, "small.dbc", "VERSION \"\"\nBO_ nonsense here\n");
    assert_problem_like_in(
        scratch.path(),
        &can_config(("M", "S")),
        "mill.toml: sources.can[0].dbc: DBC file \"small.dbc\": cannot parse: ",
    );
}

fn assert_problem_like_in(base_dir: &Path, text: &str, start: &str) {
    let error = from_toml_str(text, "mill.toml", base_dir).expect_err("rejected");
    assert_eq!(error.problems.len(), 1, "{error}");
    let found = error.to_string();
    assert!(
        found.starts_with(start),
        "{found:?} does not start with {start:?}"
    );
    assert!(!found.contains('\n'), "one line: {found:?}");
}

#[test]
fn model_path_is_relative_to_the_file_and_must_exist() {
    let scratch = scratch("model");
    std::fs::copy(
        examples_dir().join("mill.dbc"),
        scratch.path().join("mill.dbc"),
    )
    .expect("copy the DBC");
    let text = edited(
        "metal_in_stand = \"metal_in\"",
        "metal_in_stand = \"metal_in\"\nmodel = \"f1-model.toml\"",
    );
    let error = from_toml_str(&text, "mill.toml", scratch.path()).expect_err("no model yet");
    assert_eq!(error.problems.len(), 1, "{error}");
    assert!(
        error
            .to_string()
            .starts_with("mill.toml: drivelines[0].model: file \"f1-model.toml\" not found"),
        "{error}"
    );
    write(&scratch, "f1-model.toml", "");
    let config =
        from_toml_str(&text, "mill.toml", scratch.path()).unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(
        config.drivelines[0].model,
        Some(scratch.path().join("f1-model.toml"))
    );
    // With a model, the gap alarm must lie inside the maps (they end at max_gap_mrad).
    let beyond = text.replacen(
        "taf_warning = 2.2, taf_alarm = 2.6",
        "taf_warning = 2.2, taf_alarm = 2.6, gap_alarm_mrad = 8",
        1,
    );
    let error = from_toml_str(&beyond, "mill.toml", scratch.path()).expect_err("alarm at the end");
    assert_eq!(
        error.to_string(),
        "mill.toml: drivelines[0].thresholds.gap_alarm_mrad: 8 mrad is not allowed (must be < drivelines[0].wear.max_gap_mrad = 8 mrad: the gap maps end there)"
    );
}

#[test]
fn every_problem_is_listed_at_once() {
    let text = edited("poll_period_ms = 50", "poll_period_ms = 50\nunit_id = 300")
        .replacen("torque = \"spindle_top\"", "torque = \"spindel_top\"", 1)
        .replacen("k_max = 0.25", "k_max = 2.5", 1)
        .replacen("bind = \"127.0.0.1:5503\"", "bind = \"nowhere\"", 1);
    let found = problems(&text);
    let keys: Vec<_> = found
        .iter()
        .map(|p| p.split(": ").nth(1).expect("key").to_owned())
        .collect();
    assert_eq!(
        keys,
        [
            "sources.modbus[1].unit_id",
            "drivelines[0].torque",
            "tandem_mills[0].k_max",
            "outputs.server.bind"
        ]
    );
}

#[test]
fn history_path_retention_and_size() {
    let scratch = scratch("history");
    let dbc = std::fs::read_to_string(examples_dir().join("mill.dbc")).unwrap();
    write(&scratch, "mill.dbc", &dbc);
    let with = |history: &str| format!("{BASE}\n[history]\n{history}\n");
    let config = from_toml_str(
        &with("path = \"data/history.db\""),
        "mill.toml",
        scratch.path(),
    );
    let problems: Vec<String> = config
        .expect_err("the folder does not exist")
        .problems
        .iter()
        .map(ToString::to_string)
        .collect();
    assert_eq!(problems.len(), 1, "{problems:#?}");
    assert!(
        problems[0].starts_with(
            "mill.toml: history.path: the folder of \"data/history.db\" does not exist"
        ),
        "{}",
        problems[0]
    );
    std::fs::create_dir_all(scratch.path().join("data")).unwrap();
    let config = from_toml_str(
        &with("path = \"data/history.db\""),
        "mill.toml",
        scratch.path(),
    )
    .unwrap_or_else(|error| panic!("{error}"));
    let history = config.history.expect("history configured");
    assert_eq!(history.path, scratch.path().join("data/history.db"));
    assert_eq!((history.retention_days, history.max_size_mb), (400, 1024));
    let error = from_toml_str(&with("path = \"data\""), "mill.toml", scratch.path()).unwrap_err();
    assert!(
        error
            .to_string()
            .contains("history.path: \"data\" is a folder"),
        "{error}"
    );
    let error = from_toml_str(
        &with("path = \"h.db\"\nretention_days = 0\nmax_size_mb = 2000000"),
        "mill.toml",
        scratch.path(),
    )
    .unwrap_err();
    assert_eq!(
        error.to_string(),
        "mill.toml: history.retention_days: 0 is not allowed (must be 1..=36500 days)\n\
         mill.toml: history.max_size_mb: 2000000 is not allowed (must be 1..=1048576 MiB)"
    );
    // Captures: on by default with half the file as budget; a budget past half the
    // file, or thinning to every 0th bite, is refused naming the key.
    assert_eq!(
        history.captures,
        millgate_config::CaptureSettings {
            enabled: true,
            max_mb: 512,
            thin_after_days: 7,
            keep_every: 10,
        }
    );
    let error = from_toml_str(
        &with("path = \"h.db\"\nmax_size_mb = 100\ncaptures_max_mb = 60\ncaptures_keep_every = 0"),
        "mill.toml",
        scratch.path(),
    )
    .unwrap_err();
    assert_eq!(
        error.to_string(),
        "mill.toml: history.captures_max_mb: 60 is not allowed (must be 1..=50 MiB (at most half \
         of history.max_size_mb))\n\
         mill.toml: history.captures_keep_every: 0 is not allowed (must be 1..=1000)"
    );
    // Commits: synchronous=NORMAL by default, FULL when asked; anything else refused
    // with the allowed spellings.
    assert_eq!(history.synchronous, millgate_config::Synchronous::Normal);
    let full = from_toml_str(
        &with("path = \"h.db\"\nsynchronous = \"full\""),
        "mill.toml",
        scratch.path(),
    )
    .unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(
        full.history.map(|h| h.synchronous),
        Some(millgate_config::Synchronous::Full)
    );
    let error = from_toml_str(
        &with("path = \"h.db\"\nsynchronous = \"off\""),
        "mill.toml",
        scratch.path(),
    )
    .unwrap_err();
    assert_eq!(
        error.to_string(),
        "mill.toml: history.synchronous: unknown setting \"off\" (allowed: normal, full)"
    );
    let error = from_toml_str(
        &with("path = \"h.db\"\nkeep = 3"),
        "mill.toml",
        scratch.path(),
    )
    .unwrap_err();
    assert!(
        error
            .to_string()
            .starts_with("mill.toml: history.keep: unknown field `keep`"),
        "{error}"
    );
    assert!(parse(BASE).unwrap().history.is_none());
}

/// Under systemd (`StateDirectory=`, `CacheDirectory=`, `LoadCredential=`): a relative
/// history path lands in `$STATE_DIRECTORY`, the cache in `$CACHE_DIRECTORY`, the MQTT
/// password comes from `$CREDENTIALS_DIRECTORY`; problems name the key and the variable.
#[test]
fn systemd_service_folders() {
    let scratch = scratch("service-dirs");
    let config_dir = scratch.path().join("etc");
    let state = scratch.path().join("state");
    let cache = scratch.path().join("cache");
    let credentials = scratch.path().join("credentials");
    for folder in [&config_dir, &state, &cache, &credentials] {
        std::fs::create_dir_all(folder).unwrap();
    }
    let dbc = std::fs::read_to_string(examples_dir().join("mill.dbc")).unwrap();
    std::fs::write(config_dir.join("mill.dbc"), dbc).unwrap();
    std::fs::write(credentials.join("mqtt"), "from-systemd\n").unwrap();
    let systemd = ServiceDirs {
        state: Some(state.clone()),
        cache: Some(cache.clone()),
        credentials: Some(credentials.clone()),
    };
    let outside = ServiceDirs::default();
    let mqtt = "[outputs.mqtt]\nbroker = \"127.0.0.1:1883\"\ngroup_id = \"plant\"\n\
                node_id = \"f1\"\nusername = \"gw\"\n";
    let text = |top: &str, history: &str, password: &str| {
        format!("{top}\n{BASE}\n{mqtt}{password}\n[history]\npath = \"{history}\"\n")
    };
    let load = |text: &str, dirs: &ServiceDirs| {
        from_toml_str_with(text, "mill.toml", &config_dir, dirs).map_err(|error| {
            error
                .problems
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
        })
    };

    let under_systemd = load(
        &text("", "history.db", "password_credential = \"mqtt\""),
        &systemd,
    )
    .unwrap_or_else(|problems| panic!("{problems:#?}"));
    let summary = millgate_config::summary(&under_systemd);
    assert!(
        summary.contains(&format!("History: {}", state.join("history.db").display()))
            && summary.contains(&format!("Cache: {}", cache.display())),
        "{summary}"
    );
    assert_eq!(
        under_systemd.history.unwrap().path,
        state.join("history.db")
    );
    assert_eq!(under_systemd.cache_dir, Some(cache.clone()));
    assert_eq!(
        under_systemd.outputs.mqtt.unwrap().credentials,
        Some(("gw".to_owned(), "from-systemd".to_owned())),
        "the credential's text without its newline"
    );
    // Absolute paths stay; a relative cache_dir is a folder in $CACHE_DIRECTORY.
    let absolute = state.join("elsewhere.db");
    let explicit = load(
        &text(
            "cache_dir = \"maps\"",
            &absolute.display().to_string(),
            "password_credential = \"mqtt\"",
        ),
        &systemd,
    )
    .unwrap_or_else(|problems| panic!("{problems:#?}"));
    assert_eq!(explicit.history.unwrap().path, absolute);
    assert_eq!(explicit.cache_dir, Some(cache.join("maps")));

    // Outside systemd: the configuration's folder, the user's cache folder, and the
    // credential cannot be read.
    let plain = load(&text("", "history.db", "password = \"x\""), &outside)
        .unwrap_or_else(|problems| panic!("{problems:#?}"));
    assert_eq!(plain.history.unwrap().path, config_dir.join("history.db"));
    assert_eq!(plain.cache_dir, None);
    assert_eq!(
        load(
            &text("", "history.db", "password_credential = \"mqtt\""),
            &outside
        )
        .unwrap_err(),
        [
            "mill.toml: outputs.mqtt.password_credential: $CREDENTIALS_DIRECTORY is not set: \
             systemd sets it for a unit with LoadCredential=mqtt:FILE \
             (deploy/millgate.service.d/mqtt-password.conf); outside systemd give \
             password_file instead"
        ]
    );

    // A credential the unit does not load, a name that is not one, two passwords.
    let missing = load(
        &text("", "history.db", "password_credential = \"broker\""),
        &systemd,
    )
    .unwrap_err();
    assert!(
        missing.len() == 1
            && missing[0].starts_with(&format!(
                "mill.toml: outputs.mqtt.password_credential: cannot read credential \"broker\" \
                 ({}: ",
                credentials.join("broker").display()
            ))
            && missing[0].ends_with(&format!(
                "; $CREDENTIALS_DIRECTORY is {}; the unit needs LoadCredential=broker:FILE)",
                credentials.display()
            )),
        "{missing:?}"
    );
    assert_eq!(
        load(
            &text("", "history.db", "password_credential = \"../mqtt\""),
            &systemd
        )
        .unwrap_err(),
        [
            "mill.toml: outputs.mqtt.password_credential: \"../mqtt\" is not a credential name \
             (the ID of LoadCredential=ID:FILE in the unit, a file name without `/`, e.g. \"mqtt\")"
        ]
    );
    assert_eq!(
        load(
            &text(
                "",
                "history.db",
                "password_file = \"secret\"\npassword_credential = \"mqtt\""
            ),
            &systemd
        )
        .unwrap_err(),
        [
            "mill.toml: outputs.mqtt.password_credential: not allowed together with \
             password_file (give one of them)"
        ]
    );

    // A history folder that does not exist says where relative paths go.
    assert_eq!(
        load(
            &text("", "data/history.db", "password_credential = \"mqtt\""),
            &systemd
        )
        .unwrap_err(),
        [format!(
            "mill.toml: history.path: the folder of \"data/history.db\" does not exist (looked \
             for {}; create it, writable by the service's user; relative paths are resolved \
             against $STATE_DIRECTORY ({}))",
            state.join("data").display(),
            state.display()
        )]
    );
    assert_eq!(
        load(&text("", "data/history.db", "password = \"x\""), &outside).unwrap_err(),
        [format!(
            "mill.toml: history.path: the folder of \"data/history.db\" does not exist (looked \
             for {}; create it, writable by the service's user; relative paths are resolved \
             against the configuration file's folder, or $STATE_DIRECTORY when systemd sets it \
             (StateDirectory=))",
            config_dir.join("data").display()
        )]
    );
}

#[test]
fn mqtt_output_keys_defaults_and_errors() {
    let history = format!(
        "\n[history]\npath = \"{}\"\n",
        std::env::temp_dir().join("h.db").display()
    );
    let with = |mqtt: &str| format!("{BASE}\n[outputs.mqtt]\n{mqtt}\n{history}");
    let minimal = "broker = \"127.0.0.1:1883\"\ngroup_id = \"plant\"\nnode_id = \"f1\"";
    let config = parse(&with(minimal)).unwrap();
    let mqtt = config.outputs.mqtt.expect("mqtt configured");
    assert_eq!(mqtt.brokers, ["127.0.0.1:1883"]);
    assert_eq!(mqtt.client_id, "millgate-plant-f1");
    assert_eq!(mqtt.keep_alive, std::time::Duration::from_secs(30));
    assert_eq!(mqtt.data_period, std::time::Duration::from_millis(1000));
    assert_eq!((mqtt.command_qos, mqtt.credentials), (1, None));
    assert_eq!(mqtt.primary_host_id, None);
    assert_eq!(mqtt.replay_batch, 100);
    assert_eq!(mqtt.replay_period, std::time::Duration::from_millis(100));
    let paced = parse(&with(&format!(
        "{minimal}\nreplay_batch = 5\nreplay_period_ms = 250"
    )))
    .unwrap()
    .outputs
    .mqtt
    .unwrap();
    assert_eq!(
        (paced.replay_batch, paced.replay_period),
        (5, std::time::Duration::from_millis(250))
    );
    assert_eq!(
        problems(&with(&format!(
            "{minimal}\nreplay_batch = 0\nreplay_period_ms = 0"
        ))),
        [
            "mill.toml: outputs.mqtt.replay_batch: 0 is not allowed (must be 1..=100000)",
            "mill.toml: outputs.mqtt.replay_period_ms: 0 is not allowed (must be 1..=60000 ms)",
        ]
    );
    let hosted = parse(&with(&format!("{minimal}\nprimary_host_id = \"scada\""))).unwrap();
    assert_eq!(
        hosted.outputs.mqtt.unwrap().primary_host_id.as_deref(),
        Some("scada")
    );
    assert_only_problem(
        &with(&format!("{minimal}\nprimary_host_id = \"#\"")),
        "mill.toml: outputs.mqtt.primary_host_id: \"#\" is not allowed (must be non-empty, without / + or #)",
    );

    assert_eq!(
        problems(&format!("{BASE}\n[outputs.mqtt]\n{minimal}\n")),
        ["mill.toml: outputs.mqtt: needs [history]: the Sparkplug session number (bdSeq) is kept in the history file"]
    );
    let bad = "broker = \"broker\"\ngroup_id = \"a/b\"\nnode_id = \"\"\nkeep_alive_s = 2\n\
               command_qos = 2\nusername = \"u\"\nclient_id = \"\"";
    assert_eq!(
        problems(&with(bad)),
        [
            "mill.toml: outputs.mqtt.broker: \"broker\" is not allowed (must be host:port with a port 1..=65535, e.g. 192.168.0.10:502 or plc1.local:502)",
            "mill.toml: outputs.mqtt.group_id: \"a/b\" is not allowed (must be non-empty, without / + or #)",
            "mill.toml: outputs.mqtt.node_id: \"\" is not allowed (must be non-empty, without / + or #)",
            "mill.toml: outputs.mqtt.client_id: \"\" is not allowed (must be 1..=64 characters)",
            "mill.toml: outputs.mqtt.keep_alive_s: 2 is not allowed (must be 5..=3600 s)",
            "mill.toml: outputs.mqtt.command_qos: 2 is not allowed (must be 0..=1)",
            "mill.toml: outputs.mqtt.password: missing: username needs password, password_file or password_credential",
        ]
    );
    assert_problem_like(
        &with(&format!("{minimal}\nqos = 1")),
        "mill.toml: outputs.mqtt.qos: unknown field `qos`",
        &["command_qos"],
    );
}

/// `BASE` with `[outputs.mqtt]` of group `plant`, node `f1` and the `servers` keys
/// (`broker`, `brokers`, more keys), and a `[history]`.
fn mqtt_with(servers: &str) -> String {
    let history = std::env::temp_dir().join("h.db");
    format!(
        "{BASE}\n[outputs.mqtt]\n{servers}\ngroup_id = \"plant\"\nnode_id = \"f1\"\n\
         \n[history]\npath = \"{}\"\n",
        history.display()
    )
}

#[test]
fn mqtt_server_list_for_failover() {
    let with = mqtt_with;
    let listed = parse(&with(
        "brokers = [\"10.0.0.1:1883\", \"[::1]:1884\", \"mq3.local:1883\"]",
    ))
    .unwrap()
    .outputs
    .mqtt
    .unwrap();
    assert_eq!(
        listed.brokers,
        ["10.0.0.1:1883", "[::1]:1884", "mq3.local:1883"],
        "in the order given"
    );
    let summary = millgate_config::summary(
        &parse(&with("brokers = [\"10.0.0.1:1883\", \"10.0.0.2:1883\"]")).unwrap(),
    );
    assert!(
        summary.contains(
            "Sparkplug B: brokers 10.0.0.1:1883, 10.0.0.2:1883 (failover in this order) as client"
        ),
        "{summary}"
    );
    let single = millgate_config::summary(&parse(&with("broker = \"10.0.0.1:1883\"")).unwrap());
    assert!(
        single.contains("Sparkplug B: broker 10.0.0.1:1883 as client"),
        "{single}"
    );
    assert_eq!(
        problems(&with("brokers = [\"a:1883\", \"b\", \"a:1883\", \"c:0\"]")),
        [
            "mill.toml: outputs.mqtt.brokers[1]: \"b\" is not allowed (must be host:port with a port 1..=65535, e.g. 192.168.0.10:502 or plc1.local:502)",
            "mill.toml: outputs.mqtt.brokers[2]: \"a:1883\" is listed already at brokers[0]",
            "mill.toml: outputs.mqtt.brokers[3]: \"c:0\" is not allowed (must be host:port with a port 1..=65535, e.g. 192.168.0.10:502 or plc1.local:502)",
        ]
    );
    assert_only_problem(
        &with("brokers = []"),
        "mill.toml: outputs.mqtt.brokers: 0 servers are not allowed (must be 1..=16 \"host:port\" strings)",
    );
    let seventeen: Vec<String> = (1..=17).map(|k| format!("\"m{k}:1883\"")).collect();
    assert_only_problem(
        &with(&format!("brokers = [{}]", seventeen.join(", "))),
        "mill.toml: outputs.mqtt.brokers: 17 servers are not allowed (must be 1..=16 \"host:port\" strings)",
    );
    assert_only_problem(
        &with("broker = \"a:1883\"\nbrokers = [\"b:1883\"]"),
        "mill.toml: outputs.mqtt.brokers: not allowed together with broker (give one of them: brokers for a list)",
    );
    assert_only_problem(
        &with(""),
        "mill.toml: outputs.mqtt.broker: missing: give broker = \"host:port\" or brokers = [\"host:port\", ...]",
    );
}

/// A PEM certificate frame (the DER inside is rustls' to judge, not the config's).
const CERTIFICATE_PEM: &str = "-----BEGIN CERTIFICATE-----\nMAMCAQA=\n-----END CERTIFICATE-----\n";

/// `text` written into the file `name` in `folder`; its path.
fn write_in(folder: &Path, name: &str, text: &str) -> String {
    let path = folder.join(name);
    std::fs::write(&path, text).unwrap();
    path.display().to_string()
}

#[test]
fn mqtt_servers_with_their_own_tls_and_credentials() {
    let folder = scratch("mqtt-per-server");
    let scratch = folder.path();
    let file = |name: &str, text: &str| write_in(scratch, name, text);
    let ca = file("ca.pem", CERTIFICATE_PEM);
    let secret = file("secret", "s3cret\n");
    let with = mqtt_with;
    // A table has its own TLS and credentials; a string the shared ones.
    let mqtt = parse(&with(&format!(
        "brokers = [{{ address = \"mq1:8883\", tls = {{ ca_file = \"{ca}\" }}, username = \"gw\", \
         password_file = \"{secret}\" }}, \"mq2:1883\", {{ address = \"mq3:1883\" }}]\n\
         username = \"shared\"\npassword = \"pw\""
    )))
    .unwrap()
    .outputs
    .mqtt
    .unwrap();
    assert_eq!(mqtt.brokers, ["mq1:8883", "mq2:1883", "mq3:1883"]);
    let own = &mqtt.security[0];
    assert_eq!(own.credentials, Some(("gw".into(), "s3cret".into())));
    let tls = own.tls.as_ref().unwrap();
    assert_eq!(tls.key, "outputs.mqtt.brokers[0].tls");
    assert_eq!(tls.ca_file.display().to_string(), ca);
    assert_eq!(
        mqtt.security[1].credentials,
        Some(("shared".into(), "pw".into()))
    );
    assert_eq!(mqtt.security[1].tls, None);
    assert_eq!(
        mqtt.security[2],
        millgate_config::MqttSecurity::default(),
        "a table without keys is plain, without credentials"
    );
    // The single broker has the shared settings.
    let single = parse(&with("broker = \"mq1:1883\""))
        .unwrap()
        .outputs
        .mqtt
        .unwrap();
    assert_eq!(single.security, [millgate_config::MqttSecurity::default()]);

    // Problems name the entry's keys.
    let missing = scratch.join("missing.pem").display().to_string();
    assert_eq!(
        problems(&with(&format!(
            "brokers = [\"mq0:1883\", {{ address = \"mq1\", username = \"gw\" }}, \
             {{ address = \"mq2:1883\", tls = {{ ca_file = \"{missing}\" }} }}, \
             {{ address = \"mq0:1883\" }}]"
        ))),
        [
            "mill.toml: outputs.mqtt.brokers[1].address: \"mq1\" is not allowed (must be host:port with a port 1..=65535, e.g. 192.168.0.10:502 or plc1.local:502)".to_owned(),
            "mill.toml: outputs.mqtt.brokers[3].address: \"mq0:1883\" is listed already at brokers[0]".to_owned(),
            "mill.toml: outputs.mqtt.brokers[1].password: missing: username needs password, password_file or password_credential".to_owned(),
            format!(
                "mill.toml: outputs.mqtt.brokers[2].tls.ca_file: file \"{missing}\" not found \
                 (looked for {missing}; paths are relative to the configuration file)"
            ),
        ]
    );
    assert_problem_like(
        &with("brokers = [{ address = \"mq1:1883\", user = \"gw\" }]"),
        "mill.toml: outputs.mqtt.brokers",
        &["unknown field `user`", "username"],
    );
    assert_problem_like(
        &with("brokers = [1883]"),
        "mill.toml: outputs.mqtt.brokers",
        &["\"host:port\" or a table"],
    );
}

#[test]
fn mqtt_credentials_and_tls_files() {
    let folder = scratch("mqtt-tls");
    let scratch = folder.path();
    let file = |name: &str, text: &str| write_in(scratch, name, text);
    // The PEM framing is checked here; the DER inside is rustls' to judge (the
    // gateway's TLS setup).
    let cert = file("cert.pem", CERTIFICATE_PEM);
    let key = file(
        "key.pem",
        "-----BEGIN PRIVATE KEY-----\nMAMCAQA=\n-----END PRIVATE KEY-----\n",
    );
    let secret = file("secret", "s3cret\n");
    let empty = file("empty", "");
    let text = file("text.pem", "not a certificate\n");
    let missing = scratch.join("missing.pem").display().to_string();
    let history = format!(
        "\n[history]\npath = \"{}\"\n",
        std::env::temp_dir().join("h.db").display()
    );
    let with = |mqtt: &str| {
        format!(
            "{BASE}\n[outputs.mqtt]\nbroker = \"127.0.0.1:8883\"\ngroup_id = \"plant\"\n\
             node_id = \"f1\"\n{mqtt}\n{history}"
        )
    };

    let config = parse(&with(&format!(
        "username = \"gw\"\npassword_file = \"{secret}\"\n[outputs.mqtt.tls]\n\
         ca_file = \"{cert}\"\ncert_file = \"{cert}\"\nkey_file = \"{key}\""
    )))
    .unwrap_or_else(|error| panic!("{error}"));
    let mqtt = config.outputs.mqtt.unwrap();
    assert_eq!(
        mqtt.credentials,
        Some(("gw".to_owned(), "s3cret".to_owned())),
        "the file's text without its newline"
    );
    let tls = mqtt.tls.unwrap();
    assert_eq!(tls.ca_file.display().to_string(), cert);
    let material = tls.read().unwrap();
    assert_eq!((material.ca.len(), material.client.is_some()), (1, true));
    let ca_only = parse(&with(&format!("[outputs.mqtt.tls]\nca_file = \"{cert}\"")))
        .unwrap()
        .outputs
        .mqtt
        .unwrap();
    assert_eq!(ca_only.tls.unwrap().client, None);
    assert_eq!(ca_only.credentials, None);

    assert_eq!(
        problems(&with(&format!(
            "username = \"gw\"\npassword = \"x\"\npassword_file = \"{secret}\""
        ))),
        ["mill.toml: outputs.mqtt.password_file: not allowed together with password (give one of them)"]
    );
    assert_eq!(
        problems(&with(&format!(
            "username = \"gw\"\npassword_file = \"{empty}\""
        ))),
        [format!(
            "mill.toml: outputs.mqtt.password_file: \"{empty}\" is empty ({empty})"
        )]
    );
    let unreadable = problems(&with(&format!(
        "username = \"gw\"\npassword_file = \"{missing}\""
    )));
    assert!(
        unreadable.len() == 1
            && unreadable[0].starts_with(&format!(
                "mill.toml: outputs.mqtt.password_file: cannot read \"{missing}\" ({missing}: "
            )),
        "{unreadable:?}"
    );
    assert_eq!(
        problems(&with("password = \"x\"")),
        ["mill.toml: outputs.mqtt.username: missing: a password needs a username"]
    );
    assert_eq!(
        problems(&with(&format!(
            "[outputs.mqtt.tls]\nca_file = \"{cert}\"\nkey_file = \"{key}\""
        ))),
        ["mill.toml: outputs.mqtt.tls.cert_file: missing: a private key (key_file) needs its client certificate"]
    );
    assert_eq!(
        problems(&with(&format!(
            "[outputs.mqtt.tls]\nca_file = \"{cert}\"\ncert_file = \"{cert}\""
        ))),
        ["mill.toml: outputs.mqtt.tls.key_file: missing: a client certificate (cert_file) needs its private key"]
    );
    assert_eq!(
        problems(&with(&format!("[outputs.mqtt.tls]\nca_file = \"{missing}\""))),
        [format!(
            "mill.toml: outputs.mqtt.tls.ca_file: file \"{missing}\" not found (looked for {missing}; \
             paths are relative to the configuration file)"
        )]
    );
    assert_eq!(
        problems(&with(&format!("[outputs.mqtt.tls]\nca_file = \"{text}\""))),
        [format!(
            "mill.toml: outputs.mqtt.tls.ca_file: {text}: no certificate in the file (must be PEM \
             with -----BEGIN CERTIFICATE-----)"
        )]
    );
    assert_eq!(
        problems(&with(&format!(
            "[outputs.mqtt.tls]\nca_file = \"{cert}\"\ncert_file = \"{cert}\"\nkey_file = \"{cert}\""
        ))),
        [format!(
            "mill.toml: outputs.mqtt.tls.key_file: {cert}: no private key in the file (must be \
             PEM: -----BEGIN PRIVATE KEY-----, RSA PRIVATE KEY or EC PRIVATE KEY)"
        )]
    );
    assert_problem_like(
        &with(&format!("[outputs.mqtt.tls]\nca = \"{cert}\"")),
        "mill.toml: outputs.mqtt.tls.ca: unknown field `ca`",
        &["ca_file"],
    );
}

#[test]
fn rod_mill_example() {
    let config =
        load(&examples_dir().join("rod-mill.toml")).unwrap_or_else(|error| panic!("{error}"));
    let mill = &config.rod_mills[0];
    let channel = |index: usize| config.channels[index].name.as_str();
    assert_eq!(mill.name, "RSM");
    assert!(mill.mill.ends_with("sim/models/rod/rsm-mill.toml"));
    assert!(mill.schedule.ends_with("sim/models/rod/rsm-schedule.csv"));
    assert_eq!(mill.configurations, ["table3", "fast"]);
    assert_eq!(channel(mill.configuration), "rsm_configuration");
    assert_eq!(channel(mill.pass), "rsm_pass");
    assert_eq!(channel(mill.finishing_speed), "rsm_finishing_speed");
    assert_eq!(mill.temperature.map(channel), Some("rsm_rod_temperature"));
    assert_eq!(
        (
            mill.near_tongue_m_s,
            mill.hysteresis_m_s,
            mill.temperature_step_c
        ),
        (2.0, 0.5, 10.0)
    );
}

#[test]
fn rod_mill_problems_name_the_key_and_the_allowed_range() {
    let text = std::fs::read_to_string(examples_dir().join("rod-mill.toml")).expect("example");
    let check = |from: &str, to: &str| -> Vec<String> {
        assert!(text.contains(from), "the example has {from:?}");
        match from_toml_str(&text.replace(from, to), "rod.toml", &examples_dir()) {
            Ok(_) => panic!("{to:?} was accepted"),
            Err(error) => error.problems.iter().map(ToString::to_string).collect(),
        }
    };
    let found = check("hysteresis_m_s = 0.5", "hysteresis_m_s = -1.0");
    assert_eq!(
        found,
        ["rod.toml: rod_mills[0].hysteresis_m_s: -1 is not allowed (must be >= 0 m/s)"]
    );
    let found = check(
        "configurations = [\"table3\", \"fast\"]",
        "configurations = []",
    );
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(
        found[0].starts_with(
            "rod.toml: rod_mills[0].configurations: 0 names is not allowed (must be 1..=64"
        ),
        "{found:?}"
    );
    let found = check(
        "finishing_speed = \"rsm_finishing_speed\"",
        "finishing_speed = \"rsm_speed\"",
    );
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(
        found[0]
            .starts_with("rod.toml: rod_mills[0].finishing_speed: unknown channel \"rsm_speed\""),
        "{found:?}"
    );
    let found = check("near_tongue_m_s = 2.0", "near_tongue_m_s = 0.0");
    assert_eq!(
        found,
        ["rod.toml: rod_mills[0].near_tongue_m_s: 0 is not allowed (must be > 0 m/s)"]
    );
    let found = check("rsm-mill.toml\"", "rsm-mil.toml\"");
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(
        found[0].starts_with(
            "rod.toml: rod_mills[0].mill: file \"../../sim/models/rod/rsm-mil.toml\" not found"
        ),
        "{found:?}"
    );
}

#[test]
fn the_web_page_defaults_limits_and_listener_clash() {
    // Defaults: loopback 8080, 32 connections, 5 s headers, 10 s requests.
    let config = parse(&edited(
        "[outputs.metrics]",
        "[outputs.web]\n\n[outputs.metrics]",
    ))
    .unwrap_or_else(|error| panic!("{error}"));
    let web = config.outputs.web.unwrap();
    assert_eq!(web.bind, "127.0.0.1:8080".parse().unwrap());
    assert_eq!(web.max_connections, 32);
    assert_eq!(web.header_timeout, Duration::from_millis(5000));
    assert_eq!(web.request_timeout, Duration::from_millis(10_000));
    assert_eq!(
        (web.history_queries, web.max_event_streams),
        (2, 8),
        "defaults"
    );
    assert!(web.allowed_hosts.is_empty());
    assert!(parse(BASE).unwrap().outputs.web.is_none());
    let set = parse(&edited(
        "[outputs.metrics]",
        "[outputs.web]\nbind = \"0.0.0.0:8088\"\nmax_connections = 1\nheader_timeout_ms = 100\n\
         request_timeout_ms = 60000\n\n[outputs.metrics]",
    ))
    .unwrap_or_else(|error| panic!("{error}"));
    let web = set.outputs.web.unwrap();
    assert_eq!(
        (
            web.bind.port(),
            web.max_connections,
            web.header_timeout,
            web.request_timeout,
            web.max_event_streams
        ),
        (
            8088,
            1,
            Duration::from_millis(100),
            Duration::from_secs(60),
            1
        )
    );
    // Each key names itself and its range.
    for (key, value, range) in [
        ("max_connections", "0", "1..=1024"),
        ("max_connections", "1025", "1..=1024"),
        ("header_timeout_ms", "99", "100..=60000"),
        ("request_timeout_ms", "60001", "100..=60000"),
        ("history_queries", "0", "1..=8"),
        ("history_queries", "9", "1..=8"),
        ("max_event_streams", "0", "1..=31"),
        (
            "max_event_streams",
            "32",
            "1..=31 (below outputs.web.max_connections)",
        ),
    ] {
        let found = problems(&edited(
            "[outputs.metrics]",
            &format!("[outputs.web]\n{key} = {value}\n\n[outputs.metrics]"),
        ));
        assert_eq!(found.len(), 1, "{found:#?}");
        assert!(
            found[0].starts_with(&format!("mill.toml: outputs.web.{key}: {value}"))
                && found[0].contains(range),
            "{found:?}"
        );
    }
    assert_problem_like(
        &edited(
            "[outputs.metrics]",
            "[outputs.web]\nallowed_hosts = [\"mill-gw.example\", \"Mill.Example\"]\n\n\
             [outputs.metrics]",
        ),
        "mill.toml: outputs.web.allowed_hosts[1]: \"Mill.Example\" is not allowed (a host \
         name: 1..=253 characters of lower-case letters",
        &[],
    );
    assert_problem_like(
        &edited(
            "[outputs.metrics]",
            "[outputs.web]\nbind = \"localhost:80\"\n\n[outputs.metrics]",
        ),
        "mill.toml: outputs.web.bind: \"localhost:80\" is not allowed",
        &[],
    );
    assert_problem_like(
        &edited(
            "[outputs.metrics]",
            "[outputs.web]\nport = 80\n\n[outputs.metrics]",
        ),
        "mill.toml: ",
        &["port"],
    );
    // The same port as the metrics endpoint.
    assert_only_problem(
        &edited(
            "[outputs.metrics]",
            "[outputs.web]\nbind = \"127.0.0.1:9187\"\n\n[outputs.metrics]\nbind = \"127.0.0.1:9187\"",
        ),
        "mill.toml: outputs.web.bind: 127.0.0.1:9187 is not allowed: outputs.metrics.bind \
         (127.0.0.1:9187) listens on the same port; each listener needs its own port",
    );
}

#[test]
fn a_mill_to_commission_may_leave_out_its_gain_thresholds() {
    // The example tandem mill without its thresholds: the service refuses it, the
    // commissioning load takes it (with no thresholds) and still checks the rest.
    let text = std::fs::read_to_string(examples_dir().join("tandem-5stand.toml")).expect("example");
    let line = "gain_thresholds = [1.187, 1.492, 2.209, 3.087, 3.327]\n";
    assert!(text.contains(line));
    let folder = scratch("commission");
    let dir = folder.path();
    let path = dir.join("mill.toml");
    std::fs::write(&path, text.replace(line, "")).expect("write");
    let error = load(&path).expect_err("the service needs thresholds");
    assert!(
        error.to_string().contains(
            "tandem_mills[0].gain_thresholds: missing (the band-gain detector, the default, \
             needs one alarm threshold per stand, > 0, from stable rolling up to the highest \
             allowed speed: `millgate chatter commission` computes them"
        ),
        "{error}"
    );
    let config = load_uncommissioned(&path).unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(
        config.tandem_mills[0].detector,
        ChatterDetectorKind::BandGain
    );
    assert!(config.tandem_mills[0].gain_thresholds.is_empty());
    std::fs::write(&path, text.replace(line, "gain_thresholds = [1.0]\n")).expect("write");
    let error = load_uncommissioned(&path).expect_err("one threshold for five stands");
    assert!(
        error
            .to_string()
            .contains("gain_thresholds: 1 values is not allowed (must be one per stand: 5)"),
        "{error}"
    );
}

/// `BASE` with `[outputs.opcua]` holding `keys`.
fn with_opcua(keys: &str) -> String {
    edited(
        "[outputs.metrics]",
        &format!("[outputs.opcua]\n{keys}\n\n[outputs.metrics]"),
    )
}

#[test]
fn opcua_defaults_follow_the_bind() {
    // Loopback: security none, anonymous, certificates beside the configuration
    // (no history, and no STATE_DIRECTORY in the test's environment).
    let config = parse(&with_opcua("")).unwrap_or_else(|error| panic!("{error}"));
    let opcua = config.outputs.opcua.unwrap();
    assert_eq!(opcua.bind, "127.0.0.1:4840".parse().unwrap());
    assert_eq!(opcua.host, "127.0.0.1");
    assert_eq!(opcua.endpoint_url(), "opc.tcp://127.0.0.1:4840/");
    assert_eq!(opcua.security_modes, [OpcUaSecurityMode::None]);
    assert!(opcua.anonymous && opcua.users.is_empty() && !opcua.allow_remote_commands);
    if std::env::var_os("STATE_DIRECTORY").is_none() {
        assert_eq!(opcua.pki_dir, examples_dir().join("opcua-pki"));
    }
    assert_eq!(
        (
            opcua.max_connections,
            opcua.max_sessions,
            opcua.max_sessions_per_peer,
            opcua.max_subscriptions_per_session,
            opcua.max_monitored_items_per_subscription,
            opcua.max_session_timeout
        ),
        (16, 10, 5, 10, 1000, Duration::from_secs(60))
    );
    // Another host's reach: signed and encrypted by default; a wildcard needs the
    // host clients use, and the URL brackets an IPv6 host.
    let remote = parse(&with_opcua("bind = \"192.168.0.20:4840\""))
        .unwrap()
        .outputs
        .opcua
        .unwrap();
    assert_eq!(
        remote.security_modes,
        [OpcUaSecurityMode::Sign, OpcUaSecurityMode::SignAndEncrypt]
    );
    assert_only_problem(
        &with_opcua("bind = \"0.0.0.0:4840\""),
        "mill.toml: outputs.opcua.host: missing: bind 0.0.0.0:4840 listens on every address; \
         give the host name or IP address clients reach the gateway at (written into the \
         endpoint URL and the server certificate)",
    );
    let v6 = parse(&with_opcua("bind = \"[::]:4841\"\nhost = \"fd00::20\""))
        .unwrap()
        .outputs
        .opcua
        .unwrap();
    assert_eq!(v6.endpoint_url(), "opc.tcp://[fd00::20]:4841/");
}

#[test]
fn opcua_keys_name_their_range() {
    for (key, value, range) in [
        ("max_connections", "0", "1..=256"),
        ("max_sessions", "101", "1..=100"),
        ("max_subscriptions_per_session", "0", "1..=100"),
        (
            "max_monitored_items_per_subscription",
            "100001",
            "1..=100000",
        ),
        ("max_session_timeout_ms", "999", "1000..=3600000 ms"),
        (
            "max_sessions_per_peer",
            "11",
            "1..=10, at most outputs.opcua.max_sessions",
        ),
    ] {
        assert_only_problem(
            &with_opcua(&format!("{key} = {value}")),
            &format!("mill.toml: outputs.opcua.{key}: {value} is not allowed (must be {range})"),
        );
    }
    // Sessions per address: half of max_sessions (rounded up) unless given.
    let sessions_per_peer = |keys: &str| {
        let opcua = parse(&with_opcua(keys)).unwrap().outputs.opcua.unwrap();
        (opcua.max_sessions, opcua.max_sessions_per_peer)
    };
    assert_eq!(sessions_per_peer("max_sessions = 3"), (3, 2));
    assert_eq!(sessions_per_peer("max_sessions = 1"), (1, 1));
    assert_eq!(
        sessions_per_peer("max_sessions = 4\nmax_sessions_per_peer = 4"),
        (4, 4)
    );
    assert_only_problem(
        &with_opcua("security_modes = [\"sign\", \"encrypt\"]"),
        "mill.toml: outputs.opcua.security_modes[1]: unknown security mode \"encrypt\" \
         (allowed: none, sign, sign_and_encrypt)",
    );
    assert_only_problem(
        &with_opcua("security_modes = []"),
        "mill.toml: outputs.opcua.security_modes: [] is not allowed (must list one or more of \
         none, sign, sign_and_encrypt)",
    );
    assert_only_problem(
        &with_opcua("security_modes = [\"sign\", \"sign\"]"),
        "mill.toml: outputs.opcua.security_modes[1]: \"sign\" is listed twice",
    );
    assert_problem_like(
        &with_opcua("host = \"gate way\""),
        "mill.toml: outputs.opcua.host: \"gate way\" is not allowed",
        &["host name", "IP address"],
    );
    assert_only_problem(
        &with_opcua("anonymous = false"),
        "mill.toml: outputs.opcua.anonymous: false is not allowed without users_file: no \
         client could sign in (give users_file, or allow anonymous sessions)",
    );
    // The same port as the HMI server.
    assert_only_problem(
        &with_opcua("bind = \"127.0.0.1:5503\""),
        "mill.toml: outputs.opcua.bind: 127.0.0.1:5503 is not allowed: outputs.server.bind \
         (127.0.0.1:5503) listens on the same port; each listener needs its own port",
    );
    assert_problem_like(
        &with_opcua("endpoint = \"x\""),
        "mill.toml: ",
        &["endpoint"],
    );
}

#[test]
fn opcua_users_file_is_read_and_checked() {
    let folder = scratch("opcua-users");
    let scratch = folder.path();
    let file = |name: &str, text: &str| write_in(scratch, name, text);
    let good = file(
        "users",
        "# operators\noperator:s3cret:with:colons\n\nmaintenance:pw\r\n",
    );
    let config = parse(&with_opcua(&format!(
        "users_file = \"{good}\"\nanonymous = false\npki_dir = \"{}\"",
        scratch.join("pki").display()
    )))
    .unwrap_or_else(|error| panic!("{error}"));
    let opcua = config.outputs.opcua.unwrap();
    let users: Vec<(&str, &str)> = opcua
        .users
        .iter()
        .map(|u| (u.name.as_str(), u.password.as_str()))
        .collect();
    assert_eq!(
        users,
        [("operator", "s3cret:with:colons"), ("maintenance", "pw")]
    );
    assert!(!opcua.anonymous);
    assert_eq!(opcua.pki_dir, scratch.join("pki"));
    assert!(
        !format!("{:?}", opcua.users).contains("s3cret"),
        "passwords stay out of Debug output"
    );

    let bad = file("bad", "nocolon\n:empty-name\nuser:\nop:a\nop:b\n");
    let found = problems(&with_opcua(&format!("users_file = \"{bad}\"")));
    assert_eq!(
        found,
        [
            "mill.toml: outputs.opcua.users_file: bad:1: must be name:password",
            "mill.toml: outputs.opcua.users_file: bad:2: user name must be 1..=64 characters \
             before the ':'",
            "mill.toml: outputs.opcua.users_file: bad:3: password must not be empty",
            "mill.toml: outputs.opcua.users_file: bad:5: user \"op\" is listed twice",
        ]
        .map(|p| p.replace("bad:", &format!("{bad}:")))
    );
    let empty = file("empty", "# nobody\n");
    assert_only_problem(
        &with_opcua(&format!("users_file = \"{empty}\"")),
        &format!(
            "mill.toml: outputs.opcua.users_file: \"{empty}\" lists no user (one \
             name:password per line)"
        ),
    );
    assert_problem_like(
        &with_opcua("users_file = \"missing-users\""),
        "mill.toml: outputs.opcua.users_file: cannot read \"missing-users\"",
        &["relative to the configuration file"],
    );
    assert_problem_like(
        &with_opcua(&format!("pki_dir = \"{good}\"")),
        "mill.toml: outputs.opcua.pki_dir: ",
        &["is a file (must be a folder)"],
    );
    assert_problem_like(
        &with_opcua("pki_dir = \"no/such/folder/pki\""),
        "mill.toml: outputs.opcua.pki_dir: the folder above \"no/such/folder/pki\" does not exist",
        &[],
    );
}

/// `BASE` with `drivelines[0].extra_channels = <list>`.
fn with_extra_channels(list: &str) -> String {
    edited(
        "metal_in_stand = \"metal_in\"\n",
        &format!("metal_in_stand = \"metal_in\"\nextra_channels = {list}\n"),
    )
}

#[test]
fn extra_channels_are_resolved_in_order() {
    let config = parse(&with_extra_channels("[\"spindle_bottom\"]")).unwrap();
    assert_eq!(config.drivelines[0].extra_channels, vec![1]);
    assert!(parse(BASE).unwrap().drivelines[0].extra_channels.is_empty());
}

#[test]
fn bad_extra_channels_are_named_with_the_allowed_values() {
    assert_only_problem(
        &with_extra_channels("[\"motor_curent\"]"),
        "mill.toml: drivelines[0].extra_channels[0]: unknown channel \"motor_curent\" \
         (known: spindle_top, spindle_bottom, metal_in, acc0, acc1)",
    );
    assert_only_problem(
        &with_extra_channels("[\"spindle_top\"]"),
        "mill.toml: drivelines[0].extra_channels[0]: \"spindle_top\" is the driveline's \
         torque channel, captured already",
    );
    assert_only_problem(
        &with_extra_channels("[\"spindle_bottom\", \"spindle_bottom\"]"),
        "mill.toml: drivelines[0].extra_channels[1]: \"spindle_bottom\" is named already at \
         extra_channels[0]",
    );
    assert_problem_like(
        &with_extra_channels("[\"metal_in\"]"),
        "mill.toml: drivelines[0].extra_channels[0]: channel \"metal_in\" is a register value",
        &["Modbus block or CAN channel"],
    );
    assert_only_problem(
        &with_extra_channels("[\"acc0\"]"),
        "mill.toml: drivelines[0].extra_channels[0]: channel \"acc0\" samples at 4000 Hz, \
         the torque channel at 2000 Hz (extra channels must share the torque's sample rate)",
    );
}

#[test]
fn fatigue_ledger_settings_name_the_key_and_the_range() {
    let fatigue = |table: &str| {
        edited(
            "taf_warning = 2.2, taf_alarm = 2.6 }",
            &format!(
                "taf_warning = 2.2, taf_alarm = 2.6 }}\n\
                 fatigue = {{ {table} }}"
            ),
        )
    };
    let spindle = "{ name = \"spindle 1\", m = 6, ref_cycles = 2e6, ref_range_knm = 150";
    let config = parse(&fatigue(&format!(
        "life_limit = 0.7, components = [{spindle}, torque_share = 0.5, endurance_knm = 20, \
         endurance_rule = \"haibach\" }}, {{ name = \"coupling\", m = 5, ref_cycles = 1e7, \
         ref_range_knm = 300 }}]"
    )))
    .unwrap_or_else(|error| panic!("{error}"));
    let settings = config.drivelines[0].fatigue.as_ref().expect("a ledger");
    // 1% of the channel's i16 range at 0.01 kN*m per count.
    assert!(
        (settings.gate_knm - 0.01 * 655.35).abs() < 1e-9,
        "{}",
        settings.gate_knm
    );
    assert_eq!(settings.life_limit, 0.7);
    assert_eq!(settings.components.len(), 2);
    assert_eq!(settings.components[0].curve.settings().torque_share, 0.5);
    assert_eq!(parse(BASE).unwrap().drivelines[0].fatigue, None);

    let one = |extra: &str| fatigue(&format!("{extra} components = [{spindle} }}]"));
    assert_only_problem(
        &one("gate_knm = 700,"),
        "mill.toml: drivelines[0].fatigue.gate_knm: 700 is not allowed (must be >= 0 and below the torque channel's range, 655.35 kN*m)",
    );
    assert_only_problem(
        &one("life_limit = 1.5,"),
        "mill.toml: drivelines[0].fatigue.life_limit: 1.5 is not allowed (must be in (0, 1], a fraction of the life)",
    );
    assert_only_problem(
        &fatigue(&format!("components = [{spindle}, m = 0 }}]").replace("m = 6, ", "")),
        "mill.toml: drivelines[0].fatigue.components[0].m: 0 is not allowed (m must be finite and > 0)",
    );
    assert_only_problem(
        &fatigue(&format!("components = [{spindle}, torque_share = -1 }}]")),
        "mill.toml: drivelines[0].fatigue.components[0].torque_share: -1 is not allowed (torque_share must be finite and > 0)",
    );
    assert_only_problem(
        &fatigue(&format!("components = [{spindle}, endurance_rule = \"flat\" }}]")),
        "mill.toml: drivelines[0].fatigue.components[0].endurance_rule: unknown endurance rule \"flat\" (allowed: cutoff, haibach)",
    );
    assert_only_problem(
        &fatigue(&format!("components = [{spindle} }}, {spindle} }}]")),
        "mill.toml: drivelines[0].fatigue.components[1].name: \"spindle 1\" is used twice in this driveline",
    );
    assert_only_problem(
        &fatigue("components = []"),
        "mill.toml: drivelines[0].fatigue.components: no component (a ledger needs at least one [[...components]])",
    );
}

/// `log_format`: `text` by default, `json` when asked, anything else refused with the
/// allowed spellings.
#[test]
fn log_format_is_text_or_json() {
    let config = parse(BASE).unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(config.log_format, millgate_config::LogFormat::Text);
    let json = edited(
        "name = \"Test mill\"",
        "name = \"Test mill\"\nlog_format = \"json\"",
    );
    let config = parse(&json).unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(config.log_format, millgate_config::LogFormat::Json);
    assert_only_problem(
        &edited(
            "name = \"Test mill\"",
            "name = \"Test mill\"\nlog_format = \"xml\"",
        ),
        "mill.toml: log_format: unknown format \"xml\" (allowed: text, json)",
    );
}

/// `[analysis] workers`: 0 (one per core) by default, a count when given, refused
/// outside 0..=64 with the allowed range.
#[test]
fn analysis_workers_default_to_the_cores_and_are_range_checked() {
    let config = parse(BASE).unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(config.analysis.workers, 0);
    let workers = |text: &str| {
        edited(
            "name = \"Test mill\"\n",
            &format!("name = \"Test mill\"\n[analysis]\n{text}\n"),
        )
    };
    let config = parse(&workers("workers = 3")).unwrap_or_else(|error| panic!("{error}"));
    assert_eq!(config.analysis.workers, 3);
    for refused in ["65", "-1"] {
        assert_only_problem(
            &workers(&format!("workers = {refused}")),
            &format!(
                "mill.toml: analysis.workers: {refused} is not allowed (must be 0..=64 threads, 0 = one per core)"
            ),
        );
    }
}

#[test]
fn identification_is_read_in_order_and_checked_with_its_key() {
    use millgate_config::{IdentificationField as Field, IdentificationValue as Value};
    let text = BASE.to_owned()
        + "\n[gateway.identification]\nasset_id = \"IPC-7\"\nmanufacturer = \"Siemens\"\n";
    let text = text.replacen(
        "thresholds = { taf_warning = 2.2, taf_alarm = 2.6 }",
        "thresholds = { taf_warning = 2.2, taf_alarm = 2.6 }\n\
         identification = { serial_number = \"SN 4711\", manufacturer = \"SMS group\", \
         year_of_construction = 1998, product_instance_uri = \"urn:example:F1\" }",
        1,
    );
    let config = parse(&text).expect("valid");
    let text_of = |s: &str| Value::Text(s.to_owned());
    assert_eq!(
        config.drivelines[0].identification.fields,
        [
            (Field::Manufacturer, text_of("SMS group")),
            (Field::SerialNumber, text_of("SN 4711")),
            (Field::ProductInstanceUri, text_of("urn:example:F1")),
            (Field::YearOfConstruction, Value::Year(1998)),
        ]
    );
    assert_eq!(
        config.gateway_identification.fields,
        [
            (Field::Manufacturer, text_of("Siemens")),
            (Field::AssetId, text_of("IPC-7")),
        ]
    );
    assert!(config.tandem_mills[0].identification.fields.is_empty());
    // Left out: empty.
    assert!(parse(BASE)
        .unwrap()
        .gateway_identification
        .fields
        .is_empty());

    let driveline = |table: &str| {
        edited(
            "thresholds = { taf_warning = 2.2, taf_alarm = 2.6 }",
            &format!(
                "thresholds = {{ taf_warning = 2.2, taf_alarm = 2.6 }}\nidentification = {table}"
            ),
        )
    };
    assert_only_problem(
        &driveline("{ year_of_construction = 98 }"),
        "mill.toml: drivelines[0].identification.year_of_construction: 98 is not allowed (must be 1800..=2100)",
    );
    assert_only_problem(
        &driveline("{ product_instance_uri = \"F1 stand\" }"),
        "mill.toml: drivelines[0].identification.product_instance_uri: \"F1 stand\" is not allowed (must be a URI, scheme:rest without spaces, e.g. urn:example:mill:F1 or https://example.com/F1)",
    );
    assert_only_problem(
        &driveline("{ serial_number = \" \" }"),
        "mill.toml: drivelines[0].identification.serial_number: must not be empty",
    );
    let long = "x".repeat(256);
    assert_only_problem(
        &driveline(&format!("{{ model = \"{long}\" }}")),
        "mill.toml: drivelines[0].identification.model: 256 characters are not allowed (must be 1..=255)",
    );
    assert_problem_like(
        &driveline("{ serial_number = 4711 }"),
        "mill.toml: drivelines[0].identification.serial_number: invalid type: integer `4711`, expected a string",
        &["line "],
    );
    assert_problem_like(
        &driveline("{ software_revision = \"1.0\" }"),
        "mill.toml: drivelines[0].identification.software_revision: unknown field `software_revision`",
        &["serial_number", "line "],
    );
    let tandem = edited(
        "gain_thresholds = [1.2, 1.5]\n",
        "gain_thresholds = [1.2, 1.5]\nidentification = { manufacturer = \"a\\u0007b\" }\n",
    );
    assert_problem_like(
        &tandem,
        "mill.toml: tandem_mills[0].identification.manufacturer: \"a\\u{7}b\" is not allowed (must not contain control characters",
        &[],
    );
    assert_problem_like(
        &(BASE.to_owned() + "\n[gateway]\nidentification = { year_of_construction = \"1998\" }\n"),
        "mill.toml: gateway.identification.year_of_construction: invalid type: string \"1998\", expected i64",
        &["line "],
    );
}

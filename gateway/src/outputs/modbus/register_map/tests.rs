//! The register map's tests: golden words, the layout against the catalogue.

use super::layout::*;
use super::*;
use crate::field::source_health::SourceStatus;
use crate::state::catalogue::Figure;
use crate::state::catalogue::{self, FigureType, Subject};
use crate::state::results::Results;
use crate::state::results::{DrivelineResults, TandemMillResults};

use crate::testing::example_config as example;

/// The map of the tandem example and the address of its mill block.
fn tandem_map() -> (RegisterMap, usize) {
    let map = RegisterMap::new(&example("tandem-5stand.toml"));
    let flags = map.named("TCM 2030.flags").expect("mill block");
    let base = usize::from(flags.address);
    (map, base)
}

#[test]
fn blocks_tile_the_map_and_each_holds_one_subject_within_a_request() {
    let mut config = example("hot-mill.toml");
    config.drivelines.extend(example("demo.toml").drivelines);
    config.tandem_mills = example("tandem-5stand.toml").tandem_mills;
    config.rod_mills = example("rod-mill.toml").rod_mills;
    let map = RegisterMap::new(&config);
    let blocks = map.blocks();
    // The first layout's blocks, then each driveline's extension block.
    let first = 1 + config.drivelines.len() + config.tandem_mills.len() + config.rod_mills.len();
    assert_eq!(blocks.len(), first + config.drivelines.len());
    assert_eq!(map.plc_blocks(false), &blocks[..first]);
    assert_eq!(map.plc_blocks(true), blocks);
    assert_eq!(map.plc_span(false), blocks[first - 1].end);
    assert_eq!(blocks[0].start, 0);
    assert_eq!(blocks.last().unwrap().end, map.len());
    for pair in blocks.windows(2) {
        assert_eq!(pair[0].end, pair[1].start, "contiguous: {blocks:?}");
    }
    // 123: the most one FC 16 request writes.
    assert!(blocks.iter().all(|b| b.len() <= 123), "{blocks:?}");
    for register in map.registers() {
        let end = register.address + register.value_type.register_count();
        let block = blocks
            .iter()
            .position(|b| b.contains(&register.address))
            .unwrap_or_else(|| panic!("{} in no block", register.name));
        assert!(
            end <= blocks[block].end,
            "{} straddles two blocks",
            register.name
        );
        // One subject per block: the globals in the first, a subject's registers
        // (a rod mill's spans with it) in its own.
        let subject = register.name.split('.').next().unwrap();
        let owner = match block {
            0 => None,
            k if k <= config.drivelines.len() => Some(&config.drivelines[k - 1].name),
            k if k <= config.drivelines.len() + config.tandem_mills.len() => {
                Some(&config.tandem_mills[k - 1 - config.drivelines.len()].name)
            }
            k if k < first => Some(
                &config.rod_mills[k - 1 - config.drivelines.len() - config.tandem_mills.len()].name,
            ),
            k => Some(&config.drivelines[k - first].name),
        };
        match owner {
            Some(name) => assert_eq!(subject, name.as_str(), "{}", register.name),
            None => assert!(
                register.address < DRIVELINES_START,
                "{} among the globals",
                register.name
            ),
        }
    }
}

#[test]
fn mill_block_golden_words() {
    let (map, base) = tandem_map();
    let mut results = Results::new(2, 0, 1);
    results.tandem_mills[0] = TandemMillResults {
        evaluations: 9,
        sigma_n_hz: Some(0.5),
        k_mean: Some(0.25),
        chatter_frequency_hz: Some(200.0),
        chatter_gain: Some(3.5),
        gain_ratio: Some(1.25),
        band_rms_max: Some(2.0),
        worst_stand: Some(3),
        chatter_warning: true,
        chatter_alarm: true,
        source_stale: false,
        slow_down_request: true,
        weld_held_off: 4,
        context_invalid: 1,
        ..TandemMillResults::default()
    };
    let words = map.encode(&results);
    assert_eq!(words[base], 0b1011, "warning, alarm, slow-down");
    assert_eq!(words[base + 1], 0b111_1111, "every value valid");
    // f32 ABCD: 0.5 = 0x3F000000, 0.25 = 0x3E800000, 200 = 0x43480000,
    // 3.5 = 0x40600000, 1.25 = 0x3FA00000, 2 = 0x40000000; stand 3 is the 4th.
    assert_eq!(
        words[base + 2..base + 15],
        [0x3F00, 0, 0x3E80, 0, 0x4348, 0, 0x4060, 0, 0x3FA0, 0, 0x4000, 0, 4]
    );

    // Before the gain's window is full: its values invalid, the spectra's valid.
    let mill = &mut results.tandem_mills[0];
    mill.chatter_gain = None;
    mill.gain_ratio = None;
    mill.band_rms_max = None;
    mill.worst_stand = None;
    let words = map.encode(&results);
    assert_eq!(words[base + 1], 0b000_0111);
    assert_eq!(words[base + 8..base + 15], [0; 7]);

    // Stale: every value reads 0 with its quality bit clear; the request holds.
    let mill = &mut results.tandem_mills[0];
    mill.gain_ratio = Some(1.25);
    mill.source_stale = true;
    mill.chatter_warning = false;
    let words = map.encode(&results);
    assert_eq!(
        words[base], 0b1110,
        "alarm (latched), stale, slow-down held"
    );
    assert_eq!(words[base + 1], 0);
    assert_eq!(words[base + 2..base + 15], [0; 13]);
}

#[test]
fn driveline_block_golden_words_and_the_stale_rule() {
    let config = example("hot-mill.toml");
    let map = RegisterMap::new(&config);
    let base = usize::from(
        map.named("F1 main drive.flags")
            .expect("driveline block")
            .address,
    );
    let mut results = Results::new(config.sources().count(), config.drivelines.len(), 0);
    let driveline = DrivelineResults {
        bite_counter: 70_000,
        degraded_bites: 2,
        last_bite_unix_ms: Some(1_800_000_000_999),
        taf: Some(1.5),
        gap: Some(crate::state::results::GapResults {
            gap_mrad: 2.5,
            low_mrad: 2.0,
            high_mrad: 3.0,
            coupling: None,
            likeliest_coupling: Some(1),
            bites_pooled: 12,
            growth: None,
            forecast: None,
        }),
        taf_warning: true,
        restored: true,
        ..DrivelineResults::default()
    };
    results.drivelines[0] = driveline.clone();
    let words = map.encode(&results);
    assert_eq!(words[base], 0b100_0001, "taf_warning, restored");
    // last_bite_time (bit 0), taf (3), gap, interval (9-11), bites_pooled (13): the
    // coupling is undetermined, bit 12 clear.
    assert_eq!(words[base + 1], 0b10_1110_0000_1001);
    assert_eq!(words[base + 2..base + 4], [0x0001, 0x1170], "70 000");
    // 1 800 000 000 s = 0x6B49D200, whole seconds.
    assert_eq!(words[base + 4..base + 6], [0x6B49, 0xD200]);
    assert_eq!(words[base + 10..base + 12], [0x3FC0, 0], "TAF 1.5");
    assert_eq!(words[base + 22..base + 24], [0x4020, 0], "gap 2.5 mrad");
    assert_eq!(words[base + 28], 0, "undetermined coupling: no value");
    assert_eq!(words[base + 29], 12);
    assert_eq!(words[base + 30..base + 32], [0, 2], "degraded bites");

    // Stale: the last bite's values are withheld (last usable only), counters and
    // flags stay.
    results.drivelines[0].source_stale = true;
    let words = map.encode(&results);
    assert_eq!(
        words[base], 0b100_0101,
        "taf_warning, source_stale, restored"
    );
    assert_eq!(words[base + 1], 0);
    assert_eq!(words[base + 2..base + 4], [0x0001, 0x1170]);
    assert!(words[base + 4..base + 30].iter().all(|&w| w == 0));
    assert_eq!(words[base + 30..base + 32], [0, 2]);
}

#[test]
fn the_extension_block_holds_the_figures_declared_on_it_after_every_block() {
    let config = example("hot-mill.toml");
    let map = RegisterMap::new(&config);
    let quality = map
        .named("F1 main drive.extension_quality")
        .expect("the driveline's extension block")
        .address;
    assert_eq!(quality, map.plc_span(false) + 1, "after the first layout");
    let q = usize::from(quality);
    let mut results = Results::new(config.sources().count(), config.drivelines.len(), 0);
    results.drivelines[0] = DrivelineResults {
        first_period_s: Some(0.0625),
        gap: Some(crate::state::results::GapResults {
            gap_mrad: 2.5,
            low_mrad: 2.0,
            high_mrad: 3.0,
            coupling: None,
            likeliest_coupling: Some(2),
            bites_pooled: 12,
            growth: None,
            forecast: None,
        }),
        ..DrivelineResults::default()
    };
    let words = map.encode(&results);
    assert_eq!(words[q], 0b11, "first_period_s, likeliest_coupling valid");
    // 0.0625 = 0x3D800000 (f32 ABCD).
    assert_eq!(words[q + 1..q + 4], [0x3D80, 0, 2]);
    results.drivelines[0].source_stale = true;
    let words = map.encode(&results);
    assert_eq!(words[q..q + 4], [0; 4], "withheld while stale");
}

/// Every figure of `figures` has a register with a guard that fits it, or a
/// reason; each page's registers fit `strides[page]` (after its flags and quality
/// registers) and overlap nothing; a quality bit guards one value of its page.
fn covers<R: Subject>(figures: &[Figure<R>], strides: &[u16]) {
    let kind = R::KIND;
    let mut used: Vec<Vec<bool>> = strides
        .iter()
        .map(|&stride| {
            let mut used = vec![false; usize::from(stride)];
            used[0] = true;
            used[1] = true;
            used
        })
        .collect();
    let mut bits: Vec<Vec<u8>> = vec![Vec::new(); strides.len()];
    for figure in figures {
        match (figure.register, figure.guard) {
            (
                catalogue::Register::At {
                    page,
                    offset,
                    value_type,
                },
                guard,
            ) => {
                let page = usize::from(page);
                let words = used
                    .get_mut(page)
                    .unwrap_or_else(|| panic!("{}: no page {page}", figure.key));
                for word in offset..offset + value_type.register_count() {
                    let slot = words
                        .get_mut(usize::from(word))
                        .unwrap_or_else(|| panic!("{} runs past the block", figure.key));
                    assert!(!*slot, "{} overlaps another register", figure.key);
                    *slot = true;
                }
                match guard {
                    Guard::QualityBit(bit) => {
                        assert!(bit < 16, "{}", figure.key);
                        assert!(
                            !bits[page].contains(&bit),
                            "{}: bit {bit} twice",
                            figure.key
                        );
                        bits[page].push(bit);
                    }
                    Guard::Always => assert!(figure.is_counter(), "{}", figure.key),
                    other => panic!("{}: a register value guarded by {other:?}", figure.key),
                }
            }
            (catalogue::Register::Flag, guard) => {
                assert!(matches!(guard, Guard::FlagBit(_)), "{}", figure.key)
            }
            (catalogue::Register::IndexBit { .. }, _) => {
                panic!(
                    "{}: a block's figure as a global register's bit",
                    figure.key
                )
            }
            (catalogue::Register::NotMapped(why), guard) => {
                assert!(
                    !why.is_empty(),
                    "{} {} needs a reason",
                    kind.name(),
                    figure.key
                );
                assert!(
                    matches!(guard, Guard::Presence | Guard::Always),
                    "{}: unmapped, guarded by {guard:?}",
                    figure.key
                );
            }
        }
    }
}

#[test]
fn every_catalogue_figure_has_a_register_or_a_reason() {
    covers(
        catalogue::DRIVELINE,
        &[DRIVELINE_STRIDE, DRIVELINE_EXTENSION_STRIDE],
    );
    covers(catalogue::TANDEM_MILL, &[TANDEM_MILL_STRIDE]);
    covers(catalogue::ROD_MILL, &[ROD_SPANS_START]);
    covers(catalogue::ROD_SPAN, &[ROD_SPAN_STRIDE]);
}

#[test]
fn register_names_are_block_names_and_catalogue_keys() {
    let map = RegisterMap::new(&example("rod-mill.toml"));
    let keys: Vec<&str> = catalogue::all().iter().map(|f| f.key).collect();
    for register in map.registers() {
        let key = register.name.rsplit('.').next().unwrap_or_default();
        let named = match register.field {
            Field::AcknowledgeAlarms
            | Field::ResetWearTrend
            | Field::ResetWear
            | Field::ManualCapture
            | Field::ResetFatigue => register.name.starts_with("command."),
            Field::Flags(Block::Gateway) => register.name == GATEWAY_STATUS.1,
            Field::SourceBits(index) => {
                register.name == source_bits_name(catalogue::SOURCE[index].key)
            }
            _ => key == "flags" || QUALITY.contains(&key) || keys.contains(&key),
        };
        assert!(named, "{} is not named by a catalogue key", register.name);
    }
}

/// The global registers, as a PLC has always read them: heartbeat 0,
/// `gateway_status` 1 (bit0 running, bit1 stopped, bit2 a source not ok),
/// `sources_ok` 2, `sources_stale` 3, `sources_lost` 4 (bit i: source i), the
/// commands at 8..=12; nothing else below the first block.
#[test]
fn the_global_registers_golden_words() {
    let map = RegisterMap::new(&example("hot-mill.toml"));
    let globals: Vec<(u16, &str, &str)> = map
        .registers()
        .iter()
        .filter(|r| r.address < DRIVELINES_START)
        .map(|r| (r.address, r.name.as_str(), r.unit))
        .collect();
    assert_eq!(
        globals,
        [
            (0, "heartbeat", ""),
            (1, "gateway_status", "bits"),
            (2, "sources_ok", "bits"),
            (3, "sources_stale", "bits"),
            (4, "sources_lost", "bits"),
            (8, "command.acknowledge_alarms", ""),
            (9, "command.reset_wear_trend", "bits"),
            (10, "command.reset_wear", ""),
            (11, "command.manual_capture", ""),
            (12, "command.reset_fatigue", ""),
        ]
    );
    assert!(map
        .registers()
        .iter()
        .filter(|r| r.address < DRIVELINES_START)
        .all(|r| r.value_type == ValueType::U16));
    let mut results = Results::new(5, 1, 0);
    assert_eq!(map.encode(&results)[..5], [0, 0b100, 0, 0, 0], "starting");
    results.state = crate::state::results::GatewayState::Running;
    results.heartbeat = 65_535;
    let (ok, stale, lost) = (SourceStatus::Ok, SourceStatus::Stale, SourceStatus::Lost);
    results.sources = [ok, stale, lost, ok, ok].map(Some).to_vec();
    let words = map.encode(&results);
    assert_eq!(words[..5], [65_535, 0b101, 0b11001, 0b10, 0b100]);
    results.sources = vec![Some(ok); 5];
    results.state = crate::state::results::GatewayState::Stopped;
    assert_eq!(map.encode(&results)[..5], [65_535, 0b010, 0b11111, 0, 0]);
    assert_eq!(
        flag_mask(catalogue::GATEWAY, "source_problem"),
        0b100,
        "as PLC programs test it"
    );
}

/// The gateway's and the sources' figures are the global registers': each has a
/// register (the gateway's block from 0, its flags in `gateway_status`, a source's
/// flag a bit of a global register) or a reason, below the first block and apart
/// from the command registers.
#[test]
fn every_gateway_and_source_figure_has_a_global_register_or_a_reason() {
    let commands = 8..12;
    let mut used = vec![GATEWAY_STATUS.0];
    for figure in catalogue::GATEWAY {
        match (figure.register, figure.guard) {
            (catalogue::Register::At { page, offset, .. }, Guard::Always) => {
                assert_eq!(page, 0, "{}", figure.key);
                used.push(offset);
            }
            (catalogue::Register::Flag, Guard::FlagBit(bit)) => {
                assert!(bit < 16, "{}", figure.key)
            }
            (catalogue::Register::NotMapped(why), Guard::Presence) => {
                assert!(!why.is_empty(), "gateway {} needs a reason", figure.key)
            }
            other => panic!("gateway {}: {other:?}", figure.key),
        }
    }
    for figure in catalogue::SOURCE {
        match (figure.register, figure.guard) {
            (catalogue::Register::IndexBit { address }, Guard::Presence) => {
                assert_eq!(figure.figure_type, FigureType::Bool, "{}", figure.key);
                used.push(address);
            }
            (catalogue::Register::NotMapped(why), Guard::Presence) => {
                assert!(!why.is_empty(), "source {} needs a reason", figure.key)
            }
            other => panic!("source {}: {other:?}", figure.key),
        }
    }
    let mut unique = used.clone();
    unique.sort_unstable();
    unique.dedup();
    assert_eq!(
        unique.len(),
        used.len(),
        "two figures at one address: {used:?}"
    );
    for address in used {
        assert!(address < DRIVELINES_START && !commands.contains(&address));
    }
    let map = RegisterMap::new(&example("hot-mill.toml"));
    for (index, figure) in catalogue::SOURCE.iter().enumerate() {
        if let catalogue::Register::IndexBit { address } = figure.register {
            let register = map.find(address).expect("a register");
            assert_eq!(register.field, Field::SourceBits(index));
        }
    }
}

/// `outputs.driveline_slots` reserves driveline blocks (and extension blocks) that
/// read 0: a driveline added within them takes the next one and moves no other
/// address, and without the key the map is the first layout exactly.
#[test]
fn reserved_driveline_slots_read_zero_and_a_driveline_added_within_them_moves_nothing() {
    let mut config = example("hot-mill.toml");
    config.tandem_mills = example("tandem-5stand.toml").tandem_mills;
    config.rod_mills = example("rod-mill.toml").rod_mills;
    let first_layout = RegisterMap::new(&config);
    config.outputs.driveline_slots = Some(1);
    assert_eq!(
        RegisterMap::new(&config),
        first_layout,
        "as many slots as drivelines: today's layout"
    );
    config.outputs.driveline_slots = Some(3);
    let reserved = RegisterMap::new(&config);
    assert_eq!(
        reserved.len(),
        first_layout.len() + 2 * (DRIVELINE_STRIDE + DRIVELINE_EXTENSION_STRIDE)
    );
    let slot2 = reserved
        .named("driveline_slot2.quality")
        .expect("slot 2 listed");
    assert_eq!(slot2.address, DRIVELINES_START + DRIVELINE_STRIDE + 1);
    assert!(reserved
        .named("driveline_slot3.extension_quality")
        .is_some());
    assert!(reserved.named("driveline_slot1.quality").is_none(), "taken");
    // The blocks still tile the map, a reserved one among them, so the PLC is
    // written its zeros.
    let blocks = reserved.blocks();
    assert_eq!(blocks.len(), first_layout.blocks().len() + 4);
    for pair in blocks.windows(2) {
        assert_eq!(pair[0].end, pair[1].start);
    }
    let results = Results::new(config.sources().count(), config.drivelines.len(), 1);
    let words = reserved.encode(&results);
    let slot2_block = DRIVELINES_START + DRIVELINE_STRIDE;
    let range = usize::from(slot2_block)..usize::from(slot2_block + DRIVELINE_STRIDE);
    assert!(
        words[range].iter().all(|w| *w == 0),
        "a reserved block reads 0"
    );

    // A second driveline takes slot 2: every other register keeps its address.
    let mut grown = config.clone();
    let mut f2 = grown.drivelines[0].clone();
    f2.name = "F2".into();
    grown.drivelines.push(f2);
    let added = RegisterMap::new(&grown);
    assert_eq!(added.len(), reserved.len());
    assert_eq!(added.blocks(), reserved.blocks());
    assert_eq!(added.named("F2.flags").unwrap().address, slot2_block);
    let f1_ext = added.named("F2.extension_quality").unwrap().address;
    assert_eq!(
        Some(f1_ext),
        reserved
            .named("driveline_slot2.extension_quality")
            .map(|r| r.address)
    );
    for register in reserved.registers() {
        if register.name.starts_with("driveline_slot2.") {
            continue;
        }
        assert_eq!(
            added.named(&register.name).map(|r| r.address),
            Some(register.address),
            "{} moved",
            register.name
        );
    }
    // Without slots the same driveline moves the mills' blocks.
    let mut unreserved = grown.clone();
    unreserved.outputs.driveline_slots = None;
    let moved = RegisterMap::new(&unreserved);
    assert_ne!(
        moved.named("TCM 2030.flags").map(|r| r.address),
        reserved.named("TCM 2030.flags").map(|r| r.address)
    );
}

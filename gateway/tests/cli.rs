//! The `millgate` binary as a user runs it.

mod common;

use common::{millgate, scratch, text, KillOnDrop, TempDir, MILLGATE};
use std::path::PathBuf;
use std::process::Command;

fn examples() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/examples")
}

/// Writes `body` as `mill.toml` in a scratch folder beside a copy of the demo's
/// driveline model (which the demo configuration names); the folder and the file.
fn write_config(name: &str, body: &str) -> (TempDir, PathBuf) {
    let folder = scratch(&format!("cli-{name}"));
    let dir = folder.path();
    std::fs::copy(
        examples().join("table2-adjusted.toml"),
        dir.join("table2-adjusted.toml"),
    )
    .unwrap();
    let path = dir.join("mill.toml");
    std::fs::write(&path, body).unwrap();
    (folder, path)
}

#[test]
fn check_accepts_every_example_and_prints_a_summary() {
    for example in [
        "hot-mill.toml",
        "tandem-5stand.toml",
        "demo.toml",
        "rod-mill.toml",
    ] {
        let path = examples().join(example);
        let output = millgate(&["check", "--config", path.to_str().unwrap()]);
        assert!(output.status.success(), "{example}: {}", text(&output));
        assert!(!output.stdout.is_empty(), "{example}: empty summary");
    }
    // The demo compresses wear into seconds: its summary says the growth span it sets.
    let demo = millgate(&[
        "check",
        "--config",
        examples().join("demo.toml").to_str().unwrap(),
    ]);
    assert!(
        text(&demo).contains("forecast over 365 days, growth from bites over 0 s apart)"),
        "{}",
        text(&demo)
    );
}

#[test]
fn check_names_the_key_and_the_known_channels_of_a_misspelt_name() {
    let demo = std::fs::read_to_string(examples().join("demo.toml")).unwrap();
    let misspelt = demo.replace("torque = \"spindle_top\"", "torque = \"spindel_top\"");
    assert_ne!(
        demo, misspelt,
        "the demo config names spindle_top as the torque"
    );
    let (_folder, path) = write_config("misspelt", &misspelt);
    let output = millgate(&["check", "--config", path.to_str().unwrap()]);
    let said = text(&output);
    assert!(!output.status.success(), "must fail: {said}");
    assert!(said.contains("mill.toml"), "names the file: {said}");
    assert!(
        said.contains("drivelines[0].torque"),
        "names the key: {said}"
    );
    assert!(
        said.contains("spindel_top") && said.contains("spindle_top"),
        "names both: {said}"
    );
}

#[test]
fn check_builds_the_driveline_model_and_names_the_model_file_and_key() {
    let model = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../sim/models/table2-adjusted.toml"),
    )
    .unwrap();
    let malformed = model.replace("inertia = 11.85e3", "inertia = -11.85e3");
    assert_ne!(model, malformed, "the model has the pinion's inertia");
    let demo = std::fs::read_to_string(examples().join("demo.toml")).unwrap();
    let with_model = demo.replace(
        "model = \"table2-adjusted.toml\"",
        "model = \"bad-model.toml\"",
    );
    assert_ne!(demo, with_model, "the demo driveline names its model");
    let (_folder, path) = write_config("bad-model", &with_model);
    let model_path = path.with_file_name("bad-model.toml");
    std::fs::write(&model_path, malformed).unwrap();
    let output = millgate(&["check", "--config", path.to_str().unwrap()]);
    let said = text(&output);
    assert!(!output.status.success(), "must fail: {said}");
    assert!(
        said.contains("mill.toml: drivelines[0].model: "),
        "names the configuration file and key: {said}"
    );
    assert!(
        said.contains("bad-model.toml"),
        "names the model file: {said}"
    );
    assert!(
        said.contains("mass[1].inertia: -11850 is not allowed"),
        "names the key in the model: {said}"
    );
    // The same model, valid, passes: the wear reference is built from it.
    std::fs::write(&model_path, model).unwrap();
    let output = millgate(&["check", "--config", path.to_str().unwrap()]);
    assert!(output.status.success(), "{}", text(&output));
}

#[test]
fn check_names_the_line_of_malformed_toml() {
    let (_folder, path) = write_config("malformed", "name = \"x\"\n\n[[channels]\nname = 1\n");
    let output = millgate(&["check", "--config", path.to_str().unwrap()]);
    let said = text(&output);
    assert!(!output.status.success(), "must fail: {said}");
    assert!(said.contains("line 3"), "names the line: {said}");
}

// Runs a command of the `sim-tools` feature.
#[cfg(feature = "sim-tools")]
#[test]
fn demo_prints_bites_within_two_percent_of_the_simulated_truth() {
    let output = millgate(&["demo", "--duration", "4"]);
    let said = text(&output);
    assert!(output.status.success(), "{said}");
    // Bite rows: "time static TAF truth error% | gap truth, this bite, trend (low ..
    // high), coupling, growth, forecast".
    let rows: Vec<(&str, &str)> = said.lines().filter_map(|l| l.split_once(" | ")).collect();
    let errors: Vec<f64> = rows
        .iter()
        .filter_map(|(taf, _)| {
            taf.split_whitespace()
                .last()?
                .strip_suffix('%')?
                .parse()
                .ok()
        })
        .collect();
    assert!(!errors.is_empty(), "no bite printed: {said}");
    assert!(
        errors.iter().all(|e: &f64| e.abs() < 2.0),
        "TAF errors {errors:?}: {said}"
    );
    // Each bite's own gap estimate beside the simulated gap (1 mrad growing); "-"
    // while the maps are still building.
    let gaps: Vec<(f64, f64)> = rows
        .iter()
        .filter_map(|(_, gap)| {
            let mut words = gap.split_whitespace();
            Some((words.next()?.parse().ok()?, words.next()?.parse().ok()?))
        })
        .collect();
    assert!(!gaps.is_empty(), "no gap estimate printed: {said}");
    for (truth, bite) in gaps {
        assert!(
            (bite - truth).abs() < 0.3,
            "gap {bite} vs truth {truth}: {said}"
        );
    }
    // The wear trend's 90% interval holds the simulated gap at every bite: it follows
    // the growth (the pooled estimate of old lagged it and missed).
    let mut intervals = 0;
    for (_, right) in &rows {
        let words: Vec<&str> = right.split_whitespace().collect();
        let number = |k: usize, trim: &dyn Fn(&str) -> Option<&str>| {
            words
                .get(k)
                .and_then(|w| trim(w))
                .and_then(|w| w.parse::<f64>().ok())
        };
        let truth = number(0, &|w| Some(w));
        let low = number(3, &|w| w.strip_prefix('('));
        let high = number(5, &|w| w.strip_suffix(')'));
        if let (Some(truth), Some(low), Some(high)) = (truth, low, high) {
            assert!(
                low <= truth && truth <= high,
                "{truth} outside {low} .. {high}: {said}"
            );
            intervals += 1;
        }
    }
    assert!(intervals >= 1, "no trend interval printed: {said}");
    // The wear registers filled and valid (quality bits 9 gap_mrad .. 11 gap_high_mrad,
    // 13 bites_pooled); the coupling (bit 12) only once the bites name it.
    let quality: u16 = said
        .lines()
        .find(|l| l.contains("F1.quality"))
        .and_then(|l| l.split_whitespace().nth(2)?.parse().ok())
        .expect("quality register printed");
    assert_eq!(quality & (0b10111 << 9), 0b10111 << 9, "{said}");
    // After the bar: gap truth, this bite, the trend "g (low .. high)", its coupling,
    // then growth and forecast.
    let last_coupling = said
        .lines()
        .filter_map(|l| l.split_once(" | "))
        .map(|(_, right)| right.split_whitespace().nth(6).unwrap_or("-"))
        .next_back()
        .expect("a bite printed");
    assert_eq!(
        quality & (1 << 12) != 0,
        last_coupling.parse::<u16>().is_ok(),
        "gap_coupling valid exactly when the last bite names a coupling ({last_coupling}): {said}"
    );
    assert!(
        said.contains("F1.gap_mrad"),
        "register snapshot printed: {said}"
    );
}

/// The text of `docs/{page}` between `<!-- {marker}:begin -->` and `<!-- {marker}:end -->`.
fn readme_section(page: &str, marker: &str) -> String {
    let readme = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("../docs/{page}")),
    )
    .unwrap();
    let begin = format!("<!-- {marker}:begin -->\n");
    let start = readme
        .find(&begin)
        .unwrap_or_else(|| panic!("docs/{page} has the {marker}:begin marker"))
        + begin.len();
    let end = readme
        .find(&format!("<!-- {marker}:end -->"))
        .unwrap_or_else(|| panic!("docs/{page} has the {marker}:end marker"));
    readme[start..end].to_owned()
}

#[test]
fn readme_register_table_is_the_generated_one() {
    let config = examples().join("hot-mill.toml");
    let output = millgate(&[
        "registers",
        "--config",
        config.to_str().unwrap(),
        "--format",
        "md",
    ]);
    assert!(output.status.success(), "{}", text(&output));
    let generated = String::from_utf8(output.stdout).unwrap();
    assert_eq!(
        readme_section("register-map.md", "registers"),
        generated,
        "docs/register-map.md register table differs: regenerate it with millgate registers --config config/examples/hot-mill.toml --format md"
    );
}

#[test]
fn readme_figure_table_is_the_generated_one_and_the_exports_agree() {
    let output = millgate(&["figures", "--format", "md"]);
    assert!(output.status.success(), "{}", text(&output));
    let generated = String::from_utf8(output.stdout).unwrap();
    assert_eq!(
        readme_section("figures.md", "figures"),
        generated,
        "docs/figures.md figure table differs: regenerate it with millgate figures --format md"
    );
    // The JSON export: one object per catalogue figure, with every output's name.
    let json = millgate(&["figures", "--format", "json"]);
    let rows: Vec<serde_json::Value> = serde_json::from_slice(&json.stdout).unwrap();
    assert_eq!(rows.len(), millgate::state::catalogue::all().len());
    for row in &rows {
        for field in [
            "subject",
            "key",
            "register",
            "sparkplug",
            "metric",
            "history",
        ] {
            assert!(row[field].is_string(), "{field} of {row}");
        }
    }
    let csv = millgate(&["figures", "--format", "csv"]);
    let csv = String::from_utf8(csv.stdout).unwrap();
    assert_eq!(
        csv.lines().count(),
        rows.len() + 1,
        "a header and a row each"
    );
}

/// `registers --context`: what the PLC must provide for the context tags of the
/// demo's driveline (state, speed as f32 CDAB, a coil as text, product with its codes), from the
/// configuration's channels.
#[test]
fn registers_context_lists_what_the_plc_must_provide_for_the_context_tags() {
    let demo = std::fs::read_to_string(examples().join("demo.toml")).unwrap();
    let body = demo.replacen(
        "[[drivelines]]",
        "[[sources.modbus]]\nname = \"mill_plc\"\naddress = \"127.0.0.1:5031\"\npoll_period_ms = 100\n\n\
         [[channels]]\nname = \"mill_state\"\nkind = \"process_value\"\nunit = \"1\"\n\
         source = { modbus = \"mill_plc\", table = \"holding\", address = 40 }\n\n\
         [[channels]]\nname = \"mill_speed\"\nkind = \"process_value\"\nunit = \"m/min\"\n\
         source = { modbus = \"mill_plc\", table = \"input\", address = 41, type = \"f32\", word_order = \"CDAB\" }\n\n\
         [[channels]]\nname = \"grade\"\nkind = \"process_value\"\nunit = \"1\"\n\
         source = { modbus = \"mill_plc\", table = \"holding\", address = 43 }\n\n\
         [[channels]]\nname = \"coil_id\"\nkind = \"process_value\"\nunit = \"1\"\n\
         source = { modbus = \"mill_plc\", table = \"holding\", address = 44, type = \"ascii\", registers = 8 }\n\n\
         [[drivelines]]\ncontext = { state = \"mill_state\", speed_mpm = \"mill_speed\", coil = \"coil_id\", product = \"grade\", products = [101, 205] }",
        1,
    );
    let (_folder, path) = write_config("registers-context", &body);
    let md = millgate(&["registers", "--config", path.to_str().unwrap(), "--context"]);
    assert!(md.status.success(), "{}", text(&md));
    let md = String::from_utf8(md.stdout).unwrap();
    for line in [
        "| F1 | speed_mpm | mill_speed | mill_plc | input | 41 | f32 CDAB, x 1 + 0 | >= 0 m/min |",
        "| F1 | product | grade | mill_plc | holding | 43 | u16 ABCD, x 1 + 0 | one of 101, 205 |",
        "| F1 | coil | coil_id | mill_plc | holding | 44 | ascii, 8 registers, high_first | 1..=16 printable ASCII characters (0x20..=0x7E), ended by a NUL or padded with spaces |",
        "| F1 | state | mill_state | mill_plc | holding | 40 | u16 ABCD, x 1 + 0 | 0 idle, 1 threading, 2 rolling, 3 maintenance |",
    ] {
        assert!(md.lines().any(|l| l == line), "{line} not in:\n{md}");
    }
    let csv = millgate(&[
        "registers",
        "--config",
        path.to_str().unwrap(),
        "--context",
        "--format",
        "csv",
    ]);
    let csv = String::from_utf8(csv.stdout).unwrap();
    assert_eq!(
        csv.lines().next(),
        Some("subject,tag,channel,source,table,address,encoding,allowed")
    );
    assert_eq!(csv.lines().count(), 5, "{csv}");
    // Without context tags: the header only.
    let none = millgate(&[
        "registers",
        "--config",
        examples().join("demo.toml").to_str().unwrap(),
        "--context",
        "--format",
        "csv",
    ]);
    assert_eq!(String::from_utf8(none.stdout).unwrap().lines().count(), 1);
}

#[test]
fn registers_export_json_and_csv_have_the_documented_fields() {
    let config = examples().join("tandem-5stand.toml");
    let json = millgate(&[
        "registers",
        "--config",
        config.to_str().unwrap(),
        "--format",
        "json",
    ]);
    assert!(json.status.success(), "{}", text(&json));
    let rows: Vec<serde_json::Value> = serde_json::from_slice(&json.stdout).unwrap();
    assert!(rows
        .iter()
        .any(|r| r["name"].as_str().is_some_and(|n| n.ends_with(".k_mean"))));
    // The band-gain registers of the mill block (offsets 8-14 after the block start).
    let row = |suffix: &str| {
        rows.iter()
            .find(|r| r["name"].as_str().is_some_and(|n| n.ends_with(suffix)))
            .unwrap_or_else(|| panic!("no {suffix} register"))
    };
    let flags = row(".flags")["address"].as_u64().unwrap();
    for (suffix, offset, value_type) in [
        (".chatter_gain", 8, "f32"),
        (".gain_ratio", 10, "f32"),
        (".band_rms_max", 12, "f32"),
        (".worst_stand", 14, "u16"),
    ] {
        assert_eq!(
            row(suffix)["address"].as_u64(),
            Some(flags + offset),
            "{suffix}"
        );
        assert_eq!(row(suffix)["type"].as_str(), Some(value_type), "{suffix}");
    }
    assert!(row(".flags")["description"]
        .as_str()
        .is_some_and(|d| d.contains("bit3 slow_down_request: Slow-down request")));
    for row in &rows {
        for key in [
            "name",
            "address",
            "type",
            "scale",
            "word_order",
            "unit",
            "access",
            "description",
        ] {
            assert!(row.get(key).is_some(), "{key} missing in {row}");
        }
        assert!(["u16", "i16", "u32", "i32", "f32"].contains(&row["type"].as_str().unwrap()));
        assert!(["r", "rw"].contains(&row["access"].as_str().unwrap()));
    }
    let csv = millgate(&[
        "registers",
        "--config",
        config.to_str().unwrap(),
        "--format",
        "csv",
    ]);
    let csv = String::from_utf8(csv.stdout).unwrap();
    assert_eq!(
        csv.lines().next(),
        Some("name,address,plc_address,type,scale,word_order,unit,access,description")
    );
    assert_eq!(csv.lines().count(), rows.len() + 1);
    // Absolute PLC addresses beside the offsets: the example writes its map from
    // holding register 2000 (outputs.plc.register_base), read from the file here.
    let base: u64 = std::fs::read_to_string(&config)
        .unwrap()
        .lines()
        .find_map(|line| line.strip_prefix("register_base = "))
        .and_then(|value| value.split_whitespace().next()?.parse().ok())
        .expect("the example's register_base");
    for (row, line) in rows.iter().zip(csv.lines().skip(1)) {
        let offset = row["address"].as_u64().unwrap();
        assert_eq!(row["plc_address"].as_u64(), Some(base + offset), "{row}");
        let cells: Vec<&str> = line.splitn(4, ',').collect();
        assert_eq!(
            cells[1..3],
            [offset.to_string(), (base + offset).to_string()]
        );
    }
    // Without a PLC output there is no PLC address.
    let demo = std::fs::read_to_string(examples().join("demo.toml")).unwrap();
    let start = demo.find("[outputs.plc]").unwrap();
    let end = start + demo[start..].find("\n[").unwrap() + 1;
    let (_folder, path) = write_config("no-plc", &format!("{}{}", &demo[..start], &demo[end..]));
    let json = millgate(&[
        "registers",
        "--config",
        path.to_str().unwrap(),
        "--format",
        "json",
    ]);
    assert!(json.status.success(), "{}", text(&json));
    let rows: Vec<serde_json::Value> = serde_json::from_slice(&json.stdout).unwrap();
    assert!(
        rows.iter().all(|row| row["plc_address"].is_null()),
        "{rows:?}"
    );
}

/// `history --format` says what it exports, not the register map's formats.
#[test]
fn history_format_help_describes_the_history_export() {
    let help = millgate(&["history", "--help"]);
    assert!(help.status.success(), "{}", text(&help));
    let help = String::from_utf8(help.stdout).unwrap();
    let formats = &help[help.find("--format").expect("--format in the help")..];
    assert!(formats.contains("one object per row"), "{formats}");
    assert!(
        !formats.contains("register") && !formats.contains("README"),
        "{formats}"
    );
}

/// The exit status of each kind of outcome, as docs/usage.md's table states it.
#[test]
fn exit_codes_are_the_documented_ones() {
    let readme =
        std::fs::read_to_string(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../docs/usage.md"))
            .unwrap();
    for (status, _) in millgate::cli::shell::EXIT_STATUS {
        assert!(
            readme.contains(&format!("| {status} |")),
            "docs/usage.md's exit status table lists {status}"
        );
    }
    let valid = examples().join("demo.toml");
    let valid = valid.to_str().unwrap();
    let (_folder, broken) =
        write_config("exit-codes", "name = \"x\"\n[[sources.modbus]]\nname = 1\n");
    let broken = broken.to_str().unwrap();
    for (args, expected) in [
        (&["check", "--config", valid][..], 0),
        (&["--version"][..], 0),
        (&["check", "--help"][..], 0),
        (&["check", "--config", broken][..], 1),
        (&["check", "--config", "/nonexistent/mill.toml"][..], 1),
        (&["history", "--db", "/nonexistent/h.db"][..], 1),
        (&["registers", "--config", broken][..], 1),
        (&[][..], 2),
        (&["chek", "--config", valid][..], 2),
        (&["check"][..], 2),
        (&["check", "--config", valid, "--format", "xml"][..], 2),
        (&["history", "--db", "h.db", "--kind", "everything"][..], 2),
    ] {
        let output = millgate(args);
        assert_eq!(
            output.status.code(),
            Some(expected),
            "millgate {args:?}: {}",
            text(&output)
        );
        if expected == 2 {
            let stderr = String::from_utf8_lossy(&output.stderr);
            assert!(
                stderr.starts_with("error: ") || stderr.contains("Usage: millgate"),
                "{args:?}: {stderr}"
            );
        }
    }
}

#[test]
fn check_format_json_lists_the_problems_and_warnings_with_their_keys() {
    let demo = std::fs::read_to_string(examples().join("demo.toml")).unwrap();
    let bad = demo
        .replace("torque = \"spindle_top\"", "torque = \"spindel_top\"")
        .replace("register_base = 0", "register_base = 70000");
    let (_folder, path) = write_config("json-problems", &bad);
    let output = millgate(&[
        "check",
        "--config",
        path.to_str().unwrap(),
        "--format",
        "json",
    ]);
    assert_eq!(output.status.code(), Some(1), "{}", text(&output));
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(report["ok"], false, "{report}");
    assert!(report["summary"].is_null(), "{report}");
    let problems = report["problems"].as_array().unwrap();
    let mut keys: Vec<&str> = problems.iter().filter_map(|p| p["key"].as_str()).collect();
    keys.sort_unstable();
    assert_eq!(
        keys,
        ["drivelines[0].torque", "outputs.plc.register_base"],
        "{report}"
    );
    for problem in problems {
        let (file, key, message) = (
            problem["file"].as_str().unwrap(),
            problem["key"].as_str().unwrap(),
            problem["message"].as_str().unwrap(),
        );
        assert!(file.ends_with("mill.toml"), "{problem}");
        assert_eq!(problem["text"], format!("{file}: {key}: {message}"));
    }
    // The text format prints the same lines.
    let text_output = millgate(&["check", "--config", path.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&text_output.stderr);
    for problem in problems {
        assert!(
            stderr.contains(problem["text"].as_str().unwrap()),
            "{stderr}"
        );
    }

    // A valid file with a warning: exit 0, the summary and the warning's key.
    let open = demo.replace("bind = \"127.0.0.1:5503\"", "bind = \"0.0.0.0:5503\"");
    let (_folder, path) = write_config("json-warning", &open);
    let output = millgate(&[
        "check",
        "--config",
        path.to_str().unwrap(),
        "--format",
        "json",
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output));
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(report["ok"], true, "{report}");
    assert!(report["summary"].as_str().unwrap().contains("spindle_top"));
    assert_eq!(report["problems"], serde_json::json!([]));
    let warnings = report["warnings"].as_array().unwrap();
    assert_eq!(warnings.len(), 1, "{report}");
    assert_eq!(warnings[0]["key"], "outputs.server.bind", "{report}");
    assert!(warnings[0]["message"]
        .as_str()
        .unwrap()
        .starts_with("0.0.0.0:5503 accepts clients from other hosts"));
}

/// The bash completion, sourced into a real bash, completes the commands and a
/// command's options; the manual page, rendered by man, has every command and the
/// exit status.
#[test]
fn completions_and_the_manual_page_work_in_bash_and_man() {
    let script = millgate(&["completions", "bash"]);
    assert!(script.status.success(), "{}", text(&script));
    let scratch = scratch("cli-completion");
    let dir = scratch.path();
    let path = dir.join("millgate.bash");
    std::fs::write(&path, &script.stdout).unwrap();
    let complete = |words: &str| {
        let output = Command::new("bash")
            .arg("-c")
            .arg(format!(
                "source {}; COMP_WORDS=({words}); COMP_CWORD=$((${{#COMP_WORDS[@]}} - 1)); \
                 COMP_LINE=\"${{COMP_WORDS[*]}}\"; COMP_POINT=${{#COMP_LINE}}; \
                 _millgate millgate \"${{COMP_WORDS[COMP_CWORD]}}\" \
                 \"${{COMP_WORDS[COMP_CWORD - 1]}}\"; printf '%s\\n' \"${{COMPREPLY[@]}}\"",
                path.display()
            ))
            .output()
            .expect("bash");
        assert!(output.status.success(), "{}", text(&output));
        String::from_utf8(output.stdout).unwrap()
    };
    let completed = complete("millgate ch");
    let mut commands: Vec<&str> = completed.split_whitespace().collect();
    commands.sort_unstable();
    assert_eq!(commands, ["chatter", "check"]);
    let options = complete("millgate check --");
    assert!(
        options.lines().any(|o| o == "--config") && options.lines().any(|o| o == "--format"),
        "{options}"
    );
    let formats = complete("millgate check --format ''");
    assert_eq!(
        formats.split_whitespace().collect::<Vec<_>>(),
        ["text", "json"]
    );

    let page = millgate(&["man"]);
    assert!(page.status.success(), "{}", text(&page));
    let roff = dir.join("millgate.1");
    std::fs::write(&roff, &page.stdout).unwrap();
    match Command::new("man")
        .arg("-l")
        .arg(&roff)
        .env("MANWIDTH", "100")
        .output()
    {
        Ok(rendered) if rendered.status.success() => {
            let rendered = String::from_utf8_lossy(&rendered.stdout);
            assert!(rendered.contains("EXIT STATUS"), "{rendered}");
            for command in ["check", "run", "registers", "history", "completions", "man"] {
                assert!(
                    rendered.contains(&format!("millgate-{command}(1)")),
                    "{command}: {rendered}"
                );
            }
        }
        _ => eprintln!("man not installed: the page is checked as text only"),
    }
    let roff_text = String::from_utf8_lossy(&page.stdout);
    assert!(roff_text.contains(".SH \"EXIT STATUS\""), "{roff_text}");
    // One page per command into a folder.
    let folder = dir.join("man1");
    let written = millgate(&["man", "--out", folder.to_str().unwrap()]);
    assert!(written.status.success(), "{}", text(&written));
    for name in ["millgate.1", "millgate-check.1", "millgate-history.1"] {
        assert!(folder.join(name).is_file(), "{name}");
    }
}

// Runs a command of the `sim-tools` feature.
#[cfg(feature = "sim-tools")]
#[test]
fn analyze_finds_the_bite_of_a_simulated_transient_and_stiffness_inverts_table2() {
    let scratch = scratch("cli-analyze");
    let dir = scratch.path();
    let csv = dir.join("transient.csv");
    let model =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../sim/models/table2-adjusted.toml");
    let simulated = millgate(&[
        "sim",
        "transient",
        "--model",
        model.to_str().unwrap(),
        "--noise-rms",
        "0.5",
        "--seed",
        "4",
        "--out",
        csv.to_str().unwrap(),
    ]);
    assert!(simulated.status.success(), "{}", text(&simulated));
    // The record is 0.6 s with the bite at 0.05 s: the window ends with the record.
    let analyzed = millgate(&[
        "analyze",
        "--input",
        csv.to_str().unwrap(),
        "--format",
        "json",
    ]);
    assert!(analyzed.status.success(), "{}", text(&analyzed));
    let report: serde_json::Value = serde_json::from_slice(&analyzed.stdout).unwrap();
    let events = report["events"].as_array().unwrap();
    assert_eq!(events.len(), 1, "{report}");
    let static_knm = events[0]["static_torque"].as_f64().unwrap();
    assert!((static_knm - 112.0).abs() < 0.05 * 112.0, "{report}");
    let f2 = events[0]["fit"]["f2_hz"].as_f64().unwrap();
    assert!(
        (f2 - 21.09).abs() < 0.02 * 21.09,
        "second mode {f2}: {report}"
    );

    let inverse = millgate(&[
        "stiffness",
        "--inertia",
        "46.70e3,11.85e3,2.48e3",
        "--freq",
        "12.03,21.09",
        "--format",
        "json",
    ]);
    let solutions: serde_json::Value = serde_json::from_slice(&inverse.stdout).unwrap();
    let found = solutions["solutions"].as_array().unwrap().iter().any(|s| {
        (s["c12"].as_f64().unwrap() / 68.77e6 - 1.0).abs() < 0.005
            && (s["c23"].as_f64().unwrap() / 32.81e6 - 1.0).abs() < 0.005
    });
    assert!(found, "{solutions}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn run_stops_on_sigterm_with_a_final_stopped_write() {
    use millgate_sim::devices::modbus_bank::ServeOptions;
    use millgate_sim::devices::virtual_plc::VirtualPlc;

    // The demo's PLC is written the whole map, extension blocks too.
    let demo_map = millgate::outputs::modbus::register_map::RegisterMap::new(
        &millgate_config::load(&examples().join("demo.toml")).unwrap(),
    );
    let plc = VirtualPlc::new(usize::from(demo_map.plc_span(true)));
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let plc_address = listener.local_addr().unwrap();
    let running_plc = plc.spawn(listener, ServeOptions::default());

    let demo = std::fs::read_to_string(examples().join("demo.toml")).unwrap();
    let config = demo
        .replace("127.0.0.1:5020", "127.0.0.1:1")
        .replace("127.0.0.1:5502", &plc_address.to_string())
        .replace("127.0.0.1:5503", "127.0.0.1:0");
    let (_folder, path) = write_config("sigterm", &config);
    // Killed when a failing check ends the test early.
    let mut child = KillOnDrop(
        MILLGATE
            .command()
            .args(["run", "--config", path.to_str().unwrap()])
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let running = std::time::Instant::now();
    while plc.holding()[1] & 1 == 0 {
        assert!(
            running.elapsed() < std::time::Duration::from_secs(10),
            "never running"
        );
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
    }
    let killed = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let output = tokio::task::spawn_blocking(move || child.wait_with_output())
        .await
        .unwrap()
        .unwrap();
    let logs = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "exit {:?}: {logs}", output.status);
    assert!(logs.contains("shutdown requested"), "{logs}");
    assert_eq!(plc.holding()[1] & 0b11, 0b10, "status stopped, not running");
    running_plc.stop().await.unwrap();
}

/// Simulates the adjusted Table 2 driveline with a 2 mrad gap in the spindle at
/// `static_knm` into `dir/name.csv` (`millgate sim transient`, noise 0.5 kN*m).
#[cfg(feature = "sim-tools")]
fn gap_record(dir: &std::path::Path, name: &str, static_knm: f64, seed: u32) -> PathBuf {
    let models = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../sim/models");
    let adjusted = std::fs::read_to_string(models.join("table2-adjusted.toml")).unwrap();
    let with_gap = adjusted
        .replacen("damping = 5.0e3", "damping = 5.0e3\nbacklash = 2.0e-3", 1)
        .replacen(
            "static_torque = 112.0",
            &format!("static_torque = {static_knm:.1}"),
            1,
        );
    assert!(with_gap.contains("backlash") && with_gap.contains(&format!("{static_knm:.1}")));
    let truth = dir.join(format!("{name}.toml"));
    std::fs::write(&truth, with_gap).unwrap();
    let csv = dir.join(format!("{name}.csv"));
    let simulated = millgate(&[
        "sim",
        "transient",
        "--model",
        truth.to_str().unwrap(),
        "--noise-rms",
        "0.5",
        "--seed",
        &seed.to_string(),
        "--out",
        csv.to_str().unwrap(),
    ]);
    assert!(simulated.status.success(), "{}", text(&simulated));
    csv
}

// Runs a command of the `sim-tools` feature.
#[cfg(feature = "sim-tools")]
#[test]
fn discrepancy_splits_a_record_of_two_bites_and_finds_a_gap_from_drawing_stiffness() {
    let scratch = scratch("cli-discrepancy");
    let dir = scratch.path();
    let models = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../sim/models");
    // The "measured" driveline: the adjusted Table 2 model with a 2 mrad gap in the
    // spindle, two bites in one record (idle, bite, unloading ramp, idle, bite); the
    // workflow is handed the drawings' stiffness without the gap.
    let mut body = String::from("t,torque\n");
    let mut k = 0;
    let mut sample = |body: &mut String, value: f64| {
        body.push_str(&format!("{},{value}\n", k as f64 * 5.0e-4));
        k += 1;
    };
    for (i, (static_knm, seed)) in [(112.0, 9), (60.0, 10)].into_iter().enumerate() {
        let csv = gap_record(dir, &format!("bite{i}"), static_knm, seed);
        let values: Vec<f64> = std::fs::read_to_string(csv)
            .unwrap()
            .lines()
            .skip(1)
            .map(|line| line.split(',').nth(1).unwrap().parse().unwrap())
            .collect();
        for _ in 0..400 {
            sample(&mut body, 0.0);
        }
        for &value in &values {
            sample(&mut body, value);
        }
        let last = values[values.len() - 1];
        for step in 1..=100 {
            sample(&mut body, last * (1.0 - f64::from(step) / 100.0));
        }
    }
    let csv = dir.join("two-bites.csv");
    std::fs::write(&csv, body).unwrap();
    let report_dir = dir.join("report");
    let output = millgate(&[
        "discrepancy",
        "--measured",
        csv.to_str().unwrap(),
        "--model",
        models.join("table2-drawings.toml").to_str().unwrap(),
        "--report",
        report_dir.to_str().unwrap(),
        "--format",
        "json",
    ]);
    assert!(output.status.success(), "{}", text(&output));
    let progress = String::from_utf8_lossy(&output.stderr);
    assert!(progress.contains("two-bites.csv: 2 bites"), "{progress}");
    assert!(
        progress.contains("[9/9]") && progress.contains("calibration"),
        "{progress}"
    );
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(report["verdict"], "named", "{report}");
    assert_eq!(report["effect"], "backlash", "{report}");
    assert_eq!(report["location"], 1, "{report}");
    let width = report["parameters"]["width_rad"].as_f64().unwrap();
    assert!((width / 2.0e-3 - 1.0).abs() < 0.25, "{report}");
    // Per bite: its static torque and residuals, down to the noise after.
    let bites = report["bites"].as_array().unwrap();
    assert_eq!(bites.len(), 2, "{report}");
    for (bite, static_knm) in bites.iter().zip([112.0, 60.0]) {
        let fitted = bite["static_torque_knm"].as_f64().unwrap();
        assert!((fitted / static_knm - 1.0).abs() < 0.05, "{report}");
        let (before, after) = (
            bite["rmse_before"].as_f64().unwrap(),
            bite["rmse_after"].as_f64().unwrap(),
        );
        assert!(after < 0.6 && before > 3.0 * after, "{report}");
    }
    assert!(
        !report["disagreement"].as_array().unwrap().is_empty(),
        "{report}"
    );
    assert_eq!(
        report["candidates"].as_array().unwrap().len(),
        9,
        "{report}"
    );
    for key in ["calibration", "noise_rms", "candidates", "alternatives"] {
        assert!(!report[key].is_null(), "{key} missing: {report}");
    }
    // The report folder: a loadable extended model with the gap, the calibrated linear
    // model without it (stiffness moved from the drawings to the truth), the plot of
    // both bites, the summary.
    let extended =
        millgate_sim::model::Model::load(report_dir.join("extended-model.toml")).unwrap();
    assert!((extended.couplings[1].backlash / 2.0e-3 - 1.0).abs() < 0.25);
    let calibrated =
        millgate_sim::model::Model::load(report_dir.join("calibrated-model.toml")).unwrap();
    for (coupling, truth) in calibrated.couplings.iter().zip([68.77e6, 32.81e6]) {
        assert_eq!(coupling.backlash, 0.0);
        assert!(
            (coupling.stiffness / truth - 1.0).abs() < 0.05,
            "{} against {truth}",
            coupling.stiffness
        );
    }
    let svg = std::fs::read_to_string(report_dir.join("discrepancy.svg")).unwrap();
    assert!(
        svg.starts_with("<svg") && svg.contains("residual") && svg.contains("bite 2"),
        "not the plot of both bites"
    );
    let summary = std::fs::read_to_string(report_dir.join("summary.md")).unwrap();
    assert!(
        summary.contains("Missing effect: backlash in coupling 1"),
        "{summary}"
    );
}

// Runs a command of the `sim-tools` feature.
#[cfg(feature = "sim-tools")]
#[test]
fn discrepancy_takes_several_records_and_names_the_file_of_a_bad_bite() {
    let scratch = scratch("cli-bad-bite");
    let dir = scratch.path();
    // A load step of 400 samples, then one of 90: the second is too short, and the
    // error comes before any fit.
    let write = |name: &str, samples: usize| {
        let mut body = String::from("t,torque\n");
        for k in 0..samples {
            let value = if k < samples / 4 { 0.0 } else { 100.0 };
            body.push_str(&format!("{},{value}\n", k as f64 * 5.0e-4));
        }
        let path = dir.join(name);
        std::fs::write(&path, body).unwrap();
        path
    };
    let (good, short) = (write("good.csv", 400), write("short.csv", 90));
    let model =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../sim/models/table2-adjusted.toml");
    let output = millgate(&[
        "discrepancy",
        "--measured",
        good.to_str().unwrap(),
        "--measured",
        short.to_str().unwrap(),
        "--model",
        model.to_str().unwrap(),
    ]);
    assert!(!output.status.success());
    let message = text(&output);
    assert!(
        message.contains("short.csv")
            && message.contains("measured bite 2: 90 samples; at least 100 are needed")
            && !message.contains("good.csv"),
        "{message}"
    );
}

// Runs a command of the `sim-tools` feature.
#[cfg(feature = "sim-tools")]
#[test]
fn discrepancy_names_the_line_of_a_non_uniform_time_column() {
    let scratch = scratch("cli-nonuniform");
    let dir = scratch.path();
    let csv = dir.join("bad.csv");
    let mut body = String::from("t,torque\n");
    for k in 0..400 {
        // Sample 200 is missing: the step doubles between lines 201 and 202.
        if k != 200 {
            body.push_str(&format!("{},{}\n", k as f64 * 5.0e-4, 1.0));
        }
    }
    std::fs::write(&csv, body).unwrap();
    let model =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../sim/models/table2-adjusted.toml");
    let output = millgate(&[
        "discrepancy",
        "--measured",
        csv.to_str().unwrap(),
        "--model",
        model.to_str().unwrap(),
    ]);
    assert!(!output.status.success());
    let message = text(&output);
    assert!(
        message.contains("bad.csv: line 202") && message.contains("uniform"),
        "{message}"
    );
}

#[test]
fn sim_tandem_ramp_feeds_chatter_offline() {
    let scratch = scratch("cli-chatter");
    let dir = scratch.path();
    let csv = dir.join("stands.csv");
    let schedule =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../sim/schedules/lu2019-5stand.toml");
    // The documented `--ramp TO,ACCEL` form.
    let sim = millgate(&[
        "sim",
        "tandem",
        "--schedule",
        schedule.to_str().unwrap(),
        "--speed",
        "0.9",
        "--ramp",
        "1.4,1.0",
        "--hold",
        "1",
        "--duration",
        "3",
        "--out",
        csv.to_str().unwrap(),
    ]);
    assert!(sim.status.success(), "{}", text(&sim));
    let bad = millgate(&[
        "sim",
        "tandem",
        "--schedule",
        schedule.to_str().unwrap(),
        "--ramp",
        "1.4",
        "--out",
        csv.to_str().unwrap(),
    ]);
    assert!(!bad.status.success());
    assert!(
        text(&bad).contains("--ramp: 1 values is not allowed (must be TO,ACCEL"),
        "{}",
        text(&bad)
    );

    let config = examples().join("tandem-5stand.toml");
    let chatter = millgate(&[
        "chatter",
        "--input",
        csv.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
    ]);
    assert!(chatter.status.success(), "{}", text(&chatter));
    let out = String::from_utf8_lossy(&chatter.stdout);
    // 3 s: windows end 0.548 s and every 0.25 s after; stable rolling, no alarm.
    assert!(out.starts_with("     t_s    f1_hz     rms1"), "{out}");
    assert_eq!(out.lines().count(), 1 + 10 + 1, "{out}");
    assert!(out.trim_end().ends_with("first alarm: none"), "{out}");
    let missing = millgate(&[
        "chatter",
        "--input",
        csv.to_str().unwrap(),
        "--config",
        examples().join("hot-mill.toml").to_str().unwrap(),
    ]);
    assert!(!missing.status.success());
    assert!(
        text(&missing).contains("no [[tandem_mills]]"),
        "{}",
        text(&missing)
    );
}

// Runs a command of the `sim-tools` feature.
#[cfg(feature = "sim-tools")]
#[test]
fn analyze_and_discrepancy_refuse_a_record_scaled_beyond_any_mill() {
    let scratch = scratch("cli-scaled");
    let dir = scratch.path();
    let model =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../sim/models/table2-adjusted.toml");
    let csv = dir.join("transient.csv");
    let simulated = millgate(&[
        "sim",
        "transient",
        "--model",
        model.to_str().unwrap(),
        "--noise-rms",
        "0.5",
        "--seed",
        "4",
        "--out",
        csv.to_str().unwrap(),
    ]);
    assert!(simulated.status.success(), "{}", text(&simulated));
    // The simulated bite with its torque column multiplied by `factor`.
    let scaled = |name: &str, factor: f64| {
        let mut body = String::new();
        for (i, line) in std::fs::read_to_string(&csv).unwrap().lines().enumerate() {
            match (i, line.split_once(',')) {
                (0, _) | (_, None) => body.push_str(line),
                (_, Some((t, torque))) => {
                    let torque: f64 = torque.parse().unwrap();
                    body.push_str(&format!("{t},{:e}", torque * factor));
                }
            }
            body.push('\n');
        }
        let path = dir.join(name);
        std::fs::write(&path, body).unwrap();
        path
    };
    let huge = scaled("huge.csv", 1.0e300);
    let analyzed = millgate(&["analyze", "--input", huge.to_str().unwrap()]);
    let message = text(&analyzed);
    assert!(!analyzed.status.success(), "{message}");
    assert!(
        message.contains("huge.csv: line 2, column 2 (`torque`)")
            && message.contains("outside the physical range"),
        "{message}"
    );
    let tiny = scaled("tiny.csv", 1.0e-225);
    let output = millgate(&[
        "discrepancy",
        "--measured",
        tiny.to_str().unwrap(),
        "--model",
        model.to_str().unwrap(),
    ]);
    let message = text(&output);
    assert!(!output.status.success(), "{message}");
    assert!(
        message.contains("tiny.csv: the torque record's load step is")
            && message.contains("no mill's bite"),
        "{message}"
    );
}

// Runs a command of the `sim-tools` feature.
#[cfg(feature = "sim-tools")]
#[test]
fn discrepancy_on_a_constant_record_says_there_is_no_transient() {
    let scratch = scratch("cli-constant");
    let dir = scratch.path();
    let csv = dir.join("constant.csv");
    let mut body = String::from("t,torque\n");
    for k in 0..1200 {
        body.push_str(&format!("{},100\n", k as f64 * 5.0e-4));
    }
    std::fs::write(&csv, body).unwrap();
    let model =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../sim/models/table2-adjusted.toml");
    let output = millgate(&[
        "discrepancy",
        "--measured",
        csv.to_str().unwrap(),
        "--model",
        model.to_str().unwrap(),
    ]);
    assert!(!output.status.success());
    let message = text(&output);
    assert!(
        message.contains("constant.csv: the torque record has no transient"),
        "{message}"
    );
    assert!(!message.contains("extra_inertia"), "{message}");
}

/// `millgate sim tandem` of the example schedule into `dir/name.csv` with the truth
/// columns (`speed_factor`): `args` after the schedule.
#[cfg(feature = "sim-tools")]
fn tandem_record(dir: &std::path::Path, name: &str, args: &[&str]) -> PathBuf {
    let csv = dir.join(format!("{name}.csv"));
    let schedule =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../sim/schedules/lu2019-5stand.toml");
    let mut all = vec!["sim", "tandem", "--schedule", schedule.to_str().unwrap()];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--truth", "--out", csv.to_str().unwrap()]);
    let output = millgate(&all);
    assert!(output.status.success(), "{}", text(&output));
    csv
}

/// The numbers of a TOML line `key = [a, b, ...]` in `out`.
#[cfg(feature = "sim-tools")]
fn toml_list(out: &str, key: &str) -> Vec<f64> {
    let line = out
        .lines()
        .find_map(|l| l.strip_prefix(&format!("{key} = [")))
        .unwrap_or_else(|| panic!("no `{key} = [` line in {out}"));
    line.trim_end_matches(']')
        .split(',')
        .map(|v| v.trim().parse().expect("a number"))
        .collect()
}

#[cfg(feature = "sim-tools")]
#[test]
fn chatter_commission_sets_thresholds_that_hold_on_held_out_stable_rolling() {
    // The critical speed of the example schedule is 1.098 (sim/README.md): the highest
    // allowed speed here is 1.04, 95% of it.
    let scratch = scratch("cli-commission");
    let dir = scratch.path();
    let ramp_up = tandem_record(
        dir,
        "ramp-up",
        &[
            "--speed",
            "0.6",
            "--ramp",
            "1.04,1.0",
            "--hold",
            "2",
            "--duration",
            "30",
            "--seed",
            "11",
        ],
    );
    let top = tandem_record(
        dir,
        "top",
        &[
            "--speed",
            "1.04",
            "--duration",
            "30",
            "--noise-scale",
            "1.5",
            "--seed",
            "12",
        ],
    );
    // The end of an acceleration to the top speed raises the gain for a second or two:
    // commissioning records the accelerations too.
    let slow_ramp = tandem_record(
        dir,
        "slow-ramp",
        &[
            "--speed",
            "0.8",
            "--ramp",
            "1.04,0.5",
            "--hold",
            "2",
            "--duration",
            "30",
            "--seed",
            "15",
        ],
    );
    // The mill not yet commissioned: its configuration without thresholds.
    let example = std::fs::read_to_string(examples().join("tandem-5stand.toml")).unwrap();
    let config = dir.join("mill.toml");
    std::fs::write(
        &config,
        example
            .lines()
            .filter(|l| !l.starts_with("gain_thresholds"))
            .collect::<Vec<_>>()
            .join("\n"),
    )
    .unwrap();
    let check = millgate(&["check", "--config", config.to_str().unwrap()]);
    assert!(!check.status.success(), "{}", text(&check));
    assert!(
        text(&check).contains("`millgate chatter commission` computes them"),
        "{}",
        text(&check)
    );

    let commission = |inputs: &[&PathBuf], extra: &[&str]| {
        let mut args = vec![
            "chatter",
            "commission",
            "--config",
            config.to_str().unwrap(),
        ];
        for input in inputs {
            args.extend_from_slice(&["--input", input.to_str().unwrap()]);
        }
        args.extend_from_slice(extra);
        millgate(&args)
    };
    let output = commission(
        &[&ramp_up, &top, &slow_ramp],
        &["--speed-column", "speed_factor"],
    );
    assert!(output.status.success(), "{}", text(&output));
    let out = String::from_utf8_lossy(&output.stdout).to_string();
    let thresholds = toml_list(&out, "gain_thresholds");
    assert_eq!(thresholds.len(), 5, "{out}");
    // 30 s each: windows every 0.25 s once the 2 s gain window is full.
    assert!(
        out.starts_with("tandem mill \"TCM 2030\": 3 recording(s), 90.0 s, 333 windows"),
        "{out}"
    );
    assert!(
        out.contains("speeds covered (speed_factor): 0.61 .. 1.04"),
        "{out}"
    );
    // The release level for these thresholds, within its bounds.
    let release: f64 = out
        .lines()
        .find_map(|l| l.strip_prefix("slow_down_release = "))
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no slow_down_release line in {out}"));
    assert!((0.8..=0.95).contains(&release), "{release}");
    println!("{out}");

    // The thresholds are each stand's largest gain that `millgate chatter` reports for
    // the same recordings, plus 10%, rounded up to 0.001.
    let mut largest = [0.0_f64; 5];
    for input in [&ramp_up, &top, &slow_ramp] {
        let report = millgate(&[
            "chatter",
            "--input",
            input.to_str().unwrap(),
            "--config",
            config.to_str().unwrap(),
            "--format",
            "json",
        ]);
        assert!(report.status.success(), "{}", text(&report));
        let json: serde_json::Value = serde_json::from_slice(&report.stdout).unwrap();
        for window in json["windows"].as_array().unwrap() {
            for (stand, row) in window["stands"].as_array().unwrap().iter().enumerate() {
                if let Some(gain) = row["gain"].as_f64() {
                    largest[stand] = largest[stand].max(gain);
                }
            }
        }
    }
    for (threshold, largest) in thresholds.iter().zip(largest) {
        let expected = (largest * 1.1 * 1000.0).ceil() / 1000.0;
        assert!(
            (threshold - expected).abs() < 1.5e-3,
            "{threshold} vs {expected}"
        );
        assert!(*threshold >= largest * 1.1 - 1e-12);
    }
    let json = commission(
        &[&ramp_up, &top, &slow_ramp],
        &["--format", "json", "--margin", "25"],
    );
    assert!(json.status.success(), "{}", text(&json));
    let json: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    assert_eq!(json["windows"], 333);
    assert_eq!(json["margin_percent"], 25.0);
    for (threshold, largest) in json["gain_thresholds"]
        .as_array()
        .unwrap()
        .iter()
        .zip(largest)
    {
        let expected = (largest * 1.25 * 1000.0).ceil() / 1000.0;
        assert!((threshold.as_f64().unwrap() - expected).abs() < 1.5e-3);
    }

    // Pasted into the configuration: held-out stable rolling up to the top speed
    // raises no alarm, a ramp past the critical speed does, before chatter develops.
    let pasted = dir.join("commissioned.toml");
    let line = out
        .lines()
        .find(|l| l.starts_with("gain_thresholds = ["))
        .unwrap();
    std::fs::write(
        &pasted,
        format!(
            "{}\n",
            example
                .replace(
                    example
                        .lines()
                        .find(|l| l.starts_with("gain_thresholds"))
                        .unwrap(),
                    line,
                )
                .replace(
                    "slow_down_release = 0.88",
                    &format!("slow_down_release = {release}")
                )
        ),
    )
    .unwrap();
    let check = millgate(&["check", "--config", pasted.to_str().unwrap()]);
    assert!(check.status.success(), "{}", text(&check));
    let held_out = [
        tandem_record(
            dir,
            "held-out-1",
            &[
                "--speed",
                "1.04",
                "--duration",
                "30",
                "--noise-scale",
                "0.7",
                "--seed",
                "13",
            ],
        ),
        tandem_record(
            dir,
            "held-out-2",
            &[
                "--speed",
                "0.7",
                "--ramp",
                "1.04,1.0",
                "--hold",
                "2",
                "--duration",
                "30",
                "--noise-scale",
                "1.3",
                "--seed",
                "14",
            ],
        ),
    ];
    let first_alarm = |input: &PathBuf| {
        let report = millgate(&[
            "chatter",
            "--input",
            input.to_str().unwrap(),
            "--config",
            pasted.to_str().unwrap(),
        ]);
        assert!(report.status.success(), "{}", text(&report));
        let out = String::from_utf8_lossy(&report.stdout).to_string();
        out.lines().last().unwrap().to_owned()
    };
    for input in &held_out {
        let last = first_alarm(input);
        assert!(
            last.ends_with("first alarm: none"),
            "{}: {last}",
            input.display()
        );
    }
    let ramp = tandem_record(
        dir,
        "ramp",
        &[
            "--speed",
            "0.9",
            "--ramp",
            "1.5,2.0",
            "--hold",
            "6",
            "--duration",
            "14",
            "--seed",
            "7",
        ],
    );
    let alarm = first_alarm(&ramp);
    let alarm_s: f64 = alarm
        .rsplit("first alarm: ")
        .next()
        .and_then(|t| t.trim_end_matches(" s").parse().ok())
        .unwrap_or_else(|| panic!("no alarm: {alarm}"));
    // Onset 7.25 s, developed 13.42 s (README, the chatter end-to-end row).
    assert!(alarm_s > 7.25 && alarm_s < 13.42, "{alarm}");

    // Refused, each with the file and the reason, and a non-zero exit.
    let refused = |inputs: &[&PathBuf], expected: &str| {
        let output = commission(inputs, &[]);
        assert!(!output.status.success(), "{}", text(&output));
        assert!(text(&output).contains(expected), "{}", text(&output));
    };
    refused(
        &[&top, &ramp],
        &format!(
            "{}: shows chatter: the chatter-band gain of stand",
            ramp.display()
        ),
    );
    let short = tandem_record(dir, "short", &["--speed", "1.0", "--duration", "2"]);
    refused(
        &[&short],
        &format!(
            "{}: 2.000 s is too short for the gain window: the first gain needs 2.298 s",
            short.display()
        ),
    );
    let fast = tandem_record(
        dir,
        "fast",
        &["--speed", "1.0", "--duration", "4", "--sample-rate", "5000"],
    );
    refused(
        &[&top, &fast],
        &format!(
            "{}: sample rate 5000.0 Hz from column t, the stand channels sample at 2500 Hz",
            fast.display()
        ),
    );
    let renamed = dir.join("renamed.csv");
    let body = std::fs::read_to_string(&top).unwrap();
    std::fs::write(&renamed, body.replacen("s3_vib", "stand3", 1)).unwrap();
    refused(
        &[&renamed],
        &format!(
            "{}: line 1: no column `s3_vib` for a stand of tandem mill \"TCM 2030\" (columns: s1_vib, s2_vib, stand3",
            renamed.display()
        ),
    );
}

/// `check` under the variables systemd sets for `StateDirectory=`, `CacheDirectory=` and
/// `LoadCredential=` (as `ExecStartPre=millgate check` runs in the shipped unit): a
/// relative history path in `$STATE_DIRECTORY`, the cache in `$CACHE_DIRECTORY`, the
/// MQTT password from `$CREDENTIALS_DIRECTORY`; without them the credential is an
/// error naming the key and the variable.
#[test]
fn check_uses_the_folders_systemd_hands_the_service() {
    let demo = std::fs::read_to_string(examples().join("demo.toml")).unwrap();
    let (_folder, path) = write_config(
        "service-folders",
        &format!(
            "{demo}\n[outputs.mqtt]\nbroker = \"127.0.0.1:1883\"\ngroup_id = \"plant\"\n\
             node_id = \"f1\"\nusername = \"millgate\"\npassword_credential = \"mqtt\"\n\
             \n[history]\npath = \"history.db\"\n"
        ),
    );
    let folder = path.parent().unwrap();
    let [state, cache, credentials] = ["state", "cache", "credentials"].map(|name| {
        let dir = folder.join(name);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    });
    std::fs::write(credentials.join("mqtt"), "secret\n").unwrap();
    let check = |systemd: bool| {
        let mut command = MILLGATE.command();
        command.args(["check", "--config", path.to_str().unwrap()]);
        for (variable, dir) in [
            ("STATE_DIRECTORY", &state),
            ("CACHE_DIRECTORY", &cache),
            ("CREDENTIALS_DIRECTORY", &credentials),
        ] {
            if systemd {
                command.env(variable, dir);
            } else {
                command.env_remove(variable);
            }
        }
        command.output().expect("run millgate")
    };

    let output = check(true);
    let said = text(&output);
    assert!(output.status.success(), "{said}");
    assert!(
        said.contains(&format!("History: {}", state.join("history.db").display()))
            && said.contains(&format!("Cache: {}", cache.display())),
        "{said}"
    );
    assert!(!state.join("history.db").exists(), "check creates no file");

    let output = check(false);
    let said = text(&output);
    assert!(!output.status.success(), "must fail: {said}");
    assert!(
        said.contains(
            "mill.toml: outputs.mqtt.password_credential: $CREDENTIALS_DIRECTORY is not set"
        ),
        "names the key and the variable: {said}"
    );
}

/// A millgate built without the `opcua` feature refuses `[outputs.opcua]` and says how
/// to build one that serves it (with the feature, `tests/opcua.rs` checks `check`).
#[cfg(not(feature = "opcua"))]
#[test]
fn check_without_the_opcua_feature_refuses_the_opcua_output() {
    let demo = std::fs::read_to_string(examples().join("demo.toml")).unwrap();
    let (_folder, path) = write_config("opcua", &format!("{demo}\n[outputs.opcua]\n"));
    let output = millgate(&["check", "--config", path.to_str().unwrap()]);
    assert!(!output.status.success(), "{}", text(&output));
    assert!(
        text(&output).contains(
            "outputs.opcua: this millgate was built without the OPC UA server (build it with \
             cargo build --release -p millgate --features opcua)"
        ),
        "{}",
        text(&output)
    );
}

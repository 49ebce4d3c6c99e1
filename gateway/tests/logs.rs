//! The log as a log shipper and a reader get it: `--log-format json` (and
//! `log_format = "json"` in the configuration of `millgate run`) writes one JSON
//! object per line, which Python's `json` reads line by line, each bite's figures
//! JSON numbers; the text format writes them as `key=value`, without Rust's debug
//! syntax (`Some(...)`).

mod common;

use std::io::{BufRead as _, BufReader};
use std::process::{Command, Stdio};

use common::{scratch, text, KillOnDrop, MILLGATE};

/// `millgate demo` for a few seconds with the analysis' INFO lines on, in `format`:
/// its stderr.
fn demo_log(format: &str, db: &std::path::Path) -> String {
    let output = Command::new(MILLGATE.0)
        .args([
            "demo",
            "--duration",
            "4",
            "--log-format",
            format,
            "--history",
        ])
        .arg(db)
        .env("RUST_LOG", "warn,millgate::analysis=info")
        .stdin(Stdio::null())
        .output()
        .expect("run millgate demo");
    assert!(output.status.success(), "{}", text(&output));
    String::from_utf8(output.stderr).expect("UTF-8 log")
}

#[test]
fn json_log_lines_are_json_with_the_bite_s_figures_as_numbers() {
    let scratch = scratch("logs-json");
    let log = demo_log("json", &scratch.path().join("history.db"));
    // Python's json reads every line; the bites' fields are numbers and booleans.
    let python = Command::new("python3")
        .args([
            "-c",
            "import json, sys\n\
             lines = [json.loads(line) for line in sys.stdin if line.strip()]\n\
             bites = [l['fields'] for l in lines if l['fields'].get('message') == 'bite']\n\
             assert bites, lines\n\
             for bite in bites:\n\
             \x20   assert isinstance(bite['static_knm'], float), bite\n\
             \x20   assert isinstance(bite['degraded'], bool), bite\n\
             \x20   assert isinstance(bite['driveline'], str), bite\n\
             \x20   assert all(not isinstance(v, str) or not v.startswith('Some(') for v in bite.values()), bite\n\
             print(len(lines), len(bites), sum('taf' in b for b in bites), sum('gap_mrad' in b for b in bites))",
        ])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("python3");
    std::io::Write::write_all(&mut python.stdin.as_ref().unwrap(), log.as_bytes()).unwrap();
    let output = python.wait_with_output().unwrap();
    assert!(output.status.success(), "{}\n{log}", text(&output));
    let counts: Vec<usize> = String::from_utf8_lossy(&output.stdout)
        .split_whitespace()
        .map(|n| n.parse().unwrap())
        .collect();
    let [lines, bites, with_taf, with_gap] = counts[..] else {
        panic!("{counts:?}")
    };
    assert!(lines >= bites && bites >= 2, "{counts:?}\n{log}");
    assert_eq!(with_taf, bites, "every demo bite has a TAF: {log}");
    assert!(with_gap >= 1, "a gap estimate after the first bites: {log}");
}

#[test]
fn text_log_lines_have_key_value_fields_without_debug_syntax() {
    let scratch = scratch("logs-text");
    let log = demo_log("text", &scratch.path().join("history.db"));
    let bites: Vec<&str> = log.lines().filter(|line| line.contains(" bite ")).collect();
    assert!(bites.len() >= 2, "{log}");
    for line in bites {
        assert!(!line.contains("Some("), "{line}");
        assert!(line.contains("static_knm="), "{line}");
        assert!(line.contains(" taf="), "{line}");
    }
}

/// `millgate run` takes `log_format = "json"` from its configuration: its first log
/// line is already JSON. (The demo's configuration: its DAQ is not there, so the
/// service waits for it, logging, until it is killed.)
#[test]
fn run_logs_json_when_the_configuration_says_so() {
    let scratch = scratch("logs-run");
    let dir = scratch.path();
    let examples = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/examples");
    let demo = std::fs::read_to_string(examples.join("demo.toml")).unwrap();
    std::fs::copy(
        examples.join("table2-adjusted.toml"),
        dir.join("table2-adjusted.toml"),
    )
    .unwrap();
    let config = dir.join("mill.toml");
    // Its HMI server on a free port: the test may run beside others.
    let demo = demo.replace("bind = \"127.0.0.1:5503\"", "bind = \"127.0.0.1:0\"");
    std::fs::write(&config, format!("log_format = \"json\"\n{demo}")).unwrap();
    let mut service = KillOnDrop(
        Command::new(MILLGATE.0)
            .args(["run", "--config"])
            .arg(&config)
            .env("XDG_CACHE_HOME", dir)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("run millgate"),
    );
    let mut line = String::new();
    BufReader::new(service.0.stderr.take().unwrap())
        .read_line(&mut line)
        .expect("a log line");
    let parsed: serde_json::Value =
        serde_json::from_str(&line).unwrap_or_else(|e| panic!("not JSON ({e}): {line}"));
    assert!(
        parsed["level"].is_string() && parsed["fields"]["message"].is_string(),
        "{line}"
    );
}

/// A Modbus RTU line whose far end answers every request with junk (the test kit's
/// `junk_reply`: noise, another unit's frame, a frame of the wrong length) as fast as
/// it is asked, for longer than one warning period (audit round 4, finding 8): each
/// warning is logged the first time and then at most once per 10 s with the number of
/// occurrences it stands for, while the junk goes on.
#[test]
fn junk_on_an_rtu_line_is_warned_about_at_a_limited_rate() {
    use std::io::{Read as _, Write as _};
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    use std::time::{Duration, Instant};

    const UNIT: u8 = 7;
    let scratch = scratch("logs-rtu-junk");
    let pair = common::serial_line::PtyPair::open().unwrap();
    let config = scratch.path().join("rtu.toml");
    std::fs::write(
        &config,
        format!(
            "name = \"RTU junk\"\n\
             [[sources.modbus]]\nname = \"drive\"\ndevice = \"{}\"\nbaud_rate = 115200\n\
             parity = \"none\"\nstop_bits = 1\nunit_id = {UNIT}\npoll_period_ms = 20\n\
             timeout_ms = 50\n\
             [[channels]]\nname = \"speed\"\nkind = \"process_value\"\nunit = \"m/s\"\n\
             source = {{ modbus = \"drive\", table = \"holding\", address = 200, type = \"f32\" }}\n",
            pair.gateway.display()
        ),
    )
    .unwrap();

    let running = Arc::new(AtomicBool::new(true));
    let far_end = {
        let running = Arc::clone(&running);
        let mut line = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(&pair.device)
            .unwrap();
        std::thread::spawn(move || {
            let mut buffer = [0u8; 256];
            let mut answered = 0usize;
            while running.load(Ordering::Relaxed) {
                let Ok(read) = line.read(&mut buffer) else {
                    break;
                };
                let reply = common::serial_line::junk_reply(answered, &buffer[..read], UNIT);
                let _ = line.write_all(&reply);
                answered += 1;
            }
            answered
        })
    };

    let mut service = KillOnDrop(
        Command::new(MILLGATE.0)
            .args(["run", "--config"])
            .arg(&config)
            .env("RUST_LOG", "warn")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("millgate run"),
    );
    let stderr = service.stderr.take().unwrap();
    let (sender, received) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if sender.send(line).is_err() {
                break;
            }
        }
    });
    // Until a warning's summary line (its second, at least 10 s after its first: the
    // reconnect backoff, up to 5 s, spaces the junk out), within a minute.
    let start = Instant::now();
    let deadline = start + Duration::from_secs(60);
    let mut lines = Vec::new();
    while !lines
        .iter()
        .any(|l: &String| suppressed(l).is_some_and(|n| n > 0))
    {
        let left = deadline.saturating_duration_since(Instant::now());
        match received.recv_timeout(left) {
            Ok(line) => lines.push(line),
            Err(_) => panic!("no summary line in 60 s:\n{}", lines.join("\n")),
        }
    }
    let elapsed = start.elapsed().as_secs_f64();
    running.store(false, Ordering::Relaxed);
    common::terminate(&mut service);
    lines.extend(received.try_iter());
    // The far end leaves at its next read, which may never come after the stop: the
    // line is closed under it.
    drop(pair);
    let answered = far_end.join().unwrap();

    let mut per_message = std::collections::BTreeMap::<String, Vec<&String>>::new();
    for line in lines.iter().filter(|l| l.contains("WARN")) {
        // `... WARN target: message field=value ...`: the message is what repeats.
        let message = line
            .split_once(": ")
            .map_or(line.as_str(), |(_, rest)| rest)
            .split(" source=")
            .next()
            .unwrap_or_default();
        per_message
            .entry(message.to_owned())
            .or_default()
            .push(line);
    }
    let allowed = 1 + (elapsed / 10.0).ceil() as usize;
    for (message, lines) in &per_message {
        assert!(
            lines.len() <= allowed,
            "{message}: {} lines in {elapsed:.1} s (at most {allowed}):\n{lines:#?}",
            lines.len()
        );
    }
    // Every junk answer is an occurrence: each one a line, or counted in a summary.
    let logged: u64 = per_message
        .values()
        .flatten()
        .map(|l| 1 + suppressed(l).unwrap_or(0))
        .sum();
    let lines_logged = per_message.values().map(Vec::len).sum::<usize>();
    assert!(
        lines_logged < answered && logged <= answered as u64,
        "{lines_logged} warning lines standing for {logged} occurrences, for {answered} \
         junk answers:\n{}",
        lines.join("\n")
    );
}

/// The `suppressed=N` of a rate-limited warning line.
fn suppressed(line: &str) -> Option<u64> {
    line.split("suppressed=")
        .nth(1)?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

//! Every command that prints, its reader gone: `millgate figures | head -1` and the
//! like end quietly with exit status 0 (docs/usage.md, "Exit status"), never with a
//! panic (status 101, "failed printing to stdout: Broken pipe") or an error.
//!
//! Each command runs twice: with the pipe's reader closed before it starts (every
//! write fails at once with EPIPE, whatever the output's size: a test that cannot
//! race), and read for one line, then closed (the command blocks on a full pipe when
//! it prints more than the pipe holds, and its next write fails).
//!
//! The inputs are made once by the commands themselves: a history by `millgate demo`
//! (bites and their captures), a record by `millgate sim transient`, a tandem record
//! by `millgate sim tandem`.

mod common;

use std::io::{BufRead as _, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use common::{millgate, scratch, text, MILLGATE};

/// Whether stderr says nothing of the closed pipe: no panic, no error (what a command
/// says of its work there, as `wear`'s gap maps, is no matter).
fn quiet(stderr: &str) -> bool {
    !stderr.contains("panicked") && !stderr.contains("Broken pipe") && !stderr.contains("millgate:")
}

/// `millgate args` with its stdout's reader closed, then read for one line and
/// closed: both times status 0 and nothing about it on stderr ([`quiet`]).
fn ends_quietly(args: &[&str]) {
    let (reader, writer) = std::io::pipe().expect("a pipe");
    drop(reader);
    let output = Command::new(MILLGATE.0)
        .args(args)
        .stdin(Stdio::null())
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .expect("run millgate");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(
        output.status.code(),
        Some(0),
        "millgate {} (reader closed first): {stderr}",
        args.join(" ")
    );
    assert!(
        quiet(&stderr),
        "millgate {} (reader closed first): {stderr}",
        args.join(" ")
    );

    let mut child = Command::new(MILLGATE.0)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run millgate");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .expect("read a line");
    assert!(
        !line.is_empty(),
        "millgate {}: printed nothing",
        args.join(" ")
    );
    // The reader (and the pipe's only read end) dropped here.
    let output = child.wait_with_output().expect("wait for millgate");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(
        output.status.code(),
        Some(0),
        "millgate {} (closed after a line): {stderr}",
        args.join(" ")
    );
    assert!(
        quiet(&stderr),
        "millgate {} (closed after a line): {stderr}",
        args.join(" ")
    );
}

fn repo(path: &str) -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(path)
        .display()
        .to_string()
}

/// `millgate args`, which must succeed (making an input).
fn made(args: &[&str]) {
    let output = millgate(args);
    assert!(output.status.success(), "{}", text(&output));
}

fn s(path: &Path) -> &str {
    path.to_str().unwrap()
}

#[test]
fn configuration_commands_end_quietly_on_a_closed_pipe() {
    let hot = repo("config/examples/hot-mill.toml");
    ends_quietly(&["check", "--config", &hot]);
    ends_quietly(&["check", "--config", &hot, "--format", "json"]);
    for format in ["md", "csv", "json"] {
        ends_quietly(&["registers", "--config", &hot, "--format", format]);
        ends_quietly(&["figures", "--format", format]);
    }
    #[cfg(feature = "opcua")]
    ends_quietly(&[
        "address-space",
        "--config",
        &repo("config/examples/demo.toml"),
    ]);
    ends_quietly(&["completions", "bash"]);
    ends_quietly(&["man"]);
    ends_quietly(&["--help"]);
    ends_quietly(&["--version"]);
}

#[test]
fn record_commands_end_quietly_on_a_closed_pipe() {
    let scratch = scratch("closed-pipe-records");
    let dir = scratch.path();
    let model = repo("sim/models/table2-adjusted.toml");
    let record = dir.join("transient.csv");
    made(&[
        "sim",
        "transient",
        "--model",
        &model,
        "--seed",
        "4",
        "--out",
        s(&record),
    ]);
    let record = s(&record);
    ends_quietly(&["analyze", "--input", record]);
    ends_quietly(&["analyze", "--input", record, "--format", "json"]);
    ends_quietly(&["wear", "--input", record, "--model", &model]);
    ends_quietly(&[
        "fatigue",
        "--input",
        record,
        "--m",
        "5",
        "--ref-cycles",
        "2e6",
        "--ref-range-knm",
        "100",
    ]);
    ends_quietly(&["discrepancy", "--measured", record, "--model", &model]);
    ends_quietly(&[
        "stiffness",
        "--inertia",
        "46.70e3,11.85e3,2.48e3",
        "--freq",
        "12.03,21.09",
    ]);
    let stands = dir.join("stands.csv");
    made(&[
        "sim",
        "tandem",
        "--schedule",
        &repo("sim/schedules/lu2019-5stand.toml"),
        "--duration",
        "3",
        "--out",
        s(&stands),
    ]);
    let tandem = repo("config/examples/tandem-5stand.toml");
    ends_quietly(&["chatter", "--input", s(&stands), "--config", &tandem]);
    ends_quietly(&[
        "chatter",
        "commission",
        "--config",
        &tandem,
        "--input",
        s(&stands),
    ]);
    ends_quietly(&["sim", "modes", "--model", &model]);
    ends_quietly(&[
        "sim",
        "transient",
        "--model",
        &model,
        "--out",
        s(&dir.join("again.csv")),
    ]);
    ends_quietly(&[
        "sim",
        "tandem",
        "--schedule",
        &repo("sim/schedules/lu2019-5stand.toml"),
        "--duration",
        "1",
        "--out",
        s(&dir.join("stands-again.csv")),
    ]);
    ends_quietly(&[
        "sim",
        "fatigue-gap",
        "--model",
        &model,
        "--bars",
        "1",
        "--max-gap-mrad",
        "1",
        "--step-mrad",
        "1",
        "--out",
        s(&dir.join("fatigue-gap")),
    ]);
    ends_quietly(&["rod", "mathieu", "--q", "1", "--order", "2"]);
    ends_quietly(&["rod", "floquet", "--a", "1", "--q", "0.4"]);
    ends_quietly(&[
        "rod",
        "check",
        "--mill",
        &repo("sim/models/rod/rsm-mill.toml"),
        "--schedule",
        &repo("sim/models/rod/rsm-schedule.csv"),
    ]);
}

#[test]
fn history_commands_end_quietly_on_a_closed_pipe() {
    let scratch = scratch("closed-pipe-history");
    let dir = scratch.path();
    let db = dir.join("history.db");
    made(&["demo", "--duration", "4", "--history", s(&db)]);
    let db = s(&db);
    ends_quietly(&["history", "--db", db, "--format", "csv"]);
    ends_quietly(&["history", "--db", db, "--format", "json"]);
    ends_quietly(&["capture", "list", "--db", db]);
    ends_quietly(&["capture", "list", "--db", db, "--format", "json"]);
    ends_quietly(&[
        "capture",
        "export",
        "--db",
        db,
        "--format",
        "csv",
        "--out",
        s(&dir.join("export")),
    ]);
    ends_quietly(&["report", "--db", db, "--out", s(&dir.join("report"))]);
    ends_quietly(&[
        "demo",
        "--duration",
        "1",
        "--history",
        s(&dir.join("demo.db")),
    ]);
}

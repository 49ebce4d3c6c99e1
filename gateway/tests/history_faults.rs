//! The history file in trouble while `millgate run` (the real binary, between the
//! demo's virtual DAQ and PLC) starts or runs (issue 30, findings 2, 3 and 9):
//!
//! - another process (Python's sqlite3) holds the file's lock while the service
//!   starts: the counters continue from the file, no bite counter is stored twice;
//! - another process holds the write lock for several bites while it runs: every
//!   bite the PLC saw is in the file once, one run row, ended by the stop;
//! - the file deleted while running: the error is logged and the next bites go to a
//!   new file at the path, not to the unlinked one;
//! - a partly damaged file: `millgate check` warns of it (SQLite's `quick_check`), the
//!   service reports it and leaves it untouched.

mod common;

use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Child, ChildStdin, Command, Stdio};
use std::time::Duration;

use common::{terminate, wait_for, Setup, MILLGATE};

/// Longest wait for what the service does within a bite or two: a hang guard.
const BITES: Duration = Duration::from_secs(60);

/// A Python process holding `BEGIN <mode>` on a SQLite file until released; killed
/// on drop.
struct Locker {
    child: Child,
    stdin: Option<ChildStdin>,
}

impl Locker {
    /// Returns once the lock is held.
    fn hold(path: &Path, mode: &str) -> Self {
        const SCRIPT: &str = "import sqlite3, sys\n\
            c = sqlite3.connect(sys.argv[1], isolation_level=None, timeout=30)\n\
            c.execute('BEGIN ' + sys.argv[2])\n\
            print('locked', flush=True)\n\
            sys.stdin.read()\n\
            c.execute('COMMIT')\n";
        let mut child = Command::new("python3")
            .args(["-c", SCRIPT])
            .arg(path)
            .arg(mode)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("python3");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        assert_eq!(line.trim(), "locked", "the lock was not taken");
        let stdin = child.stdin.take();
        Self { child, stdin }
    }

    /// Commit and end.
    fn release(mut self) {
        drop(self.stdin.take());
        let status = self.child.wait().unwrap();
        assert!(status.success(), "{status:?}");
    }
}

impl Drop for Locker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `sql`'s rows as text, read by Debian's sqlite3 (not by the code under test).
fn sqlite3(path: &Path, sql: &str) -> Vec<String> {
    let output = Command::new("sqlite3")
        .arg("-readonly")
        .arg(path)
        .arg(sql)
        .output()
        .expect("sqlite3");
    assert!(output.status.success(), "{output:?}");
    String::from_utf8(output.stdout)
        .unwrap()
        .lines()
        .map(str::to_owned)
        .collect()
}

/// The file's bite counters in the order they were stored.
fn counters(path: &Path) -> Vec<u32> {
    sqlite3(path, "SELECT bite_counter FROM bites ORDER BY id")
        .iter()
        .map(|line| line.parse().unwrap())
        .collect()
}

fn log_contains(setup: &Setup, log: &str, text: &str) -> bool {
    std::fs::read_to_string(setup.log(log)).is_ok_and(|log| log.contains(text))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_start_while_another_process_holds_the_file_continues_its_counters() {
    let setup = Setup::new(MILLGATE, "locked-start", "db").await;
    let plc = setup.plc();
    let mut first = setup.spawn("first.log");
    plc.bites_after_now(2).await;
    terminate(&mut first);
    let before = counters(&setup.history);
    let last = *before.last().unwrap();
    assert_eq!(before, (1..=last).collect::<Vec<_>>());

    // Another process holds the file while the service starts.
    let lock = Locker::hold(&setup.history, "EXCLUSIVE");
    let mut second = setup.spawn("second.log");
    wait_for("the service meets the lock", BITES, || {
        log_contains(&setup, "second.log", "database is locked")
    })
    .await;
    assert!(
        plc.counter() >= last,
        "the PLC's counter went back to {} (the file holds {last})",
        plc.counter()
    );
    lock.release();
    plc.bites_after_now(2).await;
    terminate(&mut second);

    let after = counters(&setup.history);
    let mut sorted = after.clone();
    sorted.dedup();
    assert_eq!(sorted, after, "a counter stored twice: {after:?}");
    assert_eq!(
        after,
        (1..=*after.last().unwrap()).collect::<Vec<_>>(),
        "the counters continue from the file: {after:?}"
    );
    assert!(*after.last().unwrap() >= last + 2);
    drop(second);
    setup.finish().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_write_lock_held_over_several_bites_loses_none_the_plc_saw() {
    let setup = Setup::new(MILLGATE, "locked-run", "db").await;
    let plc = setup.plc();
    let mut service = setup.spawn("run.log");
    plc.bites_after_now(2).await;

    let lock = Locker::hold(&setup.history, "IMMEDIATE");
    plc.bites_after_now(3).await;
    assert_eq!(
        setup.metric("millgate_history_state").await,
        Some(2.0),
        "failing while locked"
    );
    assert_eq!(
        setup
            .metric("millgate_history_events_dropped_total{reason=\"error\"}")
            .await,
        Some(0.0),
        "nothing dropped"
    );
    lock.release();
    plc.bites_after_now(1).await;
    wait_for("stored again", BITES, || {
        log_contains(&setup, "run.log", "history stored again")
    })
    .await;
    terminate(&mut service);

    let in_plc = plc.counter();
    assert_eq!(
        counters(&setup.history),
        (1..=in_plc).collect::<Vec<_>>(),
        "every bite the PLC saw, once, in order"
    );
    assert_eq!(
        sqlite3(&setup.history, "SELECT ended FROM gateway_runs"),
        ["stopped"],
        "one run row, ended by the stop"
    );
    drop(service);
    setup.finish().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_history_file_deleted_while_running_is_noticed_and_a_new_one_started() {
    let setup = Setup::new(MILLGATE, "deleted", "db").await;
    let plc = setup.plc();
    let mut service = setup.spawn("run.log");
    plc.bites_after_now(1).await;
    let deleted_at = plc.counter();
    for suffix in ["", "-wal", "-shm"] {
        let path = format!("{}{suffix}", setup.history.display());
        let _ = std::fs::remove_file(path);
    }
    plc.bites_after_now(2).await;
    wait_for("a new file at the path", BITES, || setup.history.exists()).await;
    wait_for("the deletion in the log", BITES, || {
        log_contains(&setup, "run.log", "was deleted or replaced while in use")
    })
    .await;
    terminate(&mut service);
    let in_plc = plc.counter();
    let stored = counters(&setup.history);
    assert!(
        !stored.is_empty() && stored.iter().all(|&c| c > deleted_at),
        "the new file holds the bites after the deletion: {stored:?}"
    );
    assert_eq!(stored.last(), Some(&in_plc));
    assert_eq!(
        sqlite3(&setup.history, "SELECT ended FROM gateway_runs"),
        ["stopped"]
    );
    drop(service);
    setup.finish().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_partly_damaged_file_is_named_by_check_and_left_alone_by_the_service() {
    let setup = Setup::new(MILLGATE, "damaged", "db").await;
    let plc = setup.plc();
    let mut first = setup.spawn("first.log");
    plc.bites_after_now(2).await;
    terminate(&mut first);
    // Every third page after the first (the header) garbled.
    let mut bytes = std::fs::read(&setup.history).unwrap();
    let page = 4096;
    assert!(bytes.len() >= 8 * page, "{} bytes", bytes.len());
    for start in (3 * page..bytes.len()).step_by(3 * page) {
        for (i, byte) in bytes[start..start + page].iter_mut().enumerate() {
            *byte = (i * 31 + 7) as u8;
        }
    }
    std::fs::File::create(&setup.history)
        .unwrap()
        .write_all(&bytes)
        .unwrap();

    let check = common::MILLGATE
        .command()
        .args(["check", "--config"])
        .arg(&setup.config)
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&check.stderr).into_owned()
        + &String::from_utf8_lossy(&check.stdout);
    // A warning (the service runs on without the file), naming the key and why.
    assert!(check.status.success(), "{said}");
    assert!(
        said.contains("warning: ")
            && said.contains("history.path: history ")
            && said.contains("not a readable SQLite history"),
        "{said}"
    );

    let mut service = setup.spawn("run.log");
    plc.bites_after_now(1).await;
    assert_eq!(setup.metric("millgate_history_state").await, Some(2.0));
    assert!(log_contains(
        &setup,
        "run.log",
        "not a readable SQLite history"
    ));
    terminate(&mut service);
    assert_eq!(
        std::fs::read(&setup.history).unwrap(),
        bytes,
        "left as it was"
    );
    drop(service);
    setup.finish().await;
}

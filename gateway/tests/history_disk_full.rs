//! A full disk under the history, across a restart, against the real `millgate run`
//! between the demo's virtual DAQ and PLC (issue 41 "disk full", round-4 audit finding
//! 4a: the restart restored the bite counter from the file, which lacked the bites the
//! PLC saw while storing failed, and the PLC's counter went back).
//!
//! The history sits on a 4 MiB tmpfs mounted in a private user and mount namespace
//! (`unshare -rm`, util-linux) held by a `sleep` for the whole test, so the tmpfs (and
//! its full state) outlives a service; each service joins it with `nsenter`. Filled
//! while the service runs: acquisition, the PLC writes and the HMI server go on, the
//! history says why it stopped storing (`/metrics`, the log), and what the file held
//! stays intact (`PRAGMA integrity_check`, every bite up to the last stored). Killed
//! and started again while still full: the PLC's counter never goes back, and the
//! next bite continues it. Space freed: storing resumes.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use common::{fill_file_system, wait_for, KillOnDrop, Plc, Setup, MILLGATE};
use millgate::history::query::{Filter, HistoryReader};

/// A user and mount namespace with a tmpfs of `size` on `folder`, held by a `sleep`.
fn namespace_with_tmpfs(folder: &Path, size: &str) -> KillOnDrop {
    Command::new("unshare")
        .args([
            "-rm",
            "sh",
            "-c",
            "mount -t tmpfs -o size=\"$1\" tmpfs \"$2\" && exec sleep 600",
            "sh",
            size,
            folder.to_str().unwrap(),
        ])
        .stdin(Stdio::null())
        .spawn()
        .map(KillOnDrop)
        .expect("unshare (util-linux)")
}

/// `program args` inside `holder`'s namespaces.
fn inside(holder: &KillOnDrop, program: &str) -> Command {
    let mut command = Command::new("nsenter");
    command.args([
        "-t",
        &holder.id().to_string(),
        "-U",
        "-m",
        "--preserve-credentials",
        "--",
        program,
    ]);
    command
}

/// `millgate run` on `setup`'s configuration inside `holder`'s namespaces.
fn spawn_inside(setup: &Setup, holder: &KillOnDrop, log: &str) -> KillOnDrop {
    setup.spawn_command(inside(holder, MILLGATE.0), log)
}

/// Wait for a bite after the PLC showed `in_plc`, sampling the PLC's counter
/// meanwhile: it never went below `in_plc`, and the bite continues it.
async fn next_bite_continues(plc: &Plc<'_>, in_plc: u32) {
    let mut lowest = u32::MAX;
    wait_for("a bite of the second run", Duration::from_secs(60), || {
        let now = plc.counter();
        lowest = lowest.min(now);
        now > in_plc
    })
    .await;
    assert!(
        lowest >= in_plc,
        "the PLC's counter went back from {in_plc} to {lowest}"
    );
    assert_eq!(
        plc.counter(),
        in_plc + 1,
        "the next bite continues the PLC's"
    );
}

/// `sql` on the history as Debian's `sqlite3` reads it inside the namespace.
fn sqlite(holder: &KillOnDrop, history: &Path, sql: &str) -> String {
    let output = inside(holder, "sqlite3")
        .arg("-readonly")
        .arg(history)
        .arg(sql)
        .output()
        .unwrap();
    assert!(output.status.success(), "{output:?}");
    String::from_utf8(output.stdout).unwrap().trim().to_owned()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_disk_loses_nothing_stored_and_the_counter_never_goes_back() {
    let setup = Setup::new(MILLGATE, "disk-full", "tmpfs").await;
    let folder = setup.history.parent().unwrap().to_path_buf();
    let holder = namespace_with_tmpfs(&folder, "4m");
    // The namespace's view of its tmpfs, from this one.
    let seen: PathBuf = PathBuf::from(format!("/proc/{}/root", holder.id()))
        .join(folder.strip_prefix("/").unwrap());
    wait_for("the tmpfs mounted", Duration::from_secs(10), || {
        std::fs::read_to_string(format!("/proc/{}/mountinfo", holder.id()))
            .is_ok_and(|mounts| mounts.contains(folder.to_str().unwrap()))
    })
    .await;
    let plc = setup.plc();
    let mut first = spawn_inside(&setup, &holder, "first.log");
    plc.bites_after_now(1).await;

    // Fill the tmpfs.
    let filler = seen.join("filler");
    fill_file_system(&filler);
    // Storing fails: the history says why.
    wait_for(
        "a bite dropped for the full disk",
        Duration::from_secs(60),
        || {
            setup.log_text("first.log").contains("the disk is full")
                && setup.log_text("first.log").contains("cannot store")
        },
    )
    .await;
    let page = setup.metrics().await;
    assert!(
        page.contains("millgate_history_state 2"),
        "failing on /metrics"
    );
    assert!(page.contains("the disk is full"), "{page}");
    // Acquisition, the PLC and the HMI go on.
    plc.bites_after_now(2).await;
    let at = plc.at("F1.bite_counter") as u16;
    let hmi = common::hmi_u32(setup.server_port, at).await;
    assert!(hmi + 1 >= plc.counter(), "HMI {hmi}, PLC {}", plc.counter());

    // Killed while full, started again while still full.
    first.kill().unwrap();
    first.wait().unwrap();
    let in_plc = plc.counter();
    let history = &setup.history;
    let stored: u32 = sqlite(&holder, history, "SELECT max(bite_counter) FROM bites")
        .parse()
        .unwrap();
    assert!(
        stored < in_plc,
        "the file lacks bites the PLC saw ({stored} of {in_plc})"
    );
    assert_eq!(sqlite(&holder, history, "PRAGMA integrity_check"), "ok");
    let counters = sqlite(
        &holder,
        history,
        "SELECT count(DISTINCT bite_counter) FROM bites WHERE bite_counter <= (SELECT max(bite_counter) FROM bites)",
    );
    assert_eq!(
        counters,
        stored.to_string(),
        "every bite up to the last stored"
    );

    let mut second = spawn_inside(&setup, &holder, "second.log");
    next_bite_continues(&plc, in_plc).await;

    // Space again: storing resumes, the bites from now on are in the file.
    std::fs::remove_file(&filler).unwrap();
    let resumed_from = plc.counter();
    plc.bites_after_now(2).await;
    wait_for("storing resumed", Duration::from_secs(30), || {
        setup
            .log_text("second.log")
            .contains("history stored again")
            || sqlite(&holder, history, "SELECT max(bite_counter) FROM bites")
                .parse::<u32>()
                .is_ok_and(|last| last > resumed_from)
    })
    .await;
    assert_eq!(sqlite(&holder, history, "PRAGMA integrity_check"), "ok");
    common::terminate(&mut second);
    setup.stop(second).await;
    drop(holder);
}

/// A user and mount namespace where `folder` is bound onto itself read-only, held by
/// a `sleep`.
fn namespace_with_read_only(folder: &Path) -> KillOnDrop {
    Command::new("unshare")
        .args([
            "-rm",
            "sh",
            "-c",
            "mount --bind \"$1\" \"$1\" && mount -o remount,bind,ro \"$1\" && exec sleep 600",
            "sh",
            folder.to_str().unwrap(),
        ])
        .stdin(Stdio::null())
        .spawn()
        .map(KillOnDrop)
        .expect("unshare (util-linux)")
}

/// Killed, then started with the history's folder read-only (round-4 audit finding
/// 4b: the writer never recovered once it was writable, and the counter went back):
/// the start restores the counters it can read, the PLC's counter never goes back,
/// and once the folder is writable again storing resumes within the writer's reopen
/// period.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_start_on_a_read_only_folder_recovers_when_it_is_writable_again() {
    let setup = Setup::new(MILLGATE, "read-only-start", "db").await;
    let folder = setup.history.parent().unwrap().to_path_buf();
    let plc = setup.plc();
    let mut first = setup.spawn("first.log");
    plc.bites_after_now(2).await;
    first.kill().unwrap();
    first.wait().unwrap();
    let in_plc = plc.counter();

    let holder = namespace_with_read_only(&folder);
    wait_for(
        "the folder bound read-only",
        Duration::from_secs(10),
        || {
            std::fs::read_to_string(format!("/proc/{}/mountinfo", holder.id()))
                .is_ok_and(|mounts| mounts.contains(folder.to_str().unwrap()))
        },
    )
    .await;
    let mut second = spawn_inside(&setup, &holder, "second.log");
    next_bite_continues(&plc, in_plc).await;
    assert_eq!(setup.metric("millgate_history_state").await, Some(2.0));

    // Writable again: storing resumes.
    let remounted = inside(&holder, "mount")
        .args(["-o", "remount,bind,rw", folder.to_str().unwrap()])
        .status()
        .unwrap();
    assert!(remounted.success());
    let resumed_from = plc.counter();
    let resumed = || {
        HistoryReader::open(&setup.history)
            .and_then(|reader| reader.bites(&Filter::default()))
            .is_ok_and(|bites| bites.iter().any(|b| b.figures.bite_counter > resumed_from))
    };
    let waited = std::time::Instant::now();
    while !resumed() {
        assert!(
            waited.elapsed() < Duration::from_secs(60),
            "storing did not resume within 60 s: {}",
            setup.log_text("second.log")
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert_eq!(setup.metric("millgate_history_state").await, Some(1.0));
    common::terminate(&mut second);
    setup.stop(second).await;
    drop(holder);
}

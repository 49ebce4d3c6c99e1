//! `millgate demo`'s tandem mill as a new user sees it, end to end: the binary runs the
//! demo (seeded), the test scrapes its `/metrics` every 150 ms while the console
//! prints (a scrape that takes over 2 s on a loaded machine is skipped), and reads its
//! history afterwards. The weld (the virtual PLC's weld bit,
//! read by the gateway over Modbus TCP) makes the gateway hold the alarm off
//! (`weld_held_off` counts) with the slow-down request never set before the
//! operator's ramp; the ramp past the critical speed raises the request (on `/metrics`
//! and in the history's alarms) and the PLC slows the mill before chatter develops.
//! That last outcome is the closed loop's in real time: the demo says whether its loop
//! ran so (no PLC cycle late, no stand DAQ block missed; `/metrics` agrees), and on a
//! machine too busy for it the test says so and holds the run to what does not depend
//! on the wall clock (the weld's hold, the request after the ramp, its alarm stored).
//! `--no-tandem` runs the driveline alone.

mod common;

use std::io::{BufRead as _, BufReader};
use std::net::SocketAddr;
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use common::{scrape, scratch, text, KillOnDrop, MILLGATE};
use millgate::history::query::{Filter, HistoryReader};

/// The value of the tandem mill's metric `name` in the exposition `page`.
fn metric(page: &str, name: &str) -> Option<f64> {
    let prefix = format!("millgate_tandem_mill_{name}{{tandem_mill=\"TCM\"}} ");
    page.lines()
        .find_map(|line| line.strip_prefix(&prefix))
        .and_then(|value| value.trim().parse().ok())
}

/// The most blocks any stand channel (`s1_vib` .. `s5_vib`) missed, on `page`.
fn stand_blocks_missed(page: &str) -> f64 {
    page.lines()
        .filter_map(|line| {
            let value = line.strip_prefix("millgate_channel_blocks_missed_total{channel=\"s")?;
            value.split_once("} ")?.1.trim().parse::<f64>().ok()
        })
        .fold(0.0, f64::max)
}

/// One scrape: when, `weld_held_off_total`, `slow_down_request`, `chatter_alarm`, the
/// stands' blocks missed.
#[derive(Debug, Clone, Copy)]
struct Scraped {
    at: Instant,
    held_off: f64,
    request: f64,
    alarm: f64,
    missed: f64,
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_demo_s_weld_holds_the_slow_down_request_off_and_its_ramp_raises_it(
) -> anyhow::Result<()> {
    let scratch = scratch("demo-tandem");
    let db = scratch.path().join("history.db");
    let mut demo = KillOnDrop(
        Command::new(MILLGATE.0)
            .args(["demo", "--duration", "26", "--seed", "1", "--history"])
            .arg(&db)
            .env("RUST_LOG", "error")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()?,
    );
    // The console, line by line with the time each arrived.
    let stdout = demo.stdout.take().expect("piped stdout");
    let (lines_out, lines) = mpsc::channel();
    let reader = std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines() {
            let Ok(line) = line else { break };
            if lines_out.send((Instant::now(), line)).is_err() {
                break;
            }
        }
    });
    let mut console: Vec<(Instant, String)> = Vec::new();
    let mut metrics: Option<SocketAddr> = None;
    let mut scraped: Vec<Scraped> = Vec::new();
    // 26 s of demo (the ramp at 16 s; a loaded machine delays the request), its start-up and the printing after: within 90 s.
    let deadline = Instant::now() + Duration::from_secs(90);
    let mut ended = false;
    while !ended {
        assert!(
            Instant::now() < deadline,
            "the demo did not end: {console:?}"
        );
        loop {
            match lines.try_recv() {
                Ok((at, line)) => {
                    if let Some(address) = line.strip_prefix("Prometheus metrics: http://") {
                        metrics = Some(address.trim_end_matches("/metrics").parse()?);
                    }
                    console.push((at, line));
                }
                Err(mpsc::TryRecvError::Empty) => break,
                Err(mpsc::TryRecvError::Disconnected) => {
                    ended = true;
                    break;
                }
            }
        }
        if let (Some(address), false) = (metrics, ended) {
            // The service stops before the demo's last lines: a failed scrape then is
            // the end, not an error.
            if let Ok(Ok(page)) =
                tokio::time::timeout(Duration::from_secs(2), scrape(address)).await
            {
                if let (Some(held_off), Some(request), Some(alarm)) = (
                    metric(&page, "weld_held_off_total"),
                    metric(&page, "slow_down_request"),
                    metric(&page, "chatter_alarm"),
                ) {
                    scraped.push(Scraped {
                        at: Instant::now(),
                        held_off,
                        request,
                        alarm,
                        missed: stand_blocks_missed(&page),
                    });
                }
            }
        }
        tokio::time::sleep(Duration::from_millis(150)).await;
    }
    reader.join().expect("the console reader");
    let status = demo.wait()?;
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut demo.stderr.take().expect("stderr"), &mut stderr)?;
    let printed: Vec<&str> = console.iter().map(|(_, line)| line.as_str()).collect();
    assert!(status.success(), "{}\n{stderr}", printed.join("\n"));
    println!("{}", printed.join("\n"));

    let when = |what: &str| {
        console
            .iter()
            .find(|(_, line)| line.contains(what))
            .map(|(at, _)| *at)
            .unwrap_or_else(|| panic!("no line with {what:?}: {printed:#?}"))
    };
    let weld = when("TCM  weld in the mill");
    let ramp = when("TCM  the operator ramps the mill");
    // The request, raised after the ramp (a gateway far behind the wall clock may not
    // raise it within the run: only a run in real time must).
    let raised = console
        .iter()
        .find(|(_, line)| line.contains("TCM  slow-down request raised"))
        .map(|(at, _)| *at);
    assert!(weld < ramp, "{printed:#?}");
    assert!(raised.is_none_or(|raised| ramp < raised), "{printed:#?}");
    // Whether the closed loop ran in real time, as the demo says and `/metrics` saw.
    let timing = printed
        .iter()
        .find(|l| l.starts_with("tandem mill TCM: the closed loop"))
        .unwrap_or_else(|| panic!("no word on the loop's timing: {printed:#?}"));
    let real_time = timing.contains("ran in real time");
    let missed_seen = scraped.last().map_or(0.0, |s| s.missed);
    assert!(
        !real_time || missed_seen == 0.0,
        "{timing}, but /metrics counted {missed_seen} stand blocks missed"
    );
    if real_time {
        assert!(raised.is_some(), "no slow-down request: {printed:#?}");
        assert!(
            printed
                .iter()
                .any(|l| l.contains("chatter never developed")),
            "{printed:#?}"
        );
    } else {
        println!("{timing}: whether chatter developed is not asserted");
    }

    // The weld held windows off (the counter only moves in the weld hold, over before
    // the ramp: the console's line at its end says how many, and that nothing was
    // requested), and before the ramp nothing was requested or alarmed.
    let hold_over = printed
        .iter()
        .find_map(|l| l.split_once("TCM  weld hold over: "))
        .map(|(_, said)| said)
        .unwrap_or_else(|| panic!("no end of the weld hold: {printed:#?}"));
    let (held, rest) = hold_over.split_once(' ').expect("a count");
    assert!(rest.ends_with("slow-down request never set"), "{hold_over}");
    if real_time {
        assert!(held.parse::<u64>()? > 0, "{hold_over}");
        assert!(
            scraped.iter().any(|s| s.held_off > 0.0),
            "/metrics never counted a window held off: {scraped:?}"
        );
    } else {
        // A gateway behind the wall clock may hold the weld's windows off after the
        // console's moment: by the end, it has.
        let summary = printed
            .iter()
            .find_map(|l| l.split_once(" held off by the weld hold"))
            .and_then(|(before, _)| before.rsplit_once(", "))
            .map(|(_, count)| count)
            .unwrap_or_else(|| panic!("no summary of the mill: {printed:#?}"));
        assert!(summary.parse::<u64>()? > 0, "{summary} held off");
    }
    let before: Vec<&Scraped> = scraped.iter().filter(|s| s.at < ramp).collect();
    assert!(
        before.len() >= 10,
        "scraped {} times before the ramp",
        before.len()
    );
    assert!(
        before.iter().all(|s| s.request == 0.0 && s.alarm == 0.0),
        "requested or alarmed before the ramp: {before:?}"
    );
    // After it: the request raised.
    assert!(
        raised.is_none() || scraped.iter().any(|s| s.at > ramp && s.request == 1.0),
        "no request after the ramp: {scraped:?}"
    );

    // The history holds the alarm the ramp raised, once.
    let alarms = HistoryReader::open(&db)?.alarms(&Filter {
        name: Some("TCM".into()),
        ..Filter::default()
    })?;
    let raised: Vec<_> = alarms
        .iter()
        .filter(|a| a.kind == "chatter_alarm" && a.event == "raised")
        .collect();
    if real_time {
        assert_eq!(raised.len(), 1, "{alarms:?}");
    } else {
        println!("chatter alarms raised: {}", raised.len());
    }
    Ok(())
}

#[test]
fn no_tandem_runs_the_driveline_alone() {
    let scratch = scratch("demo-no-tandem");
    let db = scratch.path().join("history.db");
    let output = MILLGATE.run(&[
        "demo",
        "--duration",
        "3",
        "--no-tandem",
        "--history",
        db.to_str().expect("UTF-8 path"),
    ]);
    let said = text(&output);
    assert!(output.status.success(), "{said}");
    assert!(said.contains("bites analysed"), "{said}");
    assert!(!said.contains("TCM"), "{said}");
}

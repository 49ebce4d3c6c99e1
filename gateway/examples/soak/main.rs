//! Load bench and soak: `millgate run` (the release binary, as a separate process,
//! optionally pinned to one core with `taskset`) watching N drivelines at 2 kHz and M
//! tandem-mill stands at 2.5 or 10 kHz streamed by virtual DAQs, with the history,
//! the web page, `/metrics`, the HMI server and a Sparkplug B node (into a local
//! Debian `mosquitto`) on; the history keeps every bite's capture (its default).
//!
//! - Drivelines: the demo's simulated bars (`millgate_sim::devices::demo`, the Table 2
//!   driveline with a growing spindle gap, a bite every 2.0 s), each driveline's
//!   copy started 0.2 s after the previous one's (so the bites fall on 10 phases of
//!   the bar: about N / 10 complete in the same block, a harsher case than a train
//!   whose stands bite one after another), the demo's model for the wear and gap
//!   diagnosis; 8 torque channels per DAQ (blocks of 100 samples, polled every 20 ms).
//! - Tandem mills of up to 5 stands, one accelerometer per stand: seeded Gaussian noise
//!   (2 m/s^2 RMS) looped, the band-gain chatter detector of
//!   `config/examples/tandem-5stand.toml`; 8 channels per DAQ, blocks of 120 samples
//!   polled at a third of the block period (at most 20 ms).
//! - Every sample period: an HMI reads the first 48 registers, a web client GETs `/`
//!   and `/api/overview`, a Prometheus scrape of `/metrics`.
//! - Bite -> PLC: the virtual PLC records the time of every write, the torque DAQs
//!   the time and sequence of every read. The latency of a bite is the write that first
//!   holds its bite counter less the answer that delivered the block completing its
//!   window: the last delivery of its channel before the write, when the window's last
//!   sample (the bite's time in the history plus the window after the trigger) is
//!   within a block period of it; otherwise (a write more than a block after) from
//!   that last sample, an upper bound. So the latency covers the gateway's reading of
//!   the answer, the analysis, the history commit the PLC writer waits for and the
//!   Modbus write, not the wait for the DAQ's block to fill and be polled (up to 50 +
//!   20 ms here), which is the DAQ's; the summary also gives the latency from the
//!   window's last sample, that wait included.
//!
//! Each load point prints its samples (RSS, descriptors, threads, CPU, bites, blocks
//! missed, answers) and a summary row; a load point passes with no block missed after
//! the warm-up, every bite in the history and at the PLC, the web page and `/metrics`
//! answering every time, and bite -> PLC p99 under `--p99-limit-ms` (5 ms). A sweep (`--drivelines
//! 4,8,16`: lists are stepped together, a single value is held) stops at the first
//! point that fails. The bench's own virtual DAQs publish on its tokio timers: the
//! `stall_ms` column is the bench's longest timer lateness in the sample period; a stall
//! near a block period (50 ms) makes a DAQ skip a block, which the gateway counts as
//! missed though it did not fall behind (run the bench pinned to the other core:
//! `taskset -c 0`); `bench_%` is the bench's own CPU (its DAQs, PLC and clients, not
//! mosquitto) in the sample period, of one core; `wait_%` the time the gateway's
//! threads were ready to run but waited for a core in that period (their scheduler
//! statistics' `run_delay`), of one core like `cpu_%`: near `cpu_%`, its work waited
//! for a core about as long as it ran; `steal_%` the machine's CPU time a
//! hypervisor gave to other guests in that period (`/proc/stat`), of all cores: on a
//! shared virtual machine the latency moves with it. After each point, the gateway's own
//! latency histograms from its last `/metrics` (`millgate_bite_to_plc_seconds`,
//! `millgate_block_wait_seconds` and a bite's stages, `millgate_bite_stage_seconds`:
//! the whole run, the means and the shares within bucket bounds).
//!
//! ```sh
//! cargo build --release -p millgate --bin millgate --example soak
//! # the sweep: the gateway on core 1
//! target/release/examples/soak --cpu 1 --duration 60 --drivelines 4,8,16,32 --tandem-stands 0
//! # the soak: an hour at one load, a sample a minute
//! target/release/examples/soak --cpu 1 --duration 3600 --every 60 --drivelines 8 --tandem-stands 5
//! ```
//!
//! Options: `--duration` s per load point (default 600), `--every` s between samples
//! (10; a sample is also taken at the warm-up's end, where the figures after it start),
//! `--warm-up` s not counted (15), `--drivelines` list (1), `--tandem-stands` list
//! (0), `--tandem-rate-hz` (2500), `--cpu` the core to pin the gateway to (none),
//! `--p99-limit-ms` (5), `--keep-going` (step on after a failed point), `--millgate`
//! the binary (the one beside this example's folder), `--analysis-workers` the
//! gateway's `[analysis] workers` (left out: its default, one per core),
//! `--plc-requests-in-flight` the PLC output's `requests_in_flight`, and
//! `--daq-requests-in-flight` the DAQ sources' (left out: their default, 1).
//! `--help` lists them.

mod bites;
mod daqs;
mod options;
mod point;
mod probe;
mod samples;
mod summary;

use crate::options::Options;
use crate::point::run_point;
use crate::summary::print_table;

// Two workers whatever the bench is pinned to: the DAQs publish on one while the
// other waits on the gateway.
#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> anyhow::Result<()> {
    let options = Options::from_args()?;
    // Ctrl-C or SIGTERM (a `timeout`, a CI job cancelled) ends the run by dropping it:
    // the gateway, the broker and the devices of the point under way are killed and
    // reaped by their guards. Killed by the signal's default action instead, the
    // bench would leave them running.
    let mut terminate = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
    tokio::select! {
        outcome = run_points(&options) => outcome,
        _ = tokio::signal::ctrl_c() => stopped("interrupted"),
        _ = terminate.recv() => stopped("terminated"),
    }
}

/// The bench's end on a signal: the point under way was dropped (its processes
/// killed); a failure status, as the points did not all run.
fn stopped(how: &str) -> anyhow::Result<()> {
    anyhow::bail!("{how}: the load point under way was stopped and its processes killed")
}

/// Every load point of `options`, in turn, with the table after each.
async fn run_points(options: &Options) -> anyhow::Result<()> {
    let mut summaries = Vec::new();
    for (drivelines, stands) in options.load_points()? {
        let summary = run_point(options, drivelines, stands).await?;
        let passed = summary.passed(options.p99_limit_ms);
        summaries.push(summary);
        print_table(&summaries, options.p99_limit_ms);
        if !passed && !options.keep_going {
            println!("stopped: this load point failed");
            break;
        }
    }
    Ok(())
}

//! The chatter closed loop in real time, with the gateway in it: the online tandem mill
//! ([`crate::tandem::online`]) simulated one PLC cycle at a time, each cycle's stand
//! accelerations handed to the field (a streaming [`super::virtual_daq::VirtualDaq`],
//! or a CAN node) once the cycle has passed on the wall clock, and the mill PLC's
//! program: once per cycle it reads the slow-down request from its own holding
//! registers, where the gateway writes its register map (FC 16), and gives it to the
//! speed automation ([`crate::tandem::control`]). The gateway only raises the bit; the
//! PLC decides the speed.
//!
//! Timing: cycle `k` covers simulated time `[k, k + 1)` cycles; at wall time `k` cycles
//! after the start the rig hands over cycle `k - 1`'s samples (acquired by then), reads
//! the request, and simulates cycle `k` with it. Simulated time is wall time, one cycle
//! behind at most.

use std::io;
use std::time::{Duration, Instant};

use super::virtual_plc::VirtualPlc;
use crate::tandem::control::{SlowDownEvent, SpeedControl};
use crate::tandem::online::{OnlineError, OnlineMill};
use crate::tandem::simulate::{Record, RunError};

/// Where the mill PLC reads the slow-down request: a bit of one of its holding
/// registers (the gateway's `NAME.flags` at `register_base` + its address, bit 3).
#[derive(Debug, Clone)]
pub struct RequestBit {
    /// The PLC the gateway writes.
    pub plc: VirtualPlc,
    /// Holding register.
    pub register: usize,
    /// Bit, 0 = least significant.
    pub bit: u16,
}

impl RequestBit {
    /// The request as the PLC's registers hold it now.
    pub(crate) fn read(&self) -> bool {
        self.plc.holding_bit(self.register, self.bit)
    }
}

/// Why the rig stopped.
#[derive(Debug, thiserror::Error)]
pub enum RigError {
    /// The mill refused a setting or its simulation failed.
    #[error(transparent)]
    Online(#[from] OnlineError),
    /// Handing the samples to the field failed.
    #[error("publishing the stand samples: {0}")]
    Publish(#[from] io::Error),
}

/// One cycle of a rig run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigCycle {
    /// Simulated time at the cycle's end, s.
    pub t_s: f64,
    /// Exit speed at the cycle's end, m/s.
    pub speed_m_s: f64,
    /// The request as the PLC read it for this cycle.
    pub request: bool,
    /// Chatter amplitude over the cycle (tension swing over its developed limit).
    pub swing: f64,
    /// When the cycle's samples were handed to the field (wall clock).
    pub published: Option<Instant>,
}

/// What a rig run did.
#[derive(Debug, Clone, PartialEq)]
pub struct RigRun {
    /// Every cycle.
    pub cycles: Vec<RigCycle>,
    /// When chatter developed, s (None: never).
    pub developed_s: Option<f64>,
    /// The automation's slow-downs.
    pub events: Vec<SlowDownEvent>,
    /// Cycles handed over more than a cycle late (the machine could not keep up).
    pub late: usize,
}

/// Runs `mill` for `cycles` PLC cycles in real time: `operator` may change the
/// automation's setpoint at the start of each cycle (given the simulated time),
/// `request` is read once per cycle, and `publish` gets each cycle's samples (see the
/// module docs). The run ends early, without an error, when the simulation leaves the
/// numbers far past developed chatter.
pub async fn run(
    mill: &mut OnlineMill,
    request: &RequestBit,
    cycles: usize,
    mut operator: impl FnMut(f64, &mut SpeedControl),
    mut publish: impl AsyncFnMut(&Record) -> io::Result<()>,
) -> Result<RigRun, RigError> {
    let cycle = Duration::from_secs_f64(mill.cycle_s());
    let mut ticks = tokio::time::interval(cycle);
    ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
    let mut pending: Option<Record> = None;
    let mut run = RigRun {
        cycles: Vec::with_capacity(cycles),
        developed_s: None,
        events: Vec::new(),
        late: 0,
    };
    let start = Instant::now();
    for k in 0..=cycles {
        ticks.tick().await;
        if let Some(samples) = pending.take() {
            publish(&samples).await?;
            let now = Instant::now();
            if now.duration_since(start) > cycle.mul_f64(k as f64 + 1.0) {
                run.late += 1;
            }
            if let Some(last) = run.cycles.last_mut() {
                last.published = Some(now);
            }
        }
        if k == cycles {
            break;
        }
        let requested = request.read();
        let time_s = mill.time_s();
        operator(time_s, mill.control_mut());
        let mut samples = mill.record(mill.cycle_samples);
        let truth = match mill.cycle(requested, &mut samples) {
            Ok(truth) => truth,
            Err(OnlineError::Run(RunError::Diverged { .. })) => break,
            Err(error) => return Err(error.into()),
        };
        pending = Some(samples);
        run.cycles.push(RigCycle {
            t_s: truth.time_s,
            speed_m_s: truth.speed_m_s,
            request: requested,
            swing: truth.swing,
            published: None,
        });
    }
    run.developed_s = mill.developed_s();
    run.events = mill.control().events().to_vec();
    Ok(run)
}

//! Bite -> PLC latency bookkeeping: the blocks the torque DAQs delivered, the bite
//! counters the PLC received, the bites the history stored, and the quantiles of the
//! latencies between them.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::path::Path;
use std::time::{Duration, SystemTime};

use anyhow::Context as _;
use millgate::outputs::modbus::register_map::decode_u32;
use millgate::state::time::UtcTime;
use millgate_config::layout::BLOCK_REGISTERS;
use millgate_sim::devices::modbus_bank::ReadRecord;
use millgate_sim::devices::virtual_plc::VirtualPlc;

use crate::daqs::{CHANNELS_PER_DAQ, DRIVELINE_BLOCK, DRIVELINE_RATE_HZ, POST_TRIGGER_S};

/// Bite counters seen at the PLC and in the history, and the latencies between them.
#[derive(Default)]
pub(crate) struct Bites {
    /// The PLC's holding registers as the writes left them.
    plc_registers: Vec<u16>,
    /// Per driveline: the last bite counter the PLC held.
    plc_counter: Vec<u32>,
    /// (driveline, bite counter) -> the first write holding it.
    at_plc: HashMap<(usize, u32), SystemTime>,
    /// (driveline, bite counter) -> the bite's time and whether it is degraded.
    in_history: HashMap<(usize, u32), (UtcTime, bool)>,
    last_history_id: i64,
    /// Per driveline: the last block sequence its DAQ answered a read of its channel
    /// with, and the times of the answers that brought a new block (its deliveries),
    /// oldest first, those of the last [`Bites::DELIVERIES_KEPT`].
    deliveries: Vec<(Option<u16>, VecDeque<SystemTime>)>,
    /// Latencies of the bites after the warm-up, from the delivery of the block that
    /// completed the window, ms.
    pub(crate) latencies_ms: Vec<f64>,
    /// The same bites' latencies from their window's last sample, ms: an upper bound
    /// that includes the wait for the rest of the block and for the poll.
    pub(crate) from_sample_ms: Vec<f64>,
    /// Bites whose block could not be told from the deliveries (a write more than a
    /// block period after it): their latency is the upper bound.
    pub(crate) unattributed: usize,
    measured: std::collections::HashSet<(usize, u32)>,
}

impl Bites {
    /// How long block deliveries are kept: past the sample period that measures the
    /// bites they completed.
    const DELIVERIES_KEPT: Duration = Duration::from_secs(300);

    /// Takes the reads torque DAQ `daq` answered: a read of a channel's block with a
    /// sequence not read before delivered that block.
    pub(crate) fn daq_reads(&mut self, daq: usize, reads: Vec<ReadRecord>) {
        for read in reads {
            let driveline = daq * CHANNELS_PER_DAQ + usize::from(read.address / BLOCK_REGISTERS);
            if self.deliveries.len() <= driveline {
                self.deliveries
                    .resize(driveline + 1, (None, VecDeque::new()));
            }
            let (last, times) = &mut self.deliveries[driveline];
            if *last != Some(read.first_word) {
                *last = Some(read.first_word);
                times.push_back(read.time);
            }
        }
        let Some(keep) = SystemTime::now().checked_sub(Self::DELIVERIES_KEPT) else {
            return;
        };
        for (_, times) in &mut self.deliveries {
            while times.front().is_some_and(|&time| time < keep) {
                times.pop_front();
            }
        }
    }

    /// Takes the PLC's new writes into a copy of its registers (a map longer than
    /// one request is written in several, and a counter may straddle two): where a
    /// driveline's bite counter rises, every counter up to the new one is at the PLC
    /// from that write on.
    pub(crate) fn plc_writes(&mut self, plc: &VirtualPlc, counters: &[usize]) {
        self.plc_counter.resize(counters.len(), 0);
        for write in plc.take_write_log() {
            let start = usize::from(write.address);
            let end = start + write.words.len();
            if self.plc_registers.len() < end {
                self.plc_registers.resize(end, 0);
            }
            self.plc_registers[start..end].copy_from_slice(&write.words);
            for (driveline, &register) in counters.iter().enumerate() {
                if register + 2 <= start || register >= end {
                    continue;
                }
                let Some(counter) = self
                    .plc_registers
                    .get(register..register + 2)
                    .and_then(decode_u32)
                else {
                    continue;
                };
                for bite in self.plc_counter[driveline] + 1..=counter {
                    self.at_plc.insert((driveline, bite), write.time);
                }
                self.plc_counter[driveline] = self.plc_counter[driveline].max(counter);
            }
        }
    }

    /// Reads the bites the history has stored since the last call.
    pub(crate) fn history(
        &mut self,
        path: &Path,
        names: &HashMap<String, usize>,
    ) -> anyhow::Result<()> {
        let db = rusqlite::Connection::open_with_flags(
            path,
            rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY,
        )?;
        db.busy_timeout(Duration::from_secs(2))?;
        let mut query = db.prepare(
            "SELECT id, driveline, bite_counter, time, degraded FROM bites WHERE id > ?1 ORDER BY id",
        )?;
        let mut rows = query.query([self.last_history_id])?;
        while let Some(row) = rows.next()? {
            let id: i64 = row.get(0)?;
            let name: String = row.get(1)?;
            let counter: u32 = row.get(2)?;
            let time: String = row.get(3)?;
            let degraded: bool = row.get(4)?;
            let driveline = *names
                .get(&name)
                .with_context(|| format!("the history names an unknown driveline {name}"))?;
            let time = UtcTime::parse(&time)
                .map_err(|error| anyhow::anyhow!("history time {time:?}: {error}"))?;
            self.in_history
                .insert((driveline, counter), (time, degraded));
            self.last_history_id = id;
        }
        Ok(())
    }

    /// Latencies of the bites both at the PLC and in the history, timed after
    /// `measured_from`, not yet measured.
    pub(crate) fn measure(&mut self, measured_from: SystemTime) {
        // The window's last sample after the bite's time (the trigger), and the torque
        // DAQs' block period.
        let after_trigger = Duration::from_secs_f64(
            ((POST_TRIGGER_S * DRIVELINE_RATE_HZ).round() - 1.0) / DRIVELINE_RATE_HZ,
        );
        let block_period = Duration::from_secs_f64(f64::from(DRIVELINE_BLOCK) / DRIVELINE_RATE_HZ);
        for (key, (time, _)) in &self.in_history {
            if self.measured.contains(key) {
                continue;
            }
            let Some(written) = self.at_plc.get(key) else {
                continue;
            };
            self.measured.insert(*key);
            let complete = time.to_system() + after_trigger;
            if complete < measured_from {
                continue;
            }
            let ms_since = |from: SystemTime| {
                written
                    .duration_since(from)
                    .map_or_else(|early| -early.duration().as_secs_f64(), |d| d.as_secs_f64())
                    * 1e3
            };
            self.from_sample_ms.push(ms_since(complete));
            // The block that completed the window: the last delivered before the write,
            // when the window's last sample is in it. The gateway dates a block's last
            // sample at its arrival and the others back from it, so the window's last
            // sample is at most a block period (and the history's rounding down to the
            // ms) before the delivery; an earlier one was in an earlier block.
            let block = self
                .deliveries
                .get(key.0)
                .and_then(|(_, times)| times.iter().rev().find(|&&time| time <= *written))
                .filter(|&&delivered| {
                    complete + block_period + Duration::from_millis(1) >= delivered
                });
            match block {
                Some(&delivered) => self.latencies_ms.push(ms_since(delivered)),
                None => {
                    self.unattributed += 1;
                    self.latencies_ms.push(ms_since(complete));
                }
            }
        }
    }

    /// The bites in the history marked degraded.
    pub(crate) fn degraded(&self) -> usize {
        self.in_history
            .values()
            .filter(|(_, degraded)| *degraded)
            .count()
    }

    /// Of the bites `counted` (per driveline, its bites 1 to the count): how many are
    /// not in the history, and how many not at the PLC.
    pub(crate) fn missing(&self, counted: &BTreeMap<usize, u32>) -> (usize, usize) {
        let mut not_in_history = 0;
        let mut not_at_plc = 0;
        for (&driveline, &count) in counted {
            for bite in 1..=count {
                not_in_history += usize::from(!self.in_history.contains_key(&(driveline, bite)));
                not_at_plc += usize::from(!self.at_plc.contains_key(&(driveline, bite)));
            }
        }
        (not_in_history, not_at_plc)
    }
}

/// Whether the quantile `q` of `sorted` is below `limit` (true without a value: no
/// bite measured, as at a load point without drivelines).
pub(crate) fn quantile_below(sorted: &[f64], q: f64, limit: f64) -> bool {
    let value = quantile(sorted, q);
    value.is_nan() || value < limit
}

/// The quantile `q` (0 to 1) of `sorted`: the nearest sample, NaN without one.
pub(crate) fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

//! What acquisition tasks hand to analysis: samples in engineering units.

use std::time::{Instant, SystemTime};

/// One message from a reader task (`DaqReader`, `CanReader`) to the analysis task.
///
/// `channel` is the index of the channel in [`millgate_config::Config::channels`].
#[derive(Debug, Clone, PartialEq)]
pub enum Acquired {
    /// Consecutive samples of one channel, oldest first, in engineering units
    /// (raw * scale + offset).
    ///
    /// `received`: when the last of `values` was received, when the reader knows it.
    /// The CAN reader gives the kernel's receive timestamp of the frame that carried
    /// it (`SO_TIMESTAMPNS`), or the time it read the frame when the kernel gave none;
    /// the Modbus reader gives `None` (a block's arrival says little about when its
    /// samples were taken). Analysis then dates bites from it rather than from the
    /// time it processes them.
    Samples {
        /// Index of the channel in the configuration.
        channel: usize,
        /// The samples, oldest first, in engineering units.
        values: Vec<f64>,
        /// When the last of `values` was received, when known (see above).
        received: Option<SystemTime>,
        /// When the reader handed the samples over: a Modbus DAQ's block when its
        /// read returned, a CAN batch when it was read. The analysis measures from it
        /// how long blocks wait for it and bites take to reach the PLC
        /// (`crate::state::latency`).
        handed: Instant,
    },
    /// Samples were lost on this channel between the previous and the next
    /// `Samples`: the analysis must not join across it. `missed_samples` when known.
    Gap {
        /// Index of the channel in the configuration.
        channel: usize,
        /// Samples lost, when the reader knows (Modbus sequence numbers).
        missed_samples: Option<u64>,
    },
    /// The latest value of a scalar process value.
    ProcessValue {
        /// Index of the channel in the configuration.
        channel: usize,
        /// The value in engineering units.
        value: f64,
    },
    /// The latest text of a text channel (`type = "ascii"`, a coil id), or why its
    /// registers held none (never used as a value).
    Text {
        /// Index of the channel in the configuration.
        channel: usize,
        /// The text, or why not.
        text: Result<millgate_config::text::AsciiText, millgate_config::text::TextError>,
    },
}

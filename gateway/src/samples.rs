//! What acquisition tasks hand to analysis: samples in engineering units.

/// One message from a reader task (`DaqReader`, `CanReader`) to the analysis task.
///
/// `channel` is the index of the channel in [`millgate_config::Config::channels`].
#[derive(Debug, Clone, PartialEq)]
pub enum Acquired {
    /// Consecutive samples of one channel, oldest first, in engineering units
    /// (raw * scale + offset).
    Samples { channel: usize, values: Vec<f64> },
    /// Samples were lost on this channel between the previous and the next
    /// `Samples`: the analysis must not join across it. `missed_samples` when known.
    Gap {
        channel: usize,
        missed_samples: Option<u64>,
    },
    /// The latest value of a scalar process value.
    ProcessValue { channel: usize, value: f64 },
}

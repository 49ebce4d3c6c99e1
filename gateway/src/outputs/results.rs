//! The gateway's latest results: what analysis produced, what outputs publish.

use crate::field::source_health::SourceStatus;

/// Latest results of one driveline. `None` = not computed (yet), published with
/// its quality bit cleared.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DrivelineResults {
    /// Bites analysed since start (wraps at u32).
    pub bite_counter: u32,
    /// Time of the last bite, Unix seconds.
    pub last_bite_unix_s: Option<u32>,
    /// Static (settled) torque of the last bite, kN*m.
    pub static_torque_knm: Option<f64>,
    /// Peak torque of the last bite, kN*m.
    pub peak_torque_knm: Option<f64>,
    /// Torque amplification factor of the last bite.
    pub taf: Option<f64>,
    /// First minus second oscillation period of the last bite, s.
    pub first_period_shift_s: Option<f64>,
    /// First natural frequency identified from the last bite, Hz.
    pub beta1_hz: Option<f64>,
    /// Second natural frequency identified from the last bite, Hz.
    pub beta2_hz: Option<f64>,
    /// Wear index of the last bite: measured TAF / linear reference TAF - 1 (0 = like
    /// the linear reference; grows with opened backlash). `None` without a model.
    pub wear_index: Option<f64>,
    /// Wear trend: exponentially weighted mean of the wear index over bites
    /// ([`crate::analysis::wear::next_trend`]); `None` until the first index after start or reset.
    pub wear_trend: Option<f64>,
    /// The last bite's window had gaps, NaN or saturated samples.
    pub last_bite_degraded: bool,
    /// TAF at or above the warning threshold at the last bite.
    pub warning: bool,
    /// TAF reached the alarm threshold; latched until acknowledged.
    pub alarm: bool,
    /// The torque channel's source is stale or lost: every value is flagged.
    pub source_stale: bool,
    /// The values are from before the last restart (restored from the history);
    /// cleared by the next bite.
    pub restored: bool,
}

/// Latest chatter metrics of one tandem mill (see [`crate::analysis::chatter_monitor`]). `None` = not
/// valid: not computed yet, or the window restarted after a gap or a stale stand.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MillResults {
    /// Windows evaluated since start.
    pub evaluations: u64,
    /// RMS difference of adjacent stands' principal frequencies, Hz.
    pub sigma_n_hz: Option<f64>,
    /// Mean correlation of adjacent stands' chatter-band vibration, -1..=1.
    pub k_mean: Option<f64>,
    /// Mean of the stands' principal frequencies in the chatter band, Hz.
    pub chatter_frequency_hz: Option<f64>,
    /// sigma_n <= sigma_min in the last window.
    pub warning: bool,
    /// Both chatter conditions held in a window; latched until acknowledged.
    pub alarm: bool,
    /// A stand's source is stale or lost, or the window restarted after a gap:
    /// every value is flagged.
    pub source_stale: bool,
}

/// The gateway's own state as published in the status register.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GatewayState {
    /// Built, tasks not started yet.
    #[default]
    Starting,
    /// Readers, analysis and outputs running.
    Running,
    /// Shut down: the values are the last ones and will not change.
    Stopped,
}

/// Everything the outputs publish.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Results {
    /// Starting, running or stopped.
    pub state: GatewayState,
    /// Incremented on every write to the PLC.
    pub heartbeat: u16,
    /// Per source, in config order: Modbus sources first, then CAN sources.
    pub sources: Vec<Option<SourceStatus>>,
    /// Per driveline, in config order.
    pub drivelines: Vec<DrivelineResults>,
    /// Per tandem mill, in config order.
    pub mills: Vec<MillResults>,
}

impl Results {
    /// Empty results for `sources` sources, `drivelines` drivelines and `mills` mills.
    pub fn new(sources: usize, drivelines: usize, mills: usize) -> Self {
        Self {
            state: GatewayState::Starting,
            heartbeat: 0,
            sources: vec![None; sources],
            drivelines: vec![DrivelineResults::default(); drivelines],
            mills: vec![MillResults::default(); mills],
        }
    }
}

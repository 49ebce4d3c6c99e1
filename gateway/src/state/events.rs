//! What the history records: one [`HistoryEvent`] per thing that happened, built
//! where it happened (the analysis for bites, alarms, chatter and the commands it
//! applies, the outage monitor for sources) and written by the history's writer thread.

use super::commands::CommandOrigin;
use super::results::DrivelineResults;
use super::time::UtcTime;

/// State of a driveline's wear diagnosis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WearState {
    /// The gap is below the warning threshold.
    Ok,
    /// At or above the warning threshold.
    Warning,
    /// At or above the alarm threshold.
    Alarm,
}

impl WearState {
    /// `ok`, `warning`, `alarm`, as stored.
    pub fn name(self) -> &'static str {
        match self {
            WearState::Ok => "ok",
            WearState::Warning => "warning",
            WearState::Alarm => "alarm",
        }
    }
}

/// The gap diagnosis of a driveline at one bite: the opened gap pooled over recent
/// bites, with its 90% interval (`analysis::gap_estimate::GapEstimate` as published;
/// `None` in [`BiteRecord::gap`] while the gap maps are not ready, and for drivelines
/// without a model).
#[derive(Debug, Clone, PartialEq)]
pub struct GapEstimate {
    /// The pooled gap estimate, mrad referred to the rolls.
    pub gap_mrad: f64,
    /// Lower end of its 90% interval, mrad.
    pub gap_low_mrad: f64,
    /// Upper end of its 90% interval, mrad.
    pub gap_high_mrad: f64,
    /// The coupling holding the gap (model index, 0 = motor side), `None` when the
    /// bites cannot tell. Stored as its decimal text in the `gap_coupling` columns.
    pub coupling: Option<usize>,
    /// Bites pooled into the estimate.
    pub bites_pooled: usize,
    /// Ok, warning or alarm against the gap thresholds.
    pub state: WearState,
    /// The wear alarm is latched (until acknowledged).
    pub alarm_latched: bool,
}

/// A bite's entry in its driveline's gap pool: what the gap diagnosis needs to pool
/// it again after a restart. The same fields as `analysis::gap_estimate::GapObservation`
/// (the outputs do not import the analysis; the service converts).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PooledBite {
    /// Static (settled) torque, kN*m.
    pub static_torque_knm: f64,
    /// Torque amplification factor.
    pub taf: f64,
    /// Standard deviation of `taf` from the window's noise.
    pub taf_sigma: f64,
    /// First minus second oscillation period, s, when measured.
    pub period_shift_s: Option<f64>,
    /// Standard deviation of `period_shift_s`, s (>= 0).
    pub period_shift_sigma_s: f64,
}

/// One analysed bite with the driveline's published state after it.
#[derive(Debug, Clone, PartialEq)]
pub struct BiteRecord {
    /// The driveline's name.
    pub driveline: String,
    /// The torque channel's name.
    pub channel: String,
    /// When the bite happened.
    pub time: UtcTime,
    /// Static torque, kN*m.
    pub static_torque_knm: f64,
    /// Peak torque, kN*m.
    pub peak_torque_knm: f64,
    /// Peak / static, when measured.
    pub taf: Option<f64>,
    /// First oscillation period, s.
    pub first_period_s: Option<f64>,
    /// Second oscillation period, s.
    pub second_period_s: Option<f64>,
    /// First minus second period, s.
    pub period_shift_s: Option<f64>,
    /// Natural frequencies from the eq. (1) fit, Hz, when it converged.
    pub beta_hz: Option<(f64, f64)>,
    /// `good`, `few_crossings` or `low_static` (the transient analysis' quality).
    pub quality: &'static str,
    /// The window had gaps, NaN or saturated samples.
    pub degraded: bool,
    /// TAF of the linear reference the wear index was computed against.
    pub reference_taf: Option<f64>,
    /// Static torque level the reference was simulated at, kN*m.
    pub reference_level_knm: Option<f64>,
    /// Measured minus reference first-period shift, s.
    pub shift_over_linear_s: Option<f64>,
    /// The gap diagnosis after this bite (see [`GapEstimate`]).
    pub gap: Option<GapEstimate>,
    /// What this bite put into the driveline's gap pool (`None`: nothing, e.g. no
    /// model, no TAF or a degraded window): a restart pools the last ones again.
    pub pooled: Option<PooledBite>,
    /// The driveline's published results after this bite (counter, last values,
    /// wear index and trend, warning and latched alarm): what a restart restores.
    pub state: DrivelineResults,
    /// Further state a restart restores, as JSON in `driveline_state.extra` (kept when
    /// `None`), handed back at start in [`crate::history::restore::RestoredDriveline::extra`].
    /// `None` today: the gap pool is restored from the bites' [`BiteRecord::pooled`].
    pub extra_state: Option<serde_json::Value>,
}

/// A change of an alarm or warning.
#[derive(Debug, Clone, PartialEq)]
pub struct AlarmRecord {
    /// When.
    pub time: UtcTime,
    /// The driveline or tandem mill.
    pub subject: String,
    /// Which alarm.
    pub kind: AlarmKind,
    /// Raised, cleared or acknowledged.
    pub event: AlarmEvent,
    /// The analysis, or who acknowledged.
    pub origin: Option<CommandOrigin>,
    /// The value that raised it (TAF, K_mean).
    pub value: Option<f64>,
    /// The threshold it crossed.
    pub threshold: Option<f64>,
}

/// Which alarm or warning a record is about: the key of the flag that carries it
/// (see [`super::catalogue`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AlarmKind {
    /// A driveline's TAF at or above its warning threshold (follows each bite).
    TafWarning,
    /// A driveline's TAF reached its alarm threshold (latched).
    TafAlarm,
    /// A driveline's estimated opened gap at or above its warning threshold (follows
    /// each estimate; cleared by a wear reset).
    GapWarning,
    /// A driveline's gap diagnosis reached its alarm threshold: the pooled gap's 90%
    /// interval lay at or above it (latched).
    GapAlarm,
    /// A tandem mill's chatter warning (follows each window).
    ChatterWarning,
    /// A tandem mill's chatter alarm (latched).
    ChatterAlarm,
}

impl AlarmKind {
    /// Every kind.
    pub const ALL: [AlarmKind; 6] = [
        AlarmKind::TafWarning,
        AlarmKind::TafAlarm,
        AlarmKind::GapWarning,
        AlarmKind::GapAlarm,
        AlarmKind::ChatterWarning,
        AlarmKind::ChatterAlarm,
    ];

    /// As stored: the key of the flag.
    pub fn name(self) -> &'static str {
        match self {
            AlarmKind::TafWarning => "taf_warning",
            AlarmKind::TafAlarm => "taf_alarm",
            AlarmKind::GapWarning => "gap_warning",
            AlarmKind::GapAlarm => "gap_alarm",
            AlarmKind::ChatterWarning => "chatter_warning",
            AlarmKind::ChatterAlarm => "chatter_alarm",
        }
    }

    /// Whether the alarm latches until acknowledged (else it follows the analysis).
    pub fn latched(self) -> bool {
        matches!(
            self,
            AlarmKind::TafAlarm | AlarmKind::GapAlarm | AlarmKind::ChatterAlarm
        )
    }
}

/// What happened to an alarm.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AlarmEvent {
    /// Set by the analysis.
    Raised,
    /// Cleared by the analysis (warnings follow each bite).
    Cleared,
    /// A latched alarm cleared by a command.
    Acknowledged,
}

impl AlarmEvent {
    /// As stored.
    pub fn name(self) -> &'static str {
        match self {
            AlarmEvent::Raised => "raised",
            AlarmEvent::Cleared => "cleared",
            AlarmEvent::Acknowledged => "acknowledged",
        }
    }
}

/// One evaluated chatter window of a mill in a chatter episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChatterWindow {
    /// sigma_n, Hz.
    pub sigma_n_hz: f64,
    /// K_mean.
    pub k_mean: f64,
    /// The chatter frequency, Hz.
    pub frequency_hz: Option<f64>,
    /// Both conditions held (the alarm).
    pub synchronized: bool,
}

/// How a chatter episode or a source outage ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EndedBy {
    /// The analysis saw it end (the chatter warning cleared).
    Analysis,
    /// The source answers again.
    Recovered,
    /// The chatter window restarted (a gap, a stale stand).
    WindowRestart,
    /// The gateway stopped.
    Stop,
}

impl EndedBy {
    /// As stored.
    pub fn name(self) -> &'static str {
        match self {
            EndedBy::Analysis => "analysis",
            EndedBy::Recovered => "recovered",
            EndedBy::WindowRestart => "window_restart",
            EndedBy::Stop => "stop",
        }
    }
}

/// Everything the history records.
#[derive(Debug, Clone, PartialEq)]
pub enum HistoryEvent {
    /// A bite and, when it has wear measures, a wear estimate; updates the
    /// driveline's restorable state.
    Bite(Box<BiteRecord>),
    /// A bite with the samples behind it: one event, so the writer commits both in
    /// one transaction (a crash never leaves a bite without its capture) and before
    /// the PLC sees the bite.
    CapturedBite(Box<BiteRecord>, Box<super::captures::CaptureRecord>),
    /// The samples of a chatter episode or a manual request (a bite's go with it in
    /// [`HistoryEvent::CapturedBite`]).
    Capture(Box<super::captures::CaptureRecord>),
    /// An alarm or warning changed; a latched alarm's change updates the subject's
    /// restorable state.
    Alarm(AlarmRecord),
    /// The wear trend of a driveline was reset by a command.
    WearReset {
        /// When.
        time: UtcTime,
        /// The driveline.
        driveline: String,
        /// Who.
        origin: CommandOrigin,
    },
    /// A chatter episode began (the warning condition set) with its first window.
    ChatterStarted {
        /// When.
        time: UtcTime,
        /// The tandem mill.
        mill: String,
        /// The window that started it.
        window: ChatterWindow,
    },
    /// Another window of a running chatter episode.
    ChatterWindow {
        /// The tandem mill.
        mill: String,
        /// The window.
        window: ChatterWindow,
    },
    /// A chatter episode ended.
    ChatterEnded {
        /// When.
        time: UtcTime,
        /// The tandem mill.
        mill: String,
        /// Why.
        ended_by: EndedBy,
    },
    /// A source stopped answering (stale or lost).
    OutageStarted {
        /// When it was first seen not ok.
        time: UtcTime,
        /// The source.
        source: String,
        /// `stale` or `lost`.
        status: &'static str,
    },
    /// A source outage got worse (stale to lost).
    OutageWorse {
        /// The source.
        source: String,
    },
    /// A source answers again, or the gateway stops during its outage.
    OutageEnded {
        /// When.
        time: UtcTime,
        /// The source.
        source: String,
        /// Blocks lost on its channels during the outage.
        blocks_missed: u64,
        /// Why.
        ended_by: EndedBy,
    },
}

impl HistoryEvent {
    /// Whether the event carries a capture's samples (a bite's, a chatter episode's,
    /// a manual request's): the history counts those it could not store.
    pub fn holds_capture(&self) -> bool {
        matches!(self, Self::CapturedBite(..) | Self::Capture(_))
    }
}

//! What the history records: one [`HistoryEvent`] per thing that happened, built
//! where it happened (the analysis for bites, alarms, chatter and the commands it
//! applies, the outage monitor for sources) and written by the history's writer thread;
//! and what it gives back of a driveline, at a start or when a reload adds one under a
//! name it knows ([`RestoredDriveline`]).

pub use super::catalogue::AlarmKind;
use super::catalogue::{Figure, Subject, Value};
use super::commands::CommandOrigin;
use super::context::{ContextReading, ProcessContext};
use super::results::{DrivelineResults, TandemMillResults};
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

/// What a bite told the gap diagnosis: what the wear trend needs to fold it in again
/// after a restart without a saved trend. The same fields as `analysis::gap_estimate::GapObservation`
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

/// The restorable state of one driveline as the history last recorded it: what a
/// start restores (`history::restore`), and what a driveline a reload adds under a
/// name the history knows resumes.
#[derive(Debug, Clone, PartialEq)]
pub struct RestoredDriveline {
    /// The driveline's name (matched against the configuration's).
    pub name: String,
    /// When the state was last recorded.
    pub updated_at: Option<UtcTime>,
    /// The published results as they were, with `restored` set.
    pub results: DrivelineResults,
    /// The gap's wear trend after the last bite, in its saved form (`None`: no bite
    /// since the last wear reset, no gap diagnosis, or a file from before version 11).
    pub gap_trend: Option<String>,
    /// The last bites since the last wear reset that the gap diagnosis saw, oldest
    /// first, with their times (ms since the epoch), for a trend that cannot be
    /// continued from its saved form: at most 1000.
    pub gap_bites: Vec<(i64, PooledBite)>,
    /// The fatigue ledger after the last bite or reset, in its saved form (`None`: no
    /// ledger, or a file from before version 12).
    pub fatigue_ledger: Option<String>,
}

/// One analysed bite with the driveline's published state after it.
#[derive(Debug, Clone, PartialEq)]
pub struct BiteRecord {
    /// The driveline's name.
    pub driveline: String,
    /// The torque channel's name.
    pub channel: String,
    /// When the bite happened (`figures.last_bite_unix_ms`).
    pub time: UtcTime,
    /// The bite's own figures, as its row in the history keeps them (the catalogue's
    /// figures with a bite column): what its window measured, also from a degraded
    /// window (flagged `last_bite_degraded`; such values are not published), the wear
    /// index and trend after it, the gap estimate it gave (`None` when it gave none),
    /// its counter and its time.
    pub figures: DrivelineResults,
    /// Second oscillation period, s.
    pub second_period_s: Option<f64>,
    /// `good`, `few_crossings` or `low_static` (the transient analysis' quality).
    pub quality: &'static str,
    /// TAF of the linear reference the wear index was computed against.
    pub reference_taf: Option<f64>,
    /// Static torque level the reference was simulated at, kN*m.
    pub reference_level_knm: Option<f64>,
    /// Measured minus reference first-period shift, s.
    pub shift_over_linear_s: Option<f64>,
    /// The gap estimate of `figures` against the gap thresholds, when the bite gave
    /// one.
    pub gap_state: Option<WearState>,
    /// What this bite told the gap diagnosis (`None`: nothing, e.g. no model, no TAF
    /// or a degraded window): a restart without a saved trend folds the last ones in
    /// again.
    pub pooled: Option<PooledBite>,
    /// The driveline's wear trend after this bite, in its saved form (JSON), when the
    /// bite was folded into it: what a restart continues.
    pub gap_trend: Option<String>,
    /// The driveline's fatigue ledger after this bite, in its saved form (JSON), with
    /// `drivelines[].fatigue`: what a restart continues.
    pub fatigue_ledger: Option<String>,
    /// The mill's process context when the bite's window completed (with
    /// `drivelines[].context` and a valid context): the evidence's tags.
    pub context: Option<ProcessContext>,
    /// The driveline's published results after this bite (counter, last values,
    /// wear index and trend, gap estimate, warnings and latched alarms): what a restart
    /// restores (the catalogue's figures with a state column).
    pub state: DrivelineResults,
}

impl BiteRecord {
    /// A clean bite of `driveline` on `channel` at `time` whose row keeps what was
    /// published after it (`state`; its time set to `time`): quality good, no second
    /// period, wear reference, gap verdict or pool entry (set them on the result).
    pub fn clean(driveline: &str, channel: &str, time: UtcTime, state: DrivelineResults) -> Self {
        let state = DrivelineResults {
            last_bite_unix_ms: Some(time.unix_ms()),
            ..state
        };
        Self {
            driveline: driveline.to_owned(),
            channel: channel.to_owned(),
            time,
            figures: state.clone(),
            second_period_s: None,
            quality: "good",
            reference_taf: None,
            reference_level_knm: None,
            shift_over_linear_s: None,
            gap_state: None,
            pooled: None,
            context: None,
            gap_trend: None,
            fatigue_ledger: None,
            state,
        }
    }
}

/// A subject's restorable results after a change that is not a bite (an
/// acknowledgement, a wear reset, a gap estimate from maps just installed, a chatter
/// alarm): the history writes them to its state row.
#[derive(Debug, Clone, PartialEq)]
pub struct StateRecord {
    /// When.
    pub time: UtcTime,
    /// The driveline or tandem mill.
    pub subject: String,
    /// Its results after the change.
    pub results: SubjectResults,
}

/// The results of a subject whose state the history keeps.
#[derive(Debug, Clone, PartialEq)]
pub enum SubjectResults {
    /// A driveline's (boxed: its gap forecast's cone makes it the largest by far).
    Driveline(Box<DrivelineResults>),
    /// A tandem mill's (boxed as the driveline's, so the enum stays small).
    TandemMill(Box<TandemMillResults>),
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

impl AlarmRecord {
    /// The changes of the flags of `R` that carry one of `kinds`, from `was` to `is`
    /// (raised or cleared by the analysis), about `subject` at `time`, with `value`
    /// (what moved them: a gain ratio, a speed margin).
    pub(crate) fn flag_changes<R: Subject>(
        (was, is): (&R, &R),
        kinds: &[AlarmKind],
        (subject, time): (&str, UtcTime),
        value: Option<f64>,
    ) -> Vec<HistoryEvent> {
        let set = |figure: &Figure<R>, r: &R| figure.value(r) == Some(Value::Bool(true));
        R::FIGURES
            .iter()
            .filter_map(|figure| Some((figure, figure.alarm.filter(|k| kinds.contains(k))?)))
            .filter(|(figure, _)| set(figure, was) != set(figure, is))
            .map(|(figure, kind)| {
                HistoryEvent::Alarm(AlarmRecord {
                    time,
                    subject: subject.to_owned(),
                    kind,
                    event: match set(figure, is) {
                        true => AlarmEvent::Raised,
                        false => AlarmEvent::Cleared,
                    },
                    origin: None,
                    value,
                    threshold: None,
                })
            })
            .collect()
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

/// The reset of one component of a driveline's fatigue ledger.
#[derive(Debug, Clone, PartialEq)]
pub struct FatigueResetRecord {
    /// When.
    pub time: UtcTime,
    /// The driveline.
    pub driveline: String,
    /// The component's index in `drivelines[].fatigue.components`.
    pub index: usize,
    /// Its name.
    pub component: String,
    /// The life it had used until the reset.
    pub life_used: f64,
    /// Who.
    pub origin: CommandOrigin,
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
    /// An alarm or warning changed (the subject's state after it comes as a
    /// [`HistoryEvent::State`] or with its bite).
    Alarm(AlarmRecord),
    /// A subject's restorable state changed outside a bite.
    State(StateRecord),
    /// The wear trend of a driveline was reset by a command.
    WearReset {
        /// When.
        time: UtcTime,
        /// The driveline.
        driveline: String,
        /// Who.
        origin: CommandOrigin,
    },
    /// A fatigue ledger component's life was reset by a command (it was replaced).
    FatigueReset(FatigueResetRecord),
    /// A driveline's fatigue ledger in its saved form (after a restore or a reset;
    /// a bite carries its own in [`BiteRecord::fatigue_ledger`]).
    FatigueLedger {
        /// The driveline.
        driveline: String,
        /// The saved form (JSON).
        saved: String,
    },
    /// A chatter episode began (the warning condition set) with its first window.
    ChatterStarted {
        /// When.
        time: UtcTime,
        /// The tandem mill.
        mill: String,
        /// The window that started it.
        window: ChatterWindow,
        /// The mill's process context then; `None` without context tags.
        context: Option<ContextReading>,
        /// The product group whose thresholds judged the window (its name in the
        /// mill's `product_groups`); `None`: the mill's own `gain_thresholds`.
        thresholds_group: Option<String>,
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
    /// A reload applied new thresholds: every driveline's settings from `time` on
    /// (table `driveline_settings`, beside the run's start).
    Settings {
        /// When.
        time: UtcTime,
        /// The drivelines, as the service now runs them.
        drivelines: Vec<millgate_config::Driveline>,
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
    pub(crate) fn holds_capture(&self) -> bool {
        matches!(self, Self::CapturedBite(..) | Self::Capture(_))
    }

    /// For evidence kept with the process context of its time: its subject, what it is
    /// (`episode`: a chatter episode's start; `capture`) and the context; `None` for
    /// any other event and for evidence without context tags.
    pub(crate) fn evidence_context(&self) -> Option<(&str, &'static str, &ContextReading)> {
        match self {
            Self::ChatterStarted { mill, context, .. } => {
                Some((mill.as_str(), "episode", context.as_ref()?))
            }
            Self::CapturedBite(_, capture) | Self::Capture(capture) => Some((
                capture.subject.as_str(),
                "capture",
                capture.context.as_ref()?,
            )),
            _ => None,
        }
    }

    /// Whether the event belongs to the alarm stream ([`super::history::History::alarms`]):
    /// an alarm's change or a source outage's.
    pub(crate) fn is_alarm_stream(&self) -> bool {
        matches!(
            self,
            Self::Alarm(_)
                | Self::OutageStarted { .. }
                | Self::OutageWorse { .. }
                | Self::OutageEnded { .. }
        )
    }
}

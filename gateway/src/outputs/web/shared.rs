//! What the page's handlers share: the configuration's parts they show, the board, the
//! history file, the live results and the kept gap trends.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::watch;

use crate::state::board::Board;

/// What the configuration says about a driveline, for the pages.
#[derive(Debug, Clone)]
pub struct DrivelineInfo {
    /// Its name.
    pub name: String,
    /// TAF warning and alarm thresholds.
    pub taf_warning: f64,
    /// TAF alarm threshold.
    pub taf_alarm: f64,
    /// Gap warning threshold, mrad.
    pub gap_warning_mrad: f64,
    /// Gap alarm threshold, mrad.
    pub gap_alarm_mrad: f64,
    /// Whether it has a model (the gap diagnosis runs only with one).
    pub has_model: bool,
}

/// Everything the handlers share.
#[derive(Debug)]
pub struct WebState {
    /// The configuration's name.
    pub(crate) config_name: String,
    pub(crate) drivelines: Vec<DrivelineInfo>,
    /// Tandem mills: name and stand channel names.
    pub(crate) tandem_mills: Vec<(String, Vec<String>)>,
    /// Rod mills by name.
    pub(crate) rod_mills: Vec<String>,
    /// Sources: name and kind (`modbus`, `can`), Modbus first as in the results.
    pub(crate) sources: Vec<(String, &'static str)>,
    pub(crate) board: Arc<Board>,
    /// The history file, `None` without `[history]`.
    pub(crate) history: Option<PathBuf>,
    pub(crate) request_timeout: Duration,
    /// The live results as `/api/events` sends them (JSON), newest.
    pub(crate) live: watch::Receiver<Arc<String>>,
    /// Gap trends as last fitted, per driveline (the API's `gap_trend`).
    pub(crate) trends: TrendCache,
}

/// Gap trends as last fitted, per driveline: the time of the last bite (Unix ms) they
/// were fitted up to, and the trend. A trend changes only with a new bite (a later
/// wear reset counts from the next bite on), so an overview load looks up one index
/// entry per driveline instead of fitting four weeks of bites again (about 70 ms per
/// driveline on a year of bites, one every 30 s). Retention that deletes bites inside
/// the window leaves the trend as fitted until the next bite.
#[derive(Debug, Default)]
pub(crate) struct TrendCache(
    pub(crate) std::sync::Mutex<std::collections::HashMap<String, (i64, Option<f64>)>>,
);
